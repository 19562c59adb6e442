// Joints as DVI constraint rows (constraint_row.h): a JointSpec and the rows, violations and spring forces it gives at
// the bodies' states. The Bullet drop-in world reads its constraints into JointSpecs (bullet/bullet_joints.h).
//
// A JointSpec holds two joint frames (one per body, in the body's centre-of-mass frame), a mode per linear axis of
// frame A (free / locked at a value / limited to [lo, hi]) and an angular mode (orientation locked, a hinge about one
// axis of frame A, free, a cone-twist, or three Euler angles), plus limits, motors, servos and springs per axis and a
// gear row. The spec gives the rows:
//   linear axis e of frame A, d = pB - pA (frame origins), s = e.d:
//       J v = e.(vB + wB x rB) - e.(vA + wA x (pB - xA)) = ds/dt      (A-fixed axis: exact derivative)
//   or, with world_axes (Bullet's point-to-point), e a world axis: J v = e.(vB + wB x rB) - e.(vA + wA x rA)
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
//   gear (Bullet's btGearConstraint): one bilateral velocity row J v = wA.aA + ratio wB.aB = 0 (no position error).
// Bilateral rows correct the error C: bias = C / h while that is below a recovery speed relative to the body size
// (JointSettings), at least erp x C / h beyond it (Bullet's ERP: a large error closes by the fraction erp per step,
// with no speed cap); unilateral rows allow any approach speed (bias = C / h when C > 0) and recover past the limit
// the same way. A limit with restitution e (Bullet's bounce) whose row would be crossed within the step asks for
// J v >= -e J v0 (v0: the velocities at the start of the step), as Bullet's limit rows do. A servo (Bullet's
// Spring2 servo motor) is a motor row whose target speed is toward the servo target, min(|v|, erp |error| / h).
// Sign conventions relative to Bullet (hinge angle, motor velocities) are those of Bullet's own getHingeAngle and
// solver and are checked by the tests.
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
  real hinge_motor_velocity = 0;     // d theta/dt (a servo: its speed |v|)
  real hinge_motor_max_impulse = 0;  // per step (Bullet's hinge)
  real hinge_motor_max_force = 0;    // or a force: the bound is max_impulse + max_force h (a hinge-like 6-DoF)
  bool hinge_servo = false;          // the motor drives theta toward hinge_servo_target (a hinge-like Spring2 servo)
  real hinge_servo_target = 0, hinge_motor_erp = -1;  // < 0: the joint's erp
  real hinge_bounce = 0;                              // restitution of the limit rows
  real hinge_stop_erp = -1;                           // recovery past the limit (< 0: the joint's erp)
  real hinge_limit_bias = 1;                          // times this (Bullet's hinge limit bias factor)
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
    bool servo = false;  // the motor drives the angle toward servo_target at speed |motor_velocity| at most
    real servo_target = 0, motor_erp = -1;  // < 0: the joint's erp
    real bounce = 0, stop_erp = -1;         // the limit rows' restitution and recovery (< 0: the joint's erp)
  };
  int euler_order[3] = {0, 1, 2};
  EulerAxis euler[3];
  // A motor along a linear axis of frame A (the slider's on axis 0, a 6-DoF's on any): d s/dt = velocity with
  // |impulse| <= max_force h, or a servo toward servo_target.
  struct LinearMotor {
    bool on = false;
    real velocity = 0, max_force = 0;
    bool servo = false;
    real servo_target = 0, motor_erp = -1;  // < 0: the joint's erp
  };
  LinearMotor lin_motor[3];
  real lin_bounce[3] = {0, 0, 0};
  real lin_stop_erp[3] = {-1, -1, -1};
  real erp = -1;            // Bullet's ERP for this joint's bilateral rows (< 0: JointSettings::erp)
  bool world_axes = false;  // linear rows along world x, y, z at this step (Bullet's point-to-point), not frame A's
  bool gear = false;        // Bullet's gear: J v = wA.gear_axis_a + gear_ratio wB.gear_axis_b = 0
  Vec3 gear_axis_a{0, 0, 1}, gear_axis_b{0, 0, 1};  // in each body's centre-of-mass frame
  real gear_ratio = 1;
  struct Spring {
    int dof;  // 0..2 linear axis of frame A, 3..5 rotation about that axis (the hinge axis, or an Euler angle)
    real stiffness, damping, equilibrium;
    // Bullet's Spring2 limits (setStiffness/setDamping with limitIfNeeded): stiffness at most m / (16 h^2) (a quarter
    // of the angular frequency per step), damping at most m / h, m the joint's effective mass (BulletJoints).
    bool limit_stiffness = false, limit_damping = false;
  };
  std::vector<Spring> springs;
  const char* kind = "";
};

struct JointSettings {
  real recovery_rel = real(10);          // bilateral rows correct at least recovery_rel x size per second (linear)
  real max_recovery_angular = real(10);  // and this many radians per second, or the whole error where it is smaller,
  real erp = real(0.2);                  // and at least erp x the error per step (Bullet's m_erp; the world sets it)
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
