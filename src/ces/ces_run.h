// `dvisim run` on a CES machine: the command-line options the CLI hands over, the dispatch test, and the
// run itself (feed, step, frames, checkpoints, results, plots). apps/dvisim/main.cpp only calls these.
#pragma once

#include <string>
#include <vector>

namespace dvi {
namespace ces {

// The run options as typed (validated here). Empty strings: not given.
struct CesRunOptions {
  std::string scene;                 // .json with a top-level "ces"; empty: the embedded default machine
  std::vector<std::string> sets;     // KEY=VALUE, KEY relative to "ces" (or starting with "ces.")
  std::string backend = "auto";      // auto | cpu | gpu
  std::string collision, solver, iterations, dt, time, steps, threads, frames;
  std::string out = "dvisim-out";
  std::string resume;                // directory of an earlier run (its checkpoint/)
};

// True for an empty path (the default is the CES machine) and for a readable .json whose top level is
// an object with the key "ces". Anything else (and any unreadable or malformed file) is left to the
// generic scene loader, which reports its errors.
bool isCesScene(const std::string& path);

// Runs the machine; writes the results under o.out. Throws InputError on bad input. Returns the exit code.
int runCesMachine(const CesRunOptions& o);

}  // namespace ces
}  // namespace dvi
