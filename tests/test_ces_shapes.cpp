// Shape-aware electrostatics (src/ces/shape_charging.h) and composite particles (charging.h, feeder.h, the
// splitters) against analytic references: depolarisation factors against Osborn's closed forms and their sum
// rule, the ellipsoid's Pauthenier charge against a search over its surface and the sphere's law, the cylinder on
// a plane against quadrature of its exact field, the sphere and thin-plate limits of every shape model, the
// support against sampled surface points, the GEM conductivity against the percolation laws it reduces to.
#include <catch2/catch.hpp>

#include <cmath>
#include <complex>
#include <vector>

#include "ces/ces_config.h"
#include "ces/feeder.h"
#include "ces/output/splitters.h"
#include "ces/particle_model.h"
#include "ces/shape_charging.h"
#include "chrono_like/base/errors.h"

using namespace dvi;
using namespace dvi::ces;

namespace {

constexpr double kE0 = 8.8541878128e-12;

// Osborn (1945), eq. 5 and 6: the depolarisation factor along the symmetry axis of a spheroid of semi-axes
// (a, a, c), m = c / a.
double osbornAxial(double m) {
  if (m > 1) {
    const double s = std::sqrt(m * m - 1);
    return (m / (2 * s) * std::log((m + s) / (m - s)) - 1) / (m * m - 1);
  }
  const double s = std::sqrt(1 - m * m);
  return (1 - m / s * std::acos(m)) / (1 - m * m);
}

}  // namespace

TEST_CASE("Depolarisation factors: sphere, Osborn's spheroids, sum rule, plate and needle limits",
          "[ces][ces_shapes]") {
  CHECK(double(depolarizationFactor(1, 1, 1)) == Approx(1.0 / 3.0).epsilon(1e-12));
  for (double m : {0.05, 0.25, 0.5, 0.9, 1.5, 2.0, 4.0, 20.0}) {
    INFO("aspect " << m);
    CHECK(double(depolarizationFactor(real(m), 1, 1)) == Approx(osbornAxial(m)).epsilon(1e-9));
    CHECK(double(depolarizationFactor(1, real(m), 1)) == Approx((1 - osbornAxial(m)) / 2).epsilon(1e-9));
  }
  for (Vec3 e : {Vec3{1, 0.5, 0.7}, Vec3{0.3, 2, 1.1}, Vec3{1, 0.01, 3}}) {
    const Vec3 n = depolarizationFactors(e);
    CHECK(double(n.x + n.y + n.z) == Approx(1.0).epsilon(1e-10));
  }
  CHECK(double(depolarizationFactor(real(1e-4), 1, 1)) > 0.9998);  // across a thin plate: 1
  CHECK(double(depolarizationFactor(100, 1, 1)) < 1e-3);           // along a needle: 0
}

TEST_CASE("Pauthenier charge of an ellipsoid: the sphere's law and the maximum over its surface", "[ces][ces_shapes]") {
  const double r = 0.4e-3, E = 3e5;
  for (double eps : {2.5, 10.0, double(INFINITY)}) {
    const Vec3 e{real(r), real(r), real(r)};
    const real q = pauthenierSaturationChargeEllipsoid(e, depolarizationFactors(e), Vec3{0, real(E), 0}, real(eps));
    CHECK(double(q) == Approx(double(pauthenierSaturationCharge(real(r), real(E), real(eps)))).epsilon(1e-9));
  }
  // A general ellipsoid in an oblique field: the closed form against a search over the surface for the charge at
  // which the outward normal field of polarisation, sum c_i x_i/e_i^2 / |g|, equals the own charge's
  // q / (4 pi eps0 abc |g|) at its largest (the same condition, solved by sampling instead of Cauchy-Schwarz).
  const Vec3 e{real(0.6e-3), real(0.2e-3), real(0.35e-3)}, Eb{real(1e5), real(-2e5), real(0.7e5)};
  const double eps = 4.0;
  const Vec3 n = depolarizationFactors(e);
  const double c[3] = {eps * Eb.x / (1 + n.x * (eps - 1)), eps * Eb.y / (1 + n.y * (eps - 1)),
                       eps * Eb.z / (1 + n.z * (eps - 1))};
  double best = 0;
  for (int i = 0; i <= 400; ++i)
    for (int j = 0; j < 800; ++j) {
      const double th = M_PI * i / 400, ph = 2 * M_PI * j / 800;
      const double u[3] = {std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th)};
      best = std::max(best, c[0] * u[0] / e.x + c[1] * u[1] / e.y + c[2] * u[2] / e.z);  // x_i = e_i u_i
    }
  const double q_search = 4 * M_PI * kE0 * e.x * e.y * e.z * best;
  CHECK(double(pauthenierSaturationChargeEllipsoid(e, n, Eb, real(eps))) == Approx(q_search).epsilon(1e-4));
  // A conductor with the field along its axis i: 4 pi eps0 e_j e_k E / n_i.
  CHECK(double(pauthenierSaturationChargeEllipsoid(e, n, Vec3{real(E), 0, 0}, real(INFINITY))) ==
        Approx(4 * M_PI * kE0 * e.y * e.z * E / n.x).epsilon(1e-9));
}

