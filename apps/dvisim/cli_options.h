// Command-line options that several dvisim commands declare alike (run, compare, sweep, bench ces).
#pragma once

#include <CLI/CLI.hpp>

#include <string>
#include <vector>

namespace dvi {

// Option `name` that may be given any number of times, one value each (`--set a=1 --set b=2`), all kept in order.
inline CLI::Option* addRepeatable(CLI::App* cmd, const std::string& name, std::vector<std::string>& values,
                                  const std::string& help) {
  return cmd->add_option(name, values, help)->expected(1)->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
}

// The run settings a command lets its user override, as given (the command checks them).
struct RunOverrides {
  std::string time, steps, dt, solver, iterations;
};

// Adds --time, --steps, --dt, --solver and --iterations bound to o; `whose` ends each help text (" (each run)").
inline void addRunOverrides(CLI::App* cmd, RunOverrides& o, const std::string& whose = "") {
  cmd->add_option("--time", o.time, "Simulated time in seconds" + whose);
  cmd->add_option("--steps", o.steps, "Number of steps" + whose);
  cmd->add_option("--dt", o.dt, "Time step in seconds" + whose);
  cmd->add_option("--solver", o.solver, "Our solver: jacobi|gs|apgd|bb" + whose);
  cmd->add_option("--iterations", o.iterations, "Our solver's iterations per step" + whose);
}

}  // namespace dvi
