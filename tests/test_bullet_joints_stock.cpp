// Every constraint Bullet's discrete world steps, side by side: the same small scene in stock btDiscreteDynamicsWorld
// and in the drop-in world (bullet_world.h), the joint's error, angles, speeds and feedback of ours against Bullet's
// (a joint error at most 3x stock or 5 mm / 5 mrad). Locked hinges (setLimit(lo, lo)), slider angular limits, locked
// angles and motors, gears, Spring2 servos and bounce, linear 6-DoF motors, btJointFeedback and getAppliedImpulse,
// breaking thresholds, a hinge falling onto its limit, hinge2, a joint re-added with a large gap (Bullet's ERP), and
// ConstraintDemo's constraints in one scene (also on the GPU backend).
#include <btBulletDynamicsCommon.h>
#include <BulletDynamics/ConstraintSolver/btFixedConstraint.h>
#include <BulletDynamics/ConstraintSolver/btGearConstraint.h>
#include <BulletDynamics/ConstraintSolver/btGeneric6DofSpring2Constraint.h>
#include <BulletDynamics/ConstraintSolver/btHinge2Constraint.h>

#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "bullet_test_world.h"
#include "chrono_like/bullet/bullet_joints.h"
#include "chrono_like/bullet/bullet_world.h"
#include "device_check.h"

using namespace dvi;

namespace {

constexpr double kPi = 3.14159265358979323846;

// Stock Bullet or ours, gravity -9.81 along y, one sub-step per frame (1/60 s) unless asked otherwise.
struct Scene : TestWorld {
  explicit Scene(bool dvi, WorldBackend backend = WorldBackend::Cpu) : TestWorld(dvi, backend) {}
  btRigidBody* box(btVector3 half, btScalar mass, const btTransform& t) {
    return make(own(new btBoxShape(half)), mass, t);
  }
  void frames(int n, btScalar sub = btScalar(1) / 60) {
    for (int i = 0; i < n; ++i) world->stepSimulation(btScalar(1) / 60, 10, sub);
  }
};

// The angle of frame B's y axis about frame A's x axis (a slider's, Bullet's testAngLimits), frames in world.
double angleAboutX(const btTransform& fa, const btTransform& fb) {
  const btVector3 ya = fa.getBasis().getColumn(1), za = fa.getBasis().getColumn(2), yb = fb.getBasis().getColumn(1);
  return std::atan2(double(yb.dot(za)), double(yb.dot(ya)));
}

// The joint error tolerance: at most 3x stock's, or `floor` (5 mm / 5 mrad).
bool withinStock(double ours, double stock, double floor) { return ours <= std::max(3 * stock, floor); }

}  // namespace

TEST_CASE("hinge setLimit(lo, lo) locks the hinge as in Bullet, at zero and at another angle",
          "[world][joints][bullet]") {
  // A 2 kg bar on the fixed body through a horizontal hinge, its centre 0.5 m off the axis: gravity swings it unless
  // the lock holds. ForkLiftDemo's mast is held this way (setLimit(0, 0)).
  for (double lock : {0.0, 0.5, -2.0}) {
    double angle[2] = {0, 0}, worst[2] = {0, 0};
    for (int dvi = 0; dvi < 2; ++dvi) {
      Scene s(dvi);
      btRigidBody* bar = s.box(btVector3(0.5, 0.05, 0.05), 2, frame(btVector3(0.5, 2, 0)));
      auto* h = s.joint(new btHingeConstraint(*bar, frame(btVector3(-0.5, 0, 0))));
      h->setLimit(btScalar(lock), btScalar(lock));
      h->enableAngularMotor(true, 5, 1);  // ineffective on a locked hinge, as in Bullet
      // Start at the locked angle: the bar turned about the pivot (0, 2, 0) by +-lock, whichever Bullet reads as lock.
      for (double sign : {1.0, -1.0}) {
        const btQuaternion q(btVector3(0, 0, 1), btScalar(sign * lock));
        const btTransform t(q, btVector3(0, 2, 0) + quatRotate(q, btVector3(0.5, 0, 0)));
        bar->setCenterOfMassTransform(t);
        bar->getMotionState()->setWorldTransform(t);
        if (std::fabs(double(h->getHingeAngle()) - lock) < 1e-4) break;
      }
      REQUIRE(double(h->getHingeAngle()) == Approx(lock).margin(1e-4));
      for (int i = 0; i < 60; ++i) {
        s.frames(1);
        worst[dvi] = std::max(worst[dvi], std::fabs(double(h->getHingeAngle()) - lock));
      }
      angle[dvi] = h->getHingeAngle();
    }
    INFO("lock at " << lock << ": after 1 s Bullet " << angle[0] << ", ours " << angle[1] << "; worst |error| Bullet "
                    << worst[0] << ", ours " << worst[1]);
    CHECK(withinStock(worst[1], worst[0], 5e-3));
    CHECK(angle[1] == Approx(angle[0]).margin(5e-3));
  }
}

namespace {

// A slider from the fixed body along world x, with a box hanging 0.3 m below its axis (gravity turns it about the
// axis); `setup` sets limits and motors. Returns the angle about the axis and the slide after `n` frames, and the
// worst excess past the angular range over the run.
struct SliderRun {
  double angle = 0, slide = 0, worst = 0, omega = 0;
};
template <class Setup>
SliderRun sliderRun(bool dvi, int n, Setup setup) {
  Scene s(dvi);
  btRigidBody* body = s.box(btVector3(0.2, 0.1, 0.1), 1, frame(btVector3(0, 1.7, 0)));
  btRigidBody& fixed = btTypedConstraint::getFixedBody();
  const btTransform fa = frame(btVector3(0, 2, 0)), fb = frame(btVector3(0, 0.3, 0));
  auto* sl = s.joint(new btSliderConstraint(fixed, *body, fa, fb, true));
  setup(*sl);
  body->applyCentralImpulse(btVector3(0, 0, 0.5));  // a push across the axis: the box turns about it
  SliderRun r;
  for (int i = 0; i < n; ++i) {
    s.frames(1);
    const btTransform wb = body->getCenterOfMassTransform() * fb;
    r.angle = angleAboutX(fa, wb);
    r.slide = wb.getOrigin().x() - fa.getOrigin().x();
    if (sl->getLowerAngLimit() <= sl->getUpperAngLimit())
      r.worst = std::max(r.worst, std::max(sl->getLowerAngLimit() - r.angle, r.angle - sl->getUpperAngLimit()));
  }
  r.omega = body->getAngularVelocity().x();
  return r;
}

}  // namespace