TEST_CASE("A conducting cylinder lying on an earthed plane: charge and lift by quadrature of its exact field",
          "[ces][ces_shapes]") {
  // Omega(z) = pi a E coth(pi a / z), phi = Im Omega: zero on the plane Im z = 0 and on the circle |z - ia| = a,
  // -> E z far away. The field |dOmega/dz| integrated over the circle gives the charge per length (eps0 E.n ds) and
  // the lift ((eps0/2) E^2 n_y ds); both against the closed forms in shape_charging.h.
  const double a = 1.0, E = 1.0;
  auto Om = [&](std::complex<double> z) { return M_PI * a * E / std::tanh(M_PI * a / z); };
  auto dOm = [&](std::complex<double> z) {
    const std::complex<double> u = M_PI * a / z;
    if (std::fabs(u.real()) > 300) return std::complex<double>(0, 0);
    const std::complex<double> s = std::sinh(u);
    return M_PI * a * E * (M_PI * a / (z * z)) / (s * s);
  };
  // The boundary conditions and the far field.
  for (double th : {-1.2, 0.0, 0.7, 2.0, 3.5})
    CHECK(std::fabs(Om(std::complex<double>(0, a) + a * std::exp(std::complex<double>(0, th))).imag()) < 1e-9);
  CHECK(std::fabs(Om(std::complex<double>(3.7, 1e-12)).imag()) < 1e-9);
  CHECK(Om(std::complex<double>(0, 1e4)).imag() == Approx(1e4).epsilon(1e-6));
  const int N = 200000;
  double q = 0, F = 0;
  for (int k = 1; k < N; ++k) {
    const double th = -M_PI / 2 + 2 * M_PI * k / N, ds = a * 2 * M_PI / N;
    const double En = std::abs(dOm(std::complex<double>(0, a) + a * std::exp(std::complex<double>(0, th))));
    q += En * ds;
    F += 0.5 * En * En * std::sin(th) * ds;
  }
  CHECK(q == Approx(double(kCylinderChargeFactor)).epsilon(1e-6));  // 2 pi
  CHECK(F == Approx(double(kCylinderForceFactor)).epsilon(1e-6));   // pi (pi^2 + 3) / 9 = 4.4923
  CHECK(double(kCylinderLiftFactor) == Approx((M_PI * M_PI + 3) / 18).epsilon(1e-12));
}

