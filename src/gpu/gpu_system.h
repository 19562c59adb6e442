// The GPU system: a System whose per-step arrays live on the device (docs/MODEL.md §6; docs/ARCHITECTURE.md).
//
// The host arrays of System (bodies_, shapes_, contacts_, gamma_) are the upload source and the download
// target only: the step reads and writes device mirrors (structure of arrays, the same layout), and the
// host copies are refreshed by syncToHost() alone, never inside the step loop. Bodies added with addBody()
// (and host edits announced by markHostDirty()) are uploaded at the start of the next step.
//
// Each stage is a sequence of kernels that call the same DVI_HD per-element functions as the CPU backend:
//   IntegrateForces      integrate.h: integrateBodyForces
//   ComputeAabbs         narrowphase.h: shapeAabb
//   BroadPhase           broadphase_kernels.h: aabbBinCount/aabbWriteBins/binPairTest/directPairTest, with CUB
//                        scans, radix sorts and run-length encoding between them
//   NarrowPhase          narrowphase.h: collideShapes (count + scan + write; contacts come out ordered by
//                        (shape_a, shape_b, feature) = by persistent key, as on the CPU)
//   BuildRows            jacobian.h: makeContactJacobian, makeBodyInverseMass, contactBias, contactDiagonalBlock
//   WarmStart            binary search of each key in last step's sorted keys
//   Solve                APGD / Jacobi / BB with the matrix-free Schur product: per-body gather over a
//                        body -> contact CSR (accumulateContactImpulse), then per-contact D^T dv
//                        (contactRelativeVelocity); cone.h: projectCone
//   IntegrateVelocities  the same gather; IntegratePositions integrate.h: integrateBodyPosition
//
// Scalars that size buffers or steer a solver (counts, dot products) are read back as single values; no
// array crosses the bus during a step.
#pragma once

#include <memory>
#include <string>

#include "chrono_like/system.h"

namespace dvi {

namespace gpu {
struct DeviceState;  // device mirrors and scratch (gpu_state.cuh)
// One body's state as GpuSystem::syncBodiesToHost / markBodiesDirty move it.
struct BodyRecord {
  Vec3 pos, vel, omega;
  Quat rot;
  uint8_t flags;
};
// One body's other arrays as GpuSystem::markBodyParamsDirty moves them.
struct BodyParamsRecord {
  Vec3 inv_inertia, force, torque, gravity;
  real inv_mass, friction, restitution;
};
}  // namespace gpu

class GpuSystem : public System {
 public:
  // bullet_collision: as for System (the device steps run the native collision whatever config.collision says).
  explicit GpuSystem(SystemConfig config = {}, CollisionFactory bullet_collision = nullptr);
  ~GpuSystem() override;

  void step() override;
  std::string backendName() const override { return "gpu"; }
  std::string deviceName() const override;

  // Copies body state (pos, rot, vel, omega), shape AABBs, the contacts and their impulses of the last step
  // to the host arrays that bodies(), shapes(), contacts() and impulses() return.
  void syncToHost() override;
  // The host body arrays were edited (mutableBodies()): upload them before the next step.
  void markHostDirty() override { host_dirty_ = true; }
  // A few bodies' pos, rot, vel, omega and flags (one gather or scatter kernel and one copy each way).
  void syncBodiesToHost(const std::vector<int32_t>& ids) override;
  void markBodiesDirty(const std::vector<int32_t>& ids) override;
  // A few bodies' inv_mass, inv_inertia, force, torque, gravity, friction and restitution (one scatter kernel).
  void markBodyParamsDirty(const std::vector<int32_t>& ids) override;
  bool deviceBodies(DeviceBodyRefs& out) override;
  bool deviceContacts(DeviceContactRefs& out) override;

  // On the device arrays (one selection kernel, the selected elements read back).
  void motionBounds(real& vmax, real& wmax) const override;
  std::vector<int32_t> ownedBodiesOutside(Vec3 lo, Vec3 hi) const override;
  std::vector<ContactImpulse> contactImpulsesOf(const std::vector<int32_t>& bodies) const override;

  // Device memory held by this system's buffers, bytes.
  size_t deviceBytes() const;

 protected:
  void integrateForces() override;
  void detectCollisions() override;
  void uploadHandedOverWarmStart();
  void buildAndSolve() override;
  void integrate() override;
  // From the bodies uploaded so far (kept up to date by uploadIfNeeded), not a scan of the host arrays every
  // step (1M bodies: ~4 ms of host time per step, H200 host).
  bool hasGyroscopicBodies() const override { return gyro_bodies_; }

 private:
  void uploadIfNeeded();

  std::unique_ptr<gpu::DeviceState> d_;
  size_t uploaded_bodies_ = 0;
  bool host_dirty_ = true;
  bool gyro_bodies_ = false;                      // an uploaded dynamic body has non-spherical inertia
  std::vector<Vec3> field_force_, field_torque_;  // host scratch of the force fields
  std::vector<int32_t> sel_ids_;                  // host scratch of the selected-body copies
  // The selected bodies' states between the device and the host arrays (syncBodiesToHost, markBodiesDirty), pinned:
  // copies at the full bus bandwidth (a pageable copy of 80,000 states took ~2 ms of every step over processes).
  gpu::BodyRecord* sel_state_ = nullptr;
  size_t sel_state_cap_ = 0;
  gpu::BodyRecord* selectedStates(size_t n);
  std::vector<gpu::BodyParamsRecord> sel_params_;
};

}  // namespace dvi
