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
// + e * d/|d|); B' = B. The depth of the true shapes along n is then h(n) - e and the signed distance is
// e - h(n). Spheres and capsules are evaluated as point/segment cores plus their radius (exact, and smooth
// for MPR), a convex hull with a margin as its points' hull plus the margin (the sphere-swept hull, as Bullet's
// btConvexInternalShape::localGetSupportingVertex; support.h: sweptTerm). Portal vertices keep the support points
// of the true A and B (envelope excluded).
//
// Contact points (mprContactPoints): pa is taken on A's support face along n and pb on B's along -n, each the
// point of that face nearest a contact-region point (the portal witness), so both lie on their surfaces and
// dot(pb - pa, n) = e - h(n) exactly. (Averaging the two portal witnesses and offsetting them by +-dist/2 along
// n, or taking the raw supports along a box face normal, put points up to a bounding radius off the shapes.)
//
// Accuracy: plain MPR reports the boundary point where the ray from the centres leaves M, whose normal need
// not be the minimum-translation direction. We therefore re-run the portal search up to kMprPasses - 1 more
// times with the interior point placed just behind the origin along the last normal (v0 = -tau n), so the ray
// points along n; at the fixed point the ray meets M's boundary where its normal is n, which is the minimum
// penetration direction. Every pass is evaluated exactly through h(n) = dot(s_M(n), n), an upper bound of the
// true penetration for any n (signed distance = max over unit n of -h(n)), and the pass with the smallest
// h(n) is kept, so an extra pass can only improve the answer.
#pragma once

#include "chrono_like/base/math.h"
#include "chrono_like/base/shape.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/collision/gjk.h"
#include "chrono_like/collision/support.h"

