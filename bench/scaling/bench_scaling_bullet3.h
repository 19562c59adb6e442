// The Bullet 3 OpenCL rows of `dvisim bench scaling` (bench_scaling.cpp): one configuration (scene x N) on the
// Bullet 3 peer (bench/scaling/bullet3_peer.h), timed like the other engines.
//
// Each configuration runs in a child process, `dvisim bench bullet3-worker` (a hidden subcommand of this
// executable, started with fork + exec): Bullet 3 carries on after most of its own OpenCL errors (its asserts
// are compiled out) and may then crash or hang, and one such failure must cost one row, not the whole run. The
// child's output (Bullet 3's and the OpenCL driver's messages) goes to a log file; its numbers come back in a
// small key=value file. A crash, a non-zero exit or a run past the time limit becomes an "error: ..." outcome
// naming the log's last line.
#pragma once

#include <CLI/CLI.hpp>

#include <string>

#include "bench_common.h"
#include "scaling/bullet3_peer.h"

struct Bullet3Job {
  std::string scene;  // "pile" or "mix"
  long n = 0;
  int warmup = 0, steps = 0;  // steps: at most; fewer when the last warm-up step says they would pass `budget`
  double budget = 30;         // seconds of timed steps
  dvi::bench::OpenClDeviceType device = dvi::bench::OpenClDeviceType::Gpu;
  std::string cache_dir;  // Bullet 3's compiled kernels (Bullet3PeerSettings::kernel_cache_dir)
};

struct Bullet3Outcome {
  std::string status = "ok";  // or "error: ..."
  std::string device;         // Bullet3Peer::description()
  long bodies = 0;            // all bodies, the ground and the walls included
  int warmup = 0, steps = 0;
  double setup_s = 0;          // device, context, kernels (compiled or from the cache), scene upload
  double ms = 0;               // per timed step, each step ended by clFinish
  double contacts = 0;         // contact manifolds per timed step
  double max_penetration = 0;  // metres, after the timed steps, on withConvexHulls(scene) (scaling_scenes.h)
  bool ok() const { return status == "ok"; }
};

// The job in this process: what the worker runs. Never throws; failures are in the outcome's status.
Bullet3Outcome runBullet3(const Bullet3Job& job);

// The job in a child process (this executable's `bench bullet3-worker`), its output in log_path; never throws.
Bullet3Outcome runBullet3Isolated(const Bullet3Job& job, const std::string& log_path, double timeout_s);

// Registers the hidden `dvisim bench bullet3-worker` subcommand.
void registerBenchBullet3Worker(CLI::App& app, BenchRegistry& reg);
