// GpuSystem: the step on the device. Upload on the first step and after addBody()/markHostDirty(); host
// copies only in syncToHost().
#include "gpu/gpu_system.h"

#include <cuda_runtime.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>

#include <algorithm>
#include <stdexcept>
#include <string>

#include "chrono_like/integrate.h"
#include "gpu/cuda_check.h"
#include "gpu/gpu_info.h"
#include "gpu/gpu_state.cuh"
#include "gpu/host_copy.h"

namespace dvi {

namespace gpu {

const double* DeviceState::readScalars(const double* dev, int n) {
  DVI_CUDA(cudaMemcpyAsync(host_scalars, dev, sizeof(double) * size_t(n), cudaMemcpyDeviceToHost, stream));
  DVI_CUDA(cudaStreamSynchronize(stream));
  return host_scalars;
}

// Bytes the buffers hold (their capacity).
template <class... Buf>
size_t capacityBytes(const Buf&... buf) {
  return (size_t(0) + ... + (buf.capacity() * sizeof(*buf.data())));
}

size_t DeviceState::bytes() const {
  const size_t in_bodies =
      capacityBytes(bodies.pos, bodies.vel, bodies.omega, bodies.inv_inertia, bodies.force, bodies.torque,
                    bodies.gravity, bodies.v_free, bodies.w_free, bodies.rot, bodies.inv_mass, bodies.friction,
                    bodies.restitution, bodies.flags, bodies.inv, bodies.delta);
  const size_t in_shapes = capacityBytes(shapes.shape, shapes.hull, shapes.aabb, shapes.sweep);
  const size_t in_contacts =
      capacityBytes(contacts.shape_a, contacts.shape_b, contacts.body_a, contacts.body_b, contacts.normal, contacts.pa,
                    contacts.pb, contacts.dist, contacts.mu, contacts.size, contacts.key);
  const size_t in_broad =
      capacityBytes(broad.ext, broad.ext_sorted, broad.ext_prefix, broad.ext_stats, broad.is_binned, broad.is_large,
                    broad.bound_in, broad.binned, broad.large, broad.entry_count, broad.entry_off, broad.entry_bin,
                    broad.entry_bin_sorted, broad.entry_shape, broad.entry_shape_sorted, broad.run_bin, broad.run_len,
                    broad.pair_counter, broad.pair_key, broad.pair_key_sorted, broad.fat, broad.fat_flags, broad.moved);
  const size_t in_narrow = capacityBytes(narrow.count, narrow.off, narrow.first, narrow.first_slot, narrow.deferred,
                                         narrow.deep, narrow.deep_count, narrow.list, narrow.list_count);
  const size_t in_solver =
      capacityBytes(solver.stamps, solver.jac, solver.rhs, solver.block_inv, solver.block_step, solver.gamma,
                    solver.jacobi_step, solver.colnorm, solver.rowsum, solver.bodyq, solver.prev_gamma, solver.prev_key,
                    solver.adj_key, solver.adj_key_sorted, solver.adj_val, solver.adj_val_sorted, solver.adj_off,
                    solver.v0, solver.v1, solver.v2, solver.v3, solver.v4, solver.v5, solver.v6, solver.v7, solver.v8,
                    solver.jacf, solver.entry_jac, solver.inv_iso, solver.vf, solver.x, solver.rows, solver.row_lo,
                    solver.row_hi, solver.heavy, solver.heavy_count, solver.heavy_partial, solver.heavy_ticket,
                    solver.order, solver.order_sorted, solver.partial, solver.scalars, solver.apgd);
  const size_t in_other = capacityBytes(step_scalars, cub_temp);
  return in_bodies + in_shapes + in_contacts + in_broad + in_narrow + in_solver + in_other;
}

namespace {

__global__ void integrateForcesKernel(int n, const Vec3* vel, const Vec3* omega, const Quat* rot, const real* inv_mass,
                                      const Vec3* inv_inertia, const Vec3* force, const Vec3* torque,
                                      const Vec3* gravity, const uint8_t* flags, bool gyro, bool skip_spherical, real h,
                                      Vec3* v_free, Vec3* w_free) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  integrateBodyForces(vel[i], omega[i], rot[i], inv_mass[i], inv_inertia[i], force[i], torque[i], gravity[i], flags[i],
                      gyro, skip_spherical, h, v_free[i], w_free[i]);
}

__global__ void addForcesKernel(int n, const Vec3* f, const Vec3* t, Vec3* force, Vec3* torque) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  force[i] += f[i];
  torque[i] += t[i];
}

__global__ void gatherBodiesKernel(int n, const int32_t* ids, const Vec3* pos, const Quat* rot, const Vec3* vel,
                                   const Vec3* omega, const uint8_t* flags, BodyRecord* out) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= n) return;
  const int32_t i = ids[k];
  out[k] = BodyRecord{pos[i], vel[i], omega[i], rot[i], flags[i]};
}

