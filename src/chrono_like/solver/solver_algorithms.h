// The CCP solver algorithms (projected Jacobi, APGD, BB/SPG), written once as templates over an
// execution backend `Ops`. solver.cpp instantiates them with OpenMP loops over host arrays, and
// gpu/solver/gpu_solver.cu (GpuOps) with CUDA kernels over device arrays: the same passes, the same kern:: functors
// (solver_kernels.h), the same scalar logic on the host. See solver.h for the problem, the residual and
// the references.
//
// Ops provides:
//   int64_t blocks() const;                      blocks of 3 reals (contacts, then constraint-row blocks)
//   BlockSet blockSet() const;                   projection data
//   const real *rhs(), *blockSteps(), *jacobiSteps(), *blockInverses() const;
//   real maxDiagonal() const;
//   real* vec(int i);                            scratch vector i (0..8) of 3 blocks() reals, kept between solves
//   void schur(const real* x, real* y);          y = N x
//   template <class F> void map(const F& f);     f(k) for every block k
//   template <int M, class F> void reduce(const F& f, double* out);  out[m] = sum_k of f(k, acc)[m],
//                                                deterministic (fixed summation order for any thread count)
//   template <int M, class F> void reduceLater(const F& f, double* out);  the same sums, written to out by the
//                                                next fetch() at the latest (the GPU reads several at once)
//   void fetch();                                completes every reduceLater since the last fetch
//   void copy(const real* src, real* dst);       3 blocks() reals
//   int64_t totalBlocks() const;                 optional: the blocks of every process sharing the problem
//                                                (process_group.h); blocks() where absent (totalBlocks below)
//   static constexpr bool kDeviceLoop;           true: p.apgdIterate(...) runs the APGD iterations itself
//                                                (same signature as algo::apgdIterate, same ApgdControl), else
//                                                the host loop below runs
#pragma once

#include <algorithm>
#include <cmath>
#include <string>
#include <type_traits>

#include "chrono_like/solver/solver.h"
#include "chrono_like/solver/solver_kernels.h"

