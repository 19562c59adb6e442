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

using namespace dvi;

namespace {

Shape makeWorkShape(ShapeType t, Vec3 dims) {
  Shape s;
  std::memset(&s, 0, sizeof(s));
  s.type = t;
  s.local = Pose{Vec3{0, 0, 0}, quatIdentity()};
  s.dims = dims;
  s.group = 1;
  s.mask = -1;
  s.size = minComponent(dims);
  return s;
}

// The shapes of the scaling benchmark's mix and of the CES feed, at unit scale: spheres, ellipsoids, boxes
// (flakes), cylinders (wires), capsules, cones, and a 12-point convex fragment with a margin.
Shape workShape(ShapeType t, std::vector<Vec3>& hull) {
  switch (t) {
    case ShapeType::Sphere: return makeWorkShape(t, Vec3{0.5, 0.5, 0.5});
    case ShapeType::Ellipsoid: return makeWorkShape(t, Vec3{0.6, 0.4, 0.3});
    case ShapeType::Box: return makeWorkShape(t, Vec3{0.5, 0.3, 0.2});
    case ShapeType::Cylinder: return makeWorkShape(t, Vec3{0.4, 0.4, 0});
    case ShapeType::Capsule: return makeWorkShape(t, Vec3{0.25, 0.35, 0});
    case ShapeType::Cone: return makeWorkShape(t, Vec3{0.45, 1.0, 0});
    default: break;
  }
  // A fragment: an irregular 12-point hull (an icosahedron's vertices, stretched), margin 0.02.
  Shape s = makeWorkShape(ShapeType::ConvexHull, Vec3{0.5, 0.4, 0.3});
  s.hull_start = int32_t(hull.size());
  const double g = 1.618033988749895;
  const double v[12][3] = {{-1, g, 0}, {1, g, 0},  {-1, -g, 0}, {1, -g, 0}, {0, -1, g}, {0, 1, g},
                           {0, -1, -g}, {0, 1, -g}, {g, 0, -1},  {g, 0, 1},  {-g, 0, -1}, {-g, 0, 1}};
  for (const auto& p : v) hull.push_back(Vec3{0.28 * p[0], 0.22 * p[1], 0.17 * p[2]});
  s.hull_count = 12;
  s.margin = 0.02f;
  s.size = 0.3;
  return s;
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
  double all, polytopes;  // GjkUse::All (CPU) and GjkUse::Polytopes (GPU)
};

}  // namespace

TEST_CASE("narrow phase work: supports per pair of every MPR class stay within their bounds", "[narrowphase][work]") {
  const ShapeType types[] = {ShapeType::Sphere,   ShapeType::Ellipsoid, ShapeType::Box,       ShapeType::Cylinder,
                             ShapeType::Capsule,  ShapeType::Cone,      ShapeType::ConvexHull};
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
      std::printf("work %-11s %-11s touching %3d/%d  All: gjk %6.1f mpr %6.1f manifold %5.1f = %6.1f   "
                  "Polytopes: gjk %6.1f mpr %6.1f manifold %5.1f = %6.1f\n",
                  shapeTypeName(ta), shapeTypeName(tb), all.touching, all.pairs, double(all.work.gjk) / kPairs,
                  double(all.work.mpr) / kPairs, double(all.work.manifold) / kPairs, ma,
                  double(poly.work.gjk) / kPairs, double(poly.work.mpr) / kPairs,
                  double(poly.work.manifold) / kPairs, mp);
      INFO(shapeTypeName(ta) << "-" << shapeTypeName(tb));
      // The placement makes contacts: nearly every pair touches (a pair that does not cost nothing to count).
      CHECK(all.touching >= kPairs * 9 / 10);
      CHECK(poly.touching >= kPairs * 9 / 10);
      total_all += ma;
      total_poly += mp;
      ++classes;
    }
  std::printf("work mean over %d MPR classes: All %.1f, Polytopes %.1f supports a pair\n", classes,
              total_all / classes, total_poly / classes);
  CHECK(classes == 22);
}
