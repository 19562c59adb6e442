// The ionised field of the corona wire: conformal-grid solver and Cartesian sampling (see field_corona.h
// and docs/CES_FIELD.md for the model and the references).
#include "ces/field/field_corona.h"

#include <eigen3/Eigen/Sparse>
#include <eigen3/Eigen/SparseCholesky>
#include <eigen3/Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <complex>
#include <memory>
#include <numeric>
#include <string>
#include <utility>

#include "chrono_like/base/errors.h"

namespace dvi {
namespace ces {

namespace {
using cplx = std::complex<double>;
constexpr double kPiD = 3.14159265358979323846;
constexpr double kShapeGain = 4.0;

bool finite(real v) { return std::isfinite(double(v)); }

// f(w) and f'(w) of the map in its local frame (before the rotation and the shift).
void localMap(const ConformalMap& m, double sigma, double tau, cplx& f, cplx& fp) {
  const cplx w(sigma, tau);
  if (m.kind == ConformalMap::Bipolar) {
    const cplx u = std::exp(cplx(0, 1) * w);  // e^{iw} = e^{-tau} e^{i sigma}
    const cplx one_m_u = 1.0 - u;
    f = double(m.a) * (1.0 + u) / one_m_u;
    fp = 2.0 * double(m.a) * cplx(0, 1) * u / (one_m_u * one_m_u);
  } else {
    f = std::exp(-cplx(0, 1) * w);  // e^{tau - i sigma}
    fp = -cplx(0, 1) * f;
  }
}
// The inverse map w(z) and, at the same point, e^{i theta} f'(w) (re, im), in real arithmetic. With
// zeta = e^{-i theta} (z - origin): bipolar u = e^{iw} = (zeta - a) / (zeta + a) and, since
// 1 - u = 2a / (zeta + a), f'(w) = 2a i u / (1 - u)^2 = i (zeta^2 - a^2) / (2a); log-polar f = zeta,
// f' = -i zeta.
void inverseMap(const ConformalMap& m, double x, double y, double& sigma, double& tau, double& dre, double& dim) {
  const double X = x - double(m.ox), Y = y - double(m.oy), ct = m.ct, st = m.st;
  const double zr = ct * X + st * Y, zi = ct * Y - st * X;
  double fr, fi;
  if (m.kind == ConformalMap::Bipolar) {
    const double a = m.a;
    const double dd = (zr + a) * (zr + a) + zi * zi;
    const double ur = ((zr - a) * (zr + a) + zi * zi) / dd, ui = 2 * a * zi / dd;
    sigma = std::atan2(ui, ur);
    tau = -0.5 * std::log(ur * ur + ui * ui);
    fr = -zr * zi / a;
    fi = ((zr - a) * (zr + a) - zi * zi) / (2 * a);
  } else {
    sigma = -std::atan2(zi, zr);
    tau = 0.5 * std::log(zr * zr + zi * zi);
    fr = zi;
    fi = -zr;
  }
  dre = ct * fr - st * fi;
  dim = ct * fi + st * fr;
}
}  // namespace

// ------------------------------------------------------------------------------------------------
// ConformalMap

ConformalMap ConformalMap::bipolar(real dcx, real dcy, real dR, real wcx, real wcy, real wr) {
  if (!(dR > 0) || !(wr > 0) || !finite(dcx) || !finite(dcy) || !finite(wcx) || !finite(wcy) || !finite(dR) ||
      !finite(wr))
    throw InputError("corona grid: drum and wire radii must be positive and all values finite");
  const double D = std::hypot(double(wcx) - dcx, double(wcy) - dcy);
  if (!(D > double(dR) + wr)) throw InputError("corona grid: the wire must lie outside the drum");
  // Foci: the common inverse points of both circles (field_two_cylinder.h derives the same construction):
  // h1 = (D^2 + R^2 - r^2) / (2D) from the drum centre, a = sqrt(h1^2 - R^2).
  const double h1 = (D * D + double(dR) * dR - double(wr) * wr) / (2 * D);
  const double a = std::sqrt((h1 - dR) * (h1 + dR));
  ConformalMap m;
  m.kind = Bipolar;
  m.a = real(a);
  m.ct = real((wcx - dcx) / D);
  m.st = real((wcy - dcy) / D);
  m.ox = real(dcx + h1 * m.ct);
  m.oy = real(dcy + h1 * m.st);
  m.tau_wire = real(std::asinh(a / wr));  // circle radius a / sinh(tau)
  m.tau_drum = real(-std::asinh(a / dR));
  return m;
}

ConformalMap ConformalMap::logPolar(real cx, real cy, real R, real r0) {
  if (!(r0 > 0) || !(R > r0) || !finite(cx) || !finite(cy) || !finite(R))
    throw InputError("corona grid: coaxial radii must satisfy 0 < wire radius < cylinder radius");
  ConformalMap m;
  m.kind = LogPolar;
  m.ox = cx;
  m.oy = cy;
  m.tau_drum = real(std::log(double(R)));
  m.tau_wire = real(std::log(double(r0)));
  return m;
}

void ConformalMap::toPhysical(real sigma, real tau, real& x, real& y) const {
  cplx f, fp;
  localMap(*this, sigma, tau, f, fp);
  const cplx z = cplx(ox, oy) + cplx(ct, st) * f;
  x = real(z.real());
  y = real(z.imag());
}

void ConformalMap::toComputational(real x, real y, real& sigma, real& tau) const {
  double s, t, dr, di;
  inverseMap(*this, x, y, s, t, dr, di);
  sigma = real(s);
  tau = real(t);
}

void ConformalMap::derivative(real sigma, real tau, real& re, real& im) const {
  cplx f, fp;
  localMap(*this, sigma, tau, f, fp);
  const cplx d = cplx(ct, st) * fp;
  re = real(d.real());
  im = real(d.imag());
}

real ConformalMap::scale(real sigma, real tau) const {
  real re, im;
  derivative(sigma, tau, re, im);
  return real(std::hypot(double(re), double(im)));
}

// ------------------------------------------------------------------------------------------------
// The coupled solver.
//
// Unknowns in the ion-potential convention psi = -s phi (s = sign U): ions move up the gradient of psi,
// psi = 0 on the drum, -|U| on the wire and the tube, and lap_w psi = h^2 |rho| / eps0 >= 0.
// Poisson: 5-point finite volumes on the uniform (sigma, tau) grid (the conformal map makes the operator
// the plain Laplacian), Dirichlet faces at half a cell on the drum and wire rows, tube cells as Dirichlet
// neighbours, periodic in sigma; the charge of a cell is |rho| h^2 dsigma dtau. The matrix does not change
// during the iteration: one sparse Cholesky factorisation (Eigen SimplicialLDLT), then solves.
// Continuity: first-order upwind finite volumes. The flux through the face between cells P and Q (in
// computational units; no metric factor appears since the physical face length h dl and the physical
// normal field |grad psi| / h multiply to the computational ones) is mu rho_up c (psi_Q - psi_P) with
// c = face length / centre distance, rho_up that of the cell with the lower psi. Ordered by increasing
// psi, every cell's inflow comes from cells already visited, so one sweep in that order solves the upwind
// system exactly (a triangular system).
// Kaptzov: for a fixed transport pattern rho = rho0 * rhohat is linear in the injection density rho0 and so
// is the space-charge potential; rho0 is set so that the mean surface field of the wire (its charge per
// 2 pi r eps0) equals E_on; the new space-charge potential and injection profile are mixed with the
// previous iterates (Anderson acceleration, damped by the relaxation) and the transport redone until the
// potential stops changing.
namespace {

struct Grid {
  int ns, nt;
  double ds, dt, adt;  // dt signed (tau_wire - tau_drum) / nt
  double cs, ctau;     // face coefficients: sigma faces |dt|/ds, tau faces ds/|dt|
  const ConformalMap* map;
  int idx(int i, int j) const { return j * ns + i; }
  int wrap(int i) const { return (i + ns) % ns; }
  double sigma(int i) const { return -kPiD + (i + 0.5) * ds; }
  double tau(int j) const { return double(map->tau_drum) + (j + 0.5) * dt; }
};

// Ion transport for a given psi (per cell; tube cells hold -|U|) and injection density rho0: fills rho and
// the currents (in units of rho * V, to be multiplied by the mobility).
struct Currents {
  double injected = 0, drum = 0, far = 0, tube = 0, trapped = 0;
};

Currents sweep(const Grid& g, const std::vector<double>& psi, const std::vector<uint8_t>& kind, double psiWire,
               double rho0, const std::vector<double>& shape, const std::vector<int>& order, std::vector<double>& rho,
               std::vector<double>& inflow) {
  Currents c;
  const int n = g.ns * g.nt;
  rho.assign(n, 0.0);
  inflow.assign(n, 0.0);
  const double cb = 2 * g.ctau;  // half-cell boundary faces
  for (int i = 0; i < g.ns; ++i) {
    const int p = g.idx(i, g.nt - 1);
    if (kind[p] == 1) continue;
    const double f = rho0 * shape[i] * cb * std::max(0.0, psi[p] - psiWire);
    inflow[p] += f;
    c.injected += f;
  }
  for (int p : order) {
    const double in = inflow[p];
    if (kind[p] == 2) {  // far-field sink
      c.far += in;
      continue;
    }
    const int i = p % g.ns, j = p / g.ns;
    const double pp = psi[p];
    int nb[4] = {g.idx(g.wrap(i - 1), j), g.idx(g.wrap(i + 1), j), j > 0 ? g.idx(i, j - 1) : -1,
                 j < g.nt - 1 ? g.idx(i, j + 1) : -2};
    double coef[4], dpsi[4];
    double out = 0;
    for (int k = 0; k < 4; ++k) {
      const double cf = k < 2 ? g.cs : (nb[k] >= 0 ? g.ctau : cb);
      const double pn = nb[k] >= 0 ? psi[nb[k]] : (nb[k] == -1 ? 0.0 : psiWire);
      dpsi[k] = pn - pp;
      coef[k] = cf;
      if (dpsi[k] > 0) out += cf * dpsi[k];
    }
    if (!(out > 0)) {
      c.trapped += in;
      continue;
    }
    const double r = in / out;
    rho[p] = r;
    for (int k = 0; k < 4; ++k) {
      if (!(dpsi[k] > 0)) continue;
      const double f = r * coef[k] * dpsi[k];
      if (nb[k] == -1)
        c.drum += f;
      else if (nb[k] == -2 || kind[nb[k]] == 1)
        c.tube += f;
      else
        inflow[nb[k]] += f;
    }
  }
  return c;
}

// Anderson acceleration (type II) of a fixed-point iteration x <- g(x) with the residual f = g(x) - x:
// with dX, dF the differences of the last m iterates and residuals,
//   gamma = argmin |f_k - dF gamma|_2,  x_{k+1} = x_k + B f_k - (dX + B dF) gamma,
// B a diagonal damping (m = 0 is the plain damped iteration). D. G. Anderson, "Iterative procedures for
// nonlinear integral equations", J. ACM 12 (1965) 547-560; H. F. Walker, P. Ni, "Anderson acceleration for
// fixed-point iterations", SIAM J. Numer. Anal. 49 (2011) 1715-1735. The small least-squares problem is
// solved through its normal equations (m <= kAndersonDepth), in a fixed order: the result does not depend
// on the thread count.
constexpr int kAndersonDepth = 5;
class AndersonMixer {
 public:
  AndersonMixer(size_t n, int depth) : n_(n), depth_(depth) {}
  void reset() {
    dX_.clear();
    dF_.clear();
    have_ = false;
  }
  void step(std::vector<double>& x, const std::vector<double>& f, const std::vector<double>& beta) {
    if (have_) {
      if (int(dX_.size()) == depth_) {
        dX_.erase(dX_.begin());
        dF_.erase(dF_.begin());
      }
      std::vector<double> dx(n_), df(n_);
      for (size_t k = 0; k < n_; ++k) {
        dx[k] = x[k] - xPrev_[k];
        df[k] = f[k] - fPrev_[k];
      }
      dX_.push_back(std::move(dx));
      dF_.push_back(std::move(df));
    }
    xPrev_ = x;
    fPrev_ = f;
    have_ = true;
    const int m = int(dX_.size());
    Eigen::VectorXd gamma = Eigen::VectorXd::Zero(m);
    if (m > 0) {
      Eigen::MatrixXd G(m, m);
      Eigen::VectorXd rhs(m);
      for (int a = 0; a < m; ++a) {
        for (int b = 0; b <= a; ++b) {
          double d = 0;
          for (size_t k = 0; k < n_; ++k) d += dF_[a][k] * dF_[b][k];
          G(a, b) = G(b, a) = d;
        }
        double d = 0;
        for (size_t k = 0; k < n_; ++k) d += dF_[a][k] * f[k];
        rhs(a) = d;
      }
      // Tikhonov regularisation against nearly dependent differences.
      const double reg = 1e-10 * G.trace() / m;
      for (int a = 0; a < m; ++a) G(a, a) += reg;
      gamma = G.ldlt().solve(rhs);
      if (!gamma.allFinite()) gamma.setZero();
    }
    for (size_t k = 0; k < n_; ++k) {
      double v = x[k] + beta[k] * f[k];
      for (int a = 0; a < m; ++a) v -= gamma(a) * (dX_[a][k] + beta[k] * dF_[a][k]);
      x[k] = v;
    }
  }

