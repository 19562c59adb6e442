// The DVI system: owns the flat arrays of one simulation and runs the time step as a list of named
// stages (docs/MODEL.md §6, §2; the stage list follows Box2D v3's b2SolverStageType). The profiler, the run
// summary and docs/ARCHITECTURE.md use the same names.
//
// One step of size h:
//   v_free = v + h M^-1 f                       (IntegrateForces: gravity, external, gyroscopic)
//   contacts = narrow(broad(AABBs))             (ComputeAabbs, BroadPhase, NarrowPhase)
//   solve the CCP  (N g + r) in -Y° ⊥ g in Y    (BuildRows, WarmStart, Solve)
//   v+ = v_free + M^-1 D g                      (IntegrateVelocities)
//   q+ = q + h v+, rotations by the exponential map   (IntegratePositions)
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "chrono_like/base/data.h"
#include "chrono_like/base/errors.h"
#include "chrono_like/base/step_context.h"
#include "chrono_like/base/thread_governor.h"
#include "chrono_like/collision/broadphase.h"
#include "chrono_like/collision/collision.h"
#include "chrono_like/force_field.h"
#include "chrono_like/solver/constraint_row.h"
#include "chrono_like/solver/solver.h"

namespace dvi {

enum class StageType : int {
  IntegrateForces = 0,  // v_free from gravity, applied forces and the gyroscopic torque
  ComputeAabbs,
  BroadPhase,
  NarrowPhase,
  BuildRows,            // Jacobians D, right-hand side r
  WarmStart,            // last step's impulses matched by persistent contact keys
  Solve,                // CCP iterations
  IntegrateVelocities,  // v+ = v_free + M^-1 D g
  IntegratePositions,   // q+ by the exponential map
  Count
};
constexpr int kStageCount = int(StageType::Count);
const char* stageName(StageType s);

// Parts of the stages that the System leaves out when the scene does not need them (docs/MODEL.md §6: "the system
// assembles its stages from the scene"). Each part belongs to a StageType; its name is "Stage.Part" with the
// stage's name (stagePartName), so the run summary lists stages and parts under the profiler's names.
enum class StagePart : int {
  ForceFields = 0,      // IntegrateForces: the ForceField plug-ins (CES fields, ...)
  Gyroscopic,           // IntegrateForces: the implicit gyroscopic term (non-spherical inertia)
  Mpr,                  // NarrowPhase: MPR, for the shape pairs without a closed form
  ConstraintRows,       // BuildRows/Solve: the RowProvider rows (joints, drives)
  FrictionRows,         // BuildRows/Solve: the two tangential rows of every contact
  RollingSpinningRows,  // BuildRows/Solve: the rolling block of every contact with rolling or spinning friction
  Count
};
constexpr int kStagePartCount = int(StagePart::Count);
const char* stagePartName(StagePart p);  // e.g. "BuildRows.FrictionRows"
StageType stageOfPart(StagePart p);

// The System's configuration, in parts (in the manner of Jolt's PhysicsSettings): the step, the collision
// pipeline (collision/collision.h: CollisionSettings), the solver (solver/solver.h: SolverSettings), the GPU
// backend's tuning, and how the CPU stages run. Each setting is declared once, here or in those headers; scene
// files (io/scene.h: SceneSettings holds a SystemConfig), CES machines (ces/ces_config.h: CesConfig holds the step
// and solver parts) and the command line write into these fields. docs/ARCHITECTURE.md ("Configuration") lists
// who reads what.

// The time step and the forces every body feels.
struct StepSettings {
  // [s] the step h; must be > 0 and finite. Default 1e-3. Held in double so that a machine's clock counts in the
  // step as given (ces/machine.h); the engine steps with real(dt) (StepContext::dt).
  double dt = 1e-3;
  // [m/s^2] gravity of every body added without its own (BodyDesc::has_gravity). Default (0, -9.81, 0).
  Vec3 gravity{0, real(-9.81), 0};
  // The implicit gyroscopic term omega x I omega for bodies with non-spherical inertia. Default true.
  bool gyroscopic = true;
};

// The GPU backend's tuning (gpu/gpu_system.h). None of them changes a result: each pair of choices gives bitwise
// the same iterates.
struct GpuTuning {
  // Run each APGD trial (step, Schur product, test, control) as one captured CUDA graph, launched once per trial;
  // false launches the kernels one by one (more launch latency). Default true.
  bool graphs = true;
  // [blocks] an APGD problem of at most this many blocks (contacts, or row blocks) runs all its trials in one
  // cooperative kernel (grid-wide barriers between the step, the gather and the fused Schur/test pass; the
  // control updated in every block), larger ones trial by trial (graphs). 0: never. The default is every size:
  // on an H100 the persistent kernel was faster from 10k to 1M spheres (docs/GPU_PERFORMANCE.md). Jacobi and BB
  // always launch kernel by kernel, and so does a device without cooperative launch.
  int64_t persistent_max_blocks = std::numeric_limits<int64_t>::max();
  // In the persistent APGD kernel, a problem of at most 2 blocks per thread of its grid (2 blocks of 256 per SM:
  // ~135,000 blocks on an H100) keeps each thread's iterates and Schur values in registers from trial to trial
  // instead of reading them again. false: every trial reads its buffers. Default true.
  bool apgd_register_cache = true;
  // Float storage (VectorStorage::Float): the Schur product's gather reads each adjacency entry's normal and
  // lever arm from a 24-byte float record kept in entry order (written once a step by BuildRows), and each body's
  // inverse mass from a 16-byte record where its world inverse inertia is a multiple of the identity, instead of
  // each contact's 44-byte Jacobian at random and the 56-byte inverse mass. false: the contact records (for
  // measuring the difference). Default true.
  bool entry_gather = true;
  // Over several processes on one host (mpirun, DistributedSystem), the Schur product's velocity-change shares go GPU
  // to GPU: each process reads its neighbours' shares from their device memory (CUDA IPC, over NVLink or PCIe) and
  // sums them in rank order on its own GPU, instead of staging them through pinned host memory and MPI messages.
  // Where some GPU cannot reach another's memory the staging runs. The same sums either way. Default true.
  bool peer_exchange = true;
  // The narrow phase sorts the pairs its first pass cannot settle (not two spheres, boxes not apart) by shape-pair
  // class and runs the closed-form classes in a kernel without MPR's code, the MPR classes in another, each warp on
  // pairs of one class (gpu_collision.cu). false: one list in pair order through the general kernel (for measuring
  // the difference; the same contacts). Default true.
  bool narrow_classes = true;
};

struct SystemConfig {
  StepSettings step;            // dt, gravity, gyroscopic term
  CollisionSettings collision;  // backend, envelope, speculative contacts, MPR manifold, friction rule, broad phase
  SolverSettings solver;        // algorithm, stop, warm start, penetration recovery
  GpuTuning gpu;                // the GPU backend's launch choices
  // [threads] OpenMP threads of the CPU stages; 0 = OpenMP's default team (OMP_NUM_THREADS, else the cores),
  // dropped to one thread while other processes take the cores (base/thread_governor.h). An explicit count stands.
  int threads = 0;
  int min_bodies_per_thread = 256;  // [bodies] fewer bodies (or shapes, whichever are more) than this per thread: use
                                    // fewer threads (a small scene costs more in OpenMP barriers than it gains; 1
                                    // forces all threads)
  // Leave out the stages and rows the scene does not need (docs/MODEL.md §6): the normal row only when no contact
  // of the step has mu > 0, no gyroscopic term for spherical inertia, no row or field round trips without
  // row providers or fields. false runs every one of them (3 rows per contact even for mu = 0, the
  // gyroscopic Newton step for every body, the row and field stages when empty): for benchmarks and tests.
  // Default true.
  bool prune = true;
};

// A shape as given to addBody: the record (body index ignored) and, for a convex hull, its points.
struct ShapeDesc {
  Shape shape{};
  std::vector<Vec3> hull;
};

struct BodyDesc {
  Vec3 pos{0, 0, 0};
  Quat rot{1, 0, 0, 0};
  Vec3 vel{0, 0, 0};
  Vec3 omega{0, 0, 0};
  real mass = 1;          // 0 with kBodyFixed or kBodyKinematic
  Vec3 inertia{1, 1, 1};  // principal moments, body frame
  real friction = real(0.5);
  real restitution = 0;  // Newton's coefficient (BodyArrays::restitution), finite and >= 0; 0 = inelastic
  // [m] rolling and spinning resistance lengths (Tasora & Anitescu 2013; Bullet's m_rollingFriction and
  // m_spinningFriction): a contact resists rolling and spinning with a torque of at most mu_r (mu_s) times its normal
  // force, mu_r, mu_s combined from the two bodies by CollisionSettings::friction_combine. Finite and >= 0; 0 = none.
  real rolling_friction = 0;
  real spinning_friction = 0;
  uint8_t flags = 0;
  bool has_gravity = false;  // use `gravity` instead of the system's
  Vec3 gravity{0, 0, 0};
  std::vector<ShapeDesc> shapes;
};

// Helpers that fill a ShapeDesc in the canonical orientation (axis Y) at a local pose.
ShapeDesc makeSphere(real r, Pose local = {{0, 0, 0}, {1, 0, 0, 0}});
ShapeDesc makeBox(Vec3 half, Pose local = {{0, 0, 0}, {1, 0, 0, 0}});
ShapeDesc makeCylinder(real r, real half_height, Pose local = {{0, 0, 0}, {1, 0, 0, 0}});
ShapeDesc makeCapsule(real r, real half_length, Pose local = {{0, 0, 0}, {1, 0, 0, 0}});
ShapeDesc makeCone(real r, real height, Pose local = {{0, 0, 0}, {1, 0, 0, 0}});
ShapeDesc makeEllipsoid(Vec3 semi_axes, Pose local = {{0, 0, 0}, {1, 0, 0, 0}});
// A convex hull of `points` swept by a sphere of radius `margin` (Bullet's collision margin; Shape::margin).
ShapeDesc makeConvexHull(std::vector<Vec3> points, Pose local = {{0, 0, 0}, {1, 0, 0, 0}}, real margin = 0);
ShapeDesc makePlane(Vec3 normal, real d);

struct StepStats {
  int64_t contacts = 0;
  int64_t pairs = 0;
  bool pairs_reused = false;  // BroadPhase kept the last step's pairs (BroadPhaseSettings::pair_margin)
  real max_penetration = 0;   // largest -dist over contacts after the solve's input (>= 0)
  int iterations = 0;
  int trials = 0, speculated = 0;  // APGD: steps tested, and those speculated by the trial before (SolverStats)
  real residual = 0;               // absolute residual the solve reached (m/s)
  real relative_residual = 0;      // residual / res(0): the convergence measure (solver.h)
  bool converged = true;           // relative_residual <= the tolerance (SolverStats::converged)
  std::array<double, kStageCount> stage_seconds{};  // wall time of each stage in this step
  std::array<bool, kStageCount> stage_ran{};
  // Why a stage did not run this step (null where it ran).
  std::array<const char*, kStageCount> stage_reason{};
  // Parts of the stages (StagePart) that ran this step, and why each other one was left out.
  std::array<bool, kStagePartCount> part_ran{};
  std::array<const char*, kStagePartCount> part_reason{};
  bool normal_only = false;  // this step's CCP had the normal rows only (no contact with mu > 0)
  int threads = 0;           // the CPU stages' team size this step (threads 0: as the load allowed)
};

// Stages and parts over a run (the run summary, output.h: addStageSummary): seconds per stage, whether
// each stage and part ran in any step, and the last reason one was left out.
struct StageLog {
  int64_t steps = 0;
  int64_t normal_only_steps = 0;
  int64_t pairs_reused_steps = 0;  // steps whose BroadPhase kept the last step's pairs
  std::array<double, kStageCount> seconds{};
  std::array<bool, kStageCount> ran{};
  std::array<const char*, kStageCount> reason{};
  std::array<bool, kStagePartCount> part_ran{};
  std::array<const char*, kStagePartCount> part_reason{};
  void add(const StepStats& s) {
    ++steps;
    normal_only_steps += s.normal_only ? 1 : 0;
    pairs_reused_steps += s.pairs_reused ? 1 : 0;
    for (int i = 0; i < kStageCount; ++i) {
      seconds[size_t(i)] += s.stage_seconds[size_t(i)];
      ran[size_t(i)] = ran[size_t(i)] || s.stage_ran[size_t(i)];
      if (s.stage_reason[size_t(i)]) reason[size_t(i)] = s.stage_reason[size_t(i)];
    }
    for (int i = 0; i < kStagePartCount; ++i) {
      part_ran[size_t(i)] = part_ran[size_t(i)] || s.part_ran[size_t(i)];
      if (s.part_reason[size_t(i)]) part_reason[size_t(i)] = s.part_reason[size_t(i)];
    }
  }
};

// Convergence over a run: steps whose solve missed the tolerance, and the worst relative residual (the run
// summary's steps_not_converged, worst_relative_residual, worst_residual_step). System keeps one
// (System::convergence()); add() takes the step's index.
struct ConvergenceLog {
  int64_t steps = 0;
  int64_t steps_not_converged = 0;
  real worst_relative_residual = 0;
  int64_t worst_step = -1;  // index of the step with the worst relative residual (-1: no step yet)
  void add(const StepStats& s, int64_t step) {
    ++steps;
    steps_not_converged += s.converged ? 0 : 1;
    if (worst_step < 0 || s.relative_residual > worst_relative_residual) {
      worst_relative_residual = s.relative_residual;
      worst_step = step;
    }
  }
};

class ContactProblem;

// A contact of the last step with its impulses (System::contactImpulsesOf): its persistent key (contact.h: contactKey),
// its bodies, 3 impulses (normal, then the two tangents) and its normal.
struct ContactImpulse {
  uint64_t key;
  int32_t body_a, body_b;
  real gamma[3];
  Vec3 normal;  // from shape a to shape b (the next narrow phase's last normal: setWarmStart)
};

class System {
 public:
  // `bullet_collision` makes the collision backend when config.collision is CollisionBackend::Bullet
  // (bullet/bullet_collision_backend.h: makeBulletCollision): the core does not build Bullet's pipeline itself, so a
  // caller whose configuration may ask for it passes it. Asked for without one: InputError.
  explicit System(SystemConfig config = {}, CollisionFactory bullet_collision = nullptr);
  virtual ~System();
  System(const System&) = delete;
  System& operator=(const System&) = delete;

