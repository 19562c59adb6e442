// Forces on a CES particle: Coulomb, image force toward the grounded drum, aerodynamic drag.
// Pure DVI_HD functions (host and device). The drum axis is parallel to z (ces_constants.h).
#pragma once

#include <cmath>

#include "ces/ces_constants.h"
#include "chrono_like/base/math.h"

namespace dvi {
namespace ces {

// Where the electric forces act: inside the drum width |z - zc| <= halfWidth; the image force in
// addition only where the charge is within imageCutoff of the drum surface.
struct DrumGeometry {
  real cx, cy;       // axis in the cross-section, m
  real R;            // radius, m
  real zc;           // mid-plane of the drum along z, m
  real halfWidth;    // m
  real imageCutoff;  // m, distance of the charge (particle centre) to the drum surface
};

DVI_HD bool insideDrumWidth(const DrumGeometry& g, Vec3 p) { return std::fabs(p.z - g.zc) <= g.halfWidth; }

// Signed distance of a point to the drum surface in the cross-section (> 0 outside the drum).
DVI_HD real distanceToDrumSurface(const DrumGeometry& g, Vec3 p) { return std::hypot(p.x - g.cx, p.y - g.cy) - g.R; }

// Coulomb force on a point charge: F = q E (Jackson, "Classical Electrodynamics", 3rd ed., §1.2).
DVI_HD Vec3 coulombForce(real q, Vec3 E) { return q * E; }

// Image force magnitude on a charge q at distance d from a grounded conducting plane: the image -q
// at distance 2d attracts it with F = q^2 / (4 pi eps0 (2d)^2) = q^2 / (16 pi eps0 d^2) (Jackson,
// §2.1, method of images for a plane). Near the drum (d << R) the plane is the drum's tangent plane.
// d is clamped to d >= r (the charge of a particle of radius r in contact sits r from the surface;
// this also removes the 1/d^2 singularity).
DVI_HD real imageForceMagnitude(real q, real d, real r) {
  const real dd = d > r ? d : r;
  return q * q / (real(16) * kPi * kEps0 * dd * dd);
}

// Image force vector on a particle (centre p, radius r, charge q), pointing toward the drum axis
// (the nearest drum surface point), zero outside the drum width or beyond the cutoff.
DVI_HD Vec3 imageForce(const DrumGeometry& g, Vec3 p, real q, real r) {
  if (q == real(0) || !insideDrumWidth(g, p)) return Vec3{0, 0, 0};
  const real dx = p.x - g.cx, dy = p.y - g.cy;
  const real rho = std::hypot(dx, dy);
  const real d = rho - g.R;
  if (d > g.imageCutoff || !(rho > real(0))) return Vec3{0, 0, 0};
  const real f = imageForceMagnitude(q, d, r);
  return Vec3{-f * dx / rho, -f * dy / rho, real(0)};
}

// The electric force of the CES model on a particle: Coulomb q E plus the image force, both zero
// outside the drum width. E is the field at the particle centre (field_two_cylinder.h or field_csm.h).
DVI_HD Vec3 electricForce(const DrumGeometry& g, Vec3 p, real q, real r, Vec3 E) {
  if (!insideDrumWidth(g, p)) return Vec3{0, 0, 0};
  return coulombForce(q, E) + imageForce(g, p, q, r);
}

// Sweep of a rotating brush's bristles on a particle among them: the particle's velocity v relaxes toward the
// bristles' local velocity v_b with the time constant tau_s, dv/dt = (v_b - v)/tau_s. As a force for a step h
// of the core's semi-implicit Euler update (v' = v + h F/m) it is the exact solution of that relaxation over the
// step, v' - v_b = (v - v_b) e^(-h/tau_s):
//   F = m (v_b - v) (1 - e^(-h/tau_s)) / h,
// stable for any h/tau_s; tau_s = 0 sets the velocity to v_b within the step (before the contacts act).
DVI_HD Vec3 bristleSweepForce(real mass, Vec3 v, Vec3 vBristle, real h, real tau) {
  if (!(h > real(0))) return Vec3{0, 0, 0};
  const real f = tau > real(0) ? -std::expm1(-h / tau) : real(1);
  return (mass * f / h) * (vBristle - v);
}

// Particle Reynolds number Re = rho_f |v_rel| d / eta.
DVI_HD real reynoldsNumber(real speed, real d, real rhoFluid, real eta) { return rhoFluid * speed * d / eta; }

// Drag coefficient of a sphere, Schiller & Naumann: C_d = 24/Re (1 + 0.15 Re^0.687) for Re < 1000,
// C_d = 0.44 (Newton regime) above. L. Schiller, A. Naumann, "Über die grundlegenden Berechnungen bei
// der Schwerkraftaufbereitung", Z. Ver. Dtsch. Ing. 77 (1933) 318-320; R. Clift, J. R. Grace,
// M. E. Weber, "Bubbles, Drops, and Particles", Academic Press 1978, Table 5.2. Re <= 0 gives +inf.
DVI_HD real schillerNaumannCd(real Re) {
  if (Re >= real(1000)) return real(0.44);
  return real(24) / Re * (real(1) + real(0.15) * std::pow(Re, real(0.687)));
}

// Aerodynamic drag F = 1/2 rho_f C_d A |v_rel| v_rel with v_rel = vFluid - vParticle, d the particle's
// (volume-equivalent) diameter used in Re and A its projected area (pi d^2/4 for a sphere).
// For Re < 1000 the product C_d |v_rel| = 24 eta/(rho_f d) (1 + 0.15 Re^0.687) is evaluated directly,
// so F = 12 eta A/d (1 + 0.15 Re^0.687) v_rel is regular at v_rel = 0 and equals Stokes' 3 pi eta d v_rel
// for a sphere as Re -> 0 (G. G. Stokes, Trans. Camb. Phil. Soc. 9 (1851) 8).
DVI_HD Vec3 dragForce(Vec3 vFluid, Vec3 vParticle, real d, real area, real rhoFluid, real eta) {
  const Vec3 vr = vFluid - vParticle;
  const real speed = length(vr);
  const real Re = reynoldsNumber(speed, d, rhoFluid, eta);
  real k;  // F = k v_rel
  if (Re < real(1000))
    k = real(12) * eta * area / d * (real(1) + real(0.15) * std::pow(Re, real(0.687)));
  else
    k = real(0.5) * rhoFluid * real(0.44) * area * speed;
  return k * vr;
}

// Sphere of diameter d: A = pi d^2 / 4.
DVI_HD Vec3 dragForceSphere(Vec3 vFluid, Vec3 vParticle, real d, real rhoFluid, real eta) {
  return dragForce(vFluid, vParticle, d, kPi * d * d / real(4), rhoFluid, eta);
}

// Rolling resistance of a particle on the drum: the constant-moment model ("type A" in Ai, Chen, Rotter & Ooi,
// "Assessment of rolling resistance models in discrete element simulations", Powder Technology 206 (2011)
// 269-282, eq. 5; Zhou et al., Physica A 269 (1999) 536): a moment of magnitude mu_r r F_n opposing the particle's
// rolling relative to the drum surface, where mu_r is the tangent of the steepest slope on which the moment
// alone holds a particle against gravity (a body at rest on a slope of angle theta stays when tan theta <= mu_r),
// r the rolling radius and F_n the normal force. It stands for what makes real granules (irregular, flattened,
// rough) roll less freely than the rigid spheres and cylinders of the model.
//  - w_rel = w - w_drum, its part in the contact's tangent plane (normal n = radial, outward) is the rolling;
//  - F_n from the particle's equation of motion normal to the drum while it rides it: the drum pushes with what
//    gravity and the other forces F press inward, less the centripetal force m v_phi^2 / rho of its motion about
//    the axis (rho = distance of the centre to the axis): F_n = -(m g + F).n - m v_phi^2 / rho, and 0 when that
//    is <= 0 (the particle is leaving);
//  - explicit: the moment acts in IntegrateForces, before the contacts are solved, and is limited to the one
//    that stops the relative rolling within the step (I_min |w_rel,t| / h, I_min the smallest principal
//    moment), so it never reverses it; a particle held on a slope by it creeps by at most ~g h per step.
// Zero for mu_r = 0 or when the particle does not touch the drum (touching: centre within contact_tol x bound
// of the surface, the charge model's test, particle_model.h).
DVI_HD Vec3 drumRollingTorque(const DrumGeometry& g, Vec3 p, Vec3 v, Vec3 w, Vec3 w_drum, Vec3 F, Vec3 gravity,
                              real mass, real r, real moment, real mu_r, real h) {
  if (!(mu_r > real(0)) || !(moment > real(0)) || !(h > real(0))) return Vec3{0, 0, 0};
  const real dx = p.x - g.cx, dy = p.y - g.cy, rho = std::hypot(dx, dy);
  if (!(rho > real(0))) return Vec3{0, 0, 0};
  const Vec3 n{dx / rho, dy / rho, real(0)};
  const Vec3 e_phi{-n.y, n.x, real(0)};  // azimuthal direction, z x n
  const real v_phi = dot(v, e_phi);
  const real Fn = -dot(mass * gravity + F, n) - mass * v_phi * v_phi / rho;
  if (!(Fn > real(0))) return Vec3{0, 0, 0};
  const Vec3 wr = w - w_drum;
  const Vec3 wt = wr - dot(wr, n) * n;
  const real wt_len = length(wt);
  if (!(wt_len > real(0))) return Vec3{0, 0, 0};
  const real M_model = mu_r * r * Fn;
  const real M_stop = moment * wt_len / h;
  const real M = M_model < M_stop ? M_model : M_stop;
  return (-M / wt_len) * wt;
}

}  // namespace ces
}  // namespace dvi
