// CUDA implementation of CesDevice (ces_device.h). Every per-particle formula is the host's DVI_HD function.
#include "ces/ces_device.h"

#include <cuda_runtime.h>

#include <algorithm>

#include "ces/machine.h"
#include "gpu/cuda_check.h"
#include "gpu/device_buffer.h"

namespace dvi {
namespace ces {
namespace {

constexpr int kThreads = 256;

// The particles' charge exchange on contact (CesMachine::exchangeContactCharges' two passes): partner counts,
// then each pair's flux from the charges before the exchange, summed per particle, then added.
__global__ void exchangeHeldKernel(int64_t nc, const uint8_t* status, const int32_t* a, const int32_t* b,
                                   const real* dist, uint8_t* held) {
  const int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= nc) return;
  const int32_t i = heldParticle(status, a, b, dist, k);
  if (i >= 0) held[i] = 1;  // every writer stores 1
}

__global__ void exchangeCountKernel(int64_t nc, const uint8_t* status, const uint8_t* held, const int32_t* a,
                                    const int32_t* b, const real* dist, int32_t* partners) {
  const int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= nc || !exchangesCharge(status, held, a, b, dist, k)) return;
  atomicAdd(partners + a[k], 1);
  atomicAdd(partners + b[k], 1);
}

__global__ void exchangeFluxKernel(int64_t nc, const uint8_t* status, const uint8_t* held, const int32_t* a,
                                   const int32_t* b, const real* dist, const int32_t* partners,
                                   const ParticleElectro* electro, const real* radius, const real* charge, real h,
                                   real* dq) {
  const int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= nc || !exchangesCharge(status, held, a, b, dist, k)) return;
  const real f = exchangeFlux(electro, radius, charge, partners, a[k], b[k], h);
  atomicAdd(dq + a[k], -f);
  atomicAdd(dq + b[k], f);
}

__global__ void addChargeKernel(int64_t n, const real* dq, real* charge) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i < n) charge[i] += dq[i];
}

int blocks(int64_t n) { return int((n + kThreads - 1) / kThreads); }

__global__ void forceKernel(int64_t n, const CesModel* m, real h, const uint8_t* status, const ParticleElectro* electro,
                            const real* charge, const real* radius, const real* bound, const real* mass,
                            const real* moment, const Vec3* pos, const Quat* rot, const Vec3* vel, const Vec3* omega,
                            const uint8_t* flags, Vec3* force, Vec3* torque) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n || status[i] != kStatusInFlight || (flags[i] & kBodyFixed)) return;
  const Vec3 F = cesParticleForce(*m, electro[i], pos[i], rot[i], vel[i], charge[i], radius[i], bound[i], mass[i], h);
  force[i] += F;
  torque[i] += cesParticleTorque(*m, electro[i], pos[i], rot[i], vel[i], omega[i], omega[m->drum_body], F, radius[i],
                                 mass[i], moment[i], h);
}

// Charge update and classification (CesMachine::postStep's loop); a changed status is appended to the list.
__global__ void postStepKernel(int64_t n, const CesModel* m, real h, uint8_t* status, const ParticleElectro* electro,
                               real* charge, uint8_t* pflags, const real* radius, const real* bound, const Vec3* pos,
                               const Quat* rot, int32_t* changed, uint8_t* changed_status, int32_t* n_changed) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n || status[i] != kStatusInFlight) return;
  uint8_t f = pflags[i];
  charge[i] = cesChargeUpdate(*m, electro[i], pos[i], rot[i], charge[i], radius[i], bound[i], h, f);
  pflags[i] = f;
  const uint8_t next = cesClassify(*m, pos[i]);
  if (next != status[i]) {
    status[i] = next;
    const int32_t k = atomicAdd(n_changed, 1);
    changed[k] = int32_t(i);
    changed_status[k] = next;
  }
}

