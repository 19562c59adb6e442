// Bullet collision backend (bullet_collision_backend.h, collision.h): Bullet's own CPU pipeline
// (btDbvtBroadphase + btCollisionDispatcher with btDefaultCollisionConfiguration: analytic sphere pairs,
// ODE's box-box, convex-plane, GJK/EPA) run on OUR shape records, kept as the reference backend.
//
// Objects: one btCollisionObject per body holding all of its non-plane shapes (a btCompoundShape with
// child transforms Shape::local when there are several, else the single shape with the object placed at
// body pose * local), plus one object per plane shape. Objects persist between detect() calls, so
// Bullet's persistent manifolds (and their contact points) persist too; they are rebuilt only when the
// shape records, the body flags or envelope_rel change (body/shape count included).
//
// Tolerances are made relative to the bodies instead of Bullet's absolute ones:
//   - every manifold gets contact breaking and processing thresholds = envelope_rel x (the larger shape
//     size of the smaller object) (overriding getNewManifold, so the global gContactBreakingThreshold is
//     not used for points), and the near callback asks the algorithms for points up to that distance
//     (btManifoldResult::m_closestPointDistanceThreshold), except for compounds (see relativeNearCallback:
//     there sphere-sphere children report points only once they touch; other child pairs still report
//     points up to the breaking threshold);
//   - each point is then kept only if dist < envelope_rel x min(size_a, size_b) of ITS shape pair;
//   - broad-phase boxes are our own (shape AABB + envelope_rel x size), given to the dbvt directly
//     instead of btCollisionWorld::updateAabbs, which pads by the absolute gContactBreakingThreshold,
//     and with setAabbForceUpdate, which skips the dbvt's absolute 0.05 fattening of moved leaves; pairs
//     whose boxes separate are dropped every call (m_cupdates = 100). With Bullet's defaults, 1,000
//     resting 1 cm spheres in metres gave 258k overlapping pairs and 55 ms per call here; with these,
//     4.6k pairs (as the native broad phase) and 16 ms.
//   - convex margins (box, cylinder, cone, hull, ellipsoid) are min(0.04, 0.04 x size) instead of 0.04.
//     Box and cylinder keep their exact extents (rounded edges of that radius); cone and hull are
//     inflated by the margin (Bullet adds it outside); sphere and capsule are exact (margin = radius). A hull
//     with its own margin (Shape::margin) gets that one: Bullet then collides exactly the native shape.
//   - multi-point manifolds against planes in one call (setPlaneConvexMultipointIterations; Bullet
//     perturbs only polyhedral shapes there): a box on a plane gets 3 of its corners in the first call
//     instead of one point per call. Convex-convex pairs keep Bullet's default of one new point per call
//     (the manifold fills up over calls; box-box uses btBoxBoxDetector, up to 4 points at once): its
//     perturbation would add near-duplicate points to sphere-box and sphere-hull contacts.
// Known Bullet limitations kept as they are: box-box (btBoxBoxDetector) reports no point for separated
// boxes (no envelope); an ellipsoid is a non-uniformly scaled btMultiSphereShape whose support point is
// approximate.
//
// Convention: Bullet's m_normalWorldOnB points from B to A (pointA = pointB + normalOnB * distance);
// ours points from A to B, so normal = -m_normalWorldOnB, pa = positionWorldOnA, pb = positionWorldOnB,
// dist = getDistance() = dot(pb - pa, normal).
#include "chrono_like/bullet/bullet_collision_backend.h"

#include <btBulletCollisionCommon.h>

#include <algorithm>
#include <chrono>
#include <limits>
#include <string>

#include "chrono_like/base/errors.h"
#include "chrono_like/bullet/bullet_convert.h"
#include "chrono_like/collision/broadphase.h"
#include "chrono_like/collision/collision.h"
#include "chrono_like/collision/contact.h"

