// Scenes: JSON (our schema, scenes/schema/scene.schema.json), .bullet files and the embedded default.
// See scene.h. Everything here validates before it builds: a bad input is an InputError naming the
// file, the key path and the value, never a crash inside Bullet.
#include "chrono_like/io/scene.h"

#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/io/bullet_file_check.h"
#include "chrono_like/io/input_limits.h"
#include "chrono_like/io/json_check.h"
#include "chrono_like/base/random.h"

#include <btBulletDynamicsCommon.h>
#include <BulletCollision/CollisionShapes/btMultiSphereShape.h>
#include <LinearMath/btConvexHullComputer.h>
#include <btBulletWorldImporter.h>
#include <BulletFileLoader/btBulletFile.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>

namespace dvi {

using nlohmann::json;
namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------------------
// Validation helpers
// ---------------------------------------------------------------------------------------------------
namespace {

using jsoncheck::describe;
using jsoncheck::num;
using jsoncheck::typeName;
using Check = jsoncheck::JsonCheck;

// Checks for numbers stored as T (a scene's bodies and shapes become Bullet's btScalar, a float in Debian's
// Bullet; the settings become the engine's real): within T's range, and positive values not below its
// smallest normal value.
template <class T>
Check checkFor(const std::string& origin) {
  return Check{origin, double(std::numeric_limits<T>::max()), double(std::numeric_limits<T>::min()),
               sizeof(T) == 4 ? "a 32-bit float" : "a double"};
}

btVector3 bt(Vec3 v) { return btVector3(btScalar(v.x), btScalar(v.y), btScalar(v.z)); }
btQuaternion bt(Quat q) { return btQuaternion(btScalar(q.x), btScalar(q.y), btScalar(q.z), btScalar(q.w)); }

using Rng = SplitMix64;  // base/random.h

// Uniformly distributed rotation (Shoemake's method).
Quat randomRotation(Rng& r) {
  const double u1 = r.uniform(), u2 = r.uniform() * 2 * M_PI, u3 = r.uniform() * 2 * M_PI;
  const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
  return normalized(
      Quat{real(b * std::cos(u3)), real(a * std::sin(u2)), real(a * std::cos(u2)), real(b * std::sin(u3))});
}

}  // namespace

// ---------------------------------------------------------------------------------------------------
// Owned Bullet objects
// ---------------------------------------------------------------------------------------------------
namespace {

// btBulletWorldImporter that records the file's world gravity and lets us find the body made from a
// given rigid-body record (to restore what the stock importer drops: velocities, flags, gravity).
class SceneImporter : public btBulletWorldImporter {
 public:
  SceneImporter() : btBulletWorldImporter(nullptr) {}
  void setDynamicsWorldInfo(const btVector3& gravity, const btContactSolverInfo&) override {
    gravity_ = gravity;
    has_world_ = true;
  }
  btCollisionObject* bodyFor(const void* record) {
    btCollisionObject** p = m_bodyMap.find(btHashPtr(record));
    return p ? *p : nullptr;
  }
  btVector3 gravity_{0, btScalar(-9.81), 0};
  bool has_world_ = false;
};

}  // namespace

struct Scene::Owned {
  std::vector<std::unique_ptr<btCollisionShape>> shapes;  // children before their compounds
  std::vector<std::unique_ptr<btMotionState>> motion_states;
  std::vector<std::unique_ptr<btRigidBody>> bodies;
  std::unique_ptr<SceneImporter> importer;

  ~Owned() {
    bodies.clear();
    motion_states.clear();
    // Compounds reference their children: delete them first (they were created after the children).
    while (!shapes.empty()) shapes.pop_back();
    if (importer) importer->deleteAllData();
  }
};

Scene::Scene() : owned_(std::make_unique<Owned>()) {}
Scene::Scene(Scene&&) noexcept = default;
Scene& Scene::operator=(Scene&&) noexcept = default;
Scene::~Scene() = default;

// ---------------------------------------------------------------------------------------------------
// Settings
// ---------------------------------------------------------------------------------------------------

int64_t SceneSettings::stepCount() const {
  if (steps >= 0) return steps;
  return checkedStepCount(double(time), system.step.dt, "settings.time");
}

void SceneSettings::setIterations(int n) {
  iterations_ = n;
  if (!max_iterations_given_) system.solver.max_iterations = n;
  if (!tolerance_given_)
    system.solver.tolerance = max_iterations_given_ ? kDefaultTolerance : real(0);  // a fixed count
}

void SceneSettings::setMaxIterations(int n) {
  system.solver.max_iterations = n;
  max_iterations_given_ = true;
  if (!tolerance_given_) system.solver.tolerance = kDefaultTolerance;
}

void SceneSettings::setTolerance(real tol) {
  system.solver.tolerance = tol;
  tolerance_given_ = true;
}

const char* collisionBackendName(CollisionBackend b) { return b == CollisionBackend::Bullet ? "bullet" : "native"; }

SceneSettings parseSceneSettings(const json& j, const std::string& origin, const std::string& path) {
  const Check c = checkFor<real>(origin);
  SceneSettings s;
  StepSettings& step = s.system.step;
  CollisionSettings& col = s.system.collision;
  SolverSettings& sol = s.system.solver;
  c.object(j, path);
  c.keys(j, path,
         {"dt",
          "steps",
          "time",
          "solver",
          "iterations",
          "max_iterations",
          "tolerance",
          "storage",
          "gravity",
          "friction_combine",
          "envelope_rel",
          "recovery_rel",
          "min_bounce_speed",
          "collision",
          "threads",
          "frames",
          "checkpoint_every",
          "warm_start",
          "speculative",
          "mpr_manifold",
          "mpr_coherence",
          "bullet_length_scale",
          "bullet_iterations"});
  auto at = [&](const char* k) { return path + "." + k; };
  if (j.contains("dt")) step.dt = real(c.positive(j["dt"], at("dt")));  // in the engine's precision
  if (j.contains("steps") && j.contains("time")) c.fail(path, "give either steps or time, not both");
  if (j.contains("steps")) s.steps = c.integer(j["steps"], at("steps"), 0, int64_t(1) << 40);
  if (j.contains("time")) s.time = real(c.nonNegative(j["time"], at("time")));
  if (j.contains("solver"))
    sol.type = c.named<SolverType>(j["solver"], at("solver"),
                                   {{"jacobi", SolverType::Jacobi},
                                    {"gs", SolverType::GaussSeidel},
                                    {"apgd", SolverType::APGD},
                                    {"bb", SolverType::BB}});
  if (j.contains("iterations")) s.setIterations(int(c.integer(j["iterations"], at("iterations"), 0, 1000000)));
  if (j.contains("max_iterations"))
    s.setMaxIterations(int(c.integer(j["max_iterations"], at("max_iterations"), 1, 1000000)));
  if (j.contains("tolerance")) s.setTolerance(real(c.nonNegative(j["tolerance"], at("tolerance"))));
  if (j.contains("storage"))
    sol.storage = c.named<VectorStorage>(
        j["storage"], at("storage"),
        {{"auto", VectorStorage::Auto}, {"real", VectorStorage::Real}, {"float", VectorStorage::Float}});
  if (j.contains("gravity")) step.gravity = c.vec3(j["gravity"], at("gravity"));
  if (j.contains("friction_combine"))
    col.friction_combine = c.named<FrictionCombine>(
        j["friction_combine"], at("friction_combine"),
        {{"product", FrictionCombine::Product}, {"min", FrictionCombine::Min}, {"average", FrictionCombine::Average}});
  if (j.contains("envelope_rel")) col.envelope_rel = real(c.nonNegative(j["envelope_rel"], at("envelope_rel")));
  if (j.contains("recovery_rel")) sol.recovery_rel = real(c.positive(j["recovery_rel"], at("recovery_rel")));
  if (j.contains("min_bounce_speed"))
    sol.min_bounce_speed = real(c.nonNegative(j["min_bounce_speed"], at("min_bounce_speed")));
  if (j.contains("collision"))
    col.backend = c.named<CollisionBackend>(
        j["collision"], at("collision"), {{"native", CollisionBackend::Native}, {"bullet", CollisionBackend::Bullet}});
  if (j.contains("threads")) s.system.threads = int(c.integer(j["threads"], at("threads"), 0, 4096));
  if (j.contains("frames")) s.frames = int(c.integer(j["frames"], at("frames"), 0, 1000000));
  if (j.contains("checkpoint_every"))
    s.checkpoint_every = c.integer(j["checkpoint_every"], at("checkpoint_every"), 0, int64_t(1) << 40);
  if (j.contains("warm_start")) sol.warm_start = c.boolean(j["warm_start"], at("warm_start"));
  if (j.contains("speculative")) col.speculative = c.boolean(j["speculative"], at("speculative"));
  if (j.contains("mpr_manifold")) col.mpr_manifold = c.boolean(j["mpr_manifold"], at("mpr_manifold"));
  if (j.contains("mpr_coherence")) col.mpr_coherence = c.boolean(j["mpr_coherence"], at("mpr_coherence"));
  if (j.contains("bullet_length_scale"))
    s.bullet_length_scale = real(c.nonNegative(j["bullet_length_scale"], at("bullet_length_scale")));
  if (j.contains("bullet_iterations"))
    s.bullet_iterations = int(c.integer(j["bullet_iterations"], at("bullet_iterations"), 1, 1000000));
  if (s.steps < 0) checkedStepCount(double(s.time), step.dt, origin + ": " + at("time"));
  return s;
}

// ---------------------------------------------------------------------------------------------------
// --set KEY=VALUE on a JSON document
// ---------------------------------------------------------------------------------------------------
namespace {

void applyOverride(json& doc, const std::string& assignment) {
  const size_t eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0)
    throw InputError("--set " + assignment + ": expected KEY=VALUE (e.g. settings.dt=1e-4)");
  const std::string key = assignment.substr(0, eq), text = assignment.substr(eq + 1);
  // only the settings object may be created (a .bullet scene's overrides start from an empty document)
  jsoncheck::setByPath(doc, key, key, jsoncheck::parseSetValue(text, "--set " + key),
                       [](size_t depth, const std::string& name) { return depth == 0 && name == "settings"; });
  // steps and time are alternatives: setting one drops the other.
  if (key == "settings.steps" && doc["settings"].contains("time")) doc["settings"].erase("time");
  if (key == "settings.time" && doc["settings"].contains("steps")) doc["settings"].erase("steps");
}

}  // namespace

