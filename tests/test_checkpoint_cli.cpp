// Checkpoints of scene runs on one process (apps/dvisim/run_checkpoint.h, docs/HARDENING.md "Checkpoints"): a run
// stopped by SIGINT exits with code 4 and leaves checkpoint/; a run killed by SIGKILL leaves its periodic checkpoints
// beside --out; `--resume` continues either, and on the CPU the resumed run ends bitwise where the uninterrupted run
// does (bodies.csv prints every number with 17 significant digits, so equal files are equal doubles). Damaged,
// foreign or deep checkpoints are refused with exit code 2 and nothing written.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli_test_util.h"
#include "device_check.h"
#include "gpu/gpu_factory.h"

using namespace clitest;
using nlohmann::json;

namespace {

const std::string kPile = std::string(DVISIM_SOURCE_DIR) + "/scenes/pile.json";

int bash(const std::string& script) {
  const int status = std::system(("bash -c " + quote(script)).c_str());
  if (WIFSIGNALED(status)) return 1000 + WTERMSIG(status);
  return WIFEXITED(status) ? WEXITSTATUS(status) : 1000;
}

// `dvisim run` of the pile on the CPU with `args`; its exit code, stdout and stderr.
CliResult runPile(const std::string& args) { return runCli("run " + quote(kPile) + " --backend cpu " + args); }

json summaryOf(const fs::path& out) { return json::parse(slurp(out / "summary.json")); }

// The periodic checkpoints a killed run left beside `out` (.NAME.tmp-*/checkpoints/step_*), oldest first.
std::vector<fs::path> periodicBeside(const fs::path& out) {
  std::vector<fs::path> found;
  const std::string prefix = "." + out.filename().string() + ".tmp-";
  for (const auto& run : fs::directory_iterator(out.parent_path())) {
    if (run.path().filename().string().rfind(prefix, 0) != 0 || !fs::is_directory(run.path() / "checkpoints")) continue;
    for (const auto& c : fs::directory_iterator(run.path() / "checkpoints"))
      if (c.path().filename().string().rfind("step_", 0) == 0) found.push_back(c.path());
  }
  std::sort(found.begin(), found.end());
  return found;
}

// The uninterrupted run of `steps` steps: its bodies.csv.
std::string uninterrupted(const fs::path& dir, int64_t steps) {
  const fs::path out = dir / ("whole_" + std::to_string(steps));
  const CliResult r = runPile("--steps " + std::to_string(steps) + " --out " + quote(out.string()));
  INFO(r.out << r.err);
  REQUIRE(r.code == 0);
  return slurp(out / "bodies.csv");
}

}  // namespace

