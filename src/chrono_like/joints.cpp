// Bullet constraints as DVI constraint rows (joints.h).
#include "joints.h"
#include "bullet_convert.h"

#include <btBulletDynamicsCommon.h>
#include <BulletDynamics/ConstraintSolver/btFixedConstraint.h>
#include <BulletDynamics/ConstraintSolver/btGeneric6DofSpring2Constraint.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "errors.h"

namespace dvi {

namespace {

constexpr real kInf = std::numeric_limits<real>::infinity();


Vec3 unitAxis(int k) { return k == 0 ? Vec3{1, 0, 0} : (k == 1 ? Vec3{0, 1, 0} : Vec3{0, 0, 1}); }
real comp(Vec3 v, int k) { return k == 0 ? v.x : (k == 1 ? v.y : v.z); }

// Rotation vector of a unit quaternion (shortest rotation).
Vec3 rotationVector(Quat q) {
  if (q.w < 0) q = Quat{-q.w, -q.x, -q.y, -q.z};
  const Vec3 v{q.x, q.y, q.z};
  const real s = length(v);
  if (!(s > real(1e-12))) return v * real(2);
  return v * (real(2) * std::atan2(s, q.w) / s);
}

std::string axisName(int i) { return i < 3 ? std::string(1, "xyz"[i]) : std::string("rotation ") + "xyz"[i - 3]; }

// Six degrees of freedom of a 6-DoF constraint (Bullet's order: linear x y z, angular x y z).
struct Dof6 {
  real lo[6], hi[6];
  bool motor[6] = {false, false, false, false, false, false};
  bool spring[6] = {false, false, false, false, false, false};
  real k[6] = {0, 0, 0, 0, 0, 0}, c[6] = {0, 0, 0, 0, 0, 0}, eq[6] = {0, 0, 0, 0, 0, 0};
};

void fromDof6(const Dof6& d, const char* kind, JointSpec& j) {
  auto refuse = [&](const std::string& what) { throw InputError(std::string(kind) + ": " + what + " is not supported"); };
  for (int i = 0; i < 3; ++i) {
    if (d.lo[i] == d.hi[i]) j.lin[i] = JointSpec::Axis::Locked;
    else if (d.lo[i] > d.hi[i]) j.lin[i] = JointSpec::Axis::Free;
    else j.lin[i] = JointSpec::Axis::Limited;
    j.lin_lo[i] = d.lo[i];
    j.lin_hi[i] = d.hi[i];
  }
  int locked = 0, free_axis = -1;
  for (int i = 0; i < 3; ++i) {
    const real lo = d.lo[3 + i], hi = d.hi[3 + i];
    if (lo == hi) {
      ++locked;
      if (lo != 0) refuse("a rotational axis locked at a non-zero angle (" + axisName(3 + i) + ")");
    } else if (lo > hi) {
      free_axis = i;
    } else {
      refuse("an angular limit range on " + axisName(3 + i) + " (only locked or free rotational axes)");
    }
  }
  if (locked == 3) j.ang = JointSpec::Angular::Locked;
  else if (locked == 2) {
    j.ang = JointSpec::Angular::Hinge;
    j.hinge_axis = free_axis;
  } else if (locked == 0) j.ang = JointSpec::Angular::Free;
  else refuse("a single locked rotational axis");
  for (int i = 0; i < 6; ++i) {
    if (d.motor[i] && !d.spring[i]) refuse("a motor on " + axisName(i));
    if (!d.spring[i]) continue;
    if (i < 3) {
      if (j.lin[i] != JointSpec::Axis::Locked) j.springs.push_back({i, d.k[i], d.c[i], d.eq[i]});
    } else if (j.ang == JointSpec::Angular::Hinge && i - 3 == j.hinge_axis) {
      j.springs.push_back({i, d.k[i], d.c[i], d.eq[i]});
    } else if (!(j.ang == JointSpec::Angular::Locked)) {
      refuse("a spring on " + axisName(i) + " (angular springs only on the free axis of a hinge-like 6-DoF)");
    }
  }
}

// Linear row along unit e (an axis fixed in frame A): J v = e.(vB + wB x rB) - e.(vA + wA x rAB) with
// rAB = pB - xA.
ConstraintRow linearRow(const JointBody& A, const JointBody& B, Vec3 e, Vec3 rAB, Vec3 rB) {
  ConstraintRow r;
  r.a = A.index;
  r.b = B.index;
  const Vec3 ta = cross(rAB, e) * real(-1), tb = cross(rB, e);
  const real ja[6] = {-e.x, -e.y, -e.z, ta.x, ta.y, ta.z}, jb[6] = {e.x, e.y, e.z, tb.x, tb.y, tb.z};
  for (int i = 0; i < 6; ++i) {
    r.Ja[i] = ja[i];
    r.Jb[i] = jb[i];
  }
  return r;
}

// Angular row: J v = (wB - wA).e.
ConstraintRow angularRow(const JointBody& A, const JointBody& B, Vec3 e) {
  ConstraintRow r;
  r.a = A.index;
  r.b = B.index;
  const real ja[6] = {0, 0, 0, -e.x, -e.y, -e.z}, jb[6] = {0, 0, 0, e.x, e.y, e.z};
  for (int i = 0; i < 6; ++i) {
    r.Ja[i] = ja[i];
    r.Jb[i] = jb[i];
  }
  return r;
}

ConstraintRow negated(ConstraintRow r) {
  for (int i = 0; i < 6; ++i) {
    r.Ja[i] = -r.Ja[i];
    r.Jb[i] = -r.Jb[i];
  }
  return r;
}

real clampr(real x, real lo, real hi) { return std::min(std::max(x, lo), hi); }

struct Frames {
  Pose fa, fb;      // world joint frames
  Vec3 rA, rB;      // joint origins relative to the centres of mass, world
  Vec3 d;           // pB - pA
  Vec3 ea[3];       // axes of frame A, world
};

Frames frames(const JointSpec& j, const JointBody& A, const JointBody& B) {
  Frames f;
  f.fa = compose(Pose{A.x, A.q}, j.frame_a);
  f.fb = compose(Pose{B.x, B.q}, j.frame_b);
  f.rA = f.fa.p - A.x;
  f.rB = f.fb.p - B.x;
  f.d = f.fb.p - f.fa.p;
  for (int k = 0; k < 3; ++k) f.ea[k] = rotate(f.fa.q, unitAxis(k));
  return f;
}

real hingeTheta(const JointSpec& j, const Frames& f) {
  Quat qr = conj(f.fa.q) * f.fb.q;
  if (qr.w < 0) qr = Quat{-qr.w, -qr.x, -qr.y, -qr.z};
  return real(2) * std::atan2(comp(Vec3{qr.x, qr.y, qr.z}, j.hinge_axis), qr.w);
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

JointSpec JointSpec::fromBullet(const btTypedConstraint& c) {
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
      for (auto& a : j.lin) a = Axis::Locked;
      j.ang = Angular::Free;
      return j;
    }
    case HINGE_CONSTRAINT_TYPE: {
      auto& h = static_cast<btHingeConstraint&>(mc);
      j.kind = "hinge";
      j.frame_a = fromBt(h.getAFrame());
      j.frame_b = fromBt(h.getBFrame());
      for (auto& a : j.lin) a = Axis::Locked;
      j.ang = Angular::Hinge;
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
      return j;
    }
    case SLIDER_CONSTRAINT_TYPE: {
      auto& s = static_cast<btSliderConstraint&>(mc);
      j.kind = "slider";
      j.frame_a = fromBt(s.getFrameOffsetA());
      j.frame_b = fromBt(s.getFrameOffsetB());
      const real lo = s.getLowerLinLimit(), hi = s.getUpperLinLimit();
      j.lin[0] = lo == hi ? Axis::Locked : (lo > hi ? Axis::Free : Axis::Limited);
      j.lin_lo[0] = lo;
      j.lin_hi[0] = hi;
      j.lin[1] = j.lin[2] = Axis::Locked;
      const real alo = s.getLowerAngLimit(), ahi = s.getUpperAngLimit();
      if (alo == ahi && alo == 0) {
        j.ang = Angular::Locked;
      } else if (alo > ahi) {
        j.ang = Angular::Hinge;
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
      return j;
    }
    case D6_CONSTRAINT_TYPE:
    case D6_SPRING_CONSTRAINT_TYPE: {
      auto& g = static_cast<btGeneric6DofConstraint&>(mc);
      const bool spring = c.getConstraintType() == D6_SPRING_CONSTRAINT_TYPE;
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
        d.motor[3 + i] = g.getRotationalLimitMotor(i)->m_enableMotor;
      }
      if (spring) {
        auto& sp = static_cast<btGeneric6DofSpringConstraint&>(mc);
        for (int i = 0; i < 6; ++i) {
          d.spring[i] = sp.isSpringEnabled(i);
          d.k[i] = sp.getStiffness(i);
          d.c[i] = 0;  // Bullet's damping here is a motor factor, not a physical coefficient (docs/DROP_IN.md)
          d.eq[i] = sp.getEquilibriumPoint(i);
        }
      }
      fromDof6(d, j.kind, j);
      return j;
    }
    case FIXED_CONSTRAINT_TYPE:
    case D6_SPRING_2_CONSTRAINT_TYPE: {
      auto& g = static_cast<btGeneric6DofSpring2Constraint&>(mc);
      j.kind = c.getConstraintType() == FIXED_CONSTRAINT_TYPE ? "fixed" : "generic 6-DoF spring 2";
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
        d.spring[3 + i] = r->m_enableSpring;
        d.k[3 + i] = r->m_springStiffness;
        d.c[3 + i] = r->m_springDamping;
        d.eq[3 + i] = r->m_equilibriumPoint;
      }
      fromDof6(d, j.kind, j);
      return j;
    }
    default:
      throw InputError("unsupported Bullet constraint: " + constraintTypeName(c.getConstraintType()) +
                       " (supported: point-to-point, hinge, slider, fixed, generic 6-DoF [spring, spring 2])");
  }
}

