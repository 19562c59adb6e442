// The steady ionised (corona) field of the CES machine: Peek's onset field, the onset voltage, and the
// unipolar space-charge field of the corona wire, solved on a boundary-fitted conformal grid and sampled
// onto a Cartesian grid that the particle loop reads (host or device). docs/CES_FIELD.md describes the
// model, the discretisation and the measured accuracy.
//
// Model (2D cross-section, z along the drum axis):
//   lap(phi) = -rho/eps0,  div(rho mu E) = 0,  E = -grad phi,
//   phi = 0 on the drum, phi = U on the wire and on the tube, the far field floats (zero net charge, as in
//   the CSM Laplace model of field_csm.h); unipolar ions of the wire's polarity (rho has the sign of U);
//   Kaptzov's condition: above onset the wire's surface field stays at Peek's onset value E_on, which
//   fixes the ion density injected at the wire. Below onset rho = 0 and the field is the Laplace field.
// References: F. W. Peek, "Dielectric Phenomena in High-Voltage Engineering", 3rd ed., McGraw-Hill 1929,
// ch. II-III (onset gradient of coaxial cylinders); N. A. Kaptzov, "Elektricheskie yavleniya v gazakh i
// vakuume", Moscow 1947 (surface field held at onset); J. R. McDonald, W. B. Smith, H. W. Spencer,
// L. E. Sparks, "A mathematical model for calculating electrical conditions in wire-duct electrostatic
// precipitation devices", J. Appl. Phys. 48 (1977) 2231-2243, and G. A. Kallio, D. E. Stock, "Interaction
// of electrostatic and fluid dynamic fields in wire-plate electrostatic precipitators", J. Fluid Mech. 240
// (1992) 133-166 (the Poisson <-> charge-continuity iteration with the injection density adjusted until
// Kaptzov's condition holds).
#pragma once

#include <cmath>
#include <cstdint>
#include <functional>
#include <vector>

#include "ces/ces_constants.h"
#include "ces/field/field_common.h"
#include "ces/field/field_csm.h"

