// The Bullet drop-in world (bullet_world.h) and its joints (bullet_joints.h, joints.h), against plain Bullet and closed forms.
#include <btBulletDynamicsCommon.h>
#include <BulletDynamics/ConstraintSolver/btFixedConstraint.h>
#include <BulletDynamics/ConstraintSolver/btGearConstraint.h>
#include <BulletDynamics/ConstraintSolver/btGeneric6DofSpring2Constraint.h>
#include <BulletCollision/CollisionShapes/btMultiSphereShape.h>
#include <btBulletWorldImporter.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <cstdlib>
#include <memory>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "device_check.h"
#include "../demos/bullet_drop_in/demo_scene.h"
#include "bullet_test_world.h"
#include "chrono_like/bullet/bullet_joints.h"
#include "chrono_like/bullet/bullet_world.h"
#include "chrono_like/bullet/triangle_mesh.h"
#include "gpu/gpu_factory.h"

using namespace dvi;

namespace {

using dvi::testing::haveDevice;

// The solver side of the constraint rows (System::rowImpulses) is present in this build.
bool rowsSolved(DviDynamicsWorld& w) {
  return !w.system().constraintRows().empty() && w.system().rowImpulses().size() == w.system().constraintRows().size();
}

// Pose of the joint side B that satisfies the joint exactly, then perturbed by a small error.
JointBody closeB(const JointSpec& j, const JointBody& A, std::mt19937& rng, real err) {
  const Pose fa = compose(Pose{A.x, A.q}, j.frame_a);
  Pose fb = fa;  // B's joint frame on A's
  fb.p += randomVec(rng, err);
  fb.q = normalized(quatFromRotationVector(randomVec(rng, err)) * fb.q);
  // B's centre pose: fb = xB * frame_b  =>  xB = fb * frame_b^-1
  JointBody B;
  B.q = normalized(fb.q * conj(j.frame_b.q));
  B.x = fb.p - rotate(B.q, j.frame_b.p);
  B.index = 1;
  B.size = 1;
  return B;
}

// J v of row r: the constraint's rate at the bodies' velocities, each body's (linear, angular) part of J times its
// (v, w); written here, not taken from the code under test.
real rowVelocity(const ConstraintRow& r, const JointBody& A, const JointBody& B) {
  auto part = [](const real* J, Vec3 v, Vec3 w) {
    return J[0] * v.x + J[1] * v.y + J[2] * v.z + J[3] * w.x + J[4] * w.y + J[5] * w.z;
  };
  return part(r.Ja, A.v, A.w) + part(r.Jb, B.v, B.w);
}

}  // namespace

TEST_CASE("joint rows: Jacobians are the time derivatives of the constraint functions", "[world][joints]") {
  TestWorld w(false);
  btCollisionShape* box = w.own(new btBoxShape(btVector3(0.5, 0.5, 0.5)));
  btRigidBody* a = w.make(box, 1, btVector3(0, 0, 0), false);
  btRigidBody* b = w.make(box, 1, btVector3(1, 0, 0), false);
  const btQuaternion tilt(btVector3(1, 2, 3).normalized(), btScalar(0.4));
  std::vector<std::unique_ptr<btTypedConstraint>> cs;
  cs.emplace_back(new btPoint2PointConstraint(*a, *b, btVector3(0.5, 0.2, 0), btVector3(-0.5, 0.1, 0.3)));
  auto* hinge = new btHingeConstraint(*a, *b, frame(btVector3(0.5, 0, 0), tilt), frame(btVector3(-0.5, 0, 0.1)));
  hinge->setLimit(-1, 1);
  cs.emplace_back(hinge);
  auto* slider =
      new btSliderConstraint(*a, *b, frame(btVector3(0.3, 0.1, 0), tilt), frame(btVector3(-0.2, 0, 0)), true);
  slider->setLowerLinLimit(-0.5);
  slider->setUpperLinLimit(0.5);
  cs.emplace_back(slider);
  cs.emplace_back(new btFixedConstraint(*a, *b, frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0), tilt)));
  auto* d6 = new btGeneric6DofConstraint(*a, *b, frame(btVector3(0.5, 0, 0), tilt), frame(btVector3(-0.5, 0, 0)), true);
  d6->setLinearLowerLimit(btVector3(0, -0.2, 0));
  d6->setLinearUpperLimit(btVector3(0, 0.2, 0));
  d6->setAngularLowerLimit(btVector3(0, 0, 1));  // z free: a hinge about frame A's z
  d6->setAngularUpperLimit(btVector3(0, 0, -1));
  cs.emplace_back(d6);
  auto* d62 =
      new btGeneric6DofSpring2Constraint(*a, *b, frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0), tilt));
  d62->setLinearLowerLimit(btVector3(0, 0, 0));
  d62->setLinearUpperLimit(btVector3(0, 0, 0));
  d62->setAngularLowerLimit(btVector3(0, 0, 0));
  d62->setAngularUpperLimit(btVector3(0, 0, 0));
  cs.emplace_back(d62);

  std::mt19937 rng(7);
  JointSettings settings;
  settings.recovery_rel = real(1e9);
  settings.max_recovery_angular = real(1e9);
  settings.drift_feedforward = false;  // the bias must be exactly C / h here (J = dC/dt is tested)
  const real dt = real(0.01), d = real(1e-6);
  for (auto& c : cs) {
    const JointSpec j = jointSpecFromBullet(*c);
    INFO(j.kind);
    for (int trial = 0; trial < 20; ++trial) {
      const JointBody A = randomJointSide(rng);
      JointBody B = closeB(j, A, rng, real(0.05));
      B.v = randomVec(rng, 1);
      B.w = randomVec(rng, 1);
      std::vector<ConstraintRow> r0, r1;
      jointRows(j, A, B, dt, settings, r0);
      jointRows(j, advanced(A, d), advanced(B, d), dt, settings, r1);
      REQUIRE(r0.size() == r1.size());
      REQUIRE(!r0.empty());
      for (size_t k = 0; k < r0.size(); ++k) {
        if (std::isfinite(r0[k].hi)) continue;  // a motor row (bias = -target), not a position row
        const real fd = (r1[k].bias - r0[k].bias) * dt / d;
        const real jv = rowVelocity(r0[k], A, B);
        INFO("row " << k << " J v = " << jv << ", finite difference " << fd);
        // First order in the joint error (0.05): the rows are exact at C = 0 and accurate to O(C) near it.
        CHECK(std::fabs(fd - jv) < 0.06 * (1 + std::fabs(jv)));
      }
      // Where the joint holds exactly, every position row matches to rounding.
      JointBody B0 = closeB(j, A, rng, 0);
      B0.v = B.v;
      B0.w = B.w;
      r0.clear();
      r1.clear();
      jointRows(j, A, B0, dt, settings, r0);
      jointRows(j, advanced(A, d), advanced(B0, d), dt, settings, r1);
      for (size_t k = 0; k < r0.size(); ++k) {
        if (std::isfinite(r0[k].hi)) continue;                           // motor rows
        if (r0[k].lo == 0 && std::fabs(r0[k].bias) > real(1)) continue;  // an inactive limit far away
        const real fd = (r1[k].bias - r0[k].bias) * dt / d;
        const real jv = rowVelocity(r0[k], A, B0);
        INFO("exact pose, row " << k << " J v = " << jv << ", finite difference " << fd);
        CHECK(std::fabs(fd - jv) < 1e-4 * (1 + std::fabs(jv)));
      }
    }
  }
  delete a->getMotionState();
  delete b->getMotionState();
  delete a;
  delete b;
}

