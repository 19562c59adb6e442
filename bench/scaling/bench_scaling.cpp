// dvisim bench scaling --out DIR [--record] [--quick] [--sizes 10k,100k,1M,4M] [--scenes pile,mix]
//                      [--engines gpu,cpu,bullet,bullet3_opencl] [--cpu-max 100k] [--threads N] [--budget S]
//                      [--bullet3-device gpu|cpu|any] [--results-dir DIR]
//
// The scaling benchmark (a benchmark, not a test): a pile of N spheres (r = 1 cm, mu = 0.5) and a
// multidisperse mix (bench/scaling/scaling_scenes.h), h = 1e-3 s, APGD 50 iterations, stepped side by side
// in one run by our GPU backend (every N), Bullet 3's OpenCL GPU pipeline (every N until it fails at one;
// bench/scaling/bullet3_peer.h, each configuration in a child process: bench_scaling_bullet3.h), our CPU
// backend (all cores) and Bullet 2 (btDiscreteDynamicsWorld, sequential impulse, 1 thread, centimetre units)
// for N <= --cpu-max. Per configuration: warm-up steps, then
// timed steps; ms per step split by stage (broad = ComputeAabbs + BroadPhase, narrow, solve = BuildRows +
// WarmStart + Solve, integrate = IntegrateForces + IntegrateVelocities + IntegratePositions), contacts,
// deepest penetration relative to the scene's reference length, device memory, and the solver iteration's
// achieved bandwidth (bytes model: scaling_scenes.h solverIterationBytes) against the copy bandwidth
// measured in the same run (device copy for the GPU, a parallel host memcpy for the CPU backend).
//
// Outputs in DIR: scaling.csv (one row per engine x scene x N, `status` ok or why not), scaling.png
// (scripts/plot_scaling.py, when python3 + matplotlib are present; a copy of the script is left in DIR) and
// the table on stdout with the ratios of the performance goals. --record also writes
// bench/results/scaling_<device>_<date>.md and .csv (copies in DIR too). Without a GPU the GPU rows say
// they were skipped and why; the Bullet 3 rows say "not run: ..." where this build has no Bullet 3 peer or
// no OpenCL device of --bullet3-device's type exists (Bullet 3's logs and kernel cache: DIR/bullet3/).
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <LinearMath/btScalar.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <limits>
#include <string>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

#include "bench_common.h"
#include "scaling/bench_scaling_bullet3.h"
#ifdef DVISIM_HAVE_MPI
#include "scaling/bench_scaling_mpi.h"
#endif
#include "bench_util.h"
#include "chrono_like/bullet/bullet_peer.h"
#include "chrono_like/system.h"
#include "gpu/gpu_factory.h"
#include "scaling/scaling_scenes.h"
#if defined(DVISIM_HAVE_CUDA)
#include "gpu/gpu_system.h"
namespace dvi::gpu {
double measureCopyBandwidth(size_t bytes);  // bench/scaling/gpu_bench_support.cu
}
#endif

