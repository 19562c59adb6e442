// CES physics layer (src/ces/): fields, charges and forces, each against an answer the code under test
// did not produce (a textbook formula, a hand calculation written here, a finite difference, another
// model of the same field).
#include <catch2/catch.hpp>
#include <cmath>
#include <vector>

#include "ces/ces_config.h"
#include "ces/ces_constants.h"
#include "ces/charging.h"
#include "ces/field/field_csm.h"
#include "ces/field/field_two_cylinder.h"
#include "ces/forces.h"
#include "ces/particle_model.h"
#include "chrono_like/base/errors.h"

using namespace dvi;
using namespace dvi::ces;

namespace {

constexpr double kTwoPiD = 6.283185307179586476925286766559;

struct Geometry {
  double R1, R2, L, alphaDeg, U, cx, cy;
};

// The old default machine (one tube) and three harder variants: a 1 mm gap, a far electrode, an
// off-centre drum with a positive electrode below the horizontal.
const Geometry kGeometries[] = {
    {0.160, 0.019, 0.267, 30.0, -35000.0, 0.0, 0.0},
    {0.160, 0.019, 0.180, 30.0, -35000.0, 0.0, 0.0},
    {0.160, 0.019, 5.000, 30.0, -35000.0, 0.0, 0.0},
    {0.100, 0.005, 0.180, -70.0, 20000.0, 0.3, -0.2},
};

TwoCylinderField make(const Geometry& g) {
  TwoCylinderField f;
  REQUIRE(makeTwoCylinderField(g.R1, g.R2, g.L, degToRad(real(g.alphaDeg)), g.U, g.cx, g.cy, f));
  return f;
}

// Points of the gas region: a grid over a box around both cylinders, at least `margin` from both surfaces.
std::vector<Vec3> gapPoints(const TwoCylinderField& f, double margin, double step, double extent) {
  std::vector<Vec3> pts;
  const double ox = f.cx + f.L * f.ex, oy = f.cy + f.L * f.ey;
  for (double x = f.cx - extent; x <= f.cx + extent; x += step)
    for (double y = f.cy - extent; y <= f.cy + extent; y += step) {
      if (std::hypot(x - f.cx, y - f.cy) - f.R1 < margin) continue;
      if (std::hypot(x - ox, y - oy) - f.R2 < margin) continue;
      pts.push_back(Vec3{x, y, 0.0});
    }
  return pts;
}

}  // namespace

TEST_CASE("CES two-cylinder field: foci and constants against a hand calculation and the textbook capacitance",
          "[ces]") {
  const TwoCylinderField f = make(kGeometries[0]);
  // By hand: h1 = (0.267^2 + 0.16^2 - 0.019^2)/(2*0.267) = (0.071289 + 0.0256 - 0.000361)/0.534
  //             = 0.096528/0.534 = 0.18076404;  a = sqrt(0.18076404^2 - 0.0256) = sqrt(0.00707563) = 0.08411682
  // x1 = h1 - a = 0.09664722 m (inside the drum, < 0.16), x2 = h1 + a = 0.26488087 m
  // (|0.267 - 0.26488087| = 0.00211913 < 0.019: inside the electrode).
  CHECK(f.x1 == Approx(0.09664722).epsilon(1e-7));
  CHECK(f.x2 == Approx(0.26488087).epsilon(1e-7));
  CHECK(f.x1 < f.R1);
  CHECK(std::fabs(f.L - f.x2) < f.R2);
  // Capacitance per unit length of two parallel cylinders (Smythe, Static and Dynamic Electricity, §4.13):
  // C' = 2 pi eps0 / arccosh((L^2 - R1^2 - R2^2)/(2 R1 R2)); by hand arccosh(0.045328/0.00608)
  // = arccosh(7.4552632) = ln(7.4552632 + sqrt(7.4552632^2 - 1)) = 2.6975388, so
  // c = U/arccosh = -35000/2.6975388 = -12974.790 V and lambda_drum = -2 pi eps0 c = C' (0 - U)... > 0.
  CHECK(f.c == Approx(-12974.790).epsilon(1e-7));
  CHECK(twoCylinderDrumLineCharge(f) == Approx(2 * M_PI * 8.8541878128e-12 * 35000 / 2.6975388).epsilon(1e-7));
  // Every geometry: ln(k2/k1) from the foci equals the textbook arccosh.
  for (const Geometry& g : kGeometries) {
    const TwoCylinderField h = make(g);
    const double ac = std::acosh((g.L * g.L - g.R1 * g.R1 - g.R2 * g.R2) / (2 * g.R1 * g.R2));
    CHECK(h.c == Approx(g.U / ac).epsilon(1e-10));
  }
  // Field on the drum at the point facing the electrode, by hand: E = -c (1/(R1 - x1) + 1/(x2 - R1))
  // = 12974.790 * (1/0.06335278 + 1/0.10488087) = 12974.790 * (15.784627 + 9.534627) = 328512 V/m,
  // pointing from the drum toward the (negative) electrode.
  real phi, Ex, Ey;
  twoCylinderRaw(f, 0.16 * f.ex, 0.16 * f.ey, phi, Ex, Ey);
  CHECK(Ex * f.ex + Ey * f.ey == Approx(328512.0).epsilon(1e-5));
  CHECK(std::fabs(phi) < 1e-9 * 35000);
}

TEST_CASE("CES two-cylinder field: phi constant on both surfaces to 1e-9 relative, E normal to them", "[ces]") {
  for (const Geometry& g : kGeometries) {
    const TwoCylinderField f = make(g);
    const double ox = g.cx + g.L * f.ex, oy = g.cy + g.L * f.ey;
    const struct { double x, y, R, V; } surfaces[2] = {{g.cx, g.cy, g.R1, 0.0}, {ox, oy, g.R2, g.U}};
    double worstPhi = 0, worstTangential = 0;
    for (const auto& s : surfaces)
      for (int i = 0; i < 360; ++i) {
        const double t = kTwoPiD * i / 360;
        const double nx = std::cos(t), ny = std::sin(t);
        real phi, Ex, Ey;
        twoCylinderRaw(f, s.x + s.R * nx, s.y + s.R * ny, phi, Ex, Ey);
        worstPhi = std::max(worstPhi, std::fabs(phi - s.V) / std::fabs(g.U));
        const double En = Ex * nx + Ey * ny, Et = -Ex * ny + Ey * nx;
        worstTangential = std::max(worstTangential, std::fabs(Et) / std::hypot(En, Et));
      }
    INFO("L = " << g.L << " R1 = " << g.R1 << " R2 = " << g.R2);
    CHECK(worstPhi < 1e-9);
    CHECK(worstTangential < 1e-9);
  }
}

