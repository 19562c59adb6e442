// How a run ends and what it leaves (docs/HARDENING.md "Checkpoints", "Results, written atomically", "Signals",
// "Exit codes"): the exit code of each way a run ends (0, 2, 3, 4, 5) through the CLI binary, results replaced as
// a whole, checkpoints with a checksum and the configuration they were made with, UTF-8 names, frames.pvd.
#include <catch2/catch.hpp>

#include <chrono>
#include <cstdlib>
#include <new>
#include <regex>
#include <sstream>
#include <string>

#include <nlohmann/json.hpp>

#include "ces/ces_config.h"
#include "ces/machine.h"
#include "chrono_like/io/json_check.h"
#include "chrono_like/io/output.h"
#include "chrono_like/io/run_control.h"
#include "cli_test_util.h"

using namespace clitest;
using nlohmann::json;

namespace {

const char* kBall = R"({
  "name": "ball",
  "settings": { "dt": 0.001, "steps": 4 },
  "bodies": [
    { "name": "ground", "shape": { "type": "plane", "normal": [0, 1, 0] }, "mass": 0 },
    { "name": "a", "shape": { "type": "sphere", "radius": 0.1 }, "mass": 1, "position": [0, 0.099, 0] }
  ]
})";

// `script` under bash (for ulimit, $'...', background jobs and kill); the exit code, stdout and stderr of the last
// dvisim it runs are in the files its command line names.
int bash(const std::string& script) {
  const int status = std::system(("bash -c " + quote(script)).c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : 1000;
}

// Files and directories under `dir` whose name contains ".tmp" (ResultDir and writeFileAtomic leftovers).
int tempLeftovers(const fs::path& dir) {
  int n = 0;
  for (const auto& e : fs::directory_iterator(dir)) n += e.path().filename().string().find(".tmp") != std::string::npos;
  return n;
}

// A short CES run on the CPU (the charge-simulation field: no corona grid to solve first).
const std::string kCes =
    " --backend cpu --set field.model=\\\"csm\\\" --set output.plots=false --set feed.mass_flow_g_s=3";

}  // namespace

TEST_CASE("Exit codes: each exception maps to its code and status", "[results]") {
  using dvi::exitCodeFor;
  CHECK(exitCodeFor(std::make_exception_ptr(dvi::InputError("x"))) == 2);
  CHECK(exitCodeFor(std::make_exception_ptr(dvi::SimulationDiverged("x"))) == 3);
  CHECK(exitCodeFor(std::make_exception_ptr(dvi::SolverError("apgd: non-finite"))) == 3);
  CHECK(exitCodeFor(std::make_exception_ptr(std::bad_alloc())) == 5);
  CHECK(exitCodeFor(std::make_exception_ptr(dvi::DeviceError("GPU out of memory"))) == 5);
  CHECK(exitCodeFor(std::make_exception_ptr(std::logic_error("x"))) == 1);
  CHECK(std::string(dvi::runStatusName(3)) == "diverged");
  CHECK(std::string(dvi::runStatusName(4)) == "interrupted");
  CHECK(std::string(dvi::runStatusName(5)) == "failed");
  CHECK(dvi::exceptionMessage(std::make_exception_ptr(std::bad_alloc())) == "out of memory (std::bad_alloc)");
  // the divergence message names the step and the cause
  dvi::SystemConfig sc;
  dvi::System sys(sc);
  const std::string m = dvi::divergedMessage(7, 0.007, sys.bodies(), "apgd: non-finite residual");
  CHECK(m.find("step 7") != std::string::npos);
  CHECK(m.find("apgd: non-finite residual") != std::string::npos);
  CHECK(dvi::firstNonFiniteBody(sys.bodies()) == -1);
}

TEST_CASE("Exit codes: dvisim --help lists them", "[results][cli]") {
  const CliResult r = runCli("--help");
  CHECK(r.code == 0);
  for (const char* line :
       {"Exit codes:", "0  done", "2  bad input", "3  the simulation diverged", "4  interrupted", "5  out of memory"})
    CHECK(r.out.find(line) != std::string::npos);
}

TEST_CASE("Exit code 3: a diverging scene names the step and the body and keeps what it has", "[results][cli]") {
  const fs::path d = tempDir("diverge");
  spit(d / "ball.json", kBall);
  const fs::path out = d / "o";
  // a time step of 1e154 s: the first step's displacement is ~1e308 m, the next overflows
  const CliResult r = runCli("run " + quote((d / "ball.json").string()) +
                             " --backend cpu --dt 1e154 --steps 20 --out " + quote(out.string()));
  INFO(r.out << r.err);
  CHECK(r.code == 3);
  CHECK(r.errLines() == 1);
  CHECK(r.err.rfind("dvisim: error: the simulation diverged in step ", 0) == 0);
  CHECK(r.err.find("body 1") != std::string::npos);
  REQUIRE(fs::exists(out / "summary.json"));
  const json s = json::parse(slurp(out / "summary.json"));
  CHECK(s["status"] == "diverged");
  CHECK(s["steps"].get<int>() < 20);
  CHECK(s["error"].get<std::string>().find("diverged") != std::string::npos);
  CHECK(fs::exists(out / "bodies.csv"));
  CHECK(r.out.find("results so far") != std::string::npos);
  CHECK(tempLeftovers(d) == 0);
  fs::remove_all(d);
}

