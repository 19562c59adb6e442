#include "scaling/bench_scaling_mpi.h"

#include <mpi.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "bench_util.h"
#include "chrono_like/base/errors.h"
#include "chrono_like/mpi/distributed_system.h"
#include "chrono_like/mpi/mpi_collectives.h"
#include "gpu/gpu_factory.h"
#include "mpi_run.h"
#include "parse.h"
#include "scaling/scaling_scenes.h"

namespace {

using dvi::InputError;
using dvi::parseInt;
using namespace dvi::benchutil;

// One run of the pile on the processes of `comm`, per step: the slowest process's wall time and phases, the bytes
// sent summed over the processes.
struct MpiRow {
  std::string mode;  // weak or strong
  int processes = 1;
  long bodies = 0;  // spheres
  int steps = 0;
  double ms = 0;                                                      // per step, the slowest process
  double ghosts = 0, build = 0, step = 0, readback = 0, migrate = 0;  // ms per step, the slowest process
  double exchange = 0, reduce = 0;  // the solver's collectives inside step, ms per step, the slowest process
  std::array<double, dvi::kStageCount> stages{};         // the local step's stages, ms per step, the slowest process
  double ghost_kb = 0, exchange_kb = 0, migrate_kb = 0;  // KiB per step, summed over the processes
  double exchanges = 0, reductions = 0;                  // per step, process 0
  double contacts = 0;                                   // per step, summed over the processes
  double efficiency = 0;                                 // against the one-process row of the mode (set later)
  double rebuilds = 0;                                   // local Systems built, the warm-up's included (process 0)
  double plain_ms = 0;  // the one-process row of the weak mode: the plain System on the same pile, ms per step
  std::string spread;   // phases and parts of phases, ms per step, "min-max" over the processes
};

// The local System of a run: the CPU System, or the GPU one on this process's device (runScalingMpi selects it).
dvi::DistributedSystem::LocalFactory localFactory(bool gpu) {
  if (!gpu) return nullptr;
  return [](const dvi::SystemConfig& c) { return dvi::makeGpuSystem(c); };
}

// The plain System (no decomposition) on the pile of n, on this process alone: ms per timed step.
double runPlain(long n, int warmup, int steps, const dvi::SystemConfig& cfg, bool gpu) {
  std::unique_ptr<dvi::System> sys = gpu ? dvi::makeGpuSystem(cfg) : std::make_unique<dvi::System>(cfg);
  for (const dvi::BodyDesc& d : dvi::bench::bodyDescs(dvi::bench::makePileSpec(n))) sys->addBody(d);
  for (int s = 0; s < warmup; ++s) sys->step();
  const auto t0 = std::chrono::steady_clock::now();
  for (int s = 0; s < steps; ++s) sys->step();
  return 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / steps;
}

// Steps the pile of n spheres on comm's processes: `warmup` steps, then `steps` timed ones.
MpiRow runPile(MPI_Comm comm, const std::string& mode, long n, int warmup, int steps, const dvi::SystemConfig& cfg,
               bool gpu) {
  dvi::DistributedSystem sys(comm, cfg, {}, localFactory(gpu));
  {
    const dvi::bench::SceneSpec spec = dvi::bench::makePileSpec(n);
    for (const dvi::BodyDesc& d : dvi::bench::bodyDescs(spec)) sys.addBody(d);
  }
  for (int s = 0; s < warmup; ++s) sys.step();
  const dvi::DecompositionProfile p0 = sys.profile();
  double contacts = 0;
  MPI_Barrier(comm);
  const auto t0 = std::chrono::steady_clock::now();
  for (int s = 0; s < steps; ++s) {
    sys.step();
    contacts += double(sys.local()->lastStats().contacts);
  }
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const dvi::DecompositionProfile p = sys.profile();
  const double per = 1e3 / steps;  // seconds summed over the steps -> ms per step
  MpiRow r;
  r.mode = mode;
  r.processes = sys.processes();
  r.bodies = n;
  r.steps = steps;
  r.ms = dvi::mpiMax(comm, wall) * per;
  r.ghosts = dvi::mpiMax(comm, p.ghosts_s - p0.ghosts_s) * per;
  r.build = dvi::mpiMax(comm, p.build_s - p0.build_s) * per;
  r.step = dvi::mpiMax(comm, p.step_s - p0.step_s) * per;
  r.readback = dvi::mpiMax(comm, p.readback_s - p0.readback_s) * per;
  r.migrate = dvi::mpiMax(comm, p.migrate_s - p0.migrate_s) * per;
  r.exchange = dvi::mpiMax(comm, p.group.exchange_s - p0.group.exchange_s) * per;
  r.reduce = dvi::mpiMax(comm, p.group.reduce_s - p0.group.reduce_s) * per;
  for (int k = 0; k < dvi::kStageCount; ++k)
    r.stages[size_t(k)] = dvi::mpiMax(comm, p.stages_s[size_t(k)] - p0.stages_s[size_t(k)]) * per;
  const double kib = 1.0 / (1024.0 * steps);
  r.ghost_kb = dvi::mpiSum(comm, double(p.ghost_bytes - p0.ghost_bytes)) * kib;
  r.exchange_kb = dvi::mpiSum(comm, double(p.group.exchange_bytes - p0.group.exchange_bytes)) * kib;
  r.migrate_kb = dvi::mpiSum(comm, double(p.migrate_bytes - p0.migrate_bytes)) * kib;
  r.exchanges = double(p.group.exchanges - p0.group.exchanges) / steps;
  r.reductions = double(p.group.reductions - p0.group.reductions) / steps;
  r.contacts = dvi::mpiSum(comm, contacts) / steps;
  r.rebuilds = double(sys.migrations().rebuilds);
  const std::pair<const char*, double> parts[] = {
      {"step", p.step_s - p0.step_s},
      {"NarrowPhase",
       p.stages_s[size_t(dvi::StageType::NarrowPhase)] - p0.stages_s[size_t(dvi::StageType::NarrowPhase)]},
      {"of it touched lists", p.group.touched_s - p0.group.touched_s},
      {"Solve", p.stages_s[size_t(dvi::StageType::Solve)] - p0.stages_s[size_t(dvi::StageType::Solve)]},
      {"exchanges", p.group.exchange_s - p0.group.exchange_s - (p.group.touched_s - p0.group.touched_s)},
      {"reductions", p.group.reduce_s - p0.group.reduce_s},
      {"read-back", p.readback_s - p0.readback_s},
      {"of it the ghost width", p.width_s - p0.width_s},
      {"selection", p.select_s - p0.select_s},
      {"states", p.near_sync_s - p0.near_sync_s},
      {"migration", p.migrate_s - p0.migrate_s},
      {"of it MPI", p.migrate_mpi_s - p0.migrate_mpi_s},
      {"ghosts", p.ghosts_s - p0.ghosts_s},
      {"of it records", p.ghosts_pack_s - p0.ghosts_pack_s},
      {"MPI", p.ghosts_mpi_s - p0.ghosts_mpi_s},
      {"applied", p.ghosts_apply_s - p0.ghosts_apply_s},
      {"parked and uploaded", p.ghosts_park_s - p0.ghosts_park_s}};
  for (const auto& [name, seconds] : parts)
    r.spread += std::string(r.spread.empty() ? "" : ", ") + name + " " + num(dvi::mpiMin(comm, seconds) * per, "%.2f") +
                "-" + num(dvi::mpiMax(comm, seconds) * per, "%.2f");
  return r;
}

// The mode's one-process baseline on process 0 (the others wait; weak: the plain System too), unless `baseline` is
// off, then the run on every process of world.
void runMode(const std::string& mode, long n1, long nk, int warmup, int steps, const dvi::SystemConfig& cfg, bool gpu,
             bool baseline, std::vector<MpiRow>& rows) {
  int rank = 0, size = 1;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  MPI_Comm_size(MPI_COMM_WORLD, &size);
  MpiRow one;
  if (baseline) {
    MPI_Comm alone = MPI_COMM_NULL;
    MPI_Comm_split(MPI_COMM_WORLD, rank == 0 ? 0 : MPI_UNDEFINED, 0, &alone);
    if (rank == 0) {
      one = runPile(alone, mode, n1, warmup, steps, cfg, gpu);
      MPI_Comm_free(&alone);
      if (mode == "weak") one.plain_ms = runPlain(n1, warmup, steps, cfg, gpu);
      std::printf("  %-6s 1 process  %8ld spheres: %9.2f ms/step (plain System: %.2f)\n", mode.c_str(), n1, one.ms,
                  one.plain_ms);
      std::fflush(stdout);
    }
    MPI_Barrier(MPI_COMM_WORLD);
  }
  MpiRow all = runPile(MPI_COMM_WORLD, mode, nk, warmup, steps, cfg, gpu);
  if (rank != 0) return;
  // weak: the same work per process, efficiency T1 / TK; strong: the same pile, efficiency T1 / (K TK)
  if (baseline) all.efficiency = mode == "weak" ? one.ms / all.ms : one.ms / (double(size) * all.ms);
  one.efficiency = 1;
  std::printf("  %-6s %d processes %8ld spheres: %9.2f ms/step, efficiency %.2f\n", mode.c_str(), size, nk, all.ms,
              all.efficiency);
  std::fflush(stdout);
  if (baseline) rows.push_back(one);
  rows.push_back(all);
}

std::string stagesText(const MpiRow& r) {
  std::string s;
  for (int k = 0; k < dvi::kStageCount; ++k)
    if (r.stages[size_t(k)] > 0)
      s += std::string(s.empty() ? "" : " ") + dvi::stageName(dvi::StageType(k)) + " " +
           num(r.stages[size_t(k)], "%.2f");
  return s;
}

std::string csvText(const std::vector<MpiRow>& rows) {
  std::ostringstream c;
  c << "mode,processes,spheres,steps,ms_per_step,efficiency,ghosts_ms,build_ms,step_ms,readback_ms,migrate_ms,"
       "exchange_ms,reduce_ms,ghost_kib,exchange_kib,migrate_kib,exchanges,reductions,contacts";
  for (int k = 0; k < dvi::kStageCount; ++k) c << "," << dvi::stageName(dvi::StageType(k)) << "_ms";
  c << ",rebuilds,plain_ms\n";
  for (const MpiRow& r : rows) {
    c << r.mode << "," << r.processes << "," << r.bodies << "," << r.steps << "," << num(r.ms) << ","
      << num(r.efficiency) << "," << num(r.ghosts) << "," << num(r.build) << "," << num(r.step) << ","
      << num(r.readback) << "," << num(r.migrate) << "," << num(r.exchange) << "," << num(r.reduce) << ","
      << num(r.ghost_kb) << "," << num(r.exchange_kb) << "," << num(r.migrate_kb) << "," << num(r.exchanges) << ","
      << num(r.reductions) << "," << num(r.contacts);
    for (int k = 0; k < dvi::kStageCount; ++k) c << "," << num(r.stages[size_t(k)]);
    c << "," << num(r.rebuilds) << "," << num(r.plain_ms) << "\n";
  }
  return c.str();
}

std::string tableText(const std::vector<MpiRow>& rows) {
  std::ostringstream m;
  m << "| mode | processes | spheres | ms/step | efficiency | ghosts | build | step | of it: exchanges, reductions | "
       "read-back | migration | KiB/step: ghosts, exchanges, migration | exchanges, reductions per step |\n"
       "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n";
  for (const MpiRow& r : rows)
    m << "| " << r.mode << " | " << r.processes << " | " << r.bodies << " | " << num(r.ms, "%.2f") << " | "
      << (r.efficiency > 0 ? num(r.efficiency, "%.2f") : std::string("-")) << " | " << num(r.ghosts, "%.2f") << " | "
      << num(r.build, "%.2f") << " | " << num(r.step, "%.2f") << " | " << num(r.exchange, "%.2f") << ", "
      << num(r.reduce, "%.2f") << " | " << num(r.readback, "%.2f") << " | " << num(r.migrate, "%.2f") << " | "
      << num(r.ghost_kb, "%.0f") << ", " << num(r.exchange_kb, "%.0f") << ", " << num(r.migrate_kb, "%.0f") << " | "
      << num(r.exchanges, "%.0f") << ", " << num(r.reductions, "%.0f") << " |\n";
  m << "\nThe local step's stages (ms per step, the slowest process), and the local Systems built (the first, in the "
       "warm-up, included; process 0):\n\n";
  for (const MpiRow& r : rows)
    m << "- " << r.mode << ", " << r.processes << " processes, " << r.bodies << " spheres: " << stagesText(r) << "; "
      << num(r.rebuilds, "%.0f") << " built\n";
  m << "\nPhases and parts of phases over the processes (ms per step, fastest-slowest process; a collective's time "
       "includes the wait for the slower process, so a wide spread there is load imbalance):\n\n";
  for (const MpiRow& r : rows) m << "- " << r.mode << ", " << r.processes << " processes: " << r.spread << "\n";
  return m.str();
}

}  // namespace

