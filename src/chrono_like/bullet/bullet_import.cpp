// The Bullet bridge (bullet_import.h): btRigidBody + btCollisionShape -> BodyDesc, and back.
//
// Dimensions follow what Bullet collides with:
//  - box and cylinder: Bullet stores the dimensions minus the margin and adds the margin back in its
//    support function, so the full extents are getHalfExtentsWithMargin();
//  - sphere, capsule and multi-sphere: the radius is the whole shape (the margin is inside it);
//  - cone: the user's geometry (getRadius/getHeight). Bullet grows it by the margin on the outside; we take
//    the geometry as given, without that shell;
//  - convex hull: the scaled points with Bullet's margin as the record's sphere-swept radius (Shape::margin),
//    the shape Bullet collides (hullFromBullet).
// Axis-symmetric shapes are canonical along +Y here; Bullet's X and Z variants become a child pose
// rotated so that the record's +Y maps onto Bullet's up axis (a cone keeps its apex at +height/2).
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/bullet/bullet_convert.h"

#include <btBulletDynamicsCommon.h>
#include <BulletCollision/CollisionShapes/btBox2dShape.h>
#include <BulletCollision/CollisionShapes/btConvex2dShape.h>
#include <BulletCollision/CollisionShapes/btConvexPointCloudShape.h>
#include <BulletCollision/CollisionShapes/btConvexTriangleMeshShape.h>
#include <BulletCollision/CollisionShapes/btMultiSphereShape.h>
#include <BulletCollision/CollisionShapes/btTriangleShape.h>
#include <BulletCollision/CollisionShapes/btUniformScalingShape.h>

#include <algorithm>
#include <cmath>
#include <string>

