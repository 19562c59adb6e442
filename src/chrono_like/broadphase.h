// Broad phase by uniform spatial binning (Mazhar, Heyn, Negrut, "A scalable parallel method for large
// collision detection problems", Multibody System Dynamics 26, 2011):
//   count AABB-bin overlaps -> exclusive scan -> write (bin, shape) pairs -> sort by bin -> encode bin
//   starts -> test the shapes inside each bin, keeping a pair only in the bin that holds the minimum
//   corner of the two boxes' intersection (so no pair is reported twice).
// Large shapes (ground, walls, drum: AABB much larger than a bin, and every plane) are not binned: they
// are tested against every binned shape's AABB directly, so one huge box does not flood the bins.
#pragma once

#include <cstdint>
#include <vector>

#include "data.h"
#include "hd.h"

namespace dvi {

struct ShapePair {
  int32_t a, b;  // shape indices, a < b
};

struct BroadPhaseSettings {
  real bin_size_factor = real(2);  // bin edge = factor x mean AABB extent of the binned shapes
  real large_factor = real(8);     // a shape larger than large_factor bin edges is treated apart
  int64_t max_bins = int64_t(1) << 24;
};

struct BroadPhaseStats {
  int64_t bins = 0;         // bins of the grid
  int64_t bin_entries = 0;  // (bin, shape) pairs written
  int32_t large_shapes = 0;
  int64_t pairs = 0;
  real bin_edge = 0;
};

// True when the two shapes may collide at all: different bodies, not both immovable, groups match.
DVI_HD bool pairAllowed(const Shape& a, const Shape& b, uint8_t flags_a, uint8_t flags_b) {
  const uint8_t immovable = kBodyFixed | kBodyKinematic;
  return a.body != b.body && !((flags_a & immovable) && (flags_b & immovable)) && groupsCollide(a, b);
}

DVI_HD bool aabbOverlap(const Aabb& a, const Aabb& b) {
  return a.lo.x <= b.hi.x && b.lo.x <= a.hi.x && a.lo.y <= b.hi.y && b.lo.y <= a.hi.y && a.lo.z <= b.hi.z &&
         b.lo.z <= a.hi.z;
}

// CPU (OpenMP) implementation. Output pairs are sorted by (a, b), whatever the thread count.
class BroadPhaseBins {
 public:
  explicit BroadPhaseBins(BroadPhaseSettings s = {}) : settings_(s) {}
  // Reads shapes.shape, shapes.aabb, bodies.flags; writes out_pairs.
  void run(const ShapeArrays& shapes, const BodyArrays& bodies, std::vector<ShapePair>& out_pairs,
           BroadPhaseStats* stats = nullptr);

 private:
  BroadPhaseSettings settings_;
  // scratch reused between steps (no allocation in the step loop once warm)
  std::vector<int32_t> binned_, large_, counts_, offsets_, entry_bin_, entry_shape_, bin_start_;
  std::vector<std::vector<ShapePair>> per_thread_;
};

// O(n^2) reference used by tests as the oracle.
void broadPhaseBruteForce(const ShapeArrays& shapes, const BodyArrays& bodies, std::vector<ShapePair>& out_pairs);

}  // namespace dvi
