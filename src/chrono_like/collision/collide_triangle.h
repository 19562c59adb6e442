// Triangles: static environment geometry (Bullet's btBvhTriangleMeshShape, btHeightfieldTerrainShape), one
// Shape record per triangle, collided against any convex shape. Host and device code.
//
// Record layout (no hull points needed, so System::addBody stores it like any primitive): the shape frame has
// its origin at the triangle's centroid and its Y axis along the face normal (b - a) x (c - a); the vertices
// lie in the frame's XZ plane at
//   p0 = (dims.x, 0, dims.y),  p1 = (dims.z, 0, plane_d),  p2 = -(p0 + p1)
// (the centroid is the origin, so four numbers fix the triangle in its frame). Shape::size is the inradius.
//
// Triangles are two-sided, as in Bullet: the face normal used is the one on the side of the other shape's
// centre. Contacts (collideConvexTriangle):
//  1. Face axis: the depth of the convex shape below the triangle's plane along the face normal; when the
//     shape is farther than the envelope in front of the plane (or behind it beyond the back), no contact.
//  1b. Edge axes: the outward normals of the three edges in the triangle's plane reject a shape beside the
//     triangle (the neighbours' triangles under a body lying on a mesh) before MPR.
//  1c. A shape whose lowest point and centre lie over the triangle, far enough inside its edges, has the face
//     axis as its best axis (faceAxisIsBest, a bound on every other axis): the face contacts of 3., without MPR.
//  1d. A box: the rest of the pair's separating axes (the box's three face normals and the nine cross products of
//     its axes with the edges; boxTriangleSeparation) rule the pair out, or show the face axis best as 3. does,
//     without MPR.
//  2. MPR on the pair (the triangle's support mapping is its three vertices) gives the signed distance and
//     normal of the deepest feature pair; its contact point is computed only when 3. does not stand.
//  3. When the face axis is within a small tolerance of MPR's answer (the shape lies on the face), the
//     contacts are the convex shape's plane contacts against the triangle's plane (box corners, cylinder rim
//     points, hull vertices, ...) whose foot lies inside the triangle: several points per pair, so a box rests
//     flat on a mesh as it does on a plane. Otherwise (or when no foot lies inside), MPR's single point: an
//     edge or vertex contact.
#pragma once

#include "chrono_like/base/math.h"
#include "chrono_like/base/shape.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/collision/mpr.h"
#include "chrono_like/collision/support.h"

