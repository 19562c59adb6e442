// `dvisim sweep` (apps/dvisim/sweep.cpp, sweep.h): the design expansion and linspace levels, the Student-t
// interval against tabulated quantiles and hand-computed intervals, bad input (exit code 2, one line), resume
// (only the run whose marker is gone reruns), and a quick 3 x 3 x 2-seed sweep of the CES machine whose
// runs.csv and summary.csv are checked against each other and against the runs' own summary.json.
#include <catch2/catch.hpp>

#include <cmath>
#include <map>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "../apps/dvisim/sweep.h"
#include "cli_test_util.h"
#include "gpu/gpu_factory.h"

using namespace dvi::sweep;
using clitest::expectInputError;
using clitest::quote;
using clitest::runCli;
using clitest::slurp;
using clitest::spit;
namespace fs = std::filesystem;

namespace {

// A CSV file as rows of column name -> text (the sweep writes no quoted fields).
std::vector<std::map<std::string, std::string>> readCsv(const fs::path& p) {
  std::vector<std::map<std::string, std::string>> rows;
  std::stringstream ss(slurp(p));
  std::string line;
  std::getline(ss, line);
  const std::vector<std::string> head = split(line, ',');
  while (std::getline(ss, line)) {
    const std::vector<std::string> cells = split(line, ',');
    REQUIRE(cells.size() == head.size());
    std::map<std::string, std::string> r;
    for (size_t i = 0; i < head.size(); ++i) r[head[i]] = cells[i];
    rows.push_back(r);
  }
  return rows;
}

// Eight spheres from a seeded pile generator on a plane: a plain scene whose seed is bodies.1.generator.seed.
const char* kPileScene = R"({
  "name": "sweep-pile",
  "settings": { "dt": 0.001, "steps": 3 },
  "bodies": [
    { "name": "ground", "shape": { "type": "plane", "normal": [0, 1, 0] }, "mass": 0 },
    { "generator": { "type": "pile", "name": "p", "count": 8, "footprint": [0.2, 0.2], "origin": [-0.1, 0.01, -0.1],
                     "jitter": 0.2, "seed": 1, "density": 1000, "shapes": [ { "shape": { "type": "sphere", "radius": 0.01 } } ] } }
  ]
})";

}  // namespace

TEST_CASE("sweep: full-factorial expansion, list rows and linspace levels", "[sweep]") {
  const Factor a = parseGrid("electrode.voltage_kV=-20,-30,-40");
  CHECK(a.key == "electrode.voltage_kV");
  CHECK(a.values == std::vector<std::string>{"-20", "-30", "-40"});
  // lo:hi:n is lo + (hi - lo) i / (n - 1), both ends included, printed as the shortest round-tripping text.
  CHECK(parseGrid("x=0:1:5").values == std::vector<std::string>{"0", "0.25", "0.5", "0.75", "1"});
  CHECK(parseGrid("x=-40:-20:3").values == std::vector<std::string>{"-40", "-30", "-20"});
  CHECK(parseGrid("x=0:0.3:4").values == std::vector<std::string>{"0", "0.1", "0.2", "0.3"});
  CHECK(parseGrid("field.model=csm").values == std::vector<std::string>{"csm"});

  const Factor b = parseGrid("drum.rpm=30:60:2");
  const std::vector<Setting> d = expandDesign({}, {a, b});
  REQUIRE(d.size() == 6);
  std::set<std::pair<std::string, std::string>> seen;  // every (voltage, rpm) pair exactly once
  for (const Setting& s : d) {
    REQUIRE(s.size() == 2);
    CHECK(s[0].first == "electrode.voltage_kV");
    CHECK(s[1].first == "drum.rpm");
    seen.insert({s[0].second, s[1].second});
  }
  CHECK(seen.size() == 6);
  CHECK(d[0] == Setting{{"electrode.voltage_kV", "-20"}, {"drum.rpm", "30"}});  // the last factor varies fastest
  CHECK(d[1] == Setting{{"electrode.voltage_kV", "-20"}, {"drum.rpm", "60"}});
  CHECK(d[5] == Setting{{"electrode.voltage_kV", "-40"}, {"drum.rpm", "60"}});

  const std::vector<Setting> rows = parseList("feed.rate_g_s, drum.rpm\n1,30\n\n2,40\r\n", "l.csv");
  REQUIRE(rows.size() == 2);
  CHECK(rows[1] == Setting{{"feed.rate_g_s", "2"}, {"drum.rpm", "40"}});
  const std::vector<Setting> crossed = expandDesign(rows, {a});  // list rows x grid: 2 x 3
  REQUIRE(crossed.size() == 6);
  CHECK(crossed[3] == Setting{{"feed.rate_g_s", "2"}, {"drum.rpm", "40"}, {"electrode.voltage_kV", "-20"}});

  CHECK(caseId(7, 9, 2) == "007-seed2");
  CHECK(caseId(1234, 2000, 1) == "1234-seed1");
  CHECK_THROWS_AS(parseGrid("x=1:2:1"), dvi::InputError);
  CHECK_THROWS_AS(parseGrid("x=1,,2"), dvi::InputError);
  CHECK_THROWS_AS(parseGrid("x=1,1"), dvi::InputError);
  CHECK_THROWS_AS(parseGrid("=1,2"), dvi::InputError);
  CHECK_THROWS_AS(parseList("a,b\n1\n", "l.csv"), dvi::InputError);
}

