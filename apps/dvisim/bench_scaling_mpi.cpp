#include "bench_scaling_mpi.h"

#include <mpi.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

#include "bench_util.h"
#include "chrono_like/base/errors.h"
#include "chrono_like/mpi/distributed_system.h"
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
};

double maxOver(MPI_Comm comm, double v) {
  double out = v;
  MPI_Allreduce(&v, &out, 1, MPI_DOUBLE, MPI_MAX, comm);
  return out;
}
double sumOver(MPI_Comm comm, double v) {
  double out = v;
  MPI_Allreduce(&v, &out, 1, MPI_DOUBLE, MPI_SUM, comm);
  return out;
}

// Steps the pile of n spheres on comm's processes: `warmup` steps, then `steps` timed ones.
MpiRow runPile(MPI_Comm comm, const std::string& mode, long n, int warmup, int steps, const dvi::SystemConfig& cfg) {
  const dvi::bench::SceneSpec spec = dvi::bench::makePileSpec(n);
  dvi::DistributedSystem sys(comm, cfg);
  for (const dvi::BodyDesc& d : dvi::bench::bodyDescs(spec)) sys.addBody(d);
  for (int s = 0; s < warmup; ++s) sys.step();
  const dvi::DecompositionProfile p0 = sys.profile();
  double contacts = 0;
  MPI_Barrier(comm);
  const auto t0 = std::chrono::steady_clock::now();
  for (int s = 0; s < steps; ++s) {
    sys.step();
    contacts += double(sys.local()->contacts().count());
  }
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const dvi::DecompositionProfile p = sys.profile();
  const double per = 1e3 / steps;  // seconds summed over the steps -> ms per step
  MpiRow r;
  r.mode = mode;
  r.processes = sys.processes();
  r.bodies = n;
  r.steps = steps;
  r.ms = maxOver(comm, wall) * per;
  r.ghosts = maxOver(comm, p.ghosts_s - p0.ghosts_s) * per;
  r.build = maxOver(comm, p.build_s - p0.build_s) * per;
  r.step = maxOver(comm, p.step_s - p0.step_s) * per;
  r.readback = maxOver(comm, p.readback_s - p0.readback_s) * per;
  r.migrate = maxOver(comm, p.migrate_s - p0.migrate_s) * per;
  r.exchange = maxOver(comm, p.group.exchange_s - p0.group.exchange_s) * per;
  r.reduce = maxOver(comm, p.group.reduce_s - p0.group.reduce_s) * per;
  for (int k = 0; k < dvi::kStageCount; ++k)
    r.stages[size_t(k)] = maxOver(comm, p.stages_s[size_t(k)] - p0.stages_s[size_t(k)]) * per;
  const double kib = 1.0 / (1024.0 * steps);
  r.ghost_kb = sumOver(comm, double(p.ghost_bytes - p0.ghost_bytes)) * kib;
  r.exchange_kb = sumOver(comm, double(p.group.exchange_bytes - p0.group.exchange_bytes)) * kib;
  r.migrate_kb = sumOver(comm, double(p.migrate_bytes - p0.migrate_bytes)) * kib;
  r.exchanges = double(p.group.exchanges - p0.group.exchanges) / steps;
  r.reductions = double(p.group.reductions - p0.group.reductions) / steps;
  r.contacts = sumOver(comm, contacts) / steps;
  return r;
}