 private:
  size_t n_;
  int depth_;
  bool have_ = false;
  std::vector<double> xPrev_, fPrev_;
  std::vector<std::vector<double>> dX_, dF_;
};

// Derivative at 0 of the parabola through (-h1, fa), (0, f0), (h2, fb).
double d3(double fa, double f0, double fb, double h1, double h2) {
  return (h1 * h1 * fb - h2 * h2 * fa + (h2 * h2 - h1 * h1) * f0) / (h1 * h2 * (h1 + h2));
}

// The steady corona solve of one problem (solveConformalCorona runs its stages in order): the grid, the
// unknown numbering, the factorised Poisson matrix and the Laplace field, shared by the space-charge
// iteration and the sampling table. Potentials in the psi convention (see above).
class ConformalSolver {
 public:
  explicit ConformalSolver(const ConformalCoronaProblem& p) : p_(p) {}
  ConformalCoronaResult run();

 private:
  static void validate(const ConformalCoronaProblem& p);
  void makeGrid();
  void classifyCells();
  void assembleAndFactorise();
  void laplaceField();
  void laplaceFromModel();
  void laplaceFromGrid();
  void iterateSpaceCharge();
  Currents transport(double injection);
  double unitSpaceCharge(Eigen::VectorXd& b);
  void localKaptzov(double rho0Star, std::vector<double>& shapeNew) const;
  void andersonStep(AndersonMixer& anderson, double rho0Star, const std::vector<double>& shapeNew,
                    std::vector<double>& xk, std::vector<double>& fk, const std::vector<double>& beta);
  void reportTransport();
  void wireFieldSummary();
  void samplingTable();
  void tubeTableGradients();
  void boundaryTableRows();
  // d f / d(distance from the wire) at the wire, per unit tau (one-sided parabola).
  double wireNormalDeriv(const std::vector<double>& f, double f0, int i) const {
    const double f1 = f[g_.idx(i, g_.nt - 1)], f2 = f[g_.idx(i, g_.nt - 2)];
    return (9 * (f1 - f0) - (f2 - f0)) / (3 * g_.adt);
  }
  real& T(int row, int i, int c) { return r_.table[(size_t(row) * g_.ns + i) * 4 + c]; }
  double val(int i, int j) const { return psiSc_[g_.idx(g_.wrap(i), j)]; }  // tube cells hold 0

