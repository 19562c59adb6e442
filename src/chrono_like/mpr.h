// Minkowski Portal Refinement for any pair of convex support mappings, host and device.
//
// Reference: G. Snethen, "XenoCollide: Complex Collision Made Simple", Game Programming Gems 7 (2008).
// The configuration-space obstacle is M = A' - B' (support s_M(d) = s_A'(d) - s_B'(-d)); the origin lies in
// M exactly when A' and B' overlap. A ray is cast from an interior point v0 of M through the origin; phase 1
// finds a "portal" triangle (v1, v2, v3) of support points that the ray crosses, phase 2 refines the portal
// toward the boundary of M by replacing one vertex with the support point v4 along the portal normal,
// keeping the ray inside, until the portal no longer moves (dot(v4 - v1, n) <= tol).
//
// Conventions of this implementation (derived here, not taken from a code):
//  * A triangle (a, b, c) is oriented so that n = (b - a) x (c - a) points away from v0. The ray from v0
//    through the origin lies on the inner side of the directed edge a->b iff dot(a x b, v0) <= 0 (the triple
//    product [a - v0, b - v0, -v0] reduces to -[a, b, v0]).
//  * With n the unit portal normal, n points from A to B (M = A - B: the farthest extent of A along n minus the
//    nearest of B), and h(n) = dot(s_M(n), n) is the penetration of A' and B' along n.
//
// Envelope: MPR only answers for overlapping shapes. To get points for shapes that are apart but closer than
// the collision envelope e, A is swept by a sphere of radius e (A' = A + ball(e), i.e. its support gets
// + e * d/|d|); B' = B. The depth of the true shapes along n is then h(n) - e, the signed distance is
// e - h(n) and A's surface point is A'-point - e n. Spheres and capsules are evaluated as point/segment
// cores plus their radius, which is added to the same sweep term (exact, and smooth for MPR).
//
// Accuracy: plain MPR reports the boundary point where the ray from the centres leaves M, whose normal need
// not be the minimum-translation direction. We therefore re-run the portal search up to kMprPasses - 1 more
// times with the interior point placed just behind the origin along the last normal (v0 = -tau n), so the ray
// points along n; at the fixed point the ray meets M's boundary where its normal is n, which is the minimum
// penetration direction. Every pass is evaluated exactly through h(n) = dot(s_M(n), n), an upper bound of the
// true penetration for any n (signed distance = max over unit n of -h(n)), and the pass with the smallest
// h(n) is kept, so an extra pass can only improve the answer.
#pragma once

#include "contact.h"
#include "math.h"
#include "shape.h"
#include "support.h"

