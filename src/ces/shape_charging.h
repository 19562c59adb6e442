// Shape-aware electrostatics of a CES particle (docs/CES.md, "Shapes"): its induced charge and lift as a
// conductor lying on the earthed drum, its Pauthenier saturation charge as an ellipsoid, the image force of a
// flat contact, and its true distance to the drum (the support of the shape along the drum's normal). Pure
// DVI_HD functions over plain data (host and device).
//
// The per-particle constants (ParticleElectro) are computed once, when the particle is fed
// (makeParticleElectro, host); each step only weighs them by the orientation: with u the drum's outward normal
// in the body frame (|u| = 1), a quantity X that is X_i when the body's principal axis i lies along the normal
// is X(u) = sum_i u_i^2 X_i (exact in the three principal orientations, smooth in between, and exact for every
// orientation of a sphere).
#pragma once

#include <cmath>
#include <cstdint>

#include "ces/charging.h"
#include "ces/ces_constants.h"
#include "chrono_like/base/math.h"

namespace dvi {
namespace ces {

// ParticleShape as plain ints (ces_config.h) for the kernels.
constexpr int32_t kShapeSphere = 0, kShapeFlake = 1, kShapeWire = 2, kShapeEllipsoid = 3, kShapeFragment = 4;

// Carlson's symmetric elliptic integral of the second kind R_D(x, y, z) = 3/2 int_0^inf dt /
// ((t + x)^(1/2) (t + y)^(1/2) (t + z)^(3/2)), x, y >= 0, z > 0, by the duplication theorem
// R_D(x, y, z) = 2 R_D(x + l, y + l, z + l) + 3 / (sqrt(z) (z + l)), l = sqrt(xy) + sqrt(xz) + sqrt(yz), and
// its homogeneity R_D(kx, ky, kz) = k^(-3/2) R_D, then the Taylor series about the mean (B. C. Carlson,
// "Numerical computation of real or complex elliptic integrals", Numer. Algorithms 10 (1995) 13-26, eq. 2.29;
// NIST DLMF §19.36.1). A fixed number of steps: no data-dependent loop bound on the device.
DVI_HD real carlsonRD(real x, real y, real z) {
  double X = double(x), Y = double(y), Z = double(z), sum = 0, fac = 1;
  for (int k = 0; k < 24; ++k) {
    const double sx = std::sqrt(X), sy = std::sqrt(Y), sz = std::sqrt(Z);
    const double l = sx * sy + sx * sz + sy * sz;
    sum += fac * 3.0 / (sz * (Z + l));
    fac *= 0.25;
    X = 0.25 * (X + l), Y = 0.25 * (Y + l), Z = 0.25 * (Z + l);
  }
  const double A = (X + Y + 3 * Z) / 5, dx = (A - X) / A, dy = (A - Y) / A, dz = (A - Z) / A;
  const double e2 = dx * dy - 6 * dz * dz, e3 = (3 * dx * dy - 8 * dz * dz) * dz,
               e4 = 3 * (dx * dy - dz * dz) * dz * dz, e5 = dx * dy * dz * dz * dz;
  const double series = 1 - 3 * e2 / 14 + e3 / 6 + 9 * e2 * e2 / 88 - 3 * e4 / 22 - 9 * e2 * e3 / 52 + 3 * e5 / 26;
  return real(sum + fac * series / (A * std::sqrt(A)));
}

// Depolarisation factor of an ellipsoid with semi-axes (a, b, c) along a:
//     n_a = (abc/2) int_0^inf ds / ((s + a^2)^(3/2) (s + b^2)^(1/2) (s + c^2)^(1/2)) = (abc/3) R_D(b^2, c^2, a^2)
// (J. A. Osborn, "Demagnetizing factors of the general ellipsoid", Phys. Rev. 67 (1945) 351-357, eq. 2;
// E. C. Stoner, Phil. Mag. 36 (1945) 803). n_a + n_b + n_c = 1; a sphere's are 1/3; a thin plate's across its
// thickness tends to 1, a needle's along its axis to 0.
DVI_HD real depolarizationFactor(real a, real b, real c) {
  return a * b * c / real(3) * carlsonRD(b * b, c * c, a * a);
}
DVI_HD Vec3 depolarizationFactors(Vec3 e) {
  return Vec3{depolarizationFactor(e.x, e.y, e.z), depolarizationFactor(e.y, e.z, e.x),
              depolarizationFactor(e.z, e.x, e.y)};
}

// Pauthenier saturation charge (magnitude) of an ellipsoid with semi-axes e (body frame) and depolarisation
// factors n in a corona field whose body-frame components are Eb. Pauthenier's condition (no field line of the
// ions ends on the particle any more: the outward normal field of polarisation plus own charge nowhere points
// inward) applied to the ellipsoid's exact surface field: in a uniform field the polarised ellipsoid's outer
// normal field is sum_i c_i (x_i/e_i^2)/|g|, c_i = eps_r E_i / (1 + n_i (eps_r - 1)) (c_i = E_i / n_i for a
// conductor), and its own charge q spreads as q / (4 pi abc |g|), |g| = (sum x_i^2/e_i^4)^(1/2) (J. A.
// Stratton, "Electromagnetic Theory", McGraw-Hill 1941, §3.27; L. D. Landau, E. M. Lifshitz, "Electrodynamics of
// Continuous Media", 2nd ed., §4 and §8). The ratio is largest where sum_i c_i x_i / e_i^2 is, on the surface
// sum x_i^2/e_i^2 = 1 at the value (sum_i (c_i/e_i)^2)^(1/2), so
//     q_s = 4 pi eps0 abc (sum_i (c_i / e_i)^2)^(1/2).
// A sphere (e_i = r, n_i = 1/3) gives Pauthenier's 4 pi eps0 r^2 E 3 eps_r/(eps_r + 2) (charging.h); the field
// along axis i gives 4 pi eps0 e_j e_k c_i.
DVI_HD real pauthenierSaturationChargeEllipsoid(Vec3 e, Vec3 n, Vec3 Eb, real eps_r) {
  auto c = [&](real Ei, real ni) {
    return std::isinf(eps_r) ? Ei / ni : eps_r * Ei / (real(1) + ni * (eps_r - real(1)));
  };
  const real cx = c(Eb.x, n.x) / e.x, cy = c(Eb.y, n.y) / e.y, cz = c(Eb.z, n.z) / e.z;
  return real(4) * kPi * kEps0 * e.x * e.y * e.z * std::sqrt(cx * cx + cy * cy + cz * cz);
}

// A long conducting cylinder of radius a lying on an earthed plane in the normal field En, per unit length:
//     charge  lambda = 2 pi eps0 a En,     lift  F/L = (pi (pi^2 + 3) / 9) eps0 a En^2  (= k_c lambda En,
//     k_c = (pi^2 + 3)/18 = 0.7150).
// Derived in tangent-cylinder coordinates, the two-dimensional counterpart of Lebedev & Skal'skaya's sphere: the
// inversion zeta = 1/z (contact at z = 0, cylinder |z - ia| = a, plane Im z = 0) maps the gas to the strip
// -1/(2a) < Im zeta < 0, where the complex potential with Omega -> E z at infinity is
// Omega = pi a E coth(pi a zeta) (phi = Im Omega = 0 on both conductors). The flux through the cylinder is the
// jump of Re Omega along it, 2 pi a E; the Maxwell stress integrates to the force above (docs/CES.md, "Shapes";
// P. Moon, D. E. Spencer, "Field Theory Handbook", Springer 1961, tangent-cylinder coordinates; N. N. Lebedev,
// I. P. Skal'skaya, Sov. Phys. Tech. Phys. 7 (1962) 268 for the sphere). tests/test_ces_shapes.cpp checks both
// by quadrature of the field of Omega on the cylinder.
constexpr real kCylinderChargeFactor = real(2) * kPi;                               // lambda / (eps0 a En)
constexpr real kCylinderForceFactor = kPi * (kPi * kPi + real(3)) / real(9);        // (F/L) / (eps0 a En^2)
constexpr real kCylinderLiftFactor = kCylinderForceFactor / kCylinderChargeFactor;  // (pi^2 + 3)/18

// The sphere on the plane (charging.h, Lebedev & Skal'skaya 1962): q = (2 pi^3/3) eps0 r^2 En,
// F = 4 pi (zeta(3) + 1/6) eps0 r^2 En^2.
constexpr real kSphereChargeFactor = real(2) / real(3) * kPi * kPi * kPi;          // q / (eps0 r^2 En)
constexpr real kSphereForceFactor = real(4) * kPi * (kZeta3 + real(1) / real(6));  // F / (eps0 r^2 En^2)

// Per-particle electrostatic constants (makeParticleElectro): index i = the body's principal axis i along the
// drum's normal. q = eps0 En qcoef(u), lift = k(u) q E, footprint A(u), support h(u) (conductorSupport).
struct ParticleElectro {
  Vec3 half{0, 0, 0};   // shape dimensions: sphere (r, r, r); flake half extents; wire (r, half length, r); ellipsoid
                        // and fragment: the semi-axes of its ellipsoid (below)
  Vec3 semi{0, 0, 0};   // equivalent ellipsoid (same volume and proportions) for Pauthenier's charge
  Vec3 depol{0, 0, 0};  // its depolarisation factors
  Vec3 qcoef{0, 0, 0};  // m^2, induced charge / (eps0 En) lying on axis i
  Vec3 lift{0, 0, 0};   // k_L, lift / (q En)
  Vec3 foot{0, 0, 0};   // m^2, footprint on the drum (image force of a flat contact)
  real eps_r = 0;       // relative permittivity (inf: a conductor)
  real tau = 0;         // s, charge relaxation through the drum contact
  real metal_fraction = 0;  // volume fraction of metal (composites; 1 metal, 0 insulators)
  int32_t shape = 0;        // kShape*
  int32_t conductor = 0;    // 1: lifted like a metal on the drum (metal, or a composite above percolation)
};

DVI_HD real weighted(Vec3 x, Vec3 u) { return u.x * u.x * x.x + u.y * u.y * x.y + u.z * u.z * x.z; }

// Support of the shape in the body-frame direction u (|u| = 1): the largest extent of the body from its centre
// along u, so a body touching a plane with outward normal n has its centre h(-R^T n) = h(R^T n) above it
// (every shape here is centrally symmetric; the fragment by its ellipsoid). Box: sum |u_i| e_i; cylinder (axis
// y): H |u_y| + r (u_x^2 + u_z^2)^(1/2); ellipsoid: (sum e_i^2 u_i^2)^(1/2).
DVI_HD real shapeSupport(const ParticleElectro& pe, Vec3 u) {
  const Vec3 e = pe.half;
  switch (pe.shape) {
    case kShapeSphere: return e.x;
    case kShapeFlake: return std::fabs(u.x) * e.x + std::fabs(u.y) * e.y + std::fabs(u.z) * e.z;
    case kShapeWire: return std::fabs(u.y) * e.y + e.x * std::sqrt(u.x * u.x + u.z * u.z);
    default: return std::sqrt(e.x * e.x * u.x * u.x + e.y * e.y * u.y * u.y + e.z * e.z * u.z * u.z);
  }
}

// Induced charge coefficient and lift factor of a slab lying on its face (thickness 2t along the normal, face
// area A, rim length P): the face carries eps0 En A (Gauss: a thin plate on the plane, with the lift
// eps0 En^2 A / 2, the field's pressure); each rim is modelled as half a cylinder of radius t lying on the plane
// (kCylinder*), adding its excess over a flat strip of the same width, (pi - 1) t eps0 En per length of rim and
// (k_F - 1) t / 2 eps0 En^2 to the lift. Exact as t -> 0.
DVI_HD void slabOnPlane(real A, real P, real t, real& qcoef, real& lift) {
  qcoef = A + P * (kPi - real(1)) * t;
  const real force = real(0.5) * A + P * real(0.5) * (kCylinderForceFactor - real(1)) * t;
  lift = force / qcoef;
}

// A conductor standing tall on the plane (height 2h along the normal, base semi-axes p, s): the half of an
// ellipsoid of semi-axes (p, s, 2h) in the field, exact for a conducting half-ellipsoid boss on the plane
// (q = eps0 En pi p s / n, n its depolarisation factor along the normal: the ellipsoid's surface charge
// eps0 En n_z / n integrated over the upper half; Stratton 1941 §3.27), scaled by kBossToSphere so that a sphere
// (p = s = h = r) gets the Lebedev-Skal'skaya charge exactly; its lift factor is the sphere's.
DVI_HD real bossCharge(real p, real s, real h) {
  const real n_sphere = depolarizationFactor(real(2), real(1), real(1));  // prolate of aspect 2: 0.17356
  const real scale = kSphereChargeFactor * n_sphere / kPi;                // 1.142
  return scale * kPi * p * s / depolarizationFactor(real(2) * h, p, s);
}

// The shape's constants (everything of ParticleElectro but the material's): shape kShape*, half its
// dimensions as ParticleElectro::half. Per principal axis i along the normal (j, k the others):
//  - sphere: Lebedev & Skal'skaya's charge and lift (charging.h) in every orientation;
//  - flake (box): lying on a face no thicker than its width, the slab (slabOnPlane: face 4 e_j e_k, rim
//    4 (e_j + e_k), half thickness e_i); standing on an edge, the boss (bossCharge) of its height on the
//    ellipse of the face's area;
//  - wire (cylinder, axis y): lying (i = x, z), the capsule: the cylinder on the plane (kCylinder*) over its
//    length less one diameter plus a sphere of its radius for the two ends (exact for a long wire and for a
//    sphere); standing, a coin (slab) when no taller than its radius, else the boss;
//  - ellipsoid, fragment: the boss of its semi-axes.
// The equivalent ellipsoid for Pauthenier's charge has the body's volume and proportions.
DVI_HD void shapeElectro(int32_t shape, Vec3 half, ParticleElectro& pe) {
  pe.shape = shape;
  pe.half = half;
  const real e[3] = {half.x, half.y, half.z};
  real q[3], k[3], A[3];
  for (int i = 0; i < 3; ++i) {
    const real ei = e[i], ej = e[(i + 1) % 3], ek = e[(i + 2) % 3];
    k[i] = kFeliciLiftFactor;
    if (shape == kShapeSphere) {
      q[i] = kSphereChargeFactor * ei * ei;
      A[i] = kPi * ei * ei;
    } else if (shape == kShapeFlake) {
      A[i] = real(4) * ej * ek;
      if (ei <= ej && ei <= ek)
        slabOnPlane(A[i], real(4) * (ej + ek), ei, q[i], k[i]);
      else
        q[i] = bossCharge(real(2) / std::sqrt(kPi) * ej, real(2) / std::sqrt(kPi) * ek, ei);
    } else if (shape == kShapeWire && i != 1) {  // lying: r = half.x, H = half.y
      const real r = half.x, L = std::fmax(real(2) * (half.y - r), real(0));
      q[i] = kCylinderChargeFactor * r * L + kSphereChargeFactor * r * r;
      k[i] = (kCylinderForceFactor * r * L + kSphereForceFactor * r * r) / q[i];
      A[i] = real(4) * r * half.y;
    } else if (shape == kShapeWire) {  // standing on an end
      const real r = half.x, H = half.y;
      A[i] = kPi * r * r;
      if (H <= r)
        slabOnPlane(A[i], real(2) * kPi * r, H, q[i], k[i]);
      else
        q[i] = bossCharge(r, r, H);
    } else {  // ellipsoid, fragment
      q[i] = bossCharge(ej, ek, ei);
      A[i] = kPi * ej * ek;
    }
  }
  pe.qcoef = Vec3{q[0], q[1], q[2]};
  pe.lift = Vec3{k[0], k[1], k[2]};
  pe.foot = Vec3{A[0], A[1], A[2]};
  // Equivalent ellipsoid: box V = 8 e^3 -> x (6/pi)^(1/3); cylinder V = 2 pi r^2 H -> x (3/2)^(1/3).
  const real s = shape == kShapeFlake ? std::cbrt(real(6) / kPi) : shape == kShapeWire ? std::cbrt(real(1.5)) : real(1);
  pe.semi = s * half;
  pe.depol = depolarizationFactors(pe.semi);
}

// Image force (magnitude) on a particle of charge q whose centre is d from the earthed drum, touching it at the
// support h (true distance) with footprint A: the point image at the centre's distance, but no closer than h
// (imageForceMagnitude, forces.h), and no more than a flat charged sheet of area A on the plane, q^2/(2 eps0 A)
// (the field q/(eps0 A) between the sheet and its image, halved: the parallel-plate attraction, W. R. Smythe,
// "Static and Dynamic Electricity", 3rd ed., 1968, §3.05). A sphere's sheet bound, q^2/(2 pi eps0 r^2), is 8x
// its point image at d = r, so a sphere keeps the point image exactly.
DVI_HD real imageForceShape(real q, real d, real h, real A) {
  const real dd = d > h ? d : h;
  const real point = q * q / (real(16) * kPi * kEps0 * dd * dd);
  const real sheet = q * q / (real(2) * kEps0 * A);
  return point < sheet ? point : sheet;
}

}  // namespace ces
}  // namespace dvi