TEST_CASE("Exit code 5: running out of memory after simulating keeps the results so far", "[results][cli]") {
  const fs::path d = tempDir("oom");
  const fs::path out = d / "o";
  // 10,000 splitter positions are 5e7 table cells (6.8 GB) after the run: more than the 1.5 GB address space.
  const std::string cmd = "ulimit -v 1500000; exec " + quote(DVISIM_CLI_PATH) + " run" + kCes +
                          " --threads 1 --set splitters.positions=10000 --time 0.002 --out " + quote(out.string()) +
                          " >" + quote((d / "stdout").string()) + " 2>" + quote((d / "stderr").string());
  const int code = bash(cmd);
  const std::string err = slurp(d / "stderr");
  INFO(slurp(d / "stdout") << err);
  CHECK(code == 5);
  CHECK(err == "dvisim: error: out of memory (std::bad_alloc)\n");
  REQUIRE(fs::exists(out / "summary.json"));
  const json s = json::parse(slurp(out / "summary.json"));
  CHECK(s["status"] == "failed");
  CHECK(s["exit_code"] == 5);
  CHECK(fs::exists(out / "checkpoint" / "state.bin"));  // the last state, to resume from
  fs::remove_all(d);
}

TEST_CASE("Exit code 4: SIGTERM and SIGINT checkpoint the last state, write status interrupted, and the run resumes",
          "[results][cli]") {
  const fs::path d = tempDir("signal");
  for (const char* sig : {"TERM", "INT"}) {
    INFO("SIG" << sig);
    const fs::path out = d / (std::string("o") + sig);
    const std::string so = (d / "stdout").string(), se = (d / "stderr").string();
    // a long run; the signal once it has started stepping
    const std::string cmd = quote(DVISIM_CLI_PATH) + " run" + kCes + " --time 30 --out " + quote(out.string()) + " >" +
                            quote(so) + " 2>" + quote(se) +
                            " & p=$!; for i in $(seq 1 600); do grep -q 'ces machine:' " + quote(so) +
                            " && break; sleep 0.1; done; sleep 0.5; kill -" + sig + " $p; wait $p";
    const int code = bash(cmd);
    const std::string err = slurp(se);
    INFO(slurp(so) << err);
    CHECK(code == 4);
    CHECK(err.find(std::string("dvisim: interrupted by SIG") + sig) != std::string::npos);
    REQUIRE(fs::exists(out / "summary.json"));
    const json s = json::parse(slurp(out / "summary.json"));
    CHECK(s["status"] == "interrupted");
    const double t = s["sim_time"].get<double>();
    CHECK(t < 30);
    REQUIRE(fs::exists(out / "checkpoint" / "state.bin"));
    CHECK(tempLeftovers(d) == 0);
    if (std::string(sig) == "TERM") {
      // resumed in its own directory for two more milliseconds
      char dur[64];
      std::snprintf(dur, sizeof dur, "%.9g", t + 0.002);
      const CliResult r = runCli("run --backend cpu --resume " + quote(out.string()) + " --set duration_s=" + dur +
                                 " --out " + quote(out.string()));
      INFO(r.out << r.err);
      CHECK(r.code == 0);
      const json s2 = json::parse(slurp(out / "summary.json"));
      CHECK(s2["status"] == "done");
      CHECK(s2["sim_time"].get<double>() == Approx(t + 0.002).margin(1e-9));
    }
  }
  fs::remove_all(d);
}

