// Running the dvisim command-line program from a test: a fresh temporary directory, the exit code, stdout and
// stderr of `dvisim ARGS`, and the house check for bad input (exit code 2, one stderr line "dvisim: error: ...").
// DVISIM_CLI_PATH is the binary (tests/CMakeLists.txt).
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace clitest {

namespace fs = std::filesystem;

inline fs::path tempDir(const std::string& tag) {
  static std::atomic<int> counter{0};
  const fs::path d = fs::temp_directory_path() /
                     ("dvisim_test_" + tag + "_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

inline std::string slurp(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::ostringstream s;
  s << f.rdbuf();
  return s.str();
}

inline void spit(const fs::path& p, const std::string& text) { std::ofstream(p, std::ios::binary) << text; }

// Single-quoted for /bin/sh.
inline std::string quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

struct CliResult {
  int code = -1;  // exit code; 1000 + signal when killed
  std::string out, err;
  int errLines() const { return int(std::count(err.begin(), err.end(), '\n')); }
};

// Runs `dvisim ARGS` (ARGS as shell words) and captures its exit code, stdout and stderr.
inline CliResult runCli(const std::string& args) {
  const fs::path d = tempDir("io");
  const std::string cmd = "exec " + quote(DVISIM_CLI_PATH) + " " + args + " >" + quote((d / "out").string()) + " 2>" +
                          quote((d / "err").string());
  const int status = std::system(cmd.c_str());
  CliResult r;
  r.out = slurp(d / "out");
  r.err = slurp(d / "err");
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : 1000 + (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  fs::remove_all(d);
  return r;
}

// Expects exit code 2 and exactly one stderr line "dvisim: error: ..." that contains `needle`.
inline void expectInputError(const std::string& args, const std::string& needle) {
  INFO("dvisim " << args);
  const CliResult r = runCli(args);
  INFO("stdout: " << r.out << "\nstderr: " << r.err);
  CHECK(r.code == 2);
  CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
  CHECK(r.err.rfind("dvisim: error: ", 0) == 0);
  CHECK(r.err.find(needle) != std::string::npos);
}

}  // namespace clitest
