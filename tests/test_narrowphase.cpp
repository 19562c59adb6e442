// Narrow phase: closed-form cases, MPR and box-box against Bullet's GJK/EPA, AABBs against support points.
#include <catch2/catch.hpp>

#include <btBulletCollisionCommon.h>
#include <BulletCollision/NarrowPhaseCollision/btGjkEpaPenetrationDepthSolver.h>
#include <BulletCollision/NarrowPhaseCollision/btGjkPairDetector.h>
#include <BulletCollision/NarrowPhaseCollision/btPointCollector.h>
#include <BulletCollision/NarrowPhaseCollision/btVoronoiSimplexSolver.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "chrono_like/bullet/triangle_mesh.h"
#include "chrono_like/collision/narrowphase.h"

using namespace dvi;

namespace {

constexpr double kPi = 3.14159265358979323846;

Shape makeShape(ShapeType t, Vec3 dims, real plane_d = 0) {
  Shape s;
  std::memset(&s, 0, sizeof(s));
  s.type = t;
  s.local = Pose{Vec3{0, 0, 0}, quatIdentity()};
  s.dims = dims;
  s.plane_d = plane_d;
  s.group = 1;
  s.mask = -1;
  s.size = minComponent(dims);
  return s;
}
Shape sphere(real r) { return makeShape(ShapeType::Sphere, Vec3{r, r, r}); }
Shape box(real x, real y, real z) { return makeShape(ShapeType::Box, Vec3{x, y, z}); }
Shape cylinder(real r, real hh) { return makeShape(ShapeType::Cylinder, Vec3{r, hh, 0}); }
Shape capsule(real r, real hh) { return makeShape(ShapeType::Capsule, Vec3{r, hh, 0}); }
Shape cone(real r, real h) { return makeShape(ShapeType::Cone, Vec3{r, h, 0}); }
Shape ellipsoid(real a, real b, real c) { return makeShape(ShapeType::Ellipsoid, Vec3{a, b, c}); }
Shape plane(Vec3 n, real d) { return makeShape(ShapeType::Plane, n, d); }
Shape hull(int start, int count) {
  Shape s = makeShape(ShapeType::ConvexHull, Vec3{1, 1, 1});
  s.hull_start = start;
  s.hull_count = count;
  return s;
}

struct Rng {
  std::mt19937_64 g;
  explicit Rng(uint64_t seed) : g(seed) {}
  double uni(double a, double b) { return std::uniform_real_distribution<double>(a, b)(g); }
  Vec3 dir() {
    std::normal_distribution<double> n(0, 1);
    return normalized(Vec3{n(g), n(g), n(g)});
  }
  Quat rot() {
    std::normal_distribution<double> n(0, 1);
    return normalized(Quat{n(g), n(g), n(g), n(g)});
  }
};

Pose pose(Vec3 p, Quat q = quatIdentity()) { return Pose{p, q}; }
double angleDeg(Vec3 a, Vec3 b) { return std::atan2(length(cross(a, b)), dot(a, b)) * 180.0 / kPi; }
int deepest(const ContactPoint* c, int n) {
  int k = 0;
  for (int i = 1; i < n; ++i)
    if (c[i].dist < c[k].dist) k = i;
  return k;
}
// Every reported point must be self-consistent: unit normal, dist = dot(pb - pa, n), dist < envelope.
void checkConsistent(const ContactPoint* c, int n, double envelope) {
  for (int i = 0; i < n; ++i) {
    REQUIRE(std::fabs(length(c[i].normal) - 1) < 1e-9);
    REQUIRE(std::fabs(dot(c[i].pb - c[i].pa, c[i].normal) - c[i].dist) < 1e-9);
    REQUIRE(c[i].dist < envelope);
    REQUIRE(c[i].feature >= 0);
    REQUIRE(c[i].feature < kMaxFeature);
    if (i > 0) REQUIRE(c[i].feature > c[i - 1].feature);  // distinct, in order: the warm start's keys are sorted
  }
}

// The contacts of a pair whose exact distance is `expect`: none when that is beyond the envelope, else one, consistent
// (checkConsistent), at `expect` within margin. True when there is one, for the caller's checks of its normal.
bool oneContactAt(const ContactPoint* c, int n, double expect, double envelope, double margin) {
  if (expect >= envelope) {
    REQUIRE(n == 0);
    return false;
  }
  REQUIRE(n == 1);
  checkConsistent(c, n, envelope);
  CHECK(c[0].dist == Approx(expect).margin(margin));
  return true;
}

// The s in [0, 1] that minimises the convex function f: golden-section search, then either end where lower.
template <class F>
double argminOnUnitInterval(F f) {
  double lo = 0, hi = 1;
  for (int i = 0; i < 100; ++i) {
    double m1 = lo + (hi - lo) * 0.381966, m2 = hi - (hi - lo) * 0.381966;
    if (f(m1) < f(m2))
      hi = m2;
    else
      lo = m1;
  }
  double s = 0.5 * (lo + hi);
  if (f(0) < f(s)) s = 0;
  if (f(1) < f(s)) s = 1;
  return s;
}

// Closest distance of point p to segment [a, b], by golden-section search on the convex function
// |p - (a + s (b - a))| (independent of the closed forms used by the code under test).
double pointSegmentDistance(Vec3 p, Vec3 a, Vec3 b, double* s_out = nullptr) {
  auto f = [&](double s) { return length(p - (a + (b - a) * s)); };
  const double s = argminOnUnitInterval(f);
  if (s_out) *s_out = s;
  return f(s);
}
double segmentSegmentDistance(Vec3 a0, Vec3 a1, Vec3 b0, Vec3 b1) {
  auto f = [&](double s) { return pointSegmentDistance(a0 + (a1 - a0) * s, b0, b1); };
  return f(argminOnUnitInterval(f));
}

}  // namespace

TEST_CASE("shapeTypeName gives the lowercase names", "[narrowphase]") {
  CHECK(std::string(shapeTypeName(ShapeType::Sphere)) == "sphere");
  CHECK(std::string(shapeTypeName(ShapeType::Ellipsoid)) == "ellipsoid");
  CHECK(std::string(shapeTypeName(ShapeType::Box)) == "box");
  CHECK(std::string(shapeTypeName(ShapeType::Cylinder)) == "cylinder");
  CHECK(std::string(shapeTypeName(ShapeType::Capsule)) == "capsule");
  CHECK(std::string(shapeTypeName(ShapeType::Cone)) == "cone");
  CHECK(std::string(shapeTypeName(ShapeType::ConvexHull)) == "convex_hull");
  CHECK(std::string(shapeTypeName(ShapeType::Plane)) == "plane");
}

TEST_CASE("sphere-sphere matches the closed form in both orders", "[narrowphase]") {
  Rng rng(1);
  ContactPoint c[kMaxContactsPerPair];
  for (int it = 0; it < 2000; ++it) {
    double ra = rng.uni(0.01, 2), rb = rng.uni(0.01, 2), env = 0.1 * std::min(ra, rb);
    Vec3 pa = Vec3{rng.uni(-3, 3), rng.uni(-3, 3), rng.uni(-3, 3)};
    Vec3 u = rng.dir();
    double gap = rng.uni(-0.5, 0.2) * std::min(ra, rb);
    Vec3 pb = pa + u * (ra + rb + gap);
    Shape A = sphere(ra), B = sphere(rb);
    int n = collideShapes(A, pose(pa, rng.rot()), B, pose(pb, rng.rot()), nullptr, env, c);
    if (!oneContactAt(c, n, gap, env, 1e-12)) continue;
    CHECK(angleDeg(c[0].normal, u) < 1e-6);
    CHECK(length(c[0].pa - (pa + u * ra)) < 1e-12);
    CHECK(length(c[0].pb - (pb - u * rb)) < 1e-12);
    n = collideShapes(B, pose(pb), A, pose(pa), nullptr, env, c);
    REQUIRE(n == 1);
    CHECK(angleDeg(c[0].normal, -u) < 1e-6);
    CHECK(length(c[0].pa - (pb - u * rb)) < 1e-12);
  }
}

TEST_CASE("sphere-plane and ellipsoid-plane match the closed form", "[narrowphase]") {
  Rng rng(2);
  ContactPoint c[kMaxContactsPerPair];
  for (int it = 0; it < 500; ++it) {
    // Plane y <= 0.3 in its frame, placed by a random pose.
    Pose wp = pose(Vec3{rng.uni(-1, 1), rng.uni(-1, 1), rng.uni(-1, 1)}, rng.rot());
    Shape P = plane(Vec3{0, 1, 0}, 0.3);
    Vec3 n = rotate(wp.q, Vec3{0, 1, 0});
    Vec3 onPlane = transformPoint(wp, Vec3{rng.uni(-2, 2), 0.3, rng.uni(-2, 2)});
    double r = rng.uni(0.1, 1), gap = rng.uni(-0.3, 0.1) * r, env = 0.05 * r;
    Vec3 centre = onPlane + n * (r + gap);
    Shape S = sphere(r);
    int m = collideShapes(P, wp, S, pose(centre), nullptr, env, c);
    if (gap >= env) {
      CHECK(m == 0);
    } else {
      REQUIRE(m == 1);
      checkConsistent(c, m, env);
      CHECK(c[0].dist == Approx(gap).margin(1e-12));
      CHECK(angleDeg(c[0].normal, n) < 1e-6);
      CHECK(length(c[0].pb - (centre - n * r)) < 1e-12);
    }
    m = collideShapes(S, pose(centre), P, wp, nullptr, env, c);
    CHECK(m == (gap < env ? 1 : 0));
    if (m) CHECK(angleDeg(c[0].normal, -n) < 1e-6);

    // Ellipsoid x = R S u, |u| = 1: its lowest point along n is min_u (S R^T n).u = -|S R^T n| (Cauchy-Schwarz).
    Shape E = ellipsoid(rng.uni(0.2, 1), rng.uni(0.2, 1), rng.uni(0.2, 1));
    Quat qe = rng.rot();
    double best = -length(mul(E.dims, rotateInv(qe, n)));
    double eg = rng.uni(-0.2, 0.05) * E.dims.x;
    Vec3 ec = onPlane + n * (eg - best);  // lowest point at height eg above the plane
    m = collideShapes(E, pose(ec, qe), P, wp, nullptr, 0.1, c);
    REQUIRE(m == 1);
    checkConsistent(c, m, 0.1);
    CHECK(c[0].dist == Approx(eg).margin(1e-9));
    CHECK(angleDeg(c[0].normal, -n) < 1e-6);
  }
}

TEST_CASE("sphere-box: face, edge, corner and inside regions", "[narrowphase]") {
  Rng rng(3);
  ContactPoint c[kMaxContactsPerPair];
  for (int it = 0; it < 1000; ++it) {
    Vec3 e{rng.uni(0.2, 1), rng.uni(0.2, 1), rng.uni(0.2, 1)};
    double r = rng.uni(0.05, 0.5), env = 0.1 * r;
    // Local point: choose how many coordinates lie outside the box (0: inside, 1: face, 2: edge, 3: corner).
    int region = it % 4;
    double o[3], expect = 0;
    Vec3 nlocal{0, 0, 0};
    double sx = rng.uni(0, 1) < 0.5 ? -1 : 1, sy = rng.uni(0, 1) < 0.5 ? -1 : 1, sz = rng.uni(0, 1) < 0.5 ? -1 : 1;
    double ee[3] = {e.x, e.y, e.z}, ss[3] = {sx, sy, sz};
    if (region == 0) {  // inside, closest to face x: depth g
      double g = rng.uni(0.0, 0.9) * std::min({e.x, e.y, e.z});
      o[0] = ss[0] * (e.x - g);
      o[1] = rng.uni(-1, 1) * (e.y - g - 1e-3) * 0.99;
      o[2] = rng.uni(-1, 1) * (e.z - g - 1e-3) * 0.99;
      if (std::fabs(o[1]) > e.y - g || std::fabs(o[2]) > e.z - g) continue;
      expect = -g - r;
      nlocal = Vec3{ss[0], 0, 0};
    } else {
      double d2 = 0;
      double out[3] = {0, 0, 0};
      for (int k = 0; k < 3; ++k) {
        if (k < region) {
          out[k] = rng.uni(0, 1.1) * r / std::sqrt(double(region));
          o[k] = ss[k] * (ee[k] + out[k]);
          d2 += out[k] * out[k];
        } else {
          o[k] = rng.uni(-0.99, 0.99) * ee[k];
        }
      }
      double d = std::sqrt(d2);
      if (d < 1e-6) continue;
      expect = d - r;
      nlocal = Vec3{ss[0] * out[0], ss[1] * out[1], ss[2] * out[2]} / d;
    }
    Pose wb = pose(Vec3{rng.uni(-1, 1), rng.uni(-1, 1), rng.uni(-1, 1)}, rng.rot());
    Vec3 centre = transformPoint(wb, Vec3{o[0], o[1], o[2]});
    Vec3 nw = rotate(wb.q, nlocal);  // from box toward the sphere centre
    Shape S = sphere(r), B = box(e.x, e.y, e.z);
    int m = collideShapes(S, pose(centre), B, wb, nullptr, env, c);
    if (!oneContactAt(c, m, expect, env, 1e-9)) continue;
    CHECK(angleDeg(c[0].normal, -nw) < 1e-5);
    m = collideShapes(B, wb, S, pose(centre), nullptr, env, c);
    REQUIRE(m == 1);
    CHECK(c[0].dist == Approx(expect).margin(1e-9));
    CHECK(angleDeg(c[0].normal, nw) < 1e-5);
  }
}

