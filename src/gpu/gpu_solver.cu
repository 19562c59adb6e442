// BuildRows, WarmStart, Solve and the impulse application on the device. The per-contact and per-body
// work is jacobian.h / cone.h (the functions ContactProblem calls on the CPU); the solvers are the very
// templates of chrono_like/solver/solver_algorithms.h with their kern:: functors, instantiated with GpuOps
// (CUDA kernels over the device vectors) where the CPU instantiates them with OpenMP loops. Reductions are deterministic: a fixed grid sums
// fixed slices, then one block sums the partials in order.
#include <cuda_runtime.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <cooperative_groups.h>
#include <cuda/atomic>
#include <cub/cub.cuh>
#include <stdexcept>
#include <string>
#include <type_traits>

#include "chrono_like/solver/cone.h"
#include "chrono_like/solver/jacobian.h"
#include "chrono_like/solver/row_kernels.h"
#include "chrono_like/solver/solver.h"
#include "chrono_like/solver/solver_algorithms.h"
#include "gpu/cub_call.cuh"
#include "gpu/gpu_state.cuh"

namespace dvi::gpu {

namespace {

constexpr int kReduceBlocks = 1024;  // fixed grid of every reduction (deterministic partial order)

template <class F>
__global__ void mapKernel(int64_t n, F f) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i < n) f(i);
}

// Sums acc[0..M) over the block in a fixed order: a fixed shuffle tree per warp, then the warps' sums in order
// by thread 0, which alone holds the result (written to out; one barrier, where a cub::BlockReduce per value
// took one each). Ends with a barrier, so the shared scratch can be used again at once.
template <int M>
__device__ __forceinline__ void blockSumFixed(double* acc, double* out) {
  for (int m = 0; m < M; ++m)
    for (int o = 16; o > 0; o >>= 1) acc[m] += __shfl_down_sync(0xffffffffu, acc[m], o);
  __shared__ double warp_sum[M][kBlock / 32];
  const int lane = threadIdx.x & 31, warp = threadIdx.x >> 5;
  if (lane == 0)
    for (int m = 0; m < M; ++m) warp_sum[m][warp] = acc[m];
  __syncthreads();
  if (threadIdx.x == 0)
    for (int m = 0; m < M; ++m) {
      double s = 0;
      for (int w = 0; w < kBlock / 32; ++w) s += warp_sum[m][w];
      out[m] = s;
    }
  __syncthreads();
}

// Partial `slice` of `slices` of a deterministic reduction: the slice's grid-strided elements of f (element
// slice*kBlock + t + j*slices*kBlock in thread t), summed in a fixed tree. A kernel's block is a slice
// (reduceBlockSlice); the persistent APGD kernel runs the slices of a fixed count over whatever grid it has,
// so both sum every element in the same order.
template <int M, class F>
__device__ __forceinline__ void reduceSlice(int slice, int slices, int64_t n, const F& f, double* partial) {
  double acc[M];
  for (int m = 0; m < M; ++m) acc[m] = 0;
  for (int64_t i = int64_t(slice) * kBlock + threadIdx.x; i < n; i += int64_t(slices) * kBlock) f(i, acc);
  blockSumFixed<M>(acc, partial + int64_t(slice) * M);
}

// Block partials of a deterministic reduction: this block's grid-strided slice of f, summed in a fixed tree.
template <int M, class F>
__device__ __forceinline__ void reduceBlockSlice(int64_t n, const F& f, double* partial) {
  reduceSlice<M>(int(blockIdx.x), int(gridDim.x), n, f, partial);
}

// The partials of nblk blocks summed in a fixed order by one block (strided per thread, then blockSumFixed).
// The result lands in out (thread 0's view only is defined before the final __syncthreads).
template <int M>
__device__ __forceinline__ void reducePartials(int nblk, const double* partial, double* out) {
  double acc[M];
  for (int m = 0; m < M; ++m) acc[m] = 0;
  for (int b = threadIdx.x; b < nblk; b += blockDim.x)
    for (int m = 0; m < M; ++m) acc[m] += __ldcg(partial + b * M + m);  // L2: written by other blocks
  blockSumFixed<M>(acc, out);
}

template <int M, class F>
__global__ void __launch_bounds__(kBlock) reduceKernel(int64_t n, F f, double* partial) {
  reduceBlockSlice<M>(n, f, partial);
}

template <int M>
__global__ void __launch_bounds__(kBlock) finalizeKernel(int nblk, const double* partial, double* out) {
  reducePartials<M>(nblk, partial, out);
}

// Blocks of every deterministic reduction over n elements (a fixed grid: the partials' order is fixed).
int reduceBlocksFor(int64_t n) {
  return int(std::max<int64_t>(1, std::min<int64_t>(kReduceBlocks, (n + kBlock - 1) / kBlock)));
}

template <class F>
void launchMap(DeviceState& d, int64_t n, const F& f, const char* what) {
  if (n <= 0) return;
  mapKernel<<<blocksFor(n), kBlock, 0, d.stream>>>(n, f);
  cudaCheck(cudaGetLastError(), what, __FILE__, __LINE__);
}

// Sums M values over n elements; returns a pointer to M doubles on the host (valid until the next read)
// or, with read = false, leaves them on the device only (at S.scalars + slot).
template <int M, class F>
const double* launchReduce(DeviceState& d, int64_t n, const F& f, const char* what, bool read = true, int slot = 0) {
  SolverScratch& S = d.solver;
  const int nblk = reduceBlocksFor(n);
  S.partial.resize(size_t(nblk) * M);
  S.scalars.resize(64);
  reduceKernel<M><<<nblk, kBlock, 0, d.stream>>>(n, f, S.partial.data());
  cudaCheck(cudaGetLastError(), what, __FILE__, __LINE__);
  finalizeKernel<M><<<1, kBlock, 0, d.stream>>>(nblk, S.partial.data(), S.scalars.data() + slot);
  cudaCheck(cudaGetLastError(), what, __FILE__, __LINE__);
  return read ? d.readScalars(S.scalars.data(), M) : nullptr;
}

__device__ __forceinline__ bool movable(const BodyInverseMass& B) {
  return B.m != 0 || B.I[0] != 0 || B.I[1] != 0 || B.I[2] != 0 || B.I[3] != 0 || B.I[4] != 0 || B.I[5] != 0;
}