TEST_CASE("sweep: Student-t 95% interval against tabulated quantiles and hand-computed intervals", "[sweep]") {
  // t_{0.975,nu}, Montgomery & Runger, Applied Statistics and Probability for Engineers, 6th ed., Appendix A,
  // percentage points of the t distribution.
  const std::map<int, double> table = {{1, 12.706}, {2, 4.303},  {3, 3.182},  {4, 2.776},  {9, 2.262},
                                       {10, 2.228}, {20, 2.086}, {29, 2.045}, {40, 2.021}, {120, 1.980}};
  for (const auto& [nu, t] : table) {
    INFO("nu = " << nu);
    CHECK(tQuantile975(nu) == Approx(t).margin(5e-4));
  }
  // Large nu: z + (z^3 + z) / (4 nu) + O(1/nu^2), z = z_{0.975} = 1.959964 (Abramowitz & Stegun 26.7.5).
  const double z = 1.959963985, nu = 1e5;
  CHECK(tQuantile975(int(nu)) == Approx(z + (z * z * z + z) / (4 * nu)).epsilon(1e-8));
  // nu = 2: P(|T| < t) = t / sqrt(2 + t^2) exactly, so t_{0.975,2} = 0.95 sqrt(2 / (1 - 0.95^2)).
  CHECK(tQuantile975(2) == Approx(0.95 * std::sqrt(2 / (1 - 0.95 * 0.95))).epsilon(1e-12));

  // {1,2,3,4,5}: mean 3, s^2 = 10/4, half = 2.7764 * sqrt(2.5) / sqrt(5) = 1.9632.
  const MeanCi five = meanCi({1, 2, 3, 4, 5});
  CHECK(five.n == 5);
  CHECK(five.mean == Approx(3));
  CHECK(five.half == Approx(1.9632).margin(1e-4));
  // Two values a, b: s = |a - b| / sqrt(2), so half = t_{0.975,1} |a - b| / 2 = 12.7062 * 1.
  const MeanCi two = meanCi({2.0, 4.0});
  CHECK(two.mean == Approx(3));
  CHECK(two.half == Approx(12.7062).margin(1e-4));
  const MeanCi one = meanCi({7.0});
  CHECK(one.mean == 7.0);
  CHECK(std::isnan(one.half));
  CHECK(meanCi({}).n == 0);

  // Paired differences over the seeds in both (seed 4 only in one): {1, 2, 3}, mean 2, s = 1, half = t_{0.975,2}/sqrt(3).
  const MeanCi p = pairedDifference({{1, 10.0}, {2, 20.0}, {3, 30.0}}, {{1, 11.0}, {2, 22.0}, {3, 33.0}, {4, 99.0}});
  CHECK(p.n == 3);
  CHECK(p.mean == Approx(2));
  CHECK(p.half == Approx(0.95 * std::sqrt(2 / (1 - 0.95 * 0.95)) / std::sqrt(3.0)).epsilon(1e-9));
}

