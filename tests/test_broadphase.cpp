// Binned broad phase (BroadPhaseBins) against the O(n^2) oracle (broadPhaseBruteForce), which is itself
// checked on a hand-made case.
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include <catch2/catch.hpp>

#include "chrono_like/collision/broadphase.h"

using namespace dvi;

namespace {

struct Scene {
  ShapeArrays shapes;
  BodyArrays bodies;

  int addBody(uint8_t flags) {
    bodies.flags.push_back(flags);
    return int(bodies.flags.size()) - 1;
  }
  // Appends a shape with the given world AABB (shapes are kept sorted by body by the callers).
  int addShape(int body, ShapeType type, Aabb box, int16_t group = 1, int16_t mask = -1) {
    Shape s{};
    s.type = type;
    s.body = body;
    s.local = Pose{{0, 0, 0}, quatIdentity()};
    s.dims = {1, 1, 1};
    s.size = 1;
    s.group = group;
    s.mask = mask;
    shapes.shape.push_back(s);
    shapes.aabb.push_back(box);
    return int(shapes.shape.size()) - 1;
  }
};

Aabb cube(Vec3 c, real h) { return Aabb{{c.x - h, c.y - h, c.z - h}, {c.x + h, c.y + h, c.z + h}}; }

const real kInf = real(1e30);

// Multidisperse random scene: radii over a factor 10, several shapes per body, some fixed and kinematic
// bodies, collision groups and masks, a few huge boxes (ground, walls) and planes.
Scene randomScene(uint32_t seed, int nbodies, real box_side) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> U(0, 1);
  Scene sc;
  const int16_t groups[] = {1, 2, 4};
  const int16_t masks[] = {-1, -1, -1, 1 | 2, 4, 2 | 4};
  // large shapes first on their own fixed bodies, then particles, then a plane on a kinematic body
  int ground = sc.addBody(kBodyFixed);
  sc.addShape(ground, ShapeType::Box, Aabb{{-1, -1, -1}, {box_side + 1, box_side + 1, real(0.3)}});
  sc.addShape(ground, ShapeType::Plane, Aabb{{-kInf, -kInf, -kInf}, {kInf, kInf, kInf}});
  int wall = sc.addBody(kBodyFixed);
  sc.addShape(wall, ShapeType::Box, Aabb{{-1, -1, -1}, {real(0.2), box_side + 1, box_side + 1}});
  sc.addShape(wall, ShapeType::Box, Aabb{{box_side - real(0.2), -1, -1}, {box_side + 1, box_side + 1, box_side + 1}});
  for (int b = 0; b < nbodies; ++b) {
    const double u = U(rng);
    const uint8_t flags = u < 0.08 ? kBodyFixed : (u < 0.12 ? kBodyKinematic : 0);
    const int body = sc.addBody(flags);
    const int nsh = 1 + int(U(rng) * 3);
    const Vec3 c{real(U(rng) * box_side), real(U(rng) * box_side), real(U(rng) * box_side)};
    for (int k = 0; k < nsh; ++k) {
      const real r = real(0.05 * std::pow(10.0, U(rng)));  // 0.05 .. 0.5
      const Vec3 o{real((U(rng) - 0.5) * 0.3), real((U(rng) - 0.5) * 0.3), real((U(rng) - 0.5) * 0.3)};
      const Vec3 p = c + o;
      const Vec3 h{r * real(0.5 + 0.5 * U(rng)), r * real(0.5 + 0.5 * U(rng)), r};
      const int16_t g = groups[int(U(rng) * 3) % 3];
      const int16_t m = masks[int(U(rng) * 6) % 6];
      sc.addShape(body, U(rng) < 0.5 ? ShapeType::Sphere : ShapeType::Box, Aabb{p - h, p + h}, g, m);
    }
  }
  int plane_body = sc.addBody(kBodyKinematic);
  // half-space x + ... : bounded on one side only
  sc.addShape(plane_body, ShapeType::Plane, Aabb{{-kInf, -kInf, -kInf}, {kInf, kInf, box_side * real(0.5)}});
  return sc;
}

bool strictlySortedUnique(const std::vector<ShapePair>& p) {
  for (size_t i = 0; i < p.size(); ++i) {
    if (!(p[i].a < p[i].b)) return false;
    if (i > 0 && !(p[i - 1].a < p[i].a || (p[i - 1].a == p[i].a && p[i - 1].b < p[i].b))) return false;
  }
  return true;
}

bool samePairs(const std::vector<ShapePair>& x, const std::vector<ShapePair>& y) {
  if (x.size() != y.size()) return false;
  for (size_t i = 0; i < x.size(); ++i)
    if (x[i].a != y[i].a || x[i].b != y[i].b) return false;
  return true;
}