TEST_CASE("CES two-cylinder field: E = -grad phi by central differences", "[ces]") {
  for (const Geometry& g : kGeometries) {
    const TwoCylinderField f = make(g);
    const double h = 1e-6;  // m; truncation (h/0.005)^2 ~ 4e-8, round-off 1e-16*35000/2e-6 ~ 2e-6 V/m
    const std::vector<Vec3> pts = gapPoints(f, 1e-3, g.L / 20, g.L + 0.1);
    REQUIRE(pts.size() > 50);
    double worst = 0;
    for (const Vec3& p : pts) {
      const FieldSample s = evalTwoCylinder(f, p);
      if (s.region != 0) FAIL("grid point inside a conductor");
      const double dphidx =
          (evalTwoCylinder(f, p + Vec3{h, 0, 0}).phi - evalTwoCylinder(f, p - Vec3{h, 0, 0}).phi) / (2 * h);
      const double dphidy =
          (evalTwoCylinder(f, p + Vec3{0, h, 0}).phi - evalTwoCylinder(f, p - Vec3{0, h, 0}).phi) / (2 * h);
      const Vec3 fd{-dphidx, -dphidy, 0};
      worst = std::max(worst, double(length(fd - s.E) / length(s.E)));
    }
    INFO("L = " << g.L);
    CHECK(worst < 1e-5);
  }
}

TEST_CASE("CES two-cylinder field: a far electrode has the textbook line-charge field near it", "[ces]") {
  // Electrode radius 1 mm at 100 m from the drum: near it the field is that of an isolated line charge
  // lambda = C' U, E = lambda/(2 pi eps0 rho) radial (Jackson §1.3 / Gauss's law), with
  // C' = 2 pi eps0 / arccosh((L^2 - R1^2 - R2^2)/(2 R1 R2)). By hand: arccosh((1e4 - 0.0256)/(3.2e-4))
  // = 17.950675, so at rho = 5 mm, E = U/(17.950675 * 0.005) = -389957 V/m (pointing into the
  // negative electrode). Corrections are of order rho/L = 5e-5.
  TwoCylinderField f;
  REQUIRE(makeTwoCylinderField(0.16, 1e-3, 100.0, degToRad(30), -35000, 0, 0, f));
  const double ox = 100.0 * f.ex, oy = 100.0 * f.ey;
  for (int i = 0; i < 12; ++i) {
    const double t = kTwoPiD * i / 12, rho = 5e-3;
    const FieldSample s = evalTwoCylinder(f, Vec3{ox + rho * std::cos(t), oy + rho * std::sin(t), 0});
    const double Er = s.E.x * std::cos(t) + s.E.y * std::sin(t);
    CHECK(Er == Approx(-389957.0).epsilon(1e-4));
    CHECK(std::fabs(-s.E.x * std::sin(t) + s.E.y * std::cos(t)) < 1e-4 * std::fabs(Er));
  }
}

TEST_CASE("CES two-cylinder field: regions inside the conductors and invalid geometry", "[ces]") {
  const TwoCylinderField f = make(kGeometries[0]);
  const FieldSample in1 = evalTwoCylinder(f, Vec3{0.05, 0.02, 0.3});
  CHECK(in1.region == 1);
  CHECK(in1.phi == 0);
  CHECK(length(in1.E) == 0);
  const FieldSample in2 = evalTwoCylinder(f, Vec3{0.267 * f.ex + 0.01, 0.267 * f.ey, -1.0});
  CHECK(in2.region == 2);
  CHECK(in2.phi == -35000);
  CHECK(length(in2.E) == 0);
  const FieldSample out = evalTwoCylinder(f, Vec3{0.2, 0.0, 5.0});  // z is ignored by the 2D field
  CHECK(out.region == 0);
  CHECK(out.E.z == 0);
  CHECK(out.phi < 0);
  CHECK(out.phi > -35000);
  TwoCylinderField bad;
  CHECK_FALSE(makeTwoCylinderField(0.16, 0.019, 0.179, 0, -35000, 0, 0, bad));  // intersecting
  CHECK_FALSE(makeTwoCylinderField(0.16, 0.019, 0.100, 0, -35000, 0, 0, bad));  // electrode inside the drum
  CHECK_FALSE(makeTwoCylinderField(0.0, 0.019, 0.267, 0, -35000, 0, 0, bad));
}

TEST_CASE("CES charge-simulation model matches the exact two-cylinder field", "[ces]") {
  // Gap region compared: every point of a 2.5 mm grid over the square of half-side L + 0.1 m around the
  // drum axis (covering drum, electrode and the whole space between and around them) that lies at
  // least 1 mm from both surfaces: relative error of E and error of phi relative to |U|.
  for (const Geometry& g : kGeometries) {
    if (g.L > 1.0) continue;  // the far geometry needs no CSM check
    const TwoCylinderField f = make(g);
    CsmField csm;
    csm.addCylinder(g.cx, g.cy, g.R1, 0);
    csm.addCylinder(g.cx + g.L * f.ex, g.cy + g.L * f.ey, g.R2, g.U);
    const real residual = csm.solve();
    CHECK(residual < 1e-9 * std::fabs(g.U));
    const std::vector<Vec3> pts = gapPoints(f, 1e-3, 2.5e-3, g.L + 0.1);
    REQUIRE(pts.size() > 1000);
    double worstE = 0, worstPhi = 0;
    int outside = 0;
    for (const Vec3& p : pts) {
      const FieldSample a = evalTwoCylinder(f, p), b = csm.eval(p);
      outside += (a.region == 0 && b.region == 0);
      worstE = std::max(worstE, double(length(a.E - b.E) / length(a.E)));
      worstPhi = std::max(worstPhi, std::fabs(a.phi - b.phi) / std::fabs(g.U));
    }
    CHECK(outside == int(pts.size()));
    INFO("L = " << g.L << ", M = " << csm.chargeCount(0) << "/" << csm.chargeCount(1) << ", worst E error " << worstE
                << ", worst phi error " << worstPhi);
    // The requirement is 1e-3 on E. Measured: ~2e-12 (default machine), ~2e-4 on E and 3e-5 on phi for the
    // 1 mm gap (gap/R2 = 0.05: the images crowd the gap, the automatic placement saturates at M = 400; a
    // nearly touching pair needs charges graded toward the gap, which this model does not do).
    const bool nearlyTouching = (g.L - g.R1 - g.R2) < 0.1 * g.R2;
    CHECK(worstE < (nearlyTouching ? 1e-3 : 1e-9));
    CHECK(worstPhi < (nearlyTouching ? 1e-4 : 1e-10));
    // The simulated charge on the drum equals the exact line charge (the capacitance), net charge 0.
    CHECK(csm.cylinderCharge(0) == Approx(twoCylinderDrumLineCharge(f)).epsilon(1e-6));
    CHECK(std::fabs(csm.cylinderCharge(0) + csm.cylinderCharge(1)) < 1e-9 * std::fabs(csm.cylinderCharge(0)));
  }
  // Hand-set placement (M = 64, rho = 0.7 on both) still meets the requirement for the default machine.
  const TwoCylinderField f = make(kGeometries[0]);
  CsmField csm;
  csm.addCylinder(0, 0, 0.16, 0, 64, 0.7);
  csm.addCylinder(0.267 * f.ex, 0.267 * f.ey, 0.019, -35000, 64, 0.7);
  csm.solve();
  double worstE = 0;
  for (const Vec3& p : gapPoints(f, 1e-3, 5e-3, 0.367))
    worstE =
        std::max(worstE, double(length(evalTwoCylinder(f, p).E - csm.eval(p).E) / length(evalTwoCylinder(f, p).E)));
  CHECK(worstE < 1e-3);
}

