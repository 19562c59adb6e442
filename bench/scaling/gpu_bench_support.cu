// Device copy bandwidth, measured by the benchmarks themselves (docs/MODEL.md §8: report achieved bandwidth
// against the copy ceiling measured on the same device).
#include <cuda_runtime.h>

#include <algorithm>
#include <vector>

#include "gpu/cuda_check.h"
#include "gpu/device_buffer.h"

namespace dvi::gpu {

// GB/s of a device-to-device copy of `bytes`, counting bytes read plus bytes written; median of 10.
double measureCopyBandwidth(size_t bytes) {
  DeviceBuffer<unsigned char> a("bandwidth source"), b("bandwidth target");
  a.resize(bytes);
  b.resize(bytes);
  DVI_CUDA(cudaMemset(a.data(), 1, bytes));
  cudaEvent_t e0, e1;
  DVI_CUDA(cudaEventCreate(&e0));
  DVI_CUDA(cudaEventCreate(&e1));
  DVI_CUDA(cudaMemcpy(b.data(), a.data(), bytes, cudaMemcpyDeviceToDevice));  // warm-up
  std::vector<float> ms;
  for (int i = 0; i < 10; ++i) {
    DVI_CUDA(cudaEventRecord(e0));
    DVI_CUDA(cudaMemcpyAsync(b.data(), a.data(), bytes, cudaMemcpyDeviceToDevice));
    DVI_CUDA(cudaEventRecord(e1));
    DVI_CUDA(cudaEventSynchronize(e1));
    float t = 0;
    DVI_CUDA(cudaEventElapsedTime(&t, e0, e1));
    ms.push_back(t);
  }
  std::sort(ms.begin(), ms.end());
  DVI_CUDA(cudaEventDestroy(e0));
  DVI_CUDA(cudaEventDestroy(e1));
  return 2.0 * double(bytes) / (double(ms[ms.size() / 2]) * 1e-3) * 1e-9;
}

}  // namespace dvi::gpu
