// The Bullet drop-in world (bullet_world.h).
#include "chrono_like/bullet/bullet_world.h"
#include "chrono_like/base/parallel_for.h"
#include "chrono_like/bullet/bullet_convert.h"

#include <btBulletDynamicsCommon.h>
#include <omp.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <string>
#include <typeinfo>

#include "chrono_like/bullet/bullet_collision_backend.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/bullet/triangle_mesh.h"
#include "chrono_like/integrate.h"

namespace dvi {

namespace {

bool sameTransform(const btTransform& a, const btTransform& b) {
  return a.getOrigin() == b.getOrigin() && a.getBasis()[0] == b.getBasis()[0] && a.getBasis()[1] == b.getBasis()[1] &&
         a.getBasis()[2] == b.getBasis()[2];
}

// Writes v into dst; true when that changed it.
bool put(Vec3& dst, Vec3 v) {
  if (sameVec(dst, v)) return false;
  dst = v;
  return true;
}
bool put(real& dst, real v) {
  if (dst == v) return false;
  dst = v;
  return true;
}
bool put(uint8_t& dst, uint8_t v) {
  if (dst == v) return false;
  dst = v;
  return true;
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
  if (!shape) throw InputError("collision object without a collision shape (Bullet's collision world needs one)");
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
    Pose before;     // the body's pose before the sub-step (holdLockedAxes)
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

// Bullet's anisotropic rolling friction (btCollisionObject::setAnisotropicFriction with CF_ANISOTROPIC_ROLLING_FRICTION;
// RollingFrictionDemo passes btCollisionShape::getAnisotropicRollingFrictionDirection, a round shape's axis): Bullet's
// solver maps each rolling axis t of a contact through each body's factors s in that body's frame, t -> R (s * R^T t),
// body a's then body b's (btSequentialImpulseConstraintSolver::applyAnisotropicFriction), drops a mapped axis shorter
// than 0.001 and bounds the angular impulse about it by mu_r times the normal impulse. Our rolling cone is round in
// the tangent plane, so the contact's mu_r is scaled by the largest gain of that map over the unit tangents (the
// largest singular value of P_b P_a on the tangent plane): a cylinder lying on its side keeps mu_r, one standing on
// its end has none, as in Bullet.
real anisotropicGain(Vec3 n, Quat qa, Vec3 sa, Quat qb, Vec3 sb) {
  const Vec3 helper = std::fabs(n.x) < real(0.6) ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
  const Vec3 u = normalized(cross(n, helper)), w = cross(n, u);
  auto map = [](Vec3 t, Quat q, Vec3 s) {
    const Vec3 l = rotateInv(q, t);
    return rotate(q, Vec3{l.x * s.x, l.y * s.y, l.z * s.z});
  };
  const Vec3 mu = map(map(u, qa, sa), qb, sb), mw = map(map(w, qa, sa), qb, sb);
  const real a = dot(mu, mu), b = dot(mu, mw), d = dot(mw, mw);
  const real gain = std::sqrt(real(0.5) * (a + d + std::sqrt((a - d) * (a - d) + 4 * b * b)));
  return gain < real(0.001) ? real(0) : gain;
}

// The CPU System with pair exclusions: contacts between bodies that Bullet would not collide (a constraint
// with disableCollisionsBetweenLinkedBodies, CF_NO_CONTACT_RESPONSE) are dropped after the narrow phase; and with
// Bullet's anisotropic rolling friction (anisotropicGain; `aniso` holds each body's factors, (1, 1, 1) for none).
class FilteredCpuSystem final : public System {
 public:
  FilteredCpuSystem(const SystemConfig& c, std::function<bool(int, int)> keep, const std::vector<Vec3>* aniso)
      : System(c, makeBulletCollision), keep_(std::move(keep)), aniso_(aniso) {}

 protected:
  void detectCollisions() override {
    System::detectCollisions();
    ContactArrays& c = contacts_;
    stats_.contacts = int64_t(c.keepIf([&](size_t k) { return keep_(c.body_a[k], c.body_b[k]); }));
  }
  // Bullet's rule for the rows of a contact (btSequentialImpulseConstraintSolver::convertContact): spinning friction
  // only where the combined rolling friction is > 0 (a ball with spinning friction alone keeps spinning), and the
  // rolling coefficient scaled by the anisotropic gain.
  bool combineRolling(int64_t nc) override {
    const bool any = System::combineRolling(nc);
    const std::vector<Vec3>& s = *aniso_;
    if (!any || s.size() != bodies_.count()) return any;
    auto isotropic = [&](int32_t i) { return s[size_t(i)].x == 1 && s[size_t(i)].y == 1 && s[size_t(i)].z == 1; };
    parallelFor(int64_t(nc), ompTeam(), [&](int64_t k) {
      real& spin = roll_coef_[size_t(2 * k)];
      real& roll = roll_coef_[size_t(2 * k + 1)];
      if (!(roll > 0)) spin = 0;
      const int32_t a = contacts_.body_a[size_t(k)], b = contacts_.body_b[size_t(k)];
      if (roll > 0 && !(isotropic(a) && isotropic(b)))
        roll *= anisotropicGain(contacts_.normal[size_t(k)], bodies_.rot[size_t(a)], s[size_t(a)],
                                bodies_.rot[size_t(b)], s[size_t(b)]);
    });
    return any;
  }

 private:
  std::function<bool(int, int)> keep_;
  const std::vector<Vec3>* aniso_;
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
    s = std::make_unique<FilteredCpuSystem>(
        c, [this](int a, int b) { return keepPair(a, b); }, &rolling_aniso_);
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

// Refuses, before Bullet takes the object, what the System cannot simulate: the InputError names the API (`api`) and
// the reason (the shape type, ...). On a device backend, rolling and spinning friction are refused here too (the
// device solver has no rolling blocks), not at the first step.
void DviDynamicsWorld::refuseUnsupported(const char* api, const btCollisionObject& obj) const {
  try {
    (void)describe(obj);
  } catch (const InputError& e) { throw InputError(std::string(api) + ": " + e.what()); }
  const btScalar roll = obj.getRollingFriction(), spin = obj.getSpinningFriction();
  if (system_->backendName() != "cpu" && (roll > 0 || spin > 0))
    throw InputError(std::string(api) + ": rolling or spinning friction (setRollingFriction, setSpinningFriction) on " +
                     "the GPU backend; only the CPU backend solves it");
}

// A body without a collision shape (Bullet's createRigidBody(0, transform, 0)) is not part of Bullet's world either:
// btDiscreteDynamicsWorld::addRigidBody sets its gravity and skips it. It never moves there, so a joint to it holds it
// as the ground at its pose (bullet_joints.h: a body outside the System), as Bullet's solver does.
void DviDynamicsWorld::addRigidBody(btRigidBody* body) {
  if (!body) throw InputError("addRigidBody: null body");
  if (body->getCollisionShape()) refuseUnsupported("addRigidBody", *body);
  btDiscreteDynamicsWorld::addRigidBody(body);
  if (body->getCollisionShape()) pending_.push_back(body);
}

void DviDynamicsWorld::addRigidBody(btRigidBody* body, int group, int mask) {
  if (!body) throw InputError("addRigidBody: null body");
  if (body->getCollisionShape()) refuseUnsupported("addRigidBody", *body);
  btDiscreteDynamicsWorld::addRigidBody(body, group, mask);
  if (body->getCollisionShape()) pending_.push_back(body);
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
  refuseUnsupported("addCollisionObject", *object);
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
  contacts_current_ = true;  // none until the next sub-step
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
  const int64_t n = int64_t(tracked_.size());
  return parallelSum(n, n >= config_.parallel_min ? hostThreads() : 1, [&](int64_t i) {
           const Tracked& t = tracked_[size_t(i)];
           return t.obj && (t.obj->getCollisionShape() != t.shape || proxyGroup(*t.obj) != t.group ||
                            proxyMask(*t.obj) != t.mask || objectKind(*t.obj) != t.kind);
         }) > 0;
}

// Bullet's effort (SolverEffort::BulletIterations) or Bullet's effort as the minimum (BulletThenConverged), read
// from btContactSolverInfo each sub-step.
void DviDynamicsWorld::applyBulletEffort(SolverSettings& s) const {
  const btContactSolverInfo& info = getSolverInfo();
  const int sweeps = std::max(1, info.m_numIterations);
  // Gauss-Seidel is sequential: the GPU backend runs APGD for the same iteration counts instead (it read
  // BuildRows' APGD buffers that a Gauss-Seidel step does not build: cudaErrorIllegalAddress on the first step).
  s.type = system_->backendName() == "gpu" ? SolverType::APGD : SolverType::GaussSeidel;
  s.gs_omega = real(info.m_sor);
  s.warm_start = info.m_warmstartingFactor > 0;
  if (config_.effort == SolverEffort::BulletIterations) {
    s.max_iterations = sweeps;
    s.min_iterations = 0;
    s.tolerance = 0;  // a fixed count, judged against the default tolerance in the stats
    return;
  }
  s.min_iterations = sweeps;
  s.max_iterations = std::max(sweeps, config_.bullet_max_sweeps > 0 ? config_.bullet_max_sweeps : 3 * sweeps);
  s.gs_apgd_finish = kDefaultMaxIterations;
  s.tolerance = config_.system.solver.tolerance > 0 ? config_.system.solver.tolerance : kDefaultTolerance;
  s.gs_row_tolerance = real(0.01);
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
  joints_->setErp(real(getSolverInfo().m_erp));  // the joints' recovery of large errors, as Bullet's ERP
  if (config_.effort != SolverEffort::Converged) applyBulletEffort(cfg.solver);
  BodyArrays& B = system_->mutableBodies();
  factors_->locks.clear();
  const int64_t n = int64_t(tracked_.size());
  changes_.assign(size_t(n), 0);
  rolling_aniso_.resize(size_t(n));
  uint8_t* changes = changes_.data();
  parallelFor(int64_t(n), (n >= config_.parallel_min) ? hostThreads() : 1,
              [&](int64_t i) { changes[i] = syncBody(size_t(i), h, B); });
  for (int64_t i = 0; i < n; ++i)
    if (changes[i] & kHasFactors) syncFactors(size_t(i), B);
  joints_->springForces(B, real(h), B.force.data(), B.torque.data());
  for (btTypedConstraint* j : joints_->constraints())  // a spring's force is a parameter change of its bodies
    for (const btRigidBody* body : {&j->getRigidBodyA(), &j->getRigidBodyB()}) {
      const int k = bodyIndex(body);
      if (k >= 0 && !(sameVec(B.force[size_t(k)], Vec3{0, 0, 0}) && sameVec(B.torque[size_t(k)], Vec3{0, 0, 0})))
        changes[k] |= kChangedParams;
    }
  uploadChanges();  // a new System (rebuild) uploads everything anyway, and bodies added since the last step too
  updateExclusions();
}

void DviDynamicsWorld::updateExclusions() {
  std::vector<std::pair<int32_t, int32_t>>& pairs = excl_pairs_next_;  // scratch kept between sub-steps
  std::vector<uint8_t>& flags = excl_flags_next_;
  pairs.clear();
  const int64_t n = int64_t(tracked_.size());
  flags.resize(size_t(n));
  const bool any_flag = parallelSum(n, n >= config_.parallel_min ? hostThreads() : 1, [&](int64_t i) {
                          const btCollisionObject* o = tracked_[size_t(i)].obj;
                          flags[size_t(i)] = o && !o->hasContactResponse();
                          return flags[size_t(i)];
                        }) > 0;
  for (int64_t i = 0; i < n && has_exclusions_; ++i) {
    btCollisionObject* o = tracked_[size_t(i)].obj;
    if (!o) continue;
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

// One body, independent of every other (syncIn runs it in parallel): Bullet's state into the System's arrays.
// Returns what changed there (kChangedState, kChangedParams) and kHasFactors for a body with a linear or angular
// factor other than 1 (syncFactors, serial). The host arrays hold what the device holds after syncToHost (pose and
// velocities) and after the last upload (the rest), except force and torque, which every step clears: a body with
// a nonzero force or torque counts as changed.
uint8_t DviDynamicsWorld::syncBody(size_t i, btScalar h, BodyArrays& B) {
  Tracked& t = tracked_[i];
  const btTransform& tf = poseOf(*t.obj);
  const bool kinematic = t.kind == kBodyKinematic;
  bool state = false, params = false;
  if (kinematic || !sameTransform(tf, t.tf)) {
    state |= put(B.pos[i], fromBt(tf.getOrigin()));
    const Quat q = normalized(fromBt(tf.getRotation()));
    state |= !(B.rot[i].w == q.w && B.rot[i].x == q.x && B.rot[i].y == q.y && B.rot[i].z == q.z);
    B.rot[i] = q;
    t.tf = tf;
  }
  params |= put(B.friction[i], real(t.obj->getFriction()));
  params |= put(B.restitution[i], real(t.obj->getRestitution()));
  // Bullet takes any value here; the System's are lengths >= 0 (a negative one means none, as in Bullet's solver,
  // which adds the rolling rows only for a combined value > 0).
  const real roll = real(t.obj->getRollingFriction()), spin = real(t.obj->getSpinningFriction());
  params |= put(B.rolling_friction[i], roll > 0 && std::isfinite(roll) ? roll : real(0));
  params |= put(B.spinning_friction[i], spin > 0 && std::isfinite(spin) ? spin : real(0));
  rolling_aniso_[i] = t.obj->hasAnisotropicFriction(btCollisionObject::CF_ANISOTROPIC_ROLLING_FRICTION)
                          ? fromBt(t.obj->getAnisotropicFriction())
                          : Vec3{1, 1, 1};
  if (t.kind == kBodyFixed) return uint8_t((state ? kChangedState : 0) | (params ? kChangedParams : 0));
  const btRigidBody& b = *t.body;
  if (kinematic || !(b.getLinearVelocity() == t.v)) state |= put(B.vel[i], fromBt(b.getLinearVelocity()));
  if (kinematic || !(b.getAngularVelocity() == t.w)) state |= put(B.omega[i], fromBt(b.getAngularVelocity()));
  if (kinematic) return uint8_t((state ? kChangedState : 0) | (params ? kChangedParams : 0));
  // A sleeping body is held still until its island wakes (updateSleeping): fixed for this sub-step, so that pairs
  // of sleeping (or sleeping and static) bodies are not even collided; a body that touches it wakes its island.
  const bool asleep = b.getActivationState() == ISLAND_SLEEPING;
  state |= put(B.flags[i], asleep ? uint8_t(kBodyFixed) : uint8_t(0));
  if (asleep) {
    const Vec3 zero{0, 0, 0};
    state |= put(B.vel[i], zero) | put(B.omega[i], zero);
    params |= put(B.gravity[i], zero) | put(B.inv_mass[i], real(0)) | put(B.inv_inertia[i], zero);
    B.force[i] = B.torque[i] = zero;
    return uint8_t((state ? kChangedState : 0) | (params ? kChangedParams : 0));
  }
  params |= put(B.inv_mass[i], real(b.getInvMass()));
  params |= put(B.inv_inertia[i], fromBt(b.getInvInertiaDiagLocal()));
  params |= put(B.gravity[i], fromBt(b.getGravity()));
  B.force[i] = fromBt(b.getTotalForce());
  B.torque[i] = fromBt(b.getTotalTorque());
  params |= !sameVec(B.force[i], Vec3{0, 0, 0}) || !sameVec(B.torque[i], Vec3{0, 0, 0});
  // Bullet's damping rule (btRigidBody::applyDamping), before the forces act.
  const real ld = real(b.getLinearDamping()), ad = real(b.getAngularDamping());
  if (ld > 0) state |= put(B.vel[i], B.vel[i] * real(std::pow(1 - double(ld), double(h))));
  if (ad > 0) state |= put(B.omega[i], B.omega[i] * real(std::pow(1 - double(ad), double(h))));
  const btVector3& lf = b.getLinearFactor();
  const btVector3& af = b.getAngularFactor();
  const bool factors = !(lf == btVector3(1, 1, 1) && af == btVector3(1, 1, 1));
  return uint8_t((state ? kChangedState : 0) | (params ? kChangedParams : 0) | (factors ? kHasFactors : 0));
}

// A body's linear and angular factors other than 1 (syncBody's kHasFactors): a locked world axis becomes a CCP row
// (FactorRows); a factor other than 0 and 1 is refused. Serial: it appends to the rows.
void DviDynamicsWorld::syncFactors(size_t i, BodyArrays& B) {
  const btRigidBody& b = *tracked_[i].body;
  const btVector3 factor[2] = {b.getLinearFactor(), b.getAngularFactor()};
  for (int8_t ang = 0; ang < 2; ++ang) {
    for (int8_t k = 0; k < 3; ++k) {
      const btScalar f = factor[ang][k];
      if (f == 1) continue;
      if (f != 0)
        throw InputError("drop-in world: body " + std::to_string(i) + " has " + (ang ? "angular" : "linear") +
                         " factor " + std::to_string(double(f)) +
                         " on a world axis; only 0 (locked) and 1 (free) are supported");
      factors_->locks.push_back(
          {int32_t(i), ang, k, component(ang ? B.omega[i] : B.vel[i], k), Pose{B.pos[i], B.rot[i]}});
    }
  }
}

// Bodies whose state or parameters syncIn changed go to a device backend (System::markBodiesDirty,
// markBodyParamsDirty; no-ops on the CPU); when many changed (an app that sets every body), the whole arrays.
void DviDynamicsWorld::uploadChanges() {
  std::vector<int32_t>& state = dirty_state_;
  std::vector<int32_t>& params = dirty_params_;
  state.clear();
  params.clear();
  for (size_t i = 0; i < changes_.size(); ++i) {
    if (changes_[i] & kChangedState) state.push_back(int32_t(i));
    if (changes_[i] & kChangedParams) params.push_back(int32_t(i));
  }
  if (8 * (state.size() + params.size()) > changes_.size()) {
    system_->markHostDirty();
    return;
  }
  system_->markBodiesDirty(state);
  system_->markBodyParamsDirty(params);
}

// The factor rows hold a locked velocity component to the solver's tolerance; Bullet's factors hold it exactly (the
// component never changes). After the step each locked component is set to its target, and the body's pose is
// integrated again from its pose before the sub-step with those velocities (integrate.h: the System's own rule), so a
// body held to a plane (Planar2D) stays in it exactly.
void DviDynamicsWorld::holdLockedAxes(btScalar h) {
  if (factors_->locks.empty()) return;
  BodyArrays& B = system_->mutableBodies();
  std::vector<int32_t>& held = dirty_state_;  // uploadChanges' list, free until the next syncIn
  held.clear();
  for (const FactorRows::Lock& l : factors_->locks) {
    const size_t i = size_t(l.body);
    component(l.angular ? B.omega[i] : B.vel[i], l.axis) = l.target;
    if (held.empty() || held.back() != l.body) held.push_back(l.body);
  }
  for (const FactorRows::Lock& l : factors_->locks) {  // the locks of a body are consecutive
    const size_t i = size_t(l.body);
    Vec3 x = l.before.p;
    Quat q = l.before.q;
    integrateBodyPosition(x, q, B.vel[i], B.omega[i], B.flags[i], real(h));
    B.pos[i] = x;
    B.rot[i] = q;
  }
  system_->markBodiesDirty(held);
}

void DviDynamicsWorld::syncOut() {
  const BodyArrays& B = system_->bodies();
  const int64_t n = int64_t(tracked_.size());
  parallelFor(int64_t(n), (n >= config_.parallel_min) ? hostThreads() : 1,
              [&](int64_t i) {  // each body's own Bullet object only
                Tracked& t = tracked_[size_t(i)];
                if (t.kind != 0) return;  // static and kinematic bodies keep Bullet's pose
                btRigidBody* b = t.body;
                b->setLinearVelocity(toBt(B.vel[size_t(i)]));
                b->setAngularVelocity(toBt(B.omega[size_t(i)]));
                btTransform tf;
                tf.setOrigin(toBt(B.pos[size_t(i)]));
                tf.setRotation(toBt(B.rot[size_t(i)]));
                b->setCenterOfMassTransform(tf);  // also the interpolation transform and velocities
                t.tf = b->getCenterOfMassTransform();
                t.v = b->getLinearVelocity();
                t.w = b->getAngularVelocity();
              });
}

// The host loops' team: DviWorldConfig::host_threads, else an explicit SystemConfig::threads, else the CPU backend's team of its last step (its
// governor's choice under load, base/thread_governor.h), else OpenMP's default (the GPU backend).
int DviDynamicsWorld::hostThreads() const {
  if (config_.host_threads > 0) return config_.host_threads;
  if (config_.system.threads > 0) return config_.system.threads;
  const int last = system_ ? system_->lastStats().threads : 0;
  return last > 0 ? last : omp_get_max_threads();
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

namespace {

// Concurrent union-find (Anderson & Woll, "Wait-free parallel algorithms for the union-find problem", STOC 1991):
// a root is linked under the smaller root index by compare-and-swap, so the islands do not depend on the order of
// the unions or on the threads.
int findRoot(std::vector<std::atomic<int>>& root, int i) {
  int r = root[size_t(i)].load(std::memory_order_relaxed);
  while (r != i) {
    const int up = root[size_t(r)].load(std::memory_order_relaxed);
    if (up != r) root[size_t(i)].compare_exchange_weak(r, up, std::memory_order_relaxed);  // path halving
    i = r;
    r = root[size_t(i)].load(std::memory_order_relaxed);
  }
  return i;
}

void uniteRoots(std::vector<std::atomic<int>>& root, int a, int b) {
  for (;;) {
    a = findRoot(root, a);
    b = findRoot(root, b);
    if (a == b) return;
    if (a < b) std::swap(a, b);  // link the larger root under the smaller
    int expected = a;
    if (root[size_t(a)].compare_exchange_strong(expected, b, std::memory_order_relaxed)) return;
  }
}

}  // namespace

// The islands of updateSleeping into island_of_ (each body's union-find root), as Bullet's
// btSimulationIslandManager::findUnions builds them: objects whose broad-phase boxes overlap (Bullet's pair cache,
// computed here from the boxes of the sub-step's start) and that both merge islands, plus this sub-step's contacts
// and the enabled constraints. Sleeping bodies make no contacts with each other (they are fixed), but their boxes
// still overlap: a sleeping island stays one island, and wakes whole when an awake body's box reaches it.
void DviDynamicsWorld::buildIslands(int team) {
  const int64_t n = int64_t(tracked_.size());
  std::vector<std::atomic<int>>& root = island_root_;  // members: no allocation per sub-step once grown
  std::vector<char>& merges = island_merges_;
  if (root.size() != size_t(n)) root = std::vector<std::atomic<int>>(size_t(n));
  merges.resize(size_t(n));
  parallelFor(int64_t(n), (n >= config_.parallel_min) ? team : 1, [&](int64_t i) {
    root[size_t(i)].store(int(i), std::memory_order_relaxed);
    const Tracked& t = tracked_[size_t(i)];
    merges[size_t(i)] = t.kind == 0 && t.obj->mergesSimulationIslands();
    if (t.obj) t.obj->setIslandTag(int(i));  // the System index, to find a pair's bodies (ghosts are not tracked)
  });
  const ContactArrays& c = system_->contacts();
  const int64_t nc = int64_t(c.count());
  parallelFor(int64_t(nc), (nc >= config_.parallel_min) ? team : 1, [&](int64_t k) {
    const int a = c.body_a[size_t(k)], b = c.body_b[size_t(k)];
    if (a >= 0 && b >= 0 && merges[size_t(a)] && merges[size_t(b)]) uniteRoots(root, a, b);
  });
  if (ghosts_ == 0) computeOverlappingPairs();  // with ghost objects, the last sub-step's pairs are current
  const btOverlappingPairCache* cache = m_broadphasePairCache->getOverlappingPairCache();
  const int np = cache->getNumOverlappingPairs();
  const btBroadphasePair* pairs =
      np > 0 ? const_cast<btOverlappingPairCache*>(cache)->getOverlappingPairArrayPtr() : nullptr;
  auto trackedIndex = [&](const btBroadphaseProxy* p) {
    const auto* o = static_cast<const btCollisionObject*>(p->m_clientObject);
    const int i = o ? o->getIslandTag() : -1;
    return i >= 0 && i < n && tracked_[size_t(i)].obj == o ? i : -1;
  };
  for (int p = 0; p < np; ++p) {
    const int a = trackedIndex(pairs[p].m_pProxy0), b = trackedIndex(pairs[p].m_pProxy1);
    if (a >= 0 && b >= 0 && merges[size_t(a)] && merges[size_t(b)]) uniteRoots(root, a, b);
  }
  for (btTypedConstraint* j : joints_->constraints()) {
    const int a = bodyIndex(&j->getRigidBodyA()), b = bodyIndex(&j->getRigidBodyB());
    if (j->isEnabled() && a >= 0 && b >= 0 && merges[size_t(a)] && merges[size_t(b)]) uniteRoots(root, a, b);
  }
  std::vector<int>& island = island_of_;
  island.resize(size_t(n));
  parallelFor(int64_t(n), (n >= config_.parallel_min) ? team : 1,
              [&](int64_t i) { island[size_t(i)] = findRoot(root, int(i)); });
}

// Bullet's deactivation (btDiscreteDynamicsWorld::updateActivationState and btSimulationIslandManager): each
// dynamic body counts the time its speeds stay below its sleeping thresholds; an island (bodies joined by this
// sub-step's broad-phase pairs and contacts and by enabled constraints, buildIslands; static, kinematic and
// no-response objects join none) whose bodies all want to sleep falls asleep (velocities zeroed), any other island
// is awake. While no body wants to sleep and none sleeps, every island is awake and the islands are not built.
void DviDynamicsWorld::updateSleeping(btScalar h) {
  const int64_t n = int64_t(tracked_.size());
  const int team = hostThreads();
  // Bodies asleep or ready to sleep (as the last sub-step left them), counted as 1 each; kinematic bodies as 2^32.
  const long long counts = parallelSum(n, n >= config_.parallel_min ? team : 1, [&](int64_t i) -> long long {
    if (tracked_[size_t(i)].kind == kBodyKinematic) return 1LL << 32;
    if (tracked_[size_t(i)].kind != 0) return 0;
    const int state = tracked_[size_t(i)].body->getActivationState();
    return state == ISLAND_SLEEPING || state == WANTS_DEACTIVATION;
  });
  const long long resting = counts & 0xffffffffLL, kinematic = counts >> 32;
  if (kinematic > 0) wakeTouchedByKinematic();  // its loop over the bodies is serial
  if (resting > 0) sleepOrWakeIslands(team);
  parallelFor(int64_t(n), (n >= config_.parallel_min) ? team : 1,
              [&](int64_t i) {  // per body, as updateActivationState
                Tracked& t = tracked_[size_t(i)];
                if (t.kind != 0) return;
                btRigidBody* b = t.body;
                b->updateDeactivation(h);
                if (!b->wantsSleeping()) {
                  b->setActivationState(ACTIVE_TAG);  // leaves DISABLE_DEACTIVATION alone
                } else if (b->getActivationState() == ACTIVE_TAG) {
                  b->setActivationState(WANTS_DEACTIVATION);
                } else if (b->getActivationState() == ISLAND_SLEEPING) {
                  b->setLinearVelocity(btVector3(0, 0, 0));
                  b->setAngularVelocity(btVector3(0, 0, 0));
                  t.v = t.w = btVector3(0, 0, 0);
                }
              });
}

// btSimulationIslandManager::buildIslands' decision, on the states the last sub-step's updateActivationState left
// (Bullet decides before its solve, then updates each body's deactivation): an island whose bodies all rest
// (ISLAND_SLEEPING or WANTS_DEACTIVATION) falls asleep; in any other island a sleeping body wakes
// (WANTS_DEACTIVATION, its deactivation time restarted).
void DviDynamicsWorld::sleepOrWakeIslands(int team) {
  const int64_t n = int64_t(tracked_.size());
  buildIslands(team);
  const std::vector<int>& island = island_of_;
  std::vector<char>& awake = island_awake_;  // per island root: some body is not ready to sleep
  awake.assign(size_t(n), 0);
  for (int64_t i = 0; i < n; ++i) {
    if (tracked_[size_t(i)].kind != 0) continue;
    const int state = tracked_[size_t(i)].body->getActivationState();
    if (state != ISLAND_SLEEPING && state != WANTS_DEACTIVATION) awake[size_t(island[size_t(i)])] = 1;
  }
  parallelFor(int64_t(n), (n >= config_.parallel_min) ? team : 1,
              [&](int64_t i) {  // per island, as btSimulationIslandManager
                Tracked& t = tracked_[size_t(i)];
                if (t.kind != 0) return;
                btRigidBody* b = t.body;
                if (awake[size_t(island[size_t(i)])]) {
                  if (b->getActivationState() == ISLAND_SLEEPING) {
                    b->setActivationState(WANTS_DEACTIVATION);
                    b->setDeactivationTime(0);
                  }
                } else if (b->getActivationState() != ISLAND_SLEEPING) {
                  b->setActivationState(ISLAND_SLEEPING);
                }
              });
}

// Bullet's AABB update (btCollisionWorld::updateAabbs: every object when m_forceUpdateAllAabbs, else the active
// ones; each box grown by the contact breaking threshold and, with continuous collision, joined with the box at the
// interpolation transform), with the boxes computed in parallel. With Bullet's btDbvtBroadphase and no ghost objects,
// a box inside its leaf's grown volume changes neither tree and is written into its own proxy there (what setAabb
// does in that case, less moving the proxy to the newest stage, which only orders the incremental tree optimisation
// of calculateOverlappingPairs; with ghost objects, which need that, every box goes through setAabb). The other
// boxes go through the broad phase's setAabb, serially; a moving box too large for it goes to Bullet's own
// updateSingleAabb, which deactivates the object and reports.
void DviDynamicsWorld::updateAabbs() {
  const int n = m_collisionObjects.size();
  aabb_lo_.resize(size_t(n));
  aabb_hi_.resize(size_t(n));
  object_flags_.resize(size_t(n));
  const btVector3 grow(gContactBreakingThreshold, gContactBreakingThreshold, gContactBreakingThreshold);
  const bool continuous = getDispatchInfo().m_useContinuous;
  const bool dbvt = ghosts_ == 0 && dynamic_cast<btDbvtBroadphase*>(m_broadphasePairCache) != nullptr;
  parallelFor(int(n), (n >= config_.parallel_min) ? hostThreads() : 1, [&](int i) {
    btCollisionObject* o = m_collisionObjects[i];
    object_flags_[size_t(i)] = (m_forceUpdateAllAabbs || o->isActive()) && o->getBroadphaseHandle();
    if (!object_flags_[size_t(i)]) return;
    btVector3 lo, hi;
    o->getCollisionShape()->getAabb(o->getWorldTransform(), lo, hi);
    if (continuous && o->getInternalType() == btCollisionObject::CO_RIGID_BODY && !o->isStaticOrKinematicObject()) {
      btVector3 lo2, hi2;
      o->getCollisionShape()->getAabb(o->getInterpolationWorldTransform(), lo2, hi2);
      lo.setMin(lo2);
      hi.setMax(hi2);
    }
    lo -= grow;
    hi += grow;
    if (dbvt) {
      auto* p = static_cast<btDbvtProxy*>(o->getBroadphaseHandle());
      if (p->leaf && p->leaf->volume.Contain(btDbvtVolume::FromMM(lo, hi))) {
        p->m_aabbMin = lo;
        p->m_aabbMax = hi;
        object_flags_[size_t(i)] = 0;
        return;
      }
    }
    aabb_lo_[size_t(i)] = lo;
    aabb_hi_[size_t(i)] = hi;
  });
  for (int i = 0; i < n; ++i) {
    if (!object_flags_[size_t(i)]) continue;
    btCollisionObject* o = m_collisionObjects[i];
    if (o->isStaticObject() || (aabb_hi_[size_t(i)] - aabb_lo_[size_t(i)]).length2() < btScalar(1e12))
      m_broadphasePairCache->setAabb(o->getBroadphaseHandle(), aabb_lo_[size_t(i)], aabb_hi_[size_t(i)], m_dispatcher1);
    else
      updateSingleAabb(o);
  }
}

// Bullet's motion-state update (btDiscreteDynamicsWorld::synchronizeMotionStates: every rigid body when
// m_synchronizeAllMotionStates, else the active non-static ones; synchronizeSingleMotionState per body). Bodies with
// Bullet's own btDefaultMotionState (which writes only itself) go in parallel; an app's motion states are user code
// and are called one after the other, in order.
void DviDynamicsWorld::synchronizeMotionStates() {
  const bool all = m_synchronizeAllMotionStates;
  const int n = all ? m_collisionObjects.size() : m_nonStaticRigidBodies.size();
  object_flags_.resize(size_t(n));  // scratch: 1 for an app's motion state
  auto bodyAt = [&](int i) { return all ? btRigidBody::upcast(m_collisionObjects[i]) : m_nonStaticRigidBodies[i]; };
  parallelFor(int(n), (n >= config_.parallel_min) ? hostThreads() : 1, [&](int i) {
    btRigidBody* b = bodyAt(i);
    object_flags_[size_t(i)] = 0;
    if (!b || (!all && !b->isActive())) return;
    const btMotionState* ms = b->getMotionState();
    if (ms && typeid(*ms) != typeid(btDefaultMotionState)) {
      object_flags_[size_t(i)] = 1;
      return;
    }
    synchronizeSingleMotionState(b);
  });
  for (int i = 0; i < n; ++i)
    if (object_flags_[size_t(i)]) synchronizeSingleMotionState(bodyAt(i));
}

// Bullet's kinematic-velocity update (btDiscreteDynamicsWorld::saveKinematicState: every kinematic rigid body not
// asleep derives its velocity from its motion state's pose). The kinematic bodies are found in parallel; their
// motion states (an app's code) are called one after the other, in order.
void DviDynamicsWorld::saveKinematicState(btScalar timeStep) {
  const int n = m_collisionObjects.size();
  object_flags_.resize(size_t(n));  // scratch: 1 for a kinematic body to update
  parallelFor(int(n), (n >= config_.parallel_min) ? hostThreads() : 1, [&](int i) {
    const btRigidBody* b = btRigidBody::upcast(m_collisionObjects[i]);
    object_flags_[size_t(i)] = b && b->getActivationState() != ISLAND_SLEEPING && b->isKinematicObject();
  });
  for (int i = 0; i < n; ++i)
    if (object_flags_[size_t(i)]) btRigidBody::upcast(m_collisionObjects[i])->saveKinematicState(timeStep);
}

// Bullet's force reset (btDiscreteDynamicsWorld::clearForces, every non-static rigid body), in parallel.
void DviDynamicsWorld::clearForces() {
  const int n = m_nonStaticRigidBodies.size();
  parallelFor(int(n), (n >= config_.parallel_min) ? hostThreads() : 1,
              [&](int i) { m_nonStaticRigidBodies[i]->clearForces(); });
}

void DviDynamicsWorld::releaseManifolds() {
  // Nothing to release (e.g. the second of many removals in a row): clear() would still wipe every bucket of the
  // map, which a 100,000-body world has ~300,000 of, once per removed body.
  if (manifolds_.empty()) return;
  for (auto& e : manifolds_) m_dispatcher1->releaseManifold(e.second.manifold);
  manifolds_.clear();
}

// The manifold slot of a body pair (System indices), made on first use.
DviDynamicsWorld::ManifoldSlot& DviDynamicsWorld::manifoldSlot(int ia, int ib) {
  ManifoldSlot& slot = manifolds_[pairKey(ia, ib)];
  if (!slot.manifold) slot.manifold = m_dispatcher1->getNewManifold(tracked_[size_t(ia)].obj, tracked_[size_t(ib)].obj);
  return slot;
}

// Contact k of the System into its pair's manifold; the manifold is emptied the first time this sub-step (then true).
bool DviDynamicsWorld::fillManifold(ManifoldSlot& slot, int64_t k) {
  const ContactArrays& c = system_->contacts();
  const btCollisionObject* a = tracked_[size_t(c.body_a[size_t(k)])].obj;
  const btCollisionObject* b = tracked_[size_t(c.body_b[size_t(k)])].obj;
  btPersistentManifold* m = slot.manifold;
  const bool first = slot.used != substeps_;
  if (first) {
    m->clearManifold();
    slot.used = substeps_;
  }
  const btVector3 pa = toBt(c.pa[size_t(k)]), pb = toBt(c.pb[size_t(k)]);
  // Bullet's convention: the normal on B points from B toward A.
  btManifoldPoint p(a->getWorldTransform().invXform(pa), b->getWorldTransform().invXform(pb),
                    -toBt(c.normal[size_t(k)]), btScalar(c.dist[size_t(k)]));
  p.m_positionWorldOnA = pa;
  p.m_positionWorldOnB = pb;
  p.m_appliedImpulse = normalImpulse(k);
  p.m_combinedFriction = btScalar(a->getFriction() * b->getFriction());
  m->addManifoldPoint(p, false);
  return first;
}

// Contact k's normal impulse over the last sub-step (0 where the solver kept none).
btScalar DviDynamicsWorld::normalImpulse(int64_t k) const {
  const std::vector<real>& g = system_->impulses();
  return 3 * size_t(k) < g.size() ? btScalar(g[3 * size_t(k)]) : 0;
}

// Whether both bodies of a System contact are the world's (every one today).
bool DviDynamicsWorld::tracksPair(int ia, int ib) const {
  const int nb = int(tracked_.size());
  return ia >= 0 && ib >= 0 && ia < nb && ib < nb && tracked_[size_t(ia)].obj && tracked_[size_t(ib)].obj;
}

// contacts() from the System's contacts, in parallel (each entry its own). Contacts between bodies the world
// does not track (none today) are left out.
void DviDynamicsWorld::buildWorldContacts() const {
  const ContactArrays& c = system_->contacts();
  const int64_t nc = int64_t(c.count());
  contacts_.resize(size_t(nc));
  const int64_t untracked = parallelSum(nc, nc >= config_.parallel_min ? hostThreads() : 1, [&](int64_t k) {
    const int ia = c.body_a[size_t(k)], ib = c.body_b[size_t(k)];
    WorldContact& w = contacts_[size_t(k)];
    if (!tracksPair(ia, ib)) {
      w.a = w.b = nullptr;
      return 1;
    }
    w.a = tracked_[size_t(ia)].obj;
    w.b = tracked_[size_t(ib)].obj;
    w.point_a = toBt(c.pa[size_t(k)]);
    w.point_b = toBt(c.pb[size_t(k)]);
    w.normal = toBt(c.normal[size_t(k)]);
    w.distance = btScalar(c.dist[size_t(k)]);
    w.normal_impulse = normalImpulse(k);
    return 0;
  });
  if (untracked > 0)
    contacts_.erase(std::remove_if(contacts_.begin(), contacts_.end(), [](const WorldContact& w) { return !w.a; }),
                    contacts_.end());
}

const std::vector<WorldContact>& DviDynamicsWorld::contacts() const {
  if (!contacts_current_) {
    buildWorldContacts();
    contacts_current_ = true;
  }
  return contacts_;
}

// Bullet's manifolds from the System's contacts (in its order). The narrow phase writes a shape pair's
// points together, so where both bodies have one shape a body pair's contacts form one run, which fills its own
// manifold: those runs go in parallel (btPersistentManifold::addManifoldPoint touches its manifold only). New
// manifolds (the dispatcher makes them), runs of bodies with several shapes (one body pair, several runs) and every
// run while one of Bullet's global contact callbacks is set (user code) go one after the other.
void DviDynamicsWorld::fillManifolds() {
  const ContactArrays& c = system_->contacts();
  const BodyArrays& B = system_->bodies();
  const int64_t nc = int64_t(c.count());
  runs_.clear();
  for (int64_t k = 0; k < nc;) {
    int64_t e = k + 1;
    while (e < nc && c.body_a[size_t(e)] == c.body_a[size_t(k)] && c.body_b[size_t(e)] == c.body_b[size_t(k)]) ++e;
    if (tracksPair(c.body_a[size_t(k)], c.body_b[size_t(k)])) runs_.push_back({k, e, nullptr});
    k = e;
  }
  const bool callbacks =
      gContactStartedCallback || gContactEndedCallback || gContactDestroyedCallback || gContactProcessedCallback;
  const int team = callbacks ? 1 : hostThreads();
  const int64_t nr = int64_t(runs_.size());
  auto single = [&](int i) { return B.shape_count[size_t(i)] == 1; };
  parallelFor(int64_t(nr), (nr >= config_.parallel_min) ? team : 1, [&](int64_t r) {  // read-only look-ups
    const int64_t k = runs_[size_t(r)].begin;
    const int ia = c.body_a[size_t(k)], ib = c.body_b[size_t(k)];
    if (!single(ia) || !single(ib)) return;
    auto it = manifolds_.find(pairKey(ia, ib));
    if (it != manifolds_.end()) runs_[size_t(r)].slot = &it->second;
  });
  int64_t used = 0;         // manifolds filled this sub-step
  for (Run& run : runs_) {  // serial: new manifolds, and the runs of bodies with several shapes
    const int ia = c.body_a[size_t(run.begin)], ib = c.body_b[size_t(run.begin)];
    if (run.slot) continue;
    if (single(ia) && single(ib)) {
      run.slot = &manifoldSlot(ia, ib);
      continue;
    }
    for (int64_t k = run.begin; k < run.end; ++k) used += fillManifold(manifoldSlot(ia, ib), k);
  }
  used += parallelSum(nr, nr >= config_.parallel_min ? team : 1, [&](int64_t r) {
    const Run& run = runs_[size_t(r)];
    int64_t u = 0;
    if (run.slot)  // else filled above
      for (int64_t k = run.begin; k < run.end; ++k) u += fillManifold(*run.slot, k);
    return u;
  });
  if (size_t(used) == manifolds_.size()) return;  // every manifold filled: none to release
  // A body asleep is held fixed, so a pair of resting bodies (asleep, or asleep and static) makes no contacts; its
  // manifold keeps its last points while both rest, as Bullet's does (its dispatcher skips such pairs).
  auto resting = [&](uint32_t i) {
    const Tracked& t = tracked_[i];
    return t.obj && (t.kind != 0 || t.obj->getActivationState() == ISLAND_SLEEPING);
  };
  for (auto it = manifolds_.begin(); it != manifolds_.end();) {  // pairs that no longer touch
    const bool kept = it->second.used == substeps_
                          ? it->second.manifold->getNumContacts() > 0
                          : resting(uint32_t(it->first >> 32)) && resting(uint32_t(it->first & 0xffffffffu));
    if (kept) {
      ++it;
      continue;
    }
    m_dispatcher1->releaseManifold(it->second.manifold);
    it = manifolds_.erase(it);
  }
}

void DviDynamicsWorld::collectContacts() {
  contacts_current_ = false;  // contacts() makes them when asked
  if (config_.fill_manifolds) fillManifolds();
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
  holdLockedAxes(timeStep);
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
