// Joints as DVI constraint rows (constraint_row.h): a JointSpec and the rows, violations and spring forces it gives at
// the bodies' states. The Bullet drop-in world reads its constraints into JointSpecs (bullet/bullet_joints.h).
//
// A JointSpec holds two joint frames (one per body, in the body's centre-of-mass frame), a mode per linear axis of
// frame A (free / locked at a value / limited to [lo, hi]) and an angular mode (orientation locked, a hinge about one
// axis of frame A, free, a cone-twist, or three Euler angles), plus the hinge's limit and motor, the slider's linear
// motor and springs. The spec gives the rows:
//   linear axis e of frame A, d = pB - pA (frame origins), s = e.d:
//       J v = e.(vB + wB x rB) - e.(vA + wA x (pB - xA)) = ds/dt      (A-fixed axis: exact derivative)
//   locked orientation: qe = qFB conj(qFA), theta = rotation vector of qe;
//       rows along world x, y, z: J v = (wB - wA).e = d(theta.e)/dt
//   hinge about axis a (frame A) with b = the same axis of frame B: rows along the two other axes e of A,
//       C = e.(a x b), J v = (wB - wA).e; the hinge angle theta (B relative to A about a) has
//       d theta/dt = (wB - wA).a, which carries the limit rows (unilateral) and the motor (a rheonomic row
//       J v = target with impulse bounds +-max impulse).
//   cone-twist (joint_angles.h, Bullet's btConeTwistConstraint): unilateral rows C = (1 - F) / |g| >= 0 on the
//       elliptic swing cone, psi + twist >= 0 and twist - psi >= 0 on the twist, J v = (wB - wA).g with g the
//       angle's rate vector; a swing span below Bullet's fix threshold locks that swing (bilateral row on u.y or u.z).
//   Euler angles phi (joint_angles.h, Bullet's 6-DoF angles in its rotate order), per angle: locked (bilateral
//       phi = lo), limited (unilateral phi - lo >= 0, hi - phi >= 0), and a motor J v = d phi/dt = target with
//       impulse bounds +-max force x h.
// Bilateral rows have bias = C / h, clamped to a recovery speed relative to the body size; unilateral rows
// allow any approach speed (bias = C / h when C > 0). Sign conventions relative to Bullet (hinge angle,
// motor velocities) are those of Bullet's own getHingeAngle and solver and are checked by the tests.
#pragma once

#include <cstdint>
#include <vector>

#include "chrono_like/base/math.h"
#include "chrono_like/solver/constraint_row.h"

class btRigidBody;  // a joint's bodies are known by their Bullet handles (bullet/bullet_joints.h reads them)

namespace dvi {

struct JointSpec {
  enum class Axis : uint8_t { Free, Locked, Limited };
  enum class Angular : uint8_t { Locked, Hinge, Free, ConeTwist, Euler };

