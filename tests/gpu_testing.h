// Host-callable wrappers around single device kernels, for the [gpu] tests (CUDA builds only): they run one
// DVI_HD function over arrays on the device so a test can compare it with the same function on the host.
#pragma once

#include <vector>

#include "chrono_like/base/data.h"
#include "chrono_like/base/shape.h"
#include "chrono_like/collision/broadphase.h"
#include "chrono_like/collision/contact.h"

namespace dvi::gpu {

// For each i: collideShapes(a[i], wa[i], b[i], wb[i], hull, envelope[i]) on the device. out gets
// kMaxContactsPerPair points per pair, counts the number of valid points of each.
void collidePairsOnDevice(const std::vector<Shape>& a, const std::vector<Pose>& wa, const std::vector<Shape>& b,
                          const std::vector<Pose>& wb, const std::vector<Vec3>& hull, const std::vector<real>& envelope,
                          std::vector<int>& counts, std::vector<ContactPoint>& out);

// The GPU broad phase (gpu_collision.cu: broadPhase) over shapes.shape, shapes.aabb and bodies.flags, run
// `steps` times on the same device state (the later runs start from the bin-edge path the earlier chose). pairs
// and stats are those of the last run; sorted: whether its bin edge needed the sorted extents.
void broadPhaseOnDevice(const ShapeArrays& shapes, const BodyArrays& bodies, const BroadPhaseSettings& settings,
                        int steps, std::vector<ShapePair>& pairs, BroadPhaseStats& stats, bool& sorted);

}  // namespace dvi::gpu

namespace dvi::gpu {

// Takes the device's free memory but `leave_free` bytes (cudaMemGetInfo, one cudaMalloc) for as long as it lives,
// so that another process started meanwhile runs out of device memory for real. held() is what it took.
class DeviceMemoryHold {
 public:
  explicit DeviceMemoryHold(size_t leave_free);
  ~DeviceMemoryHold();
  DeviceMemoryHold(const DeviceMemoryHold&) = delete;
  DeviceMemoryHold& operator=(const DeviceMemoryHold&) = delete;
  size_t held() const { return held_; }

 private:
  void* ptr_ = nullptr;
  size_t held_ = 0;
};

}  // namespace dvi::gpu