namespace dvi {

namespace {

// Rotation taking the canonical axis +Y onto Bullet's up axis (0 = X, 1 = Y, 2 = Z).
Quat upAxisRotation(int up) {
  const real h = std::sqrt(real(0.5));
  switch (up) {
    case 0: return Quat{h, 0, 0, -h};  // -90 deg about Z: +Y -> +X
    case 2: return Quat{h, h, 0, 0};   // +90 deg about X: +Y -> +Z
    default: return Quat{1, 0, 0, 0};
  }
}

Pose withUpAxis(const Pose& local, int up) { return Pose{local.p, local.q * upAxisRotation(up)}; }

bool uniform(const btVector3& s) {
  const btScalar m = std::fabs(s.x());
  return std::fabs(std::fabs(s.y()) - m) <= 1e-6f * m && std::fabs(std::fabs(s.z()) - m) <= 1e-6f * m;
}

// A convex set of points swept by Bullet's margin (btConvexPointCloudShape, btTriangleShape): a hull record. The
// System's hulls take at least 4 points; fewer (a triangle, Planar2D's flat hull) repeat the first point (the support
// is the same set). A margin that is not a positive finite number is taken as 0.
ShapeDesc pointsFromBullet(std::vector<Vec3> pts, btScalar margin, const Pose& local) {
  if (pts.empty()) throw InputError("convex point set without points");
  while (pts.size() < 4) pts.push_back(pts.front());
  return makeConvexHull(std::move(pts), local, margin > 0 && std::isfinite(double(margin)) ? real(margin) : real(0));
}

// A btConvexHullShape collides as its points swept by a sphere of radius getMargin() (0.04 by default): Bullet's
// support adds margin * d/|d| to the points' support (btConvexInternalShape::localGetSupportingVertex). The System's
// hull is the same shape: the bare (scaled) points and Shape::margin = that margin, which the support functions carry
// (collision/support.h: sweptTerm). A margin that is not a positive finite number (a .bullet file can hold anything)
// is taken as 0, the bare points, as before this bridge carried margins; a point that is not finite is handed on as it
// is, and the System refuses the hull with an InputError naming the body.
ShapeDesc hullFromBullet(const btConvexHullShape& s, const Pose& local) {
  std::vector<Vec3> pts;
  pts.reserve(size_t(s.getNumPoints()));
  for (int i = 0; i < s.getNumPoints(); ++i) pts.push_back(fromBt(s.getScaledPoint(i)));
  return pointsFromBullet(std::move(pts), s.getMargin(), local);
}

// btConvexTriangleMeshShape: the convex hull of its mesh's vertices (scaled by the mesh interface, as Bullet's support
// reads them), swept by its margin.
ShapeDesc trimeshHullFromBullet(const btConvexTriangleMeshShape& s, const Pose& local) {
  struct Collect final : btInternalTriangleIndexCallback {
    std::vector<Vec3> pts;
    void internalProcessTriangleIndex(btVector3* t, int, int) override {
      for (int i = 0; i < 3; ++i) pts.push_back(fromBt(t[i]));
    }
  } collect;
  const btScalar big = btScalar(BT_LARGE_FLOAT);
  s.getMeshInterface()->InternalProcessAllTriangles(&collect, btVector3(-big, -big, -big), btVector3(big, big, big));
  std::vector<Vec3>& p = collect.pts;
  std::sort(p.begin(), p.end(), [](Vec3 a, Vec3 b) {
    return a.x != b.x ? a.x < b.x : a.y != b.y ? a.y < b.y : a.z < b.z;
  });
  p.erase(std::unique(p.begin(), p.end(), [](Vec3 a, Vec3 b) { return sameVec(a, b); }), p.end());
  return pointsFromBullet(std::move(p), s.getMargin(), local);
}

// btUniformScalingShape: the child's support times the factor (btUniformScalingShape::localGetSupportingVertex), so
// every length of the child's records (dimensions, offsets, hull points, margins) is scaled by it.
void appendScaled(const btUniformScalingShape& s, const Pose& local, std::vector<ShapeDesc>& out) {
  const real f = real(s.getUniformScalingFactor());
  if (!(f > 0) || !std::isfinite(f)) throw InputError("UniformScalingShape: scaling factor must be > 0");
  std::vector<ShapeDesc> child;
  appendShapesFromBullet(*s.getChildShape(), Pose{{0, 0, 0}, {1, 0, 0, 0}}, child);
  for (ShapeDesc& d : child) {
    Shape& c = d.shape;
    c.dims = c.type == ShapeType::Plane ? c.dims : c.dims * f;
    c.plane_d *= f;
    c.margin *= float(f);
    c.size *= f;
    for (Vec3& p : d.hull) p = p * f;
    c.local = compose(local, Pose{c.local.p * f, c.local.q});
    out.push_back(std::move(d));
  }
}

// The convex wrappers and point sets of Bullet's examples (Planar2D's btConvex2dShape and btBox2dShape, ...) and the
// other convex shapes of Bullet's set (btConvexTriangleMeshShape); false for any other type.
bool appendOtherConvex(const btCollisionShape& shape, const Pose& local, std::vector<ShapeDesc>& out) {
  switch (shape.getShapeType()) {
    case BOX_2D_SHAPE_PROXYTYPE: {  // its support is the whole box, z included (btBox2dShape::localGetSupportingVertex)
      const auto& s = static_cast<const btBox2dShape&>(shape);
      out.push_back(makeBox(fromBt(s.getHalfExtentsWithMargin()), local));
      return true;
    }
    case CONVEX_2D_SHAPE_PROXYTYPE: {  // the child's support (btConvex2dShape); the plane is the bodies' factors
      const auto& s = static_cast<const btConvex2dShape&>(shape);
      if (!s.getChildShape()) throw InputError("Convex2dShape without a child shape");
      appendShapesFromBullet(*s.getChildShape(), local, out);
      return true;
    }
    case UNIFORM_SCALING_SHAPE_PROXYTYPE: {
      appendScaled(static_cast<const btUniformScalingShape&>(shape), local, out);
      return true;
    }
    case CONVEX_POINT_CLOUD_SHAPE_PROXYTYPE: {
      const auto& s = static_cast<const btConvexPointCloudShape&>(shape);
      std::vector<Vec3> pts;
      for (int i = 0; i < s.getNumPoints(); ++i) pts.push_back(fromBt(s.getScaledPoint(i)));
      out.push_back(pointsFromBullet(std::move(pts), s.getMargin(), local));
      return true;
    }
    case CONVEX_TRIANGLEMESH_SHAPE_PROXYTYPE: {
      out.push_back(trimeshHullFromBullet(static_cast<const btConvexTriangleMeshShape&>(shape), local));
      return true;
    }
    case TRIANGLE_SHAPE_PROXYTYPE: {  // a convex triangle (btTriangleShape), e.g. a child of a compound
      const auto& s = static_cast<const btTriangleShape&>(shape);
      std::vector<Vec3> pts;
      for (int i = 0; i < 3; ++i) pts.push_back(fromBt(s.m_vertices1[i]));
      out.push_back(pointsFromBullet(std::move(pts), s.getMargin(), local));
      return true;
    }
    default: return false;
  }
}

}  // namespace

void appendShapesFromBullet(const btCollisionShape& shape, const Pose& local, std::vector<ShapeDesc>& out) {
  switch (shape.getShapeType()) {
    case SPHERE_SHAPE_PROXYTYPE: {
      const auto& s = static_cast<const btSphereShape&>(shape);
      out.push_back(makeSphere(real(s.getRadius()), local));
      return;
    }
    case BOX_SHAPE_PROXYTYPE: {
      const auto& s = static_cast<const btBoxShape&>(shape);
      out.push_back(makeBox(fromBt(s.getHalfExtentsWithMargin()), local));
      return;
    }
    case CYLINDER_SHAPE_PROXYTYPE: {
      const auto& s = static_cast<const btCylinderShape&>(shape);
      const int up = s.getUpAxis();
      const btVector3 he = s.getHalfExtentsWithMargin();
      const real radius = real(up == 0 ? he.y() : he.x());
      out.push_back(makeCylinder(radius, real(he[up]), withUpAxis(local, up)));
      return;
    }
    case CAPSULE_SHAPE_PROXYTYPE: {
      const auto& s = static_cast<const btCapsuleShape&>(shape);
      const int up = s.getUpAxis();
      out.push_back(makeCapsule(real(s.getRadius()), real(s.getHalfHeight()), withUpAxis(local, up)));
      return;
    }
    case CONE_SHAPE_PROXYTYPE: {
      const auto& s = static_cast<const btConeShape&>(shape);
      const int up = s.getConeUpIndex();
      out.push_back(makeCone(real(s.getRadius()), real(s.getHeight()), withUpAxis(local, up)));
      return;
    }
    case CONVEX_HULL_SHAPE_PROXYTYPE: {
      const auto& s = static_cast<const btConvexHullShape&>(shape);
      out.push_back(hullFromBullet(s, local));
      return;
    }
    case MULTI_SPHERE_SHAPE_PROXYTYPE: {
      const auto& s = static_cast<const btMultiSphereShape&>(shape);
      const btVector3 scale = s.getLocalScaling();
      const bool round = uniform(scale);
      for (int i = 0; i < s.getSphereCount(); ++i) {
        const Vec3 center = fromBt(s.getSpherePosition(i) * scale);
        const Pose p{transformPoint(local, center), local.q};
        const real r = real(s.getSphereRadius(i));
        // A sphere scaled non-uniformly is an ellipsoid (Bullet scales the radius per axis).
        if (round)
          out.push_back(makeSphere(r * real(std::fabs(scale.x())), p));
        else
          out.push_back(makeEllipsoid(vabs(fromBt(scale)) * r, p));
      }
      return;
    }
    case COMPOUND_SHAPE_PROXYTYPE: {
      const auto& s = static_cast<const btCompoundShape&>(shape);
      for (int i = 0; i < s.getNumChildShapes(); ++i) {
        const btCollisionShape* child = s.getChildShape(i);
        if (!child) continue;
        appendShapesFromBullet(*child, compose(local, fromBt(s.getChildTransform(i))), out);
      }
      return;
    }
    case STATIC_PLANE_PROXYTYPE: {
      const auto& s = static_cast<const btStaticPlaneShape&>(shape);
      // The plane in the body frame: n.x <= c becomes (R n).x <= c + (R n).p after the pose.
      const Vec3 n = normalized(fromBt(s.getPlaneNormal()));
      const Vec3 nw = rotate(local.q, n);
      out.push_back(makePlane(nw, real(s.getPlaneConstant()) + dot(nw, local.p)));
      return;
    }
    default:
      if (!appendOtherConvex(shape, local, out))
        throw InputError(std::string("unsupported collision shape: ") + shape.getName());
  }
}

BodyDesc bodyMotionFromBullet(const btRigidBody& body) {
  BodyDesc d;
  const btTransform& t = body.getCenterOfMassTransform();
  d.pos = fromBt(t.getOrigin());
  d.rot = fromBt(t.getRotation());
  d.vel = fromBt(body.getLinearVelocity());
  d.omega = fromBt(body.getAngularVelocity());
  d.friction = real(body.getFriction());
  d.restitution = real(body.getRestitution());
  d.rolling_friction = real(body.getRollingFriction());
  d.spinning_friction = real(body.getSpinningFriction());
  return d;
}

BodyDesc bodyDescFromBullet(const btRigidBody& body) {
  BodyDesc d = bodyMotionFromBullet(body);
  d.flags = 0;
  if (body.isStaticObject() || body.getInvMass() == 0) {
    d.flags = body.isKinematicObject() ? kBodyKinematic : kBodyFixed;
  }
  if (body.isKinematicObject()) d.flags = kBodyKinematic;
  if (d.flags) {
    d.mass = 0;
    d.inertia = Vec3{0, 0, 0};
  } else {
    d.mass = real(1) / real(body.getInvMass());
    // An inverse inertia of 0 (an axis Bullet keeps from turning) is an infinite moment: stored as a
    // huge finite one so that the system's inverse is ~0 and still finite.
    const btVector3 inv = body.getInvInertiaDiagLocal();
    auto moment = [](btScalar x) { return x > 0 ? real(1) / real(x) : real(1e30); };
    d.inertia = Vec3{moment(inv.x()), moment(inv.y()), moment(inv.z())};
  }
  // Bullet overwrites a body's gravity with the world's unless the body opts out.
  d.gravity = fromBt(body.getGravity());
  d.has_gravity = (body.getFlags() & BT_DISABLE_WORLD_GRAVITY) != 0;

  const btCollisionShape* shape = body.getCollisionShape();
  if (!shape) throw InputError("rigid body without a collision shape");
  appendShapesFromBullet(*shape, Pose{{0, 0, 0}, {1, 0, 0, 0}}, d.shapes);
  if (d.shapes.empty()) throw InputError(std::string("collision shape has no convex children: ") + shape->getName());

  int16_t group = 1, mask = -1;
  if (const btBroadphaseProxy* proxy = body.getBroadphaseHandle()) {
    group = int16_t(proxy->m_collisionFilterGroup);
    mask = int16_t(proxy->m_collisionFilterMask);
  }
  for (ShapeDesc& s : d.shapes) {
    s.shape.group = group;
    s.shape.mask = mask;
  }
  return d;
}

BodyDesc bodyDescForSystem(const btRigidBody* body, size_t index, Vec3 gravity) {
  if (!body) throw InputError("rigid body " + std::to_string(index) + " is null");
  BodyDesc d;
  try {
    d = bodyDescFromBullet(*body);
  } catch (const InputError& e) { throw InputError("rigid body " + std::to_string(index) + ": " + e.what()); }
  // A body living in a world whose gravity differs from the system's keeps its own (Bullet allows
  // per-body gravity). A body never added to a world has zero gravity in Bullet and takes the system's.
  if (!d.has_gravity && body->getBroadphaseHandle()) {
    const Vec3 diff = d.gravity - gravity;
    if (length(diff) > real(1e-6) * (length(gravity) + 1)) d.has_gravity = true;
  }
  return d;
}

std::vector<int> importBullet(System& system, const std::vector<btRigidBody*>& bodies) {
  std::vector<int> ids;
  ids.reserve(bodies.size());
  const Vec3 g = system.config().step.gravity;
  for (size_t i = 0; i < bodies.size(); ++i) ids.push_back(system.addBody(bodyDescForSystem(bodies[i], i, g)));
  return ids;
}

void writeBackToBullet(const System& system, const std::vector<int>& indices, const std::vector<btRigidBody*>& bodies) {
  const BodyArrays& b = system.bodies();
  const size_t n = std::min(indices.size(), bodies.size());
  for (size_t i = 0; i < n; ++i) {
    btRigidBody* body = bodies[i];
    const int k = indices[i];
    if (!body || k < 0 || size_t(k) >= b.count()) continue;
    btTransform t;
    t.setOrigin(toBt(b.pos[size_t(k)]));
    t.setRotation(toBt(b.rot[size_t(k)]));
    body->setCenterOfMassTransform(t);
    body->setInterpolationWorldTransform(t);
    if (btMotionState* ms = body->getMotionState()) ms->setWorldTransform(t);
    if (!body->isStaticObject()) {
      body->setLinearVelocity(toBt(b.vel[size_t(k)]));
      body->setAngularVelocity(toBt(b.omega[size_t(k)]));
      body->setInterpolationLinearVelocity(toBt(b.vel[size_t(k)]));
      body->setInterpolationAngularVelocity(toBt(b.omega[size_t(k)]));
    }
  }
}

}  // namespace dvi