__global__ void scatterBodiesKernel(int n, const int32_t* ids, const BodyRecord* in, Vec3* pos, Quat* rot, Vec3* vel,
                                    Vec3* omega, uint8_t* flags) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= n) return;
  const int32_t i = ids[k];
  const BodyRecord r = in[k];
  pos[i] = r.pos;
  rot[i] = r.rot;
  vel[i] = r.vel;
  omega[i] = r.omega;
  flags[i] = r.flags;
}

__global__ void scatterParamsKernel(int n, const int32_t* ids, const BodyParamsRecord* in, real* inv_mass,
                                    Vec3* inv_inertia, Vec3* force, Vec3* torque, Vec3* gravity, real* friction,
                                    real* restitution) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= n) return;
  const int32_t i = ids[k];
  const BodyParamsRecord r = in[k];
  inv_mass[i] = r.inv_mass;
  inv_inertia[i] = r.inv_inertia;
  force[i] = r.force;
  torque[i] = r.torque;
  gravity[i] = r.gravity;
  friction[i] = r.friction;
  restitution[i] = r.restitution;
}

// Rolling and spinning friction: solved by the CPU backend only (its rolling blocks are built on the host).
void refuseRolling(const BodyArrays& b, size_t i) {
  if (b.rolling_friction[i] > 0 || b.spinning_friction[i] > 0)
    throw InputError("GPU backend: body " + std::to_string(i) +
                     " has rolling or spinning friction, which only the CPU backend solves");
}

__global__ void integratePositionsKernel(int n, Vec3* pos, Quat* rot, const Vec3* vel, const Vec3* omega,
                                         const uint8_t* flags, real h, Vec3* force, Vec3* torque) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  Vec3 x = pos[i];
  Quat q = rot[i];
  integrateBodyPosition(x, q, vel[i], omega[i], flags[i], h);
  pos[i] = x;
  rot[i] = q;
  force[i] = Vec3{0, 0, 0};
  torque[i] = Vec3{0, 0, 0};
}

}  // namespace
}  // namespace gpu

using namespace gpu;

GpuSystem::GpuSystem(SystemConfig config, CollisionFactory bullet_collision)
    : System(config, bullet_collision), d_(std::make_unique<DeviceState>()) {
  std::string why;
  if (!queryDevice(&why)) throw InputError("GPU backend: " + why);
  if (config_.solver.type == SolverType::GaussSeidel)
    throw InputError("GPU backend: Gauss-Seidel is sequential; use jacobi, apgd or bb on the GPU");
  DVI_CUDA(cudaStreamCreateWithFlags(&d_->stream, cudaStreamNonBlocking));
  DVI_CUDA(cudaStreamCreateWithFlags(&d_->copy_stream, cudaStreamNonBlocking));
  DVI_CUDA(cudaEventCreateWithFlags(&d_->ev_shares, cudaEventDisableTiming));
  DVI_CUDA(cudaEventCreateWithFlags(&d_->ev_sums, cudaEventDisableTiming));
  {
    int dev = 0;
    DVI_CUDA(cudaGetDevice(&dev));
    DVI_CUDA(cudaDeviceGetAttribute(&d_->multiprocessors, cudaDevAttrMultiProcessorCount, dev));
    int coop = 0;
    DVI_CUDA(cudaDeviceGetAttribute(&coop, cudaDevAttrCooperativeLaunch, dev));
    d_->cooperative = coop != 0;
    d_->phase_profile = std::getenv("DVISIM_APGD_PHASES") != nullptr;
  }
  for (auto& e : d_->ev) DVI_CUDA(cudaEventCreate(&e));
  DVI_CUDA(cudaMallocHost(&d_->host_scalars, 64 * sizeof(double)));
  DVI_CUDA(cudaMallocHost(&d_->host_apgd, sizeof(ApgdDeviceState)));
  d_->step_scalars.resize(16);
}

