// Small helpers shared by the benches `dvisim bench scaling`, `bench accuracy` and `bench stability`
// (bench/*/bench_*.cpp): output directory checks, CSV/record naming (device slug, commit, date), the
// optional matplotlib plot, and a body list built as Bullet bodies (the one description both our engine, through
// importBullet, and the Bullet peer step).
#pragma once

#include <unistd.h>

#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <chrono>

#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "bench_common.h"
#include "bench_text.h"
#include "chrono_like/base/errors.h"
#include "chrono_like/base/math.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/bullet/bullet_peer.h"
#include "chrono_like/io/output.h"
#include "chrono_like/system.h"
#include "gpu/gpu_factory.h"

namespace dvi::benchutil {

namespace fs = std::filesystem;

// The names a benchmark file uses unqualified once it says `using namespace dvi::benchutil`.
using dvi::InputError;
using dvi::Quat;
using dvi::real;
using dvi::Vec3;
using Clock = std::chrono::steady_clock;

inline std::string trim(std::string s) {
  while (!s.empty() && std::isspace((unsigned char)s.back())) s.pop_back();
  size_t i = 0;
  while (i < s.size() && std::isspace((unsigned char)s[i])) ++i;
  return s.substr(i);
}

// "a,b" "c" -> {a, b, c}: the values of a repeatable comma-separated option, trimmed.
inline std::vector<std::string> splitList(const std::vector<std::string>& in) {
  std::vector<std::string> out;
  for (const std::string& s : in) {
    std::stringstream ss(s);
    std::string tok;
    while (std::getline(ss, tok, ',')) out.push_back(trim(tok));
  }
  return out;
}

// The names given to `option` (all of `known` when none), each checked against `known`.
inline std::vector<std::string> selectNames(const char* option, const std::vector<std::string>& given,
                                            const std::vector<std::string>& known) {
  std::vector<std::string> v = splitList(given);
  if (v.empty()) return known;
  for (const std::string& n : v)
    if (std::find(known.begin(), known.end(), n) == known.end()) {
      std::string list;
      for (const std::string& k : known) list += (list.empty() ? "" : ",") + k;
      throw InputError(std::string(option) + ": unknown name '" + n + "' (expected " + list + ")");
    }
  return v;
}

inline std::string shell(const std::string& cmd) {
  std::string out;
  if (FILE* f = popen(cmd.c_str(), "r")) {
    char buf[256];
    while (fgets(buf, sizeof buf, f)) out += buf;
    pclose(f);
  }
  return trim(out);
}

using dvi::shellQuote;  // chrono_like/io/output.h

inline std::string csvField(std::string s) {
  for (char& c : s)
    if (c == ',' || c == '\n' || c == '"') c = ';';
  return s;
}

// "%.4g" of a finite value, "" otherwise (a missing value in the CSV).
inline std::string num(double v, const char* fmt = "%.6g") {
  if (!std::isfinite(v)) return "";
  char b[64];
  std::snprintf(b, sizeof b, fmt, v);
  return b;
}

inline std::string sourceDir() {
#ifdef DVISIM_SOURCE_DIR
  if (fs::is_directory(DVISIM_SOURCE_DIR)) return DVISIM_SOURCE_DIR;
#endif
  return "";
}

inline std::string exeDir() {
  std::error_code ec;
  const fs::path p = fs::read_symlink("/proc/self/exe", ec);
  return ec ? std::string() : p.parent_path().string();
}

// DVISIM_COMMIT, else `git rev-parse HEAD` of the source tree, else "unknown".
inline std::string commitId() {
  if (const char* c = std::getenv("DVISIM_COMMIT"); c && *c) return c;
  const std::string dir = sourceDir().empty() ? "." : sourceDir();
  std::string head = shell("git -C " + shellQuote(dir) + " rev-parse HEAD 2>/dev/null");
  if (head.empty()) return "unknown";
  if (!shell("git -C " + shellQuote(dir) + " status --porcelain --untracked-files=no 2>/dev/null").empty())
    head += " (working tree had uncommitted changes)";
  return head;
}

// Fewer timed steps when the last warm-up step says the plan would take longer than `budget` seconds.
inline int fitSteps(int steps, double last_step_s, double budget) {
  if (last_step_s <= 0) return steps;
  return std::max(1, std::min(steps, int(budget / last_step_s)));
}

// The results of a benchmark that writes its table twice, OUT/NAME.csv and OUT/NAME.md: both files, a line saying
// where, and with --record the record bench/results/NAME_<device>_<date>.{md,csv} (into results_dir), whose md ends
// naming its csv.
inline void writeCsvMdResults(const BenchBasics& o, const std::string& name, const std::string& device,
                              const std::string& results_dir, const std::string& md, const std::string& csv) {
  writeFile(o.out + "/" + name + ".csv", csv);
  writeFile(o.out + "/" + name + ".md", md);
  std::printf("results: %s/%s.csv, %s.md\n", o.out.c_str(), name.c_str(), name.c_str());
  if (!o.record) return;
  const std::string base = name + "_" + slug(device) + "_" + utcNow("%Y%m%d-%H%M%S");
  writeBenchRecord({results_dir}, base, {{"md", md + "\nRows: " + base + ".csv\n"}, {"csv", csv}}, writeFile);
}

// Creates DIR and checks that `probe_file` can be written in it; InputError (exit 2) otherwise.
inline void prepareOutDir(const std::string& dir, const std::string& probe_file) {
  if (dir.empty()) throw InputError("--out: an output directory is required");
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    throw InputError("--out " + dir + ": cannot create the output directory" + (ec ? " (" + ec.message() + ")" : ""));
  if (::access(dir.c_str(), W_OK) != 0 || !std::ofstream(dir + "/" + probe_file))
    throw InputError("--out " + dir + ": the directory is not writable");
}

inline std::string resultsDir() {
  const std::string d = !sourceDir().empty() ? sourceDir() + "/bench/results" : std::string("bench/results");
  std::error_code ec;
  fs::create_directories(d, ec);
  if (ec || !fs::is_directory(d) || ::access(d.c_str(), W_OK) != 0)
    throw InputError("--record: cannot create or write " + d);
  return d;
}

// Runs scripts/<script> DIR with a python3 that has matplotlib; returns a one-line message (never fails).
inline std::string runPlot(const std::string& script_name, const std::string& dir, const std::string& png) {
  std::vector<std::string> candidates;
  const std::string exe = exeDir();
  if (!exe.empty()) {
    candidates.push_back(exe + "/" + script_name);
    candidates.push_back(exe + "/../share/dvisim/" + script_name);
  }
  if (!sourceDir().empty()) candidates.push_back(sourceDir() + "/scripts/" + script_name);
  std::string script;
  for (const std::string& c : candidates)
    if (fs::is_regular_file(c)) {
      script = c;
      break;
    }
  if (script.empty()) return png + " not written: " + script_name + " not found";
  const std::string python = dvi::pythonWithMatplotlib();
  if (python.empty())
    return png +
           " not written: python3 with matplotlib is missing (Debian: apt-get install python3-matplotlib); the CSV "
           "is complete, plot later with: python3 " +
           script + " " + dir;
  const std::string log = dir + "/" + script_name + ".log";
  const std::string cmd = python + " " + shellQuote(script) + " " + shellQuote(dir) + " >" + shellQuote(log) + " 2>&1";
  if (std::system(cmd.c_str()) != 0) return png + " not written: " + script_name + " failed (see " + log + ")";
  return "plot: " + dir + "/" + png;
}

inline btVector3 bt(Vec3 v) { return btVector3(btScalar(v.x), btScalar(v.y), btScalar(v.z)); }

// Bullet bodies owned together: the scene description both engines step (ours through importBullet).
struct BtBodies {
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btRigidBody>> owned;
  std::vector<btRigidBody*> bodies;
  // mass 0: fixed. Inertia from Bullet's calculateLocalInertia of the shape. Takes ownership of the shape.
  btRigidBody* add(btCollisionShape* shape, double mass, Vec3 pos, real friction, Vec3 vel = {0, 0, 0},
                   Quat rot = {1, 0, 0, 0}) {
    return addShared(own(shape), mass, pos, friction, vel, rot);
  }
  // A shape shared by several bodies: keep ownership once, then add bodies with addShared.
  btCollisionShape* own(btCollisionShape* s) {
    shapes.emplace_back(s);
    return s;
  }
  btRigidBody* addShared(btCollisionShape* shape, double mass, Vec3 pos, real friction, Vec3 vel = {0, 0, 0},
                         Quat rot = {1, 0, 0, 0}) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) shape->calculateLocalInertia(btScalar(mass), inertia);
    btRigidBody::btRigidBodyConstructionInfo info(btScalar(mass), nullptr, shape, inertia);
    info.m_startWorldTransform.setOrigin(bt(pos));
    info.m_startWorldTransform.setRotation(
        btQuaternion(btScalar(rot.x), btScalar(rot.y), btScalar(rot.z), btScalar(rot.w)));
    info.m_friction = btScalar(friction);
    owned.emplace_back(new btRigidBody(info));
    btRigidBody* b = owned.back().get();
    b->setLinearVelocity(bt(vel));
    b->setActivationState(DISABLE_DEACTIVATION);
    bodies.push_back(b);
    return b;
  }
};

