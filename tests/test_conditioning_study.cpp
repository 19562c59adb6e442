// A measured study of conditioning methods for large mass ratios (docs/ARCHITECTURE.md, "Convergence measure, the
// default stop and its report"). Hidden: `dvisim_tests "[.study]" -s` (CPU backend; no solver or library code is
// changed: every candidate other than the library's APGD, BB, Jacobi and Gauss-Seidel is written here on top of the
// public CcpProblem operators, the Schur product y = N x, the projection and the block steps).
//
// Scenes: tests/test_convergence.cpp's particle mass-ratio case (2x2 light spheres of r = 1 cm in a tight box
// carrying one heavy sphere, ratio 1e2 / 1e4 / 1e6, h = 1e-3 s) and the 10-box stack (10 cm boxes, the top 1e3 /
// 1e6 times heavier, h = 0.01 s). Two measurements:
//  (1) snapshots: the CCP (problem and warm start) of the first step and of a step mid-run, captured from a run
//      at the library's defaults; each candidate solves it to relative residual 1e-1, 1e-2 and 1e-3 (no floor of
//      50, study cap 20000 iterations): iterations, time, and the heavy body's position error over the step,
//      h |v_H(g) - v_H(g*)|, against the exact CCP solution g* (a 1e-11 solve);
//  (2) full runs at the product's stop (0.1, at least 50, at most 1000) with the candidate as the step's solver:
//      iterations a step, steps that missed, the heavy body's drift from its start.
//
// Candidates (docs/ARCHITECTURE.md cites the papers):
//   apgd       the library's APGD (gradient restart, scalar block steps; solveApgd)
//   apgd-grad  the same algorithm written here (checks this file's APGD against the library's)
//   apgd-fn    APGD with O'Donoghue & Candes' function restart (f(g_k+1) > f(g_k)) instead of the gradient one
//   apgd+gsH   APGD, and every 50 iterations 5 projected Gauss-Seidel sweeps over the heavy body's contacts
//   apgd+gsA   the same over all contacts
//   gs         the library's projected Gauss-Seidel (sequential CPU reference)
//   msplit     mass-splitting Jacobi (Tonge, Benevolenski & Voroshilov 2012): block steps of N computed with each
//              body's inverse mass and inertia times its contact count
//   apgd-ms    APGD in the metric of the mass-split block steps
//   jac3x3     the library's Jacobi with per-block N_kk^-1 scaling (Inverse3x3, omega 0.3)
//   apgd+sub   APGD with a two-group subspace step every 10 iterations: g <- (1+c1) g_H + (1+c2) g_O, the
//              heavy body's contacts and the others, (c1, c2) minimising f (2x2 system, one extra Schur product),
//              then a momentum restart; apgd+subK: without the restart; apgd+subC: without it and only where the
//              heavy body's contacts start from zero impulse (a cold start); apgd+sub0: once, on the start
//   bb         the library's BB / spectral projected gradient (solveBB)
#include <catch2/catch.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <memory>
#include <numeric>
#include <stdexcept>
#include <string>
#include <vector>

#include "body_builders.h"
#include "chrono_like/solver/contact_problem.h"
#include "chrono_like/solver/solver_algorithms.h"
#include "chrono_like/system.h"

using namespace dvi;

