// dvisim bench accuracy --out DIR [--quick] [--record] [--threads N]
//
// Work-precision benchmark: run time against error for each CCP solver (Jacobi, Gauss-Seidel
// on the CPU, APGD, BB) on our CPU backend (and the GPU backend when a device is present), with Bullet's own
// sequential-impulse solver as one more line, on standard scenes: a sphere pile (100k spheres in full mode), a
// mixed-shape pile, the 10-box stack with a 1000x heavy top (scenes/stack.json's tower) and the CES machine. Per scene, solver
// and backend it sweeps the iteration count at the scene's step h0 and the step (2 h0 .. h0/4) at a fixed
// iteration count, for the same simulated time, and measures:
//  - wall_s: wall time of the steps (step() only; the measurements below are taken outside it); run_s: the whole
//    run, scene set-up, measurements and teardown included;
//  - residual: the relative CCP residual each step ends with (solver.h: the projected-gradient residual over the
//    residual of the zero impulse), mean and last; the absolute one (m/s) in residual_abs_*;
//  - max_penetration_rel: the deepest penetration over the run relative to the scene's reference length;
//  - complementarity violation (m/s), our definition, after each step, from the post-step velocities v+:
//        C = sum_k |g_k . u_k| / sum_k |g_k|,   u_k = D_k^T v+ + b_k = (N g + r)_k
//    with g_k the world impulse of contact k on body B (n gn + u gu + w gw), D_k^T v+ the relative velocity at the
//    contact ((vB + wB x rB) - (vA + wA x rA), lever arms from the pre-step centres of mass x+ - h v+) and
//    b_k = (max(dist/h, -v_rec), 0, 0) (jacobian.h contactBias). At an exact CCP solution g_k . (N g + r)_k = 0 for
//    every contact (gamma in the cone, u in the dual cone, orthogonal: the cone complementarity of Anitescu &
//    Tasora 2010, Comput. Optim. Appl. 47; Tasora & Anitescu 2011, CMAME 200), so C is the impulse-weighted mean
//    complementarity gap, a velocity;
//  - the error of a macroscopic observable against a reference run (APGD, 500 iterations or residual < 1e-7,
//    h0/4): piles: mean height of the bodies, error relative to the reference length; stack: position of the top
//    box, error relative to its half size; CES machine: the total-variation distance (half the L1 distance, 0..1)
//    between the collected mass distributions over (bin, material kind) at the configured splitters (the
//    reference there: APGD 200 iterations, h0/2, on the CPU: its ~200 bodies are launch-bound on a GPU; its
//    sweep is shorter: iterations 10, 30, 100 and steps 2 h0, h0/2; no Bullet line, Bullet has no CES machine).
// Also the goal: on the pile, after a few settling steps, two identical systems (deterministic, so the
// same state and the same CCP) solve the next step's CCP with APGD and with Jacobi down to relative residual 1e-4
// (tolerance stop; record_history on); the ratio of the Solve-stage times is printed (goal >= 10x); and every
// solver's time to the default tolerance (SolverSettings) on the same CCP.
// --scenes and --engines narrow a run (a full run on one device can be split over several invocations).
// Outputs: DIR/accuracy.csv, DIR/accuracy.png (scripts/plot_accuracy.py, when python3 has matplotlib), a table on
// stdout; --record also writes bench/results/accuracy_<device>_<date>.{md,csv}.
#include <CLI/CLI.hpp>
#include <unistd.h>
#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "bench_common.h"
#include "bench_util.h"
#include "ces/ces_config.h"
#include "ces/machine.h"
#include "ces/output/splitters.h"
#include "ces_run.h"
#include "chrono_like/solver/jacobian.h"
#include "chrono_like/solver/solver.h"
#include "chrono_like/system.h"
#include "gpu/gpu_factory.h"
#include "scaling/scaling_scenes.h"

