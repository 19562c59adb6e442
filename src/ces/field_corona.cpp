// The ionised field of the corona wire: conformal-grid solver and Cartesian sampling (see field_corona.h
// and docs/CES_FIELD.md for the model and the references).
#include "ces/field_corona.h"

#include <eigen3/Eigen/Sparse>
#include <eigen3/Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>
#include <complex>
#include <numeric>
#include <string>

#include "chrono_like/errors.h"

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
  m.tau_wire = real(std::asinh(a / wr));   // circle radius a / sinh(tau)
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
  const cplx zeta = std::conj(cplx(ct, st)) * cplx(double(x) - ox, double(y) - oy);
  if (kind == Bipolar) {
    const cplx u = (zeta - double(a)) / (zeta + double(a));  // u = e^{iw}
    sigma = real(std::arg(u));
    tau = real(-std::log(std::abs(u)));
  } else {
    sigma = real(-std::arg(zeta));
    tau = real(std::log(std::abs(zeta)));
  }
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
// 2 pi r eps0) equals E_on, then the space-charge potential is under-relaxed and the transport redone
// until the potential stops changing.
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

// Derivative at 0 of the parabola through (-h1, fa), (0, f0), (h2, fb).
double d3(double fa, double f0, double fb, double h1, double h2) {
  return (h1 * h1 * fb - h2 * h2 * fa + (h2 * h2 - h1 * h1) * f0) / (h1 * h2 * (h1 + h2));
}

}  // namespace

