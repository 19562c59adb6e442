// `dvisim sweep`: a design of experiments over a scene (the CES machine by default) with replicate seeds.
//
//   dvisim sweep [SCENE] (--grid KEY=v1,v2,... | --grid KEY=lo:hi:n)... [--list FILE] [--seeds N] [--seed-key KEY]
//                [--jobs N] [--out DIR] [--no-plots] [--time T | --steps N] [--dt H] [--backend B] [--threads N]
//                [--solver S] [--iterations N] [--set KEY=VALUE ...]
//
// Every case (setting x seed) is a child `dvisim run` (this binary, /proc/self/exe) into DIR/runs/<case-id>/, its
// output in run.log there; up to --jobs at a time (one per GPU, through CUDA_VISIBLE_DEVICES, when the runs go to
// GPUs). A case whose child exited 0 with a readable summary.json gets the marker sweep_done.json (written
// atomically), and a re-run with the same arguments (DIR/sweep.json) skips it. Outputs: DIR/runs.csv,
// DIR/summary.csv (mean and Student-t 95% half-width per setting), DIR/paired.csv (each setting against the first,
// seed by seed), DIR/sweep_<key>.png (scripts/plot_sweep.py).
// Under `mpirun -np K` (an MPI build) the cases are shared out over the processes, case i to process i mod K, each
// running its share on its host's cores (or GPUs) as above; process 0 writes the design first and the tables last
// from every case's directory under DIR (which the hosts must share).
// The design and the statistics are in sweep.h; docs/SWEEP.md is the user's guide.
#include "sweep.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.h"
#include "ces/ces_config.h"
#include "ces_run.h"
#include "chrono_like/io/input_limits.h"
#include "chrono_like/io/json_check.h"
#include "chrono_like/io/output.h"
#include "chrono_like/io/scene.h"
#include "cli_options.h"
#include "gpu/gpu_factory.h"

extern char** environ;

#ifdef DVISIM_HAVE_MPI
#include "mpi_run.h"
#endif

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using dvi::InputError;
using namespace dvi::sweep;
using Clock = std::chrono::steady_clock;

struct SweepOptions : dvi::RunOverrides {
  std::string scene, list, seeds = "1", seed_key, jobs, out = "dvisim-sweep";
  std::vector<std::string> grids, sets;
  std::string backend = "auto", threads;
  bool no_plots = false;
};

struct Design {
  std::vector<Factor> factors;
  std::vector<Setting> list_rows, settings;
  std::vector<std::string> keys;  // the swept keys, list columns first
  long long seeds = 1;
  std::string seed_key;  // empty: the seed is not set (one replicate of a scene without a seed key)
  bool ces = false;
};

struct Case {
  std::string id;
  size_t setting = 0;
  long long seed = 1;
  fs::path dir;
};

const char* kMarker = "sweep_done.json";

std::string readText(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::ostringstream s;
  s << f.rdbuf();
  return s.str();
}

std::string keyOf(const std::string& assignment) { return trimmed(assignment.substr(0, assignment.find('='))); }

// A CES document's keys may carry the prefix "ces.": compare them without it.
std::string normalKey(const Design& d, std::string k) { return d.ces && k.rfind("ces.", 0) == 0 ? k.substr(4) : k; }

// The swept keys, the fixed --set keys and the seed key are all different.
void checkKeys(const SweepOptions& o, const Design& d) {
  std::set<std::string> swept;
  for (const std::string& k : d.keys) {
    if (!swept.insert(normalKey(d, k)).second) throw InputError("--grid/--list: key " + k + " is swept twice");
    if (!d.seed_key.empty() && normalKey(d, k) == normalKey(d, d.seed_key))
      throw InputError("--grid/--list: key " + k + " is the seed key (set by --seeds)");
  }
  for (const std::string& s : o.sets) {
    if (s.find('=') == std::string::npos) throw InputError("--set " + s + ": expected KEY=VALUE");
    if (swept.count(normalKey(d, keyOf(s)))) throw InputError("--set " + s + ": key " + keyOf(s) + " is also swept");
    if (!d.seed_key.empty() && normalKey(d, keyOf(s)) == normalKey(d, d.seed_key))
      throw InputError("--set " + s + ": the seed key is set by --seeds");
  }
}

