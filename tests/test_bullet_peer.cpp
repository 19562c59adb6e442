// The Bullet peer (Bullet's own world stepping copies of btRigidBodies, with length scaling) and the
// Bullet collision backend (Bullet's dispatcher on our shape records), against closed forms.
#include <btBulletDynamicsCommon.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <memory>
#include <vector>

#include "chrono_like/base/errors.h"
#include "chrono_like/bullet/bullet_collision_backend.h"
#include "chrono_like/bullet/bullet_peer.h"
#include "chrono_like/collision/collision.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/system.h"

using namespace dvi;

namespace {

// Owns Bullet bodies and shapes built by a test.
struct BulletScene {
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btRigidBody>> bodies;

  btCollisionShape* keep(btCollisionShape* s) {
    shapes.emplace_back(s);
    return s;
  }
  btRigidBody* add(btCollisionShape* shape, btScalar mass, const btVector3& pos,
                   const btQuaternion& rot = btQuaternion::getIdentity()) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) shape->calculateLocalInertia(mass, inertia);
    btRigidBody::btRigidBodyConstructionInfo info(mass, nullptr, shape, inertia);
    info.m_startWorldTransform = btTransform(rot, pos);
    bodies.emplace_back(new btRigidBody(info));
    return bodies.back().get();
  }
  std::vector<btRigidBody*> list() const {
    std::vector<btRigidBody*> v;
    for (auto& b : bodies) v.push_back(b.get());
    return v;
  }
};

}  // namespace

// Bullet integrates semi-implicitly: v_{n+1} = v_n + g dt, x_{n+1} = x_n + v_{n+1} dt, so after n steps
// y_n = y0 + g dt^2 n (n + 1) / 2 (not y0 + g t^2 / 2: they differ by g dt t / 2, here 0.049 m).
TEST_CASE("BulletPeer: free fall follows Bullet's semi-implicit Euler", "[bullet]") {
  BulletScene scene;
  scene.add(scene.keep(new btSphereShape(0.5f)), 1, btVector3(0, 10, 0));
  BulletPeerSettings st;
  st.dt = 0.01;
  BulletPeer peer(scene.list(), st);
  REQUIRE(peer.bodyCount() == 1);
  const int n = 100;
  for (int i = 0; i < n; ++i) peer.step();
  const double g = 9.81, dt = 0.01, t = n * dt;
  const double y_discrete = 10 - 0.5 * g * dt * dt * n * (n + 1);
  const double y_continuous = 10 - 0.5 * g * t * t;
  CHECK(std::abs(peer.position(0).y - y_discrete) < 1e-3);    // float round-off over 100 steps
  CHECK(std::abs(peer.position(0).y - y_continuous) > 0.04);  // the formula is really the discrete one
  CHECK(std::abs(peer.velocity(0).y - (-g * t)) < 1e-3);
  CHECK(std::abs(peer.position(0).x) < 1e-6);
  CHECK(peer.lastStats().contacts == 0);
  CHECK(peer.lastStats().wall_seconds >= 0);
  // the original body is untouched
  CHECK(scene.bodies[0]->getWorldTransform().getOrigin().y() == Approx(10.0f));
}

TEST_CASE("BulletPeer: sphere resting on a static plane stays within Bullet's margin", "[bullet]") {
  BulletScene scene;
  scene.add(scene.keep(new btStaticPlaneShape(btVector3(0, 1, 0), 0)), 0, btVector3(0, 0, 0));
  scene.add(scene.keep(new btSphereShape(0.5f)), 1, btVector3(0, 0.5f, 0));
  BulletPeerSettings st;  // dt 1e-3, 10 iterations, scale 1
  BulletPeer peer(scene.list(), st);
  for (int i = 0; i < 2000; ++i) peer.step();
  const double margin = 0.04;  // Bullet's default collision margin
  CHECK(std::abs(peer.position(1).y - 0.5) < margin);
  CHECK(std::abs(peer.velocity(1).y) < 0.05);
  CHECK(peer.lastStats().max_penetration < margin);
  CHECK(peer.position(0).y == 0);  // static plane did not move
}

