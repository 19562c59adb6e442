// The Bullet drop-in world: a btDiscreteDynamicsWorld whose sub-steps run the DVI System (CPU or GPU backend)
// instead of Bullet's narrow phase and sequential-impulse solver. An app switches by changing the line that
// constructs its world:
//
//   btDiscreteDynamicsWorld* world = new btDiscreteDynamicsWorld(dispatcher, broadphase, solver, config);
//   btDiscreteDynamicsWorld* world = new dvi::DviDynamicsWorld(dispatcher, broadphase, solver, config);
//
// How it fits into Bullet (the seam is internalSingleStepSimulation): Bullet's own stepSimulation still does the
// fixed sub-steps, maxSubSteps, the kinematic bodies' motion-state read (saveKinematicState), the motion-state
// interpolation (synchronizeMotionStates) and clearForces. Each sub-step here
//   1. calls the internal pre-tick callback;
//   2. brings the System up to date with Bullet: objects added since (also inside tick callbacks), objects
//      removed (the System is rebuilt from Bullet's state), poses and velocities the app set (compared with
//      what this world last wrote, so the System keeps its double-precision state otherwise), kinematic
//      poses and velocities, applied forces and torques, per-body gravity, damping (Bullet's rule,
//      v *= (1 - d)^h), friction, restitution, masses, 6-DoF spring forces, linear and angular factors;
//   3. steps the System (contacts, joints and factor rows in one CCP, joints.h);
//   4. writes poses and velocities of the dynamic bodies back (setCenterOfMassTransform, so Bullet's
//      interpolation of motion states works), updates the broad-phase AABBs (rayTest, convexSweepTest and
//      contactTest see the new poses), computes the overlapping pairs when ghost objects need them, fills the
//      contact list and, optionally, Bullet's persistent manifolds;
//   5. runs the actions (btActionInterface) and the internal tick callback.
// Objects: rigid bodies (dynamic, static, kinematic), plain btCollisionObjects (static geometry: fixed bodies
// of the System, moved when the app moves them) and ghost objects (not simulated; Bullet's pair cache keeps
// their overlaps). Collision groups and masks are Bullet's 32-bit ones: the group bits in use are renumbered
// onto the System's 16 (exact while at most 16 distinct group bits are in use; beyond that folded, and the
// exact test is applied to each contact on the CPU backend).
// Bullet's gravity force is not added to the bodies' total force (applyGravity is a no-op): the System
// applies each body's gravity itself. A body whose activation state is DISABLE_SIMULATION is held as a fixed
// body. Sleeping follows Bullet: each body's own thresholds and deactivation time (btRigidBody::updateDeactivation,
// wantsSleeping), islands of bodies joined by broad-phase pairs (Bullet's rule), contacts and constraints fall asleep
// together and wake together; a sleeping body stays in the System, held still (no mass, no gravity) until its island
// wakes.
// docs/DROP_IN.md lists what works and what does not.
#pragma once

#include <BulletDynamics/Dynamics/btDiscreteDynamicsWorld.h>

#include <array>
#include <memory>
#include <string>
#include <atomic>
#include <unordered_map>
#include <vector>

#include "chrono_like/bullet/bullet_joints.h"
#include "chrono_like/system.h"

class btPersistentManifold;

