// The CES machine's per-particle work on a device backend (docs/CES.md): the force field (Coulomb,
// image, drag), the charge update and the classification run as CUDA kernels on the GPU system's body
// arrays, through the same DVI_HD functions the host runs (cesParticleForce, cesChargeUpdate, cesClassify in
// particle_model.h). Per step only the particles whose status changed come back to the host (collected or
// lost: a few per step), with the bodies the feeder and the drive read; charges come back when an output asks.
#pragma once

#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "ces/particle_model.h"
#include "chrono_like/force_field.h"

namespace dvi {
namespace ces {

struct CesParticles;  // machine.h

class CesDevice {
 public:
  virtual ~CesDevice() = default;
  // Uploads particles [first, p.count()): status, electrostatics (ParticleElectro), charge, flags, radius, bounding
  // radius, mass, moment.
  virtual void append(const CesParticles& p, size_t first) = 0;
  // Adds the CES force of every in-flight, movable particle for a step h to force (a device array, one per body).
  virtual void forces(const DeviceBodyRefs& b, real h, Vec3* force, Vec3* torque) = 0;
  // Charge update and classification of every in-flight particle after a step of h; the device's status
  // follows. changed: the particles whose status changed (body, new status), in body order.
  virtual void postStep(const DeviceBodyRefs& b, real h, std::vector<std::pair<int32_t, uint8_t>>& changed) = 0;
  // Touching in-flight particles share their charge after a step of h (particle_model.h: exchangeFlux), on the
  // system's device contacts.
  virtual void exchangeCharges(const DeviceContactRefs& c, real h) = 0;
  virtual void downloadCharges(std::vector<real>& charge) = 0;  // resized to the uploaded count
  virtual void downloadFlags(std::vector<uint8_t>& flags) = 0;  // ParticleFlag bits, resized likewise
  virtual void setCharge(int32_t body, real q) = 0;
};

// The device implementation; null when this build has no CUDA (the machine then applies its field on the
// host and copies the bodies every step).
std::unique_ptr<CesDevice> makeCesDevice(const CesModel& model);

}  // namespace ces
}  // namespace dvi
