// dvisim_dropin_corpus [--examples A,B] [--frames N] [--repeat N] [--threads N] [--check] [--record] [--out FILE]
//                      [--bodies]
//
// Bullet's own example programs (bench/dropin_corpus/third_party/bullet3_examples/, bullet3 at 6c888f4, unmodified)
// run on stock Bullet and on the drop-in world, changed only in the line that constructs the world
// (docs/DROP_IN.md, "Bullet's example programs"). Each example runs once per world in this process: its
// CreateFunc, initPhysics and `--frames` calls (300) of its own stepSimulation(1/60), one thread each
// (OMP_NUM_THREADS=1 for the drop-in; Bullet's world is single-threaded). Printed per example: whether it ran or
// the exact error that stopped it, the largest joint error of the locked axes over the frames (stock and ours),
// a hinge locked by setLimit(lo, lo), the bodies' final positions against stock's (mean and largest distance,
// mean height along the example's up axis, the vehicle chassis' position and yaw), bodies asleep, ms per frame
// and the ratio; the geometric mean of the ratios. Everything but the time comes from the first run of each;
// `--repeat` (3) runs stock and ours that many times in alternation and keeps each one's lowest mean ms per
// frame (the examples keep some state in function statics, the same in both modules, so a repeated run may
// animate differently from the first). Per constraint, a table of its errors; `--bodies` prints each body's final
// position (stderr).
//
// --check exits 1 when an example fails a check of issue 37's "Done when" that is not in kExpectedFailures
// (listed with its numbers): ran without refusal; joints within 3x stock's error or 5 mm / 5 mrad; a locked
// hinge within 5 mrad; a vehicle's chassis within 0.5 m and 5 degrees of stock's; a pile's mean height within
// 5 cm of stock's. Timing is printed, never checked. --record writes the table to
// bench/results/dropincorpus_<cpu>_<date>.md (device, commit, date), --out to FILE. Bad options: exit 2.
#include <dlfcn.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "bench_text.h"  // slug, utcNow, writeFile
#include "corpus_api.h"

namespace {

using dvi::benchutil::slug;
using dvi::benchutil::utcNow;
using dvi::benchutil::writeFile;

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Checks of an example that fail today because of the engine (not the harness), each with the reason; --check
// reports them as XFAIL and does not fail on them (an XPASS says the entry can go). docs/DROP_IN.md lists them.
const std::map<std::string, std::string> kExpectedFailures = {
    {"RollingFrictionDemo: pile height",
     "the 125 bodies end 5.0 cm above stock's mean height at frame 300 (bound 5 cm; 4.4 cm at rest after 600 "
     "frames; over four starts 1-3 mm apart our piles rest 3-5 cm above Bullet's, docs/DROP_IN.md)"},
};

const double kPi = 3.14159265358979323846;

struct Options {
  std::vector<std::string> examples;
  int frames = 300, repeat = 3;
  std::string threads = "1";
  bool check = false, record = false, bodies = false;
  std::string out;
  std::string load;  // the load average when the run began
};

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> v;
  std::stringstream in(s);
  for (std::string item; std::getline(in, item, ',');)
    if (!item.empty()) v.push_back(item);
  return v;
}

int positiveInt(const std::string& opt, const std::string& v) {
  char* end = nullptr;
  const long n = std::strtol(v.c_str(), &end, 10);
  if (v.empty() || *end || n < 1 || n > 1000000) throw UsageError(opt + " " + v + ": expected a positive integer");
  return int(n);
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw UsageError(a + ": a value is required");
      return argv[++i];
    };
    if (a == "--examples")
      o.examples = split(value());
    else if (a == "--frames")
      o.frames = positiveInt(a, value());
    else if (a == "--threads")
      o.threads = std::to_string(positiveInt(a, value()));
    else if (a == "--repeat")
      o.repeat = positiveInt(a, value());
    else if (a == "--check")
      o.check = true;
    else if (a == "--record")
      o.record = true;
    else if (a == "--bodies")
      o.bodies = true;
    else if (a == "--out")
      o.out = value();
    else
      throw UsageError("unknown option " + a + " (see the head of bench/dropin_corpus/harness/corpus_main.cpp)");
  }
  return o;
}