namespace dvi {

namespace {

using Clock = std::chrono::steady_clock;
double seconds(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); }

// Characteristic length of a shape: Shape::size when set, else the smallest half-dimension; a plane has
// no size (infinite), so a pair with a plane uses the other shape's size.
real shapeSize(const Shape& s, const std::vector<Vec3>& hull) {
  if (s.type == ShapeType::Plane) return s.size > 0 ? s.size : std::numeric_limits<real>::infinity();
  if (s.size > 0) return s.size;
  switch (s.type) {
    case ShapeType::Sphere: return s.dims.x;
    case ShapeType::Ellipsoid:
    case ShapeType::Box: return minComponent(s.dims);
    case ShapeType::Cylinder:
    case ShapeType::Capsule: return s.type == ShapeType::Capsule ? s.dims.x : fmin(s.dims.x, s.dims.y);
    case ShapeType::Cone: return fmin(s.dims.x, real(0.5) * s.dims.y);
    case ShapeType::ConvexHull: {
      if (s.hull_count <= 0) return real(0);
      Vec3 lo = hull[size_t(s.hull_start)], hi = lo;
      for (int i = 1; i < s.hull_count; ++i) {
        lo = vmin(lo, hull[size_t(s.hull_start + i)]);
        hi = vmax(hi, hull[size_t(s.hull_start + i)]);
      }
      return real(0.5) * minComponent(hi - lo) + real(s.margin);  // the swept hull's
    }
    default: return real(0);
  }
}

bool sameShape(const Shape& a, const Shape& b) {
  return a.type == b.type && a.body == b.body && a.hull_start == b.hull_start && a.hull_count == b.hull_count &&
         a.local.p.x == b.local.p.x && a.local.p.y == b.local.p.y && a.local.p.z == b.local.p.z &&
         a.local.q.w == b.local.q.w && a.local.q.x == b.local.q.x && a.local.q.y == b.local.q.y &&
         a.local.q.z == b.local.q.z && a.dims.x == b.dims.x && a.dims.y == b.dims.y && a.dims.z == b.dims.z &&
         a.plane_d == b.plane_d && a.size == b.size && a.group == b.group && a.mask == b.mask && a.margin == b.margin;
}

class BulletCollision;

// Broad-phase filter: pairAllowed at object level (different bodies, not both immovable, some pair of
// their shapes whose groups collide).
struct ObjectFilter : btOverlapFilterCallback {
  const BulletCollision* owner = nullptr;
  bool needBroadphaseCollision(btBroadphaseProxy* p0, btBroadphaseProxy* p1) const override;
};

// Sets relative contact thresholds on every new manifold.
class RelativeDispatcher : public btCollisionDispatcher {
 public:
  RelativeDispatcher(btCollisionConfiguration* c, const BulletCollision* owner)
      : btCollisionDispatcher(c), owner_(owner) {}
  btPersistentManifold* getNewManifold(const btCollisionObject* b0, const btCollisionObject* b1) override;
  const BulletCollision* owner() const { return owner_; }

 private:
  const BulletCollision* owner_;
};

struct ObjectInfo {
  int32_t body = -1;
  std::vector<int32_t> shapes;  // our shape indices; child i of a compound is shapes[i]
  bool compound = false;
  real thresh_size = 0;  // largest shape size of the object (threshold of its manifolds)
};

class BulletCollision final : public CollisionDetector {
 public:
  BulletCollision() { filter_.owner = this; }
  ~BulletCollision() override { destroyWorld(); }
  const char* name() const override { return "bullet"; }

  void detect(const BodyArrays& bodies, ShapeArrays& shapes, const CollisionSettings& config, const StepContext& step,
              ContactArrays& out, CollisionTimes& times) override;

