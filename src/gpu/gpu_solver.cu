// BuildRows, WarmStart, Solve and the impulse application on the device. The per-contact and per-body
// work is jacobian.h / cone.h (the functions ContactProblem and solver.cpp call on the CPU); the solvers
// below are the CPU's solveJacobi / solveApgd / solveBB step for step (same fused passes, same scalar
// logic on the host), with the vectors on the device. Reductions are deterministic: a fixed grid sums
// fixed slices, then one block sums the partials in order.
#include <cuda_runtime.h>

#include <algorithm>
#include <cmath>
#include <cub/cub.cuh>

#include "chrono_like/cone.h"
#include "chrono_like/jacobian.h"
#include "chrono_like/solver.h"
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

template <int M, class F>
__global__ void __launch_bounds__(kBlock) reduceKernel(int64_t n, F f, double* partial) {
  double acc[M];
  for (int m = 0; m < M; ++m) acc[m] = 0;
  for (int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < n; i += int64_t(gridDim.x) * blockDim.x)
    f(i, acc);
  using BR = cub::BlockReduce<double, kBlock>;
  __shared__ typename BR::TempStorage tmp;
  for (int m = 0; m < M; ++m) {
    const double s = BR(tmp).Sum(acc[m]);
    if (threadIdx.x == 0) partial[blockIdx.x * M + m] = s;
    __syncthreads();
  }
}

template <int M>
__global__ void __launch_bounds__(kBlock) finalizeKernel(int nblk, const double* partial, double* out) {
  double acc[M];
  for (int m = 0; m < M; ++m) acc[m] = 0;
  for (int b = threadIdx.x; b < nblk; b += blockDim.x)
    for (int m = 0; m < M; ++m) acc[m] += partial[b * M + m];
  using BR = cub::BlockReduce<double, kBlock>;
  __shared__ typename BR::TempStorage tmp;
  for (int m = 0; m < M; ++m) {
    const double s = BR(tmp).Sum(acc[m]);
    if (threadIdx.x == 0) out[m] = s;
    __syncthreads();
  }
}

template <class F>
void launchMap(DeviceState& d, int64_t n, const F& f, const char* what) {
  if (n <= 0) return;
  mapKernel<<<blocksFor(n), kBlock, 0, d.stream>>>(n, f);
  cudaCheck(cudaGetLastError(), what, __FILE__, __LINE__);
}

// Sums M values over n elements; returns a pointer to M doubles on the host (valid until the next read)
// or, with read = false, leaves them on the device only.
template <int M, class F>
const double* launchReduce(DeviceState& d, int64_t n, const F& f, const char* what, bool read = true) {
  SolverScratch& S = d.solver;
  const int nblk = int(std::max<int64_t>(1, std::min<int64_t>(kReduceBlocks, (n + kBlock - 1) / kBlock)));
  S.partial.resize(size_t(nblk) * M);
  S.scalars.resize(8);
  reduceKernel<M><<<nblk, kBlock, 0, d.stream>>>(n, f, S.partial.data());
  cudaCheck(cudaGetLastError(), what, __FILE__, __LINE__);
  finalizeKernel<M><<<1, kBlock, 0, d.stream>>>(nblk, S.partial.data(), S.scalars.data());
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
  __device__ void operator()(int64_t i) const {
    const bool fixed = flags[i] & (kBodyFixed | kBodyKinematic);
    out[i] = fixed ? BodyInverseMass{0, {0, 0, 0, 0, 0, 0}} : makeBodyInverseMass(inv_mass[i], inv_inertia[i], rot[i]);
  }
};