// ---- BuildRows ----

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
  real h, recovery_rel;
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
               contactBias(dist[k], h, recovery_rel, size[k]);
    } else {
      real* rk = rhs + 3 * k;
      contactRelativeVelocity(J, v_free[a], w_free[a], v_free[b], w_free[b], rk);
      rk[0] += contactBias(dist[k], h, recovery_rel, size[k]);
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
      if (keys[mid] < uint32_t(i)) lo = mid + 1;
      else hi = mid;
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

// ---- Schur product: pass (a) per body, pass (b) per contact ----

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
  __device__ const real* input() const { return x_slot ? *x_slot : x; }
  // Adds entry e (of the sorted adjacency) to (F, T).
  __device__ __forceinline__ void entry(int32_t e, const real* xx, Vec3& F, Vec3& T) const {
    if (ej) accumulateEntryImpulse(adj[e], ej[e], L, rows, xx, F, T);
    else accumulateEntryImpulse(adj[e], L, jac, rows, xx, F, T);
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
    if (e1 - e0 >= kHeavyDegree) return;  // HeavyGatherKernel
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
  g.delta[i] = g.bodyDelta(i, Vec3{sum[0], sum[1], sum[2]}, Vec3{sum[3], sum[4], sum[5]});
}

// Heavy bodies are gathered by kHeavyChunks blocks each (grid kHeavyChunks x n_heavy), block (c, h) summing
// chunk c of heavy body h. One block per body made every Schur product wait for the drum: 31 us of a 65 us
// APGD trial in the CES industrial feed (15,000 entries, H200 ncu).
template <class JT>
__global__ void __launch_bounds__(kBlock) HeavyGatherKernel(const int32_t* heavy, GatherT<JT> g, real* partial,
                                                           uint32_t* ticket) {
  const real* x = g.input();
  if (!x) return;  // the same for every block of the launch
  heavyGatherChunk(heavy, g, x, partial, ticket, int32_t(blockIdx.y), int32_t(blockIdx.x));
}

struct HeavyListF {
  const int32_t* off;
  int32_t* heavy;
  int32_t* count;
  __device__ void operator()(int64_t i) const {
    if (off[i + 1] - off[i] >= kHeavyDegree) heavy[atomicAdd(count, 1)] = int32_t(i);
  }
};

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

struct ProblemView {
  int64_t nc = 0;   // contact blocks
  int64_t nb = 0;   // all blocks (contacts, then constraint-row blocks)
  const real* lo = nullptr;
  const real* hi = nullptr;
  const real* r = nullptr;
  const real* mu = nullptr;
  const real* eta = nullptr;
  const real* jeta = nullptr;
  const real* binv = nullptr;
  real max_diag = 1;
};

EntryLayout layoutOf(const DeviceState& d) {
  return EntryLayout{int64_t(d.contacts.count), d.contact_blocks, d.normal_only};
}

// The gather over jac (S.jac, or S.jacf for the float APGD trials), with the entry records and isotropic inverse
// masses where BuildRows wrote them (GpuTuning::entry_gather; the entry records only with S.jacf, whose
// values they copy).
template <class JT>
GatherT<JT> gatherOf(DeviceState& d, const JT* jac, const real* x, const real* const* x_slot) {
  SolverScratch& S = d.solver;
  GatherT<JT> g{S.adj_off.data(), S.adj_val_sorted.data(), jac, S.rows.data(), layoutOf(d),
                d.bodies.inv.data(), x, d.bodies.delta.data(), x_slot};
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
            const JT* jac = nullptr) {
  SolverScratch& S = d.solver;
  if constexpr (std::is_same_v<JT, ContactJacobian>) {
    if (!jac) jac = S.jac.data();
  }
  const GatherT<JT> g = gatherOf(d, jac, x, x_slot);
  launchMap(d, int64_t(d.bodies.count), g, what);
  if (S.n_heavy > 0) {
    HeavyGatherKernel<JT><<<dim3(kHeavyChunks, unsigned(S.n_heavy)), kBlock, 0, d.stream>>>(
        S.heavy.data(), g, S.heavy_partial.data(), S.heavy_ticket.data());
    cudaCheck(cudaGetLastError(), "launch of HeavyGatherKernel", __FILE__, __LINE__);
  }
}

// y = N x (+ add, when set). With slots, x = *x_slot and y = *y_slot are read on the device (the APGD device
// loop). V: the storage type of y; float (VectorStorage::Float) reads the float copy of the Jacobians.
template <class V = real>
void schur(DeviceState& d, const real* x, V* y, const real* const* x_slot = nullptr, V* const* y_slot = nullptr,
           const real* add = nullptr) {
  using JT = std::conditional_t<std::is_same_v<V, real>, ContactJacobian, ContactJacobianF>;
  SolverScratch& S = d.solver;
  const JT* jac = nullptr;
  if constexpr (std::is_same_v<JT, ContactJacobian>) jac = S.jac.data();
  else jac = S.jacf.data();
  const int64_t nc = int64_t(d.contacts.count);
  const SchurOut<V> out{y, y_slot, add};
  gather<JT>(d, x, "launch of GatherF (Schur pass a)", x_slot, jac);
  if (d.normal_only)
    launchMap(d, 3 * d.contact_blocks, NormalContactF<V, JT>{jac, d.bodies.delta.data(), nc, out},
              "launch of NormalContactF (Schur pass b, normal rows)");
  else
    launchMap(d, nc, ContactF<V, JT>{jac, d.bodies.delta.data(), out}, "launch of ContactF (Schur pass b)");
  launchMap(d, int64_t(S.rows.size()), RowSchurF<V>{S.rows.data(), d.bodies.delta.data(), out, 3 * d.contact_blocks},
            "launch of RowSchurF (Schur pass b, rows)");
}

// ---- APGD iterations on the device (no read-back per iteration) ----
// algo::ApgdControl lives in device memory. Every trial is: the projected step, the Schur product, and the
// test reduction, whose last block sums the partials and calls ApgdControl::afterTest, which picks the
// buffers of the next trial (the Schur passes read them through the slots). Once the control is
// done every kernel of a trial returns at once, so the host enqueues a whole batch of trials and reads the
// control back once per batch.
// How the trials of a solve are launched (GpuTuning::graphs, persistent_max_blocks,
// apgd_register_cache).
struct ApgdLaunch {
  bool graphs = true;
  int64_t persistent_max = 0;
  bool register_cache = true;
};

template <class V>
struct ApgdBuffers {
  BlockSet bs;
  const real *r, *eta;
  real* X[6];  // X[4..5]: the speculated steps' (null without speculation)
  V* NX[3];
  real a, inv_a;
};

// X[i] and NX[i] by selects: indexing the kernel-parameter arrays with a run-time index would copy them to
// local memory in every thread (measured: +20% on the 1M-sphere solve, H200).
template <class V>
__device__ __forceinline__ real* pickX(const ApgdBuffers<V>& B, int i) {
  return i == 0 ? B.X[0] : i == 1 ? B.X[1] : i == 2 ? B.X[2] : i == 3 ? B.X[3] : i == 4 ? B.X[4] : B.X[5];
}
template <class V>
__device__ __forceinline__ V* pickNX(const ApgdBuffers<V>& B, int i) {
  return i == 0 ? B.NX[0] : i == 1 ? B.NX[1] : B.NX[2];
}

// The Schur slots in the device state, the output's of the storage type V (by offset: the host passes their
// device addresses to the Schur passes without dereferencing st).
__host__ __device__ inline real** schurXSlot(ApgdDeviceState* st) {
  return reinterpret_cast<real**>(reinterpret_cast<char*>(st) + offsetof(ApgdDeviceState, schur_x));
}
template <class V>
__host__ __device__ V** schurYSlot(ApgdDeviceState* st) {
  char* base = reinterpret_cast<char*>(st);
  if constexpr (std::is_same_v<V, float>) return reinterpret_cast<V**>(base + offsetof(ApgdDeviceState, schur_yf));
  else return reinterpret_cast<V**>(base + offsetof(ApgdDeviceState, schur_y));
}

// The trial's speculation (algo::speculationOf, on the device's buffers).
template <class V>
__device__ __forceinline__ kern::ApgdSpeculation apgdSpeculationOf(const ApgdBuffers<V>& B,
                                                                   const algo::ApgdControl& c) {
  return kern::ApgdSpeculation{c.sa >= 0 ? pickX(B, c.sa) : nullptr, c.sr >= 0 ? pickX(B, c.sr) : nullptr, c.spec_ta,
                               c.spec_ba, c.spec_tr};
}

// The trial's step and test functors for the control's current buffers (both launch paths).
template <class V>
__device__ __forceinline__ kern::ApgdStepT<V> apgdStepOf(const ApgdBuffers<V>& B, const algo::ApgdControl& c) {
  constexpr bool grad_form = !std::is_same_v<V, real>;  // float Schur buffers hold N x + r
  return kern::ApgdStepT<V>{B.bs,  pickX(B, c.cur), pickX(B, c.old), pickNX(B, c.ncur), pickNX(B, c.nold), B.r,
                            B.eta, c.beta,          real(1) / c.L,   pickX(B, c.nw),    grad_form};
}
template <class V>
__device__ __forceinline__ kern::ApgdTestT<V> apgdTestOf(const ApgdBuffers<V>& B, const algo::ApgdControl& c) {
  constexpr bool grad_form = !std::is_same_v<V, real>;
  return kern::ApgdTestT<V>{B.bs,           pickX(B, c.cur),  pickX(B, c.old), pickNX(B, c.ncur), pickNX(B, c.nold),
                            pickX(B, c.nw), pickNX(B, c.nnw), B.r,            B.eta,             c.beta,
                            B.a,            B.inv_a,          grad_form,       apgdSpeculationOf(B, c)};
}

template <class V>
__global__ void __launch_bounds__(kBlock) apgdStepKernel(int64_t n, ApgdBuffers<V> B, const ApgdDeviceState* st) {
  const int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= n) return;
  const algo::ApgdControl& c = st->c;
  if (c.done || c.ready) return;  // ready: the last trial's test pass wrote this step (speculation)
  apgdStepOf(B, c)(k);
}