void jointRows(const JointSpec& j, const JointBody& A, const JointBody& B, real dt, const JointSettings& s,
               std::vector<ConstraintRow>& out) {
  const Frames f = frames(j, A, B);
  const real size = std::min(A.size, B.size);
  const real vmax = s.recovery_rel * size, wmax = s.max_recovery_angular;
  const Vec3 rAB = f.fb.p - A.x;
  auto bilateral = [&](ConstraintRow r, real C, real lim) {
    r.bias = clampr(C / dt, -lim, lim);
    out.push_back(r);
  };
  auto unilateral = [&](ConstraintRow r, real C, real lim) {  // C >= 0 wanted
    r.bias = C >= 0 ? C / dt : std::max(C / dt, -lim);
    r.lo = 0;
    r.hi = kInf;
    out.push_back(r);
  };
  // Second-order drift of a linear row over one step: the velocity-level row makes C' = C + h J v+ vanish
  // to first order, but the exponential-map rotation of the lever arms (and of e, fixed in A) adds
  //   h^2/2 C'' = h^2/2 [ e.(wB x (wB x rB) - wA x (wA x rAB)) + 2 (wA x e).v_rel + (wA x (wA x e)).d ]
  // from the velocities at the start of the step. Feeding it forward in the bias leaves an O(h^3) error
  // instead of O(h^2 w^2 L) per step (a swinging pendulum otherwise drifts by ~(w h)^2 L / 2;
  // Hairer, Lubich & Wanner, Geometric Numerical Integration, ch. VII, on drift of index-reduced DAEs).
  const Vec3 v_rel = (B.v + cross(B.w, f.rB)) - (A.v + cross(A.w, rAB));
  const Vec3 acc_rel = cross(B.w, cross(B.w, f.rB)) - cross(A.w, cross(A.w, rAB));
  auto drift = [&](Vec3 e) {
    if (!s.drift_feedforward) return real(0);
    const Vec3 de = cross(A.w, e);
    return real(0.5) * dt * dt * (dot(e, acc_rel) + 2 * dot(de, v_rel) + dot(cross(A.w, de), f.d));
  };
  for (int i = 0; i < 3; ++i) {
    if (j.lin[i] == JointSpec::Axis::Free) continue;
    const Vec3 e = f.ea[i];
    const ConstraintRow r = linearRow(A, B, e, rAB, f.rB);
    const real si = dot(e, f.d);
    if (j.lin[i] == JointSpec::Axis::Locked) {
      bilateral(r, si - j.lin_lo[i] + drift(e), vmax);
    } else {
      unilateral(r, si - j.lin_lo[i], vmax);
      unilateral(negated(r), j.lin_hi[i] - si, vmax);
    }
  }
  if (j.lin_motor) {
    ConstraintRow r = linearRow(A, B, f.ea[0], rAB, f.rB);
    r.bias = -j.lin_motor_velocity;
    r.lo = -j.lin_motor_max_force * dt;
    r.hi = j.lin_motor_max_force * dt;
    out.push_back(r);
  }
  if (j.ang == JointSpec::Angular::Locked) {
    const Vec3 theta = rotationVector(f.fb.q * conj(f.fa.q));
    for (int k = 0; k < 3; ++k) bilateral(angularRow(A, B, unitAxis(k)), comp(theta, k), wmax);
  } else if (j.ang == JointSpec::Angular::Hinge) {
    const int k = j.hinge_axis;
    const Vec3 a = f.ea[k], b = rotate(f.fb.q, unitAxis(k));
    const Vec3 c = cross(a, b);
    for (int m = 0; m < 3; ++m)
      if (m != k) bilateral(angularRow(A, B, f.ea[m]), dot(f.ea[m], c), wmax);
    const ConstraintRow ra = angularRow(A, B, a);  // J v = d theta / dt
    if (j.hinge_limit) {
      const real theta = hingeTheta(j, f);
      unilateral(ra, theta - j.hinge_lo, wmax);
      unilateral(negated(ra), j.hinge_hi - theta, wmax);
    }
    if (j.hinge_motor) {
      ConstraintRow r = ra;
      r.bias = -j.hinge_motor_velocity;
      r.lo = -j.hinge_motor_max_impulse;
      r.hi = j.hinge_motor_max_impulse;
      out.push_back(r);
    }
  }
}