struct RowsF {
  const int32_t *body_a, *body_b, *shape_a, *shape_b;
  const Vec3 *normal, *pa, *pb, *pos, *v_free, *w_free;
  const real *dist, *friction;
  const Shape* shapes;
  const BodyInverseMass* inv;
  FrictionCombine rule;
  real h, recovery_rel;
  int32_t nbodies;
  real *mu, *size, *rhs, *binv, *eta, *diag_max, *pen;
  ContactJacobian* jac;
  uint32_t* adj_key;
  int32_t* adj_val;
  __device__ void operator()(int64_t k) const {
    const int32_t a = body_a[k], b = body_b[k];
    const real fa = friction[a], fb = friction[b];
    const real m = rule == FrictionCombine::Product ? fa * fb
                   : rule == FrictionCombine::Min   ? fmin(fa, fb)
                                                    : real(0.5) * (fa + fb);
    const real sz = fmin(shapes[shape_a[k]].size, shapes[shape_b[k]].size);
    mu[k] = m;
    size[k] = sz;
    const ContactJacobian J = makeContactJacobian(normal[k], pa[k], pb[k], pos[a], pos[b], a, b);
    jac[k] = J;
    real* rk = rhs + 3 * k;
    contactRelativeVelocity(J, v_free[a], w_free[a], v_free[b], w_free[b], rk);
    rk[0] += contactBias(dist[k], h, recovery_rel, sz);
    real N[6];
    const BodyInverseMass A = inv[a], B = inv[b];
    contactDiagonalBlock(J, A, B, N);
    invertSymmetric3(N, binv + 6 * k);
    eta[k] = blockStepFromDiagonal(N);
    diag_max[k] = fmax(N[0], fmax(N[1], N[2]));
    pen[k] = -dist[k];
    // adjacency entries 2k + side, keyed by body (inactive bodies sort last)
    adj_key[2 * k] = movable(A) ? uint32_t(a) : uint32_t(nbodies);
    adj_key[2 * k + 1] = movable(B) ? uint32_t(b) : uint32_t(nbodies);
    adj_val[2 * k] = int32_t(2 * k);
    adj_val[2 * k + 1] = int32_t(2 * k + 1);
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

struct GatherF {
  const int32_t* off;
  const int32_t* adj;
  const ContactJacobian* jac;
  const BodyInverseMass* inv;
  const real* x;
  BodyDelta* delta;
  __device__ void operator()(int64_t i) const {
    Vec3 F{0, 0, 0}, T{0, 0, 0};
    const int32_t e1 = off[i + 1];
    for (int32_t e = off[i]; e < e1; ++e) {
      const int32_t ent = adj[e];
      const int32_t k = ent >> 1;
      accumulateContactImpulse(jac[k], ent & 1, x + 3 * int64_t(k), F, T);
    }
    delta[i] = bodyDeltaFromImpulse(inv[i], F, T);
  }
};

struct ContactF {
  const ContactJacobian* jac;
  const BodyDelta* delta;
  real* y;
  __device__ void operator()(int64_t k) const {
    const ContactJacobian J = jac[k];
    const BodyDelta A = delta[J.a], B = delta[J.b];
    contactRelativeVelocity(J, A.v, A.w, B.v, B.w, y + 3 * k);
  }
};

struct ProblemView {
  int64_t nc = 0;
  const real* r = nullptr;
  const real* mu = nullptr;
  const real* eta = nullptr;
  const real* binv = nullptr;
  real max_diag = 1;
};

void schur(DeviceState& d, const real* x, real* y) {
  SolverScratch& S = d.solver;
  const int64_t nb = int64_t(d.bodies.count), nc = int64_t(d.contacts.count);
  launchMap(d, nb, GatherF{S.adj_off.data(), S.adj_val_sorted.data(), S.jac.data(), d.bodies.inv.data(), x,
                           d.bodies.delta.data()}, "launch of GatherF (Schur pass a)");
  launchMap(d, nc, ContactF{S.jac.data(), d.bodies.delta.data(), y}, "launch of ContactF (Schur pass b)");
}

// ---- vector functors of the solvers ----

struct ProjectF {
  const real* mu;
  real* x;
  __device__ void operator()(int64_t k) const { projectConeBlock(mu[k], x + 3 * k); }
};
struct CopyF {
  const real* src;
  real* dst;
  __device__ void operator()(int64_t i) const { dst[i] = src[i]; }
};
struct CopyProjectF {
  const real* src;
  const real* mu;
  real* dst;
  __device__ void operator()(int64_t k) const {
    for (int j = 0; j < 3; ++j) dst[3 * k + j] = src[3 * k + j];
    projectConeBlock(mu[k], dst + 3 * k);
  }
};
struct FillF {
  real v;
  real* x;
  __device__ void operator()(int64_t i) const { x[i] = v; }
};
struct SumSquaresF {
  const real* x;
  __device__ void operator()(int64_t k, double* acc) const {
    for (int j = 0; j < 3; ++j) acc[0] += double(x[3 * k + j]) * x[3 * k + j];
  }
};
struct ResidualF {
  const real *x, *Nx, *r, *mu;
  real a;
  __device__ void operator()(int64_t k, double* acc) const {
    real grad[3] = {Nx[3 * k] + r[3 * k], Nx[3 * k + 1] + r[3 * k + 1], Nx[3 * k + 2] + r[3 * k + 2]};
    acc[0] += projectedGradientResidual2(mu[k], x + 3 * k, grad, a, real(1) / a);
  }
};

// Jacobi, scalar block step: residual of cur and next = P(cur - w eta grad)
struct JacobiScalarF {
  const real *cur, *Ng, *r, *mu, *eta;
  real a, w;
  bool last;
  real* next;
  __device__ void operator()(int64_t k, double* acc) const {
    const real* g = cur + 3 * k;
    real grad[3] = {Ng[3 * k] + r[3 * k], Ng[3 * k + 1] + r[3 * k + 1], Ng[3 * k + 2] + r[3 * k + 2]};
    acc[0] += projectedGradientResidual2(mu[k], g, grad, a, real(1) / a);
    if (!last) {
      const real t = w * eta[k];
      real* x = next + 3 * k;
      x[0] = g[0] - t * grad[0];
      x[1] = g[1] - t * grad[1];
      x[2] = g[2] - t * grad[2];
      projectConeBlock(mu[k], x);
    }
  }
};
// Jacobi, 3x3 block inverse: residual, then next = P(cur - w N_kk^-1 grad)
struct JacobiInverseF {
  const real *cur, *Ng, *r, *mu, *binv;
  real a, w;
  bool last;
  real* next;
  __device__ void operator()(int64_t k, double* acc) const {
    real grad[3];
    for (int j = 0; j < 3; ++j) grad[j] = Ng[3 * k + j] + r[3 * k + j];
    acc[0] += projectedGradientResidual2(mu[k], cur + 3 * k, grad, a, real(1) / a);
    if (!last) {
      const Vec3 sg = symMul(binv + 6 * k, Vec3{grad[0], grad[1], grad[2]});
      real* x = next + 3 * k;
      x[0] = cur[3 * k] - w * sg.x;
      x[1] = cur[3 * k + 1] - w * sg.y;
      x[2] = cur[3 * k + 2] - w * sg.z;
      projectConeBlock(mu[k], x);
    }
  }
};

// APGD pass (1): g_{k+1} = P(y - t (N y + r)), y and N y formed from (g_k, g_{k-1}).
struct ApgdStepF {
  const real *gc, *go, *Nc, *No, *r, *mu;
  real beta, t;
  real* gn;
  __device__ void operator()(int64_t k) const {
    real* x = gn + 3 * k;
    for (int j = 0; j < 3; ++j) {
      const int64_t i = 3 * k + j;
      const real y = gc[i] + beta * (gc[i] - go[i]);
      const real Ny = Nc[i] + beta * (Nc[i] - No[i]);
      x[j] = y - t * (Ny + r[i]);
    }
    projectConeBlock(mu[k], x);
  }
};
// APGD pass (2): d^T N d, d^T d, residual^2 of g_{k+1}, grad^T (g_{k+1} - g_k)
struct ApgdTestF {
  const real *gc, *go, *Nc, *No, *gn, *Nn, *r, *mu;
  real beta, a;
  __device__ void operator()(int64_t k, double* acc) const {
    real grad_n[3];
    for (int j = 0; j < 3; ++j) {
      const int64_t i = 3 * k + j;
      const real y = gc[i] + beta * (gc[i] - go[i]);
      const real Ny = Nc[i] + beta * (Nc[i] - No[i]);
      const real d = gn[i] - y;
      acc[0] += double(d) * (Nn[i] - Ny);
      acc[1] += double(d) * d;
      acc[3] += double(Ny + r[i]) * (gn[i] - gc[i]);
      grad_n[j] = Nn[i] + r[i];
    }
    acc[2] += projectedGradientResidual2(mu[k], gn + 3 * k, grad_n, a, real(1) / a);
  }
};

// BB
struct BbInitF {  // g += r; f; residual
  real *g;
  const real *x, *r, *mu;
  real a;
  __device__ void operator()(int64_t k, double* acc) const {
    real* gk = g + 3 * k;
    const real* xk = x + 3 * k;
    for (int j = 0; j < 3; ++j) {
      gk[j] += r[3 * k + j];
      acc[1] += 0.5 * double(xk[j]) * (gk[j] + r[3 * k + j]);
    }
    acc[0] += projectedGradientResidual2(mu[k], xk, gk, a, real(1) / a);
  }
};
struct BbDirF {  // d = P(x - alpha g) - x; g^T d, d^T d
  const real *x, *g, *mu;
  real alpha;
  real* d;
  __device__ void operator()(int64_t k, double* acc) const {
    real* dk = d + 3 * k;
    for (int j = 0; j < 3; ++j) dk[j] = x[3 * k + j] - alpha * g[3 * k + j];
    projectConeBlock(mu[k], dk);
    for (int j = 0; j < 3; ++j) {
      dk[j] -= x[3 * k + j];
      acc[0] += double(g[3 * k + j]) * dk[j];
      acc[1] += double(dk[j]) * dk[j];
    }
  }
};
struct DotF {
  const real *x, *y;
  __device__ void operator()(int64_t k, double* acc) const {
    for (int j = 0; j < 3; ++j) acc[0] += double(x[3 * k + j]) * y[3 * k + j];
  }
};
struct BbUpdateF {
  const real *x, *d, *Nd, *r, *mu;
  real lam;
  real *g, *xn;
  real a;
  __device__ void operator()(int64_t k, double* acc) const {
    real* gk = g + 3 * k;
    real* xk = xn + 3 * k;
    for (int j = 0; j < 3; ++j) {
      const int64_t i = 3 * k + j;
      xk[j] = x[i] + lam * d[i];
      gk[j] += lam * Nd[i];
    }
    projectConeBlock(mu[k], xk);
    for (int j = 0; j < 3; ++j) acc[1] += 0.5 * double(xk[j]) * (gk[j] + r[3 * k + j]);
    acc[0] += projectedGradientResidual2(mu[k], xk, gk, a, real(1) / a);
  }
};

int freeBuffer(int count, int a, int b, int c) {
  for (int i = 0; i < count; ++i)
    if (i != a && i != b && i != c) return i;
  return -1;
}

ProblemView view(DeviceState& d, real max_diag) {
  ProblemView p;
  p.nc = int64_t(d.contacts.count);
  p.r = d.solver.rhs.data();
  p.mu = d.contacts.mu.data();
  p.eta = d.solver.block_step.data();
  p.binv = d.solver.block_inv.data();
  p.max_diag = max_diag;
  return p;
}

real alphaFor(const ProblemView& p, const SolverSettings& s) {
  return p.max_diag > real(0) ? s.residual_alpha / p.max_diag : s.residual_alpha;
}

real lipschitzLowerBound(DeviceState& d, const ProblemView& p, real* e, real* Ne) {
  const int64_t n = 3 * p.nc;
  launchMap(d, n, FillF{real(1), e}, "launch of FillF");
  schur(d, e, Ne);
  const double s = launchReduce<1>(d, p.nc, SumSquaresF{Ne}, "launch of SumSquaresF")[0];
  real L = real(std::sqrt(s / double(n)));
  L = std::max(L, p.max_diag);
  if (!(L > real(0)) || !std::isfinite(L)) L = real(1);
  return L;
}

DeviceCcpResult solveJacobiDevice(DeviceState& d, const ProblemView& p, real* gamma, const SolverSettings& s) {
  DeviceCcpResult st;
  const int64_t n = 3 * p.nc, nc = p.nc;
  SolverScratch& S = d.solver;
  S.v0.resize(n);
  S.v1.resize(n);
  real* Ng = S.v0.data();
  real* other = S.v1.data();
  const real a = alphaFor(p, s);
  const bool full = s.block_scaling == BlockScaling::Inverse3x3;
  launchMap(d, nc, ProjectF{p.mu, gamma}, "launch of ProjectF");
  real* cur = gamma;
  real* next = other;
  real res = 0;
  const bool need_every = s.tolerance > 0;
  for (int it = 0;; ++it) {
    schur(d, cur, Ng);
    const bool last = it == s.max_iterations;
    const bool read = last || need_every;
    const double* sum = full ? launchReduce<1>(d, nc, JacobiInverseF{cur, Ng, p.r, p.mu, p.binv, a, s.jacobi_omega, last, next},
                                               "launch of JacobiInverseF", read)
                             : launchReduce<1>(d, nc, JacobiScalarF{cur, Ng, p.r, p.mu, p.eta, a, s.jacobi_omega, last, next},
                                               "launch of JacobiScalarF", read);
    if (read) res = real(std::sqrt(sum[0]));
    if (last || (s.tolerance > 0 && res < s.tolerance)) break;
    std::swap(cur, next);
    ++st.iterations;
  }
  if (cur != gamma) launchMap(d, n, CopyF{cur, gamma}, "launch of CopyF");
  st.residual = res;
  return st;
}

DeviceCcpResult solveApgdDevice(DeviceState& d, const ProblemView& p, real* gamma, const SolverSettings& s) {
  DeviceCcpResult st;
  const int64_t n = 3 * p.nc, nc = p.nc;
  SolverScratch& S = d.solver;
  DeviceBuffer<real>* bufs[7] = {&S.v0, &S.v1, &S.v2, &S.v3, &S.v4, &S.v5, &S.v6};
  for (auto* b : bufs) b->resize(n);
  real* X[4] = {S.v0.data(), S.v1.data(), S.v2.data(), S.v3.data()};
  real* NX[3] = {S.v4.data(), S.v5.data(), S.v6.data()};
  const real a = alphaFor(p, s);

  launchMap(d, nc, CopyProjectF{gamma, p.mu, X[0]}, "launch of CopyProjectF");
  int cur = 0, old = 0, best = 0;
  int ncur = 0, nold = 0;
  schur(d, X[cur], NX[ncur]);
  real best_res = real(std::sqrt(launchReduce<1>(d, nc, ResidualF{X[cur], NX[ncur], p.r, p.mu, a}, "launch of ResidualF")[0]));
  real res = best_res;

  if (!(s.tolerance > 0 && res < s.tolerance) && s.max_iterations > 0) {
    real L = lipschitzLowerBound(d, p, X[1], NX[1]);
    real theta = 1, beta = 0;
    for (int it = 0; it < s.max_iterations; ++it) {
      const int nw = freeBuffer(4, cur, old, best);
      const int nnw = freeBuffer(3, ncur, nold, -1);
      double sums[4];
      for (int bt = 0;; ++bt) {
        const real t = real(1) / L;
        launchMap(d, nc, ApgdStepF{X[cur], X[old], NX[ncur], NX[nold], p.r, p.mu, beta, t, X[nw]}, "launch of ApgdStepF");
        schur(d, X[nw], NX[nnw]);
        const double* h = launchReduce<4>(
            d, nc, ApgdTestF{X[cur], X[old], NX[ncur], NX[nold], X[nw], NX[nnw], p.r, p.mu, beta, a}, "launch of ApgdTestF");
        for (int m = 0; m < 4; ++m) sums[m] = h[m];
        if (!(sums[0] > double(L) * sums[1]) || bt >= 60 || !std::isfinite(sums[0])) break;
        L *= 2;
      }
      ++st.iterations;
      res = real(std::sqrt(sums[2]));
      old = cur;
      cur = nw;
      nold = ncur;
      ncur = nnw;
      if (res < best_res) {
        best_res = res;
        best = cur;
      }
      if (s.tolerance > 0 && res < s.tolerance) break;
      const real theta_new = (-theta * theta + theta * std::sqrt(theta * theta + 4)) / 2;
      beta = theta * (1 - theta) / (theta * theta + theta_new);
      theta = theta_new;
      if (sums[3] > 0) {
        beta = 0;
        theta = 1;
      }
      L *= real(0.9);
    }
  }
  launchMap(d, n, CopyF{X[best], gamma}, "launch of CopyF");
  st.residual = best_res;
  return st;
}

DeviceCcpResult solveBBDevice(DeviceState& d, const ProblemView& p, real* gamma, const SolverSettings& s) {
  DeviceCcpResult st;
  const int64_t n = 3 * p.nc, nc = p.nc;
  SolverScratch& S = d.solver;
  DeviceBuffer<real>* bufs[6] = {&S.v0, &S.v1, &S.v2, &S.v3, &S.v4, &S.v5};
  for (auto* b : bufs) b->resize(n);
  real* X[3] = {S.v0.data(), S.v1.data(), S.v2.data()};
  real* g = S.v3.data();
  real* dvec = S.v4.data();
  real* Nd = S.v5.data();
  constexpr int kMemory = 10;
  constexpr double kSigma = 1e-4;
  const real a = alphaFor(p, s);

  launchMap(d, nc, CopyProjectF{gamma, p.mu, X[0]}, "launch of CopyProjectF");
  int cur = 0, best = 0;
  schur(d, X[cur], g);
  const double* h = launchReduce<2>(d, nc, BbInitF{g, X[cur], p.r, p.mu, a}, "launch of BbInitF");
  real res = real(std::sqrt(h[0]));
  real best_res = res;
  double f = h[1];
  double fhist[kMemory];
  for (double& v : fhist) v = f;

  if (!(s.tolerance > 0 && res < s.tolerance) && s.max_iterations > 0) {
    const real L0 = lipschitzLowerBound(d, p, dvec, Nd);
    const real amin = real(1e-10) / L0, amax = real(1e10) / L0;
    real alpha = real(1) / L0;
    for (int it = 0; it < s.max_iterations; ++it) {
      const real* x = X[cur];
      h = launchReduce<2>(d, nc, BbDirF{x, g, p.mu, alpha, dvec}, "launch of BbDirF");
      const double gd = h[0], dd = h[1];
      if (!(dd > 0)) break;
      schur(d, dvec, Nd);
      const double q = launchReduce<1>(d, nc, DotF{dvec, Nd}, "launch of DotF")[0];
      double fmax = fhist[0];
      for (double v : fhist) fmax = std::max(fmax, v);
      double lambda = 1;
      for (int ls = 0; ls < 60; ++ls) {
        const double fn = f + lambda * gd + 0.5 * lambda * lambda * q;
        if (fn <= fmax + kSigma * lambda * gd) break;
        const double denom = 2 * (fn - f - lambda * gd);
        double lt = denom > 0 ? -gd * lambda * lambda / denom : 0.5 * lambda;
        if (!(lt >= 0.1 * lambda && lt <= 0.9 * lambda)) lt = 0.5 * lambda;
        lambda = lt;
      }
      const int nw = freeBuffer(3, cur, best, -1);
      h = launchReduce<2>(d, nc, BbUpdateF{x, dvec, Nd, p.r, p.mu, real(lambda), g, X[nw], a}, "launch of BbUpdateF");
      f = h[1];
      fhist[(it + 1) % kMemory] = f;
      cur = nw;
      ++st.iterations;
      res = real(std::sqrt(h[0]));
      if (res < best_res) {
        best_res = res;
        best = cur;
      }
      if (s.tolerance > 0 && res < s.tolerance) break;
      alpha = q > 0 ? real(dd / q) : amax;
      alpha = std::min(amax, std::max(amin, alpha));
    }
  }
  launchMap(d, n, CopyF{X[best], gamma}, "launch of CopyF");
  st.residual = best_res;
  return st;
}

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

void buildRows(DeviceState& d, const SystemConfig& cfg, real* max_penetration) {
  const int64_t nc = int64_t(d.contacts.count);
  const int64_t nb = int64_t(d.bodies.count);
  SolverScratch& S = d.solver;
  DeviceBodies& B = d.bodies;
  DeviceContacts& C = d.contacts;
  launchMap(d, nb, BodyInverseF{B.inv_mass.data(), B.inv_inertia.data(), B.rot.data(), B.flags.data(), B.inv.data()},
            "launch of BodyInverseF");
  S.jac.resize(nc);
  S.rhs.resize(3 * nc);
  S.block_inv.resize(6 * nc);
  S.block_step.resize(nc);
  S.adj_key.resize(2 * nc);
  S.adj_val.resize(2 * nc);
  S.adj_key_sorted.resize(2 * nc);
  S.adj_val_sorted.resize(2 * nc);
  S.adj_off.resize(nb + 1);
  S.v5.resize(nc);  // per-contact max diagonal entry
  S.v6.resize(nc);  // per-contact penetration
  S.v4.resize(nc);  // key order flags
  RowsF f{C.body_a.data(), C.body_b.data(), C.shape_a.data(), C.shape_b.data(), C.normal.data(), C.pa.data(),
          C.pb.data(),     B.pos.data(),    B.v_free.data(),  B.w_free.data(),  C.dist.data(),   B.friction.data(),
          d.shapes.shape.data(), B.inv.data(), cfg.friction_combine, cfg.dt, cfg.recovery_rel, int32_t(nb),
          C.mu.data(), C.size.data(), S.rhs.data(), S.block_inv.data(), S.block_step.data(), S.v5.data(), S.v6.data(),
          S.jac.data(), S.adj_key.data(), S.adj_val.data()};
  launchMap(d, nc, f, "launch of RowsF");
  launchMap(d, nc, KeyOrderF{C.key.data(), S.v4.data(), nc}, "launch of KeyOrderF");
  // body -> contact CSR: a stable radix sort by body keeps each body's entries in increasing k
  const int bits = bitsFor(uint64_t(nb));
  cubRun(d, "cub::DeviceRadixSort::SortPairs (adjacency)", [&](void* t, size_t& b) {
    return cub::DeviceRadixSort::SortPairs(t, b, S.adj_key.data(), S.adj_key_sorted.data(), S.adj_val.data(),
                                           S.adj_val_sorted.data(), int(2 * nc), 0, bits, d.stream);
  });
  launchMap(d, nb + 1, AdjOffsetF{S.adj_key_sorted.data(), 2 * nc, S.adj_off.data()}, "launch of AdjOffsetF");
  // max diag(N), max penetration, key order: three maxima, one read-back
  d.step_scalars.resize(16);
  real* out = reinterpret_cast<real*>(d.step_scalars.data());
  cubRun(d, "cub::DeviceReduce::Max (diagonal)", [&](void* t, size_t& b) {
    return cub::DeviceReduce::Max(t, b, S.v5.data(), out, int(nc), d.stream);
  });
  cubRun(d, "cub::DeviceReduce::Max (penetration)", [&](void* t, size_t& b) {
    return cub::DeviceReduce::Max(t, b, S.v6.data(), out + 1, int(nc), d.stream);
  });
  cubRun(d, "cub::DeviceReduce::Max (key order)", [&](void* t, size_t& b) {
    return cub::DeviceReduce::Max(t, b, S.v4.data(), out + 2, int(nc), d.stream);
  });
  real host[3];
  DVI_CUDA(cudaMemcpyAsync(host, out, 3 * sizeof(real), cudaMemcpyDeviceToHost, d.stream));
  DVI_CUDA(cudaStreamSynchronize(d.stream));
  d.max_diag = host[0] > real(0) ? host[0] : real(1);
  *max_penetration = std::max(real(0), host[1]);
  d.keys_unsorted = host[2] > real(0);
}

void warmStart(DeviceState& d, bool enabled) {
  const int64_t nc = int64_t(d.contacts.count);
  SolverScratch& S = d.solver;
  S.gamma.resize(3 * nc);
  if (!enabled) {
    S.gamma.fillZero(d.stream);
    return;
  }
  launchMap(d, nc, WarmF{d.contacts.key.data(), S.prev_key.data(), S.prev_gamma.data(), int64_t(d.prev_count), S.gamma.data()},
            "launch of WarmF");
}

DeviceCcpResult solveCcp(DeviceState& d, const SystemConfig& cfg) {
  const ProblemView p = view(d, d.max_diag);
  real* gamma = d.solver.gamma.data();
  switch (cfg.solver) {
    case SolverType::Jacobi: return solveJacobiDevice(d, p, gamma, cfg.solver_settings);
    case SolverType::BB: return solveBBDevice(d, p, gamma, cfg.solver_settings);
    case SolverType::GaussSeidel:  // refused by GpuSystem's constructor
    case SolverType::APGD:
    default: return solveApgdDevice(d, p, gamma, cfg.solver_settings);
  }
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
    SolverScratch& S = d.solver;
    launchMap(d, nb, GatherF{S.adj_off.data(), S.adj_val_sorted.data(), S.jac.data(), B.inv.data(), gamma, B.delta.data()},
              "launch of GatherF (impulses)");
  }
  launchMap(d, nb, VelocityF{B.v_free.data(), B.w_free.data(), gamma ? B.delta.data() : nullptr, B.vel.data(), B.omega.data()},
            "launch of VelocityF");
}

}  // namespace dvi::gpu