// The test reduction, and in its last block to finish (a counter in st; the partials are then summed in
// block order, so the result does not depend on which block is last) the control update.
template <class V>
__global__ void __launch_bounds__(kBlock) apgdTestKernel(int64_t n, ApgdBuffers<V> B, ApgdDeviceState* st,
                                                         double* partial) {
  const algo::ApgdControl& c = st->c;
  if (c.done) return;  // uniform: st->c changes only after every block has counted itself below
  reduceBlockSlice<5>(n, apgdTestOf(B, c), partial);
  __shared__ bool last;
  __threadfence();  // this block's partials are visible before it counts itself
  if (threadIdx.x == 0) last = atomicAdd(&st->blocks_done, 1u) == gridDim.x - 1;
  __syncthreads();
  if (!last) return;
  __threadfence();
  __shared__ double sums[5];
  reducePartials<5>(int(gridDim.x), partial, sums);
  if (threadIdx.x != 0) return;
  algo::ApgdControl next = st->c;
  next.afterTest(sums);
  st->c = next;
  *schurXSlot(st) = next.done ? nullptr : pickX(B, next.nw);
  *schurYSlot<V>(st) = next.done ? nullptr : pickNX(B, next.nnw);
  st->blocks_done = 0;
}

template <class V>
void launchApgdTrial(DeviceState& d, int64_t n, const ApgdBuffers<V>& B, ApgdDeviceState* st, int slices) {
  SolverScratch& S = d.solver;
  apgdStepKernel<V><<<blocksFor(n), kBlock, 0, d.stream>>>(n, B, st);
  cudaCheck(cudaGetLastError(), "launch of apgdStepKernel", __FILE__, __LINE__);
  schur<V>(d, nullptr, nullptr, schurXSlot(st), schurYSlot<V>(st), std::is_same_v<V, real> ? nullptr : B.r);
  apgdTestKernel<V><<<slices, kBlock, 0, d.stream>>>(n, B, st, S.partial.data());
  cudaCheck(cudaGetLastError(), "launch of apgdTestKernel", __FILE__, __LINE__);
}

// ---- All APGD trials of a solve in one cooperative kernel ----
// A small problem's trial is bound by its launches: at 10,000 spheres (14,000 contacts) the four kernels of a
// trial took ~25 us on an H100, each waiting for the last and loading the control before its first useful
// load. The persistent kernel runs the same per-element functions over a grid that stays resident, with a
// grid-wide barrier between the passes:
//   (1) the projected step into X[nw];  (2) the gather, heavy bodies by chunks;  (3) Schur pass (b) and the test
//   terms fused per block (the thread that writes a block's N x sums its test terms); the last block to finish
//   sums the partials in slice order into the control state; after the barrier every block reads the five sums
//   and runs ApgdControl::afterTest itself, so all blocks hold the same control.
// With speculation (SolverSettings::apgd_speculation) pass (3) also writes the next trial's step for the accepted
// outcome; when it comes true (ApgdControl::ready) the next trial starts at (2): two barriers a trial.
// Large problems are bound by their bytes (~650 B per contact a trial); there it saves less, but it was still
// faster at every size measured (10k to 1M spheres, H100 and H200: docs/GPU_PERFORMANCE.md), so it is the
// default; GpuTuning::persistent_max_blocks can send problems above a size trial by trial.
// The slices and sums are those of the trial-by-trial launches (reduceSlice, reducePartials), so both paths
// give bitwise the same iterates ([gpu] test "GPU APGD on the device").
template <class V, class JT>
struct PersistentApgd {
  ApgdBuffers<V> B;
  GatherT<JT> g;  // x set per trial
  const ConstraintRow* rows;
  int64_t nc, ncb, n;  // contacts, contact blocks, blocks (contact blocks, then row blocks)
  int64_t nbodies;
  bool normal_only;
  int slices;  // of the test reduction (apgdSlices), as launchApgdTrial's grid
  double* partial;
  const int32_t* heavy;
  int32_t n_heavy;
  real* heavy_partial;
  uint32_t* heavy_ticket;
  ApgdDeviceState* st;
  long long* stamps;  // null, or kPhaseStampTrials x kPhaseStamps clock64() stamps of block 0 (DVISIM_APGD_PHASES)
};

constexpr int kPhaseStampTrials = 64;
constexpr int kPhaseStamps = 6;  // step | wait | gather | wait | Schur (b) + test (+ the last block's sums) | wait

// Schur pass (b) of block i, the same functors as schur(): contact i (or the normal rows 3i..3i+2), or row
// block i - ncb. keep: when set, also the block's 3 values written.
template <class V, class JT>
__device__ __forceinline__ void schurBlock(const PersistentApgd<V, JT>& p, int64_t i, const SchurOut<V>& out,
                                           V* keep = nullptr) {
  if (i < p.ncb) {
    if (p.normal_only) {
      const NormalContactF<V, JT> f{p.g.jac, p.g.delta, p.nc, out};
      for (int j = 0; j < 3; ++j) f(3 * i + j, keep ? keep + j : nullptr);
    } else {
      ContactF<V, JT>{p.g.jac, p.g.delta, out}(i, keep);
    }
  } else {
    const RowSchurF<V> f{p.rows, p.g.delta, out, 3 * p.ncb};
    for (int j = 0; j < 3; ++j) f(3 * (i - p.ncb) + j, keep ? keep + j : nullptr);
  }
}

template <class V, class JT>
struct SchurTestF {  // pass (3): block i's N x, then its test terms (which read that N x back, same thread)
  const PersistentApgd<V, JT>& p;
  SchurOut<V> out;
  kern::ApgdTestT<V> test;
  __device__ void operator()(int64_t i, double* acc) const {
    schurBlock(p, i, out);
    test(i, acc);
  }
};

// Blocks of 256 resident per SM (the cooperative grid must fit at once): at most 80 registers a thread (64 for
// 4 blocks spilled the float kernel's loops, and the 100k pile's solve was 20% slower on an H100).
constexpr int kPersistentBlocksPerSm = 3;
// The register-cached form (K = kCachedBlocks): a thread keeps its K blocks' g_k, g_{k-1}, N g_k, N g_{k-1} and
// the trial's g_{k+1} and N g_{k+1} in registers from trial to trial (27 registers a block), so the step reads
// no iterate and the test none but r and eta (of ~650 B a contact a trial, ~200 B). It needs the problem to fit
// K blocks a thread: 2 blocks of 256 per SM (128 registers), K = 2: 135,000 blocks on an H100 or H200.
constexpr int kCachedBlocks = 2;
constexpr int kCachedBlocksPerSm = 2;