TEST_CASE("slider: angular limit ranges, locked angles and the angular motor as in Bullet", "[world][joints][bullet]") {
  SECTION("an angular range (ConstraintDemo's +-pi/3): the box swings and stays inside it") {
    auto setup = [](btSliderConstraint& sl) {
      sl.setLowerLinLimit(-1);
      sl.setUpperLinLimit(1);
      sl.setLowerAngLimit(btScalar(-kPi / 3));
      sl.setUpperAngLimit(btScalar(kPi / 3));
    };
    const SliderRun bullet = sliderRun(false, 240, setup), ours = sliderRun(true, 240, setup);
    INFO("angle Bullet " << bullet.angle << ", ours " << ours.angle << "; worst excess Bullet " << bullet.worst
                         << ", ours " << ours.worst);
    CHECK(withinStock(ours.worst, bullet.worst, 5e-3));
    CHECK(std::fabs(ours.angle) <= kPi / 3 + 5e-3);
  }
  // Angular limits [lo, hi]: after `frames` frames the box rests at `expect`, where Bullet's rests.
  auto restsAt = [](double lo, double hi, int frames, double expect) {
    auto setup = [lo, hi](btSliderConstraint& sl) {
      sl.setLowerAngLimit(btScalar(lo));
      sl.setUpperAngLimit(btScalar(hi));
    };
    const SliderRun bullet = sliderRun(false, frames, setup), ours = sliderRun(true, frames, setup);
    INFO("angle Bullet " << bullet.angle << ", ours " << ours.angle);
    CHECK(ours.angle == Approx(bullet.angle).margin(5e-3));
    CHECK(ours.angle == Approx(expect).margin(5e-3));
  };
  SECTION("a range off zero: the box rests at its lower end, as in Bullet") { restsAt(0.3, 0.8, 180, 0.3); }
  SECTION("a non-zero locked angle") { restsAt(0.4, 0.4, 120, 0.4); }
  SECTION("the linear limit stops the box at it, where Bullet's passes it and drifts back") {
    // Bullet's code asks for |1 - dampingLimLin| of the incoming speed back, but stock Bullet leaves at -0.24 m/s
    // with dampingLimLin 0.5 and 1 alike (its limit's position correction); ours stops at the limit.
    for (double damping : {0.5, 1.0}) {
      double v[2], x[2];
      for (int dvi = 0; dvi < 2; ++dvi) {
        Scene s(dvi);
        btRigidBody* body = s.box(btVector3(0.2, 0.1, 0.1), 1, frame(btVector3(0.02, 2, 0)));
        btRigidBody& fixed = btTypedConstraint::getFixedBody();
        auto* sl =
            s.joint(new btSliderConstraint(fixed, *body, frame(btVector3(0, 2, 0)), frame(btVector3(0, 0, 0)), true));
        sl->setLowerLinLimit(-1);
        sl->setUpperLinLimit(1);
        sl->setDampingLimLin(btScalar(damping));
        body->setLinearVelocity(btVector3(3, 0, 0));
        s.frames(30);
        v[dvi] = body->getLinearVelocity().x();
        x[dvi] = body->getCenterOfMassPosition().x();
      }
      INFO("dampingLimLin " << damping << ": velocity after 0.5 s Bullet " << v[0] << ", ours " << v[1] << "; x Bullet "
                            << x[0] << ", ours " << x[1]);
      CHECK(x[1] == Approx(x[0]).margin(0.03));
      CHECK(x[1] <= 1 + 5e-3);
      CHECK(std::fabs(v[1]) <= std::fabs(v[0]) + 0.01);
    }
  }
  SECTION("the angular limit with dampingLimAng 0.5 and 1: the box spun into it, as in Bullet") {
    for (double damping : {0.5, 1.0}) {
      double w[2], a[2];
      for (int dvi = 0; dvi < 2; ++dvi) {
        Scene s(dvi);
        s.world->setGravity(btVector3(0, 0, 0));
        btRigidBody* body = s.box(btVector3(0.2, 0.1, 0.1), 1, frame(btVector3(0, 2, 0)));
        btRigidBody& fixed = btTypedConstraint::getFixedBody();
        const btTransform fa = frame(btVector3(0, 2, 0)), fb = frame(btVector3(0, 0, 0));
        auto* sl = s.joint(new btSliderConstraint(fixed, *body, fa, fb, true));
        sl->setLowerAngLimit(btScalar(-0.5));
        sl->setUpperAngLimit(btScalar(0.47));  // 0.05 rad a step at 3 rad/s: off a step's end
        sl->setDampingLimAng(btScalar(damping));
        body->setAngularVelocity(btVector3(3, 0, 0));
        s.frames(20);
        w[dvi] = body->getAngularVelocity().x();
        a[dvi] = angleAboutX(fa, body->getCenterOfMassTransform() * fb);
      }
      INFO("dampingLimAng " << damping << ": spin after 1/3 s Bullet " << w[0] << ", ours " << w[1] << "; angle Bullet "
                            << a[0] << ", ours " << a[1]);
      // Bullet's slider limit row appears once the limit is passed (it bounces from 0.50, a step later); ours acts
      // before the crossing (from 0.45). With no bounce Bullet's position correction sends it back at 0.36 rad/s.
      if (damping < 1) CHECK(w[1] == Approx(w[0]).margin(0.1));
      CHECK(std::fabs(w[1]) <= std::fabs(w[0]) + 0.01);
      CHECK(a[1] == Approx(a[0]).margin(0.1));
      CHECK(a[1] <= 0.47 + 5e-3);
    }
  }
  SECTION("the angular motor: the box turns at the motor's speed, in Bullet's direction") {
    auto setup = [](btSliderConstraint& sl) {
      sl.setLowerAngLimit(1);
      sl.setUpperAngLimit(-1);  // free rotation
      sl.setPoweredAngMotor(true);
      sl.setTargetAngMotorVelocity(2);
      sl.setMaxAngMotorForce(50);
    };
    const SliderRun bullet = sliderRun(false, 30, setup), ours = sliderRun(true, 30, setup);
    INFO("spin about the axis: Bullet " << bullet.omega << ", ours " << ours.omega);
    CHECK(ours.omega == Approx(bullet.omega).margin(0.05));
    CHECK(std::fabs(ours.omega) == Approx(2).margin(0.05));
  }
}

