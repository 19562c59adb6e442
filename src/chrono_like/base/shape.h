// Collision shape records: one flat array of these per system, each a convex primitive attached to a
// body at a local pose. A Bullet compound becomes several records on one body; a btMultiSphereShape
// becomes sphere records (or one ellipsoid when it is a single non-uniformly scaled sphere).
#pragma once

#include <cstdint>

#include "chrono_like/base/math.h"

namespace dvi {

// Canonical primitives. Axis-symmetric shapes use the local Y axis (Bullet's X/Z variants are imported
// by rotating the child pose).
enum class ShapeType : int32_t {
  Sphere = 0,  // dims.x = radius
  Ellipsoid,   // dims = semi-axes
  Box,         // dims = half extents
  Cylinder,    // dims.x = radius, dims.y = half height (axis Y)
  Capsule,     // dims.x = radius, dims.y = half length of the core segment (axis Y)
  Cone,        // dims.x = base radius, dims.y = height; apex at +height/2, base at -height/2 (as btConeShape)
  ConvexHull,  // points hull_points[hull_start .. hull_start+hull_count) in the shape frame, swept by a sphere of
               // radius `margin` (Bullet's collision margin; 0: the bare points' hull); dims = the points' half extents
  Plane,       // static half-space {x : dot(n, x) <= d} in the shape frame: dims = unit normal n, plane_d = d
  Triangle,    // static environment triangle (collide_triangle.h): centroid at the origin, face normal +Y,
               // vertices (dims.x, 0, dims.y), (dims.z, 0, plane_d) and minus their sum
  Count
};

const char* shapeTypeName(ShapeType t);

constexpr int kMaxContactsPerPair = 8;

struct Shape {  // 120 bytes in double, 72 in float (the static_assert below)
  ShapeType type;
  int32_t body;        // owning body index
  int32_t hull_start;  // ConvexHull only
  int32_t hull_count;  // ConvexHull only
  Pose local;          // pose of the shape frame in the body frame (body frame = centre of mass, principal axes)
  Vec3 dims;           // see ShapeType
  real plane_d;        // Plane only
  real size;           // characteristic length: smallest half-dimension (radius for a sphere); scales the
                       // collision envelope and recovery speed so that they are relative, not absolute
  int16_t group;       // collision filter group (Bullet semantics: a pair collides when
  int16_t mask;        //   (a.group & b.mask) && (b.group & a.mask))
  float margin;        // ConvexHull only (0 for every other type; System::addBody refuses anything else): the radius
                       // of the sphere that sweeps the hull, as Bullet's collision margin does (its support adds
                       // margin d/|d| to the points' support: btConvexInternalShape::localGetSupportingVertex). Kept
                       // in the record, never added to the points, so the support scan stays over the bare points.
};
// `margin` took the place of a 32-bit pad: the record (copied to the GPU as it is) did not grow.
static_assert(sizeof(Shape) == (sizeof(real) == 8 ? 120 : 72), "Shape record size changed");

// Bullet's filter test, with both directions required (btOverlapFilterCallback default).
DVI_HD bool groupsCollide(const Shape& a, const Shape& b) { return (a.group & b.mask) != 0 && (b.group & a.mask) != 0; }

// Radius of a sphere about the shape origin that bounds the shape (not used for planes).
DVI_HD real boundingRadius(const Shape& s, const Vec3* hull_points) {
  switch (s.type) {
    case ShapeType::Sphere: return s.dims.x;
    case ShapeType::Ellipsoid: return maxComponent(s.dims);
    case ShapeType::Box: return length(s.dims);
    case ShapeType::Cylinder: return std::sqrt(s.dims.x * s.dims.x + s.dims.y * s.dims.y);
    case ShapeType::Capsule: return s.dims.x + s.dims.y;
    case ShapeType::Cone: return std::sqrt(s.dims.x * s.dims.x + real(0.25) * s.dims.y * s.dims.y);
    case ShapeType::ConvexHull: {  // the farthest point, plus the sweep (the sphere around it)
      real r2 = 0;
      for (int i = 0; i < s.hull_count; ++i) r2 = fmax(r2, length2(hull_points[s.hull_start + i]));
      return std::sqrt(r2) + real(s.margin);
    }
    case ShapeType::Triangle: {  // vertices as in collide_triangle.h (centroid at the origin)
      const real a = s.dims.x * s.dims.x + s.dims.y * s.dims.y, b = s.dims.z * s.dims.z + s.plane_d * s.plane_d;
      const real cx = s.dims.x + s.dims.z, cz = s.dims.y + s.plane_d;
      return std::sqrt(fmax(fmax(a, b), cx * cx + cz * cz));
    }
    default: return real(0);
  }
}

}  // namespace dvi
