// dvisim bench pruning --out DIR [--quick] [--record] [--backend cpu|gpu|auto] [--n N] [--threads N]
//
// What leaving out the stages a scene does not need saves (docs/MODEL.md §6): the same pile of
// spheres (bench/scaling/scaling_scenes.h) stepped by two systems side by side in one run, one with
// SystemConfig::prune = true (the default: a frictionless step solves one row per contact, no gyroscopic
// term for spheres, no empty row or field stages) and one with prune = false (every stage and three rows
// per contact). Both are warmed up first, then measured in alternating rounds (A B, B A, ...) so both see
// the same machine state; the ratio of their ms/step is the result, never an absolute time.
//
//   pile mu = 0    the goal: pruning saves >= 30% of the step
//   pile mu = 0.5  the control: every contact needs its friction rows, so the saving is ~0 (nothing lost)
//
// Writes DIR/pruning.csv (one row per scene x prune, ms/step per stage) and DIR/pruning.md; --record also
// writes bench/results/pruning_<device>_<date>.{md,csv}.
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "bench_common.h"
#include "bench_util.h"
#include "chrono_like/system.h"
#include "gpu/gpu_factory.h"
#include "scaling/scaling_scenes.h"

namespace {

using namespace dvi::benchutil;

struct PruneOptions : BenchBasics {
  std::string backend = "auto", n;
};

// `dvisim bench pruning`: its name, description and the texts of its common options.
const BenchSpec kBench{
    "pruning",
    "Time saved by leaving out the stages a scene does not need (prune on against off, side by side)",
    "pruning.csv, pruning.md",
    "A small pile and few steps (CI smoke test)",
    "md,csv",
    "OpenMP threads of the CPU backend (0: all)"};

long parseInt(const std::string& s, const char* opt, long lo, long hi) {
  char* end = nullptr;
  const long v = std::strtol(s.c_str(), &end, 10);
  if (s.empty() || *end || v < lo || v > hi)
    throw InputError(std::string(opt) + ": expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                     "], got '" + s + "'");
  return v;
}

struct Result {
  std::string scene;
  double mu = 0;
  bool prune = true;
  long steps = 0;
  double wall = 0;  // s, measured steps only
  std::array<double, dvi::kStageCount> stage{};
  double contacts = 0;
  long normal_only_steps = 0;
  std::string parts;  // stage parts that ran
  double msPerStep() const { return steps > 0 ? 1e3 * wall / double(steps) : 0; }
};

const char* kHeader =
    "scene,mu,prune,bodies,steps,ms_per_step,IntegrateForces_ms,ComputeAabbs_ms,BroadPhase_ms,NarrowPhase_ms,"
    "BuildRows_ms,WarmStart_ms,Solve_ms,IntegrateVelocities_ms,IntegratePositions_ms,contacts_mean,normal_only_steps,"
    "saving_pct,backend,threads,device,parts_ran";

// The saving of the pruned run results[i] against the full one results[i + 1], percent of its time.
double saving(const std::vector<Result>& results, size_t i) {
  const double a = results[i].msPerStep(), b = results[i + 1].msPerStep();
  return b > 0 ? 100.0 * (1 - a / b) : 0.0;
}

// pruning.csv: one row a run (kHeader).
std::string pruningCsv(const std::vector<Result>& results, size_t bodies, bool gpu, int used_threads,
                       const std::string& device) {
  std::ostringstream csv;
  csv << kHeader << "\n";
  for (size_t i = 0; i < results.size(); ++i) {
    const Result& r = results[i];
    csv << r.scene << "," << num(r.mu) << "," << (r.prune ? "true" : "false") << "," << bodies << "," << r.steps << ","
        << num(r.msPerStep(), "%.4f");
    for (int k = 0; k < dvi::kStageCount; ++k)
      csv << "," << num(1e3 * r.stage[size_t(k)] / double(std::max(1L, r.steps)), "%.4f");
    csv << "," << num(r.contacts, "%.1f") << "," << r.normal_only_steps << ","
        << (r.prune ? num(saving(results, i), "%.2f") : std::string()) << "," << (gpu ? "gpu" : "cpu") << ","
        << used_threads << "," << csvField(device) << "," << csvField(r.parts) << "\n";
  }
  return csv.str();
}

// The report's table of the runs and the savings against the goal (>= 30 % on the frictionless pile).
std::string pruningTable(const std::vector<Result>& results, double s0, double s1, bool pass) {
  std::ostringstream md;
  char line[512];
  md << "| scene | prune | ms/step | BuildRows | WarmStart | Solve | IntegrateVelocities | contacts | normal-only "
        "steps |\n"
     << "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n";
  for (const Result& r : results) {
    auto ms = [&](dvi::StageType s) { return 1e3 * r.stage[size_t(s)] / double(std::max(1L, r.steps)); };
    std::snprintf(line, sizeof line, "| %s | %s | %.3f | %.3f | %.3f | %.3f | %.3f | %.0f | %ld/%ld |\n",
                  r.scene.c_str(), r.prune ? "true" : "false", r.msPerStep(), ms(dvi::StageType::BuildRows),
                  ms(dvi::StageType::WarmStart), ms(dvi::StageType::Solve), ms(dvi::StageType::IntegrateVelocities),
                  r.contacts, r.normal_only_steps, r.steps);
    md << line;
  }
  std::snprintf(line, sizeof line,
                "\nSaving of prune = true against prune = false (measured side by side in this run):\n"
                "- frictionless pile: %.1f%% -> goal >= 30%%: %s\n"
                "- frictional pile (control, every contact needs its friction rows): %.1f%%\n",
                s0, pass ? "MET" : "NOT MET", s1);
  md << line;
  return md.str();
}

int runPruning(const PruneOptions& o) {
  if (o.backend != "cpu" && o.backend != "gpu" && o.backend != "auto")
    throw InputError("--backend: expected cpu, gpu or auto, got '" + o.backend + "'");
  const long threads = parseInt(o.threads, "--threads", 0, 4096);
  const long n = o.n.empty() ? (o.quick ? 400 : 10000) : parseInt(o.n, "--n", 1, 10000000);
  prepareOutDir(o.out, "pruning.csv");
  const std::string results_dir = o.record ? resultsDir() : std::string();
  std::string gpu_name;
  const bool have_gpu = dvi::gpuAvailable(&gpu_name);
  if (o.backend == "gpu" && !have_gpu) throw InputError("--backend gpu: " + gpu_name);
  const bool gpu = o.backend == "gpu" || (o.backend == "auto" && have_gpu);
  const int warmup = o.quick ? 3 : 20, rounds = o.quick ? 2 : 6, per_round = o.quick ? 3 : 10;

  auto make = [&](bool prune, double mu) {
    dvi::SystemConfig cfg;
    cfg.threads = int(threads);
    cfg.prune = prune;
    std::unique_ptr<dvi::System> sys = gpu ? dvi::makeGpuSystem(cfg) : std::make_unique<dvi::System>(cfg);
    dvi::bench::addToSystem(dvi::bench::makePileSpec(n, dvi::real(mu)), *sys);
    return sys;
  };

  std::vector<Result> results;
  std::string device;
  int used_threads = 0;
  size_t bodies = 0;
  std::printf("bench pruning%s: pile of %ld spheres on %s, %d warm-up steps, %d alternating rounds of %d steps\n",
              o.quick ? " --quick" : "", n, gpu ? "gpu" : "cpu", warmup, rounds, per_round);
  for (double mu : {0.0, 0.5}) {
    const std::string scene = mu == 0 ? "pile-frictionless" : "pile-frictional";
    std::unique_ptr<dvi::System> sys[2] = {make(true, mu), make(false, mu)};
    device = sys[0]->deviceName();
    used_threads = gpu ? 0 : sys[0]->effectiveThreads();
    bodies = sys[0]->bodies().count();
    Result r[2];
    dvi::StageLog log[2];
    for (int p = 0; p < 2; ++p) {
      r[p].scene = scene;
      r[p].mu = mu;
      r[p].prune = p == 0;
      sys[p]->advance(warmup);
    }
    for (int round = 0; round < rounds; ++round)
      for (int j = 0; j < 2; ++j) {
        const int p = (round % 2 == 0) ? j : 1 - j;  // A B, then B A: both see the same machine state
        for (int s = 0; s < per_round; ++s) {
          const auto t0 = Clock::now();
          sys[p]->step();
          r[p].wall += std::chrono::duration<double>(Clock::now() - t0).count();
          const dvi::StepStats& st = sys[p]->lastStats();
          for (int k = 0; k < dvi::kStageCount; ++k) r[p].stage[size_t(k)] += st.stage_seconds[size_t(k)];
          r[p].contacts += double(st.contacts);
          log[p].add(st);
          ++r[p].steps;
        }
      }
    for (int p = 0; p < 2; ++p) {
      r[p].contacts /= double(std::max(1L, r[p].steps));
      r[p].normal_only_steps = long(log[p].normal_only_steps);
      for (int k = 0; k < dvi::kStagePartCount; ++k)
        if (log[p].part_ran[size_t(k)])
          r[p].parts += std::string(r[p].parts.empty() ? "" : " ") + dvi::stagePartName(dvi::StagePart(k));
      results.push_back(r[p]);
    }
  }

  const std::string csv = pruningCsv(results, bodies, gpu, used_threads, device);
  const double s0 = saving(results, 0), s1 = saving(results, 2);
  const bool pass = s0 >= 30.0;
  const std::string table = pruningTable(results, s0, s1, pass);
  std::printf("%s", table.c_str());
  std::printf("Goal: pruning saves >= 30%% on a frictionless all-sphere scene: %s (%.1f%%)\n", pass ? "MET" : "NOT MET",
              s0);

  std::ostringstream head;
  head << "# Pruning: the stages a scene does not need" << (o.quick ? " (--quick)" : "") << "\n\n"
       << "Written by the benchmark (`dvisim bench pruning`, bench/pruning/bench_pruning.cpp); do not edit by hand.\n\n"
       << "- device: " << device << "\n- backend: " << (gpu ? "gpu" : "cpu")
       << (gpu ? "" : ", threads " + std::to_string(used_threads)) << "\n- commit: " << commitId()
       << "\n- date: " << utcNow("%Y-%m-%dT%H:%M:%SZ") << "\n- scene: pile of " << n
       << " spheres r 1 cm (bench/scaling/scaling_scenes.h), APGD 50 iterations, h = 1 ms; " << warmup
       << " warm-up steps, then " << rounds << " alternating rounds of " << per_round << " steps per system\n\n";
  const std::string md_text = head.str() + table;
  writeCsvMdResults(o, "pruning", device, results_dir, md_text, csv);
  return 0;
}

}  // namespace

void registerBenchPruning(CLI::App& app, BenchRegistry& reg) {
  auto [cmd, o] = addBench<PruneOptions>(app, reg, kBench, runPruning);
  cmd->add_option("--backend", o->backend, "cpu, gpu or auto (gpu when a device is present)");
  cmd->add_option("--n", o->n, "Spheres in the pile (default 10000; --quick 400)");
}
