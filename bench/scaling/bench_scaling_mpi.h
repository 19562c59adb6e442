// `mpirun -np K dvisim bench scaling --mpi --out DIR [--record] [--quick] [--per-process N] [--total N]
//  [--steps S] [--threads T] [--mpi-backend cpu|gpu] [--modes weak,strong] [--baseline on|off]`: the domain
// decomposition's weak and strong scaling on the CPU backend, or on one GPU a process (a benchmark, not a test).
// Built where MPI is (DVISIM_HAVE_MPI).
//
// Each mode runs the sphere pile of `bench scaling` (bench/scaling/scaling_scenes.h) twice in one invocation, side by
// side: on process 0 alone (the one-process baseline, through the same DistributedSystem on a communicator of one)
// and on all K processes.
//   weak:   N per process: the pile of N on one process, the pile of K N on K; efficiency T(1, N) / T(K, K N).
//   strong: the pile of M on one process and on K; speedup T(1, M) / T(K, M), efficiency speedup / K.
// A step's time is the slowest process's. Per phase (docs/ARCHITECTURE.md, "Domain decomposition over MPI"): the
// ghost exchange, the local System's build, its step (its named stages, and inside them the solver's exchanges of
// shared bodies' velocity changes and its reductions), the read-back, and migration; bytes sent per step, summed over
// the processes. APGD at a fixed 50 iterations (no tolerance stop), so every run does the same solver work.
// The weak mode also times the plain System (no decomposition) on the one-process pile: what the decomposition costs
// on one process. --baseline off leaves the one-process runs out (a pile too large for one device).
// Process 0 writes DIR/scaling_mpi.{md,csv}; --record also bench/results/scaling_mpi_<device>-<K>p_<date>.{md,csv}.
#pragma once

#include <string>

#include "bench_common.h"

struct MpiScalingOptions : BenchBasics {
  std::string per_process = "20000", total = "40000", steps = "20";
  std::string backend = "cpu", modes = "weak,strong", baseline = "on";
};

// The run; InputError for bad options. Every process calls it.
int runScalingMpi(const MpiScalingOptions& o);