TEST_CASE("sweep: metrics from summary.json, ces.metrics first, else every number flattened", "[sweep]") {
  const nlohmann::json with = nlohmann::json::parse(R"({"ces": {"metrics": {"conductor.grade": 0.9, "x": null},
                                                     "fed_mass_kg": 1}})");
  const std::map<std::string, double> m = runMetrics(with);
  CHECK(m == std::map<std::string, double>{{"conductor.grade", 0.9}});
  const nlohmann::json without = nlohmann::json::parse(R"({"steps": 5, "ces": {"bins": {"a": {"metal_kg": 2}},
                                                        "materials": [{"fed": 3, "name": "cu"}], "ok": true}})");
  CHECK(runMetrics(without) == std::map<std::string, double>{{"bins.a.metal_kg", 2}, {"materials.0.fed", 3}});
  CHECK(runMetrics(nlohmann::json::parse(R"({"steps": 5, "stage_seconds": {"solve": 0.5}})")) ==
        std::map<std::string, double>{{"stage_seconds.solve", 0.5}, {"steps", 5}});
}

TEST_CASE("sweep: bad input exits 2 with one line naming the problem", "[sweep]") {
  const fs::path d = clitest::tempDir("sweep_bad");
  const std::string out = " --out " + quote((d / "o").string());
  expectInputError("sweep --grid drum.nope=1,2 --time 0" + out, "nope");
  expectInputError("sweep --grid drum.rpm= --time 0" + out, "empty list");
  expectInputError("sweep --grid drum.rpm=10:20:1 --time 0" + out, "(n)");
  expectInputError("sweep --grid drum.rpm=10,20 --seeds 0 --time 0" + out, "--seeds");
  expectInputError("sweep --time 0" + out, "nothing to sweep");
  expectInputError("sweep --grid drum.rpm=10,20 --backend cuda --time 0" + out, "unknown backend 'cuda'");
  expectInputError("sweep --grid drum.rpm=10,20 --grid drum.rpm=30 --time 0" + out, "swept twice");
  expectInputError("sweep --grid seed=1,2 --time 0" + out, "seed key");
  expectInputError("sweep --grid drum.rpm=10,20 --set drum.rpm=5 --time 0" + out, "also swept");
  expectInputError("sweep --grid drum.rpm=10,5000 --time 0" + out, "setting 1");
  spit(d / "empty.csv", "drum.rpm\n");
  expectInputError("sweep --list " + quote((d / "empty.csv").string()) + " --time 0" + out, "empty list");
  spit(d / "scene.json", kPileScene);
  expectInputError("sweep " + quote((d / "scene.json").string()) + " --grid settings.dt=0.001,0.002 --seeds 2" + out,
                   "--seed-key");
  CHECK_FALSE(fs::exists(d / "o" / "runs"));  // nothing ran
  fs::remove_all(d);
}

TEST_CASE("sweep: resume reruns only the runs without a done marker, other arguments are refused", "[sweep]") {
  const fs::path d = clitest::tempDir("sweep_resume");
  spit(d / "scene.json", kPileScene);
  const std::string args = "sweep " + quote((d / "scene.json").string()) +
                           " --grid settings.dt=0.001,0.002 --seeds 2 --seed-key bodies.1.generator.seed --backend cpu "
                           "--jobs 2 --no-plots --out " +
                           quote((d / "o").string());
  clitest::CliResult r = runCli(args);
  INFO("stdout: " << r.out << "\nstderr: " << r.err);
  REQUIRE(r.code == 0);
  const fs::path runs = d / "o" / "runs";
  const std::vector<std::string> ids = {"000-seed1", "000-seed2", "001-seed1", "001-seed2"};
  std::map<std::string, fs::file_time_type> stamp;
  for (const std::string& id : ids) {
    REQUIRE(fs::is_regular_file(runs / id / "sweep_done.json"));
    stamp[id] = fs::last_write_time(runs / id / "summary.json");
  }
  // The seed reached the generator: the two replicates of a setting start from different bodies.
  CHECK(slurp(runs / "000-seed1" / "bodies.csv") != slurp(runs / "000-seed2" / "bodies.csv"));
  CHECK(nlohmann::json::parse(slurp(runs / "001-seed1" / "summary.json"))["dt"].get<double>() == Approx(0.002));

  fs::remove(runs / "001-seed1" / "sweep_done.json");
  r = runCli(args);
  REQUIRE(r.code == 0);
  CHECK(r.out.find("3 already finished, 1 to run") != std::string::npos);
  CHECK(r.out.find("001-seed1: ok") != std::string::npos);
  CHECK(r.out.find("000-seed1: ok") == std::string::npos);
  CHECK(fs::is_regular_file(runs / "001-seed1" / "sweep_done.json"));
  for (const std::string& id : ids) {
    INFO(id);
    CHECK((fs::last_write_time(runs / id / "summary.json") == stamp[id]) == (id != "001-seed1"));
  }
  CHECK(readCsv(d / "o" / "runs.csv").size() == 4);

  std::string other = args;
  other.replace(other.find("--seeds 2"), 9, "--seeds 3");
  expectInputError(other, "--seeds was 2, now 3");
  fs::remove_all(d);
}