ConformalCoronaResult solveConformalCorona(const ConformalCoronaProblem& p) {
  if (p.n_sigma < 8 || p.n_tau < 4 || p.n_sigma > 4096 || p.n_tau > 4096)
    throw InputError("corona grid: n_sigma must lie in [8, 4096] and n_tau in [4, 4096]");
  if (!finite(p.U) || !(p.wire_radius > 0) || !(p.E_on > 0) || !finite(p.E_on) || !(p.mobility > 0) ||
      !finite(p.mobility))
    throw InputError("corona solver: U must be finite, the wire radius, E_on and the ion mobility positive");
  if (!(p.tolerance > 0) || p.max_iterations < 1 || !(p.relaxation > 0 && p.relaxation <= 1))
    throw InputError("corona solver: tolerance must be positive, max_iterations >= 1, relaxation in (0, 1]");
  if (p.tube && !(p.tube_R > 0)) throw InputError("corona solver: the tube radius must be positive");

  Grid g;
  g.ns = p.n_sigma;
  g.nt = p.n_tau;
  g.map = &p.map;
  g.ds = 2 * kPiD / g.ns;
  g.dt = (double(p.map.tau_wire) - double(p.map.tau_drum)) / g.nt;
  g.adt = std::fabs(g.dt);
  if (!(g.adt > 0)) throw InputError("corona grid: the drum and wire boundaries coincide");
  g.cs = g.adt / g.ds;
  g.ctau = g.ds / g.adt;
  const int n = g.ns * g.nt;
  const double s = p.U < 0 ? -1.0 : 1.0;
  const double absU = std::fabs(double(p.U));
  const double psiWire = -absU;

  ConformalCoronaResult r;
  r.kind.assign(n, 0);
  std::vector<double> xs(n), ys(n), h2(n);
  for (int j = 0; j < g.nt; ++j)
    for (int i = 0; i < g.ns; ++i) {
      const int q = g.idx(i, j);
      real x, y;
      p.map.toPhysical(real(g.sigma(i)), real(g.tau(j)), x, y);
      xs[q] = x;
      ys[q] = y;
      const double h = p.map.scale(real(g.sigma(i)), real(g.tau(j)));
      h2[q] = h * h;
      if (p.tube && std::hypot(x - double(p.tube_cx), y - double(p.tube_cy)) < p.tube_R)
        r.kind[q] = 1;
      else if (p.frame_radius > 0 && std::hypot(x - double(p.frame_cx), y - double(p.frame_cy)) > p.frame_radius)
        r.kind[q] = 2;
    }

  // Unknown numbering (tube cells are not unknowns) and the Poisson matrix A = -Laplacian (SPD).
  std::vector<int> unk(n, -1);
  int nu = 0;
  for (int q = 0; q < n; ++q)
    if (r.kind[q] == 0 || (r.kind[q] == 2 && !p.frame_earthed)) unk[q] = nu++;
  if (nu == 0) throw InputError("corona grid: the tube covers the whole grid");
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(size_t(nu) * 5);
  // Boundary coefficient of each unknown towards the wire / tube (psi = -|U|), for the Laplace RHS.
  std::vector<double> bWire(nu, 0.0);
  for (int j = 0; j < g.nt; ++j)
    for (int i = 0; i < g.ns; ++i) {
      const int q = g.idx(i, j);
      if (unk[q] < 0) continue;
      double diag = 0;
      auto link = [&](int nbq, double c) {
        diag += c;
        if (unk[nbq] >= 0)
          trip.emplace_back(unk[q], unk[nbq], -c);
        else if (r.kind[nbq] == 1)
          bWire[unk[q]] += c;  // tube neighbour (psi = -|U|); an earthed frame cell adds nothing (psi = 0)
      };
      link(g.idx(g.wrap(i - 1), j), g.cs);
      link(g.idx(g.wrap(i + 1), j), g.cs);
      if (j > 0)
        link(g.idx(i, j - 1), g.ctau);
      else
        diag += 2 * g.ctau;  // drum face, psi = 0
      if (j < g.nt - 1)
        link(g.idx(i, j + 1), g.ctau);
      else {
        diag += 2 * g.ctau;  // wire face, psi = -|U|
        bWire[unk[q]] += 2 * g.ctau;
      }
      trip.emplace_back(unk[q], unk[q], diag);
    }
  Eigen::SparseMatrix<double> A(nu, nu);
  A.setFromTriplets(trip.begin(), trip.end());
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt(A);
  if (ldlt.info() != Eigen::Success) throw InputError("corona solver: the Poisson matrix could not be factorised");

  // Laplace potential (psi convention) at the cell centres and the Laplace surface field of the wire.
  std::vector<double> psiLap(n, psiWire);
  std::vector<double> gLap(g.ns), hWire(g.ns);
  for (int i = 0; i < g.ns; ++i) hWire[i] = p.map.scale(real(g.sigma(i)), p.map.tau_wire);
  const double dirOut = g.dt > 0 ? -1.0 : 1.0;  // the wire's outward normal points along dirOut * tau
  auto wireNormalDeriv = [&](const std::vector<double>& f, double f0, int i) {
    // d f / d(distance from the wire) at the wire, per unit tau (one-sided parabola).
    const double f1 = f[g.idx(i, g.nt - 1)], f2 = f[g.idx(i, g.nt - 2)];
    return (9 * (f1 - f0) - (f2 - f0)) / (3 * g.adt);
  };
  if (p.laplace) {
    for (int q = 0; q < n; ++q) {
      if (r.kind[q] == 1) continue;
      real ph, ex, ey;
      p.laplace(real(xs[q]), real(ys[q]), ph, ex, ey);
      psiLap[q] = -s * ph;
    }
    for (int i = 0; i < g.ns; ++i) {
      real x, y, ph, ex, ey, fr, fi;
      p.map.toPhysical(real(g.sigma(i)), p.map.tau_wire, x, y);
      p.laplace(x, y, ph, ex, ey);
      p.map.derivative(real(g.sigma(i)), p.map.tau_wire, fr, fi);
      // dz/dtau = i f'; the outward normal is dirOut * i f' / |f'|.
      const double nx = -dirOut * fi / hWire[i], ny = dirOut * fr / hWire[i];
      gLap[i] = s * (ex * nx + ey * ny);
    }
  } else {
    Eigen::VectorXd b(nu);
    for (int k = 0; k < nu; ++k) b(k) = bWire[k] * psiWire;
    const Eigen::VectorXd x = ldlt.solve(b);
    for (int q = 0; q < n; ++q)
      psiLap[q] = unk[q] >= 0 ? x(unk[q]) : (r.kind[q] == 1 ? psiWire : 0.0);
    for (int i = 0; i < g.ns; ++i) gLap[i] = wireNormalDeriv(psiLap, psiWire, i) / hWire[i];
  }
  double sumH = 0, sumGL = 0;
  for (int i = 0; i < g.ns; ++i) {
    sumH += hWire[i];
    sumGL += gLap[i] * hWire[i];
  }
  const double gLapMean = sumGL / sumH;  // arc-length mean = wire charge / (2 pi r eps0)
  r.laplace_wire_field = real(gLapMean);
  r.onset_voltage = real(gLapMean > 0 ? double(p.U) * p.E_on / gLapMean : 0.0);
  r.phi_laplace.assign(n, 0);
  for (int q = 0; q < n; ++q) r.phi_laplace[q] = real(-s * psiLap[q]);
  r.phi_sc.assign(n, 0);
  r.rho.assign(n, 0);
  r.wire_field.assign(g.ns, 0);
  std::vector<double> psiSc(n, 0.0), rhoHat, inflow, psiHat(n, 0.0), psi(n);
  double rho0 = 0;
  Currents cur;
  std::vector<int> order;
  order.reserve(nu);
  // Injection profile round the wire (arc-length mean 1): adjusted so that the local surface field, not
  // only its mean, reaches E_on.
  std::vector<double> shape(g.ns, 1.0);

  r.ionised = gLapMean > p.E_on;
  if (r.ionised) {
    auto transport = [&](double injection) {
      for (int q = 0; q < n; ++q) psi[q] = r.kind[q] == 1 ? psiWire : psiLap[q] + psiSc[q];
      order.clear();
      for (int q = 0; q < n; ++q)
        if (r.kind[q] != 1) order.push_back(q);
      std::sort(order.begin(), order.end(), [&](int a, int b) { return psi[a] < psi[b]; });
      return sweep(g, psi, r.kind, psiWire, injection, shape, order, rhoHat, inflow);
    };
    Eigen::VectorXd b(nu);
    for (int it = 1; it <= p.max_iterations; ++it) {
      transport(1.0);
      // Space-charge potential of the unit injection: A psi = -|rho| h^2 ds dt / eps0 (zero on conductors).
      const double cellArea = g.ds * g.adt;
      for (int q = 0; q < n; ++q)
        if (unk[q] >= 0) b(unk[q]) = -rhoHat[q] * h2[q] * cellArea / double(kEps0);
      const Eigen::VectorXd x = ldlt.solve(b);
      for (int q = 0; q < n; ++q) psiHat[q] = unk[q] >= 0 ? x(unk[q]) : 0.0;
      double sumG = 0;
      for (int i = 0; i < g.ns; ++i) sumG += wireNormalDeriv(psiHat, 0.0, i);  // (1/h) * h ds cancels
      const double gHatMean = sumG / sumH;  // < 0: the ions screen the wire
      const double rho0Star = gHatMean < 0 ? (double(p.E_on) - gLapMean) / gHatMean : 0.0;
      // Local Kaptzov: raise the injection where the surface field is above E_on, lower it where below, in
      // proportion to the excess over the screening the ions provide there, (E - E_on) / (E_Laplace - E_on);
      // the gain (4) is over-relaxed because the field at one angle feels only part of the charge injected
      // there (the rest of its screening comes from the ions of the whole wire). Keep the mean at 1.
      double sw = 0;
      for (int i = 0; i < g.ns; ++i) {
        const double gi = gLap[i] + rho0Star * wireNormalDeriv(psiHat, 0.0, i) / hWire[i];
        const double screen = std::max(gLap[i] - double(p.E_on), 1e-3 * double(p.E_on));
        shape[i] = std::max(0.0, shape[i] * (1 + kShapeGain * (gi - double(p.E_on)) / screen));
        sw += shape[i] * hWire[i];
      }
      if (sw > 0)
        for (int i = 0; i < g.ns; ++i) shape[i] *= sumH / sw;
      double change = 0;
      for (int q = 0; q < n; ++q) {
        const double target = rho0Star * psiHat[q];
        change = std::max(change, std::fabs(target - psiSc[q]));
        psiSc[q] += p.relaxation * (target - psiSc[q]);
      }
      rho0 = rho0Star;
      r.iterations = it;
      r.last_change = real(change / absU);
      if (change / absU < p.tolerance) {
        for (int q = 0; q < n; ++q) psiSc[q] = rho0Star * psiHat[q];
        break;
      }
    }
    // The final transport on the converged potential gives the reported density and currents.
    cur = transport(rho0);
    r.injection_density = real(rho0);
    r.current = real(cur.injected * p.mobility);
    r.current_drum = real(cur.drum * p.mobility);
    r.current_far = real(cur.far * p.mobility);
    r.current_tube = real((cur.tube + cur.trapped) * p.mobility);
    double q = 0;
    for (int k = 0; k < n; ++k) {
      r.rho[k] = real(rhoHat[k]);
      q += rhoHat[k] * h2[k] * g.ds * g.adt;
    }
    r.space_charge = real(q);
  }

  // Total wire surface field and Kaptzov's error.
  double wmin = 1e300, wmax = -1e300, wsum = 0;
  for (int i = 0; i < g.ns; ++i) {
    const double e = gLap[i] + wireNormalDeriv(psiSc, 0.0, i) / hWire[i];
    r.wire_field[i] = real(e);
    wmin = std::min(wmin, e);
    wmax = std::max(wmax, e);
    wsum += e * hWire[i];
  }
  r.wire_field_mean = real(wsum / sumH);
  r.wire_field_min = real(wmin);
  r.wire_field_max = real(wmax);
  r.kaptzov_error = r.ionised ? real(std::max(std::fabs(wmin / p.E_on - 1), std::fabs(wmax / p.E_on - 1))) : 0;
  for (int q = 0; q < n; ++q) r.phi_sc[q] = real(-s * psiSc[q]);

  // Sampling table: rows 0 (drum), 1..nt (cells), nt+1 (wire); (psi_sc, dpsi/dsigma, dpsi/dtau, |rho|).
  const int rows = g.nt + 2;
  r.table.assign(size_t(rows) * g.ns * 4, 0);
  auto T = [&](int row, int i, int c) -> real& { return r.table[(size_t(row) * g.ns + i) * 4 + c]; };
  auto val = [&](int i, int j) { return psiSc[g.idx(g.wrap(i), j)]; };  // tube cells hold 0
  for (int j = 0; j < g.nt; ++j)
    for (int i = 0; i < g.ns; ++i) {
      const int q = g.idx(i, j);
      if (r.kind[q] == 1) continue;
      const double f0 = psiSc[q];
      const double dsg = (val(i + 1, j) - val(i - 1, j)) / (2 * g.ds);
      double dtu;
      if (g.nt == 1)
        dtu = 0;
      else if (j == 0)
        dtu = d3(0.0, f0, val(i, 1), 0.5 * g.dt, g.dt);
      else if (j == g.nt - 1)
        dtu = d3(val(i, j - 1), f0, 0.0, g.dt, 0.5 * g.dt);
      else
        dtu = (val(i, j + 1) - val(i, j - 1)) / (2 * g.dt);
      T(j + 1, i, 0) = real(f0);
      T(j + 1, i, 1) = real(dsg);
      T(j + 1, i, 2) = real(dtu);
      T(j + 1, i, 3) = r.rho[q];
    }
  // Tube cells: the gradient continued from their gas neighbours (keeps the bilinear sampling of the gas
  // next to the staircase tube boundary smooth); potential 0 and no ions.
  for (int j = 0; j < g.nt; ++j)
    for (int i = 0; i < g.ns; ++i) {
      if (r.kind[g.idx(i, j)] != 1) continue;
      double a1 = 0, a2 = 0;
      int cnt = 0;
      const int nbi[4] = {g.wrap(i - 1), g.wrap(i + 1), i, i};
      const int nbj[4] = {j, j, j - 1, j + 1};
      for (int k = 0; k < 4; ++k) {
        if (nbj[k] < 0 || nbj[k] >= g.nt || r.kind[g.idx(nbi[k], nbj[k])] == 1) continue;
        a1 += T(nbj[k] + 1, nbi[k], 1);
        a2 += T(nbj[k] + 1, nbi[k], 2);
        ++cnt;
      }
      if (cnt) {
        T(j + 1, i, 1) = real(a1 / cnt);
        T(j + 1, i, 2) = real(a2 / cnt);
      }
    }
  for (int i = 0; i < g.ns; ++i) {
    if (g.nt >= 2) {
      T(0, i, 2) = real((9 * val(i, 0) - val(i, 1)) / (3 * g.dt));
      T(g.nt + 1, i, 2) = real(-(9 * val(i, g.nt - 1) - val(i, g.nt - 2)) / (3 * g.dt));
    }
    T(0, i, 3) = r.rho[g.idx(i, 0)];
    T(g.nt + 1, i, 3) = real(rho0);
  }
  return r;
}