  // Distance up to which points of objects i and j are generated and kept in their manifold.
  btScalar pairThreshold(int i, int j) const {
    real s = fmin(objects_[size_t(i)].thresh_size, objects_[size_t(j)].thresh_size);
    if (!std::isfinite(s)) return 0;
    return btScalar(envelope_rel_ * s);
  }
  bool objectsMayCollide(int i, int j) const {
    const ObjectInfo& a = objects_[size_t(i)];
    const ObjectInfo& b = objects_[size_t(j)];
    for (int32_t sa : a.shapes)
      for (int32_t sb : b.shapes)
        if (pairAllowed(shapes_[size_t(sa)], shapes_[size_t(sb)], flags_[size_t(a.body)], flags_[size_t(b.body)]))
          return true;
    return false;
  }

 private:
  bool needsRebuild(const BodyArrays& bodies, const ShapeArrays& shapes, const CollisionSettings& config) const;
  void rebuild(const BodyArrays& bodies, const ShapeArrays& shapes, const CollisionSettings& config);
  void destroyWorld();
  void updateAabbs(const BodyArrays& bodies, ShapeArrays& shapes, real rel);
  void collectManifoldPoints(const BodyArrays& bodies, const ShapeArrays& shapes, real rel);
  void writeContacts(const ShapeArrays& shapes, ContactArrays& out) const;
  btCollisionShape* makeShape(const Shape& s, const std::vector<Vec3>& hull, real size);
  int32_t shapeOf(int object, int child_index) const {
    const ObjectInfo& o = objects_[size_t(object)];
    if (!o.compound) return o.shapes[0];
    if (child_index < 0 || size_t(child_index) >= o.shapes.size()) return -1;
    return o.shapes[size_t(child_index)];
  }

  // The state the objects were built from (rebuild check; also read by the filter callbacks).
  std::vector<Shape> shapes_;
  std::vector<uint8_t> flags_;
  std::vector<real> sizes_;  // shapeSize of each shape
  size_t hull_point_count_ = 0;
  real envelope_rel_ = -1;
  bool built_ = false;

  std::unique_ptr<btDefaultCollisionConfiguration> config_;
  std::unique_ptr<RelativeDispatcher> dispatcher_;
  std::unique_ptr<btDbvtBroadphase> broadphase_;
  std::unique_ptr<btCollisionWorld> world_;
  ObjectFilter filter_;
  std::vector<std::unique_ptr<btCollisionShape>> owned_shapes_;
  std::vector<std::unique_ptr<btCollisionObject>> bt_objects_;
  std::vector<ObjectInfo> objects_;
  std::vector<btCollisionShape*> shape_bt_;  // Bullet shape of each of our shapes (child of a compound or not)

