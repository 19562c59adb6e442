#include "run_checkpoint.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <system_error>

#include <nlohmann/json.hpp>

#include <btBulletDynamicsCommon.h>

#include "chrono_like/base/checksum.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/base/errors.h"
#include "chrono_like/io/input_limits.h"
#include "chrono_like/io/output.h"
#include "chrono_like/io/scene.h"
#include "chrono_like/system.h"

namespace runckpt {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr uint64_t kManifestBytes = 1 << 20;
constexpr int kManifestDepth = 8;

std::string sceneChecksum(const dvi::Scene& scene) {
  if (scene.source.empty() || scene.source[0] == '<') return "none";
  const std::string bytes = dvi::readRegularFile(scene.source, scene.source, uint64_t(1) << 32);
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", (unsigned long long)dvi::fnv1a64(bytes.data(), bytes.size()));
  return hex;
}

std::string manifestText(int processes, int64_t step, double time, double dt, size_t bodies, const dvi::Scene& scene) {
  json m;
  m["format"] = "dvisim-mpi-checkpoint";  // the name of the one format of scene runs, single process or not
  m["version"] = 1;
  m["processes"] = processes;
  m["step"] = step;
  m["time"] = time;
  m["dt"] = dt;
  m["bodies"] = bodies;
  m["scene"] = scene.source;
  m["scene_checksum"] = sceneChecksum(scene);
  return m.dump(2, ' ', false, json::error_handler_t::replace) + "\n";
}

void writeSingle(const dvi::System& sys, const dvi::Scene& scene, const std::string& cdir) {
  const dvi::BodyArrays& b = sys.bodies();
  dvi::CheckpointPiece p;
  std::vector<int32_t> all;
  for (size_t i = 0; i < b.count(); ++i) {
    all.push_back(int32_t(i));
    if (b.flags[i] & dvi::kBodyFixed) continue;  // fixed bodies never move: the scene has them
    p.ids.push_back(int32_t(i));
    p.states.push_back(dvi::MotionState{b.pos[i], b.rot[i], b.vel[i], b.omega[i]});
  }
  p.impulses = sys.contactImpulsesOf(all);
  fs::create_directories(cdir);
  dvi::writeFileAtomic(cdir + "/piece_p0.bin", dvi::encodePiece(p), dvi::Durability::Synced);
  dvi::writeFileAtomic(cdir + "/manifest.json",
                       manifestText(1, sys.stepCount(), sys.time(), double(sys.config().step.dt), b.count(), scene),
                       dvi::Durability::Synced);
}

namespace {

json readManifest(const std::string& cdir, const std::string& where) {
  const std::string text = dvi::readRegularFile(cdir + "/manifest.json", where + "manifest.json", kManifestBytes);
  try {
    return dvi::parseJsonGated(text, where + "manifest.json", kManifestDepth, kManifestBytes);
  } catch (const json::exception& e) { throw dvi::InputError(where + "manifest.json: " + e.what()); }
}

// The manifest's fields, each checked: InputError naming the one that does not fit.
struct Manifest {
  uint64_t processes = 0;
  int64_t step = 0;
  double time = 0;
};
// `where` names the folder (messages about a file in it), `general` the checkpoint (messages about it as a whole).
Manifest checkManifest(const json& m, const std::string& where, const std::string& general, const dvi::Scene& scene,
                       size_t bodies, double dt) {
  auto field = [&](const char* key) -> const json& {
    if (!m.is_object() || !m.contains(key))
      throw dvi::InputError(where + "manifest.json: no \"" + std::string(key) + "\"");
    return m[key];
  };
  if (field("format") != "dvisim-mpi-checkpoint" || field("version") != 1)
    throw dvi::InputError(where + "manifest.json: not a dvisim scene checkpoint of version 1");
  if (!field("bodies").is_number_unsigned() || field("bodies").get<uint64_t>() != bodies)
    throw dvi::InputError(general + "the checkpoint has " + field("bodies").dump() + " bodies, the scene " +
                          std::to_string(bodies));
  if (!field("dt").is_number() || field("dt").get<double>() != dt)
    throw dvi::InputError(general + "the checkpoint ran at dt = " + field("dt").dump() + ", this run at " +
                          std::to_string(dt) + " (give the same --dt)");
  if (field("scene_checksum") != sceneChecksum(scene))
    throw dvi::InputError(general + "the scene file differs from the one the checkpoint ran (" + field("scene").dump() +
                          ")");
  const json &np = field("processes"), &st = field("step"), &tm = field("time");
  if (!np.is_number_unsigned() || np.get<uint64_t>() < 1 || np.get<uint64_t>() > 1000000 || !st.is_number_unsigned() ||
      st.get<uint64_t>() > uint64_t(dvi::inputLimits().max_steps) || !tm.is_number() ||
      !std::isfinite(tm.get<double>()))
    throw dvi::InputError(where + "manifest.json: processes, step or time out of range");
  return Manifest{np.get<uint64_t>(), st.get<int64_t>(), tm.get<double>()};
}

}  // namespace

Resumed read(const std::string& cdir, const std::string& what, const std::string& label, const dvi::Scene& scene,
             const std::vector<uint8_t>& flags, double dt) {
  const std::string where = what + ": " + label;
  // DIR/checkpoint/ is "the checkpoint"; a periodic one beside DIR is named
  const std::string general = what + ": " + (label == "checkpoint/" ? "" : label + ": ");
  const Manifest m = checkManifest(readManifest(cdir, where), where, general, scene, flags.size(), dt);
  Resumed r;
  r.step = m.step;
  r.time = m.time;
  r.states.resize(flags.size());
  r.present.assign(flags.size(), 0);
  for (uint64_t q = 0; q < m.processes; ++q) {
    const std::string name = "piece_p" + std::to_string(q) + ".bin";
    const dvi::CheckpointPiece p = dvi::decodePiece(
        dvi::readRegularFile(cdir + "/" + name, where + name, uint64_t(1) << 40), where + name, flags.size());
    for (size_t i = 0; i < p.ids.size(); ++i) {
      const int32_t id = p.ids[i];
      if (r.present[size_t(id)] || (flags[size_t(id)] & dvi::kBodyFixed))
        throw dvi::InputError(where + name + ": body " + std::to_string(id) + " twice, or a fixed body");
      r.present[size_t(id)] = 1;
      r.states[size_t(id)] = p.states[i];
    }
    r.impulses.insert(r.impulses.end(), p.impulses.begin(), p.impulses.end());
  }
  for (size_t id = 0; id < flags.size(); ++id)
    if (!r.present[id] && !(flags[id] & (dvi::kBodyFixed | dvi::kBodyKinematic)))
      throw dvi::InputError(general + "dynamic body " + std::to_string(id) + " is in no piece");
  // one entry a key for the warm start (a distributed run's pieces may list a contact again: the first stays)
  std::stable_sort(r.impulses.begin(), r.impulses.end(),
                   [](const dvi::ContactImpulse& a, const dvi::ContactImpulse& b) { return a.key < b.key; });
  r.impulses.erase(
      std::unique(r.impulses.begin(), r.impulses.end(),
                  [](const dvi::ContactImpulse& a, const dvi::ContactImpulse& b) { return a.key == b.key; }),
      r.impulses.end());
  return r;
}

namespace {

// The step a checkpoint folder's manifest names and its scene checksum; -2 where it has no manifest.json, -1 where
// that does not read (read() then reports the problem, should locate pick it for want of another).
int64_t manifestStep(const std::string& cdir, std::string* checksum) {
  std::error_code ec;
  if (!fs::exists(cdir + "/manifest.json", ec)) return -2;
  try {
    const json m = readManifest(cdir, "");
    if (!m.is_object() || !m.contains("step") || !m["step"].is_number_unsigned()) return -1;
    if (checksum)
      *checksum = m.contains("scene_checksum") && m["scene_checksum"].is_string() ? m["scene_checksum"] : "";
    return m["step"].get<int64_t>();
  } catch (const std::exception&) { return -1; }
}

}  // namespace

std::string locate(const std::string& dir, const std::string& checksum, std::string* label) {
  if (dir.empty()) return "";
  std::string best, best_label;
  int64_t best_step = -2;
  auto consider = [&](const fs::path& cdir, const std::string& name) {
    std::string sum;
    const int64_t step = manifestStep(cdir.string(), &sum);
    if (step > best_step && (checksum.empty() || sum == checksum))
      best = cdir.string(), best_label = name, best_step = step;
  };
  consider(fs::path(dir) / "checkpoint", "checkpoint/");
  std::error_code ec;
  fs::path target = fs::absolute(fs::path(dir), ec).lexically_normal();
  if (!target.has_filename()) target = target.parent_path();
  const std::string prefix = "." + target.filename().string() + ".tmp-";
  for (fs::directory_iterator it(target.parent_path(), ec), end; !ec && it != end; it.increment(ec)) {
    const std::string run = it->path().filename().string();
    std::error_code e2;  // a folder that vanishes or does not read is skipped, the search goes on
    if (run.rfind(prefix, 0) != 0 || !fs::is_directory(it->path() / "checkpoints", e2)) continue;
    for (fs::directory_iterator c(it->path() / "checkpoints", e2), cend; !e2 && c != cend; c.increment(e2))
      if (c->path().filename().string().rfind("step_", 0) == 0)
        consider(c->path(), (fs::path(run) / "checkpoints" / c->path().filename()).string() + "/");
  }
  if (label) *label = best_label;
  return best;
}

bool isSceneCheckpoint(const std::string& dir) { return !locate(dir, "").empty(); }

void restore(dvi::System& sys, const Resumed& r) {
  dvi::BodyArrays& b = sys.mutableBodies();
  if (b.count() != r.states.size())
    throw dvi::InputError("restore: " + std::to_string(r.states.size()) + " states for " + std::to_string(b.count()) +
                          " bodies");
  for (size_t i = 0; i < b.count(); ++i) {
    if (!r.present[i]) continue;
    const dvi::MotionState& s = r.states[i];
    b.pos[i] = s.pos, b.rot[i] = s.rot, b.vel[i] = s.vel, b.omega[i] = s.omega;
  }
  sys.markHostDirty();
  std::vector<uint64_t> keys;
  std::vector<dvi::real> gamma;
  std::vector<dvi::Vec3> normals;
  for (const dvi::ContactImpulse& c : r.impulses) {
    keys.push_back(c.key);
    gamma.insert(gamma.end(), c.gamma, c.gamma + 3);
    normals.push_back(c.normal);
  }
  if (sys.config().solver.warm_start) sys.setWarmStart(std::move(keys), std::move(gamma), std::move(normals));
  sys.setClock(r.time, r.step);
}

Resumed readResume(const std::string& dir, const dvi::Scene& scene, const dvi::SystemConfig& cfg, int64_t steps,
                   std::string& folder, bool say) {
  const std::string what = "--resume " + dir;
  std::string label;
  folder = locate(dir, sceneChecksum(scene), &label);
  if (folder.empty()) folder = locate(dir, "", &label);  // another scene's: read() says so
  if (folder.empty())
    throw dvi::InputError(what +
                          ": no checkpoint there (checkpoint/manifest.json, or the periodic checkpoints of a "
                          "run killed while it wrote " +
                          dir + ")");
  const std::vector<btRigidBody*>& bodies = scene.bodies();
  std::vector<uint8_t> flags;
  for (size_t i = 0; i < bodies.size(); ++i)
    flags.push_back(dvi::bodyDescForSystem(bodies[i], i, cfg.step.gravity).flags);
  Resumed r = read(folder, what, label, scene, flags, double(cfg.step.dt));
  if (steps <= r.step)
    throw dvi::InputError("--steps " + std::to_string(steps) + ": the checkpoint in " + dir + " is at step " +
                          std::to_string(r.step) + " already (--steps counts from the start of the run)");
  if (say)
    std::printf("resuming from %s (step %lld)\n",
                (label.rfind("checkpoint/", 0) == 0 ? dir + "/" + label : label).c_str(), (long long)r.step);
  return r;
}

bool finalCheckpoint(dvi::System& sys, const dvi::Scene& scene, const Periodic& periodic, const std::string& cdir,
                     bool failed, const std::string& resumed_from) {
  std::error_code ec;
  sys.syncToHost();
  const dvi::BodyArrays& b = sys.bodies();
  for (size_t i = 0; !failed && i < b.count(); ++i)
    failed = !dvi::isFinite(b.pos[i]) || !dvi::isFinite(b.vel[i]) || !dvi::isFinite(b.omega[i]);
  bool saved = false;
  try {
    if (!failed) {
      writeSingle(sys, scene, cdir);
      saved = true;
    } else if (!periodic.newest().empty()) {
      fs::rename(periodic.newest(), cdir);
      saved = true;
    } else if (!resumed_from.empty()) {
      fs::copy(resumed_from, cdir, fs::copy_options::recursive);
      saved = true;
    }
  } catch (const std::exception&) {
    if (!failed) throw;  // the run's own failure is the one to report
  }
  periodic.clear();
  return saved;
}

void forgetKilledRun(const std::string& resumed_from, const std::string& out) {
  if (resumed_from.empty()) return;
  const fs::path cdir = fs::path(resumed_from).lexically_normal();
  // .NAME.tmp-PID-K/checkpoints/step_N: a killed run's folder, beside `out` and named after it
  const fs::path run = cdir.parent_path().parent_path();
  if (cdir.parent_path().filename() != "checkpoints") return;
  std::error_code ec;
  const fs::path target = fs::absolute(fs::path(out), ec).lexically_normal();
  const std::string prefix = "." + target.filename().string() + ".tmp-";
  if (run.filename().string().rfind(prefix, 0) != 0 || !fs::equivalent(run.parent_path(), target.parent_path(), ec))
    return;
  fs::remove_all(run, ec);
}

std::string Periodic::name(int64_t step) const {
  char b[40];
  std::snprintf(b, sizeof b, "step_%012lld", (long long)step);
  return b;
}

std::string Periodic::begin(int64_t step, bool make) const {
  const std::string tmp = dir_ + "/." + name(step) + ".tmp";
  if (make) {
    std::error_code ec;
    fs::remove_all(tmp, ec);  // a folder left by a run killed while writing it
    fs::create_directories(tmp);
  }
  return tmp;
}

void Periodic::commit(int64_t step) {
  // The older ones go first, all but the newest; then the new one goes in place. So at most two are there at any
  // moment, and a run killed in between still leaves the newest complete one.
  const std::string final_dir = dir_ + "/" + name(step), tmp = begin(step, false);
  std::error_code ec;
  std::vector<std::string> entries;
  for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec))
    if (it->path().string() != tmp) entries.push_back(it->path().string());
  std::sort(entries.begin(), entries.end());
  bool kept = false;
  for (auto it = entries.rbegin(); it != entries.rend(); ++it) {
    if (!kept && fs::path(*it).filename().string().rfind("step_", 0) == 0) {
      kept = true;  // the newest complete one before this
      continue;
    }
    fs::remove_all(*it, ec);  // older ones, and temporary folders a killed writer left
  }
  fs::rename(tmp, final_dir);  // throws filesystem_error (exit code 1) on failure
  dvi::syncDirectory(dir_);    // the rename on the disk too (the files in it were synced when written)
}

std::string Periodic::newest() const {
  std::string best;
  std::error_code ec;
  for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string leaf = it->path().filename().string();
    if (leaf.rfind("step_", 0) == 0 && it->path().string() > best) best = it->path().string();
  }
  return best;
}

void Periodic::clear() const {
  std::error_code ec;
  fs::remove_all(dir_, ec);
}

}  // namespace runckpt
