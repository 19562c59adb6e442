// Slow dense reference for the solver tests, written independently of the code under test (it uses no
// function of cone.h, jacobian.h, contact_problem.cpp or solver.cpp): dense D, M^-1 and N = D^T M^-1 D
// formed explicitly from the definitions in contact_problem.h, a dense projected block Gauss-Seidel with
// exact block solves, and a KKT certificate that checks a solution directly against the CCP conditions.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "chrono_like/base/data.h"
#include "chrono_like/base/math.h"
#include "chrono_like/solver/solver.h"

namespace refsolver {

using Dense = std::vector<double>;  // row-major

// Projection onto {(a, t) : |t| <= mu a}, in the (a, |t|) half plane: the cone's boundary ray is
// e = (1, mu) / sqrt(1 + mu^2); a point above the ray projects onto it (or onto 0 when its component
// along e is negative), a point below the ray (t <= mu a) is inside.
inline void cone(double mu, double* g) {
  const double t = std::hypot(g[1], g[2]);
  if (mu <= 0) {
    g[0] = std::max(g[0], 0.0);
    g[1] = g[2] = 0;
    return;
  }
  if (t <= mu * g[0]) return;
  const double along = (g[0] + mu * t) / std::sqrt(1 + mu * mu);  // component along e
  if (along <= 0) {
    g[0] = g[1] = g[2] = 0;
    return;
  }
  const double a = along / std::sqrt(1 + mu * mu), tn = mu * a;
  g[0] = a;
  g[1] *= tn / t;
  g[2] *= tn / t;
}

struct DenseCcp {
  int n = 0;  // unknowns (3 per contact)
  Dense N;    // n x n
  std::vector<double> r, mu;

  std::vector<double> mul(const std::vector<double>& x) const {
    std::vector<double> y(n, 0.0);
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j) y[i] += N[size_t(i) * n + j] * x[j];
    return y;
  }
  double objective(const std::vector<double>& x) const {
    std::vector<double> y = mul(x);
    double f = 0;
    for (int i = 0; i < n; ++i) f += x[i] * (0.5 * y[i] + r[i]);
    return f;
  }
};

// Dense D (6 nb x 3 nc) and M^-1 (6 nb x 6 nb) from the definitions, then N and r.
inline DenseCcp denseFromScene(const dvi::BodyArrays& bodies, const dvi::ContactArrays& c, const dvi::Vec3* vf,
                               const dvi::Vec3* wf, double h, double recovery_rel) {
  const int nb = int(bodies.count()), nc = int(c.count());
  const int R = 6 * nb, C = 3 * nc;
  Dense D(size_t(R) * C, 0.0), Minv(size_t(R) * R, 0.0);
  for (int i = 0; i < nb; ++i) {
    const bool fixed = bodies.flags[i] & (dvi::kBodyFixed | dvi::kBodyKinematic);
    if (fixed) continue;
    for (int j = 0; j < 3; ++j) Minv[size_t(6 * i + j) * R + 6 * i + j] = bodies.inv_mass[i];
    dvi::Mat33 Rm = dvi::matFromQuat(bodies.rot[i]);
    const double Rr[3][3] = {{Rm.r0.x, Rm.r0.y, Rm.r0.z}, {Rm.r1.x, Rm.r1.y, Rm.r1.z}, {Rm.r2.x, Rm.r2.y, Rm.r2.z}};
    const double d[3] = {bodies.inv_inertia[i].x, bodies.inv_inertia[i].y, bodies.inv_inertia[i].z};
    for (int p = 0; p < 3; ++p)
      for (int q = 0; q < 3; ++q) {
        double s = 0;
        for (int m = 0; m < 3; ++m) s += Rr[p][m] * d[m] * Rr[q][m];
        Minv[size_t(6 * i + 3 + p) * R + 6 * i + 3 + q] = s;
      }
  }
  DenseCcp P;
  P.n = C;
  P.r.assign(C, 0.0);
  P.mu.assign(nc, 0.0);
  for (int k = 0; k < nc; ++k) {
    dvi::Vec3 n = c.normal[k], u, w;
    dvi::tangentBasis(n, u, w);
    const dvi::Vec3 dir[3] = {n, u, w};
    const int a = c.body_a[k], b = c.body_b[k];
    const dvi::Vec3 rA = c.pa[k] - bodies.pos[a], rB = c.pb[k] - bodies.pos[b];
    for (int j = 0; j < 3; ++j) {
      const int col = 3 * k + j;
      const dvi::Vec3 cA = dvi::cross(rA, dir[j]), cB = dvi::cross(rB, dir[j]);
      const double colA[6] = {-dir[j].x, -dir[j].y, -dir[j].z, -cA.x, -cA.y, -cA.z};
      const double colB[6] = {dir[j].x, dir[j].y, dir[j].z, cB.x, cB.y, cB.z};
      for (int m = 0; m < 6; ++m) {
        D[size_t(6 * a + m) * C + col] += colA[m];
        D[size_t(6 * b + m) * C + col] += colB[m];
      }
      // r = D^T v_free + b
      double s = 0;
      const double va[6] = {vf[a].x, vf[a].y, vf[a].z, wf[a].x, wf[a].y, wf[a].z};
      const double vb[6] = {vf[b].x, vf[b].y, vf[b].z, wf[b].x, wf[b].y, wf[b].z};
      for (int m = 0; m < 6; ++m) s += colA[m] * va[m] + colB[m] * vb[m];
      P.r[col] = s;
    }
    P.r[3 * k] += std::max(double(c.dist[k]) / h, -recovery_rel * double(c.size[k]));
    P.mu[k] = c.mu[k];
  }
  // N = D^T (M^-1 D)
  Dense MD(size_t(R) * C, 0.0);
  for (int i = 0; i < R; ++i)
    for (int m = 0; m < R; ++m) {
      const double v = Minv[size_t(i) * R + m];
      if (v == 0) continue;
      for (int j = 0; j < C; ++j) MD[size_t(i) * C + j] += v * D[size_t(m) * C + j];
    }
  P.N.assign(size_t(C) * C, 0.0);
  for (int i = 0; i < C; ++i)
    for (int j = 0; j < C; ++j) {
      double s = 0;
      for (int m = 0; m < R; ++m) s += D[size_t(m) * C + i] * MD[size_t(m) * C + j];
      P.N[size_t(i) * C + j] = s;
    }
  return P;
}

