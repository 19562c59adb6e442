// Static triangle geometry from Bullet (triangle_mesh.h).
#include "chrono_like/bullet/triangle_mesh.h"
#include "chrono_like/bullet/bullet_convert.h"

#include <btBulletDynamicsCommon.h>
#include <BulletCollision/CollisionShapes/btConcaveShape.h>
#include <BulletCollision/CollisionShapes/btTriangleCallback.h>

#include <cmath>

#include "chrono_like/bullet/bullet_import.h"

namespace dvi {

namespace {

bool isTriangleShape(int type) {
  return type == TRIANGLE_MESH_SHAPE_PROXYTYPE || type == SCALED_TRIANGLE_MESH_SHAPE_PROXYTYPE ||
         type == TERRAIN_SHAPE_PROXYTYPE;
}

class Collect final : public btTriangleCallback {
 public:
  Collect(const Pose& local, std::vector<ShapeDesc>& out) : local_(local), out_(out) {}
  void processTriangle(btVector3* t, int, int) override {
    ShapeDesc d;
    if (makeTriangle(fromBt(t[0]), fromBt(t[1]), fromBt(t[2]), local_, d)) out_.push_back(d);
  }

 private:
  Pose local_;
  std::vector<ShapeDesc>& out_;
};

}  // namespace

Quat quatFromBasis(Vec3 x, Vec3 y, Vec3 z) {
  // Shepperd's method on the matrix with columns x, y, z.
  const real m00 = x.x, m11 = y.y, m22 = z.z;
  const real tr = m00 + m11 + m22;
  Quat q;
  if (tr > 0) {
    real s = std::sqrt(tr + 1) * 2;
    q = Quat{real(0.25) * s, (y.z - z.y) / s, (z.x - x.z) / s, (x.y - y.x) / s};
  } else if (m00 > m11 && m00 > m22) {
    real s = std::sqrt(1 + m00 - m11 - m22) * 2;
    q = Quat{(y.z - z.y) / s, real(0.25) * s, (y.x + x.y) / s, (z.x + x.z) / s};
  } else if (m11 > m22) {
    real s = std::sqrt(1 + m11 - m00 - m22) * 2;
    q = Quat{(z.x - x.z) / s, (y.x + x.y) / s, real(0.25) * s, (z.y + y.z) / s};
  } else {
    real s = std::sqrt(1 + m22 - m00 - m11) * 2;
    q = Quat{(x.y - y.x) / s, (z.x + x.z) / s, (z.y + y.z) / s, real(0.25) * s};
  }
  return normalized(q);
}

bool makeTriangle(Vec3 a, Vec3 b, Vec3 c, const Pose& local, ShapeDesc& out) {
  const Vec3 n = cross(b - a, c - a);
  const real area2 = length(n);
  const real perim = length(b - a) + length(c - b) + length(a - c);
  if (!(area2 > real(1e-12) * perim * perim) || !std::isfinite(area2)) return false;
  const Vec3 y = n / area2;
  const Vec3 x = normalized(b - a);
  const Vec3 z = cross(x, y);
  const Vec3 cen = (a + b + c) / real(3);
  const Quat q = quatFromBasis(x, y, z);
  const Vec3 p0 = rotateInv(q, a - cen), p1 = rotateInv(q, b - cen);
  ShapeDesc d;
  d.shape = Shape{};
  d.shape.type = ShapeType::Triangle;
  d.shape.body = -1;
  d.shape.local = compose(local, Pose{cen, q});
  d.shape.dims = Vec3{p0.x, p0.z, p1.x};
  d.shape.plane_d = p1.z;
  d.shape.size = area2 / perim;  // inradius = area / semi-perimeter
  d.shape.group = 1;
  d.shape.mask = -1;
  out = d;
  return true;
}

bool hasTriangles(const btCollisionShape& shape) {
  if (isTriangleShape(shape.getShapeType())) return true;
  if (shape.getShapeType() == COMPOUND_SHAPE_PROXYTYPE) {
    const auto& s = static_cast<const btCompoundShape&>(shape);
    for (int i = 0; i < s.getNumChildShapes(); ++i)
      if (s.getChildShape(i) && hasTriangles(*s.getChildShape(i))) return true;
  }
  return false;
}

void appendShapesWithTriangles(const btCollisionShape& shape, const Pose& local, std::vector<ShapeDesc>& out) {
  if (isTriangleShape(shape.getShapeType())) {
    const auto& s = static_cast<const btConcaveShape&>(shape);
    btTransform id;
    id.setIdentity();
    btVector3 lo, hi;
    s.getAabb(id, lo, hi);
    const btVector3 pad(1, 1, 1);
    Collect collect(local, out);
    const size_t before = out.size();
    s.processAllTriangles(&collect, lo - pad, hi + pad);
    if (out.size() == before)
      throw InputError(std::string("triangle shape without a non-degenerate triangle: ") + shape.getName());
    return;
  }
  if (shape.getShapeType() == COMPOUND_SHAPE_PROXYTYPE && hasTriangles(shape)) {
    const auto& s = static_cast<const btCompoundShape&>(shape);
    for (int i = 0; i < s.getNumChildShapes(); ++i)
      if (const btCollisionShape* child = s.getChildShape(i))
        appendShapesWithTriangles(*child, compose(local, fromBt(s.getChildTransform(i))), out);
    return;
  }
  appendShapesFromBullet(shape, local, out);
}

}  // namespace dvi