Design makeDesign(const SweepOptions& o) {
  Design d;
  d.ces = dvi::ces::isCesScene(o.scene);
  if (!o.list.empty()) {
    d.list_rows =
        parseList(dvi::readRegularFile(o.list, "--list " + o.list, dvi::inputLimits().max_json_bytes), o.list);
    for (const auto& kv : d.list_rows[0]) d.keys.push_back(kv.first);
  }
  for (const std::string& g : o.grids) {
    d.factors.push_back(parseGrid(g));
    d.keys.push_back(d.factors.back().key);
  }
  if (d.keys.empty()) throw InputError("sweep: nothing to sweep (give --grid KEY=... or --list FILE)");
  d.settings = expandDesign(d.list_rows, d.factors);
  d.seeds = dvi::parseInt("--seeds", o.seeds, 1, 1000000);
  d.seed_key = !o.seed_key.empty() ? o.seed_key : d.ces ? "seed" : "";
  if (d.seed_key.empty() && d.seeds > 1)
    throw InputError("--seeds " + o.seeds +
                     ": this scene has no default seed key; name the value to vary with --seed-key "
                     "(e.g. bodies.1.seed for a generator's seed)");
  checkKeys(o, d);
  return d;
}

// The --set list of one case: the fixed overrides, the setting, the seed; CES runs skip their per-run plots.
std::vector<std::string> overrides(const SweepOptions& o, const Design& d, size_t setting, long long seed) {
  std::vector<std::string> v = o.sets;
  bool plots_given = false;
  for (const std::string& s : o.sets) plots_given |= normalKey(d, keyOf(s)) == "output.plots";
  for (const std::string& k : d.keys) plots_given |= normalKey(d, k) == "output.plots";
  if (d.ces && !plots_given) v.push_back("output.plots=false");
  for (const auto& kv : d.settings[setting]) v.push_back(kv.first + "=" + kv.second);
  if (!d.seed_key.empty()) v.push_back(d.seed_key + "=" + std::to_string(seed));
  return v;
}

// Loads the scene with every setting of the design (seed 1), so that an unknown key or a bad value is reported
// before any run starts; checks the pass-through options the same way `dvisim run` does.
void validate(const SweepOptions& o, const Design& d) {
  if (o.backend != "auto" && o.backend != "cpu" && o.backend != "gpu" && o.backend != "bullet")
    throw InputError("unknown backend '" + o.backend + "' (expected auto|cpu|gpu|bullet)");
  if (!o.time.empty() && !o.steps.empty()) throw InputError("--time and --steps are mutually exclusive");
  if (!o.time.empty() && !(dvi::parseReal("--time", o.time) >= 0))
    throw InputError("--time: must be >= 0, got " + o.time);
  if (!o.dt.empty() && !(dvi::parseReal("--dt", o.dt) > 0))
    throw InputError("--dt: the time step must be > 0, got " + o.dt);
  if (!o.steps.empty()) dvi::parseInt("--steps", o.steps, 0, 1LL << 40);
  if (!o.threads.empty()) dvi::parseInt("--threads", o.threads, 0, 4096);
  if (!o.iterations.empty()) dvi::parseInt("--iterations", o.iterations, 0, 1000000);
  if (!o.jobs.empty()) dvi::parseInt("--jobs", o.jobs, 1, 4096);
  // sweep.json records the arguments as JSON text, which must be UTF-8: checked here, not when it is written.
  dvi::jsoncheck::requireUtf8(o.scene, "the scene path");
  dvi::jsoncheck::requireUtf8(o.list, "--list");
  for (const std::string& g : o.grids) dvi::jsoncheck::requireUtf8(g, "--grid");
  for (const std::string& v : o.sets) dvi::jsoncheck::requireUtf8(v, "--set");
  for (size_t i = 0; i < d.settings.size(); ++i) {
    const std::vector<std::string> v = overrides(o, d, i, 1);
    try {
      if (d.ces) {
        std::string origin;
        dvi::ces::parseCesDocument(dvi::ces::loadCesDocument(o.scene, origin), v, origin);
      } else {
        dvi::Scene::load(o.scene, v);
      }
    } catch (const InputError& e) {
      std::string shown;
      for (const auto& kv : d.settings[i]) shown += (shown.empty() ? "" : " ") + kv.first + "=" + kv.second;
      throw InputError("setting " + std::to_string(i) + " (" + shown + "): " + e.what());
    }
  }
}