TEST_CASE("CES charge-simulation model: drum + corona wire + static tube, constant potential on every surface",
          "[ces]") {
  // Drum R 160 mm at 0 V; corona wire R 0.15 mm at 220 mm, 45 deg, -35 kV; static tube R 19 mm at
  // 267 mm, 30 deg, -35 kV. Tolerance stated: |phi - V| <= 1e-9 |U| on 360 points per surface placed
  // between the collocation points (measured about 1e-13).
  CsmField csm;
  const double a45 = degToRad(45), a30 = degToRad(30);
  csm.addCylinder(0, 0, 0.16, 0);
  csm.addCylinder(0.22 * std::cos(a45), 0.22 * std::sin(a45), 0.15e-3, -35000);
  csm.addCylinder(0.267 * std::cos(a30), 0.267 * std::sin(a30), 0.019, -35000);
  csm.solve();
  double worst = 0, worstTangential = 0;
  for (const CsmConductor& c : csm.conductors())
    for (int i = 0; i < 360; ++i) {
      const double t = kTwoPiD * (i + 0.37) / 360, nx = std::cos(t), ny = std::sin(t);
      real phi, Ex, Ey;
      csmRaw(csm.charges().data(), int(csm.charges().size()), csm.phiInfinity(), c.cx + c.R * nx, c.cy + c.R * ny, phi,
             Ex, Ey);
      worst = std::max(worst, std::fabs(phi - c.V) / 35000.0);
      worstTangential = std::max(worstTangential, std::fabs(-Ex * ny + Ey * nx) / std::hypot(Ex, Ey));
    }
  CHECK(worst < 1e-9);
  CHECK(worstTangential < 1e-6);
  CHECK(csm.maxSurfaceError(360) < 1e-9 * 35000);
  // Zero net charge; the drum carries the charge opposite to the electrodes'.
  CHECK(std::fabs(csm.cylinderCharge(0) + csm.cylinderCharge(1) + csm.cylinderCharge(2)) <
        1e-9 * csm.cylinderCharge(0));
  CHECK(csm.cylinderCharge(0) > 0);
  CHECK(csm.cylinderCharge(1) < 0);
  CHECK(csm.cylinderCharge(2) < 0);
  // Near the thin wire its own charge dominates: E ~ lambda_wire/(2 pi eps0 rho) at rho = 0.5 mm to a few %.
  const double rho = 0.5e-3;
  const FieldSample s = csm.eval(Vec3{0.22 * std::cos(a45) + rho, 0.22 * std::sin(a45), 0});
  CHECK(length(s.E) == Approx(std::fabs(csm.cylinderCharge(1)) / (kTwoPiD * 8.8541878128e-12 * rho)).epsilon(0.05));
  // Regions: inside the wire and the tube.
  CHECK(csm.eval(Vec3{0.22 * std::cos(a45), 0.22 * std::sin(a45), 0}).region == 2);
  CHECK(csm.eval(Vec3{0.267 * std::cos(a30), 0.267 * std::sin(a30), 0}).phi == -35000);
}

TEST_CASE("CES charge-simulation model: input errors", "[ces]") {
  CsmField csm;
  CHECK_THROWS_AS(csm.solve(), InputError);
  CHECK_THROWS_AS(csm.addCylinder(0, 0, -1, 0), InputError);
  CHECK_THROWS_AS(csm.addCylinder(0, 0, 1, 0, 16, 1.2), InputError);
  CHECK_THROWS_AS(csm.addCylinder(0, 0, 1, 0, -3), InputError);
  csm.addCylinder(0, 0, 0.16, 0);
  CHECK_THROWS_AS(csm.addCylinder(0.17, 0, 0.019, -35000), InputError);  // overlaps the drum
}

