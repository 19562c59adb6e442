// Bullet constraints as DVI constraint rows: the joints of the Bullet drop-in world. Every supported
// btTypedConstraint is read, each step, into a JointSpec (joints.h: its frames, axis modes and rows).
//
// Supported (anything else is refused by jointSpecFromBullet with an InputError naming the type or the
// feature): point-to-point; hinge with limit and angular motor; cone-twist (btConeTwistConstraint: the pivot, the
// elliptic swing cone of swingSpan1/swingSpan2 and the twist span as unilateral rows, in Bullet's definitions of
// swing and twist; limits at span x softness as in Bullet; a span below Bullet's fix threshold locks that swing;
// angular-only; the motor towards setMotorTarget as Bullet's servo row); slider with linear limits, linear motor
// and locked or free rotation; fixed; generic 6-DoF (btGeneric6DofConstraint, btGeneric6DofSpringConstraint,
// btGeneric6DofSpring2Constraint) with locked, free or limited linear axes and, per rotational axis, locked (at
// any angle), free or limited to [lo, hi] in Bullet's Euler angles (XYZ, or the rotate order of Spring2), angular
// motors (target velocity, max motor force), springs on free linear axes and on free or limited rotational axes.
// Refused: gear and contact constraints, linear 6-DoF motors, Spring2 servo motors, angular limit ranges and
// angular motors of a slider. Bullet's softness parameters with no meaning for the DVI rows (ERP/bias factors,
// CFM, the cone-twist's relaxation factor and damping, 6-DoF bounce and Bullet's motor factor near limits) are
// not used (docs/DROP_IN.md).
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

  // Spring forces of the 6-DoF springs, added to force/torque (system body indices).
  void springForces(const BodyArrays& bodies, Vec3* force, Vec3* torque) const;

  // State of one side of constraint c's joint from the system's arrays.
  JointBody side(const BodyArrays& bodies, const btRigidBody* body) const;
  // Largest violation over all enabled joints (linear relative to the smaller body size, angular in rad).
  JointViolation maxViolation(const BodyArrays& bodies) const;

 private:
  const std::unordered_map<const btRigidBody*, int>* index_;
  JointSettings settings_;
  std::vector<btTypedConstraint*> joints_;
  std::vector<int> row_joint_;  // joint of each row of the last step
};

}  // namespace dvi
