// Every CUDA runtime call and every kernel launch is checked; a failure throws std::runtime_error naming
// the call (as written at the call site), the file, the line and CUDA's own error string. Device errors
// are never ignored (docs/MODEL.md §8: Bullet's OpenCL pipeline ignores its allocation failures).
//
//   DVI_CUDA(cudaMemcpyAsync(...));          // a runtime call
//   kernel<<<grid, block, 0, stream>>>(...);
//   DVI_CUDA_LAUNCH("kernel");               // cudaGetLastError after the launch
#pragma once

#include <cuda_runtime.h>

#include <stdexcept>
#include <string>

#include "chrono_like/base/errors.h"

namespace dvi::gpu {

// A DeviceError (errors.h): the CLI exits with code 5 on it.
struct CudaError : DeviceError {
  cudaError_t code;
  CudaError(cudaError_t c, const std::string& what) : DeviceError(what), code(c) {}
};

inline void cudaCheck(cudaError_t e, const char* call, const char* file, int line) {
  if (e == cudaSuccess) return;
  throw CudaError(e, std::string("CUDA error in ") + call + " at " + file + ":" + std::to_string(line) + ": " +
                         cudaGetErrorName(e) + " (" + cudaGetErrorString(e) + ")");
}

}  // namespace dvi::gpu

#define DVI_CUDA(call) ::dvi::gpu::cudaCheck((call), #call, __FILE__, __LINE__)
// After a launch: catches bad launch configurations at once (asynchronous faults surface at the next
// checked synchronizing call, which also names itself).
#define DVI_CUDA_LAUNCH(name) ::dvi::gpu::cudaCheck(cudaGetLastError(), "launch of " name, __FILE__, __LINE__)
