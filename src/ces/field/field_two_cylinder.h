// Exact electrostatic field of two parallel, non-intersecting conducting cylinders: the drum
// (radius R1, potential 0, axis at (cx, cy)) and the electrode (radius R2, potential U, axis at
// distance L from the drum axis in the direction alpha, counter-clockwise from +x).
//
// Method of images / bipolar coordinates (e.g. W. R. Smythe, "Static and Dynamic Electricity",
// 3rd ed., McGraw-Hill 1968, §4.13; J. D. Jackson, "Classical Electrodynamics", 3rd ed., Wiley 1999,
// Problem 1.7 and §2.1; H. A. Haus & J. R. Melcher, "Electromagnetic Fields and Energy",
// Prentice Hall 1989, §4.7). Derivation (done here, not ported):
//
//  * The locus of points P whose distances r1, r2 to two fixed points F1, F2 have a constant ratio
//    r1/r2 = k is a circle (Apollonius). A line charge +lambda at F1 and -lambda at F2 has the
//    potential phi = -lambda/(2 pi eps0) ln r1 + lambda/(2 pi eps0) ln r2 = c ln(r1/r2) + c0, so every
//    Apollonius circle is an equipotential; both cylinder surfaces are reproduced if F1, F2 are
//    inverse points with respect to both circles.
//  * Put F1, F2 on the centre line at distances x1 < x2 from the drum axis. Inverse points w.r.t. the
//    drum: x1 x2 = R1^2. Inverse w.r.t. the electrode (centre at L): (L - x1)(L - x2) = R2^2.
//    Subtracting, L^2 - L (x1 + x2) + R1^2 = R2^2, so x1 + x2 = 2 h1 with
//        h1 = (L^2 + R1^2 - R2^2) / (2 L),   x1,2 = h1 -+ a,   a = sqrt(h1^2 - R1^2).
//  * Which focus is where: x1 x2 = R1^2 with x1 < x2 gives x1 < R1 < x2, so F1 (at h1 - a) lies
//    inside the drum. h1 - R1 = ((L - R1)^2 - R2^2) / (2L) > 0 for L > R1 + R2, so a is real.
//    (L - x1) + (L - x2) = 2 (L - h1) = (L^2 - R1^2 + R2^2)/L > 0 and (L - x1)(L - x2) = R2^2 > 0,
//    so both are positive with L - x2 < R2 < L - x1: F2 (at h1 + a) lies inside the electrode.
//  * On a circle of radius R whose centre is at distance p from the inner inverse point and q = R^2/p
//    from the outer one, |P - F_inner| / |P - F_outer| = p / R (evaluate at the nearest point:
//    (R - p)/(q - R) = p/R). Hence on the drum r1/r2 = k1 = x1/R1 (< 1) and on the electrode
//    r1/r2 = k2 = (L - x1)/R2 (> 1).
//  * phi = 0 on the drum and U on the electrode: c ln k1 + c0 = 0, c ln k2 + c0 = U, so
//        c = U / ln(k2/k1),   c0 = -c ln k1.
//    The line charge at F1 is lambda1 = -2 pi eps0 c, at F2 lambda2 = +2 pi eps0 c. Consistency check
//    against the textbook capacitance per unit length C' = 2 pi eps0 / arccosh((L^2-R1^2-R2^2)/(2R1R2))
//    (Smythe §4.13): ln(k2/k1) = arccosh((L^2 - R1^2 - R2^2) / (2 R1 R2)); tested.
//  * E = -grad phi = -c ((P - F1)/r1^2 - (P - F2)/r2^2), since grad ln|P - F| = (P - F)/|P - F|^2.
//
// Numerics: x1 = R1^2/(h1 + a) and a = sqrt((h1 - R1)(h1 + R1)) avoid the cancellation of h1 - a and
// h1^2 - R1^2 when the cylinders are far apart.
#pragma once

#include <cmath>

#include "ces/ces_constants.h"
#include "ces/field/field_common.h"

