// The Bullet drop-in demo: a classic Bullet app (triangle-mesh ground, a stack of boxes, a pile of mixed
// shapes, a paddle on a motorised hinge) that runs on Bullet's own world or on dvisim's DVI world. The only
// difference is the line that constructs the world, chosen at compile time (CMake builds both:
// demo_bullet_drop_in_bullet and demo_bullet_drop_in_dvi). Both print the same summary.
//
//   demo_bullet_drop_in_dvi [SECONDS] [gpu]
#include <btBulletDynamicsCommon.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>

#include "demo_scene.h"

#ifdef DVISIM_DROP_IN
#include <dvisim/bullet_world.h>
#include <dvisim/gpu.h>
#endif

int main(int argc, char** argv) {
  const double seconds = argc > 1 ? std::atof(argv[1]) : 3.0;
  if (!(seconds > 0)) {
    std::fprintf(stderr, "demo: error: SECONDS must be a positive number\n");
    return 2;
  }
  try {
    btDefaultCollisionConfiguration config;
    btCollisionDispatcher dispatcher(&config);
    btDbvtBroadphase broadphase;
    btSequentialImpulseConstraintSolver solver;
#ifdef DVISIM_DROP_IN
    dvi::DviWorldConfig dvi_config;  // the CPU backend by default; "gpu" on the command line picks the GPU
    if (argc > 2 && std::strcmp(argv[2], "gpu") == 0) {
      dvi_config.backend = dvi::WorldBackend::Gpu;
      dvi_config.make_gpu_system = dvi::makeGpuSystem;  // the world takes the GPU backend from the app
    }
    dvi::DviDynamicsWorld world(&dispatcher, &broadphase, &solver, &config, dvi_config);
    const char* engine = "dvisim DVI world";
#else
    btDiscreteDynamicsWorld world(&dispatcher, &broadphase, &solver, &config);
    const char* engine = "Bullet btDiscreteDynamicsWorld";
#endif
    drop_in::Scene scene;
    scene.build(world);
    const auto t0 = std::chrono::steady_clock::now();
    const int frames = int(seconds * 60 + 0.5);
    for (int f = 0; f < frames; ++f) world.stepSimulation(btScalar(1) / 60, 10, drop_in::kSubStep);
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("%s", scene.summary(world, frames / 60.0).c_str());
    std::fprintf(stderr, "[%s: %.3f s wall]\n", engine, wall);
    scene.destroy(world);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "demo: error: %s\n", e.what());
    return 2;
  }
  return 0;
}
