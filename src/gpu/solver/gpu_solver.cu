// The Solve stage on the device: the solvers are the very templates of chrono_like/solver/solver_algorithms.h with
// their kern:: functors, instantiated with GpuOps (CUDA kernels over the device vectors: map, deterministic
// reductions, the Schur product, APGD's device loop) where the CPU instantiates them with OpenMP loops. Also the
// warm start, the impulses kept for the next step's, and the velocities from the impulses.
#include <cuda_runtime.h>

#include <cstdint>
#include <cub/cub.cuh>
#include <stdexcept>
#include <string>
#include <vector>

#include "chrono_like/base/errors.h"
#include "chrono_like/solver/solver.h"
#include "chrono_like/solver/solver_algorithms.h"
#include "gpu/cub_call.cuh"
#include "gpu/gpu_state.cuh"
#include "gpu/solver/gpu_apgd.cuh"
#include "gpu/solver/gpu_reduce.cuh"
#include "gpu/solver/gpu_schur.cuh"

namespace dvi::gpu {

namespace {

struct ProblemView {
  int64_t nc = 0;  // contact blocks
  int64_t nb = 0;  // all blocks (contacts, then constraint-row blocks)
  const real* lo = nullptr;
  const real* hi = nullptr;
  const real* r = nullptr;
  const real* mu = nullptr;
  const real* eta = nullptr;
  const real* jeta = nullptr;
  const real* binv = nullptr;
  real max_diag = 1;
};

// Name of a functor type, for the error message of a failed launch.
template <class F>
const char* functorName() {
  return __PRETTY_FUNCTION__;
}

// The CUDA execution backend of the solver templates (chrono_like/solver/solver_algorithms.h): the CPU's
// algorithms and kern:: functors, run as kernels over the device vectors. Reductions are deterministic
// (fixed grid, partials summed in order) and read back to the host, where the scalar logic runs.
class GpuOps {
 public:
  static constexpr bool kDeviceLoop = true;
  // Over several processes (d.group) every reduction is summed over them, the block count and the largest
  // diagonal are the whole problem's, and APGD's trials keep their control on the host (each trial's test sums cross
  // the processes: apgdIterateOnDevice).
  GpuOps(DeviceState& d, const ProblemView& p, const ApgdLaunch& launch, bool float_storage)
      : d_(d), p_(p), launch_(launch), float_(float_storage), group_(d.group) {
    SolverScratch& S = d.solver;
    DeviceBuffer<real>* bufs[kVecs] = {&S.v0, &S.v1, &S.v2, &S.v3, &S.v4, &S.v5, &S.v6, &S.v7, &S.v8};
    for (int i = 0; i < kVecs; ++i) bufs_[i] = bufs[i];
    for (int i = 0; i < 7; ++i) vec(i);  // 7 and 8 (APGD's speculation) only when asked for
    total_ = p_.nb;
    if (group_) {
      double v[1] = {double(p_.nb)};
      group_->sum(v, 1);
      total_ = int64_t(v[0]);
      const double m = group_->max(p_.nb > 0 ? double(p_.max_diag) : 0.0);  // ContactProblem::maxDiagonal's rule
      p_.max_diag = m > 0 ? real(m) : real(1);
    }
  }
  int64_t totalBlocks() const { return total_; }
  int64_t blocks() const { return p_.nb; }
  BlockSet blockSet() const { return BlockSet{p_.nc, p_.mu, p_.lo, p_.hi}; }
  const real* rhs() const { return p_.r; }
  const real* blockSteps() const { return p_.eta; }
  const real* jacobiSteps() const { return p_.jeta; }
  const real* blockInverses() const { return p_.binv; }
  real maxDiagonal() const { return p_.max_diag; }
  real* vec(int i) {
    if (i < 0 || i >= kVecs) throw std::logic_error("GpuOps: solver vector " + std::to_string(i) + " does not exist");
    bufs_[i]->resize(size_t(3 * p_.nb));
    return bufs_[i]->data();
  }
  void schur(const real* x, real* y) { gpu::schur(d_, x, y); }
  template <class F>
  void map(const F& f) {
    launchMap(d_, p_.nb, f, functorName<F>());
  }
  template <int M, class F>
  void reduce(const F& f, double* out) {
    const double* h = launchReduce<M>(d_, p_.nb, f, functorName<F>());
    for (int m = 0; m < M; ++m) out[m] = h[m];
    if (group_) group_->sum(out, M);
  }
  // The sums land in slots of 8 doubles of S.scalars, read back together by fetch().
  template <int M, class F>
  void reduceLater(const F& f, double* out) {
    static_assert(M <= kSlotSize, "GpuOps::reduceLater: at most 8 sums a reduction");
    if (pending_ == kSlots) fetch();
    launchReduce<M>(d_, p_.nb, f, functorName<F>(), false, pending_ * kSlotSize);
    pending_out_[pending_] = out;
    pending_m_[pending_] = M;
    ++pending_;
  }
  void fetch() {
    if (pending_ == 0) return;
    const double* h = d_.readScalars(d_.solver.scalars.data(), pending_ * kSlotSize);
    double all[kSlots * kSlotSize];
    int n = 0;
    for (int i = 0; i < pending_; ++i)
      for (int m = 0; m < pending_m_[i]; ++m) all[n++] = h[i * kSlotSize + m];
    if (group_) group_->sum(all, n);  // one collective for every sum of the fetch
    n = 0;
    for (int i = 0; i < pending_; ++i)
      for (int m = 0; m < pending_m_[i]; ++m) pending_out_[i][m] = all[n++];
    pending_ = 0;
  }
  void copy(const real* src, real* dst) {
    if (src == dst) return;
    DVI_CUDA(cudaMemcpyAsync(dst, src, sizeof(real) * size_t(3 * p_.nb), cudaMemcpyDeviceToDevice, d_.stream));
  }
  // SolverSettings::record_history: the GPU step reports the iterations and the final residual only
  // (solveCcp), so the device loop keeps no per-iteration residuals (st is left as it is).
  void apgdIterate(algo::ApgdControl& c, real* const* X, real* const* NX, real a, real inv_a, const SolverSettings& s,
                   SolverStats& /*st*/) {
    apgdIterateOnDevice(d_, p_.nb, c, X, NX, a, inv_a, s, blockSet(), rhs(), blockSteps(), launch_, float_);
  }

