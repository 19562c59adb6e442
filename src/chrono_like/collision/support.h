// Support mappings of the convex primitives, and small helpers shared by the narrow-phase headers.
// Included by narrowphase_impl.h (after the declarations in narrowphase.h); host and device code.
#pragma once

#include "chrono_like/base/math.h"
#include "chrono_like/base/shape.h"
#include "chrono_like/collision/contact.h"

namespace dvi {
namespace np {

DVI_HD real sgn1(real x) { return x < real(0) ? real(-1) : real(1); }  // sign with sgn(0) = +1
// max and clamp by comparison: std::fmax and fmin are library calls on the host (GCC does not inline them without
// -ffinite-math-only), and these run in every support mapping. clampr(NaN) = lo, as fmin(fmax(NaN, lo), hi).
DVI_HD real maxr(real a, real b) { return a > b ? a : b; }
DVI_HD real minr(real a, real b) { return a < b ? a : b; }
DVI_HD real clampr(real x, real lo, real hi) { return !(x > lo) ? lo : (x > hi ? hi : x); }
template <class T>
DVI_HD void swapv(T& a, T& b) {  // std::swap is not usable in device code
  T t = a;
  a = b;
  b = t;
}
DVI_HD Vec3 column(const Mat33& m, int k) {
  return k == 0 ? Vec3{m.r0.x, m.r1.x, m.r2.x} : (k == 1 ? Vec3{m.r0.y, m.r1.y, m.r2.y} : Vec3{m.r0.z, m.r1.z, m.r2.z});
}
DVI_HD real comp(Vec3 v, int k) { return k == 0 ? v.x : (k == 1 ? v.y : v.z); }

DVI_HD void setContact(ContactPoint& c, Vec3 n, Vec3 pa, Vec3 pb, real dist, int feature) {
  c.normal = n;
  c.pa = pa;
  c.pb = pb;
  c.dist = dist;
  c.feature = feature;
  c.pad_ = 0;
}

// Turns contacts of the pair (B, A) into contacts of (A, B).
DVI_HD void flipContacts(ContactPoint* out, int count) {
  for (int i = 0; i < count; ++i) {
    out[i].normal = -out[i].normal;
    swapv(out[i].pa, out[i].pb);
  }
}

// World plane of a Plane shape at pose w: {x : dot(n, x) <= d}.
DVI_HD void worldPlane(const Shape& s, const Pose& w, Vec3& n, real& d) {
  n = rotate(w.q, s.dims);
  d = s.plane_d + dot(n, w.p);
}

// Radius by which the shape is swept around its core (sphere: a point, capsule: a segment, convex hull: its
// points' hull, swept by its margin); 0 otherwise.
DVI_HD real sweepRadius(const Shape& s) {
  if (s.type == ShapeType::ConvexHull) return real(s.margin);
  return (s.type == ShapeType::Sphere || s.type == ShapeType::Capsule) ? s.dims.x : real(0);
}

// Support point of a convex hull's bare points (its margin excluded) in local direction d.
DVI_HD Vec3 hullPointsSupport(const Shape& s, Vec3 d, const Vec3* hull_points);

// The sphere-swept term of a support mapping: a shape S swept by a ball of radius r has the support
// s_S(d) + r d/|d| (the support of a Minkowski sum is the sum of the supports; van den Bergen, "Collision
// Detection in Interactive 3D Environments", 2004, sec. 4.3.4; Bullet: btConvexInternalShape::
// localGetSupportingVertex adds getMargin() * d/|d| to the bare support). d = 0: no term.
DVI_HD Vec3 sweptTerm(Vec3 d, real r) {
  if (!(r > real(0))) return Vec3{0, 0, 0};
  const real l = length(d);
  return l > real(0) ? d * (r / l) : Vec3{0, 0, 0};
}

// Support point of the core (shape without its sweep radius) in local direction d.
DVI_HD Vec3 supportCoreLocal(const Shape& s, Vec3 d, const Vec3* hull_points);

// A point inside the shape (shape frame): the origin, except for hulls (mean of the points).
DVI_HD Vec3 interiorPointLocal(const Shape& s, const Vec3* hull_points) {
  if (s.type != ShapeType::ConvexHull || s.hull_count <= 0) return Vec3{0, 0, 0};
  Vec3 c{0, 0, 0};
  for (int i = 0; i < s.hull_count; ++i) c += hull_points[s.hull_start + i];
  return c / real(s.hull_count);
}

// Tie tolerance of the support mappings, relative to |d| (max-norm) times the shape's extent. Where several
// points tie on a flat feature (box face or edge, cylinder cap or side line, cone base or generator, hull face)
// the choice must not hang on the last bit of a dot product, which differs between CPU and GPU builds (FMA
// contraction, evaluation order): within the tolerance the rule is fixed -- a box or capsule takes the +
// side of a zero component, a cylinder or cone the cap centre for an axial direction, a cone the apex over
// the rim, a hull the lowest vertex index.
constexpr real kSupportTieTol = sizeof(real) == 8 ? real(1e-9) : real(2e-6);

DVI_HD real maxAbs3(Vec3 d) { return maxr(std::fabs(d.x), maxr(std::fabs(d.y), std::fabs(d.z))); }
DVI_HD real sgnTol(real x, real tol) { return x < -tol ? real(-1) : real(1); }  // sign, +1 within the tolerance

}  // namespace np

// Support functions h(d) = argmax_{x in S} d.x of the primitives, in the shape frame. d need not be unit.
// Ties are broken by the deterministic rules above. A convex hull's is that of its points swept by its margin.
DVI_HD_CALL Vec3 supportLocal(const Shape& s, Vec3 d, const Vec3* hull_points) {
  const real tol = np::kSupportTieTol * np::maxAbs3(d);
  switch (s.type) {
    case ShapeType::Sphere: {
      real l = length(d);
      return l > real(0) ? d * (s.dims.x / l) : Vec3{s.dims.x, 0, 0};
    }
    case ShapeType::Ellipsoid: {
      // Ellipsoid x^T A^-2 x <= 1, A = diag(a,b,c): support = A^2 d / sqrt(d^T A^2 d).
      Vec3 a2d = mul(mul(s.dims, s.dims), d);
      real den = std::sqrt(dot(a2d, d));
      return den > real(0) ? a2d / den : Vec3{s.dims.x, 0, 0};
    }
    case ShapeType::Box:
      return Vec3{np::sgnTol(d.x, tol) * s.dims.x, np::sgnTol(d.y, tol) * s.dims.y, np::sgnTol(d.z, tol) * s.dims.z};
    case ShapeType::Cylinder: {
      real rho = std::sqrt(d.x * d.x + d.z * d.z);
      real y = np::sgnTol(d.y, tol) * s.dims.y;
      return rho > tol ? Vec3{s.dims.x * d.x / rho, y, s.dims.x * d.z / rho} : Vec3{0, y, 0};
    }
    case ShapeType::Capsule: {
      real l = length(d);
      Vec3 c{0, np::sgnTol(d.y, tol) * s.dims.y, 0};
      return l > real(0) ? c + d * (s.dims.x / l) : c;
    }
    case ShapeType::Cone: {
      // Apex (0, h/2, 0) or the base rim point toward d; whichever is further along d (the apex on a tie).
      real hh = real(0.5) * s.dims.y;
      real rho = std::sqrt(d.x * d.x + d.z * d.z);
      real apex = d.y * hh;
      real rim = s.dims.x * rho - d.y * hh;
      if (apex >= rim - tol * (s.dims.x + hh)) return Vec3{0, hh, 0};
      return rho > tol ? Vec3{s.dims.x * d.x / rho, -hh, s.dims.x * d.z / rho} : Vec3{0, -hh, 0};
    }
    case ShapeType::ConvexHull:  // the points' support plus the margin's sphere (sweptTerm)
      return np::hullPointsSupport(s, d, hull_points) + np::sweptTerm(d, real(s.margin));
    case ShapeType::Triangle: {  // vertices as in collide_triangle.h; the lowest index on a tie
      const Vec3 p0{s.dims.x, 0, s.dims.y}, p1{s.dims.z, 0, s.plane_d}, p2 = -(p0 + p1);
      const real d0 = dot(p0, d), d1 = dot(p1, d), d2 = dot(p2, d);
      const real ttol = tol * (np::maxAbs3(p0) + np::maxAbs3(p1) + s.size);
      if (d0 >= d1 - ttol && d0 >= d2 - ttol) return p0;
      return d1 >= d2 - ttol ? p1 : p2;
    }
    case ShapeType::Plane:  // unbounded: no support; a point on the plane
    default: return s.dims * s.plane_d;
  }
}

// Lowest index among the points within the tolerance of the maximum: a later point replaces the current best
// only when it is clearly further (the values differ by rounding between builds).
DVI_HD Vec3 np::hullPointsSupport(const Shape& s, Vec3 d, const Vec3* hull_points) {
  const Vec3* p = hull_points + s.hull_start;
  if (s.hull_count <= 0) return Vec3{0, 0, 0};
  const real tol = np::kSupportTieTol * np::maxAbs3(d);
  int best = 0;
  real bd = dot(p[0], d);
  const real htol = tol * (np::maxAbs3(p[0]) + s.size);
  for (int i = 1; i < s.hull_count; ++i) {
    real v = dot(p[i], d);
    if (v > bd + htol) {
      bd = v;
      best = i;
    }
  }
  // The chain above may stop on a point that is within the tolerance of another that is higher still
  // (two steps of less than htol each): settle on the lowest index within htol of the final maximum.
  for (int i = 0; i < best; ++i)
    if (dot(p[i], d) >= bd - htol) return p[i];
  return p[best];
}

DVI_HD Vec3 np::supportCoreLocal(const Shape& s, Vec3 d, const Vec3* hull_points) {
  if (s.type == ShapeType::Sphere) return Vec3{0, 0, 0};
  if (s.type == ShapeType::ConvexHull) return np::hullPointsSupport(s, d, hull_points);
  if (s.type == ShapeType::Capsule) return Vec3{0, np::sgnTol(d.y, np::kSupportTieTol * np::maxAbs3(d)) * s.dims.y, 0};
  return supportLocal(s, d, hull_points);
}

namespace np {

// supportNearLocal of a convex hull (u: the unit direction, tol: the tie tolerance).
DVI_HD Vec3 hullSupportNear(const Shape& s, Vec3 d, Vec3 u, Vec3 t, real tol, const Vec3* hull_points) {
  // Nearest point to t of the support face conv(T), T = the points within the tie tolerance of the
  // maximum, by Frank-Wolfe steps (exact line search) from the nearest point of T: continuous in t and
  // the pose, and on the face by construction (a convex combination of its points). The swept hull's
  // support face along u is that face moved out by margin u (sweptTerm), as a capsule's side line below.
  const Vec3* p = hull_points + s.hull_start;
  if (s.hull_count <= 0) return Vec3{0, 0, 0};
  const Vec3 out = u * real(s.margin);
  t -= out;  // the face is searched at the points' level
  Vec3 sp = hullPointsSupport(s, d, hull_points);
  const real hmax = dot(sp, u);
  const real htol = tol * (maxAbs3(sp) + s.size);
  Vec3 x = sp;
  real bd = length2(sp - t);
  for (int i = 0; i < s.hull_count; ++i) {
    if (dot(p[i], u) < hmax - htol) continue;
    real dd = length2(p[i] - t);
    if (dd < bd) {
      bd = dd;
      x = p[i];
    }
  }
  for (int it = 0; it < 24; ++it) {
    Vec3 g = x - t;
    int sbest = -1;
    real sv = 0;
    for (int i = 0; i < s.hull_count; ++i) {
      if (dot(p[i], u) < hmax - htol) continue;
      real v = dot(p[i], g);
      if (sbest < 0 || v < sv) {
        sv = v;
        sbest = i;
      }
    }
    if (sbest < 0) break;
    Vec3 e = p[sbest] - x;
    real ee = length2(e);
    real gap = -dot(g, e);
    if (!(ee > real(0)) || gap <= real(1e-12) * (length2(g) + ee)) break;
    x += e * clampr(gap / ee, 0, 1);
  }
  return x + out;
}

// supportNearLocal of a triangle (u: the unit direction, tol: the tie tolerance).
DVI_HD Vec3 triangleSupportNear(const Shape& s, Vec3 u, Vec3 t, real tol) {
  const Vec3 p[3] = {Vec3{s.dims.x, 0, s.dims.y}, Vec3{s.dims.z, 0, s.plane_d},
                     -(Vec3{s.dims.x, 0, s.dims.y} + Vec3{s.dims.z, 0, s.plane_d})};
  real h[3], hmax = real(-1e30);
  for (int i = 0; i < 3; ++i) hmax = std::fmax(hmax, h[i] = dot(p[i], u));
  const real htol = tol * (maxAbs3(p[0]) + maxAbs3(p[1]) + s.size);
  int on[3], k = 0;
  for (int i = 0; i < 3; ++i)
    if (h[i] >= hmax - htol) on[k++] = i;
  if (k == 1) return p[on[0]];
  if (k == 2) {
    Vec3 ab = p[on[1]] - p[on[0]];
    real l2 = dot(ab, ab);
    return l2 > real(0) ? p[on[0]] + ab * clampr(dot(t - p[on[0]], ab) / l2, 0, 1) : p[on[0]];
  }
  // The whole face: t projected on the plane (y = 0) and clamped into the triangle by edges.
  Vec3 q{t.x, 0, t.z};
  for (int i = 0; i < 3; ++i) {
    Vec3 e = p[(i + 1) % 3] - p[i];
    Vec3 inward = cross(Vec3{0, 1, 0}, e);
    if (dot(inward, q - p[i]) < 0) {  // outside this edge: nearest point of the edge
      real l2 = dot(e, e);
      q = l2 > real(0) ? p[i] + e * clampr(dot(q - p[i], e) / l2, 0, 1) : p[i];
    }
  }
  return q;
}

// A support point of the whole shape (sweep radius included) in local direction d, chosen on the support
// face F(d) (points within the tie tolerance of the maximum) as the point nearest `t`: F(d) is a box face,
// edge or vertex (clamp the free coordinates), a cylinder cap disc, side line or rim point, a cone base disc,
// generator or point, a capsule side line, a hull face polygon (approximately: Frank-Wolfe steps), or one
// point of a curved surface. Used for contact points: on the surface by construction, and near t.
DVI_HD_CALL Vec3 supportNearLocal(const Shape& s, Vec3 d, Vec3 t, const Vec3* hull_points) {
  const real l = length(d);
  if (!(l > real(0))) return supportLocal(s, d, hull_points);
  const Vec3 u = d / l;
  const real tol = kSupportTieTol;
  switch (s.type) {
    case ShapeType::Box: {
      const Vec3 e = s.dims;
      return Vec3{std::fabs(u.x) <= tol ? clampr(t.x, -e.x, e.x) : sgn1(u.x) * e.x,
                  std::fabs(u.y) <= tol ? clampr(t.y, -e.y, e.y) : sgn1(u.y) * e.y,
                  std::fabs(u.z) <= tol ? clampr(t.z, -e.z, e.z) : sgn1(u.z) * e.z};
    }
    case ShapeType::Capsule: {
      real y = std::fabs(u.y) <= tol ? clampr(t.y, -s.dims.y, s.dims.y) : sgn1(u.y) * s.dims.y;
      return Vec3{0, y, 0} + u * s.dims.x;
    }
    case ShapeType::Cylinder: {
      const real R = s.dims.x, H = s.dims.y;
      real rho = std::sqrt(u.x * u.x + u.z * u.z);
      if (rho <= tol) {  // cap disc: t clamped into it
        real tr = std::sqrt(t.x * t.x + t.z * t.z);
        real f = tr > R ? R / tr : real(1);
        return Vec3{t.x * f, sgn1(u.y) * H, t.z * f};
      }
      real y = std::fabs(u.y) <= tol ? clampr(t.y, -H, H) : sgn1(u.y) * H;  // side line or rim point
      return Vec3{R * u.x / rho, y, R * u.z / rho};
    }
    case ShapeType::Cone: {
      const real R = s.dims.x, hh = real(0.5) * s.dims.y;
      real rho = std::sqrt(u.x * u.x + u.z * u.z);
      if (rho <= tol && u.y < 0) {  // base disc
        real tr = std::sqrt(t.x * t.x + t.z * t.z);
        real f = tr > R ? R / tr : real(1);
        return Vec3{t.x * f, -hh, t.z * f};
      }
      real apex = u.y * hh, rim = R * rho - u.y * hh;
      if (rho > tol && std::fabs(apex - rim) <= tol * (R + hh)) {  // generator: nearest point of the segment
        Vec3 a{0, hh, 0}, b{R * u.x / rho, -hh, R * u.z / rho};
        Vec3 ab = b - a;
        real w = clampr(dot(t - a, ab) / dot(ab, ab), 0, 1);
        return a + ab * w;
      }
      return supportLocal(s, d, hull_points);
    }
    case ShapeType::ConvexHull: return hullSupportNear(s, d, u, t, tol, hull_points);
    case ShapeType::Triangle: return triangleSupportNear(s, u, t, tol);
    default: return supportLocal(s, d, hull_points);  // sphere, ellipsoid: a single point
  }
}

}  // namespace np
}  // namespace dvi