TEST_CASE("gear: two wheels turn in Bullet's ratio, with Bullet's speeds", "[world][joints][bullet]") {
  // Two discs on hinges about world z; a gear with ratio 2 between them; a torque on the first for 0.5 s.
  double wa[2], wb[2];
  for (int dvi = 0; dvi < 2; ++dvi) {
    Scene s(dvi);
    s.world->setGravity(btVector3(0, 0, 0));
    btCollisionShape* disc = s.own(new btCylinderShapeZ(btVector3(0.5, 0.5, 0.05)));
    btRigidBody* a = s.make(disc, 1, btVector3(0, 2, 0));
    btRigidBody* b = s.make(disc, 2, btVector3(2, 2, 0));
    btVector3 z(0, 0, 1);
    s.joint(new btHingeConstraint(*a, btVector3(0, 0, 0), z));
    s.joint(new btHingeConstraint(*b, btVector3(0, 0, 0), z));
    s.joint(new btGearConstraint(*a, *b, z, z, 2), true);
    for (int i = 0; i < 30; ++i) {
      a->applyTorque(btVector3(0, 0, 1));
      s.frames(1);
      // Bullet's row: wA.axisA + ratio wB.axisB = 0.
      if (dvi) CHECK(std::fabs(a->getAngularVelocity().z() + 2 * b->getAngularVelocity().z()) < 1e-6);
    }
    wa[dvi] = a->getAngularVelocity().z();
    wb[dvi] = b->getAngularVelocity().z();
  }
  INFO("wA Bullet " << wa[0] << ", ours " << wa[1] << "; wB Bullet " << wb[0] << ", ours " << wb[1]);
  // Closed form: I_a wA' + ratio-coupled I_b: (I_a + 4 I_b) wA' = torque, I = m r^2 / 4 + m h^2 / 12 about z... the
  // cylinder's: m r^2 / 2 (Bullet's btCylinderShapeZ inertia): I_a = 0.125, I_b = 0.25, wA(0.5 s) = 0.5 / 1.125.
  CHECK(wa[1] == Approx(wa[0]).epsilon(0.02));
  CHECK(wb[1] == Approx(wb[0]).epsilon(0.02));
}

namespace {

// A box on the fixed body through a Spring2 with everything locked but `free_axis` (0..5, Bullet's order), where
// `setup` sets a motor or servo; gravity off. Returns Bullet's position of that axis over the run (every 6 frames).
template <class Setup>
std::vector<double> spring2Run(bool dvi, int free_axis, int n, Setup setup) {
  Scene s(dvi);
  s.world->setGravity(btVector3(0, 0, 0));
  btRigidBody* body = s.box(btVector3(0.3, 0.1, 0.1), 1, frame(btVector3(0.3, 2, 0)));
  btRigidBody& fixed = btTypedConstraint::getFixedBody();
  auto* c = s.joint(
      new btGeneric6DofSpring2Constraint(fixed, *body, frame(btVector3(0, 2, 0)), frame(btVector3(-0.3, 0, 0))));
  for (int i = 0; i < 6; ++i) c->setLimit(i, 0, 0);
  c->setLimit(free_axis, 1, -1);
  setup(*c);
  std::vector<double> out;
  for (int i = 0; i < n; ++i) {
    s.frames(1);
    if (i % 6 != 5) continue;
    c->calculateTransforms();
    out.push_back(free_axis < 3 ? double(c->getRelativePivotPosition(free_axis)) : double(c->getAngle(free_axis - 3)));
  }
  return out;
}

}  // namespace

TEST_CASE("Spring2 servo motors drive to their target as in Bullet (rotation and translation)",
          "[world][joints][bullet]") {
  struct Case {
    int axis;
    double target, speed, force;
    const char* what;
  } cases[] = {
      {5, kPi / 2, 3, 600, "Dof6Spring2Setup's servo on rotation z"},
      {3, -1.0, 2, 50, "a servo on rotation x, negative target"},
      {0, 0.4, 1, 100, "a servo on translation x"},
      {1, -0.3, 2, 100, "a servo on translation y, negative target"},
  };
  for (const Case& k : cases) {
    auto setup = [&](btGeneric6DofSpring2Constraint& c) {
      c.enableMotor(k.axis, true);
      c.setTargetVelocity(k.axis, btScalar(k.speed));
      c.setMaxMotorForce(k.axis, btScalar(k.force));
      c.setServo(k.axis, true);
      c.setServoTarget(k.axis, btScalar(k.target));
    };
    const std::vector<double> bullet = spring2Run(false, k.axis, 120, setup),
                              ours = spring2Run(true, k.axis, 120, setup);
    for (size_t i = 0; i < bullet.size(); ++i) {
      INFO(k.what << " at frame " << 6 * (i + 1) << ": Bullet " << bullet[i] << ", ours " << ours[i]);
      // Approach at the motor's speed, then Bullet's ERP near the target: within 5% of the travel all along.
      CHECK(ours[i] == Approx(bullet[i]).margin(0.05 * std::fabs(k.target)));
    }
    CHECK(ours.back() == Approx(k.target).margin(5e-3));
  }
}