TEST_CASE("sphere-cylinder: side, cap, rim and inside regions", "[narrowphase]") {
  Rng rng(4);
  ContactPoint c[kMaxContactsPerPair];
  for (int it = 0; it < 1000; ++it) {
    double R = rng.uni(0.2, 1), H = rng.uni(0.2, 1), r = rng.uni(0.05, 0.5), env = 0.1 * r;
    double phi = rng.uni(0, 2 * kPi);
    Vec3 u{std::cos(phi), 0, std::sin(phi)};
    int region = it % 4;
    Vec3 lp, nl;
    double expect;
    if (region == 0) {  // side
      double g = rng.uni(-0.5, 1.1) * r;
      if (g < 0) g = std::max(g, -0.5 * std::min(R, H));
      double y = rng.uni(-0.95, 0.95) * H;
      if (g < 0 && H - std::fabs(y) < -g) continue;
      lp = u * (R + g) + Vec3{0, y, 0};
      nl = u;
      expect = g - r;
    } else if (region == 1) {  // cap
      double g = rng.uni(0, 1.1) * r, s = rng.uni(0, 0.95) * R;
      lp = u * s + Vec3{0, H + g, 0};
      nl = Vec3{0, 1, 0};
      expect = g - r;
    } else if (region == 2) {  // rim
      double a = rng.uni(0.01, 1) * r, b = rng.uni(0.01, 1) * r, d = std::sqrt(a * a + b * b);
      lp = u * (R + a) + Vec3{0, -(H + b), 0};
      nl = (u * a + Vec3{0, -b, 0}) / d;
      expect = d - r;
    } else {  // inside, nearest the bottom cap
      double g = rng.uni(0, 0.45) * std::min(R, H), s = rng.uni(0, 1) * (R - g) * 0.99;
      if (R - s <= g) continue;
      lp = u * s + Vec3{0, -(H - g), 0};
      nl = Vec3{0, -1, 0};
      expect = -g - r;
    }
    Pose wc = pose(Vec3{rng.uni(-1, 1), rng.uni(-1, 1), rng.uni(-1, 1)}, rng.rot());
    Shape S = sphere(r), C = cylinder(R, H);
    int m = collideShapes(C, wc, S, pose(transformPoint(wc, lp)), nullptr, env, c);
    if (!oneContactAt(c, m, expect, env, 1e-9)) continue;
    CHECK(angleDeg(c[0].normal, rotate(wc.q, nl)) < 1e-5);
  }
}

TEST_CASE("capsule pairs match closest-point distances found by search", "[narrowphase]") {
  Rng rng(5);
  ContactPoint c[kMaxContactsPerPair];
  int checked = 0;
  for (int it = 0; it < 600; ++it) {
    double ra = rng.uni(0.05, 0.5), ha = rng.uni(0.05, 1), rb = rng.uni(0.05, 0.5), hb = rng.uni(0.05, 1);
    Quat qa = rng.rot(), qb = rng.rot();
    if (it % 5 == 0) qb = qa * quatFromAxisAngle(Vec3{1, 0, 0}, rng.uni(-1e-3, 1e-3));  // nearly parallel
    Vec3 pa{0, 0, 0};
    Vec3 axA = rotate(qa, Vec3{0, 1, 0}), axB = rotate(qb, Vec3{0, 1, 0});
    Vec3 pb = rng.dir() * rng.uni(0, ha + hb + ra + rb + 0.1);
    double env = 0.1 * std::min(ra, rb);
    double core = segmentSegmentDistance(pa - axA * ha, pa + axA * ha, pb - axB * hb, pb + axB * hb);
    double expect = core - ra - rb;
    Shape A = capsule(ra, ha), B = capsule(rb, hb);
    int m = collideShapes(A, pose(pa, qa), B, pose(pb, qb), nullptr, env, c);
    if (expect >= env + 1e-9) {
      CHECK(m == 0);
      continue;
    }
    if (expect >= env - 1e-9) continue;
    REQUIRE(m >= 1);
    checkConsistent(c, m, env);
    int k = deepest(c, m);
    CHECK(c[k].dist == Approx(expect).margin(1e-7));
    if (core > 1e-6) {  // normal along the closest-point direction: the deepest point's normal is
      // perpendicular to both axes unless an end is involved; check that it separates: moving B along it
      // by -dist brings the capsules to touching.
      Vec3 sh = c[k].normal * (-c[k].dist);
      double d2 = segmentSegmentDistance(pa - axA * ha, pa + axA * ha, pb - axB * hb + sh, pb + axB * hb + sh);
      CHECK(d2 - ra - rb == Approx(0).margin(1e-6));
    }
    ++checked;
    // Sphere-capsule: sphere at the B capsule's place.
    Shape S = sphere(rb);
    double es = pointSegmentDistance(pb, pa - axA * ha, pa + axA * ha) - ra - rb;
    m = collideShapes(S, pose(pb), A, pose(pa, qa), nullptr, env, c);
    if (es < env - 1e-9) {
      REQUIRE(m == 1);
      checkConsistent(c, m, env);
      CHECK(c[0].dist == Approx(es).margin(1e-9));
    } else if (es > env + 1e-9) {
      CHECK(m == 0);
    }
  }
  CHECK(checked > 100);

  // Two capsules lying side by side, parallel: two points at the overlap ends.
  Shape A = capsule(0.2, 1), B = capsule(0.2, 1);
  Quat lie = quatFromAxisAngle(Vec3{0, 0, 1}, kPi / 2);  // axis along x
  int m = collideShapes(A, pose(Vec3{0, 0, 0}, lie), B, pose(Vec3{0.5, 0.39, 0}, lie), nullptr, 0.02, c);
  REQUIRE(m == 3);
  for (int i = 0; i < m; ++i) {
    CHECK(c[i].dist == Approx(-0.01).margin(1e-12));
    CHECK(angleDeg(c[i].normal, Vec3{0, 1, 0}) < 1e-6);
  }
}

TEST_CASE("capsule-, cylinder-, cone- and box-plane manifolds", "[narrowphase]") {
  Rng rng(6);
  ContactPoint c[kMaxContactsPerPair];
  Shape P = plane(Vec3{0, 1, 0}, 0);
  for (int it = 0; it < 200; ++it) {
    // Global frame: the whole scene rotated and moved.
    Pose g = pose(Vec3{rng.uni(-2, 2), rng.uni(-2, 2), rng.uni(-2, 2)}, rng.rot());
    auto G = [&](Pose p) { return compose(g, p); };
    Vec3 up = rotate(g.q, Vec3{0, 1, 0});
    double th = rng.uni(0, 1.5), pen = rng.uni(0, 0.05);
    Quat tilt = quatFromAxisAngle(Vec3{0, 0, 1}, th) * quatFromAxisAngle(Vec3{0, 1, 0}, rng.uni(0, 2 * kPi));
    Vec3 tiltAxis = rotate(tilt, Vec3{0, 1, 0});
    double cosT = std::fabs(tiltAxis.y), sinT = std::sqrt(std::max(0.0, 1 - cosT * cosT));

    // Capsule: lowest point = centre - h cos - r.
    double r = rng.uni(0.1, 0.5), h = rng.uni(0.1, 1);
    double yc = h * cosT + r - pen;
    int m = collideShapes(capsule(r, h), G(pose(Vec3{0, yc, 0}, tilt)), P, G(pose(Vec3{0, 0, 0})), nullptr, 0.1, c);
    REQUIRE(m >= 1);
    checkConsistent(c, m, 0.1);
    CHECK(c[deepest(c, m)].dist == Approx(-pen).margin(1e-9));
    CHECK(angleDeg(c[0].normal, -up) < 1e-6);
    // the upper end is at height 2 h cos - pen above: reported when within the envelope
    CHECK(m == (2 * h * cosT - pen < 0.1 ? 2 : 1));

    // Cylinder: lowest rim point = centre - h cos - R sin.
    yc = h * cosT + r * sinT - pen;
    m = collideShapes(P, G(pose(Vec3{0, 0, 0})), cylinder(r, h), G(pose(Vec3{0, yc, 0}, tilt)), nullptr, 0.1, c);
    REQUIRE(m >= 1);
    checkConsistent(c, m, 0.1);
    CHECK(c[deepest(c, m)].dist == Approx(-pen).margin(1e-9));
    CHECK(angleDeg(c[0].normal, up) < 1e-6);

    // Cone (apex up in its frame): lowest point min(apex, rim).
    double H = rng.uni(0.3, 1.5);
    double lowApex = 0.5 * H * tiltAxis.y;  // apex height relative to the centre
    double lowRim = -0.5 * H * tiltAxis.y - r * sinT;
    yc = -std::min(lowApex, lowRim) - pen;
    m = collideShapes(cone(r, H), G(pose(Vec3{0, yc, 0}, tilt)), P, G(pose(Vec3{0, 0, 0})), nullptr, 0.1, c);
    REQUIRE(m >= 1);
    checkConsistent(c, m, 0.1);
    CHECK(c[deepest(c, m)].dist == Approx(-pen).margin(1e-9));

    // Box: lowest vertex = centre - sum |R_yj| e_j.
    Vec3 e{rng.uni(0.1, 1), rng.uni(0.1, 1), rng.uni(0.1, 1)};
    Quat qb = rng.rot();
    Vec3 col{rotate(qb, Vec3{1, 0, 0}).y, rotate(qb, Vec3{0, 1, 0}).y, rotate(qb, Vec3{0, 0, 1}).y};
    yc = std::fabs(col.x) * e.x + std::fabs(col.y) * e.y + std::fabs(col.z) * e.z - pen;
    m = collideShapes(box(e.x, e.y, e.z), G(pose(Vec3{0, yc, 0}, qb)), P, G(pose(Vec3{0, 0, 0})), nullptr, 0.1, c);
    REQUIRE(m >= 1);
    checkConsistent(c, m, 0.1);
    CHECK(c[deepest(c, m)].dist == Approx(-pen).margin(1e-9));
  }

  // Resting box: 4 points, features = the 4 bottom vertex indices, stable under a tiny wobble.
  Shape B = box(0.5, 0.25, 0.3);
  for (int k = 0; k < 2; ++k) {
    Quat q = quatFromAxisAngle(Vec3{1, 0.3, 0}, k * 1e-6);
    int m = collideShapes(B, pose(Vec3{0.2, 0.25 - 0.001, 0.1}, q), P, pose(Vec3{0, 0, 0}), nullptr, 0.01, c);
    REQUIRE(m == 4);
    int feats = 0;
    for (int i = 0; i < m; ++i) {
      CHECK(c[i].dist == Approx(-0.001).margin(1e-6));
      feats |= 1 << c[i].feature;
      CHECK(c[i].pa.y == Approx(-0.001).margin(1e-6));
    }
    CHECK(feats == 0x33);  // vertices with y = -e.y: indices 0, 1, 4, 5
  }
  // Standing cylinder: 4 bottom rim points, features 0..3, the same for a tiny tilt.
  for (int k = 0; k < 2; ++k) {
    Quat q = quatFromAxisAngle(Vec3{1, 0, 0.5}, k * 1e-5);
    int m =
        collideShapes(cylinder(0.3, 0.5), pose(Vec3{0, 0.5 - 0.002, 0}, q), P, pose(Vec3{0, 0, 0}), nullptr, 0.01, c);
    REQUIRE(m == 4);
    for (int i = 0; i < m; ++i) {
      CHECK(c[i].feature == i);
      CHECK(c[i].dist == Approx(-0.002).margin(1e-5));
      CHECK(length(c[i].pa - Vec3{0, -0.002, 0}) == Approx(0.3).margin(1e-5));
    }
  }
  // Plane-plane: nothing.
  CHECK(collideShapes(P, pose(Vec3{0, 0, 0}), P, pose(Vec3{0, 0, 0}), nullptr, 0.1, c) == 0);
}

TEST_CASE("convex hull against a plane: deepest vertices, at most 8", "[narrowphase]") {
  Rng rng(7);
  std::vector<Vec3> pts;
  for (int i = 0; i < 40; ++i) pts.push_back(rng.dir() * rng.uni(0.5, 1.0));
  // a flat bottom of 12 points at y = -1
  for (int i = 0; i < 12; ++i) pts.push_back(Vec3{0.5 * std::cos(i * kPi / 6), -1.0, 0.5 * std::sin(i * kPi / 6)});
  Shape Hs = hull(0, int(pts.size()));
  Shape P = plane(Vec3{0, 1, 0}, 0);
  ContactPoint c[kMaxContactsPerPair];
  int m = collideShapes(Hs, pose(Vec3{0, 0.99, 0}), P, pose(Vec3{0, 0, 0}), pts.data(), 0.005, c);
  REQUIRE(m == 8);
  checkConsistent(c, m, 0.005);
  for (int i = 0; i < m; ++i) {
    CHECK(c[i].dist == Approx(-0.01).margin(1e-12));
    CHECK(c[i].feature == i);
  }
  for (int it = 0; it < 100; ++it) {
    Quat q = rng.rot();
    double low = 1e9;
    for (auto& p : pts) low = std::min(low, rotate(q, p).y);
    double pen = rng.uni(0, 0.05);
    m = collideShapes(Hs, pose(Vec3{0, -low - pen, 0}, q), P, pose(Vec3{0, 0, 0}), pts.data(), 0.02, c);
    REQUIRE(m >= 1);
    REQUIRE(m <= 8);
    CHECK(c[deepest(c, m)].dist == Approx(-pen).margin(1e-12));
  }
}