  const ConformalCoronaProblem& p_;
  Grid g_;
  int n_ = 0;
  double s_ = 1, absU_ = 0, psiWire_ = 0;
  ConformalCoronaResult r_;
  std::vector<double> xs_, ys_, h2_;  // cell centres and the squared scale factor h^2
  std::vector<int> unk_;              // unknown of each cell, -1 for none
  int nu_ = 0;
  // Boundary coefficient of each unknown towards the wire / tube (psi = -|U|), for the Laplace RHS.
  std::vector<double> bWire_;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt_;
  std::vector<double> psiLap_, gLap_, hWire_;
  double dirOut_ = 1;  // the wire's outward normal points along dirOut * tau
  double sumH_ = 0, gLapMean_ = 0;
  std::vector<double> psiSc_, rhoHat_, inflow_, psiHat_, psi_;
  double rho0_ = 0;
  std::vector<int> order_;
  std::vector<std::pair<double, int>> keyed_;
  // Injection profile round the wire (arc-length mean 1): adjusted so that the local surface field, not
  // only its mean, reaches E_on.
  std::vector<double> shape_;
};

ConformalCoronaResult ConformalSolver::run() {
  validate(p_);
  makeGrid();
  classifyCells();
  assembleAndFactorise();
  laplaceField();
  r_.phi_sc.assign(n_, 0);
  r_.rho.assign(n_, 0);
  r_.wire_field.assign(g_.ns, 0);
  psiSc_.assign(n_, 0.0);
  psiHat_.assign(n_, 0.0);
  psi_.resize(n_);
  order_.reserve(n_);
  keyed_.reserve(n_);
  shape_.assign(g_.ns, 1.0);
  r_.ionised = gLapMean_ > p_.E_on;
  if (r_.ionised) iterateSpaceCharge();
  wireFieldSummary();
  for (int q = 0; q < n_; ++q) r_.phi_sc[q] = real(-s_ * psiSc_[q]);
  samplingTable();
  return std::move(r_);
}

void ConformalSolver::validate(const ConformalCoronaProblem& p) {
  if (p.n_sigma < 8 || p.n_tau < 4 || p.n_sigma > 4096 || p.n_tau > 4096)
    throw InputError("corona grid: n_sigma must lie in [8, 4096] and n_tau in [4, 4096]");
  if (!finite(p.U) || !(p.wire_radius > 0) || !(p.E_on > 0) || !finite(p.E_on) || !(p.mobility > 0) ||
      !finite(p.mobility))
    throw InputError("corona solver: U must be finite, the wire radius, E_on and the ion mobility positive");
  if (!(p.tolerance > 0) || p.max_iterations < 1 || !(p.relaxation > 0 && p.relaxation <= 1))
    throw InputError("corona solver: tolerance must be positive, max_iterations >= 1, relaxation in (0, 1]");
  if (p.tube && !(p.tube_R > 0)) throw InputError("corona solver: the tube radius must be positive");
}

void ConformalSolver::makeGrid() {
  g_.ns = p_.n_sigma;
  g_.nt = p_.n_tau;
  g_.map = &p_.map;
  g_.ds = 2 * kPiD / g_.ns;
  g_.dt = (double(p_.map.tau_wire) - double(p_.map.tau_drum)) / g_.nt;
  g_.adt = std::fabs(g_.dt);
  if (!(g_.adt > 0)) throw InputError("corona grid: the drum and wire boundaries coincide");
  g_.cs = g_.adt / g_.ds;
  g_.ctau = g_.ds / g_.adt;
  n_ = g_.ns * g_.nt;
  s_ = p_.U < 0 ? -1.0 : 1.0;
  absU_ = std::fabs(double(p_.U));
  psiWire_ = -absU_;
}

// Cell centres, scale factors and kinds: tube (1) inside the tube, far-field sink (2) beyond the frame.
void ConformalSolver::classifyCells() {
  r_.kind.assign(n_, 0);
  xs_.resize(n_);
  ys_.resize(n_);
  h2_.resize(n_);
  for (int j = 0; j < g_.nt; ++j)
    for (int i = 0; i < g_.ns; ++i) {
      const int q = g_.idx(i, j);
      real x, y;
      p_.map.toPhysical(real(g_.sigma(i)), real(g_.tau(j)), x, y);
      xs_[q] = x;
      ys_[q] = y;
      const double h = p_.map.scale(real(g_.sigma(i)), real(g_.tau(j)));
      h2_[q] = h * h;
      if (p_.tube && std::hypot(x - double(p_.tube_cx), y - double(p_.tube_cy)) < p_.tube_R)
        r_.kind[q] = 1;
      else if (p_.frame_radius > 0 && std::hypot(x - double(p_.frame_cx), y - double(p_.frame_cy)) > p_.frame_radius)
        r_.kind[q] = 2;
    }
}

// Unknown numbering (tube cells are not unknowns) and the Poisson matrix A = -Laplacian (SPD).
void ConformalSolver::assembleAndFactorise() {
  unk_.assign(n_, -1);
  nu_ = 0;
  for (int q = 0; q < n_; ++q)
    if (r_.kind[q] == 0 || (r_.kind[q] == 2 && !p_.frame_earthed)) unk_[q] = nu_++;
  if (nu_ == 0) throw InputError("corona grid: the tube covers the whole grid");
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(size_t(nu_) * 5);
  bWire_.assign(nu_, 0.0);
  for (int j = 0; j < g_.nt; ++j)
    for (int i = 0; i < g_.ns; ++i) {
      const int q = g_.idx(i, j);
      if (unk_[q] < 0) continue;
      double diag = 0;
      auto link = [&](int nbq, double c) {
        diag += c;
        if (unk_[nbq] >= 0)
          trip.emplace_back(unk_[q], unk_[nbq], -c);
        else if (r_.kind[nbq] == 1)
          bWire_[unk_[q]] += c;  // tube neighbour (psi = -|U|); an earthed frame cell adds nothing (psi = 0)
      };
      link(g_.idx(g_.wrap(i - 1), j), g_.cs);
      link(g_.idx(g_.wrap(i + 1), j), g_.cs);
      if (j > 0)
        link(g_.idx(i, j - 1), g_.ctau);
      else
        diag += 2 * g_.ctau;  // drum face, psi = 0
      if (j < g_.nt - 1)
        link(g_.idx(i, j + 1), g_.ctau);
      else {
        diag += 2 * g_.ctau;  // wire face, psi = -|U|
        bWire_[unk_[q]] += 2 * g_.ctau;
      }
      trip.emplace_back(unk_[q], unk_[q], diag);
    }
  Eigen::SparseMatrix<double> A(nu_, nu_);
  A.setFromTriplets(trip.begin(), trip.end());
  ldlt_.compute(A);
  if (ldlt_.info() != Eigen::Success) throw InputError("corona solver: the Poisson matrix could not be factorised");
}

// Laplace potential (psi convention) at the cell centres and the Laplace surface field of the wire, from
// the problem's Laplace model where it has one, else from the grid; its arc-length mean and the onset.
void ConformalSolver::laplaceField() {
  psiLap_.assign(n_, psiWire_);
  gLap_.resize(g_.ns);
  hWire_.resize(g_.ns);
  for (int i = 0; i < g_.ns; ++i) hWire_[i] = p_.map.scale(real(g_.sigma(i)), p_.map.tau_wire);
  dirOut_ = g_.dt > 0 ? -1.0 : 1.0;
  if (p_.laplace)
    laplaceFromModel();
  else
    laplaceFromGrid();
  double sumH = 0, sumGL = 0;
  for (int i = 0; i < g_.ns; ++i) {
    sumH += hWire_[i];
    sumGL += gLap_[i] * hWire_[i];
  }
  sumH_ = sumH;
  gLapMean_ = sumGL / sumH;  // arc-length mean = wire charge / (2 pi r eps0)
  r_.laplace_wire_field = real(gLapMean_);
  r_.onset_voltage = real(gLapMean_ > 0 ? double(p_.U) * p_.E_on / gLapMean_ : 0.0);
  r_.phi_laplace.assign(n_, 0);
  for (int q = 0; q < n_; ++q) r_.phi_laplace[q] = real(-s_ * psiLap_[q]);
}

void ConformalSolver::laplaceFromModel() {
  for (int q = 0; q < n_; ++q) {
    if (r_.kind[q] == 1) continue;
    real ph, ex, ey;
    p_.laplace(real(xs_[q]), real(ys_[q]), ph, ex, ey);
    psiLap_[q] = -s_ * ph;
  }
  for (int i = 0; i < g_.ns; ++i) {
    real x, y, ph, ex, ey, fr, fi;
    p_.map.toPhysical(real(g_.sigma(i)), p_.map.tau_wire, x, y);
    p_.laplace(x, y, ph, ex, ey);
    p_.map.derivative(real(g_.sigma(i)), p_.map.tau_wire, fr, fi);
    // dz/dtau = i f'; the outward normal is dirOut * i f' / |f'|.
    const double nx = -dirOut_ * fi / hWire_[i], ny = dirOut_ * fr / hWire_[i];
    gLap_[i] = s_ * (ex * nx + ey * ny);
  }
}

void ConformalSolver::laplaceFromGrid() {
  Eigen::VectorXd b(nu_);
  for (int k = 0; k < nu_; ++k) b(k) = bWire_[k] * psiWire_;
  const Eigen::VectorXd x = ldlt_.solve(b);
  for (int q = 0; q < n_; ++q) psiLap_[q] = unk_[q] >= 0 ? x(unk_[q]) : (r_.kind[q] == 1 ? psiWire_ : 0.0);
  for (int i = 0; i < g_.ns; ++i) gLap_[i] = wireNormalDeriv(psiLap_, psiWire_, i) / hWire_[i];
}

// Ion transport on psi = psi_Laplace + psi_sc for the injection density `injection`: fills rhoHat_.
Currents ConformalSolver::transport(double injection) {
  for (int q = 0; q < n_; ++q) psi_[q] = r_.kind[q] == 1 ? psiWire_ : psiLap_[q] + psiSc_[q];
  keyed_.clear();
  for (int q = 0; q < n_; ++q)
    if (r_.kind[q] != 1) keyed_.emplace_back(psi_[q], q);
  std::sort(keyed_.begin(), keyed_.end());  // contiguous keys: faster than an indirect comparison
  order_.resize(keyed_.size());
  for (size_t k = 0; k < keyed_.size(); ++k) order_[k] = keyed_[k].second;
  return sweep(g_, psi_, r_.kind, psiWire_, injection, shape_, order_, rhoHat_, inflow_);
}

// Space-charge iteration: transport at unit injection, its potential, Kaptzov's injection density and
// profile, then the Anderson step, until the space-charge potential stops changing.
void ConformalSolver::iterateSpaceCharge() {
  Eigen::VectorXd b(nu_);
  // Anderson acceleration of the fixed-point iteration x <- x + beta f (beta = the relaxation for the
  // space-charge potential, 1 for the injection profile, whose update carries its own gain).
  const size_t nx = size_t(n_) + g_.ns;
  std::vector<double> xk(nx), fk(nx), beta(nx, 1.0), shapeNew(g_.ns);
  std::fill(beta.begin(), beta.begin() + n_, double(p_.relaxation));
  AndersonMixer anderson(nx, kAndersonDepth);
  for (int it = 1; it <= p_.max_iterations; ++it) {
    transport(1.0);
    const double rho0Star = unitSpaceCharge(b);
    localKaptzov(rho0Star, shapeNew);
    double change = 0;
    for (int q = 0; q < n_; ++q) change = std::max(change, std::fabs(rho0Star * psiHat_[q] - psiSc_[q]));
    rho0_ = rho0Star;
    r_.iterations = it;
    r_.last_change = real(change / absU_);
    if (change / absU_ < p_.tolerance) {
      for (int q = 0; q < n_; ++q) psiSc_[q] = rho0Star * psiHat_[q];
      shape_ = shapeNew;
      break;
    }
    andersonStep(anderson, rho0Star, shapeNew, xk, fk, beta);
  }
  reportTransport();
}

// Space-charge potential of the unit injection (psiHat_) and the injection density that brings the mean
// wire surface field to E_on.
double ConformalSolver::unitSpaceCharge(Eigen::VectorXd& b) {
  // A psi = -|rho| h^2 ds dt / eps0 (zero on conductors).
  const double cellArea = g_.ds * g_.adt;
  for (int q = 0; q < n_; ++q)
    if (unk_[q] >= 0) b(unk_[q]) = -rhoHat_[q] * h2_[q] * cellArea / double(kEps0);
  const Eigen::VectorXd x = ldlt_.solve(b);
  for (int q = 0; q < n_; ++q) psiHat_[q] = unk_[q] >= 0 ? x(unk_[q]) : 0.0;
  double sumG = 0;
  for (int i = 0; i < g_.ns; ++i) sumG += wireNormalDeriv(psiHat_, 0.0, i);  // (1/h) * h ds cancels
  const double gHatMean = sumG / sumH_;                                      // < 0: the ions screen the wire
  return gHatMean < 0 ? (double(p_.E_on) - gLapMean_) / gHatMean : 0.0;
}

// Local Kaptzov: raise the injection where the surface field is above E_on, lower it where below, in
// proportion to the excess over the screening the ions provide there, (E - E_on) / (E_Laplace - E_on);
// the gain (4) is over-relaxed because the field at one angle feels only part of the charge injected
// there (the rest of its screening comes from the ions of the whole wire). Keep the mean at 1.
void ConformalSolver::localKaptzov(double rho0Star, std::vector<double>& shapeNew) const {
  double sw = 0;
  for (int i = 0; i < g_.ns; ++i) {
    const double gi = gLap_[i] + rho0Star * wireNormalDeriv(psiHat_, 0.0, i) / hWire_[i];
    const double screen = std::max(gLap_[i] - double(p_.E_on), 1e-3 * double(p_.E_on));
    shapeNew[i] = std::max(0.0, shape_[i] * (1 + kShapeGain * (gi - double(p_.E_on)) / screen));
    sw += shapeNew[i] * hWire_[i];
  }
  if (sw > 0)
    for (int i = 0; i < g_.ns; ++i) shapeNew[i] *= sumH_ / sw;
}

// Fixed-point residual f = g(x) - x of x = (psi_sc / |U|, shape) and the Anderson step.
void ConformalSolver::andersonStep(AndersonMixer& anderson, double rho0Star, const std::vector<double>& shapeNew,
                                   std::vector<double>& xk, std::vector<double>& fk, const std::vector<double>& beta) {
  for (int q = 0; q < n_; ++q) {
    xk[q] = psiSc_[q] / absU_;
    fk[q] = (rho0Star * psiHat_[q] - psiSc_[q]) / absU_;
  }
  for (int i = 0; i < g_.ns; ++i) {
    xk[n_ + i] = shape_[i];
    fk[n_ + i] = shapeNew[i] - shape_[i];
  }
  anderson.step(xk, fk, beta);
  for (int q = 0; q < n_; ++q) psiSc_[q] = xk[q] * absU_;
  double sw = 0;
  for (int i = 0; i < g_.ns; ++i) {
    shape_[i] = std::max(0.0, xk[n_ + i]);
    sw += shape_[i] * hWire_[i];
  }
  if (sw > 0)
    for (int i = 0; i < g_.ns; ++i) shape_[i] *= sumH_ / sw;
}

// The final transport on the converged potential gives the reported density and currents.
void ConformalSolver::reportTransport() {
  const Currents cur = transport(rho0_);
  r_.injection_density = real(rho0_);
  r_.current = real(cur.injected * p_.mobility);
  r_.current_drum = real(cur.drum * p_.mobility);
  r_.current_far = real(cur.far * p_.mobility);
  r_.current_tube = real((cur.tube + cur.trapped) * p_.mobility);
  double q = 0;
  for (int k = 0; k < n_; ++k) {
    r_.rho[k] = real(rhoHat_[k]);
    q += rhoHat_[k] * h2_[k] * g_.ds * g_.adt;
  }
  r_.space_charge = real(q);
}

// Total wire surface field and Kaptzov's error.
void ConformalSolver::wireFieldSummary() {
  double wmin = 1e300, wmax = -1e300, wsum = 0;
  for (int i = 0; i < g_.ns; ++i) {
    const double e = gLap_[i] + wireNormalDeriv(psiSc_, 0.0, i) / hWire_[i];
    r_.wire_field[i] = real(e);
    wmin = std::min(wmin, e);
    wmax = std::max(wmax, e);
    wsum += e * hWire_[i];
  }
  r_.wire_field_mean = real(wsum / sumH_);
  r_.wire_field_min = real(wmin);
  r_.wire_field_max = real(wmax);
  r_.kaptzov_error = r_.ionised ? real(std::max(std::fabs(wmin / p_.E_on - 1), std::fabs(wmax / p_.E_on - 1))) : 0;
}

// Sampling table: rows 0 (drum), 1..nt (cells), nt+1 (wire); (psi_sc, dpsi/dsigma, dpsi/dtau, |rho|).
void ConformalSolver::samplingTable() {
  const int rows = g_.nt + 2;
  r_.table.assign(size_t(rows) * g_.ns * 4, 0);
  for (int j = 0; j < g_.nt; ++j)
    for (int i = 0; i < g_.ns; ++i) {
      const int q = g_.idx(i, j);
      if (r_.kind[q] == 1) continue;
      const double f0 = psiSc_[q];
      const double dsg = (val(i + 1, j) - val(i - 1, j)) / (2 * g_.ds);
      double dtu;
      if (g_.nt == 1)
        dtu = 0;
      else if (j == 0)
        dtu = d3(0.0, f0, val(i, 1), 0.5 * g_.dt, g_.dt);
      else if (j == g_.nt - 1)
        dtu = d3(val(i, j - 1), f0, 0.0, g_.dt, 0.5 * g_.dt);
      else
        dtu = (val(i, j + 1) - val(i, j - 1)) / (2 * g_.dt);
      T(j + 1, i, 0) = real(f0);
      T(j + 1, i, 1) = real(dsg);
      T(j + 1, i, 2) = real(dtu);
      T(j + 1, i, 3) = r_.rho[q];
    }
  tubeTableGradients();
  boundaryTableRows();
}

// Tube cells: the gradient continued from their gas neighbours (keeps the bilinear sampling of the gas
// next to the staircase tube boundary smooth); potential 0 and no ions.
void ConformalSolver::tubeTableGradients() {
  for (int j = 0; j < g_.nt; ++j)
    for (int i = 0; i < g_.ns; ++i) {
      if (r_.kind[g_.idx(i, j)] != 1) continue;
      double a1 = 0, a2 = 0;
      int cnt = 0;
      const int nbi[4] = {g_.wrap(i - 1), g_.wrap(i + 1), i, i};
      const int nbj[4] = {j, j, j - 1, j + 1};
      for (int k = 0; k < 4; ++k) {
        if (nbj[k] < 0 || nbj[k] >= g_.nt || r_.kind[g_.idx(nbi[k], nbj[k])] == 1) continue;
        a1 += T(nbj[k] + 1, nbi[k], 1);
        a2 += T(nbj[k] + 1, nbi[k], 2);
        ++cnt;
      }
      if (cnt) {
        T(j + 1, i, 1) = real(a1 / cnt);
        T(j + 1, i, 2) = real(a2 / cnt);
      }
    }
}

// The drum and wire rows: the normal derivative (one-sided parabola) and the ion density.
void ConformalSolver::boundaryTableRows() {
  for (int i = 0; i < g_.ns; ++i) {
    if (g_.nt >= 2) {
      T(0, i, 2) = real((9 * val(i, 0) - val(i, 1)) / (3 * g_.dt));
      T(g_.nt + 1, i, 2) = real(-(9 * val(i, g_.nt - 1) - val(i, g_.nt - 2)) / (3 * g_.dt));
    }
    T(0, i, 3) = r_.rho[g_.idx(i, 0)];
    T(g_.nt + 1, i, 3) = real(rho0_);
  }
}

}  // namespace

ConformalCoronaResult solveConformalCorona(const ConformalCoronaProblem& p) { return ConformalSolver(p).run(); }

ConformalSample sampleConformal(const ConformalCoronaProblem& p, const ConformalCoronaResult& r, real x, real y) {
  const int ns = p.n_sigma, nt = p.n_tau;
  double sg, ta, fr, fi;
  inverseMap(p.map, x, y, sg, ta, fr, fi);
  const double ds = 2 * kPiD / ns;
  const double dt = (double(p.map.tau_wire) - double(p.map.tau_drum)) / nt;
  // sigma: periodic, cell centres at -pi + (i + 1/2) ds.
  double u = (double(sg) + kPiD) / ds - 0.5;
  const double fu = std::floor(u);
  const double wx = u - fu;
  const int i0 = ((int(fu) % ns) + ns) % ns, i1 = (i0 + 1) % ns;
  // tau: row positions (in cells from the drum) 0, 0.5, 1.5, ..., nt - 0.5, nt.
  double t = (double(ta) - double(p.map.tau_drum)) / dt;
  t = std::min(double(nt), std::max(0.0, t));
  int r0;
  double wy;
  if (t < 0.5) {
    r0 = 0;
    wy = t / 0.5;
  } else if (t > nt - 0.5) {
    r0 = nt;
    wy = (t - (nt - 0.5)) / 0.5;
  } else {
    r0 = std::min(nt - 1, int(std::floor(t + 0.5)));
    wy = t - (r0 - 0.5);
  }
  double v[4];
  for (int c = 0; c < 4; ++c) {
    auto at = [&](int row, int i) { return double(r.table[(size_t(row) * ns + i) * 4 + c]); };
    v[c] =
        (1 - wy) * ((1 - wx) * at(r0, i0) + wx * at(r0, i1)) + wy * ((1 - wx) * at(r0 + 1, i0) + wx * at(r0 + 1, i1));
  }
  const double tc = std::min(std::max(ta, std::min(double(p.map.tau_drum), double(p.map.tau_wire))),
                             std::max(double(p.map.tau_drum), double(p.map.tau_wire)));
  if (tc != ta) {  // inside the drum or the wire: f' on the surface
    real dr, di;
    p.map.derivative(real(sg), real(tc), dr, di);
    fr = dr;
    fi = di;
  }
  // grad_z psi = G_w / conj(F') = G_w F' / |F'|^2,  G_w = psi_sigma + i psi_tau.
  const double h2 = fr * fr + fi * fi;
  const double gr = (v[1] * fr - v[2] * fi) / h2, gi = (v[1] * fi + v[2] * fr) / h2;
  const double s = p.U < 0 ? -1.0 : 1.0;
  ConformalSample out;
  out.phi_sc = real(-s * v[0]);
  out.Ex_sc = real(s * gr);  // E = -grad phi = s grad psi
  out.Ey_sc = real(s * gi);
  out.rho_abs = real(std::max(0.0, v[3]));
  return out;
}

// ------------------------------------------------------------------------------------------------
// The machine.

namespace {

// The CSM Laplace field (field_csm.h) evaluated through one Laurent (multipole) expansion per cylinder.
// With the complex potential Phi(z) = sum_j lambda_j log(z - z_j) the CSM field is
//   phi = phi_inf - Re Phi / (2 pi eps0),  Ex - i Ey = Phi'(z) / (2 pi eps0).
// The M charges of a cylinder lie on a circle of radius rq round its axis c, z_j = c + rq e^{i theta_j};
// with w = z - c and u = rq / w (|u| < 1 outside that circle), log(z - z_j) = log w - sum_m (e^{i theta_j}
// u)^m / m, so
//   Phi_k(z) = Q log w - sum_{m>=1} (alpha_m / m) u^m,  Phi_k'(z) = (Q + sum_{m>=1} alpha_m u^m) / w,
//   alpha_m = sum_j lambda_j e^{i m theta_j},  Q = sum_j lambda_j
// (the Laurent series of a sum of logarithms, e.g. L. Greengard, V. Rokhlin, J. Comput. Phys. 73 (1987)
// 325-348, Lemma 2.1). |alpha_m| <= Lambda = sum_j |lambda_j|, and it decays like (s/rq)^m (s the image
// radius of field_csm.h) until the aliasing of the M-point ring makes alpha periodic in m (alpha_{m+M} =
// alpha_m). Truncated after n terms the series is off by at most
//   T(n, |u|) = sum_{n<m<=3M} |alpha_m| |u|^m + Lambda |u|^{3M+1} / (1 - |u|)
// in Phi' |w| and in Phi; n is taken per point (a table over |u|) so that T <= 1e-11 Lambda: an error in E
// of 1e-11 Lambda / (2 pi eps0 |w|), far below the float storage of the grid (6e-8 relative; measured
// 2.4e-10 of |E| against the direct sum on the default machine). Where no n <= 3M reaches that (|u| close
// to 1, only inside a conductor) the charges are summed directly. One logarithm per cylinder instead of one
// per charge, and a short Horner recurrence: the Cartesian sampling of the default machine needs about
// 30 + 5 + 2 terms per node (drum, tube, wire) instead of 216 logarithms.
class CsmExpansion {
 public:
  // counts[k] charges of cylinder k, stored consecutively in q (as CsmField::charges() orders them).
  CsmExpansion(const std::vector<CsmLineCharge>& q, const std::vector<int>& counts,
               const std::vector<CsmConductor>& conductors, double phiInf)
      : charges_(q), phiInf_(phiInf) {
    int first = 0;
    for (size_t k = 0; k < counts.size(); ++k) {
      Cyl c;
      c.cx = conductors[k].cx;
      c.cy = conductors[k].cy;
      c.first = first;
      c.count = counts[k];
      first += counts[k];
      double rq = 0, lam = 0;
      long double Q = 0;
      for (int j = c.first; j < c.first + c.count; ++j) {
        rq = std::max(rq, std::hypot(double(q[j].x) - c.cx, double(q[j].y) - c.cy));
        lam += std::fabs(double(q[j].lambda));
        Q += q[j].lambda;
      }
      c.rq = rq;
      c.Q = double(Q);
      const int mcap = 3 * std::max(1, c.count);
      // alpha_m, m = 1..mcap, in long double (the lambda_j alternate and can exceed Q by orders).
      std::vector<long double> ar(mcap + 1, 0.0L), ai(mcap + 1, 0.0L);
      for (int j = c.first; j < c.first + c.count && rq > 0; ++j) {
        const long double ex = (static_cast<long double>(q[j].x) - c.cx) / rq;
        const long double ey = (static_cast<long double>(q[j].y) - c.cy) / rq;
        long double pr = 1, pi = 0;
        for (int m = 1; m <= mcap; ++m) {
          const long double t = pr * ex - pi * ey;
          pi = pr * ey + pi * ex;
          pr = t;
          ar[m] += q[j].lambda * pr;
          ai[m] += q[j].lambda * pi;
        }
      }
      c.alpha.resize(2 * size_t(mcap + 1));
      c.beta.resize(2 * size_t(mcap + 1));
      for (int m = 0; m <= mcap; ++m) {
        c.alpha[2 * m] = double(ar[m]);
        c.alpha[2 * m + 1] = double(ai[m]);
        c.beta[2 * m] = m ? double(ar[m] / m) : 0.0;
        c.beta[2 * m + 1] = m ? double(ai[m] / m) : 0.0;
      }
      // Terms needed at |u| <= (l + 1) / kLevels; -1: sum directly.
      c.terms.assign(kLevels, -1);
      const double tol = kTruncation * lam;
      std::vector<double> term(mcap + 1);  // |alpha_m| u^m
      for (int l = 0; l < kLevels; ++l) {
        const double u = double(l + 1) / kLevels;
        if (u >= 1) break;
        double tail = lam * std::pow(u, mcap + 1) / (1 - u);
        if (tail > tol) break;  // the remaining levels are larger still
        double um = 1;
        for (int m = 1; m <= mcap; ++m) {
          um *= u;
          term[m] = std::hypot(c.alpha[2 * m], c.alpha[2 * m + 1]) * um;
        }
        int n = mcap;
        for (; n > 0 && tail + term[n] <= tol; --n) tail += term[n];  // drop term n
        c.terms[l] = n;
      }
      cyl_.push_back(std::move(c));
    }
  }

