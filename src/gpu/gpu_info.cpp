#include "gpu/gpu_info.h"

#include <cuda_runtime.h>

namespace dvi::gpu {

bool queryDevice(std::string* name) {
  int count = 0;
  cudaError_t e = cudaGetDeviceCount(&count);
  if (e != cudaSuccess || count == 0) {
    cudaGetLastError();  // "no device" / "no driver" is an answer here, not an error
    if (name) *name = std::string("no CUDA device (") + cudaGetErrorString(e) + ")";
    return false;
  }
  int dev = 0;
  cudaDeviceProp p{};
  if (cudaGetDevice(&dev) != cudaSuccess || cudaGetDeviceProperties(&p, dev) != cudaSuccess) {
    cudaGetLastError();
    if (name) *name = "CUDA device not usable";
    return false;
  }
  if (name)
    *name = std::string(p.name) + " (" + std::to_string(p.totalGlobalMem >> 20) + " MiB, sm_" +
            std::to_string(p.major) + std::to_string(p.minor) + ")";
  return true;
}

int selectDevice(int index) {
  int count = 0;
  if (cudaGetDeviceCount(&count) != cudaSuccess || count == 0) {
    cudaGetLastError();
    return -1;
  }
  const int dev = index % count;
  if (cudaSetDevice(dev) != cudaSuccess) {
    cudaGetLastError();
    return -1;
  }
  return dev;
}

}  // namespace dvi::gpu