template <int K>
constexpr int persistentBlocksPerSm() {
  return K > 0 ? kCachedBlocksPerSm : kPersistentBlocksPerSm;
}

__device__ __forceinline__ void phaseStamp(long long* stamps, int trial, int j) {
  if (stamps && blockIdx.x == 0 && threadIdx.x == 0 && trial < kPhaseStampTrials)
    stamps[kPhaseStamps * trial + j] = clock64();
}

// One kernel for both forms. K = 0: every pass reads its inputs from the buffers. K > 0: thread tid owns the
// blocks tid + j * stride (j < K) in the step and in the fused pass (3), whose test slice is then the thread's
// block (the host launches it only when slices == grid, or when every block is in slice blockIdx.x's first
// stride), so the sums are those of reduceSlice, bitwise. The buffers are written as in K = 0 (the gather and
// the caller read them); the registers hold copies of the same values.
template <class V, class JT, int K>
__global__ void __launch_bounds__(kBlock, persistentBlocksPerSm<K>())
    apgdPersistentKernel(const __grid_constant__ PersistentApgd<V, JT> p) {
  namespace cg = cooperative_groups;
  cg::grid_group grid = cg::this_grid();
  __shared__ alignas(algo::ApgdControl) unsigned char c_mem[sizeof(algo::ApgdControl)];
  __shared__ double sums[5];
  __shared__ bool last;
  algo::ApgdControl& c = *reinterpret_cast<algo::ApgdControl*>(c_mem);
  if (threadIdx.x == 0) c = p.st->c;
  __syncthreads();
  constexpr bool grad_form = !std::is_same_v<V, real>;  // float Schur buffers hold N x + r
  const int64_t tid = int64_t(blockIdx.x) * kBlock + threadIdx.x, stride = int64_t(gridDim.x) * kBlock;
  constexpr int KC = K > 0 ? K : 1;
  real cur[KC][3], old[KC][3], nxt[KC][3];  // g_k, g_{k-1}, g_{k+1} of the thread's blocks (K > 0)
  V ncur[KC][3], nold[KC][3], nnxt[KC][3];  // their Schur buffers
  if constexpr (K > 0) {
    const real *xc = pickX(p.B, c.cur), *xo = pickX(p.B, c.old);
    const V *nc = pickNX(p.B, c.ncur), *no = pickNX(p.B, c.nold);
#pragma unroll
    for (int j = 0; j < K; ++j) {
      const int64_t k = tid + j * stride;
      if (k >= p.n) continue;
      for (int m = 0; m < 3; ++m) {
        cur[j][m] = xc[3 * k + m], old[j][m] = xo[3 * k + m];
        ncur[j][m] = nc[3 * k + m], nold[j][m] = no[3 * k + m];
      }
    }
  }
  for (int trial = 0; !c.done; ++trial) {  // c is the same in every block
    real* xn = pickX(p.B, c.nw);
    phaseStamp(p.stamps, trial, 0);
    if (c.ready) {  // the last trial's pass (3) wrote this step, the same thread the same blocks (speculation)
      if constexpr (K > 0) {
#pragma unroll
        for (int j = 0; j < K; ++j) {
          const int64_t k = tid + j * stride;
          if (k >= p.n) continue;
          for (int m = 0; m < 3; ++m) nxt[j][m] = xn[3 * k + m];
        }
      }
      phaseStamp(p.stamps, trial, 1);
      phaseStamp(p.stamps, trial, 2);
    } else {
      if constexpr (K > 0) {  // (1) the projected step
        const real t = real(1) / c.L;
#pragma unroll
        for (int j = 0; j < K; ++j) {
          const int64_t k = tid + j * stride;
          if (k >= p.n) continue;
          kern::apgdStepBlock<V>(p.B.bs, k, cur[j], old[j], ncur[j], nold[j], grad_form ? nullptr : p.B.r + 3 * k,
                                 t * p.B.eta[k], c.beta, nxt[j]);
          for (int m = 0; m < 3; ++m) xn[3 * k + m] = nxt[j][m];
        }
      } else {
        const kern::ApgdStepT<V> f = apgdStepOf(p.B, c);
        for (int64_t k = tid; k < p.n; k += stride) f(k);
      }
      phaseStamp(p.stamps, trial, 1);
      grid.sync();
      phaseStamp(p.stamps, trial, 2);
    }
    {  // (2) Schur pass (a): the gather
      GatherT<JT> g = p.g;
      g.x = xn;
      for (int64_t i = tid; i < p.nbodies; i += stride) g(i);
      for (int32_t w = int32_t(blockIdx.x); w < p.n_heavy * kHeavyChunks; w += int32_t(gridDim.x))
        heavyGatherChunk(p.heavy, g, xn, p.heavy_partial, p.heavy_ticket, w / kHeavyChunks, w % kHeavyChunks);
    }
    phaseStamp(p.stamps, trial, 3);
    grid.sync();
    phaseStamp(p.stamps, trial, 4);
    {  // (3) Schur pass (b) and the test terms
      const SchurOut<V> out{pickNX(p.B, c.nnw), nullptr, grad_form ? p.B.r : nullptr};
      if constexpr (K > 0) {
        double acc[5] = {0, 0, 0, 0, 0};
        const kern::ApgdSpeculation sp = apgdSpeculationOf(p.B, c);
#pragma unroll
        for (int j = 0; j < K; ++j) {
          const int64_t k = tid + j * stride;
          if (k >= p.n) continue;
          schurBlock(p, k, out, nnxt[j]);
          kern::apgdTestBlock<V>(p.B.bs, k, cur[j], old[j], ncur[j], nold[j], nxt[j], nnxt[j], p.B.r + 3 * k,
                                 p.B.eta[k], c.beta, p.B.a, p.B.inv_a, grad_form, acc, sp);
        }
        if (int(blockIdx.x) < p.slices) blockSumFixed<5>(acc, p.partial + int64_t(blockIdx.x) * 5);
      } else {
        const SchurTestF<V, JT> f{p, out, apgdTestOf(p.B, c)};
        for (int s = int(blockIdx.x); s < p.slices; s += int(gridDim.x)) reduceSlice<5>(s, p.slices, p.n, f, p.partial);
      }
    }
    // The last block to finish sums the partials. (Every block summing them itself contended for the same L2
    // lines: 9 us a trial at 100,000 contacts on an H100.)
    if (threadIdx.x == 0) {  // thread 0 wrote this block's partials (blockSumFixed)
      // release: they are visible before the block counts itself; acquire: the last block sees every block's
      // (its other threads after the barrier below, reading through L2). One acq_rel atomic in place of two
      // fences.
      cuda::atomic_ref<unsigned, cuda::thread_scope_device> done(p.st->blocks_done);
      last = done.fetch_add(1u, cuda::memory_order_acq_rel) == gridDim.x - 1;
    }
    __syncthreads();
    if (last) {
      reducePartials<5>(p.slices, p.partial, sums);
      if (threadIdx.x == 0) {
        for (int m = 0; m < 5; ++m) p.st->sums[m] = sums[m];
        p.st->blocks_done = 0;
      }
    }
    phaseStamp(p.stamps, trial, 5);
    grid.sync();
    if (threadIdx.x == 0) {
      for (int m = 0; m < 5; ++m) sums[m] = __ldcg(p.st->sums + m);
      c.afterTest(sums);
    }
    __syncthreads();
    if constexpr (K > 0) {
      if (c.accepted) {  // the rotation of afterTest: g_{k-1} <- g_k <- g_{k+1}, and their Schur buffers
#pragma unroll
        for (int j = 0; j < K; ++j)
          for (int m = 0; m < 3; ++m) {
            old[j][m] = cur[j][m], cur[j][m] = nxt[j][m];
            nold[j][m] = ncur[j][m], ncur[j][m] = nnxt[j][m];
          }
      }
    }
  }
  if (blockIdx.x == 0 && threadIdx.x == 0) p.st->c = c;
}

