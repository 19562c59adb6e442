// BuildRows on the device: the bodies' inverse masses, the combined friction, the constraint rows from the host,
// every block's Jacobians, rhs, block inverse and steps (jacobian.h, row_kernels.h: the functions ContactProblem
// calls on the CPU), the body -> entry adjacency the gather reads, and the maxima read back once a step.
#include <cuda_runtime.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <cub/cub.cuh>
#include <string>
#include <type_traits>
#include <vector>

#include "chrono_like/base/errors.h"
#include "chrono_like/solver/jacobian.h"
#include "chrono_like/solver/row_kernels.h"
#include "chrono_like/solver/solver.h"
#include "gpu/cub_call.cuh"
#include "gpu/gpu_state.cuh"
#include "gpu/solver/gpu_reduce.cuh"
#include "gpu/solver/gpu_schur.cuh"

namespace dvi::gpu {

namespace {

__device__ __forceinline__ bool movable(const BodyInverseMass& B) {
  return B.m != 0 || B.I[0] != 0 || B.I[1] != 0 || B.I[2] != 0 || B.I[3] != 0 || B.I[4] != 0 || B.I[5] != 0;
}

struct BodyInverseF {
  const real* inv_mass;
  const Vec3* inv_inertia;
  const Quat* rot;
  const uint8_t* flags;
  BodyInverseMass* out;
  BodyInverseIso* iso;  // the gather's 16-byte form (GpuTuning::entry_gather), else null
  __device__ void operator()(int64_t i) const {
    const bool fixed = flags[i] & (kBodyFixed | kBodyKinematic);
    const BodyInverseMass B =
        fixed ? BodyInverseMass{0, {0, 0, 0, 0, 0, 0}} : makeBodyInverseMass(inv_mass[i], inv_inertia[i], rot[i]);
    out[i] = B;
    if (iso) iso[i] = isoInverse(B);
  }
};

// Combined friction, pair size and penetration of every contact (first: mu decides the problem's rows).
struct MuF {
  const int32_t *body_a, *body_b, *shape_a, *shape_b;
  const real *dist, *friction;
  const Shape* shapes;
  FrictionCombine rule;
  real *mu, *size, *pen;
  __device__ void operator()(int64_t k) const {
    const real fa = friction[body_a[k]], fb = friction[body_b[k]];
    mu[k] = rule == FrictionCombine::Product ? fa * fb
            : rule == FrictionCombine::Min   ? fmin(fa, fb)
                                             : real(0.5) * (fa + fb);
    size[k] = fmin(shapes[shape_a[k]].size, shapes[shape_b[k]].size);
    pen[k] = -dist[k];
  }
};

struct RowsF {
  const int32_t *body_a, *body_b;
  const Vec3 *normal, *pa, *pb, *pos, *v_free, *w_free;
  const real *dist, *size;
  const BodyInverseMass* inv;
  ContactBiasInputs bias;  // the normal rows' bias: step, recovery, restitution (jacobian.h: contactNormalBias)
  int32_t nbodies;
  bool normal_only;  // the normal row only (block data per three contacts: NormalBlockF)
  real *rhs, *binv, *eta, *diag_max, *colnorm, *rowsum;
  ContactJacobian* jac;
  uint32_t* adj_key;
  int32_t* adj_val;
  ContactJacobianF* jacf;  // VectorStorage::Float: the rounded Jacobian, also as float (else null)
  __device__ void operator()(int64_t k) const {
    const int32_t a = body_a[k], b = body_b[k];
    ContactJacobian J = makeContactJacobian(normal[k], pa[k], pb[k], pos[a], pos[b], a, b);
    if (jacf) {
      J = roundJacobian(J);
      jacf[k] = toFloatJacobian(J);
    }
    jac[k] = J;
    const BodyInverseMass A = inv[a], B = inv[b];
    if (normal_only) {
      rhs[k] = contactNormalVelocity(J, v_free[a], w_free[a], v_free[b], w_free[b]) +
               contactNormalBias(J, dist[k], size[k], bias);
    } else {
      real* rk = rhs + 3 * k;
      contactRelativeVelocity(J, v_free[a], w_free[a], v_free[b], w_free[b], rk);
      rk[0] += contactNormalBias(J, dist[k], size[k], bias);
      real N[6];
      contactDiagonalBlock(J, A, B, N);
      invertSymmetric3(N, binv + 6 * k);
      eta[k] = blockStepFromDiagonal(N);
      contactColumnNorms(J, A, B, colnorm + 6 * k);
      blockRowSums(N, rowsum + 3 * k);
      diag_max[k] = fmax(N[0], fmax(N[1], N[2]));
    }
    // adjacency entries 2k + side, keyed by body (inactive bodies sort last)
    adj_key[2 * k] = movable(A) ? uint32_t(a) : uint32_t(nbodies);
    adj_key[2 * k + 1] = movable(B) ? uint32_t(b) : uint32_t(nbodies);
    adj_val[2 * k] = int32_t(2 * k);
    adj_val[2 * k + 1] = int32_t(2 * k + 1);
  }
};

// Block q of a normal-only problem: contacts 3q .. 3q+2 (jacobian.h: assembleNormalBlock), their boxes
// [0, inf) and the padding rows' [0, 0].
struct NormalBlockF {
  const ContactJacobian* jac;
  const BodyInverseMass* inv;
  int64_t nc;
  real *rhs, *binv, *eta, *colnorm, *rowsum, *diag_max, *lo, *hi;
  __device__ void operator()(int64_t q) const {
    const int cnt = int(nc - 3 * q < 3 ? nc - 3 * q : 3);
    for (int j = 0; j < 3; ++j) {
      lo[3 * q + j] = 0;
      hi[3 * q + j] = j < cnt ? real(INFINITY) : real(0);
      if (j >= cnt) rhs[3 * q + j] = 0;
    }
    diag_max[q] = assembleNormalBlock(jac + 3 * q, cnt, inv, binv + 6 * q, eta + q, colnorm + 6 * q, rowsum + 3 * q);
  }
};

struct NormalJacobiStepF {
  const ContactJacobian* jac;
  const real *colnorm, *rowsum, *bodyq;
  int64_t nc;
  real* jeta;
  __device__ void operator()(int64_t q) const {
    const int cnt = int(nc - 3 * q < 3 ? nc - 3 * q : 3);
    jeta[q] = normalBlockJacobiStep(jac + 3 * q, cnt, colnorm + 6 * q, rowsum + 3 * q, bodyq);
  }
};

// Entry e of the sorted adjacency: its contact side's float record (row entries have none: the gather reads the
// row's Jacobian).
struct EntryJacobianOrderF {
  const int32_t* adj;
  const ContactJacobianF* jacf;
  int64_t contact_entries;  // 2 nc
  EntryJacobianF* out;
  __device__ void operator()(int64_t e) const {
    const int32_t v = adj[e];
    if (v < contact_entries) out[e] = entryJacobian(jacf[v >> 1], v & 1);
  }
};

struct AdjOffsetF {
  const uint32_t* keys;
  int64_t n;
  int32_t* off;
  __device__ void operator()(int64_t i) const {  // first entry with key >= i
    int64_t lo = 0, hi = n;
    while (lo < hi) {
      const int64_t mid = (lo + hi) / 2;
      if (keys[mid] < uint32_t(i))
        lo = mid + 1;
      else
        hi = mid;
    }
    off[i] = int32_t(lo);
  }
};

struct KeyOrderF {  // 1 where the keys are out of order
  const uint64_t* key;
  real* out;
  int64_t n;
  __device__ void operator()(int64_t k) const { out[k] = (k + 1 < n && key[k] > key[k + 1]) ? real(1) : real(0); }
};

struct HeavyListF {
  const int32_t* off;
  int32_t* heavy;
  int32_t* count;
  __device__ void operator()(int64_t i) const {
    if (off[i + 1] - off[i] >= kHeavyDegree) heavy[atomicAdd(count, 1)] = int32_t(i);
  }
};

// Row block q: rhs, block inverse and step, column norms, row sums, max diagonal; adjacency entries.
struct RowBlockF {
  const ConstraintRow* rows;
  const BodyInverseMass* inv;
  const Vec3 *v_free, *w_free;
  int64_t nc, rb0;  // contacts; first row block
  int32_t nbodies;
  real *rhs, *binv, *eta, *colnorm, *rowsum, *diag_max;
  uint32_t* adj_key;
  int32_t* adj_val;
  __device__ void operator()(int64_t q) const {
    const int64_t k = rb0 + q;
    diag_max[k] = assembleRowBlock(rows + 3 * q, inv, v_free, w_free, rhs + 3 * k, binv + 6 * k, eta + k,
                                   colnorm + 6 * k, rowsum + 3 * k);
    for (int j = 0; j < 3; ++j) {
      const int64_t i = 3 * q + j;
      const ConstraintRow& R = rows[i];
      const int64_t e = 2 * nc + 2 * i;
      adj_key[e] = (R.a >= 0 && movable(inv[R.a])) ? uint32_t(R.a) : uint32_t(nbodies);
      adj_key[e + 1] = (R.b >= 0 && movable(inv[R.b])) ? uint32_t(R.b) : uint32_t(nbodies);
      adj_val[e] = int32_t(e);
      adj_val[e + 1] = int32_t(e + 1);
    }
  }
};

struct RowJacobiStepF {
  const ConstraintRow* rows;
  const real *colnorm, *rowsum, *bodyq;
  int64_t rb0;  // first row block
  real* jeta;
  __device__ void operator()(int64_t q) const {
    const int64_t k = rb0 + q;
    jeta[k] = rowBlockJacobiStep(rows + 3 * q, colnorm + 6 * k, rowsum + 3 * k, bodyq);
  }
};

// Per body: the sum of the Jacobian column norms of its adjacency entries (Q_c of contactJacobiStep).
struct BodyColumnSumF {
  const int32_t* off;
  const int32_t* adj;
  const real* colnorm;
  EntryLayout L;
  real* bodyq;
  __device__ void operator()(int64_t i) const {
    real q = 0;
    for (int32_t e = off[i]; e < off[i + 1]; ++e) q += entryColumnSum(adj[e], L, colnorm);
    bodyq[i] = q;
  }
};

struct JacobiStepF {
  const ContactJacobian* jac;
  const real *colnorm, *rowsum, *bodyq;
  real* jeta;
  __device__ void operator()(int64_t k) const {
    jeta[k] = contactJacobiStep(colnorm + 6 * k, rowsum + 3 * k, bodyq[jac[k].a], bodyq[jac[k].b]);
  }
};

// The sizes of a step's problem.
struct RowCounts {
  int64_t nc = 0;          // contacts
  int64_t nb = 0;          // bodies
  int64_t ncb = 0;         // contact blocks (normal-only: three contacts a block)
  int64_t nbox = 0;        // box entries of the normal blocks, before the rows'
  int64_t nrb = 0;         // constraint-row blocks
  int64_t nblk = 0;        // all blocks
  int64_t nent = 0;        // adjacency entries: 2 per contact, 2 per row
  bool normal = false;     // normal-only problem
  bool float_jac = false;  // VectorStorage::Float with APGD: the Jacobians rounded to float, and a float copy
};

// The bodies' world inverse masses (and their 16-byte isotropic form for the entry gather).
void inverseMasses(DeviceState& d, const SystemConfig& cfg, int64_t nb) {
  SolverScratch& S = d.solver;
  DeviceBodies& B = d.bodies;
  d.entry_gather = cfg.gpu.entry_gather;
  if (d.entry_gather) S.inv_iso.resize(nb);
  launchMap(d, nb,
            BodyInverseF{B.inv_mass.data(), B.inv_inertia.data(), B.rot.data(), B.flags.data(), B.inv.data(),
                         d.entry_gather ? S.inv_iso.data() : nullptr},
            "launch of BodyInverseF");
}

// Combined friction, pair size and penetration of every contact; returns the largest mu (1 when every contact's
// mu is known to be positive, 0 without pruning: only its sign is read).
real combinedFriction(DeviceState& d, const SystemConfig& cfg, int64_t nc) {
  SolverScratch& S = d.solver;
  DeviceBodies& B = d.bodies;
  DeviceContacts& C = d.contacts;
  C.mu.resize(nc);
  C.size.resize(nc);
  S.v6.resize(nc);  // per-contact penetration
  launchMap(d, nc,
            MuF{C.body_a.data(), C.body_b.data(), C.shape_a.data(), C.shape_b.data(), C.dist.data(), B.friction.data(),
                d.shapes.shape.data(), cfg.collision.friction_combine, C.mu.data(), C.size.data(), S.v6.data()},
            "launch of MuF");
  real max_mu = 0;
  if (nc > 0 && cfg.prune && d.all_frictional) {
    max_mu = 1;  // every contact's mu is positive (GpuSystem::uploadIfNeeded): no reduction, no read-back
  } else if (nc > 0 && cfg.prune) {
    d.step_scalars.resize(16);
    real* mu_out = reinterpret_cast<real*>(d.step_scalars.data()) + 4;
    cubRun(d, "cub::DeviceReduce::Max (friction)",
           [&](void* t, size_t& b) { return cub::DeviceReduce::Max(t, b, C.mu.data(), mu_out, int(nc), d.stream); });
    max_mu = d.readValue(mu_out);
  }
  return max_mu;
}

// Constraint rows from the host (RowProvider plug-ins), padded to blocks of three (row_kernels.h), and their
// boxes after the normal blocks' (n.nbox).
void uploadRows(DeviceState& d, const std::vector<ConstraintRow>& rows, const RowCounts& n) {
  SolverScratch& S = d.solver;
  const int64_t nrb = n.nrb, nbox = n.nbox;
  std::vector<ConstraintRow>& padded = d.host_rows;
  padded.assign(rows.begin(), rows.end());
  std::vector<real>& lohi = d.host_lohi;
  lohi.assign(size_t(6 * nrb), real(0));
  for (int64_t i = 0; i < 3 * nrb; ++i) {
    if (i >= int64_t(rows.size())) {
      ConstraintRow pad;
      pad.lo = pad.hi = 0;
      padded.push_back(pad);
    }
    lohi[size_t(i)] = padded[size_t(i)].lo;
    lohi[size_t(3 * nrb + i)] = padded[size_t(i)].hi;
    for (int32_t c : {padded[size_t(i)].a, padded[size_t(i)].b})
      if (c < -1 || c >= n.nb)
        throw InputError("constraint row " + std::to_string(i) + ": body index " + std::to_string(c) + " out of range");
  }
  S.rows.upload(padded, d.stream);
  S.row_lo.resize(size_t(nbox + 3 * nrb));
  S.row_hi.resize(size_t(nbox + 3 * nrb));
  if (nrb > 0) {
    DVI_CUDA(cudaMemcpyAsync(S.row_lo.data() + nbox, lohi.data(), sizeof(real) * size_t(3 * nrb),
                             cudaMemcpyHostToDevice, d.stream));
    DVI_CUDA(cudaMemcpyAsync(S.row_hi.data() + nbox, lohi.data() + 3 * nrb, sizeof(real) * size_t(3 * nrb),
                             cudaMemcpyHostToDevice, d.stream));
  }
}

// The problem's per-contact, per-block, per-body and per-entry buffers at this step's sizes.
void resizeProblem(DeviceState& d, const RowCounts& n) {
  SolverScratch& S = d.solver;
  const int64_t nc = n.nc, nb = n.nb, nblk = n.nblk, nent = n.nent;
  S.jac.resize(nc);
  if (n.float_jac) S.jacf.resize(nc);
  S.rhs.resize(3 * nblk);
  S.block_inv.resize(6 * nblk);
  S.block_step.resize(nblk);
  S.jacobi_step.resize(nblk);
  S.colnorm.resize(6 * nblk);
  S.rowsum.resize(3 * nblk);
  S.bodyq.resize(nb);
  S.adj_key.resize(nent);
  S.adj_val.resize(nent);
  S.adj_key_sorted.resize(nent);
  S.adj_val_sorted.resize(nent);
  S.adj_off.resize(nb + 1);
  S.v5.resize(nblk);  // per-block max diagonal entry
  S.v4.resize(nc);    // key order flags
}

// Every block's rhs, inverse, steps, column norms, row sums and max diagonal, the Jacobians, the unsorted
// adjacency entries, and the contact keys' order flags.
void assembleBlocks(DeviceState& d, const SystemConfig& cfg, const StepContext& step, const RowCounts& n) {
  SolverScratch& S = d.solver;
  DeviceBodies& B = d.bodies;
  DeviceContacts& C = d.contacts;
  const int64_t nc = n.nc, nb = n.nb, ncb = n.ncb, nrb = n.nrb;
  const bool normal = n.normal;
  RowsF f{C.body_a.data(),
          C.body_b.data(),
          C.normal.data(),
          C.pa.data(),
          C.pb.data(),
          B.pos.data(),
          B.v_free.data(),
          B.w_free.data(),
          C.dist.data(),
          C.size.data(),
          B.inv.data(),
          ContactBiasInputs{step.dt, cfg.solver.recovery_rel, cfg.solver.min_bounce_speed,
                            d.any_restitution ? B.restitution.data() : nullptr, B.vel.data(), B.omega.data(),
                            B.v_free.data(), B.w_free.data()},
          int32_t(nb),
          normal,
          S.rhs.data(),
          S.block_inv.data(),
          S.block_step.data(),
          S.v5.data(),
          S.colnorm.data(),
          S.rowsum.data(),
          S.jac.data(),
          S.adj_key.data(),
          S.adj_val.data(),
          n.float_jac ? S.jacf.data() : nullptr};
  launchMap(d, nc, f, "launch of RowsF");
  if (normal)
    launchMap(d, ncb,
              NormalBlockF{S.jac.data(), B.inv.data(), nc, S.rhs.data(), S.block_inv.data(), S.block_step.data(),
                           S.colnorm.data(), S.rowsum.data(), S.v5.data(), S.row_lo.data(), S.row_hi.data()},
              "launch of NormalBlockF");
  launchMap(d, nrb,
            RowBlockF{S.rows.data(), B.inv.data(), B.v_free.data(), B.w_free.data(), nc, ncb, int32_t(nb), S.rhs.data(),
                      S.block_inv.data(), S.block_step.data(), S.colnorm.data(), S.rowsum.data(), S.v5.data(),
                      S.adj_key.data(), S.adj_val.data()},
            "launch of RowBlockF");
  launchMap(d, nc, KeyOrderF{C.key.data(), S.v4.data(), nc}, "launch of KeyOrderF");
}

// The body -> entry CSR (a stable radix sort by body keeps each body's entries in increasing k), the float
// trials' entry records in that order, and the list of heavy bodies (its count is read back with the maxima).
void buildAdjacency(DeviceState& d, const RowCounts& n) {
  SolverScratch& S = d.solver;
  const int64_t nc = n.nc, nb = n.nb, nent = n.nent;
  const int bits = bitsFor(uint64_t(nb));
  cubRun(d, "cub::DeviceRadixSort::SortPairs (adjacency)", [&](void* t, size_t& b) {
    return cub::DeviceRadixSort::SortPairs(t, b, S.adj_key.data(), S.adj_key_sorted.data(), S.adj_val.data(),
                                           S.adj_val_sorted.data(), int(nent), 0, bits, d.stream);
  });
  launchMap(d, nb + 1, AdjOffsetF{S.adj_key_sorted.data(), nent, S.adj_off.data()}, "launch of AdjOffsetF");
  if (n.float_jac && d.entry_gather) {  // the float trials' gather reads each entry's side of the Jacobian in order
    S.entry_jac.resize(nent);
    launchMap(d, nent, EntryJacobianOrderF{S.adj_val_sorted.data(), S.jacf.data(), 2 * nc, S.entry_jac.data()},
              "launch of EntryJacobianOrderF");
  }
  S.heavy.resize(nb);
  S.heavy_count.resize(1);
  DVI_CUDA(cudaMemsetAsync(S.heavy_count.data(), 0, sizeof(int32_t), d.stream));
  launchMap(d, nb, HeavyListF{S.adj_off.data(), S.heavy.data(), S.heavy_count.data()}, "launch of HeavyListF");
}

// Jacobi steps (CcpProblem::jacobiSteps): per-body column sums, then the per-block bounds.
void jacobiSteps(DeviceState& d, const RowCounts& n) {
  SolverScratch& S = d.solver;
  const int64_t nc = n.nc, nb = n.nb, ncb = n.ncb, nrb = n.nrb;
  launchMap(d, nb,
            BodyColumnSumF{S.adj_off.data(), S.adj_val_sorted.data(), S.colnorm.data(), layoutOf(d), S.bodyq.data()},
            "launch of BodyColumnSumF");
  if (d.group) exchangeBodyValues(d, S.bodyq.data());  // Q_c over every process's contacts of a shared body
  if (n.normal)
    launchMap(
        d, ncb,
        NormalJacobiStepF{S.jac.data(), S.colnorm.data(), S.rowsum.data(), S.bodyq.data(), nc, S.jacobi_step.data()},
        "launch of NormalJacobiStepF");
  else
    launchMap(d, nc, JacobiStepF{S.jac.data(), S.colnorm.data(), S.rowsum.data(), S.bodyq.data(), S.jacobi_step.data()},
              "launch of JacobiStepF");
  launchMap(d, nrb,
            RowJacobiStepF{S.rows.data(), S.colnorm.data(), S.rowsum.data(), S.bodyq.data(), ncb, S.jacobi_step.data()},
            "launch of RowJacobiStepF");
}

// max diag(N), max penetration, key order: three maxima, read back with the heavy bodies' count in one
// synchronisation; then the heavy gather's scratch for that count.
void readMaxima(DeviceState& d, const RowCounts& n, real* max_penetration) {
  SolverScratch& S = d.solver;
  const int64_t nc = n.nc, nblk = n.nblk;
  d.step_scalars.resize(16);
  real* out = reinterpret_cast<real*>(d.step_scalars.data());
  cubRun(d, "cub::DeviceReduce::Max (diagonal)",
         [&](void* t, size_t& b) { return cub::DeviceReduce::Max(t, b, S.v5.data(), out, int(nblk), d.stream); });
  cubRun(d, "cub::DeviceReduce::Max (penetration)",
         [&](void* t, size_t& b) { return cub::DeviceReduce::Max(t, b, S.v6.data(), out + 1, int(nc), d.stream); });
  cubRun(d, "cub::DeviceReduce::Max (key order)",
         [&](void* t, size_t& b) { return cub::DeviceReduce::Max(t, b, S.v4.data(), out + 2, int(nc), d.stream); });
  // with the heavy bodies' count, into the pinned scalars: one synchronisation
  static_assert(3 * sizeof(real) + sizeof(int32_t) <= 64 * sizeof(double), "host_scalars holds the read-back");
  char* hs = reinterpret_cast<char*>(d.host_scalars);
  DVI_CUDA(cudaMemcpyAsync(hs, out, 3 * sizeof(real), cudaMemcpyDeviceToHost, d.stream));
  DVI_CUDA(
      cudaMemcpyAsync(hs + 3 * sizeof(real), S.heavy_count.data(), sizeof(int32_t), cudaMemcpyDeviceToHost, d.stream));
  DVI_CUDA(cudaStreamSynchronize(d.stream));
  real host[3];
  std::memcpy(host, hs, sizeof host);
  int32_t n_heavy = 0;
  std::memcpy(&n_heavy, hs + 3 * sizeof(real), sizeof n_heavy);
  S.n_heavy = n_heavy;
  if (S.n_heavy > 0) {
    S.heavy_partial.resize(size_t(S.n_heavy) * kHeavyChunks * 6);
    S.heavy_ticket.resize(size_t(S.n_heavy));
    DVI_CUDA(cudaMemsetAsync(S.heavy_ticket.data(), 0, sizeof(uint32_t) * size_t(S.n_heavy), d.stream));
  }
  d.max_diag = host[0] > real(0) ? host[0] : real(1);
  *max_penetration = std::max(real(0), host[1]);
  d.keys_unsorted = host[2] > real(0);
}

}  // namespace

void buildRows(DeviceState& d, const SystemConfig& cfg, const StepContext& step, const std::vector<ConstraintRow>& rows,
               real* max_penetration) {
  RowCounts n;
  n.nc = int64_t(d.contacts.count);
  n.nb = int64_t(d.bodies.count);
  d.solver.n_heavy = 0;  // set again once this step's adjacency exists
  inverseMasses(d, cfg, n.nb);
  // Combined friction first: friction rows only where mu > 0 (docs/MODEL.md §6). When no contact of the step has
  // mu > 0 the CCP has the normal rows only (jacobian.h), as on the CPU (System::buildAndSolve).
  const real max_mu = combinedFriction(d, cfg, n.nc);
  // Over several processes the choice is the whole problem's: some contact anywhere, none with mu > 0.
  d.normal_only = d.group ? cfg.prune && d.group->any(n.nc > 0) && !d.group->any(max_mu > 0)
                          : cfg.prune && n.nc > 0 && !(max_mu > 0);
  n.normal = d.normal_only;
  n.ncb = n.normal ? (n.nc + 2) / 3 : n.nc;
  d.contact_blocks = n.ncb;
  n.nbox = n.normal ? 3 * n.ncb : 0;
  n.nrb = (int64_t(rows.size()) + 2) / 3;
  n.nblk = n.ncb + n.nrb;
  d.row_count = rows.size();
  uploadRows(d, rows, n);
  // The float Jacobians serve APGD's trials on the device (over several processes too).
  n.float_jac = cfg.solver.type == SolverType::APGD && floatStorage(cfg.solver, true) && !std::is_same_v<real, float>;
  n.nent = 2 * n.nc + 6 * n.nrb;
  resizeProblem(d, n);
  assembleBlocks(d, cfg, step, n);
  buildAdjacency(d, n);
  // Only Jacobi reads the Jacobi steps: for the other solvers they are left out (the per-body sum runs in one
  // thread per body, and the CES drum's 15,000 entries made it 3.6 ms of every step's BuildRows on an H200).
  if (cfg.solver.type == SolverType::Jacobi) jacobiSteps(d, n);
  readMaxima(d, n, max_penetration);
}

}  // namespace dvi::gpu
