#include "gpu_testing.h"

#include "chrono_like/collision/narrowphase.h"
#include "gpu/device_buffer.h"
#include "gpu/gpu_state.cuh"

namespace dvi::gpu {

namespace {
__global__ void collidePairsKernel(int n, const Shape* a, const Pose* wa, const Shape* b, const Pose* wb,
                                   const Vec3* hull, const real* env, int* counts, ContactPoint* out) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  ContactPoint pts[kMaxContactsPerPair];
  const int m = collideShapes(a[i], wa[i], b[i], wb[i], hull, env[i], pts);
  counts[i] = m;
  for (int k = 0; k < m; ++k) out[size_t(i) * kMaxContactsPerPair + k] = pts[k];
}
}  // namespace

void collidePairsOnDevice(const std::vector<Shape>& a, const std::vector<Pose>& wa, const std::vector<Shape>& b,
                          const std::vector<Pose>& wb, const std::vector<Vec3>& hull, const std::vector<real>& envelope,
                          std::vector<int>& counts, std::vector<ContactPoint>& out) {
  const int n = int(a.size());
  DeviceBuffer<Shape> da("test shapes a"), db("test shapes b");
  DeviceBuffer<Pose> dwa("test poses a"), dwb("test poses b");
  DeviceBuffer<Vec3> dh("test hull");
  DeviceBuffer<real> de("test envelopes");
  DeviceBuffer<int> dc("test counts");
  DeviceBuffer<ContactPoint> dout("test points");
  da.upload(a);
  db.upload(b);
  dwa.upload(wa);
  dwb.upload(wb);
  dh.upload(hull.empty() ? std::vector<Vec3>{Vec3{0, 0, 0}} : hull);
  de.upload(envelope);
  dc.resize(n);
  dout.resize(size_t(n) * kMaxContactsPerPair);
  dout.fillZero();
  if (n > 0) {
    collidePairsKernel<<<blocksFor(n), kBlock>>>(n, da.data(), dwa.data(), db.data(), dwb.data(), dh.data(), de.data(),
                                                 dc.data(), dout.data());
    DVI_CUDA_LAUNCH("collidePairsKernel");
  }
  DVI_CUDA(cudaDeviceSynchronize());
  dc.download(counts);
  dout.download(out);
}

void broadPhaseOnDevice(const ShapeArrays& shapes, const BodyArrays& bodies, const BroadPhaseSettings& settings,
                        int steps, std::vector<ShapePair>& pairs, BroadPhaseStats& stats, bool& sorted) {
  DeviceState d;
  DVI_CUDA(cudaMallocHost(&d.host_scalars, 64 * sizeof(double)));
  try {
    d.shapes.shape.upload(shapes.shape);
    d.shapes.aabb.upload(shapes.aabb);
    d.shapes.count = shapes.shape.size();
    d.bodies.flags.upload(bodies.flags);
    d.bodies.count = bodies.flags.size();
    SystemConfig cfg;
    cfg.collision.broadphase = settings;
    for (int s = 0; s < steps; ++s) broadPhase(d, cfg, &stats);
    sorted = d.broad.edge_by_sort;
    std::vector<uint64_t> keys;
    d.broad.pair_key_sorted.download(keys);
    keys.resize(size_t(d.pairs));
    pairs.clear();
    const uint64_t mask = (uint64_t(1) << d.pair_shift) - 1;
    for (uint64_t k : keys) pairs.push_back(ShapePair{int32_t(k >> d.pair_shift), int32_t(k & mask)});
  } catch (...) {
    cudaFreeHost(d.host_scalars);
    throw;
  }
  cudaFreeHost(d.host_scalars);
}

}  // namespace dvi::gpu

namespace dvi::gpu {

DeviceMemoryHold::DeviceMemoryHold(size_t leave_free) {
  size_t free_bytes = 0, total = 0;
  DVI_CUDA(cudaMemGetInfo(&free_bytes, &total));
  if (free_bytes <= leave_free) return;
  held_ = free_bytes - leave_free;
  DVI_CUDA(cudaMalloc(&ptr_, held_));
}

DeviceMemoryHold::~DeviceMemoryHold() {
  if (ptr_) cudaFree(ptr_);
}

}  // namespace dvi::gpu
