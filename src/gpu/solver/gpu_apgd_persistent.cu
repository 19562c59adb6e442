// All APGD trials of a solve in one cooperative kernel, apgdPersistentKernel, whose grid stays resident; the
// per-element work is that of the trial-by-trial launches (gpu_apgd.cuh, gpu_schur.cuh, gpu_reduce.cuh).
#include <cuda_runtime.h>

#include <algorithm>
#include <cooperative_groups.h>
#include <cstdint>
#include <cuda/atomic>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "chrono_like/solver/solver_algorithms.h"
#include "gpu/gpu_state.cuh"
#include "gpu/solver/gpu_apgd.cuh"
#include "gpu/solver/gpu_reduce.cuh"
#include "gpu/solver/gpu_schur.cuh"

namespace dvi::gpu {

namespace {

// A small problem's trial is bound by its launches: at 10,000 spheres (14,000 contacts) the four kernels of a
// trial took ~25 us on an H100, each waiting for the last and loading the control before its first useful
// load. The persistent kernel runs the same per-element functions over a grid that stays resident, with a
// grid-wide barrier between the passes:
//   (1) the projected step into X[nw];  (2) the gather, heavy bodies by chunks;  (3) Schur pass (b) and the test
//   terms fused per block (the thread that writes a block's N x sums its test terms); the last block to finish
//   sums the partials in slice order into the control state; after the barrier every block reads the five sums
//   and runs ApgdControl::afterTest itself, so all blocks hold the same control.
// With speculation (SolverSettings::apgd_speculation) pass (3) also writes the next trial's step for the accepted
// outcome; when it comes true (ApgdControl::ready) the next trial starts at (2): two barriers a trial.
// Large problems are bound by their bytes (~650 B per contact a trial); there it saves less, but it was still
// faster at every size measured (10k to 1M spheres, H100 and H200: docs/GPU_PERFORMANCE.md), so it is the
// default; GpuTuning::persistent_max_blocks can send problems above a size trial by trial.
// The slices and sums are those of the trial-by-trial launches (reduceSlice, reducePartials), so both paths
// give bitwise the same iterates ([gpu] test "GPU APGD on the device").
template <class V, class JT>
struct PersistentApgd {
  ApgdBuffers<V> B;
  GatherT<JT> g;  // x set per trial
  const ConstraintRow* rows;
  int64_t nc, ncb, n;  // contacts, contact blocks, blocks (contact blocks, then row blocks)
  int64_t nbodies;
  bool normal_only;
  int slices;  // of the test reduction (apgdSlices), as launchApgdTrial's grid
  double* partial;
  const int32_t* heavy;
  int32_t n_heavy;
  real* heavy_partial;
  uint32_t* heavy_ticket;
  ApgdDeviceState* st;
  long long* stamps;  // null, or kPhaseStampTrials x kPhaseStamps clock64() stamps of block 0 (DVISIM_APGD_PHASES)
};

constexpr int kPhaseStampTrials = 64;
constexpr int kPhaseStamps = 6;  // step | wait | gather | wait | Schur (b) + test (+ the last block's sums) | wait

// Schur pass (b) of block i, the same functors as schur(): contact i (or the normal rows 3i..3i+2), or row
// block i - ncb. keep: when set, also the block's 3 values written.
template <class V, class JT>
__device__ __forceinline__ void schurBlock(const PersistentApgd<V, JT>& p, int64_t i, const SchurOut<V>& out,
                                           V* keep = nullptr) {
  if (i < p.ncb) {
    if (p.normal_only) {
      const NormalContactF<V, JT> f{p.g.jac, p.g.delta, p.nc, out};
      for (int j = 0; j < 3; ++j) f(3 * i + j, keep ? keep + j : nullptr);
    } else {
      ContactF<V, JT>{p.g.jac, p.g.delta, out}(i, keep);
    }
  } else {
    const RowSchurF<V> f{p.rows, p.g.delta, out, 3 * p.ncb};
    for (int j = 0; j < 3; ++j) f(3 * (i - p.ncb) + j, keep ? keep + j : nullptr);
  }
}

template <class V, class JT>
struct SchurTestF {  // pass (3): block i's N x, then its test terms (which read that N x back, same thread)
  const PersistentApgd<V, JT>& p;
  SchurOut<V> out;
  kern::ApgdTestT<V> test;
  __device__ void operator()(int64_t i, double* acc) const {
    schurBlock(p, i, out);
    test(i, acc);
  }
};

__device__ __forceinline__ void phaseStamp(long long* stamps, int trial, int j) {
  if (stamps && blockIdx.x == 0 && threadIdx.x == 0 && trial < kPhaseStampTrials)
    stamps[kPhaseStamps * trial + j] = clock64();
}

// The register-cached form's iterates at the start of a solve: g_k, g_{k-1} and their Schur values of the
// thread's blocks tid + j * stride (j < K).
template <int K, class V, class JT, int KC>
__device__ __forceinline__ void loadCachedIterates(const PersistentApgd<V, JT>& p, const algo::ApgdControl& c,
                                                   int64_t tid, int64_t stride, real (&cur)[KC][3], real (&old)[KC][3],
                                                   V (&ncur)[KC][3], V (&nold)[KC][3]) {
  const real *xc = pickX(p.B, c.cur), *xo = pickX(p.B, c.old);
  const V *nc = pickNX(p.B, c.ncur), *no = pickNX(p.B, c.nold);
#pragma unroll
  for (int j = 0; j < K; ++j) {
    const int64_t k = tid + j * stride;
    if (k >= p.n) continue;
    for (int m = 0; m < 3; ++m) {
      cur[j][m] = xc[3 * k + m], old[j][m] = xo[3 * k + m];
      ncur[j][m] = nc[3 * k + m], nold[j][m] = no[3 * k + m];
    }
  }
}

// The register-cached form's g_{k+1} when the last trial's pass (3) wrote it (speculation): the same thread
// wrote the same blocks.
template <int K, class V, class JT, int KC>
__device__ __forceinline__ void loadCachedStep(const PersistentApgd<V, JT>& p, const real* xn, int64_t tid,
                                               int64_t stride, real (&nxt)[KC][3]) {
#pragma unroll
  for (int j = 0; j < K; ++j) {
    const int64_t k = tid + j * stride;
    if (k >= p.n) continue;
    for (int m = 0; m < 3; ++m) nxt[j][m] = xn[3 * k + m];
  }
}

// Pass (1): the projected step into xn = X[nw] (K > 0: from the registers, also kept in nxt).
template <int K, class V, class JT, int KC>
__device__ __forceinline__ void persistentStep(const PersistentApgd<V, JT>& p, const algo::ApgdControl& c, real* xn,
                                               int64_t tid, int64_t stride, const real (&cur)[KC][3],
                                               const real (&old)[KC][3], const V (&ncur)[KC][3], const V (&nold)[KC][3],
                                               real (&nxt)[KC][3]) {
  constexpr bool grad_form = !std::is_same_v<V, real>;  // float Schur buffers hold N x + r
  if constexpr (K > 0) {
    const real t = real(1) / c.L;
#pragma unroll
    for (int j = 0; j < K; ++j) {
      const int64_t k = tid + j * stride;
      if (k >= p.n) continue;
      kern::apgdStepBlock<V>(p.B.bs, k, cur[j], old[j], ncur[j], nold[j], grad_form ? nullptr : p.B.r + 3 * k,
                             t * p.B.eta[k], c.beta, nxt[j]);
      for (int m = 0; m < 3; ++m) xn[3 * k + m] = nxt[j][m];
    }
  } else {
    const kern::ApgdStepT<V> f = apgdStepOf(p.B, c);
    for (int64_t k = tid; k < p.n; k += stride) f(k);
  }
}

// Pass (2): Schur pass (a), the gather of xn, heavy bodies by chunks.
template <class V, class JT>
__device__ __forceinline__ void persistentGather(const PersistentApgd<V, JT>& p, real* xn, int64_t tid,
                                                 int64_t stride) {
  GatherT<JT> g = p.g;
  g.x = xn;
  for (int64_t i = tid; i < p.nbodies; i += stride) g(i);
  for (int32_t w = int32_t(blockIdx.x); w < p.n_heavy * kHeavyChunks; w += int32_t(gridDim.x))
    heavyGatherChunk(p.heavy, g, xn, p.heavy_partial, p.heavy_ticket, w / kHeavyChunks, w % kHeavyChunks);
}

// Pass (3): Schur pass (b) into NX[nnw] and the test terms, summed into this block's slice partials (K > 0: the
// thread's blocks from the registers, their N x also kept in nnxt).
template <int K, class V, class JT, int KC>
__device__ __forceinline__ void persistentSchurTest(const PersistentApgd<V, JT>& p, const algo::ApgdControl& c,
                                                    int64_t tid, int64_t stride, const real (&cur)[KC][3],
                                                    const real (&old)[KC][3], const V (&ncur)[KC][3],
                                                    const V (&nold)[KC][3], const real (&nxt)[KC][3],
                                                    V (&nnxt)[KC][3]) {
  constexpr bool grad_form = !std::is_same_v<V, real>;
  const SchurOut<V> out{pickNX(p.B, c.nnw), nullptr, grad_form ? p.B.r : nullptr};
  if constexpr (K > 0) {
    double acc[5] = {0, 0, 0, 0, 0};
    const kern::ApgdSpeculation sp = apgdSpeculationOf(p.B, c);
#pragma unroll
    for (int j = 0; j < K; ++j) {
      const int64_t k = tid + j * stride;
      if (k >= p.n) continue;
      schurBlock(p, k, out, nnxt[j]);
      kern::apgdTestBlock<V>(p.B.bs, k, cur[j], old[j], ncur[j], nold[j], nxt[j], nnxt[j], p.B.r + 3 * k, p.B.eta[k],
                             c.beta, p.B.a, p.B.inv_a, grad_form, acc, sp);
    }
    if (int(blockIdx.x) < p.slices) blockSumFixed<5>(acc, p.partial + int64_t(blockIdx.x) * 5);
  } else {
    const SchurTestF<V, JT> f{p, out, apgdTestOf(p.B, c)};
    for (int s = int(blockIdx.x); s < p.slices; s += int(gridDim.x)) reduceSlice<5>(s, p.slices, p.n, f, p.partial);
  }
}

// The last block to finish pass (3) sums the partials in slice order into the control state's sums. (Every block
// summing them itself contended for the same L2 lines: 9 us a trial at 100,000 contacts on an H100.) last and
// sums: the kernel's shared flag and sums.
template <class V, class JT>
__device__ __forceinline__ void persistentSumPartials(const PersistentApgd<V, JT>& p, bool& last, double* sums) {
  if (threadIdx.x == 0) {  // thread 0 wrote this block's partials (blockSumFixed)
    // release: they are visible before the block counts itself; acquire: the last block sees every block's
    // (its other threads after the barrier below, reading through L2). One acq_rel atomic in place of two
    // fences.
    cuda::atomic_ref<unsigned, cuda::thread_scope_device> done(p.st->blocks_done);
    last = done.fetch_add(1u, cuda::memory_order_acq_rel) == gridDim.x - 1;
  }
  __syncthreads();
  if (last) {
    reducePartials<5>(p.slices, p.partial, sums);
    if (threadIdx.x == 0) {
      for (int m = 0; m < 5; ++m) p.st->sums[m] = sums[m];
      p.st->blocks_done = 0;
    }
  }
}

// The rotation of afterTest in the registers: g_{k-1} <- g_k <- g_{k+1}, and their Schur values.
template <int K, int KC, class V>
__device__ __forceinline__ void rotateCached(real (&cur)[KC][3], real (&old)[KC][3], const real (&nxt)[KC][3],
                                             V (&ncur)[KC][3], V (&nold)[KC][3], const V (&nnxt)[KC][3]) {
#pragma unroll
  for (int j = 0; j < K; ++j)
    for (int m = 0; m < 3; ++m) {
      old[j][m] = cur[j][m], cur[j][m] = nxt[j][m];
      nold[j][m] = ncur[j][m], ncur[j][m] = nnxt[j][m];
    }
}

// One kernel for both forms. K = 0: every pass reads its inputs from the buffers. K > 0: thread tid owns the
// blocks tid + j * stride (j < K) in the step and in the fused pass (3), whose test slice is then the thread's
// block (the host launches it only when slices == grid, or when every block is in slice blockIdx.x's first
// stride), so the sums are those of reduceSlice, bitwise. The buffers are written as in K = 0 (the gather and
// the caller read them); the registers hold copies of the same values.
template <class V, class JT, int K>
__global__ void __launch_bounds__(kBlock, persistentBlocksPerSm<K>())
    apgdPersistentKernel(const __grid_constant__ PersistentApgd<V, JT> p) {
  namespace cg = cooperative_groups;
  cg::grid_group grid = cg::this_grid();
  __shared__ alignas(algo::ApgdControl) unsigned char c_mem[sizeof(algo::ApgdControl)];
  __shared__ double sums[5];
  __shared__ bool last;
  algo::ApgdControl& c = *reinterpret_cast<algo::ApgdControl*>(c_mem);
  if (threadIdx.x == 0) c = p.st->c;
  __syncthreads();
  const int64_t tid = int64_t(blockIdx.x) * kBlock + threadIdx.x, stride = int64_t(gridDim.x) * kBlock;
  constexpr int KC = K > 0 ? K : 1;
  real cur[KC][3], old[KC][3], nxt[KC][3];  // g_k, g_{k-1}, g_{k+1} of the thread's blocks (K > 0)
  V ncur[KC][3], nold[KC][3], nnxt[KC][3];  // their Schur buffers
  if constexpr (K > 0) loadCachedIterates<K>(p, c, tid, stride, cur, old, ncur, nold);
  for (int trial = 0; !c.done; ++trial) {  // c is the same in every block
    real* xn = pickX(p.B, c.nw);
    phaseStamp(p.stamps, trial, 0);
    if (c.ready) {  // the last trial's pass (3) wrote this step, the same thread the same blocks (speculation)
      if constexpr (K > 0) loadCachedStep<K>(p, xn, tid, stride, nxt);
      phaseStamp(p.stamps, trial, 1);
      phaseStamp(p.stamps, trial, 2);
    } else {
      persistentStep<K>(p, c, xn, tid, stride, cur, old, ncur, nold, nxt);  // (1) the projected step
      phaseStamp(p.stamps, trial, 1);
      grid.sync();
      phaseStamp(p.stamps, trial, 2);
    }
    persistentGather(p, xn, tid, stride);  // (2) Schur pass (a): the gather
    phaseStamp(p.stamps, trial, 3);
    grid.sync();
    phaseStamp(p.stamps, trial, 4);
    persistentSchurTest<K>(p, c, tid, stride, cur, old, ncur, nold, nxt, nnxt);  // (3) Schur pass (b), test terms
    persistentSumPartials(p, last, sums);
    phaseStamp(p.stamps, trial, 5);
    grid.sync();
    if (threadIdx.x == 0) {
      for (int m = 0; m < 5; ++m) sums[m] = __ldcg(p.st->sums + m);
      c.afterTest(sums);
    }
    __syncthreads();
    if constexpr (K > 0) {
      if (c.accepted) rotateCached<K>(cur, old, nxt, ncur, nold, nnxt);
    }
  }
  if (blockIdx.x == 0 && threadIdx.x == 0) p.st->c = c;
}
}  // namespace

template <class V, int K>
int persistentGridMax(DeviceState& d) {
  if (!d.cooperative) return 0;
  int per_sm = 0;
  DVI_CUDA(cudaOccupancyMaxActiveBlocksPerMultiprocessor(
      &per_sm, reinterpret_cast<const void*>(&apgdPersistentKernel<V, JacobianOf<V>, K>), kBlock, 0));
  return per_sm * d.multiprocessors;
}

template <class V, int K>
bool apgdPersistent(DeviceState& d, int64_t n, const ApgdBuffers<V>& B, int grid_max, int slices) {
  if (grid_max < 1) return false;
  using JT = JacobianOf<V>;
  SolverScratch& S = d.solver;
  const JT* jac = contactJacobians<JT>(S);
  PersistentApgd<V, JT> p{};
  p.B = B;
  p.g = gatherOf<JT>(d, jac, nullptr, nullptr);
  p.rows = S.rows.data();
  p.nc = int64_t(d.contacts.count);
  p.ncb = d.contact_blocks;
  p.n = n;
  p.nbodies = int64_t(d.bodies.count);
  p.normal_only = d.normal_only;
  p.slices = slices;
  p.partial = S.partial.data();
  p.heavy = S.heavy.data();
  p.n_heavy = int32_t(S.n_heavy);
  p.heavy_partial = S.heavy_partial.data();
  p.heavy_ticket = S.heavy_ticket.data();
  p.st = S.apgd.data();
  p.stamps = nullptr;
  if (d.phase_profile) {
    S.stamps.resize(size_t(kPhaseStampTrials) * kPhaseStamps);
    S.stamps.fillZero(d.stream);
    p.stamps = S.stamps.data();
  }
  const void* kernel = reinterpret_cast<const void*>(&apgdPersistentKernel<V, JT, K>);
  const int64_t want = std::max<int64_t>({blocksFor(n), blocksFor(p.nbodies), int64_t(p.n_heavy) * kHeavyChunks, 1});
  const unsigned grid = unsigned(std::min<int64_t>(want, grid_max));
  if (K > 0 && (n > int64_t(K) * kBlock * grid || (slices != int(grid) && n > int64_t(slices) * kBlock)))
    throw std::logic_error("apgdPersistent: " + std::to_string(n) + " blocks do not fit the register-cached kernel's " +
                           std::to_string(grid) + " x " + std::to_string(kBlock) + " threads and " +
                           std::to_string(slices) + " slices");
  void* args[] = {&p};
  DVI_CUDA(cudaLaunchCooperativeKernel(kernel, dim3(grid), dim3(kBlock), args, 0, d.stream));
  if (d.phase_profile) {  // DVISIM_APGD_PHASES: block 0's clock at each phase boundary of the first trials
    std::vector<long long> h(size_t(kPhaseStampTrials) * kPhaseStamps);
    DVI_CUDA(
        cudaMemcpyAsync(h.data(), S.stamps.data(), sizeof(long long) * h.size(), cudaMemcpyDeviceToHost, d.stream));
    DVI_CUDA(cudaStreamSynchronize(d.stream));
    for (int t = 0; t + 1 < kPhaseStampTrials && h[size_t(kPhaseStamps * (t + 1))] != 0; ++t) {
      const long long* a = h.data() + kPhaseStamps * t;
      for (int j = 0; j < kPhaseStamps; ++j) d.phase_cycles[j] += double(a[j + 1] - a[j]);
      ++d.phase_trials;
    }
  }
  return true;
}

// The forms the driver launches (gpu_apgd_trials.cu): the Schur buffers of the storage types float and real, each
// plain and register-cached. Instantiated in the order the driver asks for them (float storage first), which
// is the order of the kernels' shared variables in the module, and so their shared-memory offsets.
#if !defined(DVISIM_SINGLE_PRECISION)
template int persistentGridMax<float, 0>(DeviceState&);
template int persistentGridMax<float, kCachedBlocks>(DeviceState&);
template bool apgdPersistent<float, kCachedBlocks>(DeviceState&, int64_t, const ApgdBuffers<float>&, int, int);
template bool apgdPersistent<float, 0>(DeviceState&, int64_t, const ApgdBuffers<float>&, int, int);
#endif
template int persistentGridMax<real, 0>(DeviceState&);
template int persistentGridMax<real, kCachedBlocks>(DeviceState&);
template bool apgdPersistent<real, kCachedBlocks>(DeviceState&, int64_t, const ApgdBuffers<real>&, int, int);
template bool apgdPersistent<real, 0>(DeviceState&, int64_t, const ApgdBuffers<real>&, int, int);

}  // namespace dvi::gpu
