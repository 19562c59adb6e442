// Restitution: Newton's impact law in the DVI step (jacobian.h: contactNormalBias). Checked against the closed form
// of a ball dropped on a plane (rebound height e^2 H), against stock Bullet (the same ball drop in a
// btDiscreteDynamicsWorld), for the impact threshold (slow contacts stay inelastic, a bouncing ball comes to rest), for
// e = 0 (bitwise the inelastic problem), for scene files (the key and its validation) and on the GPU backend.
#include <btBulletDynamicsCommon.h>

#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "chrono_like/base/errors.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/bullet/bullet_world.h"
#include "chrono_like/io/scene.h"
#include "chrono_like/system.h"
#include "device_check.h"
#include "gpu/gpu_factory.h"
#include "scene_text.h"

using namespace dvi;

namespace {

const real kG = real(9.81);
const real kRadius = real(0.1);

BodyDesc ground(real restitution) {
  BodyDesc b;
  b.mass = 0;
  b.flags = kBodyFixed;
  b.restitution = restitution;
  b.shapes.push_back(makePlane(Vec3{0, 1, 0}, 0));
  return b;
}

BodyDesc ball(real restitution, real drop) {
  BodyDesc b;
  b.pos = Vec3{0, kRadius + drop, 0};
  b.mass = 1;
  const real I = real(0.4) * kRadius * kRadius;
  b.inertia = Vec3{I, I, I};
  b.restitution = restitution;
  b.shapes.push_back(makeSphere(kRadius));
  return b;
}

// Heights of the ball's lowest point above the plane, one per step.
struct Bounce {
  std::vector<real> y;
  real first_rebound = 0;  // highest point between the first and the second impact
};

// The apex after the first impact: the highest point after the trajectory first turns upwards, up to where it turns
// down again.
real firstRebound(const std::vector<real>& y) {
  size_t i = 1;
  while (i < y.size() && !(y[i] > y[i - 1])) ++i;  // falling until the impact
  real top = 0;
  for (; i < y.size() && y[i] >= y[i - 1]; ++i) top = y[i];
  return top;
}

Bounce dropBall(System& sys, real e_ball, real e_ground, real drop, real seconds) {
  sys.addBody(ground(e_ground));
  const int b = sys.addBody(ball(e_ball, drop));
  Bounce r;
  const int n = int(std::lround(seconds / sys.config().step.dt));
  for (int i = 0; i < n; ++i) {
    sys.step();
    sys.syncToHost();  // the GPU backend's bodies live on the device (a no-op on the CPU)
    r.y.push_back(sys.bodies().pos[size_t(b)].y - kRadius);
  }
  r.first_rebound = firstRebound(r.y);
  return r;
}

Bounce dropBallCpu(real h, real e_ball, real e_ground, real drop, real seconds) {
  SystemConfig cfg;
  cfg.step.dt = h;
  System sys(cfg);
  return dropBall(sys, e_ball, e_ground, drop, seconds);
}

}  // namespace

