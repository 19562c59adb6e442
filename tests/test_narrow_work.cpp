// The narrow phase's work, counted: support mappings per pair of every MPR shape-pair class, on a fixed set of
// resting and near contacts, under the CPU backend's GJK choice (GjkUse::All) and the GPU's (GjkUse::Polytopes).
// Each class's mean is bounded, so an algorithmic regression (more iterations, GJK where it does not settle a pair,
// a second manifold pass) fails CI without a GPU. The counts are the host's (gjk.h: NarrowWork); the GPU runs the
// same functions on the same pairs, so its work per pair is the same count. docs/GPU_PERFORMANCE.md tables the
// measured means and explains the bounds.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "chrono_like/collision/narrowphase.h"
#include "chrono_like/system.h"

using namespace dvi;

namespace {

// The shapes of the scaling benchmark's mix and of the CES feed, at unit scale, made as the System makes them
// (shape_factory.cpp: dims and the size that scales the envelope): spheres, ellipsoids, boxes (flakes), cylinders
// (wires), capsules, cones, and a 12-point convex fragment with a margin (its points appended to hull).
Shape workShape(ShapeType t, std::vector<Vec3>& hull) {
  switch (t) {
    case ShapeType::Sphere: return makeSphere(0.5).shape;
    case ShapeType::Ellipsoid: return makeEllipsoid(Vec3{0.6, 0.4, 0.3}).shape;
    case ShapeType::Box: return makeBox(Vec3{0.5, 0.3, 0.2}).shape;
    case ShapeType::Cylinder: return makeCylinder(0.4, 0.4).shape;
    case ShapeType::Capsule: return makeCapsule(0.25, 0.35).shape;
    case ShapeType::Cone: return makeCone(0.45, 1.0).shape;
    default: break;
  }
  // A fragment: an irregular 12-point hull (an icosahedron's vertices, stretched), margin 0.02.
  const double g = 1.618033988749895;
  const double v[12][3] = {{-1, g, 0},  {1, g, 0},  {-1, -g, 0}, {1, -g, 0}, {0, -1, g},  {0, 1, g},
                           {0, -1, -g}, {0, 1, -g}, {g, 0, -1},  {g, 0, 1},  {-g, 0, -1}, {-g, 0, 1}};
  std::vector<Vec3> pts;
  for (const auto& p : v) pts.push_back(Vec3{0.28 * p[0], 0.22 * p[1], 0.17 * p[2]});
  ShapeDesc d = makeConvexHull(pts, Pose{Vec3{0, 0, 0}, quatIdentity()}, 0.02);
  d.shape.hull_start = int32_t(hull.size());
  d.shape.hull_count = int32_t(d.hull.size());
  hull.insert(hull.end(), d.hull.begin(), d.hull.end());
  return d.shape;
}

struct ClassWork {
  int pairs = 0, touching = 0;
  NarrowWork work;
};

// n pairs of types (ta, tb) at random orientations and directions, placed by bisection where the pair's contact
// appears with the envelope e, then moved in by 0.2 e to 1.3 e: gaps inside the envelope and shallow overlaps, as
// in a settled pile. The bisection runs uncounted; each placed pair is collided once under `gjk`, counted.
ClassWork countClass(ShapeType ta, ShapeType tb, GjkUse gjk, int n, uint64_t seed) {
  std::vector<Vec3> hull;
  const Shape a = workShape(ta, hull), b0 = workShape(tb, hull);
  Shape b = b0;
  std::mt19937_64 g(seed);
  std::normal_distribution<double> nd(0, 1);
  std::uniform_real_distribution<double> ud(0.2, 1.3);
  auto dir = [&] { return normalized(Vec3{nd(g), nd(g), nd(g)}); };
  auto rot = [&] { return normalized(Quat{nd(g), nd(g), nd(g), nd(g)}); };
  const real e = real(0.05) * std::fmin(a.size, b.size);
  ClassWork w;
  ContactPoint pts[kMaxContactsPerPair];
  for (int k = 0; k < n; ++k) {
    const Pose wa{Vec3{0, 0, 0}, rot()};
    const Quat qb = rot();
    const Vec3 u = dir();
    auto touches = [&](real s) { return collideShapes(a, wa, b, Pose{u * s, qb}, hull.data(), e, pts) > 0; };
    real lo = 0, hi = boundingRadius(a, hull.data()) + boundingRadius(b, hull.data()) + 2 * e;
    for (int it = 0; it < 50; ++it) (touches((lo + hi) / 2) ? lo : hi) = (lo + hi) / 2;
    const Pose wb{u * (lo - e * real(ud(g))), qb};
    NarrowWork pair;
    const int m = collideShapes(a, wa, b, wb, hull.data(), e, pts, nullptr, true, gjk, &pair);
    w.pairs += 1;
    w.touching += m > 0 ? 1 : 0;
    w.work.gjk += pair.gjk;
    w.work.mpr += pair.mpr;
    w.work.manifold += pair.manifold;
  }
  return w;
}

// Bounds on the mean supports per pair, per class and GJK choice: about 1.3x the means measured when this test was
// written (docs/GPU_PERFORMANCE.md, "Work per pair"), so that a change of algorithm, not of rounding, trips them.
struct Bound {
  ShapeType a, b;
  double all, polytopes;  // measured means, GjkUse::All (the CPU's) and GjkUse::Polytopes (MPR alone on curved cores)
};
const Bound kMeasured[] = {
    {ShapeType::Sphere, ShapeType::Ellipsoid, 11.8, 114.4},
    {ShapeType::Sphere, ShapeType::Cone, 2.7, 72.6},
    {ShapeType::Sphere, ShapeType::ConvexHull, 2.9, 2.9},
    {ShapeType::Ellipsoid, ShapeType::Ellipsoid, 57.1, 113.0},
    {ShapeType::Ellipsoid, ShapeType::Box, 60.6, 61.8},
    {ShapeType::Ellipsoid, ShapeType::Cylinder, 67.5, 89.7},
    {ShapeType::Ellipsoid, ShapeType::Capsule, 26.4, 87.2},
    {ShapeType::Ellipsoid, ShapeType::Cone, 67.8, 79.4},
    {ShapeType::Ellipsoid, ShapeType::ConvexHull, 63.8, 70.2},
    {ShapeType::Box, ShapeType::Cylinder, 64.2, 61.0},
    {ShapeType::Box, ShapeType::Capsule, 24.5, 24.5},
    {ShapeType::Box, ShapeType::Cone, 51.5, 55.9},
    {ShapeType::Box, ShapeType::ConvexHull, 26.8, 26.8},
    {ShapeType::Cylinder, ShapeType::Cylinder, 72.0, 75.0},
    {ShapeType::Cylinder, ShapeType::Capsule, 38.8, 79.5},
    {ShapeType::Cylinder, ShapeType::Cone, 74.8, 68.3},
    {ShapeType::Cylinder, ShapeType::ConvexHull, 55.5, 60.7},
    {ShapeType::Capsule, ShapeType::Cone, 39.3, 74.1},
    {ShapeType::Capsule, ShapeType::ConvexHull, 19.6, 19.6},
    {ShapeType::Cone, ShapeType::Cone, 66.7, 69.2},
    {ShapeType::Cone, ShapeType::ConvexHull, 53.1, 63.7},
    {ShapeType::ConvexHull, ShapeType::ConvexHull, 25.9, 25.9},
};
// The budget of a class: 1.3 x its measured mean and 2 supports more (two or three pairs of 100 taking another path).
double budget(double measured) { return 1.3 * measured + 2; }
const Bound* measuredFor(ShapeType a, ShapeType b) {
  for (const Bound& m : kMeasured)
    if (m.a == a && m.b == b) return &m;
  return nullptr;
}

}  // namespace