real jointHingeAngle(const JointSpec& j, const JointBody& A, const JointBody& B) { return hingeTheta(j, frames(j, A, B)); }

JointViolation jointViolation(const JointSpec& j, const JointBody& A, const JointBody& B) {
  const Frames f = frames(j, A, B);
  JointViolation v;
  for (int i = 0; i < 3; ++i) {
    const real si = dot(f.ea[i], f.d);
    if (j.lin[i] == JointSpec::Axis::Locked) v.linear = std::max(v.linear, std::fabs(si - j.lin_lo[i]));
    if (j.lin[i] == JointSpec::Axis::Limited)
      v.linear = std::max(v.linear, std::max(j.lin_lo[i] - si, si - j.lin_hi[i]));
  }
  if (j.ang == JointSpec::Angular::Locked) {
    v.angular = length(rotationVector(f.fb.q * conj(f.fa.q)));
  } else if (j.ang == JointSpec::Angular::Hinge) {
    const Vec3 a = f.ea[j.hinge_axis], b = rotate(f.fb.q, unitAxis(j.hinge_axis));
    v.angular = std::atan2(length(cross(a, b)), dot(a, b));
    if (j.hinge_limit) {
      const real th = hingeTheta(j, f);
      v.angular = std::max(v.angular, std::max(j.hinge_lo - th, th - j.hinge_hi));
    }
  }
  return v;
}