GpuSystem::~GpuSystem() {
  if (!d_) return;
  if (d_->phase_trials > 0) {
    const double* c = d_->phase_cycles;
    const double n = double(d_->phase_trials);
    std::fprintf(stderr,
                 "apgd phases (SM cycles per trial, block 0, %lld trials): step %.0f, wait %.0f, gather %.0f, wait "
                 "%.0f, schur+test %.0f, wait+control %.0f; total %.0f\n",
                 static_cast<long long>(d_->phase_trials), c[0] / n, c[1] / n, c[2] / n, c[3] / n, c[4] / n, c[5] / n,
                 (c[0] + c[1] + c[2] + c[3] + c[4] + c[5]) / n);
  }
  closePeerExchange(*d_);
  for (auto& e : d_->ev)
    if (e) cudaEventDestroy(e);
  if (d_->host_scalars) cudaFreeHost(d_->host_scalars);
  if (d_->host_staging) cudaFreeHost(d_->host_staging);
  if (d_->host_apgd) cudaFreeHost(d_->host_apgd);
  if (d_->ex_host) cudaFreeHost(d_->ex_host);
  if (sel_state_) cudaFreeHost(sel_state_);
  if (d_->stream) cudaStreamDestroy(d_->stream);
  if (d_->copy_stream) cudaStreamDestroy(d_->copy_stream);
  if (d_->ev_shares) cudaEventDestroy(d_->ev_shares);
  if (d_->ev_sums) cudaEventDestroy(d_->ev_sums);
}

std::string GpuSystem::deviceName() const {
  std::string name;
  queryDevice(&name);
  return name;
}

size_t GpuSystem::deviceBytes() const { return d_->bytes(); }

void GpuSystem::uploadIfNeeded() {
  if (!host_dirty_ && uploaded_bodies_ == bodies_.count()) return;
  // After a host edit everything is uploaded; otherwise only the bodies (and their shapes) appended by
  // addBody() since the last upload, so device state that was never synced back is not overwritten.
  const size_t first_body = host_dirty_ ? 0 : uploaded_bodies_;
  const size_t first_shape = host_dirty_ ? 0 : d_->shapes.count;
  const size_t first_hull = host_dirty_ ? 0 : d_->shapes.hull.size();
  cudaStream_t s = d_->stream;
  DeviceBodies& b = d_->bodies;
  b.pos.uploadTail(bodies_.pos, first_body, s);
  b.rot.uploadTail(bodies_.rot, first_body, s);
  b.vel.uploadTail(bodies_.vel, first_body, s);
  b.omega.uploadTail(bodies_.omega, first_body, s);
  b.inv_mass.uploadTail(bodies_.inv_mass, first_body, s);
  b.inv_inertia.uploadTail(bodies_.inv_inertia, first_body, s);
  b.force.uploadTail(bodies_.force, first_body, s);
  b.torque.uploadTail(bodies_.torque, first_body, s);
  b.gravity.uploadTail(bodies_.gravity, first_body, s);
  b.friction.uploadTail(bodies_.friction, first_body, s);
  b.restitution.uploadTail(bodies_.restitution, first_body, s);
  b.flags.uploadTail(bodies_.flags, first_body, s);
  b.count = bodies_.count();
  if (first_body == 0) gyro_bodies_ = false;
  for (size_t i = first_body; i < b.count && !gyro_bodies_; ++i)
    gyro_bodies_ = needsGyroscopic(bodies_.inv_inertia[i], bodies_.flags[i]);
  // Every body frictional (f > 0 with f * f > 0): then every contact's combined friction is positive under each
  // FrictionCombine rule (a product of two such values, their least, their mean), and BuildRows knows the CCP
  // has friction rows without reducing mu on the device and reading it back.
  if (first_body == 0) d_->all_frictional = true;
  for (size_t i = first_body; i < b.count && d_->all_frictional; ++i) {
    const real f = bodies_.friction[i];
    d_->all_frictional = f > 0 && f * f > 0;
  }
  // Some body with restitution > 0: BuildRows reads the restitution and the pre-step velocities (jacobian.h:
  // contactNormalBias); else it reads neither (every contact's e is 0).
  if (first_body == 0) d_->any_restitution = false;
  for (size_t i = first_body; i < b.count && !d_->any_restitution; ++i)
    d_->any_restitution = bodies_.restitution[i] > 0;
  for (size_t i = first_body; i < b.count; ++i) refuseRolling(bodies_, i);
  b.v_free.resize(b.count);
  b.w_free.resize(b.count);
  b.inv.resize(b.count);
  b.delta.resize(b.count);
  DeviceShapes& sh = d_->shapes;
  sh.shape.uploadTail(shapes_.shape, first_shape, s);
  sh.hull.uploadTail(shapes_.hull_points, first_hull, s);
  sh.aabb.resizeKeep(shapes_.count());
  sh.sweep.resizeKeep(shapes_.count());
  sh.count = shapes_.count();
  DVI_CUDA(cudaStreamSynchronize(s));  // the host vectors may change after we return
  uploaded_bodies_ = bodies_.count();
  host_dirty_ = false;
}