TEST_CASE("small shapes on the side of a large cylinder: a point per vertex, exact radial depth", "[narrowphase]") {
  // The CES drum (R = 160 mm, axis z) against a 0.22 mm-thick flake, a wire and a fragment resting on its side
  // at several angles, in both orders. Oracle: each vertex's distance from the axis minus R, computed here from
  // the shape's definition (brute force over the box corners, the hull points and the wire's bottom line).
  const real R = 0.16;
  Shape drum = cylinder(R, 0.15);
  const Quat qz = quatFromAxisAngle(Vec3{1, 0, 0}, real(kPi / 2));  // cylinder axis Y -> world Z
  const Pose wd = pose(Vec3{0, 0, 0}, qz);
  REQUIRE(std::fabs(double(rotate(qz, Vec3{0, 1, 0}).z) - 1) < 1e-12);
  const double env = 2e-5;
  ContactPoint c[kMaxContactsPerPair];
  for (double ang : {90.0, 40.0, 135.0, -20.0}) {
    const double th = ang * kPi / 180;
    const Vec3 radial{real(std::cos(th)), real(std::sin(th)), 0};
    const Quat qr = quatFromAxisAngle(Vec3{0, 0, 1}, real(th - kPi / 2));  // local +Y -> radial
    REQUIRE(length(rotate(qr, Vec3{0, 1, 0}) - radial) < 1e-12);
    const double pen = 1.5e-5, hx = 0.44e-3, hy = 0.11e-3;
    // Flake: its thin axis radial, bottom face penetrating by `pen` at its centre.
    Shape flake = box(real(hx), real(hy), real(hx));
    const Pose wf = pose(radial * real(R + hy - pen) + Vec3{0, 0, real(0.01)}, qr);
    for (int order = 0; order < 2; ++order) {
      const int m = order == 0 ? collideShapes(flake, wf, drum, wd, nullptr, real(env), c)
                               : collideShapes(drum, wd, flake, wf, nullptr, real(env), c);
      REQUIRE(m == 4);  // the four bottom corners (the top ones are 0.22 mm away)
      checkConsistent(c, m, env);
      for (int i = 0; i < m; ++i) {
        const Vec3 x = order == 0 ? c[i].pa : c[i].pb;  // the flake's vertex
        bool corner = false;
        for (int k = 0; k < 8; ++k) {
          const Vec3 l{(k & 1) ? real(hx) : real(-hx), (k & 2) ? real(hy) : real(-hy), (k & 4) ? real(hx) : real(-hx)};
          corner = corner || length(transformPoint(wf, l) - x) < 1e-12;
        }
        CHECK(corner);
        const double rho = std::sqrt(double(x.x * x.x + x.y * x.y));
        CHECK(double(c[i].dist) == Approx(rho - double(R)).margin(1e-12));
        const Vec3 out_dir = normalized(Vec3{x.x, x.y, 0});
        CHECK(angleDeg(order == 0 ? -c[i].normal : c[i].normal, out_dir) < 1e-6);
        CHECK(double(c[i].dist) < -pen + 1e-6);  // the corners sit (0.44 mm)^2 / 2R = 0.6 um deeper than the centre
      }
    }
    // Wire along the axis: its bottom line is at radius R - pen over its whole length.
    Shape wire = cylinder(real(0.1e-3), real(0.5e-3));
    const Pose ww = pose(radial * real(R + 0.1e-3 - pen), quatFromAxisAngle(Vec3{1, 0, 0}, real(kPi / 2)));
    int m = collideShapes(drum, wd, wire, ww, nullptr, real(env), c);
    REQUIRE(m >= 2);
    checkConsistent(c, m, env);
    CHECK(double(c[deepest(c, m)].dist) == Approx(-pen).margin(1e-12));
    // Fragment (convex hull) with a flat bottom of 6 points 0.2 mm below its origin.
    std::vector<Vec3> pts;
    for (int i = 0; i < 6; ++i)
      pts.push_back(Vec3{real(0.3e-3 * std::cos(i * kPi / 3)), real(-0.2e-3), real(0.3e-3 * std::sin(i * kPi / 3))});
    pts.push_back(Vec3{0, real(0.3e-3), 0});
    Shape frag = hull(0, int(pts.size()));
    const Pose wh = pose(radial * real(R + 0.2e-3 - pen), qr);
    m = collideShapes(frag, wh, drum, wd, pts.data(), real(env), c);
    REQUIRE(m == 6);
    checkConsistent(c, m, env);
    for (int i = 0; i < m; ++i) {
      const Vec3 x = c[i].pa;
      CHECK(double(c[i].dist) == Approx(std::sqrt(double(x.x * x.x + x.y * x.y)) - double(R)).margin(1e-12));
    }
    // The same fragment with a margin of 0.05 mm, raised by it: each bottom vertex's sphere touches the drum at the
    // same depth; the point is the margin below the vertex, along the radial direction through it.
    Shape fragm = frag;
    fragm.margin = 0.05e-3f;
    const double mm = double(fragm.margin);
    m = collideShapes(fragm, pose(wh.p + radial * real(mm), qr), drum, wd, pts.data(), real(env), c);
    REQUIRE(m == 6);
    checkConsistent(c, m, env);
    for (int i = 0; i < m; ++i) {
      int vk = -1;  // the bottom vertex this point belongs to
      for (int k = 0; k < 6; ++k)
        if (std::fabs(length(transformPoint(pose(wh.p + radial * real(mm), qr), pts[size_t(k)]) - c[i].pa) - mm) <
            1e-12)
          vk = k;
      REQUIRE(vk >= 0);
      const Vec3 v = transformPoint(pose(wh.p + radial * real(mm), qr), pts[size_t(vk)]);
      const double rho = std::sqrt(double(v.x * v.x + v.y * v.y));
      CHECK(double(c[i].dist) == Approx(rho - double(R) - mm).margin(1e-12));
      CHECK(angleDeg(v - c[i].pa, normalized(Vec3{v.x, v.y, 0})) < 1e-6);
    }
  }
  // Near a cap the pair is not in the side's regime: the general path answers (MPR; the flake's face lies on the
  // drum's nearly flat side, so with the flat-feature manifold of mpr.h), every point consistent.
  Shape flake = box(real(0.44e-3), real(0.11e-3), real(0.44e-3));
  const Pose wcap = pose(Vec3{0, real(R + 0.1e-3), real(0.15)}, quatIdentity());
  const int m = collideShapes(flake, wcap, drum, wd, nullptr, real(env), c);
  CHECK(m >= 1);
  checkConsistent(c, m, env);
}

namespace {
// The ellipsoid's point nearest the axis of a cylinder (axis z through the origin), found by search over the
// surface: a 400 x 200 grid of (theta, phi), then five finer 21 x 21 grids around the best, each 1/5 the step.
double oracleNearestRho(Vec3 semi, const Pose& w, Vec3& best_x) {
  auto at = [&](double th, double ph) {
    const Vec3 l{real(semi.x * std::cos(th) * std::cos(ph)), real(semi.y * std::sin(ph)),
                 real(semi.z * std::sin(th) * std::cos(ph))};
    return transformPoint(w, l);
  };
  auto rho = [](Vec3 x) { return std::sqrt(double(x.x) * x.x + double(x.y) * x.y); };
  double bt = 0, bp = 0, br = 1e30;
  for (int i = 0; i < 400; ++i)
    for (int j = 0; j <= 200; ++j) {
      const double th = 2 * kPi * i / 400, ph = -kPi / 2 + kPi * j / 200;
      const double r = rho(at(th, ph));
      if (r < br) br = r, bt = th, bp = ph;
    }
  double step = 2 * kPi / 400;
  for (int level = 0; level < 8; ++level) {
    const double ct = bt, cp = bp;
    for (int i = -10; i <= 10; ++i)
      for (int j = -10; j <= 10; ++j) {
        const double th = ct + i * step / 10, ph = cp + j * step / 10;
        const double r = rho(at(th, ph));
        if (r < br) br = r, bt = th, bp = ph;
      }
    step /= 5;
  }
  best_x = at(bt, bp);
  return br;
}
}  // namespace

TEST_CASE("an ellipsoid on the side of a large cylinder: the point nearest the axis, its exact radial depth",
          "[narrowphase]") {
  // The CES drum (R = 160 mm, axis z) against a 1 mm ellipsoid (semi-axes 0.5, 0.25, 0.35 mm) at random
  // orientations, resting (15 um in, 5 um off) and deep (0.1 mm in), in both orders. Oracle: the search above.
  const real R = 0.16;
  const Shape drum = cylinder(R, 0.15);
  const Pose wd = pose(Vec3{0, 0, 0}, quatFromAxisAngle(Vec3{1, 0, 0}, real(kPi / 2)));
  const Vec3 semi{real(0.5e-3), real(0.25e-3), real(0.35e-3)};
  const Shape ell = ellipsoid(semi.x, semi.y, semi.z);
  const double env = 2e-5;
  std::mt19937 g(11);
  std::normal_distribution<double> nd(0, 1);
  ContactPoint c[kMaxContactsPerPair];
  int checked = 0;
  for (int k = 0; k < 24; ++k) {
    const double th = 2 * kPi * k / 24 + 0.1;
    const Vec3 radial{real(std::cos(th)), real(std::sin(th)), 0};
    const Quat q = normalized(Quat{real(nd(g)), real(nd(g)), real(nd(g)), real(nd(g))});
    // its extent along -radial puts it `pen` into the drum (approximately: the oracle gives the exact depth)
    const double reach = double(dot(supportLocal(ell, rotateInv(q, -radial), nullptr), rotateInv(q, -radial)));
    for (double pen : {1.5e-5, -5e-6, 1e-4}) {
      const Pose we = pose(radial * real(R + reach - pen) + Vec3{0, 0, real(0.02 * std::sin(3.0 * k))}, q);
      Vec3 xo;
      const double dist_o = oracleNearestRho(semi, we, xo) - double(R);
      for (int order = 0; order < 2; ++order) {
        INFO("k " << k << " pen " << pen << " order " << order);
        const int m = order == 0 ? collideShapes(ell, we, drum, wd, nullptr, real(env), c)
                                 : collideShapes(drum, wd, ell, we, nullptr, real(env), c);
        REQUIRE(m == 1);
        checkConsistent(c, m, env);
        const Vec3 x = order == 0 ? c[0].pa : c[0].pb;  // on the ellipsoid
        CHECK(double(c[0].dist) == Approx(dist_o).margin(1e-11));
        CHECK(length(x - xo) < 2e-7);              // the same point (the oracle's grid places it to ~1e-7 m)
        const Vec3 l = rotateInv(we.q, x - we.p);  // on the surface: (x/a)^2 + (y/b)^2 + (z/c)^2 = 1
        const double ex = l.x / semi.x, ey = l.y / semi.y, ez = l.z / semi.z;
        CHECK(ex * ex + ey * ey + ez * ez == Approx(1).margin(1e-9));
        CHECK(angleDeg(order == 0 ? -c[0].normal : c[0].normal, normalized(Vec3{x.x, x.y, 0})) < 1e-6);
        ++checked;
      }
    }
  }
  CHECK(checked == 24 * 3 * 2);
}