namespace {

using dvi::benchutil::commitId;
using dvi::benchutil::csvField;
using dvi::benchutil::exeDir;
using dvi::benchutil::fitSteps;
using dvi::benchutil::shell;
using dvi::benchutil::shellQuote;
using dvi::benchutil::slug;
using dvi::benchutil::sourceDir;
using dvi::benchutil::splitList;
using dvi::benchutil::trim;
using dvi::benchutil::utcNow;
using dvi::benchutil::writeFile;

using dvi::InputError;
using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

struct ScalingOptions : BenchBasics {
  std::vector<std::string> sizes, scenes, engines;
  std::string cpu_max = "100000", budget = "30", results_dir;
  bool gpu_graphs = true;
  long long gpu_persistent_max = -1;  // -1: SystemConfig's default
  bool gpu_register_cache = true;
  double pair_margin = dvi::BroadPhaseSettings{}.pair_margin;
  bool mpr_manifold = dvi::SystemConfig{}.collision.mpr_manifold;
  bool mpr_coherence = dvi::SystemConfig{}.collision.mpr_coherence;
  bool gpu_entry_gather = dvi::SystemConfig{}.gpu.entry_gather;
  bool gpu_narrow_classes = dvi::SystemConfig{}.gpu.narrow_classes;
  std::string gjk = "auto";
  std::string storage = "auto";
  std::string speculation = "auto";
  std::string stop_compare = "on";  // run ours again at the solver's default stop (ratio to the fixed 50)
  std::string bullet3_device = "gpu";
  bool mpi = false;  // the domain decomposition's weak and strong scaling instead (bench_scaling_mpi.h)
  std::string per_process = "20000", total = "40000", mpi_steps = "20";
  std::string mpi_backend = "cpu", mpi_modes = "weak,strong", mpi_baseline = "on";
};

// `dvisim bench scaling`: its name, description and the texts of its common options.
const BenchSpec kBench{"scaling",
                       "Pile and multidisperse mix for N = 10k..4M: GPU, CPU backend and Bullet side by side",
                       "scaling.csv, scaling.png", "Tiny sizes (1k, 4k) and few steps: a smoke test"};

// How the GPU launches APGD's trials under cfg (GpuTuning::persistent_max_blocks, graphs).
std::string gpuTrialsLabel(const dvi::SystemConfig& cfg) {
  const std::string single = cfg.gpu.graphs ? "one CUDA graph each" : "kernel by kernel";
  const int64_t m = cfg.gpu.persistent_max_blocks;
  if (m <= 0) return single;
  const std::string persistent = "all in one cooperative kernel per solve";
  const std::string cache = cfg.gpu.apgd_register_cache
                                ? ", each thread's blocks kept in registers between trials where they fit 2 a thread"
                                : "";
  if (m == std::numeric_limits<int64_t>::max())
    return persistent + cache + " (" + single + " without cooperative launch)";
  return persistent + cache + " up to " + std::to_string(m) + " blocks, above that " + single;
}

std::string speculationLabel(dvi::ApgdSpeculation s) {
  switch (s) {
    case dvi::ApgdSpeculation::None: return "none (--apgd-speculation none)";
    case dvi::ApgdSpeculation::Accepted: return "the accepted outcome's";
    case dvi::ApgdSpeculation::Both: return "the accepted and the rejected outcome's";
    case dvi::ApgdSpeculation::Auto: break;
  }
  return "the accepted outcome's (auto)";
}

std::string pairMarginLabel(dvi::real f) {
  if (!(f > 0)) return "a build every step (--pair-margin 0)";
  char b[32];
  std::snprintf(b, sizeof b, "%g", double(f));
  return "last step's pairs kept while every box stays inside its box grown by " + std::string(b) +
         " x the bin edge (BroadPhaseSettings::pair_margin; the same contacts as a build every step); the CSV's "
         "pairs_kept_steps counts the timed steps that kept them";
}

std::string storageLabel(const dvi::SolverSettings& s, bool gpu) {
  if (sizeof(dvi::real) != 8) return "float";
  return dvi::floatStorage(s, gpu) ? "float gradients and Jacobians (iterates double)" : "double";
}

struct Row {
  std::string engine, scene, device, status = "ok";
  long n = 0, bodies = 0;
  int threads = 0, warmup = 0, steps = 0;
  int pairs_kept = -1;  // timed steps whose BroadPhase kept the last step's pairs (ours; -1: not known)
  double setup_s = 0, ms = 0, broad = 0, narrow = 0, solve = 0, integrate = 0, other = 0;
  double solve_only_ms = 0;  // the Solve stage alone (the bandwidth's denominator)
  double contacts = 0, iterations = 0, max_pen_rel = 0, ref_length = 0;
  double device_mib = -1, solve_gbps = -1, copy_gbps = -1, pct_copy = -1;
  bool ok() const { return status == "ok"; }
};

// ---------- small helpers ----------

long parseCount(const std::string& opt, const std::string& tok_in) {
  const std::string tok = trim(tok_in);
  const std::string err =
      opt + ": expected sizes like 10k,100k,1M (integers >= 1, suffix k or M), got '" + tok_in + "'";
  if (tok.empty()) throw InputError(err);
  size_t digits = 0;
  while (digits < tok.size() && std::isdigit((unsigned char)tok[digits])) ++digits;
  if (digits == 0 || digits > 9) throw InputError(err);
  double mult = 1;
  const std::string suffix = tok.substr(digits);
  if (suffix == "k" || suffix == "K")
    mult = 1e3;
  else if (suffix == "M" || suffix == "m")
    mult = 1e6;
  else if (!suffix.empty())
    throw InputError(err);
  const double v = std::stod(tok.substr(0, digits)) * mult;
  if (v < 1 || v > 1e8) throw InputError(opt + ": " + tok + " is out of range [1, 100M]");
  return long(v);
}

std::string countLabel(long n) {
  if (n >= 1000000 && n % 1000000 == 0) return std::to_string(n / 1000000) + "M";
  if (n >= 1000 && n % 1000 == 0) return std::to_string(n / 1000) + "k";
  return std::to_string(n);
}

std::string num(double v, const char* fmt = "%.6g") {
  if (v < 0 || !std::isfinite(v)) return "";
  char b[64];
  std::snprintf(b, sizeof b, fmt, v);
  return b;
}

// Host copy bandwidth (read + write), a parallel memcpy over the threads the CPU backend uses; median of 5.
double measureHostCopyBandwidth(size_t bytes, int threads) {
  std::vector<char> a(bytes, 1), b(bytes, 0);
  std::vector<double> t;
  for (int rep = 0; rep < 6; ++rep) {
    const auto t0 = Clock::now();
#ifdef _OPENMP
#pragma omp parallel for num_threads(threads) schedule(static)
#endif
    for (long k = 0; k < 64; ++k) {
      const size_t chunk = bytes / 64, off = size_t(k) * chunk;
      std::memcpy(b.data() + off, a.data() + off, k == 63 ? bytes - off : chunk);
    }
    if (rep > 0) t.push_back(std::chrono::duration<double>(Clock::now() - t0).count());
  }
  (void)threads;
  std::sort(t.begin(), t.end());
  return 2.0 * double(bytes) / t[t.size() / 2] * 1e-9;
}

// ---------- running one configuration ----------

struct Plan {
  int warmup, steps;
};

Plan planFor(const std::string& engine, long n, bool quick) {
  if (quick) return {2, 3};
  if (engine == "gpu" || engine == "bullet3_opencl") return n >= 1000000 ? Plan{3, 5} : Plan{5, 20};
  if (n >= 100000) return {1, 3};
  if (n >= 10000) return {2, 5};
  return {3, 10};
}

void groupStages(Row& r, const std::array<double, dvi::kStageCount>& ms) {
  using dvi::StageType;
  auto at = [&](StageType s) { return ms[size_t(s)]; };
  r.broad = at(StageType::ComputeAabbs) + at(StageType::BroadPhase);
  r.narrow = at(StageType::NarrowPhase);
  r.solve = at(StageType::BuildRows) + at(StageType::WarmStart) + at(StageType::Solve);
  r.solve_only_ms = at(StageType::Solve);
  r.integrate = at(StageType::IntegrateForces) + at(StageType::IntegrateVelocities) + at(StageType::IntegratePositions);
  r.other = std::max(0.0, r.ms - r.broad - r.narrow - r.solve - r.integrate);
}

Row runOurs(const std::string& engine, const dvi::bench::SceneSpec& spec, const dvi::SystemConfig& cfg, bool quick,
            double budget, double copy_gbps) {
  Row r;
  r.engine = engine;
  r.scene = spec.name;
  r.n = long(spec.bodies.size());
  r.ref_length = double(spec.ref_length);
  const auto t_setup = Clock::now();
  std::unique_ptr<dvi::System> sys = engine == "gpu" ? dvi::makeGpuSystem(cfg) : std::make_unique<dvi::System>(cfg);
  dvi::bench::addToSystem(spec, *sys);
  r.bodies = long(sys->bodies().count());
  r.device = sys->deviceName();
  r.threads = engine == "gpu" ? 0 : sys->effectiveThreads();
  r.setup_s = std::chrono::duration<double>(Clock::now() - t_setup).count();
  Plan p = planFor(engine, r.n, quick);
  double last = 0;
  for (int s = 0; s < p.warmup; ++s) {
    const auto t0 = Clock::now();
    sys->step();
    last = std::chrono::duration<double>(Clock::now() - t0).count();
  }
  p.steps = fitSteps(p.steps, last, budget);
  r.warmup = p.warmup;
  r.steps = p.steps;
  std::array<double, dvi::kStageCount> stage_ms{};
  double wall = 0, pen = 0;
  int kept = 0;
  for (int s = 0; s < p.steps; ++s) {
    const auto t0 = Clock::now();
    sys->step();
    wall += std::chrono::duration<double>(Clock::now() - t0).count();
    const dvi::StepStats& st = sys->lastStats();
    for (int k = 0; k < dvi::kStageCount; ++k) stage_ms[size_t(k)] += st.stage_seconds[size_t(k)] * 1e3 / p.steps;
    r.contacts += double(st.contacts) / p.steps;
    r.iterations += double(st.iterations) / p.steps;
    pen = std::max(pen, double(st.max_penetration));
    kept += st.pairs_reused ? 1 : 0;
  }
  r.pairs_kept = kept;
  r.ms = wall * 1e3 / p.steps;
  groupStages(r, stage_ms);
  {  // every stage of the named step (StageType), for the profile behind the grouped columns
    std::string line = "  stages " + engine + " " + spec.name + " " + std::to_string(r.n) + " (pairs kept " +
                       std::to_string(kept) + "/" + std::to_string(p.steps) + "; ms/step):";
    for (int k = 0; k < dvi::kStageCount; ++k)
      if (stage_ms[size_t(k)] > 0)
        line += " " + std::string(dvi::stageName(dvi::StageType(k))) + " " + num(stage_ms[size_t(k)], "%.3f");
    std::printf("%s\n", line.c_str());
  }
  r.max_pen_rel = pen / r.ref_length;
  if (r.solve_only_ms > 0 && r.iterations > 0) {
    r.solve_gbps =
        dvi::bench::solverIterationBytes(r.contacts, double(r.bodies)) * r.iterations / (r.solve_only_ms * 1e-3) * 1e-9;
    if (copy_gbps > 0) {
      r.copy_gbps = copy_gbps;
      r.pct_copy = 100.0 * r.solve_gbps / copy_gbps;
    }
  }
#if defined(DVISIM_HAVE_CUDA)
  if (auto* g = dynamic_cast<dvi::GpuSystem*>(sys.get())) r.device_mib = double(g->deviceBytes()) / double(1 << 20);
#endif
  return r;
}

Row runBullet(const dvi::bench::SceneSpec& spec, bool quick, double budget) {
  Row r;
  r.engine = "bullet";
  r.scene = spec.name;
  r.n = long(spec.bodies.size());
  r.ref_length = double(spec.ref_length);
  r.threads = 1;
  const auto t_setup = Clock::now();
  dvi::bench::BulletScene scene = dvi::bench::makeBulletScene(spec);
  dvi::BulletPeerSettings bs;
  bs.dt = dvi::real(1e-3);
  bs.solver_iterations = 10;  // Bullet's default
  bs.length_scale = 100;      // centimetres: Bullet's absolute tolerances (0.04 margin) break 1 cm bodies in metres
  dvi::BulletPeer peer(scene.bodies, bs);
  r.bodies = long(scene.bodies.size());
  r.device = "Bullet " + std::to_string(btGetVersion() / 100) + "." + std::to_string(btGetVersion() % 100) +
             " btDiscreteDynamicsWorld, sequential impulse 10 it, 1 thread, cm";
  r.setup_s = std::chrono::duration<double>(Clock::now() - t_setup).count();
  Plan p = planFor("bullet", r.n, quick);
  double last = 0;
  for (int s = 0; s < p.warmup; ++s) {
    const auto t0 = Clock::now();
    peer.step();
    last = std::chrono::duration<double>(Clock::now() - t0).count();
  }
  p.steps = fitSteps(p.steps, last, budget);
  r.warmup = p.warmup;
  r.steps = p.steps;
  double wall = 0, pen = 0;
  for (int s = 0; s < p.steps; ++s) {
    const auto t0 = Clock::now();
    peer.step();
    wall += std::chrono::duration<double>(Clock::now() - t0).count();
    r.contacts += double(peer.lastStats().contacts) / p.steps;
    pen = std::max(pen, double(peer.lastStats().max_penetration));
  }
  r.ms = wall * 1e3 / p.steps;
  r.broad = r.narrow = r.solve = r.integrate = r.other = -1;  // Bullet's stages are not split here
  r.iterations = bs.solver_iterations;
  r.max_pen_rel = pen / r.ref_length;
  return r;
}

// Bullet 3's OpenCL pipeline, in a child process (bench_scaling_bullet3.h); its log and the kernel cache go to
// work_dir.
Row runBullet3Row(const dvi::bench::SceneSpec& spec, bool quick, double budget, dvi::bench::OpenClDeviceType device,
                  const std::string& work_dir) {
  Bullet3Job job;
  job.scene = spec.name;
  job.n = long(spec.bodies.size());
  const Plan p = planFor("bullet3_opencl", job.n, quick);
  job.warmup = p.warmup;
  job.steps = p.steps;
  job.budget = budget;
  job.device = device;
  job.cache_dir = work_dir + "/kernel_cache";
  // Set-up (kernels compiled on the first run: tens of seconds), warm-up and timed steps (budget), the penetration
  // check (seconds at 4M); a hung device is stopped after this, 420 s with the default budget: less than the 10
  // minutes a device-machine command may take, so a hang costs a row there too, not the run's output.
  const double timeout_s = 300 + 4 * budget;
  const Bullet3Outcome b =
      runBullet3Isolated(job, work_dir + "/" + spec.name + "_" + countLabel(job.n) + ".log", timeout_s);
  Row r;
  r.engine = "bullet3_opencl";
  r.scene = spec.name;
  r.n = job.n;
  r.ref_length = double(spec.ref_length);
  r.status = b.status;
  if (!b.ok()) return r;
  r.device = b.device;
  r.bodies = b.bodies;
  r.warmup = b.warmup;
  r.steps = b.steps;
  r.setup_s = b.setup_s;
  r.ms = b.ms;
  r.contacts = b.contacts;
  r.iterations = 4;  // Bullet 3's GPU PGS (b3GpuPgsContactSolver::solveContacts), not a setting
  r.broad = r.narrow = r.solve = r.integrate = r.other = -1;  // not split
  r.max_pen_rel = b.max_penetration / r.ref_length;
  return r;
}

// ---------- outputs ----------

const char* kCsvHeader =
    "engine,scene,n,bodies,threads,warmup_steps,timed_steps,pairs_kept_steps,setup_s,ms_per_step,ms_broad,ms_narrow,"
    "ms_solve,ms_integrate,ms_other,contacts,iterations,max_penetration_rel,ref_length_m,device_mib,solve_model_gbps,"
    "copy_gbps,solve_pct_of_copy,device,status";

std::string csvText(const std::vector<Row>& rows) {
  std::ostringstream o;
  o << kCsvHeader << "\n";
  for (const Row& r : rows) {
    const bool ok = r.ok();
    auto v = [&](double x) { return ok ? num(x) : std::string(); };
    o << r.engine << "," << r.scene << "," << r.n << "," << (ok ? std::to_string(r.bodies) : "") << ","
      << (ok ? std::to_string(r.threads) : "") << "," << (ok ? std::to_string(r.warmup) : "") << ","
      << (ok ? std::to_string(r.steps) : "") << "," << (ok && r.pairs_kept >= 0 ? std::to_string(r.pairs_kept) : "")
      << "," << v(r.setup_s) << "," << v(r.ms) << "," << v(r.broad) << "," << v(r.narrow) << "," << v(r.solve) << ","
      << v(r.integrate) << "," << v(r.other) << "," << v(r.contacts) << "," << v(r.iterations) << ","
      << v(r.max_pen_rel) << "," << num(r.ref_length) << "," << v(r.device_mib) << "," << v(r.solve_gbps) << ","
      << v(r.copy_gbps) << "," << v(r.pct_copy) << "," << csvField(r.device) << "," << csvField(r.status) << "\n";
  }
  return o.str();
}

// `common_status`: a status shared by every row of an engine that did not run at all (no Bullet 3 peer or no
// OpenCL device), said once in the notes instead of on a line per size.
std::string tableText(const std::vector<Row>& rows, const std::string& common_status) {
  std::ostringstream o;
  char line[512];
  std::snprintf(line, sizeof line, "%-14s %-5s %6s %10s %8s %8s %8s %8s %10s %8s %8s %9s %7s\n", "engine", "scene", "N",
                "ms/step", "broad", "narrow", "solve", "integr", "contacts", "pen/ref", "dev MiB", "solv GB/s",
                "%copy");
  o << line;
  auto f = [](double x, const char* fmt) { return x < 0 ? std::string("-") : num(x, fmt); };
  for (const Row& r : rows) {
    if (!r.ok()) {
      if (!common_status.empty() && r.status == common_status) continue;
      std::snprintf(line, sizeof line, "%-14s %-5s %6s  %s\n", r.engine.c_str(), r.scene.c_str(),
                    countLabel(r.n).c_str(), r.status.c_str());
      o << line;
      continue;
    }
    std::snprintf(line, sizeof line, "%-14s %-5s %6s %10s %8s %8s %8s %8s %10.0f %8s %8s %9s %7s\n", r.engine.c_str(),
                  r.scene.c_str(), countLabel(r.n).c_str(), num(r.ms, "%.2f").c_str(), f(r.broad, "%.2f").c_str(),
                  f(r.narrow, "%.2f").c_str(), f(r.solve, "%.2f").c_str(), f(r.integrate, "%.2f").c_str(), r.contacts,
                  num(r.max_pen_rel, "%.4f").c_str(), f(r.device_mib, "%.0f").c_str(), f(r.solve_gbps, "%.1f").c_str(),
                  f(r.pct_copy, "%.1f").c_str());
    o << line;
  }
  return o.str();
}

const Row* findRow(const std::vector<Row>& rows, const std::string& engine, const std::string& scene, long n) {
  for (const Row& r : rows)
    if (r.ok() && r.engine == engine && r.scene == scene && r.n == n) return &r;
  return nullptr;
}

// The largest N at which both engines ran the scene, preferring `want`.
std::optional<long> commonN(const std::vector<Row>& rows, const std::string& a, const std::string& b,
                            const std::string& scene, long want) {
  if (findRow(rows, a, scene, want) && findRow(rows, b, scene, want)) return want;
  std::optional<long> best;
  for (const Row& r : rows)
    if (r.ok() && r.engine == a && r.scene == scene && findRow(rows, b, scene, r.n) && (!best || r.n > *best))
      best = r.n;
  return best;
}

std::string verdict(double value, double goal, bool at_most) {
  char b[128];
  const bool met = at_most ? value <= goal : value >= goal;
  if (met) return "met";
  const double f = at_most ? value / goal : goal / value;
  // A near miss as a percentage ("missed by 1.0x" said nothing of 296.5x against 300x).
  if (f < 1.1)
    std::snprintf(b, sizeof b, "missed by %.1f%%", 100 * (f - 1));
  else
    std::snprintf(b, sizeof b, "missed by %.1fx", f);
  return b;
}

// The performance goals read from this run, then the same ratios for the mix.
std::string goalsText(const std::vector<Row>& rows, const std::string& gpu_status) {
  std::ostringstream o;
  char b[512];
  o << "Goals, from this run:\n";
  const bool gpu = std::any_of(rows.begin(), rows.end(), [](const Row& r) { return r.ok() && r.engine == "gpu"; });
  if (!gpu) o << "  GPU: " << gpu_status << " -- the GPU goals are not evaluated in this run.\n";
  for (const std::string scene : {"pile", "mix"}) {
    const bool any = std::any_of(rows.begin(), rows.end(), [&](const Row& r) { return r.ok() && r.scene == scene; });
    if (!any) continue;
    const std::string tag = scene == "pile" ? "" : " [mix, for information]";
    if (gpu) {
      if (const Row* g = findRow(rows, "gpu", scene, 1000000)) {
        std::snprintf(b, sizeof b, "  GPU ms/step at 1M: %.2f (goal <= 20): %s%s\n", g->ms,
                      verdict(g->ms, 20, true).c_str(), tag.c_str());
        o << b;
      } else {
        o << "  GPU ms/step at 1M: not run (1M not in --sizes)" << tag << "\n";
      }
      const Row* bw = findRow(rows, "gpu", scene, 1000000);
      if (!bw)
        for (const Row& r : rows)
          if (r.ok() && r.engine == "gpu" && r.scene == scene && (!bw || r.n > bw->n)) bw = &r;
      if (bw && bw->pct_copy >= 0) {
        std::snprintf(
            b, sizeof b,
            "  solver bandwidth at %s: %.0f GB/s = %.1f%% of the measured copy %.0f GB/s (goal >= 60%%): %s%s\n",
            countLabel(bw->n).c_str(), bw->solve_gbps, bw->pct_copy, bw->copy_gbps,
            verdict(bw->pct_copy, 60, false).c_str(), tag.c_str());
        o << b;
      }
    }
    const struct {
      const char *a, *b, *what;
      double goal;
    } ratios[] = {{"gpu", "bullet", "GPU speed-up over Bullet (1 thread)", 300},
                  {"gpu", "cpu", "GPU speed-up over our CPU backend", 20},
                  {"cpu", "bullet", "our CPU backend's speed-up over Bullet (1 thread)", 0},
                  {"gpu", "bullet3_opencl", "GPU speed-up over Bullet 3's OpenCL GPU pipeline", 0}};
    for (const auto& q : ratios) {
      if (!gpu && std::string(q.a) == "gpu") continue;
      const std::optional<long> n = commonN(rows, q.a, q.b, scene, 100000);
      if (!n) continue;
      const double ratio = findRow(rows, q.b, scene, *n)->ms / findRow(rows, q.a, scene, *n)->ms;
      std::string goal =
          q.goal > 0 ? " (goal >= " + num(q.goal, "%.0f") + "x at 100k): " + verdict(ratio, q.goal, false) : "";
      if (q.goal > 0 && *n != 100000) goal += " -- at " + countLabel(*n) + ", 100k not run";
      std::snprintf(b, sizeof b, "  %s at %s: %.1fx%s%s\n", q.what, countLabel(*n).c_str(), ratio, goal.c_str(),
                    tag.c_str());
      o << b;
    }
  }
  return o.str();
}

std::string notesText(double dev_copy, double host_copy, const std::string& bullet3) {
  std::ostringstream o;
  o << "Notes:\n"
    << "- Stages (ms/step): broad = ComputeAabbs + BroadPhase; narrow = NarrowPhase; solve = BuildRows + WarmStart + "
       "Solve; integrate = IntegrateForces + IntegrateVelocities + IntegratePositions; ms/step is the wall time of "
       "step().\n"
    << "- Solver bandwidth is a model: (contacts x 200 B + bodies x 50 B) per iteration x iterations / Solve-stage "
       "time "
       "(docs/MODEL.md §8, docs/GPU_PERFORMANCE.md). It is compared with the copy bandwidth measured in this run (read "
       "+ "
       "write): device "
    << (dev_copy > 0 ? num(dev_copy, "%.0f") + " GB/s" : std::string("not measured (no GPU)")) << ", host "
    << num(host_copy, "%.0f") << " GB/s (parallel memcpy over the CPU backend's threads).\n"
    << "- Penetration is the deepest over the timed steps (Bullet 3: at their end, see below), relative to the scene's "
       "reference length (pile: r = 1 cm; mix: its smallest size, 0.5 cm).\n"
    << "- contacts: ours count every contact within the collision envelope; Bullet's peer counts manifold points at "
       "negative distance; Bullet 3 counts its contact manifolds (one per touching sphere pair, up to 4 points per "
       "hull pair), which it makes only for touching or overlapping pairs.\n"
    << "- Bullet 2 runs the same bodies in centimetres (BulletPeer length_scale 100) with 10 sequential-impulse "
       "iterations on 1 thread; its numbers are converted back to metres.\n"
    << "- Bullet 3 OpenCL GPU pipeline (bench/scaling/bullet3_peer.h): " << bullet3 << "\n";
  return o.str();
}

// Locates scripts/plot_scaling.py (env DVISIM_PLOT_SCALING, next to the binary, ../share/dvisim, the source
// tree), copies it into DIR and runs it. Returns a one-line message.
std::string makePlot(const std::string& dir) {
  std::vector<std::string> candidates;
  if (const char* e = std::getenv("DVISIM_PLOT_SCALING")) candidates.push_back(e);
  const std::string exe = exeDir();
  if (!exe.empty()) {
    candidates.push_back(exe + "/plot_scaling.py");
    candidates.push_back(exe + "/../share/dvisim/plot_scaling.py");
  }
  if (!sourceDir().empty()) candidates.push_back(sourceDir() + "/scripts/plot_scaling.py");
  std::string script;
  for (const std::string& c : candidates)
    if (fs::is_regular_file(c)) {
      script = c;
      break;
    }
  if (script.empty()) return "scaling.png not written: plot_scaling.py not found (set DVISIM_PLOT_SCALING)";
  const std::string local = dir + "/plot_scaling.py";
  std::error_code ec;
  if (fs::absolute(script) != fs::absolute(local))
    fs::copy_file(script, local, fs::copy_options::overwrite_existing, ec);
  const std::string python = dvi::pythonWithMatplotlib();
  if (python.empty())
    return "scaling.png not written: python3 with matplotlib is missing (Debian: apt-get install python3-matplotlib); "
           "the CSV is complete, plot later with: python3 " +
           local + " " + dir;
  const std::string cmd = python + " " + shellQuote(ec ? script : local) + " " + shellQuote(dir) + " >" +
                          shellQuote(dir + "/plot_scaling.log") + " 2>&1";
  if (std::system(cmd.c_str()) != 0)
    return "scaling.png not written: plot_scaling.py failed (see " + dir + "/plot_scaling.log)";
  return "plot: " + dir + "/scaling.png";
}

// ---------- the benchmark ----------

// The newest record of the device whose records start with `prefix` ("scaling_<device slug>_") in dir, or "".
std::string newestRecord(const std::string& dir, const std::string& prefix) {
  std::string best;
  std::error_code ec;
  for (const fs::directory_entry& e : fs::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind(prefix, 0) == 0 && name.size() > 4 && name.compare(name.size() - 4, 4, ".csv") == 0 && name > best)
      best = name;
  }
  return best.empty() ? best : dir + "/" + best;
}

