// Bullet's own collision pipeline as a collision backend of the System (collision.h), kept as the reference for
// the native one (bullet_collision_backend.cpp says how it is set up). A caller whose SystemConfig may ask for
// CollisionBackend::Bullet passes makeBulletCollision to the System.
#pragma once

#include <memory>

#include "chrono_like/collision/collision.h"

namespace dvi {

std::unique_ptr<CollisionDetector> makeBulletCollision();

}  // namespace dvi
