// Rolling and spinning friction (Tasora & Anitescu, Meccanica 48 (2013); cone.h: projectRollingCone, the rolling
// blocks of contact_problem.h). Checked against
// - the Euclidean projection's optimality conditions (the projection is exact, not Chrono's sequence of projections);
// - closed forms: a ball rolling on a plane decelerates at 5 mu_r g / (7 r) (energy: the resisting torque mu_r m g
//   dissipates mu_r m g v / r against the kinetic energy 7/10 m v^2), a ball spinning about the vertical stops at
//   w0 I / (mu_s m g), and a ball on an incline holds while tan(theta) <= mu_r / r and otherwise rolls down at
//   5/7 g (sin(theta) - mu_r / r cos(theta));
// - stock Bullet, which has the same bound (|torque impulse| <= mu_r x normal impulse per contact, btSequentialImpulse-
//   ConstraintSolver's rolling friction pool) with the same combination r_a f_b + r_b f_a: the ball drops of the
//   drop-in world side by side with btDiscreteDynamicsWorld;
// - the four solvers, which must reach the same optimal value of the (convex) CCP with rolling blocks.
#include <btBulletDynamicsCommon.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "bullet_test_world.h"
#include "chrono_like/base/errors.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/io/scene.h"
#include "chrono_like/solver/contact_problem.h"
#include "chrono_like/system.h"
#include "device_check.h"
#include "gpu/gpu_factory.h"
#include "scene_text.h"

using namespace dvi;

namespace {

const double kG = 9.81;
const real kR = real(0.1);

// A point of K = {|t| <= mu n, |s| <= mu_s n, |rho| <= mu_r n}: random n >= 0 and parts inside their radii.
void randomInCone(std::mt19937& rng, real mu, real mus, real mur, real* g, real* s) {
  std::uniform_real_distribution<double> u(0, 1), ang(0, 2 * M_PI);
  const real n = real(3 * u(rng));
  const double a1 = ang(rng), a2 = ang(rng);
  const real t = real(u(rng)) * mu * n, sp = real(2 * u(rng) - 1) * mus * n, rr = real(u(rng)) * mur * n;
  g[0] = n;
  g[1] = t * real(std::cos(a1));
  g[2] = t * real(std::sin(a1));
  s[0] = sp;
  s[1] = rr * real(std::cos(a2));
  s[2] = rr * real(std::sin(a2));
}

bool inCone(real mu, real mus, real mur, const real* g, const real* s, real tol) {
  return g[0] >= -tol && std::hypot(g[1], g[2]) <= mu * g[0] + tol && std::fabs(s[0]) <= mus * g[0] + tol &&
         std::hypot(s[1], s[2]) <= mur * g[0] + tol;
}

BodyDesc plane(Vec3 normal, real friction, real rolling = 0) {
  BodyDesc b;
  b.mass = 0;
  b.flags = kBodyFixed;
  b.friction = friction;
  b.rolling_friction = rolling;
  b.shapes.push_back(makePlane(normalized(normal), 0));
  return b;
}

BodyDesc ball(Vec3 pos, real friction, real rolling, real spinning) {
  BodyDesc b;
  b.pos = pos;
  b.mass = 1;
  const real I = real(0.4) * kR * kR;
  b.inertia = Vec3{I, I, I};
  b.friction = friction;
  b.rolling_friction = rolling;
  b.spinning_friction = spinning;
  b.shapes.push_back(makeSphere(kR));
  return b;
}

// A ball on stock Bullet or our drop-in world (TestWorld), on the static ground box (friction 0.8, top at y = 0),
// started with velocity v and angular velocity w; returns the ball's centre and spin over time, one per frame.
struct Track {
  std::vector<btVector3> x, w;
};
Track bulletBall(bool dvi, btScalar rolling, btScalar spinning, const btVector3& v, const btVector3& w,
                 double seconds) {
  TestWorld tw(dvi);
  tw.ground();
  btRigidBody* b = tw.make(tw.own(new btSphereShape(btScalar(kR))), 1, btVector3(0, btScalar(kR), 0));
  b->setFriction(btScalar(0.5));
  b->setRollingFriction(rolling);
  b->setSpinningFriction(spinning);
  b->setLinearVelocity(v);
  b->setAngularVelocity(w);
  Track t;
  const int frames = int(seconds * 60 + 0.5);
  for (int i = 0; i < frames; ++i) {
    tw.world->stepSimulation(btScalar(1) / 60, 10, btScalar(1) / 240);
    t.x.push_back(b->getCenterOfMassPosition());
    t.w.push_back(b->getAngularVelocity());
  }
  return t;
}

}  // namespace

