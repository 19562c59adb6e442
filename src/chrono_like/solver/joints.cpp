// Joint rows, violations and spring forces from a JointSpec (joints.h).
#include "chrono_like/solver/joints.h"
#include "chrono_like/solver/joint_angles.h"

#include <algorithm>
#include <cmath>
#include <limits>

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

struct Frames {
  Pose fa, fb;  // world joint frames
  Vec3 rA, rB;  // joint origins relative to the centres of mass, world
  Vec3 d;       // pB - pA
  Vec3 ea[3];   // axes of frame A, world
};

Frames frames(const JointSpec& j, const JointBody& A, const JointBody& B) {
  Frames f;
  f.fa = compose(Pose{A.x, A.q}, j.frame_a);
  f.fb = compose(Pose{B.x, B.q}, j.frame_b);
  f.rA = f.fa.p - A.x;
  f.rB = f.fb.p - B.x;
  f.d = f.fb.p - f.fa.p;
  for (int k = 0; k < 3; ++k) f.ea[k] = j.world_axes ? unitAxis(k) : rotate(f.fa.q, unitAxis(k));
  return f;
}

real hingeTheta(const JointSpec& j, const Frames& f) {
  Quat qr = conj(f.fa.q) * f.fb.q;
  if (qr.w < 0) qr = Quat{-qr.w, -qr.x, -qr.y, -qr.z};
  return real(2) * std::atan2(comp(Vec3{qr.x, qr.y, qr.z}, j.hinge_axis), qr.w);
}

// Largest angle past a cone-twist's limits or locks (radians).
real coneViolation(const JointSpec& j, const Frames& f) {
  const ConeAngles c = coneAngles(f.fa.q, f.fb.q, j.cone_swing1, j.cone_swing2);
  real v = 0;
  if (j.cone_lock1) v = std::max(v, std::asin(std::min(real(1), std::fabs(c.u_y))));
  if (j.cone_lock2) v = std::max(v, std::asin(std::min(real(1), std::fabs(c.u_z))));
  if (j.cone_swing_limit) v = std::max(v, c.swing - c.swing_limit);
  if (j.cone_twist_limit) v = std::max(v, std::fabs(c.twist) - j.cone_twist);
  return v;
}

// The relative velocity a row measures at the start of the step: J v0.
real rowVelocity(const ConstraintRow& r, const JointBody& A, const JointBody& B) {
  const real va[6] = {A.v.x, A.v.y, A.v.z, A.w.x, A.w.y, A.w.z}, vb[6] = {B.v.x, B.v.y, B.v.z, B.w.x, B.w.y, B.w.z};
  real s = 0;
  for (int i = 0; i < 6; ++i) s += r.Ja[i] * va[i] + r.Jb[i] * vb[i];
  return s;
}

// An angle difference in (-pi, pi].
real wrapAngle(real a) {
  const real kPi = real(3.14159265358979323846);
  a = std::remainder(a, 2 * kPi);
  return a <= -kPi ? a + 2 * kPi : a;
}

// Appends rows with their bias: bilateral C = 0, unilateral C >= 0 (any approach speed), and motors J v = target
// within +-max impulse. An error is corrected in one step while that is slower than the recovery speed lim, and at
// least by the fraction erp per step beyond (Bullet's ERP, joints.h).
struct RowSink {
  std::vector<ConstraintRow>& out;
  const JointBody &A, &B;
  real dt, vmax, wmax, erp;
  real recover(real C, real lim, real e) const {
    const real full = std::fabs(C) / dt;
    return std::copysign(std::max(std::min(full, lim), (e < 0 ? erp : e) * full), C);
  }
  void bilateral(ConstraintRow r, real C, real lim, real e = -1) {
    r.bias = recover(C, lim, e);
    out.push_back(r);
  }
  // bounce: Bullet's limit restitution, where the row would be crossed within the step (Bullet: "bounce").
  void unilateral(ConstraintRow r, real C, real lim, real e = -1, real bounce = 0) {  // C >= 0 wanted
    r.bias = C >= 0 ? C / dt : recover(C, lim, e);
    if (bounce > 0) {
      const real v0 = rowVelocity(r, A, B);
      if (v0 < 0 && C + dt * v0 < 0) r.bias = std::min(r.bias, bounce * v0);
    }
    r.lo = 0;
    r.hi = kInf;
    out.push_back(r);
  }
  void motor(ConstraintRow r, real target, real max_impulse) {
    r.bias = -target;
    r.lo = -max_impulse;
    r.hi = max_impulse;
    out.push_back(r);
  }
  // Bullet's servo (btGeneric6DofSpring2Constraint::get_limit_motor_info2 with getMotorFactor): toward the target at
  // speed |v|, slowed to motor_erp x error / h within reach of it.
  void servo(ConstraintRow r, real error, real speed, real motor_erp, real max_impulse) {
    const real v = std::min(std::fabs(speed), (motor_erp < 0 ? erp : motor_erp) * std::fabs(error) / dt);
    motor(r, error > 0 ? v : (error < 0 ? -v : real(0)), max_impulse);
  }
};

