// Host/device portability for the single-source kernels.
//
// Every per-element operation of the engine (a narrow-phase pair, a Jacobian row, a cone projection,
// an integration step of one body) is written once as an inline function marked DVI_HD. The CPU backend
// calls it from an OpenMP loop, the GPU backend from a CUDA kernel, so the two cannot drift apart
// (Bullet's CPU and GPU copies of one kernel did).
#pragma once

#include <cstdint>

#if defined(__CUDACC__)
#define DVI_HD __host__ __device__ __forceinline__
#define DVI_HOST_DEVICE __host__ __device__
#else
#define DVI_HD inline
#define DVI_HOST_DEVICE
#endif

namespace dvi {

// Scalar type of every per-body and per-contact array. Double by default: the CPU backend is the test
// oracle. The build option DVISIM_SINGLE_PRECISION switches the whole engine to float.
#if defined(DVISIM_SINGLE_PRECISION)
using real = float;
#else
using real = double;
#endif

}  // namespace dvi