TEST_CASE("Spring2 and 6-DoF velocity motors on translation move in Bullet's direction at its speed",
          "[world][joints][bullet]") {
  for (int kind : {0, 1}) {
    double x[2];
    for (int dvi = 0; dvi < 2; ++dvi) {
      Scene s(dvi);
      s.world->setGravity(btVector3(0, 0, 0));
      btRigidBody* body = s.box(btVector3(0.3, 0.1, 0.1), 1, frame(btVector3(0.3, 2, 0)));
      btRigidBody& fixed = btTypedConstraint::getFixedBody();
      const btTransform fa = frame(btVector3(0, 2, 0)), fb = frame(btVector3(-0.3, 0, 0));
      if (kind == 0) {  // ConstraintDemo's slider-like 6-DoF with the translational motor on x
        auto* g = s.joint(new btGeneric6DofConstraint(fixed, *body, fa, fb, true));
        g->setLinearLowerLimit(btVector3(-10, 0, 0));
        g->setLinearUpperLimit(btVector3(10, 0, 0));
        g->setAngularLowerLimit(btVector3(0, 0, 0));
        g->setAngularUpperLimit(btVector3(0, 0, 0));
        g->getTranslationalLimitMotor()->m_enableMotor[0] = true;
        g->getTranslationalLimitMotor()->m_targetVelocity[0] = 1.5;
        g->getTranslationalLimitMotor()->m_maxMotorForce[0] = 20;
      } else {
        auto* g = s.joint(new btGeneric6DofSpring2Constraint(fixed, *body, fa, fb));
        for (int i = 0; i < 6; ++i) g->setLimit(i, 0, 0);
        g->setLimit(0, -10, 10);
        g->enableMotor(0, true);
        g->setTargetVelocity(0, 1.5);
        g->setMaxMotorForce(0, 20);
      }
      s.frames(60);
      x[dvi] = body->getCenterOfMassPosition().x() - 0.3;
    }
    INFO((kind ? "Spring2" : "6-DoF") << ": slide after 1 s Bullet " << x[0] << ", ours " << x[1]);
    CHECK(x[1] == Approx(x[0]).margin(0.03));
  }
}

TEST_CASE("Spring2 setBounce and stop ERP: a box bounces off a linear limit as in Bullet", "[world][joints][bullet]") {
  // Dof6Spring2Setup's bouncing box: x limited to (-inf, 2] with bounce 1 and stop ERP 0.995; the box starts at
  // 1.02 moving +x at 3 m/s (0.05 m a step: from 1 it would reach the limit exactly at a step's end, where rounding
  // decides the step of the bounce). After the bounce it moves back at Bullet's speed.
  for (double bounce : {1.0, 0.5, 0.0}) {
    double v[2], x[2];
    for (int dvi = 0; dvi < 2; ++dvi) {
      Scene s(dvi);
      s.world->setGravity(btVector3(0, 0, 0));
      btRigidBody* body = s.box(btVector3(0.1, 0.1, 0.1), 1, frame(btVector3(1.02, 2, 0)));
      btRigidBody& fixed = btTypedConstraint::getFixedBody();
      auto* c = s.joint(
          new btGeneric6DofSpring2Constraint(fixed, *body, frame(btVector3(0, 2, 0)), frame(btVector3(0, 0, 0))));
      for (int i = 0; i < 6; ++i) c->setLimit(i, 0, 0);
      c->setLimit(0, -SIMD_INFINITY, 2);
      c->setBounce(0, btScalar(bounce));
      c->setParam(BT_CONSTRAINT_STOP_ERP, btScalar(0.995), 0);
      c->setParam(BT_CONSTRAINT_STOP_CFM, 0, 0);
      body->setLinearVelocity(btVector3(3, 0, 0));
      s.frames(30);
      v[dvi] = body->getLinearVelocity().x();
      x[dvi] = body->getCenterOfMassPosition().x();
    }
    INFO("bounce " << bounce << ": velocity after 0.5 s Bullet " << v[0] << ", ours " << v[1] << "; x Bullet " << x[0]
                   << ", ours " << x[1]);
    CHECK(v[1] == Approx(v[0]).margin(0.05 * 3));
    CHECK(x[1] == Approx(x[0]).margin(0.05));
    CHECK(x[1] <= 2 + 5e-3);
  }
}