// One engine stepping a list of Bullet bodies: our System (CPU or GPU) or the Bullet peer. Body i is the i-th
// Bullet body for both.
struct Runner {
  virtual ~Runner() = default;
  virtual void step() = 0;  // throws SolverError etc.; step_seconds() is its wall time
  virtual void sync() {}    // before reading states (a device backend copies them to the host)
  virtual Vec3 pos(size_t i) const = 0;
  virtual Quat rot(size_t i) const = 0;
  virtual Vec3 vel(size_t i) const = 0;
  virtual Vec3 omega(size_t i) const = 0;
  virtual std::string name() const = 0;  // "cpu", "gpu", "bullet"
  virtual std::string device() const = 0;
  double last_step_s = 0;
};

struct OursRunner : Runner {
  std::unique_ptr<System> sys;
  std::vector<int> ids;
  OursRunner(const std::vector<btRigidBody*>& bodies, const SystemConfig& cfg, bool gpu)
      : sys(gpu ? makeGpuSystem(cfg) : std::make_unique<System>(cfg)), ids(importBullet(*sys, bodies)) {}
  void step() override {
    const auto t0 = std::chrono::steady_clock::now();
    sys->step();
    last_step_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
  void sync() override { sys->syncToHost(); }
  Vec3 pos(size_t i) const override { return sys->bodies().pos[size_t(ids[i])]; }
  Quat rot(size_t i) const override { return sys->bodies().rot[size_t(ids[i])]; }
  Vec3 vel(size_t i) const override { return sys->bodies().vel[size_t(ids[i])]; }
  Vec3 omega(size_t i) const override { return sys->bodies().omega[size_t(ids[i])]; }
  std::string name() const override { return sys->backendName(); }
  std::string device() const override { return sys->deviceName(); }
};

struct BulletRunner : Runner {
  BulletPeerSettings settings;
  std::unique_ptr<BulletPeer> peer;
  BulletRunner(const std::vector<btRigidBody*>& bodies, const BulletPeerSettings& s)
      : settings(s), peer(std::make_unique<BulletPeer>(bodies, s)) {}
  void step() override {
    const auto t0 = std::chrono::steady_clock::now();
    peer->step();
    last_step_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
  Vec3 pos(size_t i) const override { return peer->position(i); }
  Quat rot(size_t i) const override { return peer->rotation(i); }
  Vec3 vel(size_t i) const override { return peer->velocity(i); }
  Vec3 omega(size_t i) const override { return peer->angularVelocity(i); }
  std::string name() const override { return "bullet"; }
  std::string device() const override {
    char b[160];
    std::snprintf(b, sizeof b, "Bullet %d.%02d btDiscreteDynamicsWorld, sequential impulse %d it, 1 thread, length x%g",
                  btGetVersion() / 100, btGetVersion() % 100, settings.solver_iterations,
                  double(settings.length_scale));
    return b;
  }
};

inline bool finite3(Vec3 v) {
  return std::isfinite(double(v.x)) && std::isfinite(double(v.y)) && std::isfinite(double(v.z));
}

}  // namespace dvi::benchutil