template <class V>
using JacobianOf = std::conditional_t<std::is_same_v<V, real>, ContactJacobian, ContactJacobianF>;

// Blocks of the persistent APGD kernel's grid (K: its register-cached form) that fit on the device at once
// (0: no cooperative launch).
template <class V, int K>
int persistentGridMax(DeviceState& d) {
  if (!d.cooperative) return 0;
  int per_sm = 0;
  DVI_CUDA(cudaOccupancyMaxActiveBlocksPerMultiprocessor(
      &per_sm, reinterpret_cast<const void*>(&apgdPersistentKernel<V, JacobianOf<V>, K>), kBlock, 0));
  return per_sm * d.multiprocessors;
}

// Slices of the APGD test reduction, the same on every path (bitwise the same sums): at most one per block of
// the persistent grid (497 slices over its 396 blocks made some blocks sum two at 100,000 contacts, and the
// pass took twice as long for all to wait on). A problem that fits the register-cached kernel takes that
// kernel's smaller grid, whether or not the cache is enabled.
struct ApgdGrids {
  int plain = 0;   // persistentGridMax<V, 0>
  int cached = 0;  // persistentGridMax<V, kCachedBlocks>
  bool fitsCache(int64_t n) const { return cached > 0 && n <= int64_t(kCachedBlocks) * kBlock * cached; }
  int slices(int64_t n) const {
    const int r = reduceBlocksFor(n);
    const int g = fitsCache(n) ? cached : plain;
    return g > 0 ? std::min(r, g) : r;
  }
};

// Runs the trials in apgdPersistentKernel over a grid of at most grid_max blocks; false when the device cannot
// run it (grid_max 0), and the caller then launches trial by trial. The control is in S.apgd on entry and on
// return.
template <class V, int K>
bool apgdPersistent(DeviceState& d, int64_t n, const ApgdBuffers<V>& B, int grid_max, int slices) {
  if (grid_max < 1) return false;
  using JT = JacobianOf<V>;
  SolverScratch& S = d.solver;
  const JT* jac = nullptr;
  if constexpr (std::is_same_v<JT, ContactJacobian>) jac = S.jac.data();
  else jac = S.jacf.data();
  PersistentApgd<V, JT> p{};
  p.B = B;
  p.g = gatherOf<JT>(d, jac, nullptr, nullptr);
  p.rows = S.rows.data();
  p.nc = int64_t(d.contacts.count);
  p.ncb = d.contact_blocks;
  p.n = n;
  p.nbodies = int64_t(d.bodies.count);
  p.normal_only = d.normal_only;
  p.slices = slices;
  p.partial = S.partial.data();
  p.heavy = S.heavy.data();
  p.n_heavy = int32_t(S.n_heavy);
  p.heavy_partial = S.heavy_partial.data();
  p.heavy_ticket = S.heavy_ticket.data();
  p.st = S.apgd.data();
  p.stamps = nullptr;
  if (d.phase_profile) {
    S.stamps.resize(size_t(kPhaseStampTrials) * kPhaseStamps);
    S.stamps.fillZero(d.stream);
    p.stamps = S.stamps.data();
  }
  const void* kernel = reinterpret_cast<const void*>(&apgdPersistentKernel<V, JT, K>);
  const int64_t want = std::max<int64_t>({blocksFor(n), blocksFor(p.nbodies), int64_t(p.n_heavy) * kHeavyChunks, 1});
  const unsigned grid = unsigned(std::min<int64_t>(want, grid_max));
  if (K > 0 && (n > int64_t(K) * kBlock * grid || (slices != int(grid) && n > int64_t(slices) * kBlock)))
    throw std::logic_error("apgdPersistent: " + std::to_string(n) + " blocks do not fit the register-cached kernel's " +
                           std::to_string(grid) + " x " + std::to_string(kBlock) + " threads and " +
                           std::to_string(slices) + " slices");
  void* args[] = {&p};
  DVI_CUDA(cudaLaunchCooperativeKernel(kernel, dim3(grid), dim3(kBlock), args, 0, d.stream));
  if (d.phase_profile) {  // DVISIM_APGD_PHASES: block 0's clock at each phase boundary of the first trials
    std::vector<long long> h(size_t(kPhaseStampTrials) * kPhaseStamps);
    DVI_CUDA(cudaMemcpyAsync(h.data(), S.stamps.data(), sizeof(long long) * h.size(), cudaMemcpyDeviceToHost,
                             d.stream));
    DVI_CUDA(cudaStreamSynchronize(d.stream));
    for (int t = 0; t + 1 < kPhaseStampTrials && h[size_t(kPhaseStamps * (t + 1))] != 0; ++t) {
      const long long* a = h.data() + kPhaseStamps * t;
      for (int j = 0; j < kPhaseStamps; ++j) d.phase_cycles[j] += double(a[j + 1] - a[j]);
      ++d.phase_trials;
    }
  }
  return true;
}

// The float loop's start: out = float(N x + r) from the real N x.
struct GradientToFloatF {
  const real *nx, *r;
  float* out;
  __device__ void operator()(int64_t i) const { out[i] = float(nx[i] + r[i]); }
};

// Runs the APGD trials of one solve until the control is done: batches of trials, one read-back each. With
// graphs, one trial is captured once per solve and the batch is that graph launched again and again.
// V = float (VectorStorage::Float, the GPU's default): the 3 Schur buffers are float and hold the gradient
// N x + r (NX[0] converted in); the iterates stay real.
template <class V>
void apgdTrialsOnDevice(DeviceState& d, int64_t n, algo::ApgdControl& c, real* const* X, V* const* NX, real a,
                        real inv_a, const SolverSettings& s, const BlockSet& bs, const real* r, const real* eta,
                        const ApgdLaunch& launch) {
  SolverScratch& S = d.solver;
  S.apgd.resize(1);
  const ApgdGrids grids{persistentGridMax<V, 0>(d), persistentGridMax<V, kCachedBlocks>(d)};
  const int slices = grids.slices(n);  // from the device and n alone: every path sums alike
  S.partial.resize(size_t(slices) * 5);
  const ApgdBuffers<V> B{bs, r, eta, {X[0], X[1], X[2], X[3], X[4], X[5]}, {NX[0], NX[1], NX[2]}, a, inv_a};
  // Staged in pinned memory: the copy does not wait for the stream (a pageable one would), and the host writes
  // the staging again only after a read-back of this solve's control.
  ApgdDeviceState& h = *d.host_apgd;
  h = ApgdDeviceState{};
  h.c = c;
  *schurXSlot(&h) = X[c.nw];
  *schurYSlot<V>(&h) = NX[c.nnw];
  DVI_CUDA(cudaMemcpyAsync(S.apgd.data(), &h, sizeof h, cudaMemcpyHostToDevice, d.stream));
  const bool cached = launch.register_cache && grids.fitsCache(n);
  if (n <= launch.persistent_max &&
      (cached ? apgdPersistent<V, kCachedBlocks>(d, n, B, grids.cached, slices)
              : apgdPersistent<V, 0>(d, n, B, grids.plain, slices))) {
    DVI_CUDA(cudaMemcpyAsync(&h, S.apgd.data(), sizeof h, cudaMemcpyDeviceToHost, d.stream));
    DVI_CUDA(cudaStreamSynchronize(d.stream));
    c = h.c;
    return;
  }
  cudaGraphExec_t exec = nullptr;
  if (launch.graphs) {
    cudaGraph_t graph = nullptr;
    DVI_CUDA(cudaStreamBeginCapture(d.stream, cudaStreamCaptureModeThreadLocal));
    try {
      launchApgdTrial<V>(d, n, B, S.apgd.data(), slices);
    } catch (...) {
      cudaStreamEndCapture(d.stream, &graph);
      if (graph) cudaGraphDestroy(graph);
      throw;
    }
    DVI_CUDA(cudaStreamEndCapture(d.stream, &graph));
    const cudaError_t e = cudaGraphInstantiate(&exec, graph, 0);
    cudaGraphDestroy(graph);
    DVI_CUDA(e);
  }
  try {
    for (;;) {
      const int remaining = c.max_iterations - c.iterations;
      const int batch = s.tolerance > 0 ? std::min(remaining, 16) : remaining;
      for (int b = 0; b < std::max(1, batch); ++b) {
        if (exec) DVI_CUDA(cudaGraphLaunch(exec, d.stream));
        else launchApgdTrial<V>(d, n, B, S.apgd.data(), slices);
      }
      DVI_CUDA(cudaMemcpyAsync(&h, S.apgd.data(), sizeof h, cudaMemcpyDeviceToHost, d.stream));
      DVI_CUDA(cudaStreamSynchronize(d.stream));
      c = h.c;
      if (c.done) break;
    }
  } catch (...) {
    if (exec) cudaGraphExecDestroy(exec);
    throw;
  }
  if (exec) DVI_CUDA(cudaGraphExecDestroy(exec));
}