  void eval(double x, double y, double& phi, double& ex, double& ey) const {
    double sl = 0, sx = 0, sy = 0;  // Re Phi, Re Phi', -Im Phi'
    for (const Cyl& c : cyl_) {
      const double wx = x - c.cx, wy = y - c.cy;
      const double r2 = wx * wx + wy * wy;
      const int n = termsAt(c, r2);
      if (n < 0) {
        direct(c, x, y, sl, sx, sy);
        continue;
      }
      const double ux = c.rq * wx / r2, uy = -c.rq * wy / r2;
      const double* A = c.alpha.data();
      const double* B = c.beta.data();
      double pr = 0, pi = 0, qr = 0, qi = 0;  // sum beta_m u^(m-1), sum alpha_m u^(m-1) (Horner)
      for (int m = n; m >= 1; --m) {
        const double tr = pr * ux - pi * uy + B[2 * m];
        pi = pr * uy + pi * ux + B[2 * m + 1];
        pr = tr;
        const double sr = qr * ux - qi * uy + A[2 * m];
        qi = qr * uy + qi * ux + A[2 * m + 1];
        qr = sr;
      }
      accumulate(c, wx, wy, r2, ux, uy, pr, pi, qr, qi, sl, sx, sy);
    }
    phi = phiInf_ - double(kInv2PiEps0) * sl;
    ex = double(kInv2PiEps0) * sx;
    ey = double(kInv2PiEps0) * sy;
  }