namespace {

using testbodies::ball;
using testbodies::cube;
using testbodies::groundPlane;

// ---------------------------------------------------------------- a problem to solve
struct Problem {
  std::shared_ptr<ContactProblem> p;
  std::shared_ptr<ContactProblem> split;  // the same contacts, each body's inverse mass x its contact count
  std::vector<real> warm;                 // the step's warm start (the System's, before the solve)
  std::vector<int> heavy_blocks;          // contacts of the heavy body
  int heavy = -1;
  int nbodies = 0;
  Vec3 vfree_heavy{0, 0, 0};
  real h = 0;
};

// The heavy body's velocity after impulses g.
Vec3 heavyVelocity(const Problem& q, const std::vector<real>& g) {
  std::vector<Vec3> dv(size_t(q.nbodies), Vec3{0, 0, 0}), dw(size_t(q.nbodies), Vec3{0, 0, 0});
  q.p->applyImpulses(g.data(), dv.data(), dw.data());
  return q.vfree_heavy + dv[size_t(q.heavy)];
}

// ---------------------------------------------------------------- the candidates (on the operator interface)
struct Result {
  int iterations = 0;  // accepted iterations (or sweeps); polish sweeps counted separately
  int sweeps = 0;
  real rel = 0;  // relative residual reached
  bool converged = false;
};

struct Ctx {
  real tol = real(0.1);
  int min_it = 0;
  int cap = 1000;
};

real residualOf(const CcpProblem& p, const real* g, const real* Ng, real a, std::vector<real>& t) {
  const int n = p.size();
  t.resize(static_cast<size_t>(n));
  const real* r = p.rhs();
  for (int i = 0; i < n; ++i) t[size_t(i)] = g[i] - a * (Ng[i] + r[i]);
  p.project(t.data());
  double s = 0;
  for (int i = 0; i < n; ++i) {
    const double e = (double(g[i]) - t[size_t(i)]) / a;
    s += e * e;
  }
  return real(std::sqrt(s));
}
double objective(const CcpProblem& p, const real* g, const real* Ng) {
  double f = 0;
  for (int i = 0; i < p.size(); ++i) f += double(g[i]) * (0.5 * Ng[i] + p.rhs()[i]);
  return f;
}

// Scaled projected warm start (every library solver's start): g = s P(w), s = argmin f(s g).
void startOf(const CcpProblem& p, std::vector<real>& g, std::vector<real>& Ng) {
  p.project(g.data());
  p.schur(g.data(), Ng.data());
  double gNg = 0, rg = 0;
  for (int i = 0; i < p.size(); ++i)
    gNg += double(g[size_t(i)]) * Ng[size_t(i)], rg += double(p.rhs()[i]) * g[size_t(i)];
  double sc = 1;
  if (gNg > 0)
    sc = std::max(0.0, -rg / gNg);
  else if (rg > 0 || gNg < 0)
    sc = 0;
  for (int i = 0; i < p.size(); ++i) g[size_t(i)] = real(sc * g[size_t(i)]), Ng[size_t(i)] = real(sc * Ng[size_t(i)]);
}

// Projected Gauss-Seidel on a subset of blocks through extracted columns of N (the operator gives no rows; the
// columns of the subset cost 3 |subset| Schur products, once per solve). Scalar block steps (cone-preserving, the
// library's GS rule). grad = N g + r is kept current for every block.
struct SubsetGs {
  std::vector<int> blocks;
  std::vector<std::vector<real>> cols;  // 3 per block: N e_i
  void setup(const CcpProblem& p, const std::vector<int>& b) {
    blocks = b;
    cols.assign(3 * b.size(), std::vector<real>(size_t(p.size())));
    std::vector<real> e(size_t(p.size()), real(0));
    for (size_t i = 0; i < b.size(); ++i)
      for (int j = 0; j < 3; ++j) {
        e[size_t(3 * b[i] + j)] = 1;
        p.schur(e.data(), cols[3 * i + size_t(j)].data());
        e[size_t(3 * b[i] + j)] = 0;
      }
  }
  void sweep(const CcpProblem& p, real* g, real* grad) const {
    const BlockSet bs = p.blockSet();
    const real* eta = p.blockSteps();
    for (size_t i = 0; i < blocks.size(); ++i) {
      const int k = blocks[i];
      real x[3], d[3];
      for (int j = 0; j < 3; ++j) x[j] = g[3 * k + j] - eta[k] * grad[3 * k + j];
      projectBlock(bs, k, x);
      for (int j = 0; j < 3; ++j) d[j] = x[j] - g[3 * k + j], g[3 * k + j] = x[j];
      for (int j = 0; j < 3; ++j)
        if (d[j] != 0)
          for (int m = 0; m < p.size(); ++m) grad[m] += cols[3 * i + size_t(j)][size_t(m)] * d[j];
    }
  }
};

enum class Restart { Gradient, Function };
struct ApgdOptions {
  Restart restart = Restart::Gradient;
  const real* eta = nullptr;  // metric (block steps); null: p.blockSteps()
  int polish_every = 0;       // APGD iterations between Gauss-Seidel polishes (0: none)
  int polish_sweeps = 5;
  const std::vector<int>* polish_blocks = nullptr;  // null: all blocks
  int sub_every = 0;                                // two-group subspace step every sub_every iterations (0: none)
  const std::vector<int>* group = nullptr;          // group H of the subspace step
  bool sub_cold_only = false;  // the periodic subspace step only where group H starts from zero impulses
  bool sub_start = false;      // the two-group subspace step once, on the start
  bool jump_restart = true;    // restart the momentum after a polish or subspace step
};

// APGD as solver_algorithms.h's (Mazhar et al. 2015 with the scalar block metric, backtracking, L *= 0.9, best
// iterate), unfused, with the options above.
Result apgdLocal(const CcpProblem& p, std::vector<real>& gamma, const Ctx& cx, const ApgdOptions& o) {
  const int n = p.size(), nb = n / 3;
  const real* r = p.rhs();
  const real* eta = o.eta ? o.eta : p.blockSteps();
  const BlockSet bs = p.blockSet();
  SolverSettings ss;
  const real a = residualAlpha(p, ss);
  std::vector<real> t, g = gamma, Ng(static_cast<size_t>(n)), go(static_cast<size_t>(n)), Ngo(static_cast<size_t>(n)),
                       y(static_cast<size_t>(n)), Ny(static_cast<size_t>(n)), gn(static_cast<size_t>(n)),
                       Ngn(static_cast<size_t>(n)), best, grad;
  startOf(p, g, Ng);
  go = g, Ngo = Ng;
  std::vector<real> zero(static_cast<size_t>(n), real(0));
  const real res0 = residualOf(p, zero.data(), zero.data(), a, t);
  const real thr = cx.tol * res0;
  real res = residualOf(p, g.data(), Ng.data(), a, t);
  const double f0 = objective(p, g.data(), Ng.data());
  double fcur = f0;
  real best_res = res;
  best = g;
  // L0: |S^1/2 N S^1/2 1| / |1| (lipschitzLowerBound)
  real L;
  {
    std::vector<real> e(static_cast<size_t>(n)), Ne(static_cast<size_t>(n));
    for (int k = 0; k < nb; ++k)
      for (int j = 0; j < 3; ++j) e[size_t(3 * k + j)] = std::sqrt(eta[k]);
    p.schur(e.data(), Ne.data());
    double s = 0;
    for (int i = 0; i < n; ++i) s += double(e[size_t(i)] * Ne[size_t(i)]) * (e[size_t(i)] * Ne[size_t(i)]);
    L = std::max(real(std::sqrt(s / n)), real(1) / 3);
  }
  SubsetGs gs;
  std::vector<int> all(static_cast<size_t>(nb));
  std::iota(all.begin(), all.end(), 0);
  if (o.polish_every > 0) gs.setup(p, o.polish_blocks ? *o.polish_blocks : all);
  std::vector<char> inH(static_cast<size_t>(nb), 0);
  if (o.group)
    for (int k : *o.group) inH[size_t(k)] = 1;
  // the two-group subspace step on g (one Schur product)
  auto subspace = [&] {
    // v1 = g on group H, v2 = g elsewhere; N v2 = N g - N v1: one Schur product.
    std::vector<real> v1(static_cast<size_t>(n), real(0)), Nv1(static_cast<size_t>(n));
    for (int k = 0; k < nb; ++k)
      if (inH[size_t(k)])
        for (int j = 0; j < 3; ++j) v1[size_t(3 * k + j)] = g[size_t(3 * k + j)];
    p.schur(v1.data(), Nv1.data());
    double A11 = 0, A12 = 0, A22 = 0, b1 = 0, b2 = 0;
    for (int i = 0; i < n; ++i) {
      const double v1i = v1[size_t(i)], v2i = double(g[size_t(i)]) - v1i;
      const double Nv1i = Nv1[size_t(i)], Nv2i = double(Ng[size_t(i)]) - Nv1i;
      A11 += v1i * Nv1i, A12 += v1i * Nv2i, A22 += v2i * Nv2i;
      const double gr = double(Ng[size_t(i)]) + r[i];
      b1 += v1i * gr, b2 += v2i * gr;
    }
    // minimise f(g + c1 v1 + c2 v2): A c = -b; keep 1 + c >= 0 (a non-negative scaling stays in the cones)
    const double det = A11 * A22 - A12 * A12;
    double c1 = 0, c2 = 0;
    if (det > 1e-300 * (A11 * A22) && det > 0) {
      c1 = (-b1 * A22 + b2 * A12) / det;
      c2 = (-b2 * A11 + b1 * A12) / det;
    } else if (A11 > 0) {
      c1 = -b1 / A11;
    }
    c1 = std::max(c1, -1.0), c2 = std::max(c2, -1.0);
    for (int i = 0; i < n; ++i) {
      const double v1i = v1[size_t(i)], v2i = double(g[size_t(i)]) - v1i;
      const double Nv1i = Nv1[size_t(i)], Nv2i = double(Ng[size_t(i)]) - Nv1i;
      g[size_t(i)] = real(double(g[size_t(i)]) + c1 * v1i + c2 * v2i);
      Ng[size_t(i)] = real(double(Ng[size_t(i)]) + c1 * Nv1i + c2 * Nv2i);
    }
    fcur = objective(p, g.data(), Ng.data());
  };
  if (o.sub_start && o.group) {  // at the start only: the warm start's ray scaling per group
    subspace();
    go = g, Ngo = Ng;
    fcur = objective(p, g.data(), Ng.data());
    res = residualOf(p, g.data(), Ng.data(), a, t);
    if (res < best_res && fcur <= f0) best_res = res, best = g;
  }
  int sub_every = o.sub_every;
  if (o.sub_cold_only && o.group) {
    bool cold = true;
    for (int k : *o.group)
      for (int j = 0; j < 3; ++j) cold = cold && g[size_t(3 * k + j)] == 0;
    if (!cold) sub_every = 0;
  }
  real theta = 1, beta = 0;
  Result R;
  if (!reachedStop(res, thr, 0, cx.min_it)) {
    int bt = 0;
    while (R.iterations < cx.cap) {
      for (int i = 0; i < n; ++i) {
        y[size_t(i)] = g[size_t(i)] + beta * (g[size_t(i)] - go[size_t(i)]);
        Ny[size_t(i)] = Ng[size_t(i)] + beta * (Ng[size_t(i)] - Ngo[size_t(i)]);
      }
      for (int k = 0; k < nb; ++k) {
        for (int j = 0; j < 3; ++j)
          gn[size_t(3 * k + j)] = y[size_t(3 * k + j)] - eta[k] / L * (Ny[size_t(3 * k + j)] + r[3 * k + j]);
        projectBlock(bs, k, &gn[size_t(3 * k)]);
      }
      p.schur(gn.data(), Ngn.data());
      double dNd = 0, dSd = 0;
      for (int k = 0; k < nb; ++k) {
        double dd = 0;
        for (int j = 0; j < 3; ++j) {
          const size_t i = size_t(3 * k + j);
          const double d = double(gn[i]) - y[i];
          dNd += d * (double(Ngn[i]) - Ny[i]);
          dd += d * d;
        }
        if (eta[k] > 0) dSd += dd / eta[k];
      }
      if (dNd > double(L) * dSd && bt < 60) {
        L *= 2;
        ++bt;
        continue;
      }
      bt = 0;
      ++R.iterations;
      double gdir = 0;
      for (int i = 0; i < n; ++i) gdir += double(Ny[size_t(i)] + r[i]) * (gn[size_t(i)] - g[size_t(i)]);
      const double fn = objective(p, gn.data(), Ngn.data());
      go.swap(g), Ngo.swap(Ng);
      g.swap(gn), Ng.swap(Ngn);
      bool restart = o.restart == Restart::Gradient ? gdir > 0 : fn > fcur;
      fcur = fn;
      // Gauss-Seidel polish / subspace step on g (then a momentum restart: the iterate jumped).
      if (o.polish_every > 0 && R.iterations % o.polish_every == 0) {
        grad.assign(Ng.begin(), Ng.end());
        for (int i = 0; i < n; ++i) grad[size_t(i)] += r[i];
        for (int s = 0; s < o.polish_sweeps; ++s) gs.sweep(p, g.data(), grad.data());
        R.sweeps += o.polish_sweeps;
        for (int i = 0; i < n; ++i) Ng[size_t(i)] = grad[size_t(i)] - r[i];
        fcur = objective(p, g.data(), Ng.data());
        restart = restart || o.jump_restart;
      }
      if (sub_every > 0 && R.iterations % sub_every == 0) {
        subspace();
        restart = restart || o.jump_restart;
      }
      res = residualOf(p, g.data(), Ng.data(), a, t);
      if (!std::isfinite(res)) break;
      if (res < best_res && fcur <= f0) best_res = res, best = g;
      if (reachedStop(res, thr, R.iterations, cx.min_it)) break;
      if (restart) {
        theta = 1, beta = 0;
        go = g, Ngo = Ng;  // y = g next
      } else {
        real tn, b;
        algo::ApgdControl::momentum(theta, tn, b);
        theta = tn, beta = b;
      }
      L *= real(0.9);
    }
  }
  gamma = best;
  R.rel = res0 > 0 ? best_res / res0 : 0;
  R.converged = R.rel <= cx.tol;
  return R;
}

// Mass-splitting Jacobi (Tonge et al. 2012): each body split into one sub-body per contact of mass m_i / n_i; a
// Jacobi sweep against the sub-bodies then an average of their velocities is the projected Jacobi step with the
// block steps of N computed from n_i M_i^-1 (the split problem's blockSteps), scalar (cone-preserving).
Result massSplitJacobi(const Problem& q, std::vector<real>& gamma, const Ctx& cx) {
  const CcpProblem& p = *q.p;
  const int n = p.size(), nb = n / 3;
  const real* eta = q.split->blockSteps();
  const real* r = p.rhs();
  SolverSettings ss;
  const real a = residualAlpha(p, ss);
  std::vector<real> t, g = gamma, Ng(static_cast<size_t>(n)), zero(static_cast<size_t>(n), real(0));
  startOf(p, g, Ng);
  const real res0 = residualOf(p, zero.data(), zero.data(), a, t);
  real res = residualOf(p, g.data(), Ng.data(), a, t);
  Result R;
  while (R.iterations < cx.cap && !reachedStop(res, cx.tol * res0, R.iterations, cx.min_it)) {
    for (int k = 0; k < nb; ++k) {
      for (int j = 0; j < 3; ++j) g[size_t(3 * k + j)] -= eta[k] * (Ng[size_t(3 * k + j)] + r[3 * k + j]);
      projectBlock(p.blockSet(), k, &g[size_t(3 * k)]);
    }
    p.schur(g.data(), Ng.data());
    res = residualOf(p, g.data(), Ng.data(), a, t);
    ++R.iterations;
    if (!std::isfinite(res)) break;
  }
  gamma = g;
  R.rel = res0 > 0 ? res / res0 : 0;
  R.converged = R.rel <= cx.tol;
  return R;
}

Result fromStats(const SolverStats& s, const Ctx& cx) {
  Result R;
  R.iterations = s.iterations;
  R.rel = s.relative_residual;
  R.converged = R.rel <= cx.tol;
  return R;
}
SolverSettings settingsOf(const Ctx& cx) {
  SolverSettings s;
  s.tolerance = cx.tol;
  s.min_iterations = cx.min_it;
  s.max_iterations = cx.cap;
  s.storage = VectorStorage::Real;
  return s;
}

using Method = std::function<Result(const Problem&, std::vector<real>&, const Ctx&)>;
struct Candidate {
  const char* name;
  Method run;
};

// The APGD variants of the study, named by what they add to apgdLocal's defaults: "+gsH" / "+gsA" a Gauss-Seidel
// polish every 50 iterations of the heavy blocks / of all blocks; "+sub" the two-group subspace step (group: the
// heavy blocks) every 10 iterations, "+sub0" once on the start; a trailing K: no momentum restart after a polish or
// subspace step; a trailing C: that, and the periodic subspace step only where the heavy group starts from zero.
Candidate apgdVariant(const char* name) {
  const std::string v = std::string(name).substr(std::string(name).find('+') + 1);
  return {name, [v](const Problem& q, std::vector<real>& g, const Ctx& cx) {
            ApgdOptions o;
            if (v.rfind("gs", 0) == 0) {
              o.polish_every = 50;
              if (v[2] == 'H') o.polish_blocks = &q.heavy_blocks;
            } else if (v == "sub0") {
              o.sub_start = true;
              o.group = &q.heavy_blocks;
            } else {
              o.sub_every = 10;
              o.group = &q.heavy_blocks;
              o.sub_cold_only = v.back() == 'C';
            }
            o.jump_restart = v.back() != 'K' && v.back() != 'C';
            return apgdLocal(*q.p, g, cx, o);
          }};
}

std::vector<Candidate> candidates() {
  std::vector<Candidate> c;
  c.push_back({"apgd", [](const Problem& q, std::vector<real>& g, const Ctx& cx) {
                 return fromStats(solveApgd(*q.p, g.data(), settingsOf(cx)), cx);
               }});
  c.push_back({"apgd-grad", [](const Problem& q, std::vector<real>& g, const Ctx& cx) {
                 return apgdLocal(*q.p, g, cx, ApgdOptions{});
               }});
  c.push_back({"apgd-fn", [](const Problem& q, std::vector<real>& g, const Ctx& cx) {
                 ApgdOptions o;
                 o.restart = Restart::Function;
                 return apgdLocal(*q.p, g, cx, o);
               }});
  c.push_back(apgdVariant("apgd+gsH"));
  c.push_back(apgdVariant("apgd+gsA"));
  c.push_back({"gs", [](const Problem& q, std::vector<real>& g, const Ctx& cx) {
                 return fromStats(q.p->solveGaussSeidel(g.data(), settingsOf(cx)), cx);
               }});
  c.push_back(
      {"msplit", [](const Problem& q, std::vector<real>& g, const Ctx& cx) { return massSplitJacobi(q, g, cx); }});
  c.push_back({"apgd-ms", [](const Problem& q, std::vector<real>& g, const Ctx& cx) {
                 ApgdOptions o;
                 o.eta = q.split->blockSteps();
                 return apgdLocal(*q.p, g, cx, o);
               }});
  c.push_back({"jac3x3", [](const Problem& q, std::vector<real>& g, const Ctx& cx) {
                 SolverSettings s = settingsOf(cx);
                 s.block_scaling = BlockScaling::Inverse3x3;
                 s.jacobi_omega = real(0.3);
                 return fromStats(solveJacobi(*q.p, g.data(), s), cx);
               }});
  c.push_back(apgdVariant("apgd+sub"));
  c.push_back(apgdVariant("apgd+subK"));
  c.push_back(apgdVariant("apgd+gsHK"));
  c.push_back(apgdVariant("apgd+subC"));
  c.push_back(apgdVariant("apgd+sub0"));
  c.push_back({"bb", [](const Problem& q, std::vector<real>& g, const Ctx& cx) {
                 return fromStats(solveBB(*q.p, g.data(), settingsOf(cx)), cx);
               }});
  return c;
}

// ---------------------------------------------------------------- a System whose Solve stage a candidate replaces
class StudySystem : public System {
 public:
  using System::System;
  Method method;  // null: the library's solver at config().solver
  Ctx ctx;
  int heavy = -1;
  std::vector<int64_t> capture_at;  // steps whose CCP to keep
  std::vector<Problem> captured;
  int64_t iterations = 0, missed = 0, max_it = 0;
  double solve_seconds = 0;