TEST_CASE("BulletPeer: length_scale 100, a 1 cm sphere rests at the right height in scene units", "[bullet]") {
  BulletScene scene;
  scene.add(scene.keep(new btStaticPlaneShape(btVector3(0, 1, 0), 0)), 0, btVector3(0, 0, 0));
  scene.add(scene.keep(new btSphereShape(0.01f)), 1, btVector3(0.02f, 0.05f, -0.03f));
  BulletPeerSettings st;
  st.dt = 1e-3;
  st.length_scale = 100;
  BulletPeer peer(scene.list(), st);
  // Free fall first (contact at y = 0.01 after ~90 ms): scene units in and out.
  const int n = 50;
  for (int i = 0; i < n; ++i) peer.step();
  const double g = 9.81, dt = 1e-3;
  CHECK(std::abs(peer.position(1).y - (0.05 - 0.5 * g * dt * dt * n * (n + 1))) < 1e-5);
  CHECK(std::abs(peer.velocity(1).y - (-g * n * dt)) < 1e-4);
  CHECK(std::abs(peer.position(1).x - 0.02) < 1e-6);
  CHECK(std::abs(peer.position(1).z + 0.03) < 1e-6);
  for (int i = 0; i < 1000; ++i) peer.step();
  const double margin_scene = 0.04 / 100;  // Bullet's margin in scaled units, back in scene units
  CHECK(std::abs(peer.position(1).y - 0.01) < margin_scene);
  CHECK(std::abs(peer.velocity(1).y) < 0.01);
  CHECK(peer.lastStats().contacts >= 1);
  CHECK(peer.lastStats().max_penetration < margin_scene);
}