namespace dvi {
namespace algo {

inline void checkFinite(double v, const char* who, int it) {
  if (!std::isfinite(v))
    throw SolverError(std::string(who) + ": non-finite value (residual " + std::to_string(v) + ") at iteration " +
                      std::to_string(it));
}

inline int freeBuffer(int count, int a, int b, int c) {
  for (int i = 0; i < count; ++i)
    if (i != a && i != b && i != c) return i;
  return -1;
}

// The blocks of the whole problem: Ops::totalBlocks() where the backend splits it over processes
// (process_group.h), else blocks(). An empty problem and the Lipschitz start read it, so that every process takes
// the same branch.
template <class Ops>
auto totalBlocks(const Ops& p, int) -> decltype(p.totalBlocks()) {
  return p.totalBlocks();
}
template <class Ops>
int64_t totalBlocks(const Ops& p, long) {
  return p.blocks();
}
template <class Ops>
int64_t totalBlocks(const Ops& p) {
  return totalBlocks(p, 0);
}

template <class Ops>
real alphaOf(const Ops& p, const SolverSettings& s) {
  const real d = p.maxDiagonal();
  return d > real(0) ? s.residual_alpha / d : s.residual_alpha;
}

// Throws SolverError if the warm start holds a NaN or inf (the projection could otherwise hide it).
template <class Ops>
void checkWarmStart(Ops& p, const real* g, const char* who) {
  double s;
  p.template reduce<1>(kern::NonFinite{g}, &s);
  if (!(s == 0)) throw SolverError(std::string(who) + ": non-finite warm start");
}

template <class Ops>
real residualGivenNx(Ops& p, const real* x, const real* Nx, real a) {
  double s;
  p.template reduce<1>(kern::Residual{p.blockSet(), x, Nx, p.rhs(), a, real(1) / a}, &s);
  return real(std::sqrt(s));
}

// res(0), the residual of the zero impulse: the scale of the relative residual (solver.h).
template <class Ops>
real residualScale(Ops& p, real a) {
  double s;
  p.template reduce<1>(kern::ZeroResidual{p.blockSet(), p.rhs(), a, real(1) / a}, &s);
  return real(std::sqrt(s));
}

// Lower bound of lambda_max(S^1/2 N S^1/2), S = diag(eta_k I3) the preconditioner, to start the step
// estimates: max(|S^1/2 N S^1/2 e| / |e|, 1/3), e = ones (the APGD paper, Mazhar et al. 2015, takes
// L0 = |N (g0 - g^0)| / |g0 - g^0|). Both are <= lambda_max: eta_k is 1 / (Gershgorin bound of N_kk) and
// that bound is <= 3 max_i (N_kk)_ii, so some diagonal entry eta_k (N_kk)_ii of the scaled matrix is >= 1/3.
// The backtracking only has to grow it. One Schur product (setup, not per iteration).
// lipschitzProduct requests the sum (squares, by the next fetch), lipschitzBound turns it into the bound.
template <class Ops>
void lipschitzProduct(Ops& p, real* e, real* Ne, double* squares) {
  p.map(kern::FillSqrtEta{p.blockSteps(), e});
  p.schur(e, Ne);
  p.template reduceLater<1>(kern::ScaledSquares{e, Ne}, squares);
}
inline real lipschitzBound(double squares, int64_t blocks) {
  real L = real(std::sqrt(squares / double(3 * blocks)));
  L = std::max(L, real(1) / 3);
  if (!std::isfinite(L)) throw SolverError("solver: non-finite N (Lipschitz estimate is " + std::to_string(L) + ")");
  return L;
}
template <class Ops>
real lipschitzLowerBound(Ops& p, real* e, real* Ne) {
  double s;
  lipschitzProduct(p, e, Ne, &s);
  p.fetch();
  return lipschitzBound(s, totalBlocks(p));
}

// The start of every solver: x = P(warm start), then x <- s x with s = argmin_{s >= 0} f(s x), f(x) =
// 1/2 x^T N x + r^T x, i.e. s = max(0, -r^T x / x^T N x) (s = 1 where x^T N x = 0 and r^T x <= 0, 0
// where both vanish or r^T x > 0): f(start) <= min(f(P(warm)), f(0) = 0). Nx = N x on entry is scaled
// with x (no second Schur product). Returns the start's residual; throws SolverError on non-finite input.
// With row blocks (boxes [lo, hi] around 0) s is kept in [0, 1]: a larger s can carry a row past its bound (a
// motor's warm start at its impulse limit scaled to the unbounded optimum), and that infeasible start, whose f
// is below every feasible point's, would then stay the best iterate. f(s x) is convex in s, so the start still
// satisfies f(start) <= min(f(P(warm)), 0).
// The scaling s from the StartSums of x (throws on non-finite sums), applied to x and N x.
template <class Ops>
void scaleStart(Ops& p, real* x, real* Nx, const double* sums, const char* who) {
  if (!std::isfinite(sums[0]) || !std::isfinite(sums[1]) || !std::isfinite(sums[2]))
    throw SolverError(std::string(who) + ": non-finite right-hand side, N x or warm start");
  double sc = 1;
  if (sums[0] > 0)
    sc = std::max(0.0, -sums[1] / sums[0]);
  else if (sums[1] > 0 || sums[0] < 0)
    sc = 0;
  if (p.blocks() > p.blockSet().nc) sc = std::min(sc, 1.0);
  if (sc != 1) p.map(kern::Scale2{real(sc), x, Nx});
}
inline real startResidual(double res2, const char* who) {
  const real res = real(std::sqrt(res2));
  if (!std::isfinite(res)) throw SolverError(std::string(who) + ": non-finite residual at the start");
  return res;
}
template <class Ops>
real scaledStart(Ops& p, real* x, real* Nx, real a, const char* who) {
  double sums[3];
  p.template reduce<3>(kern::StartSums{x, Nx, p.rhs()}, sums);
  scaleStart(p, x, Nx, sums, who);
  double res2;
  p.template reduce<1>(kern::Residual{p.blockSet(), x, Nx, p.rhs(), a, real(1) / a}, &res2);
  return startResidual(res2, who);
}

// ---------------------------------------------------------------------------------------------------
// Projected Jacobi with over-relaxation and block scaling:
//   g <- P(g - w S (N g + r)),  S = diag(t_k I3) (Scalar: t_k = jacobiSteps(), a Gershgorin bound of the
//   whole row of N, coupling included, so rho(S N) <= 1 and w <= 1 decreases f) or N_kk^-1 (Inverse3x3).
// One Schur product per iteration; the residual of the current iterate comes out of the same loop.
template <class Ops>
SolverStats jacobi(Ops& p, real* gamma, const SolverSettings& s) {
  SolverStats st;
  if (totalBlocks(p) == 0) return st;
  const BlockSet bs = p.blockSet();
  const real* r = p.rhs();
  const real a = alphaOf(p, s), inv_a = real(1) / a;
  const real w = s.jacobi_omega;
  const bool full = s.block_scaling == BlockScaling::Inverse3x3;
  real* Ng = p.vec(0);
  real* other = p.vec(1);

  checkWarmStart(p, gamma, "jacobi");
  st.residual_scale = residualScale(p, a);
  const real thr = stopThreshold(s, st.residual_scale);
  p.map(kern::Project{bs, gamma});
  p.schur(gamma, Ng);
  scaledStart(p, gamma, Ng, a, "jacobi");
  real* cur = gamma;
  real* next = other;
  real res = 0;
  for (int it = 0;; ++it) {
    if (it > 0) p.schur(cur, Ng);
    const bool last = it == s.max_iterations;
    double sum;
    if (!full)
      p.template reduce<1>(kern::JacobiScalar{bs, cur, Ng, r, p.jacobiSteps(), a, inv_a, w, last, next}, &sum);
    else
      p.template reduce<1>(kern::JacobiInverse{bs, cur, Ng, r, p.blockInverses(), a, inv_a, w, last, next}, &sum);
    res = real(std::sqrt(sum));
    checkFinite(res, "jacobi", it);
    if (s.record_history) st.history.push_back(res);
    if (last || reachedStop(res, thr, it, s.min_iterations)) break;
    std::swap(cur, next);
    ++st.iterations;
  }
  if (cur != gamma) p.copy(cur, gamma);
  st.residual = res;
  finishStats(st, s);
  return st;
}

// ---------------------------------------------------------------------------------------------------
// APGD: Mazhar, Heyn, Negrut, Tasora, "Using Nesterov's method to accelerate multibody dynamics with
// friction and contact", ACM TOG 34(3), 2015, Algorithm APGD, in the metric of the diagonal
// preconditioner S = diag(eta_k I3) (eta_k = blockSteps()):
//   g_{k+1} = P(y_k - t_k S (N y_k + r));  while f(g_{k+1}) > f(y_k) + grad^T d + L_k/2 |d|_S^2: L_k *= 2, redo
//   theta_{k+1} = (-theta_k^2 + theta_k sqrt(theta_k^2 + 4)) / 2,  beta = theta_k (1 - theta_k) / (theta_k^2 + theta_{k+1})
//   y_{k+1} = g_{k+1} + beta (g_{k+1} - g_k)
//   keep the best g; stop below the tolerance
//   restart: if grad^T (g_{k+1} - g_k) > 0: y_{k+1} = g_{k+1}, theta_{k+1} = 1
//   L_{k+1} = 0.9 L_k, t = 1 / L
// |d|_S^2 = d^T S^-1 d. S is a positive scalar per block, so the S-metric projection onto the product of
// cones is the Euclidean one block by block and this is APGD on the equivalent problem in z = S^-1/2 g,
// whose Hessian S^1/2 N S^1/2 has its diagonal in [1/3, 1]: without S the step 1/L is set by the stiffest
// contact (a mm grain with a long lever arm: diag N ~ 1e7 against ~ 1e3 elsewhere) and the other contacts
// hardly move in 50 iterations.
// Implementation choices:
//  - f is quadratic, so the sufficient-decrease test is exactly d^T N d <= L |d|_S^2, d = g_{k+1} - y_k,
//    evaluated without cancellation as d^T (N g_{k+1} - N y_k).
//  - N y_{k+1} = (1 + beta) N g_{k+1} - beta N g_k, so one Schur product per accepted iteration (plus one
//    per backtrack); y and N y are never stored but formed on the fly from (g_k, g_{k-1}) and their
//    products, which fuses the vector work into two passes per iteration: (1) the projected step,
//    (2) the backtracking test, residual and objective of g_{k+1} and restart test.
//  - L_0 = max(|S^1/2 N S^1/2 1| / |1|, 1/3) (a lower bound of lambda_max; backtracking grows it).
//  - best iterate: the smallest residual among the iterates whose objective is not above the start's
//    (APGD is not monotone), so the result is never worse than the (scaled) warm start. It stays pinned in
//    its buffer (4 iterate buffers rotate), so tracking it copies nothing.
// The scalar side of APGD after each test reduction: backtracking, momentum, gradient restart, best
// iterate, buffer rotation and the stop test. Written once, DVI_HD: apgdIterate below calls it on the host
// after every reduction; the GPU backend calls it on the device after each trial's test
// (gpu/solver/gpu_apgd_trials.cu, gpu_apgd_persistent.cu), so the device iterates without reading anything
// back and takes the very same decisions.
struct ApgdControl {
  // iterate buffers X[0..3] (cur: g_k, old: g_{k-1}, best pinned, nw: the trial g_{k+1}; with speculation
  // X[4], and X[5] when both outcomes are speculated) and N x buffers NX[0..2] (ncur: N g_k, nold: N g_{k-1}, nnw: N of the trial)
  int cur = 0, old = 0, best = 0, nw = 1;
  int ncur = 0, nold = 0, nnw = 1;
  int iterations = 0;  // accepted iterations
  int bt = 0;          // backtracks of the current iteration
  int done = 0;        // 1: stop (converged, iteration limit, or failed)
  int failed = 0;      // 1: non-finite test sums at iteration `iterations` (failed_value)
  int accepted = 0;    // the last afterTest accepted its trial; res is its residual
  int max_iterations = 0;
  int min_iterations = 0;  // SolverSettings::min_iterations (reachedStop)
  // Speculation (kern::ApgdSpeculation, set by speculate()): the trial's test pass writes the accepted outcome's
  // next step to X[sa] and the rejected one's to X[sr] (-1: not speculated); ready: X[nw] already holds this
  // trial's step (a speculation that came true), so its step pass is left out.
  int sa = -1, sr = -1, ready = 0;
  int spec_accepted = 0, spec_rejected = 0;  // which outcomes to speculate (set once per solve)
  int trials = 0, speculated = 0;            // trials tested, and those whose step was speculated
  real tolerance = 0;  // absolute stop threshold: SolverSettings::tolerance x res(0) (stopThreshold)
  real L = 1, theta = 1, beta = 0, res = 0, best_res = 0;
  real spec_ta = 0, spec_ba = 0, spec_tr = 0;  // the speculated steps' t and the accepted one's momentum
  real spec_theta = 1;                         // theta after an accepted trial (speculate() computes it)
  double f0 = 0, failed_value = 0;

