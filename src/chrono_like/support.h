// Support mappings of the convex primitives, and small helpers shared by the narrow-phase headers.
// Included by narrowphase_impl.h (after the declarations in narrowphase.h); host and device code.
#pragma once

#include "contact.h"
#include "math.h"
#include "shape.h"

namespace dvi {
namespace np {

DVI_HD real sgn1(real x) { return x < real(0) ? real(-1) : real(1); }  // sign with sgn(0) = +1
DVI_HD real clampr(real x, real lo, real hi) { return std::fmin(std::fmax(x, lo), hi); }
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

// Radius by which the shape is swept around its core (sphere: a point, capsule: a segment); 0 otherwise.
DVI_HD real sweepRadius(const Shape& s) {
  return (s.type == ShapeType::Sphere || s.type == ShapeType::Capsule) ? s.dims.x : real(0);
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

}  // namespace np

// Support functions h(d) = argmax_{x in S} d.x of the primitives, in the shape frame. d need not be unit.
DVI_HD Vec3 supportLocal(const Shape& s, Vec3 d, const Vec3* hull_points) {
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
      return Vec3{np::sgn1(d.x) * s.dims.x, np::sgn1(d.y) * s.dims.y, np::sgn1(d.z) * s.dims.z};
    case ShapeType::Cylinder: {
      real rho = std::sqrt(d.x * d.x + d.z * d.z);
      real y = np::sgn1(d.y) * s.dims.y;
      return rho > real(0) ? Vec3{s.dims.x * d.x / rho, y, s.dims.x * d.z / rho} : Vec3{0, y, 0};
    }
    case ShapeType::Capsule: {
      real l = length(d);
      Vec3 c{0, np::sgn1(d.y) * s.dims.y, 0};
      return l > real(0) ? c + d * (s.dims.x / l) : c;
    }
    case ShapeType::Cone: {
      // Apex (0, h/2, 0) or the base rim point toward d; whichever is further along d.
      real hh = real(0.5) * s.dims.y;
      real rho = std::sqrt(d.x * d.x + d.z * d.z);
      real apex = d.y * hh;
      real rim = s.dims.x * rho - d.y * hh;
      if (apex >= rim) return Vec3{0, hh, 0};
      return rho > real(0) ? Vec3{s.dims.x * d.x / rho, -hh, s.dims.x * d.z / rho} : Vec3{0, -hh, 0};
    }
    case ShapeType::ConvexHull: {
      const Vec3* p = hull_points + s.hull_start;
      int best = 0;
      real bd = dot(p[0], d);
      for (int i = 1; i < s.hull_count; ++i) {
        real v = dot(p[i], d);
        if (v > bd) {
          bd = v;
          best = i;
        }
      }
      return s.hull_count > 0 ? p[best] : Vec3{0, 0, 0};
    }
    case ShapeType::Plane:  // unbounded: no support; a point on the plane
    default: return s.dims * s.plane_d;
  }
}

DVI_HD Vec3 np::supportCoreLocal(const Shape& s, Vec3 d, const Vec3* hull_points) {
  if (s.type == ShapeType::Sphere) return Vec3{0, 0, 0};
  if (s.type == ShapeType::Capsule) return Vec3{0, np::sgn1(d.y) * s.dims.y, 0};
  return supportLocal(s, d, hull_points);
}

}  // namespace dvi