namespace dvi {

class FactorRows;  // bullet_world.cpp: the rows of the bodies' linear and angular factors

// Auto: the GPU when one is usable, else the CPU. Gpu and Auto need DviWorldConfig's GPU functions.
enum class WorldBackend { Cpu, Gpu, Auto };

// How much work each sub-step's solve does (docs/DROP_IN.md, "Solver effort", measures both on Bullet's scenes).
enum class SolverEffort {
  // Bullet's effort as the minimum, then on to the tolerance: projected Gauss-Seidel (as BulletIterations below,
  // each contact's normal and friction impulses first stepped exactly, as Bullet's rows are) for at least
  // m_numIterations sweeps, continued while the relative residual is above SystemConfig::solver.tolerance (0.15),
  // or the joint rows' own relative residual above 0.01 (SolverSettings::gs_row_tolerance), checked every few
  // sweeps, up to DviWorldConfig::bullet_max_sweeps; a sub-step still above the tolerance there is finished by APGD
  // (SolverSettings::gs_apgd_finish). Costs Bullet's effort where Bullet's sweeps already converge and more only
  // where they do not. The GPU backend runs APGD with the same minimum, tolerance and cap. Not the default yet:
  // docs/DROP_IN.md, "Solver effort", lists the checks it still fails.
  BulletThenConverged,
  // The default. SystemConfig::solver as given (default: APGD to the relative tolerance 0.15, at least 50
  // iterations), and on to the relative tolerance 0.003 where a joint row would still move more than 1 mm (1 mrad)
  // in the step (SolverSettings::row_stop, CPU backend): every step converged, far below the tolerance on small
  // problems; Bullet's iteration count is not used.
  Converged,
  // Bullet's effort, read from the world's btContactSolverInfo (getSolverInfo()) each sub-step: projected
  // Gauss-Seidel (the method of Bullet's sequential impulses, on our cone-complementarity problem) for
  // m_numIterations sweeps, relaxation m_sor, warm start while m_warmstartingFactor > 0. No convergence test: as
  // fast as Bullet and as converged as Bullet.
  BulletIterations,
};

// The System's defaults for the drop-in world: SystemConfig's, but
//  - MPR's temporal coherence off (CollisionSettings::mpr_coherence): on Bullet's example scenes, whose bodies sink
//    deeper into each other than a granular flow's, keeping last step's face moved the resting piles of Planar2D and
//    RollingFrictionDemo 3-13 cm further from stock Bullet's than the full search every step does
//    (test_bullet_examples_world.cpp);
//  - the joint-row stop (SolverSettings::row_stop) at 1 mm: the solve goes on where a joint would drift more than
//    that in the step, as ConstraintDemo's door and Dof6Spring2Setup's pulled chain do at the relative tolerance alone.
inline SystemConfig dropInSystemDefaults() {
  SystemConfig c;
  c.collision.mpr_coherence = false;
  c.solver.row_stop = real(1e-3);
  return c;
}

struct DviWorldConfig {
  WorldBackend backend = WorldBackend::Cpu;
  SolverEffort effort = SolverEffort::Converged;
  // BulletThenConverged: at most this many Gauss-Seidel sweeps a sub-step before APGD finishes it (0: 3 x
  // btContactSolverInfo::m_numIterations).
  int bullet_max_sweeps = 0;
  SystemConfig system = dropInSystemDefaults();  // solver, threads, collision...; step.dt and gravity from Bullet
  JointSettings joints;
  bool fill_manifolds = true;  // mirror the contacts into Bullet's persistent manifolds (dispatcher)
  // The world's own per-body and per-contact loops (state in and out, sleeping, AABBs, manifolds) run on the
  // System's threads from this many bodies or contacts on; fewer run on one thread (the team costs more than it
  // saves). The results do not depend on it.
  int64_t parallel_min = 4096;
  int host_threads = 0;  // threads of those loops; 0: the System's team (SystemConfig::threads, or its governor's)
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
  // A plain btCollisionObject is static geometry (a fixed body); a ghost object only takes part in Bullet's pair
  // cache; other object types (soft bodies, multibody links) are refused with an InputError.
  void addCollisionObject(btCollisionObject* object, int group = btBroadphaseProxy::StaticFilter,
                          int mask = btBroadphaseProxy::AllFilter ^ btBroadphaseProxy::StaticFilter) override;
  void removeCollisionObject(btCollisionObject* object) override;
  void removeConstraint(btTypedConstraint* constraint) override;
  void applyGravity() override {}  // the System applies gravity (see above)
  // Bullet's own per-object loops, with the same results, in parallel where Bullet's objects allow it (a large world
  // spent most of its host time in them): AABBs into the broad phase, motion states, forces cleared.
  void updateAabbs() override;
  void synchronizeMotionStates() override;
  void clearForces() override;