// Each stage of each row against the same (engine, scene, N) row of the newest earlier record of the same device:
// one line per row with the ratios (this run / the record), and a line starting "REGRESSION" for every stage that
// got more than 10% slower (stages under 0.05 ms are left out: launch noise). Empty when there is no record.
std::string regressionText(const std::vector<Row>& rows, const std::string& record) {
  if (record.empty()) return "";
  std::ifstream in(record);
  std::string line;
  std::getline(in, line);  // the header (kCsvHeader's columns: ms_per_step is the 10th)
  std::map<std::string, std::array<double, 5>> old;
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream ss(line);
    for (std::string x; std::getline(ss, x, ',');) f.push_back(x);
    if (f.size() < 15 || f[9].empty()) continue;
    std::array<double, 5> v{};
    for (int k = 0; k < 5; ++k) v[size_t(k)] = std::atof(f[size_t(9 + k)].c_str());
    old[f[0] + "," + f[1] + "," + f[2]] = v;
  }
  const char* names[5] = {"step", "BroadPhase", "NarrowPhase", "Solve", "Integrate"};
  std::ostringstream o, bad;
  o << "against the newest record of this device (" << fs::path(record).filename().string()
    << "), this run / record:\n";
  for (const Row& r : rows) {
    auto it = old.find(r.engine + "," + r.scene + "," + std::to_string(r.n));
    if (!r.ok() || it == old.end()) continue;
    const double now[5] = {r.ms, r.broad, r.narrow, r.solve, r.integrate};
    char buf[160];
    std::snprintf(buf, sizeof buf, "  %-6s %-4s %6s:", r.engine.c_str(), r.scene.c_str(), countLabel(r.n).c_str());
    o << buf;
    for (int k = 0; k < 5; ++k) {
      const double was = it->second[size_t(k)];
      if (!(was > 0)) continue;
      std::snprintf(buf, sizeof buf, " %s %.2f", names[k], now[k] / was);
      o << buf;
      if (now[k] > 1.1 * was && std::max(now[k], was) >= 0.05) {
        std::snprintf(buf, sizeof buf, "REGRESSION %s %s %s %s: %.3f ms against %.3f ms (%.2fx)\n", r.engine.c_str(),
                      r.scene.c_str(), countLabel(r.n).c_str(), names[k], now[k], was, now[k] / was);
        bad << buf;
      }
    }
    o << "\n";
  }
  return o.str() + bad.str();
}