// The mode's one-process baseline on process 0 (the others wait), then the run on every process of world.
void runMode(const std::string& mode, long n1, long nk, int warmup, int steps, const dvi::SystemConfig& cfg,
             std::vector<MpiRow>& rows) {
  int rank = 0, size = 1;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  MPI_Comm_size(MPI_COMM_WORLD, &size);
  MPI_Comm alone = MPI_COMM_NULL;
  MPI_Comm_split(MPI_COMM_WORLD, rank == 0 ? 0 : MPI_UNDEFINED, 0, &alone);
  MpiRow one;
  if (rank == 0) {
    one = runPile(alone, mode, n1, warmup, steps, cfg);
    MPI_Comm_free(&alone);
    std::printf("  %-6s 1 process  %8ld spheres: %9.2f ms/step\n", mode.c_str(), n1, one.ms);
    std::fflush(stdout);
  }
  MPI_Barrier(MPI_COMM_WORLD);
  MpiRow all = runPile(MPI_COMM_WORLD, mode, nk, warmup, steps, cfg);
  if (rank != 0) return;
  // weak: the same work per process, efficiency T1 / TK; strong: the same pile, efficiency T1 / (K TK)
  all.efficiency = mode == "weak" ? one.ms / all.ms : one.ms / (double(size) * all.ms);
  one.efficiency = 1;
  std::printf("  %-6s %d processes %8ld spheres: %9.2f ms/step, efficiency %.2f\n", mode.c_str(), size, nk, all.ms,
              all.efficiency);
  std::fflush(stdout);
  rows.push_back(one);
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
  c << "\n";
  for (const MpiRow& r : rows) {
    c << r.mode << "," << r.processes << "," << r.bodies << "," << r.steps << "," << num(r.ms) << ","
      << num(r.efficiency) << "," << num(r.ghosts) << "," << num(r.build) << "," << num(r.step) << ","
      << num(r.readback) << "," << num(r.migrate) << "," << num(r.exchange) << "," << num(r.reduce) << ","
      << num(r.ghost_kb) << "," << num(r.exchange_kb) << "," << num(r.migrate_kb) << "," << num(r.exchanges) << ","
      << num(r.reductions) << "," << num(r.contacts);
    for (int k = 0; k < dvi::kStageCount; ++k) c << "," << num(r.stages[size_t(k)]);
    c << "\n";
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
      << num(r.efficiency, "%.2f") << " | " << num(r.ghosts, "%.2f") << " | " << num(r.build, "%.2f") << " | "
      << num(r.step, "%.2f") << " | " << num(r.exchange, "%.2f") << ", " << num(r.reduce, "%.2f") << " | "
      << num(r.readback, "%.2f") << " | " << num(r.migrate, "%.2f") << " | " << num(r.ghost_kb, "%.0f") << ", "
      << num(r.exchange_kb, "%.0f") << ", " << num(r.migrate_kb, "%.0f") << " | " << num(r.exchanges, "%.0f") << ", "
      << num(r.reductions, "%.0f") << " |\n";
  m << "\nThe local step's stages (ms per step, the slowest process):\n\n";
  for (const MpiRow& r : rows)
    m << "- " << r.mode << ", " << r.processes << " processes, " << r.bodies << " spheres: " << stagesText(r) << "\n";
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
  const long n1 = o.quick ? std::min(per, 2000L) : per, nt = o.quick ? std::min(total, 4000L) : total;
  int warmup = 3;
  if (o.quick) steps = std::min(steps, 3), warmup = 1;
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
        "bench scaling --mpi: %d processes, %d threads each; weak %ld spheres a process, strong %ld in all; "
        "%d warm-up and %d timed steps\n",
        size, cfg.threads, n1, nt, warmup, steps);
  std::vector<MpiRow> rows;
  runMode("weak", n1, n1 * size, warmup, steps, cfg, rows);
  runMode("strong", nt, nt, warmup, steps, cfg, rows);
  if (rank != 0) return 0;
  const std::string cpu = dvi::System(cfg).deviceName();
  std::ostringstream head;
  head << "# Domain decomposition over MPI: weak and strong scaling (CPU backend)\n\n"
       << "Written by the benchmark (`mpirun -np K dvisim bench scaling --mpi`, apps/dvisim/bench_scaling_mpi.cpp); "
          "do not edit by hand.\n\n"
       << "- CPU: " << cpu << ", " << size << " processes of " << cfg.threads << " thread(s)\n"
       << "- commit: " << commitId() << "\n- date: " << utcNow("%Y-%m-%dT%H:%M:%SZ") << "\n"
       << "- scene: the sphere pile of `bench scaling` (r = 1 cm, mu = 0.5, in a box); APGD, 50 iterations a step\n"
       << "- steps: " << warmup << " warm-up, then " << steps << " timed; each mode's one-process run on process 0 "
       << "alone, then all processes, in one invocation\n"
       << "- efficiency: weak T(1, N) / T(K, K N); strong T(1, M) / (K T(K, M)); times are the slowest process's, "
          "bytes summed over the processes\n\n";
  const std::string text = head.str() + tableText(rows);
  const std::string csv = csvText(rows);
  writeFile(o.out + "/scaling_mpi.csv", csv);
  writeFile(o.out + "/scaling_mpi.md", text);
  std::printf("results: %s/scaling_mpi.csv, scaling_mpi.md\n", o.out.c_str());
  if (o.record) {
    const std::string base = "scaling_mpi_" + slug(cpu) + "-" + std::to_string(size) + "p_" + utcNow("%Y%m%d-%H%M%S");
    writeBenchRecord({results_dir}, base, {{"md", text + "\nRows: " + base + ".csv\n"}, {"csv", csv}}, writeFile);
  }
  return 0;
}
