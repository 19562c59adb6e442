// Closest points of two convex cores by GJK, host and device.
//
// References: E. G. Gilbert, D. W. Johnson, S. S. Keerthi, "A fast procedure for computing the distance between
// complex objects in three-dimensional space", IEEE J. Robotics and Automation 4 (1988) 193-203; the termination
// test and the use of swept cores as in G. van den Bergen, "Collision Detection in Interactive 3D Environments"
// (2004), sec. 4.3; the closest point of a triangle by its Voronoi regions as in C. Ericson, "Real-Time Collision
// Detection" (2005), sec. 5.1.5.
//
// The narrow phase's shapes are cores swept by a ball (support.h: a hull's points by its margin, a sphere's centre
// by its radius, a capsule's segment; a box, cylinder or cone has radius 0), and MPR grows A by the envelope too.
// While the cores are apart, the swept shapes' nearest features are those of the cores, moved out along the line
// between them: the cores' closest points give the pair's exact normal and signed distance (dist - rA - rB). That
// is the resting contact of shapes with a margin (Bullet's GJK on margins works the same way) and every speculative
// contact within the envelope; MPR is left the overlapping cores. GJK on polytope cores (boxes, hulls, triangles)
// ends in a few supports with the exact closest features; on curved ones (cylinder rims, ellipsoids) it converges
// to kGjkRelTol or gives up after kGjkMaxIterations and leaves the pair to MPR.
#pragma once

#include "chrono_like/base/math.h"

namespace dvi {

// Which pairs of the MPR path try GJK on their cores first (CollisionSettings::gjk; narrowphase.h gjkTries):
//  - All: every pair (the CPU backend's default: on the drop-in's hulls and terrain it cut the whole step by ~30%);
//  - Polytopes: only pairs whose two cores are polytopes (a sphere's point, a capsule's segment, a box, a hull,
//    a triangle), where GJK ends in a few supports; pairs with a curved core (ellipsoid, cylinder, cone) go
//    straight to MPR, since GJK converges on them slowly, and when they overlap it pays its supports for nothing;
//  - NoCylinders: every pair but those with a cylinder or cone core: those cores have no sweep, so resting contacts
//    touch or overlap them, GJK rarely settles the pair and MPR runs after it anyway (the work-count test: GJK adds
//    10-20 supports to such a pair and saves none), while a sphere or ellipsoid pair with a gap is settled by GJK
//    at a tenth of MPR's supports;
//  - Off: MPR alone. Auto is resolved by the backend (docs/GPU_PERFORMANCE.md gives the measurements).
enum class GjkUse : uint8_t { Auto = 0, All, Polytopes, NoCylinders, Off };

// Support-mapping counts of the narrow phase's iterative algorithms on the host (the GPU build leaves them out):
// what the CI work-count test bounds (tests/test_narrow_work.cpp), per pair or per class of pairs.
struct NarrowWork {
  int64_t gjk = 0;       // supports of GJK (each one of A and one of B)
  int64_t mpr = 0;       // supports of M = A' - B' in MPR's passes
  int64_t manifold = 0;  // supports of the flat-feature manifold's samples (mprManifold)
  int64_t coherent = 0;  // deep pairs that kept their fixed point by last step's normal (mprBeginOverlap)
  int64_t total() const { return gjk + mpr + manifold; }
};

namespace np {

constexpr int kGjkMaxIterations = 64;
// Convergence: the gap between the upper bound |v| and the lower bound v.w / |v| of the distance, relative to |v|.
constexpr real kGjkRelTol = sizeof(real) == 8 ? real(1e-8) : real(1e-5);

struct GjkVert {
  Vec3 w, a, b;  // w = a - b: a on core A, b on core B
};

// The simplex (1 to 4 vertices) and the barycentric weights of its point nearest the origin.
struct GjkSimplex {
  GjkVert p[4];
  real l[4];
  int n = 0;
};

// Reduces s to the feature of segment (p[0], p[1]) nearest the origin, with its weights.
DVI_HD void gjkSegment(GjkSimplex& s) {
  const Vec3 a = s.p[0].w, e = s.p[1].w - a;
  const real ee = length2(e);
  const real t = ee > real(0) ? -dot(a, e) / ee : real(0);
  if (!(t > real(0))) {  // vertex a
    s.n = 1;
    s.l[0] = 1;
  } else if (t >= real(1)) {  // vertex b
    s.p[0] = s.p[1];
    s.n = 1;
    s.l[0] = 1;
  } else {
    s.l[0] = real(1) - t;
    s.l[1] = t;
  }
}

// Reduces s to the feature of triangle (p[0], p[1], p[2]) nearest the origin (Ericson, 5.1.5, with p = 0).
DVI_HD void gjkTriangle(GjkSimplex& s) {
  const GjkVert A = s.p[0], B = s.p[1], C = s.p[2];
  const Vec3 ab = B.w - A.w, ac = C.w - A.w, ap = -A.w;
  const real d1 = dot(ab, ap), d2 = dot(ac, ap);
  auto keep1 = [&](const GjkVert& v) {
    s.p[0] = v;
    s.n = 1;
    s.l[0] = 1;
  };
  auto keep2 = [&](const GjkVert& u, const GjkVert& v, real t) {
    s.p[0] = u;
    s.p[1] = v;
    s.n = 2;
    s.l[0] = real(1) - t;
    s.l[1] = t;
  };
  if (d1 <= real(0) && d2 <= real(0)) return keep1(A);
  const Vec3 bp = -B.w;
  const real d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= real(0) && d4 <= d3) return keep1(B);
  const real vc = d1 * d4 - d3 * d2;
  if (vc <= real(0) && d1 >= real(0) && d3 <= real(0)) return keep2(A, B, d1 / (d1 - d3));
  const Vec3 cp = -C.w;
  const real d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= real(0) && d5 <= d6) return keep1(C);
  const real vb = d5 * d2 - d1 * d6;
  if (vb <= real(0) && d2 >= real(0) && d6 <= real(0)) return keep2(A, C, d2 / (d2 - d6));
  const real va = d3 * d6 - d5 * d4;
  if (va <= real(0) && (d4 - d3) >= real(0) && (d5 - d6) >= real(0))
    return keep2(B, C, (d4 - d3) / ((d4 - d3) + (d5 - d6)));
  const real sum = va + vb + vc;
  if (!(sum > real(0))) return keep1(A);  // a degenerate triangle outside every region test: its first vertex
  s.l[0] = va / sum;
  s.l[1] = vb / sum;
  s.l[2] = vc / sum;
}