  // Four points at once: four independent Horner chains per step (the scalar recurrence is bound by the
  // latency of its multiply-add chain), each with the largest number of terms the four need (more terms
  // only lower the truncation error). Lanes with active[l] == false are not evaluated.
  void eval4(const double* x, const double* y, const bool* active, double* phi, double* ex, double* ey) const {
    double sl[4] = {0, 0, 0, 0}, sx[4] = {0, 0, 0, 0}, sy[4] = {0, 0, 0, 0};
    for (const Cyl& c : cyl_) {
      double wx[4], wy[4], r2[4], ux[4], uy[4];
      int nmax = 0;
      bool horner[4];
      for (int l = 0; l < 4; ++l) {
        wx[l] = x[l] - c.cx;
        wy[l] = y[l] - c.cy;
        r2[l] = wx[l] * wx[l] + wy[l] * wy[l];
        horner[l] = false;
        ux[l] = uy[l] = 0;
        if (!active[l]) continue;
        const int n = termsAt(c, r2[l]);
        if (n < 0) {
          direct(c, x[l], y[l], sl[l], sx[l], sy[l]);
          continue;
        }
        horner[l] = true;
        nmax = std::max(nmax, n);
        ux[l] = c.rq * wx[l] / r2[l];
        uy[l] = -c.rq * wy[l] / r2[l];
      }
      const double* A = c.alpha.data();
      const double* B = c.beta.data();
      double pr[4] = {0, 0, 0, 0}, pi[4] = {0, 0, 0, 0}, qr[4] = {0, 0, 0, 0}, qi[4] = {0, 0, 0, 0};
      for (int m = nmax; m >= 1; --m) {
        const double br = B[2 * m], bi = B[2 * m + 1], ar = A[2 * m], ai = A[2 * m + 1];
        for (int l = 0; l < 4; ++l) {
          const double tr = pr[l] * ux[l] - pi[l] * uy[l] + br;
          pi[l] = pr[l] * uy[l] + pi[l] * ux[l] + bi;
          pr[l] = tr;
          const double sr = qr[l] * ux[l] - qi[l] * uy[l] + ar;
          qi[l] = qr[l] * uy[l] + qi[l] * ux[l] + ai;
          qr[l] = sr;
        }
      }
      for (int l = 0; l < 4; ++l) {
        if (!horner[l]) continue;
        accumulate(c, wx[l], wy[l], r2[l], ux[l], uy[l], pr[l], pi[l], qr[l], qi[l], sl[l], sx[l], sy[l]);
      }
    }
    for (int l = 0; l < 4; ++l) {
      phi[l] = phiInf_ - double(kInv2PiEps0) * sl[l];
      ex[l] = double(kInv2PiEps0) * sx[l];
      ey[l] = double(kInv2PiEps0) * sy[l];
    }
  }