void BulletJoints::add(btTypedConstraint* c) {
  if (!c) throw InputError("null constraint");
  (void)JointSpec::fromBullet(*c);  // throws for what cannot be represented
  if (std::find(joints_.begin(), joints_.end(), c) == joints_.end()) joints_.push_back(c);
}

void BulletJoints::remove(btTypedConstraint* c) { joints_.erase(std::remove(joints_.begin(), joints_.end(), c), joints_.end()); }

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

void BulletJoints::rows(const BodyArrays& bodies, double /*t*/, real dt, std::vector<ConstraintRow>& out) {
  row_joint_.clear();
  for (size_t k = 0; k < joints_.size(); ++k) {
    btTypedConstraint* c = joints_[k];
    if (!c->isEnabled()) continue;
    const JointSpec j = JointSpec::fromBullet(*c);
    const size_t before = out.size();
    jointRows(j, side(bodies, j.a), side(bodies, j.b), dt, settings_, out);
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
    const JointSpec j = JointSpec::fromBullet(*c);
    if (j.springs.empty()) continue;
    const JointBody A = side(bodies, j.a), B = side(bodies, j.b);
    const Frames f = frames(j, A, B);
    const Vec3 rAB = f.fb.p - A.x;
    for (const JointSpec::Spring& s : j.springs) {
      if (s.dof < 3) {
        const Vec3 e = f.ea[s.dof];
        const real x = dot(e, f.d);
        const real xd = dot(e, (B.v + cross(B.w, f.rB)) - (A.v + cross(A.w, rAB)));
        const Vec3 F = e * (-s.stiffness * (x - s.equilibrium) - s.damping * xd);
        if (B.index >= 0) {
          force[B.index] += F;
          torque[B.index] += cross(f.rB, F);
        }
        if (A.index >= 0) {
          force[A.index] -= F;
          torque[A.index] -= cross(rAB, F);
        }
      } else {
        const Vec3 a = f.ea[s.dof - 3];
        const real th = hingeTheta(j, f);
        const real thd = dot(a, B.w - A.w);
        const Vec3 T = a * (-s.stiffness * (th - s.equilibrium) - s.damping * thd);
        if (B.index >= 0) torque[B.index] += T;
        if (A.index >= 0) torque[A.index] -= T;
      }
    }
  }
}

JointViolation BulletJoints::maxViolation(const BodyArrays& bodies) const {
  JointViolation m;
  for (btTypedConstraint* c : joints_) {
    if (!c->isEnabled()) continue;
    const JointSpec j = JointSpec::fromBullet(*c);
    const JointBody A = side(bodies, j.a), B = side(bodies, j.b);
    const JointViolation v = jointViolation(j, A, B);
    m.linear = std::max(m.linear, v.linear / std::min(A.size, B.size));
    m.angular = std::max(m.angular, v.angular);
  }
  return m;
}

}  // namespace dvi