// Closed form: a ball dropped from H onto a fixed plane leaves with e times its impact speed and rises to e^2 H (e the
// product e_ball e_ground, Bullet's rule). The step's errors are O(h), both bounded by the travel of one step at the
// impact speed, v h with v = sqrt(2 g H): the bounce happens at the start of the step in which the ball reaches the
// surface, from a gap d < v h above it (contactNormalBias), which raises the apex by (1 + e) d at most (the ball
// leaves from d instead of arriving at the surface at d / v and leaving at the end of the step from e (v h - d)); and
// semi-implicit Euler's flight loses about v h / 2 of height on the way down and on the way up (x += h v after
// v -= g h). So |apex - e^2 H| <= (1 + e) v h + v h = (2 + e) v h. It must also shrink with h (first order).
TEST_CASE("restitution: a ball dropped from H rebounds to e^2 H within the step's O(v h) error", "[restitution]") {
  const real H = 1;
  const real v = std::sqrt(2 * kG * H);
  real last_err = 1e30;
  for (real h : {real(1) / 60, real(1) / 240, real(1) / 1000}) {
    for (real e : {real(0.5), real(0.8)}) {
      // e_ball e_ground = e, either way round
      const Bounce b = dropBallCpu(h, e, 1, H, real(1.5));
      const Bounce b2 = dropBallCpu(h, 1, e, H, real(1.5));
      const real expect = e * e * H;
      const real err = std::fabs(b.first_rebound - expect);
      INFO("h = 1/" << std::lround(1 / h) << ", e = " << e << ": rebound " << b.first_rebound << " m, analytic "
                    << expect << " m, error " << err << " m, bound (2 + e) v h = " << (2 + e) * v * h << " m");
      CHECK(err <= (2 + e) * v * h);
      CHECK(b2.first_rebound == b.first_rebound);  // the product is symmetric
      if (e == real(0.5)) {
        CHECK(err <= last_err);
        last_err = err;
      }
    }
  }
  // at h = 1/1000 the rebound is within 3% of the closed form (2.5 v h = 0.011 m is 4.4% of 0.25 m)
  const Bounce fine = dropBallCpu(real(1) / 1000, real(0.5), 1, H, real(1.5));
  CHECK(fine.first_rebound == Approx(0.25 * H).epsilon(0.03));
}

// e = 0 (the default) stays inelastic: no rebound above 1% of the drop (test_bounce.cpp checks the same over step sizes
// and shapes); e > 0 on one side only (product rule) is inelastic too.
TEST_CASE("restitution: e = 0 on either body does not bounce", "[restitution]") {
  for (auto pair :
       {std::make_pair(real(0), real(0)), std::make_pair(real(0.9), real(0)), std::make_pair(real(0), real(0.9))}) {
    const Bounce b = dropBallCpu(real(1) / 60, pair.first, pair.second, 1, real(1.5));
    INFO("e_ball " << pair.first << ", e_ground " << pair.second << ": rebound " << b.first_rebound);
    CHECK(b.first_rebound <= real(0.01));
    CHECK(std::fabs(b.y.back()) <= real(0.01) * kRadius);
  }
}

// The impact threshold (SolverSettings::min_bounce_speed, Bullet's 0.2 m/s): the bounces of a ball with e = 0.5 decay
// geometrically; once the impact speed is below the threshold the contact is inelastic and the ball rests on the plane
// (instead of bouncing ever lower on every step, the aliasing Chrono's min_bounce_speed is there to prevent). A raised
// threshold above the impact speed turns the bounce off.
TEST_CASE("restitution: slow impacts are inelastic, so a bouncing ball comes to rest", "[restitution]") {
  const Bounce b = dropBallCpu(real(1) / 240, real(0.5), 1, real(0.5), real(4));
  CHECK(b.first_rebound > real(0.1));
  // the last second: at rest on the plane
  for (size_t i = b.y.size() - 240; i < b.y.size(); ++i) CHECK(std::fabs(b.y[i]) <= real(0.01) * kRadius);

  SystemConfig cfg;
  cfg.step.dt = real(1) / 240;
  cfg.solver.min_bounce_speed = 10;  // above the 3.1 m/s impact of a 0.5 m drop
  System sys(cfg);
  const Bounce off = dropBall(sys, real(0.5), 1, real(0.5), real(1));
  CHECK(off.first_rebound <= real(0.005));
}