// `bench scaling --mpi`: the domain decomposition's weak and strong scaling (bench_scaling_mpi.h).
int runScalingOverMpi(const ScalingOptions& o) {
#ifdef DVISIM_HAVE_MPI
  MpiScalingOptions m;
  static_cast<BenchBasics&>(m) = o;
  m.per_process = o.per_process;
  m.total = o.total;
  m.steps = o.mpi_steps;
  m.backend = o.mpi_backend;
  m.modes = o.mpi_modes;
  m.baseline = o.mpi_baseline;
  return runScalingMpi(m);
#else
  (void)o;
  throw InputError("--mpi: this build has no MPI (configure with DVISIM_ENABLE_MPI=ON and libopenmpi-dev)");
#endif
}

// The run's input, validated before any work.
struct ScalingPlan {
  std::vector<long> sizes;
  std::vector<std::string> scenes, engines;
  dvi::bench::OpenClDeviceType b3_device;
  long cpu_max;
  int threads;
  double budget;
  std::string dir, results_dir;
  bool has(const char* e) const { return std::find(engines.begin(), engines.end(), e) != engines.end(); }
};

ScalingPlan planScaling(const ScalingOptions& o) {
  std::vector<long> sizes;
  for (const std::string& t : splitList(o.sizes)) sizes.push_back(parseCount("--sizes", t));
  if (sizes.empty())
    sizes = o.quick ? std::vector<long>{1000, 4000} : std::vector<long>{10000, 100000, 1000000, 4000000};
  std::sort(sizes.begin(), sizes.end());
  sizes.erase(std::unique(sizes.begin(), sizes.end()), sizes.end());
  std::vector<std::string> scenes = splitList(o.scenes), engines = splitList(o.engines);
  if (scenes.empty()) scenes = {"pile", "mix"};
  if (engines.empty()) engines = {"gpu", "cpu", "bullet", "bullet3_opencl"};
  for (const std::string& s : scenes)
    if (s != "pile" && s != "mix") throw InputError("--scenes: unknown scene '" + s + "' (expected pile,mix)");
  for (const std::string& e : engines)
    if (e != "gpu" && e != "cpu" && e != "bullet" && e != "bullet3_opencl")
      throw InputError("--engines: unknown engine '" + e + "' (expected gpu,cpu,bullet,bullet3_opencl)");
  const dvi::bench::OpenClDeviceType b3_device = dvi::bench::parseOpenClDeviceType(o.bullet3_device);
  const long cpu_max = parseCount("--cpu-max", o.cpu_max);
  const int threads = benchThreads(o.threads);
  char* end = nullptr;
  const double budget = std::strtod(o.budget.c_str(), &end);
  if (o.budget.empty() || *end || !(budget > 0) || !std::isfinite(budget))
    throw InputError("--budget: expected seconds > 0, got '" + o.budget + "'");

  const std::string dir = o.out;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    throw InputError("--out " + dir + ": cannot create the output directory" + (ec ? " (" + ec.message() + ")" : ""));
  if (::access(dir.c_str(), W_OK) != 0 || !std::ofstream(dir + "/scaling.csv"))
    throw InputError("--out " + dir + ": the directory is not writable");
  std::string results_dir;
  if (o.record) {
    results_dir = !o.results_dir.empty() ? o.results_dir
                  : !sourceDir().empty() ? sourceDir() + "/bench/results"
                                         : std::string("bench/results");
    fs::create_directories(results_dir, ec);
    if (ec || !fs::is_directory(results_dir) || ::access(results_dir.c_str(), W_OK) != 0)
      throw InputError("--results-dir " + results_dir + ": cannot create or write the directory");
  }

  return ScalingPlan{sizes, scenes, engines, b3_device, cpu_max, threads, budget, dir, results_dir};
}

