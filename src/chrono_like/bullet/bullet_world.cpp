// The Bullet drop-in world (bullet_world.h).
#include "chrono_like/bullet/bullet_world.h"
#include "chrono_like/bullet/bullet_convert.h"

#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>

#include "chrono_like/bullet/bullet_collision_backend.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/bullet/triangle_mesh.h"

namespace dvi {

namespace {

bool sameTransform(const btTransform& a, const btTransform& b) {
  return a.getOrigin() == b.getOrigin() && a.getBasis()[0] == b.getBasis()[0] && a.getBasis()[1] == b.getBasis()[1] &&
         a.getBasis()[2] == b.getBasis()[2];
}

int bodyKind(const btRigidBody& b) {
  if (b.isKinematicObject()) return kBodyKinematic;
  if (b.isStaticObject() || b.getInvMass() == 0) return kBodyFixed;
  return 0;
}

int proxyGroup(const btRigidBody& b) {
  return b.getBroadphaseHandle() ? b.getBroadphaseHandle()->m_collisionFilterGroup : 1;
}
int proxyMask(const btRigidBody& b) {
  return b.getBroadphaseHandle() ? b.getBroadphaseHandle()->m_collisionFilterMask : -1;
}

// The body as the System takes it; shapes include static triangle geometry (triangle_mesh.h).
BodyDesc describe(const btRigidBody& body) {
  const btCollisionShape* shape = body.getCollisionShape();
  if (!shape) throw InputError("rigid body without a collision shape");
  if (!hasTriangles(*shape)) {
    BodyDesc d = bodyDescFromBullet(body);
    d.has_gravity = true;  // the body's own gravity (Bullet sets it from the world when added)
    d.gravity = fromBt(body.getGravity());
    return d;
  }
  const int kind = bodyKind(body);
  if (kind == 0)
    throw InputError(std::string("a dynamic body cannot use a triangle shape (") + shape->getName() +
                     "); Bullet supports it only on static or kinematic bodies");
  BodyDesc d = bodyMotionFromBullet(body);
  d.flags = uint8_t(kind);
  d.mass = 0;
  d.inertia = Vec3{0, 0, 0};
  appendShapesWithTriangles(*shape, Pose{{0, 0, 0}, {1, 0, 0, 0}}, d.shapes);
  const int16_t group = int16_t(proxyGroup(body)), mask = int16_t(proxyMask(body));
  for (ShapeDesc& s : d.shapes) {
    s.shape.group = group;
    s.shape.mask = mask;
  }
  return d;
}

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
    const size_t n = c.count();
    size_t m = 0;
    for (size_t k = 0; k < n; ++k) {
      if (!keep_(c.body_a[k], c.body_b[k])) continue;
      if (m != k) {
        c.shape_a[m] = c.shape_a[k];
        c.shape_b[m] = c.shape_b[k];
        c.body_a[m] = c.body_a[k];
        c.body_b[m] = c.body_b[k];
        c.normal[m] = c.normal[k];
        c.pa[m] = c.pa[k];
        c.pb[m] = c.pb[k];
        c.dist[m] = c.dist[k];
        c.key[m] = c.key[k];
      }
      ++m;
    }
    if (m != n) c.resize(m);
    stats_.contacts = int64_t(m);
  }

 private:
  std::function<bool(int, int)> keep_;
};

}  // namespace

DviDynamicsWorld::DviDynamicsWorld(btDispatcher* dispatcher, btBroadphaseInterface* pairCache,
                                   btConstraintSolver* constraintSolver,
                                   btCollisionConfiguration* collisionConfiguration, DviWorldConfig config)
    : btDiscreteDynamicsWorld(dispatcher, pairCache, constraintSolver, collisionConfiguration), config_(config) {
  joints_ = std::make_shared<BulletJoints>(&index_, config_.joints);
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
  return s;
}

