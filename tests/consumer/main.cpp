// A program built against an installed dvisim with only the public include prefix <dvisim/...>
// (docs/INSTALL.md, "Public headers"). Each part checks a result it can know without the engine; exits 0 when all
// hold.
#include <btBulletDynamicsCommon.h>

#include <cmath>
#include <cstdio>
#include <string>

#include <dvisim/bullet_import.h>
#include <dvisim/bullet_world.h>
#include <dvisim/ces.h>
#include <dvisim/gpu.h>
#include <dvisim/world.h>

bool deprecatedPathsCompile();  // compat.cpp

namespace {

bool check(bool ok, const char* what) {
  std::printf("%s: %s\n", ok ? "ok" : "FAILED", what);
  return ok;
}

// The System: a sphere dropped on a plane comes to rest on it (its centre one radius above).
bool sphereRests() {
  dvi::System sys;
  dvi::BodyDesc ground;
  ground.mass = 0;
  ground.flags = dvi::kBodyFixed;
  ground.shapes.push_back(dvi::makePlane({0, 1, 0}, 0));
  sys.addBody(ground);
  dvi::BodyDesc ball;
  ball.pos = {0, 0.2, 0};
  ball.inertia = {0.004, 0.004, 0.004};
  ball.shapes.push_back(dvi::makeSphere(0.1));
  int b = sys.addBody(ball);
  sys.advance(1000);
  double y = sys.bodies().pos[b].y;
  std::printf("sphere rests at y = %.4f (radius 0.1)\n", y);
  return std::fabs(y - 0.1) < 0.005;
}

// The drop-in world: a body in free fall for n fixed sub-steps of h has v = -g n h (semi-implicit Euler is exact
// for the velocity under constant gravity), to the rounding of Bullet's float velocities.
bool dropInFreeFall() {
  btDefaultCollisionConfiguration config;
  btCollisionDispatcher dispatcher(&config);
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  dvi::DviDynamicsWorld world(&dispatcher, &broadphase, &solver, &config);
  world.setGravity(btVector3(0, -9.81, 0));
  btSphereShape shape(0.1);
  btVector3 inertia;
  shape.calculateLocalInertia(1, inertia);
  btRigidBody body(btRigidBody::btRigidBodyConstructionInfo(1, nullptr, &shape, inertia));
  world.addRigidBody(&body);
  const int n = 30;
  for (int i = 0; i < n; ++i) world.stepSimulation(1.0 / 60, 1, 1.0 / 60);
  double v = body.getLinearVelocity().y(), expect = -9.81 * n / 60;
  std::printf("drop-in world: v = %.6f after %d steps (expected %.6f)\n", v, n, expect);
  world.removeRigidBody(&body);
  return std::fabs(v - expect) < 1e-5 * std::fabs(expect);  // btScalar: float in Debian's Bullet
}

// The GPU entry points link in every build; without a device, makeGpuSystem refuses with an InputError.
bool gpuEntryPoints() {
  std::string name;
  if (dvi::gpuAvailable(&name)) return check(dvi::makeGpuSystem(dvi::SystemConfig{}) != nullptr, "GPU system made");
  try {
    dvi::makeGpuSystem(dvi::SystemConfig{});
  } catch (const dvi::InputError&) { return true; }
  return false;
}

// The CES machine: after some steps its mass balance closes (fed = collected + in flight + held up + lost).
bool cesBalanceCloses() {
  dvi::ces::CesConfig cfg =
      dvi::ces::parseCesDocument(nlohmann::json::parse(dvi::ces::defaultCesJson()), {}, "default");
  dvi::SystemConfig sc;
  sc.step = cfg.step;
  sc.solver = cfg.solver;
  sc.collision.friction_combine = dvi::FrictionCombine::Product;
  dvi::System sys(sc);
  dvi::ces::CesMachine machine(cfg, sys);
  for (int i = 0; i < 200; ++i) machine.step();
  dvi::ces::MassBalance b = machine.balance();
  std::printf("CES machine: fed %lld particles, %lld in flight\n", (long long)b.fed, (long long)b.in_flight);
  return b.fed > 0 && b.closes();
}

}  // namespace

int main() {
  bool ok = check(sphereRests(), "System: the sphere rests on the plane");
  ok &= check(dropInFreeFall(), "DviDynamicsWorld: free-fall velocity");
  ok &= check(gpuEntryPoints(), "GPU entry points");
  ok &= check(cesBalanceCloses(), "CesMachine: the mass balance closes");
  ok &= check(deprecatedPathsCompile(), "the deprecated include paths");
  return ok ? 0 : 1;
}