TEST_CASE("rolling cone projection: the exact Euclidean projection onto the intersection of the three cones",
          "[rolling][solver]") {
  std::mt19937 rng(7);
  std::normal_distribution<double> n(0, 1);
  std::uniform_real_distribution<double> u(0, 1);
  int outside = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    const real mu = trial % 7 == 0 ? real(0) : real(u(rng)), mus = trial % 5 == 0 ? real(0) : real(0.2 * u(rng)),
               mur = trial % 3 == 0 ? real(0) : real(0.5 * u(rng));
    real x[6];
    for (real& e : x) e = real(n(rng));
    real g[3] = {x[0], x[1], x[2]}, s[3] = {x[3], x[4], x[5]};
    projectRollingCone(mu, mus, mur, g, s);
    INFO("trial " << trial << " mu " << mu << " mu_s " << mus << " mu_r " << mur);
    REQUIRE(inCone(mu, mus, mur, g, s, real(1e-12)));
    const real p[6] = {g[0], g[1], g[2], s[0], s[1], s[2]};
    bool moved = false;
    for (int j = 0; j < 6; ++j) moved = moved || p[j] != x[j];
    outside += moved ? 1 : 0;
    // Optimality of a projection onto a closed convex set: <x - P, y - P> <= 0 for every y in K (y = 0 and y = 2P
    // included: K is a cone, so x - P is orthogonal to P).
    auto vi = [&](const real* y) {
      double d = 0;
      for (int j = 0; j < 6; ++j) d += double(x[j] - p[j]) * double(y[j] - p[j]);
      return d;
    };
    const real zero[6] = {0, 0, 0, 0, 0, 0};
    const real twice[6] = {2 * p[0], 2 * p[1], 2 * p[2], 2 * p[3], 2 * p[4], 2 * p[5]};
    CHECK(vi(zero) <= 1e-12);
    CHECK(vi(twice) <= 1e-12);
    for (int k = 0; k < 20; ++k) {
      real y[6];
      randomInCone(rng, mu, mus, mur, y, y + 3);
      CHECK(vi(y) <= 1e-12);
    }
  }
  CHECK(outside > 1000);  // the trials did exercise the projection
  // Without rolling and spinning parts it is the friction cone's projection (cone.h: projectCone, a closed form).
  for (int trial = 0; trial < 500; ++trial) {
    const real mu = real(u(rng));
    real g[3] = {real(n(rng)), real(n(rng)), real(n(rng))}, s[3] = {0, 0, 0};
    real c[3] = {g[0], g[1], g[2]};
    projectRollingCone(mu, real(0.1), real(0.1), g, s);
    projectCone(mu, c[0], c[1], c[2]);
    for (int j = 0; j < 3; ++j) CHECK(g[j] == Approx(c[j]).margin(1e-14));
    CHECK(s[0] == 0);
  }
  // Rolling part alone outside its cone: onto the boundary ray of the (n, |rho|) half plane, n' = (n + mu_r m) /
  // (1 + mu_r^2), the friction cone's closed form.
  real g[3] = {real(0.5), 0, 0}, s[3] = {0, real(0.3), real(-0.4)};
  projectRollingCone(real(0.5), real(0.1), real(0.2), g, s);
  const double nn = (0.5 + 0.2 * 0.5) / (1 + 0.04);
  CHECK(g[0] == Approx(nn));
  CHECK(std::hypot(s[1], s[2]) == Approx(0.2 * nn));
  CHECK(s[1] / s[2] == Approx(0.3 / -0.4));
}