void GpuSystem::step() {
  stats_ = StepStats{};
  beginStep();
  uploadIfNeeded();
  d_->group = group_;
  uploadOwners(*d_);
  planParts();
  cudaEvent_t* ev = d_->ev;
  DVI_CUDA(cudaEventRecord(ev[0], d_->stream));
  integrateForces();
  DVI_CUDA(cudaEventRecord(ev[1], d_->stream));
  detectCollisions();  // records ev[2..4]
  buildAndSolve();     // records ev[5..7]
  integrate();         // records ev[8..9]
  DVI_CUDA(cudaEventSynchronize(ev[kStageCount]));
  for (int s = 0; s < kStageCount; ++s) {
    float ms = 0;
    DVI_CUDA(cudaEventElapsedTime(&ms, ev[s], ev[s + 1]));
    stats_.stage_seconds[s] = double(ms) * 1e-3;
  }
  endStep();
}

void GpuSystem::integrateForces() {
  DeviceBodies& b = d_->bodies;
  const int n = int(b.count);
  stats_.stage_ran[int(StageType::IntegrateForces)] = true;
  if (n == 0) return;
  if (stats_.part_ran[int(StagePart::ForceFields)]) {  // with prune = false even without fields
    // A field with device code adds into field_force/field_torque on the device (ForceField::applyOnDevice).
    // The others are host plug-ins: the body state goes to the host, they run there, and their forces are
    // added to the device's sums. That round trip happens only for such fields (docs/ARCHITECTURE.md).
    cudaStream_t s = d_->stream;
    b.field_force.resize(size_t(n));
    b.field_torque.resize(size_t(n));
    DVI_CUDA(cudaMemsetAsync(b.field_force.data(), 0, sizeof(Vec3) * size_t(n), s));
    DVI_CUDA(cudaMemsetAsync(b.field_torque.data(), 0, sizeof(Vec3) * size_t(n), s));
    DeviceBodyRefs refs;
    deviceBodies(refs);
    std::vector<ForceField*> host_fields;
    for (const auto& f : fields_)
      if (!f->applyOnDevice(refs, ctx_, b.field_force.data(), b.field_torque.data())) host_fields.push_back(f.get());
    if (!host_fields.empty()) {
      b.pos.download(bodies_.pos, b.count, s);
      b.rot.download(bodies_.rot, b.count, s);
      b.vel.download(bodies_.vel, b.count, s);
      b.omega.download(bodies_.omega, b.count, s);
      b.field_force.download(field_force_, size_t(n), s);  // the device fields' sums, synchronous
      b.field_torque.download(field_torque_, size_t(n), s);
      for (ForceField* f : host_fields) f->apply(bodies_, ctx_, field_force_.data(), field_torque_.data());
      b.field_force.upload(field_force_, s);
      b.field_torque.upload(field_torque_, s);
    }
    addForcesKernel<<<blocksFor(n), kBlock, 0, s>>>(n, b.field_force.data(), b.field_torque.data(), b.force.data(),
                                                    b.torque.data());
    DVI_CUDA_LAUNCH("addForcesKernel");
    if (!host_fields.empty()) DVI_CUDA(cudaStreamSynchronize(s));  // the host vectors may change after we return
  }
  integrateForcesKernel<<<blocksFor(n), kBlock, 0, d_->stream>>>(
      n, b.vel.data(), b.omega.data(), b.rot.data(), b.inv_mass.data(), b.inv_inertia.data(), b.force.data(),
      b.torque.data(), b.gravity.data(), b.flags.data(), stats_.part_ran[int(StagePart::Gyroscopic)], config_.prune,
      ctx_.dt, b.v_free.data(), b.w_free.data());
  DVI_CUDA_LAUNCH("integrateForcesKernel");
}