void Scene::applySettingOverride(const std::string& assignment) {
  const std::string key = assignment.substr(0, assignment.find('='));
  if (key.rfind("settings.", 0) != 0)
    throw InputError("--set " + key + ": unknown key (only settings.* apply to a " + format + " scene)");
  json doc = json::object();
  doc["settings"] = settings_json_;
  applyOverride(doc, assignment);
  settings = parseSceneSettings(doc["settings"], "--set " + key);
  settings_json_ = doc["settings"];
}

// ---------------------------------------------------------------------------------------------------
// JSON scenes: shapes, bodies, generators
// ---------------------------------------------------------------------------------------------------
namespace {

struct BuiltShape {
  btCollisionShape* shape = nullptr;
  double volume = 0;
  double bound = 0;  // bounding radius about the shape origin
  bool plane = false;
};

double hullVolume(const std::vector<btVector3>& pts) {
  btConvexHullComputer hull;
  hull.compute(&pts[0].x(), int(sizeof(btVector3)), int(pts.size()), 0, 0);
  double vol = 0;
  for (int f = 0; f < hull.faces.size(); ++f) {
    const btConvexHullComputer::Edge* e0 = &hull.edges[hull.faces[f]];
    const btVector3 a = hull.vertices[e0->getSourceVertex()];
    const btConvexHullComputer::Edge* e = e0->getNextEdgeOfFace();
    int guard = 0;
    while (e->getTargetVertex() != e0->getSourceVertex() && guard++ < 100000) {
      const btVector3 b = hull.vertices[e->getSourceVertex()], c = hull.vertices[e->getTargetVertex()];
      vol += double(a.dot(b.cross(c))) / 6.0;
      e = e->getNextEdgeOfFace();
    }
  }
  return std::fabs(vol);
}

// A margin for Bullet's collision of the shape (Bullet's default 0.04 is an absolute length, far too
// large for centimetre bodies): 5% of the shape's smallest half-dimension, at most Bullet's default.
btScalar marginFor(double size) { return btScalar(std::min(0.04, 0.05 * size)); }

class Builder {
 public:
  Builder(const Check& c, Scene::Owned& o) : c_(c), o_(o) {}

  // depth: how many compounds this shape is inside (bounded: compounds recurse here and in scaled()).
  BuiltShape shape(const json& j, const std::string& path, int depth = 0) {
    c_.object(j, path);
    if (!j.contains("type")) c_.fail(path + ".type", "missing shape type");
    const std::string type =
        c_.oneOf(j["type"], path + ".type",
                 {"sphere", "box", "cylinder", "capsule", "cone", "ellipsoid", "convex_hull", "plane", "compound"});
    const ShapeJson s{c_, j, path, type};
    if (type == "sphere") return sphere(s);
    if (type == "box") return box(s);
    if (type == "cylinder") return cylinder(s);
    if (type == "capsule") return capsule(s);
    if (type == "cone") return cone(s);
    if (type == "ellipsoid") return ellipsoid(s);
    if (type == "convex_hull") return convexHull(s);
    if (type == "plane") return plane(s, depth > 0);
    return compound(s, depth);
  }

 private:
  // A shape object being read: where it is, and the helpers every type uses.
  struct ShapeJson {
    const Check& c;
    const json& j;
    const std::string& path;
    const std::string& type;
    const json& need(const char* k) const {
      if (!j.contains(k)) c.fail(path + "." + k, std::string("missing (required for a ") + type + ")");
      return j[k];
    }
    std::string at(const char* k) const { return path + "." + k; }
    int axis() const {
      if (!j.contains("axis")) return 1;
      const std::string a = c.oneOf(j["axis"], at("axis"), {"x", "y", "z"});
      return a == "x" ? 0 : a == "y" ? 1 : 2;
    }
  };

  BuiltShape sphere(const ShapeJson& sj) {
    BuiltShape b;
    c_.keys(sj.j, sj.path, {"type", "radius"});
    const double r = c_.positive(sj.need("radius"), sj.at("radius"));
    b.shape = keep(new btSphereShape(btScalar(r)));
    b.volume = 4.0 / 3.0 * M_PI * r * r * r;
    b.bound = r;
    return b;
  }

