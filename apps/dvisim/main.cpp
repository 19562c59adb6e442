// dvisim: runs a scene with the DVI engine (CPU, GPU when present) or with Bullet's own solver.
//
//   dvisim run [SCENE] [--backend auto|cpu|gpu|bullet] [--collision native|bullet]
//              [--solver jacobi|gs|apgd|bb] [--iterations N] [--tolerance TOL] [--max-iterations N]
//              [--dt H] [--time T | --steps N]
//              [--threads N] [--frames N] [--set KEY=VALUE ...] [--out DIR] [--resume DIR]
//   Without SCENE, or with a .json whose top level has "ces", it runs a CES machine (ces_run.h).
//   dvisim compare SCENE [--time T | --steps N] [--dt H] [--out DIR]   (compare.cpp: Bullet vs our CPU/GPU)
//   dvisim sweep [SCENE] --grid KEY=v1,v2 | --grid KEY=lo:hi:n | --list FILE [--seeds N] [--jobs N] --out DIR
//                [run options]                                    (sweep.cpp: design of experiments, docs/SWEEP.md)
//   dvisim bench scaling --out DIR [--record] [--quick] [--sizes ...]     (bench_scaling.cpp; bench_common.h)
//   dvisim bench accuracy | stability | ces --out DIR [--record] [--quick]  (bench_accuracy.cpp, bench_stability.cpp,
//                                                                           bench_ces.cpp)
//   dvisim bench pruning --out DIR [--quick] [--record] [--backend B] [--n N] [--threads N]  (bench_pruning.cpp)
//
// Exit codes (run_control.h; README.md, docs/HARDENING.md): 0 done; 1 any other failure; 2 bad input (one line
// "dvisim: error: ..." on stderr, nothing run); 3 the simulation diverged; 4 interrupted (SIGINT/SIGTERM);
// 5 out of memory or a device error.
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <btBulletDynamicsCommon.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <functional>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

#include "bench_common.h"
#include "ces_run.h"
#include "chrono_like/bullet/bullet_collision_backend.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/bullet/bullet_peer.h"
#include "chrono_like/io/input_limits.h"
#include "chrono_like/io/output.h"
#include "chrono_like/io/run_control.h"
#include "chrono_like/io/scene.h"
#include "chrono_like/system.h"
#include "cli_options.h"
#include "gpu/gpu_factory.h"
#include "parse.h"
#include "progress.h"
#include "run_checkpoint.h"
#ifdef DVISIM_HAVE_MPI
#include "mpi_run.h"
#endif

