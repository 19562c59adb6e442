// Bullet constraints read into JointSpecs, and the drop-in world's joints (bullet_joints.h).
#include "chrono_like/bullet/bullet_joints.h"
#include "chrono_like/bullet/bullet_convert.h"

#include <btBulletDynamicsCommon.h>
#include <BulletDynamics/ConstraintSolver/btFixedConstraint.h>
#include <BulletDynamics/ConstraintSolver/btGearConstraint.h>
#include <BulletDynamics/ConstraintSolver/btGeneric6DofSpring2Constraint.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "chrono_like/base/errors.h"

namespace dvi {

namespace {

// Six degrees of freedom of a 6-DoF constraint (Bullet's order: linear x y z, angular x y z).
struct Dof6 {
  real lo[6], hi[6];
  bool motor[6] = {false, false, false, false, false, false};
  bool servo[6] = {false, false, false, false, false, false};
  real motor_velocity[6] = {0, 0, 0, 0, 0, 0}, motor_force[6] = {0, 0, 0, 0, 0, 0};
  real servo_target[6] = {0, 0, 0, 0, 0, 0};
  real motor_erp[6] = {-1, -1, -1, -1, -1, -1};  // < 0: the world's ERP
  real stop_erp[6] = {-1, -1, -1, -1, -1, -1};
  real bounce[6] = {0, 0, 0, 0, 0, 0};
  bool spring[6] = {false, false, false, false, false, false};
  real k[6] = {0, 0, 0, 0, 0, 0}, c[6] = {0, 0, 0, 0, 0, 0}, eq[6] = {0, 0, 0, 0, 0, 0};
  bool k_limited[6] = {false, false, false, false, false, false},
       c_limited[6] = {false, false, false, false, false, false};
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
    j.hinge_bounce = d.bounce[i];
    j.hinge_stop_erp = d.stop_erp[i];
    if (d.motor[i] && !d.spring[i]) {
      j.hinge_motor = true;
      j.hinge_motor_velocity = -d.motor_velocity[i];
      j.hinge_motor_max_force = d.motor_force[i];
      j.hinge_servo = d.servo[i];
      j.hinge_servo_target = -d.servo_target[i];
      j.hinge_motor_erp = d.motor_erp[i];
    }
    if (d.spring[i]) j.springs.push_back({i, d.k[i], d.c[i], -d.eq[i], d.k_limited[i], d.c_limited[i]});
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
      x.stop_erp = d.stop_erp[i];
      if (x.mode == JointSpec::Axis::Locked) continue;
      x.bounce = d.bounce[i];
      x.motor = d.motor[i] && !d.spring[i];
      x.motor_velocity = d.motor_velocity[i];
      x.motor_max_force = d.motor_force[i];
      x.servo = d.servo[i];
      x.servo_target = d.servo_target[i];
      x.motor_erp = d.motor_erp[i];
      if (d.spring[i]) j.springs.push_back({i, d.k[i], d.c[i], d.eq[i], d.k_limited[i], d.c_limited[i]});
    }
  }
}