TEST_CASE("sweep: a failed run is reported and the sweep exits non-zero after writing its tables", "[sweep]") {
  if (dvi::gpuAvailable()) {
    WARN("skipped: --backend gpu succeeds on this machine, the failure needs a build or machine without a GPU");
    return;
  }
  const fs::path d = clitest::tempDir("sweep_fail");
  spit(d / "scene.json", kPileScene);
  const clitest::CliResult r =
      runCli("sweep " + quote((d / "scene.json").string()) +
             " --grid settings.dt=0.001,0.002 --backend gpu --no-plots --out " + quote((d / "o").string()));
  INFO("stdout: " << r.out << "\nstderr: " << r.err);
  CHECK(r.code == 1);
  CHECK(r.err.find("run 000-seed1 failed (exit 2), log: ") != std::string::npos);
  CHECK(slurp(d / "o" / "runs" / "000-seed1" / "run.log").find("--backend gpu") != std::string::npos);
  const auto rows = readCsv(d / "o" / "runs.csv");
  REQUIRE(rows.size() == 2);
  CHECK(rows[0].at("status") == "failed");
  CHECK(rows[0].at("exit_code") == "2");
  CHECK(readCsv(d / "o" / "summary.csv").at(1).at("n") == "0");
  fs::remove_all(d);
}

TEST_CASE("sweep: quick CES sweep, 3 voltages x 3 drum speeds x 2 seeds", "[sweep]") {
  const fs::path d = clitest::tempDir("sweep_ces");
  const clitest::CliResult r = runCli(
      "sweep --grid electrode.voltage_kV=-20,-30,-40 --grid drum.rpm=30,44.8,60 --seeds 2 --time 0.02 --backend cpu "
      "--out " +
      quote(d.string()));
  INFO("stdout: " << r.out << "\nstderr: " << r.err);
  REQUIRE(r.code == 0);
  const auto runs = readCsv(d / "runs.csv");
  const auto sum = readCsv(d / "summary.csv");
  REQUIRE(runs.size() == 18);
  REQUIRE(sum.size() == 9);
  const nlohmann::json design = nlohmann::json::parse(slurp(d / "sweep.json"));
  CHECK(design["cases"].size() == 18);
  CHECK(design["settings"].size() == 9);

  // A metric that differs between seeds (the fed mass of a random feed), found in either metrics layout.
  std::string fed;
  for (const auto& kv : runs[0])
    if (kv.first.find("fed_mass_kg") != std::string::npos) fed = kv.first;
  REQUIRE(!fed.empty());
  std::set<std::pair<std::string, std::string>> settings;
  for (size_t k = 0; k < 9; ++k) {
    const auto& s = sum[k];
    std::vector<const std::map<std::string, std::string>*> reps;
    for (const auto& row : runs)
      if (row.at("setting") == std::to_string(k)) reps.push_back(&row);
    REQUIRE(reps.size() == 2);
    CHECK(std::set<std::string>{reps[0]->at("seed"), reps[1]->at("seed")} == std::set<std::string>{"1", "2"});
    for (const auto* row : reps) {
      CHECK(row->at("status") == "ok");
      CHECK(row->at("electrode.voltage_kV") == s.at("electrode.voltage_kV"));
      // The setting reached the run: its own summary.json reports the electrode voltage.
      const nlohmann::json js = nlohmann::json::parse(slurp(d / "runs" / row->at("case") / "summary.json"));
      if (js["ces"].contains("voltage_kV"))
        CHECK(js["ces"]["voltage_kV"].get<double>() == Approx(std::stod(row->at("electrode.voltage_kV"))));
    }
    settings.insert({s.at("electrode.voltage_kV"), s.at("drum.rpm")});
    CHECK(s.at("n") == "2");
    // Mean and half-width of two values: (a + b) / 2 and t_{0.975,1} |a - b| / 2, t_{0.975,1} = 12.7062.
    const double a = std::stod(reps[0]->at(fed)), b = std::stod(reps[1]->at(fed));
    CHECK(std::stod(s.at(fed + ".mean")) == Approx((a + b) / 2).epsilon(1e-8));
    CHECK(std::stod(s.at(fed + ".ci95")) == Approx(12.7062 * std::fabs(a - b) / 2).epsilon(1e-4));
  }
  CHECK(settings.size() == 9);
  // paired.csv: each setting k >= 1 against setting 0, seed by seed, from runs.csv.
  const auto paired = readCsv(d / "paired.csv");
  REQUIRE(paired.size() == 8);
  auto value = [&](size_t setting, const std::string& seed) {
    for (const auto& row : runs)
      if (row.at("setting") == std::to_string(setting) && row.at("seed") == seed) return std::stod(row.at(fed));
    return std::nan("");
  };
  for (size_t k = 1; k < 9; ++k) {
    const auto& p = paired[k - 1];
    CHECK(p.at("setting") == std::to_string(k));
    CHECK(p.at("n") == "2");
    const double d1 = value(k, "1") - value(0, "1"), d2 = value(k, "2") - value(0, "2");
    CHECK(std::stod(p.at(fed + ".diff")) == Approx((d1 + d2) / 2).margin(1e-12));
    CHECK(std::stod(p.at(fed + ".ci95")) == Approx(12.7062 * std::fabs(d1 - d2) / 2).epsilon(1e-4).margin(1e-15));
  }
  if (r.out.find("not written") == std::string::npos) {  // python3 with matplotlib present: one plot per swept key
    CHECK(fs::is_regular_file(d / "sweep_electrode.voltage_kV.png"));
    CHECK(fs::is_regular_file(d / "sweep_drum.rpm.png"));
  }
  fs::remove_all(d);
}

