// The classic Bullet scene of the drop-in demo, written against Bullet's API only: a static triangle-mesh
// ground, a stack of boxes, a pile of mixed shapes and a paddle on a motorised hinge. It builds into any
// btDiscreteDynamicsWorld (Bullet's own or dvi::DviDynamicsWorld) and prints the same summary for both.
// The tests (tests/test_bullet_world.cpp) build the same scene.
#pragma once

#include <btBulletDynamicsCommon.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

namespace drop_in {

constexpr int kStackHeight = 5;
constexpr btScalar kBoxHalf = btScalar(0.25);
constexpr btScalar kStackX = btScalar(-3);
constexpr btScalar kHingeSpeed = btScalar(1);  // rad/s, the paddle's motor
constexpr btScalar kSubStep = btScalar(1) / btScalar(240);

class Scene {
 public:
  // Builds the scene into `world`. `pile` bodies of mixed shapes are dropped at x = +3 (0 for none).
  void build(btDiscreteDynamicsWorld& world, int pile = 24) {
    world.setGravity(btVector3(0, btScalar(-9.81), 0));
    // Ground: a 16 m x 16 m grid of triangles at y = 0 (btBvhTriangleMeshShape, static environment geometry).
    mesh_ = std::make_unique<btTriangleMesh>();
    const int n = 4;
    const btScalar half = 8, cell = 2 * half / n;
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k) {
        btVector3 a(-half + i * cell, 0, -half + k * cell),
            b = a + btVector3(cell, 0, 0), c = a + btVector3(cell, 0, cell), d = a + btVector3(0, 0, cell);
        mesh_->addTriangle(a, c, b);
        mesh_->addTriangle(a, d, c);
      }
    ground = add(world, new btBvhTriangleMeshShape(mesh_.get(), true), 0, btVector3(0, 0, 0));
    ground->setFriction(btScalar(0.8));

    // A stack of boxes, 0.5 m cubes, resting one on another.
    btCollisionShape* box = own(new btBoxShape(btVector3(kBoxHalf, kBoxHalf, kBoxHalf)));
    for (int i = 0; i < kStackHeight; ++i) {
      btRigidBody* b = add(world, box, 1, btVector3(kStackX, kBoxHalf + 2 * kBoxHalf * btScalar(i), 0));
      b->setFriction(btScalar(0.8));
      stack.push_back(b);
    }

    // A pile of mixed shapes dropped from a few metres.
    btCollisionShape* shapes[5] = {own(new btSphereShape(btScalar(0.2))),
                                   own(new btBoxShape(btVector3(btScalar(0.2), btScalar(0.15), btScalar(0.1)))),
                                   own(new btCylinderShape(btVector3(btScalar(0.15), btScalar(0.2), btScalar(0.15)))),
                                   own(new btCapsuleShape(btScalar(0.12), btScalar(0.3))),
                                   own(new btConeShape(btScalar(0.2), btScalar(0.4)))};
    for (int i = 0; i < pile; ++i) {
      const btVector3 p(btScalar(3) + btScalar(0.45) * btScalar(i % 3 - 1),
                        btScalar(0.5) + btScalar(0.5) * btScalar(i / 9), btScalar(0.45) * btScalar((i / 3) % 3 - 1));
      btRigidBody* b = add(world, shapes[i % 5], btScalar(0.5 + 0.1 * (i % 4)), p);
      b->setFriction(btScalar(0.6));
      pile_bodies.push_back(b);
    }

    // A paddle turned about a vertical axis by a hinge motor (attached to the world's fixed body).
    btCollisionShape* paddle_shape = own(new btBoxShape(btVector3(btScalar(0.6), btScalar(0.05), btScalar(0.1))));
    paddle = add(world, paddle_shape, 2, btVector3(0, 1.5, -4));
    hinge = new btHingeConstraint(*paddle, btVector3(0, 0, 0), btVector3(0, 1, 0));
    hinge->enableAngularMotor(true, kHingeSpeed, btScalar(50));
    world.addConstraint(hinge);
    paddle->setActivationState(DISABLE_DEACTIVATION);
    for (btRigidBody* b : stack) b->setActivationState(DISABLE_DEACTIVATION);
  }