TEST_CASE("joint rows: the hinge angle follows Bullet's getHingeAngle", "[world][joints]") {
  TestWorld w(false);
  btCollisionShape* box = w.own(new btBoxShape(btVector3(0.5, 0.5, 0.5)));
  btRigidBody* a = w.make(box, 1, btVector3(0, 0, 0), false);
  btRigidBody* b = w.make(box, 1, btVector3(1, 0, 0), false);
  for (bool refA : {false, true}) {
    btHingeConstraint h(*a, *b, frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0)), refA);
    const JointSpec j = jointSpecFromBullet(h);
    for (double angle : {-2.5, -1.0, -0.2, 0.3, 1.2, 2.9}) {
      btTransform tb(btQuaternion(btVector3(0, 0, 1), btScalar(angle)), btVector3(1, 0, 0));
      JointBody A, B;
      B.q = Quat{real(tb.getRotation().w()), real(tb.getRotation().x()), real(tb.getRotation().y()),
                 real(tb.getRotation().z())};
      B.x = Vec3{1, 0, 0};
      const real theta = jointHingeAngle(j, A, B);
      const btScalar bullet = h.getHingeAngle(a->getCenterOfMassTransform(), tb);
      INFO("reference frame A " << refA << ", angle " << angle);
      CHECK(theta == Approx(angle).margin(1e-5));                             // theta: B relative to A, right-handed
      CHECK(double(bullet) == Approx((refA ? 1 : -1) * angle).margin(1e-5));  // Bullet's sign rule in joints.cpp
    }
  }
  delete a->getMotionState();
  delete b->getMotionState();
  delete a;
  delete b;
}

TEST_CASE("constraints we cannot represent are refused with their type named", "[world][joints]") {
  TestWorld w(true);
  btCollisionShape* box = w.own(new btBoxShape(btVector3(0.5, 0.5, 0.5)));
  btRigidBody* a = w.make(box, 1, btVector3(0, 2, 0));
  btRigidBody* b = w.make(box, 1, btVector3(1, 2, 0));
  auto refused = [&](btTypedConstraint* c, const std::string& needle) {
    std::unique_ptr<btTypedConstraint> owned(c);
    try {
      w.world->addConstraint(c);
      FAIL("accepted " << needle);
    } catch (const InputError& e) {
      INFO(e.what());
      CHECK(std::string(e.what()).find(needle) != std::string::npos);
    }
    CHECK(w.world->getNumConstraints() == 0);
  };
  // A constraint type of the app's own (Bullet steps any btTypedConstraint through getInfo1/getInfo2; we read the
  // known types' parameters, so another type is refused with its number named).
  struct AppConstraint : btTypedConstraint {
    explicit AppConstraint(btRigidBody& body) : btTypedConstraint(MAX_CONSTRAINT_TYPE, body) {}
    void getInfo1(btConstraintInfo1* info) override {
      info->m_numConstraintRows = 0;
      info->nub = 0;
    }
    void getInfo2(btConstraintInfo2*) override {}
    void setParam(int, btScalar, int) override {}
    btScalar getParam(int, int) const override { return 0; }
  };
  refused(new AppConstraint(*a),
          "unsupported Bullet constraint: constraint type " + std::to_string(MAX_CONSTRAINT_TYPE));
  // What used to be refused is accepted: gears, linear 6-DoF motors, Spring2 servos, slider angular ranges.
  std::vector<std::unique_ptr<btTypedConstraint>> accepted;
  accepted.emplace_back(new btGearConstraint(*a, *b, btVector3(0, 1, 0), btVector3(0, 1, 0), 2));
  auto* motor6 = new btGeneric6DofConstraint(*a, *b, frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0)), true);
  motor6->getTranslationalLimitMotor()->m_enableMotor[0] = true;
  accepted.emplace_back(motor6);
  auto* servo = new btGeneric6DofSpring2Constraint(*a, *b, frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0)));
  servo->setAngularLowerLimit(btVector3(-0.5, 0, 0));
  servo->setAngularUpperLimit(btVector3(0.5, 0, 0));
  servo->enableMotor(3, true);
  servo->setServo(3, true);
  accepted.emplace_back(servo);
  auto* slider = new btSliderConstraint(*a, *b, frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0)), true);
  slider->setLowerAngLimit(-1);
  slider->setUpperAngLimit(1);
  slider->setPoweredAngMotor(true);
  accepted.emplace_back(slider);
  for (auto& c : accepted) CHECK_NOTHROW(w.world->addConstraint(c.get()));
  for (auto& c : accepted) w.world->removeConstraint(c.get());
  // A dynamic body with a triangle mesh is refused too (Bullet cannot collide it either).
  btTriangleMesh mesh;
  mesh.addTriangle(btVector3(0, 0, 0), btVector3(1, 0, 0), btVector3(0, 0, 1));
  btBvhTriangleMeshShape tri(&mesh, true);
  btRigidBody* dyn = w.make(&tri, 0, btVector3(0, 0, 0), false);
  dyn->setMassProps(1, btVector3(1, 1, 1));
  dyn->setCollisionFlags(0);
  CHECK_THROWS_AS(w.world->addRigidBody(dyn), InputError);
  delete dyn->getMotionState();
  delete dyn;
}