 private:
  static constexpr int kLevels = 512;
  static constexpr double kTruncation = 1e-11;  // of Lambda
  struct Cyl {
    double cx, cy, rq, Q;
    int first, count;
    std::vector<double> alpha, beta;  // (re, im) of alpha_m and alpha_m / m, m = 0..3M
    std::vector<int> terms;
  };
  // Terms needed at |w|^2 = r2 from the axis; -1: sum the charges directly.
  static int termsAt(const Cyl& c, double r2) {
    const double au = c.rq / std::sqrt(r2);  // |u|
    if (!(au < 1)) return -1;
    const int l = int(std::ceil(au * kLevels)) - 1;
    return l < 0 ? 0 : c.terms[l];
  }
  void direct(const Cyl& c, double x, double y, double& sl, double& sx, double& sy) const {
    for (int j = c.first; j < c.first + c.count; ++j) {
      const double dx = x - charges_[j].x, dy = y - charges_[j].y;
      const double q2 = dx * dx + dy * dy;
      sl += 0.5 * charges_[j].lambda * std::log(q2);
      const double w = charges_[j].lambda / q2;
      sx += w * dx;
      sy += w * dy;
    }
  }
  // Adds Re Phi_k, Re Phi_k', -Im Phi_k' from the Horner sums p = sum beta_m u^(m-1), q = sum alpha_m u^(m-1).
  static void accumulate(const Cyl& c, double wx, double wy, double r2, double ux, double uy, double pr, double pi,
                         double qr, double qi, double& sl, double& sx, double& sy) {
    const double p1r = pr * ux - pi * uy;  // Re sum beta_m u^m
    const double q1r = qr * ux - qi * uy + c.Q, q1i = qr * uy + qi * ux;
    sl += 0.5 * c.Q * std::log(r2) - p1r;
    // Phi' = (Q + sum alpha_m u^m) conj(w) / |w|^2
    sx += (q1r * wx + q1i * wy) / r2;
    sy -= (q1i * wx - q1r * wy) / r2;
  }

