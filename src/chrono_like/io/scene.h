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

// Run settings of a scene (JSON "settings"). Command-line options override them.
struct SceneSettings {
  real dt = real(1e-3);
  int64_t steps = -1;        // number of steps; -1: from `time`
  real time = real(1);       // simulated time when steps < 0
  std::string solver = "apgd";  // jacobi | gs | apgd | bb
  // Solver stop (SolverSettings): -1 = not given. `iterations` alone is a fixed count (no tolerance);
  // otherwise the solve stops at `tolerance` (relative residual; default kDefaultTolerance) or after
  // `max_iterations` (default: `iterations` when given, else kDefaultMaxIterations).
  int iterations = -1;
  int max_iterations = -1;
  real tolerance = -1;
  std::string storage = "auto";  // auto | real | float (APGD's vectors, VectorStorage)
  Vec3 gravity{0, real(-9.81), 0};
  std::string friction_combine = "product";  // product (Bullet's rule) | min | average
  real envelope_rel = real(0.05);
  real recovery_rel = real(10);
  std::string collision = "native";  // native | bullet
  int threads = 0;                   // 0: OpenMP's default
  int frames = 0;                    // VTK frames to write
  bool warm_start = true;
  bool speculative = true;
  bool mpr_manifold = true;
  real bullet_length_scale = 0;      // Bullet peer unit scale; 0: automatic from the body sizes
  int bullet_iterations = 10;        // Bullet peer sequential-impulse iterations

  int64_t stepCount() const;  // steps, or round(time / dt)
};

// Fills a SystemConfig from the settings (solver and friction rule names already validated).
SystemConfig systemConfigFromSettings(const SceneSettings& s);

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
SceneSettings parseSceneSettings(const nlohmann::json& j, const std::string& origin, const std::string& path = "settings");

}  // namespace dvi
