// CCP solvers on the CcpProblem operator interface (DESIGN §3): projected Jacobi, APGD, BB/SPG, and the
// residual they share. Every vector operation is a fused OpenMP loop over contacts; reductions go through
// detail::blockReduce so results are bitwise identical for any thread count.
#include "solver.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>

#include "cone.h"

namespace dvi {

const char* solverName(SolverType t) {
  switch (t) {
    case SolverType::Jacobi: return "jacobi";
    case SolverType::GaussSeidel: return "gs";
    case SolverType::APGD: return "apgd";
    case SolverType::BB: return "bb";
  }
  return "?";
}

bool parseSolver(const std::string& s0, SolverType& out) {
  std::string s = s0;
  for (char& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  if (s == "jacobi") out = SolverType::Jacobi;
  else if (s == "gs" || s == "gauss-seidel" || s == "gaussseidel" || s == "pgs") out = SolverType::GaussSeidel;
  else if (s == "apgd" || s == "nesterov") out = SolverType::APGD;
  else if (s == "bb" || s == "spg" || s == "barzilai-borwein") out = SolverType::BB;
  else return false;
  return true;
}

namespace {

// Scratch kept per calling thread; it only grows, so a solve allocates at most on its first call for a
// given size, and iterations never do.
struct Workspace {
  std::vector<real> v[8];
  std::vector<double> part;
  real* get(int i, int64_t n) {
    if (int64_t(v[i].size()) < n) v[i].resize(size_t(n));
    return v[i].data();
  }
};
Workspace& workspace() {
  thread_local Workspace w;
  return w;
}

// Threads of a solve: serial below kSerialContacts (bitwise identical, see solver.h).
int solverThreads(const CcpProblem& p) { return p.size() / 3 < kSerialContacts ? 1 : std::max(1, p.threads()); }

// Throws SolverError if the warm start holds a NaN or inf (the projection could otherwise hide it).
void checkWarmStart(int64_t n, int T, const real* g, std::vector<double>& part, const char* who) {
  double s;
  detail::blockReduce<1>(n / 3, T, part, &s, [&](int64_t k, double* acc) {
    for (int j = 0; j < 3; ++j) acc[0] += double(g[3 * k + j]) * 0;  // NaN for NaN or inf
  });
  if (!(s == 0)) throw SolverError(std::string(who) + ": non-finite warm start");
}

void projectAll(int64_t nc, int T, const real* mu, real* x) {
#pragma omp parallel for schedule(static) num_threads(T) if (T > 1)
  for (int64_t k = 0; k < nc; ++k) projectConeBlock(mu[k], x + 3 * k);
}

void copyAll(int64_t n, int T, const real* src, real* dst) {
  if (src == dst) return;
#pragma omp parallel for schedule(static) num_threads(T) if (T > 1)
  for (int64_t i = 0; i < n; ++i) dst[i] = src[i];
}

// Residual of x given Nx (not N x + r).
real residualGivenNx(const CcpProblem& p, const real* x, const real* Nx, real a, std::vector<double>& part) {
  const real inv_a = real(1) / a;
  const int64_t nc = p.size() / 3;
  const real* mu = p.frictionCoefficients();
  const real* r = p.rhs();
  double s;
  detail::blockReduce<1>(nc, solverThreads(p), part, &s, [&](int64_t k, double* acc) {
    real grad[3] = {Nx[3 * k] + r[3 * k], Nx[3 * k + 1] + r[3 * k + 1], Nx[3 * k + 2] + r[3 * k + 2]};
    acc[0] += projectedGradientResidual2(mu[k], x + 3 * k, grad, a, inv_a);
  });
  return real(std::sqrt(s));
}

// Lower bound of lambda_max(S^1/2 N S^1/2), S = diag(eta_k I3) the preconditioner, to start the step
// estimates: max(|S^1/2 N S^1/2 e| / |e|, 1/3), e = ones (APGD paper, Mazhar et al. 2015, takes
// L0 = |N (g0 - g^0)| / |g0 - g^0|). Both are <= lambda_max: eta_k is 1 / (Gershgorin bound of N_kk) and
// that bound is <= 3 max_i (N_kk)_ii, so some diagonal entry eta_k (N_kk)_ii of the scaled matrix is >= 1/3.
// The backtracking only has to grow it. One Schur product (setup, not per iteration).
real lipschitzLowerBound(const CcpProblem& p, real* e, real* Ne, std::vector<double>& part, int T) {
  const int64_t n = p.size(), nc = n / 3;
  const real* eta = p.blockSteps();
#pragma omp parallel for schedule(static) num_threads(T) if (T > 1)
  for (int64_t i = 0; i < n; ++i) e[i] = std::sqrt(eta[i / 3]);
  p.schur(e, Ne);
  double s;
  detail::blockReduce<1>(nc, T, part, &s, [&](int64_t k, double* acc) {
    for (int j = 0; j < 3; ++j) {
      const double v = double(Ne[3 * k + j]) * e[3 * k + j];
      acc[0] += v * v;
    }
  });
  real L = real(std::sqrt(s / double(n)));
  L = std::max(L, real(1) / 3);
  if (!std::isfinite(L)) throw SolverError("solver: non-finite N (Lipschitz estimate is " + std::to_string(L) + ")");
  return L;
}

// The start of every solver: x = P(warm start), then x <- s x with s = argmin_{s >= 0} f(s x), f(x) =
// 1/2 x^T N x + r^T x, i.e. s = max(0, -r^T x / x^T N x) (s = 1 where x^T N x = 0 and r^T x <= 0, 0
// where both vanish or r^T x > 0): f(start) <= min(f(P(warm)), f(0) = 0). Nx = N x on entry is scaled
// with x (no second Schur product). Returns the start's residual; throws SolverError on non-finite input.
real scaledStart(const CcpProblem& p, real* x, real* Nx, real a, std::vector<double>& part, int T,
                 const char* who) {
  const int64_t n = p.size(), nc = n / 3;
  const real* r = p.rhs();
  double sums[3];  // x^T N x, r^T x, finiteness of r
  detail::blockReduce<3>(nc, T, part, sums, [&](int64_t k, double* acc) {
    for (int j = 0; j < 3; ++j) {
      acc[0] += double(x[3 * k + j]) * Nx[3 * k + j];
      acc[1] += double(r[3 * k + j]) * x[3 * k + j];
      acc[2] += double(r[3 * k + j]) * 0;  // NaN or inf in r makes this NaN
    }
  });
  if (!std::isfinite(sums[0]) || !std::isfinite(sums[1]) || !std::isfinite(sums[2]))
    throw SolverError(std::string(who) + ": non-finite right-hand side, N x or warm start");
  double sc = 1;
  if (sums[0] > 0) sc = std::max(0.0, -sums[1] / sums[0]);
  else if (sums[1] > 0 || sums[0] < 0) sc = 0;
  if (sc != 1) {
    const real c = real(sc);
#pragma omp parallel for schedule(static) num_threads(T) if (T > 1)
    for (int64_t i = 0; i < n; ++i) {
      x[i] *= c;
      Nx[i] *= c;
    }
  }
  const real res = residualGivenNx(p, x, Nx, a, part);
  if (!std::isfinite(res)) throw SolverError(std::string(who) + ": non-finite residual at the start");
  return res;
}

void checkFinite(real res, const char* who, int it) {
  if (!std::isfinite(res))
    throw SolverError(std::string(who) + ": non-finite value (residual " + std::to_string(res) + ") at iteration " +
                      std::to_string(it));
}

// Picks a buffer index among `count` that is none of the given ones.
int freeBuffer(int count, int a, int b, int c) {
  for (int i = 0; i < count; ++i)
    if (i != a && i != b && i != c) return i;
  return -1;
}

}  // namespace

real residualAlpha(const CcpProblem& p, const SolverSettings& s) {
  const real d = p.maxDiagonal();
  return d > real(0) ? s.residual_alpha / d : s.residual_alpha;
}

real ccpResidual(const CcpProblem& p, const real* gamma, real alpha, std::vector<real>& scratch) {
  const int64_t n = p.size();
  if (n == 0) return 0;
  if (int64_t(scratch.size()) < n) scratch.resize(size_t(n));
  p.schur(gamma, scratch.data());
  return residualGivenNx(p, gamma, scratch.data(), alpha, workspace().part);
}

// ---------------------------------------------------------------------------------------------------
// Projected Jacobi with over-relaxation and block scaling:
//   g <- P(g - w S (N g + r)),  S = diag(t_k I3) (Scalar: t_k = p.jacobiSteps(), a Gershgorin bound of the
//   whole row of N, coupling included, so rho(S N) <= 1 and w <= 1 decreases f) or N_kk^-1 (Inverse3x3).
// One Schur product per iteration; the residual of the current iterate comes out of the same loop.
SolverStats solveJacobi(const CcpProblem& p, real* gamma, const SolverSettings& s) {
  SolverStats st;
  const int64_t n = p.size(), nc = n / 3;
  if (n == 0) return st;
  const int T = solverThreads(p);
  const real* mu = p.frictionCoefficients();
  const real* eta = p.jacobiSteps();
  const real* r = p.rhs();
  const real a = residualAlpha(p, s), inv_a = real(1) / a;
  const real w = s.jacobi_omega;
  const bool full = s.block_scaling == BlockScaling::Inverse3x3;
  Workspace& ws = workspace();
  real* Ng = ws.get(0, n);
  real* other = ws.get(1, n);
  real* sg = full ? ws.get(2, n) : nullptr;

  checkWarmStart(n, T, gamma, ws.part, "jacobi");
  projectAll(nc, T, mu, gamma);
  p.schur(gamma, Ng);
  scaledStart(p, gamma, Ng, a, ws.part, T, "jacobi");
  real* cur = gamma;
  real* next = other;
  real res = 0;
  for (int it = 0;; ++it) {
    if (it > 0) p.schur(cur, Ng);
    const bool last = it == s.max_iterations;
    double sum;
    if (!full) {
      detail::blockReduce<1>(nc, T, ws.part, &sum, [&](int64_t k, double* acc) {
        const real* g = cur + 3 * k;
        real grad[3] = {Ng[3 * k] + r[3 * k], Ng[3 * k + 1] + r[3 * k + 1], Ng[3 * k + 2] + r[3 * k + 2]};
        acc[0] += projectedGradientResidual2(mu[k], g, grad, a, inv_a);
        if (!last) {
          const real t = w * eta[k];
          real* x = next + 3 * k;
          x[0] = g[0] - t * grad[0];
          x[1] = g[1] - t * grad[1];
          x[2] = g[2] - t * grad[2];
          projectConeBlock(mu[k], x);
        }
      });
    } else {
      detail::blockReduce<1>(nc, T, ws.part, &sum, [&](int64_t k, double* acc) {
        real* grad = Ng + 3 * k;
        for (int j = 0; j < 3; ++j) grad[j] += r[3 * k + j];
        acc[0] += projectedGradientResidual2(mu[k], cur + 3 * k, grad, a, inv_a);
      });
      if (!last) {
        p.applyBlockInverse(Ng, sg);
#pragma omp parallel for schedule(static) num_threads(T) if (T > 1)
        for (int64_t k = 0; k < nc; ++k) {
          real* x = next + 3 * k;
          for (int j = 0; j < 3; ++j) x[j] = cur[3 * k + j] - w * sg[3 * k + j];
          projectConeBlock(mu[k], x);
        }
      }
    }
    res = real(std::sqrt(sum));
    checkFinite(res, "jacobi", it);
    if (s.record_history) st.history.push_back(res);
    if (last || (s.tolerance > 0 && res < s.tolerance)) break;
    std::swap(cur, next);
    ++st.iterations;
  }
  copyAll(n, T, cur, gamma);
  st.residual = res;
  return st;
}

// ---------------------------------------------------------------------------------------------------
// APGD: Mazhar, Heyn, Negrut, Tasora, "Using Nesterov's method to accelerate multibody dynamics with
// friction and contact", ACM TOG 34(3), 2015, Algorithm APGD, in the metric of the diagonal
// preconditioner S = diag(eta_k I3) (eta_k = p.blockSteps()):
//   g_{k+1} = P(y_k - t_k S (N y_k + r));  while f(g_{k+1}) > f(y_k) + grad^T d + L_k/2 |d|_S^2: L_k *= 2, redo
//   theta_{k+1} = (-theta_k^2 + theta_k sqrt(theta_k^2 + 4)) / 2,  beta = theta_k (1 - theta_k) / (theta_k^2 + theta_{k+1})
//   y_{k+1} = g_{k+1} + beta (g_{k+1} - g_k)
//   keep the best g; stop below the tolerance
//   restart: if grad^T (g_{k+1} - g_k) > 0: y_{k+1} = g_{k+1}, theta_{k+1} = 1
//   L_{k+1} = 0.9 L_k, t = 1 / L
// |d|_S^2 = d^T S^-1 d. S is a positive scalar per contact, so the S-metric projection onto the product of
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
SolverStats solveApgd(const CcpProblem& p, real* gamma, const SolverSettings& s) {
  SolverStats st;
  const int64_t n = p.size(), nc = n / 3;
  if (n == 0) return st;
  const int T = solverThreads(p);
  const real* mu = p.frictionCoefficients();
  const real* eta = p.blockSteps();
  const real* r = p.rhs();
  const real a = residualAlpha(p, s), inv_a = real(1) / a;
  Workspace& ws = workspace();
  real* X[4] = {ws.get(0, n), ws.get(1, n), ws.get(2, n), ws.get(3, n)};
  real* NX[3] = {ws.get(4, n), ws.get(5, n), ws.get(6, n)};

  // g_0 = s P(warm start)
  checkWarmStart(n, T, gamma, ws.part, "apgd");
  copyAll(n, T, gamma, X[0]);
  projectAll(nc, T, mu, X[0]);
  int cur = 0, old = 0, best = 0;
  int ncur = 0, nold = 0;
  p.schur(X[cur], NX[ncur]);
  real best_res = scaledStart(p, X[cur], NX[ncur], a, ws.part, T, "apgd");
  real res = best_res;
  if (s.record_history) st.history.push_back(res);

  if (!(s.tolerance > 0 && res < s.tolerance) && s.max_iterations > 0) {
    // f of the start (for the best-iterate rule)
    double f0;
    detail::blockReduce<1>(nc, T, ws.part, &f0, [&](int64_t k, double* acc) {
      for (int j = 0; j < 3; ++j) {
        const int64_t i = 3 * k + j;
        acc[0] += 0.5 * double(X[cur][i]) * (NX[ncur][i] + 2 * r[i]);
      }
    });
    real L = lipschitzLowerBound(p, X[1], NX[1], ws.part, T);
    real theta = 1, beta = 0;
    for (int it = 0; it < s.max_iterations; ++it) {
      const int nw = freeBuffer(4, cur, old, best);
      const int nnw = freeBuffer(3, ncur, nold, -1);
      const real* gc = X[cur];
      const real* go = X[old];
      const real* Nc = NX[ncur];
      const real* No = NX[nold];
      real* gn = X[nw];
      real* Nn = NX[nnw];
      double sums[5];  // d^T N d, d^T S^-1 d, residual^2, grad^T (g_{k+1} - g_k), f(g_{k+1})
      for (int bt = 0;; ++bt) {
        const real t = real(1) / L;
        // (1) g_{k+1} = P(y - t S (N y + r))
#pragma omp parallel for schedule(static) num_threads(T) if (T > 1)
        for (int64_t k = 0; k < nc; ++k) {
          real* x = gn + 3 * k;
          const real te = t * eta[k];
          for (int j = 0; j < 3; ++j) {
            const int64_t i = 3 * k + j;
            const real y = gc[i] + beta * (gc[i] - go[i]);
            const real Ny = Nc[i] + beta * (Nc[i] - No[i]);
            x[j] = y - te * (Ny + r[i]);
          }
          projectConeBlock(mu[k], x);
        }
        p.schur(gn, Nn);
        // (2) backtracking test, residual and f of g_{k+1}, restart test
        detail::blockReduce<5>(nc, T, ws.part, sums, [&](int64_t k, double* acc) {
          real grad_n[3];
          double dd = 0;
          for (int j = 0; j < 3; ++j) {
            const int64_t i = 3 * k + j;
            const real y = gc[i] + beta * (gc[i] - go[i]);
            const real Ny = Nc[i] + beta * (Nc[i] - No[i]);
            const real d = gn[i] - y;
            acc[0] += double(d) * (Nn[i] - Ny);
            dd += double(d) * d;
            acc[3] += double(Ny + r[i]) * (gn[i] - gc[i]);
            acc[4] += 0.5 * double(gn[i]) * (Nn[i] + 2 * r[i]);
            grad_n[j] = Nn[i] + r[i];
          }
          if (eta[k] > 0) acc[1] += dd / eta[k];  // a contact between immovable bodies has no metric weight
          acc[2] += projectedGradientResidual2(mu[k], gn + 3 * k, grad_n, a, inv_a);
        });
        if (!std::isfinite(sums[0]) || !std::isfinite(sums[2])) checkFinite(real(sums[0] + sums[2]), "apgd", it);
        if (!(sums[0] > double(L) * sums[1]) || bt >= 60) break;
        L *= 2;
      }
      ++st.iterations;
      res = real(std::sqrt(sums[2]));
      if (s.record_history) st.history.push_back(res);
      // Rotate: g_{k-1} <- g_k, g_k <- g_{k+1}.
      old = cur;
      cur = nw;
      nold = ncur;
      ncur = nnw;
      if (res < best_res && sums[4] <= f0) {
        best_res = res;
        best = cur;
      }
      if (s.tolerance > 0 && res < s.tolerance) break;
      const real theta_new = (-theta * theta + theta * std::sqrt(theta * theta + 4)) / 2;
      beta = theta * (1 - theta) / (theta * theta + theta_new);
      theta = theta_new;
      if (sums[3] > 0) {  // gradient restart (O'Donoghue & Candes 2015, as in the APGD paper)
        beta = 0;
        theta = 1;
      }
      L *= real(0.9);
    }
  }
  copyAll(n, T, X[best], gamma);
  st.residual = best_res;
  return st;
}

// ---------------------------------------------------------------------------------------------------
// BB / SPG: spectral projected gradient, Birgin, Martinez, Raydan, "Nonmonotone spectral projected
// gradient methods on convex sets", SIAM J. Optim. 10(4), 2000 (algorithm SPG2), as applied to the CCP by
// Heyn, Anitescu, Tasora, Negrut, IJNME 95 (2013), in the metric of the diagonal preconditioner
// S = diag(eta_k I3) (see solveApgd):
//   d_k = P(x_k - a_k S g_k) - x_k                  (g = N x + r)
//   nonmonotone Armijo line search along d_k against the largest of the last M = 10 objective values,
//   sigma = 1e-4, safeguarded quadratic interpolation of the step lambda in [0.1, 0.9] lambda
//   x_{k+1} = x_k + lambda d_k,  g_{k+1} = g_k + lambda N d_k
//   a_{k+1} = d^T S^-1 d / d^T N d (BB1 in the S-metric), clamped to [1e-10, 1e10] / L_0
// f is quadratic, so every trial of the line search is evaluated exactly from (f, g^T d, d^T N d) with no
// further Schur product: one Schur product per iteration. The best iterate is the smallest residual among
// those whose objective is not above the start's.
SolverStats solveBB(const CcpProblem& p, real* gamma, const SolverSettings& s) {
  SolverStats st;
  const int64_t n = p.size(), nc = n / 3;
  if (n == 0) return st;
  const int T = solverThreads(p);
  const real* mu = p.frictionCoefficients();
  const real* eta = p.blockSteps();
  const real* r = p.rhs();
  const real a = residualAlpha(p, s), inv_a = real(1) / a;
  Workspace& ws = workspace();
  real* X[3] = {ws.get(0, n), ws.get(1, n), ws.get(2, n)};
  real* g = ws.get(3, n);
  real* d = ws.get(4, n);
  real* Nd = ws.get(5, n);
  constexpr int kMemory = 10;
  constexpr double kSigma = 1e-4;

  checkWarmStart(n, T, gamma, ws.part, "bb");
  copyAll(n, T, gamma, X[0]);
  projectAll(nc, T, mu, X[0]);
  int cur = 0, best = 0;
  p.schur(X[cur], g);
  real res = scaledStart(p, X[cur], g, a, ws.part, T, "bb");
  double sums[2];
  detail::blockReduce<1>(nc, T, ws.part, sums, [&](int64_t k, double* acc) {
    real* gk = g + 3 * k;
    const real* x = X[cur] + 3 * k;
    for (int j = 0; j < 3; ++j) {
      gk[j] += r[3 * k + j];
      acc[0] += 0.5 * double(x[j]) * (gk[j] + r[3 * k + j]);  // f = 1/2 x^T (N x + 2 r)
    }
  });
  real best_res = res;
  double f = sums[0];
  const double f0 = f;
  double fhist[kMemory];
  for (double& v : fhist) v = f;
  if (s.record_history) st.history.push_back(res);

  if (!(s.tolerance > 0 && res < s.tolerance) && s.max_iterations > 0) {
    const real L0 = lipschitzLowerBound(p, d, Nd, ws.part, T);
    const real amin = real(1e-10) / L0, amax = real(1e10) / L0;
    real alpha = real(1) / L0;
    for (int it = 0; it < s.max_iterations; ++it) {
      const real* x = X[cur];
      // d = P(x - alpha S g) - x;  g^T d, d^T S^-1 d
      double s1[2];
      detail::blockReduce<2>(nc, T, ws.part, s1, [&](int64_t k, double* acc) {
        real* dk = d + 3 * k;
        const real ae = alpha * eta[k];
        for (int j = 0; j < 3; ++j) dk[j] = x[3 * k + j] - ae * g[3 * k + j];
        projectConeBlock(mu[k], dk);
        double dd = 0;
        for (int j = 0; j < 3; ++j) {
          dk[j] -= x[3 * k + j];
          acc[0] += double(g[3 * k + j]) * dk[j];
          dd += double(dk[j]) * dk[j];
        }
        if (eta[k] > 0) acc[1] += dd / eta[k];
      });
      const double gd = s1[0], dd = s1[1];
      if (!std::isfinite(gd) || !std::isfinite(dd)) checkFinite(real(gd + dd), "bb", it);
      if (!(dd > 0)) break;  // x is a fixed point of the projected gradient map: solved
      p.schur(d, Nd);
      double q;
      detail::blockReduce<1>(nc, T, ws.part, &q, [&](int64_t k, double* acc) {
        for (int j = 0; j < 3; ++j) acc[0] += double(d[3 * k + j]) * Nd[3 * k + j];
      });
      if (!std::isfinite(q)) checkFinite(real(q), "bb", it);
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
      const real lam = real(lambda);
      // x_{k+1} = x + lambda d, g += lambda N d, residual and f of x_{k+1}
      const int nw = freeBuffer(3, cur, best, -1);
      real* xn = X[nw];
      double s2[2];
      detail::blockReduce<2>(nc, T, ws.part, s2, [&](int64_t k, double* acc) {
        real* gk = g + 3 * k;
        real* xk = xn + 3 * k;
        for (int j = 0; j < 3; ++j) {
          const int64_t i = 3 * k + j;
          xk[j] = x[i] + lam * d[i];
          gk[j] += lam * Nd[i];
        }
        projectConeBlock(mu[k], xk);  // x + lambda d is in the convex set; this only removes rounding
        for (int j = 0; j < 3; ++j) acc[1] += 0.5 * double(xk[j]) * (gk[j] + r[3 * k + j]);
        acc[0] += projectedGradientResidual2(mu[k], xk, gk, a, inv_a);
      });
      f = s2[1];
      fhist[(it + 1) % kMemory] = f;
      cur = nw;
      ++st.iterations;
      res = real(std::sqrt(s2[0]));
      checkFinite(real(res + f), "bb", it);
      if (s.record_history) st.history.push_back(res);
      if (res < best_res && f <= f0) {
        best_res = res;
        best = cur;
      }
      if (s.tolerance > 0 && res < s.tolerance) break;
      alpha = q > 0 ? real(dd / q) : amax;
      alpha = std::min(amax, std::max(amin, alpha));
    }
  }
  copyAll(n, T, X[best], gamma);
  st.residual = best_res;
  return st;
}

}  // namespace dvi