TEST_CASE("rolling friction: a rolling ball stops after v0^2 / (2 a), a = 5 mu_r g / (7 r), as in Bullet",
          "[rolling][bullet]") {
  // mu_r = r_ball f_ground = 0.0125 x 0.8 = 0.01 m (Bullet's combination); rolling without slip from v0 = 2 m/s.
  const double mur = 0.01, v0 = 2, a = 5 * mur * kG / (7 * kR), stop = v0 * v0 / (2 * a);
  const btVector3 v(btScalar(v0), 0, 0), w(0, 0, btScalar(-v0 / kR));
  const Track ours = bulletBall(true, btScalar(0.0125), 0, v, w, 4);
  const Track bullet = bulletBall(false, btScalar(0.0125), 0, v, w, 4);
  const Track free = bulletBall(true, 0, 0, v, w, 4);
  const double xo = ours.x.back().x(), xb = bullet.x.back().x(), xf = free.x.back().x();
  INFO("stopping distance: closed form " << stop << " m, ours " << xo << ", Bullet " << xb << "; without rolling "
                                         << "friction ours travel " << xf << " m in 4 s");
  CHECK(std::fabs(xo - stop) <= 0.03 * stop);
  CHECK(std::fabs(xb - stop) <= 0.05 * stop);
  CHECK(std::fabs(xo - xb) <= 0.05 * stop);
  CHECK(xf >= 0.95 * v0 * 4);  // without it the ball keeps rolling (the test can fail)
  // half way through its stopping time the speed is v0 / 2 (constant deceleration)
  const size_t half = size_t(std::lround(0.5 * v0 / a * 60)) - 1;
  const double vx = (ours.x[half + 1].x() - ours.x[half - 1].x()) * 30;
  CHECK(vx == Approx(0.5 * v0).epsilon(0.05));
}

TEST_CASE("spinning friction: a ball spinning about the vertical stops at w0 I / (mu_s m g), as in Bullet",
          "[rolling][bullet]") {
  // mu_s = s_ball f_ground = 0.0025 x 0.8 = 0.002 m; I = 2/5 m r^2: alpha = mu_s g / (0.4 r^2) = 4.905 rad/s^2.
  // Bullet adds a contact's spinning row only where its rolling friction is > 0 too (btSequentialImpulseConstraint-
  // Solver::convertContact), and so does the drop-in world: the ball gets some (it does not roll: no effect on the
  // spin); without it the ball keeps spinning in both.
  const double mus = 0.002, w0 = 10, alpha = mus * kG / (0.4 * kR * kR), t_stop = w0 / alpha;
  const btVector3 w(0, btScalar(w0), 0);
  const Track ours = bulletBall(true, btScalar(0.01), btScalar(0.0025), btVector3(0, 0, 0), w, 3);
  const Track bullet = bulletBall(false, btScalar(0.01), btScalar(0.0025), btVector3(0, 0, 0), w, 3);
  const Track bullet_alone = bulletBall(false, 0, btScalar(0.0025), btVector3(0, 0, 0), w, 3);
  const Track ours_alone = bulletBall(true, 0, btScalar(0.0025), btVector3(0, 0, 0), w, 3);
  CHECK(bullet_alone.w.back().y() == Approx(w0).epsilon(1e-3));  // Bullet: no spinning row without rolling friction
  CHECK(ours_alone.w.back().y() == Approx(w0).epsilon(1e-3));
  const size_t at1 = 59;  // t = 1 s
  INFO("spin at 1 s: closed form " << w0 - alpha << " rad/s, ours " << ours.w[at1].y() << ", Bullet "
                                   << bullet.w[at1].y() << "; at 3 s ours " << ours.w.back().y() << ", Bullet "
                                   << bullet.w.back().y() << " (stops at " << t_stop << " s)");
  CHECK(ours.w[at1].y() == Approx(w0 - alpha).epsilon(0.03));
  CHECK(bullet.w[at1].y() == Approx(w0 - alpha).epsilon(0.05));
  CHECK(std::fabs(ours.w.back().y()) <= 0.01);
  CHECK(std::fabs(bullet.w.back().y()) <= 0.01);
  CHECK(std::fabs(ours.x.back().x()) + std::fabs(ours.x.back().z()) <= 1e-3);  // it spins in place
}