// With every restitution 0, the problem's right-hand side is the inelastic one bit for bit: the same scene stepped with
// the restitution array all zero and with no restitution array at all (ContactProblem::build then reads none: the
// assembly as it was before restitution) gives identical trajectories. The scene: a frictional pile of boxes and
// spheres falling onto a plane and settling, so impacts, speculative contacts and resting contacts all occur. A
// ball resting on the plane with e = 0.5 on both is bitwise the same as with e = 0: its contact never approaches
// faster than the threshold. The shipped example scenes (no restitution key) likewise.
TEST_CASE("restitution: e = 0 leaves the trajectory bitwise unchanged", "[restitution]") {
  auto pile = [](System& sys, real e) {
    sys.addBody(ground(e));
    for (int i = 0; i < 12; ++i) {
      BodyDesc b = ball(e, 0);
      b.pos = Vec3{real(0.13) * real(i % 3), real(0.3 + 0.25 * (i / 3)), real(0.05) * real(i % 2)};
      b.friction = real(0.6);
      if (i % 2) {
        b.shapes = {makeBox(Vec3{real(0.08), real(0.06), real(0.07)})};
        b.inertia = Vec3{real(0.003), real(0.004), real(0.003)};
      }
      sys.addBody(b);
    }
  };
  auto run = [&](bool drop_array, real e, int steps) {
    SystemConfig cfg;
    cfg.step.dt = real(1) / 120;
    cfg.threads = 1;
    System sys(cfg);
    pile(sys, e);
    if (drop_array) sys.mutableBodies().restitution.clear();
    std::vector<real> trace;
    for (int i = 0; i < steps; ++i) {
      sys.step();
      for (size_t k = 0; k < sys.bodies().count(); ++k) {
        const Vec3& p = sys.bodies().pos[k];
        const Vec3& v = sys.bodies().vel[k];
        trace.insert(trace.end(), {p.x, p.y, p.z, v.x, v.y, v.z});
      }
    }
    return trace;
  };
  const std::vector<real> zeros = run(false, 0, 240), none = run(true, 0, 240);
  REQUIRE(zeros.size() == none.size());
  CHECK(std::memcmp(zeros.data(), none.data(), zeros.size() * sizeof(real)) == 0);
  // the shipped example scenes (their bodies have no restitution key: every e is 0), as `dvisim run` loads them
  for (const char* name : {"stack.json", "incline.json", "mixed_shapes.json"}) {
    auto runScene = [&](bool drop_array) {
      Scene scene = Scene::load(std::string(DVISIM_SOURCE_DIR) + "/scenes/" + name);
      System sys(scene.settings.system);
      importBullet(sys, scene.bodies());
      if (drop_array) sys.mutableBodies().restitution.clear();
      std::vector<real> trace;
      for (int i = 0; i < 200; ++i) {
        sys.step();
        for (const Vec3& p : sys.bodies().pos) trace.insert(trace.end(), {p.x, p.y, p.z});
      }
      return trace;
    };
    const std::vector<real> a = runScene(false), b = runScene(true);
    INFO(name);
    REQUIRE(a.size() == b.size());
    CHECK(std::memcmp(a.data(), b.data(), a.size() * sizeof(real)) == 0);
  }
  // bodies that only rest: a ball on the plane, started touching it (the pile above has impacts)
  auto rest = [](real e) {
    SystemConfig cfg;
    cfg.step.dt = real(1) / 120;
    System sys(cfg);
    sys.addBody(ground(e));
    const int b = sys.addBody(ball(e, 0));
    std::vector<real> y;
    for (int i = 0; i < 120; ++i) {
      sys.step();
      y.push_back(sys.bodies().pos[size_t(b)].y);
    }
    return y;
  };
  const std::vector<real> r0 = rest(0), r5 = rest(real(0.5));
  CHECK(std::memcmp(r0.data(), r5.data(), r0.size() * sizeof(real)) == 0);
}