  BuiltShape box(const ShapeJson& sj) {
    BuiltShape b;
    c_.keys(sj.j, sj.path, {"type", "half_extents"});
    const Vec3 h = c_.positiveVec3(sj.need("half_extents"), sj.at("half_extents"));
    auto* s = new btBoxShape(bt(h));
    s->setMargin(marginFor(minComponent(h)));
    b.shape = keep(s);
    b.volume = 8.0 * h.x * h.y * h.z;
    b.bound = length(h);
    return b;
  }

  // A cylinder's or capsule's keys: radius, half height (zero allowed for a capsule: a sphere) and axis.
  struct RoundKeys {
    double r, hh;
    int axis;
  };
  RoundKeys roundKeys(const ShapeJson& sj, bool zero_height) {
    c_.keys(sj.j, sj.path, {"type", "radius", "half_height", "axis"});
    const double r = c_.positive(sj.need("radius"), sj.at("radius"));
    const json& hj = sj.need("half_height");
    const double hh = zero_height ? c_.nonNegative(hj, sj.at("half_height")) : c_.positive(hj, sj.at("half_height"));
    return RoundKeys{r, hh, sj.axis()};
  }

  BuiltShape cylinder(const ShapeJson& sj) {
    BuiltShape b;
    const auto [r, hh, axis] = roundKeys(sj, false);
    btCylinderShape* s =
        axis == 0 ? new btCylinderShapeX(btVector3(btScalar(hh), btScalar(r), btScalar(r)))
        : axis == 1
            ? new btCylinderShape(btVector3(btScalar(r), btScalar(hh), btScalar(r)))
            : static_cast<btCylinderShape*>(new btCylinderShapeZ(btVector3(btScalar(r), btScalar(r), btScalar(hh))));
    s->setMargin(marginFor(std::min(r, hh)));
    b.shape = keep(s);
    b.volume = M_PI * r * r * 2 * hh;
    b.bound = std::sqrt(r * r + hh * hh);
    return b;
  }

  BuiltShape capsule(const ShapeJson& sj) {
    BuiltShape b;
    const auto [r, hh, axis] = roundKeys(sj, true);
    const btScalar R = btScalar(r), H = btScalar(2 * hh);
    btCapsuleShape* s = axis == 0   ? new btCapsuleShapeX(R, H)
                        : axis == 1 ? new btCapsuleShape(R, H)
                                    : static_cast<btCapsuleShape*>(new btCapsuleShapeZ(R, H));
    b.shape = keep(s);
    b.volume = M_PI * r * r * 2 * hh + 4.0 / 3.0 * M_PI * r * r * r;
    b.bound = r + hh;
    return b;
  }

  BuiltShape cone(const ShapeJson& sj) {
    BuiltShape b;
    c_.keys(sj.j, sj.path, {"type", "radius", "height", "axis"});
    const double r = c_.positive(sj.need("radius"), sj.at("radius"));
    const double h = c_.positive(sj.need("height"), sj.at("height"));
    const int axis = sj.axis();
    const btScalar R = btScalar(r), H = btScalar(h);
    btConeShape* s = axis == 0   ? new btConeShapeX(R, H)
                     : axis == 1 ? new btConeShape(R, H)
                                 : static_cast<btConeShape*>(new btConeShapeZ(R, H));
    s->setMargin(marginFor(std::min(r, 0.5 * h)));
    b.shape = keep(s);
    b.volume = M_PI * r * r * h / 3.0;
    b.bound = std::sqrt(r * r + 0.25 * h * h);
    return b;
  }

  BuiltShape ellipsoid(const ShapeJson& sj) {
    BuiltShape b;
    c_.keys(sj.j, sj.path, {"type", "semi_axes"});
    const Vec3 a = c_.positiveVec3(sj.need("semi_axes"), sj.at("semi_axes"));
    // Bullet has no ellipsoid: a unit multi-sphere scaled per axis, which the importer reads back
    // as an ellipsoid.
    const btVector3 center(0, 0, 0);
    const btScalar one = 1;
    auto* s = new btMultiSphereShape(&center, &one, 1);
    s->setMargin(marginFor(minComponent(a)));
    s->setLocalScaling(bt(a));
    b.shape = keep(s);
    b.volume = 4.0 / 3.0 * M_PI * a.x * a.y * a.z;
    b.bound = maxComponent(a);
    return b;
  }

  BuiltShape convexHull(const ShapeJson& sj) {
    BuiltShape b;
    c_.keys(sj.j, sj.path, {"type", "points", "margin"});
    const json& p = c_.array(sj.need("points"), sj.at("points"));
    // Optional sphere-swept margin (Shape::margin, Bullet's collision margin): >= 0, finite.
    const double margin = sj.j.contains("margin") ? c_.nonNegative(sj.j["margin"], sj.at("margin")) : -1.0;
    if (p.size() < 4)
      c_.fail(sj.at("points"), "a convex hull needs at least 4 points, got " + std::to_string(p.size()));
    std::vector<btVector3> pts;
    Vec3 lo{1e30, 1e30, 1e30}, hi{-1e30, -1e30, -1e30};
    for (size_t i = 0; i < p.size(); ++i) {
      const Vec3 v = c_.vec3(p[i], sj.at("points") + "[" + std::to_string(i) + "]");
      pts.push_back(bt(v));
      lo = vmin(lo, v);
      hi = vmax(hi, v);
      b.bound = std::max(b.bound, double(length(v)) + std::max(margin, 0.0));
    }
    b.volume = hullVolume(pts);
    if (!(b.volume > 1e-12 * std::pow(double(maxComponent(hi - lo)), 3)))
      c_.fail(sj.at("points"), "points are coplanar (the hull has zero volume)");
    auto* s = new btConvexHullShape(&pts[0].x(), int(pts.size()), int(sizeof(btVector3)));
    s->setMargin(margin >= 0 ? btScalar(margin) : marginFor(0.5 * minComponent(hi - lo)));
    b.shape = keep(s);
    return b;
  }

  BuiltShape plane(const ShapeJson& sj, bool in_compound) {
    BuiltShape b;
    c_.keys(sj.j, sj.path, {"type", "normal", "offset"});
    if (in_compound) c_.fail(sj.path, "a plane cannot be a compound child");
    // The plane n.x = offset with n as given: offset / |n| along the unit normal.
    const json& nj = sj.need("normal");
    const Vec3 u = c_.direction(nj, sj.at("normal"));
    const double d = sj.j.contains("offset") ? c_.finiteNumber(sj.j["offset"], sj.at("offset")) : 0.0;
    double nmax = 0;
    for (const json& x : nj) nmax = std::fmax(nmax, std::fabs(x.get<double>()));
    double nlen = 0;
    for (const json& x : nj) nlen += (x.get<double>() / nmax) * (x.get<double>() / nmax);
    const double dn = d / nmax / std::sqrt(nlen);
    if (!(std::fabs(dn) <= c_.max_magnitude))
      c_.fail(sj.at("offset"), "offset / |normal| = " + num(dn) + " is out of range (stored as " + c_.stored_as + ")");
    b.shape = keep(new btStaticPlaneShape(bt(u), btScalar(dn)));
    b.plane = true;
    b.bound = INFINITY;
    return b;
  }

