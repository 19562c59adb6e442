// A GPU run that does not fit the device: `dvisim run --backend gpu` must end with exit code 5 and one error line,
// leave the earlier results in --out as they were, and leave no half-written folder beside them. The device's
// memory is really exhausted: this test holds all of it but a little while the CLI runs in another process.
#include <catch2/catch.hpp>

#include <filesystem>
#include <string>

#include "cli_test_util.h"
#include "device_check.h"
#if defined(DVISIM_HAVE_CUDA)
#include "gpu_testing.h"
#endif

using namespace clitest;

#if defined(DVISIM_HAVE_CUDA)
namespace {

// A pile of `count` spheres in a box; a few steps.
std::string pileScene(int count) {
  return R"({ "name": "oom", "settings": { "dt": 0.001, "time": 0.003 }, "bodies": [
    { "name": "ground", "shape": { "type": "plane", "normal": [0, 1, 0], "offset": 0 }, "mass": 0 },
    { "generator": { "type": "pile", "name": "s", "count": )" +
         std::to_string(count) + R"(, "footprint": [20, 20], "origin": [-10, 0.001, -10],
      "shape": { "type": "sphere", "radius": 0.01 }, "density": 2500, "seed": 3 } } ] })";
}

}  // namespace
#endif

TEST_CASE("GPU out of memory: exit code 5, one line, the earlier results kept, nothing half-written",
          "[gpu][cli][oom]") {
  if (!dvi::testing::haveDevice()) return;
#if defined(DVISIM_HAVE_CUDA)
  namespace fs = std::filesystem;
  const fs::path d = tempDir("oom");
  const fs::path scene = d / "big.json", out = d / "results";
  spit(scene, pileScene(2'000'000));
  fs::create_directories(out);
  spit(out / "earlier.txt", "results of an earlier run\n");

  CliResult r;
  {
    // 1 GiB left: enough for the CLI's CUDA context, not for two million bodies and their contacts.
    dvi::gpu::DeviceMemoryHold hold(size_t(1) << 30);
    REQUIRE(hold.held() > 0);
    r = runCli("run " + quote(scene.string()) + " --backend gpu --out " + quote(out.string()));
  }
  INFO("stdout: " << r.out << "\nstderr: " << r.err);
  CHECK(r.code == 5);
  CHECK(r.errLines() == 1);
  CHECK(r.err.rfind("dvisim: error: ", 0) == 0);
  CHECK(r.err.find("out of memory") != std::string::npos);
  CHECK(slurp(out / "earlier.txt") == "results of an earlier run\n");
  CHECK_FALSE(fs::exists(out / "summary.json"));
  int beside = 0;
  for (const auto& e : fs::directory_iterator(d))
    if (e.path().filename().string().rfind(".results.tmp-", 0) == 0) ++beside;
  CHECK(beside == 0);

  // The same scene fits once the memory is back: the failure was the memory, not the scene.
  const CliResult ok =
      runCli("run " + quote(scene.string()) + " --backend gpu --steps 1 --out " + quote((d / "fits").string()));
  INFO("with the memory back: " << ok.err);
  CHECK(ok.code == 0);
  fs::remove_all(d);
#endif
}
