// The [gpu] tests' guard: true where a CUDA device is usable; elsewhere it says why in a Catch2 warning and the
// test returns (a skip that CI without a GPU prints).
#pragma once

#include <catch2/catch.hpp>

#include <string>

#include "gpu/gpu_factory.h"

namespace dvi::testing {

inline bool haveDevice() {
  std::string why;
  if (gpuAvailable(&why)) return true;
  WARN("no CUDA device: skipping (" << why << ")");
  return false;
}

}  // namespace dvi::testing