 protected:
  void buildAndSolve() override {
    const SolverSettings keep = config_.solver;
    config_.solver.max_iterations = 0;  // build, warm start, scaled start only
    config_.solver.tolerance = 0;
    System::buildAndSolve();
    config_.solver = keep;
    const int64_t nc = int64_t(contacts_.count());
    if (nc == 0) return;
    if (problem_->normalOnly() || !rows_.empty()) throw std::runtime_error("study: a normal-only problem or rows");
    if (std::find(capture_at.begin(), capture_at.end(), steps_) != capture_at.end()) capture();
    Problem q;
    q.p = std::shared_ptr<ContactProblem>(problem_.get(), [](ContactProblem*) {});
    q.heavy = heavy;
    q.heavy_blocks = heavyBlocks();
    q.nbodies = int(bodies_.count());
    if (method) q.split = splitProblem();
    const auto t0 = std::chrono::steady_clock::now();
    Result R;
    if (method) {
      R = method(q, gamma_, ctx);
    } else {
      R = fromStats(solveApgd(*problem_, gamma_.data(), config_.solver), ctx);
    }
    solve_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    iterations += R.iterations;
    max_it = std::max<int64_t>(max_it, R.iterations);
    missed += R.converged ? 0 : 1;
    // the next step's warm start, as System::buildAndSolve keeps it
    std::vector<size_t> order(static_cast<size_t>(nc));
    std::iota(order.begin(), order.end(), size_t(0));
    std::sort(order.begin(), order.end(), [&](size_t x, size_t y) { return contacts_.key[x] < contacts_.key[y]; });
    for (size_t i = 0; i < size_t(nc); ++i) {
      prev_keys_[i] = contacts_.key[order[i]];
      for (int r = 0; r < 3; ++r) prev_gamma_[3 * i + r] = gamma_[3 * order[i] + r];
    }
  }