void apgdIterateOnDevice(DeviceState& d, int64_t n, algo::ApgdControl& c, real* const* X, real* const* NX, real a,
                         real inv_a, const SolverSettings& s, const BlockSet& bs, const real* r, const real* eta,
                         const ApgdLaunch& launch, bool float_storage) {
  if constexpr (!std::is_same_v<real, float>) {
    if (float_storage) {
      SolverScratch& S = d.solver;
      const int64_t len = 3 * n;
      S.vf.resize(size_t(3 * len));
      float* NXf[3];
      for (int i = 0; i < 3; ++i) NXf[i] = S.vf.data() + i * len;
      launchMap(d, len, GradientToFloatF{NX[c.ncur], r, NXf[c.ncur]}, "launch of GradientToFloatF (APGD start)");
      apgdTrialsOnDevice<float>(d, n, c, X, NXf, a, inv_a, s, bs, r, eta, launch);
      if (c.failed) algo::checkFinite(c.failed_value, "apgd", c.iterations);
      return;
    }
  }
  (void)float_storage;
  apgdTrialsOnDevice<real>(d, n, c, X, NX, a, inv_a, s, bs, r, eta, launch);
  if (c.failed) algo::checkFinite(c.failed_value, "apgd", c.iterations);
}

// Name of a functor type, for the error message of a failed launch.
template <class F>
const char* functorName() {
  return __PRETTY_FUNCTION__;
}

// The CUDA execution backend of the solver templates (chrono_like/solver/solver_algorithms.h): the CPU's
// algorithms and kern:: functors, run as kernels over the device vectors. Reductions are deterministic
// (fixed grid, partials summed in order) and read back to the host, where the scalar logic runs.
class GpuOps {
 public:
  static constexpr bool kDeviceLoop = true;
  GpuOps(DeviceState& d, const ProblemView& p, const ApgdLaunch& launch, bool float_storage)
      : d_(d), p_(p), launch_(launch), float_(float_storage) {
    SolverScratch& S = d.solver;
    DeviceBuffer<real>* bufs[kVecs] = {&S.v0, &S.v1, &S.v2, &S.v3, &S.v4, &S.v5, &S.v6, &S.v7, &S.v8};
    for (int i = 0; i < kVecs; ++i) bufs_[i] = bufs[i];
    for (int i = 0; i < 7; ++i) vec(i);  // 7 and 8 (APGD's speculation) only when asked for
  }
  int64_t blocks() const { return p_.nb; }
  BlockSet blockSet() const { return BlockSet{p_.nc, p_.mu, p_.lo, p_.hi}; }
  const real* rhs() const { return p_.r; }
  const real* blockSteps() const { return p_.eta; }
  const real* jacobiSteps() const { return p_.jeta; }
  const real* blockInverses() const { return p_.binv; }
  real maxDiagonal() const { return p_.max_diag; }
  real* vec(int i) {
    if (i < 0 || i >= kVecs) throw std::logic_error("GpuOps: solver vector " + std::to_string(i) + " does not exist");
    bufs_[i]->resize(size_t(3 * p_.nb));
    return bufs_[i]->data();
  }
  void schur(const real* x, real* y) { gpu::schur(d_, x, y); }
  template <class F>
  void map(const F& f) {
    launchMap(d_, p_.nb, f, functorName<F>());
  }
  template <int M, class F>
  void reduce(const F& f, double* out) {
    const double* h = launchReduce<M>(d_, p_.nb, f, functorName<F>());
    for (int m = 0; m < M; ++m) out[m] = h[m];
  }
  // The sums land in slots of 8 doubles of S.scalars, read back together by fetch().
  template <int M, class F>
  void reduceLater(const F& f, double* out) {
    static_assert(M <= kSlotSize, "GpuOps::reduceLater: at most 8 sums a reduction");
    if (pending_ == kSlots) fetch();
    launchReduce<M>(d_, p_.nb, f, functorName<F>(), false, pending_ * kSlotSize);
    pending_out_[pending_] = out;
    pending_m_[pending_] = M;
    ++pending_;
  }
  void fetch() {
    if (pending_ == 0) return;
    const double* h = d_.readScalars(d_.solver.scalars.data(), pending_ * kSlotSize);
    for (int i = 0; i < pending_; ++i)
      for (int m = 0; m < pending_m_[i]; ++m) pending_out_[i][m] = h[i * kSlotSize + m];
    pending_ = 0;
  }
  void copy(const real* src, real* dst) {
    if (src == dst) return;
    DVI_CUDA(cudaMemcpyAsync(dst, src, sizeof(real) * size_t(3 * p_.nb), cudaMemcpyDeviceToDevice, d_.stream));
  }
  // SolverSettings::record_history: the GPU step reports the iterations and the final residual only
  // (solveCcp), so the device loop keeps no per-iteration residuals (st is left as it is).
  void apgdIterate(algo::ApgdControl& c, real* const* X, real* const* NX, real a, real inv_a, const SolverSettings& s,
                   SolverStats& /*st*/) {
    apgdIterateOnDevice(d_, p_.nb, c, X, NX, a, inv_a, s, blockSet(), rhs(), blockSteps(), launch_, float_);
  }

 private:
  DeviceState& d_;
  ProblemView p_;
  ApgdLaunch launch_;
  bool float_;
  static constexpr int kVecs = 9;
  DeviceBuffer<real>* bufs_[kVecs] = {};
  static constexpr int kSlots = 8, kSlotSize = 8;  // 64 doubles: DeviceState::host_scalars
  int pending_ = 0;
  double* pending_out_[kSlots] = {};
  int pending_m_[kSlots] = {};
};

ProblemView view(DeviceState& d, real max_diag) {
  ProblemView p;
  p.nc = d.normal_only ? 0 : int64_t(d.contacts.count);  // cone blocks; normal-only blocks are boxes
  p.nb = d.contact_blocks + int64_t(d.solver.rows.size() / 3);
  p.lo = d.solver.row_lo.data();
  p.hi = d.solver.row_hi.data();
  p.r = d.solver.rhs.data();
  p.mu = d.contacts.mu.data();
  p.eta = d.solver.block_step.data();
  p.jeta = d.solver.jacobi_step.data();
  p.binv = d.solver.block_inv.data();
  p.max_diag = max_diag;
  return p;
}

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