TEST_CASE("rolling friction: a ball on an incline holds while tan(theta) <= mu_r / r and rolls down otherwise",
          "[rolling]") {
  // mu_r = r_ball f_plane = 0.02 x 1 = 0.02 m: the critical slope is atan(0.2) = 11.3 degrees.
  const double mur = 0.02;
  for (double deg : {9.0, 14.0}) {
    for (bool with_rolling : {true, false}) {
      const double th = deg * M_PI / 180;
      const Vec3 n{real(std::sin(th)), real(std::cos(th)), 0};  // the plane rises toward -x
      SystemConfig cfg;
      cfg.step.dt = real(1) / 240;
      System sys(cfg);
      sys.addBody(plane(n, 1));
      sys.addBody(ball(n * kR, real(0.8), with_rolling ? real(mur) : real(0), 0));
      const int steps = 480;  // 2 s
      sys.advance(steps);
      const Vec3 down{real(std::cos(th)), real(-std::sin(th)), 0};
      const double d = double(dot(sys.bodies().pos[1] - n * kR, down));
      const double a = with_rolling ? std::max(0.0, 5.0 / 7 * kG * (std::sin(th) - mur / kR * std::cos(th)))
                                    : 5.0 / 7 * kG * std::sin(th);
      const double expect = 0.5 * a * 4;
      INFO(deg << " degrees, rolling friction " << with_rolling << ": moved " << d << " m down the slope in 2 s, "
               << "closed form " << expect << " m");
      if (expect == 0)
        CHECK(std::fabs(d) <= 1e-3);
      else
        CHECK(d == Approx(expect).epsilon(0.03));
    }
  }
}

TEST_CASE("rolling friction: Jacobi, Gauss-Seidel, APGD and BB reach the same optimum of the CCP with rolling blocks",
          "[rolling][solver]") {
  // A few steps of a small pile with rolling and spinning friction give a problem with many coupled contacts; each
  // solver then solves the same CCP from zero. The optimal value f = 1/2 g^T N g + r^T g of a convex problem is
  // unique (its minimisers need not be), so all four must reach it, and every impulse must lie in its cone.
  SystemConfig cfg;
  cfg.step.dt = real(1e-3);
  System sys(cfg);
  sys.addBody(plane(Vec3{0, 1, 0}, 1));
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> j(-0.01, 0.01);
  for (int i = 0; i < 4; ++i)
    for (int k = 0; k < 4; ++k)
      for (int l = 0; l < 3; ++l)
        sys.addBody(ball(Vec3{real(0.21 * i + j(rng)), real(0.1 + 0.205 * l), real(0.21 * k + j(rng))}, real(0.6),
                         real(0.01), real(0.005)));
  sys.advance(300);
  REQUIRE(sys.lastStats().part_ran[int(StagePart::RollingSpinningRows)]);
  const BodyArrays& B = sys.bodies();
  const ContactArrays& C = sys.contacts();
  const int64_t nc = int64_t(C.count());
  REQUIRE(nc > 40);
  std::vector<Vec3> vf(B.count()), wf(B.count());
  for (size_t i = 0; i < B.count(); ++i) {
    vf[i] = B.inv_mass[i] > 0 ? B.vel[i] + B.gravity[i] * cfg.step.dt : B.vel[i];
    wf[i] = B.omega[i];
  }
  std::vector<real> rolling(size_t(2 * nc));
  for (int64_t k = 0; k < nc; ++k) {
    rolling[size_t(2 * k)] = k % 4 == 0 ? real(0) : real(0.004);  // some contacts without spinning friction
    rolling[size_t(2 * k + 1)] = k % 5 == 0 ? real(0) : real(0.008);
  }
  ContactProblem p;
  p.build(B, C, vf.data(), wf.data(), makeStepContext(real(cfg.step.dt)), cfg.solver, ContactProblemSettings{}, nullptr,
          rolling.data());
  REQUIRE(p.rollingBlocks() > nc / 2);
  auto objective = [&](const std::vector<real>& g) {
    std::vector<real> Ng(g.size());
    p.schur(g.data(), Ng.data());
    double f = 0;
    for (size_t i = 0; i < g.size(); ++i) f += 0.5 * double(g[i]) * Ng[i] + double(p.rhs()[i]) * g[i];
    return f;
  };
  std::vector<double> values;
  for (SolverType t : {SolverType::APGD, SolverType::BB, SolverType::GaussSeidel, SolverType::Jacobi}) {
    SolverSettings s;
    s.type = t;
    s.tolerance = real(1e-7);
    s.max_iterations = 200000;
    s.storage = VectorStorage::Real;
    std::vector<real> g(size_t(p.size()), real(0));
    SolverStats st = t == SolverType::APGD     ? solveApgd(p, g.data(), s)
                     : t == SolverType::BB     ? solveBB(p, g.data(), s)
                     : t == SolverType::Jacobi ? solveJacobi(p, g.data(), s)
                                               : p.solveGaussSeidel(g.data(), s);
    INFO(solverName(t) << ": " << st.iterations << " iterations, relative residual " << st.relative_residual);
    CHECK(st.relative_residual <= 1e-6);
    for (int64_t k = 0; k < nc; ++k) {
      const int32_t q = p.rollingIndex(k);
      real s3[3] = {0, 0, 0};  // the angular impulses (the problem holds them divided by a length)
      for (int j = 0; j < 3 && q >= 0; ++j) s3[j] = g[size_t(3 * (nc + q) + j)] * p.rollingLength(q);
      REQUIRE(inCone(C.mu[k], rolling[size_t(2 * k)], rolling[size_t(2 * k + 1)], &g[size_t(3 * k)], s3, real(1e-12)));
    }
    values.push_back(objective(g));
  }
  INFO("optimal values APGD " << values[0] << ", BB " << values[1] << ", GS " << values[2] << ", Jacobi " << values[3]);
  for (double v : values) CHECK(v == Approx(values[0]).epsilon(1e-5));
  CHECK(values[0] < 0);
}