TEST_CASE("box-box: resting face contact, edge-edge, rotated", "[narrowphase]") {
  Rng rng(8);
  ContactPoint c[kMaxContactsPerPair];
  for (int it = 0; it < 100; ++it) {
    Pose g = pose(Vec3{rng.uni(-2, 2), rng.uni(-2, 2), rng.uni(-2, 2)}, it == 0 ? quatIdentity() : rng.rot());
    Vec3 up = rotate(g.q, Vec3{0, 1, 0});
    // Small cube (half 0.5) resting on a large slab (half 2 x 0.5 x 2), turned about the vertical, pen 0.01.
    double yaw = rng.uni(0, 2 * kPi), pen = rng.uni(0.001, 0.05);
    Vec3 off{rng.uni(-1, 1), 0, rng.uni(-1, 1)};
    Quat qy = quatFromAxisAngle(Vec3{0, 1, 0}, yaw);
    Shape slab = box(2, 0.5, 2), cube = box(0.5, 0.5, 0.5);
    Pose ws = compose(g, pose(Vec3{0, 0, 0}));
    Pose wc = compose(g, pose(off + Vec3{0, 1 - pen, 0}, qy));
    for (int order = 0; order < 2; ++order) {
      int m = order == 0 ? collideShapes(slab, ws, cube, wc, nullptr, 0.05, c)
                         : collideShapes(cube, wc, slab, ws, nullptr, 0.05, c);
      REQUIRE(m == 4);
      checkConsistent(c, m, 0.05);
      for (int i = 0; i < m; ++i) {
        CHECK(c[i].dist == Approx(-pen).margin(1e-9));
        CHECK(angleDeg(c[i].normal, order == 0 ? up : -up) < 1e-6);
        // each point is one of the cube's bottom corners
        Vec3 cubePt = order == 0 ? c[i].pb : c[i].pa;
        Vec3 l = inverseTransformPoint(wc, cubePt);
        CHECK(std::fabs(std::fabs(l.x) - 0.5) < 1e-9);
        CHECK(std::fabs(l.y + 0.5) < 1e-9);
        CHECK(std::fabs(std::fabs(l.z) - 0.5) < 1e-9);
      }
    }
    // Same, the cube overhanging the slab's corner: the contact region is clipped by the slab's side planes.
    Pose wo = compose(g, pose(Vec3{2, 1 - pen, 2}));  // cube centre over the slab corner, unrotated
    int m = collideShapes(slab, ws, cube, wo, nullptr, 0.05, c);
    REQUIRE(m == 4);
    double area_x[2] = {1e9, -1e9}, area_z[2] = {1e9, -1e9};
    for (int i = 0; i < m; ++i) {
      Vec3 l = inverseTransformPoint(ws, c[i].pa);
      area_x[0] = std::min(area_x[0], l.x), area_x[1] = std::max(area_x[1], l.x);
      area_z[0] = std::min(area_z[0], l.z), area_z[1] = std::max(area_z[1], l.z);
      CHECK(c[i].dist == Approx(-pen).margin(1e-9));
    }
    CHECK(area_x[0] == Approx(1.5).margin(1e-9));
    CHECK(area_x[1] == Approx(2.0).margin(1e-9));
    CHECK(area_z[0] == Approx(1.5).margin(1e-9));
    CHECK(area_z[1] == Approx(2.0).margin(1e-9));

    // Edge-edge: a cube rolled 45 deg about x (top edge along x at height sqrt 2) under a cube rolled 45 deg
    // about z (bottom edge along z): crossing edges, penetration pen, normal vertical, points on both edges.
    Shape u = box(1, 1, 1);
    Pose wa = compose(g, pose(Vec3{0, 0, 0}, quatFromAxisAngle(Vec3{1, 0, 0}, kPi / 4)));
    Pose wb = compose(g, pose(Vec3{0.1, 2 * std::sqrt(2.0) - pen, -0.2}, quatFromAxisAngle(Vec3{0, 0, 1}, kPi / 4)));
    m = collideShapes(u, wa, u, wb, nullptr, 0.05, c);
    REQUIRE(m == 1);
    checkConsistent(c, m, 0.05);
    CHECK(c[0].dist == Approx(-pen).margin(1e-9));
    CHECK(angleDeg(c[0].normal, up) < 1e-6);
    Vec3 la = inverseTransformPoint(g, c[0].pa), lb = inverseTransformPoint(g, c[0].pb);
    CHECK(la.x == Approx(0.1).margin(1e-9));
    CHECK(la.y == Approx(std::sqrt(2.0)).margin(1e-9));
    CHECK(la.z == Approx(0).margin(1e-9));
    CHECK(lb.z == Approx(0).margin(1e-9));
    CHECK(lb.x == Approx(0.1).margin(1e-9));
    // beyond the envelope: nothing
    Pose wfar = compose(g, pose(Vec3{0, 2 * std::sqrt(2.0) + 0.06, 0}, quatFromAxisAngle(Vec3{0, 0, 1}, kPi / 4)));
    CHECK(collideShapes(u, wa, u, wfar, nullptr, 0.05, c) == 0);
  }
}

