// Deterministic reductions and element-wise launches of the device solver: a fixed grid sums fixed slices of
// the elements, then one block sums the slices' partials in order, so every sum is bitwise the same from run to
// run. The persistent APGD kernel (gpu_apgd_persistent.cu) runs the same slices (reduceSlice, reducePartials).
#pragma once

#include <cuda_runtime.h>

#include <algorithm>
#include <cstdint>

#include "gpu/gpu_state.cuh"

namespace dvi::gpu {

constexpr int kReduceBlocks = 1024;  // fixed grid of every reduction (deterministic partial order)

template <class F>
__global__ void mapKernel(int64_t n, F f) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i < n) f(i);
}

// Sums acc[0..M) over the block in a fixed order: a fixed shuffle tree per warp, then the warps' sums in order
// by thread 0, which alone holds the result (written to out; one barrier, where a cub::BlockReduce per value
// took one each). Ends with a barrier, so the shared scratch can be used again at once.
template <int M>
__device__ __forceinline__ void blockSumFixed(double* acc, double* out) {
  for (int m = 0; m < M; ++m)
    for (int o = 16; o > 0; o >>= 1) acc[m] += __shfl_down_sync(0xffffffffu, acc[m], o);
  __shared__ double warp_sum[M][kBlock / 32];
  const int lane = threadIdx.x & 31, warp = threadIdx.x >> 5;
  if (lane == 0)
    for (int m = 0; m < M; ++m) warp_sum[m][warp] = acc[m];
  __syncthreads();
  if (threadIdx.x == 0)
    for (int m = 0; m < M; ++m) {
      double s = 0;
      for (int w = 0; w < kBlock / 32; ++w) s += warp_sum[m][w];
      out[m] = s;
    }
  __syncthreads();
}

// Partial `slice` of `slices` of a deterministic reduction: the slice's grid-strided elements of f (element
// slice*kBlock + t + j*slices*kBlock in thread t), summed in a fixed tree. A kernel's block is a slice
// (reduceBlockSlice); the persistent APGD kernel runs the slices of a fixed count over whatever grid it has,
// so both sum every element in the same order.
template <int M, class F>
__device__ __forceinline__ void reduceSlice(int slice, int slices, int64_t n, const F& f, double* partial) {
  double acc[M];
  for (int m = 0; m < M; ++m) acc[m] = 0;
  for (int64_t i = int64_t(slice) * kBlock + threadIdx.x; i < n; i += int64_t(slices) * kBlock) f(i, acc);
  blockSumFixed<M>(acc, partial + int64_t(slice) * M);
}

// Block partials of a deterministic reduction: this block's grid-strided slice of f, summed in a fixed tree.
template <int M, class F>
__device__ __forceinline__ void reduceBlockSlice(int64_t n, const F& f, double* partial) {
  reduceSlice<M>(int(blockIdx.x), int(gridDim.x), n, f, partial);
}

// The partials of nblk blocks summed in a fixed order by one block (strided per thread, then blockSumFixed).
// The result lands in out (thread 0's view only is defined before the final __syncthreads).
template <int M>
__device__ __forceinline__ void reducePartials(int nblk, const double* partial, double* out) {
  double acc[M];
  for (int m = 0; m < M; ++m) acc[m] = 0;
  for (int b = threadIdx.x; b < nblk; b += blockDim.x)
    for (int m = 0; m < M; ++m) acc[m] += __ldcg(partial + b * M + m);  // L2: written by other blocks
  blockSumFixed<M>(acc, out);
}

template <int M, class F>
__global__ void __launch_bounds__(kBlock) reduceKernel(int64_t n, F f, double* partial) {
  reduceBlockSlice<M>(n, f, partial);
}

template <int M>
__global__ void __launch_bounds__(kBlock) finalizeKernel(int nblk, const double* partial, double* out) {
  reducePartials<M>(nblk, partial, out);
}

// Blocks of every deterministic reduction over n elements (a fixed grid: the partials' order is fixed).
inline int reduceBlocksFor(int64_t n) {
  return int(std::max<int64_t>(1, std::min<int64_t>(kReduceBlocks, (n + kBlock - 1) / kBlock)));
}

template <class F>
void launchMap(DeviceState& d, int64_t n, const F& f, const char* what) {
  if (n <= 0) return;
  mapKernel<<<blocksFor(n), kBlock, 0, d.stream>>>(n, f);
  cudaCheck(cudaGetLastError(), what, __FILE__, __LINE__);
}

// Sums M values over n elements; returns a pointer to M doubles on the host (valid until the next read)
// or, with read = false, leaves them on the device only (at S.scalars + slot).
template <int M, class F>
const double* launchReduce(DeviceState& d, int64_t n, const F& f, const char* what, bool read = true, int slot = 0) {
  SolverScratch& S = d.solver;
  const int nblk = reduceBlocksFor(n);
  S.partial.resize(size_t(nblk) * M);
  S.scalars.resize(64);
  reduceKernel<M><<<nblk, kBlock, 0, d.stream>>>(n, f, S.partial.data());
  cudaCheck(cudaGetLastError(), what, __FILE__, __LINE__);
  finalizeKernel<M><<<1, kBlock, 0, d.stream>>>(nblk, S.partial.data(), S.scalars.data() + slot);
  cudaCheck(cudaGetLastError(), what, __FILE__, __LINE__);
  return read ? d.readScalars(S.scalars.data(), M) : nullptr;
}

}  // namespace dvi::gpu