// A 6-DoF's linear axes (limits, motors, springs), then its angular part. A motor on an axis with a spring is not
// used (the spring's force and the motor's row would fight).
void fromDof6(const Dof6& d, const char* kind, JointSpec& j) {
  j.kind = kind;
  for (int i = 0; i < 3; ++i) {
    j.lin[i] = axisMode(d.lo[i], d.hi[i]);
    j.lin_lo[i] = d.lo[i];
    j.lin_hi[i] = d.hi[i];
    j.lin_stop_erp[i] = d.stop_erp[i];
    j.lin_bounce[i] = d.bounce[i];
    if (d.spring[i] && j.lin[i] != JointSpec::Axis::Locked)
      j.springs.push_back({i, d.k[i], d.c[i], d.eq[i], d.k_limited[i], d.c_limited[i]});
    JointSpec::LinearMotor& m = j.lin_motor[i];
    m.on = d.motor[i] && !d.spring[i];
    // Bullet's linear motor rows ask (vA - vB).axis = target: d s/dt = -target (s: B's offset along A's axis).
    m.velocity = -d.motor_velocity[i];
    m.max_force = d.motor_force[i];
    m.servo = d.servo[i];
    m.servo_target = d.servo_target[i];
    m.motor_erp = d.motor_erp[i];
  }
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
// Bullet's hinge limit (btHingeConstraint::getInfo2InternalUsingFrameOffset): active while lo <= hi (lo == hi locks
// the hinge, and the motor is then ineffective); past it the row corrects fps x ERP x bias factor of the error per
// step. Bullet's code also asks for relaxation x bias factor of the incoming speed back, but stock Bullet's hinges
// hardly bounce (a bar falling 0.6 rad onto its limit rises 0.01 rad with the default relaxation 1, where that
// restitution would give 0.06; tests/test_bullet_joints_stock.cpp): ours do not bounce.
void hingeLimit(btHingeConstraint& h, real s, JointSpec& j) {
  const real lo = s * real(h.getLowerLimit()), hi = s * real(h.getUpperLimit());
  if (!(h.getLowerLimit() <= h.getUpperLimit())) return;
  j.hinge_limit = true;
  j.hinge_lo = std::min(lo, hi);
  j.hinge_hi = std::max(lo, hi);
  const int flags = h.getFlags();
  const real global = (flags & BT_HINGE_FLAGS_ERP_NORM) ? real(h.getParam(BT_CONSTRAINT_ERP)) : real(-1);
  const real stop = (flags & BT_HINGE_FLAGS_ERP_STOP) ? real(h.getParam(BT_CONSTRAINT_STOP_ERP)) : global;
  const real bias = real(h.getLimitBiasFactor());
  j.hinge_stop_erp = stop;  // < 0: the world's
  j.hinge_limit_bias = bias;
}

void hingeSpec(btHingeConstraint& h, JointSpec& j) {
  j.kind = "hinge";
  j.frame_a = fromBt(h.getAFrame());
  j.frame_b = fromBt(h.getBFrame());
  for (auto& a : j.lin) a = JointSpec::Axis::Locked;
  j.ang = JointSpec::Angular::Hinge;
  j.hinge_axis = 2;
  if (h.getFlags() & BT_HINGE_FLAGS_ERP_NORM) j.erp = real(h.getParam(BT_CONSTRAINT_ERP));
  // Bullet's hinge angle is s * theta with s = -referenceSign (referenceSign = -1 with reference frame A).
  const real s = h.getUseReferenceFrameA() ? real(1) : real(-1);
  hingeLimit(h, s, j);
  if (h.getEnableAngularMotor() && !(j.hinge_limit && j.hinge_lo == j.hinge_hi)) {
    j.hinge_motor = true;
    j.hinge_motor_velocity = s * real(h.getMotorTargetVelocity());
    j.hinge_motor_max_impulse = real(h.getMaxMotorImpulse());
  }
}

// btSliderConstraint: the linear axis is frame A's x; the rotation about it is Bullet's angle (testAngLimits:
// B relative to A, right-handed), our hinge theta about axis 0, free, limited, or locked at any angle.
void sliderSpec(btSliderConstraint& s, JointSpec& j) {
  j.kind = "slider";
  j.frame_a = fromBt(s.getFrameOffsetA());
  j.frame_b = fromBt(s.getFrameOffsetB());
  const real lo = s.getLowerLinLimit(), hi = s.getUpperLinLimit();
  j.lin[0] = lo == hi ? JointSpec::Axis::Locked : (lo > hi ? JointSpec::Axis::Free : JointSpec::Axis::Limited);
  j.lin_lo[0] = lo;
  j.lin_hi[0] = hi;
  j.lin[1] = j.lin[2] = JointSpec::Axis::Locked;
  // Bullet: the linear limit row corrects with softnessLimLin (as ERP, where set). Its code also bounces
  // |1 - dampingLimLin| of the incoming speed, but stock Bullet's slider does not (tests/test_bullet_joints_stock.cpp):
  // no bounce here either.
  if (s.getFlags() & BT_SLIDER_FLAGS_ERP_LIMLIN) j.lin_stop_erp[0] = real(s.getSoftnessLimLin());
  const real alo = s.getLowerAngLimit(), ahi = s.getUpperAngLimit();
  if (alo == ahi && alo == 0) {
    j.ang = JointSpec::Angular::Locked;
  } else {
    j.ang = JointSpec::Angular::Hinge;
    j.hinge_axis = 0;
    j.hinge_limit = alo <= ahi;
    j.hinge_lo = alo;
    j.hinge_hi = ahi;
    // Bullet: the limit row corrects with softnessLimAng (as ERP, where set) and bounces |1 - dampingLimAng|.
    if (s.getFlags() & BT_SLIDER_FLAGS_ERP_LIMANG) j.hinge_stop_erp = real(s.getSoftnessLimAng());
    j.hinge_bounce = std::fabs(1 - real(s.getDampingLimAng()));
  }
  // Bullet's angular motor row asks (wA - wB).x = target: d theta/dt = -target, |impulse| <= force / fps.
  if (s.getPoweredAngMotor() && j.ang == JointSpec::Angular::Hinge && !(j.hinge_limit && alo == ahi)) {
    j.hinge_motor = true;
    j.hinge_motor_velocity = -real(s.getTargetAngMotorVelocity());
    j.hinge_motor_max_force = real(s.getMaxAngMotorForce());
  }
  if (s.getPoweredLinMotor()) {
    j.lin_motor[0].on = true;
    j.lin_motor[0].velocity = s.getTargetLinMotorVelocity();
    j.lin_motor[0].max_force = s.getMaxLinMotorForce();
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
  if (c.getFlags() & BT_CONETWIST_FLAGS_LIN_ERP) j.erp = real(c.getParam(BT_CONSTRAINT_ERP, 0));
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
    const btTranslationalLimitMotor* t = g.getTranslationalLimitMotor();
    d.motor[i] = t->m_enableMotor[i];
    d.motor_velocity[i] = t->m_targetVelocity[i];
    d.motor_force[i] = t->m_maxMotorForce[i];
    const btRotationalLimitMotor* r = g.getRotationalLimitMotor(i);
    d.motor[3 + i] = r->m_enableMotor;
    d.motor_velocity[3 + i] = r->m_targetVelocity;  // Bullet: d(getAngle)/dt
    d.motor_force[3 + i] = r->m_maxMotorForce;      // Bullet bounds the row's impulse by force / fps
    d.bounce[3 + i] = r->m_bounce;
    // setParam(BT_CONSTRAINT_STOP_ERP) per axis (btGeneric6DofConstraint::setLinearLimits, setAngularLimits).
    if (g.getFlags() & (BT_6DOF_FLAGS_ERP_STOP << (i * BT_6DOF_FLAGS_AXIS_SHIFT))) d.stop_erp[i] = t->m_stopERP[i];
    if (g.getFlags() & (BT_6DOF_FLAGS_ERP_STOP << ((3 + i) * BT_6DOF_FLAGS_AXIS_SHIFT)))
      d.stop_erp[3 + i] = r->m_stopERP;
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

// btGeneric6DofSpring2Constraint keeps its setParam flags protected (no getter): read through a derived class.
struct Spring2Flags : btGeneric6DofSpring2Constraint {
  static int of(const btGeneric6DofSpring2Constraint& g) { return g.*(&Spring2Flags::m_flags); }
};

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
    d.motor_velocity[i] = t->m_targetVelocity[i];
    d.motor_force[i] = t->m_maxMotorForce[i];
    d.servo_target[i] = t->m_servoTarget[i];
    d.bounce[i] = t->m_bounce[i];
    d.motor_velocity[3 + i] = r->m_targetVelocity;
    d.motor_force[3 + i] = r->m_maxMotorForce;
    d.servo_target[3 + i] = r->m_servoTarget;
    d.bounce[3 + i] = r->m_bounce;
    d.spring[3 + i] = r->m_enableSpring;
    d.k[3 + i] = r->m_springStiffness;
    d.c[3 + i] = r->m_springDamping;
    d.eq[3 + i] = r->m_equilibriumPoint;
    d.k_limited[i] = t->m_springStiffnessLimited[i];
    d.c_limited[i] = t->m_springDampingLimited[i];
    d.k_limited[3 + i] = r->m_springStiffnessLimited;
    d.c_limited[3 + i] = r->m_springDampingLimited;
  }
  // Stop and motor ERP per axis where setParam set them (the flags of getInfo2's setLinearLimits and
  // setAngularLimits); else the world's ERP, as there.
  const int flags = Spring2Flags::of(g);
  for (int i = 0; i < 6; ++i) {
    const int f = flags >> (i * BT_6DOF_FLAGS_AXIS_SHIFT2);
    const btScalar stop = i < 3 ? t->m_stopERP[i] : g.getRotationalLimitMotor(i - 3)->m_stopERP;
    const btScalar motor = i < 3 ? t->m_motorERP[i] : g.getRotationalLimitMotor(i - 3)->m_motorERP;
    if (f & BT_6DOF_FLAGS_ERP_STOP2) d.stop_erp[i] = real(stop);
    if (f & BT_6DOF_FLAGS_ERP_MOTO2) d.motor_erp[i] = real(motor);
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
      j.world_axes = true;  // Bullet's rows: world x, y, z
      if (p.getFlags() & BT_P2P_FLAGS_ERP) j.erp = real(p.getParam(BT_CONSTRAINT_ERP));
      j.ang = JointSpec::Angular::Free;
      return j;
    }
    case GEAR_CONSTRAINT_TYPE: {
      const auto& g = static_cast<const btGearConstraint&>(c);
      j.kind = "gear";
      j.gear = true;
      j.gear_axis_a = fromBt(g.getAxisA());
      j.gear_axis_b = fromBt(g.getAxisB());
      j.gear_ratio = real(g.getRatio());
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
      throw InputError("unsupported Bullet constraint: " + constraintTypeName(c.getConstraintType()) +
                       " (supported: point-to-point, hinge, hinge2, cone-twist, slider, gear, fixed, generic 6-DoF "
                       "[spring, spring 2])");
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

namespace {

// A side of a joint that cannot move in this sub-step: Bullet's fixed body or a body outside the System, a static or
// kinematic body, or a sleeping one (fixed until its island wakes).
bool immovable(const BodyArrays& bodies, const JointBody& s) {
  if (s.index < 0) return true;
  const size_t i = size_t(s.index);
  return i < bodies.flags.size() && (bodies.flags[i] & (kBodyFixed | kBodyKinematic)) != 0;
}

}  // namespace

// Each enabled joint's rows, except those of a joint neither of whose bodies can move: its rows could change no
// velocity (a zero diagonal), and an error they carry would hold the solve's residual up to its iteration cap every
// sub-step (a hinge whose only dynamic body has fallen asleep). Bullet solves no sleeping island either
// (btSimulationIslandManager::buildAndProcessIslands), and its rows between two static bodies apply nothing.
// Bullet bounds every row of a constraint by its breaking threshold
// (btSequentialImpulseConstraintSolver::convertJoint), so a joint that breaks gives at most that impulse.
void BulletJoints::rows(const BodyArrays& bodies, const StepContext& step, std::vector<ConstraintRow>& out) {
  row_joint_.clear();
  rows_.clear();
  dt_ = step.dt;
  for (size_t k = 0; k < joints_.size(); ++k) {
    btTypedConstraint* c = joints_[k];
    if (!c->isEnabled()) continue;
    const JointSpec j = jointSpecFromBullet(*c);
    const JointBody A = side(bodies, j.a), B = side(bodies, j.b);
    if (immovable(bodies, A) && immovable(bodies, B)) continue;
    const size_t before = out.size();
    jointRows(j, A, B, step.dt, settings_, out);
    if (c->getBreakingImpulseThreshold() < SIMD_INFINITY) {  // Bullet's default: unbreakable, rows unbounded
      const real limit = real(c->getBreakingImpulseThreshold());
      for (size_t r = before; r < out.size(); ++r) {
        out[r].lo = std::max(out[r].lo, -limit);
        out[r].hi = std::min(out[r].hi, limit);
      }
    }
    row_joint_.resize(out.size() - before + row_joint_.size(), int(k));
    rows_.insert(rows_.end(), out.begin() + std::ptrdiff_t(before), out.end());
  }
}

// Bullet's write-back (btSequentialImpulseConstraintSolver::writeBackJoints): each constraint's btJointFeedback
// holds the forces and torques of its rows over the step (J^T lambda / h, scaled by the bodies' linear and angular
// factors), getAppliedImpulse the impulse of its last row, and a row at or above the breaking threshold breaks it.
// Every constraint's feedback is cleared first, as in convertJoints, and a disabled one reports zero.
void BulletJoints::impulses(const real* lambda, size_t count) {
  for (btTypedConstraint* c : joints_) {
    if (btJointFeedback* fb = c->getJointFeedback()) {
      fb->m_appliedForceBodyA.setZero();
      fb->m_appliedTorqueBodyA.setZero();
      fb->m_appliedForceBodyB.setZero();
      fb->m_appliedTorqueBodyB.setZero();
    }
    c->internalSetAppliedImpulse(0);
  }
  const size_t n = std::min(count, row_joint_.size());
  std::vector<char> broken(joints_.size(), 0);
  const btScalar inv_h = dt_ > 0 ? btScalar(1 / dt_) : btScalar(0);
  for (size_t r = 0; r < n; ++r) {
    btTypedConstraint* c = joints_[size_t(row_joint_[r])];
    const ConstraintRow& row = rows_[r];
    const btScalar l = btScalar(lambda[r]);
    if (btJointFeedback* fb = c->getJointFeedback()) {
      const btRigidBody &a = c->getRigidBodyA(), &b = c->getRigidBodyB();
      fb->m_appliedForceBodyA += btVector3(row.Ja[0], row.Ja[1], row.Ja[2]) * a.getLinearFactor() * l * inv_h;
      fb->m_appliedTorqueBodyA += btVector3(row.Ja[3], row.Ja[4], row.Ja[5]) * a.getAngularFactor() * l * inv_h;
      fb->m_appliedForceBodyB += btVector3(row.Jb[0], row.Jb[1], row.Jb[2]) * b.getLinearFactor() * l * inv_h;
      fb->m_appliedTorqueBodyB += btVector3(row.Jb[3], row.Jb[4], row.Jb[5]) * b.getAngularFactor() * l * inv_h;
    }
    c->internalSetAppliedImpulse(-l);  // Bullet orients its rows A minus B, ours B minus A
    if (std::fabs(l) >= c->getBreakingImpulseThreshold()) broken[size_t(row_joint_[r])] = 1;
  }
  for (size_t k = 0; k < joints_.size(); ++k)
    if (broken[k]) joints_[k]->setEnabled(false);
}

namespace {

// Bullet's effective mass of a Spring2 spring (btGeneric6DofSpring2Constraint::get_limit_motor_info2): the dynamic
// body's, or mA mB / (mA + mB); on a rotational axis each side's m r^2 + 1 / |I^-1 axis| (r: its frame's offset).
real springMass(const JointSpec& j, const JointSpec::Spring& sp, const btRigidBody& a, const btRigidBody& b) {
  auto side = [&](const btRigidBody& body, const Pose& f) {
    if (body.getInvMass() == 0) return real(0);
    real m = real(1 / body.getInvMass());
    if (sp.dof < 3) return m;
    const Pose frame = compose(fromBt(body.getCenterOfMassTransform()), f);
    const real rr = length2(frame.p - fromBt(body.getCenterOfMassPosition()));
    const Vec3 ax = rotate(compose(fromBt(a.getCenterOfMassTransform()), j.frame_a).q,
                           Vec3{real(sp.dof == 3), real(sp.dof == 4), real(sp.dof == 5)});
    return m * rr + real(1) / length(fromBt(body.getInvInertiaTensorWorld() * toBt(ax)));
  };
  const real ma = side(a, j.frame_a), mb = side(b, j.frame_b);
  return ma == 0 ? mb : (mb == 0 ? ma : ma * mb / (ma + mb));
}

}  // namespace

void BulletJoints::springForces(const BodyArrays& bodies, real h, Vec3* force, Vec3* torque) const {
  for (btTypedConstraint* c : joints_) {
    if (!c->isEnabled()) continue;
    JointSpec j = jointSpecFromBullet(*c);
    if (j.springs.empty()) continue;
    for (JointSpec::Spring& sp : j.springs) {
      if (!(sp.limit_stiffness || sp.limit_damping) || !(h > 0)) continue;
      const real m = springMass(j, sp, c->getRigidBodyA(), c->getRigidBodyB());
      if (!(m > 0)) continue;
      if (sp.limit_stiffness) sp.stiffness = std::min(sp.stiffness, m / (16 * h * h));
      if (sp.limit_damping) sp.damping = std::min(sp.damping, m / h);
    }
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