json settingJson(const Setting& s) {
  json j = json::object();
  for (const auto& kv : s) j[kv.first] = kv.second;
  return j;
}

// The arguments that define the sweep's runs (not --jobs, --out, --no-plots): a resumed sweep must match them.
json argumentsJson(const SweepOptions& o, const Design& d) {
  json rows = json::array();
  for (const Setting& s : d.list_rows) rows.push_back(settingJson(s));
  return {{"scene", o.scene},     {"grid", o.grids},
          {"list", o.list},       {"list_settings", rows},
          {"seeds", d.seeds},     {"seed_key", d.seed_key},
          {"set", o.sets},        {"time", o.time},
          {"steps", o.steps},     {"dt", o.dt},
          {"backend", o.backend}, {"threads", o.threads},
          {"solver", o.solver},   {"iterations", o.iterations}};
}

// Writes DIR/sweep.json, or, when one is there, refuses arguments that differ from the ones it holds.
void recordDesign(const SweepOptions& o, const Design& d, const std::vector<Case>& cases) {
  const json args = argumentsJson(o, d);
  const fs::path path = fs::path(o.out) / "sweep.json";
  if (fs::exists(path)) {
    json old;
    try {
      old = dvi::parseJsonGated(readText(path), path.string()).at("arguments");
    } catch (const std::exception&) {
      throw InputError("--out " + o.out + ": sweep.json is unreadable; use another --out");
    }
    for (auto it = args.begin(); it != args.end(); ++it)
      if (!old.contains(it.key()) || old[it.key()] != *it)
        throw InputError("--out " + o.out + " holds a sweep with other arguments: " +
                         (it.key() == "scene" ? std::string("SCENE") : "--" + it.key()) + " was " +
                         (old.contains(it.key()) ? old[it.key()].dump() : "absent") + ", now " + it->dump() +
                         " (repeat the first arguments to resume, or use another --out)");
    return;
  }
  json j = {{"arguments", args}, {"keys", d.keys}, {"seed_key", d.seed_key}, {"seeds", d.seeds}};
  j["factors"] = json::array();
  for (const Factor& f : d.factors) j["factors"].push_back({{"key", f.key}, {"values", f.values}});
  j["settings"] = json::array();
  for (const Setting& s : d.settings) j["settings"].push_back(settingJson(s));
  j["cases"] = json::array();
  for (const Case& c : cases) j["cases"].push_back({{"id", c.id}, {"setting", c.setting}, {"seed", c.seed}});
  dvi::writeFileAtomic(path.string(), j.dump(2) + "\n");
}

// The GPUs the runs go to (ids for CUDA_VISIBLE_DEVICES): none for --backend cpu|bullet or without a usable device.
// This process's place among the processes sharing the sweep (mpirun), and among those on its host.
struct Share {
  int rank = 0, size = 1;
  int host_rank = 0, host_size = 1;
};

Share processShare() {
  Share s;
#ifdef DVISIM_HAVE_MPI
  s.rank = mpiRank();
  s.size = mpiProcesses();
  s.host_rank = mpiHostRank();
  s.host_size = mpiHostProcesses();
#endif
  return s;
}

std::vector<std::string> gpuDevices(const std::string& backend) {
  if (backend == "cpu" || backend == "bullet" || !dvi::gpuAvailable()) return {};
  std::vector<std::string> ids;
  if (const char* v = std::getenv("CUDA_VISIBLE_DEVICES")) {
    for (const std::string& t : split(v, ','))
      if (!t.empty()) ids.push_back(t);
  } else {
    std::error_code ec;
    size_t n = 0;
    for (auto it = fs::directory_iterator("/proc/driver/nvidia/gpus", ec); !ec && it != fs::directory_iterator(); ++it)
      ++n;
    for (size_t i = 0; i < n; ++i) ids.push_back(std::to_string(i));
  }
  if (ids.empty()) ids.push_back("0");
  return ids;
}

