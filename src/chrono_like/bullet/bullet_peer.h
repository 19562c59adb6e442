// The Bullet peer: steps a set of Bullet bodies with Bullet's own btDiscreteDynamicsWorld and
// sequential-impulse solver, for side-by-side comparisons (`dvisim run --backend bullet`, benchmarks).
//
// Bullet's tolerances are absolute lengths (0.04 m margin, 0.02 m contact breaking threshold), so scenes
// of centimetre particles are given to it in scaled units: with length_scale = 100 every length is
// multiplied by 100 on the way in (positions, shape dimensions, gravity, velocities) and divided on the
// way out; the peer reports in the scene's units. Masses, angular velocities, friction, restitution and
// damping are copied unchanged, inertia is scaled by length_scale^2, and collision margins are left at
// Bullet's defaults for the scaled shapes (what a user running Bullet in those units gets). Kinematic
// bodies move with their velocity (the copies have no motion state to read a new pose from).
#pragma once

#include <memory>
#include <vector>

#include "chrono_like/base/math.h"

class btRigidBody;

namespace dvi {

struct BulletPeerSettings {
  real dt = real(1e-3);
  int solver_iterations = 10;  // Bullet's default
  real length_scale = 1;       // see above; the bodies passed in are in scene units
  Vec3 gravity{0, real(-9.81), 0};
};

struct BulletPeerStats {
  int64_t contacts = 0;      // manifold points with distance < 0 after the step
  real max_penetration = 0;  // scene units
  double wall_seconds = 0;   // of the last step
};

class BulletPeer {
 public:
  // Copies the bodies (shapes cloned and scaled), so the originals stay untouched.
  BulletPeer(const std::vector<btRigidBody*>& bodies, const BulletPeerSettings& settings);
  ~BulletPeer();
  void step();
  const BulletPeerStats& lastStats() const;
  size_t bodyCount() const;
  // State of body i in scene units.
  Vec3 position(size_t i) const;
  Quat rotation(size_t i) const;
  Vec3 velocity(size_t i) const;
  Vec3 angularVelocity(size_t i) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace dvi