std::string exeDir() {
  char buf[4096];
  const ssize_t n = readlink("/proc/self/exe", buf, sizeof buf - 1);
  if (n <= 0) return ".";
  std::string p(buf, size_t(n));
  return p.substr(0, p.find_last_of('/'));
}

struct Module {
  corpus::RunFn run = nullptr;
  std::vector<std::string> examples;
};

Module load(const std::string& file) {
  void* h = dlopen(file.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!h) throw std::runtime_error(std::string("cannot load ") + file + ": " + dlerror());
  Module m;
  m.run = reinterpret_cast<corpus::RunFn>(dlsym(h, "dvisim_corpus_run"));
  auto names = reinterpret_cast<const char* (*)()>(dlsym(h, "dvisim_corpus_examples"));
  if (!m.run || !names) throw std::runtime_error(file + ": not a corpus module");
  m.examples = split(names());
  return m;
}

// --- comparison ---------------------------------------------------------------------------------------------

struct Comparison {
  std::string example;
  corpus::RunResult stock, ours;
  double body_mean = NAN, body_max = NAN;  // distance of each dynamic body from its stock position (m)
  double height = NAN;                     // mean height of the dynamic bodies, ours - stock (m)
  double chassis_pos = NAN, chassis_yaw = NAN;
  int sleeping_stock = 0, sleeping_ours = 0, dynamic = 0;
  double ratio = NAN;
  std::vector<std::string> failed, xfailed, xpassed;
};

bool isVehicle(const std::string& e) { return e == "ForkLiftDemo" || e == "Hinge2Vehicle"; }
bool isPile(const std::string& e) {
  return e == "BasicDemo" || e == "RollingFrictionDemo" || e == "Planar2D" || e == "KinematicRigidBodyExample";
}

double dist(const corpus::BodyState& a, const corpus::BodyState& b) {
  return std::sqrt(std::pow(a.pos[0] - b.pos[0], 2) + std::pow(a.pos[1] - b.pos[1], 2) +
                   std::pow(a.pos[2] - b.pos[2], 2));
}

// Heading of a body about the up axis: its local z (the vehicles' forward axis) projected on the ground plane.
double yaw(const corpus::BodyState& b, int up) {
  const int u = (up + 1) % 3, v = (up + 2) % 3;
  return std::atan2(b.rot[3 * v + 2], b.rot[3 * u + 2]);
}

double meanHeight(const corpus::RunResult& r) {
  double s = 0;
  int n = 0;
  for (const auto& b : r.bodies)
    if (b.mass > 0) s += b.pos[r.up_axis], ++n;
  return n ? s / n : NAN;
}

void compareBodies(Comparison& c) {
  const auto &s = c.stock.bodies, &o = c.ours.bodies;
  for (const auto& b : s) c.sleeping_stock += b.sleeping, c.dynamic += b.mass > 0;
  for (const auto& b : o) c.sleeping_ours += b.sleeping;
  c.height = meanHeight(c.ours) - meanHeight(c.stock);
  if (s.size() != o.size()) return;
  double sum = 0, mx = 0;
  int n = 0, heaviest = -1;
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i].mass <= 0) continue;
    const double d = dist(s[i], o[i]);
    sum += d, mx = std::max(mx, d), ++n;
    if (heaviest < 0 || s[i].mass > s[size_t(heaviest)].mass) heaviest = int(i);
  }
  if (n) c.body_mean = sum / n, c.body_max = mx;
  if (isVehicle(c.example) && heaviest >= 0) {  // the chassis: 800 kg in both vehicle examples
    c.chassis_pos = dist(s[size_t(heaviest)], o[size_t(heaviest)]);
    double d = yaw(o[size_t(heaviest)], c.stock.up_axis) - yaw(s[size_t(heaviest)], c.stock.up_axis);
    while (d > kPi) d -= 2 * kPi;
    while (d < -kPi) d += 2 * kPi;
    c.chassis_yaw = std::fabs(d) * 180 / kPi;
  }
}