// Dense projected block Gauss-Seidel with (nearly) exact block solves: for each contact, repeat the block's
// projected gradient step, step 1 / (Frobenius norm of the block) <= 1 / lambda_max, until the block stops
// moving, then go to the next. Runs until a whole sweep changes nothing above tol.
inline std::vector<double> solve(const DenseCcp& P, double tol = 1e-13, int max_sweeps = 200000) {
  const int n = P.n, nc = n / 3;
  std::vector<double> g(n, 0.0);
  for (int sweep = 0; sweep < max_sweeps; ++sweep) {
    double change = 0, scale = 1e-300;
    for (int k = 0; k < nc; ++k) {
      double fro = 0;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
          fro += P.N[size_t(3 * k + i) * n + 3 * k + j] * P.N[size_t(3 * k + i) * n + 3 * k + j];
      fro = std::sqrt(fro);
      if (fro <= 0) continue;
      const double t = 1.0 / fro;  // Frobenius norm >= lambda_max
      // c = (N g + r)_k without the block's own contribution
      double c[3];
      for (int i = 0; i < 3; ++i) {
        double s = P.r[3 * k + i];
        for (int j = 0; j < n; ++j)
          if (j / 3 != k) s += P.N[size_t(3 * k + i) * n + j] * g[j];
        c[i] = s;
      }
      double x[3] = {g[3 * k], g[3 * k + 1], g[3 * k + 2]};
      for (int inner = 0; inner < 2000; ++inner) {
        double y[3];
        for (int i = 0; i < 3; ++i) {
          double s = c[i];
          for (int j = 0; j < 3; ++j) s += P.N[size_t(3 * k + i) * n + 3 * k + j] * x[j];
          y[i] = x[i] - t * s;
        }
        cone(P.mu[k], y);
        double dm = 0;
        for (int i = 0; i < 3; ++i) dm = std::max(dm, std::fabs(y[i] - x[i])), x[i] = y[i];
        if (dm <= 1e-17 * (1 + std::fabs(x[0]))) break;
      }
      for (int i = 0; i < 3; ++i) {
        change = std::max(change, std::fabs(x[i] - g[3 * k + i]));
        scale = std::max(scale, std::fabs(x[i]));
        g[3 * k + i] = x[i];
      }
    }
    if (change <= tol * scale) break;
  }
  return g;
}