  BuiltShape compound(const ShapeJson& sj, int depth) {
    BuiltShape b;
    c_.keys(sj.j, sj.path, {"type", "children"});
    if (depth >= inputLimits().max_compound_depth)
      c_.fail(sj.path, "compound shapes nested deeper than " + std::to_string(inputLimits().max_compound_depth) +
                           " levels (the limit)");
    const json& ch = c_.array(sj.need("children"), sj.at("children"));
    if (ch.empty()) c_.fail(sj.at("children"), "a compound needs at least one child");
    std::vector<std::pair<btTransform, btCollisionShape*>> kids;
    for (size_t i = 0; i < ch.size(); ++i) {
      const std::string cp = sj.at("children") + "[" + std::to_string(i) + "]";
      c_.object(ch[i], cp);
      c_.keys(ch[i], cp, {"shape", "position", "rotation"});
      if (!ch[i].contains("shape")) c_.fail(cp + ".shape", "missing");
      BuiltShape k = shape(ch[i]["shape"], cp + ".shape", depth + 1);
      const Vec3 pos = ch[i].contains("position") ? c_.vec3(ch[i]["position"], cp + ".position") : Vec3{0, 0, 0};
      const Quat q = ch[i].contains("rotation") ? c_.rotation(ch[i]["rotation"], cp + ".rotation") : Quat{1, 0, 0, 0};
      kids.push_back({btTransform(bt(q), bt(pos)), k.shape});
      b.volume += k.volume;
      b.bound = std::max(b.bound, double(length(pos)) + k.bound);
    }
    auto* s = new btCompoundShape(true, int(kids.size()));
    for (auto& k : kids) s->addChildShape(k.first, k.second);
    b.shape = keep(s);
    return b;
  }

 public:
  btCollisionShape* keep(btCollisionShape* s) {
    o_.shapes.emplace_back(s);
    return s;
  }

  struct BodySpec {
    BuiltShape shape;
    double mass = 1;
    Vec3 pos{0, 0, 0}, vel{0, 0, 0}, omega{0, 0, 0};
    Quat rot{1, 0, 0, 0};
    double friction = 0.5;
    double restitution = 0;
    double rolling_friction = 0, spinning_friction = 0;  // [m]
    bool kinematic = false;
    bool has_gravity = false;
    Vec3 gravity{0, 0, 0};
  };

