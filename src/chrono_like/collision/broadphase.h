// Broad phase by uniform spatial binning (Mazhar, Heyn, Negrut, "A scalable parallel method for large
// collision detection problems", Multibody System Dynamics 26, 2011):
//   count AABB-bin overlaps -> exclusive scan -> write (bin, shape) pairs -> sort by bin -> bin runs ->
//   test the shapes inside each bin, keeping a pair only in the bin that holds the minimum corner of the two
//   boxes' intersection (so no pair is reported twice).
// CPU variant of the last step: each binned shape walks its own bins from its place in the bin's run and
// tests the shapes after it (the same pairs as a per-bin double loop), so each shape's pairs come out
// together and the output needs no global sort: chunks of shapes are concatenated in order.
// Large shapes (ground, walls, drum: AABB much larger than a bin, and every plane) are not binned: they
// are tested against every binned shape's AABB directly, so one huge box does not flood the bins.
#pragma once

#include <cstdint>
#include <vector>

#include "chrono_like/base/data.h"
#include "chrono_like/base/hd.h"
#include "chrono_like/collision/broadphase_kernels.h"

namespace dvi {

struct ShapePair {
  int32_t a, b;  // shape indices, a < b
};

// Bin edge (documented rule): the median m of the largest AABB side over all bounded shapes (planes and
// unbounded boxes excluded) locates the typical particle; the mean of the sides <= large_factor * m (so the
// drum, walls and bins do not inflate it) is the "mean extent", and edge = bin_size_factor * mean extent.
// Large shapes: planes, unbounded or non-finite boxes, and bounded boxes whose largest side exceeds
// large_factor * edge. They are tested directly against every binned shape, which costs
// (large shapes) x (binned shapes) box tests; so when more than max_large bounded shapes exceed that
// threshold the edge grows until at most max_large of them do (a bimodal mix of many big and many small
// particles is then binned with a coarser grid instead of flooding the direct path).
// The grid spans the binned shapes' bounds; when it would exceed max_bins bins, the edge grows until it
// does not.
struct BroadPhaseSettings {
  real bin_size_factor = real(2);  // bin edge = factor x mean AABB extent of the binned shapes
  real large_factor = real(8);     // a shape larger than large_factor bin edges is treated apart
  int64_t max_bins = int64_t(1) << 24;
  int32_t max_large = 64;  // most bounded (non-plane) shapes treated apart
  // Pairs kept between steps (broadphase_kernels.h: fatAabb, pairsStillHold): each build grows every box by
  // pair_margin x the last build's bin edge (0 on the first build), and the next steps keep its pairs while
  // every shape's box stays inside its grown box and no body's flags change; the contacts are the same as
  // with a build every step. 0 builds every step. The default, 2.5% of the edge (about 5% of the mean
  // extent: 1 mm for spheres of 1 cm radius), adds the pairs of neighbours within two margins of touching.
  real pair_margin = real(0.025);
};

struct BroadPhaseStats {
  int64_t bins = 0;         // bins of the grid
  int64_t bin_entries = 0;  // (bin, shape) pairs written
  int32_t large_shapes = 0;
  int64_t pairs = 0;
  real bin_edge = 0;
  int64_t occupied_bins = 0;   // bins holding at least one entry
  int64_t bin_pair_tests = 0;  // shape pairs tested inside bins (the dominant cost)
  int32_t grid[3] = {0, 0, 0};
};

// pairAllowed(shape_a, shape_b, flags_a, flags_b) and aabbOverlap(a, b), like every per-element step of
// the binned broad phase, live in broadphase_kernels.h (DVI_HD, shared with the GPU kernels).

// CPU (OpenMP) implementation. Output pairs are sorted by (a, b), whatever the thread count.
class BroadPhaseBins {
 public:
  explicit BroadPhaseBins(BroadPhaseSettings s = {}) : settings_(s) {}
  // Reads shapes.shape, shapes.aabb, bodies.flags; writes out_pairs.
  void run(const ShapeArrays& shapes, const BodyArrays& bodies, std::vector<ShapePair>& out_pairs,
           BroadPhaseStats* stats = nullptr);
  // The same on other boxes than shapes.aabb (one per shape: the grown boxes of pair reuse).
  void run(const ShapeArrays& shapes, const Aabb* boxes, const BodyArrays& bodies, std::vector<ShapePair>& out_pairs,
           BroadPhaseStats* stats = nullptr);

 private:
  // One run's inputs, handed to its passes (broadphase.cpp numbers them 1-8).
  struct Pass {
    const Shape* sh;
    const Aabb* box;
    const uint8_t* flags;
    int32_t n;
    int nthreads;
  };
  real classify(const Pass& in);                                                         // 1: extents and the bin edge
  void splitBinnedLarge(const Pass& in, real edge);                                      // 1: binned_ and large_
  BinGrid makeGrid(const Pass& in, real& edge, Aabb& bounds, BroadPhaseStats& st);       // 2
  int32_t writeEntries(const Pass& in, const BinGrid& grid, BroadPhaseStats& st);        // 3-5
  void sortEntriesByBin(uint32_t max_key);                                               // 4
  void nextMovableEntries(int32_t ne);                                                   // 5b
  int32_t testBinnedPairs(const Pass& in, int32_t ne, BroadPhaseStats& st);              // 6
  void pairLargeShapes(const Pass& in);                                                  // 7
  void writeOutput(const Pass& in, int32_t nchunks, std::vector<ShapePair>& out_pairs);  // 8
  void writeLargeBinnedPairs(const Pass& in, int32_t nchunks, ShapePair* out);
  void mergeLargeLargePairs(ShapePair* out);

  BroadPhaseSettings settings_;
  // scratch reused between steps (no allocation in the step loop once warm, except growth)
  std::vector<real> extent_, extent_sel_;
  std::vector<double> block_sum_;
  std::vector<int64_t> block_cnt_, hist_, lh_count_, lh_cursor_, lh_total_, ll_count_, chunk_off_, large_off_;
  std::vector<int32_t> binned_, large_, large_active_, counts_, offsets_, entry_shape_, entry_perm_, entry_perm_tmp_,
      entry_pos_, sorted_shape_, chunk_begin_, next_movable_;
  std::vector<uint8_t> entry_mask_, sorted_mask_;
  std::vector<uint32_t> entry_bin_, entry_bin_tmp_;
  std::vector<std::vector<ShapePair>> chunk_pairs_;  // pairs (s, b) found from the binned shapes of a chunk
  std::vector<std::vector<int32_t>> cand_;           // per-thread candidates of one bin
  std::vector<std::vector<int64_t>> lhc_local_;      // per-thread (large, binned) counts of one chunk
  std::vector<ShapePair> large_large_;               // pairs of two large shapes, sorted
};

// O(n^2) reference used by tests as the oracle.
void broadPhaseBruteForce(const ShapeArrays& shapes, const BodyArrays& bodies, std::vector<ShapePair>& out_pairs);

}  // namespace dvi