// Impulses handed over (setWarmStart: a resumed checkpoint; addWarmStart: a distributed driver) go up for this step's
// WarmStart alone, with their normals where they came with them (the narrow phase's LastNormals when the device has
// no last step of its own: gpu_collision.cu, lastNormals).
void GpuSystem::uploadHandedOverWarmStart() {
  if (prev_keys_.empty()) return;
  d_->extra_count = prev_keys_.size();
  d_->extra_key.upload(prev_keys_, d_->stream);
  d_->extra_gamma.upload(prev_gamma_, d_->stream);
  d_->extra_normals = prev_normal_.size() == prev_keys_.size();
  if (d_->extra_normals) d_->extra_normal.upload(prev_normal_, d_->stream);
  DVI_CUDA(cudaStreamSynchronize(d_->stream));
  prev_keys_.clear();
  prev_gamma_.clear();
  prev_normal_.clear();
}

void GpuSystem::detectCollisions() {
  cudaEvent_t* ev = d_->ev;
  if (d_->exclusions_version != exclusions_version_) {
    d_->excluded.upload(excluded_pairs_, d_->stream);
    d_->no_contact.upload(no_contact_, d_->stream);
    d_->excluded_count = int64_t(excluded_pairs_.size());
    d_->no_contact_count = int64_t(no_contact_.size());
    d_->exclusions_version = exclusions_version_;
  }
  uploadHandedOverWarmStart();  // its normals are the narrow phase's last ones where the device has none
  computeAabbs(*d_, config_, ctx_);
  DVI_CUDA(cudaEventRecord(ev[int(StageType::ComputeAabbs) + 1], d_->stream));
  stats_.pairs_reused = broadPhaseStep(*d_, config_);
  DVI_CUDA(cudaEventRecord(ev[int(StageType::BroadPhase) + 1], d_->stream));
  narrowPhase(*d_, config_, ctx_);
  if (group_)
    keepOwnedContacts(*d_, config_.gpu.peer_exchange);  // a domain decomposition: the contacts this process owns
  DVI_CUDA(cudaEventRecord(ev[int(StageType::NarrowPhase) + 1], d_->stream));
  stats_.stage_ran[int(StageType::ComputeAabbs)] = stats_.stage_ran[int(StageType::BroadPhase)] =
      stats_.stage_ran[int(StageType::NarrowPhase)] = true;
  stats_.pairs = d_->pairs;
  stats_.contacts = int64_t(d_->contacts.count);
}

void GpuSystem::buildAndSolve() {
  cudaEvent_t* ev = d_->ev;
  const size_t nc = d_->contacts.count;
  if (stats_.part_ran[int(StagePart::ConstraintRows)]) {  // with prune = false even without providers
    // Row providers are host plug-ins (constraint_row.h) that read the body state: it comes to the host
    // here, only in scenes with constraint rows (docs/ARCHITECTURE.md), and only the bodies they name
    // when every provider names them (RowProvider::bodiesRead; the CES drum drive reads the drum alone).
    std::vector<int32_t> ids;
    bool listed = true;
    for (const auto& p : row_providers_) listed = listed && p->bodiesRead(ids);
    if (listed) {
      syncBodiesToHost(ids);
    } else {
      const DeviceBodies& b = d_->bodies;
      b.pos.download(bodies_.pos, b.count, d_->stream);
      b.rot.download(bodies_.rot, b.count, d_->stream);
      b.vel.download(bodies_.vel, b.count, d_->stream);
      b.omega.download(bodies_.omega, b.count, d_->stream);
    }
    collectRows();
  } else {
    rows_.clear();
    row_lambda_.clear();
  }
  // Over several processes a process without contacts still takes part in the solve's reductions and exchanges.
  if (nc == 0 && rows_.empty() && !group_) {
    d_->prev_count = 0;
    d_->row_count = 0;
    d_->solver.rows.resize(0);
    d_->solver.gamma.resize(0);
    for (int s : {int(StageType::BuildRows), int(StageType::WarmStart), int(StageType::Solve)})
      DVI_CUDA(cudaEventRecord(ev[s + 1], d_->stream));
    d_->normal_only = false;
    stats_.part_reason[int(StagePart::FrictionRows)] = "no contacts";
    leaveOut(StageType::BuildRows, "no contacts and no constraint rows");
    leaveOut(StageType::WarmStart, "no contacts and no constraint rows");
    leaveOut(StageType::Solve, "no contacts and no constraint rows");
    return;
  }
  real max_pen = 0;
  buildRows(*d_, config_, ctx_, rows_, &max_pen);
  stats_.max_penetration = max_pen;
  stats_.stage_ran[int(StageType::BuildRows)] = true;
  stats_.normal_only = d_->normal_only;
  stats_.part_ran[int(StagePart::FrictionRows)] = nc > 0 && !d_->normal_only;
  stats_.part_reason[int(StagePart::FrictionRows)] = nc == 0           ? "no contacts"
                                                     : d_->normal_only ? "no contact with mu > 0 this step"
                                                                       : nullptr;
  DVI_CUDA(cudaEventRecord(ev[int(StageType::BuildRows) + 1], d_->stream));
  uploadHandedOverWarmStart();  // entries handed over after this step's narrow phase
  const bool warm = config_.solver.warm_start && (d_->prev_count > 0 || d_->extra_count > 0);
  warmStart(*d_, config_.solver.warm_start, config_.solver.warm_start ? row_lambda_ : std::vector<real>{});
  d_->extra_count = 0;
  d_->extra_normals = false;
  stats_.stage_ran[int(StageType::WarmStart)] = warm;
  if (!config_.solver.warm_start)
    leaveOut(StageType::WarmStart, "switched off (SystemConfig::solver.warm_start)");
  else if (!warm)
    leaveOut(StageType::WarmStart, "no contacts in the previous step");
  DVI_CUDA(cudaEventRecord(ev[int(StageType::WarmStart) + 1], d_->stream));
  recordSolve(solveCcp(*d_, config_));
  stats_.stage_ran[int(StageType::Solve)] = true;
  keepImpulsesForWarmStart(*d_);
  if (!rows_.empty()) {  // the rows' impulses go back to their providers (a few values)
    row_lambda_.resize(rows_.size());
    DVI_CUDA(cudaMemcpyAsync(row_lambda_.data(), d_->solver.gamma.data() + 3 * nc, sizeof(real) * rows_.size(),
                             cudaMemcpyDeviceToHost, d_->stream));
    DVI_CUDA(cudaStreamSynchronize(d_->stream));
    for (size_t p = 0, offset = 0; p < row_providers_.size(); offset += provider_rows_[p], ++p)
      row_providers_[p]->impulses(row_lambda_.data() + offset, provider_rows_[p]);
  }
  DVI_CUDA(cudaEventRecord(ev[int(StageType::Solve) + 1], d_->stream));
}