TEST_CASE("drop-in world: free flight, forces, impulses, damping, per-body gravity as plain Bullet", "[world]") {
  // No contacts: Bullet and the DVI world both integrate by semi-implicit Euler, so they agree to float rounding.
  auto run = [](bool dvi) {
    TestWorld w(dvi);
    btCollisionShape* s = w.own(new btSphereShape(btScalar(0.1)));
    btRigidBody* f = w.make(s, 2, btVector3(0, 10, 0));  // central force each frame
    btRigidBody* g = w.make(s, 1, btVector3(2, 10, 0));  // own gravity
    btRigidBody* d = w.make(s, 1, btVector3(4, 10, 0));  // damping
    btRigidBody* k = w.make(s, 1, btVector3(6, 10, 0));  // impulse then torque
    g->setGravity(btVector3(0, -2, 0));
    d->setDamping(btScalar(0.3), btScalar(0.5));
    d->setLinearVelocity(btVector3(1, 0, 0));
    d->setAngularVelocity(btVector3(0, 3, 0));
    std::vector<btVector3> out;
    for (int i = 0; i < 60; ++i) {
      f->applyCentralForce(btVector3(4, 0, 0));
      if (i == 10) k->applyImpulse(btVector3(0, 0, 1), btVector3(0, 0.1, 0));
      if (i >= 20) k->applyTorque(btVector3(0.001, 0, 0));
      w.world->stepSimulation(btScalar(1) / 60, 10, btScalar(1) / 240);
    }
    for (btRigidBody* b : {f, g, d, k}) {
      out.push_back(b->getCenterOfMassPosition());
      out.push_back(b->getLinearVelocity());
      out.push_back(b->getAngularVelocity());
      btTransform t;
      b->getMotionState()->getWorldTransform(t);
      out.push_back(t.getOrigin());
    }
    return out;
  };
  const auto bullet = run(false), ours = run(true);
  REQUIRE(bullet.size() == ours.size());
  for (size_t i = 0; i < bullet.size(); ++i) {
    INFO("value " << i << ": Bullet (" << bullet[i].x() << ", " << bullet[i].y() << ", " << bullet[i].z() << "), ours ("
                  << ours[i].x() << ", " << ours[i].y() << ", " << ours[i].z() << ")");
    CHECK((bullet[i] - ours[i]).length() < 1e-4);
  }
  // And against the closed form: the body with its own gravity g = 2 fell h^2 g n (n + 1) / 2 after n sub-steps.
  const double h = 1.0 / 240, n = 240;
  CHECK(double(ours[4].y()) == Approx(10 - 2 * h * h * n * (n + 1) / 2).margin(1e-4));
}

