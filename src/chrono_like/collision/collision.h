// Collision backends: AABBs + broad phase + narrow phase, producing the contact arrays of a step.
// Native is our binning broad phase with the analytic/MPR narrow phase (the algorithms the GPU runs);
// Bullet is Bullet's own CPU pipeline (btCollisionDispatcher, GJK/EPA), kept as the reference
// (bullet/bullet_collision_backend.h).
#pragma once

#include <memory>

#include "chrono_like/base/data.h"
#include "chrono_like/base/step_context.h"
#include "chrono_like/collision/broadphase.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/collision/gjk.h"

namespace dvi {

// Which pipeline finds the contacts: the native one (broad phase broadphase.h, narrow phase narrowphase.h) or
// Bullet's (bullet/bullet_collision_backend.h: GJK/EPA, made by a factory the caller hands to the System).
enum class CollisionBackend { Native, Bullet };
// How the friction coefficients of two bodies combine into a contact's mu. Product is Bullet's rule.
enum class FrictionCombine { Product, Min, Average };

// The collision part of the System's configuration (system.h: SystemConfig::collision), read by the collision
// backends and by the System where it fills each contact's mu. The step itself comes with the StepContext.
struct CollisionSettings {
  CollisionBackend backend = CollisionBackend::Native;  // default: native
  // [1, relative] collision envelope as a fraction of the smaller shape's size: contacts are made up to this
  // separation. Default 0.05.
  real envelope_rel = real(0.05);
  // Speculative contacts: the envelopes grow to the step's sweep of each body (narrowphase.h). Default true.
  bool speculative = true;
  // MPR pairs of two flat features (cylinder caps, hull faces, a box face on a cap) get up to 4 more points of
  // their overlap (mpr.h: mprManifold): without them such stacks tip about MPR's one point and sink. Default true.
  bool mpr_manifold = true;
  // Which MPR pairs try GJK on their cores first (gjk.h: GjkUse). Auto: All on the CPU backend, Polytopes on the
  // GPU (docs/GPU_PERFORMANCE.md, narrow phase: GJK on curved cores cost the GPU's mixed pile twice its narrow
  // phase). The GPU and CPU give the same contacts only under the same resolved choice (resolvedGjk).
  GjkUse gjk = GjkUse::Auto;
  // Temporal coherence of MPR: a deep pair (pressed in by more than 2% of the smaller shape) whose first pass ends
  // on the face of its last step's contact (normals within ~2.6 degrees) keeps that point instead of testing the
  // candidate directions again (mpr.h: mprBeginOverlap). Both backends read last step's normals from the warm
  // start's store; without warm start there are none. Default true.
  bool mpr_coherence = true;
  FrictionCombine friction_combine = FrictionCombine::Product;  // default: Product (Bullet's rule)
  BroadPhaseSettings broadphase;  // the native broad phase's grid and its pair reuse (broadphase.h)
};

// The GjkUse a backend runs for `use` (Auto resolved: the GPU's choice where `gpu`, else the CPU's).
inline GjkUse resolvedGjk(GjkUse use, bool gpu) {
  if (use != GjkUse::Auto) return use;
  return gpu ? GjkUse::Polytopes : GjkUse::All;
}

struct CollisionTimes {
  double aabbs = 0, broad = 0, narrow = 0;  // seconds
  int64_t pairs = 0;
  bool pairs_reused = false;    // BroadPhase kept the last build's pairs (BroadPhaseSettings::pair_margin)
  BroadPhaseStats broad_stats;  // of the last build
};

class CollisionDetector {
 public:
  virtual ~CollisionDetector() = default;
  virtual const char* name() const = 0;
  // Reads bodies.{pos, rot, flags}, shapes.shape, shapes.hull_points; writes shapes.aabb and the
  // geometric fields of `out` (shape_a/b, body_a/b, normal, pa, pb, dist, key). The system fills mu and
  // size afterwards. Contacts are ordered by (shape_a, shape_b, feature) whatever the thread count.
  // step.dt is the sweep of the speculative contacts and their rule.
  virtual void detect(const BodyArrays& bodies, ShapeArrays& shapes, const CollisionSettings& config,
                      const StepContext& step, ContactArrays& out, CollisionTimes& times) = 0;
  // The velocities after this step's forces (the System's v_free, w_free; one per body, valid during the next
  // detect): the native backend's sweeps and speculative-contact rule read them (narrowphase.h). Unset (null):
  // bodies.vel and bodies.omega.
  void setFreeVelocities(const Vec3* v, const Vec3* w) {
    v_free_ = v;
    w_free_ = w;
  }
  // Last step's contacts (sorted keys and normals, valid during the next detect) for the narrow phase's temporal
  // coherence (CollisionSettings::mpr_coherence); n = 0: none.
  void setLastNormals(LastNormals last) { last_ = last; }

 protected:
  const Vec3* v_free_ = nullptr;
  const Vec3* w_free_ = nullptr;
  LastNormals last_;
};

std::unique_ptr<CollisionDetector> makeNativeCollision(const BroadPhaseSettings& settings);

// Makes a collision backend that lives outside the core: the System takes one for CollisionBackend::Bullet
// (bullet/bullet_collision_backend.h: makeBulletCollision).
using CollisionFactory = std::unique_ptr<CollisionDetector> (*)();

}  // namespace dvi