TEST_CASE("BulletPeer: a kinematic body moves with its velocity, in scene units", "[bullet]") {
  BulletScene scene;
  btRigidBody* k = scene.add(scene.keep(new btBoxShape(btVector3(0.1f, 0.1f, 0.1f))), 0, btVector3(0, 1, 0));
  k->setCollisionFlags(k->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
  k->setLinearVelocity(btVector3(0.5f, 0, 0));
  BulletPeerSettings st;
  st.length_scale = 100;
  BulletPeer peer(scene.list(), st);
  for (int i = 0; i < 200; ++i) peer.step();
  CHECK(std::abs(peer.position(0).x - 0.1) < 1e-5);
  CHECK(std::abs(peer.position(0).y - 1) < 1e-5);  // no gravity on a kinematic body
  CHECK(std::abs(peer.velocity(0).x - 0.5) < 1e-4);
}

TEST_CASE("BulletPeer: every supported shape clones, unsupported ones are refused by name", "[bullet]") {
  BulletScene scene;
  scene.add(scene.keep(new btStaticPlaneShape(btVector3(0, 1, 0), 0)), 0, btVector3(0, 0, 0));
  scene.add(scene.keep(new btBoxShape(btVector3(0.1f, 0.2f, 0.3f))), 1, btVector3(0, 1, 0));
  scene.add(scene.keep(new btCylinderShapeX(btVector3(0.2f, 0.1f, 0.1f))), 1, btVector3(1, 1, 0));
  scene.add(scene.keep(new btCylinderShapeZ(btVector3(0.1f, 0.1f, 0.2f))), 1, btVector3(2, 1, 0));
  scene.add(scene.keep(new btCapsuleShapeX(0.1f, 0.3f)), 1, btVector3(3, 1, 0));
  scene.add(scene.keep(new btCapsuleShapeZ(0.1f, 0.3f)), 1, btVector3(4, 1, 0));
  scene.add(scene.keep(new btConeShapeX(0.1f, 0.3f)), 1, btVector3(5, 1, 0));
  scene.add(scene.keep(new btConeShapeZ(0.1f, 0.3f)), 1, btVector3(6, 1, 0));
  {
    const btScalar pts[] = {0, 0, 0, 0.2f, 0, 0, 0, 0.2f, 0, 0, 0, 0.2f};
    scene.add(scene.keep(new btConvexHullShape(pts, 4, 3 * sizeof(btScalar))), 1, btVector3(7, 1, 0));
  }
  {
    btVector3 c(0, 0, 0);
    btScalar r = 1;
    auto* ms = new btMultiSphereShape(&c, &r, 1);
    ms->setLocalScaling(btVector3(0.1f, 0.2f, 0.15f));
    scene.add(scene.keep(ms), 1, btVector3(8, 1, 0));
  }
  {
    auto* comp = new btCompoundShape();
    scene.keep(comp);
    comp->addChildShape(btTransform(btQuaternion::getIdentity(), btVector3(0.1f, 0, 0)),
                        scene.keep(new btSphereShape(0.1f)));
    comp->addChildShape(btTransform(btQuaternion::getIdentity(), btVector3(-0.1f, 0, 0)),
                        scene.keep(new btBoxShape(btVector3(0.1f, 0.1f, 0.1f))));
    scene.add(comp, 1, btVector3(9, 1, 0));
  }
  BulletPeerSettings st;
  st.length_scale = 10;
  BulletPeer peer(scene.list(), st);
  REQUIRE(peer.bodyCount() == scene.bodies.size());
  for (int i = 0; i < 300; ++i) peer.step();  // 0.3 s: every body falls 0.44 m, none lands yet
  for (size_t i = 1; i < peer.bodyCount(); ++i) {
    const double x0 = double(i) - 1;
    CHECK(std::abs(peer.position(i).x - x0) < 1e-4);
    CHECK(peer.position(i).y < 0.6);
    CHECK(peer.position(i).y > 0.5);
  }

  BulletScene bad;
  bad.add(bad.keep(new btEmptyShape()), 1, btVector3(0, 0, 0));
  CHECK_THROWS_AS(BulletPeer(bad.list(), st), InputError);
  try {
    BulletPeer p(bad.list(), st);
  } catch (const InputError& e) { CHECK(std::string(e.what()).find("Empty") != std::string::npos); }
}

// ---------------------------------------------------------------------------------------------------
// Bullet collision backend on hand-built arrays.

namespace {

struct Arrays {
  BodyArrays bodies;
  ShapeArrays shapes;
  SystemConfig config;
  ContactArrays contacts;
  CollisionTimes times;
  std::unique_ptr<CollisionDetector> det = makeBulletCollision();

  int addBody(Vec3 pos, Quat rot, uint8_t flags, std::vector<ShapeDesc> descs) {
    const int b = int(bodies.count());
    bodies.resize(size_t(b) + 1);
    bodies.pos[size_t(b)] = pos;
    bodies.rot[size_t(b)] = rot;
    bodies.flags[size_t(b)] = flags;
    bodies.inv_mass[size_t(b)] = (flags & (kBodyFixed | kBodyKinematic)) ? 0 : 1;
    bodies.shape_start[size_t(b)] = int32_t(shapes.count());
    bodies.shape_count[size_t(b)] = int32_t(descs.size());
    real size = 1e30;
    for (ShapeDesc& d : descs) {
      d.shape.body = b;
      if (!d.hull.empty()) {
        d.shape.hull_start = int32_t(shapes.hull_points.size());
        shapes.hull_points.insert(shapes.hull_points.end(), d.hull.begin(), d.hull.end());
      }
      shapes.shape.push_back(d.shape);
      size = std::fmin(size, d.shape.size);
    }
    bodies.size[size_t(b)] = size;
    return b;
  }
  void detect() {
    det->detect(bodies, shapes, config.collision, makeStepContext(real(config.step.dt)), contacts, times);
  }
};

const Quat kId{1, 0, 0, 0};

bool near(Vec3 a, Vec3 b, double tol) { return length(a - b) < tol; }

// Invariants of every contact: unit normal, dist = dot(pb - pa, n), shape_a < shape_b, sorted keys.
void checkInvariants(const ContactArrays& c) {
  for (size_t k = 0; k < c.count(); ++k) {
    CHECK(std::abs(length(c.normal[k]) - 1) < 1e-5);
    CHECK(std::abs(dot(c.pb[k] - c.pa[k], c.normal[k]) - c.dist[k]) < 1e-5);
    CHECK(c.shape_a[k] < c.shape_b[k]);
    if (k > 0) CHECK(c.key[k - 1] < c.key[k]);
  }
}

}  // namespace

TEST_CASE("Bullet collision: sphere-sphere, normal A to B, distance and points in closed form", "[bullet]") {
  Arrays a;
  const Vec3 c0{0.1, 0.2, 0.3};
  a.addBody(c0, kId, 0, {makeSphere(0.5)});
  a.addBody({0, 0, 0}, kId, 0, {makeSphere(0.3)});
  CHECK(std::string(a.det->name()) == "bullet");
  const Vec3 dir = normalized(Vec3{1, 0.5, -0.25});
  // tolerance 1e-5: Bullet's sphere-sphere is exact, in float
  for (double gap : {-0.05, 0.01, -0.2}) {
    const Vec3 c1 = c0 + dir * (0.8 + gap);
    a.bodies.pos[1] = c1;
    a.detect();
    INFO("gap " << gap);
    REQUIRE(a.contacts.count() == 1);
    CHECK(a.contacts.shape_a[0] == 0);
    CHECK(a.contacts.shape_b[0] == 1);
    CHECK(a.contacts.body_a[0] == 0);
    CHECK(a.contacts.body_b[0] == 1);
    CHECK(near(a.contacts.normal[0], dir, 1e-5));
    CHECK(std::abs(a.contacts.dist[0] - gap) < 1e-5);
    CHECK(near(a.contacts.pa[0], c0 + dir * 0.5, 1e-5));
    CHECK(near(a.contacts.pb[0], c1 - dir * 0.3, 1e-5));
    CHECK(a.contacts.key[0] == contactKey(0, 1, 0));
    checkInvariants(a.contacts);
  }
  // Beyond the envelope (0.05 x 0.3 = 0.015): no contact.
  a.bodies.pos[1] = c0 + dir * 0.82;
  a.detect();
  CHECK(a.contacts.count() == 0);
  // AABBs: the sphere's box grown by envelope_rel x radius.
  CHECK(std::abs(a.shapes.aabb[0].hi.x - (c0.x + 0.5 + 0.025)) < 1e-5);
  CHECK(std::abs(a.shapes.aabb[1].lo.y - (a.bodies.pos[1].y - 0.3 - 0.015)) < 1e-5);
  CHECK(a.times.pairs >= 1);
}

TEST_CASE("Bullet collision: sphere-plane, flat and tilted", "[bullet]") {
  Arrays a;
  a.addBody({0, 0, 0}, kId, kBodyFixed, {makePlane({0, 1, 0}, 0)});
  a.addBody({0.2, 0.45, -0.1}, kId, 0, {makeSphere(0.5)});
  a.detect();
  REQUIRE(a.contacts.count() == 1);
  // A = the plane (shape 0), B = the sphere: normal = plane normal (Bullet's manifold has them the
  // other way round, body0 = the sphere, so this also checks the swap).
  CHECK(a.contacts.shape_a[0] == 0);
  CHECK(a.contacts.shape_b[0] == 1);
  CHECK(near(a.contacts.normal[0], {0, 1, 0}, 1e-6));
  CHECK(std::abs(a.contacts.dist[0] + 0.05) < 1e-6);
  CHECK(near(a.contacts.pa[0], {0.2, 0, -0.1}, 1e-6));
  CHECK(near(a.contacts.pb[0], {0.2, -0.05, -0.1}, 1e-6));
  checkInvariants(a.contacts);
  CHECK(a.shapes.aabb[0].hi.x >= 1e30);  // planes: unbounded box, as the native backend

  // Tilted plane dot(n, x) <= 0.3 and a sphere 0.02 inside it.
  Arrays t;
  const Vec3 n = normalized(Vec3{1, 2, -0.5});
  t.addBody({0, 0, 0}, kId, kBodyFixed, {makePlane(n, 0.3)});
  const Vec3 c = Vec3{0.4, -0.7, 0.9} + n * (0.3 - dot(n, Vec3{0.4, -0.7, 0.9}) + 0.25 - 0.02);
  t.addBody(c, kId, 0, {makeSphere(0.25)});
  t.detect();
  REQUIRE(t.contacts.count() == 1);
  CHECK(near(t.contacts.normal[0], n, 1e-5));
  CHECK(std::abs(t.contacts.dist[0] + 0.02) < 1e-5);
  CHECK(near(t.contacts.pb[0], c - n * 0.25, 1e-5));
  CHECK(std::abs(dot(t.contacts.pa[0], n) - 0.3) < 1e-5);
}

TEST_CASE("Bullet collision: box on a plane gets its bottom corners in one call", "[bullet]") {
  Arrays a;
  a.addBody({0, 0, 0}, kId, kBodyFixed, {makePlane({0, 1, 0}, 0)});
  const Vec3 half{0.5, 0.25, 0.4};
  a.addBody({1, 0.24, 2}, kId, 0, {makeBox(half)});
  a.detect();
  // Box margin m = 0.04 x 0.25 = 0.01: Bullet's support points lie on the rounded box, so corner
  // positions are within m of the exact corners; distances are exact to 1e-4.
  const double m = 0.01;
  INFO("contacts " << a.contacts.count());
  REQUIRE(a.contacts.count() >= 3);
  for (size_t k = 0; k < a.contacts.count(); ++k) {
    CHECK(near(a.contacts.normal[k], {0, 1, 0}, 1e-5));
    CHECK(std::abs(a.contacts.dist[k] + 0.01) < 1e-4);
    const Vec3 p = a.contacts.pb[k] - Vec3{1, 0, 2};
    CHECK(std::abs(std::abs(p.x) - half.x) < 1.5 * m);
    CHECK(std::abs(std::abs(p.z) - half.z) < 1.5 * m);
    CHECK(std::abs(p.y + 0.01) < 1e-4);
    CHECK(std::abs(a.contacts.pa[k].y) < 1e-5);
  }
  checkInvariants(a.contacts);
  // Persistent objects: a second call with the same poses gives the same contacts and keys.
  std::vector<uint64_t> keys = a.contacts.key;
  a.detect();
  CHECK(a.contacts.key == keys);

  // Tilted box (rotated about z): one lowest edge, distance = its height.
  Arrays t;
  t.addBody({0, 0, 0}, kId, kBodyFixed, {makePlane({0, 1, 0}, 0)});
  const Quat q = quatFromAxisAngle({0, 0, 1}, 0.3);
  // lowest y of the rotated box relative to its centre: -(|R10| hx + |R11| hy + |R12| hz)
  const Mat33 R = matFromQuat(q);
  const double low = std::abs(R.r1.x) * half.x + std::abs(R.r1.y) * half.y + std::abs(R.r1.z) * half.z;
  t.addBody({0, low - 0.005, 0}, q, 0, {makeBox(half)});
  t.detect();
  REQUIRE(t.contacts.count() >= 1);
  double deepest = 0;
  for (size_t k = 0; k < t.contacts.count(); ++k) deepest = std::fmin(deepest, t.contacts.dist[k]);
  CHECK(std::abs(deepest + 0.005) < 2e-4);  // corner rounded by the margin: within m (1 - cos) of exact
}

TEST_CASE("Bullet collision: sphere-box (GJK), separated within the envelope and penetrating", "[bullet]") {
  Arrays a;
  a.addBody({0, 0, 0}, kId, kBodyFixed, {makeBox({0.5, 0.5, 0.5})});
  a.addBody({0.1, 0.81, -0.2}, kId, 0, {makeSphere(0.3)});
  a.detect();
  // GJK on the sphere centre and the box shrunk by its margin, margins added back: tolerance 1e-4.
  REQUIRE(a.contacts.count() == 1);
  CHECK(near(a.contacts.normal[0], {0, 1, 0}, 1e-4));
  CHECK(std::abs(a.contacts.dist[0] - 0.01) < 1e-4);  // envelope 0.05 x 0.3 = 0.015
  CHECK(near(a.contacts.pa[0], {0.1, 0.5, -0.2}, 1e-4));
  CHECK(near(a.contacts.pb[0], {0.1, 0.51, -0.2}, 1e-4));
  a.bodies.pos[1] = {0.1, 0.2, 0.78};  // EPA: 0.02 into the +z face
  a.detect();
  REQUIRE(a.contacts.count() >= 1);
  for (size_t k = 0; k < a.contacts.count(); ++k) {
    CHECK(near(a.contacts.normal[k], {0, 0, 1}, 1e-3));
    CHECK(std::abs(a.contacts.dist[k] + 0.02) < 1e-3);  // EPA converges to ~1e-4 here; 1e-3 allowed
  }
  checkInvariants(a.contacts);
  // A body added between calls (shape count changes): objects rebuilt, its contact appears.
  a.addBody({0.1, 0.2, 1.35}, kId, 0, {makeSphere(0.3)});
  a.detect();
  bool found = false;
  for (size_t k = 0; k < a.contacts.count(); ++k)
    if (a.contacts.shape_a[k] == 1 && a.contacts.shape_b[k] == 2) {
      found = true;
      CHECK(std::abs(a.contacts.dist[k] + 0.03) < 1e-5);
    }
  CHECK(found);
}

TEST_CASE("Bullet collision: box-box face contact", "[bullet]") {
  Arrays a;
  a.addBody({0, 0, 0}, kId, kBodyFixed, {makeBox({0.5, 0.5, 0.5})});
  a.addBody({0.05, 0.78, -0.1}, kId, 0, {makeBox({0.3, 0.3, 0.3})});
  a.detect();
  // ODE's box-box (btBoxBoxDetector) on exact extents: tolerance 1e-4.
  REQUIRE(a.contacts.count() >= 3);
  for (size_t k = 0; k < a.contacts.count(); ++k) {
    CHECK(near(a.contacts.normal[k], {0, 1, 0}, 1e-4));
    CHECK(std::abs(a.contacts.dist[k] + 0.02) < 1e-4);
    CHECK(std::abs(a.contacts.pa[k].y - 0.5) < 1e-4);
    CHECK(std::abs(a.contacts.pb[k].y - 0.48) < 1e-4);
    CHECK(std::abs(a.contacts.pb[k].x - 0.05) <= 0.3 + 1e-4);
    CHECK(std::abs(a.contacts.pb[k].z + 0.1) <= 0.3 + 1e-4);
  }
  checkInvariants(a.contacts);

  // The small box on top, rotated 45 degrees about y: same normal and depth.
  a.bodies.rot[1] = quatFromAxisAngle({0, 1, 0}, 0.785398);
  a.detect();
  REQUIRE(a.contacts.count() >= 3);
  for (size_t k = 0; k < a.contacts.count(); ++k) {
    CHECK(near(a.contacts.normal[k], {0, 1, 0}, 1e-4));
    CHECK(std::abs(a.contacts.dist[k] + 0.02) < 1e-4);
  }
  checkInvariants(a.contacts);

  // Side contact: B to the -x of A, so the normal A->B is -x.
  a.bodies.rot[1] = kId;
  a.bodies.pos[1] = {-0.79, 0, 0};
  a.detect();
  REQUIRE(a.contacts.count() >= 1);
  for (size_t k = 0; k < a.contacts.count(); ++k) {
    CHECK(near(a.contacts.normal[k], {-1, 0, 0}, 1e-4));
    CHECK(std::abs(a.contacts.dist[k] + 0.01) < 1e-4);
  }
}

TEST_CASE("Bullet collision: compounds map children to shapes, filters as pairAllowed", "[bullet]") {
  Arrays a;
  a.addBody({0, 0, 0}, kId, kBodyFixed, {makePlane({0, 1, 0}, 0)});
  // One body with two overlapping spheres (never in contact with each other) resting on the plane.
  a.addBody({0, 0.29, 0}, kId, 0,
            {makeSphere(0.3, Pose{{-0.2, 0, 0}, kId}), makeSphere(0.2, Pose{{0.25, -0.13, 0}, kId})});
  a.detect();
  REQUIRE(a.contacts.count() == 2);
  CHECK(a.contacts.shape_a[0] == 0);
  CHECK(a.contacts.shape_b[0] == 1);
  CHECK(a.contacts.shape_b[1] == 2);
  CHECK(std::abs(a.contacts.dist[0] + 0.01) < 1e-5);
  CHECK(std::abs(a.contacts.dist[1] + 0.04) < 1e-5);
  CHECK(near(a.contacts.pb[0], {-0.2, -0.01, 0}, 1e-5));
  CHECK(near(a.contacts.pb[1], {0.25, -0.04, 0}, 1e-5));
  checkInvariants(a.contacts);

  // Two fixed bodies never collide; group/mask mismatch filters a pair.
  Arrays f;
  f.addBody({0, 0, 0}, kId, kBodyFixed, {makeSphere(0.5)});
  f.addBody({0.9, 0, 0}, kId, kBodyFixed, {makeSphere(0.5)});
  f.detect();
  CHECK(f.contacts.count() == 0);
  f.bodies.flags[1] = 0;  // now dynamic: rebuild, collides
  f.detect();
  CHECK(f.contacts.count() == 1);
  f.shapes.shape[1].group = 2;
  f.shapes.shape[0].mask = 1;  // A does not accept group 2
  f.detect();
  CHECK(f.contacts.count() == 0);
}

TEST_CASE("Bullet collision backend inside System: resting heights as the native backend", "[bullet]") {
  for (CollisionBackend be : {CollisionBackend::Native, CollisionBackend::Bullet}) {
    SystemConfig c;
    c.collision.backend = be;
    c.step.dt = 1e-3;
    c.threads = 1;  // 4 bodies: OpenMP barriers would cost more than the step on a loaded 2-core host
    System s(c, makeBulletCollision);
    BodyDesc g;
    g.flags = kBodyFixed;
    g.mass = 0;
    g.inertia = {0, 0, 0};
    g.shapes.push_back(makePlane({0, 1, 0}, 0));
    s.addBody(g);
    BodyDesc sphere;
    sphere.pos = {0, 0.05, 0};
    sphere.inertia = {4e-5, 4e-5, 4e-5};
    sphere.shapes.push_back(makeSphere(0.01));
    s.addBody(sphere);
    BodyDesc box;
    box.pos = {0.1, 0.03, 0};
    box.inertia = {1e-4, 1e-4, 1e-4};
    box.shapes.push_back(makeBox({0.02, 0.01, 0.02}));
    s.addBody(box);
    BodyDesc pair;  // two spheres on one body (a compound in Bullet)
    pair.pos = {0.2, 0.05, 0};
    pair.inertia = {1e-4, 1e-4, 1e-4};
    pair.shapes.push_back(makeSphere(0.01, Pose{{-0.01, 0, 0}, {1, 0, 0, 0}}));
    pair.shapes.push_back(makeSphere(0.01, Pose{{0.01, 0, 0}, {1, 0, 0, 0}}));
    s.addBody(pair);
    s.advance(1000);
    INFO((be == CollisionBackend::Bullet ? "bullet" : "native"));
    for (size_t i = 1; i <= 3; ++i) {
      CHECK(std::abs(s.bodies().pos[i].y - 0.01) < 2e-4);  // 2% of the size
      CHECK(length(s.bodies().vel[i]) < 1e-3);
    }
    CHECK(s.lastStats().max_penetration < 2e-4);
  }
}

TEST_CASE("Bullet collision backend: the System builds it only through the factory its caller passes", "[bullet]") {
  SystemConfig c;
  c.collision.backend = CollisionBackend::Bullet;
  CHECK_THROWS_AS(System{c}, InputError);
  CHECK_NOTHROW(System{c, makeBulletCollision});
  c.collision.backend = CollisionBackend::Native;
  CHECK_NOTHROW(System{c});
}