TEST_CASE("Shape models: the sphere, thin-plate and long-wire limits, orientation", "[ces][ces_shapes]") {
  const double r = 0.4e-3;
  ParticleElectro s, ell, plate, wire, flake;
  shapeElectro(kShapeSphere, Vec3{real(r), real(r), real(r)}, s);
  // The sphere: the Félici charge and Lebedev-Skal'skaya's lift in every orientation.
  const double qF = double(feliciCharge(real(r), real(1))) / kE0;
  for (const Vec3 u : {Vec3{1, 0, 0}, Vec3{0, 0.6, 0.8}}) {
    CHECK(double(weighted(s.qcoef, u)) == Approx(qF).epsilon(1e-9));
    CHECK(double(weighted(s.lift, u)) == Approx(double(kFeliciLiftFactor)).epsilon(1e-9));
  }
  // An ellipsoid with equal semi-axes is the sphere (the boss model is scaled to it).
  shapeElectro(kShapeEllipsoid, Vec3{real(r), real(r), real(r)}, ell);
  CHECK(double(ell.qcoef.y) == Approx(qF).epsilon(1e-9));
  // A thin plate lying flat: eps0 E A and the pressure's lift 1/2 (thickness 1e-4 of its width).
  shapeElectro(kShapeFlake, Vec3{real(r), real(r * 1e-4), real(r)}, plate);
  CHECK(double(plate.qcoef.y) == Approx(4 * r * r).epsilon(1e-3));
  CHECK(double(plate.lift.y) == Approx(0.5).epsilon(1e-3));
  // A long wire lying on the plane: 2 pi a per length, lift (pi^2 + 3)/18.
  shapeElectro(kShapeWire, Vec3{real(r), real(2000 * r), real(r)}, wire);
  CHECK(double(wire.qcoef.x) / (2 * 2000 * r) == Approx(2 * M_PI * r).epsilon(1e-3));
  CHECK(double(wire.lift.z) == Approx((M_PI * M_PI + 3) / 18).epsilon(1e-3));
  // The feeder's flake (a, a/4, a) lying flat carries the slab's charge, 4a^2 + 8a (pi - 1) a/4; on its edge more.
  const double a = 0.5e-3;
  shapeElectro(kShapeFlake, Vec3{real(a), real(a / 4), real(a)}, flake);
  CHECK(double(flake.qcoef.y) == Approx(4 * a * a + 8 * a * (M_PI - 1) * a / 4).epsilon(1e-9));
  CHECK(flake.qcoef.x > flake.qcoef.y);
}

TEST_CASE("Shape support: the largest extent along a direction, against sampled surface points", "[ces][ces_shapes]") {
  ParticleElectro box, cyl, ell;
  shapeElectro(kShapeFlake, Vec3{real(0.5), real(0.125), real(0.5)}, box);
  shapeElectro(kShapeWire, Vec3{real(0.2), real(0.8), real(0.2)}, cyl);
  shapeElectro(kShapeEllipsoid, Vec3{real(1), real(0.5), real(0.7)}, ell);
  for (const Vec3 d : {Vec3{0, 1, 0}, Vec3{0.48, 0.6, 0.64}, Vec3{-0.8, 0, 0.6}}) {
    double sb = 0, sc = 0, se = 0;
    for (int i = 0; i <= 200; ++i)
      for (int j = 0; j < 400; ++j) {
        const double t = double(i) / 200, ph = 2 * M_PI * j / 400, th = M_PI * i / 200;
        // Box corners and edges are reached by the sign pattern; cylinder rim points; ellipsoid surface points.
        for (int sx = -1; sx <= 1; sx += 2)
          for (int sy = -1; sy <= 1; sy += 2)
            sb = std::max(sb, sx * 0.5 * d.x + sy * 0.125 * d.y + (2 * t - 1) * 0.5 * d.z);
        sc = std::max(sc, 0.2 * std::cos(ph) * d.x + (2 * t - 1) * 0.8 * d.y + 0.2 * std::sin(ph) * d.z);
        se = std::max(
            se, std::sin(th) * std::cos(ph) * d.x + 0.5 * std::sin(th) * std::sin(ph) * d.y + 0.7 * std::cos(th) * d.z);
      }
    CHECK(double(shapeSupport(box, d)) == Approx(sb).epsilon(1e-9));
    CHECK(double(shapeSupport(cyl, d)) == Approx(sc).epsilon(1e-4));
    CHECK(double(shapeSupport(ell, d)) == Approx(se).epsilon(1e-4));
  }
}

