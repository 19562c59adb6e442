// The Schur product N x = D^T M^-1 D x on the device, in two passes: (a) the gather, per body over its sorted
// adjacency entries, delta = M^-1 D x (heavy bodies by chunks of blocks); (b) per contact or constraint-row block,
// N x from the deltas of its two bodies. The per-element parts are device templates shared by the launches of
// gpu_schur.cu and the persistent APGD kernel (gpu_apgd_persistent.cu), so both compute the same values.
#pragma once

#include <cuda_runtime.h>

#include <cstdint>
#include <type_traits>

#include "chrono_like/solver/jacobian.h"
#include "chrono_like/solver/row_kernels.h"
#include "gpu/gpu_state.cuh"

namespace dvi::gpu {

// A body with this many adjacency entries or more is gathered by a block of threads (HeavyGatherKernel), not
// one thread: the CES drum touches every particle on it, and a single thread summing 10,000 entries per Schur
// product made the whole solve wait for it (157 ms/step at 10,000 particles, H200).
constexpr int32_t kHeavyDegree = 512;

template <class JT>
struct GatherT {
  const int32_t* off;
  const int32_t* adj;
  const JT* jac;
  const ConstraintRow* rows;
  EntryLayout L;
  const BodyInverseMass* inv;
  const real* x;
  BodyDelta* delta;
  const real* const* x_slot = nullptr;  // set: x is *x_slot, read on the device (null there: nothing to do)
  // GpuTuning::entry_gather: the contact entries' float records in entry order (jac's values; float
  // storage only), and the bodies' 16-byte inverse masses; null: jac and inv
  const EntryJacobianF* ej = nullptr;
  const BodyInverseIso* iso = nullptr;
  const uint8_t* skip = nullptr;  // set: the bodies whose delta another kernel writes (PeerExchange::listed)
  __device__ const real* input() const { return x_slot ? *x_slot : x; }
  // Adds entry e (of the sorted adjacency) to (F, T).
  __device__ __forceinline__ void entry(int32_t e, const real* xx, Vec3& F, Vec3& T) const {
    if (ej)
      accumulateEntryImpulse(adj[e], ej[e], L, rows, xx, F, T);
    else
      accumulateEntryImpulse(adj[e], L, jac, rows, xx, F, T);
  }
  __device__ __forceinline__ BodyDelta bodyDelta(int64_t i, Vec3 F, Vec3 T) const {
    if (iso) {
      const BodyInverseIso q = iso[i];
      if (q.i == q.i) return bodyDeltaFromImpulse(q, F, T);  // NaN: not isotropic
    }
    return bodyDeltaFromImpulse(inv[i], F, T);
  }
  __device__ void operator()(int64_t i) const {
    const real* xx = input();
    if (!xx) return;
    const int32_t e0 = off[i], e1 = off[i + 1];
    if (e1 - e0 >= kHeavyDegree || (skip && skip[i])) return;  // HeavyGatherKernel, or the peer sums
    Vec3 F{0, 0, 0}, T{0, 0, 0};
    for (int32_t e = e0; e < e1; ++e) entry(e, xx, F, T);
    delta[i] = bodyDelta(i, F, T);
  }
};

constexpr int kHeavyChunks = 32;  // blocks per heavy body (heavyGatherChunk)

// Chunk c of heavy body h (heavy[h]), summed by the calling block: the entries c*kBlock + t,
// c*kBlock + t + kHeavyChunks*kBlock, ... into a fixed-order tree in shared memory, stored as the chunk's partial;
// the body's last chunk to finish (an atomic ticket, reset for the next product) adds the partials in chunk
// order and writes the body's delta, so the sum is deterministic. x: the impulses (never null here).
template <class JT>
__device__ void heavyGatherChunk(const int32_t* heavy, const GatherT<JT>& g, const real* x, real* partial,
                                 uint32_t* ticket, int32_t h, int32_t c) {
  const int32_t i = heavy[h];
  const int t = threadIdx.x;
  Vec3 F{0, 0, 0}, T{0, 0, 0};
  for (int32_t e = g.off[i] + c * kBlock + t; e < g.off[i + 1]; e += kBlock * kHeavyChunks) g.entry(e, x, F, T);
  __shared__ real sh[6][kBlock];
  __shared__ bool last;
  sh[0][t] = F.x, sh[1][t] = F.y, sh[2][t] = F.z, sh[3][t] = T.x, sh[4][t] = T.y, sh[5][t] = T.z;
  __syncthreads();
  for (int s = kBlock / 2; s > 0; s >>= 1) {
    if (t < s)
      for (int j = 0; j < 6; ++j) sh[j][t] += sh[j][t + s];
    __syncthreads();
  }
  if (t == 0) {
    real* mine = partial + (int64_t(h) * kHeavyChunks + c) * 6;
    for (int j = 0; j < 6; ++j) mine[j] = sh[j][0];
    __threadfence();  // the partial is visible device-wide before the ticket is taken
    last = atomicAdd(ticket + h, 1u) == unsigned(kHeavyChunks - 1);
  }
  __syncthreads();
  const bool finish = last;
  __syncthreads();  // `last` and sh are reused by the caller's next chunk
  if (!finish || t != 0) return;
  __threadfence();
  real sum[6] = {0, 0, 0, 0, 0, 0};
  const real* all = partial + int64_t(h) * kHeavyChunks * 6;
  for (int k = 0; k < kHeavyChunks; ++k)
    for (int j = 0; j < 6; ++j) sum[j] += __ldcg(all + k * 6 + j);  // L2: written by other blocks
  ticket[h] = 0;
  if (!(g.skip && g.skip[i])) g.delta[i] = g.bodyDelta(i, Vec3{sum[0], sum[1], sum[2]}, Vec3{sum[3], sum[4], sum[5]});
}

// The output of a Schur pass (b): y, or *slot where the device chooses the buffer (null there: skip).
// V: the storage type of y (real, or float for VectorStorage::Float). add: stores N x + add (the gradient
// form of the float APGD loop, kern::ApgdStepT::grad_form) when set.
template <class V>
struct SchurOut {
  V* y;
  V* const* slot;
  const real* add = nullptr;
  __device__ V* get() const { return slot ? *slot : y; }
  __device__ V value(real v, int64_t i) const { return V(add ? v + add[i] : v); }
};

template <class V, class JT>
struct ContactF {
  const JT* jac;
  const BodyDelta* delta;
  SchurOut<V> out;
  // keep: when set, also the 3 values written (the register-cached APGD kernel)
  __device__ void operator()(int64_t k, V* keep = nullptr) const {
    V* y = out.get();
    if (!y) return;
    const ContactJacobian J = loadJacobian(jac[k]);
    const BodyDelta A = delta[J.a], B = delta[J.b];
    real v[3];
    contactRelativeVelocity(J, A.v, A.w, B.v, B.w, v);
    for (int j = 0; j < 3; ++j) {
      const V w = out.value(v[j], 3 * k + j);
      y[3 * k + j] = w;
      if (keep) keep[j] = w;
    }
  }
};

template <class V, class JT>
struct NormalContactF {  // normal-only pass (b): y[k] over the 3 ncb rows (padding rows 0)
  const JT* jac;
  const BodyDelta* delta;
  int64_t nc;
  SchurOut<V> out;
  __device__ void operator()(int64_t k, V* keep = nullptr) const {  // keep: as ContactF's, the value written
    V* y = out.get();
    if (!y) return;
    V w;
    if (k >= nc) {
      w = out.value(0, k);
    } else {
      const ContactJacobian J = loadJacobian(jac[k]);
      const BodyDelta A = delta[J.a], B = delta[J.b];
      w = out.value(contactNormalVelocity(J, A.v, A.w, B.v, B.w), k);
    }
    y[k] = w;
    if (keep) *keep = w;
  }
};

template <class V>
struct RowSchurF {  // y of every constraint row (pass (b) for the row blocks)
  const ConstraintRow* rows;
  const BodyDelta* delta;
  SchurOut<V> out;
  int64_t first;  // y[first + i]: the row blocks follow the contact blocks
  __device__ void operator()(int64_t i, V* keep = nullptr) const {  // keep: as ContactF's, the value written
    V* y = out.get();
    if (!y) return;
    const V w = out.value(rowFromDeltas(rows[i], delta), first + i);
    y[first + i] = w;
    if (keep) *keep = w;
  }
};

// The contacts' Jacobians as JT: S.jac (ContactJacobian) or its float copy S.jacf (ContactJacobianF).
template <class JT>
const JT* contactJacobians(const SolverScratch& S) {
  if constexpr (std::is_same_v<JT, ContactJacobian>)
    return S.jac.data();
  else
    return S.jacf.data();
}

inline EntryLayout layoutOf(const DeviceState& d) {
  return EntryLayout{int64_t(d.contacts.count), d.contact_blocks, d.normal_only};
}

// The gather over jac (S.jac, or S.jacf for the float APGD trials), with the entry records and isotropic inverse
// masses where BuildRows wrote them (GpuTuning::entry_gather; the entry records only with S.jacf, whose
// values they copy).
template <class JT>
GatherT<JT> gatherOf(DeviceState& d, const JT* jac, const real* x, const real* const* x_slot) {
  SolverScratch& S = d.solver;
  GatherT<JT> g{S.adj_off.data(),
                S.adj_val_sorted.data(),
                jac,
                S.rows.data(),
                layoutOf(d),
                d.bodies.inv.data(),
                x,
                d.bodies.delta.data(),
                x_slot};
  if (d.entry_gather) {
    if constexpr (std::is_same_v<JT, ContactJacobianF>) g.ej = S.entry_jac.data();
    g.iso = S.inv_iso.data();
  }
  return g;
}

// delta = M^-1 D x per body (Schur pass a, and the impulses' velocity change); x is *x_slot when that is set.
// JT: the Jacobians read (jac: S.jac, or S.jacf for the float APGD trials).
template <class JT = ContactJacobian>
void gather(DeviceState& d, const real* x, const char* what, const real* const* x_slot = nullptr,
            const JT* jac = nullptr);

// y = N x (+ add, when set). With slots, x = *x_slot and y = *y_slot are read on the device (the APGD device
// loop). V: the storage type of y; float (VectorStorage::Float) reads the float copy of the Jacobians.
template <class V = real>
void schur(DeviceState& d, const real* x, V* y, const real* const* x_slot = nullptr, V* const* y_slot = nullptr,
           const real* add = nullptr);

}  // namespace dvi::gpu