  // Adds a body; validates it (finite numbers, mass >= 0, positive shape dimensions) and throws
  // InputError naming the problem. Returns the body index.
  int addBody(const BodyDesc& desc);
  // addBody's checks alone: InputError naming body `index` and the problem.
  static void validateBody(const BodyDesc& desc, int index);

  virtual void step();  // one step of config().step.dt
  void advance(int steps) {
    for (int i = 0; i < steps; ++i) step();
  }

  const SystemConfig& config() const { return config_; }
  SystemConfig& mutableConfig() { return config_; }
  const BodyArrays& bodies() const { return bodies_; }
  BodyArrays& mutableBodies() { return bodies_; }
  const ShapeArrays& shapes() const { return shapes_; }
  const ContactArrays& contacts() const { return contacts_; }
  // Impulses of the last step: 3 per contact, then 3 per rolling block (rollingIndex; angular impulses divided by a
  // length, see rollingImpulse), then the constraint rows' (3 per block of rows).
  const std::vector<real>& impulses() const { return gamma_; }
  // Contact k's rolling block in impulses() (at 3 (contacts + q)), or -1 where it has no rolling or spinning friction.
  int32_t rollingIndex(size_t k) const;
  // Contact k's rolling and spinning impulse (angular, on body B; N m s) of the last step; zero without a rolling
  // block.
  Vec3 rollingImpulse(size_t k) const;
  const StepStats& lastStats() const { return stats_; }
  // Every step's solve since construction: how many missed the tolerance, the worst relative residual.
  const ConvergenceLog& convergence() const { return convergence_; }
  double time() const { return time_; }
  // The context of the step running now, or of the last one between steps (StepContext).
  const StepContext& stepContext() const { return ctx_; }
  int64_t stepCount() const { return steps_; }
  // The clock of a checkpoint a run resumes from (apps/dvisim/run_checkpoint.h): the next step starts at `time`,
  // after `steps` steps. Before the first step, with the bodies and warm start (setWarmStart) of the same checkpoint.
  void setClock(double time, int64_t steps) {
    time_ = time;
    steps_ = steps;
  }
  virtual std::string backendName() const { return "cpu"; }
  virtual std::string deviceName() const;
  // Threads the CPU stages use for the current scene: config().threads, reduced for small scenes.
  int effectiveThreads() const;
  // Backends that keep state elsewhere (the GPU system) copy it into the host arrays here; bodies(),
  // contacts() and impulses() are current only after it. No-op on the CPU.
  virtual void syncToHost() {}
  // The host body arrays were edited through mutableBodies(): a device backend re-uploads them.
  virtual void markHostDirty() {}
  // The same for a few bodies (their pos, rot, vel, omega and flags only): plug-ins that read or edit some
  // bodies between steps without moving the whole state. No-op on the CPU.
  virtual void syncBodiesToHost(const std::vector<int32_t>& /*ids*/) {}
  virtual void markBodiesDirty(const std::vector<int32_t>& /*ids*/) {}
  // The same for the other per-body arrays of a few bodies (inv_mass, inv_inertia, force, torque, gravity, friction,
  // restitution, rolling and spinning friction): the Bullet drop-in world uploads only the bodies the app changed.
  virtual void markBodyParamsDirty(const std::vector<int32_t>& /*ids*/) {}
  // A device backend's body arrays (force_field.h), for plug-ins with device code; false on the CPU.
  virtual bool deviceBodies(DeviceBodyRefs& /*out*/) { return false; }
  // The same for the last step's contacts; false on the CPU (contacts() holds them there).
  virtual bool deviceContacts(DeviceContactRefs& /*out*/) { return false; }