  btRigidBody* body(const BodySpec& s, const std::string& path) {
    const bool fixed = s.kinematic || s.mass == 0;
    if (s.shape.plane && !fixed) c_.fail(path + ".mass", "a plane must be static (mass 0), got " + num(s.mass));
    // What is stored as btScalar must stay finite and, for the mass and the moments of inertia (Bullet keeps
    // their inverses), positive and above the smallest normal float; else the body silently turns static or
    // its inverse mass overflows. A mass given in the file was checked where it was read; these are the ones
    // computed here (density x volume, inertia of the shape, positions of a generator).
    if (!fixed && !(s.mass >= c_.min_positive && s.mass <= c_.max_magnitude))
      c_.fail(path + ".mass",
              "mass " + num(s.mass) + " kg (density x volume) is out of range (stored as " + c_.stored_as + ")");
    const btScalar mass = fixed ? btScalar(0) : btScalar(s.mass);
    btVector3 inertia(0, 0, 0);
    if (!fixed) {
      s.shape.shape->calculateLocalInertia(mass, inertia);
      for (int k = 0; k < 3; ++k)
        if (!(std::isfinite(inertia[k]) && double(inertia[k]) >= c_.min_positive))
          c_.fail(path, "moment of inertia " + num(double(inertia[k])) + " kg m^2 (mass " + num(s.mass) +
                            " kg on this shape) is out of range (stored as " + c_.stored_as + ")");
    }
    for (const auto& v : {std::make_pair(".position", s.pos), std::make_pair(".velocity", s.vel),
                          std::make_pair(".angular_velocity", s.omega), std::make_pair(".gravity", s.gravity)})
      if (!(std::fabs(double(v.second.x)) <= c_.max_magnitude && std::fabs(double(v.second.y)) <= c_.max_magnitude &&
            std::fabs(double(v.second.z)) <= c_.max_magnitude))
        c_.fail(path + v.first, "is out of range (stored as " + std::string(c_.stored_as) + ")");
    const btTransform t(bt(s.rot), bt(s.pos));
    auto* ms = new btDefaultMotionState(t);
    o_.motion_states.emplace_back(ms);
    btRigidBody::btRigidBodyConstructionInfo info(mass, ms, s.shape.shape, inertia);
    info.m_friction = btScalar(s.friction);
    info.m_restitution = btScalar(s.restitution);
    info.m_rollingFriction = btScalar(s.rolling_friction);
    info.m_spinningFriction = btScalar(s.spinning_friction);
    auto* rb = new btRigidBody(info);
    o_.bodies.emplace_back(rb);
    if (s.kinematic) {
      rb->setCollisionFlags(rb->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
      rb->setActivationState(DISABLE_DEACTIVATION);
    }
    if (!fixed || s.kinematic) {
      rb->setLinearVelocity(bt(s.vel));
      rb->setAngularVelocity(bt(s.omega));
    }
    if (s.has_gravity) {
      rb->setFlags(rb->getFlags() | BT_DISABLE_WORLD_GRAVITY);
      rb->setGravity(bt(s.gravity));
    }
    return rb;
  }

  // Reads mass or density (mass from the shape's volume).
  double massOf(const json& j, const std::string& path, double volume, bool plane) {
    if (j.contains("mass") && j.contains("density")) c_.fail(path, "give either mass or density, not both");
    if (j.contains("density")) {
      const double rho = c_.nonNegative(j["density"], path + ".density");
      if (plane && rho > 0) c_.fail(path + ".density", "a plane must be static (density 0)");
      return rho * volume;
    }
    if (j.contains("mass")) return c_.nonNegative(j["mass"], path + ".mass");
    return plane ? 0.0 : 1.0;
  }

  void plainBody(const json& j, const std::string& path, Scene& scene, std::vector<std::string>& names,
                 std::vector<btRigidBody*>& out) {
    c_.keys(j, path,
            {"name", "shape", "mass", "density", "position", "rotation", "velocity", "angular_velocity", "friction",
             "restitution", "rolling_friction", "spinning_friction", "kinematic", "gravity"});
    (void)scene;
    if (!j.contains("shape")) c_.fail(path + ".shape", "missing");
    BodySpec s;
    s.shape = shape(j["shape"], path + ".shape");
    s.mass = massOf(j, path, s.shape.volume, s.shape.plane);
    if (j.contains("position")) s.pos = c_.vec3(j["position"], path + ".position");
    if (j.contains("rotation")) s.rot = c_.rotation(j["rotation"], path + ".rotation");
    if (j.contains("velocity")) s.vel = c_.vec3(j["velocity"], path + ".velocity");
    if (j.contains("angular_velocity")) s.omega = c_.vec3(j["angular_velocity"], path + ".angular_velocity");
    if (j.contains("friction")) s.friction = c_.nonNegative(j["friction"], path + ".friction");
    if (j.contains("restitution")) s.restitution = c_.range(j["restitution"], path + ".restitution", 0, 1);
    if (j.contains("rolling_friction"))
      s.rolling_friction = c_.nonNegative(j["rolling_friction"], path + ".rolling_friction");
    if (j.contains("spinning_friction"))
      s.spinning_friction = c_.nonNegative(j["spinning_friction"], path + ".spinning_friction");
    if (j.contains("kinematic")) s.kinematic = c_.boolean(j["kinematic"], path + ".kinematic");
    if (j.contains("gravity")) {
      s.has_gravity = true;
      s.gravity = c_.vec3(j["gravity"], path + ".gravity");
    }
    std::string name = j.contains("name") ? c_.string(j["name"], path + ".name") : "body" + std::to_string(out.size());
    out.push_back(body(s, path));
    names.push_back(name);
  }

  // Scales every length of a shape description (used for multidisperse generators).
  static json scaled(const json& shape, double f) {
    json s = shape;
    for (const char* k : {"radius", "half_height", "height", "margin"})
      if (s.contains(k) && s[k].is_number()) s[k] = s[k].get<double>() * f;
    for (const char* k : {"half_extents", "semi_axes"})
      if (s.contains(k) && s[k].is_array())
        for (auto& x : s[k])
          if (x.is_number()) x = x.get<double>() * f;
    if (s.contains("points") && s["points"].is_array())
      for (auto& p : s["points"])
        if (p.is_array())
          for (auto& x : p)
            if (x.is_number()) x = x.get<double>() * f;
    if (s.contains("children") && s["children"].is_array())
      for (auto& c : s["children"])
        if (c.is_object()) {
          if (c.contains("shape")) c["shape"] = scaled(c["shape"], f);
          if (c.contains("position") && c["position"].is_array())
            for (auto& x : c["position"])
              if (x.is_number()) x = x.get<double>() * f;
        }
    return s;
  }

  void generator(const json& g, const std::string& path, std::vector<std::string>& names,
                 std::vector<btRigidBody*>& out) {
    c_.object(g, path);
    c_.keys(g, path,
            {"type",
             "name",
             "count",
             "footprint",
             "counts",
             "origin",
             "spacing",
             "jitter",
             "seed",
             "shape",
             "shapes",
             "scale",
             "mass",
             "density",
             "friction",
             "restitution",
             "rolling_friction",
             "spinning_friction",
             "velocity",
             "angular_velocity",
             "random_rotation"});
    if (!g.contains("type")) c_.fail(path + ".type", "missing generator type");
    const std::string type = c_.oneOf(g["type"], path + ".type", {"grid", "pile"});
    auto at = [&](const char* k) { return path + "." + k; };
    const std::string prefix = g.contains("name") ? c_.string(g["name"], at("name")) : type;
    const std::vector<MixEntry> mix = mixture(g, path);
    double smin = 1, smax = 1;
    scaleRange(g, path, smin, smax);
    const bool random_rot =
        g.contains("random_rotation") ? c_.boolean(g["random_rotation"], at("random_rotation")) : type == "pile";
    const double bound = mixtureBound(mix, smax, random_rot);
    const double jitter = g.contains("jitter") ? c_.nonNegative(g["jitter"], at("jitter")) : 0.0;
    if (jitter >= 0.5) c_.fail(at("jitter"), "must be < 0.5 (a fraction of the spacing), got " + num(jitter));
    const double spacing = latticeSpacing(g, path, bound, jitter);
    const Vec3 origin = g.contains("origin") ? c_.vec3(g["origin"], at("origin")) : Vec3{0, 0, 0};
    const Lattice L = lattice(g, path, type, spacing);
    checkBodyBudget(int64_t(out.size()) + L.count, c_.origin + ": " + path);
    Rng rng{g.contains("seed") ? uint64_t(c_.integer(g["seed"], at("seed"), 0, int64_t(1) << 53)) : 1u};
    const double friction = g.contains("friction") ? c_.nonNegative(g["friction"], at("friction")) : 0.5;
    const double restitution = g.contains("restitution") ? c_.range(g["restitution"], at("restitution"), 0, 1) : 0.0;
    const double rolling =
        g.contains("rolling_friction") ? c_.nonNegative(g["rolling_friction"], at("rolling_friction")) : 0.0;
    const double spinning =
        g.contains("spinning_friction") ? c_.nonNegative(g["spinning_friction"], at("spinning_friction")) : 0.0;
    const Vec3 vel = g.contains("velocity") ? c_.vec3(g["velocity"], at("velocity")) : Vec3{0, 0, 0};
    const Vec3 omega =
        g.contains("angular_velocity") ? c_.vec3(g["angular_velocity"], at("angular_velocity")) : Vec3{0, 0, 0};
    if (g.contains("mass") && g.contains("density")) c_.fail(path, "give either mass or density, not both");
    const bool by_density = g.contains("density");
    const double mass = g.contains("mass") ? c_.positive(g["mass"], at("mass")) : 1.0;
    const double rho = by_density ? c_.positive(g["density"], at("density")) : 0.0;
    double wsum = 0;
    for (const MixEntry& e : mix) wsum += e.weight;

    std::map<size_t, BuiltShape> shared;  // one Bullet shape per mixture entry when the scale is fixed
    for (int64_t i = 0; i < L.count; ++i) {
      const int64_t ix = i % L.nx, iz = (i / L.nx) % L.nz, iy = i / (L.nx * L.nz);
      double pick = rng.uniform() * wsum;
      size_t e = 0;
      while (e + 1 < mix.size() && pick >= mix[e].weight) pick -= mix[e++].weight;
      const double f = smin == smax ? smin : rng.uniform(smin, smax);
      BodySpec s;
      if (smin == smax) {
        auto it = shared.find(e);
        if (it == shared.end()) it = shared.emplace(e, shape(scaled(mix[e].shape, f), mix[e].path)).first;
        s.shape = it->second;
      } else {
        s.shape = shape(scaled(mix[e].shape, f), mix[e].path);
      }
      const double jx = rng.uniform(-jitter, jitter), jy = rng.uniform(-jitter, jitter),
                   jz = rng.uniform(-jitter, jitter);
      s.pos = origin +
              Vec3{real((ix + 0.5 + jx) * spacing), real((iy + 0.5 + jy) * spacing), real((iz + 0.5 + jz) * spacing)};
      s.rot = random_rot ? randomRotation(rng) : Quat{1, 0, 0, 0};
      s.mass = by_density ? rho * s.shape.volume : mass;
      s.friction = friction;
      s.restitution = restitution;
      s.rolling_friction = rolling;
      s.spinning_friction = spinning;
      s.vel = vel;
      s.omega = omega;
      out.push_back(body(s, path));
      names.push_back(prefix + "_" + std::to_string(i));
    }
  }

 private:
  // A generator's shape mixture entry: its shape object, weight and key path.
  struct MixEntry {
    json shape;
    double weight;
    std::string path;
  };
  // Where a generator puts its bodies: an nx x ny x nz lattice (a pile fills it layer by layer), count bodies.
  struct Lattice {
    int64_t nx = 1, ny = 1, nz = 1, count = 0;
  };

  // Shape mixture: one "shape", or "shapes": [{shape, weight}].
  std::vector<MixEntry> mixture(const json& g, const std::string& path) const {
    auto at = [&](const char* k) { return path + "." + k; };
    std::vector<MixEntry> mix;
    if (g.contains("shape") == g.contains("shapes")) c_.fail(path, "give exactly one of shape, shapes");
    if (g.contains("shape")) {
      mix.push_back({g["shape"], 1.0, at("shape")});
      return mix;
    }
    const json& arr = c_.array(g["shapes"], at("shapes"));
    if (arr.empty()) c_.fail(at("shapes"), "needs at least one entry");
    for (size_t i = 0; i < arr.size(); ++i) {
      const std::string ep = at("shapes") + "[" + std::to_string(i) + "]";
      c_.object(arr[i], ep);
      c_.keys(arr[i], ep, {"shape", "weight"});
      if (!arr[i].contains("shape")) c_.fail(ep + ".shape", "missing");
      const double w = arr[i].contains("weight") ? c_.positive(arr[i]["weight"], ep + ".weight") : 1.0;
      mix.push_back({arr[i]["shape"], w, ep + ".shape"});
    }
    return mix;
  }

  // "scale": a number or [min, max] (default 1).
  void scaleRange(const json& g, const std::string& path, double& smin, double& smax) const {
    if (!g.contains("scale")) return;
    const std::string at = path + ".scale";
    if (g["scale"].is_array()) {
      if (g["scale"].size() != 2) c_.fail(at, "expected a number or [min, max], got " + describe(g["scale"]));
      smin = c_.positive(g["scale"][0], at + "[0]");
      smax = c_.positive(g["scale"][1], at + "[1]");
      if (smax < smin) c_.fail(at, "max < min");
    } else {
      smin = smax = c_.positive(g["scale"], at);
    }
  }

  // Validates every entry once and measures the largest extent at the largest scale: the bounding radius when
  // bodies turn at random, the half extent of the axis-aligned box otherwise.
  double mixtureBound(const std::vector<MixEntry>& mix, double smax, bool random_rot) {
    double bound = 0;
    for (const MixEntry& e : mix) {
      BuiltShape b = shape(scaled(e.shape, smax), e.path);
      if (b.plane) c_.fail(e.path, "a generator cannot make planes");
      if (random_rot) {
        bound = std::max(bound, b.bound);
      } else {
        btVector3 lo, hi;
        btTransform id;
        id.setIdentity();
        b.shape->getAabb(id, lo, hi);
        for (int k = 0; k < 3; ++k) bound = std::max({bound, double(-lo[k]), double(hi[k])});
      }
    }
    return bound;
  }

  // The lattice spacing: "spacing", at least what bodies of that bound with that jitter need (the default 5% more).
  double latticeSpacing(const json& g, const std::string& path, double bound, double jitter) const {
    const double min_spacing = 2 * bound / (1 - 2 * jitter);
    if (!g.contains("spacing")) return 1.05 * min_spacing;
    const double spacing = c_.positive(g["spacing"], path + ".spacing");
    if (spacing < min_spacing * (1 - 1e-6))
      c_.fail(path + ".spacing", num(spacing) + " is too small: bodies of bounding radius " + num(bound) +
                                     " with jitter " + num(jitter) + " need at least " + num(min_spacing));
    return spacing;
  }

  // A grid's "counts" [nx, ny, nz], or a pile's "count" in columns over its "footprint".
  Lattice lattice(const json& g, const std::string& path, const std::string& type, double spacing) const {
    auto at = [&](const char* k) { return path + "." + k; };
    Lattice L;
    if (type == "grid") {
      if (g.contains("count") || g.contains("footprint"))
        c_.fail(path, "a grid takes counts [nx, ny, nz], not count/footprint");
      if (!g.contains("counts")) c_.fail(at("counts"), "missing (required for a grid)");
      const json& cn = g["counts"];
      if (!cn.is_array() || cn.size() != 3) c_.fail(at("counts"), "expected [nx, ny, nz], got " + describe(cn));
      L.nx = c_.integer(cn[0], at("counts") + "[0]", 1, 1 << 20);
      L.ny = c_.integer(cn[1], at("counts") + "[1]", 1, 1 << 20);
      L.nz = c_.integer(cn[2], at("counts") + "[2]", 1, 1 << 20);
      L.count = L.nx * L.ny * L.nz;
    } else {
      if (g.contains("counts")) c_.fail(at("counts"), "a pile takes count and footprint, not counts");
      if (!g.contains("count")) c_.fail(at("count"), "missing (required for a pile)");
      L.count = c_.integer(g["count"], at("count"), 1, int64_t(1) << 26);
      double fx = spacing * 10, fz = spacing * 10;
      if (g.contains("footprint")) {
        const json& f = g["footprint"];
        if (!f.is_array() || f.size() != 2) c_.fail(at("footprint"), "expected [width_x, width_z], got " + describe(f));
        fx = c_.positive(f[0], at("footprint") + "[0]");
        fz = c_.positive(f[1], at("footprint") + "[1]");
      }
      // Columns along x and z, at most `count` each (more would stay empty and leave every position as it is),
      // so that nx * nz <= count^2 cannot wrap (a 4e9 x 4e9 footprint made it 0: a division by zero).
      L.nx = int64_t(std::fmax(1.0, std::fmin(std::floor(fx / spacing), double(L.count))));
      L.nz = int64_t(std::fmax(1.0, std::fmin(std::floor(fz / spacing), double(L.count))));
      L.ny = (L.count + L.nx * L.nz - 1) / (L.nx * L.nz);
    }
    if (L.count > (int64_t(1) << 26)) c_.fail(path, "too many bodies (" + std::to_string(L.count) + ")");
    return L;
  }

 private:
  const Check& c_;
  Scene::Owned& o_;
};

// A scene file: a regular file (a FIFO or a device named .json would block the read forever) within the size limit.
std::string readFile(const std::string& path, uint64_t max_bytes) {
  return readRegularFile(path, path, max_bytes, ", not a scene file");
}

// A body as the engine will import it: every number finite, a dynamic body's mass and moments positive, its
// rotation a rotation, its shapes of finite positive size (what System::addBody needs, checked here so that the
// message names the body). `where` names it.
void checkLoadedBody(const btRigidBody& rb, const std::string& where) {
  auto bad = [&](const std::string& what) { throw InputError(where + ": " + what); };
  BodyDesc d;
  try {
    d = bodyDescFromBullet(rb);
  } catch (const InputError& e) { bad(e.what()); }
  const btMatrix3x3& r = rb.getCenterOfMassTransform().getBasis();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      const double rij = double(r[0][i]) * r[0][j] + double(r[1][i]) * r[1][j] + double(r[2][i]) * r[2][j];
      if (!(std::fabs(rij - (i == j ? 1.0 : 0.0)) < 1e-3))
        bad("orientation is not a rotation (its matrix is not orthonormal)");
    }
  if (!isFinite(d.pos)) bad("non-finite position");
  if (!isFinite(d.vel) || !isFinite(d.omega)) bad("non-finite velocity");
  if (!isFinite(d.gravity)) bad("non-finite gravity");
  if (!(std::isfinite(d.friction) && d.friction >= 0))
    bad("friction must be finite and >= 0, got " + num(double(d.friction)));
  if (!(std::isfinite(d.restitution) && d.restitution >= 0))
    bad("restitution must be finite and >= 0, got " + num(double(d.restitution)));
  if (!(std::isfinite(d.rolling_friction) && d.rolling_friction >= 0))
    bad("rolling friction must be finite and >= 0, got " + num(double(d.rolling_friction)));
  if (!(std::isfinite(d.spinning_friction) && d.spinning_friction >= 0))
    bad("spinning friction must be finite and >= 0, got " + num(double(d.spinning_friction)));
  if (d.flags == 0) {
    if (!(std::isfinite(d.mass) && d.mass > 0)) bad("mass must be finite and > 0, got " + num(double(d.mass)));
    if (!(isFinite(d.inertia) && minComponent(d.inertia) > 0)) bad("moments of inertia must be finite and > 0");
  }
  for (const ShapeDesc& sd : d.shapes) {
    const Shape& sh = sd.shape;
    if (!isFinite(sh.dims) || !isFinite(sh.local.p) || !std::isfinite(sh.plane_d) ||
        !(std::isfinite(sh.local.q.w) && std::isfinite(sh.local.q.x) && std::isfinite(sh.local.q.y) &&
          std::isfinite(sh.local.q.z)))
      bad(std::string(shapeTypeName(sh.type)) + " shape has a non-finite dimension or pose");
    if (sh.type == ShapeType::Plane) {
      if (!(std::fabs(double(length(sh.dims)) - 1) < 1e-6)) bad("plane normal has no finite non-zero length");
      continue;
    }
    if (!(sh.size > 0 && std::isfinite(sh.size)))
      bad(std::string(shapeTypeName(sh.type)) + " shape has a non-positive size");
    for (const Vec3& p : sd.hull)
      if (!isFinite(p)) bad("convex hull has a non-finite point");
  }
}

std::string lower(std::string s) {
  for (char& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

}  // namespace

Scene Scene::fromJsonText(const std::string& text, const std::string& origin,
                          const std::vector<std::string>& overrides) {
  const Check c = checkFor<btScalar>(origin);
  if (text.find_first_not_of(" \t\r\n") == std::string::npos) c.fail("", "file is empty");
  // the size and the nesting checked before and while the DOM is built (input_limits.h)
  json doc = parseJsonChecked(text, origin);
  c.object(doc, "(document)");
  for (const std::string& o : overrides) applyOverride(doc, o);
  if (!overrides.empty()) checkJsonDepth(doc, origin);
  c.keys(doc, "", {"$schema", "name", "description", "settings", "bodies"});

  Scene scene;
  scene.source = origin;
  scene.format = "json";
  scene.name = doc.contains("name") ? c.string(doc["name"], "name") : fs::path(origin).stem().string();
  if (doc.contains("description")) c.string(doc["description"], "description");
  scene.settings_json_ = doc.contains("settings") ? doc["settings"] : json::object();
  scene.settings = parseSceneSettings(scene.settings_json_, origin);

  if (!doc.contains("bodies")) c.fail("bodies", "missing (a scene needs at least one body)");
  const json& bodies = c.array(doc["bodies"], "bodies");
  // The whole scene's body count before anything is built (the builder validates these values again).
  int64_t total = 0;
  for (const json& b : bodies) {
    const json* g = b.is_object() && b.contains("generator") && b["generator"].is_object() ? &b["generator"] : nullptr;
    int64_t n = 1;
    if (g && g->contains("count") && (*g)["count"].is_number_integer())
      n = std::max<int64_t>(1, (*g)["count"].get<int64_t>());
    if (g && g->contains("counts") && (*g)["counts"].is_array() && (*g)["counts"].size() == 3) {
      for (const json& k : (*g)["counts"])
        n *= k.is_number_integer() ? std::clamp<int64_t>(k.get<int64_t>(), 1, 1 << 20) : 1;
    }
    total = std::min<int64_t>(total + std::min<int64_t>(n, int64_t(1) << 40), int64_t(1) << 62);  // saturates
  }
  checkBodyBudget(total, origin + ": bodies");
  Builder b(c, *scene.owned_);
  for (size_t i = 0; i < bodies.size(); ++i) {
    const std::string path = "bodies[" + std::to_string(i) + "]";
    c.object(bodies[i], path);
    if (bodies[i].contains("generator")) {
      c.keys(bodies[i], path, {"generator"});
      b.generator(bodies[i]["generator"], path + ".generator", scene.names_, scene.bodies_);
    } else {
      b.plainBody(bodies[i], path, scene, scene.names_, scene.bodies_);
    }
  }
  if (scene.bodies_.empty()) c.fail("bodies", "the scene has no bodies");
  for (size_t k = 0; k < scene.bodies_.size(); ++k)  // what the checks above derived (inertia, scaled sizes)
    checkLoadedBody(*scene.bodies_[k], origin + ": body " + std::to_string(k) + " (" + scene.names_[k] + ")");
  return scene;
}

// ---------------------------------------------------------------------------------------------------
// .bullet files
// ---------------------------------------------------------------------------------------------------
namespace {

btVector3 vec(const btVector3FloatData& d) {
  btVector3 v;
  v.deSerializeFloat(d);
  return v;
}
btVector3 vec(const btVector3DoubleData& d) {
  btVector3 v;
  v.deSerializeDouble(d);
  return v;
}

template <class Data>
void restoreBodyState(btRigidBody* rb, const Data* d, const btVector3& world_gravity) {
  // Bullet serialises two gravities: m_gravity is the FORCE mass x g (btRigidBody::setGravity stores
  // acceleration / inverse mass there), m_gravity_acceleration the acceleration getGravity() returns. Reading
  // the force as an acceleration made a 1000 kg body fall at 1000 g.
  const btVector3 v = vec(d->m_linearVelocity), w = vec(d->m_angularVelocity), g = vec(d->m_gravity_acceleration);
  const int flags = d->m_collisionObjectData.m_collisionFlags;
  if (flags & btCollisionObject::CF_KINEMATIC_OBJECT) {
    rb->setCollisionFlags(rb->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
    rb->setActivationState(DISABLE_DEACTIVATION);
  }
  if (!rb->isStaticObject() || rb->isKinematicObject()) {
    rb->setLinearVelocity(v);
    rb->setAngularVelocity(w);
  }
  if ((g - world_gravity).length() > 1e-5f * (world_gravity.length() + 1)) {
    rb->setFlags(rb->getFlags() | BT_DISABLE_WORLD_GRAVITY);
    rb->setGravity(g);
  } else {
    rb->setGravity(world_gravity);
  }
}

}  // namespace

Scene Scene::fromBulletFile(const std::string& path, const std::vector<std::string>& overrides) {
  return fromBulletBuffer(readFile(path, inputLimits().max_binary_bytes), path, overrides);
}

Scene Scene::fromBulletBuffer(const std::string& bytes, const std::string& origin,
                              const std::vector<std::string>& overrides) {
  if (bytes.size() > inputLimits().max_binary_bytes)
    throw InputError(origin + ": is " + std::to_string(bytes.size()) + " bytes, more than the limit of " +
                     std::to_string(inputLimits().max_binary_bytes) + " bytes");
  // Only a checked copy reaches Bullet's parser (bullet_file_check.h); the body count is known before it allocates.
  int64_t n_blocks = 0;
  std::string checked = bulletfile::sanitizeBulletFile(bytes, origin, inputLimits().max_compound_depth, &n_blocks);
  checkBodyBudget(n_blocks, origin);

  Scene scene;
  scene.source = origin;
  scene.format = "bullet";
  scene.name = fs::path(origin).stem().string();
  scene.owned_->importer = std::make_unique<SceneImporter>();
  SceneImporter& imp = *scene.owned_->importer;

  // Bullet's DNA scan reads a few bytes past the end it is given: padding, zeroed.
  const size_t length = checked.size();
  checked.append(64, '\0');
  bParse::btBulletFile file(&checked[0], int(length));
  if (!(file.getFlags() & bParse::FD_OK)) throw InputError(origin + ": not a readable .bullet file");
  if (!imp.loadFileFromMemory(&file)) throw InputError(origin + ": Bullet's importer could not read the file");

  // The checked copy holds rigid-body structs of the header's precision only.
  const bool dbl = (file.getFlags() & bParse::FD_DOUBLE_PRECISION) != 0;
  for (int i = 0; i < file.m_rigidBodies.size(); ++i) {
    btCollisionObject* made = imp.bodyFor(file.m_rigidBodies[i]);  // null where the importer skipped the body
    btRigidBody* rb = made ? btRigidBody::upcast(made) : nullptr;
    if (!rb) continue;
    if (dbl)
      restoreBodyState(rb, reinterpret_cast<const btRigidBodyDoubleData*>(file.m_rigidBodies[i]), imp.gravity_);
    else
      restoreBodyState(rb, reinterpret_cast<const btRigidBodyFloatData*>(file.m_rigidBodies[i]), imp.gravity_);
  }
  const int n = imp.getNumRigidBodies();
  if (n == 0) throw InputError(origin + ": the .bullet file holds no rigid bodies Bullet's importer can read");
  if (n != file.m_rigidBodies.size())
    throw InputError(origin + ": " + std::to_string(file.m_rigidBodies.size() - n) + " of " +
                     std::to_string(file.m_rigidBodies.size()) +
                     " rigid bodies have shapes Bullet's importer cannot read");
  if (!(std::isfinite(imp.gravity_.x()) && std::isfinite(imp.gravity_.y()) && std::isfinite(imp.gravity_.z())))
    throw InputError(origin + ": the world's gravity is not finite");
  for (int i = 0; i < n; ++i) {
    btRigidBody* rb = btRigidBody::upcast(imp.getRigidBodyByIndex(i));
    if (!rb) throw InputError(origin + ": object " + std::to_string(i) + " is not a rigid body");
    const char* nm = imp.getNameForPointer(rb);
    scene.names_.push_back(nm ? nm : "body" + std::to_string(i));
    checkLoadedBody(*rb, origin + ": rigid body " + std::to_string(i) + " (" + scene.names_.back() + ")");
    scene.bodies_.push_back(rb);
  }
  scene.settings = SceneSettings{};
  Vec3& g = scene.settings.system.step.gravity;
  g = Vec3{real(imp.gravity_.x()), real(imp.gravity_.y()), real(imp.gravity_.z())};
  scene.settings_json_ = json::object();
  scene.settings_json_["gravity"] = {g.x, g.y, g.z};
  for (const std::string& o : overrides) scene.applySettingOverride(o);
  return scene;
}

Scene Scene::load(const std::string& path, const std::vector<std::string>& overrides) {
  if (path.empty()) {
    Scene s = fromJsonText(defaultSceneJson(), "<default>", overrides);
    s.source = "<default>";
    s.format = "default";
    return s;
  }
  const std::string ext = lower(fs::path(path).extension().string());
  if (ext != ".json" && ext != ".bullet") {
    std::error_code ec;
    if (!fs::exists(path, ec)) throw InputError(path + ": no such file");
    throw InputError(path + ": unknown scene file extension '" + ext + "' (expected .json or .bullet)");
  }
  if (ext == ".bullet") return fromBulletFile(path, overrides);
  return fromJsonText(readFile(path, inputLimits().max_json_bytes), path, overrides);
}

// ---------------------------------------------------------------------------------------------------
// The embedded default: 2,000 mixed particles of 1-2 cm (spheres, boxes, cylinders, capsules,
// ellipsoids, cones, tetrahedra; sizes x0.8..1.2) dropped at 1 m/s from a jittered lattice into a
// 0.3 m x 0.3 m box; they land within 0.4 s and settle in about a second.
// ---------------------------------------------------------------------------------------------------
const char* Scene::defaultSceneJson() {
  return R"JSON({
  "name": "default-pile",
  "description": "Granular pile: 2000 mixed particles of 1-2 cm falling into a 0.3 m box",
  "settings": { "dt": 0.001, "time": 1.0, "solver": "apgd", "iterations": 50, "gravity": [0, -9.81, 0],
                "friction_combine": "product" },
  "bodies": [
    { "name": "ground", "shape": { "type": "plane", "normal": [0, 1, 0], "offset": 0 }, "mass": 0, "friction": 0.7 },
    { "name": "wall_px", "shape": { "type": "box", "half_extents": [0.01, 0.6, 0.17] }, "mass": 0, "position": [ 0.16, 0.6, 0], "friction": 0.7 },
    { "name": "wall_nx", "shape": { "type": "box", "half_extents": [0.01, 0.6, 0.17] }, "mass": 0, "position": [-0.16, 0.6, 0], "friction": 0.7 },
    { "name": "wall_pz", "shape": { "type": "box", "half_extents": [0.17, 0.6, 0.01] }, "mass": 0, "position": [0, 0.6,  0.16], "friction": 0.7 },
    { "name": "wall_nz", "shape": { "type": "box", "half_extents": [0.17, 0.6, 0.01] }, "mass": 0, "position": [0, 0.6, -0.16], "friction": 0.7 },
    { "generator": {
        "type": "pile", "name": "particle", "count": 2000, "footprint": [0.295, 0.295], "origin": [-0.1475, 0.002, -0.1475],
        "jitter": 0.05, "seed": 42, "scale": [0.8, 1.2], "density": 2500, "friction": 0.7, "velocity": [0, -1, 0],
        "shapes": [
          { "weight": 3, "shape": { "type": "sphere", "radius": 0.007 } },
          { "weight": 1, "shape": { "type": "box", "half_extents": [0.006, 0.005, 0.004] } },
          { "weight": 1, "shape": { "type": "cylinder", "radius": 0.005, "half_height": 0.006 } },
          { "weight": 1, "shape": { "type": "capsule", "radius": 0.004, "half_height": 0.004 } },
          { "weight": 1, "shape": { "type": "ellipsoid", "semi_axes": [0.008, 0.006, 0.005] } },
          { "weight": 0.5, "shape": { "type": "cone", "radius": 0.006, "height": 0.012 } },
          { "weight": 0.5, "shape": { "type": "convex_hull",
              "points": [[0.007, 0.007, 0.007], [-0.007, -0.007, 0.007], [-0.007, 0.007, -0.007], [0.007, -0.007, -0.007]] } }
        ] } }
  ]
})JSON";
}

}  // namespace dvi