namespace dvi {
namespace ces {

// ---------------------------------------------------------------------------------------------------
// Peek's law. The onset (visual critical) surface field of a smooth wire of radius r in a coaxial
// cylinder, Peek 1929: g_v = 31 m delta (1 + 0.308 / sqrt(delta r)) kV/cm with r in cm, i.e. in SI
//     E_on = E0 m delta (1 + K / sqrt(delta r)),  E0 = 3.1e6 V/m,  K = 0.0308 m^0.5
// (0.308 cm^0.5 = 0.308 * 0.1 m^0.5). delta = relative air density (p / 101.325 kPa) (298 K / T), 1 at
// 25 C and 1 atm; m = surface roughness factor (1 polished, 0.98-0.93 weathered, ~0.85 stranded: Peek 1929).
// The coaxial form is used: the field round a 0.1-0.3 mm wire is that of a coaxial one to within r/d.
constexpr real kPeekE0 = real(3.1e6);  // V/m
constexpr real kPeekK = real(0.0308);  // m^0.5
// Mobility of negative air ions at 1 atm, 20-25 C: 1.8-2.2e-4 m^2/(V s) (e.g. McDonald et al. 1977 use
// 2.2e-4; K. Adamiak, P. Atten, J. Electrostatics 61 (2004) 85-98 use 2.1e-4 for positive ions).
constexpr real kNegativeAirIonMobility = real(2.0e-4);  // m^2/(V s)

DVI_HD real peekOnsetField(real wire_radius, real rel_air_density = real(1), real roughness = real(1)) {
  return kPeekE0 * roughness * rel_air_density * (real(1) + kPeekK / std::sqrt(rel_air_density * wire_radius));
}

// ---------------------------------------------------------------------------------------------------
// The Cartesian sampling that the particle loop reads. Node (i, j) at (x0 + i dx, y0 + j dy), arrays of
// nx*ny floats indexed j*nx + i. Up to 3 conductors (drum, wire, tube, in that order: region 1, 2, 3 as in
// FieldSample); a point inside conductor k gets phi = V_k, E = 0, region k+1. Nodes just inside a
// conductor hold the exterior field continued inwards, so that bilinear interpolation stays accurate up to
// the surface. Outside the box the position is clamped to the box.
struct GridConductor {
  real cx, cy, R, V;
};
struct GridFieldView {  // plain data, device-copyable; pointers point to host or device arrays
  real x0, y0, dx, dy;
  int32_t nx, ny;
  const float* Ex;
  const float* Ey;
  const float* phi;
  const float* ion_density;  // ions per m^3 (|rho| / e)
  int32_t nConductors;
  GridConductor conductors[3];
};

namespace detail {
// Bilinear weights of p in the grid (clamped to the box): the lower-left node index and the fractions.
DVI_HD void gridCell(const GridFieldView& g, real px, real py, int32_t& k, real& fx, real& fy) {
  real u = (px - g.x0) / g.dx, v = (py - g.y0) / g.dy;
  const real umax = real(g.nx - 1), vmax = real(g.ny - 1);
  u = u < real(0) ? real(0) : (u > umax ? umax : u);
  v = v < real(0) ? real(0) : (v > vmax ? vmax : v);
  int32_t i = int32_t(u), j = int32_t(v);
  if (i > g.nx - 2) i = g.nx - 2;
  if (j > g.ny - 2) j = g.ny - 2;
  fx = u - real(i);
  fy = v - real(j);
  k = j * g.nx + i;
}
DVI_HD real bilinear(const float* a, int32_t k, int32_t nx, real fx, real fy) {
  return (real(1) - fy) * ((real(1) - fx) * real(a[k]) + fx * real(a[k + 1])) +
         fy * ((real(1) - fx) * real(a[k + nx]) + fx * real(a[k + nx + 1]));
}
DVI_HD int gridRegion(const GridFieldView& g, real px, real py) {
  for (int32_t c = 0; c < g.nConductors; ++c) {
    const real dx = px - g.conductors[c].cx, dy = py - g.conductors[c].cy;
    if (dx * dx + dy * dy < g.conductors[c].R * g.conductors[c].R) return c + 1;
  }
  return 0;
}
}  // namespace detail

// Bilinear interpolation of the sampled field: E in V/m, phi in V.
DVI_HD FieldSample evalGrid(const GridFieldView& g, Vec3 p) {
  const int region = detail::gridRegion(g, p.x, p.y);
  if (region > 0) return FieldSample{g.conductors[region - 1].V, Vec3{0, 0, 0}, region};
  int32_t k;
  real fx, fy;
  detail::gridCell(g, p.x, p.y, k, fx, fy);
  FieldSample s;
  s.region = 0;
  s.phi = detail::bilinear(g.phi, k, g.nx, fx, fy);
  s.E = Vec3{detail::bilinear(g.Ex, k, g.nx, fx, fy), detail::bilinear(g.Ey, k, g.nx, fx, fy), real(0)};
  return s;
}

// Ion number density (|rho|/e, per m^3, >= 0) at p; 0 inside conductors.
DVI_HD real ionDensityAt(const GridFieldView& g, Vec3 p) {
  if (detail::gridRegion(g, p.x, p.y) > 0) return real(0);
  int32_t k;
  real fx, fy;
  detail::gridCell(g, p.x, p.y, k, fx, fy);
  const real n = detail::bilinear(g.ion_density, k, g.nx, fx, fy);
  return n > real(0) ? n : real(0);
}

// Owning storage of a sampled field.
struct GridField {
  real x0 = 0, y0 = 0, dx = 0, dy = 0;
  int32_t nx = 0, ny = 0;
  std::vector<float> Ex, Ey, phi, ion_density;
  std::vector<GridConductor> conductors;
  GridFieldView view() const;
};

// ---------------------------------------------------------------------------------------------------
// The conformal grids. z = x + i y, w = sigma + i tau, z = origin + e^{i theta} f(w), f holomorphic, so
// lap_z = |f'|^-2 lap_w and the scale factor is h = |f'(w)|:
//   Bipolar (drum and wire, two disjoint circles): f(w) = a (1 + e^{iw}) / (1 - e^{iw}), the foci at -a
//   (inside the drum, tau < 0) and +a (inside the wire, tau > 0), h = a / (cosh tau - cos sigma), the circle
//   tau = c has centre a coth c and radius a / |sinh c|, the point at infinity is w = 0
//   (W. R. Smythe, "Static and Dynamic Electricity", 3rd ed. 1968, §4.13; P. Moon, D. E. Spencer, "Field
//   Theory Handbook", Springer 1961, p. 91).
//   LogPolar (coaxial wire in a cylinder): f(w) = e^{-iw} = e^{tau - i sigma}, h = e^tau, tau = ln r.
// sigma is periodic on (-pi, pi]; tau runs from tau_drum (phi = 0) to tau_wire (phi = U).
struct ConformalMap {
  enum Kind { Bipolar, LogPolar };
  Kind kind = Bipolar;
  real a = 1;                       // bipolar focal half-distance, m
  real ox = 0, oy = 0;              // origin of f (foci midpoint / coaxial centre)
  real ct = 1, st = 0;              // cos, sin of the rotation theta
  real tau_drum = 0, tau_wire = 1;  // the two boundaries