TEST_CASE("rolling friction: scene keys, validation, pruning and the GPU backend's refusal", "[rolling][cli]") {
  auto* scene = &testscenes::groundAndPair;
  Scene s = Scene::fromJsonText(
      scene(R"(, "rolling_friction": 0.01, "spinning_friction": 0.002)", R"(, "rolling_friction": 0.03)"), "test");
  REQUIRE(s.bodyCount() == 3);
  CHECK(bodyDescFromBullet(*s.bodies()[0]).rolling_friction == Approx(0.01));
  CHECK(bodyDescFromBullet(*s.bodies()[0]).spinning_friction == Approx(0.002));
  CHECK(bodyDescFromBullet(*s.bodies()[2]).rolling_friction == Approx(0.03));
  CHECK(bodyDescFromBullet(*s.bodies()[2]).spinning_friction == 0);
  for (const char* bad :
       {R"(, "rolling_friction": -0.1)", R"(, "spinning_friction": "nan")", R"(, "rolling_friction": "x")"}) {
    INFO(bad);
    CHECK_THROWS_AS(Scene::fromJsonText(scene(bad, ""), "test"), InputError);
    CHECK_THROWS_AS(Scene::fromJsonText(scene("", bad), "test"), InputError);
  }
  try {
    Scene::fromJsonText(scene(R"(, "spinning_friction": -1)", ""), "test");
    FAIL("accepted a negative spinning friction");
  } catch (const InputError& e) { CHECK(std::string(e.what()).find("spinning_friction") != std::string::npos); }
  {
    System sys;
    CHECK_THROWS_AS(sys.addBody(ball(Vec3{0, 1, 0}, real(0.5), real(-0.01), 0)), InputError);
    CHECK_THROWS_AS(sys.addBody(ball(Vec3{0, 1, 0}, real(0.5), 0, real(NAN))), InputError);
  }
  // Pruning: without rolling or spinning friction the rolling blocks are left out, and the step says why.
  for (real roll : {real(0), real(0.01)}) {
    System sys;
    sys.addBody(plane(Vec3{0, 1, 0}, 1));
    sys.addBody(ball(Vec3{0, kR, 0}, real(0.5), roll, 0));
    sys.advance(3);
    const StepStats& st = sys.lastStats();
    CHECK(st.part_ran[int(StagePart::RollingSpinningRows)] == (roll > 0));
    if (roll == 0) {
      REQUIRE(st.part_reason[int(StagePart::RollingSpinningRows)] != nullptr);
      CHECK(std::string(st.part_reason[int(StagePart::RollingSpinningRows)]) ==
            "no body has rolling or spinning friction");
      CHECK(sys.impulses().size() == 3 * sys.contacts().count());
    } else {
      CHECK(sys.rollingIndex(0) == 0);
      CHECK(sys.impulses().size() == 6 * sys.contacts().count());
    }
  }
}