  struct Raw {
    int32_t sa, sb, manifold, point;
    Vec3 normal, pa, pb;
    real dist;
  };
  std::vector<Raw> raw_;
};

bool ObjectFilter::needBroadphaseCollision(btBroadphaseProxy* p0, btBroadphaseProxy* p1) const {
  auto* o0 = static_cast<const btCollisionObject*>(p0->m_clientObject);
  auto* o1 = static_cast<const btCollisionObject*>(p1->m_clientObject);
  return owner->objectsMayCollide(o0->getUserIndex(), o1->getUserIndex());
}

btPersistentManifold* RelativeDispatcher::getNewManifold(const btCollisionObject* b0, const btCollisionObject* b1) {
  btPersistentManifold* m = btCollisionDispatcher::getNewManifold(b0, b1);
  const btScalar t = owner_->pairThreshold(b0->getUserIndex(), b1->getUserIndex());
  m->setContactBreakingThreshold(t);
  m->setContactProcessingThreshold(t);
  return m;
}

// btCollisionDispatcher::defaultNearCallback, plus the distance up to which points are wanted.
void relativeNearCallback(btBroadphasePair& pair, btCollisionDispatcher& dispatcher, const btDispatcherInfo& info) {
  auto* o0 = static_cast<const btCollisionObject*>(pair.m_pProxy0->m_clientObject);
  auto* o1 = static_cast<const btCollisionObject*>(pair.m_pProxy1->m_clientObject);
  if (!dispatcher.needsCollision(o0, o1)) return;
  btCollisionObjectWrapper w0(nullptr, o0->getCollisionShape(), o0, o0->getWorldTransform(), -1, -1);
  btCollisionObjectWrapper w1(nullptr, o1->getCollisionShape(), o1, o1->getWorldTransform(), -1, -1);
  if (!pair.m_algorithm) pair.m_algorithm = dispatcher.findAlgorithm(&w0, &w1, nullptr, BT_CONTACT_POINT_ALGORITHMS);
  if (!pair.m_algorithm) return;
  btManifoldResult result(&w0, &w1);
  result.setShapeIdentifiersA(-1, -1);  // left uninitialised by Bullet outside DEBUG_PART_INDEX builds
  result.setShapeIdentifiersB(-1, -1);
  // Positive-distance points up to the pair threshold; not for compounds: with a threshold > 0
  // btCompoundCollisionAlgorithm switches its children to throw-away closest-point algorithms whose
  // manifolds are released at once (no contact would survive), so compound children get Bullet's usual
  // behaviour (points within the manifold's breaking threshold, which sphere-sphere reads as touching).
  if (!o0->getCollisionShape()->isCompound() && !o1->getCollisionShape()->isCompound()) {
    auto& rd = static_cast<RelativeDispatcher&>(dispatcher);
    result.m_closestPointDistanceThreshold = rd.owner()->pairThreshold(o0->getUserIndex(), o1->getUserIndex());
  }
  pair.m_algorithm->processCollision(&w0, &w1, info, &result);
}

bool BulletCollision::needsRebuild(const BodyArrays& bodies, const ShapeArrays& shapes,
                                   const CollisionSettings& config) const {
  if (!built_ || shapes.count() != shapes_.size() || bodies.count() != flags_.size() ||
      shapes.hull_points.size() != hull_point_count_ || config.envelope_rel != envelope_rel_)
    return true;
  for (size_t i = 0; i < flags_.size(); ++i)
    if (bodies.flags[i] != flags_[i]) return true;
  for (size_t i = 0; i < shapes_.size(); ++i)
    if (!sameShape(shapes.shape[i], shapes_[i])) return true;
  return false;
}

void BulletCollision::destroyWorld() {
  if (world_) {
    for (auto& o : bt_objects_) world_->removeCollisionObject(o.get());
  }
  world_.reset();
  bt_objects_.clear();
  broadphase_.reset();
  dispatcher_.reset();
  config_.reset();
  owned_shapes_.clear();
  objects_.clear();
  shape_bt_.clear();
  built_ = false;
}

btCollisionShape* BulletCollision::makeShape(const Shape& s, const std::vector<Vec3>& hull, real size) {
  // Bullet's default margin is 0.04 absolute; scale it down with the shape.
  const btScalar margin = btScalar(fmin(real(0.04), real(0.04) * size));
  btCollisionShape* out = nullptr;
  switch (s.type) {
    case ShapeType::Sphere: out = new btSphereShape(btScalar(s.dims.x)); break;
    case ShapeType::Ellipsoid: {
      btVector3 centre(0, 0, 0);
      btScalar radius = 1;
      auto* ms = new btMultiSphereShape(&centre, &radius, 1);
      ms->setMargin(margin);
      ms->setLocalScaling(toBt(s.dims));
      out = ms;
      break;
    }
    case ShapeType::Box: {
      auto* b = new btBoxShape(toBt(s.dims));
      b->setMargin(margin);  // btBoxShape::setMargin keeps the half extents (margin included) unchanged
      out = b;
      break;
    }
    case ShapeType::Cylinder: {
      auto* c = new btCylinderShape(btVector3(btScalar(s.dims.x), btScalar(s.dims.y), btScalar(s.dims.x)));
      c->setMargin(margin);  // same: extents unchanged
      out = c;
      break;
    }
    case ShapeType::Capsule: out = new btCapsuleShape(btScalar(s.dims.x), btScalar(2 * s.dims.y)); break;
    case ShapeType::Cone: {
      auto* c = new btConeShape(btScalar(s.dims.x), btScalar(s.dims.y));
      c->setMargin(margin);
      out = c;
      break;
    }
    case ShapeType::ConvexHull: {
      if (s.hull_count <= 0 || s.hull_start < 0 || size_t(s.hull_start + s.hull_count) > hull.size())
        throw InputError("Bullet collision: convex hull with an invalid point range");
      auto* h = new btConvexHullShape();
      for (int i = 0; i < s.hull_count; ++i) h->addPoint(toBt(hull[size_t(s.hull_start + i)]), false);
      h->recalcLocalAabb();
      // A hull with its own margin (Shape::margin, the sphere-swept radius) is exactly Bullet's hull with that
      // margin (btConvexInternalShape::localGetSupportingVertex); one without gets the scaled default.
      h->setMargin(s.margin > 0 ? btScalar(s.margin) : margin);
      out = h;
      break;
    }
    case ShapeType::Plane: out = new btStaticPlaneShape(toBt(s.dims), btScalar(s.plane_d)); break;
    default:
      throw InputError(std::string("Bullet collision: unsupported shape type '") + shapeTypeName(s.type) + "' (" +
                       std::to_string(int(s.type)) + ")");
  }
  owned_shapes_.emplace_back(out);
  return out;
}

void BulletCollision::rebuild(const BodyArrays& bodies, const ShapeArrays& shapes, const CollisionSettings& config) {
  destroyWorld();
  shapes_ = shapes.shape;
  flags_ = bodies.flags;
  hull_point_count_ = shapes.hull_points.size();
  envelope_rel_ = config.envelope_rel;
  const size_t ns = shapes.count();
  sizes_.resize(ns);
  for (size_t i = 0; i < ns; ++i) {
    const Shape& s = shapes.shape[i];
    if (s.body < 0 || size_t(s.body) >= bodies.count())
      throw InputError("Bullet collision: shape " + std::to_string(i) + " refers to a missing body");
    sizes_[i] = shapeSize(s, shapes.hull_points);
  }

  // Group the shapes into objects: per body, all non-plane shapes together; each plane alone.
  std::vector<int32_t> body_object(bodies.count(), -1);
  for (size_t i = 0; i < ns; ++i) {
    const Shape& s = shapes.shape[i];
    if (s.type == ShapeType::Plane) {
      ObjectInfo o;
      o.body = s.body;
      o.shapes.push_back(int32_t(i));
      objects_.push_back(o);
      continue;
    }
    int32_t& oi = body_object[size_t(s.body)];
    if (oi < 0) {
      oi = int32_t(objects_.size());
      ObjectInfo o;
      o.body = s.body;
      objects_.push_back(o);
    }
    objects_[size_t(oi)].shapes.push_back(int32_t(i));
  }

  config_ = std::make_unique<btDefaultCollisionConfiguration>();
  config_->setPlaneConvexMultipointIterations();
  dispatcher_ = std::make_unique<RelativeDispatcher>(config_.get(), this);
  dispatcher_->setNearCallback(relativeNearCallback);
  broadphase_ = std::make_unique<btDbvtBroadphase>();
  broadphase_->m_cupdates = 100;  // drop every pair whose boxes no longer overlap, each call
  broadphase_->getOverlappingPairCache()->setOverlapFilterCallback(&filter_);
  world_ = std::make_unique<btCollisionWorld>(dispatcher_.get(), broadphase_.get(), config_.get());

  shape_bt_.assign(ns, nullptr);
  for (size_t oi = 0; oi < objects_.size(); ++oi) {
    ObjectInfo& o = objects_[oi];
    o.compound = o.shapes.size() > 1;
    int group = 0, mask = 0;
    real tsize = 0;
    for (int32_t si : o.shapes) {
      const Shape& s = shapes.shape[size_t(si)];
      shape_bt_[size_t(si)] = makeShape(s, shapes.hull_points, sizes_[size_t(si)]);
      group |= int(uint16_t(s.group));
      mask |= int(uint16_t(s.mask));
      tsize = fmax(tsize, sizes_[size_t(si)]);
    }
    o.thresh_size = tsize;
    btCollisionShape* root = shape_bt_[size_t(o.shapes[0])];
    if (o.compound) {
      auto* c = new btCompoundShape(true, int(o.shapes.size()));
      owned_shapes_.emplace_back(c);
      for (int32_t si : o.shapes) c->addChildShape(toBt(shapes.shape[size_t(si)].local), shape_bt_[size_t(si)]);
      root = c;
    }
    auto obj = std::make_unique<btCollisionObject>();
    obj->setCollisionShape(root);
    obj->setUserIndex(int(oi));
    const uint8_t f = bodies.flags[size_t(o.body)];
    if (f & kBodyFixed) obj->setCollisionFlags(obj->getCollisionFlags() | btCollisionObject::CF_STATIC_OBJECT);
    if (f & kBodyKinematic) obj->setCollisionFlags(obj->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
    const btScalar pt = std::isfinite(tsize) ? btScalar(envelope_rel_ * tsize) : btScalar(BT_LARGE_FLOAT);
    obj->setContactProcessingThreshold(pt);
    world_->addCollisionObject(obj.get(), group, mask);
    bt_objects_.push_back(std::move(obj));
  }
  built_ = true;
}

void BulletCollision::detect(const BodyArrays& bodies, ShapeArrays& shapes, const CollisionSettings& config,
                             const StepContext& /*step*/, ContactArrays& out, CollisionTimes& times) {
  const auto t0 = Clock::now();
  if (needsRebuild(bodies, shapes, config)) rebuild(bodies, shapes, config);
  updateAabbs(bodies, shapes, config.envelope_rel);
  const auto t1 = Clock::now();

  world_->computeOverlappingPairs();
  const auto t2 = Clock::now();

  btOverlappingPairCache* cache = world_->getPairCache();
  dispatcher_->dispatchAllCollisionPairs(cache, world_->getDispatchInfo(), dispatcher_.get());
  collectManifoldPoints(bodies, shapes, config.envelope_rel);
  writeContacts(shapes, out);
  const auto t3 = Clock::now();

  times.aabbs = seconds(t0, t1);
  times.broad = seconds(t1, t2);
  times.narrow = seconds(t2, t3);
  times.pairs = cache->getNumOverlappingPairs();
  times.broad_stats = BroadPhaseStats{};
  times.broad_stats.pairs = times.pairs;
}

// Poses and AABBs (ours for shapes.aabb; union of the object's shapes for the dbvt).
void BulletCollision::updateAabbs(const BodyArrays& bodies, ShapeArrays& shapes, real rel) {
  shapes.aabb.resize(shapes.count());
  const real big = real(1e30);
  for (size_t oi = 0; oi < objects_.size(); ++oi) {
    const ObjectInfo& o = objects_[oi];
    const Pose body{bodies.pos[size_t(o.body)], bodies.rot[size_t(o.body)]};
    btCollisionObject* obj = bt_objects_[oi].get();
    obj->setWorldTransform(toBt(o.compound ? body : compose(body, shapes.shape[size_t(o.shapes[0])].local)));
    btVector3 olo(BT_LARGE_FLOAT, BT_LARGE_FLOAT, BT_LARGE_FLOAT), ohi = -olo;
    for (int32_t si : o.shapes) {
      const Shape& s = shapes.shape[size_t(si)];
      const btTransform tw = toBt(compose(body, s.local));
      btVector3 lo, hi;
      shape_bt_[size_t(si)]->getAabb(tw, lo, hi);
      if (s.type == ShapeType::Plane) {
        shapes.aabb[size_t(si)] = Aabb{{-big, -big, -big}, {big, big, big}};  // unbounded, as shapeAabb
      } else {
        const real env = rel * sizes_[size_t(si)];
        shapes.aabb[size_t(si)] = Aabb{fromBt(lo) - Vec3{env, env, env}, fromBt(hi) + Vec3{env, env, env}};
        const btScalar e = btScalar(env);
        lo -= btVector3(e, e, e);
        hi += btVector3(e, e, e);
      }
      olo.setMin(lo);
      ohi.setMax(hi);
    }
    broadphase_->setAabbForceUpdate(obj->getBroadphaseHandle(), olo, ohi, dispatcher_.get());
  }
}

// Manifold points -> raw_ (our shapes, a < b, within the envelope), sorted by (shape pair, manifold, point).
void BulletCollision::collectManifoldPoints(const BodyArrays& bodies, const ShapeArrays& shapes, real rel) {
  raw_.clear();
  const int nm = dispatcher_->getNumManifolds();
  for (int mi = 0; mi < nm; ++mi) {
    const btPersistentManifold* m = dispatcher_->getManifoldByIndexInternal(mi);
    const int oa = m->getBody0()->getUserIndex();
    const int ob = m->getBody1()->getUserIndex();
    for (int k = 0; k < m->getNumContacts(); ++k) {
      const btManifoldPoint& p = m->getContactPoint(k);
      int32_t sa = shapeOf(oa, p.m_index0);
      int32_t sb = shapeOf(ob, p.m_index1);
      if (sa < 0 || sb < 0) continue;
      const Shape& A = shapes.shape[size_t(sa)];
      const Shape& B = shapes.shape[size_t(sb)];
      if (!pairAllowed(A, B, bodies.flags[size_t(A.body)], bodies.flags[size_t(B.body)])) continue;
      const real env = rel * fmin(sizes_[size_t(sa)], sizes_[size_t(sb)]);
      const real d = real(p.getDistance());
      if (!(d < env)) continue;
      Raw r{
          sa, sb, mi, k, -fromBt(p.m_normalWorldOnB), fromBt(p.getPositionWorldOnA()), fromBt(p.getPositionWorldOnB()),
          d};
      if (sa > sb) {
        std::swap(r.sa, r.sb);
        std::swap(r.pa, r.pb);
        r.normal = -r.normal;
      }
      raw_.push_back(r);
    }
  }
  std::sort(raw_.begin(), raw_.end(), [](const Raw& x, const Raw& y) {
    if (x.sa != y.sa) return x.sa < y.sa;
    if (x.sb != y.sb) return x.sb < y.sb;
    if (x.manifold != y.manifold) return x.manifold < y.manifold;
    return x.point < y.point;
  });
}

// raw_ -> the contact arrays; a point's feature is its manifold slot, offset by the manifolds seen before for the
// same shape pair.
void BulletCollision::writeContacts(const ShapeArrays& shapes, ContactArrays& out) const {
  out.resize(raw_.size());
  int32_t rank = 0;  // manifolds seen before this one for the same shape pair (normally 0)
  for (size_t i = 0; i < raw_.size(); ++i) {
    const Raw& r = raw_[i];
    if (i > 0) {
      const Raw& q = raw_[i - 1];
      if (q.sa != r.sa || q.sb != r.sb)
        rank = 0;
      else if (q.manifold != r.manifold)
        ++rank;
    }
    const int32_t feature = r.point + MANIFOLD_CACHE_SIZE * rank;
    out.shape_a[i] = r.sa;
    out.shape_b[i] = r.sb;
    out.body_a[i] = shapes.shape[size_t(r.sa)].body;
    out.body_b[i] = shapes.shape[size_t(r.sb)].body;
    out.normal[i] = normalized(r.normal);
    out.pa[i] = r.pa;
    out.pb[i] = r.pb;
    out.dist[i] = r.dist;
    out.key[i] = contactKey(r.sa, r.sb, feature);
  }
}

}  // namespace

std::unique_ptr<CollisionDetector> makeBulletCollision() { return std::make_unique<BulletCollision>(); }

}  // namespace dvi