class CudaCesDevice final : public CesDevice {
 public:
  explicit CudaCesDevice(const CesModel& host) {
    CesModel m = host;
    if (m.field.model == 1) {  // the CSM view points at host arrays: copy them and point at the copies
      charges_.upload(m.field.csm.charges, size_t(m.field.csm.nCharges));
      conductors_.upload(m.field.csm.conductors, size_t(m.field.csm.nConductors));
      DVI_CUDA(cudaDeviceSynchronize());
      m.field.csm.charges = charges_.data();
      m.field.csm.conductors = conductors_.data();
    }
    if (m.field.model == 2) {  // the corona grid: its four arrays to the device once, the view pointed at them
      const GridFieldView& g = m.field.grid;
      const size_t nn = size_t(g.nx) * size_t(g.ny);
      grid_ex_.upload(g.Ex, nn);
      grid_ey_.upload(g.Ey, nn);
      grid_phi_.upload(g.phi, nn);
      grid_ions_.upload(g.ion_density, nn);
      DVI_CUDA(cudaDeviceSynchronize());
      m.field.grid.Ex = grid_ex_.data();
      m.field.grid.Ey = grid_ey_.data();
      m.field.grid.phi = grid_phi_.data();
      m.field.grid.ion_density = grid_ions_.data();
    }
    model_.upload(&m, 1);
    DVI_CUDA(cudaDeviceSynchronize());
    n_changed_.resize(1);
  }

  void append(const CesParticles& p, size_t first) override {
    status_.uploadTail(p.status, first);
    electro_.uploadTail(p.electro, first);
    charge_.uploadTail(p.charge, first);
    pflags_.uploadTail(p.flags, first);
    radius_.uploadTail(p.radius, first);
    bound_.uploadTail(p.bound, first);
    mass_.uploadTail(p.mass, first);
    moment_.uploadTail(p.moment, first);
    count_ = p.count();
    DVI_CUDA(cudaDeviceSynchronize());  // the host vectors may grow (reallocate) after we return
  }

  void forces(const DeviceBodyRefs& b, real h, Vec3* force, Vec3* torque) override {
    const int64_t n = std::min<int64_t>(int64_t(count_), b.count);
    if (n == 0) return;
    forceKernel<<<blocks(n), kThreads, 0, stream(b)>>>(
        n, model_.data(), h, status_.data(), electro_.data(), charge_.data(), radius_.data(), bound_.data(),
        mass_.data(), moment_.data(), b.pos, b.rot, b.vel, b.omega, b.flags, force, torque);
    DVI_CUDA_LAUNCH("CES forceKernel");
  }

  void postStep(const DeviceBodyRefs& b, real h, std::vector<std::pair<int32_t, uint8_t>>& changed) override {
    changed.clear();
    const int64_t n = std::min<int64_t>(int64_t(count_), b.count);
    if (n == 0) return;
    cudaStream_t s = stream(b);
    changed_.resize(size_t(n));
    changed_status_.resize(size_t(n));
    DVI_CUDA(cudaMemsetAsync(n_changed_.data(), 0, sizeof(int32_t), s));
    postStepKernel<<<blocks(n), kThreads, 0, s>>>(n, model_.data(), h, status_.data(), electro_.data(), charge_.data(),
                                                  pflags_.data(), radius_.data(), bound_.data(), b.pos, b.rot,
                                                  changed_.data(), changed_status_.data(), n_changed_.data());
    DVI_CUDA_LAUNCH("CES postStepKernel");
    std::vector<int32_t> count;
    n_changed_.download(count, 1, s);  // synchronous
    if (count[0] == 0) return;
    std::vector<int32_t> ids;
    std::vector<uint8_t> st;
    changed_.download(ids, size_t(count[0]), s);
    changed_status_.download(st, size_t(count[0]), s);
    changed.reserve(ids.size());
    for (size_t k = 0; k < ids.size(); ++k) changed.emplace_back(ids[k], st[k]);
    std::sort(changed.begin(), changed.end());  // the atomic order is arbitrary; the host's is by body
  }

