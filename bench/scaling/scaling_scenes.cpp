// Benchmark scenes (scaling_scenes.h).
#include "scaling_scenes.h"

#include <btBulletDynamicsCommon.h>
#include <BulletCollision/CollisionShapes/btMultiSphereShape.h>

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "chrono_like/base/random.h"
#include "chrono_like/collision/collision.h"

namespace dvi::bench {

namespace {

constexpr double kDensity = 2500;  // glass
constexpr double kPi = 3.14159265358979323846;

// Deterministic uniform numbers in [0, 1): SplitMix64 (chrono_like/base/random.h), the same on every platform.
struct Rng : SplitMix64 {
  explicit Rng(uint64_t seed) { s = seed; }
  double next() { return uniform(); }
};

Quat aboutY(double angle) { return Quat{real(std::cos(angle / 2)), 0, real(std::sin(angle / 2)), 0}; }

void sphereBody(BodySpec& b, double r) {
  b.kind = BodyKind::Sphere;
  b.dims = Vec3{real(r), real(r), real(r)};
  const double m = kDensity * 4.0 / 3.0 * kPi * r * r * r;
  b.mass = real(m);
  b.inertia = Vec3{real(0.4 * m * r * r), real(0.4 * m * r * r), real(0.4 * m * r * r)};
}

void ellipsoidInertia(BodySpec& b, double a, double c_y, double c) {
  const double m = double(b.mass);
  b.inertia = Vec3{real(m / 5 * (c_y * c_y + c * c)), real(m / 5 * (a * a + c * c)), real(m / 5 * (a * a + c_y * c_y))};
}

}  // namespace

const char* bodyKindName(BodyKind k) {
  switch (k) {
    case BodyKind::Sphere: return "sphere";
    case BodyKind::Box: return "box";
    case BodyKind::Cylinder: return "cylinder";
    case BodyKind::Ellipsoid: return "ellipsoid";
    case BodyKind::Hull: return "hull";
  }
  return "?";
}

SceneSpec makePileSpec(long n, real mu) {
  SceneSpec s;
  s.name = "pile";
  s.friction = real(std::sqrt(double(mu)));
  const double r = 0.01;
  s.ref_length = real(r);
  const long side = std::max(1L, long(std::ceil(std::cbrt(double(n) / 2.0))));  // height ~ 2 x width
  const double pitch = 2.0 * r * 1.05, vpitch = 2.0 * r * 1.001;
  s.width = real(side * pitch);
  const long layers = (n + side * side - 1) / (side * side);
  s.wall_height = real(1.2 * (double(layers) * vpitch + r));
  s.wall_thickness = real(0.05);
  Rng rng(42);
  s.bodies.resize(size_t(std::max(0L, n)));
  for (long i = 0; i < n; ++i) {
    BodySpec& b = s.bodies[size_t(i)];
    sphereBody(b, r);
    const long layer = i / (side * side), in = i % (side * side);
    const double jx = rng.uniform(-0.04 * r, 0.04 * r), jz = rng.uniform(-0.04 * r, 0.04 * r);
    b.pos = Vec3{real((double(in % side) + 0.5) * pitch + jx), real(r * 1.001 + double(layer) * vpitch),
                 real((double(in / side) + 0.5) * pitch + jz)};
  }
  return s;
}

SceneSpec makeMixSpec(long n, real mu) {
  SceneSpec s;
  s.name = "mix";
  s.friction = real(std::sqrt(double(mu)));
  const double smin = 0.005, smax = 0.02;  // characteristic size (largest half extent), a factor 4
  s.ref_length = real(smin);
  Rng rng(7);
  // Convex hull prototypes: 16 points on a unit sphere (Fibonacci spiral), squashed per prototype, with
  // the largest horizontal radius 1 so a hull of size s fits the column like the other shapes.
  for (int p = 0; p < 8; ++p) {
    const double ay = rng.uniform(0.6, 1.0), az = rng.uniform(0.7, 1.0);
    std::vector<Vec3> pts;
    double rh = 0;
    const int k = 16;
    for (int i = 0; i < k; ++i) {
      const double y = 1.0 - 2.0 * (i + 0.5) / k, rr = std::sqrt(1 - y * y);
      const double phi = i * 2.399963229728653 + p;  // golden angle
      const Vec3 q{real(rr * std::cos(phi)), real(y * ay), real(rr * std::sin(phi) * az)};
      rh = std::max(rh, std::sqrt(double(q.x * q.x + q.z * q.z)));
      pts.push_back(q);
    }
    for (Vec3& q : pts) q = Vec3{real(q.x / rh), q.y, real(q.z / rh)};
    s.hulls.push_back(std::move(pts));
  }
  const double pitch = 2.0 * smax * 1.05;
  const long side = std::max(1L, long(std::ceil(std::cbrt(0.2 * double(n)))));  // height ~ 2 x width
  const long cols = side * side;
  s.width = real(side * pitch);
  s.wall_thickness = real(0.05);
  std::vector<double> top(size_t(cols), 0.0);
  s.bodies.resize(size_t(std::max(0L, n)));
  for (long i = 0; i < n; ++i) {
    BodySpec& b = s.bodies[size_t(i)];
    const double size = smin * std::pow(smax / smin, rng.next());
    const int kind = int(rng.next() * 5) % 5;
    double half_y = size;  // vertical half extent (rotations are about y only)
    switch (kind) {
      case 0: sphereBody(b, size); break;
      case 1: {
        const double hx = size * rng.uniform(0.5, 0.7), hy = size * rng.uniform(0.5, 1.0),
                     hz = size * rng.uniform(0.5, 0.7);
        b.kind = BodyKind::Box;
        b.dims = Vec3{real(hx), real(hy), real(hz)};
        const double m = kDensity * 8 * hx * hy * hz;
        b.mass = real(m);
        b.inertia = Vec3{real(m / 3 * (hy * hy + hz * hz)), real(m / 3 * (hx * hx + hz * hz)),
                         real(m / 3 * (hx * hx + hy * hy))};
        half_y = hy;
        break;
      }
      case 2: {
        const double r = size * rng.uniform(0.6, 1.0), hh = size * rng.uniform(0.5, 1.0);
        b.kind = BodyKind::Cylinder;
        b.dims = Vec3{real(r), real(hh), real(r)};
        const double m = kDensity * kPi * r * r * 2 * hh;
        b.mass = real(m);
        const double ix = m * (3 * r * r + 4 * hh * hh) / 12;
        b.inertia = Vec3{real(ix), real(0.5 * m * r * r), real(ix)};
        half_y = hh;
        break;
      }
      case 3: {
        const double a = size, cy = size * rng.uniform(0.5, 1.0), c = size * rng.uniform(0.6, 1.0);
        b.kind = BodyKind::Ellipsoid;
        b.dims = Vec3{real(a), real(cy), real(c)};
        b.mass = real(kDensity * 4.0 / 3.0 * kPi * a * cy * c);
        ellipsoidInertia(b, a, cy, c);
        half_y = cy;
        break;
      }
      default: {
        b.kind = BodyKind::Hull;
        b.hull = int(rng.next() * double(s.hulls.size())) % int(s.hulls.size());
        b.dims = Vec3{real(size), real(size), real(size)};  // scale of the prototype
        Vec3 lo{1e9, 1e9, 1e9}, hi{-1e9, -1e9, -1e9};
        for (const Vec3& q : s.hulls[size_t(b.hull)]) lo = vmin(lo, q), hi = vmax(hi, q);
        // Mass and inertia of the ellipsoid inscribed in the hull's bounding box (a hull of 16 points on
        // an ellipsoid is close to it); every engine gets these same values.
        const double a = 0.5 * size * double(hi.x - lo.x), cy = 0.5 * size * double(hi.y - lo.y),
                     c = 0.5 * size * double(hi.z - lo.z);
        b.mass = real(kDensity * 4.0 / 3.0 * kPi * a * cy * c);
        ellipsoidInertia(b, a, cy, c);
        half_y = size * std::max(std::fabs(double(lo.y)), std::fabs(double(hi.y)));
        break;
      }
    }
    b.rot = aboutY(rng.uniform(0, 2 * kPi));
    const long col = i % cols;
    const double jx = rng.uniform(-0.1, 0.1) * size, jz = rng.uniform(-0.1, 0.1) * size;
    const double y = top[size_t(col)] + 1e-5 + half_y;  // 10 um above the body below (or the ground)
    top[size_t(col)] = y + half_y;
    b.pos = Vec3{real((double(col % side) + 0.5) * pitch + jx), real(y), real((double(col / side) + 0.5) * pitch + jz)};
  }
  s.wall_height = real(1.2 * (*std::max_element(top.begin(), top.end()) + smax));
  return s;
}

SceneSpec makeSceneSpec(const std::string& name, long n) {
  if (name == "pile") return makePileSpec(n);
  if (name == "mix") return makeMixSpec(n);
  throw InputError("unknown benchmark scene '" + name + "' (expected pile or mix)");
}

namespace {

// The 42 vertices of a unit icosphere: an icosahedron with each edge split once, pushed onto the sphere.
std::vector<Vec3> unitIcosphere() {
  const double phi = (1 + std::sqrt(5.0)) / 2;
  std::vector<Vec3> v;
  for (double a : {-1.0, 1.0})
    for (double b : {-phi, phi}) {
      v.push_back(Vec3{0, real(a), real(b)});
      v.push_back(Vec3{real(a), real(b), 0});
      v.push_back(Vec3{real(b), 0, real(a)});
    }
  const size_t corners = v.size();
  for (size_t i = 0; i < corners; ++i)
    for (size_t j = i + 1; j < corners; ++j)
      if (std::fabs(double(dot(v[i] - v[j], v[i] - v[j])) - 4.0) < 1e-6)
        v.push_back(v[i] + v[j]);  // edges have length 2
  for (Vec3& p : v) p = p / length(p);
  return v;  // 12 corners + 30 edge midpoints
}

std::vector<Vec3> unitCylinderHull() {  // radius 1, half height 1, axis y
  std::vector<Vec3> p;
  for (int i = 0; i < kCylinderSides; ++i) {
    const double a = 2 * kPi * i / kCylinderSides;
    for (real y : {real(-1), real(1)}) p.push_back(Vec3{real(std::cos(a)), y, real(std::sin(a))});
  }
  return p;
}

}  // namespace

SceneSpec withConvexHulls(const SceneSpec& spec) {
  SceneSpec out = spec;
  const int cylinder = int(out.hulls.size()), ellipsoid = cylinder + 1;
  out.hulls.push_back(unitCylinderHull());
  out.hulls.push_back(unitIcosphere());
  for (BodySpec& b : out.bodies) {
    if (b.kind == BodyKind::Cylinder) {
      b.kind = BodyKind::Hull;
      b.hull = cylinder;
      b.dims = Vec3{b.dims.x, b.dims.y, b.dims.x};
    } else if (b.kind == BodyKind::Ellipsoid) {
      b.kind = BodyKind::Hull;
      b.hull = ellipsoid;
    }
  }
  return out;
}

std::vector<WallSpec> containerWalls(const SceneSpec& s) {
  const real w = s.width, h = s.wall_height, t = s.wall_thickness;
  return {{Vec3{-t, h / 2, w / 2}, Vec3{t, h / 2, w / 2 + 2 * t}},
          {Vec3{w + t, h / 2, w / 2}, Vec3{t, h / 2, w / 2 + 2 * t}},
          {Vec3{w / 2, h / 2, -t}, Vec3{w / 2 + 2 * t, h / 2, t}},
          {Vec3{w / 2, h / 2, w + t}, Vec3{w / 2 + 2 * t, h / 2, t}}};
}

std::vector<BodyDesc> bodyDescs(const SceneSpec& spec) {
  std::vector<BodyDesc> out;
  out.reserve(size_t(kStaticBodies) + spec.bodies.size());
  BodyDesc g;
  g.mass = 0;
  g.flags = kBodyFixed;
  g.friction = spec.friction;
  g.shapes.push_back(makePlane(Vec3{0, 1, 0}, 0));
  out.push_back(g);
  for (const WallSpec& w : containerWalls(spec)) {
    g.shapes.clear();
    g.shapes.push_back(makeBox(w.half));
    g.pos = w.centre;
    out.push_back(g);
  }
  BodyDesc d;
  d.friction = spec.friction;
  d.shapes.resize(1);
  for (const BodySpec& b : spec.bodies) {
    switch (b.kind) {
      case BodyKind::Sphere: d.shapes[0] = makeSphere(b.dims.x); break;
      case BodyKind::Box: d.shapes[0] = makeBox(b.dims); break;
      case BodyKind::Cylinder: d.shapes[0] = makeCylinder(b.dims.x, b.dims.y); break;
      case BodyKind::Ellipsoid: d.shapes[0] = makeEllipsoid(b.dims); break;
      case BodyKind::Hull: {
        std::vector<Vec3> pts = spec.hulls[size_t(b.hull)];
        for (Vec3& q : pts) q = Vec3{q.x * b.dims.x, q.y * b.dims.y, q.z * b.dims.z};
        d.shapes[0] = makeConvexHull(std::move(pts));
        break;
      }
    }
    d.pos = b.pos;
    d.rot = b.rot;
    d.mass = b.mass;
    d.inertia = b.inertia;
    out.push_back(d);
  }
  return out;
}

void addToSystem(const SceneSpec& spec, System& sys) {
  for (const BodyDesc& d : bodyDescs(spec)) sys.addBody(d);
}

real deepestPenetration(const SceneSpec& spec, const std::vector<Vec3>& pos, const std::vector<Quat>& rot) {
  if (pos.size() != spec.bodies.size() || rot.size() != spec.bodies.size())
    throw InputError("deepestPenetration: " + std::to_string(pos.size()) + " positions and " +
                     std::to_string(rot.size()) + " rotations for " + std::to_string(spec.bodies.size()) + " bodies");
  SystemConfig cfg;
  cfg.collision.speculative = false;  // poses only: no sweep, the envelope alone decides which pairs are tested
  System sys(cfg);
  addToSystem(spec, sys);
  BodyArrays bodies = sys.bodies();
  for (size_t i = 0; i < pos.size(); ++i) {
    const Vec3 p = pos[i];
    const Quat q = rot[i];
    if (!std::isfinite(double(p.x + p.y + p.z)) || !std::isfinite(double(q.w + q.x + q.y + q.z)))
      throw InputError("deepestPenetration: body " + std::to_string(i) + " has a non-finite pose");
    const size_t b = size_t(kStaticBodies) + i;
    bodies.pos[b] = p;
    bodies.rot[b] = q;
    bodies.vel[b] = Vec3{0, 0, 0};
    bodies.omega[b] = Vec3{0, 0, 0};
  }
  ShapeArrays shapes = sys.shapes();
  ContactArrays contacts;
  CollisionTimes times;
  makeNativeCollision(cfg.collision.broadphase)
      ->detect(bodies, shapes, cfg.collision, makeStepContext(real(cfg.step.dt)), contacts, times);
  real deepest = 0;
  for (size_t k = 0; k < contacts.count(); ++k) deepest = std::max(deepest, -contacts.dist[k]);
  return deepest;
}

struct BulletScene::Owned {
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btRigidBody>> bodies;
};

BulletScene::BulletScene() : owned(std::make_unique<Owned>()) {}
BulletScene::~BulletScene() = default;
BulletScene::BulletScene(BulletScene&&) noexcept = default;
BulletScene& BulletScene::operator=(BulletScene&&) noexcept = default;

BulletScene makeBulletScene(const SceneSpec& spec) {
  BulletScene out;
  auto& own = *out.owned;
  auto bt = [](Vec3 v) { return btVector3(btScalar(v.x), btScalar(v.y), btScalar(v.z)); };
  auto add = [&](btCollisionShape* shape, double mass, btVector3 inertia, btVector3 pos, btQuaternion rot) {
    btRigidBody::btRigidBodyConstructionInfo info(btScalar(mass), nullptr, shape, inertia);
    info.m_startWorldTransform.setOrigin(pos);
    info.m_startWorldTransform.setRotation(rot);
    info.m_friction = btScalar(spec.friction);  // Bullet's product rule, as ours
    own.bodies.emplace_back(new btRigidBody(info));
    out.bodies.push_back(own.bodies.back().get());
  };
  const btQuaternion identity(0, 0, 0, 1);
  own.shapes.emplace_back(new btStaticPlaneShape(btVector3(0, 1, 0), 0));
  add(own.shapes.back().get(), 0, btVector3(0, 0, 0), btVector3(0, 0, 0), identity);
  for (const WallSpec& w : containerWalls(spec)) {
    own.shapes.emplace_back(new btBoxShape(bt(w.half)));
    add(own.shapes.back().get(), 0, btVector3(0, 0, 0), bt(w.centre), identity);
  }
  btCollisionShape* shared_sphere = nullptr;  // the pile's spheres share one shape
  for (const BodySpec& b : spec.bodies) {
    btCollisionShape* shape = nullptr;
    switch (b.kind) {
      case BodyKind::Sphere:
        if (shared_sphere && spec.name == "pile") {
          shape = shared_sphere;
        } else {
          own.shapes.emplace_back(new btSphereShape(btScalar(b.dims.x)));
          shape = own.shapes.back().get();
          if (spec.name == "pile") shared_sphere = shape;
        }
        break;
      case BodyKind::Box:
        own.shapes.emplace_back(new btBoxShape(bt(b.dims)));
        shape = own.shapes.back().get();
        break;
      case BodyKind::Cylinder:
        own.shapes.emplace_back(new btCylinderShape(bt(b.dims)));  // axis y, half extents (r, hh, r)
        shape = own.shapes.back().get();
        break;
      case BodyKind::Ellipsoid: {
        const btVector3 centre(0, 0, 0);
        const btScalar radius = 1;
        auto* ms = new btMultiSphereShape(&centre, &radius, 1);
        ms->setLocalScaling(bt(b.dims));  // a unit sphere scaled per axis: the ellipsoid
        own.shapes.emplace_back(ms);
        shape = ms;
        break;
      }
      case BodyKind::Hull: {
        auto* h = new btConvexHullShape();
        for (const Vec3& q : spec.hulls[size_t(b.hull)])
          h->addPoint(bt(Vec3{q.x * b.dims.x, q.y * b.dims.y, q.z * b.dims.z}), false);
        h->recalcLocalAabb();
        own.shapes.emplace_back(h);
        shape = h;
        break;
      }
    }
    add(shape, double(b.mass), bt(b.inertia), bt(b.pos),
        btQuaternion(btScalar(b.rot.x), btScalar(b.rot.y), btScalar(b.rot.z), btScalar(b.rot.w)));
  }
  return out;
}

}  // namespace dvi::bench