TEST_CASE("btJointFeedback and getAppliedImpulse are filled as Bullet fills them", "[world][joints][bullet]") {
  // TestHingeTorque's use: a 0.53 kg link hanging from a fixed 6-DoF and a hinge, feedback read each frame; gravity
  // -z (force on the link from the joint +m g along z, Bullet's (0, 0, 5.19)).
  struct Out {
    btJointFeedback fb_fixed, fb_hinge, fb_p2p, fb_weld;
    double p2p_impulse = 0;
  };
  Out out[2];
  for (int dvi = 0; dvi < 2; ++dvi) {
    Scene s(dvi);
    s.world->setGravity(btVector3(0, 0, -9.8));
    btRigidBody& fixed = btTypedConstraint::getFixedBody();
    btRigidBody* link = s.box(btVector3(0.05, 0.05, 0.2), btScalar(0.53), frame(btVector3(0, 0, 1)));
    auto* g = s.joint(
        new btGeneric6DofSpring2Constraint(fixed, *link, frame(btVector3(0, 0, 1.2)), frame(btVector3(0, 0, 0.2))));
    for (int i = 0; i < 6; ++i) g->setLimit(i, 0, 0);
    btJointFeedback fb1, fb2, fb3;
    g->setJointFeedback(&fb1);
    g->enableFeedback(true);
    // A pendulum on a hinge (about y), at rest hanging: its feedback carries the link's weight.
    btRigidBody* bob = s.box(btVector3(0.05, 0.05, 0.2), 1, frame(btVector3(2, 0, 1)));
    auto* h = s.joint(new btHingeConstraint(
        fixed, *bob, frame(btVector3(2, 0, 1.2), btQuaternion(btVector3(1, 0, 0), btScalar(kPi / 2))),
        frame(btVector3(0, 0, 0.2), btQuaternion(btVector3(1, 0, 0), btScalar(kPi / 2)))));
    h->setJointFeedback(&fb2);
    // A point-to-point: getAppliedImpulse is its last row's (Bullet: world z) impulse, m g h.
    btRigidBody* ball = s.box(btVector3(0.1, 0.1, 0.1), 2, frame(btVector3(-2, 0, 1)));
    auto* p = s.joint(new btPoint2PointConstraint(*ball, btVector3(0, 0, 0.2)));
    p->setJointFeedback(&fb3);
    p->enableFeedback(true);
    // A btFixedConstraint holding a 1.5 kg box 0.4 m out from its pivot: a force m g, and about the box's centre of
    // mass no torque (the pivot force's moment and the angular rows' cancel).
    btRigidBody* welded = s.box(btVector3(0.2, 0.05, 0.05), btScalar(1.5), frame(btVector3(4.4, 0, 1)));
    btJointFeedback fb4;
    auto* weld =
        s.joint(new btFixedConstraint(fixed, *welded, frame(btVector3(4, 0, 1)), frame(btVector3(-0.4, 0, 0))));
    weld->setJointFeedback(&fb4);
    s.frames(60);
    out[dvi] = Out{fb1, fb2, fb3, fb4, double(p->getAppliedImpulse())};
  }
  auto near = [](const btVector3& a, const btVector3& b, double tol) { return (a - b).length() <= tol; };
  auto str = [](const btVector3& v) {
    return "(" + std::to_string(v.x()) + ", " + std::to_string(v.y()) + ", " + std::to_string(v.z()) + ")";
  };
  const Out &b = out[0], &o = out[1];
  INFO("fixed: force on B Bullet " << str(b.fb_fixed.m_appliedForceBodyB) << ", ours "
                                   << str(o.fb_fixed.m_appliedForceBodyB));
  INFO("hinge: force on B Bullet " << str(b.fb_hinge.m_appliedForceBodyB) << ", ours "
                                   << str(o.fb_hinge.m_appliedForceBodyB));
  INFO("p2p: force on A Bullet " << str(b.fb_p2p.m_appliedForceBodyA) << ", ours " << str(o.fb_p2p.m_appliedForceBodyA)
                                 << "; applied impulse Bullet " << b.p2p_impulse << ", ours " << o.p2p_impulse);
  CHECK(near(b.fb_fixed.m_appliedForceBodyB, btVector3(0, 0, btScalar(0.53 * 9.8)), 0.01));  // the closed form
  CHECK(near(o.fb_fixed.m_appliedForceBodyB, b.fb_fixed.m_appliedForceBodyB, 0.01));
  CHECK(near(o.fb_fixed.m_appliedTorqueBodyB, b.fb_fixed.m_appliedTorqueBodyB, 0.01));
  CHECK(near(o.fb_fixed.m_appliedForceBodyA, b.fb_fixed.m_appliedForceBodyA, 0.01));  // the fixed body's side
  CHECK(near(o.fb_hinge.m_appliedForceBodyB, b.fb_hinge.m_appliedForceBodyB, 0.01));
  CHECK(near(o.fb_hinge.m_appliedTorqueBodyB, b.fb_hinge.m_appliedTorqueBodyB, 0.01));
  CHECK(near(o.fb_p2p.m_appliedForceBodyA, b.fb_p2p.m_appliedForceBodyA, 0.01));
  CHECK(o.p2p_impulse == Approx(b.p2p_impulse).epsilon(0.01));
  CHECK(o.p2p_impulse == Approx(2 * 9.8 / 60).epsilon(0.01));
  INFO("btFixedConstraint: force on B Bullet " << str(b.fb_weld.m_appliedForceBodyB) << ", ours "
                                               << str(o.fb_weld.m_appliedForceBodyB) << "; torque on B Bullet "
                                               << str(b.fb_weld.m_appliedTorqueBodyB) << ", ours "
                                               << str(o.fb_weld.m_appliedTorqueBodyB));
  CHECK(near(o.fb_weld.m_appliedForceBodyB, btVector3(0, 0, btScalar(1.5 * 9.8)), 0.02));
  CHECK(near(o.fb_weld.m_appliedForceBodyB, b.fb_weld.m_appliedForceBodyB, 0.02));
  CHECK(near(o.fb_weld.m_appliedTorqueBodyB, b.fb_weld.m_appliedTorqueBodyB, 0.02));
}

