// `dvisim bench ...`: the group of benchmark subcommands. Each benchmark lives in its own file
// (bench_scaling.cpp: `bench scaling`; `bench accuracy`, `bench stability` can join the same way):
//
//   void registerBenchFoo(CLI::App& app) {
//     CLI::App* cmd = benchCommand(app)->add_subcommand("foo", "...");
//     auto opts = std::make_shared<FooOptions>();   // options bound to cmd
//     addBenchRunner(cmd, [opts] { return runFoo(*opts); });
//   }
//
// main.cpp calls each register function once, then, when `bench` was given, runBenchCommand() runs the
// one subcommand that was parsed. Runners return the exit code and throw dvi::InputError on bad input
// (main maps it to exit code 2).
#pragma once

#include <CLI/CLI.hpp>

#include <functional>
#include <stdexcept>
#include <utility>
#include <vector>

// The `bench` subcommand of app: the existing one, or a new one (which requires exactly one benchmark).
inline CLI::App* benchCommand(CLI::App& app) {
  for (CLI::App* s : app.get_subcommands([](CLI::App* c) { return c->get_name() == "bench"; })) return s;
  CLI::App* bench = app.add_subcommand("bench", "Benchmarks (not tests): bench scaling, ...");
  bench->require_subcommand(1);
  return bench;
}

inline std::vector<std::pair<CLI::App*, std::function<int()>>>& benchRunners() {
  static std::vector<std::pair<CLI::App*, std::function<int()>>> runners;
  return runners;
}

// Registers the function that runs benchmark subcommand `cmd` (a subcommand of benchCommand(app)).
inline void addBenchRunner(CLI::App* cmd, std::function<int()> run) { benchRunners().emplace_back(cmd, std::move(run)); }

// Runs the benchmark subcommand that was parsed; call when app.got_subcommand("bench").
inline int runBenchCommand() {
  for (auto& [cmd, run] : benchRunners())
    if (cmd->parsed()) return run();
  throw std::logic_error("bench: no benchmark subcommand was parsed");
}
