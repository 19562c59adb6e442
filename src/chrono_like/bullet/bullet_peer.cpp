// The Bullet peer (bullet_peer.h): copies of the given bodies stepped by Bullet's own
// btDiscreteDynamicsWorld with its sequential-impulse solver, in Bullet units = scene units x length_scale.
//
// What is scaled by s = length_scale on the way in (and divided on the way out):
//   positions, linear velocities, shape dimensions (radii, half extents, heights, hull points, sphere
//   centres, child offsets of compounds, plane constants), gravity, the linear sleeping threshold and the
//   CCD motion threshold / swept-sphere radius; principal inertia by s^2 (the body's own values, so a
//   user-set inertia survives). Masses, angular velocities, friction, restitution and damping are copied.
// What is NOT scaled: collision margins. Every cloned shape gets Bullet's default margin for its type
// (0.04, or btBoxShape's/btCylinderShape's "safe margin" for small boxes), i.e. exactly what a user who
// built the scene in Bullet units would run: that is the point of the peer.
#include "chrono_like/bullet/bullet_peer.h"
#include "chrono_like/bullet/bullet_convert.h"

#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <chrono>
#include <string>

#include "chrono_like/base/errors.h"

namespace dvi {

namespace {}  // namespace

struct BulletPeer::Impl {
  BulletPeerSettings settings;
  btScalar s = 1;  // length scale
  std::unique_ptr<btDefaultCollisionConfiguration> config;
  std::unique_ptr<btCollisionDispatcher> dispatcher;
  std::unique_ptr<btDbvtBroadphase> broadphase;
  std::unique_ptr<btSequentialImpulseConstraintSolver> solver;
  std::unique_ptr<btDiscreteDynamicsWorld> world;
  std::vector<std::unique_ptr<btCollisionShape>> shapes;  // every cloned shape, compound children included
  std::vector<std::unique_ptr<btRigidBody>> bodies;
  BulletPeerStats stats;

  ~Impl() {
    if (world) {
      // Removing bodies one by one is quadratic in Bullet 3.24 (2.6 s for 100k spheres): every removal cleans
      // its proxy from the whole pair cache, and btDiscreteDynamicsWorld::removeRigidBody finds the body in
      // its non-static array by a linear search from the front. So: empty the pair cache in one pass, then
      // remove the non-static bodies in the order that keeps each at the front of that array (b0, then the
      // last one, which took b0's slot, and so on backwards), and the static ones last.
      struct RemoveAll : btOverlapCallback {
        bool processOverlap(btBroadphasePair&) override { return true; }
      } remove_all;
      world->getPairCache()->processAllOverlappingPairs(&remove_all, world->getDispatcher());
      std::vector<btRigidBody*> moving, fixed;
      for (auto& b : bodies) (b->isStaticObject() ? fixed : moving).push_back(b.get());
      if (!moving.empty()) {
        world->removeRigidBody(moving.front());
        for (size_t i = moving.size() - 1; i >= 1; --i) world->removeRigidBody(moving[i]);
      }
      for (btRigidBody* b : fixed) world->removeRigidBody(b);
    }
    bodies.clear();
    world.reset();
    solver.reset();
    broadphase.reset();
    dispatcher.reset();
    config.reset();
    shapes.clear();
  }

  btCollisionShape* keep(btCollisionShape* shape) {
    shapes.emplace_back(shape);
    return shape;
  }

