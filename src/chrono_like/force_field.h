// Force fields, the System's extension point for external forces (IntegrateForces): plug-ins (the CES machine's
// forces) implement ForceField; the core never knows what they model. Constraint rows, the other extension point,
// are in constraint_row.h.
#pragma once

#include <cstdint>

#include "chrono_like/base/data.h"
#include "chrono_like/base/math.h"
#include "chrono_like/base/step_context.h"

namespace dvi {

// Raw device pointers to a device backend's body arrays (System::deviceBodies), for plug-ins with device code
// (the CES machine's field and charging kernels). stream: the backend's cudaStream_t; work enqueued on it is
// ordered with the step's.
struct DeviceBodyRefs {
  Vec3* pos = nullptr;
  Quat* rot = nullptr;
  Vec3* vel = nullptr;
  Vec3* omega = nullptr;
  uint8_t* flags = nullptr;
  int64_t count = 0;
  void* stream = nullptr;
};

// A device backend's contacts of the last step (device pointers, one per contact point, the points of a pair
// adjacent), for plug-ins with device code that act on touching bodies.
struct DeviceContactRefs {
  const int32_t* body_a = nullptr;
  const int32_t* body_b = nullptr;
  const real* dist = nullptr;  // signed distance (negative = penetration)
  int64_t count = 0;
  void* stream = nullptr;
};

// Adds forces and torques (world frame, N and N m, acting at the centre of mass) to every body it
// models. Called once per step in IntegrateForces, before the velocities are updated, with the step's context
// (step.t: the time at the start of the step; step.dt: h).
class ForceField {
 public:
  virtual ~ForceField() = default;
  virtual void apply(const BodyArrays& bodies, const StepContext& step, Vec3* force, Vec3* torque) = 0;
  // A device backend first offers the field its device arrays (force, torque: device pointers, one per body,
  // to add to). true: applied there, no host round trip; false (the default): the backend copies the bodies
  // to the host and calls apply().
  virtual bool applyOnDevice(const DeviceBodyRefs& /*bodies*/, const StepContext& /*step*/, Vec3* /*force*/,
                             Vec3* /*torque*/) {
    return false;
  }
};

}  // namespace dvi
