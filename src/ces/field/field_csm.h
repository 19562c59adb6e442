// Charge-simulation method (CSM) for any set of parallel cylindrical conductors (drum, corona wires,
// static tubes), each at a given potential, in free space.
//
// Method: H. Singer, H. Steinbigler, P. Weiss, "A charge simulation method for the calculation of
// high voltage fields", IEEE Trans. Power App. Syst. PAS-93 (1974) 1660-1668; N. H. Malik, "A review
// of the charge simulation method and its applications", IEEE Trans. Electr. Insul. 24 (1989) 3-20.
//
//  * Each cylinder k (centre (cx, cy), radius R, potential V) holds M_k infinite line charges lambda_j
//    on a concentric circle of radius rho R (0 < rho < 1), at the angles 2 pi j / M_k, and has M_k
//    contour (collocation) points on its surface at the same angles.
//  * The potential of a line charge in 2D is -lambda/(2 pi eps0) ln r + const (Jackson, "Classical
//    Electrodynamics", 3rd ed., §1.3 / Gauss's law), defined only up to a constant. We write
//        phi(P) = phi_inf - sum_j lambda_j/(2 pi eps0) ln|P - S_j|
//    with the constant phi_inf an unknown, and add the equation sum_j lambda_j = 0 (zero net charge
//    per unit length). Only with zero net charge does phi tend to a finite value (phi_inf) far away, so
//    the problem "isolated conductors at given potentials" is well posed; the ground reference is the
//    drum, whose phi = 0 is imposed at its contour points like every other potential. The exact
//    two-cylinder solution (field_two_cylinder.h, lines +-lambda) has the same structure: it is
//    reproduced by this model, and that is tested. With zero net charge the reference length of the
//    logarithm drops out.
//  * Unknowns: the sum M_k charges and phi_inf; equations: one per contour point and the charge sum;
//    square dense solve (Eigen, column-pivoting Householder QR), host only.
//  * E = -grad phi = sum_j lambda_j/(2 pi eps0) (P - S_j)/|P - S_j|^2.
//
// Accuracy (derived here; cf. Malik 1989 on the placement of simulation charges): the exterior
// potential of cylinder k continues analytically into it down to the images of the other conductors'
// charges; all of them (and their nested images) lie within s_k = max_j R_k^2 / (D_kj - R_j) of its
// axis (D_kj the centre distance, D_kj - R_j the nearest distance of conductor j). The collocation error
// then decays geometrically like max(rho, s_k/(rho R_k))^M: the first term is the aliasing of the
// M-point contour sampling, the second the truncation of the charge representation. The best choice is
// rho = sqrt(s_k/R_k), and M = log(tol)/log(rho) reaches tol. addCylinder(..., nCharges = 0, rho = 0)
// selects both automatically this way (tol = 1e-12, rho clamped to [0.05, 0.95], M to [8, 400]).
// Ill-conditioning grows like rho^(-M/2) (the m-th Fourier mode of the contour potential is rho^m times
// that of the charges) but does not spoil the solution here (QR, double precision): measured, the
// default two-cylinder machine is reproduced to ~2e-12 in E and ~6e-14 |U| in phi
// (tests/test_ces_physics.cpp).
// maxSurfaceError() measures the result between the collocation points. The model only covers
// exterior problems (field outside all cylinders): a hollow conductor enclosing the others (coaxial
// geometry) would need its charges outside it and is not supported.
//
// The evaluation is a DVI_HD function over plain arrays, so the GPU evaluates the same code on a
// device copy of charges() and conductors().
#pragma once

#include <cmath>
#include <vector>

#include "ces/ces_constants.h"
#include "ces/field/field_common.h"

namespace dvi {
namespace ces {

struct CsmLineCharge {
  real x, y;    // m
  real lambda;  // C/m
};

struct CsmConductor {
  real cx, cy, R;  // m
  real V;          // V
};

// Raw CSM sum (no region test) at (px, py).
DVI_HD void csmRaw(const CsmLineCharge* q, int n, real phiInf, real px, real py, real& phi, real& Ex, real& Ey) {
  real sl = 0, sx = 0, sy = 0;
  for (int j = 0; j < n; ++j) {
    const real dx = px - q[j].x, dy = py - q[j].y;
    const real r2 = dx * dx + dy * dy;
    sl += q[j].lambda * std::log(r2);
    const real w = q[j].lambda / r2;
    sx += w * dx;
    sy += w * dy;
  }
  phi = phiInf - real(0.5) * kInv2PiEps0 * sl;
  Ex = kInv2PiEps0 * sx;
  Ey = kInv2PiEps0 * sy;
}

// A non-owning view of a solved model: what a kernel needs (device pointers on the GPU).
struct CsmFieldView {
  const CsmLineCharge* charges;
  int nCharges;
  const CsmConductor* conductors;
  int nConductors;
  real phiInf;
};

// The field at a 3D point (z ignored). Inside (or on) conductor k: region k+1, phi = V_k, E = 0.
DVI_HD FieldSample evalCsm(const CsmFieldView& v, Vec3 p) {
  for (int k = 0; k < v.nConductors; ++k) {
    const real dx = p.x - v.conductors[k].cx, dy = p.y - v.conductors[k].cy;
    if (dx * dx + dy * dy < v.conductors[k].R * v.conductors[k].R)
      return FieldSample{v.conductors[k].V, Vec3{0, 0, 0}, k + 1};
  }
  FieldSample s;
  s.region = 0;
  s.E.z = real(0);
  csmRaw(v.charges, v.nCharges, v.phiInf, p.x, p.y, s.phi, s.E.x, s.E.y);
  return s;
}

// Host-side builder and solver. addCylinder() and solve() throw dvi::InputError on bad input
// (non-positive radius, rho outside [0, 1), M < 0, overlapping cylinders, no cylinder).
class CsmField {
 public:
  // Returns the index of the cylinder. nCharges = M (0: automatic), chargeRadiusFraction = rho (0:
  // automatic), see "Accuracy" above.
  int addCylinder(real cx, real cy, real R, real V, int nCharges = 0, real chargeRadiusFraction = real(0));
  // Builds and solves the collocation system; returns the largest |phi - V| at the collocation points
  // (the residual of the solve, in V).
  real solve();

  bool solved() const { return solved_; }
  const std::vector<CsmLineCharge>& charges() const { return charges_; }
  const std::vector<CsmConductor>& conductors() const { return conductors_; }
  real phiInfinity() const { return phiInf_; }
  // Net line charge on cylinder k (C/m): the capacitance coefficients times the potentials.
  real cylinderCharge(int k) const;
  // The M and rho used for cylinder k by the last solve().
  int chargeCount(int k) const { return mUsed_.at(k); }
  real chargeRadiusFraction(int k) const { return rhoUsed_.at(k); }
  // Host view (pointers into this object).
  CsmFieldView view() const;
  FieldSample eval(Vec3 p) const { return evalCsm(view(), p); }
  // max over cylinders of max_i |phi(P_i) - V_k| over nSamples points evenly spaced on each surface,
  // offset by half a step from the collocation angles of a cylinder with nSamples charges (V).
  real maxSurfaceError(int nSamples) const;

 private:
  std::vector<CsmConductor> conductors_;
  std::vector<int> m_;
  std::vector<real> rho_;
  std::vector<int> mUsed_;
  std::vector<real> rhoUsed_;
  std::vector<CsmLineCharge> charges_;
  std::vector<int> first_;  // index of the first charge of each cylinder
  real phiInf_ = 0;
  bool solved_ = false;
};

}  // namespace ces
}  // namespace dvi