namespace {

// The ball drop in a Bullet world (stock btDiscreteDynamicsWorld or our drop-in), Bullet's calls as an app makes them:
// a static plane, a sphere of radius 0.5 whose lowest point starts 3 m above it, restitution set on both bodies,
// stepSimulation(1/60, 10, fixed). Returns the apex of the lowest point after the first impact.
double bulletDrop(bool dvi, double e_ball, double e_ground, double fixed_step,
                  SolverEffort effort = SolverEffort::Converged) {
  btDefaultCollisionConfiguration config;
  btCollisionDispatcher dispatcher(&config);
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  std::unique_ptr<btDiscreteDynamicsWorld> world;
  if (dvi) {
    DviWorldConfig c;
    c.effort = effort;
    world = std::make_unique<DviDynamicsWorld>(&dispatcher, &broadphase, &solver, &config, c);
  }
  if (!dvi) world = std::make_unique<btDiscreteDynamicsWorld>(&dispatcher, &broadphase, &solver, &config);
  world->setGravity(btVector3(0, btScalar(-9.81), 0));
  btStaticPlaneShape plane(btVector3(0, 1, 0), 0);
  btDefaultMotionState plane_motion;
  btRigidBody groundBody(btRigidBody::btRigidBodyConstructionInfo(0, &plane_motion, &plane, btVector3(0, 0, 0)));
  groundBody.setRestitution(btScalar(e_ground));
  world->addRigidBody(&groundBody);
  const double r = 0.5;
  btSphereShape sphere{btScalar(r)};
  btVector3 inertia(0, 0, 0);
  sphere.calculateLocalInertia(1, inertia);
  btTransform start;
  start.setIdentity();
  start.setOrigin(btVector3(0, btScalar(3 + r), 0));
  btDefaultMotionState motion(start);
  btRigidBody body(btRigidBody::btRigidBodyConstructionInfo(1, &motion, &sphere, inertia));
  body.setRestitution(btScalar(e_ball));
  body.setActivationState(DISABLE_DEACTIVATION);
  world->addRigidBody(&body);
  std::vector<real> y;
  for (int i = 0; i < 180; ++i) {  // 3 s of frames
    world->stepSimulation(btScalar(1.0 / 60), 10, btScalar(fixed_step));
    y.push_back(real(body.getCenterOfMassPosition().getY()) - real(r));
  }
  world->removeRigidBody(&body);
  world->removeRigidBody(&groundBody);
  return double(firstRebound(y));
}

}  // namespace

// Against stock Bullet: the same ball drop (3 m, radius 0.5 m, e_ground = 1) in btDiscreteDynamicsWorld and in the
// drop-in world, at Bullet's default step (stepSimulation(1/60, 10)). Bullet's sequential-impulse solver applies the
// same law (restitutionCurve: the contact leaves at e times the pre-step approach speed, above
// m_restitutionVelocityThreshold), with O(v h) errors of its own. Both rebounds must be within 3 v h of each other and
// of the closed form e^2 H (v = 7.7 m/s at impact, 3 v h = 0.38 m at 1/60 s; ours is within (2 + e) v h by the
// analytic test above). At 1/240 s Bullet falls short of e^2 H by far more than its step's travel (its contact is
// found before the ball touches, and a separated contact's target v+ = e |v-| - dist/h loses speed): ours must then
// stay within (2 + e) v h of the closed form, and closer to it than Bullet. Both with the default effort (APGD) and
// with SolverEffort::BulletThenConverged (Gauss-Seidel from Bullet's 10 sweeps on: its contact step must solve the
// impact's normal row exactly, as Bullet's does, or the relative tolerance stops it short of the bounce).
TEST_CASE("restitution: a Bullet app's setRestitution bounces as in stock Bullet", "[restitution][bullet]") {
  const double H = 3, v = std::sqrt(2 * 9.81 * H);
  for (SolverEffort effort : {SolverEffort::Converged, SolverEffort::BulletThenConverged}) {
    const char* name = effort == SolverEffort::Converged ? "Converged" : "BulletThenConverged";
    for (double e : {0.5, 0.9}) {
      const double h = 1.0 / 60;
      const double bullet = bulletDrop(false, e, 1, h), ours = bulletDrop(true, e, 1, h, effort);
      INFO(name << ", h = 1/60, e = " << e << ": stock Bullet " << bullet << " m, drop-in " << ours << " m, analytic "
                << e * e * H << " m, tolerance 3 v h = " << 3 * v * h << " m");
      CHECK(std::fabs(ours - bullet) <= 3 * v * h);
      CHECK(std::fabs(ours - e * e * H) <= 3 * v * h);
      CHECK(std::fabs(bullet - e * e * H) <= 3 * v * h);
    }
    for (double e : {0.5, 0.9}) {
      const double h = 1.0 / 240;
      const double bullet = bulletDrop(false, e, 1, h), ours = bulletDrop(true, e, 1, h, effort);
      INFO(name << ", h = 1/240, e = " << e << ": stock Bullet " << bullet << " m, drop-in " << ours << " m, analytic "
                << e * e * H << " m");
      CHECK(std::fabs(ours - e * e * H) <= (2 + e) * v * h);
      CHECK(std::fabs(ours - e * e * H) <= std::fabs(bullet - e * e * H));
    }
  }
  // no restitution: neither bounces above 1% of the drop
  CHECK(bulletDrop(false, 0, 0, 1.0 / 60) <= 0.01 * H);
  CHECK(bulletDrop(true, 0, 0, 1.0 / 60) <= 0.01 * H);
}