  // Drum circle (cx, cy, R) and wire circle (cx, cy, r), disjoint: bipolar map. Throws InputError.
  static ConformalMap bipolar(real dcx, real dcy, real dR, real wcx, real wcy, real wr);
  // Wire of radius r0 coaxial inside a drum (outer cylinder) of radius R, centred at (cx, cy).
  static ConformalMap logPolar(real cx, real cy, real R, real r0);

  void toPhysical(real sigma, real tau, real& x, real& y) const;
  void toComputational(real x, real y, real& sigma, real& tau) const;
  // f'(w) rotated to the physical frame (e^{i theta} f'), as (re, im); h = |f'|.
  void derivative(real sigma, real tau, real& re, real& im) const;
  real scale(real sigma, real tau) const;
};

// The coupled problem on a conformal grid: cells (i, j), i = 0..n_sigma-1 at sigma_i = -pi + (i + 1/2) ds,
// j = 0..n_tau-1 at tau_j = tau_drum + (j + 1/2) dt (j = 0 next to the drum, n_tau-1 next to the wire).
// Cells whose centre lies inside the tube are Dirichlet (phi = U) and carry no ions; ions reaching a cell
// farther than frame_radius from the drum axis leave the model there (the far-field current).
struct ConformalCoronaProblem {
  ConformalMap map;
  int n_sigma = 128, n_tau = 192;
  real U = -30000;          // V, the wire and tube potential; the drum is at 0
  real wire_radius = 1e-4;  // m (the tau_wire circle)
  real E_on = 0;            // V/m, Kaptzov's surface field
  real mobility = kNegativeAirIonMobility;
  bool tube = false;
  real tube_cx = 0, tube_cy = 0, tube_R = 0;
  real frame_cx = 0, frame_cy = 0, frame_radius = 1;  // m; <= 0: no far-field sink
  bool frame_earthed = true;  // the frame cells are Dirichlet phi = 0 for the space-charge potential
  real tolerance = 1e-4;      // on max |change of the space-charge potential| / |U| per iteration
  int max_iterations = 300;
  real relaxation = 0.4;  // damping of the (Anderson-accelerated) update of the space-charge potential
  // The Laplace field (phi, Ex, Ey at a point of the gas). Empty: the solver solves Laplace's equation on
  // the conformal grid itself (exact on the coaxial grid, where phi is linear in tau).
  std::function<void(real x, real y, real& phi, real& Ex, real& Ey)> laplace;
};

struct ConformalCoronaResult {
  bool ionised = false;
  real onset_voltage = 0;       // V, signed like U: where the mean Laplace surface field of the wire is E_on
  real laplace_wire_field = 0;  // V/m, mean Laplace surface field of the wire at U
  real injection_density = 0;   // C/m^3, |rho| injected at the wire
  real current = 0;             // A/m, injected at the wire
  real current_drum = 0, current_far = 0, current_tube = 0;          // A/m, where it goes
  real wire_field_mean = 0, wire_field_min = 0, wire_field_max = 0;  // V/m, total surface field
  real kaptzov_error = 0;                                            // max_i |E_wire(sigma_i) / E_on - 1|
  real space_charge = 0;                                             // C/m, total |rho| dA
  int iterations = 0;
  real last_change = 0;  // max |change| / |U| of the last iteration
  // Per cell (index j * n_sigma + i): potential of the space charge alone (zero on all conductors), the
  // Laplace potential, the ion charge density |rho| (C/m^3); cell kind 0 gas, 1 tube, 2 far-field sink.
  std::vector<real> phi_sc, phi_laplace, rho;
  std::vector<uint8_t> kind;
  // Per sigma_i: the total surface field of the wire (V/m, magnitude of the normal component).
  std::vector<real> wire_field;
  // Sampling table for sampleConformal: (n_tau + 2) rows of n_sigma entries, row 0 on the drum, rows
  // 1..n_tau the cell centres, row n_tau + 1 on the wire; 4 values each: the space-charge potential in
  // the ion-potential convention psi = -sign(U) phi, its sigma- and tau-derivatives, and |rho|.
  std::vector<real> table;
};

// Solves the problem; throws InputError on bad input. Host only.
ConformalCoronaResult solveConformalCorona(const ConformalCoronaProblem& p);

// Evaluation of a conformal solution at a physical point (host): the space-charge part of the potential
// and field, and |rho|, bilinear on the cell centres (in sigma, tau; the field via f'), with the boundary
// rows (drum, wire) added. Inside the drum or the wire it returns the surface values at the same sigma.
struct ConformalSample {
  real phi_sc, Ex_sc, Ey_sc;  // V, V/m
  real rho_abs;               // |rho|, C/m^3
};
ConformalSample sampleConformal(const ConformalCoronaProblem& p, const ConformalCoronaResult& r, real x, real y);

// ---------------------------------------------------------------------------------------------------
// The CES machine: drum, wire, optional tube.
struct CoronaCylinder {
  real cx = 0, cy = 0, R = 0;  // m
  bool present = true;
};

struct CoronaSetup {
  CoronaCylinder drum{real(0), real(0), real(0.160), true};
  // Default wire: 0.2 mm diameter, 60 mm from the drum surface at 60 deg; default tube: 38 mm at 0.267 m, 30 deg
  // (the old demo machine's). A stand-alone problem's geometry [assumed]: the CES machine sets both from its
  // configuration (CesConfig::wire, tube; the config's defaults are the machine's).
  CoronaCylinder wire{real(0.110), real(0.190526), real(1e-4), true};
  CoronaCylinder tube{real(0.231229), real(0.1335), real(0.019), true};
  real U = real(-30000);                        // V, wire and tube (one supply); drum earthed
  real ion_mobility = kNegativeAirIonMobility;  // m^2/(V s)
  real rel_air_density = 1;
  real roughness = 1;
  // The Cartesian box and its node spacing (m).
  real box_x0 = real(-0.25), box_x1 = real(0.45), box_y0 = real(-0.40), box_y1 = real(0.25);
  real spacing = real(1e-3);
  // Conformal grid resolution and the iteration's tolerance (see ConformalCoronaProblem).
  int n_sigma = 128, n_tau = 192;
  real tolerance = real(1e-4);
  real relaxation = real(0.4);
  int max_iterations = 300;
  bool frame_earthed = true;
  real frame_radius = real(1.0);  // m from the drum axis: ions beyond are collected by the (earthed) frame
};

struct CoronaSolution {
  bool ionised = false;
  real onset_voltage = 0;      // V, signed like U
  real wire_field_on = 0;      // E_on, V/m
  real current_per_m = 0;      // A/m, the ion current per metre of wire (into the drum + far field)
  real injection_density = 0;  // C/m^3 at the wire (magnitude)
  int iterations = 0;
  real kaptzov_error = 0;                  // max over the wire surface of |E / E_on - 1| (0 below onset)
  real current_drum = 0, current_far = 0;  // A/m
  real laplace_wire_field = 0;             // V/m, mean Laplace surface field of the wire at U (CSM)
  GridField grid;
};

class CoronaField {
 public:
  // Throws InputError on bad input (a non-positive radius, overlapping cylinders, an empty box, ...).
  const CoronaSolution& solve(const CoronaSetup& setup);
  const CoronaSolution& solution() const { return sol_; }
  GridFieldView view() const { return sol_.grid.view(); }
  // Host evaluation without the Cartesian grid: CSM Laplace field + the conformal space-charge field.
  FieldSample evalFine(Vec3 p) const;
  real ionDensityFine(Vec3 p) const;  // ions per m^3
  const ConformalCoronaProblem& problem() const { return prob_; }
  const ConformalCoronaResult& conformal() const { return res_; }
  // The CSM Laplace model (drum, wire, tube at U).
  FieldSample evalLaplace(Vec3 p) const;

 private:
  CoronaSolution sol_;
  ConformalCoronaProblem prob_;
  ConformalCoronaResult res_;
  std::vector<CsmLineCharge> charges_;  // the CSM Laplace model at U (drum, wire, tube)
  std::vector<CsmConductor> conductors_;
  real phiInf_ = 0;
};

}  // namespace ces
}  // namespace dvi
