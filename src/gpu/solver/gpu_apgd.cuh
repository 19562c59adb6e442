// APGD trials on the device, shared by the two ways of launching them: the trial-by-trial kernels with CUDA graphs
// (gpu_apgd_trials.cu) and the persistent cooperative kernel (gpu_apgd_persistent.cu). Both build a trial's step
// and test from the same buffers and control (apgdStepOf, apgdTestOf) and sum the same slices, so they give
// bitwise the same iterates.
#pragma once

#include <cuda_runtime.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <type_traits>

#include "chrono_like/solver/jacobian.h"
#include "chrono_like/solver/solver.h"
#include "chrono_like/solver/solver_algorithms.h"
#include "gpu/gpu_state.cuh"
#include "gpu/solver/gpu_reduce.cuh"

namespace dvi::gpu {

// algo::ApgdControl lives in device memory. Every trial is: the projected step, the Schur product, and the
// test reduction, whose last block sums the partials and calls ApgdControl::afterTest, which picks the
// buffers of the next trial (the Schur passes read them through the slots). Once the control is
// done every kernel of a trial returns at once, so the host enqueues a whole batch of trials and reads the
// control back once per batch.
// How the trials of a solve are launched (GpuTuning::graphs, persistent_max_blocks,
// apgd_register_cache).
struct ApgdLaunch {
  bool graphs = true;
  int64_t persistent_max = 0;
  bool register_cache = true;
};

template <class V>
struct ApgdBuffers {
  BlockSet bs;
  const real *r, *eta;
  real* X[6];  // X[4..5]: the speculated steps' (null without speculation)
  V* NX[3];
  real a, inv_a;
};

// X[i] and NX[i] by selects: indexing the kernel-parameter arrays with a run-time index would copy them to
// local memory in every thread (measured: +20% on the 1M-sphere solve, H200).
template <class V>
__device__ __forceinline__ real* pickX(const ApgdBuffers<V>& B, int i) {
  return i == 0 ? B.X[0] : i == 1 ? B.X[1] : i == 2 ? B.X[2] : i == 3 ? B.X[3] : i == 4 ? B.X[4] : B.X[5];
}
template <class V>
__device__ __forceinline__ V* pickNX(const ApgdBuffers<V>& B, int i) {
  return i == 0 ? B.NX[0] : i == 1 ? B.NX[1] : B.NX[2];
}

// The Schur slots in the device state, the output's of the storage type V (by offset: the host passes their
// device addresses to the Schur passes without dereferencing st).
__host__ __device__ inline real** schurXSlot(ApgdDeviceState* st) {
  return reinterpret_cast<real**>(reinterpret_cast<char*>(st) + offsetof(ApgdDeviceState, schur_x));
}
template <class V>
__host__ __device__ V** schurYSlot(ApgdDeviceState* st) {
  char* base = reinterpret_cast<char*>(st);
  if constexpr (std::is_same_v<V, float>)
    return reinterpret_cast<V**>(base + offsetof(ApgdDeviceState, schur_yf));
  else
    return reinterpret_cast<V**>(base + offsetof(ApgdDeviceState, schur_y));
}

// The trial's speculation (algo::speculationOf, on the device's buffers).
template <class V>
__device__ __forceinline__ kern::ApgdSpeculation apgdSpeculationOf(const ApgdBuffers<V>& B,
                                                                   const algo::ApgdControl& c) {
  return kern::ApgdSpeculation{c.sa >= 0 ? pickX(B, c.sa) : nullptr, c.sr >= 0 ? pickX(B, c.sr) : nullptr, c.spec_ta,
                               c.spec_ba, c.spec_tr};
}

// The trial's step and test functors for the control's current buffers (both launch paths).
template <class V>
__device__ __forceinline__ kern::ApgdStepT<V> apgdStepOf(const ApgdBuffers<V>& B, const algo::ApgdControl& c) {
  constexpr bool grad_form = !std::is_same_v<V, real>;  // float Schur buffers hold N x + r
  return kern::ApgdStepT<V>{B.bs,  pickX(B, c.cur), pickX(B, c.old), pickNX(B, c.ncur), pickNX(B, c.nold), B.r,
                            B.eta, c.beta,          real(1) / c.L,   pickX(B, c.nw),    grad_form};
}
template <class V>
__device__ __forceinline__ kern::ApgdTestT<V> apgdTestOf(const ApgdBuffers<V>& B, const algo::ApgdControl& c) {
  constexpr bool grad_form = !std::is_same_v<V, real>;
  return kern::ApgdTestT<V>{B.bs,
                            pickX(B, c.cur),
                            pickX(B, c.old),
                            pickNX(B, c.ncur),
                            pickNX(B, c.nold),
                            pickX(B, c.nw),
                            pickNX(B, c.nnw),
                            B.r,
                            B.eta,
                            c.beta,
                            B.a,
                            B.inv_a,
                            grad_form,
                            apgdSpeculationOf(B, c)};
}

template <class V>
using JacobianOf = std::conditional_t<std::is_same_v<V, real>, ContactJacobian, ContactJacobianF>;

// The forms of the persistent kernel (gpu_apgd_persistent.cu: apgdPersistentKernel<V, JT, K>).
// Blocks of 256 resident per SM (the cooperative grid must fit at once): at most 80 registers a thread (64 for
// 4 blocks spilled the float kernel's loops, and the 100k pile's solve was 20% slower on an H100).
constexpr int kPersistentBlocksPerSm = 3;
// The register-cached form (K = kCachedBlocks): a thread keeps its K blocks' g_k, g_{k-1}, N g_k, N g_{k-1} and
// the trial's g_{k+1} and N g_{k+1} in registers from trial to trial (27 registers a block), so the step reads
// no iterate and the test none but r and eta (of ~650 B a contact a trial, ~200 B). It needs the problem to fit
// K blocks a thread: 2 blocks of 256 per SM (128 registers), K = 2: 135,000 blocks on an H100 or H200.
constexpr int kCachedBlocks = 2;
constexpr int kCachedBlocksPerSm = 2;

template <int K>
constexpr int persistentBlocksPerSm() {
  return K > 0 ? kCachedBlocksPerSm : kPersistentBlocksPerSm;
}

// Slices of the APGD test reduction, the same on every path (bitwise the same sums): at most one per block of
// the persistent grid (497 slices over its 396 blocks made some blocks sum two at 100,000 contacts, and the
// pass took twice as long for all to wait on). A problem that fits the register-cached kernel takes that
// kernel's smaller grid, whether or not the cache is enabled.
struct ApgdGrids {
  int plain = 0;   // persistentGridMax<V, 0>
  int cached = 0;  // persistentGridMax<V, kCachedBlocks>
  bool fitsCache(int64_t n) const { return cached > 0 && n <= int64_t(kCachedBlocks) * kBlock * cached; }
  int slices(int64_t n) const {
    const int r = reduceBlocksFor(n);
    const int g = fitsCache(n) ? cached : plain;
    return g > 0 ? std::min(r, g) : r;
  }
};

// Blocks of the persistent APGD kernel's grid (K: its register-cached form) that fit on the device at once
// (0: no cooperative launch).
template <class V, int K>
int persistentGridMax(DeviceState& d);

// Runs the trials in apgdPersistentKernel over a grid of at most grid_max blocks; false when the device cannot
// run it (grid_max 0), and the caller then launches trial by trial. The control is in S.apgd on entry and on
// return.
template <class V, int K>
bool apgdPersistent(DeviceState& d, int64_t n, const ApgdBuffers<V>& B, int grid_max, int slices);

// Runs APGD's trials from the control c until it is done (GpuOps::apgdIterate): persistent where it fits, else
// trial by trial; float_storage: the Schur buffers as float (VectorStorage::Float).
void apgdIterateOnDevice(DeviceState& d, int64_t n, algo::ApgdControl& c, real* const* X, real* const* NX, real a,
                         real inv_a, const SolverSettings& s, const BlockSet& bs, const real* r, const real* eta,
                         const ApgdLaunch& launch, bool float_storage);

}  // namespace dvi::gpu