TEST_CASE("CES charges: Felici and Pauthenier against hand calculations", "[ces]") {
  // r = 0.5 mm, E = 2 MV/m. pi^3 = 31.006277.
  // Félici: q = (2/3) pi^3 eps0 r^2 E = (2/3) * 31.006277 * 8.8541878e-12 * 2.5e-7 * 2e6 = 9.15118e-11 C.
  CHECK(feliciCharge(0.5e-3, 2e6) == Approx(9.15118e-11).epsilon(1e-5));
  CHECK(feliciCharge(0.5e-3, Vec3{0, 2e6, 0}, Vec3{0, 1, 0}) == Approx(9.15118e-11).epsilon(1e-5));
  CHECK(feliciCharge(0.5e-3, -2e6) == Approx(-9.15118e-11).epsilon(1e-5));  // sign follows E.n
  // On the default drum facing the electrode, E.n = 328512 V/m (hand value above):
  // q = (2/3) * 31.006277 * 8.8541878e-12 * 2.5e-7 * 328512 = 1.50314e-11 C.
  CHECK(feliciCharge(0.5e-3, 328512.0) == Approx(1.50314e-11).epsilon(1e-5));
  // Pauthenier, eps_r = 2.5: p = 3 * 2.5/4.5 = 1.666667; 4 pi eps0 r^2 E = 4 * 3.1415927 * 8.8541878e-12
  // * 2.5e-7 * 2e6 = 5.563250e-11 C, so q_s = 9.272084e-11 C.
  CHECK(pauthenierFactor(2.5) == Approx(1.6666667).epsilon(1e-7));
  CHECK(pauthenierFactor(INFINITY) == 3);
  CHECK(pauthenierSaturationCharge(0.5e-3, 2e6, 2.5) == Approx(9.272084e-11).epsilon(1e-6));
  CHECK(pauthenierSaturationCharge(0.5e-3, -2e6, 2.5) == Approx(9.272084e-11).epsilon(1e-6));  // magnitude
  // Pauthenier time constant 4 eps0/(N0 e mu): N0 = 1e15 /m^3, mu = 2e-4 m^2/Vs:
  // 4 * 8.8541878e-12 / (1e15 * 1.602176634e-19 * 2e-4) = 3.54168e-11 / 3.204353e-8 = 1.105270e-3 s.
  CHECK(pauthenierTimeConstant(1e15, 2e-4) == Approx(1.105270e-3).epsilon(1e-6));
}

TEST_CASE("CES charges: relaxation update exact against exp, limits, brush, Pauthenier kinetics", "[ces]") {
  // q = 1e-10 C relaxing to 0 with tau = 2 ms over h = 1 ms: 1e-10 * exp(-0.5) = 6.0653066e-11 C.
  CHECK(relaxCharge(1e-10, 0, 1e-3, 2e-3) == Approx(6.0653066e-11).epsilon(1e-8));
  // Toward a nonzero q_inf and composed over steps: 100 steps of h equal one step of 100 h exactly.
  double q = -3e-11;
  for (int i = 0; i < 100; ++i) q = relaxCharge(q, 5e-11, 1e-4, 3e-3);
  CHECK(q == Approx(5e-11 + (-3e-11 - 5e-11) * std::exp(-1e-2 / 3e-3)).epsilon(1e-12));
  CHECK(relaxCharge(1e-10, 2e-11, 1e-3, 0) == 2e-11);         // tau = 0: immediate
  CHECK(relaxCharge(1e-10, 2e-11, 1e-3, INFINITY) == 1e-10);  // tau = inf: unchanged
  CHECK(relaxCharge(1e-10, 2e-11, 0, 0) == 2e-11);            // no 0/0
  // tau = eps0 eps_r / sigma: eps_r = 3, sigma = 1e-9 S/m -> 8.8541878e-12 * 3 / 1e-9 = 0.026562563 s.
  CHECK(relaxationTime(3, 1e-9) == Approx(0.026562563).epsilon(1e-7));
  CHECK(std::isinf(relaxationTime(2.5, 0)));
  CHECK(brushDischarge(1e-10, 1e-4, 0) == 0);
  CHECK(brushDischarge(1e-10, 1e-3, 1e-3) == Approx(1e-10 * std::exp(-1.0)).epsilon(1e-12));
  // Pauthenier kinetics: stepping from 0 reproduces q_s t/(t + tau_c) at every step, in any step sizes.
  const double qs = 9.272084e-11, tc = 1.1e-3;
  q = 0;
  double t = 0;
  for (int i = 0; i < 50; ++i) {
    const double h = 1e-5 * (1 + i % 7);
    q = pauthenierChargeUpdate(q, qs, h, tc);
    t += h;
    CHECK(q == Approx(qs * t / (t + tc)).epsilon(1e-12));
  }
  CHECK(pauthenierChargeUpdate(qs, qs, 1e-3, tc) == qs);
  CHECK(pauthenierChargeUpdate(0, qs, 1e-3, 0) == qs);
}

TEST_CASE("CES forces: Coulomb, image force, drum width and cutoff against hand calculations", "[ces]") {
  const DrumGeometry drum{0, 0, 0.16, 0, 0.15, 5e-3};
  // Coulomb: q = 9.272084e-11 C in E = (0, 2e6, 0) V/m -> F = (0, 1.8544168e-4, 0) N.
  const Vec3 Fc = coulombForce(9.272084e-11, Vec3{0, 2e6, 0});
  CHECK(Fc.y == Approx(1.8544168e-4).epsilon(1e-7));
  // Image force, q = 9.272084e-11 C at d = r = 0.5 mm: q^2/(16 pi eps0 d^2) = 8.597153e-21 /
  // (16 * 3.1415927 * 8.8541878e-12 * 2.5e-7) = 8.597153e-21 / 1.112650e-16 = 7.72674e-5 N
  // (16x the weight 4.86e-6 N of a 1 mm plastic sphere of 946 kg/m^3).
  CHECK(imageForceMagnitude(9.272084e-11, 0.5e-3, 0.5e-3) == Approx(7.72674e-5).epsilon(1e-5));
  CHECK(imageForceMagnitude(9.272084e-11, 0.1e-3, 0.5e-3) == Approx(7.72674e-5).epsilon(1e-5));  // clamped d >= r
  // At d = 2 mm: a quarter of 1/16 of the d = r value... (0.5/2)^2 = 1/16 -> 4.82921e-6 N.
  CHECK(imageForceMagnitude(9.272084e-11, 2e-3, 0.5e-3) == Approx(4.82921e-6).epsilon(1e-5));
  // Vector: particle of radius 0.5 mm touching the drum on top (centre at y = 0.1605): force -y.
  const Vec3 p{0, 0.1605, 0.1};
  const Vec3 Fi = imageForce(drum, p, 9.272084e-11, 0.5e-3);
  CHECK(Fi.y == Approx(-7.72674e-5).epsilon(1e-5));
  CHECK(std::fabs(Fi.x) < 1e-20);
  CHECK(Fi.z == 0);
  // At 45 degrees, d = 1 mm: |F| = 7.72674e-5/4 = 1.931685e-5, along -(1,1)/sqrt 2.
  const double s2 = std::sqrt(0.5);
  const Vec3 Fi45 = imageForce(drum, Vec3{0.161 * s2, 0.161 * s2, 0}, 9.272084e-11, 0.5e-3);
  CHECK(Fi45.x == Approx(-1.931685e-5 * s2).epsilon(1e-5));
  CHECK(Fi45.y == Approx(-1.931685e-5 * s2).epsilon(1e-5));
  // Beyond the cutoff (5 mm) and beyond the drum width (|z| > 0.15): no image force.
  CHECK(length(imageForce(drum, Vec3{0, 0.1660, 0}, 9.272084e-11, 0.5e-3)) == 0);
  CHECK(length(imageForce(drum, Vec3{0, 0.1605, 0.151}, 9.272084e-11, 0.5e-3)) == 0);
  // electricForce = Coulomb + image inside the width, nothing outside.
  const Vec3 E{1e5, 2e5, 0};
  const Vec3 Fe = electricForce(drum, p, 9.272084e-11, 0.5e-3, E);
  CHECK(Fe.x == Approx(9.272084e-6).epsilon(1e-6));
  CHECK(Fe.y == Approx(1.8544168e-5 - 7.72674e-5).epsilon(1e-5));
  CHECK(length(electricForce(drum, Vec3{0, 0.1605, -0.2}, 9.272084e-11, 0.5e-3, E)) == 0);
  CHECK(insideDrumWidth(drum, Vec3{0, 0, 0.15}));
  CHECK(distanceToDrumSurface(drum, Vec3{0.3, 0.4, 1}) == Approx(0.34));
}