namespace {
// The drum at the origin (R = 0.16 m), a uniform upward 8 kV/cm field and no ions; no air, no brush.
struct Hand {
  std::vector<float> ex = std::vector<float>(16, 0.f), ey = std::vector<float>(16, 8e5f);
  std::vector<float> phi = std::vector<float>(16, 0.f), n = std::vector<float>(16, 0.f);
  CesModel m{};
  Hand() {
    m.drum = DrumGeometry{0, 0, 0.16, 0, 0.15, 5e-3};
    m.polarity = -1;
    m.ion_mobility = 2.1e-4;
    m.pin_dy = -0.15;
    m.brush = CylinderXY{10, 10, 0.05};
    m.air_density = 0;
    m.air_viscosity = 1e-12;
    m.contact_tol = 1.1;
    m.field.model = 2;
    GridFieldView& g = m.field.grid;
    g.x0 = -1, g.y0 = -1, g.dx = g.dy = 2.0 / 3.0, g.nx = g.ny = 4;
    g.Ex = ex.data(), g.Ey = ey.data(), g.phi = phi.data(), g.ion_density = n.data();
  }
};
}  // namespace

TEST_CASE("A copper flake and wire on the drum: induced charge, lift and contact by their true distance",
          "[ces][ces_shapes]") {
  Hand h;
  MaterialConfig cu;
  cu.kind = MaterialKind::Metal;
  SplitMix64 rng{1};
  const double d = 0.8e-3, En = 8e5;
  const ParticleSpec fs = makeParticleSpec(0, ParticleShape::Flake, d, 8900, rng);
  const ParticleElectro flake = makeParticleElectro(fs, cu);
  const Quat flat{1, 0, 0, 0};  // the flake's thin axis (y) along the drum's normal at its top
  const real b = fs.dims.y;
  // Lying flat, its centre b above the drum: touching, and it takes eps0 En (A + rim) at once (tau = 0).
  uint8_t f = 0;
  const Vec3 top{0, real(0.16) + b, 0};
  const double q = cesChargeUpdate(h.m, flake, top, flat, real(-1e-12), fs.radius, fs.bound, real(2e-4), f);
  CHECK(q == Approx(kE0 * En * double(flake.qcoef.y)).epsilon(1e-5));
  // Its lift is the slab's k_L q E (< the sphere's 0.832), straight up.
  const Vec3 F =
      cesParticleForce(h.m, flake, top, flat, Vec3{0, 0, 0}, real(q), fs.radius, fs.bound, real(1e-6), real(2e-4));
  CHECK(double(F.y) == Approx(double(flake.lift.y) * q * En).epsilon(1e-5));
  CHECK(flake.lift.y < kFeliciLiftFactor);
  // 0.6 bounding radii off the drum a flat flake no longer touches (the old 1.1 x bound test said it did), and
  // keeps its charge.
  const Vec3 off{0, real(0.16) + real(0.6) * fs.bound, 0};
  CHECK(double(cesChargeUpdate(h.m, flake, off, flat, real(-1e-12), fs.radius, fs.bound, real(2e-4), f)) ==
        Approx(-1e-12));
  // Standing on its edge (x along the normal) it touches with its centre a above the drum, and takes more charge.
  const Quat edge = quatFromAxisAngle(Vec3{0, 0, 1}, real(M_PI / 2));
  const Vec3 top_edge{0, real(0.16) + fs.dims.x, 0};
  CHECK(double(cesChargeUpdate(h.m, flake, top_edge, edge, 0, fs.radius, fs.bound, real(2e-4), f)) ==
        Approx(kE0 * En * double(flake.qcoef.x)).epsilon(1e-5));
  // A wire lying on the drum (axis y turned to x): the capsule's charge.
  const ParticleSpec ws = makeParticleSpec(0, ParticleShape::Wire, d, 8900, rng);
  const ParticleElectro wire = makeParticleElectro(ws, cu);
  const double a = ws.dims.x, L = 2 * (ws.dims.y - a);
  const Vec3 top_wire{0, real(0.16) + real(a), 0};
  CHECK(double(cesChargeUpdate(h.m, wire, top_wire, edge, 0, ws.radius, ws.bound, real(2e-4), f)) ==
        Approx(kE0 * En * (2 * M_PI * a * L + 2.0 / 3.0 * std::pow(M_PI, 3) * a * a)).epsilon(1e-5));
  // A sphere's charge is Félici's: the material-indexed form the model had before (no shape) agrees.
  const ParticleSpec ss = makeParticleSpec(0, ParticleShape::Sphere, d, 8900, rng);
  const ParticleElectro sph = makeParticleElectro(ss, cu);
  CHECK(double(cesChargeUpdate(h.m, sph, Vec3{0, real(0.16 + 0.4e-3), 0}, edge, 0, ss.radius, ss.bound, real(2e-4),
                               f)) == Approx(double(feliciCharge(ss.radius, real(En)))).epsilon(1e-6));
}