TEST_CASE("drop-in world: kinematic body follows its motion state and pushes", "[world]") {
  TestWorld w(true);
  w.ground();
  btRigidBody* kin = w.make(w.own(new btBoxShape(btVector3(0.5, 0.5, 0.5))), 0, btVector3(0, 0.5, 0), false);
  kin->setCollisionFlags(kin->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
  w.world->addRigidBody(kin);  // kinematic before it is added, as Bullet wants
  w.bodies.push_back(kin);
  btRigidBody* ball = w.make(w.own(new btSphereShape(btScalar(0.2))), 1, btVector3(1.0, 0.2, 0));
  for (int i = 0; i < 60; ++i) {
    btTransform t(btQuaternion::getIdentity(), btVector3(btScalar(i + 1) / 60, 0.5, 0));  // 1 m/s along x
    kin->getMotionState()->setWorldTransform(t);
    w.world->stepSimulation(btScalar(1) / 60, 10, btScalar(1) / 240);
  }
  CHECK(kin->getCenterOfMassPosition().x() == Approx(1.0).margin(1e-6));
  // The ball was pushed ahead of the box's face (x = 1.5 at the end).
  CHECK(ball->getCenterOfMassPosition().x() > 1.5 + 0.2 - 0.01);
}

TEST_CASE("drop-in world: collision groups and masks", "[world]") {
  TestWorld w(true);
  btRigidBody* g = w.make(w.own(new btBoxShape(btVector3(20, 1, 20))), 0, btVector3(0, -1, 0));
  (void)g;
  btCollisionShape* s = w.own(new btSphereShape(btScalar(0.2)));
  btRigidBody* rests = w.make(s, 1, btVector3(0, 0.2, 0));
  btRigidBody* ghost = w.make(s, 1, btVector3(1, 0.2, 0), false);
  w.world->addRigidBody(ghost, 4, 4);  // group 4 only collides with group 4: not with the ground (static filter)
  w.bodies.push_back(ghost);
  w.run(0.5);
  CHECK(rests->getCenterOfMassPosition().y() == Approx(0.2).margin(1e-3));
  const double t = 0.5;
  CHECK(double(ghost->getCenterOfMassPosition().y()) == Approx(0.2 - 9.81 * t * t / 2).margin(0.02));
}

TEST_CASE("drop-in world: static triangle mesh is environment geometry", "[world][triangle]") {
  TestWorld w(true);
  btTriangleMesh mesh;
  for (int i = -2; i < 2; ++i)
    for (int k = -2; k < 2; ++k) {
      btVector3 a(btScalar(i), 0, btScalar(k)), b(btScalar(i + 1), 0, btScalar(k)),
          c(btScalar(i + 1), 0, btScalar(k + 1)), d(btScalar(i), 0, btScalar(k + 1));
      mesh.addTriangle(a, c, b);
      mesh.addTriangle(a, d, c);
    }
  btBvhTriangleMeshShape tri(&mesh, true);
  w.make(&tri, 0, btVector3(0, 0, 0));
  // A box across the triangles' shared edges, a sphere on an edge, a capsule lying on the mesh.
  btRigidBody* box = w.make(w.own(new btBoxShape(btVector3(0.3, 0.2, 0.3))), 1, btVector3(0.1, 0.25, 0.2));
  btRigidBody* ball = w.make(w.own(new btSphereShape(btScalar(0.2))), 1, btVector3(-1.0, 0.3, -0.5));
  btRigidBody* cyl = w.make(w.own(new btCylinderShape(btVector3(0.2, 0.3, 0.2))), 1, btVector3(1.2, 0.35, 1.1));
  w.run(1.5);
  CHECK(box->getCenterOfMassPosition().y() == Approx(0.2).margin(1e-3));
  CHECK(std::fabs(box->getOrientation().getAngle()) < 1e-3);  // rests flat, no rocking on triangle edges
  CHECK(ball->getCenterOfMassPosition().y() == Approx(0.2).margin(1e-3));
  CHECK(cyl->getCenterOfMassPosition().y() == Approx(0.3).margin(1e-3));
  CHECK(box->getLinearVelocity().length() < 1e-2);
  // Triangle records: one per triangle.
  const ShapeArrays& shapes = w.dvi().system().shapes();
  int triangles = 0;
  for (const Shape& s : shapes.shape) triangles += s.type == ShapeType::Triangle;
  CHECK(triangles == 32);
}

TEST_CASE("drop-in world: the demo scene agrees with Bullet on what is not chaotic", "[world][demo]") {
  auto run = [](bool dvi, double seconds, std::vector<btVector3>& stack, double& angle) {
    TestWorld w(dvi);
    drop_in::Scene scene;
    scene.build(*w.world, 0);  // no pile: the stack and the hinge only (the pile is chaotic)
    w.run(seconds);
    for (btRigidBody* b : scene.stack) stack.push_back(drop_in::Scene::position(b));
    angle = double(scene.hinge->getHingeAngle());
    const bool solved = !dvi || rowsSolved(w.dvi());
    scene.destroy(*w.world);
    return solved;
  };
  std::vector<btVector3> sb, so;
  double ab = 0, ao = 0;
  run(false, 1.5, sb, ab);
  const bool solved = run(true, 1.5, so, ao);
  for (size_t i = 0; i < sb.size(); ++i) {
    INFO("box " << i << ": Bullet y " << sb[i].y() << ", ours " << so[i].y());
    CHECK((sb[i] - so[i]).length() < 1e-3);
    CHECK(double(so[i].y()) == Approx(0.25 + 0.5 * double(i)).margin(1e-3));  // analytic resting height
  }
  INFO("hinge angle after 1.5 s: Bullet " << ab * 180 / M_PI << " deg, ours " << ao * 180 / M_PI << " deg");
  REQUIRE(solved);  // the hinge's rows were solved (System::rowImpulses filled)
  CHECK(std::fabs(ao - ab) * 180 / M_PI < 0.1);
  CHECK(ao == Approx(1.5 * double(drop_in::kHingeSpeed)).margin(0.1 * M_PI / 180 + 1.0 / 240));
}

TEST_CASE("drop-in world: joint violations stay below 1e-4 of the body size over 10 s", "[world][joints]") {
  TestWorld w(true);
  btCollisionShape* box = w.own(new btBoxShape(btVector3(0.2, 0.2, 0.2)));
  btRigidBody& fixed = btTypedConstraint::getFixedBody();
  // A point-to-point pendulum, a hinge pendulum, a slider on a tilted rail, a fixed pair, a 6-DoF hinge.
  btRigidBody* p = w.make(box, 1, btVector3(0, 2, 0));
  w.joint(new btPoint2PointConstraint(*p, btVector3(0.5, 0.2, 0)));
  btRigidBody* h = w.make(box, 1, btVector3(3, 2, 0));
  w.joint(new btHingeConstraint(*h, btVector3(-0.6, 0, 0), btVector3(0, 0, 1)));
  btRigidBody* s = w.make(box, 1, btVector3(6, 2, 0));
  auto* sl =
      w.joint(new btSliderConstraint(*s, frame(btVector3(0, 0, 0), btQuaternion(btVector3(0, 0, 1), 0.5)), true));
  sl->setLowerLinLimit(-1);
  sl->setUpperLinLimit(1);
  btRigidBody* f1 = w.make(box, 1, btVector3(9, 2, 0));
  btRigidBody* f2 = w.make(box, 1, btVector3(9.5, 2, 0));
  w.joint(new btHingeConstraint(*f1, btVector3(0, 0.3, 0), btVector3(0, 0, 1)));
  w.joint(new btFixedConstraint(*f1, *f2, frame(btVector3(0.25, 0, 0)), frame(btVector3(-0.25, 0, 0))), true);
  btRigidBody* d = w.make(box, 1, btVector3(12, 2, 0));
  auto* d6 = w.joint(
      new btGeneric6DofConstraint(fixed, *d, frame(btVector3(12.5, 2.3, 0)), frame(btVector3(0.5, 0.3, 0)), true));
  d6->setAngularLowerLimit(btVector3(0, 0, 1));
  d6->setAngularUpperLimit(btVector3(0, 0, -1));
  h->setAngularVelocity(btVector3(0, 0, 2));
  p->setLinearVelocity(btVector3(0, 0, 1));
  real worst_lin = 0, worst_ang = 0;
  for (int i = 0; i < 600; ++i) {
    w.world->stepSimulation(btScalar(1) / 60, 10, btScalar(1) / 240);
    const JointViolation v = w.dvi().maxJointViolation();
    worst_lin = std::max(worst_lin, v.linear);
    worst_ang = std::max(worst_ang, v.angular);
  }
  REQUIRE(rowsSolved(w.dvi()));
  INFO("worst linear violation / size " << worst_lin << ", angular " << worst_ang << " rad");
  CHECK(worst_lin < 1e-4);
  CHECK(worst_ang < 1e-4);
  // The pendulums moved (the check is not on bodies at rest).
  CHECK(h->getCenterOfMassPosition().distance(btVector3(3, 2, 0)) > 0.1);
  CHECK(s->getCenterOfMassPosition().distance(btVector3(6, 2, 0)) > 0.1);
}

TEST_CASE("drop-in world: add and remove bodies inside a tick callback", "[world]") {
  TestWorld w(true);
  w.ground();
  struct State {
    TestWorld* w;
    btCollisionShape* s;
    std::vector<btRigidBody*> live;
    int ticks = 0, added = 0, removed = 0;
  } st{&w, w.own(new btSphereShape(btScalar(0.1))), {}};
  auto tick = [](btDynamicsWorld* world, btScalar) {
    auto* s = static_cast<State*>(world->getWorldUserInfo());
    ++s->ticks;
    if (s->ticks % 10 == 0) {  // add one sphere 2 m up
      btRigidBody* b = s->w->make(s->s, 1, btVector3(btScalar(s->added) * btScalar(0.3), 2, 0), false);
      world->addRigidBody(b);
      s->live.push_back(b);
      ++s->added;
    }
    if (s->ticks % 25 == 0 && !s->live.empty()) {  // remove the oldest
      btRigidBody* b = s->live.front();
      s->live.erase(s->live.begin());
      world->removeRigidBody(b);
      delete b->getMotionState();
      delete b;
      ++s->removed;
    }
  };
  w.world->setInternalTickCallback(tick, &st);
  w.run(1.0);
  CHECK(st.ticks == 240);
  CHECK(st.added == 24);
  CHECK(st.removed == 9);
  CHECK(w.world->getNumCollisionObjects() == 1 + 24 - 9);
  // The newest sphere (added at tick 240, not stepped yet) is not in the System until the next sub-step; every
  // other live sphere is, and fell as a free body since it was added (closed form of semi-implicit Euler).
  for (size_t i = 0; i + 1 < st.live.size(); ++i) {
    btRigidBody* b = st.live[i];
    CHECK(w.dvi().bodyIndex(b) >= 0);
  }
  btRigidBody* last = st.live[st.live.size() - 2];  // added at tick 230: 10 sub-steps of free fall
  const double h = 1.0 / 240, n = 10;
  CHECK(double(last->getCenterOfMassPosition().y()) == Approx(2 - 9.81 * h * h * n * (n + 1) / 2).margin(1e-5));
  w.world->setInternalTickCallback(nullptr);
  w.run(1.0);  // they land and rest on the ground
  for (btRigidBody* b : st.live)
    if (w.dvi().bodyIndex(b) >= 0 && b->getCenterOfMassPosition().y() < 0.5)
      CHECK(b->getCenterOfMassPosition().y() == Approx(0.1).margin(1e-3));
  for (btRigidBody* b : st.live) {
    w.world->removeRigidBody(b);
    delete b->getMotionState();
    delete b;
  }
}

TEST_CASE("drop-in world: rayTest and contactTest return the same hits as plain Bullet", "[world][queries]") {
  struct Hits {
    std::vector<int> ray_body;
    std::vector<btVector3> ray_point;
    std::vector<std::set<int>> contact_partners;
    size_t manifold_pairs = 0;
  };
  auto run = [](bool dvi) {
    TestWorld w(dvi);
    w.ground();
    btCollisionShape* box = w.own(new btBoxShape(btVector3(0.25, 0.25, 0.25)));
    for (int i = 0; i < 3; ++i) w.make(box, 1, btVector3(0, btScalar(0.25 + 0.5 * i), 0));  // a stack
    w.make(w.own(new btSphereShape(btScalar(0.3))), 1, btVector3(2, 0.3, 0));
    w.make(w.own(new btCylinderShape(btVector3(0.2, 0.4, 0.2))), 1, btVector3(-2, 0.4, 1));
    w.run(0.5);
    auto id = [&](const btCollisionObject* o) {
      for (size_t i = 0; i < w.bodies.size(); ++i)
        if (w.bodies[i] == o) return int(i);
      return -1;
    };
    Hits h;
    const btVector3 from[] = {{0, 5, 0}, {2, 5, 0.1}, {-2, 5, 1}, {5, 0.2, 0}, {0.1, 5, 0.1}, {7, 5, 7}};
    const btVector3 to[] = {{0, -5, 0}, {2, -5, 0.1}, {-2, -5, 1}, {-5, 0.2, 0}, {0.1, -5, 0.1}, {7, 4, 7}};
    for (int r = 0; r < 6; ++r) {
      btCollisionWorld::ClosestRayResultCallback cb(from[r], to[r]);
      w.world->rayTest(from[r], to[r], cb);
      h.ray_body.push_back(cb.hasHit() ? id(cb.m_collisionObject) : -1);
      h.ray_point.push_back(cb.hasHit() ? cb.m_hitPointWorld : btVector3(0, 0, 0));
    }
    struct Partners : btCollisionWorld::ContactResultCallback {
      std::set<const btCollisionObject*> set;
      btScalar addSingleResult(btManifoldPoint&, const btCollisionObjectWrapper* a, int, int,
                               const btCollisionObjectWrapper* b, int, int) override {
        set.insert(a->getCollisionObject());
        set.insert(b->getCollisionObject());
        return 0;
      }
    };
    for (size_t i = 1; i < w.bodies.size(); ++i) {
      Partners p;
      w.world->contactTest(w.bodies[i], p);
      std::set<int> ids;
      for (const btCollisionObject* o : p.set)
        if (o != w.bodies[i]) ids.insert(id(o));
      h.contact_partners.push_back(ids);
    }
    return h;
  };
  const Hits b = run(false), o = run(true);
  for (size_t r = 0; r < b.ray_body.size(); ++r) {
    INFO("ray " << r << ": Bullet hit body " << b.ray_body[r] << " at y " << b.ray_point[r].y() << ", ours body "
                << o.ray_body[r] << " at y " << o.ray_point[r].y());
    CHECK(b.ray_body[r] == o.ray_body[r]);
    CHECK((b.ray_point[r] - o.ray_point[r]).length() < 2e-3);
  }
  CHECK(b.ray_body[5] == -1);
  REQUIRE(b.contact_partners.size() == o.contact_partners.size());
  for (size_t i = 0; i < b.contact_partners.size(); ++i) {
    INFO("body " << i + 1);
    CHECK(b.contact_partners[i] == o.contact_partners[i]);
    CHECK(!o.contact_partners[i].empty());
  }
}

TEST_CASE("drop-in world: contacts readable through our list and Bullet's manifolds", "[world]") {
  TestWorld w(true);
  w.ground();
  btRigidBody* b = w.make(w.own(new btBoxShape(btVector3(0.25, 0.25, 0.25))), 2, btVector3(0, 0.25, 0));
  w.run(0.5);
  // Four corners on the ground; their normal impulses carry the weight: sum = m g h.
  double sum = 0;
  int n = 0;
  for (const WorldContact& c : w.dvi().contacts()) {
    if (c.a != b && c.b != b) continue;
    ++n;
    sum += double(c.normal_impulse);
  }
  CHECK(n == 4);
  CHECK(sum == Approx(2 * 9.81 / 240).epsilon(1e-2));
  int points = 0;
  for (int i = 0; i < w.dispatcher.getNumManifolds(); ++i) {
    const btPersistentManifold* m = w.dispatcher.getManifoldByIndexInternal(i);
    points += m->getNumContacts();
    // Each manifold point is one of contacts()'s (the list is made on demand from the same System contacts).
    for (int k = 0; k < m->getNumContacts(); ++k) {
      const btManifoldPoint& p = m->getContactPoint(k);
      int same = 0;
      for (const WorldContact& c : w.dvi().contacts())
        same +=
            (c.point_a - p.getPositionWorldOnA()).length() < 1e-6 && (c.normal + p.m_normalWorldOnB).length() < 1e-6;
      CHECK(same == 1);
    }
  }
  CHECK(points == 4);
  // A removal drops the last sub-step's contacts (none until the next sub-step), then they come back.
  w.world->removeRigidBody(b);
  CHECK(w.dvi().contacts().empty());
  w.world->addRigidBody(b);
  w.world->stepSimulation(btScalar(1) / 240, 0);
  CHECK(w.dvi().contacts().size() == 4);
}

TEST_CASE("a .bullet scene with each shape and joint type round-trips through the importer", "[world][import]") {
  // Written by Bullet's serializer from a plain world, read by btBulletWorldImporter into our world.
  TestWorld src(false);
  src.make(src.own(new btStaticPlaneShape(btVector3(0, 1, 0), 0)), 0, btVector3(0, 0, 0));
  btTriangleMesh* mesh = new btTriangleMesh();
  mesh->addTriangle(btVector3(-5, 0, -5), btVector3(5, 0, -5), btVector3(0, 0, 5));
  src.make(src.own(new btBvhTriangleMeshShape(mesh, true)), 0, btVector3(10, 0, 0));
  std::vector<btRigidBody*> dyn;
  dyn.push_back(src.make(src.own(new btSphereShape(0.3)), 1, btVector3(0, 1, 0)));
  dyn.push_back(src.make(src.own(new btBoxShape(btVector3(0.3, 0.2, 0.1))), 1, btVector3(1, 1, 0)));
  dyn.push_back(src.make(src.own(new btCylinderShapeZ(btVector3(0.2, 0.2, 0.3))), 1, btVector3(2, 1, 0)));
  dyn.push_back(src.make(src.own(new btCapsuleShapeX(0.1, 0.4)), 1, btVector3(3, 1, 0)));
  dyn.push_back(src.make(src.own(new btConeShape(0.2, 0.5)), 1, btVector3(4, 1, 0)));
  const btScalar pts[] = {0, 0, 0, 0.4f, 0, 0, 0, 0.4f, 0, 0, 0, 0.4f, 0.3f, 0.3f, 0.3f};
  // Packed points: three scalars each (the constructor's default stride is a btVector3's, 4 scalars).
  dyn.push_back(src.make(src.own(new btConvexHullShape(pts, 5, 3 * sizeof(btScalar))), 1, btVector3(5, 1, 0)));
  const btVector3 centers[] = {{0, 0, 0}, {0, 0.3f, 0}};
  const btScalar radii[] = {0.2f, 0.15f};
  dyn.push_back(src.make(src.own(new btMultiSphereShape(centers, radii, 2)), 1, btVector3(6, 1, 0)));
  auto* compound = new btCompoundShape();
  compound->addChildShape(frame(btVector3(0.2, 0, 0)), src.own(new btBoxShape(btVector3(0.1, 0.1, 0.1))));
  compound->addChildShape(frame(btVector3(-0.2, 0, 0)), src.own(new btSphereShape(0.1)));
  dyn.push_back(src.make(src.own(compound), 1, btVector3(7, 1, 0)));
  src.joint(new btPoint2PointConstraint(*dyn[0], *dyn[1], btVector3(0.5, 0, 0), btVector3(-0.5, 0, 0)));
  auto* hinge =
      src.joint(new btHingeConstraint(*dyn[1], *dyn[2], frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0))));
  hinge->enableAngularMotor(true, 2, 5);
  hinge->setLimit(-1, 1);
  src.joint(new btSliderConstraint(*dyn[2], *dyn[3], frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0)), true));
  src.joint(new btFixedConstraint(*dyn[3], *dyn[4], frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0))));
  src.joint(
      new btGeneric6DofConstraint(*dyn[4], *dyn[5], frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0)), true));
  auto* spring = src.joint(new btGeneric6DofSpringConstraint(*dyn[5], *dyn[6], frame(btVector3(0.5, 0, 0)),
                                                             frame(btVector3(-0.5, 0, 0)), true));
  spring->setLinearLowerLimit(btVector3(1, 0, 0));
  spring->setLinearUpperLimit(btVector3(-1, 0, 0));
  spring->enableSpring(0, true);
  spring->setStiffness(0, 20);
  auto* spring2 = src.joint(
      new btGeneric6DofSpring2Constraint(*dyn[6], *dyn[7], frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0))));
  spring2->setLinearLowerLimit(btVector3(-0.2, 0, 0));
  spring2->setLinearUpperLimit(btVector3(0.2, 0, 0));
  spring2->setAngularLowerLimit(btVector3(-0.3, 0, 1));  // x limited, y locked, z free: Euler rows
  spring2->setAngularUpperLimit(btVector3(0.4, 0, -1));
  auto* cone =
      src.joint(new btConeTwistConstraint(*dyn[7], *dyn[0], frame(btVector3(0.5, 0, 0)), frame(btVector3(-0.5, 0, 0))));
  cone->setLimit(btScalar(0.5), btScalar(0.8), btScalar(0.3));
  btDefaultSerializer ser;
  src.world->serialize(&ser);

  TestWorld dst(true);
  btBulletWorldImporter importer(dst.world.get());
  REQUIRE(importer.loadFileFromMemory(reinterpret_cast<char*>(const_cast<unsigned char*>(ser.getBufferPointer())),
                                      ser.getCurrentBufferSize()));
  REQUIRE(dst.world->getNumCollisionObjects() == src.world->getNumCollisionObjects());
  REQUIRE(dst.world->getNumConstraints() == src.world->getNumConstraints());
  // Shapes: every body becomes the same records as the original.
  DviDynamicsWorld& dw = dst.dvi();
  dst.world->stepSimulation(btScalar(1) / 240, 0);  // bring the bodies into the System
  for (int i = 0; i < dst.world->getNumCollisionObjects(); ++i) {
    const btRigidBody* imported = btRigidBody::upcast(dst.world->getCollisionObjectArray()[i]);
    const btRigidBody* original = btRigidBody::upcast(src.world->getCollisionObjectArray()[i]);
    REQUIRE(imported);
    std::vector<ShapeDesc> a, b;
    appendShapesWithTriangles(*original->getCollisionShape(), Pose{{0, 0, 0}, {1, 0, 0, 0}}, a);
    appendShapesWithTriangles(*imported->getCollisionShape(), Pose{{0, 0, 0}, {1, 0, 0, 0}}, b);
    INFO("body " << i << " (" << original->getCollisionShape()->getName() << ")");
    REQUIRE(a.size() == b.size());
    for (size_t k = 0; k < a.size(); ++k) {
      CHECK(a[k].shape.type == b[k].shape.type);
      CHECK(length(a[k].shape.dims - b[k].shape.dims) < 1e-6);
      CHECK(length(a[k].shape.local.p - b[k].shape.local.p) < 1e-6);
      CHECK(a[k].hull.size() == b[k].hull.size());
    }
    CHECK(dw.bodyIndex(imported) >= 0);
  }
  // Joints: the same rows (modes, frames, motor, limits, springs).
  for (int i = 0; i < dst.world->getNumConstraints(); ++i) {
    const JointSpec a = jointSpecFromBullet(*src.world->getConstraint(i));
    const JointSpec b = jointSpecFromBullet(*dst.world->getConstraint(i));
    INFO("constraint " << i << ": " << a.kind << " -> " << b.kind);
    CHECK(int(a.ang) == int(b.ang));
    for (int k = 0; k < 3; ++k) {
      CHECK(int(a.lin[k]) == int(b.lin[k]));
      CHECK(a.lin_lo[k] == Approx(b.lin_lo[k]));
    }
    CHECK(length(a.frame_a.p - b.frame_a.p) < 1e-6);
    CHECK(length(a.frame_b.p - b.frame_b.p) < 1e-6);
    CHECK(a.hinge_motor == b.hinge_motor);
    CHECK(a.hinge_motor_velocity == Approx(b.hinge_motor_velocity));
    CHECK(a.hinge_limit == b.hinge_limit);
    CHECK(a.springs.size() == b.springs.size());
    CHECK(a.cone_swing_limit == b.cone_swing_limit);
    CHECK(a.cone_swing1 == Approx(b.cone_swing1));
    CHECK(a.cone_swing2 == Approx(b.cone_swing2));
    CHECK(a.cone_twist == Approx(b.cone_twist));
    for (int k = 0; k < 3; ++k) {
      CHECK(int(a.euler[k].mode) == int(b.euler[k].mode));
      CHECK(a.euler[k].lo == Approx(b.euler[k].lo));
      CHECK(a.euler[k].hi == Approx(b.euler[k].hi));
    }
  }
  importer.deleteAllData();
  delete mesh;
}