ConformalSample sampleConformal(const ConformalCoronaProblem& p, const ConformalCoronaResult& r, real x, real y) {
  const int ns = p.n_sigma, nt = p.n_tau;
  real sg, ta;
  p.map.toComputational(x, y, sg, ta);
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
    v[c] = (1 - wy) * ((1 - wx) * at(r0, i0) + wx * at(r0, i1)) + wy * ((1 - wx) * at(r0 + 1, i0) + wx * at(r0 + 1, i1));
  }
  const double tc = std::min(std::max(double(ta), std::min(double(p.map.tau_drum), double(p.map.tau_wire))),
                             std::max(double(p.map.tau_drum), double(p.map.tau_wire)));
  real fr, fi;
  p.map.derivative(sg, real(tc), fr, fi);
  // grad_z psi = G_w / conj(F'),  G_w = psi_sigma + i psi_tau.
  const cplx grad = cplx(v[1], v[2]) / std::conj(cplx(fr, fi));
  const double s = p.U < 0 ? -1.0 : 1.0;
  ConformalSample out;
  out.phi_sc = real(-s * v[0]);
  out.Ex_sc = real(s * grad.real());  // E = -grad phi = s grad psi
  out.Ey_sc = real(s * grad.imag());
  out.rho_abs = real(std::max(0.0, v[3]));
  return out;
}