  // Plug-ins (force_field.h, solver/constraint_row.h). Force fields run in IntegrateForces in the order added; row
  // providers add their constraint rows to the CCP of every step (solved with the contacts, stage BuildRows/Solve).
  void addForceField(std::shared_ptr<ForceField> field) { fields_.push_back(std::move(field)); }
  void addRowProvider(std::shared_ptr<RowProvider> rows) { row_providers_.push_back(std::move(rows)); }
  // Contacts the step leaves out (collision/contact.h: contactExcluded), on both backends after the narrow phase:
  // every contact between the two bodies of a pair in `pairs` (body indices, either order), and every contact of a
  // body whose entry in `no_contact` is nonzero (empty: none; bodies past its end: none). The Bullet drop-in world
  // sets them from constraints made with disableCollisionsBetweenLinkedBodies and from CF_NO_CONTACT_RESPONSE.
  void setContactExclusions(const std::vector<std::pair<int32_t, int32_t>>& pairs, std::vector<uint8_t> no_contact);
  const std::vector<ConstraintRow>& constraintRows() const { return rows_; }  // last step's rows
  const std::vector<real>& rowImpulses() const { return row_lambda_; }        // and their impulses

  // A domain decomposition's share (solver/process_group.h; chrono_like/mpi/distributed_system.h): this System
  // holds one process's bodies (its own and copies of its neighbours'), keeps only the contacts the group says it
  // owns, and solves them with the other processes (APGD, Jacobi or BB; no Gauss-Seidel, constraint rows, rolling
  // friction or Bullet collision: InputError). null: this System alone (the default). The group outlives the System's steps.
  void setProcessGroup(ProcessGroup* group);
  // The next step's warm start (WarmStart stage): impulses (3 per key) of the contacts with these keys, sorted
  // ascending, in place of the last step's. For a driver that rebuilds the System between steps. `normals` (one per
  // key, or empty): the contacts' normals, which the next narrow phase reads as last step's
  // (CollisionSettings::mpr_coherence); without them it has none, and a deep pair tests its candidates again.
  void setWarmStart(std::vector<uint64_t> sorted_keys, std::vector<real> impulses, std::vector<Vec3> normals = {});
  // Adds to the next step's warm start (an entry of a key already there replaces it): a driver hands over the impulses
  // of the contacts another process solved in the last step. Keys sorted ascending, 3 impulses each; normals as in
  // setWarmStart (kept only where both the table and the added entries have them).
  virtual void addWarmStart(const std::vector<uint64_t>& sorted_keys, const std::vector<real>& impulses,
                            const std::vector<Vec3>& normals = {});