 private:
  std::vector<int> heavyBlocks() const {
    std::vector<int> b;
    for (size_t k = 0; k < contacts_.count(); ++k)
      if (contacts_.body_a[k] == heavy || contacts_.body_b[k] == heavy) b.push_back(int(k));
    return b;
  }
  std::shared_ptr<ContactProblem> splitProblem() const {
    BodyArrays b = bodies_;
    std::vector<int> count(b.count(), 0);
    for (size_t k = 0; k < contacts_.count(); ++k)
      ++count[size_t(contacts_.body_a[k])], ++count[size_t(contacts_.body_b[k])];
    for (size_t i = 0; i < b.count(); ++i) {
      const real m = real(std::max(1, count[i]));
      b.inv_mass[i] *= m;
      b.inv_inertia[i] = b.inv_inertia[i] * m;
    }
    ContactProblemSettings ps;
    ps.threads = 1;
    auto sp = std::make_shared<ContactProblem>();
    sp->build(b, contacts_, v_free_.data(), w_free_.data(), stepContext(), config_.solver, ps);
    return sp;
  }
  void capture() {
    Problem q;
    q.p = std::make_shared<ContactProblem>(*problem_);
    q.split = splitProblem();
    q.warm = gamma_;  // the scaled projected warm start (a zero-iteration solve)
    q.heavy = heavy;
    q.heavy_blocks = heavyBlocks();
    q.nbodies = int(bodies_.count());
    q.vfree_heavy = v_free_[size_t(heavy)];
    q.h = real(config_.step.dt);
    captured.push_back(std::move(q));
  }
};

struct Scene {
  std::string name;
  bool particles;
  double ratio;
  double unit;  // the length the position error is given in (r, or a mm)
  const char* unit_name;
};

// Builds the scene into s, returns the heavy body.
int build(const Scene& sc, StudySystem& s) {
  s.addBody(groundPlane(real(0.7)));
  if (!sc.particles) {
    const real a = real(0.05);
    int top = -1;
    for (int i = 0; i < 10; ++i)
      top =
          s.addBody(cube(a, i == 9 ? real(sc.ratio) : real(1), Vec3{0, real(a * (1.0002 + 2.0002 * i)), 0}, real(0.7)));
    return top;
  }
  return testbodies::addParticleBox(s, sc.ratio);
}

SystemConfig configOf(const Scene& sc) {
  SystemConfig cfg;
  cfg.step.dt = real(sc.particles ? 1e-3 : 1e-2);
  cfg.solver.storage = VectorStorage::Real;
  return cfg;
}

std::vector<Scene> scenes() {
  return {{"particles 1e2", true, 1e2, 0.01, "r"},
          {"particles 1e4", true, 1e4, 0.01, "r"},
          {"particles 1e6", true, 1e6, 0.01, "r"},
          {"stack 1e3", false, 1e3, 1e-3, "mm"},
          {"stack 1e6", false, 1e6, 1e-3, "mm"}};
}

bool selected(const char* what, const char* env) {
  const char* s = std::getenv(env);
  return !s || std::string(s).find(what) != std::string::npos;
}

}  // namespace