bool DviDynamicsWorld::keepPair(int a, int b) const {
  const btRigidBody* ba = tracked_[size_t(a)].body;
  const btRigidBody* bb = tracked_[size_t(b)].body;
  if (ba->hasContactResponse() == false || bb->hasContactResponse() == false) return false;
  if (has_exclusions_ && (!ba->checkCollideWith(bb) || !bb->checkCollideWith(ba))) return false;
  return true;
}

int DviDynamicsWorld::bodyIndex(const btRigidBody* body) const {
  auto it = index_.find(body);
  return it == index_.end() ? -1 : it->second;
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

void DviDynamicsWorld::removeRigidBody(btRigidBody* body) {
  btDiscreteDynamicsWorld::removeRigidBody(body);
  pending_.erase(std::remove(pending_.begin(), pending_.end(), body), pending_.end());
  auto it = index_.find(body);
  if (it != index_.end()) {
    tracked_.erase(tracked_.begin() + it->second);
    index_.clear();
    for (size_t i = 0; i < tracked_.size(); ++i) index_[tracked_[i].body] = int(i);
    rebuild_ = true;
  }
  // Joints on the body leave the System with it (Bullet asks the app to remove them first).
  for (btTypedConstraint* c : std::vector<btTypedConstraint*>(joints_->constraints()))
    if (&c->getRigidBodyA() == body || &c->getRigidBodyB() == body) joints_->remove(c);
  releaseManifolds();
  contacts_.erase(std::remove_if(contacts_.begin(), contacts_.end(),
                                 [&](const WorldContact& c) { return c.a == body || c.b == body; }),
                  contacts_.end());
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

void DviDynamicsWorld::addToSystem(btRigidBody* body) {
  BodyDesc d = describe(*body);
  const int i = system_->addBody(d);
  index_[body] = i;
  Tracked t;
  t.body = body;
  t.tf = body->getCenterOfMassTransform();
  t.v = body->getLinearVelocity();
  t.w = body->getAngularVelocity();
  t.shape = body->getCollisionShape();
  t.group = proxyGroup(*body);
  t.mask = proxyMask(*body);
  t.kind = bodyKind(*body);
  if (size_t(i) != tracked_.size()) throw InputError("drop-in world: body index out of step with the System");
  tracked_.push_back(t);
}

void DviDynamicsWorld::rebuild() {
  std::vector<btRigidBody*> bodies;
  bodies.reserve(tracked_.size());
  for (const Tracked& t : tracked_) bodies.push_back(t.body);
  tracked_.clear();
  index_.clear();
  system_ = makeSystem();
  for (btRigidBody* b : bodies) addToSystem(b);
  rebuild_ = false;
}

void DviDynamicsWorld::syncIn(btScalar h) {
  // Structural changes first: a new shape, filter or body kind needs the System rebuilt.
  for (const Tracked& t : tracked_)
    if (t.body->getCollisionShape() != t.shape || proxyGroup(*t.body) != t.group || proxyMask(*t.body) != t.mask ||
        bodyKind(*t.body) != t.kind)
      rebuild_ = true;
  if (rebuild_) rebuild();
  for (btRigidBody* b : pending_) addToSystem(b);
  pending_.clear();

  system_->mutableConfig().step.dt = real(h);
  system_->mutableConfig().solver.min_bounce_speed = real(getSolverInfo().m_restitutionVelocityThreshold);
  BodyArrays& B = system_->mutableBodies();
  for (size_t i = 0; i < tracked_.size(); ++i) {
    Tracked& t = tracked_[i];
    const btRigidBody& b = *t.body;
    const btTransform& tf = b.getCenterOfMassTransform();
    const bool kinematic = t.kind == kBodyKinematic;
    if (kinematic || !sameTransform(tf, t.tf)) {
      B.pos[i] = fromBt(tf.getOrigin());
      B.rot[i] = normalized(fromBt(tf.getRotation()));
      t.tf = tf;
    }
    if (t.kind == kBodyFixed) continue;
    if (kinematic || !(b.getLinearVelocity() == t.v)) B.vel[i] = fromBt(b.getLinearVelocity());
    if (kinematic || !(b.getAngularVelocity() == t.w)) B.omega[i] = fromBt(b.getAngularVelocity());
    if (kinematic) continue;
    B.inv_mass[i] = real(b.getInvMass());
    B.inv_inertia[i] = fromBt(b.getInvInertiaDiagLocal());
    B.gravity[i] = fromBt(b.getGravity());
    B.friction[i] = real(b.getFriction());
    B.restitution[i] = real(b.getRestitution());
    B.force[i] = fromBt(b.getTotalForce());
    B.torque[i] = fromBt(b.getTotalTorque());
    // Bullet's damping rule (btRigidBody::applyDamping), before the forces act.
    const real ld = real(b.getLinearDamping()), ad = real(b.getAngularDamping());
    if (ld > 0) B.vel[i] = B.vel[i] * real(std::pow(1 - double(ld), double(h)));
    if (ad > 0) B.omega[i] = B.omega[i] * real(std::pow(1 - double(ad), double(h)));
  }
  for (size_t i = 0; i < tracked_.size(); ++i)
    if (tracked_[i].kind == kBodyFixed) {
      B.friction[i] = real(tracked_[i].body->getFriction());
      B.restitution[i] = real(tracked_[i].body->getRestitution());
    }
  joints_->springForces(B, B.force.data(), B.torque.data());
  system_->markHostDirty();
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

void DviDynamicsWorld::releaseManifolds() {
  for (btPersistentManifold* m : manifolds_) m_dispatcher1->releaseManifold(m);
  manifolds_.clear();
}

void DviDynamicsWorld::collectContacts() {
  const ContactArrays& c = system_->contacts();
  const std::vector<real>& g = system_->impulses();
  contacts_.clear();
  contacts_.reserve(c.count());
  releaseManifolds();
  std::map<std::pair<int, int>, btPersistentManifold*> by_pair;
  for (size_t k = 0; k < c.count(); ++k) {
    const int ia = c.body_a[k], ib = c.body_b[k];
    if (ia < 0 || ib < 0 || size_t(ia) >= tracked_.size() || size_t(ib) >= tracked_.size()) continue;
    WorldContact w;
    w.a = tracked_[size_t(ia)].body;
    w.b = tracked_[size_t(ib)].body;
    w.point_a = toBt(c.pa[k]);
    w.point_b = toBt(c.pb[k]);
    w.normal = toBt(c.normal[k]);
    w.distance = btScalar(c.dist[k]);
    w.normal_impulse = 3 * k < g.size() ? btScalar(g[3 * k]) : 0;
    contacts_.push_back(w);
    if (!config_.fill_manifolds) continue;
    btPersistentManifold*& m = by_pair[{ia, ib}];
    if (!m) {
      m = m_dispatcher1->getNewManifold(w.a, w.b);
      manifolds_.push_back(m);
    }
    // Bullet's convention: the normal on B points from B toward A.
    btManifoldPoint p(w.a->getWorldTransform().invXform(w.point_a), w.b->getWorldTransform().invXform(w.point_b),
                      -w.normal, w.distance);
    p.m_positionWorldOnA = w.point_a;
    p.m_positionWorldOnB = w.point_b;
    p.m_appliedImpulse = w.normal_impulse;
    p.m_combinedFriction =
        btScalar(tracked_[size_t(ia)].body->getFriction() * tracked_[size_t(ib)].body->getFriction());
    m->addManifoldPoint(p, false);
  }
}

void DviDynamicsWorld::internalSingleStepSimulation(btScalar timeStep) {
  if (m_internalPreTickCallback) (*m_internalPreTickCallback)(this, timeStep);
  syncIn(timeStep);
  system_->step();
  convergence_.add(system_->lastStats(), substeps_);
  system_->syncToHost();
  syncOut();
  updateAabbs();
  collectContacts();
  updateActions(timeStep);
  ++substeps_;
  sim_time_ += double(timeStep);
  if (m_internalTickCallback) (*m_internalTickCallback)(this, timeStep);
}

}  // namespace dvi