void GpuSystem::integrate() {
  cudaEvent_t* ev = d_->ev;
  DeviceBodies& b = d_->bodies;
  const int n = int(b.count);
  // IntegrateVelocities: v = v_free + M^-1 D gamma (the gather of the Schur product).
  // Over several processes every process applies (and exchanges) its share, with or without contacts.
  const bool impulses = d_->contacts.count > 0 || d_->row_count > 0 || group_;
  if (n > 0) applyImpulsesToBodies(*d_, impulses ? solution(*d_) : nullptr);
  DVI_CUDA(cudaEventRecord(ev[int(StageType::IntegrateVelocities) + 1], d_->stream));
  if (n > 0) {
    integratePositionsKernel<<<blocksFor(n), kBlock, 0, d_->stream>>>(n, b.pos.data(), b.rot.data(), b.vel.data(),
                                                                      b.omega.data(), b.flags.data(), ctx_.dt,
                                                                      b.force.data(), b.torque.data());
    DVI_CUDA_LAUNCH("integratePositionsKernel");
  }
  DVI_CUDA(cudaEventRecord(ev[int(StageType::IntegratePositions) + 1], d_->stream));
  stats_.stage_ran[int(StageType::IntegrateVelocities)] = stats_.stage_ran[int(StageType::IntegratePositions)] = true;
}

void GpuSystem::motionBounds(real& vmax, real& wmax) const {
  d_->group = group_;
  gpu::motionBounds(*d_, vmax, wmax);
}

std::vector<int32_t> GpuSystem::ownedBodiesOutside(Vec3 lo, Vec3 hi) const {
  d_->group = group_;
  return gpu::ownedBodiesOutside(*d_, lo, hi);
}

std::vector<ContactImpulse> GpuSystem::contactImpulsesOf(const std::vector<int32_t>& bodies) const {
  return gpu::contactImpulsesOf(*d_, bodies);
}

bool GpuSystem::deviceBodies(DeviceBodyRefs& out) {
  uploadIfNeeded();
  DeviceBodies& b = d_->bodies;
  out.pos = b.pos.data();
  out.rot = b.rot.data();
  out.vel = b.vel.data();
  out.omega = b.omega.data();
  out.flags = b.flags.data();
  out.count = int64_t(b.count);
  out.stream = d_->stream;
  return true;
}