namespace {

using namespace dvi::benchutil;

struct AccOptions : BenchBasics {
  std::vector<std::string> scenes, engines;
};

// `dvisim bench accuracy`: its name, description and the texts of its common options.
const BenchSpec kBench{
    "accuracy", "Work-precision: CCP residual, penetration, complementarity and observable error against run time",
    "accuracy.csv, accuracy.png", "Small scenes and a short sweep (CI smoke test)"};

// A scene of the benchmark: its bodies (rebuilt for each run), step, duration and observable.
struct AccScene {
  std::string name;
  double h0 = 1e-3, T = 0.03, ref_length = 0.01, bullet_scale = 100;
  std::function<void(BtBodies&, std::unique_ptr<dvi::bench::BulletScene>&)> build;
  // observable of the final state and its error scale
  std::function<Vec3(const Runner&, const std::vector<btRigidBody*>&)> observe;
  double obs_scale = 0.01;
  std::string obs_name;
  // Non-empty: the CES machine (scenes/ces_default.json through the loader of `dvisim run`) with these --set
  // overrides; build and observe are unused.
  std::vector<std::string> ces_sets;
};

struct Row {
  std::string scene, engine, solver, sweep, status = "ok", device;
  int iterations = 0, steps = 0;
  double dt = 0, wall_s = 0, run_s = 0, res_mean = NAN, res_last = NAN, res_abs_mean = NAN, res_abs_last = NAN,
         pen_rel = 0, compl_mean = NAN, obs = NAN, obs_err = NAN;
};

Vec3 meanHeight(const Runner& r, const std::vector<btRigidBody*>& b) {
  double s = 0;
  long n = 0;
  for (size_t i = 0; i < b.size(); ++i)
    if (b[i]->getInvMass() > 0) s += double(r.pos(i).y), ++n;
  return Vec3{0, real(n ? s / double(n) : 0), 0};
}

// Scene `name` of bench scaling (pile or mix, bench/scaling/scaling_scenes.h) of n bodies, h0 = 1 ms: observed by the
// mean height of its bodies on the scale of its particle size (ref_length).
AccScene scalingScene(const std::string& name, long n, double ref_length, const std::string& obs_name, bool quick) {
  AccScene s;
  s.name = name;
  s.h0 = 1e-3, s.T = quick ? 0.03 : 0.02, s.ref_length = ref_length;
  s.build = [name, n](BtBodies& b, std::unique_ptr<dvi::bench::BulletScene>& keep) {
    (void)b;
    keep = std::make_unique<dvi::bench::BulletScene>(dvi::bench::makeBulletScene(dvi::bench::makeSceneSpec(name, n)));
  };
  s.observe = meanHeight, s.obs_scale = ref_length, s.obs_name = obs_name;
  return s;
}

std::vector<AccScene> makeScenes(bool quick) {
  std::vector<AccScene> v;
  v.push_back(scalingScene("pile", quick ? 400 : 100000, 0.01, "mean height of the spheres", quick));
  v.push_back(scalingScene("mix", quick ? 250 : 20000, 0.005, "mean height of the bodies", quick));
  {
    // The default CES machine, fed for a short time so that a run ends with most particles collected: full
    // 0.15 s of the default feed (0.5 g/s, about 190 particles of 0.5-1 mm) and 1 s of machine time; quick
    // 0.05 s and 0.8 s with the collection plane raised to 200 mm below the drum axis. Observable: the mass
    // distribution over (bin at the configured splitters) x (material kind) of the collected mass.
    AccScene s;
    s.name = "ces";
    s.h0 = 2e-4, s.T = quick ? 0.8 : 1.0, s.ref_length = 0.25e-3;  // the smallest particle radius
    s.ces_sets = {"duration_s=" + num(s.T, "%.17g"),
                  "feed.start_s=0",
                  "feed.duration_s=" + std::string(quick ? "0.05" : "0.15"),
                  "output.frames=0",
                  "output.plots=false",
                  "output.checkpoint_every_s=0"};
    if (quick) s.ces_sets.push_back("collection.y_mm=-200");
    s.obs_scale = 1, s.obs_name = "metal recovery in the conductor bin";
    v.push_back(s);
  }
  {
    AccScene s;
    s.name = "stack";
    s.h0 = 1e-2, s.T = quick ? 0.5 : 2.0, s.ref_length = 0.1, s.bullet_scale = 1;
    // scenes/stack.json: 10 boxes of 0.2 m, mass 1, friction 0.5, the top one 1000 kg, on a plane (friction 1).
    s.build = [](BtBodies& b, std::unique_ptr<dvi::bench::BulletScene>&) {
      b.add(new btStaticPlaneShape(btVector3(0, 1, 0), 0), 0, Vec3{0, 0, 0}, real(1.0));
      btCollisionShape* box = b.own(new btBoxShape(btVector3(0.1f, 0.1f, 0.1f)));
      for (int i = 0; i < 10; ++i)
        b.addShared(box, i == 9 ? 1000.0 : 1.0, Vec3{0, real(0.1 * 1.0002 + 0.2002 * i), 0}, real(0.5));
    };
    s.observe = [](const Runner& r, const std::vector<btRigidBody*>& b) { return r.pos(b.size() - 1); };
    s.obs_scale = 0.1, s.obs_name = "position of the top box";
    v.push_back(s);
  }
  return v;
}

// The complementarity violation of the last step (header comment), from the host copy of `sys` (synced); -1
// when no contact carries an impulse. The lever arms start at the pre-step centres of mass, x+ - h v+
// (the position update is x+ = x + h v+, integrate.h), so no copy of the state is kept across the step.
double complementarityGap(const dvi::System& sys) {
  const dvi::ContactArrays& c = sys.contacts();
  const dvi::BodyArrays& b = sys.bodies();
  const real dt = real(sys.config().step.dt);
  auto x_pre = [&](size_t i) { return b.pos[i] - b.vel[i] * dt; };
  double gap = 0, mag = 0;
  for (size_t k = 0; k < c.dist.size(); ++k) {
    const size_t A = size_t(c.body_a[k]), B = size_t(c.body_b[k]);
    const Vec3 rA = c.pa[k] - x_pre(A), rB = c.pb[k] - x_pre(B);
    const Vec3 vrel = (b.vel[B] + dvi::cross(b.omega[B], rB)) - (b.vel[A] + dvi::cross(b.omega[A], rA));
    const real bn = dvi::contactBias(c.dist[k], dt, sys.config().solver.recovery_rel, c.size[k]);
    const Vec3 G = sys.contactForce(k) * dt;
    gap += std::fabs(double(dvi::dot(G, vrel + bn * c.normal[k])));
    mag += double(dvi::length(G));
  }
  return mag > 0 ? gap / mag : -1;
}

// One run of the CES scene on our backend `engine`. The observable is the fraction of the collected mass in each
// (bin, material kind) at the configured splitters (splitters.h binDirect), 9 numbers in *fractions; row.obs is
// the metal recovery in the conductor bin. Penetration: of the particles only (contacts with a moving body),
// relative to the pair's size.
Row runCesOne(const AccScene& sc, const std::string& engine, const std::string& solver, int iterations, double dt,
              double tol, int threads, std::vector<double>* fractions) {
  const auto t_run = Clock::now();
  Row row;
  row.scene = sc.name, row.engine = engine, row.solver = solver, row.iterations = iterations, row.dt = dt;
  std::vector<std::string> sets = sc.ces_sets;
  sets.push_back("time_step_s=" + num(dt, "%.17g"));
  sets.push_back("solver.type=" + solver);
  sets.push_back("solver.iterations=" + std::to_string(iterations));
  std::string origin;
  nlohmann::json doc = dvi::ces::loadCesDocument("", origin);
  const dvi::ces::CesConfig cfg = dvi::ces::parseCesDocument(doc, sets, origin);
  std::unique_ptr<dvi::System> sys = dvi::ces::makeCesSystem(cfg, engine, threads, "native");
  sys->mutableConfig().solver.tolerance = real(tol);
  dvi::ces::CesMachine m(cfg, *sys);
  row.device = sys->deviceName();
  row.steps = int(std::llround(cfg.duration / cfg.step.dt));
  double res_sum = 0, res_abs_sum = 0, compl_sum = 0;
  int compl_n = 0;
  for (int k = 0; k < row.steps; ++k) {
    const auto t0 = Clock::now();
    m.step();
    row.wall_s += std::chrono::duration<double>(Clock::now() - t0).count();
    const dvi::StepStats& st = sys->lastStats();
    res_sum += double(st.relative_residual);
    row.res_last = double(st.relative_residual);
    res_abs_sum += double(st.residual);
    row.res_abs_last = double(st.residual);
    // Penetration of the particles only, relative to the pair's size: StepStats' max_penetration also sees the
    // overlaps between the machine's own fixed and kinematic parts, which no solver acts on.
    sys->syncToHost();
    const dvi::ContactArrays& c = sys->contacts();
    const dvi::BodyArrays& bd = sys->bodies();
    for (size_t q = 0; q < c.dist.size(); ++q)
      if (c.dist[q] < 0 && (bd.inv_mass[size_t(c.body_a[q])] > 0 || bd.inv_mass[size_t(c.body_b[q])] > 0)) {
        row.pen_rel = std::max(row.pen_rel, -double(c.dist[q]) / double(c.size[q]));
      }
    const double gap = complementarityGap(*sys);
    if (gap >= 0) compl_sum += gap, ++compl_n;
  }
  row.res_mean = res_sum / std::max(1, row.steps);
  row.res_abs_mean = res_abs_sum / std::max(1, row.steps);
  row.compl_mean = compl_n ? compl_sum / compl_n : 0;
  const dvi::ces::BinMasses b = dvi::ces::binDirect(m.collected(), cfg.s1, cfg.s2);
  double total = 0, metal = 0;
  for (int bin = 0; bin < 3; ++bin)
    for (int kind = 0; kind < dvi::ces::kMaterialKinds; ++kind) {
      total += double(b.fg[size_t(bin)][size_t(kind)]);
      if (kind == int(dvi::ces::MaterialKind::Metal)) metal += double(b.fg[size_t(bin)][size_t(kind)]);
    }
  fractions->assign(9, NAN);
  for (int bin = 0; bin < 3; ++bin)
    for (int kind = 0; kind < 3; ++kind)
      if (total > 0) (*fractions)[size_t(3 * bin + kind)] = double(b.fg[size_t(bin)][size_t(kind)]) / total;
  row.obs = metal > 0 ? double(b.fg[dvi::ces::kBinConductor][size_t(dvi::ces::MaterialKind::Metal)]) / metal : NAN;
  if (!(total > 0)) row.status = "nothing collected";
  if (!m.balance().closes()) row.status = "mass balance does not close";
  sys.reset();
  row.run_s = std::chrono::duration<double>(Clock::now() - t_run).count();
  return row;
}

// Total-variation distance of two mass distributions (half the L1 distance, in [0, 1]).
double tvDistance(const std::vector<double>& a, const std::vector<double>& b) {
  if (a.size() != b.size() || a.empty()) return NAN;
  double d = 0;
  for (size_t i = 0; i < a.size(); ++i) d += std::fabs(a[i] - b[i]);
  return d / 2;
}

// One run of a scene on one engine. `solver` empty: Bullet with `iterations` sequential-impulse iterations.
Row runOne(const AccScene& sc, const std::string& engine, const std::string& solver, int iterations, double dt,
           double tol, int threads, Vec3* obs_out) {
  const auto t_run = Clock::now();
  Row row;
  row.scene = sc.name, row.engine = engine, row.solver = solver.empty() ? "bullet-si" : solver;
  row.iterations = iterations, row.dt = dt;
  row.steps = std::max(1, int(std::lround(sc.T / dt)));
  BtBodies own;
  std::unique_ptr<dvi::bench::BulletScene> keep;
  sc.build(own, keep);
  const std::vector<btRigidBody*>& bodies = keep ? keep->bodies : own.bodies;
  std::unique_ptr<Runner> run;
  OursRunner* ours = nullptr;
  if (engine == "bullet") {
    dvi::BulletPeerSettings bs;
    bs.dt = real(dt);
    bs.solver_iterations = iterations;
    bs.length_scale = real(sc.bullet_scale);
    run = std::make_unique<BulletRunner>(bodies, bs);
  } else {
    dvi::SystemConfig cfg;
    cfg.step.dt = real(dt);
    dvi::parseSolver(solver, cfg.solver.type);
    cfg.solver.max_iterations = iterations;
    cfg.solver.tolerance = real(tol);  // relative (0: the fixed count of the sweep)
    cfg.threads = threads;
    auto o = std::make_unique<OursRunner>(bodies, cfg, engine == "gpu");
    ours = o.get();
    run = std::move(o);
  }
  row.device = run->device();
  double res_sum = 0, res_abs_sum = 0, compl_sum = 0;
  int compl_n = 0;
  for (int s = 0; s < row.steps; ++s) {
    run->step();
    row.wall_s += run->last_step_s;
    if (ours) {
      dvi::System& sys = *ours->sys;
      const dvi::StepStats& st = sys.lastStats();
      res_sum += double(st.relative_residual);
      row.res_last = double(st.relative_residual);
      res_abs_sum += double(st.residual);
      row.res_abs_last = double(st.residual);
      row.pen_rel = std::max(row.pen_rel, double(st.max_penetration) / sc.ref_length);
      sys.syncToHost();
      const double gap = complementarityGap(sys);
      if (gap >= 0) compl_sum += gap, ++compl_n;
    } else {
      const auto* br = static_cast<BulletRunner*>(run.get());
      row.pen_rel = std::max(row.pen_rel, double(br->peer->lastStats().max_penetration) / sc.ref_length);
    }
  }
  if (ours) {
    row.res_mean = res_sum / row.steps;
    row.res_abs_mean = res_abs_sum / row.steps;
    row.compl_mean = compl_n ? compl_sum / compl_n : 0;
  }
  run->sync();
  const Vec3 o = sc.observe(*run, bodies);
  if (obs_out) *obs_out = o;
  row.obs = double(o.y);  // the height (pile, mix) or the top box's y (stack)
  for (size_t i = 0; i < bodies.size(); ++i)
    if (bodies[i]->getInvMass() > 0 && (!finite3(run->pos(i)) || !finite3(run->vel(i))))
      row.status = "non-finite state";
  run.reset();
  keep.reset();
  row.run_s = std::chrono::duration<double>(Clock::now() - t_run).count();  // setup, steps, measurements, teardown
  return row;
}

// ---------- the goal: time to residual 1e-4, APGD against Jacobi, on the same CCP ----------

struct GoalResult {
  double seconds = 0, residual = 0;
  int iterations = 0;
  bool reached = false;
  std::string error;
};

GoalResult timeToResidual(long n, dvi::SolverType solver, bool warm, int cap, int threads, int presteps, bool gpu,
                          double tol = 1e-4) {
  GoalResult g;
  try {
    dvi::bench::BulletScene scene = dvi::bench::makeBulletScene(dvi::bench::makePileSpec(n));
    dvi::SystemConfig cfg;
    cfg.step.dt = real(1e-3);
    cfg.solver.type = dvi::SolverType::APGD;
    cfg.solver.max_iterations = 50;
    cfg.threads = threads;
    OursRunner run(scene.bodies, cfg, gpu);
    for (int i = 0; i < presteps; ++i) run.step();
    dvi::SystemConfig& c = run.sys->mutableConfig();
    c.solver.type = solver;
    c.solver.max_iterations = cap;
    c.solver.tolerance = real(tol);  // relative residual (solver.h)
    c.solver.record_history = true;
    c.solver.warm_start = warm;
    run.step();
    const dvi::StepStats& st = run.sys->lastStats();
    g.seconds = st.stage_seconds[size_t(dvi::StageType::Solve)];
    g.iterations = st.iterations;
    g.residual = double(st.relative_residual);
    g.reached = st.relative_residual <= real(tol);
  } catch (const std::exception& e) { g.error = e.what(); }
  return g;
}

// ---------- outputs ----------

const char* kCsvHeader =
    "scene,engine,solver,sweep,iterations,dt_s,steps,wall_s,ms_per_step,residual_mean,residual_last,"
    "max_penetration_rel,compl_violation_mps,observable,observable_ref,observable_err_rel,device,status,run_s,"
    "residual_abs_mean_mps,residual_abs_last_mps";

std::string csvText(const std::vector<Row>& rows, const std::vector<double>& refs_obs,
                    const std::vector<std::string>& ref_scene) {
  std::ostringstream o;
  o << kCsvHeader << "\n";
  for (const Row& r : rows) {
    double ref = NAN;
    for (size_t i = 0; i < ref_scene.size(); ++i)
      if (ref_scene[i] == r.scene) ref = refs_obs[i];
    o << r.scene << "," << r.engine << "," << r.solver << "," << r.sweep << "," << r.iterations << "," << num(r.dt)
      << "," << r.steps << "," << num(r.wall_s) << "," << num(1e3 * r.wall_s / std::max(1, r.steps)) << ","
      << num(r.res_mean) << "," << num(r.res_last) << "," << num(r.pen_rel) << "," << num(r.compl_mean) << ","
      << num(r.obs) << "," << num(ref) << "," << num(r.obs_err) << "," << csvField(r.device) << ","
      << csvField(r.status) << "," << num(r.run_s) << "," << num(r.res_abs_mean) << "," << num(r.res_abs_last) << "\n";
  }
  return o.str();
}

std::string joined(const std::vector<std::string>& v) {
  std::string s;
  for (const std::string& x : v) s += (s.empty() ? "" : ",") + x;
  return s;
}

// The goal section of the report: APGD against Jacobi to residual 1e-4 on the pile's CCP, and each solver's time to
// the default tolerance, on each engine (none unless run_goal).
std::string goalText(const std::vector<std::string>& engines, bool run_goal, bool quick, int threads) {
  // The goal: APGD against Jacobi to residual 1e-4 on the pile's CCP.
  const long goal_n = quick ? 2000 : 100000;
  const int cap = quick ? 3000 : 5000;
  std::ostringstream goal;
  goal << "Goal: time for the CCP solve to reach relative residual 1e-4 on the " << goal_n
       << "-sphere pile, APGD vs Jacobi, the same CCP (5 settling steps, then one step per solver from the same state; "
          "Solve-stage time, tolerance stop, Jacobi capped at "
       << cap << " iterations):\n";
  for (const std::string& engine : run_goal ? engines : std::vector<std::string>{})
    for (bool warm : {true, false}) {
      const bool gpu = engine == "gpu";
      const GoalResult a = timeToResidual(goal_n, dvi::SolverType::APGD, warm, cap, threads, 5, gpu);
      const GoalResult j = timeToResidual(goal_n, dvi::SolverType::Jacobi, warm, cap, threads, 5, gpu);
      char b[512];
      const std::string label = engine + (warm ? ", warm start" : ", cold start");
      if (!a.error.empty() || !j.error.empty()) {
        goal << "  " << label << ": error: " << a.error << " " << j.error << "\n";
        continue;
      }
      const double ratio = a.seconds > 0 ? j.seconds / a.seconds : NAN;
      std::snprintf(
          b, sizeof b,
          "  %s: APGD %d it, %.4g s (res %.3g%s); Jacobi %d it, %.4g s (res %.3g%s): ratio %s%.1fx (goal >= 10x): %s\n",
          label.c_str(), a.iterations, a.seconds, a.residual, a.reached ? "" : ", NOT reached", j.iterations, j.seconds,
          j.residual, j.reached ? "" : ", NOT reached", j.reached ? "" : ">= ", ratio,
          !a.reached    ? "APGD did not reach 1e-4"
          : ratio >= 10 ? "met"
                        : (j.reached ? "missed" : "met (lower bound)"));
      goal << b;
    }
  // Time to the default tolerance (SolverSettings: relative residual, iteration cap) per solver, the same CCP.
  if (run_goal) {
    const dvi::SolverSettings defaults;
    goal << "Time to the default tolerance (relative residual " << num(double(defaults.tolerance), "%g") << ", cap "
         << defaults.max_iterations << " iterations) on the " << goal_n
         << "-sphere pile's CCP after 5 settling steps, warm start, Solve-stage time:\n";
    for (const std::string& engine : engines) {
      const bool gpu = engine == "gpu";
      for (dvi::SolverType t :
           {dvi::SolverType::APGD, dvi::SolverType::BB, dvi::SolverType::Jacobi, dvi::SolverType::GaussSeidel}) {
        if (gpu && t == dvi::SolverType::GaussSeidel) continue;  // CPU only
        const GoalResult a =
            timeToResidual(goal_n, t, true, defaults.max_iterations, threads, 5, gpu, double(defaults.tolerance));
        char b[256];
        if (!a.error.empty())
          std::snprintf(b, sizeof b, "  %s %s: error: %s\n", engine.c_str(), dvi::solverName(t), a.error.c_str());
        else
          std::snprintf(b, sizeof b, "  %s %-6s: %5d it, %.4g s, relative residual %.3g%s\n", engine.c_str(),
                        dvi::solverName(t), a.iterations, a.seconds, a.residual, a.reached ? "" : " (NOT reached)");
        goal << b;
      }
    }
  }
  return goal.str();
}

// One run of a scene's sweep (engine, solver, iterations, step), printed as a line: its row, or the error it ended
// with. ref and ces_ref: the scene's reference observable; cpu_device: set by a CPU run.
Row attemptRun(const AccScene& sc, const std::string& engine, const std::string& solver, int it, double dt,
               const std::string& sweep, int threads, const std::vector<double>& ces_ref, Vec3 ref,
               std::string& cpu_device) {
  const bool ces = !sc.ces_sets.empty();
  if (isatty(fileno(stdout))) {  // a progress line on a terminal, overwritten by the row's line
    std::printf("  %-5s %-6s %-9s %-10s it %4d h %-8g ...\r", sc.name.c_str(), engine.c_str(),
                solver.empty() ? "bullet-si" : solver.c_str(), sweep.c_str(), it, dt);
    std::fflush(stdout);
  }
  Row r;
  Vec3 obs{0, 0, 0};
  try {
    if (ces) {
      std::vector<double> frac;
      r = runCesOne(sc, engine, solver, it, dt, 0, threads, &frac);
      r.obs_err = tvDistance(frac, ces_ref);
    } else {
      r = runOne(sc, engine, solver, it, dt, 0, threads, &obs);
      r.obs_err = double(dvi::length(obs - ref)) / sc.obs_scale;
    }
    if (engine == "cpu") cpu_device = r.device;
  } catch (const dvi::SolverError& e) {
    r.scene = sc.name, r.engine = engine, r.solver = solver, r.iterations = it, r.dt = dt;
    r.status = std::string("SolverError: ") + e.what();
  } catch (const std::exception& e) {
    r.scene = sc.name, r.engine = engine, r.solver = solver.empty() ? "bullet-si" : solver, r.iterations = it,
    r.dt = dt;
    r.status = std::string("error: ") + e.what();
  }
  r.sweep = sweep;
  std::printf(
      "  %-5s %-6s %-9s %-10s it %4d h %-8g %8.3f s (run %.1f s)  res %-10s pen %-10s compl %-10s obs err %s%s\n",
      sc.name.c_str(), r.engine.c_str(), r.solver.c_str(), sweep.c_str(), it, dt, r.wall_s, r.run_s,
      num(r.res_mean, "%.3g").c_str(), num(r.pen_rel, "%.3g").c_str(), num(r.compl_mean, "%.3g").c_str(),
      num(r.obs_err, "%.3g").c_str(), r.status == "ok" ? "" : ("  [" + r.status + "]").c_str());
  std::fflush(stdout);
  return r;
}

// The record of a run (--record): the report as .md and the rows as .csv, into bench/results/ and the output folder.
void writeAccuracyRecord(const AccOptions& o, const std::string& device, const std::string& scenes,
                         const std::string& engines, bool have_gpu, const std::string& goal_text,
                         const std::string& results_dir, const std::string& csv) {
  const std::string base = "accuracy_" + slug(device) + "_" + utcNow("%Y%m%d-%H%M%S");
  std::ostringstream md;
  md << "# Accuracy against run time" << (o.quick ? " (--quick)" : "") << "\n\n"
     << "Written by `dvisim bench accuracy --record` (bench/accuracy/bench_accuracy.cpp).\n\n- device: " << device
     << "\n- commit: " << commitId() << "\n- date: " << utcNow("%Y-%m-%dT%H:%M:%SZ") << "\n- scenes: pile "
     << (o.quick ? "400" : "100k") << " spheres r 1 cm; mix " << (o.quick ? "250" : "20k")
     << " mixed shapes 0.5-2 cm; 10-box stack with a 1000x top, h0 = 1e-2; the default CES machine fed for "
     << (o.quick ? "0.05 s, 0.8 s" : "0.15 s, 1 s") << " of machine time, h0 = 2e-4\n- this run: --scenes " << scenes
     << " --engines " << engines << (have_gpu ? "" : " (no GPU)") << "\n\n"
     << goal_text << "\nRows: " << base << ".csv (columns in bench/accuracy/bench_accuracy.cpp's header).\n";
  writeBenchRecord({results_dir, o.out}, base, {{"md", md.str()}, {"csv", csv}}, writeFile);
}

int runAccuracy(const AccOptions& o) {
  const int threads = benchThreads(o.threads);
  const std::vector<std::string> scene_sel = selectNames("--scenes", o.scenes, {"pile", "mix", "stack", "ces", "goal"});
  const std::vector<std::string> engine_sel = selectNames("--engines", o.engines, {"cpu", "gpu", "bullet"});
  auto selected = [](const std::vector<std::string>& v, const std::string& n) {
    return std::find(v.begin(), v.end(), n) != v.end();
  };
  prepareOutDir(o.out, "accuracy.csv");
  const std::string results_dir = o.record ? resultsDir() : std::string();
  std::string gpu_name;
  const bool have_gpu = dvi::gpuAvailable(&gpu_name);
  const auto t_all = Clock::now();

  const std::vector<int> iters = o.quick ? std::vector<int>{5, 20, 80} : std::vector<int>{5, 10, 25, 50, 100, 200};
  const std::vector<double> dt_factors = o.quick ? std::vector<double>{2.0, 0.5} : std::vector<double>{2.0, 0.5, 0.25};
  const int dt_iters = o.quick ? 20 : 50;
  std::vector<std::string> engines;
  if (selected(engine_sel, "cpu")) engines.push_back("cpu");
  if (have_gpu && selected(engine_sel, "gpu")) engines.push_back("gpu");
  const bool run_bullet = selected(engine_sel, "bullet");
  std::printf("bench accuracy%s: solvers jacobi, gs (CPU), apgd, bb on %s; Bullet's sequential impulse; iterations",
              o.quick ? " --quick" : "",
              have_gpu ? ("cpu and gpu (" + gpu_name + ")").c_str() : "cpu (no GPU in this run)");
  for (int i : iters) std::printf(" %d", i);
  std::printf("; steps 2 h0 .. h0/4 at %d iterations\n", dt_iters);

  std::fflush(stdout);

  std::vector<Row> rows;
  std::vector<double> ref_obs;
  std::vector<std::string> ref_scene;
  std::string cpu_device;
  auto flush = [&] { writeFile(o.out + "/accuracy.csv", csvText(rows, ref_obs, ref_scene)); };
  for (const AccScene& sc : makeScenes(o.quick)) {
    if (!selected(scene_sel, sc.name)) continue;
    // Reference: APGD, tight tolerance, h0/4, on the fastest backend we have.
    const bool ces = !sc.ces_sets.empty();
    Vec3 ref{0, 0, 0};
    std::vector<double> ces_ref;
    Row rr;
    try {
      if (ces) {
        rr = runCesOne(sc, "cpu", "apgd", 200, sc.h0 / 2, 1e-7, int(threads), &ces_ref);
        ref.y = real(rr.obs);
      } else {
        rr = runOne(sc, have_gpu ? "gpu" : "cpu", "apgd", o.quick ? 300 : 500, sc.h0 / 4, 1e-7, int(threads), &ref);
      }
    } catch (const std::exception& e) { rr.scene = sc.name, rr.status = std::string("error: ") + e.what(); }
    rr.sweep = "reference";
    rr.obs_err = 0;
    rows.push_back(rr);
    ref_obs.push_back(double(ref.y));
    ref_scene.push_back(sc.name);
    std::printf("%s: reference (APGD %d it, tol 1e-7, h = %g): %s = %.6g, %.2f s\n", sc.name.c_str(), rr.iterations,
                rr.dt, sc.obs_name.c_str(), double(ref.y), rr.wall_s);
    std::fflush(stdout);
    auto attempt = [&](const std::string& engine, const std::string& solver, int it, double dt,
                       const std::string& sweep) {
      rows.push_back(attemptRun(sc, engine, solver, it, dt, sweep, int(threads), ces_ref, ref, cpu_device));
      flush();
    };
    for (const std::string& engine : engines)
      for (const char* solver : {"jacobi", "gs", "apgd", "bb"}) {
        if (engine == "gpu" && std::string(solver) == "gs") continue;  // Gauss-Seidel is CPU only
        const std::vector<int> it_sweep = !ces      ? iters
                                          : o.quick ? std::vector<int>{10, 40}
                                                    : std::vector<int>{10, 30, 100};
        const std::vector<double> dt_sweep = !ces      ? dt_factors
                                             : o.quick ? std::vector<double>{}
                                                       : std::vector<double>{2.0, 0.5};
        for (int it : it_sweep) attempt(engine, solver, it, sc.h0, "iterations");
        for (double f : dt_sweep) attempt(engine, solver, ces ? 30 : dt_iters, sc.h0 * f, "dt");
      }
    if (run_bullet && !ces) {
      for (int it : o.quick ? std::vector<int>{5, 10, 40} : std::vector<int>{5, 10, 25, 50, 100})
        attempt("bullet", "", it, sc.h0, "iterations");
      for (double f : dt_factors) attempt("bullet", "", 10, sc.h0 * f, "dt");
    }
  }

  const std::string goal_text = goalText(engines, selected(scene_sel, "goal"), o.quick, int(threads));
  const double total = std::chrono::duration<double>(Clock::now() - t_all).count();
  flush();
  std::printf("\n%s", goal_text.c_str());
  std::printf("results: %s/accuracy.csv (%.1f s)\n", o.out.c_str(), total);
  std::printf("%s\n", runPlot("plot_accuracy.py", o.out, "accuracy.png").c_str());
  if (o.record)
    writeAccuracyRecord(o, have_gpu ? gpu_name : cpu_device, joined(scene_sel), joined(engine_sel), have_gpu, goal_text,
                        results_dir, csvText(rows, ref_obs, ref_scene));
  return 0;
}

}  // namespace

void registerBenchAccuracy(CLI::App& app, BenchRegistry& reg) {
  auto [cmd, o] = addBench<AccOptions>(app, reg, kBench, runAccuracy);
  cmd->add_option("--scenes", o->scenes,
                  "pile,mix,stack,ces,goal (default all; goal: the APGD/Jacobi time to residual 1e-4)");
  cmd->add_option("--engines", o->engines, "cpu,gpu,bullet (default all; gpu where a device is present)");
}