// Our engine's settings for the rows: APGD at a fixed 50 iterations, h = 1 ms, and the options' variants.
dvi::SystemConfig scalingConfig(const ScalingOptions& o, int threads) {
  dvi::SystemConfig cfg;
  cfg.step.dt = dvi::real(1e-3);
  cfg.solver.type = dvi::SolverType::APGD;
  cfg.solver.max_iterations = 50;
  cfg.solver.tolerance = 0;  // all 50 iterations
  cfg.threads = int(threads);
  cfg.gpu.graphs = o.gpu_graphs;
  if (o.gpu_persistent_max >= 0) cfg.gpu.persistent_max_blocks = o.gpu_persistent_max;
  cfg.gpu.apgd_register_cache = o.gpu_register_cache;
  cfg.collision.broadphase.pair_margin = dvi::real(o.pair_margin);
  cfg.collision.mpr_manifold = o.mpr_manifold;
  cfg.collision.mpr_coherence = o.mpr_coherence;
  cfg.gpu.entry_gather = o.gpu_entry_gather;
  cfg.gpu.narrow_classes = o.gpu_narrow_classes;
  cfg.collision.gjk = o.gjk == "all"           ? dvi::GjkUse::All
                      : o.gjk == "polytopes"   ? dvi::GjkUse::Polytopes
                      : o.gjk == "nocylinders" ? dvi::GjkUse::NoCylinders
                      : o.gjk == "off"         ? dvi::GjkUse::Off
                                               : dvi::GjkUse::Auto;
  cfg.solver.storage = o.storage == "real"    ? dvi::VectorStorage::Real
                       : o.storage == "float" ? dvi::VectorStorage::Float
                                              : dvi::VectorStorage::Auto;
  cfg.solver.apgd_speculation = o.speculation == "none"       ? dvi::ApgdSpeculation::None
                                : o.speculation == "accepted" ? dvi::ApgdSpeculation::Accepted
                                : o.speculation == "both"     ? dvi::ApgdSpeculation::Both
                                                              : dvi::ApgdSpeculation::Auto;

  return cfg;
}

