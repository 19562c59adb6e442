#include "gpu/gpu_factory.h"

#if defined(DVISIM_HAVE_CUDA)
#include "gpu/gpu_info.h"
#include "gpu/gpu_system.h"
#endif

namespace dvi {

bool gpuAvailable(std::string* name) {
#if defined(DVISIM_HAVE_CUDA)
  return gpu::queryDevice(name);
#else
  if (name) *name = "this build has no CUDA backend";
  return false;
#endif
}

std::unique_ptr<System> makeGpuSystem(const SystemConfig& config, CollisionFactory bullet_collision) {
#if defined(DVISIM_HAVE_CUDA)
  std::string why;
  if (!gpu::queryDevice(&why)) throw InputError("GPU backend: " + why);
  return std::make_unique<GpuSystem>(config, bullet_collision);
#else
  (void)config;
  (void)bullet_collision;
  throw InputError("GPU backend: this build has no CUDA backend");
#endif
}

int selectGpu(int index) {
#if defined(DVISIM_HAVE_CUDA)
  return gpu::selectDevice(index);
#else
  (void)index;
  return -1;
#endif
}

}  // namespace dvi
