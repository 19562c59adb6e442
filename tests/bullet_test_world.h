// A Bullet world for the drop-in tests: stock btDiscreteDynamicsWorld or our DviDynamicsWorld (bullet_world.h),
// built the same way, with the shapes, bodies and constraints it owns.
#pragma once

#include <btBulletDynamicsCommon.h>

#include <memory>
#include <random>
#include <vector>

#include "chrono_like/bullet/bullet_world.h"
#include "chrono_like/solver/joints.h"
#include "gpu/gpu_factory.h"

namespace dvi {

// A Bullet world (plain, or ours) with the objects it needs.
struct TestWorld {
  btDefaultCollisionConfiguration config;
  btCollisionDispatcher dispatcher{&config};
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  std::unique_ptr<btDiscreteDynamicsWorld> world;
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<btRigidBody*> bodies;
  std::vector<std::unique_ptr<btTypedConstraint>> constraints;

  explicit TestWorld(bool dvi, WorldBackend backend = WorldBackend::Cpu) {
    if (dvi) {
      DviWorldConfig c;
      c.backend = backend;
      makeDvi(c);
    } else {
      world = std::make_unique<btDiscreteDynamicsWorld>(&dispatcher, &broadphase, &solver, &config);
    }
    world->setGravity(btVector3(0, btScalar(-9.81), 0));
  }
  explicit TestWorld(DviWorldConfig c) {  // our world with these settings
    makeDvi(c);
    world->setGravity(btVector3(0, btScalar(-9.81), 0));
  }
  TestWorld(bool dvi, btVector3 gravity, DviWorldConfig c) {  // ours with these settings, or stock Bullet
    if (dvi)
      makeDvi(c);
    else
      world = std::make_unique<btDiscreteDynamicsWorld>(&dispatcher, &broadphase, &solver, &config);
    world->setGravity(gravity);
  }
  void makeDvi(DviWorldConfig& c) {
    c.make_gpu_system = makeGpuSystem;
    c.gpu_available = gpuAvailable;
    world = std::make_unique<DviDynamicsWorld>(&dispatcher, &broadphase, &solver, &config, c);
  }
  ~TestWorld() {
    for (auto& c : constraints) world->removeConstraint(c.get());
    for (btRigidBody* b : bodies) {
      world->removeRigidBody(b);
      delete b->getMotionState();
      delete b;
    }
  }
  DviDynamicsWorld& dvi() { return static_cast<DviDynamicsWorld&>(*world); }
  btCollisionShape* own(btCollisionShape* s) {
    shapes.emplace_back(s);
    return s;
  }
  btRigidBody* make(btCollisionShape* s, btScalar mass, const btTransform& t, bool add = true) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) s->calculateLocalInertia(mass, inertia);
    auto* b = new btRigidBody(btRigidBody::btRigidBodyConstructionInfo(mass, new btDefaultMotionState(t), s, inertia));
    b->setActivationState(DISABLE_DEACTIVATION);
    if (add) {
      world->addRigidBody(b);
      bodies.push_back(b);
    }
    return b;
  }
  btRigidBody* make(btCollisionShape* s, btScalar mass, const btVector3& p, bool add = true) {
    return make(s, mass, btTransform(btQuaternion::getIdentity(), p), add);
  }
  btRigidBody* ground() {  // static box, top face at y = 0
    btRigidBody* g = make(own(new btBoxShape(btVector3(20, 1, 20))), 0, btVector3(0, -1, 0));
    g->setFriction(btScalar(0.8));
    return g;
  }
  template <class C>
  C* joint(C* c, bool disable_collisions = false) {
    constraints.emplace_back(c);
    world->addConstraint(c, disable_collisions);
    return c;
  }
  void run(double seconds, btScalar sub = btScalar(1) / 240) {
    const int frames = int(seconds * 60 + 0.5);
    for (int i = 0; i < frames; ++i) world->stepSimulation(btScalar(1) / 60, 10, sub);
  }
};

// Random rotations and vectors for the joint tests, and a body state advanced by its velocities over d (exact for the
// position, exponential map for the rotation).
inline Quat randomRotation(std::mt19937& rng) {
  std::normal_distribution<double> n(0, 1);
  return normalized(Quat{real(n(rng)), real(n(rng)), real(n(rng)), real(n(rng))});
}
inline Vec3 randomVec(std::mt19937& rng, double s) {
  std::uniform_real_distribution<double> u(-s, s);
  return Vec3{real(u(rng)), real(u(rng)), real(u(rng))};
}
inline JointBody advanced(JointBody b, real d) {
  b.x += b.v * d;
  b.q = normalized(quatFromRotationVector(b.w * d) * b.q);
  return b;
}
// A random joint side A (index 0): position within 2 m, any rotation, speeds up to 1.
inline JointBody randomJointSide(std::mt19937& rng) {
  JointBody A;
  A.index = 0;
  A.x = randomVec(rng, 2);
  A.q = randomRotation(rng);
  A.v = randomVec(rng, 1);
  A.w = randomVec(rng, 1);
  return A;
}
inline btTransform frame(const btVector3& p, const btQuaternion& q = btQuaternion::getIdentity()) {
  return btTransform(q, p);
}

}  // namespace dvi