TEST_CASE("breaking thresholds: a joint breaks on the frame Bullet's breaks, and holds below",
          "[world][joints][bullet]") {
  // ConstraintDemo's breakable point-to-point (threshold 10.2): a 1 kg box hangs from it, and at frame 30 a push of
  // `push` N s straight down. Each row is bounded by the threshold; a row at it breaks the joint.
  for (double push : {5.0, 12.0}) {
    int broke[2] = {-1, -1};
    double y[2];
    for (int dvi = 0; dvi < 2; ++dvi) {
      Scene s(dvi);
      btRigidBody* box = s.box(btVector3(0.2, 0.2, 0.2), 1, frame(btVector3(0, 2, 0)));
      auto* p = s.joint(new btPoint2PointConstraint(*box, btVector3(0, 0.5, 0)));
      p->setBreakingImpulseThreshold(btScalar(10.2));
      for (int i = 0; i < 60; ++i) {
        if (i == 30) box->applyCentralImpulse(btVector3(0, btScalar(-push), 0));
        s.frames(1);
        if (broke[dvi] < 0 && !p->isEnabled()) broke[dvi] = i;
      }
      y[dvi] = box->getCenterOfMassPosition().y();
    }
    INFO("push " << push << ": broke at frame Bullet " << broke[0] << ", ours " << broke[1] << "; y Bullet " << y[0]
                 << ", ours " << y[1]);
    CHECK(broke[1] == broke[0]);
    CHECK(y[1] == Approx(y[0]).margin(0.05));
  }
}

TEST_CASE("hinge limits: a bar falls onto its limit and stays there as in Bullet", "[world][joints][bullet]") {
  // A bar on a hinge about z falls from horizontal onto its limit at -0.6 rad (setLimit's softness, bias and
  // relaxation as given). Bullet's limit code asks for relaxation x bias factor of the incoming speed back, yet
  // stock Bullet's bar rises only ~0.01 rad after the hit; ours stops at the limit (docs/DROP_IN.md).
  for (double relaxation : {1.0, 0.0}) {
    double peak_after[2] = {-10, -10}, end[2], worst[2] = {0, 0};
    for (int dvi = 0; dvi < 2; ++dvi) {
      Scene s(dvi);
      btRigidBody* bar = s.box(btVector3(0.5, 0.05, 0.05), 1, frame(btVector3(0.5, 2, 0)));
      auto* h = s.joint(new btHingeConstraint(*bar, frame(btVector3(-0.5, 0, 0))));
      h->setLimit(-0.6, 0.6, 0.9, 0.3, btScalar(relaxation));
      bool hit = false;
      for (int i = 0; i < 90; ++i) {
        s.frames(1, btScalar(1) / 240);
        const double a = h->getHingeAngle();
        worst[dvi] = std::max(worst[dvi], std::fabs(a) - 0.6);
        if (a < -0.59) hit = true;
        if (hit) peak_after[dvi] = std::max(peak_after[dvi], a);
      }
      end[dvi] = h->getHingeAngle();
    }
    INFO("relaxation " << relaxation << ": highest angle after the hit Bullet " << peak_after[0] << ", ours "
                       << peak_after[1] << "; end Bullet " << end[0] << ", ours " << end[1] << "; worst excess Bullet "
                       << worst[0] << ", ours " << worst[1]);
    CHECK(peak_after[1] == Approx(peak_after[0]).margin(0.015));
    CHECK(end[1] == Approx(end[0]).margin(5e-3));
    CHECK(withinStock(worst[1], worst[0], 5e-3));
  }
}

TEST_CASE("a joint re-added with an 11 m gap closes at Bullet's ERP rate, with Bullet's energy",
          "[world][joints][bullet]") {
  // A 10 kg box on a point-to-point to the fixed body: removed, moved 11 m away, re-added. Bullet closes the gap by
  // ERP (0.2) of it per step; so do we once the error is beyond the recovery speed (JointSettings).
  double gap[2], energy[2];
  for (int dvi = 0; dvi < 2; ++dvi) {
    Scene s(dvi);
    btRigidBody* box = s.box(btVector3(0.3, 0.3, 0.3), 10, frame(btVector3(0, 2, 0)));
    auto* p = s.joint(new btPoint2PointConstraint(*box, btVector3(0, 0.5, 0)));
    s.frames(10);
    s.world->removeConstraint(p);
    btTransform t = box->getCenterOfMassTransform();
    t.setOrigin(t.getOrigin() + btVector3(11, 0, 0));
    box->setCenterOfMassTransform(t);
    box->getMotionState()->setWorldTransform(t);
    s.world->addConstraint(p);
    s.frames(120);
    gap[dvi] = (box->getCenterOfMassTransform() * btVector3(0, 0.5, 0) - p->getPivotInB()).length();
    const btVector3 v = box->getLinearVelocity(), w = box->getAngularVelocity();
    energy[dvi] = 0.5 * 10 * v.length2() + 0.5 * w.dot(box->getInvInertiaTensorWorld().inverse() * w);
  }
  INFO("after 120 steps: gap Bullet " << gap[0] << " m, ours " << gap[1] << " m; kinetic energy Bullet " << energy[0]
                                      << " J, ours " << energy[1] << " J");
  CHECK(withinStock(gap[1], gap[0], 5e-3));
  CHECK(energy[1] <= 3 * energy[0] + 1);
}

