// The Bullet drop-in world (bullet_world.h).
#include "chrono_like/bullet/bullet_world.h"
#include "chrono_like/bullet/bullet_convert.h"

#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <string>

#include "chrono_like/bullet/bullet_collision_backend.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/bullet/triangle_mesh.h"

namespace dvi {

namespace {

bool sameTransform(const btTransform& a, const btTransform& b) {
  return a.getOrigin() == b.getOrigin() && a.getBasis()[0] == b.getBasis()[0] && a.getBasis()[1] == b.getBasis()[1] &&
         a.getBasis()[2] == b.getBasis()[2];
}

// The System's kind of an object: plain collision objects are fixed geometry; a body Bullet does not simulate
// (activation state DISABLE_SIMULATION) is held as a fixed body.
int objectKind(const btCollisionObject& o) {
  const btRigidBody* b = btRigidBody::upcast(&o);
  if (!b) return kBodyFixed;
  if (b->isKinematicObject()) return kBodyKinematic;
  if (b->isStaticObject() || b->getInvMass() == 0 || b->getActivationState() == DISABLE_SIMULATION) return kBodyFixed;
  return 0;
}

int proxyGroup(const btCollisionObject& o) {
  return o.getBroadphaseHandle() ? o.getBroadphaseHandle()->m_collisionFilterGroup : 1;
}
int proxyMask(const btCollisionObject& o) {
  return o.getBroadphaseHandle() ? o.getBroadphaseHandle()->m_collisionFilterMask : -1;
}

// The pose the System holds: a body's centre of mass, a plain object's world transform.
const btTransform& poseOf(const btCollisionObject& o) {
  const btRigidBody* b = btRigidBody::upcast(&o);
  return b ? b->getCenterOfMassTransform() : o.getWorldTransform();
}

// The object as the System takes it (groups and masks are set by the caller); shapes include static triangle
// geometry (triangle_mesh.h).
BodyDesc describeUnclamped(const btCollisionObject& obj);

// Bullet takes any rolling or spinning friction; a value <= 0 (or not finite) adds no rolling rows in Bullet's solver
// (they need a combined value > 0), so the System's lengths get 0 for it.
BodyDesc describe(const btCollisionObject& obj) {
  BodyDesc d = describeUnclamped(obj);
  if (!(d.rolling_friction > 0) || !std::isfinite(d.rolling_friction)) d.rolling_friction = 0;
  if (!(d.spinning_friction > 0) || !std::isfinite(d.spinning_friction)) d.spinning_friction = 0;
  return d;
}

BodyDesc describeUnclamped(const btCollisionObject& obj) {
  const btCollisionShape* shape = obj.getCollisionShape();
  if (!shape) throw InputError("collision object without a collision shape");
  const btRigidBody* body = btRigidBody::upcast(&obj);
  const int kind = objectKind(obj);
  if (body && !hasTriangles(*shape)) {
    BodyDesc d = bodyDescFromBullet(*body);
    d.has_gravity = true;  // the body's own gravity (Bullet sets it from the world when added)
    d.gravity = fromBt(body->getGravity());
    if (kind != 0) {
      d.flags = uint8_t(kind);
      d.mass = 0;
      d.inertia = Vec3{0, 0, 0};
    }
    return d;
  }
  if (body && kind == 0)
    throw InputError(std::string("a dynamic body cannot use a triangle shape (") + shape->getName() +
                     "); Bullet supports it only on static or kinematic bodies");
  BodyDesc d;
  if (body) {
    d = bodyMotionFromBullet(*body);
  } else {
    d.pos = fromBt(obj.getWorldTransform().getOrigin());
    d.rot = fromBt(obj.getWorldTransform().getRotation());
    d.friction = real(obj.getFriction());
    d.rolling_friction = real(obj.getRollingFriction());
    d.spinning_friction = real(obj.getSpinningFriction());
  }
  d.flags = uint8_t(kind);
  d.mass = 0;
  d.inertia = Vec3{0, 0, 0};
  appendShapesWithTriangles(*shape, Pose{{0, 0, 0}, {1, 0, 0, 0}}, d.shapes);
  if (d.shapes.empty()) throw InputError(std::string("collision shape has no children: ") + shape->getName());
  return d;
}

real& component(Vec3& v, int k) { return k == 0 ? v.x : k == 1 ? v.y : v.z; }

}  // namespace

// Bullet's linear and angular factors (btRigidBody::setLinearFactor, setAngularFactor) scale every force and
// impulse a body receives, per world axis (btRigidBody::applyCentralForce, applyTorque, applyImpulse and the
// sequential-impulse solver's m_linearFactor / m_angularFactor). A factor of 1 changes nothing; a factor of 0
// leaves that velocity component as it was: one bilateral row per locked axis, J v = v0 (bias -v0, unbounded
// impulse), solved with the contacts and joints, so that no force, contact or joint changes it. Other factors
// would change the body's mass matrix per axis and are refused (syncBody).
class FactorRows final : public RowProvider {
 public:
  struct Lock {
    int32_t body;
    int8_t angular;  // 0 linear, 1 angular
    int8_t axis;     // world x, y, z
    real target;     // the velocity component kept [m/s or rad/s]
  };
  std::vector<Lock> locks;

