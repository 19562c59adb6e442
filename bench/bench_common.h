// `dvisim bench ...`: the group of benchmark subcommands. Each benchmark lives in its own file
// (bench_scaling.cpp: `bench scaling`; `bench accuracy`, `bench stability` can join the same way):
//
//   void registerBenchFoo(CLI::App& app, BenchRegistry& reg) {
//     auto [cmd, o] = addBench<FooOptions>(app, reg, {"foo", "...", "foo.csv", "..."}, runFoo);
//     cmd->add_option("--size", o->size, "...");   // its own options, bound to *o
//   }
//
// main.cpp calls each register function once, then, when `bench` was given, runBenchCommand(reg) runs the
// one subcommand that was parsed. Runners return the exit code and throw dvi::InputError on bad input
// (main maps it to exit code 2).
#pragma once

#include <CLI/CLI.hpp>

#include <cstdio>
#include <cstdlib>
#include <functional>
#include <memory>
#include <string>
#include <stdexcept>
#include <utility>
#include <vector>

#include "chrono_like/base/errors.h"

// The `bench` subcommand of app: the existing one, or a new one (which requires exactly one benchmark).
inline CLI::App* benchCommand(CLI::App& app) {
  for (CLI::App* s : app.get_subcommands([](CLI::App* c) { return c->get_name() == "bench"; })) return s;
  CLI::App* bench = app.add_subcommand("bench", "Benchmarks (not tests): bench scaling, ...");
  bench->require_subcommand(1);
  return bench;
}

// The benchmark subcommands and the function that runs each; main() owns one and hands it to the register functions.
struct BenchRegistry {
  std::vector<std::pair<CLI::App*, std::function<int()>>> runners;
};

// Registers the function that runs benchmark subcommand `cmd` (a subcommand of benchCommand(app)).
inline void addBenchRunner(BenchRegistry& reg, CLI::App* cmd, std::function<int()> run) {
  reg.runners.emplace_back(cmd, std::move(run));
}

// Runs the benchmark subcommand that was parsed; call when app.got_subcommand("bench").
inline int runBenchCommand(const BenchRegistry& reg) {
  for (const auto& [cmd, run] : reg.runners)
    if (cmd->parsed()) return run();
  throw std::logic_error("bench: no benchmark subcommand was parsed");
}

// The options every benchmark takes: --out DIR (required), --quick, --record and --threads N.
struct BenchBasics {
  std::string out, threads = "0";
  bool quick = false, record = false;
};

// What a benchmark subcommand is called and says of itself: its name and one-line description; what --out receives
// (out_files), what --quick does, the extensions of the record --record writes under bench/results/ and what
// --threads sets.
struct BenchSpec {
  std::string name, description, out_files, quick_help;
  std::string record_exts = "md,csv", threads_help = "OpenMP threads of our CPU backend (0: all)";
};

// Adds the BenchBasics options of benchmark spec.name to cmd, bound to o.
inline void addBenchBasics(CLI::App* cmd, BenchBasics& o, const BenchSpec& spec) {
  cmd->add_option("--out", o.out, "Output directory (" + spec.out_files + ")")->required();
  cmd->add_flag("--quick", o.quick, spec.quick_help);
  cmd->add_flag("--record", o.record,
                "Also write bench/results/" + spec.name + "_<device>_<date>.{" + spec.record_exts + "}");
  cmd->add_option("--threads", o.threads, spec.threads_help);
}

// The benchmark subcommand spec.name: its BenchBasics options bound to a new Options (a BenchBasics) and run(options)
// registered as its runner. Returns the subcommand and the options, to which the benchmark binds its own options.
template <class Options, class Run>
std::pair<CLI::App*, std::shared_ptr<Options>> addBench(CLI::App& app, BenchRegistry& reg, const BenchSpec& spec,
                                                        Run run) {
  auto o = std::make_shared<Options>();
  CLI::App* cmd = benchCommand(app)->add_subcommand(spec.name, spec.description);
  addBenchBasics(cmd, *o, spec);
  addBenchRunner(reg, cmd, [o, run] { return run(*o); });
  return {cmd, o};
}

// The value of --threads: an integer in [0, 4096] (0: all), else an InputError naming it.
inline int benchThreads(const std::string& text) {
  char* end = nullptr;
  const long threads = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || *end || threads < 0 || threads > 4096)
    throw dvi::InputError("--threads: expected an integer in [0, 4096], got '" + text + "'");
  return int(threads);
}

// A record of a benchmark run: each (extension, text) of files written as DIR/BASE.EXTENSION into each of dirs,
// then one line saying where (the first of dirs).
template <class WriteFile>
void writeBenchRecord(const std::vector<std::string>& dirs, const std::string& base,
                      const std::vector<std::pair<std::string, std::string>>& files, WriteFile writeFile) {
  std::string exts;
  for (const std::string& d : dirs)
    for (const auto& [ext, text] : files) writeFile(d + "/" + base + "." + ext, text);
  for (size_t i = 0; i < files.size(); ++i)
    exts += (i == 0 ? "." : i + 1 == files.size() ? " and ." : ", .") + files[i].first;
  std::printf("recorded: %s/%s%s\n", dirs.front().c_str(), base.c_str(), exts.c_str());
}
