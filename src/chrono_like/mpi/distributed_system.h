// The System over several MPI processes by domain decomposition (docs/ARCHITECTURE.md, "Domain decomposition over
// MPI"): every process owns the dynamic bodies whose centre lies in its box of a recursive coordinate bisection
// (bisection.h), holds copies (ghosts) of its neighbours' bodies near its box and every fixed or kinematic body, and
// steps a System of those bodies whose contacts it owns. The solve runs over all processes (solver/process_group.h):
// the Schur product exchanges the shared bodies' velocity changes, every reduction is summed over the processes,
// so the iterates equal one process's up to the order of summation. After each step the bodies that left a box
// move to their new owner, with the warm-start impulses of the contacts they own.
//
// The local System lives from one rebuild to the next, on either backend (a factory makes it: the CPU System or the
// GPU one). It holds the copies within a halo (DecompositionSettings::halo_factor times the ghost width); each step
// only the copies within the ghost width are refreshed from their owners, the others are parked (fixed, none of their
// contacts kept), and only bodies near a box face cross to the host. It is rebuilt when a body comes from beyond the
// halo, and after a re-balance.
//
// Every process adds the same bodies in the same order (the scene): the bodies' descriptions (shapes, masses,
// materials) are kept on every process, their state (position, rotation, velocities) only on the owner.
// A collective object: every process calls the same methods in the same order. APGD, Jacobi or BB; Gauss-Seidel,
// constraint rows, rolling or spinning friction, Bullet's collision and dynamic planes are refused (InputError).
#pragma once

#include <mpi.h>

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "chrono_like/mpi/bisection.h"
#include "chrono_like/checkpoint_piece.h"
#include "chrono_like/mpi/mpi_group.h"
#include "chrono_like/system.h"

namespace dvi {

struct DecompositionSettings {
  // Recompute the bisection (re-balance) after a step whose largest owned count exceeds this times the mean
  // (> 1), and the mean rounded up. Default 1.2.
  real rebalance_ratio = real(1.2);
  // Factor (>= 1) on the ghost width: 2 x the largest bounding radius + the largest collision envelope + 2 x the
  // largest sweep of a step (the farthest two bodies' centres can be and still touch). Default 1.5.
  real ghost_safety = real(1.5);
  // Factor (>= 1) on the ghost width for the copies the local System keeps between rebuilds: the wider, the rarer the
  // rebuilds (a body must come from beyond it) and the more parked copies collide for nothing. Default 2.
  real halo_factor = real(2);
};

// Where this process's steps went and what it sent, summed since construction (seconds by steady clock, bytes).
struct DecompositionProfile {
  double ghosts_s = 0;    // the copies' refresh: records to the neighbours, and their states into the local System
  double build_s = 0;     // rebuilds of the local System (its bodies added, its warm start)
  double step_s = 0;      // the local System's step: its stages in stages_s, the solver's collectives in group
  double readback_s = 0;  // the ghost width, and the states of the owned bodies near a box face to the host
  double migrate_s = 0;   // bodies to their new owners (with their contacts' impulses), and re-balancing
  // Parts of the above: the ghost width (of readback_s: a reduction over the local bodies and an MPI_Allreduce), the
  // refresh's MPI_Alltoallv (of ghosts_s) and the moves' MPI_Alltoallv's with the re-balance test's reductions (of
  // migrate_s); each collective's time includes the wait for the slower process.
  double width_s = 0, ghosts_mpi_s = 0, migrate_mpi_s = 0;
  // Finer parts, for tuning: the near-face selection and its states to the host (of readback_s), the refresh records
  // made, the arrived records applied, and the copies parked with the uploads (of ghosts_s).
  double select_s = 0, near_sync_s = 0, ghosts_pack_s = 0, ghosts_apply_s = 0, ghosts_park_s = 0;
  std::array<double, kStageCount> stages_s{};
  int64_t ghost_bytes = 0, migrate_bytes = 0;  // sent to other processes
  GroupTraffic group;                          // the solver's exchanges and reductions (MpiGroup)
};

// Bodies handed between processes since construction, per other process (index = rank).
struct MigrationLog {
  std::vector<int64_t> sent;      // to that process
  std::vector<int64_t> received;  // from it
  int64_t rebalances = 0;         // bisections recomputed after the first
  int64_t rebuilds = 0;           // local Systems built (the first included)
};

class DistributedSystem {
 public:
  // Makes the local System (null: the CPU System): makeGpuSystem (gpu/gpu_factory.h) puts it on this process's GPU.
  using LocalFactory = std::function<std::unique_ptr<System>(const SystemConfig&)>;
  // comm is duplicated (the object's messages never meet the caller's). config as for System: its solver must not be
  // Gauss-Seidel and its collision backend must be native (InputError).
  DistributedSystem(MPI_Comm comm, SystemConfig config, DecompositionSettings settings = {},
                    LocalFactory make_local = nullptr);
  ~DistributedSystem();
  DistributedSystem(const DistributedSystem&) = delete;
  DistributedSystem& operator=(const DistributedSystem&) = delete;

  // Adds a body on every process (call with the same bodies in the same order everywhere) before the first step;
  // validated as System::addBody does. Returns its global id (the order of addition).
  int addBody(const BodyDesc& desc);
  void step();
  void advance(int steps) {
    for (int i = 0; i < steps; ++i) step();
  }