std::string fmt(double v, const char* f = "%.3g") {
  if (std::isnan(v)) return "-";
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

void judge(Comparison& c, const std::string& check, bool ok, const std::string& numbers) {
  const std::string key = c.example + ": " + check;
  const bool expected = kExpectedFailures.count(key) > 0;
  if (!ok && expected)
    c.xfailed.push_back(check + " (" + numbers + ")");
  else if (!ok)
    c.failed.push_back(check + " (" + numbers + ")");
  else if (expected)
    c.xpassed.push_back(check + " (" + numbers + ")");
}

// Each constraint against the same constraint of stock's run (creation order), over the frames after the first 60
// (where the examples' starting gaps are closed): its error at most 3x stock's or 5 mm / 5 mrad. The numbers are
// the worst constraint's, as a share of its bound.
void judgeJoints(Comparison& c) {
  const auto &s = c.stock.joint_stats, &o = c.ours.joint_stats;
  bool ok = s.size() == o.size();
  double worst = 0;
  std::string numbers = ok ? "" : "constraint count " + std::to_string(o.size()) + " vs " + std::to_string(s.size());
  for (size_t i = 0; i < std::min(s.size(), o.size()); ++i) {
    const double lb = std::max(3 * s[i].lin_settled, 5e-3), ab = std::max(3 * s[i].ang_settled, 5e-3);
    const double share = std::max(o[i].lin_settled / lb, o[i].ang_settled / ab);
    ok = ok && share <= 1;
    if (share > worst)
      worst = share, numbers = "#" + std::to_string(i) + " " + s[i].type + ": " + fmt(o[i].lin_settled * 1e3) +
                               " mm (stock " + fmt(s[i].lin_settled * 1e3) + ", bound " + fmt(lb * 1e3) + "), " +
                               fmt(o[i].ang_settled * 1e3) + " mrad (stock " + fmt(s[i].ang_settled * 1e3) +
                               ", bound " + fmt(ab * 1e3) + ")";
  }
  int over = 0;
  for (size_t i = 0; i < std::min(s.size(), o.size()); ++i)
    over += o[i].lin_settled > std::max(3 * s[i].lin_settled, 5e-3) ||
            o[i].ang_settled > std::max(3 * s[i].ang_settled, 5e-3);
  judge(c, "joints", ok,
        std::to_string(over) + " of " + std::to_string(s.size()) + " over the bound; worst " + numbers);
}

void runChecks(Comparison& c) {
  const auto &s = c.stock, &o = c.ours;
  judge(c, "runs", o.ran, o.ran ? "ran" : "refused: " + o.error);
  if (!o.ran) return;
  if (s.joints > 0) judgeJoints(c);
  if (s.locked_hinges > 0)
    judge(c, "locked hinge", o.locked_hinge <= 5e-3, fmt(o.locked_hinge * 1e3) + " mrad, bound 5");
  if (isVehicle(c.example))
    judge(c, "vehicle", c.chassis_pos <= 0.5 && c.chassis_yaw <= 5,
          "chassis " + fmt(c.chassis_pos) + " m and " + fmt(c.chassis_yaw) + " deg from stock, bounds 0.5 m, 5 deg");
  if (isPile(c.example))
    judge(c, "pile height", std::fabs(c.height) <= 0.05, "mean height " + fmt(c.height, "%+.4f") + " m, bound 5 cm");
}

// --- report -------------------------------------------------------------------------------------------------

std::string cpuName() {
  std::ifstream f("/proc/cpuinfo");
  for (std::string line; std::getline(f, line);)
    if (line.rfind("model name", 0) == 0) {
      std::string v = line.substr(line.find(':') + 1);
      v.erase(0, v.find_first_not_of(' '));
      return v;
    }
  return "unknown CPU";
}

std::string loadAverage() {
  std::ifstream f("/proc/loadavg");
  std::string one, five, fifteen;
  f >> one >> five >> fifteen;
  return one.empty() ? "unknown" : one + " " + five + " " + fifteen + " (1, 5, 15 min)";
}

std::string shellLine(const std::string& cmd) {
  std::string out;
  if (FILE* p = popen(cmd.c_str(), "r")) {
    char b[256];
    while (std::fgets(b, sizeof b, p)) out += b;
    pclose(p);
  }
  while (!out.empty() && (out.back() == '\n' || out.back() == '\r')) out.pop_back();
  return out;
}

std::string commitId() {
  const std::string dir = DVISIM_SOURCE_DIR;
  std::string head = shellLine("git -C '" + dir + "' rev-parse HEAD 2>/dev/null");
  if (head.empty()) return "unknown";
  if (!shellLine("git -C '" + dir + "' status --porcelain --untracked-files=no 2>/dev/null").empty())
    head += " (working tree had uncommitted changes)";
  return head;
}

std::string outcome(const corpus::RunResult& r) {
  return r.ran ? "runs" : "refused at " + r.stage + ": `" + r.error + "`";
}

std::string tableRow(const Comparison& c) {
  const auto &s = c.stock, &o = c.ours;
  std::ostringstream row;
  auto pair = [&](double a, double b, double a2, double b2) {
    return fmt(a * 1e3) + " / " + (o.ran ? fmt(b * 1e3) : "-") + " (" + fmt(a2 * 1e3) + " / " +
           (o.ran ? fmt(b2 * 1e3) : "-") + ")";
  };
  row << "| " << c.example << " | " << (o.ran ? "runs" : "**refused**") << " | " << s.joints << " | "
      << pair(s.joint_lin_settled, o.joint_lin_settled, s.joint_lin, o.joint_lin) << " | "
      << pair(s.joint_ang_settled, o.joint_ang_settled, s.joint_ang, o.joint_ang) << " | "
      << (s.locked_hinges ? fmt(s.locked_hinge * 1e3) + " / " + (o.ran ? fmt(o.locked_hinge * 1e3) : "-") : "-")
      << " | " << fmt(c.body_mean) << " / " << fmt(c.body_max) << " | " << fmt(c.height, "%+.4f") << " | "
      << (isVehicle(c.example) ? fmt(c.chassis_pos) + " m, " + fmt(c.chassis_yaw) + " deg" : "-") << " | "
      << c.sleeping_stock << " / " << (o.ran ? std::to_string(c.sleeping_ours) : "-") << " of " << c.dynamic << " | "
      << fmt(s.deepest * 1e3) << " / " << (o.ran ? fmt(o.deepest * 1e3) : "-") << " | " << fmt(s.ms_per_frame, "%.4f")
      << " | " << (o.ran ? fmt(o.ms_per_frame, "%.4f") : "-") << " | " << (o.ran ? fmt(c.ratio, "%.2fx") : "-") << " |";
  return row.str();
}

// Per constraint of each example with joints: its type and largest errors, stock and ours.
std::string jointDetails(const std::vector<Comparison>& all) {
  std::ostringstream md;
  md << "\n## Joints\n\nPer constraint, in the order the example created it: the largest error of its locked axes "
     << "after the first 60 frames, stock / ours (all frames in brackets); a hinge locked by setLimit(lo, lo) adds "
     << "|angle - lo|.\n\n| example | # | type | frames | mm | mrad |\n| --- | ---: | --- | ---: | --- | --- |\n";
  for (const auto& c : all) {
    if (!c.ours.ran) continue;
    const auto &s = c.stock.joint_stats, &o = c.ours.joint_stats;
    for (size_t i = 0; i < s.size(); ++i) {
      const corpus::JointStats none;
      const corpus::JointStats& q = i < o.size() ? o[i] : none;
      md << "| " << c.example << " | " << i << " | " << s[i].type << " | " << s[i].frames << " / " << q.frames << " | "
         << fmt(s[i].lin_settled * 1e3) << " / " << fmt(q.lin_settled * 1e3) << " (" << fmt(s[i].lin * 1e3) << " / "
         << fmt(q.lin * 1e3) << ") | " << fmt(s[i].ang_settled * 1e3) << " / " << fmt(q.ang_settled * 1e3) << " ("
         << fmt(s[i].ang * 1e3) << " / " << fmt(q.ang * 1e3) << ") |\n";
    }
  }
  return md.str();
}

std::string report(const Options& o, const std::vector<Comparison>& all) {
  std::ostringstream md;
  md << "# Bullet's example programs on the drop-in world (`dvisim_dropin_corpus`)\n\n"
     << "- device: " << cpuName() << " (" << o.threads << " thread each), no GPU used\n"
     << "- host CPU: " << cpuName() << "\n- load average at the start: " << o.load << "\n- commit: " << commitId()
     << "\n- date: " << utcNow("%Y-%m-%dT%H:%M:%SZ")
     << "\n- examples: bullet3 6c888f4 (bench/dropin_corpus/third_party/bullet3_examples), unchanged but for the world "
        "line\n"
     << "- frames: " << o.frames << " calls of each example's stepSimulation(1/60); drop-in at the default "
     << "DviWorldConfig; time: the lowest mean ms per frame of " << o.repeat << " alternating runs\n\n"
     << "Joint errors: the largest error of a locked axis (mm, mrad) over the frames after the first 60, stock / ours, "
     << "and in brackets over all frames (the examples start some joints apart); locked hinge: "
     << "|angle - lo| of hinges with setLimit(lo, lo) (mrad); bodies: distance of each dynamic body from its stock "
     << "position at the end, mean / largest (m); height: mean height of the dynamic bodies along the example's up "
     << "axis, ours - stock (m); chassis: the heaviest body's position and yaw against stock's; asleep: stock / ours"
     << "; deepest: the deepest contact point of the manifolds over the last 60 frames, stock / ours (mm); ms per "
     << "frame: mean wall time of the example's stepSimulation.\n\n"
     << "| example | drop-in | joints | joint error mm | joint error mrad | locked hinge mrad | bodies m | height m"
     << " | chassis | asleep | deepest mm | stock ms | ours ms | ratio |\n"
     << "| --- | --- | ---: | --- | --- | --- | --- | ---: | --- | --- | --- | ---: | ---: | ---: |\n";
  double logsum = 0, worst = 0;
  int n = 0;
  for (const auto& c : all) {
    md << tableRow(c) << "\n";
    if (!std::isnan(c.ratio) && c.ours.ran) logsum += std::log(c.ratio), ++n, worst = std::max(worst, c.ratio);
  }
  const double geomean = n ? std::exp(logsum / n) : NAN;
  md << "\nGeometric mean of the ratios: " << fmt(geomean, "%.2fx") << " over " << n << " examples that ran"
     << " (largest " << fmt(worst, "%.2fx") << ").\n"
     << "Goal (issue 37): at most 3x on every example and 1.5x in geometric mean: "
     << (n == int(all.size()) && worst <= 3 && geomean <= 1.5 ? "MET" : "NOT MET") << ".\n\n";
  for (const auto& c : all) {
    if (!c.ours.ran) md << "- " << c.example << ": " << outcome(c.ours) << "\n";
    for (const auto& f : c.xfailed)
      md << "- " << c.example << " fails " << f
         << "; a known failure: " << kExpectedFailures.at(c.example + ": " + f.substr(0, f.find(" ("))) << "\n";
    for (const auto& f : c.failed) md << "- " << c.example << " FAILS " << f << "\n";
    for (const auto& f : c.xpassed)
      md << "- " << c.example << " passes a check listed as expected to fail: " << f << "\n";
  }
  md << "\n## The drop-in's solver\n\nIterations of the last sub-step of each frame (mean, largest) and the "
     << "sub-steps that ended above the solver's tolerance.\n\n| example | iterations mean | largest | sub-steps "
     << "not converged |\n| --- | ---: | ---: | --- |\n";
  for (const auto& c : all)
    if (c.ours.ran)
      md << "| " << c.example << " | " << fmt(c.ours.iterations_mean, "%.1f") << " | " << c.ours.iterations_max << " | "
         << c.ours.substeps_not_converged << " of " << c.ours.substeps << " |\n";
  md << jointDetails(all);
  return md.str();
}

// --bodies: each body's final position, stock and ours (stderr).
void printBodies(const Comparison& c) {
  const auto &s = c.stock.bodies, &o = c.ours.bodies;
  for (size_t i = 0; i < s.size(); ++i) {
    std::fprintf(stderr, "  %s body %zu mass %g: stock (%.4f, %.4f, %.4f)", c.example.c_str(), i, s[i].mass,
                 s[i].pos[0], s[i].pos[1], s[i].pos[2]);
    if (i < o.size()) std::fprintf(stderr, " ours (%.4f, %.4f, %.4f)", o[i].pos[0], o[i].pos[1], o[i].pos[2]);
    std::fprintf(stderr, "\n");
  }
}

int run(Options o) {
  o.load = loadAverage();
  setenv("OMP_NUM_THREADS", o.threads.c_str(), 1);  // before the drop-in module loads libgomp
  const Module stock = load(exeDir() + "/dropin_corpus_stock.so");
  const Module ours = load(exeDir() + "/dropin_corpus_dvi.so");
  std::vector<std::string> names = o.examples.empty() ? stock.examples : o.examples;
  for (const auto& n : names)
    if (std::find(stock.examples.begin(), stock.examples.end(), n) == stock.examples.end())
      throw UsageError("--examples " + n + ": no such example (have: " + [&] {
        std::string s;
        for (const auto& e : stock.examples) s += (s.empty() ? "" : ", ") + e;
        return s;
      }() + ")");
  std::vector<Comparison> all;
  bool failed = false;
  for (const auto& n : names) {
    Comparison c;
    c.example = n;
    const corpus::RunRequest q{n, o.frames};
    stock.run(&q, &c.stock);
    if (!c.stock.ran) throw std::runtime_error(n + " does not run on stock Bullet: " + c.stock.error);
    ours.run(&q, &c.ours);
    for (int k = 1; k < o.repeat && c.ours.ran; ++k) {  // timing only: the lowest mean of the alternating rounds
      corpus::RunResult again;
      stock.run(&q, &again);
      c.stock.ms_per_frame = std::min(c.stock.ms_per_frame, again.ms_per_frame);
      ours.run(&q, &again);
      c.ours.ms_per_frame = std::min(c.ours.ms_per_frame, again.ms_per_frame);
    }
    compareBodies(c);
    if (c.ours.ran && c.stock.ms_per_frame > 0) c.ratio = c.ours.ms_per_frame / c.stock.ms_per_frame;
    runChecks(c);
    failed = failed || !c.failed.empty();
    std::fprintf(stderr, "%s: %s, %.4f vs %.4f ms per frame\n", n.c_str(), outcome(c.ours).c_str(),
                 c.stock.ms_per_frame, c.ours.ms_per_frame);
    if (o.bodies) printBodies(c);
    all.push_back(c);
  }
  const std::string md = report(o, all);
  std::fputs(md.c_str(), stdout);
  if (!o.out.empty()) writeFile(o.out, md);
  if (o.record) {
    const std::string path = std::string(DVISIM_SOURCE_DIR) + "/bench/results/dropincorpus_" + slug(cpuName()) + "-" +
                             o.threads + "-threads_" + utcNow("%Y%m%d-%H%M%S") + ".md";
    writeFile(path, md);
    std::fprintf(stderr, "recorded %s\n", path.c_str());
  }
  return o.check && failed ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(parse(argc, argv));
  } catch (const UsageError& e) {
    std::fprintf(stderr, "dvisim_dropin_corpus: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "dvisim_dropin_corpus: %s\n", e.what());
    return 1;
  }
}
