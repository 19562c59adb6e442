// RAII device array with capacity growth, so per-step buffers are allocated once and reused; a buffer
// that must hold more grows (x1.5 headroom) instead of dropping elements. An allocation that cannot be
// served throws std::runtime_error stating the bytes asked for, the buffer's name and the free memory:
// never a silent truncation (docs/MODEL.md §8).
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <string>
#include <utility>
#include <vector>

#include "gpu/cuda_check.h"

namespace dvi::gpu {

// Allocates `bytes` on the device or throws, naming what it was for.
inline void* deviceAlloc(size_t bytes, const char* what) {
  if (bytes == 0) return nullptr;
  void* p = nullptr;
  cudaError_t e = cudaMalloc(&p, bytes);
  if (e == cudaErrorMemoryAllocation) {
    cudaGetLastError();  // clear the sticky-free allocation error so later calls are not blamed
    size_t free_b = 0, total_b = 0;
    cudaMemGetInfo(&free_b, &total_b);
    throw CudaError(e, std::string("GPU out of memory: ") + what + " asked for " + std::to_string(bytes) + " bytes (" +
                           std::to_string(bytes >> 20) + " MiB); " + std::to_string(free_b >> 20) + " MiB free of " +
                           std::to_string(total_b >> 20) + " MiB");
  }
  cudaCheck(e, (std::string("cudaMalloc for ") + what).c_str(), __FILE__, __LINE__);
  return p;
}

template <class T>
class DeviceBuffer {
 public:
  explicit DeviceBuffer(const char* name = "buffer") : name_(name) {}
  ~DeviceBuffer() { release(); }
  DeviceBuffer(const DeviceBuffer&) = delete;
  DeviceBuffer& operator=(const DeviceBuffer&) = delete;
  DeviceBuffer(DeviceBuffer&& o) noexcept { swap(o); }
  DeviceBuffer& operator=(DeviceBuffer&& o) noexcept {
    swap(o);
    return *this;
  }

  T* data() { return ptr_; }
  const T* data() const { return ptr_; }
  size_t size() const { return size_; }
  size_t capacity() const { return cap_; }
  size_t bytes() const { return size_ * sizeof(T); }
  const char* name() const { return name_; }

  // Ensures capacity >= n; contents are kept only when keep is true. Room to grow: half again, an eighth for arrays
  // of 256 MiB or more (a pile of 20 million spheres a card then fits 80 GB); an array whose contents go is freed
  // before the new one is made (cudaFree waits for the device).
  void reserve(size_t n, bool keep = false) {
    if (n <= cap_) return;
    const size_t want = n + (n * sizeof(T) >= (size_t(256) << 20) ? n / 8 : n / 2);
    if (!keep && ptr_) {
      DVI_CUDA(cudaFree(ptr_));
      ptr_ = nullptr;
      cap_ = 0;
    }
    T* p = static_cast<T*>(deviceAlloc(want * sizeof(T), name_));
    if (keep && size_ > 0) {
      DVI_CUDA(cudaDeviceSynchronize());  // work in flight on any stream may still write the old array
      DVI_CUDA(cudaMemcpy(p, ptr_, size_ * sizeof(T), cudaMemcpyDeviceToDevice));
    }
    if (ptr_) DVI_CUDA(cudaFree(ptr_));
    ptr_ = p;
    cap_ = want;
  }
  // Sets the logical size, growing (contents not kept) when needed.
  void resize(size_t n) {
    reserve(n);
    size_ = n;
  }
  void resizeKeep(size_t n) {
    reserve(n, true);
    size_ = n;
  }
  void upload(const T* host, size_t n, cudaStream_t s = 0) {
    resize(n);
    if (n) DVI_CUDA(cudaMemcpyAsync(ptr_, host, n * sizeof(T), cudaMemcpyHostToDevice, s));
  }
  void upload(const std::vector<T>& v, cudaStream_t s = 0) { upload(v.data(), v.size(), s); }
  // Grows to v.size() keeping the device contents, and uploads v[first..] (appended elements).
  void uploadTail(const std::vector<T>& v, size_t first, cudaStream_t s = 0) {
    resizeKeep(v.size());
    if (v.size() > first)
      DVI_CUDA(
          cudaMemcpyAsync(ptr_ + first, v.data() + first, (v.size() - first) * sizeof(T), cudaMemcpyHostToDevice, s));
  }
  // Synchronous copy of the first n elements to the host vector (resized to n).
  void download(std::vector<T>& v, size_t n, cudaStream_t s = 0) const {
    v.resize(n);
    if (n) {
      DVI_CUDA(cudaMemcpyAsync(v.data(), ptr_, n * sizeof(T), cudaMemcpyDeviceToHost, s));
      DVI_CUDA(cudaStreamSynchronize(s));
    }
  }
  void download(std::vector<T>& v, cudaStream_t s = 0) const { download(v, size_, s); }
  void fillZero(cudaStream_t s = 0) {
    if (size_) DVI_CUDA(cudaMemsetAsync(ptr_, 0, size_ * sizeof(T), s));
  }
  void release() {
    if (ptr_) cudaFree(ptr_);  // no throw from a destructor path
    ptr_ = nullptr;
    size_ = cap_ = 0;
  }
  void swap(DeviceBuffer& o) noexcept {
    std::swap(ptr_, o.ptr_);
    std::swap(size_, o.size_);
    std::swap(cap_, o.cap_);
    std::swap(name_, o.name_);
  }

 private:
  T* ptr_ = nullptr;
  size_t size_ = 0, cap_ = 0;
  const char* name_ = "buffer";
};

// Untyped scratch for CUB's temporary storage.
using ByteBuffer = DeviceBuffer<unsigned char>;

}  // namespace dvi::gpu