// KKT violation of g for the CCP: g in K, u = N g + r in K* = {u_n >= mu |u_t|}, g_k . u_k = 0 per contact.
// Returns the largest violation, each relative to the size of the quantities involved.
inline double kktViolation(const DenseCcp& P, const std::vector<double>& g) {
  const std::vector<double> Ng = P.mul(g);
  double gs = 1e-300, us = 1e-300;
  // velocities are measured against the larger of |N g| and |r| (u itself is ~0 at a resting contact)
  for (int i = 0; i < P.n; ++i)
    gs = std::max(gs, std::fabs(g[i])), us = std::max(us, std::max(std::fabs(Ng[i]), std::fabs(P.r[i])));
  double v = 0;
  for (int k = 0; k < P.n / 3; ++k) {
    const double* x = &g[3 * k];
    const double u[3] = {Ng[3 * k] + P.r[3 * k], Ng[3 * k + 1] + P.r[3 * k + 1], Ng[3 * k + 2] + P.r[3 * k + 2]};
    const double mu = P.mu[k];
    v = std::max(v, (std::hypot(x[1], x[2]) - mu * x[0]) / gs);  // primal cone
    if (mu > 0)
      v = std::max(v, (mu * std::hypot(u[1], u[2]) - u[0]) / us);  // dual cone
    else
      v = std::max(v, -u[0] / us);
    v = std::max(v, std::fabs(x[0] * u[0] + x[1] * u[1] + x[2] * u[2]) / (gs * us));
  }
  return v;
}

// A CcpProblem over a dense N, for solver tests that do not go through ContactProblem.
class DenseProblem final : public dvi::CcpProblem {
 public:
  explicit DenseProblem(const DenseCcp& P, int threads = 1) : P_(P), threads_(threads) {
    const int nc = P.n / 3;
    r_.assign(P.r.begin(), P.r.end());
    mu_.assign(P.mu.begin(), P.mu.end());
    eta_.assign(nc, 0);
    binv_.assign(9 * size_t(nc), 0);
    binv6_.clear();
    maxd_ = 0;
    for (int k = 0; k < nc; ++k) {
      double b[3][3], row = 0;
      for (int i = 0; i < 3; ++i) {
        double rs = 0;
        for (int j = 0; j < 3; ++j) b[i][j] = P.N[size_t(3 * k + i) * P.n + 3 * k + j], rs += std::fabs(b[i][j]);
        row = std::max(row, rs);
        maxd_ = std::max(maxd_, b[i][i]);
      }
      eta_[k] = row > 0 ? 1 / row : 0;
      // inverse by Cramer's rule
      const double det = b[0][0] * (b[1][1] * b[2][2] - b[1][2] * b[2][1]) -
                         b[0][1] * (b[1][0] * b[2][2] - b[1][2] * b[2][0]) +
                         b[0][2] * (b[1][0] * b[2][1] - b[1][1] * b[2][0]);
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          const int i1 = (j + 1) % 3, i2 = (j + 2) % 3, j1 = (i + 1) % 3, j2 = (i + 2) % 3;
          binv_[9 * size_t(k) + 3 * i + j] = (b[i1][j1] * b[i2][j2] - b[i1][j2] * b[i2][j1]) / det;
        }
      const double* B = &binv_[9 * size_t(k)];
      const double sym[6] = {B[0], B[4], B[8], 0.5 * (B[1] + B[3]), 0.5 * (B[2] + B[6]), 0.5 * (B[5] + B[7])};
      for (int e = 0; e < 6; ++e) binv6_.push_back(dvi::real(sym[e]));
    }
  }
  int size() const override { return P_.n; }
  const dvi::real* rhs() const override { return r_.data(); }
  void schur(const dvi::real* x, dvi::real* y) const override {
    for (int i = 0; i < P_.n; ++i) {
      double s = 0;
      for (int j = 0; j < P_.n; ++j) s += P_.N[size_t(i) * P_.n + j] * x[j];
      y[i] = s;
    }
  }
  dvi::BlockSet blockSet() const override { return dvi::BlockSet{P_.n / 3, mu_.data(), nullptr, nullptr}; }
  // N_kk^-1 in the solver's symmetric storage [00, 11, 22, 01, 02, 12] (from the full Cramer inverse).
  const dvi::real* blockInverses() const override { return binv6_.data(); }
  int threads() const override { return threads_; }
  const dvi::real* blockSteps() const override { return eta_.data(); }
  dvi::real maxDiagonal() const override { return maxd_; }

 private:
  DenseCcp P_;
  int threads_;
  std::vector<dvi::real> r_, mu_, eta_, binv6_;
  std::vector<double> binv_;
  double maxd_;
};

}  // namespace refsolver