namespace dvi {
namespace np {

constexpr int kMprMaxIterations = 64;  // per phase, per pass
// Tuning knobs (compile-time): passes of the normal refinement, and the interior point's distance behind
// the origin in units of the current depth estimate.
#ifndef DVI_MPR_PASSES
#define DVI_MPR_PASSES 3
#endif
#ifndef DVI_MPR_DEEP
#define DVI_MPR_DEEP 0.02
#endif
// A deep pair whose first pass ends within this cosine of last step's normal of the pair keeps that fixed point
// (mprBeginOverlap: temporal coherence). ~2.6 degrees.
#ifndef DVI_MPR_COHERENT_COS
#define DVI_MPR_COHERENT_COS 0.999
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
  real sweep;   // the shape's own sweep radius (sphere, capsule, a hull's margin) added to the core support
  real env;     // the envelope sweep (A only): A' = A + ball(env)
#ifndef __CUDA_ARCH__
  NarrowWork* work = nullptr;  // host only (never copied to the device): the supports counted, where set
#endif
};

// Counts n supports of kind `field` where the host's work counter is set (A's); nothing on the device.
#ifndef __CUDA_ARCH__
#define DVI_NARROW_WORK(shape, field, n)          \
  do {                                            \
    if ((shape).work) (shape).work->field += (n); \
  } while (0)
#else
#define DVI_NARROW_WORK(shape, field, n) \
  do {                                   \
  } while (0)
#endif

DVI_HD MprShape makeMprShape(const Shape& s, const Pose& w, const Vec3* hull_points, real extra_sweep) {
  MprShape m;
  m.s = &s;
  m.R = matFromQuat(w.q);
  m.p = w.p;
  m.center = w.p + m.R * interiorPointLocal(s, hull_points);
  m.sweep = sweepRadius(s);
  m.env = extra_sweep;
  return m;
}

// Support point of the true shape (its own sweep included, the envelope not); l = |d|.
DVI_HD Vec3 mprSupportL(const MprShape& m, Vec3 d, real l, const Vec3* hull_points) {
  Vec3 c = m.p + m.R * supportCoreLocal(*m.s, mulTransposed(m.R, d), hull_points);
  if (m.sweep > real(0) && l > real(0)) c += d * (m.sweep / l);
  return c;
}
DVI_HD Vec3 mprSupport(const MprShape& m, Vec3 d, const Vec3* hull_points) {
  return mprSupportL(m, d, m.sweep > real(0) ? length(d) : real(0), hull_points);
}

// Support value of the true shape along d.
DVI_HD real mprSupportValue(const MprShape& m, Vec3 d, const Vec3* hull_points) {
  return dot(mprSupport(m, d, hull_points), d);
}

// The point of the true shape's support face along d nearest to the world point t (see supportNearLocal),
// moved onto the exact support plane (a shift within the tie tolerance).
DVI_HD Vec3 mprSurfacePoint(const MprShape& m, Vec3 d, Vec3 t, const Vec3* hull_points) {
  Vec3 dl = mulTransposed(m.R, d);
  Vec3 x = m.p + m.R * supportNearLocal(*m.s, dl, mulTransposed(m.R, t - m.p), hull_points);
  return x + d * (mprSupportValue(m, d, hull_points) - dot(x, d));
}

struct MprVert {
  Vec3 v, a, b;  // v = a' - b with a' = a + env d/|d|; a on the true A, b on B
};

DVI_HD_CALL void mprSupportM(const MprShape& A, const MprShape& B, Vec3 d, const Vec3* hull_points, MprVert& o) {
  const real l = length(d);  // |d| = |-d|: one square root for both sweeps and the envelope
  DVI_NARROW_WORK(A, mpr, 1);
  o.a = mprSupportL(A, d, l, hull_points);
  o.b = mprSupportL(B, -d, l, hull_points);
  o.v = o.a - o.b;
  if (A.env > real(0) && l > real(0)) o.v += d * (A.env / l);
}

struct MprResult {
  Vec3 n;      // unit, from A to B
  real depth;  // h(n) = penetration of A' and B' along n
};

// Support point of the core (the shape without its own sweep).
DVI_HD Vec3 mprCoreSupport(const MprShape& m, Vec3 d, const Vec3* hull_points) {
  return m.p + m.R * supportCoreLocal(*m.s, mulTransposed(m.R, d), hull_points);
}

// The pair through its cores' closest points (gjk.h), before MPR: kGjkApart (no contact: the swept shapes are
// apart by more than the envelope), kGjkClose (best is the exact normal, from A to B, and depth of A' and B'), or
// kGjkOverlap (the cores overlap: MPR's case).
DVI_HD_CALL int mprCoresApart(const MprShape& A, const MprShape& B, const Vec3* hull_points, MprResult& best) {
  const real reach = A.sweep + B.sweep + A.env;  // swept shapes within the envelope: cores closer than this
  auto support = [&](Vec3 d, Vec3& a, Vec3& b) {
    DVI_NARROW_WORK(A, gjk, 1);
    a = mprCoreSupport(A, d, hull_points);
    b = mprCoreSupport(B, -d, hull_points);
  };
  real dist = 0;
  Vec3 pa, pb;
  const int g = gjkDistance(support, A.center - B.center, reach, dist, pa, pb);
  if (g != kGjkClose) return g;
  best.n = (pb - pa) / dist;
  best.depth = reach - dist;
  return best.depth > real(0) ? kGjkClose : kGjkApart;
}

// One MPR pass with interior point v0 of M. Returns false when the origin is found outside M.
DVI_HD_CALL bool mprPass(const MprShape& A, const MprShape& B, Vec3 v0, const Vec3* hull_points, MprResult& res) {
#ifndef DVI_MPR_REL_TOL
#define DVI_MPR_REL_TOL 1e-7
#endif
  const real rel_tol = sizeof(real) == 8 ? real(DVI_MPR_REL_TOL) : real(1e-5);
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
      return true;
    }
    Vec3 w = cross(v0, V4.v);
    real c1 = dot(V1.v, w), c2 = dot(V2.v, w), c3 = dot(V3.v, w);
    if (c1 >= real(0)) {
      if (c3 <= real(0))
        V2 = V4;  // (v1, v4, v3)
      else
        V1 = V4;  // (v4, v2, v3)
    } else {
      if (c2 >= real(0))
        V3 = V4;  // (v1, v2, v4)
      else
        V1 = V4;
    }
  }
  // Degenerate portal: report what we have if the origin is inside.
  if (!hit) return false;
  Vec3 pn = normalized(cross(V2.v - V1.v, V3.v - V1.v));
  mprSupportM(A, B, pn, hull_points, V4);
  res.n = pn;
  res.depth = dot(V4.v, pn);
  return true;
}