namespace {

// Largest difference of any number of two bodies.csv files (same bodies), or -1 when they differ in shape.
double largestDifference(const std::string& a, const std::string& b) {
  std::istringstream fa(a), fb(b);
  std::string la, lb;
  double worst = 0;
  std::getline(fa, la), std::getline(fb, lb);  // the header
  while (std::getline(fa, la)) {
    if (!std::getline(fb, lb)) return -1;
    std::istringstream ra(la), rb(lb);
    std::string x, y;
    while (std::getline(ra, x, ',')) {
      if (!std::getline(rb, y, ',')) return -1;
      worst = std::max(worst, std::fabs(std::stod(x) - std::stod(y)));
    }
  }
  return std::getline(fb, lb) ? -1 : worst;
}

// A run of the pile on `backend` stopped by SIGINT, then resumed 30 steps further into another folder: the resumed
// run's bodies.csv and the uninterrupted run's.
std::pair<std::string, std::string> interruptAndResume(const fs::path& d, const std::string& backend) {
  const fs::path out = d / "stopped";
  const std::string so = (d / "stdout").string(), se = (d / "stderr").string();
  const int code = bash(quote(DVISIM_CLI_PATH) + " run " + quote(kPile) + " --backend " + backend +
                        " --steps 100000 --out " + quote(out.string()) + " >" + quote(so) + " 2>" + quote(se) +
                        " & p=$!; for i in $(seq 1 600); do grep -q 'scene:' " + quote(so) +
                        " && break; sleep 0.1; done; sleep 1.5; kill -INT $p; wait $p");
  INFO(slurp(so) << slurp(se));
  REQUIRE(code == 4);
  CHECK(slurp(se).find("dvisim: interrupted by SIGINT") != std::string::npos);
  const json s = summaryOf(out);
  CHECK(s["status"] == "interrupted");
  CHECK(s["checkpoint"] == "checkpoint/");
  const int64_t stopped = s["steps"].get<int64_t>();
  REQUIRE(stopped > 0);
  REQUIRE(stopped < 100000);
  const json m = json::parse(slurp(out / "checkpoint" / "manifest.json"));
  CHECK(m["processes"] == 1);
  CHECK(m["step"] == stopped);
  CHECK(fs::exists(out / "checkpoint" / "piece_p0.bin"));

  const int64_t target = stopped + 30;
  const fs::path resumed = d / "resumed";
  const CliResult r = runCli("run " + quote(kPile) + " --backend " + backend + " --resume " + quote(out.string()) +
                             " --steps " + std::to_string(target) + " --out " + quote(resumed.string()));
  INFO(r.out << r.err);
  REQUIRE(r.code == 0);
  CHECK(r.out.find("resuming from " + out.string() + "/checkpoint/ (step " + std::to_string(stopped) + ")") !=
        std::string::npos);
  const json s2 = summaryOf(resumed);
  CHECK(s2["status"] == "done");
  CHECK(s2["steps"] == target);
  CHECK(s2["resumed_from_step"] == stopped);
  CHECK(json::parse(slurp(resumed / "checkpoint" / "manifest.json"))["step"] == target);
  const fs::path whole = d / "whole";
  const CliResult w = runCli("run " + quote(kPile) + " --backend " + backend + " --steps " + std::to_string(target) +
                             " --out " + quote(whole.string()));
  INFO(w.out << w.err);
  REQUIRE(w.code == 0);
  return {slurp(resumed / "bodies.csv"), slurp(whole / "bodies.csv")};
}

}  // namespace

TEST_CASE("Scene checkpoints: SIGINT exits 4 with checkpoint/, and --resume ends bitwise where the whole run ends",
          "[checkpoint][cli]") {
  const fs::path d = tempDir("ckpt_int");
  const auto [resumed, whole] = interruptAndResume(d, "cpu");
  CHECK(resumed == whole);  // bitwise: every number printed with 17 significant digits
  fs::remove_all(d);
}

TEST_CASE("Scene checkpoints: a GPU run stopped by SIGINT resumes where the whole run ends", "[checkpoint][cli][gpu]") {
  if (!dvi::testing::haveDevice()) return;
  const fs::path d = tempDir("ckpt_gpu");
  const auto [resumed, whole] = interruptAndResume(d, "gpu");
  const double diff = largestDifference(resumed, whole);
  WARN("GPU: the resumed run against the whole run: largest difference " << diff);
  CHECK(diff == 0);
  fs::remove_all(d);
}