  // Our API.
  // The last sub-step's contacts, made from the System's on the first call after a sub-step (an app that does not
  // read them does not pay for them). Not for concurrent calls, as the rest of a Bullet world.
  const std::vector<WorldContact>& contacts() const;
  System& system() { return *system_; }
  const System& system() const { return *system_; }
  int bodyIndex(const btRigidBody* body) const;         // System index, -1 if not (yet) in the System
  int objectIndex(const btCollisionObject* obj) const;  // the same for any object (plain collision objects too)
  std::string backendName() const { return system_->backendName(); }
  int64_t subSteps() const { return substeps_; }
  // The solver's convergence over every sub-step so far (ConvergenceLog: steps that missed the tolerance,
  // the worst relative residual and its sub-step); the last sub-step's is system().lastStats().
  const ConvergenceLog& convergence() const { return convergence_; }
  // Wall time of the parts of each sub-step (internalSingleStepSimulation), summed since the last reset: what the
  // drop-in costs around the System's step.
  struct PhaseTimes {
    double sync_in = 0;   // [s] Bullet's state into the System's arrays (syncIn: bodies, joints' springs, exclusions)
    double step = 0;      // [s] the System's step and its syncToHost (a device backend's copies back)
    double sync_out = 0;  // [s] the System's state into Bullet's bodies, sleeping, AABBs, ghost pairs (all three)
    double sleeping = 0;  // [s]   of which sleeping (updateSleeping)
    double aabbs = 0;     // [s]   of which Bullet's AABBs and ghost pairs (updateAabbs)
    double contacts = 0;  // [s] Bullet's manifolds and contacts() filled from the System's contacts
    std::array<double, kStageCount> stages{};  // [s] the System's own stage times within `step` (StepStats)
    int64_t substeps = 0;
  };
  const PhaseTimes& phaseTimes() const { return phase_times_; }
  void resetPhaseTimes() { phase_times_ = PhaseTimes{}; }
  double simulatedTime() const { return sim_time_; }
  // Largest joint violation now: linear relative to the smaller body size, angular in radians.
  JointViolation maxJointViolation() const { return joints_->maxViolation(system_->bodies()); }
  const DviWorldConfig& dviConfig() const { return config_; }

 protected:
  void internalSingleStepSimulation(btScalar timeStep) override;
  void saveKinematicState(btScalar timeStep) override;  // Bullet's, with the kinematic bodies found in parallel

 private:
  struct Tracked {
    btCollisionObject* obj;  // null once removed (compacted at the next sub-step)
    btRigidBody* body;       // null for a plain collision object
    btTransform tf;          // what this world last wrote (or read)
    btVector3 v, w;
    const btCollisionShape* shape;
    int group, mask, kind;  // kind: 0 dynamic, kBodyFixed, kBodyKinematic
  };
  std::unique_ptr<System> makeSystem() const;
  void rebuild();
  void addToSystem(btCollisionObject* obj);
  void refuseUnsupported(const char* api, const btCollisionObject& obj) const;
  void forget(btCollisionObject* obj);
  bool structureChanged() const;
  // syncBody's answer: what it changed in the System's arrays, and whether the body has factors other than 1.
  static constexpr uint8_t kChangedState = 1, kChangedParams = 2, kHasFactors = 4;
  struct ManifoldSlot {  // a body pair's Bullet manifold, and the sub-step that last filled it
    btPersistentManifold* manifold = nullptr;
    int64_t used = -1;
  };
  struct Run {  // contacts [begin, end) of the System's list, of one body pair
    int64_t begin, end;
    ManifoldSlot* slot;  // filled in parallel when set
  };
  static uint64_t pairKey(int a, int b) { return (uint64_t(uint32_t(a)) << 32) | uint32_t(b); }
  void syncIn(btScalar h);
  void applyBulletEffort(SolverSettings& s) const;  // SolverEffort::BulletIterations and BulletThenConverged
  uint8_t syncBody(size_t i, btScalar h, BodyArrays& B);
  void syncFactors(size_t i, BodyArrays& B);
  void uploadChanges();
  int hostThreads() const;
  void holdLockedAxes(btScalar h);
  void syncOut();
  void updateSleeping(btScalar h);
  void buildIslands(int team);
  void sleepOrWakeIslands(int team);
  void wakeTouchedByKinematic();
  void collectContacts();
  void buildWorldContacts() const;
  bool tracksPair(int ia, int ib) const;
  btScalar normalImpulse(int64_t k) const;
  void fillManifolds();
  ManifoldSlot& manifoldSlot(int ia, int ib);
  bool fillManifold(ManifoldSlot& slot, int64_t k);
  void releaseManifolds();
  bool keepPair(int a, int b) const;
  // The System's contact exclusions (System::setContactExclusions) from Bullet's per-object ignore lists (constraints
  // made with disableCollisionsBetweenLinkedBodies) and CF_NO_CONTACT_RESPONSE; sent when they change.
  void updateExclusions();
  void noteFilter(int group);
  int16_t mapFilter(int bits) const;