TEST_CASE("drop-in world on the GPU backend: the demo's stack rests as on Bullet", "[world][gpu]") {
  if (!haveDevice()) return;
  TestWorld w(true, WorldBackend::Gpu);
  drop_in::Scene scene;
  scene.build(*w.world, 0);
  // Under compute-sanitizer (DVISIM_SANITIZER_RUN, scripts/device/run_device.sh) one frame (4 substeps, every
  // kernel of a step with joints and MPR pairs): the stack starts at rest, so the check holds at any time, and
  // racecheck did not finish 0.25 s (60 substeps) within 150 s.
  w.run(std::getenv("DVISIM_SANITIZER_RUN") ? 1.0 / 60 : 1.5);
  CHECK(w.dvi().backendName() == "gpu");
  for (size_t i = 0; i < scene.stack.size(); ++i)
    CHECK(double(drop_in::Scene::position(scene.stack[i]).y()) == Approx(0.25 + 0.5 * double(i)).margin(1e-3));
  scene.destroy(*w.world);
}

// 60 stacks of 3 boxes dropped onto the ground with small offsets, and 20 boxes thrown in a lane beside them: contacts begin
// and end, manifolds come and go, and the stacks fall asleep (Bullet's 2 s) while the thrown boxes still move.
// Returns the world's observable state after 3 s: every body's pose, velocity and activation state, and each touching
// pair's manifold point count, in the dispatcher's order.
std::vector<double> sleepingStacksState(TestWorld& w) {
  w.ground();
  btCollisionShape* box = w.own(new btBoxShape(btVector3(btScalar(0.5), btScalar(0.5), btScalar(0.5))));
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.05, 0.05);
  std::vector<btRigidBody*> b;
  for (int k = 0; k < 6; ++k)
    for (int i = 0; i < 10; ++i)
      for (int j = 0; j < 3; ++j)
        b.push_back(w.make(
            box, 1, btVector3(btScalar(2.5 * i + u(rng)), btScalar(0.55 + 1.05 * j), btScalar(2.5 * k + u(rng)))));
  for (int i = 0; i < 20; ++i) {
    btRigidBody* r = w.make(box, 1, btVector3(btScalar(-3), btScalar(1 + 1.5 * (i % 4)), btScalar(-3 - 1.5 * (i / 4))));
    r->setLinearVelocity(btVector3(btScalar(6 + 0.2 * i), 0, 0));
    b.push_back(r);
  }
  for (btRigidBody* r : b) r->forceActivationState(ACTIVE_TAG);  // TestWorld::make disables deactivation
  w.run(3, btScalar(1) / 60);
  std::vector<double> out;
  for (btRigidBody* r : b) {
    const btTransform& t = r->getCenterOfMassTransform();
    for (int k = 0; k < 3; ++k) out.push_back(double(t.getOrigin()[k]));
    for (int k = 0; k < 4; ++k) out.push_back(double(t.getRotation()[k]));
    for (int k = 0; k < 3; ++k) out.push_back(double(r->getLinearVelocity()[k]));
    out.push_back(r->getActivationState());
  }
  btDispatcher* d = w.world->getDispatcher();
  for (int m = 0; m < d->getNumManifolds(); ++m) out.push_back(d->getManifoldByIndexInternal(m)->getNumContacts());
  return out;
}

