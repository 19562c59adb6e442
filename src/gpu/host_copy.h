// Host-side copies of large buffers on the OpenMP team (compiled as C++ with OpenMP; the CUDA sources are not):
// GpuSystem::syncToHost moves its pinned staging buffer into the host vectors with it.
#pragma once

#include <cstddef>

namespace dvi {

struct HostCopy {
  void* dst;
  const void* src;
  size_t bytes;
};

// Every copy of `parts`, split into chunks of about a megabyte shared by the threads.
void copyInParallel(const HostCopy* parts, int n);

}  // namespace dvi