namespace dvi {
namespace np {

DVI_HD int collideConvexPlane(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, const Vec3* hull_points,
                              real envelope, ContactPoint* out);

// Vertex i (0, 1, 2) of a Triangle record, in the shape frame.
DVI_HD Vec3 triangleVertexLocal(const Shape& s, int i) {
  const Vec3 p0{s.dims.x, 0, s.dims.y}, p1{s.dims.z, 0, s.plane_d};
  return i == 0 ? p0 : (i == 1 ? p1 : -(p0 + p1));
}

// Barycentric test of point x (in the triangle's plane) against triangle (a, b, c) with unit normal n,
// allowing `tol` (a length) outside each edge.
DVI_HD bool insideTriangle(Vec3 x, Vec3 a, Vec3 b, Vec3 c, Vec3 n, real tol) {
  const Vec3 v[3] = {a, b, c};
  for (int i = 0; i < 3; ++i) {
    Vec3 e = v[(i + 1) % 3] - v[i];
    real le = length(e);
    if (!(le > real(0))) return false;
    // inward edge normal (n x e) / |e|: distance of x inside the edge
    if (dot(cross(n, e), x - v[i]) / le < -tol) return false;
  }
  return true;
}

// Nearest point of segment [a, b] to t.
DVI_HD Vec3 nearestOnSegment(Vec3 a, Vec3 b, Vec3 t) {
  Vec3 ab = b - a;
  real l2 = dot(ab, ab);
  if (!(l2 > real(0))) return a;
  return a + ab * clampr(dot(t - a, ab) / l2, 0, 1);
}

// Nearest point of triangle (a, b, c) to t (Ericson, Real-Time Collision Detection, 5.1.5).
DVI_HD Vec3 nearestOnTriangle(Vec3 a, Vec3 b, Vec3 c, Vec3 t) {
  Vec3 n = cross(b - a, c - a);
  real n2 = dot(n, n);
  if (!(n2 > real(0))) return nearestOnSegment(a, b, t);
  Vec3 q = t - n * (dot(t - a, n) / n2);  // projection on the plane
  if (insideTriangle(q, a, b, c, n / std::sqrt(n2), real(0))) return q;
  Vec3 best = nearestOnSegment(a, b, t);
  Vec3 c1 = nearestOnSegment(b, c, t), c2 = nearestOnSegment(c, a, t);
  if (length2(c1 - t) < length2(best - t)) best = c1;
  if (length2(c2 - t) < length2(best - t)) best = c2;
  return best;
}

// Least distance of x's foot on the triangle's plane from the edges of (v0, v1, v2), inside positive (nw: the
// winding normal).
DVI_HD real footMargin(Vec3 x, const Vec3* v, Vec3 nw) {
  real m = real(INFINITY);
  for (int i = 0; i < 3; ++i) {
    const Vec3 e = v[(i + 1) % 3] - v[i];
    const Vec3 in = cross(nw, e);
    const real l = length(in);
    m = std::fmin(m, l > real(0) ? dot(in, x - v[i]) / l : real(-INFINITY));
  }
  return m;
}

// Whether the face axis is the pair's minimum-separation axis, so the face contacts stand without MPR. With d the
// face distance of the lowest point p (negative: p below the face) and n = cos t nf + sin t u any other axis (u in
// the plane), the separation along n is at most cos t d - sin t m_p where m_p is the distance of p's foot inside
// the triangle (the triangle reaches m_p beyond it along u), and for t > 90 degrees at most
// cos t H_c - sin t m_c with the interior point c (height H_c, foot m_c inside). Both are <= d when d >= 0 and
// m_p >= 0, or when m_p, m_c and H_c are all >= -d: then no axis separates more than the face's.
DVI_HD bool faceAxisIsBest(Vec3 low, real face_dist, Vec3 c, real c_height, const Vec3* v, Vec3 nw) {
  const real need = std::fmax(real(0), -face_dist);
  if (!(footMargin(low, v, nw) >= need)) return false;
  return face_dist >= real(0) || (c_height >= need && footMargin(c, v, nw) >= need);
}

// Largest separation of box a (half extents a.dims, pose wa) and triangle v over the separating axes of the pair
// other than the triangle's face normal: the box's three face normals and the nine cross products of a box axis
// with a triangle edge (Gottschalk, Lin, Manocha, "OBBTree", SIGGRAPH 1996; Ericson, Real-Time Collision
// Detection, 5.2.9). Along a unit axis n the separation is max(min_k n.(v_k - c) - r, -max_k n.(v_k - c) - r) with
// r = sum_i h_i |n.u_i| the box's reach. With the face normal these axes are every candidate for two convex
// polytopes, so the largest separation is minus the penetration depth when they overlap, and a lower bound on the
// distance when they do not (any axis with separation >= the envelope rules the pair out).
DVI_HD real boxTriangleSeparation(const Shape& a, const Pose& wa, const Vec3* v) {
  const Vec3 u[3] = {rotate(wa.q, Vec3{1, 0, 0}), rotate(wa.q, Vec3{0, 1, 0}), rotate(wa.q, Vec3{0, 0, 1})};
  const real h[3] = {a.dims.x, a.dims.y, a.dims.z};
  const Vec3 d[3] = {v[0] - wa.p, v[1] - wa.p, v[2] - wa.p};
  real best = real(-INFINITY);
  for (int i = 0; i < 3; ++i) {
    const real p0 = dot(u[i], d[0]), p1 = dot(u[i], d[1]), p2 = dot(u[i], d[2]);
    best = maxr(best, maxr(minr(p0, minr(p1, p2)), -maxr(p0, maxr(p1, p2))) - h[i]);
  }
  for (int j = 0; j < 3; ++j) {
    const Vec3 e = v[(j + 1) % 3] - v[j];
    const real le = length(e);
    for (int i = 0; i < 3; ++i) {
      Vec3 n = cross(u[i], e);
      const real ln = length(n);
      if (!(ln > real(1e-6) * le)) continue;  // box axis along the edge: no axis of its own
      n = n / ln;
      const real r = h[0] * std::fabs(dot(n, u[0])) + h[1] * std::fabs(dot(n, u[1])) + h[2] * std::fabs(dot(n, u[2]));
      const real p0 = dot(n, d[j]), p2 = dot(n, d[(j + 2) % 3]);  // the edge's two ends project alike
      best = maxr(best, maxr(minr(p0, p2), -maxr(p0, p2)) - r);
    }
  }
  return best;
}

// The convex shape's plane contacts against the triangle's face (normal nf, the side of a), those whose foot lies
// inside the triangle; their count.
DVI_HD int triangleFaceContacts(const Shape& a, const Pose& wa, const Shape& b, const Vec3* v, Vec3 nw, Vec3 nf,
                                const Vec3* hull_points, real envelope, ContactPoint* out) {
  Shape pl = b;
  pl.type = ShapeType::Plane;
  pl.dims = nf;  // plane {x : dot(nf, x) <= dot(nf, v0)}, solid behind the face
  pl.plane_d = dot(nf, v[0]);
  const Pose id{{0, 0, 0}, {1, 0, 0, 0}};
  ContactPoint pts[kMaxContactsPerPair];
  const int n = collideConvexPlane(a, wa, pl, id, hull_points, envelope, pts);
  const real edge_tol = real(1e-9) * (length(v[1] - v[0]) + length(v[2] - v[0]));
  int m = 0;
  for (int k = 0; k < n; ++k)
    if (insideTriangle(pts[k].pb, v[0], v[1], v[2], nw, edge_tol)) out[m++] = pts[k];
  return m;
}

// Convex shape a (any type but Plane and Triangle) against triangle b. Normals from a to b.
DVI_HD_CALL int collideConvexTriangle(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb,
                                      const Vec3* hull_points, real envelope, ContactPoint* out) {
  const Vec3 v[3] = {transformPoint(wb, triangleVertexLocal(b, 0)), transformPoint(wb, triangleVertexLocal(b, 1)),
                     transformPoint(wb, triangleVertexLocal(b, 2))};
  const Vec3 nw = rotate(wb.q, Vec3{0, 1, 0});  // winding normal
  Vec3 nf = nw;
  // The side of a's centre (two-sided triangle).
  const Vec3 ca = wa.p + rotate(wa.q, interiorPointLocal(a, hull_points));
  if (dot(ca - v[0], nf) < 0) nf = -nf;
  // 1. Face axis: lowest point of a along -nf.
  const Vec3 low = transformPoint(wa, supportLocal(a, rotateInv(wa.q, -nf), hull_points));
  const real face_dist = dot(low - v[0], nf);
  if (!(face_dist < envelope)) return 0;
  // 1b. Edge axes: the outward normal o of each edge in the triangle's plane. The triangle's extent along o ends at
  // that edge, so a shape whose lowest point along o is beyond it by the envelope or more is that far away: no
  // contact (any direction separates: Ericson, Real-Time Collision Detection, 5.2.1). Most triangles under a body
  // lying on a mesh are its neighbours' and end here, before MPR.
  for (int i = 0; i < 3; ++i) {
    const Vec3 o = cross(v[(i + 1) % 3] - v[i], nw);  // outward: nw x e points inside
    const real lo = length(o);
    if (!(lo > real(0))) continue;
    const Vec3 ou = o / lo;
    const Vec3 near = transformPoint(wa, supportLocal(a, rotateInv(wa.q, -ou), hull_points));
    if (!(dot(near - v[i], ou) < envelope)) return 0;
  }
  // 1c. A shape resting inside the triangle: the face axis is the best one (faceAxisIsBest), no MPR needed.
  if (faceAxisIsBest(low, face_dist, ca, dot(ca - v[0], nf), v, nw)) {
    const int m = triangleFaceContacts(a, wa, b, v, nw, nf, hull_points, envelope, out);
    if (m > 0) return m;
  }
  const real tol = real(0.02) * a.size;
  // 1d. A box: the remaining separating axes decide without MPR whether the pair is apart, or whether the face
  // axis is (within tol) its best axis, as step 3 does on MPR's answer.
  if (a.type == ShapeType::Box) {
    const real other = boxTriangleSeparation(a, wa, v);
    if (!(other < envelope)) return 0;
    if (face_dist >= other - tol) {
      const int m = triangleFaceContacts(a, wa, b, v, nw, nf, hull_points, envelope, out);
      if (m > 0) return m;
    }
  }
  // 2. MPR: normal and depth of the deepest feature pair (A grown by the envelope, so the signed distance of the
  // true shapes along n is envelope - depth); its contact point only when the face contacts do not stand.
  const MprShape A = makeMprShape(a, wa, hull_points, envelope), B = makeMprShape(b, wb, hull_points, real(0));
  MprResult best;
  MprRound round;
  const int stage = mprBegin(A, B, a, b, hull_points, best, round);
  if (stage == 0) return 0;
  if (stage == 2) mprDeepRounds(A, B, a, b, hull_points, round, best);
  if (!(best.depth > real(0))) return 0;
  // 3. Face contacts when the face axis is (nearly) the best one.
  if (face_dist >= envelope - best.depth - tol) {
    const int m = triangleFaceContacts(a, wa, b, v, nw, nf, hull_points, envelope, out);
    if (m > 0) return m;
  }
  if (mprFinish(A, B, hull_points, best, envelope, out, false) == 0) return 0;
  out[0].feature = kMaxContactsPerPair;  // distinct from the face points' features (warm start keys)
  return 1;
}

}  // namespace np
}  // namespace dvi