 private:
  DeviceState& d_;
  ProblemView p_;
  ApgdLaunch launch_;
  bool float_;
  const ProcessGroup* group_;
  int64_t total_ = 0;
  static constexpr int kVecs = 9;
  DeviceBuffer<real>* bufs_[kVecs] = {};
  static constexpr int kSlots = 8, kSlotSize = 8;  // 64 doubles: DeviceState::host_scalars
  int pending_ = 0;
  double* pending_out_[kSlots] = {};
  int pending_m_[kSlots] = {};
};

ProblemView view(DeviceState& d, real max_diag) {
  ProblemView p;
  p.nc = d.normal_only ? 0 : int64_t(d.contacts.count);  // cone blocks; normal-only blocks are boxes
  p.nb = d.contact_blocks + int64_t(d.solver.rows.size() / 3);
  p.lo = d.solver.row_lo.data();
  p.hi = d.solver.row_hi.data();
  p.r = d.solver.rhs.data();
  p.mu = d.contacts.mu.data();
  p.eta = d.solver.block_step.data();
  p.jeta = d.solver.jacobi_step.data();
  p.binv = d.solver.block_inv.data();
  p.max_diag = max_diag;
  return p;
}

// Each contact's impulses from the handed-over table (DeviceState::extra_key) where it has the key, else from last
// step's, else zero.
struct WarmF {
  const uint64_t* key;
  const uint64_t* prev_key;
  const real* prev_gamma;
  int64_t np;
  const uint64_t* extra_key;
  const real* extra_gamma;
  int64_t ne;
  real* gamma;
  __device__ void operator()(int64_t k) const {
    const uint64_t x = key[k];
    const int64_t e = findSorted(extra_key, ne, x);
    const int64_t j = e >= 0 ? -1 : findSorted(prev_key, np, x);
    for (int r = 0; r < 3; ++r)
      gamma[3 * k + r] = e >= 0 ? extra_gamma[3 * e + r] : (j >= 0 ? prev_gamma[3 * j + r] : real(0));
  }
};

struct GatherByIndexF {
  const int32_t* idx;
  const real* gamma;
  real* out;
  __device__ void operator()(int64_t i) const {
    for (int r = 0; r < 3; ++r) out[3 * i + r] = gamma[3 * int64_t(idx[i]) + r];
  }
};

struct GatherVec3F {
  const int32_t* idx;
  const Vec3* in;
  Vec3* out;
  __device__ void operator()(int64_t i) const { out[i] = in[idx[i]]; }
};

struct IotaF {
  int32_t* x;
  __device__ void operator()(int64_t i) const { x[i] = int32_t(i); }
};

struct VelocityF {
  const Vec3 *v_free, *w_free;
  const BodyDelta* delta;  // null: no contacts
  Vec3 *vel, *omega;
  __device__ void operator()(int64_t i) const {
    Vec3 v = v_free[i], w = w_free[i];
    if (delta) {
      v += delta[i].v;
      w += delta[i].w;
    }
    vel[i] = v;
    omega[i] = w;
  }
};

}  // namespace

void warmStart(DeviceState& d, bool enabled, const std::vector<real>& row_lambda) {
  const int64_t nc = int64_t(d.contacts.count);
  SolverScratch& S = d.solver;
  const int64_t nrows = int64_t(d.row_count);
  S.gamma.resize(3 * nc + S.rows.size());
  S.gamma.fillZero(d.stream);
  if (nrows > 0 && int64_t(row_lambda.size()) == nrows)  // rows: by index, while their count is unchanged
    DVI_CUDA(cudaMemcpyAsync(S.gamma.data() + 3 * nc, row_lambda.data(), sizeof(real) * size_t(nrows),
                             cudaMemcpyHostToDevice, d.stream));
  if (!enabled || nc == 0 || (d.prev_count == 0 && d.extra_count == 0)) {
    DVI_CUDA(cudaStreamSynchronize(d.stream));  // row_lambda may change after we return
    return;
  }
  launchMap(d, nc,
            WarmF{d.contacts.key.data(), S.prev_key.data(), S.prev_gamma.data(), int64_t(d.prev_count),
                  d.extra_key.data(), d.extra_gamma.data(), int64_t(d.extra_count), S.gamma.data()},
            "launch of WarmF");
}

real* solution(DeviceState& d) { return d.normal_only ? d.solver.x.data() : d.solver.gamma.data(); }

SolverStats solveCcp(DeviceState& d, const SystemConfig& cfg) {
  const ProblemView pv = view(d, d.max_diag);
  GpuOps ops(d, pv, ApgdLaunch{cfg.gpu.graphs, cfg.gpu.persistent_max_blocks, cfg.gpu.apgd_register_cache},
             floatStorage(cfg.solver, true));
  SolverScratch& S = d.solver;
  const int64_t nc = int64_t(d.contacts.count);
  if (d.normal_only) {  // gamma (3 per contact, then the rows) -> x (normal layout), as ContactProblem::toSolverLayout
    S.x.resize(size_t(3 * pv.nb));
    launchMap(d, 3 * pv.nb, kern::ToNormalLayout{S.gamma.data(), S.x.data(), nc, d.contact_blocks},
              "launch of ToNormalLayout");
  }
  real* gamma = solution(d);
  SolverStats st;
  switch (cfg.solver.type) {
    case SolverType::Jacobi: st = algo::jacobi(ops, gamma, cfg.solver); break;
    case SolverType::BB: st = algo::bb(ops, gamma, cfg.solver); break;
    case SolverType::GaussSeidel:  // refused by GpuSystem's constructor, and here when a config edit asks for it
      throw InputError("GPU backend: Gauss-Seidel is sequential; use jacobi, apgd or bb on the GPU");
    case SolverType::APGD:
    default: st = algo::apgd(ops, gamma, cfg.solver); break;
  }
  if (d.normal_only)
    launchMap(d, int64_t(S.gamma.size()), kern::FromNormalLayout{S.x.data(), S.gamma.data(), nc, d.contact_blocks},
              "launch of FromNormalLayout");
  return st;
}

void keepImpulsesForWarmStart(DeviceState& d) {
  const int64_t nc = int64_t(d.contacts.count);
  SolverScratch& S = d.solver;
  S.prev_key.resize(nc);
  S.prev_gamma.resize(3 * nc);
  S.prev_normal.resize(nc);
  d.prev_count = size_t(nc);
  if (nc == 0) return;
  if (!d.keys_unsorted) {  // the narrow phase emits contacts in key order: a copy
    DVI_CUDA(cudaMemcpyAsync(S.prev_key.data(), d.contacts.key.data(), sizeof(uint64_t) * nc, cudaMemcpyDeviceToDevice,
                             d.stream));
    DVI_CUDA(cudaMemcpyAsync(S.prev_gamma.data(), S.gamma.data(), sizeof(real) * 3 * nc, cudaMemcpyDeviceToDevice,
                             d.stream));
    DVI_CUDA(cudaMemcpyAsync(S.prev_normal.data(), d.contacts.normal.data(), sizeof(Vec3) * nc,
                             cudaMemcpyDeviceToDevice, d.stream));
    return;
  }
  S.order.resize(nc);
  S.order_sorted.resize(nc);
  launchMap(d, nc, IotaF{S.order.data()}, "launch of IotaF");
  cubRun(d, "cub::DeviceRadixSort::SortPairs (contact keys)", [&](void* t, size_t& b) {
    return cub::DeviceRadixSort::SortPairs(t, b, d.contacts.key.data(), S.prev_key.data(), S.order.data(),
                                           S.order_sorted.data(), int(nc), 0, 64, d.stream);
  });
  launchMap(d, nc, GatherByIndexF{S.order_sorted.data(), S.gamma.data(), S.prev_gamma.data()},
            "launch of GatherByIndexF");
  launchMap(d, nc, GatherVec3F{S.order_sorted.data(), d.contacts.normal.data(), S.prev_normal.data()},
            "launch of GatherVec3F");
}

void applyImpulsesToBodies(DeviceState& d, const real* gamma) {
  DeviceBodies& B = d.bodies;
  const int64_t nb = int64_t(B.count);
  if (d.group && !gamma) {  // no contacts here: a gather of zero shares still takes part in the exchange
    d.solver.v0.resize(3);
    gamma = d.solver.v0.data();
  }
  if (gamma) { gather(d, gamma, "launch of GatherF (impulses)"); }
  launchMap(d, nb,
            VelocityF{B.v_free.data(), B.w_free.data(), gamma ? B.delta.data() : nullptr, B.vel.data(), B.omega.data()},
            "launch of VelocityF");
}

}  // namespace dvi::gpu