TEST_CASE("hinge2: a wheel on its suspension, drive and steering motors, as on Bullet", "[world][joints][bullet]") {
  // Hinge2Vehicle's wheel joint under a static chassis: anchor at the wheel, parent axis (steering, Bullet's z) world
  // y, child axis (spin, Bullet's x) world x; the suspension spring along the parent axis carries the wheel's weight;
  // the drive motor (axis 3) spins the wheel, the steering motor (axis 5) turns it to its limit.
  double y[2], spin[2], steer[2], worst[2] = {0, 0};
  for (int dvi = 0; dvi < 2; ++dvi) {
    Scene s(dvi);
    btRigidBody* chassis = s.box(btVector3(0.5, 0.1, 0.5), 0, frame(btVector3(0, 2, 0)));
    btRigidBody* wheel = s.make(s.own(new btCylinderShapeX(btVector3(0.1, 0.3, 0.3))), 1, btVector3(0.9, 2, 0));
    btVector3 anchor(0.9, 2, 0), parent(0, 1, 0), child(1, 0, 0);
    auto* h2 = s.joint(new btHinge2Constraint(*chassis, *wheel, anchor, parent, child), true);
    h2->setLowerLimit(btScalar(-kPi / 4));
    h2->setUpperLimit(btScalar(kPi / 4));
    h2->enableMotor(3, true);
    h2->setMaxMotorForce(3, 10);
    h2->setTargetVelocity(3, 4);
    h2->enableMotor(5, true);
    h2->setMaxMotorForce(5, 10);
    h2->setTargetVelocity(5, 0.5);
    h2->setParam(BT_CONSTRAINT_CFM, btScalar(0.15), 2);
    h2->setParam(BT_CONSTRAINT_ERP, btScalar(0.35), 2);
    h2->setDamping(2, 2.0);
    h2->setStiffness(2, 400.0);
    for (int i = 0; i < 120; ++i) {
      s.frames(1);
      h2->calculateTransforms();
      worst[dvi] = std::max(worst[dvi], std::fabs(double(h2->getAngle(1))));  // the locked middle angle
    }
    y[dvi] = wheel->getCenterOfMassPosition().y();
    spin[dvi] = h2->getRigidBodyB().getAngularVelocity().dot(wheel->getWorldTransform().getBasis().getColumn(0));
    steer[dvi] = h2->getAngle(2);
  }
  INFO("wheel height Bullet " << y[0] << ", ours " << y[1] << " (spring sag m g / k = " << 9.81 / 400
                              << "); spin Bullet " << spin[0] << ", ours " << spin[1] << "; steering Bullet "
                              << steer[0] << ", ours " << steer[1] << "; worst locked angle Bullet " << worst[0]
                              << ", ours " << worst[1]);
  CHECK(y[1] == Approx(y[0]).margin(5e-3));
  CHECK(spin[1] == Approx(spin[0]).margin(0.1));
  CHECK(std::fabs(steer[1]) == Approx(std::fabs(steer[0])).margin(0.02));
  CHECK(withinStock(worst[1], worst[0], 5e-3));
}