bool GpuSystem::deviceContacts(DeviceContactRefs& out) {
  DeviceContacts& c = d_->contacts;
  out.body_a = c.body_a.data();
  out.body_b = c.body_b.data();
  out.dist = c.dist.data();
  out.count = int64_t(c.count);
  out.stream = d_->stream;
  return true;
}

namespace {
void checkIds(const std::vector<int32_t>& ids, size_t count, const char* what) {
  for (int32_t i : ids)
    if (i < 0 || size_t(i) >= count)
      throw std::out_of_range(std::string(what) + ": body " + std::to_string(i) + " does not exist (" +
                              std::to_string(count) + " bodies)");
}
}  // namespace

void GpuSystem::syncBodiesToHost(const std::vector<int32_t>& ids) {
  if (ids.empty()) return;
  uploadIfNeeded();
  checkIds(ids, bodies_.count(), "syncBodiesToHost");
  DeviceBodies& b = d_->bodies;
  cudaStream_t s = d_->stream;
  const int n = int(ids.size());
  b.sel_ids.upload(ids, s);
  b.sel_state.resize(size_t(n));
  gatherBodiesKernel<<<blocksFor(n), kBlock, 0, s>>>(n, b.sel_ids.data(), b.pos.data(), b.rot.data(), b.vel.data(),
                                                     b.omega.data(), b.flags.data(), b.sel_state.data());
  DVI_CUDA_LAUNCH("gatherBodiesKernel");
  BodyRecord* staged = selectedStates(size_t(n));
  DVI_CUDA(cudaMemcpyAsync(staged, b.sel_state.data(), sizeof(BodyRecord) * size_t(n), cudaMemcpyDeviceToHost, s));
  DVI_CUDA(cudaStreamSynchronize(s));
  for (int k = 0; k < n; ++k) {
    const size_t i = size_t(ids[size_t(k)]);
    const BodyRecord& r = staged[size_t(k)];
    bodies_.pos[i] = r.pos;
    bodies_.rot[i] = r.rot;
    bodies_.vel[i] = r.vel;
    bodies_.omega[i] = r.omega;
    bodies_.flags[i] = r.flags;
  }
}

void GpuSystem::markBodiesDirty(const std::vector<int32_t>& ids) {
  if (ids.empty() || host_dirty_) return;  // everything goes up before the next step anyway
  uploadIfNeeded();
  checkIds(ids, bodies_.count(), "markBodiesDirty");
  DeviceBodies& b = d_->bodies;
  cudaStream_t s = d_->stream;
  const int n = int(ids.size());
  BodyRecord* staged = selectedStates(size_t(n));
  for (int k = 0; k < n; ++k) {
    const size_t i = size_t(ids[size_t(k)]);
    staged[size_t(k)] = BodyRecord{bodies_.pos[i], bodies_.vel[i], bodies_.omega[i], bodies_.rot[i], bodies_.flags[i]};
  }
  b.sel_ids.upload(ids, s);
  b.sel_state.resize(size_t(n));
  DVI_CUDA(cudaMemcpyAsync(b.sel_state.data(), staged, sizeof(BodyRecord) * size_t(n), cudaMemcpyHostToDevice, s));
  scatterBodiesKernel<<<blocksFor(n), kBlock, 0, s>>>(n, b.sel_ids.data(), b.sel_state.data(), b.pos.data(),
                                                      b.rot.data(), b.vel.data(), b.omega.data(), b.flags.data());
  DVI_CUDA_LAUNCH("scatterBodiesKernel");
  DVI_CUDA(cudaStreamSynchronize(s));  // the staging may change after we return
}

BodyRecord* GpuSystem::selectedStates(size_t n) {
  if (n > sel_state_cap_) {
    if (sel_state_) DVI_CUDA(cudaFreeHost(sel_state_));
    sel_state_ = nullptr;
    const size_t cap = n + n / 2;
    DVI_CUDA(cudaMallocHost(&sel_state_, cap * sizeof(BodyRecord)));
    sel_state_cap_ = cap;
  }
  return sel_state_;
}