int runScalingMpi(const MpiScalingOptions& o) {
  int rank = 0, size = 1;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  MPI_Comm_size(MPI_COMM_WORLD, &size);
  const long per = long(parseInt("--per-process", o.per_process, 1, 50000000));
  const long total = long(parseInt("--total", o.total, 1, 100000000));
  const int threads = int(parseInt("--threads", o.threads, 0, 1024));
  int steps = int(parseInt("--steps", o.steps, 1, 100000));
  const std::vector<std::string> modes = selectNames("--modes", {o.modes}, {"weak", "strong"});
  const bool gpu = o.backend == "gpu", baseline = o.baseline != "off";
  if (o.backend != "cpu" && !gpu) throw InputError("--mpi-backend " + o.backend + ": expected cpu or gpu");
  const long n1 = o.quick ? std::min(per, 2000L) : per, nt = o.quick ? std::min(total, 4000L) : total;
  int warmup = 3;
  if (o.quick) steps = std::min(steps, 3), warmup = 1;
  // One device a process (host rank i on device i mod the devices), chosen before any GPU System exists.
  if (gpu && dvi::selectGpu(mpiHostRank()) < 0)
    throw InputError("--mpi-backend gpu: process " + std::to_string(rank) + " sees no CUDA device");
  {  // the output directory, checked on process 0; every process stops together when it is unusable
    std::string why;
    if (rank == 0) try {
        prepareOutDir(o.out, "scaling_mpi.csv");
      } catch (const std::exception& e) { why = e.what(); }
    int bad = why.empty() ? 0 : 1;
    MPI_Bcast(&bad, 1, MPI_INT, 0, MPI_COMM_WORLD);
    if (bad) throw InputError(rank == 0 ? why : "--out: unusable (process 0 says why)");
  }
  const std::string results_dir = o.record && rank == 0 ? resultsDir() : std::string();
  dvi::SystemConfig cfg;
  cfg.threads = threads > 0 ? threads : 1;  // one thread a process unless asked: K processes on K cores
  cfg.solver.type = dvi::SolverType::APGD;
  cfg.solver.tolerance = 0;  // a fixed count: every run does the same solver work
  cfg.solver.max_iterations = 50;
  if (rank == 0)
    std::printf(
        "bench scaling --mpi: %d processes (%s), %d threads each; weak %ld spheres a process, strong %ld in all; "
        "%d warm-up and %d timed steps\n",
        size, gpu ? "one GPU each" : "CPU", cfg.threads, n1, nt, warmup, steps);
  std::vector<MpiRow> rows;
  for (const std::string& mode : modes)
    runMode(mode, mode == "weak" ? n1 : nt, mode == "weak" ? n1 * size : nt, warmup, steps, cfg, gpu, baseline, rows);
  if (rank != 0) return 0;
  const std::string cpu = dvi::System(cfg).deviceName();
  const std::string device = gpu ? dvi::makeGpuSystem(cfg)->deviceName() : cpu;
  std::ostringstream head;
  head << "# Domain decomposition over MPI: weak and strong scaling ("
       << (gpu ? "GPU backend, one GPU a process" : "CPU backend") << ")\n\n"
       << "Written by the benchmark (`mpirun -np K dvisim bench scaling --mpi`, bench/scaling/bench_scaling_mpi.cpp); "
          "do not edit by hand.\n\n";
  if (gpu) head << "- GPU: " << device << ", " << size << " processes, one GPU each\n";
  head << "- CPU: " << cpu
       << (gpu ? " (host)"
               : ", " + std::to_string(size) + " processes of " + std::to_string(cfg.threads) + " thread(s)")
       << "\n- commit: " << commitId() << "\n- date: " << utcNow("%Y-%m-%dT%H:%M:%SZ") << "\n"
       << "- scene: the sphere pile of `bench scaling` (r = 1 cm, mu = 0.5, in a box); APGD, 50 iterations a step"
       << (gpu ? " (over the processes APGD's trials run on the device, their control on the host: one test reduction "
                 "a trial crosses them)"
               : "")
       << "\n- steps: " << warmup << " warm-up, then " << steps << " timed; "
       << (baseline ? "each mode's one-process run on process 0 alone, then all processes, in one invocation"
                    : "the K-process runs alone (--baseline off)")
       << "\n- efficiency: weak T(1, N) / T(K, K N); strong T(1, M) / (K T(K, M)); times are the slowest process's, "
          "bytes summed over the processes\n";
  for (const MpiRow& r : rows)
    if (r.plain_ms > 0)
      head << "- the plain " << (gpu ? "GPU " : "") << "System on the weak one-process pile (" << r.bodies
           << " spheres, no decomposition): " << num(r.plain_ms, "%.2f") << " ms/step; the one-process "
           << "decomposition takes " << num(r.ms / r.plain_ms, "%.2f") << "x that\n";
  head << "\n";
  const std::string text = head.str() + tableText(rows);
  const std::string csv = csvText(rows);
  writeFile(o.out + "/scaling_mpi.csv", csv);
  writeFile(o.out + "/scaling_mpi.md", text);
  std::printf("results: %s/scaling_mpi.csv, scaling_mpi.md\n", o.out.c_str());
  if (o.record) {
    const std::string base =
        "scaling_mpi_" + slug(device) + "-" + std::to_string(size) + "p_" + utcNow("%Y%m%d-%H%M%S");
    writeBenchRecord({results_dir}, base, {{"md", text + "\nRows: " + base + ".csv\n"}, {"csv", csv}}, writeFile);
  }
  return 0;
}