TEST_CASE("Image force of a flat contact: the point image at the true distance, at most a sheet's",
          "[ces][ces_shapes]") {
  const double q = 1e-12, r = 0.4e-3;
  // A sphere keeps the point image at d >= r.
  CHECK(double(imageForceShape(real(q), real(r), real(r), real(M_PI * r * r))) ==
        Approx(q * q / (16 * M_PI * kE0 * r * r)).epsilon(1e-9));
  // A flat flake (half thickness r/8, face 4 r^2) on the drum: the sheet's q^2 / (2 eps0 A).
  CHECK(double(imageForceShape(real(q), real(r / 8), real(r / 8), real(4 * r * r))) ==
        Approx(q * q / (2 * kE0 * 4 * r * r)).epsilon(1e-9));
}

TEST_CASE("Composite conductivity: GEM's limits are the percolation laws, relaxation between metal and plastic",
          "[ces][ces_shapes]") {
  const real pc = kPercolationThreshold, t = kPercolationExponent;
  CHECK(double(gemConductivity(0, 6e7, 1e-14, pc, t)) == Approx(1e-14).epsilon(1e-9));
  CHECK(double(gemConductivity(1, 6e7, 1e-14, pc, t)) == Approx(6e7).epsilon(1e-9));
  // An insulating matrix (sp -> 0): s = sm ((phi - phi_c)/(1 - phi_c))^t above the threshold.
  for (double phi : {0.2, 0.4, 0.7})
    CHECK(double(gemConductivity(real(phi), 6e7, 1e-30, pc, t)) ==
          Approx(6e7 * std::pow((phi - 0.16) / 0.84, 2)).epsilon(1e-6));
  // A perfectly conducting filler (sm -> inf): s = sp (phi_c / (phi_c - phi))^t below it.
  for (double phi : {0.02, 0.08, 0.12})
    CHECK(double(gemConductivity(real(phi), 1e30, 1e-14, pc, t)) ==
          Approx(1e-14 * std::pow(0.16 / (0.16 - phi), 2)).epsilon(1e-6));
  // Maxwell Garnett: eps_m (1 + 2 phi)/(1 - phi); conducting from the threshold.
  CHECK(double(compositePermittivity(real(0.1), real(4.4), pc)) == Approx(4.4 * 1.2 / 0.9).epsilon(1e-9));
  CHECK(std::isinf(compositePermittivity(real(0.2), real(4.4), pc)));
  // The relaxation time falls monotonically from the plastic's to the metal's.
  double prev = double(relaxationTime(real(4.4), real(1e-14)));
  for (double phi = 0.02; phi < 1; phi += 0.04) {
    const double tau = double(compositeRelaxationTime(real(phi), real(4.4), kCopperConductivity, real(1e-14)));
    CHECK(tau < prev);
    prev = tau;
  }
  CHECK(prev < 1e-15);
}

