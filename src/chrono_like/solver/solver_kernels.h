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
// Rolling and spinning friction: a contact with either has a rolling block (spinning, rolling u, rolling w: angular
// impulses) among the first row blocks, projected TOGETHER with its contact block onto the cone of cone.h
// (projectRollingCone), because both are bounded by the contact's normal impulse. Every functor below that projects
// handles such a pair in the contact block's call (block k and its partner p = roll[k]) and does nothing in the
// rolling block's own call; the linear passes (copies, dot products) stay block by block.
//
// Preconditioner: S = diag(eta_k I3), one positive scalar per block, so the S-metric projection onto the
// product of cones and boxes is the Euclidean one block by block (a rolling pair: block by block in the metric, then
// the pair's Euclidean projection; with the pair's two steps unequal this is the projection in the metric
// diag(eta_k I3, eta_p I3) only approximately, see docs/MODEL.md).
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
  // Rolling blocks: blocks [nc, nc + nroll), the first row blocks; contact k with roll[k] >= 0 owns block roll[k].
  int64_t nroll = 0;
  const int32_t* roll = nullptr;  // per contact block: its rolling block, or -1 (unused when nroll == 0)
  const real* roll_mu = nullptr;  // 2 per rolling block: mu_s (spinning), mu_r (rolling), metres
};

// A rolling block: projected by its contact block's call (see above).
DVI_HD bool isRollingBlock(const BlockSet& s, int64_t k) { return k >= s.nc && k < s.nc + s.nroll; }
// The rolling block contact block k projects with, or -1.
DVI_HD int64_t rollingPartner(const BlockSet& s, int64_t k) {
  return s.nroll > 0 && k < s.nc ? int64_t(s.roll[k]) : int64_t(-1);
}

DVI_HD real clampRow(real x, real lo, real hi) { return x < lo ? lo : (x > hi ? hi : x); }  // keeps NaN

DVI_HD void projectBlock(const BlockSet& s, int64_t k, real* x) {
  if (k < s.nc) {
    projectConeBlock(s.mu[k], x);
    return;
  }
  const int64_t i = 3 * (k - s.nc);
  for (int j = 0; j < 3; ++j) x[j] = clampRow(x[j], s.lo[i + j], s.hi[i + j]);
}

// Projects block k's values x and, where k leads a rolling pair (p >= 0), its partner's values xp with them.
DVI_HD void projectUnit(const BlockSet& s, int64_t k, int64_t p, real* x, real* xp) {
  if (p < 0) return projectBlock(s, k, x);
  const real* c = s.roll_mu + 2 * (p - s.nc);
  projectRollingCone(s.mu[k], c[0], c[1], x, xp);
}

// |(g - P(g - a grad)) / a|^2 of block k (the projected-gradient residual, solver.h).
DVI_HD real blockResidual2(const BlockSet& s, int64_t k, const real* g, const real* grad, real a, real inv_a) {
  real t[3] = {g[0] - a * grad[0], g[1] - a * grad[1], g[2] - a * grad[2]};
  projectBlock(s, k, t);
  const real e0 = (g[0] - t[0]) * inv_a, e1 = (g[1] - t[1]) * inv_a, e2 = (g[2] - t[2]) * inv_a;
  return e0 * e0 + e1 * e1 + e2 * e2;
}

// blockResidual2 of block k, or of the rolling pair (k, p) when p >= 0 (gp, gradp: the partner's values).
DVI_HD real unitResidual2(const BlockSet& s, int64_t k, int64_t p, const real* g, const real* grad, const real* gp,
                          const real* gradp, real a, real inv_a) {
  if (p < 0) return blockResidual2(s, k, g, grad, a, inv_a);
  real t[3], tp[3];
  for (int j = 0; j < 3; ++j) t[j] = g[j] - a * grad[j], tp[j] = gp[j] - a * gradp[j];
  projectUnit(s, k, p, t, tp);
  real sum = 0;
  for (int j = 0; j < 3; ++j) {
    const real e = (g[j] - t[j]) * inv_a, ep = (gp[j] - tp[j]) * inv_a;
    sum += e * e + ep * ep;
  }
  return sum;
}

