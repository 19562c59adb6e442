// APGD's trials on the device: the driver of a solve (apgdIterateOnDevice: the persistent kernel where the device
// runs it, else trial by trial; over several processes trial by trial with the control on the host), and the
// trial-by-trial launches: the step kernel, the Schur product through the
// slots, and the test reduction whose last block updates the control; one trial captured as a CUDA graph and
// launched in batches, with one read-back of the control a batch.
#include <cuda_runtime.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <type_traits>

#include "chrono_like/solver/solver_algorithms.h"
#include "gpu/gpu_state.cuh"
#include "gpu/solver/gpu_apgd.cuh"
#include "gpu/solver/gpu_reduce.cuh"
#include "gpu/solver/gpu_schur.cuh"

namespace dvi::gpu {

namespace {

template <class V>
__global__ void __launch_bounds__(kBlock) apgdStepKernel(int64_t n, ApgdBuffers<V> B, const ApgdDeviceState* st) {
  const int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= n) return;
  const algo::ApgdControl& c = st->c;
  if (c.done || c.ready) return;  // ready: the last trial's test pass wrote this step (speculation)
  apgdStepOf(B, c)(k);
}

// The test reduction, and in its last block to finish (a counter in st; the partials are then summed in
// block order, so the result does not depend on which block is last) the control update.
// HostControl (a problem shared over processes): the last block stores the sums in st->sums and leaves the control
// to the host, which adds the other processes' sums first.
template <class V, bool HostControl>
__global__ void __launch_bounds__(kBlock)
    apgdTestKernel(int64_t n, ApgdBuffers<V> B, ApgdDeviceState* st, double* partial) {
  const algo::ApgdControl& c = st->c;
  if (c.done) return;  // uniform: st->c changes only after every block has counted itself below
  reduceBlockSlice<5>(n, apgdTestOf(B, c), partial);
  __shared__ bool last;
  __threadfence();  // this block's partials are visible before it counts itself
  if (threadIdx.x == 0) last = atomicAdd(&st->blocks_done, 1u) == gridDim.x - 1;
  __syncthreads();
  if (!last) return;
  __threadfence();
  __shared__ double sums[5];
  reducePartials<5>(int(gridDim.x), partial, sums);
  if (threadIdx.x != 0) return;
  if constexpr (HostControl) {
    for (int m = 0; m < 5; ++m) st->sums[m] = sums[m];
    st->blocks_done = 0;
    return;
  }
  algo::ApgdControl next = st->c;
  next.afterTest(sums);
  st->c = next;
  *schurXSlot(st) = next.done ? nullptr : pickX(B, next.nw);
  *schurYSlot<V>(st) = next.done ? nullptr : pickNX(B, next.nnw);
  st->blocks_done = 0;
}

// One trial's launches. HostControl: see apgdTestKernel; a process with no blocks launches the Schur product alone
// (its gather takes part in the exchange of the shared bodies' shares).
template <class V, bool HostControl = false>
void launchApgdTrial(DeviceState& d, int64_t n, const ApgdBuffers<V>& B, ApgdDeviceState* st, int slices) {
  SolverScratch& S = d.solver;
  if (n > 0) {
    apgdStepKernel<V><<<blocksFor(n), kBlock, 0, d.stream>>>(n, B, st);
    cudaCheck(cudaGetLastError(), "launch of apgdStepKernel", __FILE__, __LINE__);
  }
  schur<V>(d, nullptr, nullptr, schurXSlot(st), schurYSlot<V>(st), std::is_same_v<V, real> ? nullptr : B.r);
  if (n == 0) return;
  apgdTestKernel<V, HostControl><<<slices, kBlock, 0, d.stream>>>(n, B, st, S.partial.data());
  cudaCheck(cudaGetLastError(), "launch of apgdTestKernel", __FILE__, __LINE__);
}

// The trials of a problem shared over processes (d.group): the same launches as the device loop's, but the control
// stays on the host: each trial's Schur product exchanges the shared bodies' shares (gather), and its test sums are
// added over the processes (one collective) before ApgdControl::afterTest runs here and the next trial's control
// goes up (pinned staging h, written again only after the read-back that ends the trial).
template <class V>
void apgdTrialsGroup(DeviceState& d, int64_t n, algo::ApgdControl& c, real* const* X, V* const* NX,
                     const ApgdBuffers<V>& B, ApgdDeviceState& h, int slices) {
  SolverScratch& S = d.solver;
  while (!c.done) {
    h.c = c;
    *schurXSlot(&h) = X[c.nw];
    *schurYSlot<V>(&h) = NX[c.nnw];
    DVI_CUDA(cudaMemcpyAsync(S.apgd.data(), &h, sizeof h, cudaMemcpyHostToDevice, d.stream));
    launchApgdTrial<V, true>(d, n, B, S.apgd.data(), slices);
    double sums[5] = {0, 0, 0, 0, 0};
    if (n > 0) {
      const char* sums_on_device = reinterpret_cast<const char*>(S.apgd.data()) + offsetof(ApgdDeviceState, sums);
      DVI_CUDA(cudaMemcpyAsync(h.sums, sums_on_device, sizeof h.sums, cudaMemcpyDeviceToHost, d.stream));
      DVI_CUDA(cudaStreamSynchronize(d.stream));
      for (int m = 0; m < 5; ++m) sums[m] = h.sums[m];
    }
    d.group->sum(sums, 5);
    c.afterTest(sums);
  }
}

// The float loop's start: out = float(N x + r) from the real N x.
struct GradientToFloatF {
  const real *nx, *r;
  float* out;
  __device__ void operator()(int64_t i) const { out[i] = float(nx[i] + r[i]); }
};

// Runs the APGD trials of one solve until the control is done: batches of trials, one read-back each. With
// graphs, one trial is captured once per solve and the batch is that graph launched again and again.
// V = float (VectorStorage::Float, the GPU's default): the 3 Schur buffers are float and hold the gradient
// N x + r (NX[0] converted in); the iterates stay real.
template <class V>
void apgdTrialsOnDevice(DeviceState& d, int64_t n, algo::ApgdControl& c, real* const* X, V* const* NX, real a,
                        real inv_a, const SolverSettings& s, const BlockSet& bs, const real* r, const real* eta,
                        const ApgdLaunch& launch) {
  SolverScratch& S = d.solver;
  S.apgd.resize(1);
  const ApgdGrids grids{persistentGridMax<V, 0>(d), persistentGridMax<V, kCachedBlocks>(d)};
  const int slices = grids.slices(n);  // from the device and n alone: every path sums alike
  S.partial.resize(size_t(slices) * 5);
  const ApgdBuffers<V> B{bs, r, eta, {X[0], X[1], X[2], X[3], X[4], X[5]}, {NX[0], NX[1], NX[2]}, a, inv_a};
  // Staged in pinned memory: the copy does not wait for the stream (a pageable one would), and the host writes
  // the staging again only after a read-back of this solve's control.
  ApgdDeviceState& h = *d.host_apgd;
  h = ApgdDeviceState{};
  h.c = c;
  *schurXSlot(&h) = X[c.nw];
  *schurYSlot<V>(&h) = NX[c.nnw];
  DVI_CUDA(cudaMemcpyAsync(S.apgd.data(), &h, sizeof h, cudaMemcpyHostToDevice, d.stream));
  if (d.group) {
    apgdTrialsGroup<V>(d, n, c, X, NX, B, h, slices);
    return;
  }
  const bool cached = launch.register_cache && grids.fitsCache(n);
  if (n <= launch.persistent_max && (cached ? apgdPersistent<V, kCachedBlocks>(d, n, B, grids.cached, slices)
                                            : apgdPersistent<V, 0>(d, n, B, grids.plain, slices))) {
    DVI_CUDA(cudaMemcpyAsync(&h, S.apgd.data(), sizeof h, cudaMemcpyDeviceToHost, d.stream));
    DVI_CUDA(cudaStreamSynchronize(d.stream));
    c = h.c;
    return;
  }
  cudaGraphExec_t exec = nullptr;
  if (launch.graphs) {
    cudaGraph_t graph = nullptr;
    DVI_CUDA(cudaStreamBeginCapture(d.stream, cudaStreamCaptureModeThreadLocal));
    try {
      launchApgdTrial<V>(d, n, B, S.apgd.data(), slices);
    } catch (...) {
      cudaStreamEndCapture(d.stream, &graph);
      if (graph) cudaGraphDestroy(graph);
      throw;
    }
    DVI_CUDA(cudaStreamEndCapture(d.stream, &graph));
    const cudaError_t e = cudaGraphInstantiate(&exec, graph, 0);
    cudaGraphDestroy(graph);
    DVI_CUDA(e);
  }
  try {
    for (;;) {
      const int remaining = c.max_iterations - c.iterations;
      const int batch = s.tolerance > 0 ? std::min(remaining, 16) : remaining;
      for (int b = 0; b < std::max(1, batch); ++b) {
        if (exec)
          DVI_CUDA(cudaGraphLaunch(exec, d.stream));
        else
          launchApgdTrial<V>(d, n, B, S.apgd.data(), slices);
      }
      DVI_CUDA(cudaMemcpyAsync(&h, S.apgd.data(), sizeof h, cudaMemcpyDeviceToHost, d.stream));
      DVI_CUDA(cudaStreamSynchronize(d.stream));
      c = h.c;
      if (c.done) break;
    }
  } catch (...) {
    if (exec) cudaGraphExecDestroy(exec);
    throw;
  }
  if (exec) DVI_CUDA(cudaGraphExecDestroy(exec));
}

}  // namespace

