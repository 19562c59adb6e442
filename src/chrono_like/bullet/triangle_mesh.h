// Static triangle geometry from Bullet: btBvhTriangleMeshShape, btScaledBvhTriangleMeshShape,
// btTriangleMeshShape and btHeightfieldTerrainShape (any btConcaveShape that enumerates its triangles)
// become one Triangle shape record per triangle (collide_triangle.h) on the same fixed body.
#pragma once

#include <vector>

#include "chrono_like/system.h"

class btCollisionShape;

namespace dvi {

// A Triangle record for the triangle (a, b, c) given in the body frame; `local` is the pose of the
// shape that holds the triangle in the body frame. Degenerate triangles (area ~ 0) return false.
bool makeTriangle(Vec3 a, Vec3 b, Vec3 c, const Pose& local, ShapeDesc& out);

// Quaternion of the rotation whose columns are the orthonormal right-handed axes x, y, z.
Quat quatFromBasis(Vec3 x, Vec3 y, Vec3 z);

// Converts a Bullet collision shape like appendShapesFromBullet (bullet_import.h), and in addition the
// concave (triangle) shapes listed above, also as children of compounds. Throws InputError naming the
// shape for anything else.
void appendShapesWithTriangles(const btCollisionShape& shape, const Pose& local, std::vector<ShapeDesc>& out);

// True when the shape is, or a compound holds, a triangle shape (such a body must be static or kinematic).
bool hasTriangles(const btCollisionShape& shape);

}  // namespace dvi