TEST_CASE("CES drag: Schiller-Naumann, its Stokes limit and the Newton regime", "[ces]") {
  const double eta = 1.81e-5, rho = 1.225, d = 1e-3;
  // Stokes limit: v = 1e-7 m/s -> Re = 6.8e-6; F -> 3 pi eta d v = 3 * 3.1415927 * 1.81e-5 * 1e-3 * 1e-7
  // = 1.7058848e-14 N (the correction 0.15 Re^0.687 ~ 4e-5).
  const Vec3 Fs = dragForceSphere(Vec3{0, 0, 0}, Vec3{1e-7, 0, 0}, d, rho, eta);
  CHECK(Fs.x == Approx(-1.7058848e-14).epsilon(1e-4));
  CHECK(Fs.x == Approx(-3 * M_PI * eta * d * 1e-7).epsilon(1e-4));
  // At v = 0 the force is 0 (no 0/0).
  CHECK(length(dragForceSphere(Vec3{0, 0, 0}, Vec3{0, 0, 0}, d, rho, eta)) == 0);
  // Re ~ 68 (1 mm particle at 1 m/s relative to still air): Re = 1.225 * 1 * 1e-3 / 1.81e-5 = 67.679558,
  // Re^0.687 = 18.093572, C_d = 24/67.679558 * (1 + 0.15 * 18.093572) = 0.3546122 * 3.7140358 = 1.3170426,
  // F = 0.5 * 1.225 * 1.3170426 * (pi/4 * 1e-6) * 1^2 = 6.335717e-7 N -- 3.7x Stokes' 1.7058848e-7 N.
  CHECK(reynoldsNumber(1.0, d, rho, eta) == Approx(67.679558).epsilon(1e-7));
  CHECK(schillerNaumannCd(67.679558) == Approx(1.3170426).epsilon(1e-6));
  const Vec3 F68 = dragForceSphere(Vec3{0, 1.0, 0}, Vec3{0, 0, 0}, d, rho, eta);  // air moving +y past it
  CHECK(F68.y == Approx(6.335717e-7).epsilon(1e-6));
  CHECK(F68.x == 0);
  // Newton regime: v = 20 m/s, Re = 1353.6 > 1000: C_d = 0.44,
  // F = 0.5 * 1.225 * 0.44 * 7.8539816e-7 * 400 = 8.466592e-5 N.
  const Vec3 F20 = dragForceSphere(Vec3{0, 0, 0}, Vec3{0, 0, 20}, d, rho, eta);
  CHECK(F20.z == Approx(-8.466592e-5).epsilon(1e-6));
  CHECK(schillerNaumannCd(1e4) == 0.44);
  // Near continuity at Re = 1000: 24/1000 * (1 + 0.15 * 1000^0.687) = 0.4385 vs 0.44.
  CHECK(schillerNaumannCd(999.999) == Approx(0.44).epsilon(0.01));
}

// ---------------------------------------------------------------------------------------------------
// The per-particle model (particle_model.h) on hand-made fields
// ---------------------------------------------------------------------------------------------------

namespace {

// A model with the drum at the origin (R = 0.16 m, width 0.3 m), one metal, one plastic (eps_r 2.5, tau 10 s)
// and one middling (eps_r 10, tau 0.5 s); no air; the brush far away.
CesModel handModel() {
  CesModel m{};
  m.drum = DrumGeometry{0, 0, 0.16, 0, 0.15, 5e-3};
  m.polarity = -1;
  m.ion_mobility = 2.1e-4;
  m.pin_dy = -0.16 * std::cos(20 * M_PI / 180);
  m.brush = CylinderXY{10, 10, 0.05};
  m.brush_omega = -12.566370614359172;
  m.brush_tau = 1e-3;
  m.brush_sweep_tau = 2e-3;
  m.n_electrodes = 0;
  m.air_density = 0;
  m.air_viscosity = 1e-12;
  m.contact_tol = 1.1;
  m.n_materials = 3;
  m.kind[0] = 0, m.eps_r[0] = INFINITY, m.tau[0] = 0;
  m.kind[1] = 1, m.eps_r[1] = 2.5, m.tau[1] = 10;
  m.kind[2] = 2, m.eps_r[2] = 10, m.tau[2] = 0.5;
  return m;
}

// A uniform sampled field E = (0, Ey) with ion density N everywhere (a 4 x 4 grid over the box).
struct UniformGrid {
  std::vector<float> ex, ey, phi, n;
  GridFieldView view{};
  UniformGrid(double Ey, double N) : ex(16, 0.f), ey(16, float(Ey)), phi(16, 0.f), n(16, float(N)) {
    view.x0 = -1, view.y0 = -1, view.dx = view.dy = 2.0 / 3.0, view.nx = view.ny = 4;
    view.Ex = ex.data(), view.Ey = ey.data(), view.phi = phi.data(), view.ion_density = n.data();
    view.nConductors = 0;
  }
};

}  // namespace