namespace dvi {
namespace ces {

struct TwoCylinderField {
  // Geometry and potentials.
  real cx, cy;  // drum axis in the cross-section, m
  real R1;      // drum radius, m (potential 0)
  real R2;      // electrode radius, m (potential U)
  real L;       // centre distance, m
  real U;       // electrode potential, V
  // Derived by makeTwoCylinderField.
  real ex, ey;  // unit vector from the drum axis to the electrode axis
  real x1, x2;  // distances of the foci F1 (inside the drum) and F2 (inside the electrode) from the drum axis
  real c, c0;   // phi = c ln(r1/r2) + c0
};

// Builds the field; returns false (and leaves f unusable) unless R1 > 0, R2 > 0 and L > R1 + R2
// (the electrode outside the drum, cylinders not touching).
DVI_HD bool makeTwoCylinderField(real R1, real R2, real L, real alpha, real U, real cx, real cy, TwoCylinderField& f) {
  if (!(R1 > real(0)) || !(R2 > real(0)) || !(L > R1 + R2)) return false;
  f = TwoCylinderField{cx, cy, R1, R2, L, U, std::cos(alpha), std::sin(alpha), real(0), real(0), real(0), real(0)};
  const real h1 = (L * L + R1 * R1 - R2 * R2) / (real(2) * L);
  const real a = std::sqrt((h1 - R1) * (h1 + R1));
  f.x1 = R1 * R1 / (h1 + a);        // = h1 - a, inside the drum
  f.x2 = L - R2 * R2 / (L - f.x1);  // = h1 + a, inside the electrode
  const real k1 = f.x1 / R1;        // r1/r2 on the drum surface
  const real k2 = (L - f.x1) / R2;  // r1/r2 on the electrode surface
  f.c = U / std::log(k2 / k1);
  f.c0 = -f.c * std::log(k1);
  return true;
}

// Line charge per unit length (C/m) at F1 (inside the drum); the electrode carries the opposite one.
DVI_HD real twoCylinderDrumLineCharge(const TwoCylinderField& f) { return -f.c / kInv2PiEps0; }

// The analytic image-charge formula at (px, py), valid in the gas (outside both cylinders) and on
// their surfaces; no region test. Singular only at the foci (inside the conductors).
DVI_HD void twoCylinderRaw(const TwoCylinderField& f, real px, real py, real& phi, real& Ex, real& Ey) {
  const real dx1 = px - (f.cx + f.x1 * f.ex), dy1 = py - (f.cy + f.x1 * f.ey);
  const real dx2 = px - (f.cx + f.x2 * f.ex), dy2 = py - (f.cy + f.x2 * f.ey);
  const real r1s = dx1 * dx1 + dy1 * dy1;
  const real r2s = dx2 * dx2 + dy2 * dy2;
  phi = real(0.5) * f.c * std::log(r1s / r2s) + f.c0;
  Ex = -f.c * (dx1 / r1s - dx2 / r2s);
  Ey = -f.c * (dy1 / r1s - dy2 / r2s);
}

// The field at a 3D point (z ignored). region 1: inside the drum (phi = 0, E = 0); region 2: inside
// the electrode (phi = U, E = 0); region 0: the gas, where the image solution holds.
DVI_HD FieldSample evalTwoCylinder(const TwoCylinderField& f, Vec3 p) {
  const real dx = p.x - f.cx, dy = p.y - f.cy;
  if (dx * dx + dy * dy < f.R1 * f.R1) return FieldSample{real(0), Vec3{0, 0, 0}, 1};
  const real ux = dx - f.L * f.ex, uy = dy - f.L * f.ey;
  if (ux * ux + uy * uy < f.R2 * f.R2) return FieldSample{f.U, Vec3{0, 0, 0}, 2};
  FieldSample s;
  s.region = 0;
  s.E.z = real(0);
  twoCylinderRaw(f, p.x, p.y, s.phi, s.E.x, s.E.y);
  return s;
}

}  // namespace ces
}  // namespace dvi
