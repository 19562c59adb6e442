// The Bullet 3 peer of the scaling benchmark: a benchmark scene (scaling_scenes.h) stepped by Bullet 3's
// OpenCL GPU pipeline (b3GpuRigidBodyPipeline: SAP broad phase, b3GpuNarrowPhase, batched PGS contact
// solver), so `dvisim bench scaling` can put it beside our engines and Bullet 2 (docs/MODEL.md §8).
//
// Built only where Debian's libbullet-dev ships Bullet3OpenCL and OpenCL is found (bench/scaling/CMakeLists.txt);
// elsewhere bullet3PeerBuilt() says why and the constructor throws. The benchmark runs each configuration
// in a child process (`dvisim bench bullet3-worker`, bench_scaling.cpp), because Bullet 3 ignores most of its
// own OpenCL errors and can crash or hang after one; the tests use the class directly.
//
// What the peer sets, and what Bullet 3 fixes whatever we set (Bullet 3.24 sources, named below):
// - Units: the scene is given in centimetres (length_scale 100, as the Bullet 2 peer), gravity scaled to
//   match. Bullet 3's tolerances are absolute lengths too: 0.01 AABB margin (b3GpuRigidBodyPipeline::
//   registerPhysicsInstance), 0.02 contact distance of hull pairs (primitiveContacts.cl), 0.005 position
//   drift (b3Solver.h ConstraintCfg) and 6-unit solver batching cells (b3GpuPgsContactSolver.cpp).
// - Friction: the contact kernels write mu = 0.7 into every contact constraint (solverSetup.cl,
//   `dstC->m_linear.w = 0.7f`) and ignore the bodies' coefficients, so Bullet 3 runs mu = 0.7, not the
//   scene's 0.5. The peer cannot change it without patching Bullet's kernels.
// - Solver: 4 PGS iterations and a solver time step of 1/60 s for its position correction, whatever the
//   step (b3GpuPgsContactSolver::solveContacts); angular velocities damped by 0.99 every step
//   (b3GpuRigidBodyPipeline::integrate).
// - Inertia: Bullet 3 derives it from the shape's bounding box; the peer overwrites it with the scene's
//   principal inertia (x length_scale^2) before the bodies go to the device. Masses are the scene's.
// - Capacities (b3Config): bodies, shapes, broad-phase pairs and contacts are sized from the scene
//   (pairs_per_body); running over one is reported as an error, never truncated silently.
// - Shapes: spheres and the ground plane natively; boxes, the walls and convex hulls as Bullet 3 convex
//   hulls; cylinders and ellipsoids, which Bullet 3's GPU pipeline lacks, as the convex hulls of
//   withConvexHulls (scaling_scenes.h), which is also the scene to measure its penetration on. Seen on pocl
//   (the only OpenCL device this was written on): Bullet 3's sphere-hull test (primitiveContacts.cl,
//   computeContactSphereConvex) gives up on the first face whose plane is within the radius but whose polygon
//   is not, so spheres sink into the mix's rounded hulls at edges and vertices, and its GPU SAT missed some
//   hull-hull contacts that its CPU SAT finds; boxes and the pile behave. The mix rows' penetration shows
//   what a GPU driver does.
//
// Failures (no device, an OpenCL error, an allocation failure, a capacity overflow, a kernel that fails to
// build, a b3Error message from the library) throw Bullet3Error with a one-line reason.
#pragma once

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "chrono_like/base/errors.h"
#include "scaling/scaling_scenes.h"

namespace dvi::bench {

struct Bullet3Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Which OpenCL devices the peer may use: GPUs (the benchmark's default), CPUs (pocl, for tests on
// machines without a GPU) or any, GPUs first.
enum class OpenClDeviceType { Gpu, Cpu, Any };

inline const char* openClDeviceTypeName(OpenClDeviceType t) {
  return t == OpenClDeviceType::Gpu ? "gpu" : t == OpenClDeviceType::Cpu ? "cpu" : "any";
}

inline OpenClDeviceType parseOpenClDeviceType(const std::string& name) {
  if (name == "gpu") return OpenClDeviceType::Gpu;
  if (name == "cpu") return OpenClDeviceType::Cpu;
  if (name == "any") return OpenClDeviceType::Any;
  throw InputError("OpenCL device type '" + name + "' (expected gpu, cpu or any)");
}

struct Bullet3PeerSettings {
  real dt = real(1e-3);
  real length_scale = 100;          // Bullet units per scene unit: centimetres (see above)
  Vec3 gravity{0, real(-9.81), 0};  // scene units
  OpenClDeviceType device = OpenClDeviceType::Gpu;
  int pairs_per_body = 16;  // broad-phase pair and contact capacity per body (Bullet's GPU demos use 16)
  // Where Bullet 3 keeps the kernels it compiled (it reads and writes `<dir>/<kernel>.<device>.<driver>.bin`;
  // without a directory it would write ./cache). Empty: <temp>/dvisim-bullet3-kernels-<uid>.
  std::string kernel_cache_dir;
};

struct Bullet3StepStats {
  int64_t contacts = 0;  // contact manifolds of the step (b3GpuNarrowPhase::getNumContactsGpu; one per sphere pair)
  int64_t pairs = 0;     // broad-phase pairs
};

// Whether this build has the peer; where it has not, *why says so.
bool bullet3PeerBuilt(std::string* why = nullptr);

// The first OpenCL device of `type`: true and its description ("NVIDIA H200 (NVIDIA CUDA, OpenCL 3.0 CUDA
// 12.4.131)") in *what, or false and why not (no OpenCL platform, no device of that type, no peer built).
bool findOpenClDevice(OpenClDeviceType type, std::string* what);

class Bullet3Peer {
 public:
  // Builds withConvexHulls(spec) (the ground, the walls, then spec.bodies in order) on the first device of
  // settings.device.
  // Throws Bullet3Error (no device, OpenCL or Bullet 3 failure, not enough device memory) or InputError
  // (bad settings).
  Bullet3Peer(const SceneSpec& spec, const Bullet3PeerSettings& settings);
  ~Bullet3Peer();
  Bullet3Peer(const Bullet3Peer&) = delete;
  Bullet3Peer& operator=(const Bullet3Peer&) = delete;

  // One b3GpuRigidBodyPipeline::stepSimulation(dt) and a clFinish on its queue, so the time of step() is the
  // device's. Throws Bullet3Error when the step failed (an OpenCL error, a message from Bullet 3, a capacity
  // overflow).
  void step();
  const Bullet3StepStats& lastStats() const;

  // The poses and velocities of spec.bodies (scene units), read back from the device (a checked, blocking
  // read; not part of step()).
  void readBodies(std::vector<Vec3>& pos, std::vector<Quat>& rot, std::vector<Vec3>& vel) const;

  size_t bodyCount() const;         // spec.bodies.size()
  std::string deviceName() const;   // as findOpenClDevice
  std::string description() const;  // the pipeline and its settings, for a benchmark row

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace dvi::bench