void apgdIterateOnDevice(DeviceState& d, int64_t n, algo::ApgdControl& c, real* const* X, real* const* NX, real a,
                         real inv_a, const SolverSettings& s, const BlockSet& bs, const real* r, const real* eta,
                         const ApgdLaunch& launch, bool float_storage) {
  if constexpr (!std::is_same_v<real, float>) {
    if (float_storage) {
      SolverScratch& S = d.solver;
      const int64_t len = 3 * n;
      S.vf.resize(size_t(3 * len));
      float* NXf[3];
      for (int i = 0; i < 3; ++i) NXf[i] = S.vf.data() + i * len;
      launchMap(d, len, GradientToFloatF{NX[c.ncur], r, NXf[c.ncur]}, "launch of GradientToFloatF (APGD start)");
      apgdTrialsOnDevice<float>(d, n, c, X, NXf, a, inv_a, s, bs, r, eta, launch);
      if (c.failed) algo::checkFinite(c.failed_value, "apgd", c.iterations);
      return;
    }
  }
  (void)float_storage;
  apgdTrialsOnDevice<real>(d, n, c, X, NX, a, inv_a, s, bs, r, eta, launch);
  if (c.failed) algo::checkFinite(c.failed_value, "apgd", c.iterations);
}

}  // namespace dvi::gpu