namespace {

using dvi::InputError;
using dvi::parseInt;
using dvi::parseReal;
using dvi::requireOneOf;
using Clock = std::chrono::steady_clock;

struct Options {
  std::string scene;
  std::string backend = "auto";
  std::string collision;
  std::string solver;
  std::string iterations, tolerance, max_iterations, dt, time, steps, threads, frames, checkpoint_every;
  std::vector<std::string> sets;
  std::string out = "dvisim-out";
  std::string resume;  // continue the run whose checkpoint is in (or, killed, was written beside) this directory
};

std::string oneLine(std::string s) {
  for (char& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

// Characteristic size of each body (for the frames), from the Bullet shapes.
std::vector<dvi::real> bodySizes(const std::vector<btRigidBody*>& bodies) {
  std::vector<dvi::real> s(bodies.size(), 0);
  for (size_t i = 0; i < bodies.size(); ++i) {
    try {
      const dvi::BodyDesc d = dvi::bodyDescFromBullet(*bodies[i]);
      dvi::real m = dvi::real(1e30);
      for (const auto& sh : d.shapes) m = std::fmin(m, sh.shape.size);
      s[i] = m;
    } catch (const std::exception&) {
      btVector3 c;
      btScalar r = 0;
      bodies[i]->getCollisionShape()->getBoundingSphere(c, r);
      s[i] = dvi::real(r);
    }
  }
  return s;
}

// Bullet's tolerances are absolute lengths: scale the scene so the smallest moving body is >= ~0.5 units.
dvi::real autoLengthScale(const std::vector<btRigidBody*>& bodies, const std::vector<dvi::real>& sizes) {
  dvi::real smallest = dvi::real(1e30);
  for (size_t i = 0; i < bodies.size(); ++i)
    if (!bodies[i]->isStaticOrKinematicObject() && sizes[i] > 0) smallest = std::fmin(smallest, sizes[i]);
  if (!(smallest < dvi::real(0.5))) return 1;
  return dvi::real(std::pow(10.0, std::ceil(std::log10(0.5 / double(smallest)))));
}

// Steps at which frames are written: N frames spread evenly over [0, steps], ending at the last step.
std::vector<int64_t> frameSteps(int frames, int64_t steps) {
  std::vector<int64_t> f;
  if (frames <= 0) return f;
  if (frames == 1) return {steps};
  for (int k = 0; k < frames; ++k) f.push_back(int64_t(std::llround(double(k) * double(steps) / double(frames - 1))));
  return f;
}

// A CES machine (no scene: the default machine; a .json with a top-level "ces"; --resume) runs in src/ces/.
int runCes(const Options& o) {
  dvi::ces::CesRunOptions c;
  c.scene = o.scene, c.sets = o.sets, c.backend = o.backend, c.collision = o.collision, c.solver = o.solver;
  if (!o.tolerance.empty() || !o.max_iterations.empty())
    throw InputError(
        "--tolerance and --max-iterations: not available for a CES machine (it runs ces.solver.iterations)");
  c.iterations = o.iterations, c.dt = o.dt, c.time = o.time, c.steps = o.steps, c.threads = o.threads;
  c.frames = o.frames, c.out = o.out, c.resume = o.resume;
  return dvi::ces::runCesMachine(c);
}

// The command line validated and written into the scene's settings (SceneSettings, its SystemConfig) after the
// scene file; the scene is loaded here.
dvi::Scene loadScene(const Options& o) {
  requireOneOf("--backend", o.backend, {"auto", "cpu", "gpu", "bullet"});
  if (!o.collision.empty()) requireOneOf("--collision", o.collision, {"native", "bullet"});
  if (!o.solver.empty()) requireOneOf("--solver", o.solver, {"jacobi", "gs", "apgd", "bb"});
  if (!o.time.empty() && !o.steps.empty()) throw InputError("--time and --steps are mutually exclusive");
  std::optional<double> dt, time;
  if (!o.dt.empty()) {
    dt = parseReal("--dt", o.dt);
    if (!(*dt > 0)) throw InputError("--dt: the time step must be > 0, got " + o.dt);
  }
  if (!o.time.empty()) {
    time = parseReal("--time", o.time);
    if (*time < 0) throw InputError("--time: must be >= 0, got " + o.time);
  }

  dvi::Scene scene = dvi::Scene::load(o.scene, o.sets);
  // The command line writes into the scene's settings (SceneSettings, its SystemConfig) after the scene file.
  dvi::SceneSettings& st = scene.settings;
  dvi::SystemConfig& cfg = st.system;
  if (dt) cfg.step.dt = dvi::real(*dt);  // in the engine's precision, as a scene's settings.dt
  if (time) st.time = dvi::real(*time), st.steps = -1;
  if (!o.steps.empty()) st.steps = parseInt("--steps", o.steps, 0, 1LL << 40);
  if (!o.iterations.empty()) st.setIterations(int(parseInt("--iterations", o.iterations, 0, 1000000)));
  if (!o.max_iterations.empty()) st.setMaxIterations(int(parseInt("--max-iterations", o.max_iterations, 1, 1000000)));
  if (!o.tolerance.empty()) {
    const double tol = parseReal("--tolerance", o.tolerance);
    if (!(tol >= 0) || !std::isfinite(tol))
      throw InputError("--tolerance: must be a finite number >= 0, got " + o.tolerance);
    st.setTolerance(dvi::real(tol));
  }
  if (!o.threads.empty()) cfg.threads = int(parseInt("--threads", o.threads, 0, 4096));
  if (!o.frames.empty()) st.frames = int(parseInt("--frames", o.frames, 0, 1000000));
  if (!o.checkpoint_every.empty())
    st.checkpoint_every = parseInt("--checkpoint-every", o.checkpoint_every, 0, 1LL << 40);
  if (!o.solver.empty()) dvi::parseSolver(o.solver, cfg.solver.type);  // validated above
  if (!o.collision.empty())
    cfg.collision.backend = o.collision == "bullet" ? dvi::CollisionBackend::Bullet : dvi::CollisionBackend::Native;
  return scene;
}

// Steps either backend: writes the due frames (through `collect`), times `stepOnce`, then lets `afterStep` gather its
// statistics. One loop for both, so frames and timing cannot differ. A step that diverges (SimulationDiverged,
// SolverError), fails, or SIGINT/SIGTERM ends the loop early: `done` counts the steps that completed, `failure` holds
// the exception.
struct StepLoop {
  int64_t first, steps;
  double dt;
  std::vector<dvi::BodyState>& state;
  dvi::FrameWriter& frames;
  std::vector<int64_t> frame_at;
  Progress progress;
  size_t next_frame = 0;
  double wall = 0;
  int64_t done = first;
  bool interrupted = false;
  std::exception_ptr failure;

  StepLoop(int64_t first_, int64_t steps_, double dt_, std::vector<dvi::BodyState>& state_, dvi::FrameWriter& frames_,
           std::vector<int64_t> frame_at_)
      : first(first_),
        steps(steps_),
        dt(dt_),
        state(state_),
        frames(frames_),
        frame_at(std::move(frame_at_)),
        progress(steps_) {
    while (next_frame < frame_at.size() && frame_at[next_frame] < first) ++next_frame;
  }

  template <class Collect, class StepOnce, class AfterStep>
  void run(Collect&& collect, StepOnce&& stepOnce, AfterStep&& afterStep) {
    try {
      for (int64_t k = first;; ++k) {
        while (next_frame < frame_at.size() && frame_at[next_frame] == k) {
          collect();
          frames.write(double(k) * dt, state);
          ++next_frame;
        }
        if (k == steps) break;
        if (dvi::stopRequested()) {
          interrupted = true;
          break;
        }
        const auto t0 = Clock::now();
        stepOnce(k);
        wall += std::chrono::duration<double>(Clock::now() - t0).count();
        done = k + 1;
        afterStep();
        progress.update(k + 1);
      }
    } catch (...) { failure = std::current_exception(); }
    progress.finish();
    collect();
  }
};

// The run on Bullet's own world (--backend bullet), the peer to compare against.
void runOnBullet(const Options& o, const dvi::SceneSettings& st, const std::vector<btRigidBody*>& bodies,
                 const std::vector<dvi::real>& sizes, StepLoop& loop, nlohmann::json& summary) {
  const dvi::SystemConfig& cfg = st.system;
  std::vector<dvi::BodyState>& state = loop.state;
  const int64_t steps = loop.steps;
  const double& wall = loop.wall;
  dvi::BulletPeerSettings ps;
  ps.dt = dvi::real(cfg.step.dt);
  ps.gravity = cfg.step.gravity;
  ps.solver_iterations = o.iterations.empty() ? st.bullet_iterations : std::max(1, st.iterations());
  ps.length_scale = st.bullet_length_scale > 0 ? st.bullet_length_scale : autoLengthScale(bodies, sizes);
  dvi::BulletPeer peer(bodies, ps);
  auto collect = [&] {
    for (size_t i = 0; i < bodies.size(); ++i)
      state[i] =
          dvi::BodyState{peer.position(i), peer.rotation(i), peer.velocity(i), peer.angularVelocity(i), sizes[i]};
  };
  int64_t contacts = 0;
  dvi::real max_pen = 0;
  loop.run(
      collect,
      [&](int64_t k) {
        peer.step();
        for (size_t i = 0; i < bodies.size(); ++i)
          if (!dvi::isFinite(peer.position(i)) || !dvi::isFinite(peer.velocity(i))) {
            char msg[200];
            std::snprintf(msg, sizeof msg,
                          "the simulation diverged in step %lld (t = %.6g s): body %zu has a non-finite "
                          "position or velocity; try a smaller time step",
                          (long long)(k + 1), double(k + 1) * cfg.step.dt, i);
            throw dvi::SimulationDiverged(msg);
          }
      },
      [&] {
        contacts += peer.lastStats().contacts;
        max_pen = std::fmax(max_pen, peer.lastStats().max_penetration);
      });
  summary["backend"] = "bullet";
  summary["device"] = "Bullet " + std::to_string(btGetVersion()) + " btDiscreteDynamicsWorld (CPU, 1 thread)";
  summary["solver"] = "bullet-si";
  summary["collision"] = "bullet";
  summary["iterations_mean"] = ps.solver_iterations;
  summary["residual_final"] = nullptr;
  summary["contacts_mean"] = steps > 0 ? double(contacts) / double(steps) : 0.0;
  summary["max_penetration"] = max_pen;
  summary["bullet_length_scale"] = ps.length_scale;
  summary["stages"] = {"bullet"};
  summary["stage_seconds"] = {{"bullet", wall}};
  summary["threads"] = 1;
  summary["checkpoint"] = nullptr;  // Bullet's world has none
}

// The run on the DVI System (cpu or gpu), with checkpoints.
void runOnSystem(const std::string& backend, const dvi::Scene& scene, const std::optional<runckpt::Resumed>& resumed,
                 const std::string& resumed_from, const std::string& out, StepLoop& loop, nlohmann::json& summary,
                 std::string& not_converged) {
  const dvi::SceneSettings& st = scene.settings;
  const dvi::SystemConfig& cfg = st.system;
  const std::vector<btRigidBody*>& bodies = scene.bodies();
  std::vector<dvi::BodyState>& state = loop.state;
  const int64_t steps = loop.steps;
  const int64_t& done = loop.done;
  const std::exception_ptr& failure = loop.failure;
  std::unique_ptr<dvi::System> sys = backend == "gpu" ? dvi::makeGpuSystem(cfg, dvi::makeBulletCollision)
                                                      : std::make_unique<dvi::System>(cfg, dvi::makeBulletCollision);
  const std::vector<int> ids = dvi::importBullet(*sys, bodies);
  if (resumed) runckpt::restore(*sys, *resumed);
  // a checkpoint every checkpoint_every steps (the newest two kept) into the run's folder, and one at the end
  runckpt::Periodic periodic(out, st.checkpoint_every);
  auto collect = [&] {
    sys->syncToHost();  // a device backend copies its state into the host arrays
    const dvi::BodyArrays& b = sys->bodies();
    for (size_t i = 0; i < ids.size(); ++i) {
      const size_t k = size_t(ids[i]);
      state[i] = dvi::BodyState{b.pos[k], b.rot[k], b.vel[k], b.omega[k], b.size[k]};
    }
  };
  int64_t contacts = 0, iterations = 0;
  dvi::real max_pen = 0, residual = 0, relative = 0;
  double checkpoint_s = 0;
  dvi::StageLog stage_log;
  const bool host_state = sys->backendName() == "cpu";  // the bodies are checked for divergence every step
  loop.run(
      collect,
      [&](int64_t k) {
        try {
          sys->step();
        } catch (const dvi::SolverError& e) {
          sys->syncToHost();
          throw dvi::SimulationDiverged(
              dvi::divergedMessage(k + 1, double(k + 1) * cfg.step.dt, sys->bodies(), e.what(), cfg.step.dt));
        }
        if (host_state) dvi::checkFiniteState(k + 1, double(k + 1) * cfg.step.dt, sys->bodies());
      },
      [&] {
        const dvi::StepStats& s = sys->lastStats();
        contacts += s.contacts;
        iterations += s.iterations;
        max_pen = std::fmax(max_pen, s.max_penetration);
        residual = s.residual;
        relative = s.relative_residual;
        stage_log.add(s);
        if (!periodic.due(done)) return;
        const auto c0 = Clock::now();
        sys->syncToHost();
        runckpt::writeSingle(*sys, scene, periodic.begin(done));
        periodic.commit(done);
        checkpoint_s += std::chrono::duration<double>(Clock::now() - c0).count();
      });
  const auto c0 = Clock::now();
  const bool saved = runckpt::finalCheckpoint(*sys, scene, periodic, out + "/checkpoint", bool(failure), resumed_from);
  checkpoint_s += std::chrono::duration<double>(Clock::now() - c0).count();
  summary["checkpoint"] = saved ? nlohmann::json("checkpoint/") : nlohmann::json(nullptr);
  summary["checkpoint_seconds"] = checkpoint_s;  // writing them (periodic and final), not in wall_time_s
  summary["backend"] = sys->backendName();
  summary["device"] = sys->deviceName();
  summary["solver"] = dvi::solverName(cfg.solver.type);
  summary["collision"] = dvi::collisionBackendName(cfg.collision.backend);
  summary["iterations_mean"] = steps > 0 ? double(iterations) / double(steps) : 0.0;
  summary["residual_final"] = relative;  // relative residual (solver.h)
  summary["residual_final_abs"] = residual;
  summary["contacts_mean"] = steps > 0 ? double(contacts) / double(steps) : 0.0;
  summary["max_penetration"] = max_pen;
  dvi::addConvergenceSummary(summary, sys->convergence(), cfg.solver);
  dvi::addStageSummary(summary, stage_log);
  not_converged = dvi::convergenceWarning(sys->convergence(), cfg.solver);
  summary["prune"] = cfg.prune;
}

// The run's end: the state checked (a device backend's only here), summary.json and bodies.csv written, the result
// directory put in place, and the lines that say how it ended. Returns the exit code, or rethrows the run's failure.
int finishRun(StepLoop& loop, nlohmann::json& summary, dvi::ResultDir& rd, const std::string& out,
              const std::string& resumed_from, const std::string& not_converged) {
  const int64_t done = loop.done, first = loop.first, steps = loop.steps;
  const bool interrupted = loop.interrupted;
  std::exception_ptr failure = loop.failure;
  const double wall = loop.wall;
  const std::vector<dvi::BodyState>& state = loop.state;
  const dvi::FrameWriter& frames = loop.frames;
  // A device backend's state is checked once, at the end (the host copy of every step would cost a transfer).
  for (size_t i = 0; !failure && !interrupted && i < state.size(); ++i)
    if (!dvi::isFinite(state[i].pos) || !dvi::isFinite(state[i].vel))
      failure = std::make_exception_ptr(dvi::SimulationDiverged(
          "the simulation diverged by step " + std::to_string(done) + ": body " + std::to_string(i) +
          " has a non-finite position or velocity; try a smaller time step"));
  const int code = failure ? dvi::exitCodeFor(failure) : interrupted ? int(dvi::kExitInterrupted) : int(dvi::kExitDone);
  summary["status"] = dvi::runStatusName(code);
  if (failure) {
    summary["error"] = dvi::exceptionMessage(failure);
    summary["exit_code"] = code;
  }
  summary["steps"] = done;
  summary["steps_planned"] = steps;
  if (first > 0) summary["resumed_from_step"] = first;
  summary["sim_time"] = double(done) * loop.dt;
  summary["wall_time_s"] = wall;
  summary["ms_per_step"] = done > first ? 1000.0 * wall / double(done - first) : 0.0;
  summary["frames"] = frames.count();

  try {
    dvi::writeBodiesCsv(out + "/bodies.csv", state);
    dvi::writeSummary(out + "/summary.json", summary);
    rd.commit();
    runckpt::forgetKilledRun(resumed_from, rd.out());
  } catch (...) {
    if (!failure) throw;  // the failure of the run is the one to report
  }
  if (failure) {
    std::printf("results so far: %s/ (summary.json status \"%s\", bodies.csv after step %lld)\n", rd.out().c_str(),
                dvi::runStatusName(code), (long long)done);
    std::rethrow_exception(failure);
  }
  std::printf("results: %s/ (summary.json, bodies.csv%s%s), %.3f s wall, %.2f ms/step\n", rd.out().c_str(),
              frames.count() ? (", " + std::to_string(frames.count()) + " frames + frames.pvd").c_str() : "",
              summary["checkpoint"].is_null() ? "" : ", checkpoint/", wall,
              done > first ? 1000.0 * wall / double(done - first) : 0.0);
  if (!not_converged.empty()) {
    std::fflush(stdout);
    std::fprintf(stderr, "%s\n", not_converged.c_str());
  }
  if (interrupted) {
    std::fflush(stdout);
    std::fprintf(stderr, "dvisim: interrupted by %s after step %lld of %lld; the results so far are in %s/\n",
                 dvi::stopSignalName(), (long long)done, (long long)steps, rd.out().c_str());
    return dvi::kExitInterrupted;
  }
  return 0;
}

int run(const Options& o) {
  // --resume DIR of a scene run (run_checkpoint.h: one process or under mpirun) needs the scene it ran; without a
  // scene, DIR is a CES machine's.
  if (o.scene.empty() && !o.resume.empty() && runckpt::isSceneCheckpoint(o.resume))
    throw InputError("--resume " + o.resume +
                     ": a scene run's checkpoint resumes with the scene it ran: dvisim run SCENE --resume DIR");
  const bool ces = o.scene.empty() || dvi::ces::isCesScene(o.scene);
#ifdef DVISIM_HAVE_MPI
  if (ces && mpiProcesses() > 1)
    throw InputError("a CES machine does not run over several processes (MPI): run it without mpirun");
#endif
  if (ces) return runCes(o);
  dvi::Scene scene = loadScene(o);
  const dvi::SceneSettings& st = scene.settings;
  const dvi::SystemConfig& cfg = st.system;
  const int64_t steps = st.stepCount();
  dvi::checkFrameCount(st.frames, steps, o.frames.empty() ? scene.source + ": settings.frames" : "--frames");
#ifdef DVISIM_HAVE_MPI
  // Under `mpirun -np K` (K > 1): the domain decomposition (mpi_run.h).
  if (mpiProcesses() > 1 || (mpiInitialized() && !o.resume.empty()))
    return runSceneMpi(scene, cfg, steps, frameSteps(st.frames, steps), o.out, o.backend, o.resume,
                       st.checkpoint_every);
#endif

  const std::string backend = dvi::ces::resolveBackend(o.backend);  // auto: the GPU where there is one
  // --resume: the checkpoint read and checked before anything is written (run_checkpoint.h).
  std::optional<runckpt::Resumed> resumed;
  std::string resumed_from;  // its folder
  if (!o.resume.empty()) {
    if (backend == "bullet")
      throw InputError("--resume: the bullet backend (Bullet's own world) has no checkpoints; resume on cpu or gpu");
    resumed = runckpt::readResume(o.resume, scene, cfg, steps, resumed_from);
  }
  const int64_t first = resumed ? resumed->step : 0;  // the step the run starts from

  // Everything is written into a fresh directory beside --out, put in its place at the end (ResultDir).
  dvi::ResultDir rd(o.out);
  const std::string out = rd.path();

  const std::vector<btRigidBody*>& bodies = scene.bodies();
  const std::vector<dvi::real> sizes = bodySizes(bodies);
  std::printf("scene: %s (%zu bodies), %lld steps of %g s%s\n", scene.name.c_str(), bodies.size(), (long long)steps,
              cfg.step.dt, first > 0 ? (" (resumed at step " + std::to_string(first) + ")").c_str() : "");
  std::fflush(stdout);

#ifdef _OPENMP
  const int threads = cfg.threads > 0 ? cfg.threads : omp_get_max_threads();
#else
  const int threads = 1;
#endif

  nlohmann::json summary;
  std::string not_converged;  // the warning line of a run whose steps missed the tolerance
  summary["scene"] = scene.source;
  summary["scene_name"] = scene.name;
  summary["bodies"] = bodies.size();
  summary["dt"] = cfg.step.dt;
  summary["steps"] = steps;
  summary["threads"] = threads;
  summary["frames"] = 0;

  std::vector<dvi::BodyState> state(bodies.size());
  dvi::FrameWriter frames(out);

  StepLoop loop(first, steps, cfg.step.dt, state, frames, frameSteps(st.frames, steps));
  dvi::installStopHandlers();
  if (backend == "bullet")
    runOnBullet(o, st, bodies, sizes, loop, summary);
  else
    runOnSystem(backend, scene, resumed, resumed_from, out, loop, summary, not_converged);
  return finishRun(loop, summary, rd, out, resumed_from, not_converged);
}

// An option given an empty value (--dt "") is refused, not taken as "not given" (the run options test
// value.empty() for that): every option with a value, of every subcommand on the command line.
void refuseEmptyValues(const CLI::App& app) {
  for (const CLI::App* sub : app.get_subcommands()) {
    for (const CLI::Option* opt : sub->get_options())
      if (opt->count() > 0 && opt->get_expected_min() > 0)
        for (const std::string& v : opt->results())
          if (v.empty()) throw InputError(opt->get_name() + ": empty value");
    refuseEmptyValues(*sub);
  }
}

int fail(int code, const std::string& msg) {
  std::fflush(stdout);
  std::fprintf(stderr, "dvisim: error: %s\n", oneLine(msg).c_str());
  return code;
}

// Whether `bench scaling --mpi` was parsed: the one benchmark that runs over several processes.
bool mpiBenchParsed(CLI::App& app) {
  if (!app.got_subcommand("bench")) return false;
  CLI::App* scaling = app.get_subcommand("bench")->get_subcommand("scaling");
  return scaling->parsed() && scaling->get_option("--mpi")->count() > 0;
}

}  // namespace

// `dvisim compare` (compare.cpp): registers the subcommand; the returned function runs it.
std::function<int()> addCompareCommand(CLI::App& app);
// `dvisim sweep` (sweep.cpp): design of experiments over a scene with replicate seeds, the same way.
std::function<int()> addSweepCommand(CLI::App& app);
// `dvisim bench scaling` (bench_scaling.cpp); runs through runBenchCommand (bench_common.h).
void registerBenchScaling(CLI::App& app, BenchRegistry& reg);
// `dvisim bench accuracy` (bench_accuracy.cpp) and `dvisim bench stability` (bench_stability.cpp), the same way.
void registerBenchAccuracy(CLI::App& app, BenchRegistry& reg);
void registerBenchStability(CLI::App& app, BenchRegistry& reg);
// `dvisim bench ces` (bench_ces.cpp): the CES machine at an industrial feed against wall time.
void registerBenchCes(CLI::App& app, BenchRegistry& reg);
// `dvisim bench pruning` (bench_pruning.cpp): prune on against off, side by side.
void registerBenchPruning(CLI::App& app, BenchRegistry& reg);
// `dvisim bench dropin` (bench_dropin.cpp): Bullet's benchmark scenes on stock Bullet and on the drop-in world.
void registerBenchDropin(CLI::App& app, BenchRegistry& reg);

int main(int argc, char** argv) {
#ifdef DVISIM_HAVE_MPI
  MpiSession mpi(&argc, &argv);  // MPI_Init under mpirun only
#endif
  CLI::App app{"dvisim: DVI multibody engine for dense granular flows (CPU/OpenMP, GPU, Bullet peer)", "dvisim"};
  app.require_subcommand(1);
  app.footer(
      "Exit codes:\n"
      "  0  done\n"
      "  1  any other failure (an internal error)\n"
      "  2  bad input: one line \"dvisim: error: ...\" naming the problem; nothing was run or written\n"
      "  3  the simulation diverged (the message names the step and the body); the results so far are written\n"
      "  4  interrupted by SIGINT or SIGTERM: the last state is checkpointed, summary.json has status \"interrupted\"\n"
      "  5  out of memory (std::bad_alloc) or a device (GPU) error");
  Options o;
  CLI::App* run_cmd = app.add_subcommand(
      "run",
      "Run a scene (.json or .bullet) or a CES machine (.json with \"ces\"; the default CES machine without a scene)");
  run_cmd->add_option("scene", o.scene, "Scene file: .json (scenes/schema/scene.schema.json) or .bullet");
  run_cmd->add_option("--backend", o.backend, "auto|cpu|gpu|bullet (default auto)");
  run_cmd->add_option("--collision", o.collision, "native|bullet");
  run_cmd->add_option("--solver", o.solver, "jacobi|gs|apgd|bb");
  run_cmd->add_option(
      "--iterations", o.iterations,
      "A fixed number of solver iterations per step (alone: no tolerance stop; with --tolerance: the cap)");
  run_cmd->add_option(
      "--tolerance", o.tolerance,
      "Solver stop: relative residual, residual / residual of the zero impulse (default 0.15; 0: none)");
  run_cmd->add_option("--max-iterations", o.max_iterations, "Iteration cap of the tolerance stop (default 1000)");
  run_cmd->add_option("--dt", o.dt, "Time step in seconds");
  run_cmd->add_option("--time", o.time, "Simulated time in seconds");
  run_cmd->add_option("--steps", o.steps, "Number of steps");
  run_cmd->add_option("--threads", o.threads, "OpenMP threads (0: default)");
  run_cmd->add_option("--frames", o.frames, "Number of VTK frames to write");
  dvi::addRepeatable(run_cmd, "--set", o.sets,
                     "Override a scene value by dotted key, e.g. settings.dt=1e-4 (repeatable)");
  run_cmd->add_option("--out", o.out, "Output directory (default dvisim-out)");
  run_cmd->add_option("--resume", o.resume,
                      "Continue the run checkpointed in DIR (DIR/checkpoint/, or the last periodic checkpoint of a run "
                      "killed while writing DIR): a CES machine's, or a scene's (with its scene, on one process or any "
                      "number under mpirun, to --steps)");
  run_cmd->add_option("--checkpoint-every", o.checkpoint_every,
                      "A scene run's checkpoint every N steps while it runs, the last two kept (0: at its end only)");
  const std::function<int()> compare = addCompareCommand(app);
  const std::function<int()> sweep = addSweepCommand(app);
  BenchRegistry bench;  // the `bench` subcommands
  registerBenchScaling(app, bench);
  registerBenchAccuracy(app, bench);
  registerBenchStability(app, bench);
  registerBenchCes(app, bench);
  registerBenchPruning(app, bench);
  registerBenchDropin(app, bench);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);  // --help
    return fail(2, e.what());
  }
  try {
    refuseEmptyValues(app);
#ifdef DVISIM_HAVE_MPI
    if (mpiProcesses() > 1 && !app.got_subcommand("run") && !app.got_subcommand("sweep") && !mpiBenchParsed(app))
      throw InputError(
          "only `dvisim run SCENE`, `dvisim sweep` and `dvisim bench scaling --mpi` run over several processes (MPI): "
          "run the others without mpirun");
#endif
    if (app.got_subcommand("compare")) return compare();
    if (app.got_subcommand("sweep")) return sweep();
    if (app.got_subcommand("bench")) return runBenchCommand(bench);
    return run(o);
  } catch (...) {
    // InputError 2, SimulationDiverged/SolverError 3, std::bad_alloc/DeviceError 5, anything else 1 (run_control.h).
    const std::exception_ptr e = std::current_exception();
    const int code = fail(dvi::exitCodeFor(e), dvi::exceptionMessage(e));
    // Under mpirun a process that fails alone (a GPU out of memory) would leave the others waiting in a collective:
    // every process stops with this exit code.
    if (mpiProcesses() > 1) mpiAbort(code);
    return code;
  }
}
