// Scenes and runs from Python (py_system.h): a System from a .json or .bullet scene (Scene::load, the CLI's loader
// and its messages), a run of it with ParaView frames as `dvisim run` writes them, and the run summary.
#include <chrono>
#include <cmath>

#include "chrono_like/bullet/bullet_collision_backend.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/io/input_limits.h"
#include "chrono_like/io/output.h"
#include "chrono_like/io/run_control.h"
#include "chrono_like/solver/solver.h"
#include "gpu/gpu_factory.h"
#include "parse.h"
#include "py_system.h"

namespace dvipy {

namespace {

std::unique_ptr<PySystem> loadScene(const std::string& path, const std::vector<std::string>& overrides,
                                    const std::string& backend_in) {
  dvi::requireOneOf("--backend", backend_in, {"auto", "cpu", "gpu"});
  if (path.empty()) throw dvi::InputError("load_scene: empty path (a .json or .bullet scene)");
  dvi::Scene scene = dvi::Scene::load(path, overrides);
  auto s = std::make_unique<PySystem>();
  s->settings = scene.settings;
  s->scene_source = scene.source;
  makeEngine(*s, backend_in);
  dvi::importBullet(*s->sys, scene.bodies());
  return s;
}

// The run summary: the keys of `dvisim run`'s summary.json that describe the steps taken so far.
nlohmann::json summaryJson(const PySystem& s) {
  const dvi::SystemConfig& cfg = s.sys->config();
  const int64_t steps = s.log.steps;
  nlohmann::json j;
  j["scene"] = s.scene_source.empty() ? nlohmann::json(nullptr) : nlohmann::json(s.scene_source);
  j["bodies"] = s.sys->bodies().count();
  j["backend"] = s.sys->backendName();
  j["device"] = s.sys->deviceName();
  j["dt"] = cfg.step.dt;
  j["steps"] = steps;
  j["sim_time"] = s.sys->time();
  j["solver"] = dvi::solverName(cfg.solver.type);
  j["collision"] = dvi::collisionBackendName(cfg.collision.backend);
  j["iterations_mean"] = steps > 0 ? double(s.iterations_sum) / double(steps) : 0.0;
  j["contacts_mean"] = steps > 0 ? double(s.contacts_sum) / double(steps) : 0.0;
  j["max_penetration"] = s.max_penetration;
  j["residual_final"] = s.sys->lastStats().relative_residual;
  j["residual_final_abs"] = s.sys->lastStats().residual;
  dvi::addConvergenceSummary(j, s.sys->convergence(), cfg.solver);
  dvi::addStageSummary(j, s.log);
  j["prune"] = cfg.prune;
  j["wall_time_s"] = s.wall_s;
  j["ms_per_step"] = steps > 0 ? 1000.0 * s.wall_s / double(steps) : 0.0;
  return j;
}

py::object toPython(const nlohmann::json& j) {
  return py::module_::import("json").attr("loads")(j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace));
}

std::vector<dvi::BodyState> bodyStates(PySystem& s) {
  s.sys->syncToHost();
  const dvi::BodyArrays& b = s.sys->bodies();
  std::vector<dvi::BodyState> st(b.count());
  for (size_t i = 0; i < st.size(); ++i) st[i] = dvi::BodyState{b.pos[i], b.rot[i], b.vel[i], b.omega[i], b.size[i]};
  return st;
}

// Steps `steps` (< 0: the scene's settings), writing `frames` ParaView frames evenly over the run (frames.pvd and
// frame_*.vtp in `out`, as `dvisim run --frames`) and, with `out`, bodies.csv and summary.json. Returns the summary.
py::object runSteps(PySystem& s, long long steps, long long frames, const std::string& out) {
  s.checkIdle();
  if (steps < 0) steps = s.settings.stepCount();
  if (frames < 0) frames = s.settings.frames;
  if (frames > 0 && out.empty()) throw dvi::InputError("run: frames need an output directory (out=...)");
  dvi::checkFrameCount(int(std::min<long long>(frames, 1000000)), steps, "frames");
  std::unique_ptr<dvi::ResultDir> rd = out.empty() ? nullptr : std::make_unique<dvi::ResultDir>(out);
  std::unique_ptr<dvi::FrameWriter> fw = rd ? std::make_unique<dvi::FrameWriter>(rd->path()) : nullptr;
  std::vector<long long> at;  // frame steps: N frames spread evenly over [0, steps], ending at the last
  for (long long k = 0; k < frames; ++k)
    at.push_back(frames == 1 ? steps : std::llround(double(k) * double(steps) / double(frames - 1)));
  const double t0 = s.sys->time();
  long long done = 0;
  for (const long long f : at) {
    if (f > done) stepSystem(s, f - done);  // releases the GIL
    done = std::max(done, f);
    fw->write(t0 + double(done) * s.sys->config().step.dt, bodyStates(s));
  }
  if (steps > done) stepSystem(s, steps - done);
  nlohmann::json j = summaryJson(s);
  j["frames"] = fw ? fw->count() : 0;
  j["status"] = "done";
  if (rd) {
    dvi::writeBodiesCsv(rd->path() + "/bodies.csv", bodyStates(s));
    dvi::writeSummary(rd->path() + "/summary.json", j);
    rd->commit();
  }
  return toPython(j);
}

}  // namespace

void bindSceneMethods(py::class_<PySystem>& c) {
  c.def("summary", [](const PySystem& s) { return toPython(summaryJson(s)); });
  c.def("_run", &runSteps, py::arg("steps"), py::arg("frames"), py::arg("out"));
  c.def_property_readonly("scene_steps", [](const PySystem& s) { return s.settings.stepCount(); });
  c.def_property_readonly("scene_frames", [](const PySystem& s) { return s.settings.frames; });
}

void bindScene(py::module_& m) {
  m.def("_load_scene", &loadScene, py::arg("path"), py::arg("overrides"), py::arg("backend"));
  m.def("gpu_available", [] {
    std::string name;
    const bool ok = dvi::gpuAvailable(&name);
    return py::make_tuple(ok, name);
  });
}

}  // namespace dvipy
