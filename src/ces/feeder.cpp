// The feeder (feeder.h): particle shapes with exact volume and inertia, mass-flow emission.
#include "ces/feeder.h"

#include <btBulletCollisionCommon.h>
#include <LinearMath/btConvexHullComputer.h>

#include <eigen3/Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "ces/ces_constants.h"
#include "chrono_like/base/errors.h"

namespace dvi {
namespace ces {

namespace {

constexpr double kPiD = 3.14159265358979323846;

// Volume, centroid and inertia tensor (about the centroid, unit density) of the convex hull of `pts`,
// by the signed tetrahedra (centre, face triangle): for a tetrahedron with vertices x_i (one at the
// origin of the sums) int x x^T dV = V/20 (sum x_i x_i^T + s s^T), s = sum x_i (Tonon, "Explicit exact
// formulas for the 3-D tetrahedron inertia tensor in terms of its vertex coordinates", J. Math. Stat.
// 1 (2005) 8-11).
void hullMassProperties(const std::vector<Vec3>& pts, double& volume, Eigen::Vector3d& centroid,
                        Eigen::Matrix3d& inertia) {
  btConvexHullComputer hull;
  std::vector<double> flat;
  for (const Vec3& p : pts) flat.insert(flat.end(), {double(p.x), double(p.y), double(p.z)});
  hull.compute(flat.data(), int(3 * sizeof(double)), int(pts.size()), 0, 0);
  Eigen::Vector3d o(0, 0, 0);
  for (const Vec3& p : pts) o += Eigen::Vector3d(p.x, p.y, p.z);
  o /= double(pts.size());
  double V = 0;
  Eigen::Vector3d first(0, 0, 0);
  Eigen::Matrix3d second = Eigen::Matrix3d::Zero();  // int x x^T dV about o
  for (int f = 0; f < hull.faces.size(); ++f) {
    const btConvexHullComputer::Edge* e0 = &hull.edges[hull.faces[f]];
    const btVector3& A = hull.vertices[e0->getSourceVertex()];
    const btConvexHullComputer::Edge* e = e0->getNextEdgeOfFace();
    for (int guard = 0; e->getTargetVertex() != e0->getSourceVertex() && guard < 1000; ++guard) {
      const btVector3& B = hull.vertices[e->getSourceVertex()];
      const btVector3& C = hull.vertices[e->getTargetVertex()];
      const Eigen::Vector3d a = Eigen::Vector3d(A.x(), A.y(), A.z()) - o, b = Eigen::Vector3d(B.x(), B.y(), B.z()) - o,
                            c = Eigen::Vector3d(C.x(), C.y(), C.z()) - o;
      const double v = a.dot(b.cross(c)) / 6.0;
      const Eigen::Vector3d s = a + b + c;
      V += v;
      first += v * s / 4.0;
      second += v / 20.0 * (a * a.transpose() + b * b.transpose() + c * c.transpose() + s * s.transpose());
      e = e->getNextEdgeOfFace();
    }
  }
  if (V < 0) V = -V, first = -first, second = -second;
  volume = V;
  const Eigen::Vector3d cl = first / V;  // centroid relative to o
  centroid = o + cl;
  const Eigen::Matrix3d cov = second - V * cl * cl.transpose();  // about the centroid
  inertia = cov.trace() * Eigen::Matrix3d::Identity() - cov;
}

}  // namespace

ParticleSpec makeParticleSpec(int material, ParticleShape shape, double diameter, double density, SplitMix64& rng) {
  ParticleSpec s;
  s.material = material;
  s.shape = shape;
  const double V = kPiD * diameter * diameter * diameter / 6.0;
  s.mass_fg = std::max<int64_t>(1, int64_t(std::llround(density * V / kFemtogram)));
  const double m = double(s.mass_fg) * kFemtogram;
  s.radius = real(diameter / 2);
  double I[3];
  switch (shape) {
    case ParticleShape::Sphere: {
      const double r = diameter / 2;
      s.dims = Vec3{real(r), 0, 0};
      I[0] = I[1] = I[2] = 0.4 * m * r * r;
      s.bound = real(r);
      break;
    }
    case ParticleShape::Flake: {  // box (a, a/4, a): V = 2 a^3
      const double a = std::cbrt(V / 2), b = a / 4;
      s.dims = Vec3{real(a), real(b), real(a)};
      I[0] = m / 3 * (b * b + a * a);
      I[1] = m / 3 * (a * a + a * a);
      I[2] = m / 3 * (a * a + b * b);
      s.bound = real(std::sqrt(2 * a * a + b * b));
      break;
    }
    case ParticleShape::Wire: {  // cylinder radius r, half height 4 r: V = 8 pi r^3
      const double r = std::cbrt(V / (8 * kPiD)), H = 4 * r;
      s.dims = Vec3{real(r), real(H), 0};
      I[1] = 0.5 * m * r * r;
      I[0] = I[2] = m * (3 * r * r + 4 * H * H) / 12;
      s.bound = real(std::sqrt(r * r + H * H));
      break;
    }
    case ParticleShape::Ellipsoid: {  // semi-axes (a, 0.5 a, 0.7 a): V = 4/3 pi 0.35 a^3
      const double a = std::cbrt(V / (4.0 / 3.0 * kPiD * 0.35)), b = 0.5 * a, c = 0.7 * a;
      s.dims = Vec3{real(a), real(b), real(c)};
      I[0] = m / 5 * (b * b + c * c);
      I[1] = m / 5 * (a * a + c * c);
      I[2] = m / 5 * (a * a + b * b);
      s.bound = real(a);
      break;
    }
    case ParticleShape::Fragment: {
      // 10 points on an ellipsoid with random semi-axes in [0.6, 1] (all of them hull vertices).
      const double ax[3] = {rng.uniform(0.6, 1.0), rng.uniform(0.6, 1.0), rng.uniform(0.6, 1.0)};
      std::vector<Vec3> pts;
      for (int i = 0; i < 10; ++i) {
        const double zc = rng.uniform(-1, 1), ph = rng.uniform(0, 2 * kPiD), rr = std::sqrt(1 - zc * zc);
        pts.push_back(Vec3{real(ax[0] * rr * std::cos(ph)), real(ax[1] * rr * std::sin(ph)), real(ax[2] * zc)});
      }
      double V0;
      Eigen::Vector3d c0;
      Eigen::Matrix3d I0;
      hullMassProperties(pts, V0, c0, I0);
      if (!(V0 > 1e-3)) {  // degenerate draw (all points near a plane): fall back to an ellipsoid
        return makeParticleSpec(material, ParticleShape::Ellipsoid, diameter, density, rng);
      }
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(I0);
      Eigen::Matrix3d R = eig.eigenvectors();
      if (R.determinant() < 0) R.col(2) = -R.col(2);
      const double k = std::cbrt(V / V0);  // scale to the target volume
      double bound = 0;
      s.hull.clear();
      for (const Vec3& p : pts) {
        const Eigen::Vector3d q = k * (R.transpose() * (Eigen::Vector3d(p.x, p.y, p.z) - c0));
        s.hull.push_back(Vec3{real(q.x()), real(q.y()), real(q.z())});
        bound = std::max(bound, q.norm());
      }
      // Inertia scales with density x k^5; unit density x V0 -> mass m.
      const double scale = m / V0 * k * k;
      for (int i = 0; i < 3; ++i) I[i] = eig.eigenvalues()(i) * scale;
      s.bound = real(bound);
      break;
    }
    default: throw InputError("CES feeder: unknown particle shape");
  }
  s.inertia = Vec3{real(I[0]), real(I[1]), real(I[2])};
  return s;
}

ShapeDesc particleShapeDesc(const ParticleSpec& s) {
  switch (s.shape) {
    case ParticleShape::Sphere: return makeSphere(s.dims.x);
    case ParticleShape::Flake: return makeBox(s.dims);
    case ParticleShape::Wire: return makeCylinder(s.dims.x, s.dims.y);
    case ParticleShape::Ellipsoid: return makeEllipsoid(s.dims);
    case ParticleShape::Fragment: return makeConvexHull(s.hull);
    default: throw InputError("CES feeder: unknown particle shape");
  }
}

void compositeParts(ParticleSpec& s, const MaterialConfig& mat) {
  s.metal_fraction = mat.kind == MaterialKind::Metal ? 1.0 : 0.0;
  s.metal_fg = mat.kind == MaterialKind::Metal ? s.mass_fg : 0;
  if (mat.kind != MaterialKind::Composite) return;
  const double r = double(s.radius), V = 4.0 / 3.0 * kPiD * r * r * r;
  const double rho = double(s.mass_fg) * kFemtogram / V;
  const double phi = (rho - mat.matrix_density) / (mat.metal_density - mat.matrix_density);
  s.metal_fraction = std::min(1.0, std::max(0.0, phi));
  const int64_t metal = int64_t(std::llround(double(s.mass_fg) * s.metal_fraction * mat.metal_density / rho));
  s.metal_fg = std::min(s.mass_fg, std::max<int64_t>(0, metal));
}

ParticleElectro makeParticleElectro(const ParticleSpec& s, const MaterialConfig& mat) {
  ParticleElectro pe;
  const real r = s.radius;
  Vec3 half{r, r, r};
  switch (s.shape) {
    case ParticleShape::Flake:
    case ParticleShape::Ellipsoid: half = s.dims; break;
    case ParticleShape::Wire: half = Vec3{s.dims.x, s.dims.y, s.dims.x}; break;
    case ParticleShape::Fragment: {  // solid ellipsoid: I_x = m (b^2 + c^2)/5, so a^2 ~ I_y + I_z - I_x
      const double I[3] = {s.inertia.x, s.inertia.y, s.inertia.z};
      double e[3];
      for (int i = 0; i < 3; ++i) e[i] = std::sqrt(std::max(I[(i + 1) % 3] + I[(i + 2) % 3] - I[i], 1e-30));
      const double k = double(r) / std::cbrt(e[0] * e[1] * e[2]);  // the ellipsoid of the body's volume
      half = Vec3{real(k * e[0]), real(k * e[1]), real(k * e[2])};
      break;
    }
    default: break;
  }
  shapeElectro(int32_t(s.shape), half, pe);
  pe.metal_fraction = real(s.metal_fraction);
  switch (mat.kind) {
    case MaterialKind::Metal: pe.eps_r = real(INFINITY), pe.tau = real(mat.relaxation_time), pe.conductor = 1; break;
    case MaterialKind::Composite: {
      const real phi = real(s.metal_fraction), sm = real(mat.conductivity >= 0 ? mat.conductivity : 1e-14);
      pe.eps_r = compositePermittivity(phi, real(mat.eps_r), kPercolationThreshold);
      pe.tau = compositeRelaxationTime(phi, real(mat.eps_r), kCopperConductivity, sm);
      pe.conductor = phi >= kPercolationThreshold ? 1 : 0;
      break;
    }
    default: pe.eps_r = real(mat.eps_r), pe.tau = real(mat.relaxation_time), pe.conductor = 0; break;
  }
  pe.tau = surfaceRelaxationTime(pe.tau, real(mat.surface_conductivity), r, pe.eps_r);
  return pe;
}

double expectedParticleMass(const CesConfig& cfg) {
  const double a = cfg.diameter_min, b = cfg.diameter_max;
  const double d3 = b > a ? (b * b * b * b - a * a * a * a) / (4 * (b - a)) : a * a * a;  // E[d^3], d ~ U[a, b]
  const double volume = kPiD / 6.0 * d3;
  double fsum = 0, per_mass = 0;  // sum f_k, sum f_k / m_k
  for (const MaterialConfig& m : cfg.materials) {
    if (!(m.mass_fraction > 0)) continue;
    const double mean_mass = volume * 0.5 * (m.density_min + m.density_max);
    fsum += m.mass_fraction;
    per_mass += m.mass_fraction / mean_mass;
  }
  if (!(per_mass > 0)) throw InputError("CES feeder: no material with a positive mass fraction");
  return fsum / per_mass;
}

double expectedFootprintArea(const CesConfig& cfg) {
  const double a = cfg.diameter_min, b = cfg.diameter_max;
  const double d2 = b > a ? (b * b * b - a * a * a) / (3 * (b - a)) : a * a;  // E[d^2], d ~ U[a, b]
  const double d3 = b > a ? (b * b * b * b - a * a * a * a) / (4 * (b - a)) : a * a * a;
  // Footprint / d^2 of each shape lying on its largest face (feeder.h).
  const double flake = 4 * std::pow(kPiD / 12, 2.0 / 3.0), wire = 16 * std::pow(1.0 / 48, 2.0 / 3.0);
  const double ellipsoid = 0.7 * kPiD * std::pow(1 / 2.8, 2.0 / 3.0);
  const double coef[kParticleShapes] = {kPiD / 4, flake, wire, ellipsoid, ellipsoid};
  double count = 0, area = 0;
  for (const MaterialConfig& m : cfg.materials) {
    if (!(m.mass_fraction > 0)) continue;
    const double n = m.mass_fraction / (0.5 * (m.density_min + m.density_max) * kPiD / 6 * d3);  // count share
    double wsum = 0, c = 0;
    for (int s = 0; s < kParticleShapes; ++s) wsum += m.shape_weight[s], c += m.shape_weight[s] * coef[s];
    count += n;
    area += n * c / wsum;
  }
  if (!(count > 0)) throw InputError("CES feeder: no material with a positive mass fraction");
  return d2 * area / count;
}

double monolayerMassFlow(const CesConfig& cfg) {
  return std::abs(cfg.omegaDrum()) * cfg.drumRadius() * cfg.feed_width * expectedParticleMass(cfg) /
         expectedFootprintArea(cfg);
}

Feeder::Feeder(const CesConfig& cfg) : cfg_(cfg), fed_fg_(cfg.materials.size(), 0) {
  rng_.s = cfg.seed * 0x9e3779b97f4a7c15ull + 0x632be59bd9b4e019ull;
  double sum = 0;
  for (const MaterialConfig& m : cfg.materials) sum += m.mass_fraction;
  for (const MaterialConfig& m : cfg.materials) fraction_.push_back(m.mass_fraction / sum);
}

Quat Feeder::randomRotation() {
  const double u1 = rng_.uniform(), u2 = rng_.uniform() * 2 * kPiD, u3 = rng_.uniform() * 2 * kPiD;
  const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
  return normalized(
      Quat{real(b * std::cos(u3)), real(a * std::sin(u2)), real(a * std::cos(u2)), real(b * std::sin(u3))});
}

ParticleSpec Feeder::drawNext() {
  // The material furthest below its share of the mass fed so far (ties: the first).
  int best = -1;
  double deficit = 0;
  for (size_t k = 0; k < fraction_.size(); ++k) {
    if (!(fraction_[k] > 0)) continue;
    const double d = fraction_[k] * double(fed_total_fg_) - double(fed_fg_[k]);
    if (best < 0 || d > deficit) best = int(k), deficit = d;
  }
  const MaterialConfig& mat = cfg_.materials[size_t(best)];
  double wsum = 0;
  for (double w : mat.shape_weight) wsum += w;
  double pick = rng_.uniform() * wsum;
  int shape = 0;
  while (shape + 1 < kParticleShapes && (pick >= mat.shape_weight[shape] || mat.shape_weight[shape] == 0))
    pick -= mat.shape_weight[shape++];
  while (shape > 0 && mat.shape_weight[shape] == 0) --shape;  // rounding at the end of the list
  const double d = rng_.uniform(cfg_.diameter_min, cfg_.diameter_max);
  const double rho = rng_.uniform(mat.density_min, mat.density_max);
  return makeParticleSpec(best, ParticleShape(shape), d, rho, rng_);
}

void Feeder::emit(double t, double h, std::vector<ParticleSpec>& out) {
  const double t0 = cfg_.feed_start, t1 = cfg_.feed_start + cfg_.feed_duration;
  if (t + 0.5 * h < t0 || t + 0.5 * h >= t1 || !(cfg_.feed_mass_flow > 0)) return;
  owed_kg_ += cfg_.feed_mass_flow * h;
  while (owed_kg_ >= 0) {
    ParticleSpec s = drawNext();
    owed_kg_ -= double(s.mass_fg) * kFemtogram;
    fed_total_fg_ += s.mass_fg;
    fed_fg_[size_t(s.material)] += s.mass_fg;
    out.push_back(std::move(s));
  }
}

Feeder::State Feeder::state() const { return State{rng_.s, owed_kg_, fed_total_fg_, fed_fg_}; }

void Feeder::setState(const State& s) {
  rng_.s = s.rng;
  owed_kg_ = s.owed_kg;
  fed_total_fg_ = s.fed_total_fg;
  fed_fg_ = s.fed_fg;
}

}  // namespace ces
}  // namespace dvi