TEST_CASE("Composite particles: metal fraction, exact mass split, accounting as metal and plastic",
          "[ces][ces_shapes]") {
  CesConfig cfg = parseCesDocument(nlohmann::json::parse(defaultCesJson()), {}, "default");
  size_t ic = 0;
  while (cfg.materials[ic].kind != MaterialKind::Composite) ++ic;
  const MaterialConfig& mc = cfg.materials[ic];
  cfg.feed_mass_flow = 2e-3;  // 4x the default: ~140 composites in the 0.6 s window
  CHECK(mc.metal_fraction_min == 0.05);
  CHECK(mc.metal_fraction_max == 0.6);
  Feeder feeder(cfg);
  std::vector<ParticleSpec> out;
  for (int k = 0; k < 600; ++k) feeder.emit(k * 1e-3, 1e-3, out);  // the feed window, 0.6 s
  int n = 0;
  double phi_sum = 0;
  std::vector<CollectedParticle> col;
  int64_t metal = 0, plastic = 0;
  for (ParticleSpec& s : out) {
    compositeParts(s, cfg.materials[size_t(s.material)]);
    const MaterialKind kind = cfg.materials[size_t(s.material)].kind;
    if (kind != MaterialKind::Composite) continue;
    ++n;
    phi_sum += s.metal_fraction;
    CHECK(s.metal_fraction >= 0.05 - 1e-6);
    CHECK(s.metal_fraction <= 0.6 + 1e-6);
    // The metal's mass share phi rho_m / rho with rho = phi rho_m + (1 - phi) rho_p, in whole femtograms.
    const double rho = s.metal_fraction * 8900 + (1 - s.metal_fraction) * 1850;
    CHECK(double(s.metal_fg) == Approx(double(s.mass_fg) * s.metal_fraction * 8900 / rho).epsilon(1e-5));
    CollectedParticle c{0, int32_t(s.material), kind, float(double(s.metal_fg) / double(s.mass_fg)), s.mass_fg, 0.3, 0,
                        0};
    metal += metalFg(c);
    plastic += s.mass_fg - metalFg(c);
    col.push_back(c);
    const ParticleElectro pe = makeParticleElectro(s, mc);
    CHECK(pe.conductor == (s.metal_fraction >= 0.16 ? 1 : 0));
  }
  REQUIRE(n > 50);
  CHECK(phi_sum / n == Approx(0.325).margin(0.05));  // uniform on [0.05, 0.6]
  // In the conductor bin they count as their metal and plastic parts, which add up to their mass exactly.
  const BinMasses bins = binDirect(col, 0.0, 0.2);
  CHECK(bins.fg[kBinConductor][0] == metal);
  CHECK(bins.fg[kBinConductor][1] == plastic);
  CHECK(bins.fg[kBinConductor][2] == 0);
  const SplitterCell cell = splitterCell(col, 0.0, 0.2);
  CHECK(cell.grade_metal == Approx(double(metal) / double(metal + plastic)).epsilon(1e-12));
}

TEST_CASE("Composite configuration: bad metal fractions and keys are input errors", "[ces][ces_shapes]") {
  const nlohmann::json doc = nlohmann::json::parse(defaultCesJson());
  auto bad = [&](const std::string& set, const char* what) {
    INFO(set);
    CHECK_THROWS_AS(parseCesDocument(doc, {set}, "t"), InputError);
    CHECK_THROWS_WITH(parseCesDocument(doc, {set}, "t"), Catch::Contains(what));
  };
  bad("feed.materials.2.metal_fraction=[0.6,0.2]", "metal_fraction");
  bad("feed.materials.2.metal_fraction=1.5", "metal_fraction");
  bad("feed.materials.2.metal_fraction=[-0.1,0.5]", "metal_fraction");
  bad("feed.materials.2.metal_density_kg_m3=1000", "metal_density_kg_m3");
  bad("feed.materials.2.relaxation_time_s=1", "relaxation_time_s");
  bad("feed.materials.1.metal_fraction=0.3", "only a composite");
  CHECK(parseCesDocument(doc, {"feed.materials.2.metal_fraction=0.3"}, "t").materials[2].metal_fraction_max == 0.3);
}

