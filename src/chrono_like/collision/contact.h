// One contact point as the narrow phase reports it.
#pragma once

#include <cstdint>

#include "chrono_like/base/math.h"

namespace dvi {

struct ContactPoint {  // 80 bytes in double
  Vec3 normal;         // unit, pointing from shape A to shape B
  Vec3 pa;             // world point on the surface of A
  Vec3 pb;             // world point on the surface of B
  real dist;           // signed distance along normal: dot(pb - pa, normal); negative = penetration
  int32_t feature;     // index of the point within its pair's manifold (0..kMaxContactsPerPair-1), part of the
                       // persistent key that warm starts the solver
  int32_t pad_;
};

// Persistent key of a contact: the shape pair and the point's feature index. Shape indices are stable
// between steps while no body is added or removed, so the key finds last step's impulse.
DVI_HD uint64_t contactKey(int32_t shape_a, int32_t shape_b, int32_t feature) {
  return (uint64_t(uint32_t(shape_a)) << 36) | (uint64_t(uint32_t(shape_b) & 0xFFFFFFFu) << 8) |
         uint64_t(feature & 0xFF);
}

}  // namespace dvi