TEST_CASE("drop-in world: its host loops in parallel give the serial loops' results bitwise", "[world]") {
  DviWorldConfig serial, parallel;
  serial.system.threads = parallel.system.threads = 1;  // the System alike; only the world's loops differ
  parallel.host_threads = 2;
  serial.effort = parallel.effort = SolverEffort::BulletIterations;
  serial.parallel_min = int64_t(1) << 40;
  parallel.parallel_min = 1;
  TestWorld ws(serial), wp(parallel);
  const std::vector<double> a = sleepingStacksState(ws), b = sleepingStacksState(wp);
  int asleep = 0;
  for (btRigidBody* r : ws.bodies) asleep += r->getActivationState() == ISLAND_SLEEPING;
  INFO("bodies asleep " << asleep << " of " << ws.bodies.size() << ", manifolds "
                        << ws.world->getDispatcher()->getNumManifolds());
  CHECK(asleep > 30);                         // the sleeping islands were built
  CHECK(asleep < int(ws.bodies.size()) - 1);  // and some stayed awake
  CHECK(ws.world->getDispatcher()->getNumManifolds() > 50);
  REQUIRE(a.size() == b.size());
  int differ = 0;
  for (size_t i = 0; i < a.size(); ++i) differ += !(a[i] == b[i]);
  CHECK(differ == 0);
}