TEST_CASE("CES checkpoints: a run killed by SIGKILL resumes from its last periodic checkpoint, bitwise",
          "[results][cli]") {
  const fs::path d = tempDir("ces_kill");
  const fs::path out = d / "k";
  const std::string so = (d / "stdout").string(), se = (d / "stderr").string();
  // a checkpoint every 250 steps (50 ms at the default 0.2 ms step); SIGKILL once the first is there
  const int code =
      bash(quote(DVISIM_CLI_PATH) + " run" + kCes + " --set output.checkpoint_every_s=0.05 --time 30" + " --out " +
           quote(out.string()) + " >" + quote(so) + " 2>" + quote(se) + " & p=$!; for i in $(seq 1 900); do ls " +
           quote(d.string()) + "/.k.tmp-*/checkpoint/state.bin >/dev/null 2>&1 && break; sleep 0.05; done; " +
           "kill -KILL $p; { wait $p; } 2>/dev/null");
  INFO(slurp(so) << slurp(se));
  REQUIRE(code == 128 + 9);
  REQUIRE_FALSE(fs::exists(out));
  // --resume with the killed run's --out finds its checkpoint beside it (at 50 or 100 ms) and runs to 150 ms
  const CliResult r = runCli("run --backend cpu --resume " + quote(out.string()) + " --set duration_s=0.15 --out " +
                             quote(out.string()));
  INFO(r.out << r.err);
  REQUIRE(r.code == 0);
  CHECK(r.out.find("resuming from .k.tmp-") != std::string::npos);
  CHECK(tempLeftovers(d) == 0);  // the killed run's folder is gone
  const fs::path whole = d / "whole";
  const CliResult w = runCli("run" + kCes + " --time 0.15 --out " + quote(whole.string()));
  INFO(w.out << w.err);
  REQUIRE(w.code == 0);
  CHECK(slurp(out / "bodies.csv") == slurp(whole / "bodies.csv"));  // bitwise: 17 significant digits
  fs::remove_all(d);
}

TEST_CASE("Atomic results: a rerun replaces the whole directory, a refused run leaves it as it was", "[results][cli]") {
  const fs::path d = tempDir("atomic");
  spit(d / "ball.json", kBall);
  const fs::path out = d / "o";
  const std::string scene = quote((d / "ball.json").string());
  CliResult r = runCli("run " + scene + " --backend cpu --frames 5 --out " + quote(out.string()));
  REQUIRE(r.code == 0);
  CHECK(fs::exists(out / "frame_0004.vtp"));
  spit(out / "stray.txt", "left by the user");
  r = runCli("run " + scene + " --backend cpu --frames 2 --out " + quote(out.string()));
  REQUIRE(r.code == 0);
  CHECK(fs::exists(out / "frame_0001.vtp"));
  CHECK_FALSE(fs::exists(out / "frame_0002.vtp"));  // no frame of the longer run beside the new summary
  CHECK_FALSE(fs::exists(out / "frame_0004.vtp"));
  CHECK_FALSE(fs::exists(out / "stray.txt"));
  const std::string pvd = slurp(out / "frames.pvd");
  CHECK(std::count(pvd.begin(), pvd.end(), '\n') == 3 + 2 + 2);  // header (3 lines), 2 frames, closing tags (2 lines)
  const std::string before = slurp(out / "summary.json");
  // bad input: refused, nothing touched
  expectInputError("run " + scene + " --backend cpu --set settings.bogus=1 --out " + quote(out.string()), "bogus");
  CHECK(slurp(out / "summary.json") == before);
  CHECK(fs::exists(out / "frame_0001.vtp"));
  // --out naming a file
  spit(d / "file", "x");
  expectInputError("run " + scene + " --backend cpu --out " + quote((d / "file").string()), "not a directory");
  CHECK(slurp(d / "file") == "x");
  CHECK(tempLeftovers(d) == 0);
  fs::remove_all(d);
}

TEST_CASE("Checkpoints: edits are refused by the checksum, physics changes by name, a failed resume keeps the old",
          "[results][cli]") {
  const fs::path d = tempDir("ckpt");
  const fs::path a = d / "a";
  CliResult r = runCli("run" + kCes + " --time 0.002 --out " + quote(a.string()));
  INFO(r.out << r.err);
  REQUIRE(r.code == 0);
  const fs::path state = a / "checkpoint" / "state.bin", config = a / "checkpoint" / "ces_config.json";
  const std::string good = slurp(state), good_config = slurp(config), summary = slurp(a / "summary.json");
  REQUIRE(good.rfind("DVICES03", 0) == 0);
  const std::string resume = "run --backend cpu --resume " + quote(a.string()) + " --out " + quote(a.string());

  // a physics setting differs: refused by name; what the run may change is allowed
  expectInputError(resume + " --set electrode.voltage_kV=-30", "ces.electrode.voltage_kV (-35 -> -30)");
  expectInputError(resume + " --set feed.mass_flow_g_s=4", "ces.feed.mass_flow_g_s");
  expectInputError(resume + " --dt 1e-5", "ces.time_step_s");
  expectInputError(resume + " --collision bullet", "--collision (native -> bullet)");
  // every byte of the state is covered: a flipped bit anywhere is refused
  for (size_t at : {size_t(20), good.size() / 2, good.size() - 9, good.size() - 1}) {
    std::string f = good;
    f[at] = char(f[at] ^ 0x10);
    spit(state, f);
    expectInputError(resume, "checkpoint: checksum mismatch");
  }
  spit(state, good);
  // the readable copy of the configuration, edited
  json c = json::parse(good_config);
  REQUIRE(c["ces"]["electrode"]["voltage_kV"] == -35);
  c["ces"]["electrode"]["voltage_kV"] = -36;
  spit(config, c.dump(2) + "\n");
  expectInputError(resume, "ces_config.json was edited");
  spit(config, good_config);
  // nothing of the run resumed from was touched by the refused resumes
  CHECK(slurp(state) == good);
  CHECK(slurp(a / "summary.json") == summary);
  CHECK(tempLeftovers(d) == 0);
  // a resume into its own directory that may change the duration runs, and replaces the checkpoint and summary
  r = runCli(resume + " --set duration_s=0.004");
  INFO(r.out << r.err);
  REQUIRE(r.code == 0);
  CHECK(slurp(state) != good);
  CHECK(json::parse(slurp(a / "summary.json"))["sim_time"].get<double>() == Approx(0.004));
  fs::remove_all(d);
}