std::vector<std::string> childArgs(const SweepOptions& o, const Design& d, const Case& c, const std::string& threads) {
  std::vector<std::string> a = {"dvisim", "run"};
  if (!o.scene.empty()) a.push_back(o.scene);
  a.insert(a.end(), {"--out", c.dir.string()});
  for (const std::string& s : overrides(o, d, c.setting, c.seed)) a.insert(a.end(), {"--set", s});
  const std::pair<const char*, std::string> pass[] = {{"--time", o.time},
                                                      {"--steps", o.steps},
                                                      {"--dt", o.dt},
                                                      {"--backend", o.backend},
                                                      {"--threads", threads},
                                                      {"--solver", o.solver},
                                                      {"--iterations", o.iterations}};
  for (const auto& p : pass)
    if (!p.second.empty()) a.insert(a.end(), {p.first, p.second});
  return a;
}

// Starts `args` (argv[0] replaced by this binary) with stdout and stderr to `log`, stdin from /dev/null.
pid_t spawnChild(const std::vector<std::string>& args, const fs::path& log, const std::string& gpu) {
  std::vector<char*> argv;
  for (const std::string& s : args) argv.push_back(const_cast<char*>(s.c_str()));
  argv.push_back(nullptr);
  std::vector<std::string> env_store;
  // The MPI launcher's variables stay behind: a run started by a sweep under mpirun is a plain process of its own.
  auto launcher = [](const std::string& v) {
    for (const char* p : {"OMPI_", "PMIX_", "PMI_", "OPAL_", "HYDRA_", "MPI_LOCALNRANKS", "MPI_LOCALRANKID"})
      if (v.rfind(p, 0) == 0) return true;
    return false;
  };
  for (char** e = environ; *e; ++e) {
    const std::string v = *e;
    if (launcher(v) || (!gpu.empty() && v.rfind("CUDA_VISIBLE_DEVICES=", 0) == 0)) continue;
    env_store.push_back(v);
  }
  if (!gpu.empty()) env_store.push_back("CUDA_VISIBLE_DEVICES=" + gpu);
  std::vector<char*> envp;
  for (std::string& s : env_store) envp.push_back(s.data());
  envp.push_back(nullptr);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&fa, 1, 2);
  pid_t pid = 0;
  const int rc = posix_spawn(&pid, "/proc/self/exe", &fa, nullptr, argv.data(), envp.data());
  posix_spawn_file_actions_destroy(&fa);
  if (rc != 0) throw std::runtime_error("cannot start " + args[0] + " run: " + std::strerror(rc));
  return pid;
}

bool finished(const Case& c) {
  return fs::is_regular_file(c.dir / kMarker) && fs::is_regular_file(c.dir / "summary.json");
}

// After a child exits: the marker when it exited 0 with a readable summary.json. Returns the exit code (1 for a
// child that exited 0 without a readable summary).
int recordExit(const Case& c, int status, double wall) {
  const int code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  if (code != 0) return code;
  if (!json::accept(readText(c.dir / "summary.json"))) {
    std::fprintf(stderr, "dvisim: %s exited 0 without a readable summary.json\n", c.id.c_str());
    return 1;
  }
  dvi::writeFileAtomic((c.dir / kMarker).string(), json{{"exit_code", 0}, {"wall_s", wall}}.dump() + "\n");
  return 0;
}

struct Slots {
  int jobs = 1;
  std::vector<std::string> gpus;  // slot k runs on gpus[k % size]; empty: CPU
  std::string child_threads;      // --threads of each child
};

// The host's cores and GPUs shared out over the sweep's processes on it (sh): each takes cores / host processes, and
// the GPUs whose position is its host rank modulo the host processes (all of them when there are fewer GPUs).
Slots planSlots(const SweepOptions& o, const Share& sh) {
  Slots s;
  s.gpus = gpuDevices(o.backend);
  if (sh.host_size > 1 && int(s.gpus.size()) >= sh.host_size) {
    std::vector<std::string> mine;
    for (size_t k = 0; k < s.gpus.size(); ++k)
      if (int(k) % sh.host_size == sh.host_rank) mine.push_back(s.gpus[k]);
    s.gpus = mine;
  }
  const int cores = std::max(1, int(std::thread::hardware_concurrency()) / std::max(1, sh.host_size));
  s.jobs = !o.jobs.empty()  ? int(dvi::parseInt("--jobs", o.jobs, 1, 4096))
           : s.gpus.empty() ? cores
                            : int(s.gpus.size());
  // The runs together use the cores once (a GPU run's host side too): cores / jobs threads each unless --threads.
  s.child_threads = !o.threads.empty() ? o.threads : std::to_string(std::max(1, cores / s.jobs));
  return s;
}