  void rows(const BodyArrays&, const StepContext&, std::vector<ConstraintRow>& out) override {
    for (const Lock& l : locks) {
      ConstraintRow r;
      r.a = l.body;
      r.Ja[3 * l.angular + l.axis] = 1;
      r.bias = -l.target;
      out.push_back(r);
    }
  }
};

namespace {

// The CPU System with pair exclusions: contacts between bodies that Bullet would not collide (a constraint
// with disableCollisionsBetweenLinkedBodies, CF_NO_CONTACT_RESPONSE) are dropped after the narrow phase.
class FilteredCpuSystem final : public System {
 public:
  FilteredCpuSystem(const SystemConfig& c, std::function<bool(int, int)> keep)
      : System(c, makeBulletCollision), keep_(std::move(keep)) {}

 protected:
  void detectCollisions() override {
    System::detectCollisions();
    ContactArrays& c = contacts_;
    stats_.contacts = int64_t(c.keepIf([&](size_t k) { return keep_(c.body_a[k], c.body_b[k]); }));
  }

 private:
  std::function<bool(int, int)> keep_;
};

}  // namespace

DviDynamicsWorld::DviDynamicsWorld(btDispatcher* dispatcher, btBroadphaseInterface* pairCache,
                                   btConstraintSolver* constraintSolver,
                                   btCollisionConfiguration* collisionConfiguration, DviWorldConfig config)
    : btDiscreteDynamicsWorld(dispatcher, pairCache, constraintSolver, collisionConfiguration), config_(config) {
  // Bullet's pair cache is not used by the step (the System finds its own pairs): a Dbvt broad phase only keeps
  // its trees up to date for the queries (rayTest, contactTest, ...), and the pairs are computed when ghost
  // objects need them (computeOverlappingPairs in the sub-step).
  if (auto* dbvt = dynamic_cast<btDbvtBroadphase*>(pairCache)) dbvt->m_deferedcollide = true;
  joints_ = std::make_shared<BulletJoints>(&index_, config_.joints);
  factors_ = std::make_shared<FactorRows>();
  system_ = makeSystem();
}

DviDynamicsWorld::~DviDynamicsWorld() { releaseManifolds(); }

std::unique_ptr<System> DviDynamicsWorld::makeSystem() const {
  SystemConfig c = config_.system;
  c.step.gravity = fromBt(m_gravity);
  if (!(real(c.step.dt) > 0)) c.step.dt = real(1) / 60;
  std::unique_ptr<System> s;
  const bool gpu = config_.backend == WorldBackend::Gpu ||
                   (config_.backend == WorldBackend::Auto && config_.gpu_available && config_.gpu_available(nullptr));
  if (gpu) {
    if (!config_.make_gpu_system)
      throw InputError(
          "WorldBackend::Gpu: DviWorldConfig::make_gpu_system is not set (gpu/gpu_factory.h: makeGpuSystem)");
    s = config_.make_gpu_system(c, makeBulletCollision);  // throws InputError naming why when no device is usable
  } else {
    s = std::make_unique<FilteredCpuSystem>(c, [this](int a, int b) { return keepPair(a, b); });
  }
  s->addRowProvider(joints_);
  s->addRowProvider(factors_);
  return s;
}

// Bullet's pair test (btOverlappingPairCache needsBroadphaseCollision) on the full 32-bit groups and masks, where the
// System's 16-bit filters are folded (CPU backend). Contact response and constraint exclusions (btCollisionDispatcher
// needsCollision) are the System's contact exclusions on both backends (updateExclusions).
bool DviDynamicsWorld::keepPair(int a, int b) const {
  const Tracked& ta = tracked_[size_t(a)];
  const Tracked& tb = tracked_[size_t(b)];
  // The renumbered 16-bit filters are exact unless folded: only then does the System's test pass extra pairs.
  return !folded_filters_ || ((ta.group & tb.mask) != 0 && (tb.group & ta.mask) != 0);
}

// Group bit positions in use get System bits in order of appearance; a new one renumbers nothing, but the masks
// already given out lack it, so the System is rebuilt. Beyond 16 positions the filters are folded (bit p onto bit
// p mod 16: every pair Bullet collides still passes the System's test) and keepPair applies the exact test.
void DviDynamicsWorld::noteFilter(int group) {
  for (int bit = 0; bit < 32; ++bit) {
    if (!((uint32_t(group) >> bit) & 1u)) continue;
    if (std::find(group_bits_.begin(), group_bits_.end(), bit) != group_bits_.end()) continue;
    group_bits_.push_back(bit);
    if (!tracked_.empty()) rebuild_ = true;
    if (group_bits_.size() > 16) folded_filters_ = true;
  }
}

int16_t DviDynamicsWorld::mapFilter(int bits) const {
  const uint32_t u = uint32_t(bits);
  if (folded_filters_) return int16_t(uint16_t((u & 0xFFFFu) | (u >> 16)));
  uint32_t out = 0;
  for (size_t k = 0; k < group_bits_.size(); ++k)
    if ((u >> group_bits_[k]) & 1u) out |= 1u << k;
  return int16_t(uint16_t(out));
}

int DviDynamicsWorld::bodyIndex(const btRigidBody* body) const {
  auto it = index_.find(body);
  return it == index_.end() ? -1 : it->second;
}

int DviDynamicsWorld::objectIndex(const btCollisionObject* obj) const {
  auto it = object_index_.find(obj);
  return it == object_index_.end() ? -1 : it->second;
}

void DviDynamicsWorld::addRigidBody(btRigidBody* body) {
  if (!body) throw InputError("addRigidBody: null body");
  (void)describe(*body);  // refuse what we cannot simulate before Bullet takes the body
  btDiscreteDynamicsWorld::addRigidBody(body);
  pending_.push_back(body);
}

void DviDynamicsWorld::addRigidBody(btRigidBody* body, int group, int mask) {
  if (!body) throw InputError("addRigidBody: null body");
  (void)describe(*body);
  btDiscreteDynamicsWorld::addRigidBody(body, group, mask);
  pending_.push_back(body);
}

void DviDynamicsWorld::addCollisionObject(btCollisionObject* object, int group, int mask) {
  if (!object) throw InputError("addCollisionObject: null object");
  const int type = object->getInternalType();
  if (type == btCollisionObject::CO_RIGID_BODY) {  // from btDiscreteDynamicsWorld::addRigidBody
    btDiscreteDynamicsWorld::addCollisionObject(object, group, mask);
    return;
  }
  if (type == btCollisionObject::CO_GHOST_OBJECT) {
    btDiscreteDynamicsWorld::addCollisionObject(object, group, mask);
    ++ghosts_;
    return;
  }
  if (type != btCollisionObject::CO_COLLISION_OBJECT && type != btCollisionObject::CO_USER_TYPE)
    throw InputError("addCollisionObject: collision object type " + std::to_string(type) +
                     " (soft body, fluid or multibody link) is not supported by the drop-in world");
  (void)describe(*object);
  btDiscreteDynamicsWorld::addCollisionObject(object, group, mask);
  pending_.push_back(object);
}

// Takes an object out of the System's bookkeeping; the System itself is rebuilt at the next sub-step (so that
// removing many objects costs O(1) each).
void DviDynamicsWorld::forget(btCollisionObject* obj) {
  pending_.erase(std::remove(pending_.begin(), pending_.end(), obj), pending_.end());
  auto it = object_index_.find(obj);
  if (it != object_index_.end()) {
    tracked_[size_t(it->second)].obj = nullptr;
    tracked_[size_t(it->second)].body = nullptr;
    object_index_.erase(it);
    rebuild_ = true;
  }
  if (btRigidBody* b = btRigidBody::upcast(obj)) index_.erase(b);
  // The last sub-step's contacts and manifolds go with it (they are rebuilt by the next sub-step): O(1) per removal.
  releaseManifolds();
  contacts_.clear();
}

void DviDynamicsWorld::removeRigidBody(btRigidBody* body) {
  btDiscreteDynamicsWorld::removeRigidBody(body);
  forget(body);
  // Joints on the body leave the System with it (Bullet asks the app to remove them first).
  for (btTypedConstraint* c : std::vector<btTypedConstraint*>(joints_->constraints()))
    if (&c->getRigidBodyA() == body || &c->getRigidBodyB() == body) joints_->remove(c);
}

void DviDynamicsWorld::removeCollisionObject(btCollisionObject* object) {
  if (btRigidBody* b = btRigidBody::upcast(object)) {
    removeRigidBody(b);
    return;
  }
  if (object && object->getInternalType() == btCollisionObject::CO_GHOST_OBJECT) --ghosts_;
  btDiscreteDynamicsWorld::removeCollisionObject(object);
  forget(object);
}

void DviDynamicsWorld::addConstraint(btTypedConstraint* constraint, bool disableCollisionsBetweenLinkedBodies) {
  joints_->add(constraint);  // throws InputError for what we cannot represent
  btDiscreteDynamicsWorld::addConstraint(constraint, disableCollisionsBetweenLinkedBodies);
  if (disableCollisionsBetweenLinkedBodies) has_exclusions_ = true;
}

void DviDynamicsWorld::removeConstraint(btTypedConstraint* constraint) {
  joints_->remove(constraint);
  btDiscreteDynamicsWorld::removeConstraint(constraint);
}

void DviDynamicsWorld::addToSystem(btCollisionObject* obj) {
  BodyDesc d = describe(*obj);
  Tracked t;
  t.obj = obj;
  t.body = btRigidBody::upcast(obj);
  t.tf = poseOf(*obj);
  t.v = t.body ? t.body->getLinearVelocity() : btVector3(0, 0, 0);
  t.w = t.body ? t.body->getAngularVelocity() : btVector3(0, 0, 0);
  t.shape = obj->getCollisionShape();
  t.group = proxyGroup(*obj);
  t.mask = proxyMask(*obj);
  t.kind = objectKind(*obj);
  for (ShapeDesc& s : d.shapes) {
    s.shape.group = mapFilter(t.group);
    s.shape.mask = mapFilter(t.mask);
  }
  const int i = system_->addBody(d);
  if (size_t(i) != tracked_.size()) throw InputError("drop-in world: body index out of step with the System");
  object_index_[obj] = i;
  if (t.body) index_[t.body] = i;
  tracked_.push_back(t);
}

void DviDynamicsWorld::rebuild() {
  std::vector<btCollisionObject*> objects;
  objects.reserve(tracked_.size());
  for (const Tracked& t : tracked_)
    if (t.obj) objects.push_back(t.obj);
  tracked_.clear();
  index_.clear();
  object_index_.clear();
  releaseManifolds();
  system_ = makeSystem();
  for (btCollisionObject* o : objects) addToSystem(o);
  rebuild_ = false;
}

// A new shape, filter or kind needs the System rebuilt; new group bits do too (noteFilter).
bool DviDynamicsWorld::structureChanged() const {
  for (const Tracked& t : tracked_) {
    if (!t.obj) continue;
    if (t.obj->getCollisionShape() != t.shape || proxyGroup(*t.obj) != t.group || proxyMask(*t.obj) != t.mask ||
        objectKind(*t.obj) != t.kind)
      return true;
  }
  return false;
}

void DviDynamicsWorld::syncIn(btScalar h) {
  for (btCollisionObject* o : pending_) noteFilter(proxyGroup(*o));
  if (!rebuild_ && structureChanged()) {
    for (const Tracked& t : tracked_)
      if (t.obj) noteFilter(proxyGroup(*t.obj));
    rebuild_ = true;
  }
  if (rebuild_) rebuild();
  for (btCollisionObject* o : pending_) addToSystem(o);
  pending_.clear();

  SystemConfig& cfg = system_->mutableConfig();
  cfg.step.dt = real(h);
  cfg.solver.min_bounce_speed = real(getSolverInfo().m_restitutionVelocityThreshold);
  if (config_.effort == SolverEffort::BulletIterations) {
    const btContactSolverInfo& info = getSolverInfo();
    cfg.solver.type = SolverType::GaussSeidel;
    cfg.solver.max_iterations = std::max(1, info.m_numIterations);
    cfg.solver.min_iterations = 0;
    cfg.solver.tolerance = 0;  // a fixed count, judged against the default tolerance in the stats
    cfg.solver.gs_omega = real(info.m_sor);
    cfg.solver.warm_start = info.m_warmstartingFactor > 0;
  }
  BodyArrays& B = system_->mutableBodies();
  factors_->locks.clear();
  for (size_t i = 0; i < tracked_.size(); ++i) syncBody(i, h, B);
  joints_->springForces(B, B.force.data(), B.torque.data());
  updateExclusions();
  system_->markHostDirty();
}

void DviDynamicsWorld::updateExclusions() {
  std::vector<std::pair<int32_t, int32_t>>& pairs = excl_pairs_next_;  // scratch kept between sub-steps
  std::vector<uint8_t>& flags = excl_flags_next_;
  pairs.clear();
  flags.assign(tracked_.size(), 0);
  bool any_flag = false;
  for (size_t i = 0; i < tracked_.size(); ++i) {
    btCollisionObject* o = tracked_[i].obj;
    if (!o) continue;
    if (!o->hasContactResponse()) flags[i] = 1, any_flag = true;
    if (!has_exclusions_) continue;
    for (int j = 0; j < o->getNumObjectsWithoutCollision(); ++j) {  // Bullet's checkCollideWith lists
      auto it = object_index_.find(o->getObjectWithoutCollision(j));
      if (it != object_index_.end() && it->second != int(i)) pairs.emplace_back(int32_t(i), int32_t(it->second));
    }
  }
  if (!any_flag) flags.clear();
  if (excl_system_ == system_.get() && pairs == excl_pairs_ && flags == excl_flags_) return;
  system_->setContactExclusions(pairs, flags);
  excl_pairs_.swap(pairs);
  excl_flags_.swap(flags);
  excl_system_ = system_.get();
}

void DviDynamicsWorld::syncBody(size_t i, btScalar h, BodyArrays& B) {
  Tracked& t = tracked_[i];
  const btTransform& tf = poseOf(*t.obj);
  const bool kinematic = t.kind == kBodyKinematic;
  if (kinematic || !sameTransform(tf, t.tf)) {
    B.pos[i] = fromBt(tf.getOrigin());
    B.rot[i] = normalized(fromBt(tf.getRotation()));
    t.tf = tf;
  }
  B.friction[i] = real(t.obj->getFriction());
  B.restitution[i] = real(t.obj->getRestitution());
  // Bullet takes any value here; the System's are lengths >= 0 (a negative one means none, as in Bullet's solver,
  // which adds the rolling rows only for a combined value > 0).
  const real roll = real(t.obj->getRollingFriction()), spin = real(t.obj->getSpinningFriction());
  B.rolling_friction[i] = roll > 0 && std::isfinite(roll) ? roll : real(0);
  B.spinning_friction[i] = spin > 0 && std::isfinite(spin) ? spin : real(0);
  if (t.kind == kBodyFixed) return;
  const btRigidBody& b = *t.body;
  if (kinematic || !(b.getLinearVelocity() == t.v)) B.vel[i] = fromBt(b.getLinearVelocity());
  if (kinematic || !(b.getAngularVelocity() == t.w)) B.omega[i] = fromBt(b.getAngularVelocity());
  if (kinematic) return;
  // A sleeping body is held still until its island wakes (updateSleeping): fixed for this sub-step, so that pairs
  // of sleeping (or sleeping and static) bodies are not even collided; a body that touches it wakes its island.
  B.flags[i] = b.getActivationState() == ISLAND_SLEEPING ? uint8_t(kBodyFixed) : uint8_t(0);
  if (B.flags[i]) {
    B.vel[i] = B.omega[i] = B.gravity[i] = B.force[i] = B.torque[i] = Vec3{0, 0, 0};
    B.inv_mass[i] = 0;
    B.inv_inertia[i] = Vec3{0, 0, 0};
    return;
  }
  B.inv_mass[i] = real(b.getInvMass());
  B.inv_inertia[i] = fromBt(b.getInvInertiaDiagLocal());
  B.gravity[i] = fromBt(b.getGravity());
  B.force[i] = fromBt(b.getTotalForce());
  B.torque[i] = fromBt(b.getTotalTorque());
  // Bullet's damping rule (btRigidBody::applyDamping), before the forces act.
  const real ld = real(b.getLinearDamping()), ad = real(b.getAngularDamping());
  if (ld > 0) B.vel[i] = B.vel[i] * real(std::pow(1 - double(ld), double(h)));
  if (ad > 0) B.omega[i] = B.omega[i] * real(std::pow(1 - double(ad), double(h)));
  const btVector3 factor[2] = {b.getLinearFactor(), b.getAngularFactor()};
  for (int8_t ang = 0; ang < 2; ++ang) {
    for (int8_t k = 0; k < 3; ++k) {
      const btScalar f = factor[ang][k];
      if (f == 1) continue;
      if (f != 0)
        throw InputError("drop-in world: body " + std::to_string(i) + " has " + (ang ? "angular" : "linear") +
                         " factor " + std::to_string(double(f)) +
                         " on a world axis; only 0 (locked) and 1 (free) are supported");
      factors_->locks.push_back({int32_t(i), ang, k, component(ang ? B.omega[i] : B.vel[i], k)});
    }
  }
}

void DviDynamicsWorld::syncOut() {
  const BodyArrays& B = system_->bodies();
  for (size_t i = 0; i < tracked_.size(); ++i) {
    Tracked& t = tracked_[i];
    if (t.kind != 0) continue;  // static and kinematic bodies keep Bullet's pose
    btRigidBody* b = t.body;
    b->setLinearVelocity(toBt(B.vel[i]));
    b->setAngularVelocity(toBt(B.omega[i]));
    btTransform tf;
    tf.setOrigin(toBt(B.pos[i]));
    tf.setRotation(toBt(B.rot[i]));
    b->setCenterOfMassTransform(tf);  // also the interpolation transform and velocities
    t.tf = b->getCenterOfMassTransform();
    t.v = b->getLinearVelocity();
    t.w = b->getAngularVelocity();
  }
}

// Kinematic bodies join no island, but wake what they touch (btSimulationIslandManager::buildIslands does the same
// for its pairs). A sleeping body is fixed in the System, so a kinematic body makes no contact with it: their
// boxes in Bullet's broad phase are tested instead.
void DviDynamicsWorld::wakeTouchedByKinematic() {
  struct Waker : btBroadphaseAabbCallback {
    bool process(const btBroadphaseProxy* proxy) override {
      auto* o = static_cast<btCollisionObject*>(proxy->m_clientObject);
      if (o && o->getActivationState() == ISLAND_SLEEPING && o->hasContactResponse()) o->activate();
      return true;
    }
  } waker;
  for (const Tracked& t : tracked_) {
    if (t.kind != kBodyKinematic || !t.obj->hasContactResponse() || !t.obj->getBroadphaseHandle()) continue;
    const btBroadphaseProxy* p = t.obj->getBroadphaseHandle();
    m_broadphasePairCache->aabbTest(p->m_aabbMin, p->m_aabbMax, waker);
  }
}

// Bullet's deactivation (btDiscreteDynamicsWorld::updateActivationState and btSimulationIslandManager): each
// dynamic body counts the time its speeds stay below its sleeping thresholds; an island (bodies joined by this
// sub-step's contacts and by enabled constraints; static, kinematic and no-response objects join none) whose bodies
// all want to sleep falls asleep (velocities zeroed), any other island is awake.
void DviDynamicsWorld::updateSleeping(btScalar h) {
  const size_t n = tracked_.size();
  std::vector<int>& root = island_root_;  // members: no allocation per sub-step once grown
  root.resize(n);
  for (size_t i = 0; i < n; ++i) root[i] = int(i);
  auto find = [&](int i) {
    while (root[size_t(i)] != i) i = root[size_t(i)] = root[size_t(root[size_t(i)])];
    return i;
  };
  auto merges = [&](int i) {
    return i >= 0 && tracked_[size_t(i)].kind == 0 && tracked_[size_t(i)].obj->mergesSimulationIslands();
  };
  auto unite = [&](int a, int b) {
    if (merges(a) && merges(b)) root[size_t(find(a))] = find(b);
  };
  const ContactArrays& c = system_->contacts();
  for (size_t k = 0; k < c.count(); ++k) unite(c.body_a[k], c.body_b[k]);
  wakeTouchedByKinematic();
  for (btTypedConstraint* j : joints_->constraints())
    if (j->isEnabled()) unite(bodyIndex(&j->getRigidBodyA()), bodyIndex(&j->getRigidBodyB()));
  for (size_t i = 0; i < n; ++i) {  // per body, as updateActivationState
    if (tracked_[i].kind != 0) continue;
    btRigidBody* b = tracked_[i].body;
    b->updateDeactivation(h);
    if (!b->wantsSleeping())
      b->setActivationState(ACTIVE_TAG);  // leaves DISABLE_DEACTIVATION alone
    else if (b->getActivationState() == ACTIVE_TAG)
      b->setActivationState(WANTS_DEACTIVATION);
  }
  std::vector<char>& awake = island_awake_;  // per island root: some body is not ready to sleep
  awake.assign(n, 0);
  for (size_t i = 0; i < n; ++i) {
    if (tracked_[i].kind != 0) continue;
    const int state = tracked_[i].body->getActivationState();
    if (state != ISLAND_SLEEPING && state != WANTS_DEACTIVATION) awake[size_t(find(int(i)))] = 1;
  }
  for (size_t i = 0; i < n; ++i) {  // per island, as btSimulationIslandManager
    if (tracked_[i].kind != 0) continue;
    btRigidBody* b = tracked_[i].body;
    if (awake[size_t(find(int(i)))]) {
      if (b->getActivationState() == ISLAND_SLEEPING) {
        b->setActivationState(WANTS_DEACTIVATION);
        b->setDeactivationTime(0);
      }
    } else if (b->getActivationState() != ISLAND_SLEEPING) {
      b->setActivationState(ISLAND_SLEEPING);
      b->setLinearVelocity(btVector3(0, 0, 0));
      b->setAngularVelocity(btVector3(0, 0, 0));
      tracked_[i].v = tracked_[i].w = btVector3(0, 0, 0);
    }
  }
}

void DviDynamicsWorld::releaseManifolds() {
  for (auto& e : manifolds_) m_dispatcher1->releaseManifold(e.second);
  manifolds_.clear();
}

// One contact into Bullet's persistent manifold of its pair; the manifolds live as long as their pair touches.
void DviDynamicsWorld::fillManifold(const WorldContact& w, int ia, int ib) {
  btPersistentManifold*& m = manifolds_[(uint64_t(uint32_t(ia)) << 32) | uint32_t(ib)];
  if (!m) m = m_dispatcher1->getNewManifold(w.a, w.b);
  // Bullet's convention: the normal on B points from B toward A.
  btManifoldPoint p(w.a->getWorldTransform().invXform(w.point_a), w.b->getWorldTransform().invXform(w.point_b),
                    -w.normal, w.distance);
  p.m_positionWorldOnA = w.point_a;
  p.m_positionWorldOnB = w.point_b;
  p.m_appliedImpulse = w.normal_impulse;
  p.m_combinedFriction = btScalar(w.a->getFriction() * w.b->getFriction());
  m->addManifoldPoint(p, false);
}

void DviDynamicsWorld::collectContacts() {
  const ContactArrays& c = system_->contacts();
  const std::vector<real>& g = system_->impulses();
  contacts_.clear();
  contacts_.reserve(c.count());
  for (auto& e : manifolds_) e.second->clearManifold();
  for (size_t k = 0; k < c.count(); ++k) {
    const int ia = c.body_a[k], ib = c.body_b[k];
    if (ia < 0 || ib < 0 || size_t(ia) >= tracked_.size() || size_t(ib) >= tracked_.size()) continue;
    WorldContact w;
    w.a = tracked_[size_t(ia)].obj;
    w.b = tracked_[size_t(ib)].obj;
    w.point_a = toBt(c.pa[k]);
    w.point_b = toBt(c.pb[k]);
    w.normal = toBt(c.normal[k]);
    w.distance = btScalar(c.dist[k]);
    w.normal_impulse = 3 * k < g.size() ? btScalar(g[3 * k]) : 0;
    contacts_.push_back(w);
    if (config_.fill_manifolds) fillManifold(w, ia, ib);
  }
  for (auto it = manifolds_.begin(); it != manifolds_.end();) {
    if (it->second->getNumContacts() > 0) {
      ++it;
      continue;
    }
    m_dispatcher1->releaseManifold(it->second);
    it = manifolds_.erase(it);
  }
}

void DviDynamicsWorld::internalSingleStepSimulation(btScalar timeStep) {
  if (m_internalPreTickCallback) (*m_internalPreTickCallback)(this, timeStep);
  using Clock = std::chrono::steady_clock;
  auto since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
  auto t = Clock::now();
  syncIn(timeStep);
  phase_times_.sync_in += since(t);
  t = Clock::now();
  system_->step();
  convergence_.add(system_->lastStats(), substeps_);
  system_->syncToHost();
  phase_times_.step += since(t);
  for (int s = 0; s < kStageCount; ++s) phase_times_.stages[size_t(s)] += system_->lastStats().stage_seconds[size_t(s)];
  t = Clock::now();
  syncOut();
  auto t1 = Clock::now();
  updateSleeping(timeStep);
  phase_times_.sleeping += since(t1);
  t1 = Clock::now();
  updateAabbs();
  if (ghosts_ > 0) computeOverlappingPairs();  // the ghost objects' overlapping pairs (Bullet's pair cache)
  phase_times_.aabbs += since(t1);
  phase_times_.sync_out += since(t);
  t = Clock::now();
  collectContacts();
  phase_times_.contacts += since(t);
  ++phase_times_.substeps;
  updateActions(timeStep);
  ++substeps_;
  sim_time_ += double(timeStep);
  if (m_internalTickCallback) (*m_internalTickCallback)(this, timeStep);
}

}  // namespace dvi
