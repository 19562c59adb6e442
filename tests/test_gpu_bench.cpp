// The GPU scaling benchmark is `dvisim bench scaling` (bench/scaling/bench_scaling.cpp, scenes in
// bench/scaling/). This hidden test only runs that command, so device scripts that ask for "[gpu_bench]"
// (scripts/device/run_device.sh bench) keep working:
//   dvisim_tests "[gpu_bench]"   (env DVISIM_BENCH_OUT=DIR, DVISIM_BENCH_SIZES=10k,100k,1M,4M)
// It writes DIR/scaling.csv, scaling.png and, as --record, the dated result under bench/results/ (a copy in DIR).
// The CTest smoke test of the same command is bench_scaling_quick (tests/CMakeLists.txt).
#include <sys/wait.h>

#include <catch2/catch.hpp>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace {

std::string quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

}  // namespace

TEST_CASE("GPU scaling benchmark: dvisim bench scaling --record", "[.][gpu_bench]") {
  const std::string cli = DVISIM_CLI_PATH;
  if (!std::filesystem::is_regular_file(cli)) {
    WARN("the dvisim binary is not built (" << cli << "): skipping; run `dvisim bench scaling --out DIR --record`");
    return;
  }
  const char* out = std::getenv("DVISIM_BENCH_OUT");
  std::string cmd = quote(cli) + " bench scaling --record --out " +
                    quote(out && *out ? std::string(out)
                                      : (std::filesystem::temp_directory_path() / "dvisim_bench_scaling").string());
  if (const char* sizes = std::getenv("DVISIM_BENCH_SIZES")) cmd += " --sizes " + quote(sizes);
  const int status = std::system(cmd.c_str());
  REQUIRE(WIFEXITED(status));
  CHECK(WEXITSTATUS(status) == 0);
}
