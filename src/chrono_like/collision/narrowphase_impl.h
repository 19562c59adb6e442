// Narrow phase implementation (included at the end of narrowphase.h): support mappings, AABBs, the closed-form
// pairs and the dispatcher; MPR (mpr.h) for every other convex pair, box-box in collide_box.h.
// Every function is inline host+device code: no allocation, no recursion, fixed-size local arrays only.
//
// Pairs are collided in a canonical order (lower ShapeType first, so a plane is always second); the result of
// collideShapes(a, b) with a.type > b.type is the canonical result with normals negated and points swapped.
//
// Closed form: sphere-sphere, sphere-box, sphere-cylinder, sphere-capsule, capsule-capsule, box-box (SAT +
// clipping), and every convex shape against a plane (sphere, ellipsoid, box, cylinder, capsule, cone, hull).
// MPR: all remaining pairs (ellipsoid, cone and hull with anything but a plane; box-cylinder, box-capsule,
// cylinder-cylinder, cylinder-capsule, ...).
#pragma once

#include "chrono_like/base/math.h"
#include "chrono_like/base/shape.h"
#include "chrono_like/collision/collide_box.h"
#include "chrono_like/collision/collide_triangle.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/collision/mpr.h"
#include "chrono_like/collision/support.h"

namespace dvi {

// ---------------------------------------------------------------------------------------------------------
// AABB
// ---------------------------------------------------------------------------------------------------------

// Extents of the rotated primitives: for a box, e_i = sum_j |R_ij| h_j; for a disc of radius r with unit
// normal a, e_i = r sqrt(1 - a_i^2); for an ellipsoid with semi-axes s, e_i = sqrt(sum_j (R_ij s_j)^2)
// (support of x^T (R S^2 R^T)^-1 x <= 1 along the world axis i).
DVI_HD Aabb shapeAabb(const Shape& s, const Pose& world, const Vec3* hull_points, real envelope) {
  const Vec3 c = world.p;
  Vec3 e{0, 0, 0};
  switch (s.type) {
    case ShapeType::Sphere: e = Vec3{s.dims.x, s.dims.x, s.dims.x}; break;
    case ShapeType::Ellipsoid: {
      Mat33 R = matFromQuat(world.q);
      e = Vec3{length(mul(R.r0, s.dims)), length(mul(R.r1, s.dims)), length(mul(R.r2, s.dims))};
      break;
    }
    case ShapeType::Box: {
      Mat33 R = matFromQuat(world.q);
      e = Vec3{dot(vabs(R.r0), s.dims), dot(vabs(R.r1), s.dims), dot(vabs(R.r2), s.dims)};
      break;
    }
    case ShapeType::Cylinder:
    case ShapeType::Capsule: {
      Vec3 a = rotate(world.q, Vec3{0, 1, 0});
      Vec3 ax = vabs(a) * s.dims.y;
      if (s.type == ShapeType::Capsule) {
        e = ax + Vec3{s.dims.x, s.dims.x, s.dims.x};
      } else {
        Vec3 disc{std::sqrt(std::fmax(real(0), 1 - a.x * a.x)), std::sqrt(std::fmax(real(0), 1 - a.y * a.y)),
                  std::sqrt(std::fmax(real(0), 1 - a.z * a.z))};
        e = ax + disc * s.dims.x;
      }
      break;
    }
    case ShapeType::Cone: {
      Vec3 a = rotate(world.q, Vec3{0, 1, 0});
      real hh = real(0.5) * s.dims.y;
      Vec3 apex = c + a * hh, base = c - a * hh;
      Vec3 disc = Vec3{std::sqrt(std::fmax(real(0), 1 - a.x * a.x)), std::sqrt(std::fmax(real(0), 1 - a.y * a.y)),
                       std::sqrt(std::fmax(real(0), 1 - a.z * a.z))} *
                  s.dims.x;
      Vec3 env{envelope, envelope, envelope};
      return Aabb{vmin(apex, base - disc) - env, vmax(apex, base + disc) + env};
    }
    case ShapeType::ConvexHull: {
      Mat33 R = matFromQuat(world.q);
      Vec3 lo{0, 0, 0}, hi{0, 0, 0};
      for (int i = 0; i < s.hull_count; ++i) {
        Vec3 p = R * hull_points[s.hull_start + i];
        lo = i == 0 ? p : vmin(lo, p);
        hi = i == 0 ? p : vmax(hi, p);
      }
      // The swept hull's box is the points' box grown by the margin on every side (the support along each axis
      // gains exactly the margin: sweptTerm in support.h).
      const real g = envelope + real(s.margin);
      Vec3 env{g, g, g};
      return Aabb{c + lo - env, c + hi + env};
    }
    case ShapeType::Triangle: {
      Vec3 lo{0, 0, 0}, hi{0, 0, 0};
      for (int i = 0; i < 3; ++i) {
        Vec3 p = transformPoint(world, np::triangleVertexLocal(s, i));
        lo = i == 0 ? p : vmin(lo, p);
        hi = i == 0 ? p : vmax(hi, p);
      }
      Vec3 env{envelope, envelope, envelope};
      return Aabb{lo - env, hi + env};
    }
    case ShapeType::Plane:
    default: return Aabb{Vec3{real(-1e30), real(-1e30), real(-1e30)}, Vec3{real(1e30), real(1e30), real(1e30)}};
  }
  e += Vec3{envelope, envelope, envelope};
  return Aabb{c - e, c + e};
}

namespace np {

// ---------------------------------------------------------------------------------------------------------
// Closed-form pairs. Each writes contacts with normals from its first to its second argument.
// ---------------------------------------------------------------------------------------------------------

// Sphere-sphere: n = (cb - ca)/|cb - ca|, dist = |cb - ca| - ra - rb.
DVI_HD int collideSphereSphere(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, real envelope,
                               ContactPoint* out) {
  Vec3 d = wb.p - wa.p;
  real rs = a.dims.x + b.dims.x;
  real l2 = length2(d);
  real lim = rs + envelope;
  if (l2 >= lim * lim) return 0;
  real l = std::sqrt(l2);
  Vec3 n = l > real(0) ? d / l : Vec3{1, 0, 0};
  setContact(out[0], n, wa.p + n * a.dims.x, wb.p - n * b.dims.x, l - rs, 0);
  return 1;
}

// Sphere (a) against a convex solid whose closest point q to the centre and outward normal nb (from the
// solid toward the centre) are known, and signed distance sd of the centre to the solid's surface
// (negative inside). Normal a->b is -nb.
DVI_HD int sphereAgainst(const Vec3& c, real r, Vec3 q, Vec3 nb, real sd, real envelope, ContactPoint* out) {
  real dist = sd - r;
  if (!(dist < envelope)) return 0;
  setContact(out[0], -nb, c - nb * r, q, dist, 0);
  return 1;
}

// Sphere-box: closest point of the box to the centre (clamp in the box frame); centre inside: nearest face.
DVI_HD int collideSphereBox(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, real envelope,
                            ContactPoint* out) {
  const Vec3 e = b.dims;
  Vec3 cl = rotateInv(wb.q, wa.p - wb.p);
  Vec3 q{clampr(cl.x, -e.x, e.x), clampr(cl.y, -e.y, e.y), clampr(cl.z, -e.z, e.z)};
  Vec3 d = cl - q;
  real l2 = length2(d);
  Vec3 nl;
  real sd;
  if (l2 > real(0)) {
    real l = std::sqrt(l2);
    if (l - a.dims.x >= envelope) return 0;
    nl = d / l;
    sd = l;
  } else {  // centre inside: leave through the nearest face
    real gx = e.x - std::fabs(cl.x), gy = e.y - std::fabs(cl.y), gz = e.z - std::fabs(cl.z);
    if (gx <= gy && gx <= gz) {
      nl = Vec3{sgn1(cl.x), 0, 0};
      q.x = sgn1(cl.x) * e.x;
      sd = -gx;
    } else if (gy <= gz) {
      nl = Vec3{0, sgn1(cl.y), 0};
      q.y = sgn1(cl.y) * e.y;
      sd = -gy;
    } else {
      nl = Vec3{0, 0, sgn1(cl.z)};
      q.z = sgn1(cl.z) * e.z;
      sd = -gz;
    }
  }
  return sphereAgainst(wa.p, a.dims.x, transformPoint(wb, q), rotate(wb.q, nl), sd, envelope, out);
}

// Sphere-cylinder: closest point of the solid cylinder (clamp radius and height); inside: nearest of side/cap.
DVI_HD int collideSphereCylinder(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, real envelope,
                                 ContactPoint* out) {
  const real R = b.dims.x, H = b.dims.y;
  Vec3 cl = rotateInv(wb.q, wa.p - wb.p);
  real rho = std::sqrt(cl.x * cl.x + cl.z * cl.z);
  Vec3 u = rho > real(0) ? Vec3{cl.x / rho, 0, cl.z / rho} : Vec3{1, 0, 0};
  Vec3 nl, q;
  real sd;
  if (rho <= R && std::fabs(cl.y) <= H) {
    real gr = R - rho, gy = H - std::fabs(cl.y);
    if (gr < gy) {
      nl = u;
      q = u * R + Vec3{0, cl.y, 0};
      sd = -gr;
    } else {
      nl = Vec3{0, sgn1(cl.y), 0};
      q = Vec3{cl.x, sgn1(cl.y) * H, cl.z};
      sd = -gy;
    }
  } else {
    q = u * std::fmin(rho, R) + Vec3{0, clampr(cl.y, -H, H), 0};
    Vec3 d = cl - q;
    sd = length(d);
    if (sd - a.dims.x >= envelope) return 0;
    nl = d / sd;
  }
  return sphereAgainst(wa.p, a.dims.x, transformPoint(wb, q), rotate(wb.q, nl), sd, envelope, out);
}

// A unit vector normal to v.
DVI_HD Vec3 anyPerpendicular(Vec3 v) {
  Vec3 u, w;
  tangentBasis(normalized(v), u, w);
  return u;
}

// Sphere-capsule: closest point of the capsule's segment to the centre.
DVI_HD int collideSphereCapsule(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, real envelope,
                                ContactPoint* out) {
  Vec3 ax = rotate(wb.q, Vec3{0, 1, 0});
  real t = clampr(dot(wa.p - wb.p, ax), -b.dims.y, b.dims.y);
  Vec3 q = wb.p + ax * t;
  Vec3 d = wa.p - q;  // from capsule core to sphere centre
  real l = length(d);
  real dist = l - a.dims.x - b.dims.x;
  if (!(dist < envelope)) return 0;
  Vec3 nb = l > real(0) ? d / l : anyPerpendicular(ax);
  setContact(out[0], -nb, wa.p - nb * a.dims.x, q + nb * b.dims.x, dist, 0);
  return 1;
}

// Contact between a point qa on A's core and qb on B's core, with radii ra, rb; `fallback` a normal to use
// when the cores touch.
DVI_HD bool sweptPointContact(Vec3 qa, Vec3 qb, real ra, real rb, Vec3 fallback, real envelope, int feature,
                              ContactPoint& c) {
  Vec3 d = qb - qa;
  real l = length(d);
  real dist = l - ra - rb;
  if (!(dist < envelope)) return false;
  Vec3 n = l > real(1e-14) ? d / l : fallback;
  setContact(c, n, qa + n * ra, qb - n * rb, dist, feature);
  return true;
}

// Capsule-capsule: closest points of the two core segments. Nearly parallel overlapping segments (lying
// side by side) get the two ends of their overlap as extra points (features 1, 2) so they rest stably.
DVI_HD int collideCapsuleCapsule(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, real envelope,
                                 ContactPoint* out) {
  Vec3 axA = rotate(wa.q, Vec3{0, 1, 0}), axB = rotate(wb.q, Vec3{0, 1, 0});
  Vec3 p1 = wa.p - axA * a.dims.y, d1 = axA * (2 * a.dims.y);
  Vec3 p2 = wb.p - axB * b.dims.y, d2 = axB * (2 * b.dims.y);
  real s, t;
  closestSegmentSegment(p1, d1, p2, d2, s, t);
  Vec3 qa = p1 + d1 * s, qb = p2 + d2 * t;
  // Fallback normal when the cores intersect: perpendicular to both axes, oriented a -> b.
  Vec3 fb = cross(axA, axB);
  if (length2(fb) < real(1e-12)) fb = anyPerpendicular(axA);
  fb = normalized(fb);
  if (dot(fb, wb.p - wa.p) < 0) fb = -fb;
  int m = 0;
  if (sweptPointContact(qa, qb, a.dims.x, b.dims.x, fb, envelope, 0, out[m])) ++m;
  if (m == 0) return 0;
  real la = dot(d1, d1), lb = dot(d2, d2);
  real sn = length2(cross(axA, axB));
  if (la > real(0) && lb > real(0) && sn < real(1e-4)) {  // |sin angle| < 1e-2
    real s0 = dot(p2 - p1, d1) / la, s1 = dot(p2 + d2 - p1, d1) / la;
    real lo = std::fmax(real(0), std::fmin(s0, s1)), hi = std::fmin(real(1), std::fmax(s0, s1));
    if (hi - lo > real(1e-3)) {
      for (int k = 0; k < 2; ++k) {
        Vec3 pa = p1 + d1 * (k == 0 ? lo : hi);
        real tt = clampr(dot(pa - p2, d2) / lb, 0, 1);
        if (sweptPointContact(pa, p2 + d2 * tt, a.dims.x, b.dims.x, fb, envelope, 1 + k, out[m])) ++m;
      }
    }
  }
  return m;
}

// ---------------------------------------------------------------------------------------------------------
// Shape (a) against a plane (b). Plane normal np (pointing out of the solid), offset pd; the contact normal
// a -> b is -np; a point x of a gives dist = dot(np, x) - pd, pb = its projection on the plane.
// ---------------------------------------------------------------------------------------------------------

DVI_HD bool planePoint(Vec3 x, real r, Vec3 pn, real pd, real envelope, int feature, ContactPoint& c) {
  real h = dot(pn, x) - pd;
  real dist = h - r;
  if (!(dist < envelope)) return false;
  setContact(c, -pn, x - pn * r, x - pn * h, dist, feature);
  return true;
}

// Two unit vectors u, v spanning the plane normal to axis ax: u toward the deepest direction -pn projected on
// that plane, or, when the axis is within ~1e-3 rad of the plane normal (standing on a cap), the shape's own
// local X axis, so the rim points and their features stay fixed on the body while it rests.
DVI_HD void rimFrame(Vec3 ax, Vec3 xaxis, Vec3 pn, Vec3& u, Vec3& v) {
  Vec3 w = pn * real(-1) + ax * dot(pn, ax);
  real rho = length(w);
  u = rho > real(1e-3) ? w / rho : xaxis;
  v = cross(ax, u);
}

// Shape (a) against the half-space {x : dot(pn, x) <= pd}.
DVI_HD_CALL int collideConvexHalfSpace(const Shape& a, const Pose& wa, Vec3 pn, real pd, const Vec3* hull_points,
                                       real envelope, ContactPoint* out) {
  int m = 0;
  switch (a.type) {
    case ShapeType::Sphere: m += planePoint(wa.p, a.dims.x, pn, pd, envelope, 0, out[m]); break;
    case ShapeType::Ellipsoid: {  // support point along -n
      Vec3 x = transformPoint(wa, supportLocal(a, rotateInv(wa.q, -pn), hull_points));
      m += planePoint(x, 0, pn, pd, envelope, 0, out[m]);
      break;
    }
    case ShapeType::Box: {  // every vertex within the envelope; feature = vertex index
      Mat33 R = matFromQuat(wa.q);
      for (int i = 0; i < 8; ++i) {
        Vec3 l{(i & 1) ? a.dims.x : -a.dims.x, (i & 2) ? a.dims.y : -a.dims.y, (i & 4) ? a.dims.z : -a.dims.z};
        m += planePoint(wa.p + R * l, 0, pn, pd, envelope, i, out[m]);
      }
      break;
    }
    case ShapeType::Capsule: {  // both segment ends with the radius
      Vec3 ax = rotate(wa.q, Vec3{0, 1, 0});
      m += planePoint(wa.p - ax * a.dims.y, a.dims.x, pn, pd, envelope, 0, out[m]);
      m += planePoint(wa.p + ax * a.dims.y, a.dims.x, pn, pd, envelope, 1, out[m]);
      break;
    }
    case ShapeType::Cylinder: {  // 4 rim points per cap; feature = cap * 4 + k
      Mat33 R = matFromQuat(wa.q);
      Vec3 ax = column(R, 1), u, v;
      rimFrame(ax, column(R, 0), pn, u, v);
      u *= a.dims.x;
      v *= a.dims.x;
      for (int cap = 0; cap < 2; ++cap) {
        Vec3 cc = wa.p + ax * (cap == 0 ? -a.dims.y : a.dims.y);
        m += planePoint(cc + u, 0, pn, pd, envelope, cap * 4 + 0, out[m]);
        m += planePoint(cc + v, 0, pn, pd, envelope, cap * 4 + 1, out[m]);
        m += planePoint(cc - u, 0, pn, pd, envelope, cap * 4 + 2, out[m]);
        m += planePoint(cc - v, 0, pn, pd, envelope, cap * 4 + 3, out[m]);
      }
      break;
    }
    case ShapeType::Cone: {  // apex (feature 0) and 4 base rim points (1..4)
      Mat33 R = matFromQuat(wa.q);
      Vec3 ax = column(R, 1), u, v;
      real hh = real(0.5) * a.dims.y;
      m += planePoint(wa.p + ax * hh, 0, pn, pd, envelope, 0, out[m]);
      rimFrame(ax, column(R, 0), pn, u, v);
      u *= a.dims.x;
      v *= a.dims.x;
      Vec3 cc = wa.p - ax * hh;
      m += planePoint(cc + u, 0, pn, pd, envelope, 1, out[m]);
      m += planePoint(cc + v, 0, pn, pd, envelope, 2, out[m]);
      m += planePoint(cc - u, 0, pn, pd, envelope, 3, out[m]);
      m += planePoint(cc - v, 0, pn, pd, envelope, 4, out[m]);
      break;
    }
    case ShapeType::ConvexHull: {
      // Vertices within the envelope, the kMaxContactsPerPair deepest, kept in vertex order; feature = rank. With a
      // margin r the swept hull's point nearest the plane is each vertex's sphere's lowest point: the vertex's
      // height minus r, as a capsule's ends above (Bullet: btConvexInternalShape::localGetSupportingVertex).
      const real r = real(a.margin);
      Mat33 R = matFromQuat(wa.q);
      int idx[kMaxContactsPerPair];
      real hv[kMaxContactsPerPair];
      int cnt = 0;
      for (int i = 0; i < a.hull_count; ++i) {
        real h = dot(pn, wa.p + R * hull_points[a.hull_start + i]) - pd - r;
        if (!(h < envelope)) continue;
        if (cnt < kMaxContactsPerPair) {
          idx[cnt] = i;
          hv[cnt] = h;
          ++cnt;
        } else {  // replace the shallowest kept vertex if this one is deeper
          int w = 0;
          for (int k = 1; k < cnt; ++k)
            if (hv[k] > hv[w]) w = k;
          if (h < hv[w]) {
            for (int k = w; k + 1 < cnt; ++k) {  // keep vertex order
              idx[k] = idx[k + 1];
              hv[k] = hv[k + 1];
            }
            idx[cnt - 1] = i;
            hv[cnt - 1] = h;
          }
        }
      }
      for (int k = 0; k < cnt; ++k)
        m += planePoint(wa.p + R * hull_points[a.hull_start + idx[k]], r, pn, pd, envelope, k, out[m]);
      break;
    }
    default: break;
  }
  return m;
}

DVI_HD int collideConvexPlane(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, const Vec3* hull_points,
                              real envelope, ContactPoint* out) {
  Vec3 pn;
  real pd;
  worldPlane(b, wb, pn, pd);
  return collideConvexHalfSpace(a, wa, pn, pd, hull_points, envelope, out);
}

// ---------------------------------------------------------------------------------------------------------
// A small polyhedral shape (a: box, convex hull, cylinder or cone, its points of radius 0, or a hull's margin; an
// ellipsoid goes to collideSmoothBigCylinder below)
// against the side of a large cylinder (b): the CES drum and brush against 0.5-1 mm flakes, wires and
// fragments. MPR gives one point per pair, and a flat face resting on the drum then tips and sinks (1.2 mm
// into the drum for a 0.1 mm-thick flake in bench accuracy's CES scene); this gives the face's vertices
// instead, as the plane pair does. The candidates are the vertices that collideConvexHalfSpace selects against
// the tangent plane at the point of the side nearest a's centre; each is then measured exactly against the
// cylinder: dist = rho - R with rho its distance from the axis, normal radial. A point at lateral offset s and
// height h above the tangent plane has rho = sqrt((R + h)^2 + s^2) >= R + h, so the plane keeps every vertex
// the exact test would. A hull's margin r (Shape::margin) sweeps each vertex by a sphere: its point nearest
// the cylinder lies r from the vertex along the radial normal, dist = rho - R - r. Used when R >=
// kBigCylinderRatio x a's bounding radius and a lies within the side's axial span (away from the caps);
// otherwise the pair goes to MPR.
// ---------------------------------------------------------------------------------------------------------

constexpr real kBigCylinderRatio = 20;

DVI_HD bool polyhedralPoints(ShapeType t) {
  return t == ShapeType::Box || t == ShapeType::ConvexHull || t == ShapeType::Cylinder || t == ShapeType::Cone;
}

DVI_HD bool bigCylinderSide(const Shape& a, const Pose& wa, const Shape& cyl, const Pose& wc, const Vec3* hull_points) {
  if (cyl.type != ShapeType::Cylinder || !(polyhedralPoints(a.type) || a.type == ShapeType::Ellipsoid)) return false;
  const real R = cyl.dims.x, ra = boundingRadius(a, hull_points);
  if (!(R >= kBigCylinderRatio * ra)) return false;
  const Vec3 ax = rotate(wc.q, Vec3{0, 1, 0}), d = wa.p - wc.p;
  const real axial = dot(d, ax);
  if (fabs(axial) + ra > cyl.dims.y) return false;
  return length(d - ax * axial) > real(0.5) * R;  // a radial direction well defined, a near the side
}

// An ellipsoid (a smooth particle) against the side of a large cylinder: its point nearest the axis is where its
// surface normal is radial (the gradient of the distance from the axis). The fixed point x = support_a(-radial(x)),
// started from the radial direction through a's centre, contracts its error by about a's radius / R per
// iteration (<= 1 / kBigCylinderRatio: the radial direction turns by |x - x*| / R when x moves), so
// kSmoothBigCylinderIterations leave ~20^-4 of a's size; the depth is then measured exactly at x, dist = rho - R.
// One point (curved against curved); MPR's restarts for "deep" pairs (mpr.h) are not needed: the side is
// nearly flat over the particle, so the nearest face is the radial one.
constexpr int kSmoothBigCylinderIterations = 4;

DVI_HD_CALL int collideSmoothBigCylinder(const Shape& a, const Pose& wa, const Shape& cyl, const Pose& wc,
                                         const Vec3* hull_points, real envelope, ContactPoint* out) {
  const real R = cyl.dims.x;
  const Vec3 ax = rotate(wc.q, Vec3{0, 1, 0});
  Vec3 d = wa.p - wc.p, x = wa.p;
  real axial = dot(d, ax);
  Vec3 dr = d - ax * axial;
  real rho = length(dr);
  Vec3 nr = dr / rho;  // rho > R / 2 (bigCylinderSide)
  for (int it = 0; it < kSmoothBigCylinderIterations; ++it) {
    x = transformPoint(wa, supportLocal(a, rotateInv(wa.q, -nr), hull_points));
    d = x - wc.p;
    axial = dot(d, ax);
    dr = d - ax * axial;
    rho = length(dr);
    nr = dr / rho;
  }
  const real dist = rho - R;
  if (!(dist < envelope)) return 0;
  setContact(out[0], -nr, x, wc.p + ax * axial + nr * R, dist, 0);
  return 1;
}

DVI_HD_CALL int collideConvexBigCylinder(const Shape& a, const Pose& wa, const Shape& cyl, const Pose& wc,
                                         const Vec3* hull_points, real envelope, ContactPoint* out) {
  if (a.type == ShapeType::Ellipsoid) return collideSmoothBigCylinder(a, wa, cyl, wc, hull_points, envelope, out);
  const real R = cyl.dims.x;
  const Vec3 ax = rotate(wc.q, Vec3{0, 1, 0});
  const Vec3 d0 = wa.p - wc.p;
  const Vec3 n0 = normalized(d0 - ax * dot(d0, ax));
  const int cnt = collideConvexHalfSpace(a, wa, n0, dot(n0, wc.p) + R, hull_points, envelope, out);
  const real r = sweepRadius(a);  // a hull's margin; 0 for the other polyhedral shapes
  int m = 0;
  for (int k = 0; k < cnt; ++k) {
    const Vec3 x = out[k].pa + n0 * r;  // the vertex (planePoint put pa r below it along -n0)
    const Vec3 d = x - wc.p;
    const real axial = dot(d, ax);
    const Vec3 dr = d - ax * axial;
    const real rho = length(dr);
    const Vec3 nr = rho > real(0) ? dr / rho : n0;
    const real dist = rho - R - r;
    if (!(dist < envelope)) continue;
    setContact(out[m], -nr, x - nr * r, wc.p + ax * axial + nr * R, dist, out[k].feature);
    ++m;
  }
  return m;
}

// Canonical order: a.type <= b.type. kMpr = false leaves MPR (and the triangle pairs, which use it) out of the
// code: the GPU's kernel for the closed-form classes (pairUsesMpr false) takes far fewer registers without it.
template <bool kMpr = true>
DVI_HD int collideOrdered(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, const Vec3* hull_points,
                          real envelope, ContactPoint* out, MprDeferred* defer = nullptr, bool manifold = true,
                          GjkUse gjk = GjkUse::All, NarrowWork* work = nullptr, const PairHistory* history = nullptr) {
  if (b.type == ShapeType::Triangle) {  // static geometry: never against a plane or another triangle
    if (a.type == ShapeType::Plane || a.type == ShapeType::Triangle) return 0;
    if constexpr (kMpr) return collideConvexTriangle(a, wa, b, wb, hull_points, envelope, out);
    return 0;
  }
  if (b.type == ShapeType::Plane) {
    if (a.type == ShapeType::Plane) return 0;
    return collideConvexPlane(a, wa, b, wb, hull_points, envelope, out);
  }
  // A particle against the side of a drum or brush (either order: a.type <= b.type).
  if (bigCylinderSide(a, wa, b, wb, hull_points))
    return collideConvexBigCylinder(a, wa, b, wb, hull_points, envelope, out);
  if (bigCylinderSide(b, wb, a, wa, hull_points)) {
    const int m = collideConvexBigCylinder(b, wb, a, wa, hull_points, envelope, out);
    flipContacts(out, m);
    return m;
  }
  switch (a.type) {
    case ShapeType::Sphere:
      switch (b.type) {
        case ShapeType::Sphere: return collideSphereSphere(a, wa, b, wb, envelope, out);
        case ShapeType::Box: return collideSphereBox(a, wa, b, wb, envelope, out);
        case ShapeType::Cylinder: return collideSphereCylinder(a, wa, b, wb, envelope, out);
        case ShapeType::Capsule: return collideSphereCapsule(a, wa, b, wb, envelope, out);
        default: break;
      }
      break;
    case ShapeType::Box:
      if (b.type == ShapeType::Box) return collideBoxBox(a, wa, b, wb, envelope, out);
      break;
    case ShapeType::Capsule:
      if (b.type == ShapeType::Capsule) return collideCapsuleCapsule(a, wa, b, wb, envelope, out);
      break;
    default: break;
  }
  if constexpr (kMpr) return collideMpr(a, wa, b, wb, hull_points, envelope, out, defer, manifold, gjk, work, history);
  return 0;
}

}  // namespace np

// Whether the narrow phase may run MPR for a pair of shape types (in either order): the pairs without a
// closed form in collideOrdered's dispatch above (keep the two in step), and convex-triangle pairs (the face
// axis, then MPR for edge and vertex contacts). Pairs that never collide (plane-plane, triangle-plane,
// triangle-triangle) do not. The System reports the NarrowPhase.Mpr part from it (docs/MODEL.md §6).
DVI_HD bool pairUsesMpr(ShapeType a, ShapeType b) {
  if (b < a) {
    const ShapeType t = a;
    a = b;
    b = t;
  }
  const bool a_static = a == ShapeType::Plane || a == ShapeType::Triangle;
  if (b == ShapeType::Triangle) return !a_static;
  if (b == ShapeType::Plane) return false;
  if (a == ShapeType::Sphere)
    return !(b == ShapeType::Sphere || b == ShapeType::Box || b == ShapeType::Cylinder || b == ShapeType::Capsule);
  if (a == b && (a == ShapeType::Box || a == ShapeType::Capsule)) return false;
  return true;
}

// A pair collided in the opposite order (collideShapes' canonical order) has its contacts flipped; its first MPR
// point (np::kMprFirst) then says so, for mprManifoldAgain.
constexpr int32_t kMprFirstSwapped = 2;
DVI_HD void markFlippedMpr(ContactPoint* out, int m) {
  if (m >= 1 && out[0].pad_ == np::kMprFirst) out[0].pad_ = kMprFirstSwapped;
}

DVI_HD int collideShapes(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, const Vec3* hull_points,
                         real envelope, ContactPoint* out, np::MprDeferred* defer, bool manifold, GjkUse gjk,
                         NarrowWork* work, const PairHistory* history) {
  if (a.type == ShapeType::Sphere && b.type == ShapeType::Sphere)  // the hot path
    return np::collideSphereSphere(a, wa, b, wb, envelope, out);
  if (int(a.type) <= int(b.type)) {
    const int m = np::collideOrdered(a, wa, b, wb, hull_points, envelope, out, defer, manifold, gjk, work, history);
    if (m == np::kMprDeferred) defer->swapped = 0;
    return m;
  }
  PairHistory swapped_history;  // the normal of b to a
  if (history) {
    swapped_history = *history;
    swapped_history.sign = -history->sign;
  }
  int m = np::collideOrdered(b, wb, a, wa, hull_points, envelope, out, defer, manifold, gjk, work,
                             history ? &swapped_history : nullptr);
  if (m == np::kMprDeferred) {
    defer->swapped = 1;
    return m;
  }
  np::flipContacts(out, m);
  markFlippedMpr(out, m);
  return m;
}

// collideShapes for a pair with a closed form (pairUsesMpr false; the caller makes sure), without MPR's code: the
// same arithmetic and the same points as collideShapes.
DVI_HD int collideShapesClosedForm(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb,
                                   const Vec3* hull_points, real envelope, ContactPoint* out) {
  if (int(a.type) <= int(b.type)) return np::collideOrdered<false>(a, wa, b, wb, hull_points, envelope, out);
  const int m = np::collideOrdered<false>(b, wb, a, wa, hull_points, envelope, out);
  np::flipContacts(out, m);
  return m;
}

// The points of a pair whose first point came from MPR (pad_ np::kMprFirst or kMprFirstSwapped) again from that
// point: np::mprManifold in the order the pair was collided, the same arithmetic as collideShapes without MPR
// (the GPU's write pass, which keeps only a pair's first point from the count pass).
DVI_HD int mprManifoldAgain(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, const Vec3* hull_points,
                            real envelope, const ContactPoint& first, ContactPoint* out) {
  const bool swapped = first.pad_ == kMprFirstSwapped;
  out[0] = first;
  if (swapped) np::flipContacts(out, 1);  // its own inverse: the point as mprFinish wrote it
  out[0].pad_ = np::kMprFirst;
  const np::MprShape A = np::makeMprShape(swapped ? b : a, swapped ? wb : wa, hull_points, envelope);
  const np::MprShape B = np::makeMprShape(swapped ? a : b, swapped ? wa : wb, hull_points, real(0));
  const int m = np::mprManifold(A, B, hull_points, envelope, out);
  if (swapped) {
    np::flipContacts(out, m);
    markFlippedMpr(out, m);
  }
  return m;
}

// The MPR shapes of a deferred pair in the order mprBegin saw them (swapped back where collideShapes swapped),
// with that order's shapes in *fa, *fb: what finishDeferredMpr and the GPU's narrowDeepKernel start from.
DVI_HD void deferredMprShapes(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, const Vec3* hull_points,
                              real envelope, bool swapped, np::MprShape& A, np::MprShape& B, const Shape*& fa,
                              const Shape*& fb) {
  fa = swapped ? &b : &a;
  fb = swapped ? &a : &b;
  A = np::makeMprShape(*fa, swapped ? wb : wa, hull_points, envelope);
  B = np::makeMprShape(*fb, swapped ? wa : wb, hull_points, real(0));
}

// Finishes a pair that collideShapes left in `defer` (the GPU runs the same steps a lane per restart).
DVI_HD int finishDeferredMpr(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, const Vec3* hull_points,
                             real envelope, np::MprDeferred d, ContactPoint* out, bool manifold = true) {
  np::MprShape A, B;
  const Shape *fa, *fb;
  deferredMprShapes(a, wa, b, wb, hull_points, envelope, d.swapped != 0, A, B, fa, fb);
  np::mprRunRound(A, B, hull_points, d.round, d.best);
  if (np::mprTiltRound(A, *fa, *fb, d.best, d.round)) np::mprRunRound(A, B, hull_points, d.round, d.best);
  const int m = np::mprFinish(A, B, hull_points, d.best, envelope, out, manifold);
  if (d.swapped) {
    np::flipContacts(out, m);
    markFlippedMpr(out, m);
  }
  return m;
}

}  // namespace dvi