  std::vector<CsmLineCharge> charges_;
  double phiInf_;
  std::vector<Cyl> cyl_;
};

}  // namespace

GridFieldView GridField::view() const {
  GridFieldView v{x0, y0, dx, dy, nx, ny, Ex.data(), Ey.data(), phi.data(), ion_density.data(), 0, {}};
  v.nConductors = int32_t(std::min<size_t>(3, conductors.size()));
  for (int32_t k = 0; k < v.nConductors; ++k) v.conductors[k] = conductors[k];
  return v;
}

FieldSample CoronaField::evalLaplace(Vec3 p) const {
  CsmFieldView v{charges_.data(), int(charges_.size()), conductors_.data(), int(conductors_.size()), phiInf_};
  return evalCsm(v, p);
}

FieldSample CoronaField::evalFine(Vec3 p) const {
  FieldSample f = evalLaplace(p);
  if (f.region != 0 || !sol_.ionised) return f;
  const ConformalSample c = sampleConformal(prob_, res_, p.x, p.y);
  f.phi += c.phi_sc;
  f.E.x += c.Ex_sc;
  f.E.y += c.Ey_sc;
  return f;
}

real CoronaField::ionDensityFine(Vec3 p) const {
  if (evalLaplace(p).region != 0 || !sol_.ionised) return 0;
  return sampleConformal(prob_, res_, p.x, p.y).rho_abs / kElementaryCharge;
}

namespace {

// Checks the setup of CoronaField::solve; nxd, nyd: the node counts of the Cartesian grid box.
void validateSetup(const CoronaSetup& st, double& nxd, double& nyd) {
  auto bad = [](const std::string& m) { throw InputError("corona: " + m); };
  if (!finite(st.U)) bad("U must be finite");
  if (!(st.ion_mobility > 0) || !finite(st.ion_mobility)) bad("ion_mobility must be positive");
  if (!(st.rel_air_density > 0) || !finite(st.rel_air_density)) bad("rel_air_density must be positive");
  if (!(st.roughness > 0 && st.roughness <= 1)) bad("roughness must lie in (0, 1]");
  if (!st.drum.present || !st.wire.present) bad("the drum and the wire must be present");
  if (!(st.box_x1 > st.box_x0) || !(st.box_y1 > st.box_y0) || !finite(st.box_x0) || !finite(st.box_x1) ||
      !finite(st.box_y0) || !finite(st.box_y1))
    bad("the grid box must have x1 > x0 and y1 > y0");
  if (!(st.spacing > 0)) bad("the grid spacing must be positive");
  nxd = std::floor((double(st.box_x1) - st.box_x0) / st.spacing + 1e-9) + 1;
  nyd = std::floor((double(st.box_y1) - st.box_y0) / st.spacing + 1e-9) + 1;
  if (nxd * nyd > 5e7) bad("the grid box holds more than 5e7 nodes; raise the spacing");
  if (!(st.tolerance > 0)) bad("tolerance must be positive");
}

// CSM Laplace model at a unit voltage of U's sign (solved in csm), scaled by |U| (linear in U) into
// charges, conductors and phiInf. Returns the mean surface field of the wire per volt.
real csmModel(const CoronaSetup& st, CsmField& csm, std::vector<CsmLineCharge>& charges,
              std::vector<CsmConductor>& conductors, real& phiInf) {
  const real sgn = st.U < 0 ? real(-1) : real(1);
  csm.addCylinder(st.drum.cx, st.drum.cy, st.drum.R, 0);
  csm.addCylinder(st.wire.cx, st.wire.cy, st.wire.R, sgn);
  if (st.tube.present) csm.addCylinder(st.tube.cx, st.tube.cy, st.tube.R, sgn);
  csm.solve();
  const real absU = std::fabs(st.U);
  charges = csm.charges();
  for (CsmLineCharge& c : charges) c.lambda *= absU;
  conductors = csm.conductors();
  for (CsmConductor& c : conductors) c.V *= absU;
  phiInf = csm.phiInfinity() * absU;
  // Mean surface field of the wire per volt = its charge per volt / (2 pi eps0 r) (Gauss).
  return std::fabs(csm.cylinderCharge(1)) / (2 * kPi * kEps0 * st.wire.R);
}

// The conformal problem of the setup (without its Laplace model).
void setConformalProblem(ConformalCoronaProblem& p, const CoronaSetup& st, real Eon) {
  p = ConformalCoronaProblem{};
  p.map = ConformalMap::bipolar(st.drum.cx, st.drum.cy, st.drum.R, st.wire.cx, st.wire.cy, st.wire.R);
  p.n_sigma = st.n_sigma;
  p.n_tau = st.n_tau;
  p.U = st.U;
  p.wire_radius = st.wire.R;
  p.E_on = Eon;
  p.mobility = st.ion_mobility;
  p.tube = st.tube.present;
  p.tube_cx = st.tube.cx;
  p.tube_cy = st.tube.cy;
  p.tube_R = st.tube.R;
  p.frame_cx = st.drum.cx;
  p.frame_cy = st.drum.cy;
  p.frame_radius = st.frame_radius;
  p.frame_earthed = st.frame_earthed;
  p.tolerance = st.tolerance;
  p.relaxation = st.relaxation;
  p.max_iterations = st.max_iterations;
}

// Cartesian sampling: CSM Laplace field (exact) + the conformal space-charge correction. Row by row:
// which nodes need the field and where their space-charge part is sampled, then the CSM part four nodes
// at a time (groups fixed by the node index: the result does not depend on the thread count), then the
// space-charge part.
struct GridSampler {
  const std::vector<CsmConductor>& conductors;
  const CsmExpansion& lap;
  const ConformalCoronaProblem& prob;
  const ConformalCoronaResult& res;
  real reach;  // nodes this deep inside a conductor hold the continued field