  void exchangeCharges(const DeviceContactRefs& c, real h) override {
    const int64_t n = int64_t(count_);
    if (n == 0 || c.count == 0) return;
    cudaStream_t s = static_cast<cudaStream_t>(c.stream);
    held_.resize(size_t(n));
    partners_.resize(size_t(n));
    dq_.resize(size_t(n));
    DVI_CUDA(cudaMemsetAsync(held_.data(), 0, sizeof(uint8_t) * size_t(n), s));
    DVI_CUDA(cudaMemsetAsync(partners_.data(), 0, sizeof(int32_t) * size_t(n), s));
    DVI_CUDA(cudaMemsetAsync(dq_.data(), 0, sizeof(real) * size_t(n), s));
    exchangeHeldKernel<<<blocks(c.count), kThreads, 0, s>>>(c.count, status_.data(), c.body_a, c.body_b, c.dist,
                                                            held_.data());
    DVI_CUDA_LAUNCH("CES exchangeHeldKernel");
    exchangeCountKernel<<<blocks(c.count), kThreads, 0, s>>>(c.count, status_.data(), held_.data(), c.body_a, c.body_b,
                                                             c.dist, partners_.data());
    DVI_CUDA_LAUNCH("CES exchangeCountKernel");
    exchangeFluxKernel<<<blocks(c.count), kThreads, 0, s>>>(c.count, status_.data(), held_.data(), c.body_a, c.body_b,
                                                            c.dist, partners_.data(), electro_.data(), radius_.data(),
                                                            charge_.data(), h, dq_.data());
    DVI_CUDA_LAUNCH("CES exchangeFluxKernel");
    addChargeKernel<<<blocks(n), kThreads, 0, s>>>(n, dq_.data(), charge_.data());
    DVI_CUDA_LAUNCH("CES addChargeKernel");
  }

  void downloadCharges(std::vector<real>& charge) override { charge_.download(charge, count_, 0); }
  void downloadFlags(std::vector<uint8_t>& flags) override { pflags_.download(flags, count_, 0); }

  void setCharge(int32_t body, real q) override {
    if (body < 0 || size_t(body) >= count_) return;
    DVI_CUDA(cudaMemcpy(charge_.data() + body, &q, sizeof(real), cudaMemcpyHostToDevice));
  }

 private:
  static cudaStream_t stream(const DeviceBodyRefs& b) { return static_cast<cudaStream_t>(b.stream); }

  gpu::DeviceBuffer<CesModel> model_{"CES model"};
  gpu::DeviceBuffer<CsmLineCharge> charges_{"CES CSM line charges"};
  gpu::DeviceBuffer<CsmConductor> conductors_{"CES CSM conductors"};
  gpu::DeviceBuffer<float> grid_ex_{"CES corona grid Ex"}, grid_ey_{"CES corona grid Ey"};
  gpu::DeviceBuffer<float> grid_phi_{"CES corona grid phi"}, grid_ions_{"CES corona grid ion density"};
  gpu::DeviceBuffer<uint8_t> status_{"CES particle status"}, pflags_{"CES particle flags"};
  gpu::DeviceBuffer<ParticleElectro> electro_{"CES particle electrostatics"};
  gpu::DeviceBuffer<real> charge_{"CES particle charge"}, radius_{"CES particle radius"}, bound_{"CES particle bound"};
  gpu::DeviceBuffer<real> mass_{"CES particle mass"}, moment_{"CES particle moment"};
  gpu::DeviceBuffer<int32_t> changed_{"CES changed particles"}, n_changed_{"CES changed count"};
  gpu::DeviceBuffer<uint8_t> changed_status_{"CES changed status"};
  gpu::DeviceBuffer<uint8_t> held_{"CES particles held by a part"};
  gpu::DeviceBuffer<int32_t> partners_{"CES exchange partners"};
  gpu::DeviceBuffer<real> dq_{"CES exchanged charge"};
  size_t count_ = 0;
};

}  // namespace

std::unique_ptr<CesDevice> makeCesDevice(const CesModel& model) { return std::make_unique<CudaCesDevice>(model); }

}  // namespace ces
}  // namespace dvi
