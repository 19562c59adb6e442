// Bullet constraints read into JointSpecs, and the drop-in world's joints (bullet_joints.h).
#include "chrono_like/bullet/bullet_joints.h"
#include "chrono_like/bullet/bullet_convert.h"

#include <btBulletDynamicsCommon.h>
#include <BulletDynamics/ConstraintSolver/btFixedConstraint.h>
#include <BulletDynamics/ConstraintSolver/btGeneric6DofSpring2Constraint.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "chrono_like/base/errors.h"

namespace dvi {

namespace {

std::string axisName(int i) { return i < 3 ? std::string(1, "xyz"[i]) : std::string("rotation ") + "xyz"[i - 3]; }

// Six degrees of freedom of a 6-DoF constraint (Bullet's order: linear x y z, angular x y z).
struct Dof6 {
  real lo[6], hi[6];
  bool motor[6] = {false, false, false, false, false, false};
  bool servo[6] = {false, false, false, false, false, false};
  real motor_velocity[6] = {0, 0, 0, 0, 0, 0}, motor_force[6] = {0, 0, 0, 0, 0, 0};
  bool spring[6] = {false, false, false, false, false, false};
  real k[6] = {0, 0, 0, 0, 0, 0}, c[6] = {0, 0, 0, 0, 0, 0}, eq[6] = {0, 0, 0, 0, 0, 0};
  int order[3] = {0, 1, 2};  // rotate order of the angles (btGeneric6DofSpring2Constraint's RotateOrder)
};

JointSpec::Axis axisMode(real lo, real hi) {
  return lo == hi ? JointSpec::Axis::Locked : (lo > hi ? JointSpec::Axis::Free : JointSpec::Axis::Limited);
}

// The angular part of a 6-DoF: orientation locked at zero, a hinge (two axes locked at zero, the third free or
// limited, with its motor and spring), all free, or else Bullet's three Euler angles each locked, limited or free.
void angularFromDof6(const Dof6& d, JointSpec& j) {
  int locked_zero = 0, other = -1, active = 0;
  for (int i = 0; i < 3; ++i) {
    const JointSpec::Axis m = axisMode(d.lo[3 + i], d.hi[3 + i]);
    const bool lz = m == JointSpec::Axis::Locked && d.lo[3 + i] == 0;
    locked_zero += lz;
    if (!lz) other = i;
    active += m != JointSpec::Axis::Free || ((d.motor[3 + i] || d.spring[3 + i]) && m != JointSpec::Axis::Locked);
  }
  if (locked_zero == 3) {
    j.ang = JointSpec::Angular::Locked;
  } else if (locked_zero == 2 && axisMode(d.lo[3 + other], d.hi[3 + other]) != JointSpec::Axis::Locked) {
    // The hinge angle theta (B relative to A) is minus Bullet's angle (A relative to B) when the other two are 0.
    j.ang = JointSpec::Angular::Hinge;
    j.hinge_axis = other;
    const int i = 3 + other;
    if (axisMode(d.lo[i], d.hi[i]) == JointSpec::Axis::Limited) {
      j.hinge_limit = true;
      j.hinge_lo = -d.hi[i];
      j.hinge_hi = -d.lo[i];
    }
    if (d.motor[i] && !d.spring[i]) {
      j.hinge_motor = true;
      j.hinge_motor_velocity = -d.motor_velocity[i];
      j.hinge_motor_max_force = d.motor_force[i];
    }
    if (d.spring[i]) j.springs.push_back({i, d.k[i], d.c[i], -d.eq[i]});
  } else if (active == 0) {
    j.ang = JointSpec::Angular::Free;
  } else {
    j.ang = JointSpec::Angular::Euler;
    for (int m = 0; m < 3; ++m) {
      const int i = 3 + m;
      JointSpec::EulerAxis& x = j.euler[m];
      j.euler_order[m] = d.order[m];
      x.mode = axisMode(d.lo[i], d.hi[i]);
      x.lo = d.lo[i];
      x.hi = d.hi[i];
      if (x.mode == JointSpec::Axis::Locked) continue;
      x.motor = d.motor[i] && !d.spring[i];
      x.motor_velocity = d.motor_velocity[i];
      x.motor_max_force = d.motor_force[i];
      if (d.spring[i]) j.springs.push_back({i, d.k[i], d.c[i], d.eq[i]});
    }
  }
}

void fromDof6(const Dof6& d, const char* kind, JointSpec& j) {
  auto refuse = [&](const std::string& what) {
    throw InputError(std::string(kind) + ": " + what + " is not supported");
  };
  for (int i = 0; i < 3; ++i) {
    j.lin[i] = axisMode(d.lo[i], d.hi[i]);
    j.lin_lo[i] = d.lo[i];
    j.lin_hi[i] = d.hi[i];
  }
  for (int i = 0; i < 6; ++i) {
    if (d.servo[i]) refuse("a servo motor on " + axisName(i));
    if (i < 3 && d.motor[i] && !d.spring[i]) refuse("a linear motor on " + axisName(i));
  }
  for (int i = 0; i < 3; ++i)
    if (d.spring[i] && j.lin[i] != JointSpec::Axis::Locked) j.springs.push_back({i, d.k[i], d.c[i], d.eq[i]});
  angularFromDof6(d, j);
}

}  // namespace

std::string constraintTypeName(int type) {
  switch (type) {
    case POINT2POINT_CONSTRAINT_TYPE: return "point-to-point (btPoint2PointConstraint)";
    case HINGE_CONSTRAINT_TYPE: return "hinge (btHingeConstraint)";
    case CONETWIST_CONSTRAINT_TYPE: return "cone-twist (btConeTwistConstraint)";
    case D6_CONSTRAINT_TYPE: return "generic 6-DoF (btGeneric6DofConstraint)";
    case SLIDER_CONSTRAINT_TYPE: return "slider (btSliderConstraint)";
    case CONTACT_CONSTRAINT_TYPE: return "contact (btContactConstraint)";
    case D6_SPRING_CONSTRAINT_TYPE: return "generic 6-DoF spring (btGeneric6DofSpringConstraint)";
    case GEAR_CONSTRAINT_TYPE: return "gear (btGearConstraint)";
    case FIXED_CONSTRAINT_TYPE: return "fixed (btFixedConstraint)";
    case D6_SPRING_2_CONSTRAINT_TYPE: return "generic 6-DoF spring 2 (btGeneric6DofSpring2Constraint)";
    default: return "constraint type " + std::to_string(type);
  }
}

namespace {

// The joint specification of each Bullet constraint type (j holds the two bodies already).
void hingeSpec(btHingeConstraint& h, JointSpec& j) {
  j.kind = "hinge";
  j.frame_a = fromBt(h.getAFrame());
  j.frame_b = fromBt(h.getBFrame());
  for (auto& a : j.lin) a = JointSpec::Axis::Locked;
  j.ang = JointSpec::Angular::Hinge;
  j.hinge_axis = 2;
  // Bullet's hinge angle is s * theta with s = -referenceSign (referenceSign = -1 with reference frame A).
  const real s = h.getUseReferenceFrameA() ? real(1) : real(-1);
  if (h.hasLimit()) {
    j.hinge_limit = true;
    const real lo = s * real(h.getLowerLimit()), hi = s * real(h.getUpperLimit());
    j.hinge_lo = std::min(lo, hi);
    j.hinge_hi = std::max(lo, hi);
  }
  if (h.getEnableAngularMotor()) {
    j.hinge_motor = true;
    j.hinge_motor_velocity = s * real(h.getMotorTargetVelocity());
    j.hinge_motor_max_impulse = real(h.getMaxMotorImpulse());
  }
}

void sliderSpec(btSliderConstraint& s, JointSpec& j) {
  j.kind = "slider";
  j.frame_a = fromBt(s.getFrameOffsetA());
  j.frame_b = fromBt(s.getFrameOffsetB());
  const real lo = s.getLowerLinLimit(), hi = s.getUpperLinLimit();
  j.lin[0] = lo == hi ? JointSpec::Axis::Locked : (lo > hi ? JointSpec::Axis::Free : JointSpec::Axis::Limited);
  j.lin_lo[0] = lo;
  j.lin_hi[0] = hi;
  j.lin[1] = j.lin[2] = JointSpec::Axis::Locked;
  const real alo = s.getLowerAngLimit(), ahi = s.getUpperAngLimit();
  if (alo == ahi && alo == 0) {
    j.ang = JointSpec::Angular::Locked;
  } else if (alo > ahi) {
    j.ang = JointSpec::Angular::Hinge;
    j.hinge_axis = 0;
  } else {
    throw InputError("slider: an angular limit range or a non-zero locked angle is not supported");
  }
  if (s.getPoweredAngMotor()) throw InputError("slider: an angular motor is not supported");
  if (s.getPoweredLinMotor()) {
    j.lin_motor = true;
    j.lin_motor_velocity = s.getTargetLinMotorVelocity();
    j.lin_motor_max_force = s.getMaxLinMotorForce();
  }
}

// btConeTwistConstraint: the point-to-point part (unless angular only), the elliptic swing cone and the twist limit.
// Bullet enforces its limits at span x softness (the correction of calcAngleInfo2 is taken from the "soft" limit);
// a swing span below Bullet's fix threshold locks that swing (Bullet turns the joint into a hinge or a fixed
// joint). Bullet's bias factor (Baumgarte), relaxation factor (a row scale) and damping (used only by its
// obsolete solver path) have no meaning for the DVI rows, which correct the whole error in each step.
void coneTwistSpec(btConeTwistConstraint& c, JointSpec& j) {
  j.kind = "cone-twist";
  j.frame_a = fromBt(c.getAFrame());
  j.frame_b = fromBt(c.getBFrame());
  if (!c.getAngularOnly())
    for (auto& a : j.lin) a = JointSpec::Axis::Locked;
  j.ang = JointSpec::Angular::ConeTwist;
  const real soft = real(c.getLimitSoftness()), fix = real(c.getFixThresh());
  const real s1 = real(c.getSwingSpan1()), s2 = real(c.getSwingSpan2()), tw = real(c.getTwistSpan());
  const real kPi = real(3.14159265358979323846);
  j.cone_lock1 = s1 < fix;
  j.cone_lock2 = s2 < fix;
  j.cone_swing1 = j.cone_lock1 ? s2 * soft : s1 * soft;  // one swing locked: the other alone is the limit
  j.cone_swing2 = j.cone_lock2 ? s1 * soft : s2 * soft;
  j.cone_swing_limit = !(j.cone_lock1 && j.cone_lock2) && std::min(j.cone_swing1, j.cone_swing2) < kPi;
  j.cone_twist_limit = tw >= 0 && tw * soft < kPi;
  j.cone_twist = tw * soft;
  if (c.isMotorEnabled()) {
    // getInfo2's swing row carries the motor: impulse in [0, max motor impulse] (no bound where it is < 0).
    // Bullet's "normalized" strength only acts in its obsolete solver path.
    j.cone_motor = true;
    j.cone_motor_target = normalized(fromBt(c.getMotorTarget()));
    const real m = real(c.getMaxMotorImpulse());
    j.cone_motor_max_impulse = m >= 0 ? m : std::numeric_limits<real>::infinity();
    j.cone_motor_bias = real(c.getBiasFactor());
  }
}

// btGeneric6DofConstraint, and its spring form.
void dof6Spec(btGeneric6DofConstraint& g, bool spring, JointSpec& j) {
  j.kind = spring ? "generic 6-DoF spring" : "generic 6-DoF";
  j.frame_a = fromBt(g.getFrameOffsetA());
  j.frame_b = fromBt(g.getFrameOffsetB());
  Dof6 d;
  btVector3 llo, lhi, alo, ahi;
  g.getLinearLowerLimit(llo);
  g.getLinearUpperLimit(lhi);
  g.getAngularLowerLimit(alo);
  g.getAngularUpperLimit(ahi);
  for (int i = 0; i < 3; ++i) {
    d.lo[i] = llo[i];
    d.hi[i] = lhi[i];
    d.lo[3 + i] = alo[i];
    d.hi[3 + i] = ahi[i];
    d.motor[i] = g.getTranslationalLimitMotor()->m_enableMotor[i];
    const btRotationalLimitMotor* r = g.getRotationalLimitMotor(i);
    d.motor[3 + i] = r->m_enableMotor;
    d.motor_velocity[3 + i] = r->m_targetVelocity;  // Bullet: d(getAngle)/dt
    d.motor_force[3 + i] = r->m_maxMotorForce;      // Bullet bounds the row's impulse by force / fps
  }
  if (spring) {
    auto& sp = static_cast<btGeneric6DofSpringConstraint&>(g);
    for (int i = 0; i < 6; ++i) {
      d.spring[i] = sp.isSpringEnabled(i);
      d.k[i] = sp.getStiffness(i);
      d.c[i] = 0;  // Bullet's damping here is a motor factor, not a physical coefficient (docs/DROP_IN.md)
      d.eq[i] = sp.getEquilibriumPoint(i);
    }
  }
  fromDof6(d, j.kind, j);
}

// btGeneric6DofSpring2Constraint, and btFixedConstraint (one of them with every axis locked).
void dof6Spring2Spec(btGeneric6DofSpring2Constraint& g, bool fixed, JointSpec& j) {
  j.kind = fixed ? "fixed" : "generic 6-DoF spring 2";
  j.frame_a = fromBt(g.getFrameOffsetA());
  j.frame_b = fromBt(g.getFrameOffsetB());
  Dof6 d;
  btTranslationalLimitMotor2* t = g.getTranslationalLimitMotor();
  for (int i = 0; i < 3; ++i) {
    btRotationalLimitMotor2* r = g.getRotationalLimitMotor(i);
    d.lo[i] = t->m_lowerLimit[i];
    d.hi[i] = t->m_upperLimit[i];
    d.motor[i] = t->m_enableMotor[i];
    d.spring[i] = t->m_enableSpring[i];
    d.k[i] = t->m_springStiffness[i];
    d.c[i] = t->m_springDamping[i];
    d.eq[i] = t->m_equilibriumPoint[i];
    d.lo[3 + i] = r->m_loLimit;
    d.hi[3 + i] = r->m_hiLimit;
    d.motor[3 + i] = r->m_enableMotor;
    d.servo[3 + i] = r->m_enableMotor && r->m_servoMotor;
    d.servo[i] = t->m_enableMotor[i] && t->m_servoMotor[i];
    d.motor_velocity[3 + i] = r->m_targetVelocity;
    d.motor_force[3 + i] = r->m_maxMotorForce;
    d.spring[3 + i] = r->m_enableSpring;
    d.k[3 + i] = r->m_springStiffness;
    d.c[3 + i] = r->m_springDamping;
    d.eq[3 + i] = r->m_equilibriumPoint;
  }
  static const int kOrders[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};  // RotateOrder
  const int o = int(g.getRotationOrder());
  for (int m = 0; m < 3; ++m) d.order[m] = kOrders[o >= 0 && o < 6 ? o : 0][m];
  fromDof6(d, j.kind, j);
}

}  // namespace

JointSpec jointSpecFromBullet(const btTypedConstraint& c) {
  JointSpec j;
  j.a = &c.getRigidBodyA();
  j.b = &c.getRigidBodyB();
  auto& mc = const_cast<btTypedConstraint&>(c);  // several Bullet getters are not const
  switch (c.getConstraintType()) {
    case POINT2POINT_CONSTRAINT_TYPE: {
      const auto& p = static_cast<const btPoint2PointConstraint&>(c);
      j.kind = "point-to-point";
      j.frame_a = Pose{fromBt(p.getPivotInA()), {1, 0, 0, 0}};
      j.frame_b = Pose{fromBt(p.getPivotInB()), {1, 0, 0, 0}};
      for (auto& a : j.lin) a = JointSpec::Axis::Locked;
      j.ang = JointSpec::Angular::Free;
      return j;
    }
    case HINGE_CONSTRAINT_TYPE: hingeSpec(static_cast<btHingeConstraint&>(mc), j); return j;
    case SLIDER_CONSTRAINT_TYPE: sliderSpec(static_cast<btSliderConstraint&>(mc), j); return j;
    case CONETWIST_CONSTRAINT_TYPE: coneTwistSpec(static_cast<btConeTwistConstraint&>(mc), j); return j;
    case D6_CONSTRAINT_TYPE:
    case D6_SPRING_CONSTRAINT_TYPE:
      dof6Spec(static_cast<btGeneric6DofConstraint&>(mc), c.getConstraintType() == D6_SPRING_CONSTRAINT_TYPE, j);
      return j;
    case FIXED_CONSTRAINT_TYPE:
    case D6_SPRING_2_CONSTRAINT_TYPE:
      dof6Spring2Spec(static_cast<btGeneric6DofSpring2Constraint&>(mc), c.getConstraintType() == FIXED_CONSTRAINT_TYPE,
                      j);
      return j;
    default:
      throw InputError(
          "unsupported Bullet constraint: " + constraintTypeName(c.getConstraintType()) +
          " (supported: point-to-point, hinge, cone-twist, slider, fixed, generic 6-DoF [spring, spring 2])");
  }
}

void BulletJoints::add(btTypedConstraint* c) {
  if (!c) throw InputError("null constraint");
  (void)jointSpecFromBullet(*c);  // throws for what cannot be represented
  if (std::find(joints_.begin(), joints_.end(), c) == joints_.end()) joints_.push_back(c);
}

void BulletJoints::remove(btTypedConstraint* c) {
  joints_.erase(std::remove(joints_.begin(), joints_.end(), c), joints_.end());
}

JointBody BulletJoints::side(const BodyArrays& bodies, const btRigidBody* body) const {
  JointBody s;
  auto it = index_->find(body);
  if (it != index_->end() && it->second >= 0 && size_t(it->second) < bodies.count()) {
    const size_t i = size_t(it->second);
    s.index = it->second;
    s.x = bodies.pos[i];
    s.q = bodies.rot[i];
    s.v = bodies.vel[i];
    s.w = bodies.omega[i];
    s.size = bodies.size[i];
  } else {  // Bullet's fixed body, or a body outside the system: the ground at its Bullet pose
    const Pose p = fromBt(body->getCenterOfMassTransform());
    s.x = p.p;
    s.q = p.q;
    s.size = real(1e30);
  }
  return s;
}

void BulletJoints::rows(const BodyArrays& bodies, const StepContext& step, std::vector<ConstraintRow>& out) {
  row_joint_.clear();
  for (size_t k = 0; k < joints_.size(); ++k) {
    btTypedConstraint* c = joints_[k];
    if (!c->isEnabled()) continue;
    const JointSpec j = jointSpecFromBullet(*c);
    const size_t before = out.size();
    jointRows(j, side(bodies, j.a), side(bodies, j.b), step.dt, settings_, out);
    row_joint_.resize(out.size(), int(k));
    (void)before;
  }
}

void BulletJoints::impulses(const real* lambda, size_t count) {
  const size_t n = std::min(count, row_joint_.size());
  std::vector<real> peak(joints_.size(), 0);
  for (size_t r = 0; r < n; ++r) {
    real& p = peak[size_t(row_joint_[r])];
    p = std::max(p, std::fabs(lambda[r]));
  }
  for (size_t k = 0; k < joints_.size(); ++k) {
    btTypedConstraint* c = joints_[k];
    if (!c->isEnabled()) continue;
    c->internalSetAppliedImpulse(btScalar(peak[k]));
    // Bullet's rule: a row impulse at or above the threshold breaks the constraint.
    if (peak[k] >= real(c->getBreakingImpulseThreshold())) c->setEnabled(false);
  }
}

void BulletJoints::springForces(const BodyArrays& bodies, Vec3* force, Vec3* torque) const {
  for (btTypedConstraint* c : joints_) {
    if (!c->isEnabled()) continue;
    const JointSpec j = jointSpecFromBullet(*c);
    if (j.springs.empty()) continue;
    jointSpringForces(j, side(bodies, j.a), side(bodies, j.b), force, torque);
  }
}

JointViolation BulletJoints::maxViolation(const BodyArrays& bodies) const {
  JointViolation m;
  for (btTypedConstraint* c : joints_) {
    if (!c->isEnabled()) continue;
    const JointSpec j = jointSpecFromBullet(*c);
    const JointBody A = side(bodies, j.a), B = side(bodies, j.b);
    const JointViolation v = jointViolation(j, A, B);
    m.linear = std::max(m.linear, v.linear / std::min(A.size, B.size));
    m.angular = std::max(m.angular, v.angular);
  }
  return m;
}

}  // namespace dvi