  // Clone of `src` with every length multiplied by s; local scaling of the original is baked into the
  // dimensions (kept as local scaling only for multi-spheres, where it makes an ellipsoid).
  btCollisionShape* cloneShape(const btCollisionShape* src) {
    switch (src->getShapeType()) {
      case SPHERE_SHAPE_PROXYTYPE: {
        auto* sp = static_cast<const btSphereShape*>(src);
        return keep(new btSphereShape(sp->getRadius() * s));
      }
      case BOX_SHAPE_PROXYTYPE: {
        auto* b = static_cast<const btBoxShape*>(src);
        return keep(new btBoxShape(b->getHalfExtentsWithMargin() * s));
      }
      case CYLINDER_SHAPE_PROXYTYPE: {
        auto* c = static_cast<const btCylinderShape*>(src);
        btVector3 half = c->getHalfExtentsWithMargin() * s;
        switch (c->getUpAxis()) {
          case 0: return keep(new btCylinderShapeX(half));
          case 2: return keep(new btCylinderShapeZ(half));
          default: return keep(new btCylinderShape(half));
        }
      }
      case CAPSULE_SHAPE_PROXYTYPE: {
        auto* c = static_cast<const btCapsuleShape*>(src);
        btScalar r = c->getRadius() * s, h = 2 * c->getHalfHeight() * s;
        switch (c->getUpAxis()) {
          case 0: return keep(new btCapsuleShapeX(r, h));
          case 2: return keep(new btCapsuleShapeZ(r, h));
          default: return keep(new btCapsuleShape(r, h));
        }
      }
      case CONE_SHAPE_PROXYTYPE: {
        auto* c = static_cast<const btConeShape*>(src);
        btScalar r = c->getRadius() * s, h = c->getHeight() * s;
        switch (c->getConeUpIndex()) {
          case 0: return keep(new btConeShapeX(r, h));
          case 2: return keep(new btConeShapeZ(r, h));
          default: return keep(new btConeShape(r, h));
        }
      }
      case CONVEX_HULL_SHAPE_PROXYTYPE: {
        auto* h = static_cast<const btConvexHullShape*>(src);
        auto* out = new btConvexHullShape();
        keep(out);
        const btVector3 scaling = h->getLocalScaling() * s;
        for (int i = 0; i < h->getNumPoints(); ++i) out->addPoint(h->getUnscaledPoints()[i] * scaling, false);
        out->recalcLocalAabb();
        return out;
      }
      case MULTI_SPHERE_SHAPE_PROXYTYPE: {
        auto* m = static_cast<const btMultiSphereShape*>(src);
        const int n = m->getSphereCount();
        std::vector<btVector3> pos(static_cast<size_t>(n));
        std::vector<btScalar> rad(static_cast<size_t>(n));
        for (int i = 0; i < n; ++i) {
          pos[size_t(i)] = m->getSpherePosition(i) * s;
          rad[size_t(i)] = m->getSphereRadius(i) * s;
        }
        auto* out = new btMultiSphereShape(pos.data(), rad.data(), n);
        keep(out);
        out->setLocalScaling(m->getLocalScaling());
        return out;
      }
      case COMPOUND_SHAPE_PROXYTYPE: {
        auto* c = static_cast<const btCompoundShape*>(src);
        auto* out = new btCompoundShape(true, c->getNumChildShapes());
        keep(out);
        for (int i = 0; i < c->getNumChildShapes(); ++i) {
          btTransform t = c->getChildTransform(i);  // already includes the compound's local scaling
          t.setOrigin(t.getOrigin() * s);
          out->addChildShape(t, cloneShape(c->getChildShape(i)));
        }
        return out;
      }
      case STATIC_PLANE_PROXYTYPE: {
        auto* p = static_cast<const btStaticPlaneShape*>(src);
        return keep(new btStaticPlaneShape(p->getPlaneNormal(), p->getPlaneConstant() * s));
      }
      default:
        throw InputError(std::string("BulletPeer: unsupported collision shape '") + src->getName() + "' (shape type " +
                         std::to_string(src->getShapeType()) + ")");
    }
  }