// The running children by job slot (0: none), so that a sweep stopped by SIGINT or SIGTERM stops its runs too
// instead of leaving them to write into DIR after it is gone. The handler passes the signal on and sets
// g_stopped; the sweep starts no more runs, waits for the running ones (each checkpoints and writes its results
// with status "interrupted", exit code 4), writes its tables and exits with code 4.
volatile sig_atomic_t g_child[4096];
volatile sig_atomic_t g_stopped = 0;

void stopChildren(int sig) {
  g_stopped = sig;
  for (volatile sig_atomic_t& pid : g_child)
    if (pid > 0) ::kill(pid_t(pid), sig);
}

// The log of a running case: beside its directory, which the run replaces as a whole when it ends (ResultDir);
// moved into it as run.log afterwards.
fs::path pendingLog(const Case& c) { return c.dir.parent_path() / ("." + c.id + ".log"); }

void keepLog(const Case& c) {
  std::error_code ec;
  fs::create_directories(c.dir, ec);
  fs::rename(pendingLog(c), c.dir / "run.log", ec);
}

// Runs the unfinished cases, up to s.jobs at a time. Returns the exit code of each case run now (index -> code).
std::map<size_t, int> runCases(const SweepOptions& o, const Design& d, const std::vector<Case>& cases, const Slots& s,
                               const Share& sh) {
  std::vector<size_t> todo;
  size_t share = 0;  // this process's cases (i mod size == rank)
  for (size_t i = 0; i < cases.size(); ++i) {
    if (int(i % size_t(sh.size)) != sh.rank) continue;
    ++share;
    if (!finished(cases[i])) todo.push_back(i);
  }
  const std::string who =
      sh.size > 1 ? "process " + std::to_string(sh.rank) + " of " + std::to_string(sh.size) + ": " : std::string();
  std::printf("%ssweep: %zu settings x %lld seeds = %zu runs%s; %zu already finished, %zu to run, %d at a time%s\n",
              who.c_str(), d.settings.size(), d.seeds, cases.size(),
              sh.size > 1 ? (", " + std::to_string(share) + " of them here").c_str() : "", share - todo.size(),
              todo.size(), s.jobs, s.gpus.empty() ? "" : (" on " + std::to_string(s.gpus.size()) + " GPU(s)").c_str());
  std::fflush(stdout);
  std::map<pid_t, std::pair<size_t, Clock::time_point>> running;  // pid -> (case, start)
  std::vector<int> slot_of(cases.size(), 0), free_slots;
  for (int k = s.jobs - 1; k >= 0; --k) free_slots.push_back(k);
  std::map<size_t, int> codes;
  size_t next = 0, done = 0;
  std::signal(SIGINT, stopChildren);
  std::signal(SIGTERM, stopChildren);
  while ((next < todo.size() && !g_stopped) || !running.empty()) {
    while (next < todo.size() && !free_slots.empty() && !g_stopped) {
      const Case& c = cases[todo[next]];
      // The run replaces c.dir when it ends (its results, or what it has and the status); a failed start keeps
      // what was there. Without the marker it is not taken for finished meanwhile.
      fs::remove(c.dir / kMarker);
      fs::create_directories(c.dir.parent_path());
      const int slot = free_slots.back();
      free_slots.pop_back();
      slot_of[todo[next]] = slot;
      const std::string gpu = s.gpus.empty() ? "" : s.gpus[size_t(slot) % s.gpus.size()];
      const pid_t pid = spawnChild(childArgs(o, d, c, s.child_threads), pendingLog(c), gpu);
      g_child[slot] = pid;
      running[pid] = {todo[next], Clock::now()};
      ++next;
    }
    int status = 0;
    const pid_t pid = ::waitpid(-1, &status, 0);
    if (pid < 0 && errno == EINTR) continue;
    if (pid < 0) throw std::runtime_error(std::string("waitpid: ") + std::strerror(errno));
    const auto it = running.find(pid);
    if (it == running.end()) continue;
    const size_t i = it->second.first;
    const double wall = std::chrono::duration<double>(Clock::now() - it->second.second).count();
    running.erase(it);
    g_child[slot_of[i]] = 0;
    free_slots.push_back(slot_of[i]);
    keepLog(cases[i]);
    codes[i] = recordExit(cases[i], status, wall);
    std::printf("%s[%zu/%zu] %s: %s (%.1f s)\n", who.c_str(), ++done, todo.size(), cases[i].id.c_str(),
                codes[i] == 0 ? "ok" : ("FAILED, exit " + std::to_string(codes[i])).c_str(), wall);
    std::fflush(stdout);
  }
  std::signal(SIGINT, SIG_DFL);
  std::signal(SIGTERM, SIG_DFL);
  return codes;
}

