#include "gpu/gpu_testing.h"

#include "chrono_like/narrowphase.h"
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
                          const std::vector<Pose>& wb, const std::vector<Vec3>& hull,
                          const std::vector<real>& envelope, std::vector<int>& counts,
                          std::vector<ContactPoint>& out) {
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

}  // namespace dvi::gpu