TEST_CASE("CES lift of a conductor on the drum: Lebedev-Skal'skaya 0.832 q E, image included, none added", "[ces]") {
  // (zeta(3) + 1/6) / (pi^2/6) = (1.2020569032 + 0.1666666667) / 1.6449340668 = 1.3687235698 / 1.6449340668
  // = 0.8320842.
  CHECK(double(kFeliciLiftFactor) == Approx(0.8320842).epsilon(1e-6));
  CesModel m = handModel();
  UniformGrid g(8e5, 0);  // 8 kV/cm, upward: E.n > 0 on top of the drum
  m.field.model = 2;
  m.field.grid = g.view;
  const double r = 0.5e-3, En = 8e5;
  const Vec3 top{0, real(0.16 + r), 0};
  const double qF = feliciCharge(r, En);  // the induced charge, hand value above: 3.66047e-11 C at 8e5 V/m
  CHECK(qF == Approx(2.0 / 3.0 * std::pow(M_PI, 3) * 8.8541878128e-12 * r * r * En).epsilon(1e-12));
  // On the drum: F = (zeta(3) + 1/6) 4 pi eps0 r^2 En^2 along the normal, nothing else (v = 0: no drag).
  const Vec3 F = cesParticleForce(m, 0, top, Vec3{0, 0, 0}, real(qF), real(r), real(r), real(1e-6), real(2e-4));
  CHECK(F.y == Approx((1.2020569031595942 + 1.0 / 6.0) * 4 * M_PI * 8.8541878128e-12 * r * r * En * En).epsilon(1e-9));
  CHECK(F.x == 0);
  // In flight (2 mm off the drum): q E, no image.
  const Vec3 up{0, real(0.16 + 2e-3), 0};
  CHECK(cesParticleForce(m, 0, up, Vec3{0, 0, 0}, real(qF), real(r), real(r), real(1e-6), real(2e-4)).y ==
        Approx(qF * En).epsilon(1e-12));
  // An insulator with the same charge on the drum: q E minus the image attraction q^2/(16 pi eps0 r^2).
  const double img = qF * qF / (16 * M_PI * 8.8541878128e-12 * r * r);
  CHECK(cesParticleForce(m, 1, top, Vec3{0, 0, 0}, real(qF), real(r), real(r), real(1e-6), real(2e-4)).y ==
        Approx(qF * En - img).epsilon(1e-9));
  // The charge update: a metal touching the drum takes the Félici charge at once, with the sign of E.n
  // (positive here, under a field that points away from the drum: the electrode is negative).
  uint8_t flags = 0;
  CHECK(cesChargeUpdate(m, 0, top, real(-5e-11), real(r), real(r), real(2e-4), flags) == Approx(qF).epsilon(1e-12));
  CHECK(flags == 0);  // the top of the drum is not where particles are pinned
}

TEST_CASE("CES charging: Pauthenier with the local field and ion density, relaxation on the drum, pinning", "[ces]") {
  CesModel m = handModel();
  const double E = 6e5, N = 2e14, r = 0.4e-3, h = 2e-4, mu = 2.1e-4;
  UniformGrid g(E, N);
  m.field.model = 2;
  m.field.grid = g.view;
  // Hand values: q_s = 4 pi eps0 r^2 E p, p = 3 eps_r/(eps_r + 2); tau_c = 4 eps0/(N e mu).
  const double eps0 = 8.8541878128e-12, e = 1.602176634e-19;
  const double qs_plastic = 4 * M_PI * eps0 * r * r * E * 3 * 2.5 / 4.5, qs_metal = 4 * M_PI * eps0 * r * r * E * 3;
  const double tc = 4 * eps0 / (N * e * mu);  // 8.41 ms
  const Vec3 free{0.1, 0.3, 0};               // in the gas, away from the drum
  uint8_t flags = 0;
  // From 0, one step: q = -q_s h/(h + tau_c) (negative corona); ten steps of h = one of 10 h.
  CHECK(cesChargeUpdate(m, 1, free, 0, real(r), real(r), real(h), flags) ==
        Approx(-qs_plastic * h / (h + tc)).epsilon(1e-6));
  real q = 0;
  for (int k = 0; k < 10; ++k) q = cesChargeUpdate(m, 1, free, q, real(r), real(r), real(h), flags);
  CHECK(double(q) == Approx(-qs_plastic * 10 * h / (10 * h + tc)).epsilon(1e-6));
  // A conductor in flight charges with p = 3, starting from its induced (opposite) charge q0 = +q_s: the
  // Pauthenier equation dq/dt = (q_s/tau)(1 - q/q_s)^2 in the ions' polarity, integrated here by RK4.
  auto rhs = [&](double x) { return (qs_metal / tc) * (1 - x / qs_metal) * (1 - x / qs_metal); };
  double x = -qs_metal;  // +q_s in volts' sign = -q_s in the ions' polarity
  for (int k = 0; k < 2000; ++k) {
    const double dt = h / 2000;
    const double k1 = rhs(x), k2 = rhs(x + dt / 2 * k1), k3 = rhs(x + dt / 2 * k2), k4 = rhs(x + dt * k3);
    x += dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4);
  }
  CHECK(double(cesChargeUpdate(m, 0, free, real(qs_metal), real(r), real(r), real(h), flags)) ==
        Approx(-x).epsilon(1e-9));
  // No ions, no charging: the same place with N = 0 (below onset) leaves the charge alone.
  UniformGrid g0(E, 0);
  m.field.grid = g0.view;
  CHECK(cesChargeUpdate(m, 1, free, real(-3e-12), real(r), real(r), real(h), flags) == real(-3e-12));
  // On the drum, an insulator relaxes toward the induced charge with tau = eps0 eps_r / sigma (10 s here),
  // a middling with its 0.5 s; exactly q_F + (q - q_F) exp(-h/tau).
  const Vec3 bottom{0, real(-(0.16 + r)), 0};  // E = (0, 6e5) points into the drum here: E.n = -6e5
  const double qF = 2.0 / 3.0 * std::pow(M_PI, 3) * eps0 * r * r * (-E);
  const double q0 = -2e-11;
  CHECK(double(cesChargeUpdate(m, 1, bottom, real(q0), real(r), real(r), real(h), flags)) ==
        Approx(qF + (q0 - qF) * std::exp(-h / 10)).epsilon(1e-12));
  CHECK(double(cesChargeUpdate(m, 2, bottom, real(q0), real(r), real(r), real(h), flags)) ==
        Approx(qF + (q0 - qF) * std::exp(-h / 0.5)).epsilon(1e-12));
  // Touching the drum at its lowest point: pinned.
  CHECK((flags & kFlagPinned) != 0);
  uint8_t f2 = 0;
  cesChargeUpdate(m, 1, Vec3{0, real(-(0.16 + 3 * r)), 0}, real(q0), real(r), real(r), real(h), f2);
  CHECK(f2 == 0);  // 2 radii off the drum: not touching, not pinned
}