  void addBody(const btRigidBody& src) {
    if (!src.getCollisionShape()) throw InputError("BulletPeer: body without a collision shape");
    btCollisionShape* shape = cloneShape(src.getCollisionShape());

    const btScalar inv_mass = src.getInvMass();
    const btScalar mass = inv_mass > 0 ? btScalar(1) / inv_mass : btScalar(0);
    btVector3 inertia(0, 0, 0);
    if (mass > 0) {
      const btVector3 inv_i = src.getInvInertiaDiagLocal();
      for (int k = 0; k < 3; ++k) inertia[k] = inv_i[k] > 0 ? s * s / inv_i[k] : btScalar(0);
    }
    btRigidBody::btRigidBodyConstructionInfo info(mass, nullptr, shape, inertia);
    info.m_friction = src.getFriction();
    info.m_rollingFriction = src.getRollingFriction();
    info.m_spinningFriction = src.getSpinningFriction();
    info.m_restitution = src.getRestitution();
    info.m_linearDamping = src.getLinearDamping();
    info.m_angularDamping = src.getAngularDamping();
    info.m_linearSleepingThreshold = src.getLinearSleepingThreshold() * s;
    info.m_angularSleepingThreshold = src.getAngularSleepingThreshold();
    btTransform t = src.getWorldTransform();
    t.setOrigin(t.getOrigin() * s);
    info.m_startWorldTransform = t;

    auto body = std::make_unique<btRigidBody>(info);
    body->setCollisionFlags(src.getCollisionFlags());
    body->setFlags(src.getFlags());
    body->setLinearVelocity(src.getLinearVelocity() * s);
    body->setAngularVelocity(src.getAngularVelocity());
    body->setLinearFactor(src.getLinearFactor());
    body->setAngularFactor(src.getAngularFactor());
    body->setAnisotropicFriction(src.getAnisotropicFriction());
    body->setCcdMotionThreshold(src.getCcdMotionThreshold() * s);
    body->setCcdSweptSphereRadius(src.getCcdSweptSphereRadius() * s);
    body->setDeactivationTime(src.getDeactivationTime());
    body->setContactProcessingThreshold(src.getContactProcessingThreshold());
    if (src.isKinematicObject()) body->setActivationState(DISABLE_DEACTIVATION);

    if (const btBroadphaseProxy* proxy = src.getBroadphaseHandle()) {
      world->addRigidBody(body.get(), proxy->m_collisionFilterGroup, proxy->m_collisionFilterMask);
    } else {
      world->addRigidBody(body.get());
    }
    if (src.getFlags() & BT_DISABLE_WORLD_GRAVITY) body->setGravity(src.getGravity() * s);
    const int state = src.getActivationState();
    if (!src.isStaticObject() && (state == DISABLE_DEACTIVATION || state == DISABLE_SIMULATION))
      body->forceActivationState(state);
    bodies.push_back(std::move(body));
  }
};

BulletPeer::BulletPeer(const std::vector<btRigidBody*>& bodies, const BulletPeerSettings& settings)
    : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  if (!(settings.length_scale > 0) || !(settings.dt > 0) || settings.solver_iterations < 1)
    throw InputError("BulletPeer: length_scale and dt must be positive, solver_iterations >= 1");
  m.settings = settings;
  m.s = btScalar(settings.length_scale);
  m.config = std::make_unique<btDefaultCollisionConfiguration>();
  m.dispatcher = std::make_unique<btCollisionDispatcher>(m.config.get());
  m.broadphase = std::make_unique<btDbvtBroadphase>();
  m.solver = std::make_unique<btSequentialImpulseConstraintSolver>();
  m.world =
      std::make_unique<btDiscreteDynamicsWorld>(m.dispatcher.get(), m.broadphase.get(), m.solver.get(), m.config.get());
  m.world->setGravity(toBt(settings.gravity) * m.s);  // before adding bodies: addRigidBody copies it
  m.world->getSolverInfo().m_numIterations = settings.solver_iterations;
  m.bodies.reserve(bodies.size());
  for (const btRigidBody* b : bodies) {
    if (!b) throw InputError("BulletPeer: null body");
    m.addBody(*b);
  }
}

BulletPeer::~BulletPeer() = default;

void BulletPeer::step() {
  Impl& m = *impl_;
  const btScalar dt = btScalar(m.settings.dt);
  auto t0 = std::chrono::steady_clock::now();
  // Kinematic bodies move with their prescribed velocity (Bullet reads their new pose from the motion
  // state, which the copies do not have, and derives the velocity from the pose change).
  for (auto& b : m.bodies) {
    if (!b->isKinematicObject()) continue;
    btTransform next;
    btTransformUtil::integrateTransform(b->getWorldTransform(), b->getLinearVelocity(), b->getAngularVelocity(), dt,
                                        next);
    b->setWorldTransform(next);
  }
  m.world->stepSimulation(dt, 0);  // exactly one internal step of dt, no interpolation
  auto t1 = std::chrono::steady_clock::now();

  BulletPeerStats st;
  st.wall_seconds = std::chrono::duration<double>(t1 - t0).count();
  btScalar deepest = 0;
  const int nm = m.dispatcher->getNumManifolds();
  for (int i = 0; i < nm; ++i) {
    const btPersistentManifold* man = m.dispatcher->getManifoldByIndexInternal(i);
    for (int k = 0; k < man->getNumContacts(); ++k) {
      const btScalar d = man->getContactPoint(k).getDistance();
      if (d < 0) {
        ++st.contacts;
        deepest = std::max(deepest, -d);
      }
    }
  }
  st.max_penetration = real(deepest) / real(m.s);
  m.stats = st;
}

const BulletPeerStats& BulletPeer::lastStats() const { return impl_->stats; }
size_t BulletPeer::bodyCount() const { return impl_->bodies.size(); }

Vec3 BulletPeer::position(size_t i) const {
  return fromBt(impl_->bodies.at(i)->getWorldTransform().getOrigin()) / real(impl_->s);
}
Quat BulletPeer::rotation(size_t i) const {
  const btQuaternion q = impl_->bodies.at(i)->getWorldTransform().getRotation();
  return Quat{real(q.w()), real(q.x()), real(q.y()), real(q.z())};
}
Vec3 BulletPeer::velocity(size_t i) const { return fromBt(impl_->bodies.at(i)->getLinearVelocity()) / real(impl_->s); }
Vec3 BulletPeer::angularVelocity(size_t i) const { return fromBt(impl_->bodies.at(i)->getAngularVelocity()); }

}  // namespace dvi
