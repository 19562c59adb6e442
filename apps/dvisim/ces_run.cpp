// `dvisim run` for a CES machine (ces_run.h).
#include "ces_run.h"

#include "parse.h"

#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <cstring>
#include <map>
#include <sstream>

#include <nlohmann/json.hpp>

#include "ces/ces_config.h"
#include "ces/feeder.h"
#include "ces/field/field_corona.h"
#include "ces/machine.h"
#include "ces/output/ces_output.h"
#include "ces/output/splitters.h"
#include "chrono_like/base/errors.h"
#include "chrono_like/bullet/bullet_collision_backend.h"
#include "chrono_like/io/input_limits.h"
#include "chrono_like/io/output.h"
#include "chrono_like/io/run_control.h"
#include "chrono_like/io/scene.h"
#include "gpu/gpu_factory.h"

namespace dvi {
namespace ces {

using nlohmann::json;
namespace fs = std::filesystem;

namespace {

using Clock = std::chrono::steady_clock;

// A regular file within the size limit (a FIFO named .json would block the read forever).
std::string readText(const std::string& path, const std::string& what) {
  return readRegularFile(path, what, inputLimits().max_json_bytes, ", not a file");
}

// The size and the nesting are checked before and while the DOM is built (input_limits.h: parseJsonChecked): a
// document nested a million levels deep is refused as the parser meets its 65th level.
json parseJson(const std::string& text, const std::string& origin) {
  if (text.find_first_not_of(" \t\r\n") == std::string::npos) throw InputError(origin + ": file is empty");
  return parseJsonChecked(text, origin);
}

std::string fmt(double x) {
  char b[40];
  std::snprintf(b, sizeof b, "%.17g", x);
  return b;
}

json binsJson(const BinMasses& m) {
  json j;
  for (int bin = 0; bin < 3; ++bin) {
    json k;
    k["metal_kg"] = double(m.fg[size_t(bin)][0]) * kFemtogram;
    k["plastic_kg"] = double(m.fg[size_t(bin)][1]) * kFemtogram;
    k["middling_kg"] = double(m.fg[size_t(bin)][2]) * kFemtogram;
    j[binName(bin)] = k;
  }
  return j;
}

json cellJson(const SplitterCell& c) {
  return json{{"s1_mm", c.s1 * 1e3},
              {"s2_mm", c.s2 * 1e3},
              {"grade_metal", c.grade_metal},
              {"recovery_metal", c.recovery_metal},
              {"grade_plastic", c.grade_plastic},
              {"recovery_plastic", c.recovery_plastic},
              {"middling_fraction", c.middling_fraction},
              {"score", c.score},
              {"meets_targets", c.meets_targets},
              {"bins", binsJson(c.mass)}};
}

// A number, or null when undefined (no particle to average over, no corona model).
json numberOrNull(double x) { return std::isfinite(x) ? json(x) : json(nullptr); }

// Peek's onset field of the static tube (a smooth cylinder of its radius, field_corona.h), and the tube's largest
// surface field over it: >= 1 flags a static electrode that would ionise (docs/CES.md, "Spark-over").
double tubeOnsetField(const CesConfig& cfg) {
  return cfg.tube.enabled ? double(peekOnsetField(real(cfg.tube.diameter / 2), real(cfg.rel_air_density)))
                          : std::nan("");
}
double tubeFieldRatio(const CesMachine& m) { return m.tubeSurfaceField() / tubeOnsetField(m.config()); }

// The metadata a checkpoint records (CesMachine::save): the document as run and the collision backend, the
// configuration a resumed run is compared with (checkResumable).
std::string checkpointMeta(const json& doc, const std::string& collision) {
  return json{{"document", doc}, {"collision", collision}}.dump();
}

// checkpoint/state.bin (checksummed, with the configuration inside) and checkpoint/ces_config.json (the same
// configuration for people to read; a resume refuses it edited).
void writeCheckpoint(const CesMachine& m, const json& doc, const std::string& collision, const std::string& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw std::runtime_error("cannot create " + dir + ": " + ec.message());
  std::ostringstream bin(std::ios::binary);
  m.save(bin, checkpointMeta(doc, collision));
  writeFileAtomic(dir + "/ces_config.json", doc.dump(2) + "\n", Durability::Synced);
  writeFileAtomic(dir + "/state.bin", bin.str(), Durability::Synced);
}

// Leaves of a JSON value by dotted key ("feed.mass_flow_g_s"; array elements by index).
void flatten(const json& v, const std::string& key, std::map<std::string, json>& out) {
  if (v.is_object() && !v.empty()) {
    for (auto it = v.begin(); it != v.end(); ++it) flatten(*it, key.empty() ? it.key() : key + "." + it.key(), out);
  } else if (v.is_array() && !v.empty()) {
    for (size_t i = 0; i < v.size(); ++i) flatten(v[i], key + "." + std::to_string(i), out);
  } else {
    out[key] = v;
  }
}

// Keys of a CES document that a resumed run may change: how long it runs and what it writes. Every other key
// changes the physics of the steps to come (or of the ones already run), and a resume refuses it by name.
bool resumeMayChange(const std::string& key) {
  for (const char* k : {"ces.duration_s", "ces.output", "ces.splitters"}) {
    const size_t n = std::strlen(k);
    if (key.compare(0, n, k) == 0 && (key.size() == n || key[n] == '.')) return true;
  }
  return key.compare(0, 4, "ces.") != 0;  // outside "ces": the name
}

// Refuses a resumed configuration that differs from the checkpoint's in a key that changes the physics.
void checkResumable(const json& before, const json& now, const std::string& collision_before,
                    const std::string& collision) {
  std::map<std::string, json> a, b;
  flatten(before, "", a);
  flatten(now, "", b);
  std::string diff;
  int n = 0;
  auto note = [&](const std::string& key, const std::string& was, const std::string& is) {
    if (++n <= 4) diff += (diff.empty() ? "" : ", ") + key + " (" + was + " -> " + is + ")";
  };
  for (const auto& [k, v] : a) {
    if (resumeMayChange(k)) continue;
    const auto it = b.find(k);
    if (it == b.end())
      note(k, v.dump(), "absent");
    else if (it->second != v)
      note(k, v.dump(), it->second.dump());
  }
  for (const auto& [k, v] : b)
    if (!resumeMayChange(k) && !a.count(k)) note(k, "absent", v.dump());
  if (collision != collision_before) note("--collision", collision_before, collision);
  if (n > 0)
    throw InputError("--resume: the configuration differs from the checkpoint's in " + std::to_string(n) +
                     " setting(s) that change the physics: " + diff + (n > 4 ? ", ..." : "") +
                     " (a resume may change only duration_s, output.* and splitters.*)");
}

// The folder `--resume dir` reads a CES checkpoint from: `dir`, or the temporary folder of a run killed while it
// wrote `dir` (.NAME.tmp-PID-K beside it, whose checkpoint/state.bin is its last periodic checkpoint), whichever
// wrote checkpoint/state.bin last. `label` names it for messages ("" for dir itself).
std::string cesResumeFolder(const std::string& dir, std::string& label) {
  std::error_code ec;
  std::string best = dir;
  label.clear();
  fs::file_time_type newest = fs::last_write_time(dir + "/checkpoint/state.bin", ec);
  if (ec) newest = fs::file_time_type::min();
  fs::path target = fs::absolute(fs::path(dir), ec).lexically_normal();
  if (!target.has_filename()) target = target.parent_path();
  const std::string prefix = "." + target.filename().string() + ".tmp-";
  for (fs::directory_iterator it(target.parent_path(), ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    std::error_code e2;
    const fs::file_time_type t = fs::last_write_time(it->path() / "checkpoint" / "state.bin", e2);
    if (name.rfind(prefix, 0) != 0 || e2 || t <= newest) continue;
    newest = t, best = it->path().string(), label = name + "/";
  }
  return best;
}

}  // namespace

json loadCesDocument(const std::string& scene, std::string& origin) {
  if (scene.empty()) {
    origin = "<default ces machine>";
    return parseJson(defaultCesJson(), origin);
  }
  origin = scene;
  return parseJson(readText(scene, scene), scene);
}

std::string resolveCesBackend(const std::string& requested) {
  if (requested == "bullet")
    throw InputError("--backend bullet: the CES machine runs on the DVI engine only (auto|cpu|gpu)");
  requireOneOf("--backend", requested, {"auto", "cpu", "gpu"});
  return resolveBackend(requested);
}

std::string resolveBackend(const std::string& requested) {
  std::string backend = requested, gpu_name;
  const bool have_gpu = gpuAvailable(&gpu_name);
  if (backend == "auto") {
    backend = have_gpu ? "gpu" : "cpu";
    std::printf("backend: %s (%s)\n", backend.c_str(), have_gpu ? gpu_name.c_str() : "no GPU device");
  }
  if (backend == "gpu" && !have_gpu)
    throw InputError("--backend gpu: no usable GPU device" +
                     (gpu_name.empty() ? std::string() : " (" + gpu_name + ")"));
  return backend;
}

std::unique_ptr<System> makeCesSystem(const CesConfig& cfg, const std::string& backend, int threads,
                                      const std::string& collision) {
  SystemConfig sc;
  sc.step = cfg.step;
  sc.solver = cfg.solver;
  sc.threads = threads;
  sc.collision.backend = collision == "bullet" ? CollisionBackend::Bullet : CollisionBackend::Native;
  sc.collision.friction_combine = FrictionCombine::Product;  // the pair coefficients of ces.friction are for this rule
  // The particle cloud spans the machine (0.8 x 0.6 x 0.3 m) sparsely: a grid of 2^24 bins of 2 mm costs
  // more to scan than the pairs it finds (measured 7.5 ms/step); 2^20 bins of ~5 mm keep every bin sparse.
  sc.collision.broadphase.max_bins = int64_t(1) << 20;
  if (backend == "gpu") return makeGpuSystem(sc, makeBulletCollision);
  return std::make_unique<CheckpointSystem>(sc, makeBulletCollision);
}

void CesRunTotals::add(const CesMachine& m) {
  const StepStats& s = m.system().lastStats();
  ++steps;
  contacts += s.contacts;
  max_contacts = std::max<int64_t>(max_contacts, s.contacts);
  iterations += s.iterations;
  max_penetration = std::fmax(max_penetration, s.max_penetration);
  residual = s.residual;
  drive_torque_sum += m.driveTorque();
  log.add(s);
}

json CesRunTotals::stageNames() const {
  json a = json::array();
  for (int i = 0; i < kStageCount; ++i)
    if (log.ran[size_t(i)]) a.push_back(stageName(StageType(i)));
  return a;
}

json CesRunTotals::stageSeconds() const {
  json o = json::object();
  for (int i = 0; i < kStageCount; ++i)
    if (log.ran[size_t(i)]) o[stageName(StageType(i))] = log.seconds[size_t(i)];
  return o;
}

json massBalanceJson(const MassBalance& bal) {
  json c;
  c["fed_mass_kg"] = double(bal.fed_fg) * kFemtogram;
  c["collected_mass_kg"] = double(bal.collected_fg) * kFemtogram;
  c["in_flight_mass_kg"] = double(bal.in_flight_fg) * kFemtogram;
  c["held_up_mass_kg"] = double(bal.held_up_fg) * kFemtogram;
  c["lost_mass_kg"] = double(bal.lost_fg) * kFemtogram;
  c["fed_particles"] = bal.fed;
  c["collected_particles"] = bal.collected;
  c["in_flight_particles"] = bal.in_flight;
  c["held_up_particles"] = bal.held_up;
  c["lost_particles"] = bal.lost;
  c["balance_closes"] = bal.closes();
  c["mass_unit_kg"] = kFemtogram;
  return c;
}

std::string massBalanceLine(const MassBalance& bal) {
  const double g = kFemtogram * 1e3;
  char b[480];
  std::snprintf(b, sizeof b,
                "fed %.6g g = collected %.6g g + in flight %.6g g + held up %.6g g + lost %.6g g "
                "(%lld = %lld + %lld + %lld + %lld particles)%s",
                double(bal.fed_fg) * g, double(bal.collected_fg) * g, double(bal.in_flight_fg) * g,
                double(bal.held_up_fg) * g, double(bal.lost_fg) * g, (long long)bal.fed, (long long)bal.collected,
                (long long)bal.in_flight, (long long)bal.held_up, (long long)bal.lost,
                bal.closes() ? ", closes exactly" : ", DOES NOT CLOSE");
  return b;
}

SplitterBasis splitterBasis(const CesMachine& m) {
  SplitterBasis basis;
  const CesParticles& p = m.particles();
  for (size_t i = size_t(m.firstParticleBody()); i < p.count(); ++i) {  // a composite as its metal and plastic
    CollectedParticle c{};
    c.kind = m.config().materials[size_t(p.material[i])].kind;
    c.mass_fg = p.mass_fg[i];
    c.metal_mass_fraction = m.compositeMassFraction(i);
    const int64_t metal = c.kind == MaterialKind::Composite ? metalFg(c) : 0;
    basis.fed_fg[size_t(c.kind == MaterialKind::Composite ? MaterialKind::Metal : c.kind)] +=
        c.kind == MaterialKind::Composite ? metal : c.mass_fg;
    if (c.kind == MaterialKind::Composite) basis.fed_fg[size_t(MaterialKind::Plastic)] += c.mass_fg - metal;
  }
  basis.target_conductor = m.config().grade_target_conductor;
  basis.target_nonconductor = m.config().grade_target_nonconductor;
  return basis;
}

json cesMetrics(const CesMachine& m, const SplitterTable& table, const MassBalance& bal) {
  const CesConfig& cfg = m.config();
  const CesParticles& p = m.particles();
  const SplitterCell& best = table.cells[table.best];
  const size_t nm = cfg.materials.size();
  std::vector<int64_t> fed(nm, 0), pinned(nm, 0), binned(nm, 0), col_fg(nm, 0), col_n(nm, 0), positive(nm, 0);
  std::vector<double> x_fg(nm, 0), q_sum(nm, 0), x_pos(nm, 0), fg_pos(nm, 0), x_neg(nm, 0), fg_neg(nm, 0);
  for (size_t i = size_t(m.firstParticleBody()); i < p.count(); ++i) {
    const size_t k = size_t(p.material[i]);
    fed[k] += p.mass_fg[i];
    if (p.flags[i] & kFlagPinned) pinned[k] += p.mass_fg[i];
  }
  // The bin each kind belongs in: metal -> conductor, plastic -> nonconductor, middling and composite -> middling.
  auto ownBin = [](MaterialKind kind) {
    return kind == MaterialKind::Metal     ? kBinConductor
           : kind == MaterialKind::Plastic ? kBinNonconductor
                                           : kBinMiddling;
  };
  for (const CollectedParticle& c : m.collected()) {
    const size_t k = size_t(c.material);
    col_fg[k] += c.mass_fg;
    ++col_n[k];
    x_fg[k] += c.x * double(c.mass_fg);
    const double q = double(p.charge[size_t(c.body)]);
    q_sum[k] += q;
    positive[k] += q > 0;
    (q > 0 ? x_pos : x_neg)[k] += c.x * double(c.mass_fg);  // by charge sign: a conductor's induced one or not
    (q > 0 ? fg_pos : fg_neg)[k] += double(c.mass_fg);
    const int bin = c.x < best.s1 ? kBinNonconductor : c.x < best.s2 ? kBinMiddling : kBinConductor;
    if (bin == ownBin(c.kind)) binned[k] += c.mass_fg;
  }
  auto frac = [](int64_t a, int64_t b) { return b > 0 ? double(a) / double(b) : std::nan(""); };
  json o = json::object();
  for (size_t k = 0; k < nm; ++k) {
    const std::string n = cfg.materials[k].name;
    o[n + ".fed_mass_kg"] = double(fed[k]) * kFemtogram;
    o[n + ".collected_fraction"] = numberOrNull(frac(col_fg[k], fed[k]));
    o[n + ".mean_landing_mm"] = numberOrNull(col_fg[k] > 0 ? 1e3 * x_fg[k] / double(col_fg[k]) : std::nan(""));
    o[n + ".mean_charge_C"] = numberOrNull(col_n[k] > 0 ? q_sum[k] / double(col_n[k]) : std::nan(""));
    o[n + ".positive_charge_fraction"] = numberOrNull(frac(positive[k], col_n[k]));
    o[n + ".mean_landing_q_pos_mm"] = numberOrNull(fg_pos[k] > 0 ? 1e3 * x_pos[k] / fg_pos[k] : std::nan(""));
    o[n + ".mean_landing_q_neg_mm"] = numberOrNull(fg_neg[k] > 0 ? 1e3 * x_neg[k] / fg_neg[k] : std::nan(""));
    o[n + ".recovery"] = numberOrNull(frac(binned[k], fed[k]));
    o["pinned." + n] = numberOrNull(frac(pinned[k], fed[k]));
  }
  o["conductor.grade"] = best.grade_metal;
  o["conductor.recovery"] = best.recovery_metal;
  o["nonconductor.grade"] = best.grade_plastic;
  o["nonconductor.recovery"] = best.recovery_plastic;
  o["middling.mass_fraction"] = best.middling_fraction;
  o["splitters.s1_mm"] = best.s1 * 1e3;
  o["splitters.s2_mm"] = best.s2 * 1e3;
  o["splitters.targets_met"] = table.targets_met ? 1 : 0;
  // The same at the configured splitters (fixed.*): trends over a sweep at fixed splitter positions.
  const SplitterCell fixed = splitterCell(m.collected(), cfg.s1, cfg.s2, splitterBasis(m));
  o["fixed.conductor.grade"] = fixed.grade_metal;
  o["fixed.conductor.recovery"] = fixed.recovery_metal;
  o["fixed.nonconductor.grade"] = fixed.grade_plastic;
  o["fixed.nonconductor.recovery"] = fixed.recovery_plastic;
  o["fixed.middling.mass_fraction"] = fixed.middling_fraction;
  o["holdup.mass_fraction"] = numberOrNull(frac(bal.held_up_fg, bal.fed_fg));
  o["in_flight.mass_fraction"] = numberOrNull(frac(bal.in_flight_fg, bal.fed_fg));
  o["lost.mass_fraction"] = numberOrNull(frac(bal.lost_fg, bal.fed_fg));
  const CoronaInfo ci = m.coronaInfo();
  o["onset_voltage_kV"] = numberOrNull(ci.onset_voltage * 1e-3);
  o["corona_current_uA_per_m"] = numberOrNull(ci.current_per_m * 1e6);
  o["ionised"] = ci.ionised ? 1 : 0;
  o["voltage_kV"] = cfg.voltage * 1e-3;
  o["drum_rpm"] = cfg.drum_rpm;
  o["feed_g_s"] = cfg.feed_mass_flow * 1e3;
  o["feed.monolayer_g_s"] = monolayerMassFlow(cfg) * 1e3;  // feeder.h: the feed that covers the drum once
  o["feed.coverage"] = cfg.feed_mass_flow / monolayerMassFlow(cfg);
  o["sparkover.margin"] = sparkoverMargin(cfg);  // |U| / the uniform-field breakdown voltage of the nearest gap
  o["sparkover.tube_field_ratio"] = numberOrNull(tubeFieldRatio(m));  // tube surface field / its Peek onset field
  return o;
}

bool isCesScene(const std::string& path) {
  if (path.empty()) return true;
  if (fs::path(path).extension() != ".json") return false;
  std::error_code ec;
  // Not a regular file, or too large: the scene loader reports why.
  if (!fs::is_regular_file(path, ec) || fs::file_size(path, ec) > inputLimits().max_json_bytes || ec) return false;
  std::ifstream f(path, std::ios::binary);
  std::ostringstream ss;
  ss << f.rdbuf();
  try {  // too deep: InputError (the file's name and the key path); malformed: the scene loader reports it
    return isCesDocument(parseJsonGated(ss.str(), path));
  } catch (const json::exception&) { return false; }
}

// The machine document of a run and where it came from: a scene file, the embedded default, or (--resume) the one
// the checkpoint was written with (state_bytes: the checkpoint; collision_before: the collision backend it ran with;
// rdir: the folder resumed from; rlabel: its name when it is a killed run's, cesResumeFolder).
struct CesRunInput {
  json doc;
  std::string origin, state_bytes, collision_before, rdir, rlabel;
};

CesRunInput loadCesRunInput(const CesRunOptions& o) {
  CesRunInput in;
  json& doc = in.doc;
  std::string& origin = in.origin;
  std::string &state_bytes = in.state_bytes, &collision_before = in.collision_before;
  std::string &rdir = in.rdir, &rlabel = in.rlabel;
  const bool resume = !o.resume.empty();
  if (resume) {
    if (!o.scene.empty()) throw InputError("--resume " + o.resume + ": give either a scene or --resume, not both");
    rdir = cesResumeFolder(o.resume, rlabel);
    if (!rlabel.empty())
      std::printf("resuming from %s (a run killed while it wrote %s)\n", rlabel.c_str(), o.resume.c_str());
    // The configuration comes from state.bin (checksummed); checkpoint/ces_config.json must be its copy.
    state_bytes =
        readRegularFile(rdir + "/checkpoint/state.bin", "--resume " + o.resume + ": " + rlabel + "checkpoint/state.bin",
                        inputLimits().max_binary_bytes);
    const std::string meta_text = cesCheckpointMeta(state_bytes);
    json meta;
    try {
      meta = parseJsonGated(meta_text, "--resume " + o.resume + ": " + rlabel + "checkpoint/state.bin");
      doc = meta.at("document");
      collision_before = meta.at("collision").get<std::string>();
    } catch (const json::exception&) {
      throw InputError("--resume " + o.resume + ": " + rlabel + "checkpoint/state.bin: corrupt configuration record");
    }
    origin = rdir + "/checkpoint/ces_config.json";
    if (parseJson(readText(origin, "--resume " + o.resume + ": " + rlabel + "checkpoint/ces_config.json"), origin) !=
        doc)
      throw InputError("--resume " + o.resume +
                       ": checkpoint/ces_config.json was edited (it differs from the configuration "
                       "recorded in checkpoint/state.bin; change settings with --set)");
  } else {
    doc = loadCesDocument(o.scene, origin);
  }
  return in;
}

// --dt as a number into the document's ces.time_step_s (the one place the machine's step is set; a checkpoint
// records the document): no round trip through text. A document without a ces object is left to the parser's error.
void setCommandLineStep(const CesRunOptions& o, json& doc) {
  if (o.dt.empty()) return;
  const double dt = parseReal("--dt", o.dt);
  if (!(dt > 0)) throw InputError("--dt: the time step must be > 0, got " + o.dt);
  for (const std::string& s : o.sets)
    if (s.rfind("time_step_s=", 0) == 0 || s.rfind("ces.time_step_s=", 0) == 0)
      throw InputError("--dt and --set " + s.substr(0, s.find('=')) + " are mutually exclusive");
  if (doc.is_object() && doc.contains("ces") && doc["ces"].is_object()) doc["ces"]["time_step_s"] = dt;
}

// The command line's other options as overrides of the document (so that a checkpoint records them).
std::vector<std::string> commandLineSets(const CesRunOptions& o) {
  std::vector<std::string> sets = o.sets;
  if (!o.time.empty()) {
    const double t = parseReal("--time", o.time);
    if (t < 0) throw InputError("--time: must be >= 0, got " + o.time);
    sets.push_back("duration_s=" + fmt(t));
  }
  if (!o.solver.empty()) sets.push_back("solver.type=" + o.solver);
  if (!o.iterations.empty())
    sets.push_back("solver.iterations=" + std::to_string(parseInt("--iterations", o.iterations, 1, 1000000)));
  if (!o.frames.empty()) sets.push_back("output.frames=" + std::to_string(parseInt("--frames", o.frames, 0, 1000000)));
  return sets;
}

// What the steps left: the totals, the stepping time, and how the loop ended.
struct CesLoop {
  CesRunTotals tot;
  double wall = 0;
  std::exception_ptr failure;
  bool interrupted = false, checkpointed = false;
};

// Steps the machine from its step to total: frames at N evenly spaced steps over [0, total], a checkpoint every
// checkpoint_every_s and one at the end, a progress line on a terminal. A step that diverges or fails, or
// SIGINT/SIGTERM, ends the loop (L.failure, L.interrupted).
CesLoop stepCesMachine(CesMachine& m, const CesConfig& cfg, const json& doc, const std::string& collision,
                       const std::string& out, int64_t total, CesFrameWriter& frames) {
  const int64_t first = m.steps();
  CesLoop L;
  CesRunTotals& tot = L.tot;
  double& wall = L.wall;
  std::exception_ptr& failure = L.failure;
  bool &interrupted = L.interrupted, &checkpointed = L.checkpointed;
  std::vector<int64_t> frame_at;
  if (cfg.frames == 1) frame_at.push_back(total);
  for (int k = 0; cfg.frames > 1 && k < cfg.frames; ++k)
    frame_at.push_back(int64_t(std::llround(double(k) * double(total) / double(cfg.frames - 1))));
  // Steps between checkpoints; an interval longer than the run is none before the end (and no overflow).
  const double ckpt_steps = cfg.checkpoint_every > 0 ? std::round(cfg.checkpoint_every / cfg.step.dt) : 0;
  const int64_t ckpt_every = ckpt_steps <= 0              ? 0
                             : ckpt_steps > double(total) ? total + 1
                                                          : std::max<int64_t>(1, int64_t(ckpt_steps));
  const std::string ckpt_dir = out + "/checkpoint";
  size_t next_frame = 0;
  while (next_frame < frame_at.size() && frame_at[next_frame] < first) ++next_frame;
  const bool tty = ::isatty(2);
  const bool host_state = m.system().backendName() == "cpu";  // the bodies are checked for divergence every step
  const auto t0 = Clock::now();
  auto last = t0;
  installStopHandlers();
  try {
    for (int64_t k = first;; ++k) {
      while (next_frame < frame_at.size() && frame_at[next_frame] == k) {
        m.system().syncToHost();
        frames.write(m.time(), m);
        ++next_frame;
      }
      if (k == total) break;
      if (stopRequested()) {
        interrupted = true;
        break;
      }
      const auto s0 = Clock::now();
      try {
        m.step();
      } catch (const SolverError& e) {
        m.system().syncToHost();
        throw SimulationDiverged(divergedMessage(k + 1, m.time(), m.system().bodies(), e.what(), cfg.step.dt));
      }
      if (host_state) checkFiniteState(k + 1, m.time(), m.system().bodies());
      wall += std::chrono::duration<double>(Clock::now() - s0).count();
      tot.add(m);
      if (ckpt_every > 0 && m.steps() % ckpt_every == 0 && m.steps() < total) {
        m.system().syncToHost();
        writeCheckpoint(m, doc, collision, ckpt_dir);
        checkpointed = true;
      }
      const auto now = Clock::now();
      if (tty && (now - last > std::chrono::milliseconds(200) || k + 1 == total)) {
        last = now;
        const double frac = double(k + 1 - first) / double(std::max<int64_t>(1, total - first));
        const double el = std::chrono::duration<double>(now - t0).count();
        const MassBalance b = m.balance();
        std::fprintf(stderr, "\r[%3d%%] t = %.3f s, %lld fed, %lld collected, %lld in flight, ETA %.0f s  ",
                     int(frac * 100), m.time(), (long long)b.fed, (long long)b.collected, (long long)b.in_flight,
                     frac > 0 ? el * (1 - frac) / frac : 0.0);
        std::fflush(stderr);
      }
    }
    if (tty) std::fprintf(stderr, "\r\033[K");
    // The last state (also of an interrupted run): what --resume continues.
    m.system().syncToHost();
    if (m.system().backendName() != "cpu") checkFiniteState(m.steps(), m.time(), m.system().bodies());
    writeCheckpoint(m, doc, collision, ckpt_dir);
    checkpointed = true;
  } catch (...) { failure = std::current_exception(); }
  return L;
}

// Diverged or failed after simulating: what there is (a summary with the status and the error, the last checkpoint;
// that of the run resumed from when this one wrote none) in place of the previous results, then the exception again
// (main() turns it into the exit code).
[[noreturn]] void writeCesFailure(std::exception_ptr failure, const CesRunOptions& o, const CesConfig& cfg,
                                  const CesMachine& m, int64_t first, const CesFrameWriter& frames, bool checkpointed,
                                  const std::string& rdir, ResultDir& rd) {
  const bool resume = !o.resume.empty(), tty = ::isatty(2);
  const std::string out = rd.path(), ckpt_dir = out + "/checkpoint";
  if (tty) std::fprintf(stderr, "\r\033[K");
  const int code = exitCodeFor(failure);
  try {
    std::error_code ec;
    if (!checkpointed && resume) fs::copy(rdir + "/checkpoint", ckpt_dir, fs::copy_options::recursive, ec);
    json summary;
    summary["status"] = runStatusName(code);
    summary["error"] = exceptionMessage(failure);
    summary["exit_code"] = code;
    summary["scene"] = resume ? o.resume : (o.scene.empty() ? "<default>" : o.scene);
    summary["dt"] = cfg.step.dt;
    summary["steps"] = m.steps() - first;
    summary["sim_time"] = m.time();
    summary["frames"] = frames.count();
    summary["checkpoint"] = fs::exists(ckpt_dir + "/state.bin") ? json("checkpoint/") : json(nullptr);
    summary["note"] = "incomplete: the run ended with the error above; checkpoint/ (if any) is the last good state";
    writeSummary(out + "/summary.json", summary);
    rd.commit();
    std::printf("results so far: %s/ (summary.json status \"%s\"%s)\n", rd.out().c_str(), runStatusName(code),
                summary["checkpoint"].is_null() ? "" : ", checkpoint/");
  } catch (...) {}
  std::rethrow_exception(failure);
}

// summary.json of a finished (or interrupted) CES run: the run's keys as a scene run's, and "ces": the mass balance,
// the bins at the configured splitters, the best splitters, the corona, the drive and each material's masses.
json cesRunSummary(const CesRunOptions& o, const json& doc, const CesMachine& m, const CesRunTotals& tot,
                   const std::string& collision, int64_t steps_run, double wall, int frame_count, bool interrupted,
                   const MassBalance& bal, const SplitterTable& table, const BinMasses& at,
                   const SplitterCell& configured) {
  const CesConfig& cfg = m.config();
  const bool resume = !o.resume.empty();
  json summary;
  summary["status"] = interrupted ? "interrupted" : "done";
  summary["scene"] = resume ? o.resume : (o.scene.empty() ? "<default>" : o.scene);
  summary["scene_name"] = doc.contains("name") && doc["name"].is_string() ? doc["name"].get<std::string>() : "ces";
  summary["bodies"] = m.system().bodies().count();
  summary["dt"] = cfg.step.dt;
  summary["steps"] = steps_run;
  summary["threads"] = m.system().effectiveThreads();
  summary["backend"] = m.system().backendName();
  summary["device"] = m.system().deviceName();
  summary["solver"] = solverName(cfg.solver.type);
  summary["collision"] = collision;
  summary["iterations_mean"] = steps_run > 0 ? double(tot.iterations) / double(steps_run) : 0.0;
  summary["residual_final"] = m.system().lastStats().relative_residual;  // relative (solver.h)
  summary["residual_final_abs"] = tot.residual;
  addConvergenceSummary(summary, m.system().convergence(), m.system().config().solver);
  summary["contacts_mean"] = steps_run > 0 ? double(tot.contacts) / double(steps_run) : 0.0;
  summary["max_penetration"] = tot.max_penetration;
  addStageSummary(summary, tot.log);
  summary["sim_time"] = m.time();
  summary["wall_time_s"] = wall;
  summary["ms_per_step"] = steps_run > 0 ? 1000.0 * wall / double(steps_run) : 0.0;
  summary["frames"] = frame_count;
  json c = massBalanceJson(bal);
  c["splitters"] = {{"s1_mm", cfg.s1 * 1e3}, {"s2_mm", cfg.s2 * 1e3}};
  c["bins"] = binsJson(at);
  c["at_splitters"] = cellJson(configured);
  c["best"] = cellJson(table.cells[table.best]);
  c["best"]["targets_met"] = table.targets_met;
  c["grade_targets"] = {{"conductor", cfg.grade_target_conductor}, {"nonconductor", cfg.grade_target_nonconductor}};
  c["metrics"] = cesMetrics(m, table, bal);
  {
    const CoronaInfo ci = m.coronaInfo();
    c["corona"] = {{"ionised", ci.ionised},
                   {"onset_voltage_kV", numberOrNull(ci.onset_voltage * 1e-3)},
                   {"wire_field_on_kV_cm", numberOrNull(ci.wire_field_on * 1e-5)},
                   {"current_uA_per_m", numberOrNull(ci.current_per_m * 1e6)}};
  }
  c["sparkover"] = {{"margin", sparkoverMargin(cfg)},
                    {"tube_surface_field_kV_cm", numberOrNull(m.tubeSurfaceField() * 1e-5)},
                    {"tube_onset_field_kV_cm", numberOrNull(tubeOnsetField(cfg) * 1e-5)},
                    {"tube_in_corona", tubeFieldRatio(m) >= 1}};
  c["voltage_kV"] = cfg.voltage * 1e-3;
  c["splitter_positions"] = cfg.splitter_positions;
  c["splitter_range_mm"] = {cfg.splitter_lo * 1e3, cfg.splitter_hi * 1e3};
  c["splitter_methods_agree"] = true;  // splitterAnalysis throws otherwise
  c["field_model"] = cfg.field_model;
  c["drum_drive"] = m.rheonomicDrive() ? "rheonomic" : "kinematic";
  if (m.rheonomicDrive()) c["drive_torque_mean_Nm"] = steps_run > 0 ? tot.drive_torque_sum / double(steps_run) : 0.0;
  c["forces_on_host"] = m.system().backendName() != "cpu";
  json mats = json::array();
  for (size_t k = 0; k < cfg.materials.size(); ++k) {
    int64_t fed = 0, col = 0;
    for (size_t i = size_t(m.firstParticleBody()); i < m.particles().count(); ++i) {
      if (m.particles().material[i] != int32_t(k)) continue;
      fed += m.particles().mass_fg[i];
      if (m.particles().status[i] == kStatusCollected) col += m.particles().mass_fg[i];
    }
    mats.push_back({{"name", cfg.materials[k].name},
                    {"kind", materialKindName(cfg.materials[k].kind)},
                    {"fed_mass_kg", double(fed) * kFemtogram},
                    {"collected_mass_kg", double(col) * kFemtogram}});
  }
  c["materials"] = mats;
  summary["ces"] = c;
  return summary;
}

// The run's lines: the mass balance, the corona, the bins at the configured splitters and the best splitters.
void printCesResults(const CesMachine& m, const MassBalance& bal, const SplitterTable& table, const BinMasses& at) {
  const CesConfig& cfg = m.config();
  const double g = kFemtogram * 1e3;
  std::printf("mass balance: %s\n", massBalanceLine(bal).c_str());
  if (bal.lost > 0)
    std::fprintf(stderr, "dvisim: warning: %lld particles were lost (left the machine without being collected)\n",
                 (long long)bal.lost);
  const SplitterCell& best = table.cells[table.best];
  {
    const CoronaInfo ci = m.coronaInfo();
    if (cfg.field_model == "corona")
      std::printf("corona: onset %.3g kV, %s, current %.4g uA/m\n", ci.onset_voltage * 1e-3,
                  ci.ionised ? "ionised" : "below onset (Laplace field, no ions)", ci.current_per_m * 1e6);
  }
  std::printf(
      "bins at s1 = %.1f mm, s2 = %.1f mm: metal %.3g/%.3g/%.3g g, plastic %.3g/%.3g/%.3g g "
      "(nonconductor/middling/conductor)\n",
      cfg.s1 * 1e3, cfg.s2 * 1e3, double(at.fg[0][0]) * g, double(at.fg[1][0]) * g, double(at.fg[2][0]) * g,
      double(at.fg[0][1]) * g, double(at.fg[1][1]) * g, double(at.fg[2][1]) * g);
  std::printf(
      "best splitters: s1 = %.1f mm, s2 = %.1f mm (%s grade targets %.2f/%.2f; metal grade %.3f recovery %.3f; "
      "plastic grade %.3f recovery %.3f; middlings %.3f of the feed; recoveries of the fed mass)\n",
      best.s1 * 1e3, best.s2 * 1e3, table.targets_met ? "meets the" : "MISSES the", cfg.grade_target_conductor,
      cfg.grade_target_nonconductor, best.grade_metal, best.recovery_metal, best.grade_plastic, best.recovery_plastic,
      best.middling_fraction);
}

// The command line's choices checked before any work (bullet is refused: the machine runs on the DVI engine).
void checkCesOptions(const CesRunOptions& o) {
  if (o.backend == "bullet")
    throw InputError("--backend bullet: the CES machine runs on the DVI engine only (auto|cpu|gpu)");
  requireOneOf("--backend", o.backend, {"auto", "cpu", "gpu"});
  if (!o.collision.empty()) requireOneOf("--collision", o.collision, {"native", "bullet"});
  if (!o.solver.empty()) requireOneOf("--solver", o.solver, {"jacobi", "gs", "apgd", "bb"});
  if (!o.time.empty() && !o.steps.empty()) throw InputError("--time and --steps are mutually exclusive");
}

// The configuration as run: the document with the command line's overrides (--steps as a duration); in.doc becomes
// the document as run (what a checkpoint records), and a resumed run's must match its checkpoint's.
CesConfig configureCesRun(const CesRunOptions& o, CesRunInput& in, const std::string& collision) {
  json& doc = in.doc;
  std::vector<std::string> sets = commandLineSets(o);
  const json doc_before = doc;
  setCommandLineStep(o, doc);
  CesConfig cfg = parseCesDocument(doc, sets, in.origin);
  if (!o.steps.empty()) {
    const long long n = parseInt("--steps", o.steps, 0, 1LL << 40);
    cfg.duration = double(n) * cfg.step.dt;
    sets.push_back("duration_s=" + fmt(cfg.duration));
  }
  for (const std::string& s : sets) applyCesOverride(doc, s);  // the document as run
  if (!o.resume.empty()) checkResumable(doc_before, doc, in.collision_before, collision);
  return cfg;
}

// The run's first lines: the machine, its field, drive, voltage and feed, the steps to run.
void printCesStart(const CesMachine& m, const std::string& origin, int64_t total, bool resume) {
  const CesConfig& cfg = m.config();
  const int64_t first = m.steps();
  std::printf("ces machine: %s, %s field, drum %s at %g rpm, U = %g kV, feed %g g/s for %g s; %lld steps of %g s%s\n",
              origin.c_str(), cfg.field_model.c_str(), m.rheonomicDrive() ? "rheonomic" : "kinematic", cfg.drum_rpm,
              cfg.voltage * 1e-3, cfg.feed_mass_flow * 1e3, cfg.feed_duration, (long long)(total - first), cfg.step.dt,
              resume ? (" (resumed at t = " + fmt(m.time()) + " s)").c_str() : "");
  if (m.system().backendName() != "cpu" && !m.deviceParticles())
    std::printf("note: the %s backend applies the CES forces on the host (bodies synced every step)\n",
                m.system().backendName().c_str());
  std::fflush(stdout);
  if (tubeFieldRatio(m) >= 1)
    std::fprintf(stderr,
                 "dvisim: warning: the static tube's surface field %.1f kV/cm reaches Peek's onset field %.1f kV/cm of "
                 "its radius: it would ionise (spark-over risk, docs/CES.md \"Spark-over\")\n",
                 m.tubeSurfaceField() * 1e-5, tubeOnsetField(cfg) * 1e-5);
}

int runCesMachine(const CesRunOptions& o) {
  checkCesOptions(o);
  CesRunInput in = loadCesRunInput(o);
  json& doc = in.doc;
  const std::string &origin = in.origin, &rdir = in.rdir, &rlabel = in.rlabel;
  std::string& state_bytes = in.state_bytes;
  const bool resume = !o.resume.empty();
  const std::string collision = o.collision.empty() ? "native" : o.collision;
  const CesConfig cfg = configureCesRun(o, in, collision);
  const int threads = o.threads.empty() ? 0 : int(parseInt("--threads", o.threads, 0, 4096));
  const int64_t total = checkedStepCount(cfg.duration, cfg.step.dt, origin + ": ces.duration_s");
  checkFrameCount(cfg.frames, total, o.frames.empty() ? origin + ": ces.output.frames" : "--frames");
  const std::string backend = resolveCesBackend(o.backend);
  // Everything is written into a fresh directory beside --out, put in its place at the end (ResultDir).
  ResultDir rd(o.out);
  const std::string out = rd.path();
  std::unique_ptr<System> sys = makeCesSystem(cfg, backend, threads, collision);
  CesMachine m(cfg, *sys);
  if (resume) {
    std::istringstream in(std::move(state_bytes), std::ios::binary);
    m.load(in);
    if (m.steps() > total)
      throw InputError("--resume: the checkpoint is at t = " + fmt(m.time()) +
                       " s, beyond duration_s = " + fmt(cfg.duration));
  }
  const int64_t first = m.steps();
  printCesStart(m, origin, total, resume);

  CesFrameWriter frames(out);
  if (cfg.frames > 0) writeFileAtomic(out + "/machine.vtp", cesMachineVtp(m));
  const CesLoop L = stepCesMachine(m, cfg, doc, collision, out, total, frames);
  const CesRunTotals& tot = L.tot;
  const double wall = L.wall;
  const bool interrupted = L.interrupted;
  auto writeFailure = [&](std::exception_ptr failure) {
    writeCesFailure(failure, o, cfg, m, first, frames, L.checkpointed, rdir, rd);
  };
  if (L.failure) writeFailure(L.failure);

  try {
    // Results.
    const MassBalance bal = m.balance();
    if (!bal.closes()) throw std::logic_error("CES mass balance does not close (internal error)");
    const SplitterBasis basis = splitterBasis(m);
    const SplitterTable table =
        splitterAnalysis(m.collected(), cfg.splitter_lo, cfg.splitter_hi, cfg.splitter_positions, basis);
    const BinMasses at = binDirect(m.collected(), cfg.s1, cfg.s2);
    const SplitterCell configured = splitterCell(m.collected(), cfg.s1, cfg.s2, basis);
    const Distribution dist = massDistribution(m.collected(), cfg.histogram_bin);

    const int64_t steps_run = m.steps() - first;
    json summary = cesRunSummary(o, doc, m, tot, collision, steps_run, wall, frames.count(), interrupted, bal, table,
                                 at, configured);
    std::string plots = "disabled (ces.output.plots = false)";

    std::vector<BodyState> state;
    const BodyArrays& b = m.system().bodies();
    for (size_t i = 0; i < b.count(); ++i)
      state.push_back(BodyState{b.pos[i], b.rot[i], b.vel[i], b.omega[i], b.size[i]});
    writeBodiesCsv(out + "/bodies.csv", state);
    writeFileAtomic(out + "/ces_particles.csv", cesParticlesCsv(m));
    writeFileAtomic(out + "/ces_collected.csv", cesCollectedCsv(m));
    writeFileAtomic(out + "/ces_distribution.csv", distributionCsv(dist));
    writeFileAtomic(out + "/ces_splitters.csv", splittersCsv(table));
    writeFileAtomic(out + "/ces_grade_recovery.csv", gradeRecoveryCsv(gradeRecoveryCurve(table)));
    writeSummary(out + "/summary.json", summary);
    if (cfg.plots) {
      const std::string err = cesMakePlots(out);
      plots = err.empty() ? "distribution.png, splitters.png" : err;
      if (!err.empty()) std::fprintf(stderr, "dvisim: warning: %s\n", err.c_str());
      summary["ces"]["plots"] = plots;
      writeSummary(out + "/summary.json", summary);
    }

    printCesResults(m, bal, table, at);
    rd.commit();
    std::error_code ec;  // a killed run that wrote this --out is superseded: its folder goes
    if (!rlabel.empty() && fs::equivalent(rd.out(), fs::absolute(o.resume, ec), ec)) fs::remove_all(rdir, ec);
    std::printf(
        "results: %s/ (summary.json, ces_*.csv, bodies.csv%s%s, checkpoint/), %.1f s wall, %.2f ms/step\n",
        rd.out().c_str(),
        cfg.plots && plots.find("png") != std::string::npos ? ", distribution.png, splitters.png" : "",
        frames.count() ? (", " + std::to_string(frames.count()) + " frames + frames.pvd + machine.vtp").c_str() : "",
        wall, steps_run > 0 ? 1000.0 * wall / double(steps_run) : 0.0);
    const std::string remedy = "raise --set solver.iterations (now " + std::to_string(cfg.solver.max_iterations) + ")";
    const std::string unconverged = convergenceWarning(m.system().convergence(), m.system().config().solver, remedy);
    if (!unconverged.empty()) std::fprintf(stderr, "%s\n", unconverged.c_str());
    if (interrupted) {
      std::fflush(stdout);
      std::fprintf(stderr,
                   "dvisim: interrupted by %s at t = %g s (step %lld of %lld); the results so far and a checkpoint "
                   "(--resume %s) are in %s/\n",
                   stopSignalName(), m.time(), (long long)m.steps(), (long long)total, rd.out().c_str(),
                   rd.out().c_str());
      return kExitInterrupted;
    }
    return 0;
  } catch (...) { writeFailure(std::current_exception()); }
  return kExitFailed;  // not reached: writeFailure rethrows
}

}  // namespace ces
}  // namespace dvi