// 200 boxes 1.5 m apart on the ground; between frames the app edits a few of them, as apps do: a velocity, a
// teleport, a body's gravity, a force every frame, a friction. Returns every box's final position.
std::vector<btVector3> appEditsScene(TestWorld& w) {
  w.ground();
  btCollisionShape* box = w.own(new btBoxShape(btVector3(btScalar(0.5), btScalar(0.5), btScalar(0.5))));
  std::vector<btRigidBody*> b;
  for (int k = 0; k < 10; ++k)
    for (int i = 0; i < 20; ++i)
      b.push_back(w.make(box, 1, btVector3(btScalar(-15 + 1.5 * i), btScalar(0.5), btScalar(-7 + 1.5 * k))));
  for (int f = 0; f < 90; ++f) {
    if (f == 5) b[0]->setLinearVelocity(btVector3(0, 0, -3));  // row k = 0 slides out of the grid (-z)
    if (f == 10) b[199]->setCenterOfMassTransform(frame(btVector3(0, 5, 15)));
    if (f == 15) b[50]->setGravity(btVector3(0, 2, 0));
    if (f >= 20) b[185]->applyCentralForce(btVector3(0, 0, 20));  // last row (k = 9) pushed out (+z)
    if (f == 25) {
      b[5]->setFriction(0);
      b[5]->setLinearVelocity(btVector3(0, 0, -2));
    }
    w.world->stepSimulation(btScalar(1) / 60, 10, btScalar(1) / 240);
  }
  std::vector<btVector3> p;
  for (btRigidBody* r : b) p.push_back(r->getCenterOfMassPosition());
  return p;
}