DVI_HD Vec3 gjkPoint(const GjkSimplex& s) {
  Vec3 v{0, 0, 0};
  for (int i = 0; i < s.n; ++i) v += s.p[i].w * s.l[i];
  return v;
}

// Reduces s to the feature of tetrahedron p[0..3] nearest the origin: the nearest of the faces whose outer side
// holds the origin. False when the origin is inside (or the tetrahedron is flat): the cores overlap, or GJK stalls.
DVI_HD bool gjkTetrahedron(GjkSimplex& s) {
  const int face[4][4] = {{0, 1, 2, 3}, {0, 2, 3, 1}, {0, 3, 1, 2}, {1, 3, 2, 0}};  // three vertices, the opposite
  const Vec3 e1 = s.p[1].w - s.p[0].w, e2 = s.p[2].w - s.p[0].w, e3 = s.p[3].w - s.p[0].w;
  const real vol = dot(cross(e1, e2), e3);
  const real scale = length2(e1) + length2(e2) + length2(e3);
  if (!(std::fabs(vol) > real(1e-12) * scale * std::sqrt(scale))) return false;
  GjkSimplex best;
  real best_d2 = real(-1);
  for (int f = 0; f < 4; ++f) {
    const Vec3 a = s.p[face[f][0]].w, b = s.p[face[f][1]].w, c = s.p[face[f][2]].w, d = s.p[face[f][3]].w;
    const Vec3 nrm = cross(b - a, c - a);
    // origin and d on opposite sides of the face's plane: the origin is outside across this face
    if (!(dot(nrm, -a) * dot(nrm, d - a) < real(0))) continue;
    GjkSimplex t;
    t.p[0] = s.p[face[f][0]];
    t.p[1] = s.p[face[f][1]];
    t.p[2] = s.p[face[f][2]];
    t.n = 3;
    gjkTriangle(t);
    const real d2 = length2(gjkPoint(t));
    if (best_d2 < real(0) || d2 < best_d2) {
      best = t;
      best_d2 = d2;
    }
  }
  if (best_d2 < real(0)) return false;  // inside
  s = best;
  return true;
}

enum GjkAnswer { kGjkApart = 0, kGjkClose = 1, kGjkOverlap = 2 };

// Distance of two cores given by `support(d, a, b)` (a: core A's support along d, b: core B's along -d), from the
// start direction v0 = a point of A - B (the interior points' difference). kGjkApart: the cores are farther apart
// than `reach` (a lower bound proves it); kGjkClose: converged, with the distance `dist` > 0 and the closest points
// pa (on A) and pb (on B); kGjkOverlap: the cores overlap or touch, or GJK did not converge (left to MPR).
template <class Support>
DVI_HD int gjkDistance(const Support& support, Vec3 v0, real reach, real& dist, Vec3& pa, Vec3& pb) {
  GjkSimplex s;
  Vec3 v = v0;
  real scale2 = length2(v0);  // the largest |w|^2 seen: the size of A - B near the origin
  for (int it = 0; it < kGjkMaxIterations; ++it) {
    const real vv = length2(v);
    // the origin on the simplex, to rounding: the cores touch or overlap
    if (!(vv > real(1e-12) * scale2)) return kGjkOverlap;
    GjkVert w;
    support(-v, w.a, w.b);
    w.w = w.a - w.b;
    scale2 = fmax(scale2, length2(w.w));
    const real vw = dot(v, w.w);
    if (vw > real(0) && vw * vw > reach * reach * vv) return kGjkApart;  // lower bound vw / |v| beyond reach
    bool repeated = false;
    for (int i = 0; i < s.n; ++i) repeated = repeated || sameVec(s.p[i].w, w.w);
    if (s.n > 0 && (repeated || vv - vw <= kGjkRelTol * vv)) {  // converged on the simplex's feature
      pa = pb = Vec3{0, 0, 0};
      for (int i = 0; i < s.n; ++i) {
        pa += s.p[i].a * s.l[i];
        pb += s.p[i].b * s.l[i];
      }
      dist = length(pa - pb);
      return kGjkClose;
    }
    s.p[s.n++] = w;
    if (s.n == 1) {
      s.l[0] = 1;
    } else if (s.n == 2) {
      gjkSegment(s);
    } else if (s.n == 3) {
      gjkTriangle(s);
    } else if (!gjkTetrahedron(s)) {
      return kGjkOverlap;
    }
    v = gjkPoint(s);
  }
  return kGjkOverlap;
}

}  // namespace np
}  // namespace dvi
