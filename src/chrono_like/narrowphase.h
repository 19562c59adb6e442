// Narrow phase: contact points between two convex shapes, written once for host and device.
//
// Pairs with a closed form (sphere, plane, box, capsule, cylinder cases) use it; every other pair of
// convex support functions uses Minkowski Portal Refinement (Snethen, "XenoCollide: Complex Collision
// Made Simple", Game Programming Gems 7, 2008). Points are reported while the shapes are closer than
// the collision envelope, so contacts exist before they touch and the solver sees them one step early.
#pragma once

#include "contact.h"
#include "math.h"
#include "shape.h"

namespace dvi {

// World pose of a shape attached to a body at pose `body`.
DVI_HD Pose shapeWorldPose(const Pose& body, const Shape& s) { return compose(body, s.local); }

// Support point of shape s (in its own frame) in local direction d, margin excluded.
DVI_HD Vec3 supportLocal(const Shape& s, Vec3 d, const Vec3* hull_points);

// World AABB of the shape at world pose `world`, grown by `envelope` on every side. Planes return an
// unbounded box (callers treat them as large bodies).
DVI_HD Aabb shapeAabb(const Shape& s, const Pose& world, const Vec3* hull_points, real envelope);

// Collides shape a at world pose wa with shape b at wb. Writes up to kMaxContactsPerPair points with
// signed distance < envelope into out[], normals pointing from a to b, and returns how many.
DVI_HD int collideShapes(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb,
                         const Vec3* hull_points, real envelope, ContactPoint* out);

}  // namespace dvi

#include "narrowphase_impl.h"