struct Row {
  bool ok = false;
  int exit_code = -1;  // -1: not run by this invocation and not finished
  double wall = NAN;
  std::map<std::string, double> metrics;
};

std::vector<Row> collectRows(const std::vector<Case>& cases, const std::map<size_t, int>& codes) {
  std::vector<Row> rows(cases.size());
  for (size_t i = 0; i < cases.size(); ++i) {
    Row& r = rows[i];
    if (codes.count(i)) r.exit_code = codes.at(i);
    if (!finished(cases[i])) continue;
    try {
      r.wall = dvi::parseJsonGated(readText(cases[i].dir / kMarker), kMarker).at("wall_s").get<double>();
      r.metrics = runMetrics(dvi::parseJsonGated(readText(cases[i].dir / "summary.json"), "summary.json"));
      r.ok = true, r.exit_code = 0;
    } catch (const std::exception&) { r.ok = false; }
  }
  return rows;
}

std::vector<std::string> metricNames(const std::vector<Row>& rows) {
  std::set<std::string> names;
  for (const Row& r : rows)
    for (const auto& kv : r.metrics) names.insert(kv.first);
  return {names.begin(), names.end()};
}

std::string num(double v) { return dvi::benchutil::num(v, "%.10g"); }

void writeRunsCsv(const SweepOptions& o, const Design& d, const std::vector<Case>& cases,
                  const std::vector<Row>& rows) {
  const std::vector<std::string> names = metricNames(rows);
  std::ostringstream s;
  s << "case,setting";
  for (const std::string& k : d.keys) s << "," << dvi::benchutil::csvField(k);
  s << ",seed,status,exit_code,wall_s";
  for (const std::string& n : names) s << "," << dvi::benchutil::csvField(n);
  s << "\n";
  for (size_t i = 0; i < cases.size(); ++i) {
    const Row& r = rows[i];
    s << cases[i].id << "," << cases[i].setting;
    for (const auto& kv : d.settings[cases[i].setting]) s << "," << dvi::benchutil::csvField(kv.second);
    s << "," << cases[i].seed << "," << (r.ok ? "ok" : "failed") << ","
      << (r.exit_code < 0 ? "" : std::to_string(r.exit_code)) << "," << num(r.wall);
    for (const std::string& n : names) s << "," << (r.metrics.count(n) ? num(r.metrics.at(n)) : "");
    s << "\n";
  }
  dvi::writeFileAtomic(o.out + "/runs.csv", s.str());
}

// The header line of a CSV with a row per setting: setting, the swept keys, `fixed`, then NAME<first>,NAME<second>
// for each metric name.
std::string perSettingHeader(const Design& d, const std::string& fixed, const std::vector<std::string>& names,
                             const std::string& first, const std::string& second) {
  std::string s = "setting";
  for (const std::string& k : d.keys) s += "," + dvi::benchutil::csvField(k);
  s += fixed;
  for (const std::string& n : names)
    s += "," + dvi::benchutil::csvField(n) + first + "," + dvi::benchutil::csvField(n) + second;
  return s + "\n";
}

// The first cells of setting k's row in such a CSV: its index and its levels.
std::string settingCells(const Design& d, size_t k) {
  std::string s = std::to_string(k);
  for (const auto& kv : d.settings[k]) s += "," + dvi::benchutil::csvField(kv.second);
  return s;
}