  // For a domain decomposition (chrono_like/mpi/distributed_system.h), on the current state without copying it:
  // the largest |v| and |w| of the dynamic bodies this process owns (all dynamic bodies without a process group),
  virtual void motionBounds(real& vmax, real& wmax) const;
  // those of them whose centre lies outside the box [lo, hi] (ascending; the box may be infinite on a side),
  virtual std::vector<int32_t> ownedBodiesOutside(Vec3 lo, Vec3 hi) const;
  // and the last step's contacts (those this process kept) that touch one of `bodies` (ascending), in key order.
  virtual std::vector<ContactImpulse> contactImpulsesOf(const std::vector<int32_t>& bodies) const;

  // Contact force on each contact in the last step (impulse / dt), world frame, acting on body B.
  Vec3 contactForce(size_t k) const;
  // Sum of the hash of every body's state, for determinism tests (bitwise).
  uint64_t stateHash() const;

 protected:
  // The step's context from the configuration and the clock (every backend's step() starts with it), and the
  // clock advanced by it (every step() ends with it).
  void beginStep() { ctx_ = makeStepContext(real(config_.step.dt), time_, steps_); }
  void endStep() {
    time_ += double(ctx_.dt);
    ++steps_;
  }
  // The stages; a GPU subclass overrides them with device versions.
  virtual void integrateForces();
  virtual void detectCollisions();                      // ComputeAabbs + BroadPhase + NarrowPhase
  virtual void buildAndSolve();                         // BuildRows + WarmStart + Solve
  void buildProblem(int64_t nc);                        // BuildRows after the rows: mu, size, parts, the problem
  SolverStats solveApgdRowStop(real* x) const;          // Solve with SolverType::APGD (SolverSettings::row_stop)
  SolverStats solveGaussSeidelThenApgd(real* x) const;  // Solve with SolverType::GaussSeidel (gs_apgd_finish)
  void warmStartContacts(int64_t nc, int64_t nroll);    // WarmStart of the contacts and rolling blocks
  virtual void integrate();                             // IntegrateVelocities + IntegratePositions
  void collectRows();                                   // rows_ from the row providers (part of BuildRows)
  void cacheImpulsesByKey(int64_t nc);                  // this step's impulses by contact key (end of Solve)
  std::vector<int32_t> touchedCopies() const;           // the group's copies this process's contacts touch
  // Scene-level parts (host arrays): gyroscopic term and MPR needed? Fills stats_.part_ran/part_reason for
  // ForceFields, Gyroscopic, Mpr, ConstraintRows and RollingSpinningRows; returns whether the gyroscopic
  // term runs.
  bool planParts();
  // Does any body have rolling or spinning friction? (host arrays)
  bool hasRollingBodies() const;
  // Each contact's (mu_s, mu_r) into roll_coef_ (friction_combine); returns whether any is > 0. Virtual: the Bullet
  // drop-in world scales mu_r by Bullet's anisotropic rolling friction (bullet_world.cpp).
  virtual bool combineRolling(int64_t nc);
  // Does any dynamic body have non-spherical inertia (needsGyroscopic)? Scans the host arrays (they may have
  // been edited through mutableBodies()); the GPU system answers from its last upload instead.
  virtual bool hasGyroscopicBodies() const;
  // The Solve stage's outcome into stats_ and convergence_ (both backends).
  void recordSolve(const SolverStats& s) {
    stats_.iterations = s.iterations;
    stats_.trials = s.trials;
    stats_.speculated = s.speculated;
    stats_.residual = s.residual;
    stats_.relative_residual = s.relative_residual;
    stats_.converged = s.converged;
    convergence_.add(stats_, steps_);
  }
  // Records a stage as left out of this step.
  void leaveOut(StageType s, const char* why) {
    if (!stats_.stage_ran[int(s)]) stats_.stage_reason[int(s)] = why;
  }