TEST_CASE("Surface conductivity: O'Konski's 2 sigma_s / r adds to the bulk's rate, and the key is checked",
          "[ces][ces_shapes]") {
  const double r = 0.4e-3, eps = 2.5, ss = 1e-14;
  // No bulk conduction: tau = eps0 eps_r r / (2 sigma_s) = 0.4427 s.
  CHECK(double(surfaceRelaxationTime(real(INFINITY), real(ss), real(r), real(eps))) ==
        Approx(kE0 * eps * r / (2 * ss)).epsilon(1e-9));
  // With bulk conduction the rates add; sigma_s = 0 and a conductor keep the bulk's time.
  CHECK(double(surfaceRelaxationTime(real(2), real(ss), real(r), real(eps))) ==
        Approx(1 / (0.5 + 2 * ss / (r * kE0 * eps))).epsilon(1e-9));
  CHECK(surfaceRelaxationTime(real(2), 0, real(r), real(eps)) == real(2));
  CHECK(surfaceRelaxationTime(0, real(ss), real(r), real(INFINITY)) == 0);
  // Through the configuration to a fed plastic sphere.
  const nlohmann::json doc = nlohmann::json::parse(defaultCesJson());
  const CesConfig cfg = parseCesDocument(doc, {"feed.materials.1.surface_conductivity_S=1e-14"}, "t");
  SplitMix64 rng{1};
  const ParticleSpec s = makeParticleSpec(1, ParticleShape::Sphere, 2 * r, 946, rng);
  const double tau_bulk = cfg.materials[1].relaxation_time;  // 2214 s (1e-14 S/m)
  CHECK(double(makeParticleElectro(s, cfg.materials[1]).tau) ==
        Approx(1 / (1 / tau_bulk + 2 * ss / (r * kE0 * eps))).epsilon(1e-6));
  CHECK_THROWS_AS(parseCesDocument(doc, {"feed.materials.1.surface_conductivity_S=-1"}, "t"), InputError);
}

TEST_CASE("A metal with a contact time on the drum in the corona keeps ion charge: the steady state of the two rates",
          "[ces][ces_shapes]") {
  // Ions everywhere (tau_c = 1 ms) in the upward 8 kV/cm field, negative corona; a copper sphere on top of the
  // drum with a contact relaxation time tau = 1 ms. Counted in the ions' polarity (Q = -q), Pauthenier's charging
  // (Q_s/tau_c)(1 - Q/Q_s)^2 balances the relaxation (Q - Q_ind)/tau toward the induced charge (Q_ind = -q_F):
  // a quadratic for Q, solved here by hand; the stepped charge must settle there (to the splitting's O(h)).
  Hand h;
  const double tau_c = 1e-3, tau = 1e-3, mu = 2.1e-4, En = 8e5, r = 0.4e-3;
  const double N = 4 * kE0 / (tau_c * 1.602176634e-19 * mu);
  std::fill(h.n.begin(), h.n.end(), float(N));
  ParticleElectro pe;
  shapeElectro(kShapeSphere, Vec3{real(r), real(r), real(r)}, pe);
  pe.eps_r = real(INFINITY), pe.tau = real(tau), pe.conductor = 1;
  const double qs = 4 * M_PI * kE0 * r * r * En * 3, Qi = -double(feliciCharge(real(r), real(En)));
  // (qs/tau_c)(1 - Q/qs)^2 = (Q - Qi)/tau  ->  A Q^2 + B Q + C = 0
  const double A = tau / (tau_c * qs), B = -2 * tau / tau_c - 1, C = tau * qs / tau_c + Qi;
  const double Q = (-B - std::sqrt(B * B - 4 * A * C)) / (2 * A);
  REQUIRE(Q > Qi);
  REQUIRE(Q < qs);
  uint8_t f = 0;
  real q = 0;
  const Vec3 top{0, real(0.16 + r), 0};
  for (int k = 0; k < 20000; ++k)
    q = cesChargeUpdate(h.m, pe, top, Quat{1, 0, 0, 0}, q, real(r), real(r), real(1e-6), f);
  CHECK(-double(q) == Approx(Q).epsilon(5e-3));
  // With tau = 0 (the default metal) the ion charge goes to earth every step: the induced charge.
  pe.tau = 0;
  CHECK(double(cesChargeUpdate(h.m, pe, top, Quat{1, 0, 0, 0}, q, real(r), real(r), real(1e-6), f)) ==
        Approx(-Qi).epsilon(1e-9));
}
