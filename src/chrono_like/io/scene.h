// A scene: owned Bullet bodies and shapes plus run settings, read from a JSON scene (our schema,
// scenes/schema/scene.schema.json), from a .bullet file written by Bullet's serializer (read with
// btBulletWorldImporter), or the embedded default (a granular pile of mixed shapes in a box).
//
// Bullet stays the source of bodies and shapes: the scene builds btRigidBody/btCollisionShape objects,
// and the engine imports them with importBullet (bullet/bullet_import.h); the Bullet peer steps the same ones.
//
// Every bad input throws dvi::InputError with a one-line message naming the file, the key path and the
// value (unknown keys, wrong types, non-finite numbers, negative mass, non-positive dimensions, unknown
// shape types, missing/empty/truncated/foreign files, unknown extensions).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "chrono_like/base/math.h"
#include "chrono_like/system.h"

class btRigidBody;
class btCollisionShape;
class btMotionState;
class btBulletWorldImporter;

namespace dvi {

// Run settings of a scene (JSON "settings"). The engine's settings are parsed straight into `system` (the
// keys dt, gravity, solver, max_iterations, tolerance, storage, warm_start, recovery_rel, min_bounce_speed,
// friction_combine,
// envelope_rel, collision, speculative, mpr_manifold, threads; docs/ARCHITECTURE.md, "Configuration", lists the
// field of each); the run's own (how long, frames, the Bullet peer's) are declared here. Command-line options write into
// the same fields.
struct SceneSettings {
  SystemConfig system;           // the System the scene runs on
  int64_t steps = -1;            // [steps] number of steps; -1: from `time`
  real time = real(1);           // [s] simulated time when steps < 0
  int frames = 0;                // VTK frames to write
  int64_t checkpoint_every = 0;  // [steps] a checkpoint every N steps while the run goes (0: at its end only)
  real bullet_length_scale = 0;  // [m per Bullet unit] Bullet peer unit scale; 0: automatic from the body sizes
  int bullet_iterations = 10;    // Bullet peer sequential-impulse iterations

  int64_t stepCount() const;  // steps, or round(time / system.step.dt)

  // The solver's stop (system.solver.max_iterations and tolerance) from the keys iterations, max_iterations and
  // tolerance, in any order: `iterations` alone is a fixed count (tolerance 0); otherwise the solve stops at
  // `tolerance` (default kDefaultTolerance) or after `max_iterations` (default: `iterations` when given, else
  // kDefaultMaxIterations). The scene parser and the command line both set them through these.
  void setIterations(int n);
  void setMaxIterations(int n);
  void setTolerance(real tol);
  int iterations() const { return iterations_; }  // `iterations` as given; -1: not given (the Bullet peer's count)

 private:
  int iterations_ = -1;
  bool max_iterations_given_ = false, tolerance_given_ = false;
};

// The names the scene files and the command line use for the enumerated settings (the inverses of the parser's).
const char* collisionBackendName(CollisionBackend b);  // "native" | "bullet"

class Scene {
 public:
  // Reads SCENE by extension (.json or .bullet); an empty path gives the embedded default scene.
  // `overrides` are KEY=VALUE strings (dotted key paths into the JSON document, e.g. settings.dt=1e-4 or
  // bodies.2.mass=3); .bullet scenes and the defaults accept settings.* keys only. Unknown keys throw.
  static Scene load(const std::string& path, const std::vector<std::string>& overrides = {});
  static Scene fromJsonText(const std::string& text, const std::string& origin,
                            const std::vector<std::string>& overrides = {});
  static Scene fromBulletFile(const std::string& path, const std::vector<std::string>& overrides = {});
  // The bytes of a .bullet file (`origin` names it in messages and gives the scene's name).
  static Scene fromBulletBuffer(const std::string& bytes, const std::string& origin,
                                const std::vector<std::string>& overrides = {});

  // The embedded default scene, as JSON text.
  static const char* defaultSceneJson();

  Scene();
  Scene(Scene&&) noexcept;
  Scene& operator=(Scene&&) noexcept;
  ~Scene();

  // Rigid bodies in scene order (for .bullet files, the importer's rigid-body index).
  const std::vector<btRigidBody*>& bodies() const { return bodies_; }
  const std::vector<std::string>& bodyNames() const { return names_; }
  size_t bodyCount() const { return bodies_.size(); }

  SceneSettings settings;
  std::string source;  // file path, or "<default>"
  std::string name;    // the scene's name (JSON "name", else the file stem)
  std::string format;  // "json" | "bullet" | "default"

  // Applies "settings.KEY=VALUE" to settings (validated as in a scene file).
  void applySettingOverride(const std::string& assignment);

  struct Owned;  // the Bullet objects the scene owns (implementation detail)

 private:
  std::unique_ptr<Owned> owned_;
  std::vector<btRigidBody*> bodies_;
  std::vector<std::string> names_;
  nlohmann::json settings_json_ = nlohmann::json::object();
};

// Parses and validates a JSON "settings" object (key path prefix `path`, e.g. "settings").
SceneSettings parseSceneSettings(const nlohmann::json& j, const std::string& origin,
                                 const std::string& path = "settings");

}  // namespace dvi
