// The first dvisim program to read: a pile of mixed shapes built with plain Bullet calls, handed to
// the DVI system, stepped, and written back to the Bullet bodies.
//
//   demo_granular_pile [steps]
#include <btBulletDynamicsCommon.h>

#include <cstdio>
#include <cstdlib>
#include <memory>
#include <vector>

#include <dvisim/bullet_import.h>
#include <dvisim/world.h>

int main(int argc, char** argv) {
  const int steps = argc > 1 ? std::atoi(argv[1]) : 1000;

  // 1. Shapes and bodies exactly as a Bullet application makes them (metres, kilograms).
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btRigidBody>> owned;
  std::vector<btRigidBody*> bodies;
  auto addBody = [&](btCollisionShape* shape, btScalar mass, const btVector3& pos) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) shape->calculateLocalInertia(mass, inertia);
    btRigidBody::btRigidBodyConstructionInfo info(mass, nullptr, shape, inertia);
    info.m_startWorldTransform.setOrigin(pos);
    info.m_friction = 0.5;
    owned.emplace_back(new btRigidBody(info));
    bodies.push_back(owned.back().get());
  };
  shapes.emplace_back(new btStaticPlaneShape(btVector3(0, 1, 0), 0));  // the ground, y up
  addBody(shapes.back().get(), 0, btVector3(0, 0, 0));

  shapes.emplace_back(new btSphereShape(0.01));                              // 1 cm spheres
  shapes.emplace_back(new btBoxShape(btVector3(0.01, 0.006, 0.008)));        // flakes
  shapes.emplace_back(new btCylinderShape(btVector3(0.006, 0.012, 0.006)));  // short rods
  const btScalar density = 1000;
  const btScalar masses[3] = {density * 4.18879e-6f, density * 3.84e-6f, density * 2.71434e-6f};
  for (int i = 0, x = 0; x < 10; ++x)
    for (int y = 0; y < 10; ++y)
      for (int z = 0; z < 10; ++z, ++i) {
        const int kind = i % 3;
        btVector3 pos(0.025f * x + 0.003f * (y % 2), 0.015f + 0.025f * y, 0.025f * z);
        addBody(shapes[1 + kind].get(), masses[kind], pos);
      }

  // 2. The one change: a DVI system steps them instead of btDiscreteDynamicsWorld.
  dvi::SystemConfig config;
  config.step.dt = 1e-3;  // 1 ms: large for a penalty DEM, fine for DVI
  config.solver.type = dvi::SolverType::APGD;
  config.solver.max_iterations = 50;
  dvi::System system(config);
  std::vector<int> ids = dvi::importBullet(system, bodies);

  for (int s = 0; s < steps; ++s) {
    system.step();
    if (s % 200 == 0)
      std::printf("t = %.3f s  contacts %lld  max penetration %.2e m  residual %.2e\n", system.time(),
                  (long long)system.lastStats().contacts, system.lastStats().max_penetration,
                  system.lastStats().residual);
  }

  // 3. Results go back into the Bullet bodies, where the rest of the application reads them.
  dvi::writeBackToBullet(system, ids, bodies);
  btScalar top = 0;
  for (btRigidBody* b : bodies) top = std::max(top, b->getCenterOfMassPosition().y());
  std::printf("after %d steps: %zu bodies, pile height %.3f m\n", steps, bodies.size(), top);
  return 0;
}
