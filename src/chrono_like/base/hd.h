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
// DVI_HD for the large pieces of the narrow phase (support mappings, an MPR pass, box-box, ...): one copy called
// from every site instead of one inlined copy per site. With everything forced inline, the narrow-phase kernel's
// code outgrew the instruction cache: a thread left alone with a deep MPR pair issued an instruction every ~10k
// cycles of its ~400 MPR iterations, and that one thread set the pass's length (ncu, CES feed on an H200).
#define DVI_HD_CALL __host__ __device__ __noinline__ inline
// A loop over a block's 3 components unrolled in device code, so arrays indexed by its counter stay in registers
// (a rolled loop puts them in local memory).
#define DVI_UNROLL _Pragma("unroll")
#else
#define DVI_UNROLL
#define DVI_HD inline
#define DVI_HOST_DEVICE
#define DVI_HD_CALL inline
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