// The edits take effect (closed forms; mu = 0.8 x 0.5 = 0.4 on the ground): the sliding box (3 m/s) stops
// 3^2 / (2 mu g) = 1.15 m out; the teleported one comes to rest at (0, 0.5, 15); gravity +2 lifts its box 2 t^2 / 2
// in the 1.25 s left; 20 N less 3.92 N of friction pushes its 1 kg box (the force acts in every sub-step of a frame,
// as in Bullet) 16.08 t^2 / 2 in 7/6 s; the frictionless one slides 2 m/s for 65 frames.
void checkAppEdits(const std::vector<btVector3>& p) {
  CHECK(double(p[0].z()) == Approx(-7 - 9 / (2 * 0.4 * 9.81)).margin(0.05));
  CHECK(double((p[199] - btVector3(0, btScalar(0.5), 15)).length()) < 0.02);
  CHECK(double(p[50].y()) == Approx(0.5 + 1.25 * 1.25).margin(0.02));
  CHECK(double(p[185].z()) == Approx(6.5 + 0.5 * 16.08 * (7.0 / 6) * (7.0 / 6)).margin(0.1));
  CHECK(double(p[5].z()) == Approx(-7 - 2 * 65.0 / 60).margin(0.02));
}

TEST_CASE("drop-in world: the app's edits between steps take effect", "[world]") {
  TestWorld w(true);
  checkAppEdits(appEditsScene(w));
}

TEST_CASE("drop-in world on the GPU backend: the app's edits between steps reach the device as on the CPU",
          "[world][gpu]") {
  if (!haveDevice()) return;
  TestWorld cpu(true, WorldBackend::Cpu), gpu(true, WorldBackend::Gpu);
  const std::vector<btVector3> pc = appEditsScene(cpu), pg = appEditsScene(gpu);
  CHECK(gpu.dvi().backendName() == "gpu");
  checkAppEdits(pg);
  double worst = 0;
  for (size_t i = 0; i < pc.size(); ++i) worst = std::max(worst, double((pc[i] - pg[i]).length()));
  INFO("largest GPU - CPU position difference " << worst << " m");
  CHECK(worst < 2e-3);
}

TEST_CASE(
    "drop-in world: the GPU backend comes from the app, Gpu without it is refused, Auto without it runs on the CPU",
    "[world]") {
  btDefaultCollisionConfiguration config;
  btCollisionDispatcher dispatcher(&config);
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  DviWorldConfig c;
  c.backend = WorldBackend::Gpu;
  CHECK_THROWS_AS(DviDynamicsWorld(&dispatcher, &broadphase, &solver, &config, c), InputError);
  c.backend = WorldBackend::Auto;
  DviDynamicsWorld world(&dispatcher, &broadphase, &solver, &config, c);
  CHECK(world.backendName() == "cpu");
}

TEST_CASE("Drop-in: a refused GPU backend names the API, not a command-line flag", "[bullet]") {
  if (dvi::gpuAvailable()) {
    WARN("skipped: a GPU is available, so makeGpuSystem does not refuse");
    return;
  }
  try {
    (void)dvi::makeGpuSystem(dvi::SystemConfig{});
    FAIL("makeGpuSystem without a GPU did not throw");
  } catch (const dvi::InputError& e) {
    const std::string m = e.what();
    INFO(m);
    CHECK(m.rfind("GPU backend: ", 0) == 0);
    CHECK(m.find("--backend") == std::string::npos);
  }
}