// What the machine offers: the GPU (or why none), the host's CPU, Bullet 3's OpenCL device, copy bandwidths.
struct ScalingEnv {
  bool have_gpu;
  std::string gpu_name, gpu_status, cpu_model, cpu_name, b3_what, b3_status, b3_dir;
  int host_threads;
  double dev_copy, host_copy;
};

// Probes the machine, prints what it found, and (with --record on a GPU) adds the mixed pile at 1M bodies.
ScalingEnv probeScaling(const ScalingOptions& o, ScalingPlan& p, const dvi::SystemConfig& cfg) {
  std::vector<long>& sizes = p.sizes;
  std::vector<std::string>& scenes = p.scenes;
  const int threads = p.threads;
  const std::string& dir = p.dir;
  auto has = [&](const char* e) { return p.has(e); };
  const dvi::bench::OpenClDeviceType b3_device = p.b3_device;
  std::error_code ec;
  std::string gpu_name;
  const bool have_gpu = has("gpu") && dvi::gpuAvailable(&gpu_name);
  // Every GPU record carries the mixed pile at 1M bodies: the narrow phase's cost there (MPR pairs) is what a
  // sphere-only record cannot show, and a record without it once let a 2x slower narrow phase go unseen.
  if (o.record && have_gpu && !o.quick) {
    if (std::find(scenes.begin(), scenes.end(), "mix") == scenes.end()) scenes.push_back("mix");
    if (std::find(sizes.begin(), sizes.end(), 1000000L) == sizes.end()) {
      sizes.push_back(1000000);
      std::sort(sizes.begin(), sizes.end());
    }
  }
  const std::string gpu_status =
      has("gpu")
          ? (have_gpu ? "" : "skipped: no GPU (" + (gpu_name.empty() ? std::string("no CUDA device") : gpu_name) + ")")
          : "skipped: not in --engines";
#ifdef _OPENMP
  const int host_threads = threads > 0 ? int(threads) : omp_get_num_procs();
#else
  const int host_threads = 1;
#endif
  std::string cpu_model = dvi::System(cfg).deviceName();  // "model (k threads)" for an empty scene
  cpu_model = cpu_model.substr(0, cpu_model.rfind(" ("));
  const std::string cpu_name = cpu_model + " (" + std::to_string(host_threads) + " threads)";
  std::printf("bench scaling: scenes %s; sizes",
              [&] {
                std::string s;
                for (auto& x : scenes) s += (s.empty() ? "" : ",") + x;
                return s;
              }()
                  .c_str());
  for (long n : sizes) std::printf(" %s", countLabel(n).c_str());
  std::printf("; h = 1e-3 s, APGD 50 iterations, %s precision\n", sizeof(dvi::real) == 8 ? "double" : "float");
  std::printf("GPU: %s\nCPU: %s\n", have_gpu ? gpu_name.c_str() : gpu_status.c_str(), cpu_name.c_str());
  // Bullet 3: the peer in this build and an OpenCL device of the asked type, else one status for all its rows.
  std::string b3_what, b3_status;
  if (has("bullet3_opencl")) {
    if (!dvi::bench::bullet3PeerBuilt(&b3_what))
      b3_status = "not run: " + b3_what;
    else if (!dvi::bench::findOpenClDevice(b3_device, &b3_what))
      b3_status = "not run: " + b3_what;
    std::printf("Bullet 3 OpenCL: %s\n", b3_status.empty() ? b3_what.c_str() : b3_status.c_str());
  }
  const std::string b3_dir = dir + "/bullet3";  // the workers' logs and Bullet 3's kernel cache
  if (has("bullet3_opencl") && b3_status.empty()) {
    fs::create_directories(b3_dir + "/kernel_cache", ec);
    if (ec) throw InputError("--out " + dir + ": cannot create " + b3_dir + " (" + ec.message() + ")");
  }
  std::fflush(stdout);

  double dev_copy = -1;
#if defined(DVISIM_HAVE_CUDA)
  if (have_gpu) dev_copy = dvi::gpu::measureCopyBandwidth(o.quick ? (size_t(64) << 20) : (size_t(1) << 30));
#endif
  const double host_copy = measureHostCopyBandwidth(o.quick ? (size_t(32) << 20) : (size_t(256) << 20), host_threads);
  std::printf("copy bandwidth (read + write): device %s, host %.0f GB/s\n",
              dev_copy > 0 ? (num(dev_copy, "%.0f") + " GB/s").c_str() : "-", host_copy);
  std::fflush(stdout);

  return ScalingEnv{have_gpu,  gpu_name, gpu_status,   cpu_model, cpu_name, b3_what,
                    b3_status, b3_dir,   host_threads, dev_copy,  host_copy};
}

// The status of Bullet 3's rows, or what its rows measured and how.
std::string bullet3Note(const ScalingOptions& o, const ScalingPlan& p, const ScalingEnv& e) {
  const std::string &b3_status = e.b3_status, &b3_what = e.b3_what, &b3_dir = e.b3_dir;
  auto has = [&](const char* x) { return p.has(x); };
  std::string b3_note = b3_status;
  if (b3_status.empty() && has("bullet3_opencl"))
    b3_note =
        "b3GpuRigidBodyPipeline on " + b3_what + " (--bullet3-device " + o.bullet3_device +
        "), the same bodies in centimetres, each configuration in a child process (logs in " + b3_dir +
        "). Bullet 3 fixes mu = 0.7 in its kernels (the scene's 0.5 cannot be set), solves contacts with 4 PGS "
        "iterations and a 1/60 s solver step, damps angular velocity by 0.99 per step; the peer gives it the scenes' "
        "masses and inertias, and the mix's cylinders and ellipsoids as convex hulls (scaling_scenes.h "
        "withConvexHulls). ms/step ends each step with clFinish; setup includes compiling Bullet 3's kernels in the "
        "first configuration (the later ones load them from " +
        b3_dir +
        "/kernel_cache). Its penetration is "
        "measured once, after the timed steps, by our narrow phase on the poses read back and the shapes Bullet 3 "
        "had; after a failure at one N the larger N of that scene are not run.";
  else if (!has("bullet3_opencl"))
    b3_note = "not in --engines.";
  return b3_note;
}

