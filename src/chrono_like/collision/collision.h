// Collision backends: AABBs + broad phase + narrow phase, producing the contact arrays of a step.
// Native is our binning broad phase with the analytic/MPR narrow phase (the algorithms the GPU runs);
// Bullet is Bullet's own CPU pipeline (btCollisionDispatcher, GJK/EPA), kept as the reference
// (bullet/bullet_collision_backend.h).
#pragma once

#include <memory>

#include "chrono_like/base/data.h"
#include "chrono_like/collision/broadphase.h"

namespace dvi {

// What a collision backend reads of the System's configuration (system.h: collisionSettings(SystemConfig)), so
// that the backends do not depend on the System.
struct CollisionSettings {
  real dt = 0;                // the step (the sweep of speculative contacts and their rule)
  real envelope_rel = 0;      // SystemConfig::envelope_rel
  bool speculative = false;   // SystemConfig::speculative
  bool mpr_manifold = false;  // SystemConfig::mpr_manifold
  real pair_margin = 0;       // BroadPhaseSettings::pair_margin
};

struct CollisionTimes {
  double aabbs = 0, broad = 0, narrow = 0;  // seconds
  int64_t pairs = 0;
  bool pairs_reused = false;  // BroadPhase kept the last build's pairs (BroadPhaseSettings::pair_margin)
  BroadPhaseStats broad_stats;  // of the last build
};

class CollisionDetector {
 public:
  virtual ~CollisionDetector() = default;
  virtual const char* name() const = 0;
  // Reads bodies.{pos, rot, flags}, shapes.shape, shapes.hull_points; writes shapes.aabb and the
  // geometric fields of `out` (shape_a/b, body_a/b, normal, pa, pb, dist, key). The system fills mu and
  // size afterwards. Contacts are ordered by (shape_a, shape_b, feature) whatever the thread count.
  virtual void detect(const BodyArrays& bodies, ShapeArrays& shapes, const CollisionSettings& config,
                      ContactArrays& out, CollisionTimes& times) = 0;
  // The velocities after this step's forces (the System's v_free, w_free; one per body, valid during the next
  // detect): the native backend's sweeps and speculative-contact rule read them (narrowphase.h). Unset (null):
  // bodies.vel and bodies.omega.
  void setFreeVelocities(const Vec3* v, const Vec3* w) {
    v_free_ = v;
    w_free_ = w;
  }

 protected:
  const Vec3* v_free_ = nullptr;
  const Vec3* w_free_ = nullptr;
};

std::unique_ptr<CollisionDetector> makeNativeCollision(const BroadPhaseSettings& settings);

// Makes a collision backend that lives outside the core: the System takes one for CollisionBackend::Bullet
// (bullet/bullet_collision_backend.h: makeBulletCollision).
using CollisionFactory = std::unique_ptr<CollisionDetector> (*)();

}  // namespace dvi