void hingeRows(const JointSpec& j, const JointBody& A, const JointBody& B, const Frames& f, RowSink& sink) {
  const int k = j.hinge_axis;
  const Vec3 a = f.ea[k], b = rotate(f.fb.q, unitAxis(k));
  const Vec3 c = cross(a, b);
  for (int m = 0; m < 3; ++m)
    if (m != k) sink.bilateral(angularRow(A, B, f.ea[m]), dot(f.ea[m], c), sink.wmax, j.erp);
  const ConstraintRow ra = angularRow(A, B, a);  // J v = d theta / dt
  const real theta = hingeTheta(j, f);
  if (j.hinge_limit) {
    // Deviation from the range's centre, wrapped (Bullet's btAngularLimit::test): a range may contain +-pi.
    const real half = (j.hinge_hi - j.hinge_lo) / 2, dev = wrapAngle(theta - (j.hinge_lo + j.hinge_hi) / 2);
    const real erp = (j.hinge_stop_erp < 0 ? sink.erp : j.hinge_stop_erp) * j.hinge_limit_bias;
    if (half == 0) {  // lo == hi: locked (Bullet: one row with unbounded impulse)
      sink.bilateral(ra, dev, sink.wmax, erp);
    } else {
      sink.unilateral(ra, dev + half, sink.wmax, erp, j.hinge_bounce);
      sink.unilateral(negated(ra), half - dev, sink.wmax, erp, j.hinge_bounce);
    }
  }
  if (!j.hinge_motor) return;
  const real bound = j.hinge_motor_max_impulse + j.hinge_motor_max_force * sink.dt;
  if (j.hinge_servo)
    sink.servo(ra, wrapAngle(j.hinge_servo_target - theta), j.hinge_motor_velocity, j.hinge_motor_erp, bound);
  else
    sink.motor(ra, j.hinge_motor_velocity, bound);
}

// Bullet's cone-twist motor (btConeTwistConstraint::calcAngleInfo2 with the motor on): the rotation
// qDelta = qFB target conj(qFA) still to go, about its axis (world), error = bias factor x angle.
void coneMotorRow(const JointSpec& j, const JointBody& A, const JointBody& B, const Frames& f, RowSink& sink) {
  const Quat qd = normalized(f.fb.q * j.cone_motor_target * conj(f.fa.q));
  const Vec3 axis{qd.x, qd.y, qd.z};
  const real s = length(axis);
  if (!(s > real(1e-7))) return;  // at the target (Bullet: no row)
  const real angle = real(2) * std::acos(std::min(real(1), std::max(real(-1), qd.w)));
  ConstraintRow r = angularRow(A, B, axis * (real(-1) / s));  // J v = (wA - wB).axis
  r.bias = -j.cone_motor_bias * angle / sink.dt;
  r.lo = 0;
  r.hi = j.cone_motor_max_impulse;
  sink.out.push_back(r);
}

void coneTwistRows(const JointSpec& j, const JointBody& A, const JointBody& B, const Frames& f, RowSink& sink) {
  if (j.cone_motor) {
    coneMotorRow(j, A, B, f, sink);
    return;
  }
  const ConeAngles c = coneAngles(f.fa.q, f.fb.q, j.cone_swing1, j.cone_swing2);
  if (j.cone_lock1) sink.bilateral(angularRow(A, B, c.u_y_g), c.u_y, sink.wmax);
  if (j.cone_lock2) sink.bilateral(angularRow(A, B, c.u_z_g), c.u_z, sink.wmax);
  if (j.cone_swing_limit) sink.unilateral(angularRow(A, B, c.swing_g), c.swing_c, sink.wmax);
  if (j.cone_twist_limit) {
    const ConstraintRow r = angularRow(A, B, c.twist_g);  // J v = d psi / dt
    if (j.cone_twist == 0) {                              // twist locked (Bullet: a bilateral row at span 0)
      sink.bilateral(r, c.twist, sink.wmax);
    } else {
      sink.unilateral(r, c.twist + j.cone_twist, sink.wmax);
      sink.unilateral(negated(r), j.cone_twist - c.twist, sink.wmax);
    }
  }
}