TEST_CASE("narrow phase work: supports per pair of every MPR class stay within their bounds", "[narrowphase][work]") {
  const ShapeType types[] = {ShapeType::Sphere,  ShapeType::Ellipsoid, ShapeType::Box,       ShapeType::Cylinder,
                             ShapeType::Capsule, ShapeType::Cone,      ShapeType::ConvexHull};
  constexpr int kPairs = 100;
  double total_all = 0, total_poly = 0;
  int classes = 0;
  for (int i = 0; i < 7; ++i)
    for (int j = i; j < 7; ++j) {
      const ShapeType ta = types[i], tb = types[j];
      if (!pairUsesMpr(ta, tb)) continue;
      const uint64_t seed = 1000 + uint64_t(i) * 16 + uint64_t(j);
      const ClassWork all = countClass(ta, tb, GjkUse::All, kPairs, seed);
      const ClassWork poly = countClass(ta, tb, GjkUse::Polytopes, kPairs, seed);
      const double ma = double(all.work.total()) / all.pairs, mp = double(poly.work.total()) / poly.pairs;
      std::printf(
          "work %-11s %-11s touching %3d/%d  All: gjk %6.1f mpr %6.1f manifold %5.1f = %6.1f   "
          "Polytopes: gjk %6.1f mpr %6.1f manifold %5.1f = %6.1f\n",
          shapeTypeName(ta), shapeTypeName(tb), all.touching, all.pairs, double(all.work.gjk) / kPairs,
          double(all.work.mpr) / kPairs, double(all.work.manifold) / kPairs, ma, double(poly.work.gjk) / kPairs,
          double(poly.work.mpr) / kPairs, double(poly.work.manifold) / kPairs, mp);
      INFO(shapeTypeName(ta) << "-" << shapeTypeName(tb));
      // The placement makes contacts: nearly every pair touches (a pair that does not cost nothing to count).
      CHECK(all.touching >= kPairs * 9 / 10);
      CHECK(poly.touching >= kPairs * 9 / 10);
      const Bound* m = measuredFor(ta, tb);
      REQUIRE(m != nullptr);
      CHECK(ma <= budget(m->all));
      CHECK(mp <= budget(m->polytopes));
      total_all += ma;
      total_poly += mp;
      ++classes;
    }
  std::printf("work mean over %d MPR classes: All %.1f, Polytopes %.1f supports a pair\n", classes, total_all / classes,
              total_poly / classes);
  CHECK(classes == 22);
}

