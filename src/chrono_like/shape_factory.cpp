// ShapeDesc factory helpers (system.h): canonical primitives (axis Y) at a local pose in the body frame.
// Each sets Shape::size, the characteristic length that makes the collision envelope and the recovery
// speed relative to the body (the smallest half-dimension; the radius for a sphere), and Bullet's
// default collision filter (group 1, mask all).
#include <algorithm>
#include <cmath>
#include <limits>

#include "chrono_like/system.h"

namespace dvi {

namespace {

ShapeDesc base(ShapeType type, Pose local, Vec3 dims, real size) {
  ShapeDesc d;
  d.shape = Shape{};
  d.shape.type = type;
  d.shape.body = -1;
  d.shape.hull_start = 0;
  d.shape.hull_count = 0;
  d.shape.local = local;
  d.shape.dims = dims;
  d.shape.plane_d = 0;
  d.shape.size = size;
  d.shape.group = 1;
  d.shape.mask = -1;  // 0xFFFF: collides with every group
  d.shape.margin = 0;
  return d;
}

}  // namespace

ShapeDesc makeSphere(real r, Pose local) { return base(ShapeType::Sphere, local, {r, r, r}, r); }

ShapeDesc makeBox(Vec3 half, Pose local) { return base(ShapeType::Box, local, half, minComponent(half)); }

ShapeDesc makeCylinder(real r, real half_height, Pose local) {
  return base(ShapeType::Cylinder, local, {r, half_height, r}, std::fmin(r, half_height));
}

ShapeDesc makeCapsule(real r, real half_length, Pose local) {
  return base(ShapeType::Capsule, local, {r, half_length, r}, r);
}

ShapeDesc makeCone(real r, real height, Pose local) {
  return base(ShapeType::Cone, local, {r, height, r}, std::fmin(r, real(0.5) * height));
}

ShapeDesc makeEllipsoid(Vec3 semi_axes, Pose local) {
  return base(ShapeType::Ellipsoid, local, semi_axes, minComponent(semi_axes));
}

// dims of a hull: the half extents of its points' local bounding box; size: the smallest of them plus the margin
// (the swept hull's smallest half extent). The margin is stored as given: System::addBody refuses a negative or
// non-finite one.
ShapeDesc makeConvexHull(std::vector<Vec3> points, Pose local, real margin) {
  Vec3 lo{0, 0, 0}, hi{0, 0, 0};
  if (!points.empty()) {
    lo = hi = points[0];
    for (const Vec3& p : points) {
      lo = vmin(lo, p);
      hi = vmax(hi, p);
    }
  }
  const Vec3 half = (hi - lo) * real(0.5);
  ShapeDesc d = base(ShapeType::ConvexHull, local, half, minComponent(half) + margin);
  d.shape.margin = float(margin);
  d.shape.hull_count = int32_t(points.size());
  d.hull = std::move(points);
  return d;
}

// Half-space {x : dot(n, x) <= d}; n is normalised here (a zero normal stays zero and is refused by
// System::addBody). A plane has no finite size: 1e30, so that a pair's size is the other shape's.
ShapeDesc makePlane(Vec3 normal, real d) {
  const real len = length(normal);
  Vec3 n = len > 0 ? normal / len : normal;
  real dd = len > 0 ? d / len : d;
  ShapeDesc s = base(ShapeType::Plane, Pose{{0, 0, 0}, {1, 0, 0, 0}}, n, real(1e30));
  s.shape.plane_d = dd;
  return s;
}

}  // namespace dvi