  // Per-thread scratch of one row (padded to a multiple of 4 nodes).
  struct Row {
    explicit Row(int32_t nx4) : xs(nx4), sxs(nx4), sys(nx4), ph(nx4), ex(nx4), ey(nx4), need(new bool[nx4]) {}
    std::vector<double> xs, sxs, sys, ph, ex, ey;
    std::unique_ptr<bool[]> need;
  };

  void run(GridField& G) const {
#pragma omp parallel
    {
      Row w((G.nx + 3) / 4 * 4);
#pragma omp for schedule(dynamic, 4)
      for (int32_t j = 0; j < G.ny; ++j) row(G, j, w);
    }
  }

  // The conductor the node (x, y) lies in (-1: none), the node's distance d from its centre (0 outside)
  // and the point (sx, sy) where the node's space-charge part is sampled.
  int conductorOf(real x, real y, real& sx, real& sy, real& d) const {
    sx = x;
    sy = y;
    d = 0;
    for (size_t c = 0; c < conductors.size(); ++c) {
      const CsmConductor& cd = conductors[c];
      const real d2 = (x - cd.cx) * (x - cd.cx) + (y - cd.cy) * (y - cd.cy);
      if (d2 < cd.R * cd.R) {
        d = std::hypot(x - cd.cx, y - cd.cy);
        if (d > 0) {
          const real f = (cd.R * (1 + real(1e-9))) / d;
          sx = cd.cx + (x - cd.cx) * f;
          sy = cd.cy + (y - cd.cy) * f;
        }
        return int(c);
      }
    }
    return -1;
  }

  void row(GridField& G, int32_t j, Row& w) const {
    const int32_t nx4 = int32_t(w.xs.size());
    const real y = G.y0 + j * G.dy;
    for (int32_t i = 0; i < nx4; ++i) {
      w.need[i] = false;
      if (i >= G.nx) continue;
      const size_t k = size_t(j) * G.nx + i;
      const real x = G.x0 + i * G.dx;
      w.xs[i] = x;
      real sx, sy, d;
      const int inside = conductorOf(x, y, sx, sy, d);
      if (inside >= 0 && d < conductors[inside].R - reach && inside != 1) {
        G.phi[k] = float(conductors[inside].V);
        continue;
      }
      w.need[i] = true;
      w.sxs[i] = sx;
      w.sys[i] = sy;
    }
    const double yy[4] = {y, y, y, y};
    for (int32_t i = 0; i < nx4; i += 4)
      if (w.need[i] || w.need[i + 1] || w.need[i + 2] || w.need[i + 3])
        lap.eval4(&w.xs[i], yy, &w.need[i], &w.ph[i], &w.ex[i], &w.ey[i]);
    for (int32_t i = 0; i < G.nx; ++i) {
      if (!w.need[i]) continue;
      const size_t k = size_t(j) * G.nx + i;
      double p = w.ph[i], fx = w.ex[i], fy = w.ey[i];
      if (res.ionised) {
        const ConformalSample c = sampleConformal(prob, res, w.sxs[i], w.sys[i]);
        p += c.phi_sc;
        fx += c.Ex_sc;
        fy += c.Ey_sc;
        G.ion_density[k] = float(c.rho_abs / kElementaryCharge);
      }
      G.phi[k] = float(p);
      G.Ex[k] = float(fx);
      G.Ey[k] = float(fy);
    }
  }
};

// The Cartesian grid of the setup's box, zero-filled, with the conductors.
void initGrid(GridField& G, const CoronaSetup& st, double nxd, double nyd, const std::vector<CsmConductor>& cs) {
  G.x0 = st.box_x0;
  G.y0 = st.box_y0;
  G.dx = G.dy = st.spacing;
  G.nx = int32_t(nxd);
  G.ny = int32_t(nyd);
  const size_t nn = size_t(G.nx) * G.ny;
  G.Ex.assign(nn, 0.f);
  G.Ey.assign(nn, 0.f);
  G.phi.assign(nn, 0.f);
  G.ion_density.assign(nn, 0.f);
  G.conductors.clear();
  for (const CsmConductor& c : cs) G.conductors.push_back(GridConductor{c.cx, c.cy, c.R, c.V});
}

}  // namespace

const CoronaSolution& CoronaField::solve(const CoronaSetup& st) {
  double nxd, nyd;
  validateSetup(st, nxd, nyd);
  sol_ = CoronaSolution{};
  const real Eon = peekOnsetField(st.wire.R, st.rel_air_density, st.roughness);
  sol_.wire_field_on = Eon;

  CsmField csm;
  const real ePerVolt = csmModel(st, csm, charges_, conductors_, phiInf_);
  const real sgn = st.U < 0 ? real(-1) : real(1);
  const real absU = std::fabs(st.U);
  sol_.onset_voltage = sgn * Eon / ePerVolt;
  sol_.laplace_wire_field = ePerVolt * absU;

  setConformalProblem(prob_, st, Eon);
  std::vector<int> counts;
  for (size_t k = 0; k < conductors_.size(); ++k) counts.push_back(csm.chargeCount(int(k)));
  const auto lap = std::make_shared<const CsmExpansion>(charges_, counts, conductors_, double(phiInf_));
  prob_.laplace = [lap](real x, real y, real& ph, real& ex, real& ey) {
    double a, b, c;
    lap->eval(x, y, a, b, c);
    ph = real(a);
    ex = real(b);
    ey = real(c);
  };
  res_ = solveConformalCorona(prob_);
  sol_.ionised = res_.ionised;
  sol_.iterations = res_.iterations;
  sol_.kaptzov_error = res_.kaptzov_error;
  sol_.injection_density = res_.injection_density;
  sol_.current_per_m = res_.current;
  sol_.current_drum = res_.current_drum;
  sol_.current_far = res_.current_far;

  initGrid(sol_.grid, st, nxd, nyd, conductors_);
  GridSampler{conductors_, *lap, prob_, res_, 2 * st.spacing}.run(sol_.grid);
  return sol_;
}

}  // namespace ces
}  // namespace dvi