// The skip both backends make before any narrow-phase work (narrowphase.h: boxesApart) is conservative: a pair whose
// grown boxes are apart has no point within its envelope. Every class, random poses from overlapping to apart by
// twice the envelope along each axis, with the envelopes the step would use (a sweep of up to two envelopes).
TEST_CASE("narrow phase: a pair whose grown boxes are apart has no contact", "[narrowphase][work]") {
  const ShapeType types[] = {ShapeType::Sphere,  ShapeType::Ellipsoid, ShapeType::Box,       ShapeType::Cylinder,
                             ShapeType::Capsule, ShapeType::Cone,      ShapeType::ConvexHull};
  std::mt19937_64 g(77);
  std::normal_distribution<double> nd(0, 1);
  std::uniform_real_distribution<double> ud(0, 1);
  const real env_rel = real(0.05);
  int skipped = 0, checked = 0;
  for (ShapeType ta : types)
    for (ShapeType tb : types) {
      std::vector<Vec3> hull;
      const Shape a = workShape(ta, hull), b = workShape(tb, hull);
      for (int k = 0; k < 300; ++k) {
        const Pose wa{Vec3{0, 0, 0}, normalized(Quat{nd(g), nd(g), nd(g), nd(g)})};
        const real reach = boundingRadius(a, hull.data()) + boundingRadius(b, hull.data());
        const Pose wb{normalized(Vec3{nd(g), nd(g), nd(g)}) * (reach * real(0.6 + 0.6 * ud(g))),
                      normalized(Quat{nd(g), nd(g), nd(g), nd(g)})};
        const real sa = real(ud(g)) * 2 * env_rel * a.size, sb = real(ud(g)) * 2 * env_rel * b.size;
        const Aabb ba = shapeAabb(a, wa, hull.data(), shapeMargin(a, env_rel, sa));
        const Aabb bb = shapeAabb(b, wb, hull.data(), shapeMargin(b, env_rel, sb));
        if (!boxesApart(ba, bb)) continue;
        ++skipped;
        // the largest envelope pairEnvelope can give these sweeps: the plain one or the two sweeps together
        const real envelope = std::fmax(plainEnvelope(a, b, env_rel), sa + sb);
        ContactPoint pts[kMaxContactsPerPair];
        INFO(shapeTypeName(ta) << "-" << shapeTypeName(tb) << " pair " << k);
        CHECK(collideShapes(a, wa, b, wb, hull.data(), envelope, pts) == 0);
        ++checked;
      }
    }
  INFO("pairs skipped by their boxes " << skipped);
  CHECK(skipped > 1000);
  CHECK(checked == skipped);
}