// Scene files: `restitution` on a body and a generator reaches the body (through Bullet's btRigidBody, as friction
// does); values outside [0, 1] and NaN are refused with the key named.
TEST_CASE("restitution: the scene key, and its validation", "[restitution][cli]") {
  auto* scene = &testscenes::groundAndPair;
  Scene s = Scene::fromJsonText(scene(R"(, "restitution": 0.5)", R"(, "restitution": 0.25)"), "test");
  REQUIRE(s.bodyCount() == 3);
  CHECK(bodyDescFromBullet(*s.bodies()[0]).restitution == Approx(0.5));
  CHECK(bodyDescFromBullet(*s.bodies()[1]).restitution == Approx(0.25));
  CHECK(bodyDescFromBullet(*s.bodies()[2]).restitution == Approx(0.25));
  Scene plain = Scene::fromJsonText(scene("", ""), "test");
  CHECK(bodyDescFromBullet(*plain.bodies()[1]).restitution == 0);
  for (const char* bad : {R"(, "restitution": 1.5)", R"(, "restitution": -0.1)", R"(, "restitution": "nan")",
                          R"(, "restitution": "x")"}) {
    INFO(bad);
    CHECK_THROWS_AS(Scene::fromJsonText(scene(bad, ""), "test"), InputError);
    CHECK_THROWS_AS(Scene::fromJsonText(scene("", bad), "test"), InputError);
  }
  try {
    Scene::fromJsonText(scene(R"(, "restitution": 2)", ""), "test");
  } catch (const InputError& e) { CHECK(std::string(e.what()).find("restitution") != std::string::npos); }
  // the settings key of the threshold
  Scene t = Scene::fromJsonText(R"({ "settings": { "min_bounce_speed": 0.5 }, "bodies": [
      { "shape": { "type": "sphere", "radius": 0.1 } } ] })",
                                "test");
  CHECK(t.settings.system.solver.min_bounce_speed == Approx(0.5));
  CHECK_THROWS_AS(Scene::fromJsonText(R"({ "settings": { "min_bounce_speed": -1 }, "bodies": [] })", "test"),
                  InputError);
  // the System refuses a negative or non-finite coefficient
  System sys;
  CHECK_THROWS_AS(sys.addBody(ball(real(-0.5), 1)), InputError);
  CHECK_THROWS_AS(sys.addBody(ball(real(NAN), 1)), InputError);
}

// The GPU backend assembles the same right-hand side (RowsF calls contactNormalBias with the restitution and the
// pre-step velocities on the device): the ball drop rebounds as on the CPU backend (to float rounding of the device's
// Jacobians: within 1 mm), and e = 0 does not bounce.
TEST_CASE("restitution on the GPU backend: the ball drop rebounds as on the CPU", "[restitution][gpu]") {
  if (!dvi::testing::haveDevice()) return;
  for (real e : {real(0), real(0.5)}) {
    SystemConfig cfg;
    cfg.step.dt = real(1) / 240;
    auto gpu = makeGpuSystem(cfg);
    const Bounce g = dropBall(*gpu, e, 1, 1, real(1.5));
    const Bounce c = dropBallCpu(cfg.step.dt, e, 1, 1, real(1.5));
    INFO("e = " << e << ": GPU rebound " << g.first_rebound << " m, CPU " << c.first_rebound << " m");
    CHECK(std::fabs(g.first_rebound - c.first_rebound) <= real(1e-3));
    CHECK(std::fabs(g.first_rebound - e * e) <= (2 + e) * std::sqrt(2 * kG) / 240);
  }
}