// The GPU backend refuses it with an InputError naming it (its rolling blocks are built on the host only).
TEST_CASE("rolling friction: the GPU backend refuses it by name", "[rolling][gpu]") {
  if (!dvi::testing::haveDevice()) return;
  auto gpu = makeGpuSystem(SystemConfig{});
  gpu->addBody(plane(Vec3{0, 1, 0}, 1));
  gpu->addBody(ball(Vec3{0, kR, 0}, real(0.5), real(0.01), 0));
  try {
    gpu->step();
    FAIL("the GPU backend stepped a body with rolling friction");
  } catch (const InputError& e) { CHECK(std::string(e.what()).find("rolling") != std::string::npos); }
}

TEST_CASE("rolling friction: spheres poured on a plane heap up with it and spread without it", "[rolling][physics]") {
  // 180 spheres (r = 5 cm, mu = 0.5) in a loose 6 x 6 x 5 block released on a rough plane. Round grains with Coulomb friction
  // alone keep rolling on the plane and spread into a thin layer; rolling resistance lets them stand in a heap, the
  // role Zhou et al. (Powder Technology 125 (2002) 45-54, "Rolling friction in the dynamic simulation of sandpile
  // formation") give it for the angle of repose of spheres. Heap height and the radius holding 90% of the grains after
  // 4 s, with mu_r = 0 and mu_r = 0.2 r (combined: the ground's friction is 1). Measured: a layer 0.1 m high spread to
  // 3.65 m (1.6 degrees) without, a heap 0.275 m high within 0.66 m (22.7 degrees, about glass beads' angle of
  // repose) with.
  auto heap = [](real mur) {
    SystemConfig cfg;
    cfg.step.dt = real(1) / 240;
    System sys(cfg);
    sys.addBody(plane(Vec3{0, 1, 0}, 1));
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> j(-0.01, 0.01);
    const real r = real(0.05);
    for (int l = 0; l < 5; ++l)
      for (int i = 0; i < 6; ++i)
        for (int k = 0; k < 6; ++k) {
          BodyDesc b;
          b.pos = Vec3{real(0.105 * (i - 2.5) + j(rng)), real(r + 0.105 * l + 0.002), real(0.105 * (k - 2.5) + j(rng))};
          b.mass = 1;
          const real I = real(0.4) * r * r;
          b.inertia = Vec3{I, I, I};
          b.friction = real(0.5);
          b.rolling_friction = mur;
          b.shapes.push_back(makeSphere(r));
          sys.addBody(b);
        }
    sys.advance(4 * 240);
    const BodyArrays& B = sys.bodies();
    double top = 0;
    std::vector<double> radial;
    for (size_t i = 1; i < B.count(); ++i) {
      top = std::max(top, double(B.pos[i].y) + r);
      radial.push_back(std::hypot(double(B.pos[i].x), double(B.pos[i].z)));
    }
    std::sort(radial.begin(), radial.end());
    return std::pair<double, double>(top, radial[size_t(0.9 * double(radial.size()))]);
  };
  const auto free = heap(0), rolling = heap(real(0.01));
  const double angle_free = std::atan2(free.first, free.second) * 180 / M_PI;
  const double angle_roll = std::atan2(rolling.first, rolling.second) * 180 / M_PI;
  INFO("without rolling friction: height " << free.first << " m, 90% radius " << free.second << " m (" << angle_free
                                           << " deg); with mu_r = 0.2 r: height " << rolling.first << " m, radius "
                                           << rolling.second << " m (" << angle_roll << " deg)");
  CHECK(rolling.first >= 2 * free.first);
  CHECK(rolling.second <= 0.5 * free.second);
  CHECK(angle_roll >= 15);  // a heap, not a layer
  CHECK(angle_free <= 10);
}