  const btRigidBody* a = nullptr;
  const btRigidBody* b = nullptr;
  Pose frame_a{{0, 0, 0}, {1, 0, 0, 0}};  // joint frames in each body's centre-of-mass frame
  Pose frame_b{{0, 0, 0}, {1, 0, 0, 0}};
  Axis lin[3] = {Axis::Free, Axis::Free, Axis::Free};
  real lin_lo[3] = {0, 0, 0}, lin_hi[3] = {0, 0, 0};
  Angular ang = Angular::Free;
  int hinge_axis = 2;  // axis of frame A (0 x, 1 y, 2 z) for Angular::Hinge
  bool hinge_limit = false;
  real hinge_lo = 0, hinge_hi = 0;  // on theta (B relative to A about the axis, right-handed)
  bool hinge_motor = false;
  real hinge_motor_velocity = 0;     // d theta/dt
  real hinge_motor_max_impulse = 0;  // per step (Bullet's hinge)
  real hinge_motor_max_force = 0;    // or a force: the bound is max_impulse + max_force h (a hinge-like 6-DoF)
  // Angular::ConeTwist: the swing of frame A's x axis seen from frame B inside the ellipse of half-axes swing1
  // (swing about z) and swing2 (about y), the twist about x within +-twist (joint_angles.h).
  bool cone_swing_limit = false;
  real cone_swing1 = 0, cone_swing2 = 0;
  bool cone_lock1 = false, cone_lock2 = false;  // swing about z (u.y = 0) or about y (u.z = 0) locked
  bool cone_twist_limit = false;
  real cone_twist = 0;
  // Bullet's cone-twist motor (enableMotor, setMotorTarget): a servo of frame A towards the orientation
  // qFB * cone_motor_target, one unilateral row about the rotation left, J v = (wA - wB).axis >= bias x angle / h
  // with 0 <= impulse <= max impulse; as in Bullet the limits are off while the motor is on.
  bool cone_motor = false;
  Quat cone_motor_target{1, 0, 0, 0};  // frame A relative to frame B (constraint space)
  real cone_motor_max_impulse = 0;     // per step (infinite where Bullet's is negative)
  real cone_motor_bias = real(0.3);    // Bullet's bias factor: the fraction of the angle corrected per step
  // Angular::Euler: Bullet's 6-DoF angles of A relative to B in the rotate order euler_order (joint_angles.h),
  // each free, locked at lo or limited to [lo, hi], with an optional motor (d phi/dt = velocity, |torque| <= force).
  struct EulerAxis {
    Axis mode = Axis::Free;
    real lo = 0, hi = 0;
    bool motor = false;
    real motor_velocity = 0, motor_max_force = 0;
  };
  int euler_order[3] = {0, 1, 2};
  EulerAxis euler[3];
  bool lin_motor = false;  // along axis 0 of frame A
  real lin_motor_velocity = 0, lin_motor_max_force = 0;
  struct Spring {
    int dof;  // 0..2 linear axis of frame A, 3..5 rotation about that axis (the hinge axis, or an Euler angle)
    real stiffness, damping, equilibrium;
  };
  std::vector<Spring> springs;
  const char* kind = "";
};

struct JointSettings {
  real recovery_rel = real(10);          // bilateral rows correct at most recovery_rel x size per second (linear)
  real max_recovery_angular = real(10);  // and this many radians per second
  bool drift_feedforward = true;         // add the second-order drift of linear rows to their bias (joints.cpp)
};

// World pose and body index of one side of a joint.
struct JointBody {
  int index = -1;  // system body index; -1 for a body not in the system (Bullet's fixed body)
  Vec3 x{0, 0, 0};
  Quat q{1, 0, 0, 0};
  Vec3 v{0, 0, 0}, w{0, 0, 0};
  real size = 1;
};

// Rows of one joint at the given body states (appended to out). Exposed for the Jacobian tests.
void jointRows(const JointSpec& j, const JointBody& A, const JointBody& B, real dt, const JointSettings& s,
               std::vector<ConstraintRow>& out);

// Position-level violations of a joint's bilateral parts at the given states: the largest linear error
// (length) and the largest angular error (radians).
struct JointViolation {
  real linear = 0, angular = 0;
};
JointViolation jointViolation(const JointSpec& j, const JointBody& A, const JointBody& B);

// The hinge angle theta (B relative to A about the hinge axis), radians in (-pi, pi].
real jointHingeAngle(const JointSpec& j, const JointBody& A, const JointBody& B);

// The swing angle, its limit in the swing's direction and the twist of a cone-twist joint (radians).
struct JointConeState {
  real swing = 0, swing_limit = 0, twist = 0;
};
JointConeState jointConeState(const JointSpec& j, const JointBody& A, const JointBody& B);

// Bullet's 6-DoF angles (getAngle(0..2)) of a joint in Euler mode.
void jointEulerAngles(const JointSpec& j, const JointBody& A, const JointBody& B, real out[3]);

// Forces and torques of the joint's springs at the given states, added to force/torque (system body indices; a side
// with index -1 gets none).
void jointSpringForces(const JointSpec& j, const JointBody& A, const JointBody& B, Vec3* force, Vec3* torque);

}  // namespace dvi