TEST_CASE("Checkpoints: an old-format file is refused by name", "[results]") {
  std::string f = "DVICES02" + std::string(64, '\0');
  CHECK_THROWS_WITH(dvi::ces::cesCheckpointMeta(f), Catch::Contains("is not the current DVICES03"));
  CHECK_THROWS_WITH(dvi::ces::cesCheckpointMeta("garbage"), Catch::Contains("not a dvisim CES checkpoint"));
}

TEST_CASE("UTF-8: a name that is not UTF-8 is refused up front", "[results][cli]") {
  const fs::path d = tempDir("utf8");
  const std::string so = (d / "stdout").string(), se = (d / "stderr").string();
  const int code =
      bash(quote(DVISIM_CLI_PATH) + " run --backend cpu --set $'feed.materials.0.name=cu\\xff' --time 0.001 --out " +
           quote((d / "o").string()) + " >" + quote(so) + " 2>" + quote(se));
  const std::string err = slurp(se);
  INFO(err);
  CHECK(code == 2);
  CHECK(std::count(err.begin(), err.end(), '\n') == 1);
  CHECK(err.find("--set feed.materials.0.name: the value: not valid UTF-8 (byte 0xff at offset 2)") !=
        std::string::npos);
  CHECK_FALSE(fs::exists(d / "o"));
  // in a scene file: the JSON parser refuses it
  spit(d / "bad.json", std::string(kBall).replace(std::string(kBall).find("\"ball\""), 6, "\"b\xc3\x28\""));
  expectInputError("run " + quote((d / "bad.json").string()) + " --out " + quote((d / "o").string()), "UTF-8");
  CHECK(dvi::jsoncheck::invalidUtf8At("plain, caf\xc3\xa9, \xe2\x82\xac, \xf0\x9f\x98\x80") == std::string::npos);
  CHECK(dvi::jsoncheck::invalidUtf8At("\xc0\xaf") == 0);          // overlong
  CHECK(dvi::jsoncheck::invalidUtf8At("ab\xed\xa0\x80") == 2);    // a surrogate
  CHECK(dvi::jsoncheck::invalidUtf8At("abc\xe2\x82") == 3);       // truncated
  CHECK(dvi::jsoncheck::invalidUtf8At("\xf4\x90\x80\x80") == 0);  // above U+10FFFF
  fs::remove_all(d);
}

TEST_CASE("frames.pvd: a valid collection after every frame, entries appended in place", "[results]") {
  const fs::path d = tempDir("pvd");
  {
    dvi::PvdSeries s(d.string());
    for (int k = 0; k < 3; ++k) {
      s.add(0.5 * k, "<VTKFile/>\n");
      const std::string pvd = slurp(d / "frames.pvd");
      CHECK(pvd.rfind("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\"", 0) == 0);
      const std::string tail = "</Collection>\n</VTKFile>\n";
      REQUIRE(pvd.size() > tail.size());
      CHECK(pvd.substr(pvd.size() - tail.size()) == tail);
      CHECK(std::count(pvd.begin(), pvd.end(), '\n') == 3 + (k + 1) + 2);
    }
    CHECK(s.count() == 3);
  }
  const std::string pvd = slurp(d / "frames.pvd");
  CHECK(pvd.find("<DataSet timestep=\"0\" group=\"\" part=\"0\" file=\"frame_0000.vtp\"/>\n"
                 "<DataSet timestep=\"0.5\" group=\"\" part=\"0\" file=\"frame_0001.vtp\"/>\n"
                 "<DataSet timestep=\"1\" group=\"\" part=\"0\" file=\"frame_0002.vtp\"/>\n</Collection>") !=
        std::string::npos);
  CHECK(slurp(d / "frame_0002.vtp") == "<VTKFile/>\n");
  fs::remove_all(d);
}
