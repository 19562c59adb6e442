// The data manager: flat arrays, one per quantity (structure of arrays, as Chrono::Multicore's
// ChDataManager), so every stage streams only the quantities it needs and the same layout maps onto
// device memory. Index i of every BodyArrays vector is body i; index k of every ContactArrays vector is
// contact k.
#pragma once

#include <cstdint>
#include <vector>

#include "chrono_like/base/math.h"
#include "chrono_like/base/shape.h"

namespace dvi {

enum BodyFlags : uint8_t {
  kBodyFixed = 1,      // infinite mass, never moves (static ground, walls)
  kBodyKinematic = 2,  // infinite mass, moves with its prescribed velocity
};

struct BodyArrays {
  std::vector<Vec3> pos;                // centre of mass, world
  std::vector<Quat> rot;                // body frame (principal axes) to world
  std::vector<Vec3> vel;                // linear velocity, world
  std::vector<Vec3> omega;              // angular velocity, world
  std::vector<real> inv_mass;           // 0 for fixed and kinematic bodies
  std::vector<Vec3> inv_inertia;        // principal inverse inertia, body frame (0 for fixed/kinematic)
  std::vector<Vec3> force;              // external force accumulated for this step, world
  std::vector<Vec3> torque;             // external torque accumulated for this step, world
  std::vector<Vec3> gravity;            // per-body gravitational acceleration (Bullet allows per-body gravity)
  std::vector<real> friction;           // Coulomb coefficient of the body's surface
  std::vector<real> restitution;        // Newton's coefficient of the body's surface; a contact's is e_a e_b
  std::vector<real> rolling_friction;   // [m] rolling resistance length of the surface (cone.h: projectRollingCone)
  std::vector<real> spinning_friction;  // [m] spinning (drilling) resistance length of the surface
  std::vector<uint8_t> flags;           // BodyFlags
  std::vector<int32_t> shape_start;     // first shape of the body in ShapeArrays
  std::vector<int32_t> shape_count;     // number of shapes of the body
  std::vector<real> size;               // characteristic length of the body (smallest shape size)

  size_t count() const { return pos.size(); }
  void resize(size_t n);
};

struct ShapeArrays {
  std::vector<Shape> shape;       // sorted by body
  std::vector<Vec3> hull_points;  // vertices of all convex hulls, referenced by Shape::hull_start/count
  std::vector<Aabb> aabb;         // world AABB of each shape, enlarged by shapeMargin (narrowphase.h)
  std::vector<real> sweep;        // this step's shapeSweep (speculative contacts; 0 when they are off)

  size_t count() const { return shape.size(); }
};

struct ContactArrays {
  std::vector<int32_t> shape_a, shape_b;
  std::vector<int32_t> body_a, body_b;
  std::vector<Vec3> normal;   // unit, from A to B
  std::vector<Vec3> pa, pb;   // world contact points on A and on B
  std::vector<real> dist;     // signed distance (negative = penetration)
  std::vector<real> mu;       // combined friction coefficient
  std::vector<real> size;     // characteristic length of the pair (min of the two shapes' sizes)
  std::vector<uint64_t> key;  // persistent key (contactKey) for warm starting

  size_t count() const { return normal.size(); }
  // Keeps the contacts k with keep(k) true, in order (the narrow phase's fields: shapes, bodies, normal, points,
  // distance, key); returns how many are left.
  template <class Keep>
  size_t keepIf(Keep keep) {
    const size_t n = count();
    size_t m = 0;
    for (size_t k = 0; k < n; ++k) {
      if (!keep(k)) continue;
      if (m != k) moveContact(k, m);
      ++m;
    }
    if (m != n) resize(m);
    return m;
  }
  void moveContact(size_t from, size_t to);
  void clear();
  void resize(size_t n);
};

}  // namespace dvi