  int rank() const { return rank_; }
  int processes() const { return size_; }
  size_t bodyCount() const { return descs_.size(); }
  size_t dynamicCount() const { return dynamic_.size(); }
  // Global ids of the dynamic bodies this process owns, ascending (fixed and kinematic bodies are every process's).
  const std::vector<int32_t>& ownedIds() const;
  // Every body's state in global order, on every process (collective).
  std::vector<MotionState> gatherState() const;
  // The states of the bodies this process owns, in ownedIds() order (one copy from the local System).
  std::vector<MotionState> ownedStates() const;
  // This process's share of a checkpoint (checkpoint.h): its owned bodies' states and the impulses of the contacts it
  // solved in the last step, under global ids and keys. Not collective.
  CheckpointPiece checkpointPiece() const;
  // Before the first step: start from `states` (every body, global order; fixed bodies keep their description's) with
  // `impulses` (the pieces of every process together) as the warm start, the clock at `time` after `steps` steps. The
  // bisection is made from these positions, so any number of processes can resume.
  void restore(const std::vector<MotionState>& states, const std::vector<ContactImpulse>& impulses, double time,
               int64_t steps);
  // The current state of a body this process owns, or of a fixed or kinematic body (every process's); InputError
  // for another (its state is its owner's).
  MotionState stateOf(int32_t id) const;
  // Whether body id is fixed or kinematic (held by every process).
  bool replicated(int32_t id) const { return replicated_[size_t(id)] != 0; }
  // This process's System (its contacts are the ones it owns; a GPU System's host arrays are current after
  // syncToHost) and the global id of each of its bodies. Null before the first step.
  const System* local() const { return sys_.get(); }
  // The process group the local System solves with (its exchange list, its traffic).
  MpiGroup& group() { return *group_; }
  const std::vector<int32_t>& localIds() const { return local_ids_; }
  const MigrationLog& migrations() const { return log_; }
  DecompositionProfile profile() const;
  const Bisection& bisection() const { return tree_; }
  double time() const { return time_; }
  int64_t stepCount() const { return steps_; }

 private:
  struct WarmEntry {  // a contact's impulses by global key, kept by the owner of its owning body
    uint64_t key;
    int32_t body_a, body_b, owner;  // global ids; owner: the pair's owning body (pairOwner; -1: none)
    real gamma[3];
    Vec3 normal;  // the next narrow phase's last normal (System::setWarmStart)
  };
  struct Record {  // a body's state on the wire
    int32_t id;
    MotionState s;
  };
  void start();
  real ghostWidth() const;
  void setListedRegion();
  void rebuild(bool read_local);
  void afterStep();
  std::vector<Record> nearFaceBodies(std::vector<int32_t>& locals);
  void migrate(std::vector<Record>& near, const std::vector<int32_t>& near_locals, std::vector<int32_t>& arrived_ids,
               bool& need_rebuild);
  void refreshCopies(const std::vector<Record>& near, const std::vector<int32_t>& arrived, bool& need_rebuild);
  void readLocal();
  void setLocalWarmStart(const std::vector<WarmEntry>& entries, bool replace);
  std::vector<WarmEntry> warmEntries(const std::vector<ContactImpulse>& contacts) const;
  bool rebalanceIfNeeded();
  void migrateAll();
  std::vector<WarmEntry> exchangeMoves(const std::vector<std::vector<Record>>& out,
                                       const std::vector<std::vector<WarmEntry>>& out_warm, std::vector<Record>& in);
  int32_t pairOwner(int32_t a, int32_t b) const;
  void setLocalState(int32_t local, const MotionState& s, bool parked);
  void syncOwned() const;

  MPI_Comm comm_ = MPI_COMM_NULL;
  int rank_ = 0, size_ = 1;
  SystemConfig config_;
  DecompositionSettings settings_;
  LocalFactory make_local_;
  std::vector<BodyDesc> descs_;
  std::vector<int32_t> shape_start_;  // global index of each body's first shape
  std::vector<uint8_t> replicated_;   // fixed or kinematic: on every process
  std::vector<real> radius_;          // bounding radius about the centre
  real rmax_ = 0, gmax_ = 0;          // the largest dynamic body's radius, the largest gravity
  std::vector<int32_t> dynamic_, fixed_;
  mutable std::vector<MotionState> state_;  // current for replicated bodies; for owned ones after syncOwned()
  std::vector<int32_t> owner_;              // per global id: its owner as this process knows it (exact for its own)
  int64_t owned_count_ = 0;
  mutable std::vector<int32_t> owned_;  // ownedIds(), made on demand
  mutable bool owned_stale_ = true;
  std::vector<WarmEntry> warm_;  // between readLocal and a rebuild
  std::vector<int32_t> fresh_;   // copies refreshed by the last step's records (local indices)
  // Per local body: the refresh that last counted it current (refreshCopies; a stamp, not a sorted list to search).
  std::vector<uint32_t> current_stamp_;
  uint32_t stamp_ = 0;
  real width_ = 0;                // the ghost width of the coming step
  bool rebuild_pending_ = false;  // rebuild at the next step's start (the last System stays readable)
  bool host_states_ = false;      // state_ holds the owned states (a re-balance moved bodies)
  Bisection tree_;
  bool started_ = false;
  std::unique_ptr<MpiGroup> group_;
  std::unique_ptr<System> sys_;
  std::vector<int32_t> local_ids_;  // per local body: global id (ascending)
  std::vector<int32_t> local_of_;   // per global id: local index or -1
  MigrationLog log_;
  DecompositionProfile prof_;
  double time_ = 0;
  int64_t steps_ = 0;
  std::vector<MotionState> restored_;  // restore(): the states start() takes
};

}  // namespace dvi