void eulerRows(const JointSpec& j, const JointBody& A, const JointBody& B, const Frames& f, RowSink& sink) {
  const EulerAngles e = eulerAngles(f.fa.q, f.fb.q, j.euler_order);
  for (int m = 0; m < 3; ++m) {
    const JointSpec::EulerAxis& x = j.euler[m];
    const ConstraintRow r = angularRow(A, B, e.g[m]);  // J v = d phi / dt
    if (x.mode == JointSpec::Axis::Locked) {
      sink.bilateral(r, e.angle[m] - x.lo, sink.wmax, x.stop_erp);
      continue;  // a motor on a locked axis does nothing (as in Bullet)
    }
    if (x.mode == JointSpec::Axis::Limited) {
      if (std::isfinite(x.lo)) sink.unilateral(r, e.angle[m] - x.lo, sink.wmax, x.stop_erp, x.bounce);
      if (std::isfinite(x.hi)) sink.unilateral(negated(r), x.hi - e.angle[m], sink.wmax, x.stop_erp, x.bounce);
    }
    if (x.motor && x.servo)
      sink.servo(r, wrapAngle(x.servo_target - e.angle[m]), x.motor_velocity, x.motor_erp, x.motor_max_force * sink.dt);
    else if (x.motor)
      sink.motor(r, x.motor_velocity, x.motor_max_force * sink.dt);
  }
}

// Bullet's gear (btGearConstraint::getInfo2): the two bodies' spins about their axes in the ratio, no position error.
void gearRow(const JointSpec& j, const JointBody& A, const JointBody& B, std::vector<ConstraintRow>& out) {
  ConstraintRow r;
  r.a = A.index;
  r.b = B.index;
  const Vec3 ga = rotate(A.q, j.gear_axis_a), gb = rotate(B.q, j.gear_axis_b) * j.gear_ratio;
  const real ja[3] = {ga.x, ga.y, ga.z}, jb[3] = {gb.x, gb.y, gb.z};
  for (int i = 0; i < 3; ++i) {
    r.Ja[3 + i] = ja[i];
    r.Jb[3 + i] = jb[i];
  }
  out.push_back(r);
}

// The linear rows: locked, limited and motor axes of frame A (or the world's axes, Bullet's point-to-point).
void linearRows(const JointSpec& j, const JointBody& A, const JointBody& B, const Frames& f, bool feedforward,
                RowSink& sink) {
  const real dt = sink.dt;
  // An axis fixed in A has the exact rate e.(vB + wB x rB) - e.(vA + wA x (pB - xA)); a world axis
  // e.(vB + wB x rB) - e.(vA + wA x rA).
  const Vec3 rAB = j.world_axes ? f.rA : f.fb.p - A.x;
  // Second-order drift of a linear row over one step: the velocity-level row makes C' = C + h J v+ vanish
  // to first order, but the exponential-map rotation of the lever arms (and of e, fixed in A) adds
  //   h^2/2 C'' = h^2/2 [ e.(wB x (wB x rB) - wA x (wA x rAB)) + 2 (wA x e).v_rel + (wA x (wA x e)).d ]
  // from the velocities at the start of the step (the last two terms vanish for a world axis). Feeding it forward
  // in the bias leaves an O(h^3) error instead of O(h^2 w^2 L) per step (a swinging pendulum otherwise drifts by
  // ~(w h)^2 L / 2; Hairer, Lubich & Wanner, Geometric Numerical Integration, ch. VII, on drift of index-reduced
  // DAEs).
  const Vec3 v_rel = (B.v + cross(B.w, f.rB)) - (A.v + cross(A.w, rAB));
  const Vec3 acc_rel = cross(B.w, cross(B.w, f.rB)) - cross(A.w, cross(A.w, rAB));
  const Vec3 wA = j.world_axes ? Vec3{0, 0, 0} : A.w;
  auto drift = [&](Vec3 e) {
    if (!feedforward) return real(0);
    const Vec3 de = cross(wA, e);
    return real(0.5) * dt * dt * (dot(e, acc_rel) + 2 * dot(de, v_rel) + dot(cross(wA, de), f.d));
  };
  for (int i = 0; i < 3; ++i) {
    const Vec3 e = f.ea[i];
    const ConstraintRow r = linearRow(A, B, e, rAB, f.rB);
    const real si = dot(e, f.d);
    if (j.lin[i] == JointSpec::Axis::Locked) {
      sink.bilateral(r, si - j.lin_lo[i] + drift(e), sink.vmax, j.lin_stop_erp[i]);
    } else if (j.lin[i] == JointSpec::Axis::Limited) {  // an infinite end (Bullet's setLimit(i, -inf, hi)): no row
      if (std::isfinite(j.lin_lo[i]))
        sink.unilateral(r, si - j.lin_lo[i], sink.vmax, j.lin_stop_erp[i], j.lin_bounce[i]);
      if (std::isfinite(j.lin_hi[i]))
        sink.unilateral(negated(r), j.lin_hi[i] - si, sink.vmax, j.lin_stop_erp[i], j.lin_bounce[i]);
    }
    const JointSpec::LinearMotor& m = j.lin_motor[i];
    if (!m.on || j.lin[i] == JointSpec::Axis::Locked) continue;
    if (m.servo)
      sink.servo(r, m.servo_target - si, m.velocity, m.motor_erp, m.max_force * dt);
    else
      sink.motor(r, m.velocity, m.max_force * dt);
  }
}

}  // namespace

