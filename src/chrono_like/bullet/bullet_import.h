// The Bullet bridge: btRigidBody + btCollisionShape -> System bodies, and results written back.
// Supported shapes: sphere, box, cylinder X/Y/Z, capsule X/Y/Z, cone X/Y/Z, convex hull, multi-sphere
// (a single non-uniformly scaled sphere becomes an ellipsoid), compound of convex children, static
// plane, and the convex wrappers and point sets of Bullet's examples: btConvex2dShape (its child), btBox2dShape,
// btUniformScalingShape (its child scaled), btConvexPointCloudShape, btConvexTriangleMeshShape and btTriangleShape
// (hulls). Anything else is
// refused with an InputError naming the shape type.
#pragma once

#include <vector>

#include "chrono_like/system.h"

class btRigidBody;
class btCollisionShape;

namespace dvi {

// A BodyDesc with a Bullet body's pose of the centre of mass, velocities, friction and restitution only (no mass,
// flags or shapes).
BodyDesc bodyMotionFromBullet(const btRigidBody& body);

// Converts a Bullet body into a BodyDesc: pose of the centre of mass, velocities, mass and principal
// inertia from the body (Bullet's own values), friction and restitution from the body, flags (static / kinematic),
// collision group and mask from its broadphase proxy when it has one.
BodyDesc bodyDescFromBullet(const btRigidBody& body);

// Converts a collision shape (recursively for compounds) into shape records at `local` in the body frame.
void appendShapesFromBullet(const btCollisionShape& shape, const Pose& local, std::vector<ShapeDesc>& out);

// The BodyDesc importBullet adds for body `index` of a scene whose System has this gravity: bodyDescFromBullet, with
// the body's own gravity kept where it differs from the System's. A null body or an unsupported shape: InputError.
BodyDesc bodyDescForSystem(const btRigidBody* body, size_t index, Vec3 gravity);
// Adds every body to the system in order; returns the system index of each.
std::vector<int> importBullet(System& system, const std::vector<btRigidBody*>& bodies);

// Writes transform (through the motion state when present) and velocities back to Bullet.
void writeBackToBullet(const System& system, const std::vector<int>& indices, const std::vector<btRigidBody*>& bodies);

}  // namespace dvi
