// The Bullet 3 OpenCL rows of `dvisim bench scaling`: the measurement, the child process that runs it and the
// hidden `dvisim bench bullet3-worker` subcommand (bench_scaling_bullet3.h).
#include "scaling/bench_scaling_bullet3.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <vector>

#include "bench_common.h"
#include "bench_util.h"
#include "scaling/scaling_scenes.h"

namespace {

using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

double secondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

std::string oneLine(std::string s) {
  for (char& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  return s;
}

// The outcome as key=value lines, and back.
std::string outcomeText(const Bullet3Outcome& r) {
  std::ostringstream o;
  o.precision(17);
  o << "status=" << oneLine(r.status) << "\ndevice=" << oneLine(r.device) << "\nbodies=" << r.bodies
    << "\nwarmup=" << r.warmup << "\nsteps=" << r.steps << "\nsetup_s=" << r.setup_s << "\nms=" << r.ms
    << "\ncontacts=" << r.contacts << "\nmax_penetration=" << r.max_penetration << "\n";
  return o.str();
}

bool parseOutcome(const std::string& path, Bullet3Outcome& r) {
  std::ifstream f(path);
  std::map<std::string, std::string> kv;
  std::string line;
  while (std::getline(f, line)) {
    const size_t eq = line.find('=');
    if (eq != std::string::npos) kv[line.substr(0, eq)] = line.substr(eq + 1);
  }
  for (const char* k :
       {"status", "device", "bodies", "warmup", "steps", "setup_s", "ms", "contacts", "max_penetration"})
    if (!kv.count(k)) return false;
  try {
    r.status = kv["status"];
    r.device = kv["device"];
    r.bodies = std::stol(kv["bodies"]);
    r.warmup = std::stoi(kv["warmup"]);
    r.steps = std::stoi(kv["steps"]);
    r.setup_s = std::stod(kv["setup_s"]);
    r.ms = std::stod(kv["ms"]);
    r.contacts = std::stod(kv["contacts"]);
    r.max_penetration = std::stod(kv["max_penetration"]);
  } catch (const std::exception&) { return false; }
  return !r.status.empty();
}

// The last line of the log that says something (not the OpenCL compiler's "N warnings generated.").
std::string lastLogLine(const std::string& path) {
  std::ifstream f(path);
  std::string line, last;
  while (std::getline(f, line)) {
    line = dvi::benchutil::trim(line);
    if (!line.empty() && line.find("generated.") == std::string::npos) last = line;
  }
  if (last.size() > 200) last = last.substr(0, 200) + "...";
  return last.empty() ? "the log is empty" : "last log line: " + last;
}

struct WorkerOptions {
  std::string scene = "pile", device = "gpu", cache_dir, result;
  long n = 1000;
  int warmup = 3, steps = 10;
  double budget = 30;
};

int runWorker(const WorkerOptions& o) {
  Bullet3Job job;
  job.scene = o.scene;
  job.n = o.n;
  job.warmup = o.warmup;
  job.steps = o.steps;
  job.budget = o.budget;
  job.device = dvi::bench::parseOpenClDeviceType(o.device);
  job.cache_dir = o.cache_dir;
  const Bullet3Outcome r = runBullet3(job);
  const std::string text = outcomeText(r);
  std::printf("%s", text.c_str());
  std::fflush(stdout);
  if (!o.result.empty()) dvi::benchutil::writeFile(o.result, text);
  return 0;
}

}  // namespace

Bullet3Outcome runBullet3(const Bullet3Job& job) {
  using namespace dvi::bench;
  Bullet3Outcome r;
  try {
    if (job.n < 1 || job.warmup < 0 || job.steps < 1 || !(job.budget > 0))
      throw dvi::InputError("bullet3 job: n and steps must be >= 1, warmup >= 0, budget > 0");
    const SceneSpec spec = makeSceneSpec(job.scene, job.n);
    Bullet3PeerSettings settings;
    settings.dt = dvi::real(1e-3);
    settings.length_scale = 100;  // centimetres, as the Bullet 2 peer (bullet3_peer.h says why)
    settings.device = job.device;
    settings.kernel_cache_dir = job.cache_dir;
    settings.pairs_per_body = spec.name == "mix" ? 32 : 16;  // the mix's largest bodies touch many small ones
    const auto t_setup = Clock::now();
    Bullet3Peer peer(spec, settings);
    r.setup_s = secondsSince(t_setup);
    r.device = peer.description();
    r.bodies = long(spec.bodies.size()) + kStaticBodies;
    double last = 0;
    for (int s = 0; s < job.warmup; ++s) {
      const auto t0 = Clock::now();
      peer.step();
      last = secondsSince(t0);
    }
    r.warmup = job.warmup;
    r.steps = dvi::benchutil::fitSteps(job.steps, last, job.budget);
    double wall = 0;
    for (int s = 0; s < r.steps; ++s) {
      const auto t0 = Clock::now();
      peer.step();  // ends with clFinish: the device's time
      wall += secondsSince(t0);
      r.contacts += double(peer.lastStats().contacts) / r.steps;
    }
    r.ms = wall * 1e3 / r.steps;
    std::vector<dvi::Vec3> pos, vel;
    std::vector<dvi::Quat> rot;
    peer.readBodies(pos, rot, vel);
    for (size_t i = 0; i < pos.size(); ++i)
      if (!dvi::benchutil::finite3(pos[i]) || !dvi::benchutil::finite3(vel[i]))
        throw Bullet3Error("body " + std::to_string(i) +
                           " has a non-finite position or velocity after the timed steps");
    r.max_penetration = double(deepestPenetration(withConvexHulls(spec), pos, rot));  // the shapes Bullet 3 had
  } catch (const std::exception& e) { r.status = std::string("error: ") + e.what(); }
  return r;
}

Bullet3Outcome runBullet3Isolated(const Bullet3Job& job, const std::string& log_path, double timeout_s) {
  Bullet3Outcome r;
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (ec) {
    r.status = "error: cannot find this executable (/proc/self/exe) to start the Bullet 3 worker";
    return r;
  }
  const std::string result = log_path + ".result";
  fs::remove(result, ec);
  const std::vector<std::string> args = {exe.string(),
                                         "bench",
                                         "bullet3-worker",
                                         "--scene",
                                         job.scene,
                                         "--n",
                                         std::to_string(job.n),
                                         "--warmup",
                                         std::to_string(job.warmup),
                                         "--steps",
                                         std::to_string(job.steps),
                                         "--budget",
                                         dvi::benchutil::num(job.budget, "%.17g"),
                                         "--device",
                                         dvi::bench::openClDeviceTypeName(job.device),
                                         "--cache-dir",
                                         job.cache_dir,
                                         "--result",
                                         result};
  std::vector<char*> argv;
  for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  std::fflush(stdout);
  std::fflush(stderr);
  const pid_t pid = fork();
  if (pid < 0) {
    r.status = std::string("error: fork failed: ") + std::strerror(errno);
    return r;
  }
  if (pid == 0) {  // the child: only async-signal-safe calls until exec
    const int fd = open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd >= 0) {
      dup2(fd, STDOUT_FILENO);
      dup2(fd, STDERR_FILENO);
      close(fd);
    }
    execv(argv[0], argv.data());
    _exit(127);
  }
  const auto t0 = Clock::now();
  int wstatus = 0;
  for (;;) {
    const pid_t w = waitpid(pid, &wstatus, WNOHANG);
    if (w == pid) break;
    if (w < 0 && errno != EINTR) {
      r.status = std::string("error: waitpid failed: ") + std::strerror(errno);
      return r;
    }
    if (secondsSince(t0) > timeout_s) {
      kill(pid, SIGKILL);
      waitpid(pid, &wstatus, 0);
      r.status = "error: the Bullet 3 worker ran past " + dvi::benchutil::num(timeout_s, "%.0f") +
                 " s and was stopped (" + lastLogLine(log_path) + ", " + log_path + ")";
      return r;
    }
    usleep(20000);
  }
  if (WIFSIGNALED(wstatus)) {
    r.status = "error: the Bullet 3 worker died of signal " + std::to_string(WTERMSIG(wstatus)) + " (" +
               strsignal(WTERMSIG(wstatus)) + "; " + lastLogLine(log_path) + ", " + log_path + ")";
    return r;
  }
  if (!WIFEXITED(wstatus) || WEXITSTATUS(wstatus) != 0) {
    r.status = "error: the Bullet 3 worker exited with code " + std::to_string(WEXITSTATUS(wstatus)) + " (" +
               lastLogLine(log_path) + ", " + log_path + ")";
    return r;
  }
  if (!parseOutcome(result, r)) {
    r = Bullet3Outcome{};
    r.status = "error: the Bullet 3 worker left no result (" + lastLogLine(log_path) + ", " + log_path + ")";
  }
  return r;
}