TEST_CASE("CES brush: the bristles' sweep relaxes the velocity exactly over a step, and they discharge", "[ces]") {
  // One step of the core's semi-implicit Euler update v' = v + h F/m with the sweep force is the exact
  // solution of dv/dt = (v_b - v)/tau_s: v' = v_b + (v - v_b) exp(-h/tau_s); tau_s = 0 gives v' = v_b.
  const double m = 3e-7, h = 2e-4;
  const Vec3 v{0.7, -0.2, 0.05}, vb{-0.3, 0.4, 0};
  for (const double tau : {2e-3, 1e-4, 0.0}) {
    INFO("tau_s = " << tau);
    const Vec3 F = bristleSweepForce(real(m), v, vb, real(h), real(tau));
    const double e = tau > 0 ? std::exp(-h / tau) : 0.0;
    const Vec3 v1 = v + real(h / m) * F;
    CHECK(double(v1.x) == Approx(-0.3 + 1.0 * e).epsilon(1e-12));
    CHECK(double(v1.y) == Approx(0.4 - 0.6 * e).epsilon(1e-12));
    CHECK(double(v1.z) == Approx(0.05 * e).margin(1e-15));
  }
  // In the model: a brush with its axis at (0.3, 0), bristle tips at radius 0.05 m, turning at -4 pi rad/s
  // (120 rpm clockwise). The bristles at p move with omega z x (p - c): at p = (0.27, 0.01, 0),
  // v_b = -4 pi (-0.01, -0.03, 0) = (0.125664, 0.376991, 0). No air (drag ~ 0), no charge.
  CesModel md = handModel();
  md.brush = CylinderXY{0.3, 0, 0.05};
  md.brush_omega = real(-4 * M_PI);
  const double r = 0.4e-3, mass = 946 * 4.0 / 3.0 * M_PI * r * r * r;
  const Vec3 p{0.27, 0.01, 0}, vp{0, -1, 0};
  const Vec3 Fb = cesParticleForce(md, 1, p, vp, 0, real(r), real(r), real(mass), real(h));
  const double f = -std::expm1(-h / 2e-3);
  CHECK(double(Fb.x) == Approx(mass * f / h * (4 * M_PI * 0.01 - 0)).epsilon(1e-6));
  CHECK(double(Fb.y) == Approx(mass * f / h * (4 * M_PI * 0.03 + 1)).epsilon(1e-6));
  // Touching the tips from outside (centre 1.05 bounding radii beyond them): among the bristles; 1.2 radii
  // beyond: not (the contact tolerance is 1.1 radii), only the (negligible) drag.
  CHECK(length(cesParticleForce(md, 1, Vec3{real(0.35 + 1.05 * r), 0, 0}, vp, 0, real(r), real(r), real(mass),
                                real(h))) > 0.01 * mass / h);  // the sweep: mass (1 - e^(-0.1))/h x 0.372 m/s
  CHECK(length(cesParticleForce(md, 1, Vec3{real(0.35 + 1.2 * r), 0, 0}, vp, 0, real(r), real(r), real(mass),
                                real(h))) < 1e-9 * mass / h);
  // Among the bristles the charge decays with the brush's time constant (1 ms here); outside it is kept.
  uint8_t flags = 0;
  CHECK(double(cesChargeUpdate(md, 1, p, real(-4e-12), real(r), real(r), real(h), flags)) ==
        Approx(-4e-12 * std::exp(-h / 1e-3)).epsilon(1e-12));
  CHECK(cesChargeUpdate(md, 1, Vec3{0.4, 0, 0}, real(-4e-12), real(r), real(r), real(h), flags) == real(-4e-12));
}

// The configuration's defaults are the machine of docs/CES.md (drum 320 x 300 mm at 44.8 rpm, the 38 mm tube at
// 230 mm, brush 106 mm, h = 2e-4 s) and the default document (scenes/ces_default.json) says the same.
TEST_CASE("CES default machine parameters", "[ces]") {
  const CesConfig m;
  CHECK(m.drumRadius() == Approx(0.16));
  CHECK(m.drum_width == Approx(0.300));
  CHECK(m.tube.diameter / 2 == Approx(0.019));
  CHECK(m.tube.distance == Approx(0.230));
  CHECK(m.brush_diameter / 2 == Approx(0.053));
  CHECK(m.omegaDrum() == Approx(-44.8 * 2 * M_PI / 60));  // 4.6914 rad/s, clockwise seen from +z
  CHECK(m.step.dt == 2e-4);
  CHECK(defaultMaterial(MaterialKind::Metal).density_max == 8900);
  CHECK(std::isinf(defaultMaterial(MaterialKind::Plastic).relaxation_time));
  const CesConfig doc = parseCesDocument(nlohmann::json::parse(defaultCesJson()), {}, "default");
  CHECK(doc.drum_diameter == Approx(m.drum_diameter));
  CHECK(doc.tube.distance == Approx(m.tube.distance));
  CHECK(doc.step.dt == m.step.dt);
  CHECK(kEps0 == 8.8541878128e-12);
}