// Runs the binned broad phase with 1, 2 and 3 threads and checks it against the oracle.
void checkAgainstOracle(const Scene& sc, BroadPhaseSettings set = {}, BroadPhaseStats* stats_out = nullptr) {
  std::vector<ShapePair> ref;
  broadPhaseBruteForce(sc.shapes, sc.bodies, ref);
  const int saved = omp_get_max_threads();
  std::vector<ShapePair> first;
  for (int threads : {1, 2, 3}) {
    omp_set_num_threads(threads);
    BroadPhaseBins bp(set);
    std::vector<ShapePair> got;
    BroadPhaseStats st;
    bp.run(sc.shapes, sc.bodies, got, &st);
    INFO("threads " << threads << ", shapes " << sc.shapes.count() << ", pairs " << got.size() << " vs " << ref.size()
                    << ", bins " << st.bins << ", large " << st.large_shapes);
    CHECK(strictlySortedUnique(got));
    CHECK(samePairs(got, ref));
    CHECK(st.pairs == int64_t(got.size()));
    if (threads == 1) {
      first = got;
      if (stats_out) *stats_out = st;
    } else {
      CHECK(samePairs(got, first));
    }
  }
  omp_set_num_threads(saved);
}

}  // namespace

TEST_CASE("broad phase brute force on a hand-made 4-shape case", "[broadphase]") {
  Scene sc;
  const int b0 = sc.addBody(0), b1 = sc.addBody(0), b2 = sc.addBody(kBodyFixed);
  sc.addShape(b0, ShapeType::Box, Aabb{{0, 0, 0}, {1, 1, 1}});                  // 0
  sc.addShape(b0, ShapeType::Box, Aabb{{0.5, 0.5, 0.5}, {1.5, 1.5, 1.5}});      // 1: same body as 0
  sc.addShape(b1, ShapeType::Sphere, Aabb{{0.9, 0.9, 0.9}, {2, 2, 2}}, 1, -1);  // 2
  sc.addShape(b2, ShapeType::Box, Aabb{{1.9, 0, 0}, {3, 1, 1}}, 2, 2);          // 3: filtered by 2's group
  std::vector<ShapePair> p;
  broadPhaseBruteForce(sc.shapes, sc.bodies, p);
  REQUIRE(p.size() == 2);
  CHECK((p[0].a == 0 && p[0].b == 2));
  CHECK((p[1].a == 1 && p[1].b == 2));

  sc.shapes.shape[2].group = 3;  // now 2 and 3 pass the filter both ways
  broadPhaseBruteForce(sc.shapes, sc.bodies, p);
  REQUIRE(p.size() == 3);
  CHECK((p[2].a == 2 && p[2].b == 3));

  sc.bodies.flags[size_t(b1)] = kBodyKinematic;  // kinematic vs fixed: never a pair
  broadPhaseBruteForce(sc.shapes, sc.bodies, p);
  CHECK(p.size() == 2);

  sc.bodies.flags[size_t(b1)] = 0;
  sc.shapes.aabb[3].lo.x = 2;  // exactly touching 2's box: closed intervals still overlap
  broadPhaseBruteForce(sc.shapes, sc.bodies, p);
  CHECK(p.size() == 3);
  sc.shapes.aabb[3].lo.x = real(2.0001);
  broadPhaseBruteForce(sc.shapes, sc.bodies, p);
  CHECK(p.size() == 2);
  checkAgainstOracle(sc);
}

TEST_CASE("broad phase bins equal brute force on random multidisperse scenes", "[broadphase]") {
  for (uint32_t seed : {1u, 2u, 3u, 4u}) {
    Scene sc = randomScene(seed, 600 + 300 * int(seed), real(6));
    BroadPhaseStats st;
    checkAgainstOracle(sc, {}, &st);
    CHECK(st.large_shapes == 5);  // ground box, plane, two walls, half-space
    CHECK(st.bin_entries >= int64_t(sc.shapes.count()) - 5);
    CHECK(st.bins > 1);
    CHECK(st.pairs > 0);
  }
  // coarse and fine bins, a tight bin cap, every bounded shape binned, and large shapes capped
  Scene sc = randomScene(7, 800, real(5));
  BroadPhaseSettings s;
  s.bin_size_factor = real(0.5);
  checkAgainstOracle(sc, s);
  s.bin_size_factor = real(6);
  checkAgainstOracle(sc, s);
  s = {};
  s.max_bins = 64;
  BroadPhaseStats st;
  checkAgainstOracle(sc, s, &st);
  CHECK(st.bins <= 64);
  s = {};
  s.large_factor = real(1e6);
  checkAgainstOracle(sc, s, &st);
  CHECK(st.large_shapes == 2);  // only the planes
  s = {};
  s.max_large = 1;
  checkAgainstOracle(sc, s, &st);
  CHECK(st.large_shapes <= 3);  // the two planes and at most one bounded shape
}

