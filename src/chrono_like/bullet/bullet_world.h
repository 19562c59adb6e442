// The Bullet drop-in world: a btDiscreteDynamicsWorld whose sub-steps run the DVI System (CPU or GPU backend)
// instead of Bullet's narrow phase and sequential-impulse solver. An app switches by changing the line that
// constructs its world:
//
//   btDiscreteDynamicsWorld* world = new btDiscreteDynamicsWorld(dispatcher, broadphase, solver, config);
//   btDiscreteDynamicsWorld* world = new dvi::DviDynamicsWorld(dispatcher, broadphase, solver, config);
//
// How it fits into Bullet (the seam is internalSingleStepSimulation, as STYLE.md notes): Bullet's own
// stepSimulation still does the fixed sub-steps, maxSubSteps, the kinematic bodies' motion-state read
// (saveKinematicState), the motion-state interpolation (synchronizeMotionStates) and clearForces. Each
// sub-step here
//   1. calls the internal pre-tick callback;
//   2. brings the System up to date with Bullet: bodies added since (also inside tick callbacks), bodies
//      removed (the System is rebuilt from Bullet's state), poses and velocities the app set (compared with
//      what this world last wrote, so the System keeps its double-precision state otherwise), kinematic
//      poses and velocities, applied forces and torques, per-body gravity, damping (Bullet's rule,
//      v *= (1 - d)^h), friction, restitution, masses, 6-DoF spring forces;
//   3. steps the System (contacts and joints in one CCP, joints.h);
//   4. writes poses and velocities of the dynamic bodies back (setCenterOfMassTransform, so Bullet's
//      interpolation of motion states works), updates the broad-phase AABBs (rayTest, convexSweepTest and
//      contactTest see the new poses), fills the contact list and, optionally, Bullet's persistent manifolds;
//   5. runs the actions (btActionInterface) and the internal tick callback.
// Bullet's gravity force is not added to the bodies' total force (applyGravity is a no-op): the System
// applies each body's gravity itself. Sleeping is not used: every body is simulated every sub-step.
// docs/DROP_IN.md lists what works and what does not.
#pragma once

#include <BulletDynamics/Dynamics/btDiscreteDynamicsWorld.h>

#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "chrono_like/bullet/bullet_joints.h"
#include "chrono_like/system.h"

class btPersistentManifold;

namespace dvi {

// Auto: the GPU when one is usable, else the CPU. Gpu and Auto need DviWorldConfig's GPU functions.
enum class WorldBackend { Cpu, Gpu, Auto };

struct DviWorldConfig {
  WorldBackend backend = WorldBackend::Cpu;
  SystemConfig system;  // solver, threads, collision...; step.dt and step.gravity come from Bullet
  JointSettings joints;
  bool fill_manifolds = true;  // mirror the contacts into Bullet's persistent manifolds (dispatcher)
  // The GPU backend for WorldBackend::Gpu and Auto, given by the app (gpu/gpu_factory.h: dvi::makeGpuSystem and
  // dvi::gpuAvailable) so that the world does not depend on the GPU code. Gpu without make_gpu_system is refused
  // with an InputError; Auto without gpu_available runs on the CPU.
  std::unique_ptr<System> (*make_gpu_system)(const SystemConfig&, CollisionFactory) = nullptr;
  bool (*gpu_available)(std::string* why) = nullptr;
};

// A contact of the last sub-step, as the app reads it (DviDynamicsWorld::contacts()).
struct WorldContact {
  const btCollisionObject* a = nullptr;
  const btCollisionObject* b = nullptr;
  btVector3 point_a, point_b;   // world points on the surfaces of a and b
  btVector3 normal;             // unit, from a to b
  btScalar distance = 0;        // signed, negative = penetration
  btScalar normal_impulse = 0;  // over the sub-step, N s (force = impulse / sub-step)
};

class DviDynamicsWorld : public btDiscreteDynamicsWorld {
 public:
  // Same arguments as btDiscreteDynamicsWorld (the constraint solver is kept, unused), plus our config.
  DviDynamicsWorld(btDispatcher* dispatcher, btBroadphaseInterface* pairCache, btConstraintSolver* constraintSolver,
                   btCollisionConfiguration* collisionConfiguration, DviWorldConfig config = {});
  ~DviDynamicsWorld() override;

  // Bullet's API, kept: a body with a shape we cannot simulate is refused with an InputError naming it.
  void addRigidBody(btRigidBody* body) override;
  void addRigidBody(btRigidBody* body, int group, int mask) override;
  void removeRigidBody(btRigidBody* body) override;
  // Constraints become DVI rows (bullet_joints.h); a type or feature we cannot represent is refused with an
  // InputError naming it (never ignored).
  void addConstraint(btTypedConstraint* constraint, bool disableCollisionsBetweenLinkedBodies = false) override;
  void removeConstraint(btTypedConstraint* constraint) override;
  void applyGravity() override {}  // the System applies gravity (see above)

  // Our API.
  const std::vector<WorldContact>& contacts() const { return contacts_; }  // last sub-step's contacts
  System& system() { return *system_; }
  const System& system() const { return *system_; }
  int bodyIndex(const btRigidBody* body) const;  // System index, -1 if not (yet) in the System
  std::string backendName() const { return system_->backendName(); }
  int64_t subSteps() const { return substeps_; }
  // The solver's convergence over every sub-step so far (ConvergenceLog: steps that missed the tolerance,
  // the worst relative residual and its sub-step); the last sub-step's is system().lastStats().
  const ConvergenceLog& convergence() const { return convergence_; }
  double simulatedTime() const { return sim_time_; }
  // Largest joint violation now: linear relative to the smaller body size, angular in radians.
  JointViolation maxJointViolation() const { return joints_->maxViolation(system_->bodies()); }
  const DviWorldConfig& dviConfig() const { return config_; }

 protected:
  void internalSingleStepSimulation(btScalar timeStep) override;

 private:
  struct Tracked {
    btRigidBody* body;
    btTransform tf;  // what this world last wrote (or read)
    btVector3 v, w;
    const btCollisionShape* shape;
    int group, mask, kind;  // kind: 0 dynamic, kBodyFixed, kBodyKinematic
  };
  std::unique_ptr<System> makeSystem() const;
  void rebuild();
  void addToSystem(btRigidBody* body);
  void syncIn(btScalar h);
  void syncOut();
  void collectContacts();
  void releaseManifolds();
  bool keepPair(int a, int b) const;

  DviWorldConfig config_;
  std::unique_ptr<System> system_;
  std::shared_ptr<BulletJoints> joints_;
  std::unordered_map<const btRigidBody*, int> index_;
  std::vector<Tracked> tracked_;       // in System order
  std::vector<btRigidBody*> pending_;  // added since the last sub-step
  bool rebuild_ = false;
  bool has_exclusions_ = false;  // some constraint disables collisions between its bodies
  std::vector<WorldContact> contacts_;
  std::vector<btPersistentManifold*> manifolds_;
  int64_t substeps_ = 0;
  ConvergenceLog convergence_;  // kept across rebuilds of the System
  double sim_time_ = 0;
};

}  // namespace dvi