TEST_CASE("Scene checkpoints: a run killed by SIGKILL resumes from its last periodic checkpoint, bitwise",
          "[checkpoint][cli]") {
  const fs::path d = tempDir("ckpt_kill");
  const fs::path out = d / "killed";
  const std::string so = (d / "stdout").string(), se = (d / "stderr").string();
  // a checkpoint every 10 steps (the scene key through --set); SIGKILL once there are two of them
  const int code =
      bash(quote(DVISIM_CLI_PATH) + " run " + quote(kPile) +
           " --backend cpu --steps 100000 --set settings.checkpoint_every=10 --out " + quote(out.string()) + " >" +
           quote(so) + " 2>" + quote(se) + " & p=$!; for i in $(seq 1 900); do " + "[ $(ls -d " + quote(d.string()) +
           "/.killed.tmp-*/checkpoints/step_* 2>/dev/null | wc -l) -ge 2 ]" +
           " && break; sleep 0.1; done; sleep 0.3; kill -KILL $p; { wait $p; } 2>/dev/null");
  INFO(slurp(so) << slurp(se));
  REQUIRE(code == 128 + 9);      // bash's status of a job killed by SIGKILL
  CHECK_FALSE(fs::exists(out));  // the results folder never came: the run did not end
  const std::vector<fs::path> left = periodicBeside(out);
  REQUIRE(!left.empty());
  CHECK(left.size() <= 2);  // the newest two at most
  const json m = json::parse(slurp(left.back() / "manifest.json"));
  const int64_t last = m["step"].get<int64_t>();
  CHECK(last % 10 == 0);
  CHECK(last >= 20);

  // --resume with the killed run's --out finds it; the resumed run writes that --out and forgets the killed run
  const int64_t target = last + 25;
  const CliResult r = runPile("--resume " + quote(out.string()) + " --steps " + std::to_string(target) + " --out " +
                              quote(out.string()));
  INFO(r.out << r.err);
  REQUIRE(r.code == 0);
  CHECK(r.out.find("resuming from .killed.tmp-") != std::string::npos);
  CHECK(summaryOf(out)["resumed_from_step"] == last);
  CHECK(periodicBeside(out).empty());
  CHECK_FALSE(fs::exists(out / "checkpoints"));  // the periodic ones are gone once the run's own checkpoint is there
  CHECK(fs::exists(out / "checkpoint" / "manifest.json"));
  CHECK(slurp(out / "bodies.csv") == uninterrupted(d, target));
  fs::remove_all(d);
}

TEST_CASE("Scene checkpoints: bad checkpoints are refused with one line and nothing written", "[checkpoint][cli]") {
  const fs::path d = tempDir("ckpt_bad");
  const fs::path good = d / "good";
  CliResult r = runPile("--steps 12 --checkpoint-every 5 --out " + quote(good.string()));
  INFO(r.out << r.err);
  REQUIRE(r.code == 0);
  CHECK_FALSE(fs::exists(good / "checkpoints"));
  REQUIRE(fs::exists(good / "checkpoint" / "piece_p0.bin"));
  const fs::path o = d / "o";
  const std::string to = " --out " + quote(o.string());
  auto refused = [&](const std::string& args, const std::string& needle) {
    expectInputError("run " + quote(kPile) + " --backend cpu " + args + to, needle);
    CHECK_FALSE(fs::exists(o));
  };
  refused("--resume " + quote(good.string()) + " --steps 12",
          "the checkpoint in " + good.string() + " is at step 12 already");
  refused("--resume " + quote(good.string()) + " --steps 20 --dt 0.002", "give the same --dt");
  refused("--resume " + quote((d / "nothing").string()) + " --steps 20", "no checkpoint there");
  // a scene checkpoint without its scene
  expectInputError("run --resume " + quote(good.string()) + to, "resumes with the scene it ran");
  // a flipped bit in the piece
  fs::copy(good, d / "flipped", fs::copy_options::recursive);
  std::string piece = slurp(d / "flipped" / "checkpoint" / "piece_p0.bin");
  piece[100] = char(piece[100] ^ 1);
  spit(d / "flipped" / "checkpoint" / "piece_p0.bin", piece);
  refused("--resume " + quote((d / "flipped").string()) + " --steps 20", "checkpoint/piece_p0.bin: checksum mismatch");
  // a manifest nested 100,000 deep: refused as it is parsed
  fs::copy(good, d / "deep", fs::copy_options::recursive);
  spit(d / "deep" / "checkpoint" / "manifest.json", std::string(100000, '[') + std::string(100000, ']'));
  refused("--resume " + quote((d / "deep").string()) + " --steps 20", "nested deeper than 8 levels");
  fs::remove_all(d);
}