  void destroy(btDiscreteDynamicsWorld& world) {
    if (hinge) {
      world.removeConstraint(hinge);
      delete hinge;
      hinge = nullptr;
    }
    for (btRigidBody* b : bodies_) {
      world.removeRigidBody(b);
      delete b->getMotionState();
      delete b;
    }
    bodies_.clear();
  }

  // Position of a body as the app sees it: through its motion state (interpolated).
  static btVector3 position(const btRigidBody* b) {
    btTransform t;
    b->getMotionState()->getWorldTransform(t);
    return t.getOrigin();
  }

  std::string summary(btDiscreteDynamicsWorld& world, double t) const {
    char line[256];
    std::string s;
    std::snprintf(line, sizeof line, "t = %.3f s, %d rigid bodies, %d constraint(s)\n", t,
                  world.getNumCollisionObjects(), world.getNumConstraints());
    s += line;
    s += "stack heights (m):";
    for (btRigidBody* b : stack) {
      std::snprintf(line, sizeof line, " %.4f", double(position(b).y()));
      s += line;
    }
    const btVector3 top = position(stack.back());
    std::snprintf(line, sizeof line, "\nstack top (x, z) = (%.4f, %.4f)\n", double(top.x()), double(top.z()));
    s += line;
    double lowest = 1e30, mean = 0;
    for (btRigidBody* b : pile_bodies) {
      lowest = std::fmin(lowest, double(position(b).y()));
      mean += double(position(b).y());
    }
    if (!pile_bodies.empty()) {
      std::snprintf(line, sizeof line, "pile: %zu bodies, mean height %.3f m, lowest %.3f m\n", pile_bodies.size(),
                    mean / double(pile_bodies.size()), lowest);
      s += line;
    }
    std::snprintf(line, sizeof line, "hinge angle %.3f deg (motor %.2f rad/s)\n",
                  double(hinge->getHingeAngle()) * 180 / M_PI, double(kHingeSpeed));
    s += line;
    int points = 0;
    double deepest = 0;
    btDispatcher* d = world.getDispatcher();
    for (int i = 0; i < d->getNumManifolds(); ++i) {
      const btPersistentManifold* m = d->getManifoldByIndexInternal(i);
      for (int k = 0; k < m->getNumContacts(); ++k) {
        if (m->getContactPoint(k).getDistance() > 0) continue;
        ++points;
        deepest = std::fmax(deepest, -double(m->getContactPoint(k).getDistance()));
      }
    }
    std::snprintf(line, sizeof line, "touching contact points %d, deepest penetration %.4f m\n", points, deepest);
    s += line;
    return s;
  }

  btRigidBody* ground = nullptr;
  btRigidBody* paddle = nullptr;
  btHingeConstraint* hinge = nullptr;
  std::vector<btRigidBody*> stack, pile_bodies;

 private:
  btCollisionShape* own(btCollisionShape* s) {
    shapes_.emplace_back(s);
    return s;
  }
  btRigidBody* add(btDiscreteDynamicsWorld& world, btCollisionShape* shape, btScalar mass, const btVector3& p) {
    if (shapes_.empty() || shapes_.back().get() != shape) {
      bool owned = false;
      for (auto& s : shapes_) owned = owned || s.get() == shape;
      if (!owned) shapes_.emplace_back(shape);
    }
    btVector3 inertia(0, 0, 0);
    if (mass > 0) shape->calculateLocalInertia(mass, inertia);
    btTransform t;
    t.setIdentity();
    t.setOrigin(p);
    auto* body =
        new btRigidBody(btRigidBody::btRigidBodyConstructionInfo(mass, new btDefaultMotionState(t), shape, inertia));
    world.addRigidBody(body);
    bodies_.push_back(body);
    return body;
  }

  std::unique_ptr<btTriangleMesh> mesh_;
  std::vector<std::unique_ptr<btCollisionShape>> shapes_;
  std::vector<btRigidBody*> bodies_;
};

}  // namespace drop_in