TEST_CASE("sweep: SIGINT stops the running cases cleanly, writes the tables and exits 4", "[sweep]") {
  const fs::path d = clitest::tempDir("sweep_int");
  const fs::path o = d / "o", runs = o / "runs";
  const std::string so = (d / "stdout").string(), se = (d / "stderr").string();
  // two long CES runs at once; SIGINT to the sweep once both are stepping
  const std::string script = quote(DVISIM_CLI_PATH) +
                             " sweep --grid feed.mass_flow_g_s=3,4 --backend cpu --jobs 2 --threads 1 --no-plots "
                             "--set field.model='\"csm\"' --time 30 --out " +
                             quote(o.string()) + " >" + quote(so) + " 2>" + quote(se) +
                             " & p=$!; for i in $(seq 1 600); do [ \"$(cat " + quote(runs.string()) +
                             "/.*.log 2>/dev/null | grep -c 'ces machine:')\" = 2 ] && break; "
                             "sleep 0.1; done; sleep 0.5; kill -INT $p; wait $p";
  const int status = std::system(("bash -c " + quote(script)).c_str());
  const int code = WIFEXITED(status) ? WEXITSTATUS(status) : 1000;
  const std::string err = slurp(se);
  INFO("stdout: " << slurp(so) << "\nstderr: " << err);
  CHECK(code == 4);
  CHECK(err.find("dvisim: sweep interrupted by SIGINT: 2 of 2 runs unfinished") != std::string::npos);
  const auto rows = readCsv(o / "runs.csv");
  REQUIRE(rows.size() == 2);
  for (const auto& row : rows) CHECK(row.at("exit_code") == "4");
  for (const char* id : {"000-seed1", "001-seed1"}) {
    INFO(id);
    REQUIRE(fs::is_regular_file(runs / id / "summary.json"));
    CHECK(nlohmann::json::parse(slurp(runs / id / "summary.json"))["status"] == "interrupted");
    CHECK(fs::is_regular_file(runs / id / "checkpoint" / "state.bin"));
    CHECK(slurp(runs / id / "run.log").find("interrupted by SIGINT") != std::string::npos);
    CHECK_FALSE(fs::exists(runs / id / "sweep_done.json"));
  }
  fs::remove_all(d);
}
