// A stock Bullet world (btDiscreteDynamicsWorld, gravity 9.81 m/s^2 along -y) that owns its shapes and bodies: the
// scenes the tests and the fuzz seed generator (tests/fuzz/make_seeds.cpp) build and have Bullet serialise.
#pragma once

#include <btBulletDynamicsCommon.h>

#include <memory>
#include <vector>

namespace dvi {

struct StockBulletWorld {
  btDefaultCollisionConfiguration config;
  btCollisionDispatcher dispatcher{&config};
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  btDiscreteDynamicsWorld world{&dispatcher, &broadphase, &solver, &config};
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btRigidBody>> bodies;

  StockBulletWorld() { world.setGravity(btVector3(0, -9.81f, 0)); }
  StockBulletWorld(const StockBulletWorld&) = delete;
  StockBulletWorld& operator=(const StockBulletWorld&) = delete;
  ~StockBulletWorld() {
    for (auto& b : bodies) world.removeRigidBody(b.get());
  }
  btCollisionShape* keep(btCollisionShape* s) {
    shapes.emplace_back(s);
    return s;
  }
  // A body of shape s and mass (0: static) at pos, turned by rot, added to the world.
  btRigidBody* addBody(btCollisionShape* s, btScalar mass, const btVector3& pos, const btQuaternion& rot) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) s->calculateLocalInertia(mass, inertia);
    btRigidBody::btRigidBodyConstructionInfo info(mass, nullptr, s, inertia);
    info.m_startWorldTransform = btTransform(rot, pos);
    bodies.emplace_back(new btRigidBody(info));
    world.addRigidBody(bodies.back().get());
    return bodies.back().get();
  }
};

}  // namespace dvi