// Rolling resistance on the drum (forces.h: drumRollingTorque), against its definition: the moment mu_r r F_n
// opposing the rolling relative to the drum, F_n from the particle's equation of motion normal to the drum.
TEST_CASE("CES rolling resistance: mu_r r F_n against the relative rolling, limited to stopping it", "[ces]") {
  const DrumGeometry g{0, 0, 0.16, 0, 0.15, 0.005};
  const double r = 0.5e-3, m = 4e-6, I = 0.4 * m * r * r, h = 2e-4, mu_r = 0.1, gy = -9.81;
  const Vec3 grav{0, real(gy), 0};
  const double th = 60 * M_PI / 180, rho = 0.16 + r;
  const Vec3 n{real(std::cos(th)), real(std::sin(th)), 0};
  const Vec3 p = real(rho) * n;
  const Vec3 none{0, 0, 0};
  // At rest on a still drum, rolling backwards at 50 rad/s about z: F_n = m g sin(theta) (the normal component of
  // gravity), the moment mu_r r F_n about +z (against w = -50 z).
  {
    const Vec3 M = drumRollingTorque(g, p, none, Vec3{0, 0, -50}, none, none, grav, real(m), real(r), real(I),
                                     real(mu_r), real(h));
    const double Fn = m * 9.81 * std::sin(th);
    CHECK(double(M.z) == Approx(mu_r * r * Fn).epsilon(1e-5));
    CHECK(std::fabs(double(M.x)) + std::fabs(double(M.y)) < 1e-20);
  }
  // Relative to the drum: a particle turning with the drum (w = w_drum) feels none.
  CHECK(length(drumRollingTorque(g, p, none, Vec3{0, 0, -4.7}, Vec3{0, 0, -4.7}, none, grav, real(m), real(r), real(I),
                                 real(mu_r), real(h))) == 0);
  // The spin about the normal is not rolling.
  CHECK(length(drumRollingTorque(g, p, none, real(30) * n, none, none, grav, real(m), real(r), real(I), real(mu_r),
                                 real(h))) < 1e-20);
  // Slow rolling: limited to the moment that stops it within the step, I |w| / h.
  {
    const Vec3 M = drumRollingTorque(g, p, none, Vec3{0, 0, 1e-3}, none, none, grav, real(m), real(r), real(I),
                                     real(mu_r), real(h));
    CHECK(double(M.z) == Approx(-I * 1e-3 / h).epsilon(1e-5));
  }
  // Other forces pressing in add to F_n; fast enough about the axis (v_phi^2 / rho > the inward push) it leaves: 0.
  {
    const Vec3 F = real(-2 * m * 9.81) * n;  // 2 m g toward the axis (an image force, say)
    const Vec3 M =
        drumRollingTorque(g, p, none, Vec3{0, 0, -50}, none, F, grav, real(m), real(r), real(I), real(mu_r), real(h));
    CHECK(double(M.z) == Approx(mu_r * r * m * 9.81 * (std::sin(th) + 2)).epsilon(1e-5));
    const double v_leave = std::sqrt(9.81 * std::sin(th) * rho) * 1.01;
    const Vec3 e_phi{-n.y, n.x, 0};
    CHECK(length(drumRollingTorque(g, p, real(v_leave) * e_phi, Vec3{0, 0, -50}, none, none, grav, real(m), real(r),
                                   real(I), real(mu_r), real(h))) == 0);
  }
  CHECK(length(drumRollingTorque(g, p, none, Vec3{0, 0, -50}, none, none, grav, real(m), real(r), real(I), 0,
                                 real(h))) == 0);
}

TEST_CASE("CES charge exchange on contact: equal potentials, the pair's relaxation, charge kept, no overshoot",
          "[ces][charging]") {
  const real h = real(2e-4);
  // Two metals (tau = 0) share at once until q/r is equal: r 1 and 3, charges 1 and 0 -> 1/4 and 3/4.
  CHECK(double(contactChargeFlux(1, 0, 1, 3, 0, 0, h, 1)) == Approx(0.75).epsilon(1e-14));
  // Equal spheres split evenly, whatever the signs.
  CHECK(double(contactChargeFlux(2, -4, 1, 1, 0, 0, h, 1)) == Approx(3.0).epsilon(1e-14));
  // tau_i + tau_j = h / ln 2: half of the way in one step.
  const real tau = h / real(std::log(2.0));
  CHECK(double(contactChargeFlux(1, 0, 1, 1, tau / 2, tau / 2, h, 1)) == Approx(0.25).epsilon(1e-12));
  // A metal against an insulator (tau 2214 s): h / tau of the way, i.e. practically nothing.
  CHECK(std::fabs(double(contactChargeFlux(1, 0, 1, 1, 0, 2214, h, 1))) < 1e-7);
  // Equal potentials already: nothing moves.
  CHECK(double(contactChargeFlux(2, 6, 1, 3, 0, 0, h, 1)) == Approx(0.0).margin(1e-15));

  // A chain of three metals a-b-c (b has two partners): one Jacobi sweep keeps the total charge and moves no body
  // past its partners' potentials (q/r between the smallest and the largest before).
  const real r[3] = {real(0.4e-3), real(0.25e-3), real(0.5e-3)};
  const real q[3] = {real(3e-12), real(-1e-12), real(0.5e-12)};
  const int32_t partners[3] = {1, 2, 1};
  ParticleElectro pe[3];
  for (ParticleElectro& e : pe) e.tau = 0;
  const int32_t body_a[2] = {0, 1}, body_b[2] = {1, 2};
  real dq[3] = {0, 0, 0};
  for (int k = 0; k < 2; ++k) {
    const real f = exchangeFlux(pe, r, q, partners, body_a[k], body_b[k], h);
    dq[body_a[k]] -= f;
    dq[body_b[k]] += f;
  }
  double before = 0, after = 0, vmin = 1e300, vmax = -1e300;
  for (int i = 0; i < 3; ++i) {
    before += double(q[i]);
    after += double(q[i] + dq[i]);
    vmin = std::min(vmin, double(q[i] / r[i]));
    vmax = std::max(vmax, double(q[i] / r[i]));
  }
  CHECK(after == Approx(before).epsilon(1e-14));
  for (int i = 0; i < 3; ++i) {
    const double v = double((q[i] + dq[i]) / r[i]);
    CHECK(v >= vmin * (1 + 1e-12) - 1e-30);
    CHECK(v <= vmax * (1 + 1e-12) + 1e-30);
  }
  // The spread of the potentials shrinks.
  double wmin = 1e300, wmax = -1e300;
  for (int i = 0; i < 3; ++i) {
    wmin = std::min(wmin, double((q[i] + dq[i]) / r[i]));
    wmax = std::max(wmax, double((q[i] + dq[i]) / r[i]));
  }
  CHECK(wmax - wmin < 0.6 * (vmax - vmin));
}

TEST_CASE("CES charge exchange: a pair counts once, at its first touching point", "[ces][charging]") {
  // Contacts: pair (1,2) with three points (the first apart, the second and third touching), pair (1,3) apart,
  // pair (2,4) with one touching point.
  const int32_t a[5] = {1, 1, 1, 1, 2}, b[5] = {2, 2, 2, 3, 4};
  const real dist[5] = {real(1e-6), real(-1e-7), real(-2e-7), real(5e-7), real(0)};
  const bool expect[5] = {false, true, false, false, true};
  for (int k = 0; k < 5; ++k) CHECK(firstTouchingPointOfPair(a, b, dist, k) == expect[k]);
}
