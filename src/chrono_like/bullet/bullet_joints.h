// Bullet constraints as DVI constraint rows: the joints of the Bullet drop-in world. Every supported
// btTypedConstraint is read, each step, into a JointSpec (joints.h: its frames, axis modes and rows).
//
// Supported (anything else is refused by jointSpecFromBullet with an InputError naming the type): point-to-point
// (rows along world x, y, z, as Bullet's); hinge with limit (lo == hi locks it; past the limit the row recovers at
// ERP x bias factor, as Bullet's; no bounce, as stock Bullet's hinges hardly bounce), angular motor; hinge2
// (a Spring2); cone-twist (btConeTwistConstraint: the pivot, the elliptic swing cone of swingSpan1/swingSpan2 and
// the twist span as unilateral rows, in Bullet's definitions of swing and twist; limits at span x softness as in
// Bullet; a span below Bullet's fix threshold locks that swing; angular-only; the motor towards setMotorTarget as
// Bullet's servo row); slider with linear limits and motor, the rotation about its axis free, limited, locked at
// any angle (its limit bouncing |1 - dampingLimAng|) or driven by its angular motor; gear (btGearConstraint: one velocity row); fixed; generic 6-DoF
// (btGeneric6DofConstraint, btGeneric6DofSpringConstraint, btGeneric6DofSpring2Constraint) with locked, free or
// limited linear axes and, per rotational axis, locked (at any angle), free or limited to [lo, hi] in Bullet's Euler
// angles (XYZ, or the rotate order of Spring2), velocity motors and Spring2 servo motors on every axis, limit bounce
// and stop ERP per axis, springs on free or limited axes. Every joint: Bullet's ERP for large errors (joints.h),
// breaking thresholds (each row bounded by the threshold; a row at it breaks the joint), btJointFeedback and
// getAppliedImpulse as Bullet's solver fills them. Not modelled (docs/DROP_IN.md): CFM (setParam's CFM and stop
// CFM; our rows are hard), the cone-twist's relaxation factor and damping, the hinge's limit softness (unused by
// Bullet's solver too), the damping of btGeneric6DofSpringConstraint, and Bullet's motor factor that slows a
// velocity motor near a limit.
#pragma once

#include <string>
#include <unordered_map>
#include <vector>

#include "chrono_like/solver/joints.h"

class btRigidBody;
class btTypedConstraint;

namespace dvi {

// Reads a Bullet constraint; throws InputError naming the constraint type or the unsupported feature.
JointSpec jointSpecFromBullet(const btTypedConstraint& c);

// Name of a Bullet constraint type (btTypedConstraintType), e.g. "cone-twist (btConeTwistConstraint)".
std::string constraintTypeName(int type);

// The joints of a drop-in world: a RowProvider over Bullet constraints. Bodies are found through the
// world's map from btRigidBody to system index; bodies outside the system (Bullet's fixed body) are the
// ground.
class BulletJoints final : public RowProvider {
 public:
  explicit BulletJoints(const std::unordered_map<const btRigidBody*, int>* index, JointSettings s = {})
      : index_(index), settings_(s) {}

  void add(btTypedConstraint* c);  // validates (jointSpecFromBullet)
  void remove(btTypedConstraint* c);
  size_t size() const { return joints_.size(); }
  const std::vector<btTypedConstraint*>& constraints() const { return joints_; }

  void rows(const BodyArrays& bodies, const StepContext& step, std::vector<ConstraintRow>& out) override;
  void impulses(const real* lambda, size_t count) override;

  // Bullet's ERP (btContactSolverInfo::m_erp), read by the world each sub-step: the rate at which large joint
  // errors close (joints.h).
  void setErp(real erp) { settings_.erp = erp; }

  // Spring forces of the 6-DoF springs over a step h, added to force/torque (system body indices).
  void springForces(const BodyArrays& bodies, real h, Vec3* force, Vec3* torque) const;

  // State of one side of constraint c's joint from the system's arrays.
  JointBody side(const BodyArrays& bodies, const btRigidBody* body) const;
  // Largest violation over all enabled joints (linear relative to the smaller body size, angular in rad).
  JointViolation maxViolation(const BodyArrays& bodies) const;

 private:
  const std::unordered_map<const btRigidBody*, int>* index_;
  JointSettings settings_;
  std::vector<btTypedConstraint*> joints_;
  std::vector<int> row_joint_;       // joint of each row of the last step
  std::vector<ConstraintRow> rows_;  // and the rows (their Jacobians give Bullet's joint feedback)
  real dt_ = 0;
};

}  // namespace dvi