namespace kern {

// ---- maps over blocks: operator()(k) ----

struct Project {
  BlockSet s;
  real* x;
  DVI_HD void operator()(int64_t k) const {
    if (isRollingBlock(s, k)) return;
    const int64_t p = rollingPartner(s, k);
    projectUnit(s, k, p, x + 3 * k, p >= 0 ? x + 3 * p : nullptr);
  }
};

struct CopyProject {
  BlockSet s;
  const real* src;
  real* dst;
  DVI_HD void operator()(int64_t k) const {
    if (isRollingBlock(s, k)) return;
    const int64_t p = rollingPartner(s, k);
    for (int j = 0; j < 3; ++j) dst[3 * k + j] = src[3 * k + j];
    if (p >= 0)
      for (int j = 0; j < 3; ++j) dst[3 * p + j] = src[3 * p + j];
    projectUnit(s, k, p, dst + 3 * k, p >= 0 ? dst + 3 * p : nullptr);
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
  // Block b's step before the projection.
  DVI_HD void value(int64_t b, real* x) const {
    for (int j = 0; j < 3; ++j) {
      const int64_t i = 3 * b + j;
      x[j] = apgdStepValue<V>(gc[i], go[i], Nc[i], No[i], grad_form ? nullptr : r + 3 * b, j, t * eta[b], beta);
    }
  }
  DVI_HD void operator()(int64_t k) const {
    if (isRollingBlock(s, k)) return;
    const int64_t p = rollingPartner(s, k);
    if (p < 0) {  // apgdStepBlock, as the GPU's register-cached kernel runs it
      real c[3], o[3], x[3];
      V nc[3], no[3];
      for (int j = 0; j < 3; ++j) {
        c[j] = gc[3 * k + j], o[j] = go[3 * k + j], nc[j] = Nc[3 * k + j], no[j] = No[3 * k + j];
      }
      apgdStepBlock<V>(s, k, c, o, nc, no, grad_form ? nullptr : r + 3 * k, t * eta[k], beta, x);
      for (int j = 0; j < 3; ++j) gn[3 * k + j] = x[j];
      return;
    }
    real x[3], xp[3];
    value(k, x);
    value(p, xp);
    projectUnit(s, k, p, x, xp);
    for (int j = 0; j < 3; ++j) gn[3 * k + j] = x[j], gn[3 * p + j] = xp[j];
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
    if (isRollingBlock(s, k)) return;
    const int64_t p = rollingPartner(s, k);
    const real grad[3] = {Nx[3 * k] + r[3 * k], Nx[3 * k + 1] + r[3 * k + 1], Nx[3 * k + 2] + r[3 * k + 2]};
    if (p < 0) {
      acc[0] += blockResidual2(s, k, x + 3 * k, grad, a, inv_a);
      return;
    }
    const real gradp[3] = {Nx[3 * p] + r[3 * p], Nx[3 * p + 1] + r[3 * p + 1], Nx[3 * p + 2] + r[3 * p + 2]};
    acc[0] += unitResidual2(s, k, p, x + 3 * k, grad, x + 3 * p, gradp, a, inv_a);
  }
};

struct ZeroResidual {  // 1 sum: squared residual of the zero impulse, res(0)^2 (the relative residual's scale)
  BlockSet s;
  const real* r;
  real a, inv_a;
  DVI_HD void operator()(int64_t k, double* acc) const {
    if (isRollingBlock(s, k)) return;
    const int64_t p = rollingPartner(s, k);
    const real zero[3] = {0, 0, 0};
    acc[0] += unitResidual2(s, k, p, zero, r + 3 * k, zero, p >= 0 ? r + 3 * p : nullptr, a, inv_a);
  }
};

// Jacobi's gradients N cur + r of block k and (p >= 0) its rolling partner, into grad[0] and grad[1], and their
// unit's squared residual.
DVI_HD real jacobiUnitResidual2(const BlockSet& s, int64_t k, int64_t p, const real* cur, const real* Ng, const real* r,
                                real a, real inv_a, real (*grad)[3]) {
  const int64_t b[2] = {k, p};
  for (int u = 0; u < (p >= 0 ? 2 : 1); ++u)
    for (int j = 0; j < 3; ++j) grad[u][j] = Ng[3 * b[u] + j] + r[3 * b[u] + j];
  return unitResidual2(s, k, p, cur + 3 * k, grad[0], p >= 0 ? cur + 3 * p : nullptr, grad[1], a, inv_a);
}

// Jacobi: residual of cur; unless last, next = P(cur - w S_k (N cur + r)) with S_k the scalar step t_k (Inverse false:
// scale holds one step per block) or the 3x3 block inverse N_kk^-1 (Inverse true: scale holds 6 per block).
template <bool Inverse>
struct JacobiT {
  BlockSet s;
  const real *cur, *Ng, *r, *scale;
  real a, inv_a, w;
  bool last;
  real* next;
  DVI_HD void operator()(int64_t k, double* acc) const {
    if (isRollingBlock(s, k)) return;
    const int64_t p = rollingPartner(s, k);
    const int64_t b[2] = {k, p};
    real grad[2][3] = {};
    acc[0] += jacobiUnitResidual2(s, k, p, cur, Ng, r, a, inv_a, grad);
    if (last) return;
    for (int u = 0; u < (p >= 0 ? 2 : 1); ++u) {
      const real* gr = grad[u];
      real sg[3];
      if (Inverse) {
        const real* B = scale + 6 * b[u];  // symmetric [00, 11, 22, 01, 02, 12]
        sg[0] = w * (B[0] * gr[0] + B[3] * gr[1] + B[4] * gr[2]);
        sg[1] = w * (B[3] * gr[0] + B[1] * gr[1] + B[5] * gr[2]);
        sg[2] = w * (B[4] * gr[0] + B[5] * gr[1] + B[2] * gr[2]);
      } else {
        const real t = w * scale[b[u]];
        for (int j = 0; j < 3; ++j) sg[j] = t * gr[j];
      }
      for (int j = 0; j < 3; ++j) next[3 * b[u] + j] = cur[3 * b[u] + j] - sg[j];
    }
    projectUnit(s, k, p, next + 3 * k, p >= 0 ? next + 3 * p : nullptr);
  }
};
using JacobiScalar = JacobiT<false>;
using JacobiInverse = JacobiT<true>;

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
// apgdTestSums: the block's part of the sums but the residual, its gradient at g (grad_n) and its speculated steps
// before the projection (xa, xr, where sp asks for them).
template <class V>
DVI_HD void apgdTestSums(const real* c, const real* o, const V* nc, const V* no, const real* g, const V* ng,
                         const real* r3, real eta, real beta, bool grad_form, double* acc, const ApgdSpeculation sp,
                         real* grad_n, real* xa, real* xr) {
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
}

template <class V>
DVI_HD void apgdTestBlock(const BlockSet& s, int64_t k, const real* c, const real* o, const V* nc, const V* no,
                          const real* g, const V* ng, const real* r3, real eta, real beta, real a, real inv_a,
                          bool grad_form, double* acc, const ApgdSpeculation sp = {}) {
  real grad_n[3], xa[3] = {0, 0, 0}, xr[3] = {0, 0, 0};  // written and read only where sp asks (GCC cannot see it)
  apgdTestSums<V>(c, o, nc, no, g, ng, r3, eta, beta, grad_form, acc, sp, grad_n, xa, xr);
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
    if (isRollingBlock(s, k)) return;
    const int64_t p = rollingPartner(s, k);
    if (p >= 0) return pair(k, p, acc);
    real c[3], o[3], g[3];
    V nc[3], no[3], ng[3];
    for (int j = 0; j < 3; ++j) {
      const int64_t i = 3 * k + j;
      c[j] = gc[i], o[j] = go[i], nc[j] = Nc[i], no[j] = No[i], g[j] = gn[i], ng[j] = Nn[i];
    }
    apgdTestBlock<V>(s, k, c, o, nc, no, g, ng, r + 3 * k, eta[k], beta, a, inv_a, grad_form, acc, spec);
  }
  // A rolling pair (k, p): the sums block by block, the residual and the speculated steps projected together.
  DVI_HD void pair(int64_t k, int64_t p, double* acc) const {
    const int64_t b[2] = {k, p};
    real c[6], o[6], g[6];
    V nc[6], no[6], ng[6];
    for (int u = 0; u < 2; ++u)
      for (int j = 0; j < 3; ++j) {
        const int64_t i = 3 * b[u] + j;
        const int l = 3 * u + j;
        c[l] = gc[i], o[l] = go[i], nc[l] = Nc[i], no[l] = No[i], g[l] = gn[i], ng[l] = Nn[i];
      }
    real grad[6], xa[6], xr[6];
    for (int u = 0; u < 2; ++u)
      apgdTestSums<V>(c + 3 * u, o + 3 * u, nc + 3 * u, no + 3 * u, g + 3 * u, ng + 3 * u, r + 3 * b[u], eta[b[u]],
                      beta, grad_form, acc, spec, grad + 3 * u, xa + 3 * u, xr + 3 * u);
    acc[2] += unitResidual2(s, k, p, g, grad, g + 3, grad + 3, a, inv_a);
    real* outs[2] = {spec.xa, spec.xr};
    real* vals[2] = {xa, xr};
    for (int q = 0; q < 2; ++q) {
      if (!outs[q]) continue;
      projectUnit(s, k, p, vals[q], vals[q] + 3);
      for (int j = 0; j < 3; ++j) outs[q][3 * k + j] = vals[q][j], outs[q][3 * p + j] = vals[q][3 + j];
    }
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
    if (isRollingBlock(s, k)) return;
    const int64_t p = rollingPartner(s, k);
    const int64_t b[2] = {k, p};
    const int units = p >= 0 ? 2 : 1;
    for (int u = 0; u < units; ++u) {
      const real ae = alpha * eta[b[u]];
      for (int j = 0; j < 3; ++j) d[3 * b[u] + j] = x[3 * b[u] + j] - ae * g[3 * b[u] + j];
    }
    projectUnit(s, k, p, d + 3 * k, p >= 0 ? d + 3 * p : nullptr);
    for (int u = 0; u < units; ++u) {
      real* dk = d + 3 * b[u];
      double dd = 0;
      for (int j = 0; j < 3; ++j) {
        dk[j] -= x[3 * b[u] + j];
        acc[0] += double(g[3 * b[u] + j]) * dk[j];
        dd += double(dk[j]) * dk[j];
      }
      if (eta[b[u]] > 0) acc[1] += dd / eta[b[u]];
    }
  }
};

// BB update, 2 sums: xn = P(x + lambda d), g += lambda N d; residual^2 and f of xn.
struct BbUpdate {
  BlockSet s;
  const real *x, *d, *Nd, *r;
  real lam, a, inv_a;
  real *g, *xn;
  DVI_HD void operator()(int64_t k, double* acc) const {
    if (isRollingBlock(s, k)) return;
    const int64_t p = rollingPartner(s, k);
    const int64_t b[2] = {k, p};
    const int units = p >= 0 ? 2 : 1;
    for (int u = 0; u < units; ++u)
      for (int j = 0; j < 3; ++j) {
        const int64_t i = 3 * b[u] + j;
        xn[i] = x[i] + lam * d[i];
        g[i] += lam * Nd[i];
      }
    // x + lambda d is in the convex set; this only removes rounding
    projectUnit(s, k, p, xn + 3 * k, p >= 0 ? xn + 3 * p : nullptr);
    for (int u = 0; u < units; ++u)
      for (int j = 0; j < 3; ++j) {
        const int64_t i = 3 * b[u] + j;
        acc[1] += 0.5 * double(xn[i]) * (g[i] + r[i]);
      }
    acc[0] += unitResidual2(s, k, p, xn + 3 * k, g + 3 * k, p >= 0 ? xn + 3 * p : nullptr, p >= 0 ? g + 3 * p : nullptr,
                            a, inv_a);
  }
};

}  // namespace kern
}  // namespace dvi