void GpuSystem::markBodyParamsDirty(const std::vector<int32_t>& ids) {
  if (ids.empty() || host_dirty_) return;  // everything goes up before the next step anyway
  uploadIfNeeded();
  checkIds(ids, bodies_.count(), "markBodyParamsDirty");
  const int n = int(ids.size());
  sel_params_.resize(size_t(n));
  for (int k = 0; k < n; ++k) {
    const size_t i = size_t(ids[size_t(k)]);
    refuseRolling(bodies_, i);
    const real f = bodies_.friction[i];
    sel_params_[size_t(k)] = BodyParamsRecord{bodies_.inv_inertia[i], bodies_.force[i],    bodies_.torque[i],
                                              bodies_.gravity[i],     bodies_.inv_mass[i], f,
                                              bodies_.restitution[i]};
    // What uploadIfNeeded derives from all bodies, kept true where one of these bodies makes it so.
    gyro_bodies_ = gyro_bodies_ || needsGyroscopic(bodies_.inv_inertia[i], bodies_.flags[i]);
    d_->all_frictional = d_->all_frictional && f > 0 && f * f > 0;
    d_->any_restitution = d_->any_restitution || bodies_.restitution[i] > 0;
  }
  DeviceBodies& b = d_->bodies;
  cudaStream_t s = d_->stream;
  b.sel_ids.upload(ids, s);
  b.sel_params.upload(sel_params_, s);
  scatterParamsKernel<<<blocksFor(n), kBlock, 0, s>>>(n, b.sel_ids.data(), b.sel_params.data(), b.inv_mass.data(),
                                                      b.inv_inertia.data(), b.force.data(), b.torque.data(),
                                                      b.gravity.data(), b.friction.data(), b.restitution.data());
  DVI_CUDA_LAUNCH("scatterParamsKernel");
  DVI_CUDA(cudaStreamSynchronize(s));  // sel_params_ may change after we return
}

namespace {

// syncToHost's copies: each device array goes into the pinned staging buffer at its offset (asynchronous copies at
// the full copy bandwidth, one synchronisation), then into its host vector on the OpenMP team (host_copy.h). A
// pageable cudaMemcpy per array (17 synchronisations, staged by the driver) took ~8 ms for 100k bodies and 290k
// contacts on an H100 host.
struct Staged {
  void* host;  // the host vector's data, resized to the count
  const void* device;
  size_t bytes, offset;
};

template <class T>
Staged staged(std::vector<T>& v, const DeviceBuffer<T>& d, size_t n) {
  v.resize(n);
  return Staged{v.data(), d.data(), n * sizeof(T), 0};
}

}  // namespace

void GpuSystem::syncToHost() {
  uploadIfNeeded();  // bodies added since the last step: the host copy is the current one
  cudaStream_t s = d_->stream;
  const DeviceBodies& b = d_->bodies;
  const DeviceContacts& c = d_->contacts;
  const size_t nc = c.count;
  Staged parts[] = {staged(bodies_.pos, b.pos, b.count),
                    staged(bodies_.rot, b.rot, b.count),
                    staged(bodies_.vel, b.vel, b.count),
                    staged(bodies_.omega, b.omega, b.count),
                    staged(shapes_.aabb, d_->shapes.aabb, d_->shapes.count),
                    staged(contacts_.shape_a, c.shape_a, nc),
                    staged(contacts_.shape_b, c.shape_b, nc),
                    staged(contacts_.body_a, c.body_a, nc),
                    staged(contacts_.body_b, c.body_b, nc),
                    staged(contacts_.normal, c.normal, nc),
                    staged(contacts_.pa, c.pa, nc),
                    staged(contacts_.pb, c.pb, nc),
                    staged(contacts_.dist, c.dist, nc),
                    staged(contacts_.mu, c.mu, nc),
                    staged(contacts_.size, c.size, nc),
                    staged(contacts_.key, c.key, nc),
                    staged(gamma_, d_->solver.gamma, d_->solver.gamma.size())};
  size_t total = 0;
  for (Staged& p : parts) {
    p.offset = total;
    total += (p.bytes + 255) / 256 * 256;
  }
  if (total > d_->host_staging_bytes) {
    if (d_->host_staging) DVI_CUDA(cudaFreeHost(d_->host_staging));
    d_->host_staging = nullptr;
    d_->host_staging_bytes = 0;
    const size_t grown = total + total / 4;
    DVI_CUDA(cudaMallocHost(&d_->host_staging, grown));
    d_->host_staging_bytes = grown;
  }
  for (const Staged& p : parts)
    if (p.bytes) DVI_CUDA(cudaMemcpyAsync(d_->host_staging + p.offset, p.device, p.bytes, cudaMemcpyDeviceToHost, s));
  DVI_CUDA(cudaStreamSynchronize(s));
  HostCopy copies[sizeof(parts) / sizeof(parts[0])];
  int nc_copies = 0;
  for (const Staged& p : parts) copies[nc_copies++] = HostCopy{p.host, d_->host_staging + p.offset, p.bytes};
  copyInParallel(copies, nc_copies);
}

}  // namespace dvi