struct WarmF {
  const uint64_t* key;
  const uint64_t* prev_key;
  const real* prev_gamma;
  int64_t np;
  real* gamma;
  __device__ void operator()(int64_t k) const {
    const uint64_t x = key[k];
    int64_t lo = 0, hi = np;
    while (lo < hi) {
      const int64_t mid = (lo + hi) / 2;
      if (prev_key[mid] < x) lo = mid + 1;
      else hi = mid;
    }
    const bool hit = lo < np && prev_key[lo] == x;
    for (int r = 0; r < 3; ++r) gamma[3 * k + r] = hit ? prev_gamma[3 * lo + r] : real(0);
  }
};

struct GatherByIndexF {
  const int32_t* idx;
  const real* gamma;
  real* out;
  __device__ void operator()(int64_t i) const {
    for (int r = 0; r < 3; ++r) out[3 * i + r] = gamma[3 * int64_t(idx[i]) + r];
  }
};

struct IotaF {
  int32_t* x;
  __device__ void operator()(int64_t i) const { x[i] = int32_t(i); }
};

struct VelocityF {
  const Vec3 *v_free, *w_free;
  const BodyDelta* delta;  // null: no contacts
  Vec3 *vel, *omega;
  __device__ void operator()(int64_t i) const {
    Vec3 v = v_free[i], w = w_free[i];
    if (delta) {
      v += delta[i].v;
      w += delta[i].w;
    }
    vel[i] = v;
    omega[i] = w;
  }
};

}  // namespace