// A static mesh (thousands of small shapes on fixed bodies, like a terrain's triangles) under movable shapes: an
// immovable shape walks only the movable shapes of its bins (the next-movable chain), since two immovable shapes
// never pair. Enough entries that the chain's blocks (16384 entries) are crossed inside bins; against the oracle,
// and with no movable shape at all no in-bin test is made.
TEST_CASE("broad phase on a static mesh tests the movable shapes only", "[broadphase]") {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> U(0, 1);
  Scene sc;
  const int mesh_a = sc.addBody(kBodyFixed), mesh_b = sc.addBody(kBodyFixed);
  const int n = 110;  // 2 x 110 x 110 cells of 0.1: 24,200 static shapes
  for (int body : {mesh_a, mesh_b})
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k) {
        const real x = real(0.1) * real(i), z = real(0.1) * real(k), y = real(0.05 * std::sin(0.3 * i) + 0.2 * body);
        sc.addShape(body, ShapeType::Triangle, Aabb{{x, y, z}, {x + real(0.11), y + real(0.06), z + real(0.11)}});
      }
  Scene statics = sc;
  BroadPhaseBins bp;
  std::vector<ShapePair> got;
  BroadPhaseStats st;
  bp.run(statics.shapes, statics.bodies, got, &st);
  CHECK(got.empty());
  CHECK(st.bin_entries > 3 * 16384);
  CHECK(st.bin_pair_tests == 0);
  for (int b = 0; b < 400; ++b) {
    const int body = sc.addBody(U(rng) < 0.1 ? kBodyKinematic : 0);
    const Vec3 c{real(U(rng) * 11), real(U(rng) * 0.5), real(U(rng) * 11)};
    const real h = real(0.03 + 0.1 * U(rng));
    sc.addShape(body, ShapeType::Box, Aabb{c - Vec3{h, h, h}, c + Vec3{h, h, h}});
  }
  checkAgainstOracle(sc, {}, &st);
  CHECK(st.pairs > 1000);
  CHECK(st.bin_pair_tests < 40 * st.pairs);
}

TEST_CASE("broad phase reuses its scratch across scenes", "[broadphase]") {
  BroadPhaseBins bp;
  std::vector<ShapePair> got, ref;
  for (uint32_t seed : {11u, 12u, 13u}) {
    Scene sc = randomScene(seed, 200 * int(seed - 9), real(3 + seed - 11));
    bp.run(sc.shapes, sc.bodies, got);
    broadPhaseBruteForce(sc.shapes, sc.bodies, ref);
    CHECK(samePairs(got, ref));
  }
}

TEST_CASE("broad phase edge cases", "[broadphase]") {
  SECTION("no shapes") {
    Scene sc;
    BroadPhaseBins bp;
    std::vector<ShapePair> got{{1, 2}};
    BroadPhaseStats st;
    bp.run(sc.shapes, sc.bodies, got, &st);
    CHECK(got.empty());
    CHECK(st.pairs == 0);
    CHECK(st.bin_entries == 0);
  }
  SECTION("one shape") {
    Scene sc;
    sc.addShape(sc.addBody(0), ShapeType::Sphere, cube({1, 2, 3}, 1));
    BroadPhaseStats st;
    checkAgainstOracle(sc, {}, &st);
    CHECK(st.pairs == 0);
    Scene sp;  // one plane
    sp.addShape(sp.addBody(kBodyFixed), ShapeType::Plane, Aabb{{-kInf, -kInf, -kInf}, {kInf, kInf, kInf}});
    checkAgainstOracle(sp, {}, &st);
    CHECK(st.large_shapes == 1);
  }
  SECTION("all shapes in one bin") {
    Scene sc;
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> U(-0.1, 0.1);
    for (int i = 0; i < 40; ++i)
      sc.addShape(sc.addBody(0), ShapeType::Sphere, cube({real(U(rng)), real(U(rng)), real(U(rng))}, 1));
    BroadPhaseStats st;
    checkAgainstOracle(sc, {}, &st);
    CHECK(st.bins == 1);
    CHECK(st.pairs == 40 * 39 / 2);
  }
  SECTION("shapes exactly touching bin boundaries") {
    // unit cubes on an integer lattice: faces touch exactly, and with edge 1 or 2 every (or every other)
    // face lies on a bin boundary
    Scene sc;
    for (int k = 0; k < 5; ++k)
      for (int j = 0; j < 5; ++j)
        for (int i = 0; i < 5; ++i) {
          const Vec3 lo{real(i), real(j), real(k)};
          sc.addShape(sc.addBody(0), ShapeType::Box, Aabb{lo, lo + Vec3{1, 1, 1}});
        }
    for (real f : {real(1), real(2), real(0.5)}) {
      BroadPhaseSettings s;
      s.bin_size_factor = f;
      BroadPhaseStats st;
      checkAgainstOracle(sc, s, &st);
      CHECK(st.bin_edge == Approx(f));
      // every lattice neighbour (26-neighbourhood) touches: 3D count of adjacent cell pairs
      const int64_t n = 5, expected = 3 * (n - 1) * n * n + 6 * (n - 1) * (n - 1) * n + 4 * (n - 1) * (n - 1) * (n - 1);
      CHECK(st.pairs == expected);
    }
  }
  SECTION("all large") {
    Scene sc;
    for (int i = 0; i < 6; ++i) {
      const int b = sc.addBody(i % 2 ? 0 : kBodyFixed);
      sc.addShape(b, ShapeType::Plane, Aabb{{-kInf, -kInf, -kInf}, {kInf, kInf, real(i)}});
    }
    const int b = sc.addBody(0);  // non-finite box (an exploded body): never a pair
    sc.addShape(b, ShapeType::Box, Aabb{{NAN, 0, 0}, {1, 1, 1}});
    BroadPhaseStats st;
    checkAgainstOracle(sc, {}, &st);
    CHECK(st.large_shapes == 7);
    CHECK(st.bin_entries == 0);
    CHECK(st.pairs == 6 * 5 / 2 - 3);  // fixed-fixed pairs dropped
  }
  SECTION("degenerate point boxes") {
    Scene sc;
    for (int i = 0; i < 30; ++i) {
      const Vec3 p{real(i % 3), real((i / 3) % 3), real(i / 9)};
      sc.addShape(sc.addBody(0), ShapeType::Sphere, Aabb{p, p});
    }
    sc.addShape(sc.addBody(0), ShapeType::Sphere, Aabb{{0, 0, 0}, {0, 0, 0}});  // coincides with shape 0
    checkAgainstOracle(sc);
  }
}