// (1) Snapshots: iterations and time to 1e-1 / 1e-2 / 1e-3 from the same warm start.
// DVISIM_STUDY_SCENES / DVISIM_STUDY_METHODS: substrings selecting scenes / candidates.
TEST_CASE("study: mass-ratio CCP snapshots, iterations and time to 1e-1, 1e-2, 1e-3", "[.study]") {
  const auto cands = candidates();
  for (const Scene& sc : scenes()) {
    if (!selected(sc.name.c_str(), "DVISIM_STUDY_SCENES")) continue;
    StudySystem sys(configOf(sc));
    sys.heavy = build(sc, sys);
    const int steps = sc.particles ? 500 : 150;
    sys.capture_at = {0, steps - 1};
    sys.advance(steps);
    REQUIRE(sys.captured.size() == 2);
    for (const Problem& q : sys.captured) {
      const int64_t step = &q == &sys.captured[0] ? 1 : steps;
      // the exact CCP solution: the library's APGD to 1e-11 (checked against Gauss-Seidel's objective)
      std::vector<real> ref = q.warm;
      Ctx rc;
      rc.tol = real(1e-11);
      rc.cap = 400000;
      const Result rr = fromStats(solveApgd(*q.p, ref.data(), settingsOf(rc)), rc);
      const Vec3 vref = heavyVelocity(q, ref);
      std::printf(
          "\n%s, step %lld: %d contacts (%zu on the heavy body), reference relative residual %.2e after %d "
          "iterations, heavy body v_ref.y %.3e m/s\n",
          sc.name.c_str(), (long long)step, q.p->size() / 3, q.heavy_blocks.size(), double(rr.rel), rr.iterations,
          double(vref.y));
      std::printf("  %-10s | %-34s | %-34s | %-34s\n", "method", "1e-1: it, ms, rel, err", "1e-2: it, ms, rel, err",
                  "1e-3: it, ms, rel, err");
      for (const Candidate& c : cands) {
        if (!selected(c.name, "DVISIM_STUDY_METHODS")) continue;
        std::printf("  %-10s", c.name);
        for (double tol : {1e-1, 1e-2, 1e-3}) {
          Ctx cx;
          cx.tol = real(tol);
          cx.cap = 20000;
          std::vector<real> g;
          Result R;
          double best_ms = 1e30;
          for (int rep = 0; rep < 3; ++rep) {  // the fastest of 3 (a shared machine)
            g = q.warm;
            const auto t0 = std::chrono::steady_clock::now();
            R = c.run(q, g, cx);
            best_ms =
                std::min(best_ms, 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
            if (best_ms > 200) break;
          }
          const Vec3 v = heavyVelocity(q, g);
          const double err = double(q.h) * double(length(v - vref)) / sc.unit;
          char cell[64];
          if (R.sweeps)
            std::snprintf(cell, sizeof cell, "%d+%ds %.2f %.1e %.1e%s", R.iterations, R.sweeps, best_ms, double(R.rel),
                          err, R.converged ? "" : "!");
          else
            std::snprintf(cell, sizeof cell, "%d %.2f %.1e %.1e%s", R.iterations, best_ms, double(R.rel), err,
                          R.converged ? "" : "!");
          std::printf(" | %-34s", cell);
        }
        std::printf("\n");
        std::fflush(stdout);
      }
    }
    std::printf("  (err: h |v_H - v_H(exact)| in %s; !: not reached within 20000)\n", sc.unit_name);
  }
}

// (2) Full runs at the product's stop (0.1, at least 50, at most 1000) with each candidate as the solver.
TEST_CASE("study: mass-ratio runs at the default stop with each candidate", "[.study]") {
  const auto cands = candidates();
  for (const Scene& sc : scenes()) {
    if (!selected(sc.name.c_str(), "DVISIM_STUDY_SCENES")) continue;
    for (const Candidate& c : cands) {
      if (!selected(c.name, "DVISIM_STUDY_METHODS")) continue;
      StudySystem sys(configOf(sc));
      sys.heavy = build(sc, sys);
      sys.method = c.run;
      sys.ctx.tol = kDefaultTolerance;
      sys.ctx.min_it = kDefaultMinIterations;
      sys.ctx.cap = kDefaultMaxIterations;
      const double y0 = double(sys.bodies().pos[size_t(sys.heavy)].y);
      const int steps = sc.particles ? 1000 : 300;
      double pen = 0;
      for (int k = 0; k < steps; ++k) {
        sys.step();
        pen = std::max(pen, double(sys.lastStats().max_penetration));
      }
      const double dy = double(sys.bodies().pos[size_t(sys.heavy)].y) - y0;
      std::printf("run %-14s %-10s it %6.1f/%4lld missed %4lld/%d  heavy dy %+.2e %s  pen %.1e %s  solve %.3f s\n",
                  sc.name.c_str(), c.name, double(sys.iterations) / steps, (long long)sys.max_it, (long long)sys.missed,
                  steps, dy / sc.unit, sc.unit_name, pen / sc.unit, sc.unit_name, sys.solve_seconds);
      std::fflush(stdout);
    }
  }
}