void buildRows(DeviceState& d, const SystemConfig& cfg, const std::vector<ConstraintRow>& rows,
               real* max_penetration) {
  const int64_t nc = int64_t(d.contacts.count);
  const int64_t nb = int64_t(d.bodies.count);
  SolverScratch& S = d.solver;
  S.n_heavy = 0;  // set again once this step's adjacency exists
  DeviceBodies& B = d.bodies;
  DeviceContacts& C = d.contacts;
  d.entry_gather = cfg.gpu.entry_gather;
  if (d.entry_gather) S.inv_iso.resize(nb);
  launchMap(d, nb,
            BodyInverseF{B.inv_mass.data(), B.inv_inertia.data(), B.rot.data(), B.flags.data(), B.inv.data(),
                         d.entry_gather ? S.inv_iso.data() : nullptr},
            "launch of BodyInverseF");
  // Combined friction first: friction rows only where mu > 0 (docs/MODEL.md §6). When no contact of the step has
  // mu > 0 the CCP has the normal rows only (jacobian.h), as on the CPU (System::buildAndSolve).
  C.mu.resize(nc);
  C.size.resize(nc);
  S.v6.resize(nc);  // per-contact penetration
  launchMap(d, nc, MuF{C.body_a.data(), C.body_b.data(), C.shape_a.data(), C.shape_b.data(), C.dist.data(),
                       B.friction.data(), d.shapes.shape.data(), cfg.collision.friction_combine, C.mu.data(), C.size.data(),
                       S.v6.data()},
            "launch of MuF");
  real max_mu = 0;
  if (nc > 0 && cfg.prune && d.all_frictional) {
    max_mu = 1;  // every contact's mu is positive (GpuSystem::uploadIfNeeded): no reduction, no read-back
  } else if (nc > 0 && cfg.prune) {
    d.step_scalars.resize(16);
    real* mu_out = reinterpret_cast<real*>(d.step_scalars.data()) + 4;
    cubRun(d, "cub::DeviceReduce::Max (friction)", [&](void* t, size_t& b) {
      return cub::DeviceReduce::Max(t, b, C.mu.data(), mu_out, int(nc), d.stream);
    });
    max_mu = d.readValue(mu_out);
  }
  d.normal_only = cfg.prune && nc > 0 && !(max_mu > 0);
  const bool normal = d.normal_only;
  const int64_t ncb = normal ? (nc + 2) / 3 : nc;
  d.contact_blocks = ncb;
  const int64_t nbox = normal ? 3 * ncb : 0;  // box entries of the normal blocks, before the rows'
  // Constraint rows from the host (RowProvider plug-ins), padded to blocks of three (row_kernels.h).
  const int64_t nrb = (int64_t(rows.size()) + 2) / 3;
  const int64_t nblk = ncb + nrb;
  d.row_count = rows.size();
  {
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
        if (c < -1 || c >= nb)
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
  S.jac.resize(nc);
  // VectorStorage::Float with APGD: the Jacobians rounded to float, and a float copy for the trials
  const bool float_jac = cfg.solver.type == SolverType::APGD && floatStorage(cfg.solver, true) &&
                         !std::is_same_v<real, float>;
  if (float_jac) S.jacf.resize(nc);
  S.rhs.resize(3 * nblk);
  S.block_inv.resize(6 * nblk);
  S.block_step.resize(nblk);
  S.jacobi_step.resize(nblk);
  S.colnorm.resize(6 * nblk);
  S.rowsum.resize(3 * nblk);
  S.bodyq.resize(nb);
  const int64_t nent = 2 * nc + 6 * nrb;  // adjacency entries: 2 per contact, 2 per row
  S.adj_key.resize(nent);
  S.adj_val.resize(nent);
  S.adj_key_sorted.resize(nent);
  S.adj_val_sorted.resize(nent);
  S.adj_off.resize(nb + 1);
  S.v5.resize(nblk);  // per-block max diagonal entry
  S.v4.resize(nc);  // key order flags
  RowsF f{C.body_a.data(), C.body_b.data(), C.normal.data(), C.pa.data(), C.pb.data(), B.pos.data(),
          B.v_free.data(), B.w_free.data(), C.dist.data(), C.size.data(), B.inv.data(), real(cfg.step.dt), cfg.solver.recovery_rel,
          int32_t(nb), normal, S.rhs.data(), S.block_inv.data(), S.block_step.data(), S.v5.data(), S.colnorm.data(),
          S.rowsum.data(), S.jac.data(), S.adj_key.data(), S.adj_val.data(), float_jac ? S.jacf.data() : nullptr};
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
  // body -> contact CSR: a stable radix sort by body keeps each body's entries in increasing k
  const int bits = bitsFor(uint64_t(nb));
  cubRun(d, "cub::DeviceRadixSort::SortPairs (adjacency)", [&](void* t, size_t& b) {
    return cub::DeviceRadixSort::SortPairs(t, b, S.adj_key.data(), S.adj_key_sorted.data(), S.adj_val.data(),
                                           S.adj_val_sorted.data(), int(nent), 0, bits, d.stream);
  });
  launchMap(d, nb + 1, AdjOffsetF{S.adj_key_sorted.data(), nent, S.adj_off.data()}, "launch of AdjOffsetF");
  if (float_jac && d.entry_gather) {  // the float trials' gather reads each entry's side of the Jacobian in order
    S.entry_jac.resize(nent);
    launchMap(d, nent, EntryJacobianOrderF{S.adj_val_sorted.data(), S.jacf.data(), 2 * nc, S.entry_jac.data()},
              "launch of EntryJacobianOrderF");
  }
  S.heavy.resize(nb);
  S.heavy_count.resize(1);
  DVI_CUDA(cudaMemsetAsync(S.heavy_count.data(), 0, sizeof(int32_t), d.stream));
  launchMap(d, nb, HeavyListF{S.adj_off.data(), S.heavy.data(), S.heavy_count.data()}, "launch of HeavyListF");
  // (the heavy count is read back with the maxima below)
  // Jacobi steps (CcpProblem::jacobiSteps): per-body column sums, then the per-block bounds. Only Jacobi
  // reads them: for the other solvers they are left out (the per-body sum runs in one thread per body, and
  // the CES drum's 15,000 entries made it 3.6 ms of every step's BuildRows on an H200).
  if (cfg.solver.type == SolverType::Jacobi) {
    launchMap(d, nb, BodyColumnSumF{S.adj_off.data(), S.adj_val_sorted.data(), S.colnorm.data(), layoutOf(d), S.bodyq.data()},
              "launch of BodyColumnSumF");
    if (normal)
      launchMap(d, ncb, NormalJacobiStepF{S.jac.data(), S.colnorm.data(), S.rowsum.data(), S.bodyq.data(), nc, S.jacobi_step.data()},
                "launch of NormalJacobiStepF");
    else
      launchMap(d, nc, JacobiStepF{S.jac.data(), S.colnorm.data(), S.rowsum.data(), S.bodyq.data(), S.jacobi_step.data()},
                "launch of JacobiStepF");
    launchMap(d, nrb, RowJacobiStepF{S.rows.data(), S.colnorm.data(), S.rowsum.data(), S.bodyq.data(), ncb, S.jacobi_step.data()},
              "launch of RowJacobiStepF");
  }
  // max diag(N), max penetration, key order: three maxima, one read-back
  d.step_scalars.resize(16);
  real* out = reinterpret_cast<real*>(d.step_scalars.data());
  cubRun(d, "cub::DeviceReduce::Max (diagonal)", [&](void* t, size_t& b) {
    return cub::DeviceReduce::Max(t, b, S.v5.data(), out, int(nblk), d.stream);
  });
  cubRun(d, "cub::DeviceReduce::Max (penetration)", [&](void* t, size_t& b) {
    return cub::DeviceReduce::Max(t, b, S.v6.data(), out + 1, int(nc), d.stream);
  });
  cubRun(d, "cub::DeviceReduce::Max (key order)", [&](void* t, size_t& b) {
    return cub::DeviceReduce::Max(t, b, S.v4.data(), out + 2, int(nc), d.stream);
  });
  // with the heavy bodies' count, into the pinned scalars: one synchronisation
  static_assert(3 * sizeof(real) + sizeof(int32_t) <= 64 * sizeof(double), "host_scalars holds the read-back");
  char* hs = reinterpret_cast<char*>(d.host_scalars);
  DVI_CUDA(cudaMemcpyAsync(hs, out, 3 * sizeof(real), cudaMemcpyDeviceToHost, d.stream));
  DVI_CUDA(cudaMemcpyAsync(hs + 3 * sizeof(real), S.heavy_count.data(), sizeof(int32_t), cudaMemcpyDeviceToHost,
                           d.stream));
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

void warmStart(DeviceState& d, bool enabled, const std::vector<real>& row_lambda) {
  const int64_t nc = int64_t(d.contacts.count);
  SolverScratch& S = d.solver;
  const int64_t nrows = int64_t(d.row_count);
  S.gamma.resize(3 * nc + S.rows.size());
  S.gamma.fillZero(d.stream);
  if (nrows > 0 && int64_t(row_lambda.size()) == nrows)  // rows: by index, while their count is unchanged
    DVI_CUDA(cudaMemcpyAsync(S.gamma.data() + 3 * nc, row_lambda.data(), sizeof(real) * size_t(nrows),
                             cudaMemcpyHostToDevice, d.stream));
  if (!enabled || nc == 0 || d.prev_count == 0) {
    DVI_CUDA(cudaStreamSynchronize(d.stream));  // row_lambda may change after we return
    return;
  }
  launchMap(d, nc, WarmF{d.contacts.key.data(), S.prev_key.data(), S.prev_gamma.data(), int64_t(d.prev_count), S.gamma.data()},
            "launch of WarmF");
}

real* solution(DeviceState& d) { return d.normal_only ? d.solver.x.data() : d.solver.gamma.data(); }

SolverStats solveCcp(DeviceState& d, const SystemConfig& cfg) {
  const ProblemView pv = view(d, d.max_diag);
  GpuOps ops(d, pv, ApgdLaunch{cfg.gpu.graphs, cfg.gpu.persistent_max_blocks, cfg.gpu.apgd_register_cache},
             floatStorage(cfg.solver, true));
  SolverScratch& S = d.solver;
  const int64_t nc = int64_t(d.contacts.count);
  if (d.normal_only) {  // gamma (3 per contact, then the rows) -> x (normal layout), as ContactProblem::toSolverLayout
    S.x.resize(size_t(3 * pv.nb));
    launchMap(d, 3 * pv.nb, kern::ToNormalLayout{S.gamma.data(), S.x.data(), nc, d.contact_blocks}, "launch of ToNormalLayout");
  }
  real* gamma = solution(d);
  SolverStats st;
  switch (cfg.solver.type) {
    case SolverType::Jacobi: st = algo::jacobi(ops, gamma, cfg.solver); break;
    case SolverType::BB: st = algo::bb(ops, gamma, cfg.solver); break;
    case SolverType::GaussSeidel:  // refused by GpuSystem's constructor
    case SolverType::APGD:
    default: st = algo::apgd(ops, gamma, cfg.solver); break;
  }
  if (d.normal_only)
    launchMap(d, int64_t(S.gamma.size()), kern::FromNormalLayout{S.x.data(), S.gamma.data(), nc, d.contact_blocks},
              "launch of FromNormalLayout");
  return st;
}

void keepImpulsesForWarmStart(DeviceState& d) {
  const int64_t nc = int64_t(d.contacts.count);
  SolverScratch& S = d.solver;
  S.prev_key.resize(nc);
  S.prev_gamma.resize(3 * nc);
  d.prev_count = size_t(nc);
  if (nc == 0) return;
  if (!d.keys_unsorted) {  // the narrow phase emits contacts in key order: a copy
    DVI_CUDA(cudaMemcpyAsync(S.prev_key.data(), d.contacts.key.data(), sizeof(uint64_t) * nc, cudaMemcpyDeviceToDevice,
                             d.stream));
    DVI_CUDA(cudaMemcpyAsync(S.prev_gamma.data(), S.gamma.data(), sizeof(real) * 3 * nc, cudaMemcpyDeviceToDevice,
                             d.stream));
    return;
  }
  S.order.resize(nc);
  S.order_sorted.resize(nc);
  launchMap(d, nc, IotaF{S.order.data()}, "launch of IotaF");
  cubRun(d, "cub::DeviceRadixSort::SortPairs (contact keys)", [&](void* t, size_t& b) {
    return cub::DeviceRadixSort::SortPairs(t, b, d.contacts.key.data(), S.prev_key.data(), S.order.data(),
                                           S.order_sorted.data(), int(nc), 0, 64, d.stream);
  });
  launchMap(d, nc, GatherByIndexF{S.order_sorted.data(), S.gamma.data(), S.prev_gamma.data()}, "launch of GatherByIndexF");
}

void applyImpulsesToBodies(DeviceState& d, const real* gamma) {
  DeviceBodies& B = d.bodies;
  const int64_t nb = int64_t(B.count);
  if (gamma) {
    gather(d, gamma, "launch of GatherF (impulses)");
  }
  launchMap(d, nb, VelocityF{B.v_free.data(), B.w_free.data(), gamma ? B.delta.data() : nullptr, B.vel.data(), B.omega.data()},
            "launch of VelocityF");
}

}  // namespace dvi::gpu
