// Device mirrors of the System's flat arrays and the scratch of every stage (internal to src/gpu).
#pragma once

#include <cuda_runtime.h>

#include <cstdint>
#include <vector>

#include "chrono_like/base/contact_fields.h"
#include "chrono_like/base/data.h"
#include "chrono_like/collision/broadphase.h"
#include "chrono_like/collision/narrowphase.h"
#include "chrono_like/solver/jacobian.h"
#include "chrono_like/solver/process_group.h"
#include "chrono_like/solver/solver_algorithms.h"
#include "chrono_like/system.h"
#include "gpu/device_buffer.h"
#include "gpu/gpu_system.h"

namespace dvi::gpu {

constexpr int kBlock = 256;
inline unsigned blocksFor(int64_t n, int block = kBlock) { return unsigned((n + block - 1) / block); }

// The place of x in keys[0 .. n) (ascending), or -1.
template <class K>
__device__ int64_t findSorted(const K* keys, int64_t n, K x) {
  int64_t lo = 0, hi = n;
  while (lo < hi) {
    const int64_t mid = (lo + hi) / 2;
    if (keys[mid] < x)
      lo = mid + 1;
    else
      hi = mid;
  }
  return lo < n && keys[lo] == x ? lo : -1;
}

struct DeviceBodies {
  DeviceBuffer<Vec3> pos{"body pos"}, vel{"body vel"}, omega{"body omega"}, inv_inertia{"body inv_inertia"},
      force{"body force"}, torque{"body torque"}, gravity{"body gravity"}, v_free{"body v_free"}, w_free{"body w_free"},
      field_force{"body force-field force"}, field_torque{"body force-field torque"};
  DeviceBuffer<Quat> rot{"body rot"};
  DeviceBuffer<real> inv_mass{"body inv_mass"}, friction{"body friction"}, restitution{"body restitution"};
  DeviceBuffer<uint8_t> flags{"body flags"};
  DeviceBuffer<BodyInverseMass> inv{"body world inverse mass"};
  DeviceBuffer<BodyDelta> delta{"body velocity change"};
  DeviceBuffer<int32_t> sel_ids{"selected body ids"};
  DeviceBuffer<BodyRecord> sel_state{"selected body states"};
  DeviceBuffer<BodyParamsRecord> sel_params{"selected body parameters"};
  size_t count = 0;
};

struct DeviceShapes {
  DeviceBuffer<Shape> shape{"shapes"};
  DeviceBuffer<Vec3> hull{"hull points"};
  DeviceBuffer<Aabb> aabb{"shape aabbs"};
  DeviceBuffer<real> sweep{"shape sweeps"};
  size_t count = 0;
};

struct DeviceContacts {
  DeviceBuffer<int32_t> shape_a{"contact shape_a"}, shape_b{"contact shape_b"}, body_a{"contact body_a"},
      body_b{"contact body_b"};
  DeviceBuffer<Vec3> normal{"contact normal"}, pa{"contact pa"}, pb{"contact pb"};
  DeviceBuffer<real> dist{"contact dist"}, mu{"contact mu"}, size{"contact size"};
  DeviceBuffer<uint64_t> key{"contact key"};
  size_t count = 0;
  void resize(size_t n) {
    forEachContactField(*this, [n](auto& field) { field.resize(n); });
    count = n;
  }
};

// Parameters the broad phase derives on the device and reads back once per step (a few dozen bytes).
struct BroadParams {
  BinGrid grid;
  Aabb bounds;
  real edge;       // bin edge used for the large/binned split (before the max_bins growth)
  int32_t binned;  // shapes binned
  int32_t large;   // shapes treated apart
  int64_t bins;
  // 1: the edge needs the sorted extents (median, cut, max_large); 0: the split of the extents at large_factor x
  // the least gives it (gpu_collision.cu: edgeFromSplit).
  int32_t needs_sort;
};

struct BroadScratch {
  DeviceBuffer<real> ext{"broad extents"}, ext_sorted{"broad sorted extents"};
  DeviceBuffer<double> ext_prefix{"broad extent prefix sums"};
  DeviceBuffer<uint8_t> is_binned{"broad binned flags"}, is_large{"broad large flags"};
  DeviceBuffer<Aabb> bound_in{"broad bounds input"};
  DeviceBuffer<int32_t> binned{"broad binned list"}, large{"broad large list"}, counts_sel{"broad select counts"};
  DeviceBuffer<uint64_t> entry_count{"broad entry counts"}, entry_off{"broad entry offsets"};
  DeviceBuffer<uint32_t> entry_bin{"broad entry bins"}, entry_bin_sorted{"broad sorted entry bins"};
  DeviceBuffer<int32_t> entry_shape{"broad entry shapes"}, entry_shape_sorted{"broad sorted entry shapes"};
  DeviceBuffer<uint32_t> run_bin{"broad run bins"};
  DeviceBuffer<int32_t> run_len{"broad run lengths"}, num_runs{"broad run count"};  // statistics only
  DeviceBuffer<unsigned long long> pair_counter{"broad pair counter"};              // pairEmitKernel's places taken
  DeviceBuffer<uint64_t> pair_key{"broad pair keys"}, pair_key_sorted{"broad sorted pair keys"};
  DeviceBuffer<BroadParams> params{"broad params"};
  DeviceBuffer<unsigned char> ext_stats{
      "broad extent statistics"};  // ExtentSplit and the least extent (gpu_collision.cu)
  bool edge_by_sort = false;       // last step's BroadParams::needs_sort: start there
  DeviceBuffer<int64_t> tests{"broad bin pair tests"};
  // pair reuse (broadPhaseStep; broadphase_kernels.h: pairsStillHold): the last build's grown boxes and body
  // flags per shape, its bin edge, and the count of shapes that left their grown box this step
  DeviceBuffer<Aabb> fat{"broad grown boxes"};
  DeviceBuffer<uint8_t> fat_flags{"broad build flags"};
  DeviceBuffer<int32_t> moved{"broad moved count"};
  real last_edge = 0;
  bool built = false;
};

struct NarrowScratch {
  DeviceBuffer<int64_t> count{"narrow counts"};
  DeviceBuffer<int64_t> off{"narrow offsets"};
  // the first point of each touching general pair by its place in the general list (gpu_collision.cu:
  // FirstPoints; room for last step's general pairs and half again), and where each pair's point is
  DeviceBuffer<ContactPoint> first{"narrow first points"};
  DeviceBuffer<int32_t> first_slot{"narrow first point slots"};
  int64_t general_last = 0;  // pairs of the general list in the last step
  // deep MPR pairs, finished by narrowDeepKernel a lane per restart (mpr.h: MprRound)
  DeviceBuffer<np::MprDeferred> deferred{"narrow deferred MPR states"};  // per deep pair (slot of the deep list)
  DeviceBuffer<int32_t> deep{"narrow deep pairs"}, deep_count{"narrow deep pair count"};
  int64_t deep_last = 0;  // deep pairs of the last step (the room of the deferred and deep lists follows it)
  // pairs left by the sphere kernel to the general count kernel, then pairs of several contacts (write pass)
  DeviceBuffer<int64_t> list{"narrow pair list"};
  DeviceBuffer<unsigned long long> list_count{"narrow pair list counts"};
  // the pairs' shape-pair classes (gpu_collision.cu: pairClass; kNoClass for pairs settled by the first pass) and
  // the classes' counts, start places and fill cursors
  DeviceBuffer<uint8_t> cls{"narrow pair classes"};
  DeviceBuffer<unsigned long long> class_count{"narrow class counts"};
  // resident blocks per SM of narrowCountKernel and narrowMultiKernel (their grids), 0 until first asked
  int count_blocks_per_sm = 0, multi_blocks_per_sm = 0, closed_blocks_per_sm = 0;
};

// The APGD control of the device loop (gpu/solver/gpu_apgd_trials.cu: apgdIterateOnDevice), in device memory.
struct ApgdDeviceState {
  algo::ApgdControl c;
  const real* schur_x;       // X[c.nw] while running, null when done
  real* schur_y;             // NX[c.nnw] (real storage)
  float* schur_yf;           // NX[c.nnw] (float storage, VectorStorage)
  unsigned int blocks_done;  // test-reduction blocks finished this trial (the last one updates c)
  double sums[5];            // the persistent kernel's test sums of this trial (written by its last block)
};

struct SolverScratch {
  DeviceBuffer<ContactJacobian> jac{"contact jacobians"};
  DeviceBuffer<ContactJacobianF> jacf{"contact jacobians (float)"};
  DeviceBuffer<real> rhs{"ccp rhs"}, block_inv{"ccp block inverses"}, block_step{"ccp block steps"};
  DeviceBuffer<ConstraintRow> rows{"constraint rows"};
  DeviceBuffer<real> row_lo{"constraint row lower bounds"}, row_hi{"constraint row upper bounds"};
  DeviceBuffer<real> jacobi_step{"ccp jacobi steps"}, colnorm{"ccp column norms"}, rowsum{"ccp block row sums"},
      bodyq{"ccp body column sums"};
  DeviceBuffer<real> gamma{"ccp gamma"}, prev_gamma{"ccp previous gamma"};
  DeviceBuffer<real> x{"ccp normal-only solution"};  // the solution in a normal-only problem's layout
  DeviceBuffer<uint64_t> prev_key{"ccp previous keys"};
  DeviceBuffer<Vec3> prev_normal{"ccp previous normals"};  // by prev_key's order: the narrow phase's LastNormals
  // body -> contact adjacency (CSR): entries (2k + side) sorted by body, offsets per body
  DeviceBuffer<uint32_t> adj_key{"adjacency keys"}, adj_key_sorted{"adjacency sorted keys"};
  DeviceBuffer<int32_t> adj_val{"adjacency values"}, adj_val_sorted{"adjacency sorted values"};
  DeviceBuffer<int32_t> adj_off{"adjacency offsets"};
  // GpuTuning::entry_gather: each sorted entry's side of the float Jacobian, and the bodies' isotropic
  // inverse masses (jacobian.h: EntryJacobianF, BodyInverseIso)
  DeviceBuffer<EntryJacobianF> entry_jac{"adjacency entry jacobians (float)"};
  DeviceBuffer<BodyInverseIso> inv_iso{"body inverse masses (isotropic form)"};
  // bodies with kHeavyDegree or more entries (a CES drum touches every particle on it): gathered by a block
  DeviceBuffer<int32_t> heavy{"heavy bodies"}, heavy_count{"heavy body count"};
  DeviceBuffer<real> heavy_partial{"heavy body partial sums"};  // n_heavy x kHeavyChunks x 6
  DeviceBuffer<uint32_t> heavy_ticket{"heavy body tickets"};    // blocks done per heavy body (0 between launches)
  int64_t n_heavy = 0;
  DeviceBuffer<int32_t> order{"key order"}, order_sorted{"sorted key order"};
  // solver vectors
  DeviceBuffer<real> v0{"solver vector 0"}, v1{"solver vector 1"}, v2{"solver vector 2"}, v3{"solver vector 3"},
      v4{"solver vector 4"}, v5{"solver vector 5"}, v6{"solver vector 6"}, v7{"solver vector 7"},
      v8{"solver vector 8"};  // v7 (v8): APGD's speculated step(s) only (SolverSettings::apgd_speculation)
  DeviceBuffer<double> partial{"reduction partials"};
  DeviceBuffer<double> scalars{"reduction results"};
  DeviceBuffer<ApgdDeviceState> apgd{"APGD device control"};
  DeviceBuffer<float> vf{"APGD float-storage vectors"};  // 7 x 3 blocks: X[0..3], NX[0..2]
  DeviceBuffer<long long> stamps{"APGD phase stamps"};   // DVISIM_APGD_PHASES only
};

// The shares of the Schur product's exchange GPU to GPU (GpuTuning::peer_exchange, gpu_peer_exchange.cu): each
// process writes its listed bodies' shares into its own device buffer (two slots, for even and odd products, so a
// product's shares are never overwritten while a neighbour may still read them), which the other processes of the
// host have opened through CUDA IPC; each sums its listed bodies' terms in rank order reading the others' slots.
struct PeerExchange {
  int state = 0;             // 0: not decided yet, 1: on, -1: off (pinned host staging)
  BodyDelta* own = nullptr;  // cudaMalloc'd, 2 x cap shares
  size_t cap = 0;
  std::vector<void*> opened;  // per process: its buffer as opened here (null: this process's own, or none)
  DeviceBuffer<BodyDelta*> slots{"peer exchange slots"};  // [parity * processes + q]: process q's slot
  DeviceBuffer<int32_t> term_start{"peer exchange term starts"}, term_rank{"peer exchange term processes"},
      term_index{"peer exchange term places"};
  // Per local body: listed this step. The product's gather skips the listed bodies, whose sums the sum kernel writes
  // on copy_stream meanwhile (ev_sums: pass (b) waits for it).
  DeviceBuffer<uint8_t> listed{"peer exchange listed bodies"};
  int parity = 0;                 // of the next product
  cudaEvent_t ev_list = nullptr;  // the listed shares written (the host waits for it, then tells the neighbours)
  cudaEvent_t ev_sums = nullptr;
};

struct DeviceState {
  cudaStream_t stream = nullptr;
  DeviceBodies bodies;
  DeviceShapes shapes;
  DeviceContacts contacts;
  BroadScratch broad;
  NarrowScratch narrow;
  SolverScratch solver;
  ByteBuffer cub_temp{"CUB temporary storage"};
  DeviceBuffer<double> step_scalars{"step scalars"};
  double* host_scalars = nullptr;  // pinned, for single-value read-backs
  char* host_staging = nullptr;    // pinned, syncToHost's copies (one synchronisation, full copy bandwidth)
  size_t host_staging_bytes = 0;
  ApgdDeviceState* host_apgd = nullptr;  // pinned staging of the APGD control (copies without a synchronisation)
  int64_t pairs = 0;
  int pair_shift = 32;       // the pair keys hold (a << pair_shift) | b (gpu_collision.cu: packPair)
  int multiprocessors = 1;   // of the device (fixed grids of the persistent kernels)
  bool cooperative = false;  // the device can launch cooperative kernels (grid-wide barriers: apgdPersistentKernel)
  // DVISIM_APGD_PHASES set: the persistent APGD kernel's block 0 stamps its phases (step, wait, gather, wait,
  // Schur/test, wait and control) for the first trials of every solve; the sums (SM cycles) are printed when the
  // system goes (a profiling switch: one more read-back per solve).
  bool phase_profile = false;
  double phase_cycles[6] = {};
  int64_t phase_trials = 0;
  cudaEvent_t ev[kStageCount + 1] = {};
  size_t prev_count = 0;  // contacts of the previous step (warm start source)
  real max_diag = 1;      // largest diagonal entry of N this step (scales the residual's alpha)
  bool keys_unsorted = false;
  size_t row_count = 0;          // constraint rows this step (before padding)
  bool normal_only = false;      // this step's CCP has the contacts' normal rows only (jacobian.h)
  bool entry_gather = false;     // GpuTuning::entry_gather of this step's BuildRows
  bool all_frictional = false;   // every uploaded body has friction > 0 (GpuSystem::uploadIfNeeded)
  bool any_restitution = false;  // some uploaded body has restitution > 0 (else BuildRows reads none)
  int64_t contact_blocks = 0;    // contact blocks: contacts, or ceil(contacts / 3) when normal_only
  // Contacts left out (System::setContactExclusions): sorted body-pair keys and per-body flags, uploaded when their
  // version changes; the narrow phase zeroes the contact count of such pairs.
  DeviceBuffer<uint64_t> excluded{"excluded body pairs"};
  DeviceBuffer<uint8_t> no_contact{"bodies without contacts"};
  int64_t excluded_count = 0, no_contact_count = 0;
  uint64_t exclusions_version = ~uint64_t(0);
  std::vector<ConstraintRow> host_rows;  // host staging of the padded rows
  std::vector<real> host_lohi;           //   and of their bounds
  // A domain decomposition (System::setProcessGroup, gpu_decomposition.cu): the group; per body its owner and key
  // (both uploaded when bodiesVersion changes, the changed owners scattered); this step's exchange list (local indices) with its device and pinned
  // host staging; scratch of the selections (marks, indices, a count); the warm start handed over by
  // System::addWarmStart (sorted keys, 3 impulses each), read by the next WarmStart and then dropped.
  ProcessGroup* group = nullptr;
  cudaStream_t copy_stream = nullptr;  // the exchange's copies, beside the gather on `stream`
  cudaEvent_t ev_shares = nullptr, ev_sums = nullptr;
  DeviceBuffer<int32_t> owner{"body owners"}, owner_key{"body keys"};
  uint64_t owners_version = ~uint64_t(0);
  DeviceBuffer<int32_t> ex_ids{"exchanged bodies"};
  DeviceBuffer<BodyDelta> ex_buf{"exchanged velocity changes"};
  BodyDelta* ex_host = nullptr;  // pinned, ex_host_cap entries
  size_t ex_host_cap = 0, ex_count = 0;
  DeviceBuffer<uint8_t> mark{"selection marks"};
  DeviceBuffer<int32_t> sel{"selected indices"}, sel_count{"selected count"}, ex_scatter{"changed owners"};
  DeviceBuffer<uint64_t> extra_key{"handed-over warm-start keys"};
  DeviceBuffer<real> extra_gamma{"handed-over warm-start impulses"};
  DeviceBuffer<Vec3> extra_normal{"handed-over warm-start normals"};
  size_t extra_count = 0;
  bool extra_normals = false;    // extra_normal holds one normal per handed-over key
  DeviceContacts contacts_kept;  // the owned contacts while they are compacted (swapped with contacts)
  DeviceBuffer<ContactImpulse> impulse_records{"contact impulse records"};  // contactImpulsesOf's read-back
  PeerExchange peer;