// Per setting: the finished runs' count, then mean and 95% half-width (sweep.h: meanCi) of wall_s and every metric.
void writeSummaryCsv(const SweepOptions& o, const Design& d, const std::vector<Case>& cases,
                     const std::vector<Row>& rows) {
  const std::vector<std::string> names = metricNames(rows);
  std::ostringstream s;
  s << perSettingHeader(d, ",n,wall_s.mean,wall_s.ci95", names, ".mean", ".ci95");
  for (size_t k = 0; k < d.settings.size(); ++k) {
    std::vector<double> wall;
    std::map<std::string, std::vector<double>> vals;
    for (size_t i = 0; i < cases.size(); ++i) {
      if (cases[i].setting != k || !rows[i].ok) continue;
      wall.push_back(rows[i].wall);
      for (const auto& kv : rows[i].metrics) vals[kv.first].push_back(kv.second);
    }
    s << settingCells(d, k);
    const MeanCi w = meanCi(wall);
    s << "," << w.n << "," << num(w.mean) << "," << num(w.half);
    for (const std::string& n : names) {
      const MeanCi m = meanCi(vals[n]);
      s << "," << num(m.mean) << "," << num(m.half);
    }
    s << "\n";
  }
  dvi::writeFileAtomic(o.out + "/summary.csv", s.str());
}

// Per setting after the first and per metric: the paired difference against setting 0, seed by seed (sweep.h:
// pairedDifference): seeds in both, mean difference and its 95% half-width.
void writePairedCsv(const SweepOptions& o, const Design& d, const std::vector<Case>& cases,
                    const std::vector<Row>& rows) {
  const std::vector<std::string> names = metricNames(rows);
  std::vector<std::map<std::string, std::map<int, double>>> by(d.settings.size());  // setting -> metric -> seed
  for (size_t i = 0; i < cases.size(); ++i)
    if (rows[i].ok)
      for (const auto& kv : rows[i].metrics) by[cases[i].setting][kv.first][cases[i].seed] = kv.second;
  std::ostringstream s;
  s << perSettingHeader(d, ",n", names, ".diff", ".ci95");
  for (size_t k = 1; k < d.settings.size(); ++k) {
    s << settingCells(d, k);
    size_t n = 0;
    std::ostringstream cols;
    for (const std::string& m : names) {
      const MeanCi c = pairedDifference(by[0][m], by[k][m]);
      n = std::max(n, c.n);
      cols << "," << num(c.mean) << "," << num(c.half);
    }
    s << "," << n << cols.str() << "\n";
  }
  dvi::writeFileAtomic(o.out + "/paired.csv", s.str());
}

// scripts/plot_sweep.py plots the grade and recovery metrics (names containing "grade" or "recovery").
std::string plots(const std::string& out, const std::vector<Row>& rows) {
  for (const std::string& n : metricNames(rows))
    if (n.find("grade") != std::string::npos || n.find("recovery") != std::string::npos)
      return dvi::benchutil::runPlot("plot_sweep.py", out, "sweep_<key>.png");
  return "no plots: no grade or recovery metric to plot";
}

// Process 0 checks DIR and writes the design (sweep.json) before any process starts a run; an error there stops
// every process with it (the others with a pointer to process 0's message).
void prepareShared(const SweepOptions& o, const Design& d, const std::vector<Case>& cases, const Share& sh) {
  std::exception_ptr failed;
  if (sh.rank == 0) try {
      dvi::benchutil::prepareOutDir(o.out, ".sweep-probe");
      fs::remove(fs::path(o.out) / ".sweep-probe");
      recordDesign(o, d, cases);
    } catch (...) {
      if (sh.size == 1) throw;
      failed = std::current_exception();
    }
#ifdef DVISIM_HAVE_MPI
  if (mpiBroadcast(failed ? 1 : 0) != 0) {
    if (failed) std::rethrow_exception(failed);
    throw dvi::InputError("the sweep's output directory: see process 0's message");
  }
#endif
}

