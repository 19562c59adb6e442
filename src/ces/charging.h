// Particle charge models of the CES: induction on the drum, corona (field) charging, charge relaxation
// through the drum contact, brush discharge. All lengths are particle radii r (m), fields in V/m,
// charges in C. Pure DVI_HD functions (host and device).
#pragma once

#include <cmath>
#include <cstdint>

#include "ces/ces_constants.h"
#include "chrono_like/base/math.h"

namespace dvi {
namespace ces {

// Induced charge of a conducting sphere of radius r resting on a grounded electrode in a field whose
// component along the electrode's outward normal is En (signed):
//     q = (2/3) pi^3 eps0 r^2 En   (= (pi^2/6) * 4 pi eps0 r^2 En, about 1.645 * 4 pi eps0 r^2 En).
// N. J. Félici, "Forces et charges de petits objets en contact avec une électrode affectée d'un champ
// électrique", Revue Générale de l'Électricité 75 (1966) 1145-1160; also N. N. Lebedev, I. P.
// Skal'skaya, Sov. Phys. Tech. Phys. 7 (1962) 268. The sign is that of the surface charge
// eps0 E.n of the electrode, so the Coulomb force q E lifts the particle off the drum.
DVI_HD real feliciCharge(real r, real En) { return real(2) / real(3) * kPi * kPi * kPi * kEps0 * r * r * En; }
// Vector form: n is the unit outward normal of the drum at the contact.
DVI_HD real feliciCharge(real r, Vec3 E, Vec3 n) { return feliciCharge(r, dot(E, n)); }

// Force on that sphere, resting on the electrode in the field En: F = (zeta(3) + 1/6) 4 pi eps0 r^2 En^2
// along the normal (Lebedev & Skal'skaya 1962; Félici 1966), the attraction of the sphere's own image
// in the electrode included. In terms of its charge q_F = (pi^2/6) 4 pi eps0 r^2 En:
//     F = k_L q_F En,   k_L = (zeta(3) + 1/6) / (pi^2/6) = 0.8321.
// So the lift is 0.832 q E with the image already in it: no separate image force may be added for a
// conductor in contact. zeta(3) = 1.2020569031595942 (Apéry's constant).
constexpr real kZeta3 = real(1.2020569031595942);
constexpr real kFeliciLiftFactor = (kZeta3 + real(1) / real(6)) / (kPi * kPi / real(6));

// Pauthenier's field-charging factor p = 3 eps_r / (eps_r + 2) (p -> 3 for a conductor, eps_r -> inf).
DVI_HD real pauthenierFactor(real eps_r) {
  if (std::isinf(eps_r)) return real(3);
  return real(3) * eps_r / (eps_r + real(2));
}

// Pauthenier saturation charge (magnitude) of a sphere of radius r in a corona (ionised) field of
// magnitude E:  q_s = 4 pi eps0 r^2 E p,  p = 3 eps_r/(eps_r + 2).
// M. M. Pauthenier, M. Moreau-Hanot, "La charge des particules sphériques dans un champ ionisé",
// J. Phys. Radium 3 (1932) 590-613; H. J. White, "Industrial Electrostatic Precipitation",
// Addison-Wesley 1963, ch. 5. The sign is the polarity of the corona ions (that of the corona
// electrode's potential): the caller multiplies by it.
DVI_HD real pauthenierSaturationCharge(real r, real E, real eps_r) {
  return real(4) * kPi * kEps0 * r * r * std::fabs(E) * pauthenierFactor(eps_r);
}

// Pauthenier's charging time constant tau_c = 4 eps0 / (N0 e mu) for ion number density N0 (1/m^3)
// and ion mobility mu (m^2/(V s)) (Pauthenier & Moreau-Hanot 1932; White 1963, eq. 5.8).
DVI_HD real pauthenierTimeConstant(real ionDensity, real ionMobility) {
  return real(4) * kEps0 / (ionDensity * kElementaryCharge * ionMobility);
}

// Field charging in a constant field: dq/dt = (q_s / tau_c)(1 - q/q_s)^2, whose solution from q = 0 is
// q(t) = q_s t / (t + tau_c) (Pauthenier & Moreau-Hanot 1932). Exact update over a step h of the charge
// q counted in the ions' polarity (q < 0: a particle charged against the ions, which attracts them
// faster, as the same equation says): the equivalent time t0 = tau_c q / (q_s - q) in (-tau_c, inf),
// then q(t0 + h). q >= q_s does not change (field charging stops at saturation); tau_c <= 0 means
// instantaneous saturation.
DVI_HD real pauthenierChargeUpdate(real q, real qs, real h, real tau_c) {
  if (q >= qs) return q;
  if (!(tau_c > real(0))) return qs;
  // q(t0 + h) = qs (t0 + h)/(t0 + h + tau_c) with t0 = tau_c q/(qs - q); rearranged to avoid the
  // division by qs - q: q_new = qs (tau_c q + h (qs - q)) / (tau_c qs + h (qs - q)).
  const real d = qs - q;
  return qs * (tau_c * q + h * d) / (tau_c * qs + h * d);
}

// Charge relaxation time of a material of relative permittivity eps_r and conductivity sigma (S/m):
// tau = eps / sigma = eps0 eps_r / sigma (H. A. Haus, J. R. Melcher, "Electromagnetic Fields and
// Energy", Prentice Hall 1989, §7.7; J. R. Melcher, "Continuum Electromechanics", MIT Press 1981,
// §5.9). sigma <= 0 (a perfect insulator) gives tau = infinity.
DVI_HD real relaxationTime(real eps_r, real sigma) {
  if (!(sigma > real(0))) return real(INFINITY);
  return kEps0 * eps_r / sigma;
}

// Exponential relaxation of a charge q toward q_inf with time constant tau (dq/dt = -(q - q_inf)/tau,
// Haus & Melcher §7.7), advanced exactly over a step h with q_inf held constant:
//     q(t + h) = q_inf + (q - q_inf) exp(-h/tau).
// tau = 0: immediate (q_inf); tau = infinity: unchanged (q).
// On the drum: q_inf = 0 for a corona-charged particle losing its charge to the grounded drum, or the
// Félici charge for a (semi-)conducting particle charging by induction.
DVI_HD real relaxCharge(real q, real q_inf, real h, real tau) {
  if (!(tau > real(0))) return q_inf;
  if (std::isinf(tau)) return q;
  return q_inf + (q - q_inf) * std::exp(-h / tau);
}

// Brush discharge: a particle in contact with the grounded brush relaxes toward zero charge with the
// brush contact time constant tau_brush (relaxCharge with q_inf = 0; tau_brush = 0 removes the charge at
// once, the usual idealisation of a grounded conductive brush).
DVI_HD real brushDischarge(real q, real h, real tau_brush) { return relaxCharge(q, real(0), h, tau_brush); }

// --- Non-liberated (composite) particles: metal in a plastic matrix, volume fraction phi of metal ---

// Continuum percolation threshold (critical volume fraction) of conducting grains in an insulating matrix in
// three dimensions, phi_c = 0.16, and the universal conductivity exponent t = 2 (H. Scher, R. Zallen, "Critical
// density in percolation processes", J. Chem. Phys. 53 (1970) 3759; D. Stauffer, A. Aharony, "Introduction to
// Percolation Theory", 2nd ed., Taylor & Francis 1994, §5.3).
constexpr real kPercolationThreshold = real(0.16);
constexpr real kPercolationExponent = real(2);

// Effective conductivity of the composite, McLachlan's general effective-medium (GEM) equation
//     (1 - phi) (sp^(1/t) - s^(1/t)) / (sp^(1/t) + A s^(1/t)) + phi (sm^(1/t) - s^(1/t)) / (sm^(1/t) + A s^(1/t)) = 0,
//     A = (1 - phi_c) / phi_c,
// (D. S. McLachlan, M. Blaszkiewicz, R. E. Newnham, "Electrical resistivity of composites", J. Am. Ceram. Soc.
// 73 (1990) 2187-2203, eq. 16), which joins the percolation laws: for sp = 0 it is s = sm ((phi - phi_c) /
// (1 - phi_c))^t above phi_c (and 0 below), for sm = inf s = sp (phi_c / (phi_c - phi))^t below; phi = 0 gives
// sp, phi = 1 sm. Solved for s^(1/t) by bisection on its logarithm (the left side falls monotonically in s),
// 100 halvings of [sp, sm]: s to a relative 1e-12 over the 21 decades between copper and a plastic.
DVI_HD real gemConductivity(real phi, real sigma_metal, real sigma_plastic, real phi_c, real t) {
  if (!(phi > real(0))) return sigma_plastic;
  if (!(phi < real(1))) return sigma_metal;
  const double A = (1.0 - double(phi_c)) / double(phi_c), it = 1.0 / double(t);
  const double xp = std::pow(double(sigma_plastic), it), xm = std::pow(double(sigma_metal), it);
  auto f = [&](double x) {
    return (1.0 - double(phi)) * (xp - x) / (xp + A * x) + double(phi) * (xm - x) / (xm + A * x);
  };
  double lo = std::log(xp > 1e-300 ? xp : 1e-300), hi = std::log(xm);
  for (int k = 0; k < 100; ++k) {
    const double mid = 0.5 * (lo + hi);
    (f(std::exp(mid)) > 0 ? lo : hi) = mid;
  }
  return real(std::pow(std::exp(0.5 * (lo + hi)), double(t)));
}

// Relative permittivity of metal grains (perfect conductors) at volume fraction phi in a matrix of eps_m, the
// Maxwell Garnett mixing rule eps = eps_m (1 + 2 phi) / (1 - phi) (J. C. Maxwell Garnett, Phil. Trans. R. Soc.
// A 203 (1904) 385; its limit eps_inclusion -> inf), below the percolation threshold; at and above it the
// composite conducts (returned as inf).
DVI_HD real compositePermittivity(real phi, real eps_matrix, real phi_c) {
  if (phi >= phi_c) return real(INFINITY);
  return eps_matrix * (real(1) + real(2) * phi) / (real(1) - phi);
}

// Charge relaxation time of the composite through a contact, tau = eps0 eps / sigma (relaxationTime) with the
// GEM conductivity and the Maxwell Garnett permittivity (taken at phi_c above the threshold): between the
// metal's (~1e-19 s) and the plastic's (hours), falling by ~20 decades across phi_c.
DVI_HD real compositeRelaxationTime(real phi, real eps_matrix, real sigma_metal, real sigma_plastic) {
  const real phi_e = phi < kPercolationThreshold ? phi : kPercolationThreshold;
  const real eps = eps_matrix * (real(1) + real(2) * phi_e) / (real(1) - phi_e);
  const real s = gemConductivity(phi, sigma_metal, sigma_plastic, kPercolationThreshold, kPercolationExponent);
  return relaxationTime(eps, s);
}

// Conductivity of copper, 5.96e7 S/m at 20 C (CRC Handbook of Chemistry and Physics, 97th ed., 2016, "Electrical
// resistivity of pure metals": 1.68e-8 Ohm m): the metal of the composites.
constexpr real kCopperConductivity = real(5.96e7);

// Relaxation time of a particle of radius r whose charge leaks through its bulk (relaxation time tau_bulk) and
// along its surface (surface conductivity sigma_s, S): the surface conduction adds 2 sigma_s / r to the
// particle's effective conductivity (C. T. O'Konski, "Electric properties of macromolecules. V. Theory of ionic
// polarization in polyelectrolytes", J. Phys. Chem. 64 (1960) 605-619, eq. 13: K = K_bulk + 2 K_s / a), so the
// rates add: 1/tau = 1/tau_bulk + 2 sigma_s / (r eps0 eps_r). sigma_s = 0 leaves tau_bulk; a conductor
// (eps_r = inf) keeps its tau_bulk.
DVI_HD real surfaceRelaxationTime(real tau_bulk, real sigma_s, real r, real eps_r) {
  if (!(sigma_s > real(0)) || std::isinf(eps_r) || !(r > real(0))) return tau_bulk;
  const real rate =
      real(2) * sigma_s / (r * kEps0 * eps_r) + (tau_bulk > real(0) ? real(1) / tau_bulk : real(INFINITY));
  return real(1) / rate;
}

// Charge exchange between two touching particles i and j. Through their contact the two bodies come to one
// potential: charge moves until q_i / C_i = q_j / C_j. The capacitances are those of isolated spheres of the
// volume-equivalent radii, C = 4 pi eps0 r (J. D. Jackson, Classical Electrodynamics, 3rd ed., 1999, sec. 1.13),
// so only r_i / r_j enters; for two equal touching spheres the even split is exact by symmetry. The charge flows
// through the two bodies' resistances in series, so the pair relaxes with tau_ij = tau_i + tau_j, each body's
// tau = eps / sigma its charge relaxation time (Haus & Melcher, Electromagnetic Fields and Energy, sec. 7.7):
// two metals (tau = 0) share at once, a metal and an insulator (tau = 2214 s) in practice not at all. The
// charge passed from i to j over a step h:
//     f = (1 - exp(-h / tau_ij)) (r_j q_i - r_i q_j) / (r_i + r_j) / m_ij,
// with m_ij = max(n_i, n_j), the larger count of touching partners of the two. Every contact is evaluated from
// the charges at the start of the exchange (one Jacobi sweep): each body moves at most 1/n_i of the way towards
// each partner's potential, so none overshoots, and f leaves i as it reaches j, so the total charge is kept
// exactly.
DVI_HD real contactChargeFlux(real qi, real qj, real ri, real rj, real tau_i, real tau_j, real h, int32_t m_ij) {
  const real tau = tau_i + tau_j;
  const real share = tau > real(0) ? real(1) - std::exp(-h / tau) : real(1);
  const real m = real(m_ij > 1 ? m_ij : 1);
  return share * (rj * qi - ri * qj) / ((ri + rj) * m);
}

// The contact points k that stand for a touching pair of bodies in the exchange above: the first point of its
// pair (the points of one pair are adjacent in both backends' contact lists) at a distance <= 0.
DVI_HD bool firstTouchingPointOfPair(const int32_t* body_a, const int32_t* body_b, const real* dist, int64_t k) {
  if (!(dist[k] <= real(0))) return false;
  for (int64_t j = k - 1; j >= 0 && body_a[j] == body_a[k] && body_b[j] == body_b[k]; --j)
    if (dist[j] <= real(0)) return false;
  return true;
}

}  // namespace ces
}  // namespace dvi