  // Reads `n` doubles from device memory into host_scalars (one synchronisation).
  const double* readScalars(const double* dev, int n);
  template <class T>
  T readValue(const T* dev) {
    T v;
    DVI_CUDA(cudaMemcpyAsync(&v, dev, sizeof(T), cudaMemcpyDeviceToHost, stream));
    DVI_CUDA(cudaStreamSynchronize(stream));
    return v;
  }
  size_t bytes() const;
};

// Stages (one .cu each), called by GpuSystem. `step` is the System's context of the step running (System::beginStep):
// the stages read its h (StepContext::dt) from there, never from cfg.step.
void computeAabbs(DeviceState& d, const SystemConfig& cfg, const StepContext& step);
// The binned broad phase on `boxes` (one per shape; null: d.shapes.aabb), every pair into d.pairs.
void broadPhase(DeviceState& d, const SystemConfig& cfg, BroadPhaseStats* stats, const Aabb* boxes = nullptr);
// The BroadPhase stage: last step's pairs kept while they hold (BroadPhaseSettings::pair_margin), else
// broadPhase on the boxes grown by the margin. Returns true when the pairs were kept.
bool broadPhaseStep(DeviceState& d, const SystemConfig& cfg);
void narrowPhase(DeviceState& d, const SystemConfig& cfg, const StepContext& step);

// Builds rows (Jacobians, rhs, block inverses, the adjacency) for the current contacts.
// rows: the constraint rows of this step from the host's RowProviders (may be empty).
void buildRows(DeviceState& d, const SystemConfig& cfg, const StepContext& step, const std::vector<ConstraintRow>& rows,
               real* max_penetration);
// Contacts from last step's impulses by key (when enabled), rows from row_lambda by index when it has
// one value per row.
void warmStart(DeviceState& d, bool enabled, const std::vector<real>& row_lambda);
// The CCP solve; the stats hold no history (SolverSettings::record_history is not kept on the device).
SolverStats solveCcp(DeviceState& d, const SystemConfig& cfg);
void keepImpulsesForWarmStart(DeviceState& d);
// v = v_free + M^-1 D gamma for every body (and positions), the IntegrateVelocities/Positions stages.
void applyImpulsesToBodies(DeviceState& d, const real* gamma);

// The domain decomposition's device side (gpu_decomposition.cu; solver/process_group.h).
// The group's owners and keys to the device when they changed.
void uploadOwners(DeviceState& d);
// Keeps the contacts this process owns (in order), then names the copies they touch to the group (collective) and
// uploads the step's exchange list.
void keepOwnedContacts(DeviceState& d, bool peer_exchange);
// The velocity-change exchange of a gather, overlapped with it: the listed bodies' shares, written to ex_buf on
// d.stream, start for the host on copy_stream (sendSharesAsync); receiveSums waits for that copy alone while the
// gather runs on, exchanges over the group, and queues the sums into delta on d.stream after the gather.
void sendSharesAsync(DeviceState& d);
void receiveSums(DeviceState& d, BodyDelta* delta);
// The exchange GPU to GPU (gpu_peer_exchange.cu; PeerExchange). preparePeerExchange (collective, once a step after the
// exchange list is set): decides once whether it runs (allowed, one host, every GPU reaching the others' memory),
// grows and shares the buffers where the list outgrew them, and uploads the step's terms. peerSharesSlot: where a
// product's listed shares go; receivePeerSums: waits for them (the host), meets the neighbours, and queues the sums
// into delta on d.stream (the next product takes the other slot).
void preparePeerExchange(DeviceState& d, bool allowed);
BodyDelta* peerSharesSlot(DeviceState& d);
void receivePeerSums(DeviceState& d, BodyDelta* delta);
void closePeerExchange(DeviceState& d);
// The same for one value per body (Jacobi's column sums).
void exchangeBodyValues(DeviceState& d, real* per_body);
// System::motionBounds, ownedBodiesOutside and contactImpulsesOf on the device arrays.
void motionBounds(DeviceState& d, real& vmax, real& wmax);
std::vector<int32_t> ownedBodiesOutside(DeviceState& d, Vec3 lo, Vec3 hi);
std::vector<ContactImpulse> contactImpulsesOf(DeviceState& d, const std::vector<int32_t>& bodies);
// The solution in the problem's layout (solver.x when normal_only, else solver.gamma).
real* solution(DeviceState& d);

}  // namespace dvi::gpu
