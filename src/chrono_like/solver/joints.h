// Joints as DVI constraint rows (constraint_row.h): a JointSpec and the rows, violations and spring forces it gives at
// the bodies' states. The Bullet drop-in world reads its constraints into JointSpecs (bullet/bullet_joints.h).
//
// A JointSpec holds two joint frames (one per body, in the body's centre-of-mass frame), a mode per linear axis of
// frame A (free / locked at a value / limited to [lo, hi]) and an angular mode (orientation locked, a hinge about one
// axis of frame A, or free), plus the hinge's limit and motor, the slider's linear motor and springs. The spec gives
// the rows:
//   linear axis e of frame A, d = pB - pA (frame origins), s = e.d:
//       J v = e.(vB + wB x rB) - e.(vA + wA x (pB - xA)) = ds/dt      (A-fixed axis: exact derivative)
//   locked orientation: qe = qFB conj(qFA), theta = rotation vector of qe;
//       rows along world x, y, z: J v = (wB - wA).e = d(theta.e)/dt
//   hinge about axis a (frame A) with b = the same axis of frame B: rows along the two other axes e of A,
//       C = e.(a x b), J v = (wB - wA).e; the hinge angle theta (B relative to A about a) has
//       d theta/dt = (wB - wA).a, which carries the limit rows (unilateral) and the motor (a rheonomic row
//       J v = target with impulse bounds +-max impulse).
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
  enum class Angular : uint8_t { Locked, Hinge, Free };

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
  real hinge_motor_max_impulse = 0;  // per step
  bool lin_motor = false;            // along axis 0 of frame A
  real lin_motor_velocity = 0, lin_motor_max_force = 0;
  struct Spring {
    int dof;  // 0..2 linear axis of frame A, 3..5 rotation about that axis (the hinge axis only)
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

// Forces and torques of the joint's springs at the given states, added to force/torque (system body indices; a side
// with index -1 gets none).
void jointSpringForces(const JointSpec& j, const JointBody& A, const JointBody& B, Vec3* force, Vec3* torque);

}  // namespace dvi
