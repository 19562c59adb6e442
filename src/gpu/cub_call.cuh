// Runs a CUB device-wide algorithm with its two-phase temporary-storage protocol on DeviceState's
// reusable scratch, checking both calls.
#pragma once

#include <cub/cub.cuh>

#include "gpu/cuda_check.h"
#include "gpu/gpu_state.cuh"

namespace dvi::gpu {

// f(void* temp, size_t& bytes) -> cudaError_t, called once to size and once to run.
template <class F>
void cubRun(DeviceState& d, const char* what, F&& f) {
  size_t bytes = 0;
  cudaCheck(f(nullptr, bytes), what, __FILE__, __LINE__);
  d.cub_temp.resize(bytes > 0 ? bytes : 1);
  cudaCheck(f(d.cub_temp.data(), bytes), what, __FILE__, __LINE__);
}

inline int bitsFor(uint64_t max_value) {
  int b = 0;
  while (b < 64 && (uint64_t(1) << b) <= max_value) ++b;
  return b > 0 ? b : 1;
}

}  // namespace dvi::gpu