namespace dvi {
namespace np {

constexpr int kMprMaxIterations = 64;  // per phase, per pass
// Tuning knobs (compile-time): passes of the normal refinement, and the interior point's distance behind
// the origin in units of the current depth estimate.
#ifndef DVI_MPR_PASSES
#define DVI_MPR_PASSES 3
#endif
#ifndef DVI_MPR_TAU
#define DVI_MPR_TAU 0.25
#endif
constexpr int kMprPasses = DVI_MPR_PASSES;

struct MprShape {
  const Shape* s;
  Mat33 R;      // world rotation
  Vec3 p;       // world position of the shape frame
  Vec3 center;  // world interior point
  real sweep;   // sphere-swept radius added to the core support
};

DVI_HD MprShape makeMprShape(const Shape& s, const Pose& w, const Vec3* hull_points, real extra_sweep) {
  MprShape m;
  m.s = &s;
  m.R = matFromQuat(w.q);
  m.p = w.p;
  m.center = w.p + m.R * interiorPointLocal(s, hull_points);
  m.sweep = sweepRadius(s) + extra_sweep;
  return m;
}

DVI_HD Vec3 mprSupport(const MprShape& m, Vec3 d, const Vec3* hull_points) {
  Vec3 c = m.p + m.R * supportCoreLocal(*m.s, mulTransposed(m.R, d), hull_points);
  if (m.sweep > real(0)) {
    real l = length(d);
    if (l > real(0)) c += d * (m.sweep / l);
  }
  return c;
}

struct MprVert {
  Vec3 v, a, b;  // v = a - b
};

DVI_HD void mprSupportM(const MprShape& A, const MprShape& B, Vec3 d, const Vec3* hull_points, MprVert& o) {
  o.a = mprSupport(A, d, hull_points);
  o.b = mprSupport(B, -d, hull_points);
  o.v = o.a - o.b;
}

struct MprResult {
  Vec3 n;     // unit, from A to B
  Vec3 pa;    // on A' (swept) surface
  Vec3 pb;    // on B' surface
  real depth; // h(n) = penetration of A' and B' along n
};

// Witness points: the origin projected on the portal plane, in barycentric coordinates of the portal
// (clamped into the triangle), applied to the A and B support points of the portal vertices.
DVI_HD void mprWitness(const MprVert& V1, const MprVert& V2, const MprVert& V3, Vec3 n, Vec3& pa, Vec3& pb) {
  Vec3 p = n * dot(n, V1.v);
  Vec3 e1 = V2.v - V1.v, e2 = V3.v - V1.v, q = p - V1.v;
  real d00 = dot(e1, e1), d01 = dot(e1, e2), d11 = dot(e2, e2), d20 = dot(q, e1), d21 = dot(q, e2);
  real den = d00 * d11 - d01 * d01;
  real l1 = 1, l2 = 0, l3 = 0;
  if (den > real(1e-12) * d00 * d11) {
    l2 = (d11 * d20 - d01 * d21) / den;
    l3 = (d00 * d21 - d01 * d20) / den;
    l1 = real(1) - l2 - l3;
    l1 = std::fmax(l1, real(0));
    l2 = std::fmax(l2, real(0));
    l3 = std::fmax(l3, real(0));
    real s = l1 + l2 + l3;
    if (s > real(0)) {
      l1 /= s;
      l2 /= s;
      l3 /= s;
    } else {
      l1 = 1;
      l2 = l3 = 0;
    }
  }
  pa = V1.a * l1 + V2.a * l2 + V3.a * l3;
  pb = V1.b * l1 + V2.b * l2 + V3.b * l3;
}

// One MPR pass with interior point v0 of M. Returns false when the origin is found outside M.
DVI_HD bool mprPass(const MprShape& A, const MprShape& B, Vec3 v0, const Vec3* hull_points, MprResult& res) {
  const real rel_tol = sizeof(real) == 8 ? real(1e-9) : real(1e-5);
  MprVert V1, V2, V3, V4;
  // Phase 1: portal discovery.
  mprSupportM(A, B, -v0, hull_points, V1);
  if (dot(V1.v, -v0) <= real(0)) return false;  // plane through v1 normal to -v0 separates origin from M
  const real scale = length(v0) + length(V1.v);
  const real tol = rel_tol * scale;
  Vec3 n = cross(V1.v, v0);
  if (length2(n) <= real(1e-24) * length2(V1.v) * length2(v0)) {
    // v0, origin and v1 collinear: the ray leaves M at v1, along -v0.
    res.n = normalized(-v0);
    res.depth = dot(V1.v, res.n);
    res.pa = V1.a;
    res.pb = V1.b;
    return true;
  }
  mprSupportM(A, B, n, hull_points, V2);
  if (dot(V2.v, n) <= real(0)) return false;
  n = cross(V1.v - v0, V2.v - v0);  // points from plane (v0, v1, v2) toward the origin
  int it = 0;
  for (; it < kMprMaxIterations; ++it) {
    mprSupportM(A, B, n, hull_points, V3);
    if (dot(V3.v, n) <= real(0)) return false;
    if (dot(cross(V3.v, V1.v), v0) > real(0)) {  // ray outside edge v3->v1: portal (v1, v3, .)
      V2 = V3;
      n = cross(V1.v - v0, V2.v - v0);
      continue;
    }
    if (dot(cross(V2.v, V3.v), v0) > real(0)) {  // ray outside edge v2->v3: portal (v3, v2, .)
      V1 = V3;
      n = cross(V1.v - v0, V2.v - v0);
      continue;
    }
    break;
  }
  if (it == kMprMaxIterations) return false;  // no portal found (degenerate input)
  // Phase 2: portal refinement.
  bool hit = false;
  for (it = 0; it < kMprMaxIterations; ++it) {
    Vec3 pn = cross(V2.v - V1.v, V3.v - V1.v);
    real ln = length(pn);
    if (!(ln > real(0))) break;
    pn = pn / ln;
    if (!hit && dot(pn, V1.v) >= real(0)) hit = true;  // origin behind the portal: inside M
    mprSupportM(A, B, pn, hull_points, V4);
    real h4 = dot(V4.v, pn);
    if (h4 < real(0)) return false;  // separating plane
    if (h4 - dot(V1.v, pn) <= tol || it == kMprMaxIterations - 1) {
      if (!hit) return false;
      res.n = pn;
      res.depth = h4;
      mprWitness(V1, V2, V3, pn, res.pa, res.pb);
      return true;
    }
    Vec3 w = cross(v0, V4.v);
    real c1 = dot(V1.v, w), c2 = dot(V2.v, w), c3 = dot(V3.v, w);
    if (c1 >= real(0)) {
      if (c3 <= real(0)) V2 = V4;  // (v1, v4, v3)
      else V1 = V4;                // (v4, v2, v3)
    } else {
      if (c2 >= real(0)) V3 = V4;  // (v1, v2, v4)
      else V1 = V4;
    }
  }
  // Degenerate portal: report what we have if the origin is inside.
  if (!hit) return false;
  Vec3 pn = normalized(cross(V2.v - V1.v, V3.v - V1.v));
  mprSupportM(A, B, pn, hull_points, V4);
  res.n = pn;
  res.depth = dot(V4.v, pn);
  mprWitness(V1, V2, V3, pn, res.pa, res.pb);
  return true;
}

// Re-runs the portal search with the ray along the current normal (see the header comment) until h(n) stops
// decreasing or kMprPasses passes are done.
DVI_HD void mprRefine(const MprShape& A, const MprShape& B, const Vec3* hull_points, MprResult& best) {
  for (int pass = 1; pass < kMprPasses; ++pass) {
    if (!(best.depth > real(0))) break;
    MprResult r;
    if (!mprPass(A, B, best.n * (real(-DVI_MPR_TAU) * best.depth), hull_points, r)) break;
    if (!(r.depth < best.depth)) break;
    real gain = best.depth - r.depth;
    best = r;
    if (gain <= real(1e-12) * (real(1) + best.depth)) break;
  }
}

// Starts MPR with the ray along unit direction d (interior point just behind the origin, scaled by the
// current depth estimate) and refines; keeps the result if it is shallower than `best`.
DVI_HD void mprTryDirection(const MprShape& A, const MprShape& B, const Vec3* hull_points, Vec3 d, MprResult& best) {
  MprResult r;
  if (!mprPass(A, B, d * (real(-DVI_MPR_TAU) * best.depth), hull_points, r)) return;
  mprRefine(A, B, hull_points, r);
  if (r.depth < best.depth) best = r;
}

// Contact of two convex shapes through MPR (see the header comment). Writes at most one point.
//
// MPR's fixed points are faces of M whose plane holds the origin's projection, not necessarily the nearest
// one. Two cheap global steps guard against the wrong face: the known face normals of boxes, cylinder caps
// and cone bases are evaluated, and for convex hulls (whose faces are not stored) MPR is restarted along the
// two most promising of the 12 frame axes (+-x, +-y, +-z of both shapes).
DVI_HD int collideMpr(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, const Vec3* hull_points,
                      real envelope, ContactPoint* out) {
  MprShape A = makeMprShape(a, wa, hull_points, envelope);
  MprShape B = makeMprShape(b, wb, hull_points, real(0));
  Vec3 v0 = A.center - B.center;
  if (length2(v0) < real(1e-30)) v0 = Vec3{real(1e-10) * (real(1) + boundingRadius(a, hull_points)), 0, 0};
  MprResult best;
  if (!mprPass(A, B, v0, hull_points, best)) return 0;
  mprRefine(A, B, hull_points, best);
  {
    Vec3 cand[8];
    int nc = 0;
    const MprShape* sh[2] = {&A, &B};
    for (int k = 0; k < 2; ++k) {
      ShapeType t = sh[k]->s->type;
      if (t == ShapeType::Box) {
        cand[nc++] = column(sh[k]->R, 0);
        cand[nc++] = column(sh[k]->R, 1);
        cand[nc++] = column(sh[k]->R, 2);
      } else if (t == ShapeType::Cylinder || t == ShapeType::Cone) {
        cand[nc++] = column(sh[k]->R, 1);
      }
    }
    real bh = best.depth;
    Vec3 bn{0, 0, 0};
    for (int i = 0; i < nc; ++i) {
      for (int sgn = -1; sgn <= 1; sgn += 2) {
        Vec3 n = cand[i] * real(sgn);
        MprVert V;
        mprSupportM(A, B, n, hull_points, V);
        real h = dot(V.v, n);
        if (h < bh) {
          bh = h;
          bn = n;
        }
      }
    }
    if (bh < best.depth * (real(1) - real(1e-9)) && bh > real(0)) {
      MprResult r = best;
      mprTryDirection(A, B, hull_points, bn, r);
      if (r.depth <= bh * (real(1) + real(1e-9))) {
        best = r;
      } else {  // keep the face normal; points from the supports along it
        MprVert V;
        mprSupportM(A, B, bn, hull_points, V);
        best.n = bn;
        best.depth = bh;
        best.pa = V.a;
        best.pb = V.b;
      }
    }
  }
  if (a.type == ShapeType::ConvexHull || b.type == ShapeType::ConvexHull) {
    Vec3 d1{0, 0, 0}, d2{0, 0, 0};
    real h1 = real(1e30), h2 = real(1e30);
    for (int k = 0; k < 12; ++k) {
      const MprShape& S = k < 6 ? A : B;
      Vec3 d = column(S.R, (k % 6) / 2) * ((k & 1) ? real(-1) : real(1));
      MprVert V;
      mprSupportM(A, B, d, hull_points, V);
      real h = dot(V.v, d);
      if (h < h1) {
        h2 = h1;
        d2 = d1;
        h1 = h;
        d1 = d;
      } else if (h < h2) {
        h2 = h;
        d2 = d;
      }
    }
    if (h1 > real(0) && h1 < real(1e30)) mprTryDirection(A, B, hull_points, d1, best);
    if (h2 > real(0) && h2 < real(1e30)) mprTryDirection(A, B, hull_points, d2, best);
  }
  real dist = envelope - best.depth;
  if (!(dist < envelope)) return 0;
  Vec3 pa = best.pa - best.n * envelope;
  Vec3 mid = (pa + best.pb) * real(0.5);
  ContactPoint& c = out[0];
  c.normal = best.n;
  c.pa = mid - best.n * (real(0.5) * dist);
  c.pb = mid + best.n * (real(0.5) * dist);
  c.dist = dist;
  c.feature = 0;
  c.pad_ = 0;
  return 1;
}

}  // namespace np
}  // namespace dvi