// The record's .md (--record): the machine, the settings, the table, the goals and the notes.
std::string scalingRecordMd(const ScalingOptions& o, const ScalingPlan& p, const ScalingEnv& e,
                            const dvi::SystemConfig& cfg, const std::string& table, const std::string& goals,
                            const std::string& notes, const std::string& stop_lines, const std::string& regressions,
                            const std::string& base) {
  const bool have_gpu = e.have_gpu;
  const std::string &gpu_name = e.gpu_name, &gpu_status = e.gpu_status, &cpu_name = e.cpu_name;
  const std::string &b3_status = e.b3_status, &b3_what = e.b3_what;
  const double dev_copy = e.dev_copy, host_copy = e.host_copy;
  auto has = [&](const char* x) { return p.has(x); };
  std::ostringstream md;
  md << "# Scaling benchmark: sphere pile and multidisperse mix\n\n"
     << "Written by `dvisim bench scaling --record` (bench/scaling/bench_scaling.cpp); do not edit by hand.\n\n"
     << "- GPU: " << (have_gpu ? gpu_name : gpu_status) << "\n- host CPU: " << cpu_name << "\n- Bullet 3 OpenCL: "
     << (!has("bullet3_opencl") ? std::string("not in --engines")
         : b3_status.empty()    ? b3_what
                                : b3_status)
     << "\n- commit: " << commitId() << "\n- date: " << utcNow("%Y-%m-%dT%H:%M:%SZ")
     << "\n- precision: " << (sizeof(dvi::real) == 8 ? "double" : "float")
     << "\n- GPU APGD trials: " << gpuTrialsLabel(cfg) << "; APGD storage: " << storageLabel(cfg.solver, true)
     << " on the GPU, "
     << (cfg.gpu.entry_gather ? "the gather reading each adjacency entry's float Jacobian side in entry order and "
                                "isotropic inverse masses as 16 B (gpu_entry_gather), "
                              : "the gather reading each contact's Jacobian (--gpu-entry-gather false), ")
     << storageLabel(cfg.solver, false) << " on the CPU (arithmetic in "
     << (sizeof(dvi::real) == 8 ? "double" : "float") << ")"
     << "; next step speculated by the test pass: " << speculationLabel(cfg.solver.apgd_speculation)
     << "\n- BroadPhase (ours): " << pairMarginLabel(cfg.collision.broadphase.pair_margin) << "\n- NarrowPhase (ours): "
     << (cfg.collision.mpr_manifold
             ? "MPR pairs of two flat features get up to 4 more points of their overlap (mpr_manifold)"
             : "MPR's one point per pair (--mpr-manifold false)")
     << "; deep MPR pairs on last step's face keep it (--mpr-coherence): "
     << (cfg.collision.mpr_coherence ? "true" : "false") << "; GJK before MPR (--gjk): " << o.gjk
     << "; GPU pairs by shape-pair class (--gpu-narrow-classes): " << (cfg.gpu.narrow_classes ? "true" : "false")
     << "\n- scenes: pile of N spheres (r = 1 cm, mu = 0.5) and a mix of spheres, boxes, cylinders, ellipsoids and "
        "convex hulls (sizes 0.5-2 cm, mu = 0.5), h = 1e-3 s, APGD 50 iterations (ours)\n"
     << "- copy bandwidth (read + write): device "
     << (dev_copy > 0 ? num(dev_copy, "%.0f") + " GB/s" : std::string("-")) << ", host " << num(host_copy, "%.0f")
     << " GB/s\n\n"
     << "```\n"
     << table << "```\n\n"
     << goals << "\n"
     << notes
     << (stop_lines.empty()
             ? std::string()
             : "\nSolver stop, the default (relative tolerance, iteration cap) against the rows' fixed 50 "
               "iterations, each row run again in this run (ratio = default / fixed ms per step):\n\n```\n" +
                   stop_lines + "```\n")
     << (regressions.empty() ? std::string() : "\n```\n" + regressions + "```\n") << "\nThe rows: " << base << ".csv\n";
  return md.str();
}

// cfg at the solver's default stop (SolverSettings: tolerance on the relative residual, iteration cap).
dvi::SystemConfig withDefaultStop(const dvi::SystemConfig& cfg) {
  dvi::SystemConfig d = cfg;
  d.solver.max_iterations = dvi::SolverSettings{}.max_iterations;
  d.solver.tolerance = dvi::SolverSettings{}.tolerance;
  return d;
}

// A row's line as it is measured (Bullet 3's rows that share one status print it once, above).
void printRow(const Row& r, const std::string& b3_status) {
  if (r.ok())
    std::printf(
        "  %-6s %-4s %6s: %10.2f ms/step (%d timed after %d warm-up), %.0f contacts, pen/ref %.4f, setup %.1f s\n",
        r.engine.c_str(), r.scene.c_str(), countLabel(r.n).c_str(), r.ms, r.steps, r.warmup, r.contacts, r.max_pen_rel,
        r.setup_s);
  else if (b3_status.empty() || r.status != b3_status)
    std::printf("  %-6s %-4s %6s: %s\n", r.engine.c_str(), r.scene.c_str(), countLabel(r.n).c_str(), r.status.c_str());
  std::fflush(stdout);
}

// The row of an engine that did not run a scene (status says why).
Row failedRow(const std::string& engine, const dvi::bench::SceneSpec& spec, const std::string& status) {
  Row r;
  r.engine = engine, r.scene = spec.name, r.n = long(spec.bodies.size()), r.status = status;
  r.ref_length = double(spec.ref_length);
  return r;
}

// The solver's default stop against the row's fixed 50 iterations: the row (fixed) run again at cfg_default, the
// line printed and appended to stop_lines.
void stopLine(const Row& fixed, const std::string& engine, const dvi::bench::SceneSpec& spec, double copy,
              const dvi::SystemConfig& cfg_default, const ScalingOptions& o, double budget, std::string& stop_lines) {
  if (!fixed.ok() || o.stop_compare == "off") return;
  std::string line;
  try {
    const Row d = runOurs(engine, spec, cfg_default, o.quick, budget, copy);
    char buf[400];
    std::snprintf(buf, sizeof buf,
                  "  stop   %-4s %-4s %6s: default stop (tolerance %g, cap %d) %.2f ms/step, %.1f iterations; fixed 50 "
                  "%.2f ms/step; ratio %.3f",
                  engine.c_str(), spec.name.c_str(), countLabel(fixed.n).c_str(), double(cfg_default.solver.tolerance),
                  cfg_default.solver.max_iterations, d.ms, d.iterations, fixed.ms, d.ms / fixed.ms);
    line = buf;
  } catch (const std::exception& e) {
    line = "  stop   " + engine + " " + spec.name + " " + countLabel(fixed.n) + ": default stop failed: " + e.what();
  }
  std::printf("%s\n", line.c_str());
  std::fflush(stdout);
  stop_lines += line + "\n";
}

int runScaling(const ScalingOptions& o) {
  if (o.mpi) return runScalingOverMpi(o);
  ScalingPlan p = planScaling(o);
  const dvi::SystemConfig cfg = scalingConfig(o, p.threads);
  const ScalingEnv env = probeScaling(o, p, cfg);
  const std::vector<long>& sizes = p.sizes;
  const std::vector<std::string>& scenes = p.scenes;
  auto has = [&](const char* e) { return p.has(e); };
  const dvi::bench::OpenClDeviceType b3_device = p.b3_device;
  const long cpu_max = p.cpu_max;
  const double budget = p.budget;
  const std::string &dir = p.dir, &results_dir = p.results_dir;
  const bool have_gpu = env.have_gpu;
  const std::string &gpu_name = env.gpu_name, &gpu_status = env.gpu_status, &cpu_model = env.cpu_model;
  const std::string &cpu_name = env.cpu_name, &b3_status = env.b3_status, &b3_dir = env.b3_dir;
  const double dev_copy = env.dev_copy, host_copy = env.host_copy;
  std::vector<Row> rows;
  auto flush = [&] { writeFile(dir + "/scaling.csv", csvText(rows)); };
  auto report = [&](const Row& r) { printRow(r, b3_status); };
  std::map<std::string, long> b3_failed_at;  // scene -> the N at which Bullet 3 failed (larger N are not run)
  // The solver's default stop (tolerance on the relative residual, SolverSettings) against the fixed 50 iterations
  // of the rows: each of our rows is run again at the defaults and the ratio printed side by side (one line per row,
  // repeated after the table). The CSV keeps the fixed-50 rows.
  const dvi::SystemConfig cfg_default = withDefaultStop(cfg);
  std::string stop_lines;
  auto compareStop = [&](const std::string& engine, const dvi::bench::SceneSpec& spec, double copy) {
    stopLine(rows.back(), engine, spec, copy, cfg_default, o, budget, stop_lines);
  };
  for (long n : sizes) {
    for (const std::string& scene : scenes) {
      const dvi::bench::SceneSpec spec = dvi::bench::makeSceneSpec(scene, n);
      auto attempt = [&](const std::string& engine, auto&& fn) {
        try {
          rows.push_back(fn());
        } catch (const std::exception& e) {
          rows.push_back(failedRow(engine, spec, std::string("error: ") + e.what()));
        }
        report(rows.back());
        flush();
      };
      if (has("gpu")) {
        if (have_gpu)
          attempt("gpu", [&] { return runOurs("gpu", spec, cfg, o.quick, budget, dev_copy); }),
              compareStop("gpu", spec, dev_copy);
        else
          rows.push_back(failedRow("gpu", spec, gpu_status)), report(rows.back());
      }
      if (has("bullet3_opencl")) {
        if (!b3_status.empty()) {
          rows.push_back(failedRow("bullet3_opencl", spec, b3_status)), report(rows.back());
        } else if (b3_failed_at.count(scene)) {
          rows.push_back(failedRow("bullet3_opencl", spec,
                                   "not run: failed at smaller N (" + countLabel(b3_failed_at[scene]) + ")"));
          report(rows.back());
        } else {
          attempt("bullet3_opencl", [&] { return runBullet3Row(spec, o.quick, budget, b3_device, b3_dir); });
          if (!rows.back().ok()) b3_failed_at[scene] = n;
        }
      }
      if (n <= cpu_max) {
        if (has("cpu"))
          attempt("cpu", [&] { return runOurs("cpu", spec, cfg, o.quick, budget, host_copy); }),
              compareStop("cpu", spec, host_copy);
        if (has("bullet")) attempt("bullet", [&] { return runBullet(spec, o.quick, budget); });
      }
      flush();
    }
  }

  const std::string b3_note = bullet3Note(o, p, env);
  const std::string table = tableText(rows, b3_status), goals = goalsText(rows, gpu_status),
                    notes = notesText(dev_copy, host_copy, b3_note);
  std::printf("\n%s\n%s\n%s", table.c_str(), goals.c_str(), notes.c_str());
  if (!stop_lines.empty())
    std::printf("solver stop, default against the rows' fixed 50 iterations (ratio = default / fixed ms per step):\n%s",
                stop_lines.c_str());
  std::printf("results: %s/scaling.csv\n", dir.c_str());
  std::printf("%s\n", makePlot(dir).c_str());
  const std::string device_prefix = "scaling_" + slug(have_gpu ? gpu_name : "cpu-" + cpu_model) + "_";
  const std::string records = !results_dir.empty()   ? results_dir
                              : !sourceDir().empty() ? sourceDir() + "/bench/results"
                                                     : "bench/results";
  const std::string regressions = regressionText(rows, newestRecord(records, device_prefix));
  std::printf("%s", regressions.c_str());

  if (o.record) {
    const std::string device = have_gpu ? gpu_name : cpu_name;
    const std::string base = device_prefix + utcNow("%Y%m%d-%H%M%S");
    const std::string md = scalingRecordMd(o, p, env, cfg, table, goals, notes, stop_lines, regressions, base);
    for (const std::string& d : {results_dir, dir}) {
      writeFile(d + "/" + base + ".md", md);
      writeFile(d + "/" + base + ".csv", csvText(rows));
    }
    std::printf("recorded: %s/%s.md and .csv (copies in %s/) -- device %s\n", results_dir.c_str(), base.c_str(),
                dir.c_str(), device.c_str());
  }
  return 0;
}

}  // namespace