  DviWorldConfig config_;
  std::unique_ptr<System> system_;
  std::shared_ptr<BulletJoints> joints_;
  std::shared_ptr<FactorRows> factors_;
  std::unordered_map<const btRigidBody*, int> index_;               // rigid bodies (the joints read it)
  std::unordered_map<const btCollisionObject*, int> object_index_;  // every simulated object
  std::vector<Tracked> tracked_;                                    // in System order
  std::vector<btCollisionObject*> pending_;                         // added since the last sub-step
  bool rebuild_ = false;
  bool has_exclusions_ = false;                          // some constraint disables collisions between its bodies
  std::vector<std::pair<int32_t, int32_t>> excl_pairs_;  // the exclusions last sent to excl_system_
  std::vector<uint8_t> excl_flags_;
  std::vector<std::pair<int32_t, int32_t>> excl_pairs_next_;  // updateExclusions' scratch (no allocation per sub-step)
  std::vector<uint8_t> excl_flags_next_;
  const System* excl_system_ = nullptr;
  int ghosts_ = 0;               // ghost objects in the world: Bullet's pair cache is computed each sub-step
  std::vector<int> group_bits_;  // Bullet group bit positions in use, in order of appearance (their System bit)
  bool folded_filters_ = false;  // more than 16 group bits in use: folded, exact test per contact (CPU)
  std::vector<std::atomic<int>> island_root_;  // updateSleeping's union-find over the bodies
  std::vector<int> island_of_;                 // and each body's island
  std::vector<char> island_merges_;  // whether a body joins islands (btCollisionObject::mergesSimulationIslands)
  std::vector<char> island_awake_;   // and its islands that stay awake
  std::vector<uint8_t> changes_;     // syncIn: syncBody's answer per body
  std::vector<Vec3> rolling_aniso_;  // per body: Bullet's anisotropic rolling friction factors, (1, 1, 1) for none
  std::vector<int32_t> dirty_state_, dirty_params_;  // uploadChanges' lists
  std::vector<btVector3> aabb_lo_, aabb_hi_;         // updateAabbs' boxes
  std::vector<char> object_flags_;                   // per Bullet object: scratch of the loops over m_collisionObjects
  mutable std::vector<WorldContact> contacts_;       // contacts(), made on demand
  mutable bool contacts_current_ = true;             // contacts_ holds the last sub-step's contacts (or none)
  std::vector<Run> runs_;                            // fillManifolds' runs of one body pair
  std::unordered_map<uint64_t, ManifoldSlot> manifolds_;  // by (a, b) System indices, kept across steps
  int64_t substeps_ = 0;
  ConvergenceLog convergence_;  // kept across rebuilds of the System
  PhaseTimes phase_times_;
  double sim_time_ = 0;
};

}  // namespace dvi