TEST_CASE("broad phase timing: 100k spheres of radius 1 cm in a dense pile", "[broadphase]") {
  // jittered lattice of touching 1 cm spheres (AABBs enlarged by a 0.5 mm envelope) on a ground box
  Scene sc;
  const int side = 47;  // 47^3 = 103,823
  const real r = real(0.01), env = real(0.0005), pitch = real(0.0202);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> J(-0.0001, 0.0001);
  const int ground = sc.addBody(kBodyFixed);
  sc.addShape(ground, ShapeType::Box, Aabb{{-1, -1, -1}, {2, 2, real(0.0005)}});
  sc.addShape(ground, ShapeType::Plane, Aabb{{-kInf, -kInf, -kInf}, {kInf, kInf, kInf}});
  for (int k = 0; k < side; ++k)
    for (int j = 0; j < side; ++j)
      for (int i = 0; i < side; ++i) {
        const Vec3 c{pitch * real(i) + real(J(rng)), pitch * real(j) + real(J(rng)),
                     r + pitch * real(k) + real(J(rng))};
        sc.addShape(sc.addBody(0), ShapeType::Sphere, cube(c, r + env));
      }
  BroadPhaseBins bp;
  std::vector<ShapePair> pairs;
  BroadPhaseStats st;
  bp.run(sc.shapes, sc.bodies, pairs, &st);  // warm up the scratch
  const int reps = 10;
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < reps; ++i) bp.run(sc.shapes, sc.bodies, pairs, &st);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / reps;
  std::printf(
      "[broadphase] %zu shapes, %d threads: %.2f ms per call; %lld pairs, %lld bins (%d x %d x %d, edge %.4g), "
      "%lld occupied, %lld entries, %lld in-bin tests, %d large\n",
      sc.shapes.count(), omp_get_max_threads(), ms, (long long)st.pairs, (long long)st.bins, st.grid[0], st.grid[1],
      st.grid[2], double(st.bin_edge), (long long)st.occupied_bins, (long long)st.bin_entries,
      (long long)st.bin_pair_tests, st.large_shapes);
  CHECK(strictlySortedUnique(pairs));
  CHECK(st.large_shapes == 2);
  // independent count: every sphere touches the ground box (bottom layer: overlap; others: the plane
  // pairs with all, fixed ground body vs free spheres), lattice neighbours in the 26-neighbourhood overlap
  // (pitch 2.02 cm < AABB side 2.1 cm, jitter 0.01 cm)
  const int64_t n = side;
  const int64_t lattice = 3 * (n - 1) * n * n + 6 * (n - 1) * (n - 1) * n + 4 * (n - 1) * (n - 1) * (n - 1);
  CHECK(st.pairs == lattice + n * n * n /* plane */ + n * n /* ground box vs bottom layer */);
}