void registerBenchScaling(CLI::App& app, BenchRegistry& reg) {
  auto [cmd, o] = addBench<ScalingOptions>(app, reg, kBench, runScaling);
  cmd->add_option("--sizes", o->sizes, "Body counts, e.g. 10k,100k,1M,4M (default; --quick: 1k,4k)");
  cmd->add_option("--scenes", o->scenes, "pile,mix (default both)");
  cmd->add_option("--engines", o->engines, "gpu,cpu,bullet,bullet3_opencl (default all)");
  cmd->add_option("--cpu-max", o->cpu_max, "Largest N for our CPU backend and Bullet (default 100k)");
  cmd->add_option("--budget", o->budget, "Seconds of timed steps per configuration at most (default 30)");
  cmd->add_option("--gpu-graphs", o->gpu_graphs,
                  "GPU APGD trials launched one by one: as one CUDA graph each (true, the default) or kernel by "
                  "kernel (false)");
  cmd->add_option("--gpu-persistent-max", o->gpu_persistent_max,
                  "APGD problems of at most this many blocks run all trials in one cooperative kernel (0: never; "
                  "default: SystemConfig's)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--gpu-register-cache", o->gpu_register_cache,
                  "Persistent APGD kernel: keep each thread's blocks in registers between trials where the problem "
                  "fits 2 blocks a thread (true, the default) or read them from memory every trial (false)");
  cmd->add_option("--pair-margin", o->pair_margin,
                  "BroadPhase keeps its pairs between steps within boxes grown by this fraction of the bin edge "
                  "(BroadPhaseSettings::pair_margin; 0: a build every step; default 0.025)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option(
      "--mpr-manifold", o->mpr_manifold,
      "MPR pairs of two flat features get up to 4 more points of their overlap (CollisionSettings::mpr_manifold; "
      "true, the default, or false: MPR's one point)");
  cmd->add_option("--mpr-coherence", o->mpr_coherence,
                  "A deep MPR pair whose first pass ends on the face of its last step's contact keeps that point "
                  "(CollisionSettings::mpr_coherence; true, the default, or false: the candidates every step)");
  cmd->add_option("--gpu-entry-gather", o->gpu_entry_gather,
                  "GPU float storage: the Schur product's gather reads each adjacency entry's side of the Jacobian in "
                  "entry order and isotropic inverse masses as 16 bytes (GpuTuning::entry_gather; true, the "
                  "default, or false: each contact's Jacobian and the full inverse mass)");
  cmd->add_option("--storage", o->storage,
                  "APGD vector storage: auto (float on the GPU, real on the CPU; the default), real or float")
      ->check(CLI::IsMember({"auto", "real", "float"}));
  cmd->add_option("--apgd-speculation", o->speculation,
                  "APGD's test pass computes the next trial's step ahead (SolverSettings::apgd_speculation; the same "
                  "iterates): auto (the default), none, accepted or both")
      ->check(CLI::IsMember({"auto", "none", "accepted", "both"}));
  cmd->add_option(
         "--stop-compare", o->stop_compare,
         "on (the default): each of our rows (fixed 50 APGD iterations) runs again at the solver's default stop "
         "(relative tolerance, iteration cap) and the ms/step ratio is printed; off: not")
      ->check(CLI::IsMember({"on", "off"}));
  cmd->add_option("--bullet3-device", o->bullet3_device,
                  "OpenCL device type of the Bullet 3 peer: gpu (the default), cpu (pocl, for tests) or any")
      ->check(CLI::IsMember({"gpu", "cpu", "any"}));
  cmd->add_option("--gjk", o->gjk,
                  "Which MPR pairs try GJK first: auto (the backend's choice), all, polytopes, nocylinders, off "
                  "(CollisionSettings::gjk)")
      ->check(CLI::IsMember({"auto", "all", "polytopes", "nocylinders", "off"}));
  cmd->add_option("--gpu-narrow-classes", o->gpu_narrow_classes,
                  "GPU narrow phase by shape-pair class (GpuTuning::narrow_classes; default true)");
  cmd->add_option("--results-dir", o->results_dir, "Where --record writes (default bench/results of the source tree)");
  cmd->add_flag("--mpi", o->mpi,
                "The domain decomposition instead, under `mpirun -np K`: the sphere pile's weak and strong scaling on "
                "the CPU backend or one GPU a process, each against process 0 alone in the same run "
                "(scaling_mpi.{md,csv})");
  cmd->add_option("--per-process", o->per_process, "--mpi: spheres a process in the weak run (default 20000)");
  cmd->add_option("--total", o->total, "--mpi: spheres in the strong run (default 40000)");
  cmd->add_option("--steps", o->mpi_steps, "--mpi: timed steps of each run (default 20; 3 warm-up steps before)");
  cmd->add_option("--mpi-backend", o->mpi_backend, "--mpi: cpu (the default) or gpu (one device a process)")
      ->check(CLI::IsMember({"cpu", "gpu"}));
  cmd->add_option("--modes", o->mpi_modes, "--mpi: weak, strong or both (default weak,strong)");
  cmd->add_option("--baseline", o->mpi_baseline,
                  "--mpi: on (the default): each mode's one-process run first; off: the K-process runs alone")
      ->check(CLI::IsMember({"on", "off"}));
  registerBenchBullet3Worker(app, reg);
}