// ---------------------------------------------------------------------------------------------------------
// Against Bullet's GJK/EPA
// ---------------------------------------------------------------------------------------------------------
namespace {

// Exact ellipsoid support for Bullet (btMultiSphereShape with a non-uniform scaling is not an ellipsoid
// support: it returns the scaled sphere point, not the farthest point).
class BtEllipsoid : public btConvexInternalShape {
 public:
  btVector3 semi;
  explicit BtEllipsoid(const btVector3& s) : semi(s) {
    m_shapeType = CUSTOM_CONVEX_SHAPE_TYPE;
    setMargin(0);
  }
  btVector3 localGetSupportingVertexWithoutMargin(const btVector3& d) const override {
    btVector3 a2d(semi.x() * semi.x() * d.x(), semi.y() * semi.y() * d.y(), semi.z() * semi.z() * d.z());
    btScalar den = btSqrt(a2d.dot(d));
    return den > 0 ? a2d / den : btVector3(semi.x(), 0, 0);
  }
  btVector3 localGetSupportingVertex(const btVector3& d) const override {
    return localGetSupportingVertexWithoutMargin(d);
  }
  void batchedUnitVectorGetSupportingVertexWithoutMargin(const btVector3* v, btVector3* out, int n) const override {
    for (int i = 0; i < n; ++i) out[i] = localGetSupportingVertexWithoutMargin(v[i]);
  }
  void calculateLocalInertia(btScalar, btVector3& inertia) const override { inertia.setValue(1, 1, 1); }
  const char* getName() const override { return "BtEllipsoid"; }
  void getAabb(const btTransform& t, btVector3& lo, btVector3& hi) const override { getAabbSlow(t, lo, hi); }
  int getNumPreferredPenetrationDirections() const override { return 0; }
  void getPreferredPenetrationDirection(int, btVector3&) const override {}
};

struct Pair {
  Shape s;
  std::unique_ptr<btConvexShape> bt;
};

// b with collision margin 0: its surface is then exactly the shape it twins (ours have no margin).
btConvexShape* withoutMargin(btConvexShape* b) {
  b->setMargin(0);
  return b;
}

const ShapeType kConvexTypes[] = {ShapeType::Sphere,  ShapeType::Ellipsoid, ShapeType::Box,       ShapeType::Cylinder,
                                  ShapeType::Capsule, ShapeType::Cone,      ShapeType::ConvexHull};

// A random shape of type t, with its Bullet twin (margins 0 where Bullet allows; sphere and capsule radii are
// their margins; a hull gets `hull_margin` on both). Hull points are appended to `pts`.
Pair randomShape(ShapeType t, Rng& rng, std::vector<Vec3>& pts, double hull_margin = 0) {
  Pair p;
  switch (t) {
    case ShapeType::Sphere: {
      double r = rng.uni(0.3, 1);
      p.s = sphere(r);
      p.bt.reset(new btSphereShape(btScalar(r)));
      break;
    }
    case ShapeType::Ellipsoid: {
      Vec3 a{rng.uni(0.3, 1), rng.uni(0.3, 1), rng.uni(0.3, 1)};
      p.s = ellipsoid(a.x, a.y, a.z);
      p.bt.reset(new BtEllipsoid(btVector3(btScalar(a.x), btScalar(a.y), btScalar(a.z))));
      break;
    }
    case ShapeType::Box: {
      Vec3 e{rng.uni(0.2, 1), rng.uni(0.2, 1), rng.uni(0.2, 1)};
      p.s = box(e.x, e.y, e.z);
      p.bt.reset(withoutMargin(new btBoxShape(btVector3(btScalar(e.x), btScalar(e.y), btScalar(e.z)))));
      break;
    }
    case ShapeType::Cylinder: {
      double r = rng.uni(0.2, 0.8), h = rng.uni(0.2, 1);
      p.s = cylinder(r, h);
      p.bt.reset(withoutMargin(new btCylinderShape(btVector3(btScalar(r), btScalar(h), btScalar(r)))));
      break;
    }
    case ShapeType::Capsule: {
      double r = rng.uni(0.15, 0.6), h = rng.uni(0.1, 0.8);
      p.s = capsule(r, h);
      p.bt.reset(new btCapsuleShape(btScalar(r), btScalar(2 * h)));
      break;
    }
    case ShapeType::Cone: {
      double r = rng.uni(0.3, 0.8), h = rng.uni(0.5, 1.5);
      p.s = cone(r, h);
      p.bt.reset(withoutMargin(new btConeShape(btScalar(r), btScalar(h))));
      break;
    }
    default: {  // convex hull: points around a random ellipsoid, offset from the origin
      int n = 12 + int(rng.uni(0, 12));
      Vec3 a{rng.uni(0.3, 1), rng.uni(0.3, 1), rng.uni(0.3, 1)},
          o{rng.uni(-0.1, 0.1), rng.uni(-0.1, 0.1), rng.uni(-0.1, 0.1)};
      p.s = hull(int(pts.size()), n);
      auto* b = new btConvexHullShape();
      for (int i = 0; i < n; ++i) {
        Vec3 x = o + mul(rng.dir(), a) * rng.uni(0.9, 1.0);
        pts.push_back(x);
        b->addPoint(btVector3(btScalar(x.x), btScalar(x.y), btScalar(x.z)), false);
      }
      b->recalcLocalAabb();
      b->setMargin(btScalar(hull_margin));
      p.s.margin = float(hull_margin);
      p.bt.reset(b);
      break;
    }
  }
  p.s.size = t == ShapeType::ConvexHull ? 0.3 + hull_margin : minComponent(p.s.dims);
  if (t == ShapeType::Sphere || t == ShapeType::Cylinder || t == ShapeType::Capsule || t == ShapeType::Cone)
    p.s.size = std::min(p.s.dims.x, p.s.dims.y);
  return p;
}

btTransform toBt(const Pose& p) {
  return btTransform(btQuaternion(btScalar(p.q.x), btScalar(p.q.y), btScalar(p.q.z), btScalar(p.q.w)),
                     btVector3(btScalar(p.p.x), btScalar(p.p.y), btScalar(p.p.z)));
}

struct BtResult {
  double dist;
  Vec3 normal;  // from A to B
  bool ok;
};

BtResult bulletDistance(const btConvexShape* a, const Pose& pa, const btConvexShape* b, const Pose& pb) {
  btVoronoiSimplexSolver simplex;
  // Default threshold: new support points within 1e-2 (squared 1e-4) of a simplex vertex stop GJK, which
  // leaves errors of ~3e-3 on curved shapes of unit size; tighten it.
  simplex.setEqualVertexThreshold(btScalar(1e-12));
  btGjkEpaPenetrationDepthSolver epa;
  btGjkPairDetector gjk(a, b, &simplex, &epa);
  btDiscreteCollisionDetectorInterface::ClosestPointInput in;
  in.m_transformA = toBt(pa);
  in.m_transformB = toBt(pb);
  in.m_maximumDistanceSquared = BT_LARGE_FLOAT;
  btPointCollector pc;
  gjk.getClosestPoints(in, pc, nullptr);
  btVector3 n = pc.m_normalOnBInWorld;  // on B, pointing toward A
  return BtResult{double(pc.m_distance), Vec3{-n.x(), -n.y(), -n.z()}, pc.m_hasResult};
}

// The offset t at which B, posed at c0 + t u with orientation qb, just touches A at pa: bisection on Bullet's
// distance (the independent reference; float, ~1e-6) between 0 and the sum of the bounding radii (+0.1), 30 halvings.
double touchingOffset(const Pair& A, const Pose& pa, const Pair& B, Vec3 c0, Vec3 u, Quat qb,
                      const std::vector<Vec3>& pts) {
  double lo = 0, hi = boundingRadius(A.s, pts.data()) + boundingRadius(B.s, pts.data()) + 0.1;
  for (int k = 0; k < 30; ++k) {
    const double mid = 0.5 * (lo + hi);
    (bulletDistance(A.bt.get(), pa, B.bt.get(), pose(c0 + u * mid, qb)).dist < 0 ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace

TEST_CASE("Bullet GJK/EPA sign conventions (sanity)", "[narrowphase][bullet]") {
  btSphereShape a(1), b(0.5);
  BtResult r = bulletDistance(&a, pose(Vec3{0, 0, 0}), &b, pose(Vec3{0, 1.4, 0}));
  REQUIRE(r.ok);
  CHECK(r.dist == Approx(-0.1).margin(1e-5));
  CHECK(angleDeg(r.normal, Vec3{0, 1, 0}) < 1e-3);
  btBoxShape bx(btVector3(1, 1, 1));
  bx.setMargin(0);
  r = bulletDistance(&bx, pose(Vec3{0, 0, 0}), &bx, pose(Vec3{0.3, 2.1, 0}));
  CHECK(r.dist == Approx(0.1).margin(1e-5));
  CHECK(angleDeg(r.normal, Vec3{0, 1, 0}) < 1e-3);
}

// Signed distance by brute force, independent of the narrow phase: for convex A, B the signed distance is
// max over unit n of -h(n), h(n) = max_A n.x - min_B n.x (support functions; for separated shapes this is
// the distance, for overlapping ones minus the minimum penetration depth). Searched over a Fibonacci sphere of
// directions plus the given hints, then refined by a pattern search (8 directions, halving steps) from the
// best few. Support points come from supportLocal, itself compared with Bullet's support mappings below.
double oracleSignedDistance(const Shape& A, const Pose& pa, const Shape& B, const Pose& pb, const Vec3* pts,
                            const Vec3* hints, int nhints, Vec3* nbest) {
  auto negh = [&](Vec3 n) {
    Vec3 sa = transformPoint(pa, supportLocal(A, rotateInv(pa.q, n), pts));
    Vec3 sb = transformPoint(pb, supportLocal(B, rotateInv(pb.q, -n), pts));
    return -dot(sa - sb, n);
  };
  const int K = 3000, kTop = 4;
  Vec3 top[kTop + 8];
  double topv[kTop + 8];
  int nt = 0;
  auto offer = [&](Vec3 n, double v) {
    if (nt < kTop) {
      top[nt] = n, topv[nt] = v, ++nt;
      return;
    }
    int w = 0;
    for (int i = 1; i < nt; ++i)
      if (topv[i] < topv[w]) w = i;
    if (v > topv[w]) top[w] = n, topv[w] = v;
  };
  for (int i = 0; i < K; ++i) {
    double z = 1 - 2 * (i + 0.5) / K, r = std::sqrt(1 - z * z), ph = i * kPi * (3 - std::sqrt(5.0));
    Vec3 n{r * std::cos(ph), r * std::sin(ph), z};
    offer(n, negh(n));
  }
  for (int h = 0; h < nhints; ++h) top[nt] = normalized(hints[h]), topv[nt] = negh(top[nt]), ++nt;
  double best = -1e300;
  for (int t = 0; t < nt; ++t) {
    Vec3 n = top[t];
    double v = topv[t];
    Vec3 u, w;
    for (double step = 0.05; step > 1e-10; step *= 0.5) {
      bool improved = true;
      for (int guard = 0; improved && guard < 200; ++guard) {
        improved = false;
        tangentBasis(n, u, w);
        for (int k = 0; k < 8; ++k) {
          double ang = k * kPi / 4;
          Vec3 m = normalized(n + (u * std::cos(ang) + w * std::sin(ang)) * step);
          double vm = negh(m);
          if (vm > v) v = vm, n = m, improved = true;
        }
      }
    }
    if (v > best) best = v, *nbest = n;
  }
  return best;
}

// For every pair of convex types: random shapes and orientations; the pair is placed along a random direction
// at Bullet's touching distance (bisection on Bullet's signed distance), then offset by a random amount in
// [-8 %, +8 %] of the smaller shape's size (resting contacts in a DVI simulation penetrate far less).
// Checked, for our deepest point:
//  * against the brute-force oracle above: ours is -h(n) for its own normal, so never above the oracle;
//    closed-form and box-box pairs must match it to 1e-6, MPR pairs to 1e-3 (shapes are 0.2 .. 1.5 long;
//    MPR converges to a face of the Minkowski difference that holds the origin's projection, not always the
//    nearest one; measured worst 4.5e-4, cone-cone).
//  * against Bullet (float build; margins 0 except sphere and capsule, whose radius is the margin). Where
//    Bullet is exact (spheres, boxes, capsules, hulls: polytopes and point/segment cores) distance within 1e-4
//    and normal within 2 degrees. With a curved shape (ellipsoid, cylinder, cone) Bullet itself is off: measured
//    against the oracle, its float GJK stops up to ~5e-3 early on separated curved pairs and EPA
//    underestimates curved penetrations by up to ~3e-3 (its polytope lies inside the shape), so there the
//    bound is 7e-3 and 12 degrees. Normals are compared where |dist| > 5e-3 (ill-defined near touching).
// Box-box separated by a gap: our SAT contacts are conservative (dist <= the true distance, or no point where
// the closest features are vertex-vertex or vertex-edge), checked as such.
TEST_CASE("every convex pair agrees with Bullet's GJK/EPA and a brute-force oracle", "[narrowphase][bullet]") {
  const int kSamples = 100;
  std::vector<Vec3> pts;
  pts.reserve(100000);
  Rng rng(9);
  double worstBt = 0, worstAng = 0, worstOr = 0, worstBtOr = 0;
  int compared = 0;
  for (int ia = 0; ia < 7; ++ia)
    for (int ib = ia; ib < 7; ++ib) {
      ShapeType ta = kConvexTypes[ia], tb = kConvexTypes[ib];
      std::string name = std::string(shapeTypeName(ta)) + "-" + shapeTypeName(tb);
      bool closedForm = ta == ShapeType::Sphere && (tb == ShapeType::Sphere || tb == ShapeType::Box ||
                                                    tb == ShapeType::Cylinder || tb == ShapeType::Capsule);
      closedForm = closedForm || (ta == tb && (ta == ShapeType::Box || ta == ShapeType::Capsule));
      bool boxbox = ta == ShapeType::Box && tb == ShapeType::Box;
      auto curved = [](ShapeType t) {
        return t == ShapeType::Ellipsoid || t == ShapeType::Cylinder || t == ShapeType::Cone;
      };
      const bool btExact = !curved(ta) && !curved(tb);
      const double tolBt = btExact ? 1e-4 : 7e-3, tolAng = btExact ? 2.0 : 12.0;
      double pBt = 0, pAng = 0, pOr = 0, pBtOr = 0;
      for (int it = 0; it < kSamples; ++it) {
        Pair A = randomShape(ta, rng, pts), B = randomShape(tb, rng, pts);
        bool swap = it % 2 == 1;  // exercise both argument orders
        Quat qa = rng.rot(), qb = rng.rot();
        Vec3 u = rng.dir();
        Vec3 c0{rng.uni(-1, 1), rng.uni(-1, 1), rng.uni(-1, 1)};
        auto at = [&](double t) { return pose(c0 + u * t, qb); };
        Pose pa = pose(c0, qa);
        const double touch = touchingOffset(A, pa, B, c0, u, qb, pts);
        double size = std::min(A.s.size, B.s.size);
        double t = touch + rng.uni(-0.08, 0.08) * size;
        Pose pb = at(t);
        BtResult ref = bulletDistance(A.bt.get(), pa, B.bt.get(), pb);
        REQUIRE(ref.ok);
        double env = 0.1 * size;
        if (ref.dist > 0.8 * env) continue;  // keep clear of the envelope edge
        ContactPoint c[kMaxContactsPerPair];
        int m = swap ? collideShapes(B.s, pb, A.s, pa, pts.data(), env, c)
                     : collideShapes(A.s, pa, B.s, pb, pts.data(), env, c);
        if (swap) {
          for (int i = 0; i < m; ++i) {
            c[i].normal = -c[i].normal;
            std::swap(c[i].pa, c[i].pb);
          }
        }
        INFO(name << " sample " << it << " bullet dist " << ref.dist);
        if (boxbox && ref.dist > 0) {
          if (m > 0) CHECK(c[deepest(c, m)].dist <= ref.dist + 1e-4);
          continue;
        }
        REQUIRE(m >= 1);
        checkConsistent(c, m, env);
        int k = deepest(c, m);
        Vec3 hints[2] = {c[k].normal, ref.normal}, nor;
        double orc = oracleSignedDistance(A.s, pa, B.s, pb, pts.data(), hints, 2, &nor);
        INFO("ours " << c[k].dist << " oracle " << orc);
        double eo = orc - c[k].dist;
        CHECK(eo > -1e-9);
        CHECK(eo < (closedForm ? 1e-6 : 1e-3));
        double eb = std::fabs(c[k].dist - ref.dist);
        CHECK(eb < tolBt);
        pOr = std::max(pOr, eo);
        pBt = std::max(pBt, eb);
        pBtOr = std::max(pBtOr, std::fabs(ref.dist - orc));
        if (std::fabs(ref.dist) > 5e-3) {
          double ang = angleDeg(c[k].normal, ref.normal);
          CHECK(ang < tolAng);
          pAng = std::max(pAng, ang);
        }
        ++compared;
      }
      std::printf("  %-24s |ours-oracle| %.1e  |ours-bullet| %.1e  normal vs bullet %5.2f deg  |bullet-oracle| %.1e\n",
                  name.c_str(), pOr, pBt, pAng, pBtOr);
      worstOr = std::max(worstOr, pOr), worstBt = std::max(worstBt, pBt), worstAng = std::max(worstAng, pAng);
      worstBtOr = std::max(worstBtOr, pBtOr);
    }
  std::printf(
      "  all pairs, %d samples: |ours-oracle| %.1e  |ours-bullet| %.1e  normal %.2f deg  |bullet-oracle| %.1e\n",
      compared, worstOr, worstBt, worstAng, worstBtOr);
  CHECK(compared > 28 * kSamples / 2);
}

// Pairs whose cores are apart (the swept shapes separated, or overlapping within their sweeps: a hull's margin, a
// sphere's or capsule's radius) take their normal and distance from the cores' closest points (gjk.h), which are
// exact: for every MPR pair type, placed at a random gap from touching in [-sweeps / 2, 8 % of the smaller size],
// the deepest point must equal the brute-force oracle to 1e-7 (polytope and point/segment cores: GJK ends on the
// exact features) or 1e-5 (curved cores: GJK stops at its relative tolerance, or leaves the pair to MPR), and its
// normal the oracle's to 0.01 degree where the gap is above 1e-3. Far apart, gjkDistance proves it (kGjkApart);
// with the cores overlapping it answers kGjkOverlap.
TEST_CASE("cores apart: GJK's closest points give the oracle's distance and normal", "[narrowphase]") {
  std::vector<Vec3> pts;
  pts.reserve(100000);
  Rng rng(41);
  double worst = 0, worstAng = 0;
  int compared = 0, close = 0;
  for (int ia = 0; ia < 7; ++ia)
    for (int ib = ia; ib < 7; ++ib) {
      const ShapeType ta = kConvexTypes[ia], tb = kConvexTypes[ib];
      if (!pairUsesMpr(ta, tb)) continue;
      auto curved = [](ShapeType t) {
        return t == ShapeType::Ellipsoid || t == ShapeType::Cylinder || t == ShapeType::Cone;
      };
      const double tol = curved(ta) || curved(tb) ? 1e-5 : 1e-7;
      int pc = 0, pg = 0;
      double pw = 0;
      for (int it = 0; it < 40; ++it) {
        Pair A = randomShape(ta, rng, pts, rng.uni(0, 0.1)), B = randomShape(tb, rng, pts, rng.uni(0, 0.1));
        const Quat qa = rng.rot(), qb = rng.rot();
        const Vec3 u = rng.dir(), c0{rng.uni(-1, 1), rng.uni(-1, 1), rng.uni(-1, 1)};
        auto at = [&](double t) { return pose(c0 + u * t, qb); };
        const Pose pa = pose(c0, qa);
        Vec3 nor;
        const double touch = touchingOffset(A, pa, B, c0, u, qb, pts);
        const double sweeps = np::sweepRadius(A.s) + np::sweepRadius(B.s);
        const double size = std::min(A.s.size, B.s.size);
        const Pose pb = at(touch + rng.uni(-0.5 * sweeps, 0.08 * size));
        const double env = 0.1 * size;
        // the cores' own answer, as the narrow phase asks it
        const np::MprShape MA = np::makeMprShape(A.s, pa, pts.data(), env),
                           MB = np::makeMprShape(B.s, pb, pts.data(), 0);
        np::MprResult r;
        const int g = np::mprCoresApart(MA, MB, pts.data(), r);
        ContactPoint c[kMaxContactsPerPair];
        const int m = collideShapes(A.s, pa, B.s, pb, pts.data(), env, c);
        // The oracle searches from our normal too: ours is -h(n) for that normal, so the oracle's value is never
        // below it, and exceeds it where a better normal exists.
        const Vec3 hints[2] = {u, m > 0 ? c[deepest(c, m)].normal : u};
        const double orc = oracleSignedDistance(A.s, pa, B.s, pb, pts.data(), hints, 2, &nor);
        INFO(shapeTypeName(ta) << "-" << shapeTypeName(tb) << " sample " << it << " oracle " << orc);
        if (orc < -0.5 * sweeps - 1e-5) continue;  // placed deeper than half the sweeps (Bullet's rounding)
        if (orc >= env) {
          CHECK(g == np::kGjkApart);
          continue;
        }
        REQUIRE(m >= 1);
        checkConsistent(c, m, env);
        const ContactPoint& k = c[deepest(c, m)];
        INFO("ours " << k.dist << " gjk answer " << g);
        CHECK(orc - k.dist > -1e-9);
        CHECK(orc - k.dist < tol);
        worst = std::max(worst, std::fabs(k.dist - orc));
        if (orc > 1e-3) {
          CHECK(angleDeg(k.normal, nor) < 0.01);
          worstAng = std::max(worstAng, angleDeg(k.normal, nor));
        }
        close += g == np::kGjkClose;
        ++compared;
        pg += g == np::kGjkClose;
        ++pc;
        pw = std::max(pw, orc - k.dist);
      }
      std::printf("  %-26s %2d samples, %2d through GJK: |ours-oracle| %.1e\n",
                  (std::string(shapeTypeName(ta)) + "-" + shapeTypeName(tb)).c_str(), pc, pg, pw);
    }
  std::printf("  cores apart, %d samples (%d through GJK): |ours-oracle| %.1e  normal %.4f deg\n", compared, close,
              worst, worstAng);
  CHECK(close > compared / 2);
  // Overlapping cores: two unit boxes 1.5 apart (cores overlap by 0.5) go to MPR.
  const Shape bx = box(1, 1, 1);
  const np::MprShape O1 = np::makeMprShape(bx, pose(Vec3{0, 0, 0}), pts.data(), 0.1);
  const np::MprShape O2 = np::makeMprShape(bx, pose(Vec3{1.5, 0.2, 0}), pts.data(), 0);
  np::MprResult r;
  CHECK(np::mprCoresApart(O1, O2, pts.data(), r) == np::kGjkOverlap);
  // 0.05 apart along x within an envelope of 0.1: exact, normal +x, depth 0.1 - 0.05.
  const np::MprShape N2 = np::makeMprShape(bx, pose(Vec3{2.05, 0.2, 0.1}), pts.data(), 0);
  REQUIRE(np::mprCoresApart(O1, N2, pts.data(), r) == np::kGjkClose);
  CHECK(r.depth == Approx(0.05).margin(1e-12));
  CHECK(angleDeg(r.n, Vec3{1, 0, 0}) < 1e-9);
}

TEST_CASE("supportLocal agrees with Bullet's support mappings", "[narrowphase][bullet]") {
  Rng rng(10);
  std::vector<Vec3> pts;
  for (ShapeType t : kConvexTypes) {
    for (int it = 0; it < 20; ++it) {
      Pair p = randomShape(t, rng, pts);
      for (int k = 0; k < 50; ++k) {
        Vec3 d = rng.dir();
        Vec3 s = supportLocal(p.s, d, pts.data());
        btVector3 bs = p.bt->localGetSupportingVertex(btVector3(btScalar(d.x), btScalar(d.y), btScalar(d.z)));
        // compare the support values h(d) (the points may differ on flat features)
        CHECK(dot(s, d) == Approx(double(bs.dot(btVector3(btScalar(d.x), btScalar(d.y), btScalar(d.z))))).margin(1e-5));
      }
    }
  }
}

// A hull with a margin m is its points swept by a sphere of radius m (Bullet: btConvexInternalShape::
// localGetSupportingVertex): support s(d) = s_points(d) + m d/|d|. Expected values: the cube's corners in closed form
// and, for random points, the brute-force maximum of dot(p, d); margins exact in float (Shape::margin is a float).
TEST_CASE("convex hull margin: the support is the points' support plus m d/|d|", "[narrowphase][hull]") {
  const double h = 0.5;
  std::vector<Vec3> cube;
  for (int i = 0; i < 8; ++i) cube.push_back(Vec3{i & 1 ? h : -h, i & 2 ? h : -h, i & 4 ? h : -h});
  Rng rng(31);
  std::vector<Vec3> rnd;
  for (int i = 0; i < 30; ++i) rnd.push_back(Vec3{rng.uni(-0.1, 0.1), 0.2, 0} + mul(rng.dir(), Vec3{1, 0.5, 0.7}));
  for (double m : {0.0, 0.03125, 0.125, 0.375}) {
    Shape s = hull(0, 8);
    s.margin = float(m);
    Shape r = hull(0, int(rnd.size()));
    r.margin = float(m);
    for (int k = 0; k < 300; ++k) {
      const Vec3 d = rng.dir() * rng.uni(1e-3, 1e3);  // any length
      const double l = length(d);
      const Vec3 expect{(d.x < 0 ? -h : h) + m * d.x / l, (d.y < 0 ? -h : h) + m * d.y / l,
                        (d.z < 0 ? -h : h) + m * d.z / l};
      INFO("margin " << m << " d " << d.x << " " << d.y << " " << d.z);
      CHECK(length(supportLocal(s, d, cube.data()) - expect) < 1e-12);
      // random points: the support minus m d/|d| is a point of maximal dot(p, d)
      double best = -1e300;
      for (const Vec3& p : rnd) best = std::max(best, dot(p, d));
      const Vec3 core = supportLocal(r, d, rnd.data()) - d * (m / l);
      double nearest = 1e300;
      for (const Vec3& p : rnd) nearest = std::min(nearest, length(p - core));
      CHECK(nearest < 1e-12);
      CHECK(dot(core, d) == Approx(best).epsilon(1e-12));
    }
  }
}

TEST_CASE("convex hull margin: AABB, bounding radius and plane contacts include it exactly", "[narrowphase][hull]") {
  const double h = 0.5, m = 0.125;
  std::vector<Vec3> cube;
  for (int i = 0; i < 8; ++i) cube.push_back(Vec3{i & 1 ? h : -h, i & 2 ? h : -h, i & 4 ? h : -h});
  Shape s = hull(0, 8);
  s.margin = float(m);
  CHECK(boundingRadius(s, cube.data()) == Approx(std::sqrt(3.0) * h + m).epsilon(1e-14));
  Rng rng(32);
  for (int it = 0; it < 50; ++it) {
    const Pose w = pose(Vec3{rng.uni(-2, 2), rng.uni(-2, 2), rng.uni(-2, 2)}, rng.rot());
    const double env = rng.uni(0, 0.1);
    const Aabb bb = shapeAabb(s, w, cube.data(), env);
    // the rotated cube's half extent along world axis i is h sum_j |R_ij|; the sphere adds m, the envelope env
    for (int i = 0; i < 3; ++i) {
      Vec3 e{i == 0 ? 1.0 : 0.0, i == 1 ? 1.0 : 0.0, i == 2 ? 1.0 : 0.0};
      const Vec3 row = rotateInv(w.q, e);  // row i of R
      const double half = h * (std::fabs(row.x) + std::fabs(row.y) + std::fabs(row.z)) + m + env;
      CHECK(np::comp(bb.hi, i) == Approx(np::comp(w.p, i) + half).margin(1e-12));
      CHECK(np::comp(bb.lo, i) == Approx(np::comp(w.p, i) - half).margin(1e-12));
    }
  }
  // Resting on the plane y = 0 (turned about the vertical): the bottom face is m below the points, so the cube is
  // touching at centre height h + m; every bottom corner's contact point lies m below it.
  const Shape P = plane(Vec3{0, 1, 0}, 0);
  ContactPoint c[kMaxContactsPerPair];
  for (int it = 0; it < 20; ++it) {
    const double pen = it == 0 ? 0.0 : rng.uni(0, 0.01);
    const Quat q = quatFromAxisAngle(Vec3{0, 1, 0}, real(rng.uni(0, 2 * kPi)));
    const Pose w = pose(Vec3{rng.uni(-1, 1), h + m - pen, rng.uni(-1, 1)}, q);
    const int n = collideShapes(s, w, P, pose(Vec3{0, 0, 0}), cube.data(), 0.01, c);
    REQUIRE(n == 4);
    checkConsistent(c, n, 0.01);
    for (int i = 0; i < n; ++i) {
      CHECK(c[i].dist == Approx(-pen).margin(1e-12));
      CHECK(c[i].pa.y == Approx(-pen).margin(1e-12));
      CHECK(c[i].pb.y == Approx(0).margin(1e-12));
      CHECK(c[i].normal.y == Approx(-1).margin(1e-15));
    }
  }
  // Tilted: the lowest corner's sphere decides, dist = (lowest corner height) - m.
  for (int it = 0; it < 50; ++it) {
    const Quat q = rng.rot();
    double low = 1e9;
    for (const Vec3& p : cube) low = std::min(low, rotate(q, p).y);
    const double y = rng.uni(-0.05, 0.05) - low + m;
    const int n = collideShapes(s, pose(Vec3{0, y, 0}, q), P, pose(Vec3{0, 0, 0}), cube.data(), 0.1, c);
    if (y + low - m >= 0.1) continue;
    REQUIRE(n >= 1);
    CHECK(c[deepest(c, n)].dist == Approx(y + low - m).margin(1e-12));
  }
  // Far above: nothing; just inside the envelope: found.
  CHECK(collideShapes(s, pose(Vec3{0, h + m + 0.011, 0}), P, pose(Vec3{0, 0, 0}), cube.data(), 0.01, c) == 0);
  CHECK(collideShapes(s, pose(Vec3{0, h + m + 0.009, 0}), P, pose(Vec3{0, 0, 0}), cube.data(), 0.01, c) == 4);
}

// Hulls with a margin against every convex type through MPR (and the closed forms it meets), against Bullet's
// GJK/EPA on the same shapes (btConvexHullShape::setMargin): the signed distance, and contact points on the swept
// surfaces (their height along the normal is Bullet's support value there).
TEST_CASE("convex hull margin: every pair with a swept hull agrees with Bullet's GJK/EPA",
          "[narrowphase][bullet][hull]") {
  std::vector<Vec3> pts;
  pts.reserve(100000);
  Rng rng(33);
  double worst = 0, worstGap = 0;
  int compared = 0;
  auto btSupport = [](const btConvexShape* s, const Pose& w, Vec3 d) {  // Bullet's support value in world frame
    const Vec3 dl = rotateInv(w.q, d);
    const btVector3 v = s->localGetSupportingVertex(btVector3(btScalar(dl.x), btScalar(dl.y), btScalar(dl.z)));
    return dot(transformPoint(w, Vec3{v.x(), v.y(), v.z()}), d);
  };
  for (ShapeType tb : kConvexTypes) {
    const bool curved = tb == ShapeType::Ellipsoid || tb == ShapeType::Cylinder || tb == ShapeType::Cone;
    double pWorst = 0, pGap = 0;
    for (int it = 0; it < 60; ++it) {
      Pair A = randomShape(ShapeType::ConvexHull, rng, pts, rng.uni(0.02, 0.15));
      Pair B = randomShape(tb, rng, pts, tb == ShapeType::ConvexHull ? rng.uni(0, 0.1) : 0.0);
      const bool swap = it % 2 == 1;
      const Quat qa = rng.rot(), qb = rng.rot();
      const Vec3 u = rng.dir(), c0{rng.uni(-1, 1), rng.uni(-1, 1), rng.uni(-1, 1)};
      auto at = [&](double t) { return pose(c0 + u * t, qb); };
      const Pose pa = pose(c0, qa);
      const double touch = touchingOffset(A, pa, B, c0, u, qb, pts);
      const double size = std::min(A.s.size, B.s.size);
      const Pose pb = at(touch + rng.uni(-0.08, 0.08) * size);
      const BtResult ref = bulletDistance(A.bt.get(), pa, B.bt.get(), pb);
      REQUIRE(ref.ok);
      const double env = 0.1 * size;
      if (ref.dist > 0.8 * env) continue;
      ContactPoint c[kMaxContactsPerPair];
      const int m = swap ? collideShapes(B.s, pb, A.s, pa, pts.data(), env, c)
                         : collideShapes(A.s, pa, B.s, pb, pts.data(), env, c);
      if (swap) np::flipContacts(c, m);
      INFO("hull-" << shapeTypeName(tb) << " sample " << it << " bullet dist " << ref.dist);
      REQUIRE(m >= 1);
      checkConsistent(c, m, env);
      const ContactPoint& k = c[deepest(c, m)];
      const double e = std::fabs(k.dist - ref.dist);
      INFO("ours " << k.dist);
      CHECK(e < (curved ? 7e-3 : 1e-4));
      // the deepest point: pa on A's swept surface along n, pb on B's along -n (Bullet's supports, float)
      const double ga = std::fabs(dot(k.pa, k.normal) - btSupport(A.bt.get(), pa, k.normal));
      const double gb = std::fabs(dot(k.pb, -k.normal) - btSupport(B.bt.get(), pb, -k.normal));
      CHECK(ga < 1e-5);
      CHECK(gb < 1e-5);
      pWorst = std::max(pWorst, e);
      pGap = std::max({pGap, ga, gb});
      ++compared;
    }
    std::printf("  margin hull-%-10s |ours-bullet| %.1e  support-plane gap %.1e\n", shapeTypeName(tb), pWorst, pGap);
    worst = std::max(worst, pWorst), worstGap = std::max(worstGap, pGap);
  }
  std::printf("  margin hulls, %d samples: |ours-bullet| %.1e  support-plane gap %.1e\n", compared, worst, worstGap);
  CHECK(compared > 7 * 60 / 2);
}

TEST_CASE("shapeAabb contains the support points at any rotation, and is tight", "[narrowphase]") {
  Rng rng(11);
  std::vector<Vec3> pts;
  for (ShapeType t : kConvexTypes) {
    for (int it = 0; it < 30; ++it) {
      Pair p = randomShape(t, rng, pts);
      Pose w = pose(Vec3{rng.uni(-5, 5), rng.uni(-5, 5), rng.uni(-5, 5)}, rng.rot());
      double env = rng.uni(0, 0.1);
      Aabb bb = shapeAabb(p.s, w, pts.data(), env);
      auto sup = [&](Vec3 d) { return transformPoint(w, supportLocal(p.s, rotateInv(w.q, d), pts.data())); };
      for (int k = 0; k < 100; ++k) {
        Vec3 x = sup(rng.dir());
        CHECK(x.x >= bb.lo.x + env - 1e-9);
        CHECK(x.y >= bb.lo.y + env - 1e-9);
        CHECK(x.z >= bb.lo.z + env - 1e-9);
        CHECK(x.x <= bb.hi.x - env + 1e-9);
        CHECK(x.y <= bb.hi.y - env + 1e-9);
        CHECK(x.z <= bb.hi.z - env + 1e-9);
      }
      // tight: each face of the box touches the shape grown by env
      CHECK(sup(Vec3{1, 0, 0}).x + env == Approx(bb.hi.x).margin(1e-9));
      CHECK(sup(Vec3{0, 1, 0}).y + env == Approx(bb.hi.y).margin(1e-9));
      CHECK(sup(Vec3{0, 0, 1}).z + env == Approx(bb.hi.z).margin(1e-9));
      CHECK(sup(Vec3{-1, 0, 0}).x - env == Approx(bb.lo.x).margin(1e-9));
      CHECK(sup(Vec3{0, -1, 0}).y - env == Approx(bb.lo.y).margin(1e-9));
      CHECK(sup(Vec3{0, 0, -1}).z - env == Approx(bb.lo.z).margin(1e-9));
    }
  }
  Aabb pb = shapeAabb(plane(Vec3{0, 1, 0}, 0), pose(Vec3{0, 0, 0}), nullptr, 0.1);
  CHECK(pb.lo.x <= -1e29);
  CHECK(pb.hi.y >= 1e29);
}

TEST_CASE("every pair: deep overlap and coincident centres give finite contacts, far apart gives none",
          "[narrowphase]") {
  Rng rng(12);
  std::vector<Vec3> pts;
  pts.reserve(10000);
  ContactPoint c[kMaxContactsPerPair];
  for (ShapeType ta : kConvexTypes)
    for (ShapeType tb : kConvexTypes) {
      for (int it = 0; it < 10; ++it) {
        Pair A = randomShape(ta, rng, pts), B = randomShape(tb, rng, pts);
        Pose pa = pose(Vec3{0.3, 0.2, 0.1}, rng.rot());
        Pose pb = pose(pa.p + (it == 0 ? Vec3{0, 0, 0} : rng.dir() * rng.uni(0, 0.2)), rng.rot());
        int m = collideShapes(A.s, pa, B.s, pb, pts.data(), 0.01, c);
        INFO(shapeTypeName(ta) << "-" << shapeTypeName(tb));
        REQUIRE(m >= 1);
        REQUIRE(m <= kMaxContactsPerPair);
        for (int i = 0; i < m; ++i) {
          CHECK(isFinite(c[i].normal));
          CHECK(isFinite(c[i].pa));
          CHECK(c[i].dist < 0);
        }
        pb.p = pa.p + rng.dir() * (boundingRadius(A.s, pts.data()) + boundingRadius(B.s, pts.data()) + 0.02);
        CHECK(collideShapes(A.s, pa, B.s, pb, pts.data(), 0.01, c) == 0);
      }
    }
}

// Regression (off-surface MPR points in the mixed pile): for every MPR pair, random penetrating poses down to
// 50 % of the smaller size. The reported pa must lie on A's surface: on A's support plane along n (within a
// small tolerance), and inside A (checked through the support function: dot(pa, d) <= h_A(d) for many
// directions d, which for a convex A is containment; this also bounds pa by A's bounding sphere); pb likewise
// on B with -n. dot(pb - pa, n) == dist, and the depth is h(n) for the reported normal and close to the
// brute-force minimum penetration (MPR may settle on a face of the Minkowski difference that is not the
// nearest: bounded at 2 % of the smaller size for these deep poses, and never deeper than the true minimum
// over directions by construction).
TEST_CASE("MPR pairs: contact points lie on both surfaces (deep penetrations included)", "[narrowphase]") {
  const int kSamples = 150;
  std::vector<Vec3> pts;
  pts.reserve(200000);
  Rng rng(21);
  Vec3 dirs[256];
  for (int i = 0; i < 256; ++i) {
    double z = 1 - 2 * (i + 0.5) / 256, r = std::sqrt(1 - z * z), ph = i * kPi * (3 - std::sqrt(5.0));
    dirs[i] = Vec3{r * std::cos(ph), r * std::sin(ph), z};
  }
  auto h = [&](const Shape& s, const Pose& w, Vec3 d) {
    return dot(transformPoint(w, supportLocal(s, rotateInv(w.q, d), pts.data())), d);
  };
  // Largest violation of dot(p, d) <= h(d) over the sample directions and the given one.
  auto outside = [&](const Shape& s, const Pose& w, Vec3 p, Vec3 extra) {
    double worst = dot(p, extra) - h(s, w, extra);
    for (const Vec3& d : dirs) worst = std::max(worst, dot(p, d) - h(s, w, d));
    return worst;
  };
  double worstPlane = 0, worstOut = 0, worstDepth = 0;
  int checked = 0;
  for (int ia = 0; ia < 7; ++ia)
    for (int ib = ia; ib < 7; ++ib) {
      ShapeType ta = kConvexTypes[ia], tb = kConvexTypes[ib];
      bool closedForm = ta == ShapeType::Sphere && (tb == ShapeType::Sphere || tb == ShapeType::Box ||
                                                    tb == ShapeType::Cylinder || tb == ShapeType::Capsule);
      closedForm = closedForm || (ta == tb && (ta == ShapeType::Box || ta == ShapeType::Capsule));
      if (closedForm) continue;
      std::string name = std::string(shapeTypeName(ta)) + "-" + shapeTypeName(tb);
      double pPlane = 0, pOut = 0, pDepth = 0;
      for (int it = 0; it < kSamples; ++it) {
        Pair A = randomShape(ta, rng, pts), B = randomShape(tb, rng, pts);
        // flat faces meeting face to face are the hard case for the tangential placement: every 3rd sample
        // shares the orientation
        Quat qa = rng.rot(), qb = it % 3 == 0 ? qa : rng.rot();
        Vec3 u = it % 3 == 0 ? rotate(qa, Vec3{0, 1, 0}) : rng.dir();
        Vec3 c0{rng.uni(-1, 1), rng.uni(-1, 1), rng.uni(-1, 1)};
        Pose pa = pose(c0, qa);
        auto at = [&](double t) { return pose(c0 + u * t, qb); };
        const double touch = touchingOffset(A, pa, B, c0, u, qb, pts);
        double size = std::min(A.s.size, B.s.size);
        Pose pb = at(touch - rng.uni(0.0, 0.5) * size);
        double env = 0.1 * size;
        ContactPoint c[kMaxContactsPerPair];
        bool swap = it % 2 == 1;
        int m = swap ? collideShapes(B.s, pb, A.s, pa, pts.data(), env, c)
                     : collideShapes(A.s, pa, B.s, pb, pts.data(), env, c);
        if (swap) np::flipContacts(c, m);
        INFO(name << " sample " << it << " swap " << swap);
        REQUIRE(m >= 1);  // the first point is MPR's; flat features add up to 4 (mprManifold, tested apart)
        checkConsistent(c, m, env);
        const ContactPoint& k = c[0];
        Vec3 n = k.normal;
        // on the support planes
        double ga = std::fabs(dot(k.pa, n) - h(A.s, pa, n)), gb = std::fabs(dot(k.pb, -n) - h(B.s, pb, -n));
        double oa = outside(A.s, pa, k.pa, n), ob = outside(B.s, pb, k.pb, -n);
        INFO("plane gaps " << ga << " " << gb << " outside " << oa << " " << ob << " dist " << k.dist);
        CHECK(ga < 1e-9 * (1 + size));
        CHECK(gb < 1e-9 * (1 + size));
        CHECK(oa < 1e-7);
        CHECK(ob < 1e-7);
        CHECK(length(k.pa - transformPoint(pa, Vec3{0, 0, 0})) <= boundingRadius(A.s, pts.data()) + 1e-7);
        CHECK(length(k.pb - transformPoint(pb, Vec3{0, 0, 0})) <= boundingRadius(B.s, pts.data()) + 1e-7);
        // depth: h(n) for the reported normal, and near the brute-force minimum
        double hn = h(A.s, pa, n) + h(B.s, pb, -n);
        CHECK(k.dist == Approx(-hn).margin(1e-9));
        Vec3 hints[1] = {n}, nor;
        double orc = oracleSignedDistance(A.s, pa, B.s, pb, pts.data(), hints, 1, &nor);
        INFO("ours " << k.dist << " oracle " << orc << " size " << size);
        CHECK(orc - k.dist > -1e-9);
        CHECK(orc - k.dist < 0.02 * size);
        pPlane = std::max({pPlane, ga, gb});
        pOut = std::max({pOut, oa, ob});
        pDepth = std::max(pDepth, (orc - k.dist) / size);
        ++checked;
      }
      std::printf("  deep %-24s plane gap %.1e  outside %.1e  (oracle-ours)/size %.1e\n", name.c_str(), pPlane, pOut,
                  pDepth);
      worstPlane = std::max(worstPlane, pPlane), worstOut = std::max(worstOut, pOut);
      worstDepth = std::max(worstDepth, pDepth);
    }
  std::printf("  deep, all MPR pairs, %d samples: plane gap %.1e  outside %.1e  (oracle-ours)/size %.1e\n", checked,
              worstPlane, worstOut, worstDepth);
}

// CPU and GPU builds round dot products differently (FMA contraction, order): where support points tie on a
// flat feature the choice must follow a fixed rule within a tolerance, not the sign of a rounding error.
TEST_CASE("support ties on flat features are broken deterministically", "[narrowphase]") {
  const double e = 1e-17;
  Shape B = box(0.5, 0.25, 0.3);
  CHECK(length(supportLocal(B, Vec3{e, 1, -e}, nullptr) - supportLocal(B, Vec3{-e, 1, e}, nullptr)) == 0);
  CHECK(length(supportLocal(B, Vec3{e, 1, -e}, nullptr) - Vec3{0.5, 0.25, 0.3}) == 0);  // + side on a tie
  Shape C = cylinder(0.3, 0.5);
  CHECK(length(supportLocal(C, Vec3{e, -1, -e}, nullptr) - Vec3{0, -0.5, 0}) == 0);  // cap centre
  CHECK(length(supportLocal(C, Vec3{-e, -1, e}, nullptr) - Vec3{0, -0.5, 0}) == 0);
  Shape K = cone(0.3, 0.8);
  CHECK(length(supportLocal(K, Vec3{e, -1, e}, nullptr) - Vec3{0, -0.4, 0}) == 0);  // base centre
  // hull: a square face of four points (and one below); any direction within rounding of the face normal
  // gives the lowest index of the face
  std::vector<Vec3> pts = {{0, -1, 0}, {1, 1, 1}, {-1, 1, 1}, {-1, 1, -1}, {1, 1, -1}};
  Shape H = hull(0, 5);
  for (int k = 0; k < 8; ++k) {
    Vec3 d{(k & 1) ? e : -e, 1 + ((k & 4) ? 1e-16 : 0), (k & 2) ? e : -e};
    CHECK(length(supportLocal(H, d, pts.data()) - pts[1]) == 0);
  }
  // MPR contacts of flat faces: a cylinder standing on a box and a hull resting on it, poses perturbed by
  // rounding-sized amounts, give the same contact points (within 1e-12), and they lie under the cylinder.
  ContactPoint c0[kMaxContactsPerPair], c1[kMaxContactsPerPair];
  Shape slab = box(1, 0.1, 1);
  for (int k = 0; k < 2; ++k) {
    Pose pc0 = pose(Vec3{0.2, 0.1 + 0.5 - 0.01, -0.1}), pc1 = pc0;
    pc1.p.x += 1e-16;
    pc1.q = quatFromAxisAngle(Vec3{1, 0, -1}, 1e-16);
    const Shape& S = k == 0 ? C : H;
    if (k == 1) pc0.p.y = pc1.p.y = 0.1 + 1 - 0.01;
    int m0 = collideShapes(slab, pose(Vec3{0, 0, 0}), S, pc0, pts.data(), 0.02, c0);
    int m1 = collideShapes(slab, pose(Vec3{0, 0, 0}), S, pc1, pts.data(), 0.02, c1);
    // the cylinder's cap on the slab: MPR's point and the face overlap's extremes (mprManifold); the hull rests
    // on its apex (pts[0]): one point
    if (k == 0)
      REQUIRE(m0 >= 4);
    else
      REQUIRE(m0 == 1);
    // without the manifold (CollisionSettings::mpr_manifold = false) MPR's point alone, the same as the first
    ContactPoint c2[kMaxContactsPerPair];
    REQUIRE(collideShapes(slab, pose(Vec3{0, 0, 0}), S, pc0, pts.data(), 0.02, c2, nullptr, false) == 1);
    CHECK(length(c2[0].pa - c0[0].pa) == 0);
    REQUIRE(m1 == m0);
    for (int i = 0; i < m0; ++i) {
      INFO("point " << i);
      CHECK(c0[i].feature == c1[i].feature);
      CHECK(c0[i].dist == Approx(-0.01).margin(1e-9));
      CHECK(angleDeg(c0[i].normal, Vec3{0, 1, 0}) < 1e-6);
      CHECK(length(c0[i].pa - c1[i].pa) < 1e-12);
      CHECK(length(c0[i].pb - c1[i].pb) < 1e-12);
      CHECK(c0[i].pa.y == Approx(0.1).margin(1e-12));                                         // on the slab's top face
      if (k == 0) CHECK(length(Vec3{c0[i].pa.x - 0.2, 0, c0[i].pa.z + 0.1}) <= 0.3 + 1e-12);  // under the cylinder
    }
  }
}

// The GPU narrow phase leaves deep MPR pairs to a second kernel (collideShapes with `defer`, then the rounds of
// mpr.h a lane per restart). On the CPU the same split, finished by finishDeferredMpr, must give exactly the
// contacts of the one-call path, in both argument orders, and every deferred pair must be a deep MPR pair.
TEST_CASE("deferred deep MPR pairs finish to exactly the one-call contacts", "[narrowphase]") {
  std::vector<Vec3> pts;
  pts.reserve(100000);
  Rng rng(77);
  int deferred = 0, total = 0;
  for (int ia = 0; ia < 7; ++ia)
    for (int ib = 0; ib < 7; ++ib) {
      const ShapeType ta = kConvexTypes[ia], tb = kConvexTypes[ib];
      for (int it = 0; it < 40; ++it) {
        Pair A = randomShape(ta, rng, pts), B = randomShape(tb, rng, pts);
        const Pose wa = pose(Vec3{0, 0, 0}, rng.rot());
        // centres 0.1 to 0.9 of the summed extents apart: from deep to touching
        const Pose wb = pose(rng.dir() * (rng.uni(0.1, 0.9) * (A.s.dims.x + B.s.dims.x)), rng.rot());
        const real env = real(0.05) * std::min(A.s.size, B.s.size);
        ContactPoint direct[kMaxContactsPerPair], split[kMaxContactsPerPair];
        const int n = collideShapes(A.s, wa, B.s, wb, pts.data(), env, direct);
        np::MprDeferred d;
        int m = collideShapes(A.s, wa, B.s, wb, pts.data(), env, split, &d);
        ++total;
        if (m == np::kMprDeferred) {
          ++deferred;
          CHECK(pairUsesMpr(ta, tb));
          CHECK(d.round.n >= 1);
          CHECK(d.round.n <= np::kMprRoundTries);
          CHECK(d.swapped == (int(ta) > int(tb) ? 1 : 0));
          m = finishDeferredMpr(A.s, wa, B.s, wb, pts.data(), env, d, split);
        }
        REQUIRE(m == n);
        auto same = [](Vec3 a, Vec3 b) { return a.x == b.x && a.y == b.y && a.z == b.z; };
        for (int k = 0; k < n; ++k) {
          CHECK(same(split[k].normal, direct[k].normal));
          CHECK(same(split[k].pa, direct[k].pa));
          CHECK(same(split[k].pb, direct[k].pb));
          CHECK(split[k].dist == direct[k].dist);
          CHECK(split[k].feature == direct[k].feature);
        }
      }
    }
  INFO(deferred << " of " << total << " pairs deferred");
  CHECK(deferred > total / 10);  // the split is exercised, not just the shallow path
}

// The pair envelope from relative motion (narrowphase.h: pairEnvelope) against the sum of the two sweeps it
// replaced, for random pairs of every convex type with a large common velocity (a falling block, grains riding a
// drum) plus random relative linear and angular velocities:
//  - every point that the speculative rule keeps among those found with the sum of the sweeps lies within the
//    relative envelope: the bound (a point of B moves relative to a point of A at most |v_b - v_a| + |w_a| L_a +
//    |w_b| L_b, rigid-body kinematics) holds, so the smaller envelope drops no point the rule keeps;
//  - the pair's nearest point within the relative envelope is found with it as with the larger one, at a distance
//    as good or better (MPR's distance is a lower bound of the true one);
//  - the relative envelope is never larger, and for most of these pairs under half the sum.
TEST_CASE("speculative contacts: the relative-motion envelope keeps every point the sum of sweeps keeps",
          "[narrowphase][speculative]") {
  Rng rng(31);
  std::vector<Vec3> pts;
  pts.reserve(20000);
  const real h = real(1) / 60;
  int kept = 0, smaller = 0, pairs = 0, nearest = 0;
  for (ShapeType ta : kConvexTypes)
    for (ShapeType tb : kConvexTypes)
      for (int it = 0; it < 40; ++it) {
        Pair A = randomShape(ta, rng, pts), B = randomShape(tb, rng, pts);
        const Pose pa = pose(Vec3{0.3, 0.2, 0.1}, rng.rot());
        const real reach = boundingRadius(A.s, pts.data()) + boundingRadius(B.s, pts.data());
        const Pose pb = pose(pa.p + rng.dir() * (reach * rng.uni(0.6, 1.1)), rng.rot());
        const Vec3 common = rng.dir() * rng.uni(0, 20);  // up to 20 m/s, shared
        const PairMotion m{pa.p, common + rng.dir() * rng.uni(0, 2), rng.dir() * rng.uni(0, 10),
                           pb.p, common + rng.dir() * rng.uni(0, 2), rng.dir() * rng.uni(0, 10)};
        const real sa = shapeSweep(A.s, pts.data(), m.va, m.wa, h), sb = shapeSweep(B.s, pts.data(), m.vb, m.wb, h);
        const real plain = plainEnvelope(A.s, B.s, real(0.05));
        const real e_sum = std::fmax(plain, sa + sb), e_rel = pairEnvelope(A.s, B.s, real(0.05), sa, sb, h, m);
        INFO(shapeTypeName(ta) << "-" << shapeTypeName(tb) << " #" << it << ": envelopes " << e_sum << ", " << e_rel);
        REQUIRE(e_rel <= e_sum);
        REQUIRE(e_rel >= plain);
        smaller += e_rel < real(0.5) * e_sum;
        ++pairs;
        ContactPoint c_sum[kMaxContactsPerPair], c_rel[kMaxContactsPerPair];
        const int n_sum = collideShapes(A.s, pa, B.s, pb, pts.data(), e_sum, c_sum);
        const int n_rel = collideShapes(A.s, pa, B.s, pb, pts.data(), e_rel, c_rel);
        const real size = std::fmin(A.s.size, B.s.size);
        if (n_sum > 0 && c_sum[0].dist < e_rel - real(0.02) * size) {
          // MPR's distance along its normal n, -h_A(n) - h_B(-n), is a lower bound of the true signed distance
          // (the separation along any one direction), closer to the truth the better n is. With the smaller
          // envelope it came out up to 10% of the size larger (better) for these pairs, never smaller beyond
          // MPR's accuracy.
          const real tol = c_sum[0].dist >= 0 ? real(1e-4) * size : real(0.01) * size;
          INFO("nearest point " << c_sum[0].dist << ", " << n_rel << " found with the relative envelope");
          REQUIRE(n_rel > 0);
          CHECK(c_rel[0].dist >= c_sum[0].dist - tol);
          ++nearest;
        }
        ContactPoint k_sum[kMaxContactsPerPair];
        std::copy(c_sum, c_sum + n_sum, k_sum);
        const int nk = keepSpeculativePoints(k_sum, n_sum, plain, h, m);
        for (int i = 0; i < nk; ++i) {
          INFO("kept point " << i << " of " << nk << ": dist " << k_sum[i].dist);
          CHECK(k_sum[i].dist < e_rel);
        }
        kept += nk;
      }
  INFO(pairs << " pairs, " << kept << " points kept, " << nearest << " nearest points compared, " << smaller
             << " pairs with a relative envelope under half the sum");
  CHECK(kept > pairs / 4);  // the poses make contacts, so the bound is tested
  CHECK(nearest > pairs / 4);
  CHECK(smaller > pairs / 2);  // and the common velocity makes the relative envelope the smaller one
}

// The triangle's fast paths (collide_triangle.h) against a brute-force oracle, for random convex shapes of every
// type near random triangles: the signed distance D = max over unit n of (min over the shape of n.x - max over the
// triangle of n.x) by oracleSignedDistance (a lower bound of D, hinted with the face and edge normals):
//  - wherever np::faceAxisIsBest holds, no sampled axis separates more than the face axis (its bound holds);
//  - a pair rejected outright (no contact) is at least the envelope apart;
//  - the deepest contact reported agrees with the oracle's D: MPR's and the face's distances are lower bounds of D,
//    at most 2% of the size below it; the oracle, a lower bound too, can stop short of D by up to ~2% of the
//    size beside an edge, where the separation has a ridge.
TEST_CASE("convex shape against a triangle: the face and edge fast paths agree with a brute-force oracle",
          "[narrowphase][triangle]") {
  Rng rng(47);
  std::vector<Vec3> pts;
  pts.reserve(20000);
  const real envelope = 0.01;
  int fast = 0, rejected = 0, contacts = 0;
  for (ShapeType ta : kConvexTypes)
    for (int it = 0; it < 60; ++it) {
      Pair A = randomShape(ta, rng, pts);
      ShapeDesc tri;
      const Vec3 a{rng.uni(-1.5, -0.5), 0, rng.uni(-1, 0)}, b{rng.uni(0.5, 1.5), rng.uni(-0.1, 0.1), rng.uni(-1, 0)},
          c{rng.uni(-0.5, 0.5), rng.uni(-0.1, 0.1), rng.uni(0.5, 1.5)};
      REQUIRE(makeTriangle(a, b, c, Pose{Vec3{0, 0, 0}, quatIdentity()}, tri));
      const Pose wb = tri.shape.local;
      const Vec3 v[3] = {a, b, c};
      const Vec3 nw = rotate(wb.q, Vec3{0, 1, 0});
      // the shape over the triangle (or beside it), from 0.3 size below the face to 0.3 above its lowest point
      const Quat q = rng.rot();
      const Vec3 foot{rng.uni(-1.2, 1.2), 0, rng.uni(-1.2, 1.2)};
      const real lowest = -dot(rotate(q, supportLocal(A.s, rotateInv(q, Vec3{0, -1, 0}), pts.data())), Vec3{0, 1, 0});
      const Pose wa = pose(foot + nw * (lowest + A.s.size * rng.uni(-0.3, 0.3)), q);
      // the oracle (oracleSignedDistance above), hinted with the face normal and the edges' outward normals
      Vec3 hints[5] = {nw, -nw};
      for (int i = 0; i < 3; ++i) hints[2 + i] = cross(v[(i + 1) % 3] - v[i], nw);
      Vec3 nbest;
      const real D = real(oracleSignedDistance(A.s, wa, tri.shape, wb, pts.data(), hints, 5, &nbest));
      INFO(shapeTypeName(ta) << " #" << it << ": oracle distance " << D);
      // the face axis as collideConvexTriangle takes it
      const Vec3 ca = wa.p + rotate(wa.q, np::interiorPointLocal(A.s, pts.data()));
      const Vec3 nf = dot(ca - v[0], nw) < 0 ? -nw : nw;
      const Vec3 low = transformPoint(wa, supportLocal(A.s, rotateInv(wa.q, -nf), pts.data()));
      const real face_dist = dot(low - v[0], nf);
      if (np::faceAxisIsBest(low, face_dist, ca, dot(ca - v[0], nf), v, nw)) {
        ++fast;
        CHECK(D <= face_dist + real(1e-7));  // to rounding
      }
      ContactPoint out[kMaxContactsPerPair];
      const int n = collideShapes(A.s, wa, tri.shape, wb, pts.data(), envelope, out);
      if (n == 0) {
        ++rejected;
        CHECK(D > envelope - real(2e-4) * A.s.size);
        continue;
      }
      ++contacts;
      real deepest = out[0].dist;
      for (int k = 1; k < n; ++k) deepest = std::fmin(deepest, out[k].dist);
      CHECK(deepest <= D + real(0.02) * A.s.size);
      CHECK(deepest >= D - real(0.02) * A.s.size);
    }
  INFO(fast << " pairs on the fast face path, " << rejected << " without contact, " << contacts << " with");
  CHECK(fast > 50);
  CHECK(rejected > 50);
  CHECK(contacts > 100);
}

// The box-triangle separating axes (np::boxTriangleSeparation with the face axis) against the brute-force signed
// distance D. For two convex polytopes these axes are complete: when they overlap, the largest separation over
// them is D itself (minus the penetration depth); when they are apart, one of them separates (a positive value, a
// lower bound of the distance, which the closest features of two corners can exceed). The oracle is a lower bound
// of D (sampled directions and a pattern search, short by up to ~2% of the size beside a ridge).
TEST_CASE("box against a triangle: the separating axes give the signed distance", "[narrowphase][triangle]") {
  Rng rng(91);
  std::vector<Vec3> pts;
  int overlapping = 0, apart = 0;
  for (int it = 0; it < 300; ++it) {
    Pair A = randomShape(ShapeType::Box, rng, pts);
    ShapeDesc tri;
    const Vec3 a{rng.uni(-1.5, -0.5), 0, rng.uni(-1, 0)}, b{rng.uni(0.5, 1.5), rng.uni(-0.3, 0.3), rng.uni(-1, 0)},
        c{rng.uni(-0.5, 0.5), rng.uni(-0.3, 0.3), rng.uni(0.5, 1.5)};
    REQUIRE(makeTriangle(a, b, c, Pose{Vec3{0, 0, 0}, quatIdentity()}, tri));
    const Vec3 v[3] = {a, b, c};
    const Vec3 nw = rotate(tri.shape.local.q, Vec3{0, 1, 0});
    const Pose wa = pose(Vec3{rng.uni(-1.6, 1.6), rng.uni(-0.6, 0.6) * A.s.size * 3, rng.uni(-1.6, 1.6)}, rng.rot());
    Vec3 hints[5] = {nw, -nw};
    for (int i = 0; i < 3; ++i) hints[2 + i] = cross(v[(i + 1) % 3] - v[i], nw);
    Vec3 nbest;
    const double D = oracleSignedDistance(A.s, wa, tri.shape, tri.shape.local, pts.data(), hints, 5, &nbest);
    const Vec3 nf = dot(wa.p - v[0], nw) < 0 ? -nw : nw;
    const Vec3 low = transformPoint(wa, supportLocal(A.s, rotateInv(wa.q, -nf), pts.data()));
    const double sat = std::max(double(dot(low - v[0], nf)), double(np::boxTriangleSeparation(A.s, wa, v)));
    INFO("#" << it << ": oracle " << D << ", axes " << sat << ", size " << A.s.size);
    const double rounding = 1e-7 * A.s.size;
    if (D < -rounding) {
      ++overlapping;
      CHECK(sat >= D - rounding);
      CHECK(sat <= D + 0.02 * A.s.size);
    } else if (D > rounding) {
      ++apart;
      CHECK(sat > 0);
      CHECK(sat <= D + 0.02 * A.s.size);
    }
  }
  CHECK(overlapping > 50);
  CHECK(apart > 50);
}