void registerBenchBullet3Worker(CLI::App& app, BenchRegistry& reg) {
  auto o = std::make_shared<WorkerOptions>();
  CLI::App* cmd = benchCommand(app)->add_subcommand(
      "bullet3-worker", "One Bullet 3 OpenCL configuration of bench scaling (run by it in a child process)");
  cmd->group("");  // hidden from --help: bench scaling starts it
  cmd->add_option("--scene", o->scene, "pile or mix")->check(CLI::IsMember({"pile", "mix"}));
  cmd->add_option("--n", o->n, "Bodies")->check(CLI::Range(1L, 100000000L));
  cmd->add_option("--warmup", o->warmup, "Warm-up steps")->check(CLI::Range(0, 1000000));
  cmd->add_option("--steps", o->steps, "Timed steps at most")->check(CLI::Range(1, 1000000));
  cmd->add_option("--budget", o->budget, "Seconds of timed steps at most")->check(CLI::PositiveNumber);
  cmd->add_option("--device", o->device, "OpenCL device type: gpu, cpu or any")
      ->check(CLI::IsMember({"gpu", "cpu", "any"}));
  cmd->add_option("--cache-dir", o->cache_dir, "Bullet 3's kernel cache (default: under the temp directory)");
  cmd->add_option("--result", o->result, "Write the outcome (key=value lines) to this file too");
  addBenchRunner(reg, cmd, [o] { return runWorker(*o); });
}