namespace {

// Our violation measure (joints.h: jointViolation) of a constraint at its bodies' Bullet poses: it reads only the
// btRigidBody transforms, so it measures stock Bullet's joints and ours alike.
JointViolation violationAt(const btTypedConstraint& c) {
  const JointSpec j = jointSpecFromBullet(c);
  auto side = [](const btRigidBody& b) {
    JointBody s;
    const btTransform& t = b.getCenterOfMassTransform();
    s.x = Vec3{real(t.getOrigin().x()), real(t.getOrigin().y()), real(t.getOrigin().z())};
    const btQuaternion q = t.getRotation();
    s.q = Quat{real(q.w()), real(q.x()), real(q.y()), real(q.z())};
    return s;
  };
  return jointViolation(j, side(c.getRigidBodyA()), side(c.getRigidBodyB()));
}

// After bullet3's examples/Constraints/ConstraintDemo: a gear between two spinning discs (one tilted, its linear
// factor 0), a breakable point-to-point, a ball socket, a slider with linear limits and an angular range of
// +-pi/3, a 6-DoF slider driven by its linear motor with the rotation about x limited to [-pi, 1.5], a door hinge
// limited to +-pi/4 and pushed, a 6-DoF spring, a cone-twist and a hinge with a motor; 300 frames at 60 Hz.
// Each joint's worst linear and angular error over the run, by our measure at the bodies' Bullet poses, on stock
// Bullet (dvi false) or ours on `backend`.
struct DemoErrors {
  double linear[9] = {}, angular[9] = {};
};
DemoErrors constraintDemoErrors(bool dvi, WorldBackend backend) {
  DemoErrors e;
  {
    Scene s(dvi, backend);
    btRigidBody& fixed = btTypedConstraint::getFixedBody();
    btCollisionShape* cube = s.own(new btBoxShape(btVector3(1, 1, 1)));
    btCollisionShape* disc = s.own(new btCylinderShape(btVector3(0.5, 0.2, 0.5)));
    std::vector<btTypedConstraint*> c;
    // The gear: disc A spins about y, disc B tilted by 0.3 about z, both held in place.
    const double theta = 0.3;
    btRigidBody* da = s.make(disc, btScalar(3.14), btVector3(-10, 2, -8));
    btRigidBody* db = s.make(disc, btScalar(6.28),
                             btTransform(btQuaternion(btVector3(0, 0, 1), btScalar(-theta)), btVector3(-10, 2, -6)));
    da->setLinearFactor(btVector3(0, 0, 0));
    db->setLinearFactor(btVector3(0, 0, 0));
    c.push_back(s.joint(new btHingeConstraint(*da, btVector3(0, 0, 0), btVector3(0, 1, 0), true)));
    s.joint(new btHingeConstraint(*db, btVector3(0, 0, 0), btVector3(0, 1, 0), true));
    db->setAngularVelocity(btTransform(db->getWorldTransform()).getBasis() * btVector3(0, 3, 0));
    const btVector3 axisB = btMatrix3x3(btQuaternion(btVector3(0, 0, 1), btScalar(-theta))).getRow(1);
    s.joint(new btGearConstraint(*da, *db, btVector3(0, 1, 0), axisB, 4), true);
    // Breakable point-to-point (threshold 10.2) and a ball socket, each on a hanging cube.
    btRigidBody* b0 = s.make(cube, 1, btVector3(0, 0, -5));
    auto* breakable = s.joint(new btPoint2PointConstraint(*b0, btVector3(1, 1, 0)));
    breakable->setBreakingImpulseThreshold(btScalar(10.2));
    c.push_back(breakable);
    btRigidBody* b1 = s.make(cube, 1, btVector3(2, 20, 0));
    c.push_back(s.joint(new btPoint2PointConstraint(*b1, btVector3(1, -1, -1))));
    // Slider between two cubes, linear [-15, -5], angular +-pi/3.
    btRigidBody* sa = s.make(cube, 1, btVector3(-20, 0, 30));
    btRigidBody* sb = s.make(cube, 1, btVector3(-30, 0, 30));
    auto* slider =
        s.joint(new btSliderConstraint(*sa, *sb, btTransform::getIdentity(), btTransform::getIdentity(), true), true);
    slider->setLowerLinLimit(-15);
    slider->setUpperLinLimit(-5);
    slider->setLowerAngLimit(btScalar(-kPi / 3));
    slider->setUpperAngLimit(btScalar(kPi / 3));
    c.push_back(slider);
    // 6-DoF slider on the fixed body with its linear motor.
    btRigidBody* d6 = s.make(cube, 1, btVector3(0, 10, 0));
    auto* slider6 =
        s.joint(new btGeneric6DofConstraint(fixed, *d6, frame(btVector3(0, 15, 0)), frame(btVector3(0, 5, 0)), true));
    slider6->setLinearLowerLimit(btVector3(-10, 0, 0));
    slider6->setLinearUpperLimit(btVector3(10, 0, 0));
    slider6->setAngularLowerLimit(btVector3(btScalar(-kPi), 0, 0));
    slider6->setAngularUpperLimit(btVector3(1.5, 0, 0));
    slider6->getTranslationalLimitMotor()->m_enableMotor[0] = true;
    slider6->getTranslationalLimitMotor()->m_targetVelocity[0] = -5;
    slider6->getTranslationalLimitMotor()->m_maxMotorForce[0] = 6;
    c.push_back(slider6);
    // A door on a hinge limited to +-pi/4, pushed.
    btRigidBody* door = s.make(s.own(new btBoxShape(btVector3(2, 5, 0.1))), 1, btVector3(-5, 4, 0));
    auto* hinge = s.joint(new btHingeConstraint(*door, btVector3(-2.1, 0, 0), btVector3(0, 1, 0), true));
    hinge->setLimit(btScalar(-kPi / 4), btScalar(kPi / 4));
    door->applyImpulse(btVector3(0, 0, 5), btVector3(2, 0, 0));
    c.push_back(hinge);
    // A 6-DoF spring between the fixed body and a cube: x within +-5 with a spring, z rotation within +-1.5 with one.
    btRigidBody* sp = s.make(cube, 1, btVector3(0, 10, 10));
    auto* spring = s.joint(
        new btGeneric6DofSpringConstraint(fixed, *sp, frame(btVector3(0, 10, 10)), frame(btVector3(0, 0, 0)), true));
    spring->setLinearLowerLimit(btVector3(-5, 0, 0));
    spring->setLinearUpperLimit(btVector3(5, 0, 0));
    spring->setAngularLowerLimit(btVector3(0, 0, -1.5));
    spring->setAngularUpperLimit(btVector3(0, 0, 1.5));
    spring->enableSpring(0, true);
    spring->setStiffness(0, btScalar(39.478));
    spring->enableSpring(5, true);
    spring->setStiffness(5, btScalar(39.478));
    sp->applyCentralImpulse(btVector3(3, 0, 0));
    c.push_back(spring);
    // A cone-twist pendulum, and a hinge driven by its motor.
    btRigidBody* ct = s.make(cube, 1, btVector3(10, 5, 0));
    const btQuaternion down(btVector3(0, 0, 1), btScalar(kPi / 2));  // the cone's axis (frame x) along y
    auto* cone = s.joint(
        new btConeTwistConstraint(fixed, *ct, frame(btVector3(10, 8, 0), down), frame(btVector3(0, 3, 0), down)));
    cone->setLimit(btScalar(kPi / 4 * 0.6), btScalar(kPi / 4), btScalar(kPi * 0.8), btScalar(0.5));
    ct->applyCentralImpulse(btVector3(2, 0, 3));
    c.push_back(cone);
    btRigidBody* mh = s.make(cube, 1, btVector3(20, 5, 0));
    auto* motor = s.joint(new btHingeConstraint(*mh, btVector3(0, 3, 0), btVector3(0, 0, 1), true));
    motor->enableAngularMotor(true, 1, 1);
    c.push_back(motor);
    REQUIRE(c.size() == 9);
    for (int i = 0; i < 300; ++i) {
      s.frames(1);
      for (size_t k = 0; k < c.size(); ++k) {
        if (!c[k]->isEnabled()) continue;
        const JointViolation v = violationAt(*c[k]);
        e.linear[k] = std::max(e.linear[k], double(v.linear));
        e.angular[k] = std::max(e.angular[k], double(v.angular));
      }
    }
  }
  return e;
}

const char* const kDemoJoints[9] = {"gear hinge", "breakable p2p", "ball socket", "slider",     "6-DoF slider",
                                    "door hinge", "6-DoF spring",  "cone-twist",  "motor hinge"};

void checkDemoAgainstStock(WorldBackend backend) {
  const DemoErrors bullet = constraintDemoErrors(false, backend), ours = constraintDemoErrors(true, backend);
  for (int k = 0; k < 9; ++k) {
    INFO(kDemoJoints[k] << ": worst linear error Bullet " << bullet.linear[k] << " m, ours " << ours.linear[k]
                        << " m; worst angular error Bullet " << bullet.angular[k] << " rad, ours " << ours.angular[k]);
    CHECK(withinStock(ours.linear[k], bullet.linear[k], 5e-3));
    CHECK(withinStock(ours.angular[k], bullet.angular[k], 5e-3));
  }
}

}  // namespace

TEST_CASE("ConstraintDemo's constraints together: each joint held as stock Bullet holds it",
          "[world][joints][bullet]") {
  checkDemoAgainstStock(WorldBackend::Cpu);
}

TEST_CASE("ConstraintDemo's constraints on the GPU backend: each joint held as stock Bullet holds it",
          "[world][joints][bullet][gpu]") {
  if (!dvi::testing::haveDevice()) return;
  checkDemoAgainstStock(WorldBackend::Gpu);
}