void jointRows(const JointSpec& j, const JointBody& A, const JointBody& B, real dt, const JointSettings& s,
               std::vector<ConstraintRow>& out) {
  const Frames f = frames(j, A, B);
  const real size = std::min(A.size, B.size);
  RowSink sink{out, A, B, dt, s.recovery_rel * size, s.max_recovery_angular, j.erp >= 0 ? j.erp : s.erp};
  linearRows(j, A, B, f, s.drift_feedforward, sink);
  switch (j.ang) {
    case JointSpec::Angular::Locked: {
      const Vec3 theta = rotationVector(f.fb.q * conj(f.fa.q));
      for (int k = 0; k < 3; ++k) sink.bilateral(angularRow(A, B, unitAxis(k)), comp(theta, k), sink.wmax);
      break;
    }
    case JointSpec::Angular::Hinge: hingeRows(j, A, B, f, sink); break;
    case JointSpec::Angular::ConeTwist: coneTwistRows(j, A, B, f, sink); break;
    case JointSpec::Angular::Euler: eulerRows(j, A, B, f, sink); break;
    case JointSpec::Angular::Free: break;
  }
  if (j.gear) gearRow(j, A, B, out);
}

real jointHingeAngle(const JointSpec& j, const JointBody& A, const JointBody& B) {
  return hingeTheta(j, frames(j, A, B));
}

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
    if (j.hinge_limit) {  // past the range, wrapped about its centre as the rows see it
      const real half = (j.hinge_hi - j.hinge_lo) / 2;
      const real dev = wrapAngle(hingeTheta(j, f) - (j.hinge_lo + j.hinge_hi) / 2);
      v.angular = std::max(v.angular, std::fabs(dev) - half);
    }
  } else if (j.ang == JointSpec::Angular::ConeTwist) {
    v.angular = coneViolation(j, f);
  } else if (j.ang == JointSpec::Angular::Euler) {
    const EulerAngles e = eulerAngles(f.fa.q, f.fb.q, j.euler_order);
    for (int m = 0; m < 3; ++m) {
      const JointSpec::EulerAxis& x = j.euler[m];
      if (x.mode == JointSpec::Axis::Locked) v.angular = std::max(v.angular, std::fabs(e.angle[m] - x.lo));
      if (x.mode == JointSpec::Axis::Limited)
        v.angular = std::max(v.angular, std::max(x.lo - e.angle[m], e.angle[m] - x.hi));
    }
  }
  return v;
}

JointConeState jointConeState(const JointSpec& j, const JointBody& A, const JointBody& B) {
  const Frames f = frames(j, A, B);
  const ConeAngles c = coneAngles(f.fa.q, f.fb.q, j.cone_swing1, j.cone_swing2);
  return JointConeState{c.swing, c.swing_limit, c.twist};
}

void jointEulerAngles(const JointSpec& j, const JointBody& A, const JointBody& B, real out[3]) {
  const Frames f = frames(j, A, B);
  const EulerAngles e = eulerAngles(f.fa.q, f.fb.q, j.euler_order);
  for (int m = 0; m < 3; ++m) out[m] = e.angle[m];
}

void jointSpringForces(const JointSpec& j, const JointBody& A, const JointBody& B, Vec3* force, Vec3* torque) {
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
      // The hinge angle theta about axis a, or an Euler angle phi with d phi/dt = (wB - wA).g: the torque on B
      // is -(k (angle - eq) + c angle') times the angle's rate vector (the generalized force of the spring).
      Vec3 a = f.ea[s.dof - 3];
      real th = 0;
      if (j.ang == JointSpec::Angular::Euler) {
        const EulerAngles e = eulerAngles(f.fa.q, f.fb.q, j.euler_order);
        a = e.g[s.dof - 3];
        th = e.angle[s.dof - 3];
      } else {
        th = hingeTheta(j, f);
      }
      const real thd = dot(a, B.w - A.w);
      const Vec3 T = a * (-s.stiffness * (th - s.equilibrium) - s.damping * thd);
      if (B.index >= 0) torque[B.index] += T;
      if (A.index >= 0) torque[A.index] -= T;
    }
  }
}

}  // namespace dvi
