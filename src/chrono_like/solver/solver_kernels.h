// Per-block operations of the CCP solvers, written once as DVI_HD functors: the OpenMP loops of
// solver.cpp and the CUDA kernels of gpu/solver/ call these very structs through the algorithm
// templates of solver_algorithms.h, so the CPU tests exercise the code the GPU runs.
//
// Vectors are laid out in blocks of 3 reals. Blocks [0, nc) are contacts (normal, tangent u, tangent w)
// projected onto their friction cone (cone.h); blocks [nc, nb) hold generic constraint rows
// (constraint_row.h: joints, drives), three rows per block, each row projected onto its box [lo, hi]
// (Tasora & Anitescu, CMAME 200 (2011): bilateral rows have the whole line as their "cone"; a motor with
// a force limit or a unilateral limit has an interval). Padding rows have lo = hi = 0.
//
// Preconditioner: S = diag(eta_k I3), one positive scalar per block, so the S-metric projection onto the
// product of cones and boxes is the Euclidean one block by block (solver.h).
#pragma once

#include <cmath>
#include <cstdint>

#include "chrono_like/base/hd.h"
#include "chrono_like/base/math.h"
#include "chrono_like/solver/cone.h"

namespace dvi {

// How each block is projected.
struct BlockSet {
  int64_t nc = 0;            // contact blocks (cones); the blocks after them are row boxes
  const real* mu = nullptr;  // friction coefficient per contact block
  const real* lo = nullptr;  // 3 per row block: lower and upper impulse bounds
  const real* hi = nullptr;
};

DVI_HD real clampRow(real x, real lo, real hi) { return x < lo ? lo : (x > hi ? hi : x); }  // keeps NaN

DVI_HD void projectBlock(const BlockSet& s, int64_t k, real* x) {
  if (k < s.nc) {
    projectConeBlock(s.mu[k], x);
    return;
  }
  const int64_t i = 3 * (k - s.nc);
  for (int j = 0; j < 3; ++j) x[j] = clampRow(x[j], s.lo[i + j], s.hi[i + j]);
}

// |(g - P(g - a grad)) / a|^2 of block k (the projected-gradient residual, solver.h).
DVI_HD real blockResidual2(const BlockSet& s, int64_t k, const real* g, const real* grad, real a, real inv_a) {
  real t[3] = {g[0] - a * grad[0], g[1] - a * grad[1], g[2] - a * grad[2]};
  projectBlock(s, k, t);
  const real e0 = (g[0] - t[0]) * inv_a, e1 = (g[1] - t[1]) * inv_a, e2 = (g[2] - t[2]) * inv_a;
  return e0 * e0 + e1 * e1 + e2 * e2;
}

namespace kern {

// ---- maps over blocks: operator()(k) ----

struct Project {
  BlockSet s;
  real* x;
  DVI_HD void operator()(int64_t k) const { projectBlock(s, k, x + 3 * k); }
};

struct CopyProject {
  BlockSet s;
  const real* src;
  real* dst;
  DVI_HD void operator()(int64_t k) const {
    for (int j = 0; j < 3; ++j) dst[3 * k + j] = src[3 * k + j];
    projectBlock(s, k, dst + 3 * k);
  }
};

struct Copy {
  const real* src;
  real* dst;
  DVI_HD void operator()(int64_t k) const {
    for (int j = 0; j < 3; ++j) dst[3 * k + j] = src[3 * k + j];
  }
};

struct Scale2 {  // x *= c, Nx *= c
  real c;
  real *x, *Nx;
  DVI_HD void operator()(int64_t k) const {
    for (int j = 0; j < 3; ++j) {
      x[3 * k + j] *= c;
      Nx[3 * k + j] *= c;
    }
  }
};

struct FillSqrtEta {  // e = S^1/2 1
  const real* eta;
  real* e;
  DVI_HD void operator()(int64_t k) const {
    const real v = sqrt(eta[k]);
    for (int j = 0; j < 3; ++j) e[3 * k + j] = v;
  }
};

// APGD pass (1): g_{k+1} = P(y - t S (N y + r)), y and N y formed from (g_k, g_{k-1}).
// V: the storage type of the Schur buffers (real; float for VectorStorage::Float on the GPU); the iterates g,
// r, eta and all arithmetic are real.
// grad_form: the Schur buffers hold the gradient N x + r, not N x (VectorStorage::Float: rounding then errs by a
// float ulp of the gradient, which vanishes at the solution, not of N x, which does not). The extrapolation
// keeps the form: its weights (1 + beta, -beta) sum to 1.
// Component j of pass (1) before the projection (arguments as in apgdStepBlock below, one component of each).
template <class V>
DVI_HD real apgdStepValue(real c, real o, V nc, V no, const real* r3, int j, real te, real beta) {
  const real n0 = real(nc);
  const real y = c + beta * (c - o);
  const real Ny = n0 + beta * (n0 - real(no));
  return y - te * (r3 ? Ny + r3[j] : Ny);
}

// Block k of pass (1) from its values: c = g_k, o = g_{k-1}, nc = N g_k, no = N g_{k-1} (plus r when the Schur
// buffers hold N x: r3 is block k's r, null in grad_form), te = t eta_k; x = g_{k+1}. The per-block arithmetic of
// ApgdStepT, called as well by the GPU kernel that keeps a thread's blocks in registers between trials.
template <class V>
DVI_HD void apgdStepBlock(const BlockSet& s, int64_t k, const real* c, const real* o, const V* nc, const V* no,
                          const real* r3, real te, real beta, real* x) {
  for (int j = 0; j < 3; ++j) x[j] = apgdStepValue<V>(c[j], o[j], nc[j], no[j], r3, j, te, beta);
  projectBlock(s, k, x);
}

template <class V>
struct ApgdStepT {
  BlockSet s;
  const real *gc, *go;
  const V *Nc, *No;
  const real *r, *eta;
  real beta, t;
  real* gn;
  bool grad_form = false;
  DVI_HD void operator()(int64_t k) const {
    real c[3], o[3], x[3];
    V nc[3], no[3];
    for (int j = 0; j < 3; ++j) {
      c[j] = gc[3 * k + j], o[j] = go[3 * k + j], nc[j] = Nc[3 * k + j], no[j] = No[3 * k + j];
    }
    apgdStepBlock<V>(s, k, c, o, nc, no, grad_form ? nullptr : r + 3 * k, t * eta[k], beta, x);
    for (int j = 0; j < 3; ++j) gn[3 * k + j] = x[j];
  }
};
using ApgdStep = ApgdStepT<real>;

// VectorStorage::Float on the CPU: the values the GPU's float Schur buffers hold, in place: x = float(x + add)
// (add = r turns a Schur product into the stored gradient, see ApgdStepT::grad_form).
struct RoundToFloat {
  real* x;
  const real* add;
  DVI_HD void operator()(int64_t k) const {
    for (int j = 0; j < 3; ++j) {
      const int64_t i = 3 * k + j;
      x[i] = real(float(add ? x[i] + add[i] : x[i]));
    }
  }
};

// ---- layout conversions of a normal-only problem (jacobian.h): maps over single reals ----
// The System keeps 3 impulses per contact (then the rows') for the warm start and its callers; a
// normal-only problem solves for x = (gn of every contact, padded to blocks of 3, then the rows).

struct ToNormalLayout {  // x[i] for i in [0, 3 (ncb + nrb))
  const real* g3;        // 3 per contact, then the rows
  real* x;
  int64_t nc, ncb;
  DVI_HD void operator()(int64_t i) const {
    if (i < 3 * ncb)
      x[i] = i < nc ? g3[3 * i] : real(0);
    else
      x[i] = g3[3 * nc + (i - 3 * ncb)];
  }
};

struct FromNormalLayout {  // g3[i] for i in [0, 3 nc + 3 nrb): tangential impulses are 0
  const real* x;
  real* g3;
  int64_t nc, ncb;
  DVI_HD void operator()(int64_t i) const {
    if (i < 3 * nc)
      g3[i] = i % 3 == 0 ? x[i / 3] : real(0);
    else
      g3[i] = x[3 * ncb + (i - 3 * nc)];
  }
};

// ---- reductions over blocks: operator()(k, acc) adds block k's terms to acc[0..M) ----

struct NonFinite {  // 1 sum: NaN or inf when x holds one
  const real* x;
  DVI_HD void operator()(int64_t k, double* acc) const {
    for (int j = 0; j < 3; ++j) acc[0] += double(x[3 * k + j]) * 0;
  }
};

struct Dot {  // 1 sum: x^T y
  const real *x, *y;
  DVI_HD void operator()(int64_t k, double* acc) const {
    for (int j = 0; j < 3; ++j) acc[0] += double(x[3 * k + j]) * y[3 * k + j];
  }
};

struct ScaledSquares {  // 1 sum: |diag(e) Ne|^2 (Lipschitz estimate)
  const real *e, *Ne;
  DVI_HD void operator()(int64_t k, double* acc) const {
    for (int j = 0; j < 3; ++j) {
      const double v = double(Ne[3 * k + j]) * e[3 * k + j];
      acc[0] += v * v;
    }
  }
};

struct StartSums {  // 3 sums: x^T N x, r^T x, finiteness of r
  const real *x, *Nx, *r;
  DVI_HD void operator()(int64_t k, double* acc) const {
    for (int j = 0; j < 3; ++j) {
      acc[0] += double(x[3 * k + j]) * Nx[3 * k + j];
      acc[1] += double(r[3 * k + j]) * x[3 * k + j];
      acc[2] += double(r[3 * k + j]) * 0;
    }
  }
};

struct Objective {  // 1 sum: f = 1/2 x^T (N x + 2 r)
  const real *x, *Nx, *r;
  DVI_HD void operator()(int64_t k, double* acc) const {
    for (int j = 0; j < 3; ++j) acc[0] += 0.5 * double(x[3 * k + j]) * (Nx[3 * k + j] + 2 * r[3 * k + j]);
  }
};

struct Residual {  // 1 sum: squared residual of x given N x
  BlockSet s;
  const real *x, *Nx, *r;
  real a, inv_a;
  DVI_HD void operator()(int64_t k, double* acc) const {
    const real grad[3] = {Nx[3 * k] + r[3 * k], Nx[3 * k + 1] + r[3 * k + 1], Nx[3 * k + 2] + r[3 * k + 2]};
    acc[0] += blockResidual2(s, k, x + 3 * k, grad, a, inv_a);
  }
};

struct ZeroResidual {  // 1 sum: squared residual of the zero impulse, res(0)^2 (the relative residual's scale)
  BlockSet s;
  const real* r;
  real a, inv_a;
  DVI_HD void operator()(int64_t k, double* acc) const {
    const real zero[3] = {0, 0, 0};
    acc[0] += blockResidual2(s, k, zero, r + 3 * k, a, inv_a);
  }
};

// Jacobi with the scalar step: residual of cur; unless last, next = P(cur - w t_k (N cur + r)).
struct JacobiScalar {
  BlockSet s;
  const real *cur, *Ng, *r, *step;
  real a, inv_a, w;
  bool last;
  real* next;
  DVI_HD void operator()(int64_t k, double* acc) const {
    const real* g = cur + 3 * k;
    const real grad[3] = {Ng[3 * k] + r[3 * k], Ng[3 * k + 1] + r[3 * k + 1], Ng[3 * k + 2] + r[3 * k + 2]};
    acc[0] += blockResidual2(s, k, g, grad, a, inv_a);
    if (!last) {
      const real t = w * step[k];
      real* x = next + 3 * k;
      for (int j = 0; j < 3; ++j) x[j] = g[j] - t * grad[j];
      projectBlock(s, k, x);
    }
  }
};

// Jacobi with the 3x3 block inverse: residual of cur; unless last, next = P(cur - w N_kk^-1 (N cur + r)).
struct JacobiInverse {
  BlockSet s;
  const real *cur, *Ng, *r, *binv;
  real a, inv_a, w;
  bool last;
  real* next;
  DVI_HD void operator()(int64_t k, double* acc) const {
    const real* g = cur + 3 * k;
    const real grad[3] = {Ng[3 * k] + r[3 * k], Ng[3 * k + 1] + r[3 * k + 1], Ng[3 * k + 2] + r[3 * k + 2]};
    acc[0] += blockResidual2(s, k, g, grad, a, inv_a);
    if (!last) {
      const real* B = binv + 6 * k;  // symmetric [00, 11, 22, 01, 02, 12]
      const real sg[3] = {B[0] * grad[0] + B[3] * grad[1] + B[4] * grad[2],
                          B[3] * grad[0] + B[1] * grad[1] + B[5] * grad[2],
                          B[4] * grad[0] + B[5] * grad[1] + B[2] * grad[2]};
      real* x = next + 3 * k;
      for (int j = 0; j < 3; ++j) x[j] = g[j] - w * sg[j];
      projectBlock(s, k, x);
    }
  }
};

// The next trial's step, speculated by the test pass (SolverSettings::apgd_speculation): its outcome is known only
// once every block's sums are in, but either outcome's step is a function of values the test has already loaded:
//   accepted: g_{k+2} = P(y' - t' S grad(y')), y' from (g_{k+1}, g_k), t' = 1 / (0.9 L), the momentum beta'
//             of ApgdControl::momentum (a gradient restart, beta' = 0, makes it void unless beta' was 0 anyway);
//   rejected: the same y, t' = 1 / (2 L).
// Each is apgdStepValue and projectBlock with apgdStepBlock's arguments, so a used speculation is bitwise the step
// the next trial's pass (1) would compute, and that pass (a read of the iterates and, on the GPU, a grid-wide
// barrier) is left out.
struct ApgdSpeculation {
  real *xa = nullptr, *xr = nullptr;  // the accepted and the rejected outcome's g_{k+2} (null: not speculated)
  real ta = 0, ba = 0, tr = 0;        // their step t (and the accepted one's momentum)
};

// APGD pass (2), 5 sums: d^T N d, d^T S^-1 d, residual^2 of g_{k+1}, grad(y)^T (g_{k+1} - g_k), f(g_{k+1}),
// with d = g_{k+1} - y (see solveApgd). grad_form: as in ApgdStepT.
// Block k of pass (2) from its values (see apgdStepBlock; g = g_{k+1}, ng its Schur buffer), added to acc.
// sp: also the speculated steps of the next trial (ApgdSpeculation; by value: a pointer to a functor's member put
// the whole functor in local memory on the GPU), each component from the values the test has loaded, projected and
// written to sp.xa and sp.xr where they are not null.
template <class V>
DVI_HD void apgdTestBlock(const BlockSet& s, int64_t k, const real* c, const real* o, const V* nc, const V* no,
                          const real* g, const V* ng, const real* r3, real eta, real beta, real a, real inv_a,
                          bool grad_form, double* acc, const ApgdSpeculation sp = {}) {
  real grad_n[3], xa[3], xr[3];
  double dd = 0;
  const real* rs = grad_form ? nullptr : r3;  // the step's r (apgdStepBlock)
  DVI_UNROLL
  for (int j = 0; j < 3; ++j) {
    const real n0 = real(nc[j]), Ng = real(ng[j]);
    const real y = c[j] + beta * (c[j] - o[j]);
    const real Ny = n0 + beta * (n0 - real(no[j]));
    const real d = g[j] - y;
    acc[0] += double(d) * (Ng - Ny);
    dd += double(d) * d;
    const real rr = grad_form ? real(0) : r3[j];  // the gradients are Ny + rr, Ng + rr
    acc[3] += double(Ny + rr) * (g[j] - c[j]);
    acc[4] += 0.5 * double(g[j]) * (Ng + rr + r3[j]);
    grad_n[j] = Ng + rr;
    if (sp.xa) xa[j] = apgdStepValue<V>(g[j], c[j], ng[j], nc[j], rs, j, sp.ta * eta, sp.ba);
    if (sp.xr) xr[j] = apgdStepValue<V>(c[j], o[j], nc[j], no[j], rs, j, sp.tr * eta, beta);
  }
  if (eta > 0) acc[1] += dd / eta;  // a block between immovable bodies has no metric weight
  acc[2] += blockResidual2(s, k, g, grad_n, a, inv_a);
  if (sp.xa) {
    projectBlock(s, k, xa);
    for (int j = 0; j < 3; ++j) sp.xa[3 * k + j] = xa[j];
  }
  if (sp.xr) {
    projectBlock(s, k, xr);
    for (int j = 0; j < 3; ++j) sp.xr[3 * k + j] = xr[j];
  }
}

template <class V>
struct ApgdTestT {
  BlockSet s;
  const real *gc, *go;
  const V *Nc, *No;
  const real* gn;
  const V* Nn;
  const real *r, *eta;
  real beta, a, inv_a;
  bool grad_form = false;
  ApgdSpeculation spec = {};
  DVI_HD void operator()(int64_t k, double* acc) const {
    real c[3], o[3], g[3];
    V nc[3], no[3], ng[3];
    for (int j = 0; j < 3; ++j) {
      const int64_t i = 3 * k + j;
      c[j] = gc[i], o[j] = go[i], nc[j] = Nc[i], no[j] = No[i], g[j] = gn[i], ng[j] = Nn[i];
    }
    apgdTestBlock<V>(s, k, c, o, nc, no, g, ng, r + 3 * k, eta[k], beta, a, inv_a, grad_form, acc, spec);
  }
};
using ApgdTest = ApgdTestT<real>;

// BB start, 1 sum: g += r (g held N x), f of x.
struct BbInit {
  const real *x, *r;
  real* g;
  DVI_HD void operator()(int64_t k, double* acc) const {
    for (int j = 0; j < 3; ++j) {
      g[3 * k + j] += r[3 * k + j];
      acc[0] += 0.5 * double(x[3 * k + j]) * (g[3 * k + j] + r[3 * k + j]);
    }
  }
};

// BB direction, 2 sums: d = P(x - alpha S g) - x; g^T d, d^T S^-1 d.
struct BbDirection {
  BlockSet s;
  const real *x, *g, *eta;
  real alpha;
  real* d;
  DVI_HD void operator()(int64_t k, double* acc) const {
    real* dk = d + 3 * k;
    const real ae = alpha * eta[k];
    for (int j = 0; j < 3; ++j) dk[j] = x[3 * k + j] - ae * g[3 * k + j];
    projectBlock(s, k, dk);
    double dd = 0;
    for (int j = 0; j < 3; ++j) {
      dk[j] -= x[3 * k + j];
      acc[0] += double(g[3 * k + j]) * dk[j];
      dd += double(dk[j]) * dk[j];
    }
    if (eta[k] > 0) acc[1] += dd / eta[k];
  }
};

// BB update, 2 sums: xn = P(x + lambda d), g += lambda N d; residual^2 and f of xn.
struct BbUpdate {
  BlockSet s;
  const real *x, *d, *Nd, *r;
  real lam, a, inv_a;
  real *g, *xn;
  DVI_HD void operator()(int64_t k, double* acc) const {
    real* gk = g + 3 * k;
    real* xk = xn + 3 * k;
    for (int j = 0; j < 3; ++j) {
      const int64_t i = 3 * k + j;
      xk[j] = x[i] + lam * d[i];
      gk[j] += lam * Nd[i];
    }
    projectBlock(s, k, xk);  // x + lambda d is in the convex set; this only removes rounding
    for (int j = 0; j < 3; ++j) acc[1] += 0.5 * double(xk[j]) * (gk[j] + r[3 * k + j]);
    acc[0] += blockResidual2(s, k, xk, gk, a, inv_a);
  }
};

}  // namespace kern
}  // namespace dvi
