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
  int32_t feature;     // which point of its pair's manifold (0..kMaxFeature-1, distinct and increasing within the
                       // pair; collide_box.h numbers box-box points by the features that made them), part of the
                       // persistent key that warm starts the solver
  int32_t pad_;
};

// Features fit the key's 8 bits.
constexpr int32_t kMaxFeature = 256;

// Persistent key of a contact: the shape pair and the point's feature index. Shape indices are stable
// between steps while no body is added or removed, so the key finds last step's impulse.
DVI_HD uint64_t contactKey(int32_t shape_a, int32_t shape_b, int32_t feature) {
  return (uint64_t(uint32_t(shape_a)) << 36) | (uint64_t(uint32_t(shape_b) & 0xFFFFFFFu) << 8) |
         uint64_t(feature & 0xFF);
}

// ---- last step's normal of a pair (temporal coherence of the narrow phase) ----

// Last step's contacts as the narrow phase may consult them: their keys, sorted, and their normals (from shape_a to
// shape_b), n entries; empty (n = 0) where there was no last step or the shapes changed since. Both backends keep
// these beside the warm start's impulses (System::cacheImpulsesByKey, the GPU's keepImpulsesForWarmStart).
struct LastNormals {
  const uint64_t* key = nullptr;
  const Vec3* normal = nullptr;
  int64_t n = 0;
};

// One pair's view of LastNormals: the pair's shapes in the order of its contacts' keys, and the sign that turns
// their normal into the order the narrow phase collides the pair in (-1 where collideShapes swapped them).
struct PairHistory {
  LastNormals last;
  int32_t a = 0, b = 0;
  real sign = 1;
};

// Last step's normal of the pair (its first point's: all points of an MPR pair share it), in the collided order.
// False when the pair had no contact. A binary search over the sorted keys (the pair's keys share their high bits).
DVI_HD bool lastPairNormal(const PairHistory& h, Vec3& n) {
  if (h.last.n <= 0) return false;
  const uint64_t first = contactKey(h.a, h.b, 0);
  int64_t lo = 0, hi = h.last.n;
  while (lo < hi) {
    const int64_t mid = lo + (hi - lo) / 2;
    if (h.last.key[mid] < first)
      lo = mid + 1;
    else
      hi = mid;
  }
  if (lo >= h.last.n || (h.last.key[lo] >> 8) != (first >> 8)) return false;
  n = h.last.normal[lo] * h.sign;
  return true;
}

// ---- contacts a scene excludes (System::setContactExclusions; Bullet's disableCollisionsBetweenLinkedBodies and
// CF_NO_CONTACT_RESPONSE) ----

// Key of an unordered body pair: (min << 32) | max.
DVI_HD uint64_t bodyPairKey(int32_t a, int32_t b) {
  const uint32_t lo = uint32_t(a < b ? a : b), hi = uint32_t(a < b ? b : a);
  return (uint64_t(lo) << 32) | uint64_t(hi);
}

// Whether a contact between bodies a and b is left out: either body is flagged in no_contact (n_flags entries, null:
// none), or the pair's key is in the sorted keys[0 .. n_keys) (binary search). One function for the CPU's compaction
// and the GPU's narrow phase.
DVI_HD bool contactExcluded(int32_t a, int32_t b, const uint64_t* keys, int64_t n_keys, const uint8_t* no_contact,
                            int64_t n_flags) {
  if (no_contact && ((a < n_flags && no_contact[a]) || (b < n_flags && no_contact[b]))) return true;
  const uint64_t key = bodyPairKey(a, b);
  int64_t lo = 0, hi = n_keys;
  while (lo < hi) {
    const int64_t mid = lo + (hi - lo) / 2;
    if (keys[mid] < key)
      lo = mid + 1;
    else
      hi = mid;
  }
  return lo < n_keys && keys[lo] == key;
}

}  // namespace dvi