  SystemConfig config_;
  BodyArrays bodies_;
  ShapeArrays shapes_;
  ContactArrays contacts_;
  std::vector<real> gamma_;          // impulses of this step, 3 per contact, then the rolling blocks', then rows'
  std::vector<real> roll_coef_;      // 2 per contact: (mu_s, mu_r) this step, when some body has rolling friction
  std::vector<real> prev_roll_;      // last step's rolling impulses, 3 per key of prev_keys_ (empty: none)
  std::vector<uint64_t> prev_keys_;  // sorted keys of last step's contacts
  std::vector<real> prev_gamma_;     // their impulses
  std::vector<Vec3> prev_normal_;    // their normals (the narrow phase's LastNormals; empty after a handed-over start)
  std::vector<Vec3> v_free_, w_free_;  // velocities after forces
  std::vector<std::shared_ptr<ForceField>> fields_;
  std::vector<std::shared_ptr<RowProvider>> row_providers_;
  std::vector<ConstraintRow> rows_;               // constraint rows of this step
  std::vector<real> row_lambda_;                  // their impulses
  std::vector<size_t> provider_rows_;             // rows of each provider this step, in order
  std::unique_ptr<CollisionDetector> collision_;  // narrow + broad phase backend (native or Bullet's)
  std::vector<uint64_t> excluded_pairs_;          // sorted bodyPairKey of the excluded pairs (setContactExclusions)
  std::vector<uint8_t> no_contact_;               // per body: makes no contacts (empty: none)
  uint64_t exclusions_version_ = 0;               // bumped by every setContactExclusions (a device re-uploads)
  bool hasExclusions() const { return !excluded_pairs_.empty() || !no_contact_.empty(); }
  std::unique_ptr<ContactProblem> problem_;
  ProcessGroup* group_ = nullptr;   // setProcessGroup
  std::vector<real> x_;             // solution in the problem's layout when it is normal-only
  const real* solution_ = nullptr;  // gamma_ or x_: what IntegrateVelocities applies
  size_t typed_shapes_ = 0;         // shapes whose type is in shape_types_
  uint32_t shape_types_ = 0;        // bit t: the scene has a shape of type t
  StepStats stats_;
  ThreadGovernor governor_;  // the team size of threads 0 under load
  ConvergenceLog convergence_;
  StepContext ctx_;  // of this step (beginStep)
  double time_ = 0;
  int64_t steps_ = 0;
};

}  // namespace dvi