// Re-runs the portal search with the ray along the current normal (see the header comment) until h(n) stops
// decreasing or kMprPasses passes are done.
DVI_HD_CALL void mprRefine(const MprShape& A, const MprShape& B, const Vec3* hull_points, MprResult& best) {
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

// Contact points of the final normal n: pa on A's support face along n and pb on B's along -n, so both lie on
// their shape's surface and dot(pb - pa, n) = -h_A(n) - h_B(-n), the signed distance of the true shapes along
// n. Where a support face is flat (box face, cap, base, hull face) the point is placed by alternating
// projections between the two faces, started from the midpoint of the shapes' interior points: it lands in
// (or near) the overlap of the two faces seen along n. The start and every projection depend continuously on
// the poses, never on the MPR portal (whose final triangle can change with the rounding of its branch tests),
// so CPU and GPU builds agree.
DVI_HD_CALL void mprContactPoints(const MprShape& A, const MprShape& B, Vec3 n, const Vec3* hull_points, Vec3& pa,
                                  Vec3& pb) {
  Vec3 t = (A.center + B.center) * real(0.5);
  pa = mprSurfacePoint(A, n, t, hull_points);
  pb = mprSurfacePoint(B, -n, pa, hull_points);
  pa = mprSurfacePoint(A, n, pb, hull_points);
  pb = mprSurfacePoint(B, -n, pa, hull_points);
}

// The deep stage of collideMpr runs its restarts in rounds: every restart of a round starts from the same
// depth estimate (the interior point v0 = -tau depth d) and the results are taken in index order (the first
// strictly shallower one wins), so a round's restarts are independent. The CPU runs them one after the other;
// the GPU narrow phase runs deep pairs apart, one lane per restart (gpu_collision.cu), with the same result.
constexpr int kMprRoundTries = 4;
struct MprRound {
  int n = 0;
  Vec3 dir[kMprRoundTries];
};

// One restart of a round (mprTryDirection with a fixed depth estimate); depth +inf when the pass fails.
DVI_HD_CALL MprResult mprRestart(const MprShape& A, const MprShape& B, const Vec3* hull_points, Vec3 d, real depth0) {
  MprResult r;
  if (!mprPass(A, B, d * (real(-DVI_MPR_TAU) * depth0), hull_points, r)) {
    r.n = d;
    r.depth = real(INFINITY);
    return r;
  }
  mprRefine(A, B, hull_points, r);
  return r;
}

// Takes r when it is shallower (the combine of a round, in index order).
DVI_HD void mprKeepShallower(MprResult& best, const MprResult& r) {
  if (r.depth < best.depth) best = r;
}

// Runs a round sequentially.
DVI_HD void mprRunRound(const MprShape& A, const MprShape& B, const Vec3* hull_points, const MprRound& round,
                        MprResult& best) {
  const real depth0 = best.depth;
  MprResult s = best;
  for (int i = 0; i < round.n; ++i) mprKeepShallower(s, mprRestart(A, B, hull_points, round.dir[i], depth0));
  best = s;
}

// The second round: deep hull penetrations (faces of M unknown, many local fixed points) restart from the
// current normal tilted by ~35 degrees toward four tangent directions. False when none is needed.
DVI_HD bool mprTiltRound(const MprShape& A, const Shape& a, const Shape& b, const MprResult& best, MprRound& round) {
  round.n = 0;
  if (!((a.type == ShapeType::ConvexHull || b.type == ShapeType::ConvexHull) &&
        best.depth - A.env > real(0.1) * std::fmin(a.size, b.size)))
    return false;
  Vec3 u, w;
  tangentBasis(best.n, u, w);
  for (int k = 0; k < 4; ++k) {
    const Vec3 t = (k & 1) ? w : u;
    round.dir[round.n++] = normalized(best.n + t * real((k & 2) ? -0.7 : 0.7));
  }
  return true;
}

// Temporal coherence: a deep pair whose fixed point lies on the face its last step's contact was on (the normals
// within DVI_MPR_COHERENT_COS) keeps it. Last step's normal was either a shallow fixed point or the winner of the
// candidates below, and a pair that moves onto another face of M moves MPR's fixed point with it, which breaks the
// agreement. A resting deep pair (a thin flake pressed in by more than 2% of its thickness) thus costs one pass.
DVI_HD bool mprKeepsLastFace(const MprShape& A, const MprResult& best, const PairHistory* history) {
  Vec3 last_n;
  if (!history || !lastPairNormal(*history, last_n) || !(dot(last_n, best.n) > real(DVI_MPR_COHERENT_COS)))
    return false;
#ifndef __CUDA_ARCH__
  if (A.work) ++A.work->coherent;
#else
  (void)A;
#endif
  return true;
}

// The first stage of collideMpr (mprBegin below) for overlapping cores: the first pass and its refinement and, for a
// deep pair, the global candidates. Returns 0 (no contact), 1 (best is final) or 2 (deep: run `round`, then
// mprTiltRound's, then mprFinish).
//
// MPR's fixed points are faces of M whose plane holds the origin's projection, not necessarily the nearest
// one, least of all for deep penetrations. Global candidates guard against the wrong face (see the block
// below): known face normals, side normals, axis cross products, the centre line and, for hulls, the frame
// axes are evaluated exactly by h(n) and MPR is restarted from the best; deep hull pairs also restart from
// the normal tilted four ways.
// mprBegin's MPR, for overlapping cores.
DVI_HD_CALL int mprBeginOverlap(const MprShape& A, const MprShape& B, const Shape& a, const Shape& b,
                                const Vec3* hull_points, MprResult& best, MprRound& round,
                                const PairHistory* history = nullptr) {
  round.n = 0;
  Vec3 v0 = A.center - B.center;
  if (length2(v0) < real(1e-30)) v0 = Vec3{real(1e-10) * (real(1) + boundingRadius(a, hull_points)), 0, 0};
  if (!mprPass(A, B, v0, hull_points, best)) return 0;
  mprRefine(A, B, hull_points, best);
  // Shallow contacts (penetration of the true shapes below DVI_MPR_DEEP x the smaller size) keep MPR's fixed
  // point: it is the nearest face of M there, and the candidate restarts below cost ~10x the first pass.
  const bool deep = best.depth - A.env > real(DVI_MPR_DEEP) * std::fmin(a.size, b.size);
  if (!deep || mprKeepsLastFace(A, best, history)) return 1;
  Vec3 cand[40];
  int nc = 0, nface = 0;
  Vec3 ax[2][3];
  int nax[2] = {0, 0};
  const MprShape* sh[2] = {&A, &B};
  for (int k = 0; k < 2; ++k) {
    ShapeType t = sh[k]->s->type;
    if (t == ShapeType::Box) {
      for (int j = 0; j < 3; ++j) ax[k][nax[k]++] = cand[nc++] = column(sh[k]->R, j);
    } else if (t == ShapeType::Cylinder || t == ShapeType::Cone) {
      ax[k][nax[k]++] = cand[nc++] = column(sh[k]->R, 1);
    } else if (t == ShapeType::Capsule) {
      ax[k][nax[k]++] = column(sh[k]->R, 1);
    }
  }
  nface = nc;
  for (int k = 0; k < 2; ++k) {  // side normals toward the other shape's centre
    ShapeType t = sh[k]->s->type;
    if (t != ShapeType::Cylinder && t != ShapeType::Cone && t != ShapeType::Capsule) continue;
    Vec3 y = column(sh[k]->R, 1);
    Vec3 w = sh[1 - k]->center - sh[k]->center;
    w -= y * dot(w, y);
    real lw = length(w);
    if (!(lw > real(0))) continue;
    w = w / lw;
    cand[nc++] = w;
    if (t == ShapeType::Cone) {  // generator normal: (2 hh, R) in (radial, axis) coordinates
      real R = sh[k]->s->dims.x, H = sh[k]->s->dims.y;
      cand[nc++] = normalized(w * H + y * R);
    }
  }
  for (int i = 0; i < nax[0]; ++i)
    for (int j = 0; j < nax[1]; ++j) {
      Vec3 c = cross(ax[0][i], ax[1][j]);
      real lc = length(c);
      if (lc > real(1e-6)) cand[nc++] = c / lc;
    }
  {
    Vec3 cc = B.center - A.center;
    real lc = length(cc);
    if (lc > real(0)) cand[nc++] = cc / lc;
  }
  if (a.type == ShapeType::ConvexHull || b.type == ShapeType::ConvexHull)
    for (int k = 0; k < 2; ++k)
      for (int j = 0; j < 3; ++j) cand[nc++] = column(sh[k]->R, j);
  constexpr int kTop = 4;
  real bh = best.depth, th[kTop];
  Vec3 bn{0, 0, 0}, td[kTop];
  for (int i = 0; i < kTop; ++i) {
    th[i] = real(1e30);
    td[i] = Vec3{0, 0, 0};
  }
  for (int i = 0; i < nc; ++i) {
    for (int sgn = -1; sgn <= 1; sgn += 2) {
      Vec3 n = cand[i] * real(sgn);
      MprVert V;
      mprSupportM(A, B, n, hull_points, V);
      real h = dot(V.v, n);
      if (i < nface && h < bh) {
        bh = h;
        bn = n;
      }
      if (h < th[kTop - 1]) {  // insert into the sorted list of the kTop smallest
        int j = kTop - 1;
        for (; j > 0 && h < th[j - 1]; --j) {
          th[j] = th[j - 1];
          td[j] = td[j - 1];
        }
        th[j] = h;
        td[j] = n;
      }
    }
  }
  if (bh < best.depth * (real(1) - real(1e-9)) && bh > real(0)) {
    MprResult r = best;
    mprTryDirection(A, B, hull_points, bn, r);
    if (r.depth <= bh * (real(1) + real(1e-9))) {
      best = r;
    } else {  // keep the face normal
      best.n = bn;
      best.depth = bh;
    }
  }
  const int ntry = (a.type == ShapeType::ConvexHull || b.type == ShapeType::ConvexHull) ? kTop : 2;
  for (int i = 0; i < ntry; ++i)
    if (th[i] > real(0) && th[i] < real(1e30)) round.dir[round.n++] = td[i];
  return 2;
}

// Whether a pair of these shape types tries GJK on its cores before MPR (GjkUse, gjk.h).
DVI_HD bool polytopeCore(ShapeType t) {
  return t == ShapeType::Sphere || t == ShapeType::Capsule || t == ShapeType::Box || t == ShapeType::ConvexHull ||
         t == ShapeType::Triangle;
}
DVI_HD bool gjkTries(GjkUse use, ShapeType a, ShapeType b) {
  if (use == GjkUse::Off) return false;
  if (use == GjkUse::Polytopes) return polytopeCore(a) && polytopeCore(b);
  if (use == GjkUse::NoCylinders)
    return a != ShapeType::Cylinder && a != ShapeType::Cone && b != ShapeType::Cylinder && b != ShapeType::Cone;
  return true;  // All (and an unresolved Auto)
}

// The first stage of a pair: with the cores apart (resting shapes with a margin, speculative contacts) their closest
// points answer exactly (mprCoresApart); overlapping cores go through MPR (mprBeginOverlap). Returns as above.
DVI_HD_CALL int mprBegin(const MprShape& A, const MprShape& B, const Shape& a, const Shape& b, const Vec3* hull_points,
                         MprResult& best, MprRound& round, GjkUse gjk = GjkUse::All,
                         const PairHistory* history = nullptr) {
  const int g = gjkTries(gjk, a.type, b.type) ? mprCoresApart(A, B, hull_points, best) : int(kGjkOverlap);
  if (g == kGjkOverlap) return mprBeginOverlap(A, B, a, b, hull_points, best, round, history);
  round.n = 0;
  return g == kGjkClose ? 1 : 0;
}

// ---- the manifold of two flat features ----
// MPR gives one point per pair. Two flat faces resting on each other (cylinder caps, hull faces, a box face on a
// cap) then carry the load on that one point, the upper body tips about it, and the next step's point is on the
// other side: a stack of five 1 cm cylinders standing on their caps sank 10 mm (their whole height) in 0.25 s.
// mprManifold adds, to the first point out[0] (normal n, from A to B), points of the overlap of the two
// features, as the clipping of the support polygons in box-box and Bullet's manifolds do:
//  - each feature is sampled by the supports along n tilted by kManifoldTilt towards 8 tangent directions e_k
//    (A along +n, B along -n): the extreme points of a flat face along e_k (a polygon's vertices, a disc's rim),
//    or points within ~tilt x radius of the contact on a curved surface;
//  - the pair has a manifold only when both samples spread over more than kManifoldFlat x the shape's size and
//    as far at a tenth of the tilt (faces, or edges and cylinder sides lying on faces: a line); a curved
//    surface's samples draw in with the tilt, so spheres and ellipsoids keep their one point;
//  - a sample of A inside B's sampled polygon (seen along n) is a contact with its image on B's support plane,
//    and one of B inside A's with its image on A's; both polygons are inscribed in the true features, so the
//    points lie in the true overlap (its edge crossings are left out, which can only shrink the support);
//  - of those within the envelope, the extreme one along each of t1, t2, -t1, -t2 is kept, with feature
//    1 + that index (persistent keys for the warm start): at most 5 points with the first.
// The distance of a point is taken to the other feature's support plane: exact for flat features, a lower bound
// of the gap otherwise (the speculative contact then acts slightly early, never late).
constexpr int kManifoldDirs = 8;
constexpr real kManifoldFlat = real(0.5);
// cos and sin of the tilt (0.05 rad) and of k x 45 degrees as literals: the same bits on every compiler.
constexpr real kManifoldCosTilt = real(0.99875026039496628), kManifoldSinTilt = real(0.04997916927067833);
constexpr real kManifoldCosSmall = real(0.9999875000260416), kManifoldSinSmall = real(0.004999979166692708);
constexpr real kSqrtHalf = real(0.70710678118654752);

DVI_HD bool insideConvexPolygon(const real (*poly)[2], int n, real qx, real qy, real eps) {
  for (int k = 0; k < n; ++k) {
    const real* a = poly[k];
    const real* b = poly[(k + 1) % n];
    if ((b[0] - a[0]) * (qy - a[1]) - (b[1] - a[1]) * (qx - a[0]) < -eps) return false;
  }
  return true;
}

// The samples p[k] of one shape's feature along d0 (A's along +n, B's along -n): its supports along d0 tilted by
// kManifoldTilt towards t1 cos + t2 sin of k x 45 degrees, and their spread (largest distance of opposite ones).
// False when the feature is not flat: the spread is below kManifoldFlat x size, or draws in at a tenth of the
// tilt. Spheres and ellipsoids are curved everywhere: false without sampling.
DVI_HD bool manifoldSamples(const MprShape& S, Vec3 d0, Vec3 t1, Vec3 t2, const Vec3* hull_points, Vec3* p,
                            real& spread) {
  if (S.s->type == ShapeType::Sphere || S.s->type == ShapeType::Ellipsoid) return false;
  const real ck[kManifoldDirs] = {1, kSqrtHalf, 0, -kSqrtHalf, -1, -kSqrtHalf, 0, kSqrtHalf};
  const real sk[kManifoldDirs] = {0, kSqrtHalf, 1, kSqrtHalf, 0, -kSqrtHalf, -1, -kSqrtHalf};
  DVI_NARROW_WORK(S, manifold, kManifoldDirs);
  for (int k = 0; k < kManifoldDirs; ++k)
    p[k] = mprSupport(S, d0 * kManifoldCosTilt + (t1 * ck[k] + t2 * sk[k]) * kManifoldSinTilt, hull_points);
  spread = 0;
  for (int k = 0; k < kManifoldDirs / 2; ++k) spread = fmax(spread, length(p[k] - p[k + kManifoldDirs / 2]));
  if (!(spread > kManifoldFlat * S.s->size)) return false;
  real small = 0;
  DVI_NARROW_WORK(S, manifold, kManifoldDirs / 2);
  for (int k = 0; k < kManifoldDirs / 2; k += 2) {
    const Vec3 dc = d0 * kManifoldCosSmall, es = (t1 * ck[k] + t2 * sk[k]) * kManifoldSinSmall;
    small = fmax(small, length(mprSupport(S, dc + es, hull_points) - mprSupport(S, dc - es, hull_points)));
  }
  return small > real(0.5) * spread;
}

DVI_HD_CALL int mprManifold(const MprShape& A, const MprShape& B, const Vec3* hull_points, real envelope,
                            ContactPoint* out) {
  const Vec3 n = out[0].normal;
  Vec3 t1, t2;
  tangentBasis(n, t1, t2);
  Vec3 a3[kManifoldDirs], b3[kManifoldDirs];
  real spread_a = 0, spread_b = 0;
  if (!manifoldSamples(A, n, t1, t2, hull_points, a3, spread_a)) return 1;
  if (!manifoldSamples(B, -n, t1, t2, hull_points, b3, spread_b)) return 1;
  const Vec3 o = out[0].pa;
  real pa2[kManifoldDirs][2], pb2[kManifoldDirs][2];
  for (int k = 0; k < kManifoldDirs; ++k) {
    pa2[k][0] = dot(a3[k] - o, t1), pa2[k][1] = dot(a3[k] - o, t2);
    pb2[k][0] = dot(b3[k] - o, t1), pb2[k][1] = dot(b3[k] - o, t2);
  }
  const real scale = fmax(spread_a, spread_b);
  const real eps = real(1e-9) * scale * scale;                // cross products of zero-length (repeated) polygon edges
  const real ha = dot(out[0].pa, n), hb = dot(out[0].pb, n);  // A's and B's support planes along n
  // candidates inside the other polygon and within the envelope; the extreme along each axis direction. Samples
  // of a regular polygon or disc tie along an axis (45 and 135 degrees): within `tie` the first sample stays, so
  // the choice, and with it the point's feature key, does not hang on the normal's last bits (MPR's and the
  // cores' closest points give the same normal to rounding, not bit for bit).
  const real tie = real(1e-9) * scale;
  const real ax[4][2] = {{1, 0}, {0, 1}, {-1, 0}, {0, -1}};
  int best[4] = {-1, -1, -1, -1};
  real best_v[4] = {0, 0, 0, 0};
  for (int c = 0; c < 2 * kManifoldDirs; ++c) {
    const bool from_a = c < kManifoldDirs;
    const int k = from_a ? c : c - kManifoldDirs;
    const real* q = from_a ? pa2[k] : pb2[k];
    if (!insideConvexPolygon(from_a ? pb2 : pa2, kManifoldDirs, q[0], q[1], eps)) continue;
    const real dist = from_a ? hb - dot(a3[k], n) : dot(b3[k], n) - ha;
    if (!(dist < envelope)) continue;
    for (int j = 0; j < 4; ++j) {
      const real v = q[0] * ax[j][0] + q[1] * ax[j][1];
      if (best[j] < 0 || v > best_v[j] + tie) best[j] = c, best_v[j] = v;
    }
  }
  int m = 1;
  const real min_sep = real(0.05) * fmin(A.s->size, B.s->size);
  for (int j = 0; j < 4; ++j) {
    const int c = best[j];
    if (c < 0) continue;
    const bool from_a = c < kManifoldDirs;
    const int k = from_a ? c : c - kManifoldDirs;
    Vec3 pa, pb;
    if (from_a) {
      pa = a3[k];
      pb = pa + n * (hb - dot(pa, n));
    } else {
      pb = b3[k];
      pa = pb - n * (dot(pb, n) - ha);
    }
    bool dup = false;  // the same point as one kept (tangentially), e.g. a corner extreme along two axes
    for (int i = 0; i < m && !dup; ++i) {
      const Vec3 d = pa - out[i].pa;
      const real d1 = dot(d, t1), d2 = dot(d, t2);
      dup = d1 * d1 + d2 * d2 < min_sep * min_sep;
    }
    if (dup) continue;
    setContact(out[m], n, pa, pb, dot(pb - pa, n), 1 + j);
    ++m;
  }
  return m;
}

// The last stage: contact points along the final normal: the first one, and with `manifold` those of two flat
// features (mprManifold). The first point carries kMprFirst in pad_ (narrowphase_impl.h: the GPU's write pass
// computes a pair's other points again from it).
constexpr int32_t kMprFirst = 1;
DVI_HD_CALL int mprFinish(const MprShape& A, const MprShape& B, const Vec3* hull_points, const MprResult& best,
                          real envelope, ContactPoint* out, bool manifold = true) {
  if (!(best.depth > real(0))) return 0;
  Vec3 pa, pb;
  mprContactPoints(A, B, best.n, hull_points, pa, pb);
  real dist = dot(pb - pa, best.n);
  if (!(dist < envelope)) return 0;
  setContact(out[0], best.n, pa, pb, dist, 0);
  if (!manifold) return 1;
  out[0].pad_ = kMprFirst;
  return mprManifold(A, B, hull_points, envelope, out);
}

// The deep stage in one thread (the GPU's deferred pairs run a round's restarts on separate lanes instead): the
// global candidates' round, then the tilted one where mprTiltRound asks for it.
DVI_HD_CALL void mprDeepRounds(const MprShape& A, const MprShape& B, const Shape& a, const Shape& b,
                               const Vec3* hull_points, MprRound& round, MprResult& best) {
  mprRunRound(A, B, hull_points, round, best);
  if (mprTiltRound(A, a, b, best, round)) mprRunRound(A, B, hull_points, round, best);
}

// A deep pair left for later (collideMpr with `defer`): the state after mprBegin. `swapped`: the pair's shapes
// were collided in the opposite order (collideShapes' canonical order), so the contacts get flipped.
struct MprDeferred {
  MprResult best;
  MprRound round;
  int32_t swapped;
};
constexpr int kMprDeferred = -1;  // collideShapes' answer for a pair left in *defer

// Contact of two convex shapes through MPR (see the header comment). Writes one point, and with `manifold` up to
// four more of two flat features (mprManifold). With `defer`,
// a deep pair is not finished: its state goes to *defer and the answer is kMprDeferred.
DVI_HD_CALL int collideMpr(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, const Vec3* hull_points,
                           real envelope, ContactPoint* out, MprDeferred* defer = nullptr, bool manifold = true,
                           GjkUse gjk = GjkUse::All, NarrowWork* work = nullptr, const PairHistory* history = nullptr) {
  MprShape A = makeMprShape(a, wa, hull_points, envelope);
  MprShape B = makeMprShape(b, wb, hull_points, real(0));
#ifndef __CUDA_ARCH__
  A.work = B.work = work;
#else
  (void)work;
#endif
  MprResult best;
  MprRound round;
  const int stage = mprBegin(A, B, a, b, hull_points, best, round, gjk, history);
  if (stage == 0) return 0;
  if (stage == 2) {
    if (defer) {
      defer->best = best;
      defer->round = round;
      return kMprDeferred;
    }
    mprDeepRounds(A, B, a, b, hull_points, round, best);
  }
  return mprFinish(A, B, hull_points, best, envelope, out, manifold);
}

}  // namespace np
}  // namespace dvi
