// `dvisim run` on a CES machine: the command-line options the CLI hands over, the dispatch test, and the
// run itself (feed, step, frames, checkpoints, results, plots), on the CES model and machine of src/ces/.
// main.cpp only calls these; dvisim bench ces and dvisim sweep share its pieces.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "ces/ces_config.h"
#include "ces/machine.h"
#include "ces/output/splitters.h"
#include "chrono_like/system.h"

namespace dvi {
namespace ces {

// The run options as typed (validated here). Empty strings: not given.
struct CesRunOptions {
  std::string scene;              // .json with a top-level "ces"; empty: the embedded default machine
  std::vector<std::string> sets;  // KEY=VALUE, KEY relative to "ces" (or starting with "ces.")
  std::string backend = "auto";   // auto | cpu | gpu
  std::string collision, solver, iterations, dt, time, steps, threads, frames;
  std::string out = "dvisim-out";
  std::string resume;  // directory of an earlier run (its checkpoint/)
};

// True for an empty path (the default is the CES machine) and for a readable .json whose top level is
// an object with the key "ces". Anything else (and any unreadable or malformed file) is left to the
// generic scene loader, which reports its errors.
bool isCesScene(const std::string& path);

// Runs the machine; writes the results under o.out. Throws InputError on bad input. Returns the exit code.
int runCesMachine(const CesRunOptions& o);

// ---- Pieces of the run, shared with `dvisim bench ces` (bench/ces/bench_ces.cpp) ----

// The machine document: the embedded default (empty scene) or a scene file. `origin` names it in errors.
nlohmann::json loadCesDocument(const std::string& scene, std::string& origin);

// Checks `requested` (auto|cpu|gpu; bullet is refused) and resolves auto to gpu when a device is usable
// (printed), else cpu. gpu without a device is an InputError.
std::string resolveCesBackend(const std::string& requested);
// The backend a run uses for --backend (`dvisim run` of a scene, and the CES machine above): auto picks the GPU where
// there is one (and prints which), gpu without a usable device is an InputError; any other name is returned as given.
std::string resolveBackend(const std::string& requested);

// The System the machine runs on: cfg's step and solver, `threads` (0: OpenMP default), collision
// native|bullet, the product friction rule, a sparse broad-phase grid; a CheckpointSystem on the CPU.
std::unique_ptr<System> makeCesSystem(const CesConfig& cfg, const std::string& backend, int threads,
                                      const std::string& collision);

// Per-step statistics summed over the steps of a run.
struct CesRunTotals {
  int64_t steps = 0, contacts = 0, max_contacts = 0, iterations = 0;
  real max_penetration = 0, residual = 0;
  double drive_torque_sum = 0;
  StageLog log;                         // seconds per stage, stages and parts that ran, what was left out
  void add(const CesMachine& m);        // after each CesMachine::step()
  nlohmann::json stageNames() const;    // the stages that ran (stageName), in stage order
  nlohmann::json stageSeconds() const;  // {name: seconds summed over the run}
};

// fed/collected/in flight/held up/lost in kg and particles, balance_closes, mass_unit_kg (summary.json: ces).
nlohmann::json massBalanceJson(const MassBalance& b);
// "fed X g = collected X g + in flight X g + held up X g + lost X g (n = n + n + n + n particles), closes exactly"
std::string massBalanceLine(const MassBalance& b);

// The fed mass per kind and the grade targets of the configuration (splitters.h).
SplitterBasis splitterBasis(const CesMachine& m);
// summary.json ces.metrics: a flat object name -> number (null when undefined), docs/CES.md "Outputs".
nlohmann::json cesMetrics(const CesMachine& m, const SplitterTable& table, const MassBalance& bal);

}  // namespace ces
}  // namespace dvi