  DVI_HD static int freeBuf(int count, int a, int b, int c, int d = -1, int e = -1) {
    for (int i = 0; i < count; ++i)
      if (i != a && i != b && i != c && i != d && i != e) return i;
    return -1;
  }
  DVI_HD static bool finite(double v) { return v - v == 0; }  // false for inf and NaN
  // Nesterov's momentum after an accepted step from theta (Beck & Teboulle 2009, FISTA; the APGD paper's
  // theta update): theta' solves theta'^2 = (1 - theta') theta^2, beta = theta (1 - theta) / (theta^2 + theta').
  DVI_HD static void momentum(real theta, real& theta_new, real& beta) {
    theta_new = (-theta * theta + theta * real(sqrt(double(theta * theta + 4)))) / 2;
    beta = theta * (1 - theta) / (theta * theta + theta_new);
  }
  DVI_HD void pick() {
    nw = freeBuf(buffers(), cur, old, best);
    nnw = freeBuf(3, ncur, nold, -1);
  }
  // Readies the coming trial (after pick() at the start, and at the end of afterTest(); afterTest relies on it):
  // the momentum an acceptance will take, computed once a trial, and where and with what the trial's test pass
  // speculates.
  DVI_HD void speculate() {
    sa = spec_accepted ? freeBuf(buffers(), cur, old, best, nw) : -1;
    sr = spec_rejected ? freeBuf(buffers(), cur, old, best, nw, sa) : -1;
    momentum(theta, spec_theta, spec_ba);
    if (sa >= 0) spec_ta = real(1) / (L * real(0.9));  // the L of an accepted trial, below
    if (sr >= 0) spec_tr = real(1) / (L * 2);          // of a rejected one
  }
  // Iterate buffers X holds: 4, and one more per speculated outcome (the four in use leave it free).
  DVI_HD int buffers() const { return 4 + spec_accepted + spec_rejected; }
  // Speculation per solve.
  DVI_HD void setSpeculation(bool accepted_outcome, bool rejected_outcome) {
    spec_accepted = accepted_outcome;
    spec_rejected = rejected_outcome;
  }
  // sums: d^T N d, d^T S^-1 d, residual^2, grad^T (g_{k+1} - g_k), f(g_{k+1}) of the trial in X[nw].
  DVI_HD void afterTest(const double* sums) {
    accepted = 0;
    if (done) return;
    ++trials;
    if (!finite(sums[0]) || !finite(sums[2])) {
      failed = 1;
      failed_value = sums[0] + sums[2];
      done = 1;
      return;
    }
    if (sums[0] > double(L) * sums[1] && bt < 60) {  // sufficient decrease failed: L *= 2, redo the step
      L *= 2;
      ++bt;
      ready = sr >= 0;  // the redone step is in X[sr]; else pass (1) writes it to X[nw] again
      if (ready) nw = sr;
      speculated += ready;
      speculate();
      return;
    }
    bt = 0;
    ++iterations;
    accepted = 1;
    res = real(sqrt(sums[2]));
    old = cur;  // rotate: g_{k-1} <- g_k, g_k <- g_{k+1}
    cur = nw;
    nold = ncur;
    ncur = nnw;
    if (res < best_res && sums[4] <= f0) {
      best_res = res;
      best = cur;
    }
    if (reachedStop(res, tolerance, iterations, min_iterations) || iterations >= max_iterations) {
      done = 1;
      return;
    }
    beta = spec_ba;  // momentum(theta), by speculate()
    theta = spec_theta;
    if (sums[3] > 0) {  // gradient restart (O'Donoghue & Candes 2015, as in the APGD paper)
      beta = 0;
      theta = 1;
    }
    L *= real(0.9);
    // The speculated step is this trial's when its momentum is (a restart voids it unless beta' was 0 anyway).
    ready = sa >= 0 && beta == spec_ba;
    pick();
    if (ready) nw = sa;
    speculated += ready;
    speculate();
  }
};

// The trial's speculation (ApgdControl::speculate) as the test pass's output pointers.
inline kern::ApgdSpeculation speculationOf(const ApgdControl& c, real* const* X) {
  return kern::ApgdSpeculation{c.sa >= 0 ? X[c.sa] : nullptr, c.sr >= 0 ? X[c.sr] : nullptr, c.spec_ta, c.spec_ba,
                               c.spec_tr};
}

// The APGD iterations on the host: one projected step, one Schur product and one test reduction per trial.
// round: VectorStorage::Float, the Schur buffers hold the gradient N x + r rounded to float, as the GPU's float
// buffers do (kern::ApgdStepT::grad_form; the start's is rounded by apgd()).
template <class Ops>
void apgdIterate(Ops& p, ApgdControl& c, real* const* X, real* const* NX, real a, real inv_a, const SolverSettings& s,
                 SolverStats& st, bool round) {
  const BlockSet bs = p.blockSet();
  const real* eta = p.blockSteps();
  const real* r = p.rhs();
  while (!c.done) {
    if (!c.ready)
      p.map(kern::ApgdStep{bs, X[c.cur], X[c.old], NX[c.ncur], NX[c.nold], r, eta, c.beta, real(1) / c.L, X[c.nw],
                           round});
    p.schur(X[c.nw], NX[c.nnw]);
    if (round) p.map(kern::RoundToFloat{NX[c.nnw], r});
    double sums[5];
    p.template reduce<5>(kern::ApgdTest{bs, X[c.cur], X[c.old], NX[c.ncur], NX[c.nold], X[c.nw], NX[c.nnw], r, eta,
                                        c.beta, a, inv_a, round, speculationOf(c, X)},
                         sums);
    c.afterTest(sums);
    if (c.failed) checkFinite(c.failed_value, "apgd", c.iterations);
    if (c.accepted && s.record_history) st.history.push_back(c.res);
  }
}

template <class Ops>
SolverStats apgd(Ops& p, real* gamma, const SolverSettings& s) {
  SolverStats st;
  if (totalBlocks(p) == 0) return st;
  const BlockSet bs = p.blockSet();
  const real* r = p.rhs();
  const real a = alphaOf(p, s), inv_a = real(1) / a;
  // Speculation (SolverSettings::apgd_speculation; Auto: the accepted outcome) needs an iterate buffer more per
  // speculated outcome (ApgdControl::buffers).
  const ApgdSpeculation spec =
      s.apgd_speculation == ApgdSpeculation::Auto ? ApgdSpeculation::Accepted : s.apgd_speculation;
  const bool specs = spec != ApgdSpeculation::None, both = spec == ApgdSpeculation::Both;
  real* X[6] = {p.vec(0), p.vec(1), p.vec(2), p.vec(3), specs ? p.vec(7) : nullptr, both ? p.vec(8) : nullptr};
  real* NX[3] = {p.vec(4), p.vec(5), p.vec(6)};

  // g_0 = s P(warm start). The sums of the start come in two fetches (on the GPU, two read-backs instead of
  // five): the warm start's finiteness, the scaling's sums and the Lipschitz bound's (its product does not depend
  // on the start), then the residual and f of the scaled start (f: the best-iterate rule).
  p.map(kern::CopyProject{bs, gamma, X[0]});
  ApgdControl c;
  p.schur(X[0], NX[0]);
  double warm = 0, start[3] = {0, 0, 0}, squares = 0, res2 = 0, scale2 = 0;
  p.template reduceLater<1>(kern::NonFinite{gamma}, &warm);
  p.template reduceLater<1>(kern::ZeroResidual{bs, r, a, inv_a}, &scale2);
  p.template reduceLater<3>(kern::StartSums{X[0], NX[0], r}, start);
  lipschitzProduct(p, X[1], NX[1], &squares);
  p.fetch();
  if (!(warm == 0)) throw SolverError("apgd: non-finite warm start");
  scaleStart(p, X[0], NX[0], start, "apgd");
  p.template reduceLater<1>(kern::Residual{bs, X[0], NX[0], r, a, inv_a}, &res2);
  p.template reduceLater<1>(kern::Objective{X[0], NX[0], r}, &c.f0);
  p.fetch();
  c.res = c.best_res = startResidual(res2, "apgd");
  if (s.record_history) st.history.push_back(c.res);
  st.residual_scale = real(std::sqrt(scale2));
  c.max_iterations = s.max_iterations;
  c.tolerance = stopThreshold(s, st.residual_scale);
  c.min_iterations = s.min_iterations;
  c.done = reachedStop(c.res, c.tolerance, 0, s.min_iterations) || !(s.max_iterations > 0);
  if (!c.done) {
    c.L = lipschitzBound(squares, totalBlocks(p));
    c.setSpeculation(specs, both);
    c.pick();
    c.speculate();
    if constexpr (Ops::kDeviceLoop) {  // the backend's own trials (the GPU's, over several processes too)
      p.apgdIterate(c, X, NX, a, inv_a, s, st);
    } else {
      // VectorStorage: the GPU (the backend with a device loop) rounds the gradients to float by default.
      const bool round = floatStorage(s, Ops::kDeviceLoop) && !std::is_same_v<real, float>;
      if (round) p.map(kern::RoundToFloat{NX[0], r});  // f0 and L above are of the exact start, as on the GPU
      apgdIterate(p, c, X, NX, a, inv_a, s, st, round);
    }
  }
  st.iterations = c.iterations;
  st.trials = c.trials;
  st.speculated = c.speculated;
  p.copy(X[c.best], gamma);
  st.residual = c.best_res;
  finishStats(st, s);
  return st;
}

// ---------------------------------------------------------------------------------------------------
// BB / SPG: spectral projected gradient, Birgin, Martinez, Raydan, "Nonmonotone spectral projected
// gradient methods on convex sets", SIAM J. Optim. 10(4), 2000 (algorithm SPG2), as applied to the CCP by
// Heyn, Anitescu, Tasora, Negrut, IJNME 95 (2013), in the metric of the diagonal preconditioner
// S = diag(eta_k I3) (see apgd):
//   d_k = P(x_k - a_k S g_k) - x_k                  (g = N x + r)
//   nonmonotone Armijo line search along d_k against the largest of the last M = 10 objective values,
//   sigma = 1e-4, safeguarded quadratic interpolation of the step lambda in [0.1, 0.9] lambda
//   x_{k+1} = x_k + lambda d_k,  g_{k+1} = g_k + lambda N d_k
//   a_{k+1} = d^T S^-1 d / d^T N d (BB1 in the S-metric), clamped to [1e-10, 1e10] / L_0
// f is quadratic, so every trial of the line search is evaluated exactly from (f, g^T d, d^T N d) with no
// further Schur product: one Schur product per iteration. The best iterate is the smallest residual among
// those whose objective is not above the start's.
template <class Ops>
SolverStats bb(Ops& p, real* gamma, const SolverSettings& s) {
  SolverStats st;
  if (totalBlocks(p) == 0) return st;
  const BlockSet bs = p.blockSet();
  const real* eta = p.blockSteps();
  const real* r = p.rhs();
  const real a = alphaOf(p, s), inv_a = real(1) / a;
  real* X[3] = {p.vec(0), p.vec(1), p.vec(2)};
  real* g = p.vec(3);
  real* d = p.vec(4);
  real* Nd = p.vec(5);
  constexpr int kMemory = 10;
  constexpr double kSigma = 1e-4;

  checkWarmStart(p, gamma, "bb");
  st.residual_scale = residualScale(p, a);
  const real thr = stopThreshold(s, st.residual_scale);
  p.map(kern::CopyProject{bs, gamma, X[0]});
  int cur = 0, best = 0;
  p.schur(X[cur], g);
  real res = scaledStart(p, X[cur], g, a, "bb");
  double f;
  p.template reduce<1>(kern::BbInit{X[cur], r, g}, &f);
  real best_res = res;
  const double f0 = f;
  double fhist[kMemory];
  for (double& v : fhist) v = f;
  if (s.record_history) st.history.push_back(res);

  if (!reachedStop(res, thr, 0, s.min_iterations) && s.max_iterations > 0) {
    const real L0 = lipschitzLowerBound(p, d, Nd);
    const real amin = real(1e-10) / L0, amax = real(1e10) / L0;
    real alpha = real(1) / L0;
    for (int it = 0; it < s.max_iterations; ++it) {
      const real* x = X[cur];
      double s1[2];  // g^T d, d^T S^-1 d
      p.template reduce<2>(kern::BbDirection{bs, x, g, eta, alpha, d}, s1);
      const double gd = s1[0], dd = s1[1];
      if (!std::isfinite(gd) || !std::isfinite(dd)) checkFinite(gd + dd, "bb", it);
      if (!(dd > 0)) break;  // x is a fixed point of the projected gradient map: solved
      p.schur(d, Nd);
      double q;
      p.template reduce<1>(kern::Dot{d, Nd}, &q);
      if (!std::isfinite(q)) checkFinite(q, "bb", it);
      double fmax = fhist[0];
      for (double v : fhist) fmax = std::max(fmax, v);
      double lambda = 1;
      for (int ls = 0; ls < 60; ++ls) {
        const double fn = f + lambda * gd + 0.5 * lambda * lambda * q;
        if (fn <= fmax + kSigma * lambda * gd) break;
        const double denom = 2 * (fn - f - lambda * gd);  // = lambda^2 q
        double lt = denom > 0 ? -gd * lambda * lambda / denom : 0.5 * lambda;
        if (!(lt >= 0.1 * lambda && lt <= 0.9 * lambda)) lt = 0.5 * lambda;
        lambda = lt;
      }
      const int nw = freeBuffer(3, cur, best, -1);
      double s2[2];  // residual^2, f of x_{k+1}
      p.template reduce<2>(kern::BbUpdate{bs, x, d, Nd, r, real(lambda), a, inv_a, g, X[nw]}, s2);
      f = s2[1];
      fhist[(it + 1) % kMemory] = f;
      cur = nw;
      ++st.iterations;
      res = real(std::sqrt(s2[0]));
      checkFinite(double(res) + f, "bb", it);
      if (s.record_history) st.history.push_back(res);
      if (res < best_res && f <= f0) {
        best_res = res;
        best = cur;
      }
      if (reachedStop(res, thr, st.iterations, s.min_iterations)) break;
      alpha = q > 0 ? real(dd / q) : amax;
      alpha = std::min(amax, std::max(amin, alpha));
    }
  }
  p.copy(X[best], gamma);
  st.residual = best_res;
  finishStats(st, s);
  return st;
}

}  // namespace algo
}  // namespace dvi