// ------------------------------------------------------------------------------------------------
// The machine.

GridFieldView GridField::view() const {
  GridFieldView v{};
  v.x0 = x0;
  v.y0 = y0;
  v.dx = dx;
  v.dy = dy;
  v.nx = nx;
  v.ny = ny;
  v.Ex = Ex.data();
  v.Ey = Ey.data();
  v.phi = phi.data();
  v.ion_density = ion_density.data();
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

const CoronaSolution& CoronaField::solve(const CoronaSetup& st) {
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
  const double nxd = std::floor((double(st.box_x1) - st.box_x0) / st.spacing + 1e-9) + 1;
  const double nyd = std::floor((double(st.box_y1) - st.box_y0) / st.spacing + 1e-9) + 1;
  if (nxd * nyd > 5e7) bad("the grid box holds more than 5e7 nodes; raise the spacing");
  if (!(st.tolerance > 0)) bad("tolerance must be positive");

  sol_ = CoronaSolution{};
  const real Eon = peekOnsetField(st.wire.R, st.rel_air_density, st.roughness);
  sol_.wire_field_on = Eon;

  // CSM Laplace model at a unit voltage of U's sign, scaled by |U| (linear in U).
  const real sgn = st.U < 0 ? real(-1) : real(1);
  CsmField csm;
  csm.addCylinder(st.drum.cx, st.drum.cy, st.drum.R, 0);
  csm.addCylinder(st.wire.cx, st.wire.cy, st.wire.R, sgn);
  if (st.tube.present) csm.addCylinder(st.tube.cx, st.tube.cy, st.tube.R, sgn);
  csm.solve();
  const real absU = std::fabs(st.U);
  charges_ = csm.charges();
  for (CsmLineCharge& c : charges_) c.lambda *= absU;
  conductors_ = csm.conductors();
  for (CsmConductor& c : conductors_) c.V *= absU;
  phiInf_ = csm.phiInfinity() * absU;
  // Mean surface field of the wire per volt = its charge per volt / (2 pi eps0 r) (Gauss).
  const real ePerVolt = std::fabs(csm.cylinderCharge(1)) / (2 * kPi * kEps0 * st.wire.R);
  sol_.onset_voltage = sgn * Eon / ePerVolt;
  sol_.laplace_wire_field = ePerVolt * absU;

  prob_ = ConformalCoronaProblem{};
  prob_.map = ConformalMap::bipolar(st.drum.cx, st.drum.cy, st.drum.R, st.wire.cx, st.wire.cy, st.wire.R);
  prob_.n_sigma = st.n_sigma;
  prob_.n_tau = st.n_tau;
  prob_.U = st.U;
  prob_.wire_radius = st.wire.R;
  prob_.E_on = Eon;
  prob_.mobility = st.ion_mobility;
  prob_.tube = st.tube.present;
  prob_.tube_cx = st.tube.cx;
  prob_.tube_cy = st.tube.cy;
  prob_.tube_R = st.tube.R;
  prob_.frame_cx = st.drum.cx;
  prob_.frame_cy = st.drum.cy;
  prob_.frame_radius = st.frame_radius;
  prob_.frame_earthed = st.frame_earthed;
  prob_.tolerance = st.tolerance;
  prob_.relaxation = st.relaxation;
  prob_.max_iterations = st.max_iterations;
  const std::vector<CsmLineCharge>* qs = &charges_;
  const real pinf = phiInf_;
  prob_.laplace = [qs, pinf](real x, real y, real& ph, real& ex, real& ey) {
    csmRaw(qs->data(), int(qs->size()), pinf, x, y, ph, ex, ey);
  };
  res_ = solveConformalCorona(prob_);
  sol_.ionised = res_.ionised;
  sol_.iterations = res_.iterations;
  sol_.kaptzov_error = res_.kaptzov_error;
  sol_.injection_density = res_.injection_density;
  sol_.current_per_m = res_.current;
  sol_.current_drum = res_.current_drum;
  sol_.current_far = res_.current_far;

  // Cartesian sampling: CSM Laplace field (exact) + the conformal space-charge correction.
  GridField& G = sol_.grid;
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
  for (const CsmConductor& c : conductors_) G.conductors.push_back(GridConductor{c.cx, c.cy, c.R, c.V});
  const real reach = 2 * st.spacing;  // nodes this deep inside a conductor hold the continued field
  const bool ion = res_.ionised;
#pragma omp parallel for schedule(dynamic, 4)
  for (int32_t j = 0; j < G.ny; ++j) {
    for (int32_t i = 0; i < G.nx; ++i) {
      const size_t k = size_t(j) * G.nx + i;
      const real x = G.x0 + i * G.dx, y = G.y0 + j * G.dy;
      // The conductor the node lies in (if any) and the point where the space-charge part is sampled.
      int inside = -1;
      real sx = x, sy = y;
      for (size_t c = 0; c < conductors_.size(); ++c) {
        const CsmConductor& cd = conductors_[c];
        const real d = std::hypot(x - cd.cx, y - cd.cy);
        if (d < cd.R) {
          inside = int(c);
          if (d > 0) {
            const real f = (cd.R * (1 + real(1e-9))) / d;
            sx = cd.cx + (x - cd.cx) * f;
            sy = cd.cy + (y - cd.cy) * f;
          }
          break;
        }
      }
      if (inside >= 0 && std::hypot(x - conductors_[inside].cx, y - conductors_[inside].cy) <
                             conductors_[inside].R - reach && inside != 1) {
        G.phi[k] = float(conductors_[inside].V);
        continue;
      }
      real ph, ex, ey;
      csmRaw(charges_.data(), int(charges_.size()), phiInf_, x, y, ph, ex, ey);
      if (ion) {
        const ConformalSample c = sampleConformal(prob_, res_, sx, sy);
        ph += c.phi_sc;
        ex += c.Ex_sc;
        ey += c.Ey_sc;
        G.ion_density[k] = float(c.rho_abs / kElementaryCharge);
      }
      G.phi[k] = float(ph);
      G.Ex[k] = float(ex);
      G.Ey[k] = float(ey);
    }
  }
  return sol_;
}

}  // namespace ces
}  // namespace dvi