// Every process's exit codes of the cases it ran, on process 0 (index -> code); after all have finished.
std::map<size_t, int> gatherCodes(const std::map<size_t, int>& mine, const Share& sh) {
  if (sh.size == 1) return mine;
#ifdef DVISIM_HAVE_MPI
  std::vector<long long> flat;
  for (const auto& [i, c] : mine) flat.insert(flat.end(), {(long long)i, (long long)c});
  mpiBarrier();
  const std::vector<long long> all = mpiGatherToRoot(flat);
  std::map<size_t, int> codes;
  for (size_t k = 0; k + 1 < all.size(); k += 2) codes[size_t(all[k])] = int(all[k + 1]);
  return codes;
#else
  return mine;
#endif
}

int runSweep(const SweepOptions& o) {
  const Design d = makeDesign(o);
  validate(o, d);
  const Share sh = processShare();
  std::vector<Case> cases;
  for (size_t i = 0; i < d.settings.size(); ++i)
    for (long long seed = 1; seed <= d.seeds; ++seed) {
      const std::string id = caseId(i, d.settings.size(), seed);
      cases.push_back({id, i, seed, fs::path(o.out) / "runs" / id});
    }
  prepareShared(o, d, cases, sh);
  const Slots slots = planSlots(o, sh);
  const std::map<size_t, int> codes = gatherCodes(runCases(o, d, cases, slots, sh), sh);
  if (sh.rank != 0) return g_stopped ? 4 : 0;  // process 0 tabulates every case and answers for the sweep
  const std::vector<Row> rows = collectRows(cases, codes);
  writeRunsCsv(o, d, cases, rows);
  writeSummaryCsv(o, d, cases, rows);
  if (d.settings.size() > 1) writePairedCsv(o, d, cases, rows);
  size_t failed = 0;
  for (size_t i = 0; i < cases.size(); ++i)
    if (!rows[i].ok) {
      ++failed;
      std::fprintf(stderr, "dvisim: run %s failed (exit %d), log: %s\n", cases[i].id.c_str(), rows[i].exit_code,
                   (cases[i].dir / "run.log").c_str());
    }
  std::printf("results: %s/ (sweep.json, runs.csv, summary.csv, paired.csv, runs/)\n", o.out.c_str());
  if (!o.no_plots) std::printf("%s\n", plots(o.out, rows).c_str());
  if (g_stopped) {
    std::fflush(stdout);
    std::fprintf(stderr,
                 "dvisim: sweep interrupted by %s: %zu of %zu runs unfinished; rerun the same command to finish them\n",
                 g_stopped == SIGINT ? "SIGINT" : "SIGTERM", failed, cases.size());
    return 4;
  }
  if (failed) std::fprintf(stderr, "dvisim: error: %zu of %zu runs failed\n", failed, cases.size());
  return failed ? 1 : 0;
}

}  // namespace

std::function<int()> addSweepCommand(CLI::App& app) {
  auto o = std::make_shared<SweepOptions>();
  CLI::App* cmd = app.add_subcommand("sweep",
                                     "Design of experiments: run a scene (the CES machine by default) over "
                                     "a grid or list of settings with replicate seeds; statistics and plots");
  cmd->add_option("scene", o->scene, "Scene file (.json, a CES document or a plain scene); default: the CES machine");
  dvi::addRepeatable(cmd, "--grid", o->grids, "KEY=v1,v2,... or KEY=lo:hi:n (repeatable: full factorial)");
  cmd->add_option("--list", o->list, "CSV of settings: a header of keys, one row per setting");
  cmd->add_option("--seeds", o->seeds, "Replicates per setting, seeds 1..N (default 1)");
  cmd->add_option("--seed-key", o->seed_key, "Scene key the seed goes to (default: seed for a CES document)");
  cmd->add_option("--jobs", o->jobs, "Runs at a time (default: one per GPU, else one per core)");
  cmd->add_option("--out", o->out, "Output directory (default dvisim-sweep)");
  cmd->add_flag("--no-plots", o->no_plots, "Do not write the sweep_<key>.png plots");
  dvi::addRunOverrides(cmd, *o, " (each run)");
  cmd->add_option("--backend", o->backend, "auto|cpu|gpu|bullet (default auto)");
  cmd->add_option("--threads", o->threads, "OpenMP threads of each run (default: cores / jobs)");
  dvi::addRepeatable(cmd, "--set", o->sets, "A fixed override KEY=VALUE for every run (repeatable)");
  return [o] { return runSweep(*o); };
}
