// Per-element operations of the binned broad phase (Mazhar, Heyn, Negrut 2011), written once as DVI_HD
// inline functions over plain values and arrays. BroadPhaseBins (broadphase.cpp) calls them from OpenMP
// loops; the GPU broad phase calls the same functions from CUDA kernels (one thread per shape for the
// count and write passes, one thread per bin for the pair test), so both backends bin, own and filter
// pairs identically.
#pragma once

#include <cstdint>

#include "chrono_like/base/data.h"
#include "chrono_like/base/hd.h"
#include "chrono_like/base/math.h"
#include "chrono_like/base/shape.h"

namespace dvi {

// True when the two shapes may collide at all: different bodies, not both immovable, groups match.
DVI_HD bool pairAllowed(const Shape& a, const Shape& b, uint8_t flags_a, uint8_t flags_b) {
  const uint8_t immovable = kBodyFixed | kBodyKinematic;
  return a.body != b.body && !((flags_a & immovable) && (flags_b & immovable)) && groupsCollide(a, b);
}

// Closed-interval overlap: boxes that only touch overlap. Any NaN coordinate makes it false.
DVI_HD bool aabbOverlap(const Aabb& a, const Aabb& b) {
  return a.lo.x <= b.hi.x && b.lo.x <= a.hi.x && a.lo.y <= b.hi.y && b.lo.y <= a.hi.y && a.lo.z <= b.hi.z &&
         b.lo.z <= a.hi.z;
}

// ---- pairs kept between steps (fat boxes) ----
// A broad phase run on boxes grown by a margin m finds every pair whose grown boxes overlap. While each
// shape's box stays inside its grown box and no body's flags change, that list stays a superset of the pairs
// a fresh broad phase would find (two boxes that overlap lie inside grown boxes that overlap; pairAllowed
// reads only the flags and the immutable shapes). The narrow phase keeps only contacts within each pair's
// envelope, and the pairs stay sorted by (a, b), so the contacts and their order are those of a fresh broad
// phase: only its cost is saved. This is the fat-AABB rule of Box2D's dynamic tree (b2_aabbMargin, Catto,
// box2d.org) and Bullet's btDbvtBroadphase, applied to the binned grid.
DVI_HD Aabb fatAabb(const Aabb& b, real m) {  // unbounded (+-1e30) and NaN coordinates stay as they are
  return Aabb{{b.lo.x - m, b.lo.y - m, b.lo.z - m}, {b.hi.x + m, b.hi.y + m, b.hi.z + m}};
}

// in inside out (closed); false when either holds a NaN.
DVI_HD bool aabbInside(const Aabb& in, const Aabb& out) {
  return in.lo.x >= out.lo.x && in.lo.y >= out.lo.y && in.lo.z >= out.lo.z && in.hi.x <= out.hi.x &&
         in.hi.y <= out.hi.y && in.hi.z <= out.hi.z;
}

// Shape i still fits the pairs of the last build: box inside the grown box of the build, body flags unchanged.
DVI_HD bool pairsStillHold(const Aabb& box, const Aabb& fat, uint8_t flags, uint8_t fat_flags) {
  return flags == fat_flags && aabbInside(box, fat);
}

// An AABB coordinate at or beyond this magnitude marks an unbounded shape (planes carry +-1e30).
constexpr real kBroadPhaseHuge = real(1e29);

// Uniform grid of cubic bins: bin (i, j, k) covers origin + edge * [i, i+1) x [j, j+1) x [k, k+1).
// Coordinates outside the grid are clamped to the border bins, so every point maps to exactly one bin.
// Bin index = i + n[0] * (j + n[1] * k); the grid never has more than 2^31 - 1 bins.
struct BinGrid {
  Vec3 origin;
  real inv_edge;  // 1 / bin edge
  int32_t n[3];   // bins per axis, each >= 1
};

DVI_HD int32_t binCoord(real x, real origin, real inv_edge, int32_t n) {
  const real t = (x - origin) * inv_edge;  // monotone in x, so the bin coordinate is monotone too
  if (!(t >= real(0))) return 0;           // below the grid (or NaN)
  if (t >= real(n)) return n - 1;          // above the grid
  const int32_t c = int32_t(t);            // t >= 0: truncation = floor
  return c < n ? c : n - 1;
}

DVI_HD void binCell(const BinGrid& g, Vec3 p, int32_t c[3]) {
  c[0] = binCoord(p.x, g.origin.x, g.inv_edge, g.n[0]);
  c[1] = binCoord(p.y, g.origin.y, g.inv_edge, g.n[1]);
  c[2] = binCoord(p.z, g.origin.z, g.inv_edge, g.n[2]);
}

DVI_HD uint32_t binIndex(const BinGrid& g, int32_t i, int32_t j, int32_t k) {
  return uint32_t(i) + uint32_t(g.n[0]) * (uint32_t(j) + uint32_t(g.n[1]) * uint32_t(k));
}

// Inclusive bin ranges [lo[d], hi[d]] overlapped by the box.
DVI_HD void aabbBinRange(const BinGrid& g, const Aabb& box, int32_t lo[3], int32_t hi[3]) {
  binCell(g, box.lo, lo);
  binCell(g, box.hi, hi);
}

// Number of bins the box overlaps (count pass).
DVI_HD int32_t aabbBinCount(const BinGrid& g, const Aabb& box) {
  int32_t lo[3], hi[3];
  aabbBinRange(g, box, lo, hi);
  return (hi[0] - lo[0] + 1) * (hi[1] - lo[1] + 1) * (hi[2] - lo[2] + 1);
}

// Write pass: the (bin, shape) entries of one shape at out_bin/out_shape[0 .. aabbBinCount), bins in
// increasing index order, and for each entry the box's "start mask" in that bin: bit d set when the bin is
// the first one the box overlaps along axis d (see binOwnsPairByMask). out_mask may be null.
// Returns the number written.
DVI_HD int32_t aabbWriteBins(const BinGrid& g, const Aabb& box, int32_t shape, uint32_t* out_bin, int32_t* out_shape,
                             uint8_t* out_mask) {
  int32_t lo[3], hi[3];
  aabbBinRange(g, box, lo, hi);
  int32_t w = 0;
  for (int32_t k = lo[2]; k <= hi[2]; ++k)
    for (int32_t j = lo[1]; j <= hi[1]; ++j)
      for (int32_t i = lo[0]; i <= hi[0]; ++i) {
        out_bin[w] = binIndex(g, i, j, k);
        out_shape[w] = shape;
        if (out_mask) out_mask[w] = uint8_t((i == lo[0]) | ((j == lo[1]) << 1) | ((k == lo[2]) << 2));
        ++w;
      }
  return w;
}

// The bin that owns an overlapping pair: the one holding the minimum corner of the boxes' intersection.
// That corner lies in both boxes, hence (binCoord being monotone) in a bin both boxes were written to, and
// in exactly one bin: testing the pair in every shared bin and keeping it only in the owner reports it once.
DVI_HD uint32_t pairOwnerBin(const BinGrid& g, const Aabb& a, const Aabb& b) {
  const Vec3 m{a.lo.x > b.lo.x ? a.lo.x : b.lo.x, a.lo.y > b.lo.y ? a.lo.y : b.lo.y, a.lo.z > b.lo.z ? a.lo.z : b.lo.z};
  int32_t c[3];
  binCell(g, m, c);
  return binIndex(g, c[0], c[1], c[2]);
}

// The same rule on the start masks of the two boxes in a bin X they share: the owner's cell is
// max(cell(lo_a), cell(lo_b)) per axis (binCoord is monotone), and as both boxes overlap X,
// max(lo_a[d], lo_b[d]) == X[d] exactly when one of them starts in X along d. So X owns the pair iff
// every axis has a box starting in X. Equal to pairOwnerBin(g, a, b) == X, bit for bit.
// Bits above the three axis bits (the CPU's kMaskImmovable) are ignored.
DVI_HD bool binOwnsPairByMask(uint8_t mask_a, uint8_t mask_b) { return ((mask_a | mask_b) & 7) == 7; }

// Entry-mask bit of the CPU broad phase: the entry's shape belongs to an immovable (fixed or kinematic) body, so it
// pairs with no other immovable shape (pairAllowed) and is tested against the bin's movable shapes only.
constexpr uint8_t kMaskImmovable = 8;

// Cell coordinates of a bin index.
DVI_HD void binCellOfIndex(const BinGrid& g, uint32_t bin, int32_t c[3]) {
  c[0] = int32_t(bin % uint32_t(g.n[0]));
  const uint32_t r = bin / uint32_t(g.n[0]);
  c[1] = int32_t(r % uint32_t(g.n[1]));
  c[2] = int32_t(r / uint32_t(g.n[1]));
}

// Branch-free overlap (no short-circuit: both SIMD lanes and GPU warps evaluate it without divergence).
DVI_HD bool aabbOverlapBranchFree(const Aabb& a, const Aabb& b) {
  return (a.lo.x <= b.hi.x) & (b.lo.x <= a.hi.x) & (a.lo.y <= b.hi.y) & (b.lo.y <= a.hi.y) & (a.lo.z <= b.hi.z) &
         (b.lo.z <= a.hi.z);
}

// First stage of the in-bin test, branch free: the boxes overlap and this bin owns the pair.
DVI_HD bool binCandidate(const Aabb& a, const Aabb& b, uint8_t mask_a, uint8_t mask_b) {
  return aabbOverlapBranchFree(a, b) & binOwnsPairByMask(mask_a, mask_b);
}

// Pair test inside bin `bin` for shapes a and b (both written to that bin): the boxes overlap, the bin owns
// the pair, and the pair may collide at all.
DVI_HD bool binPairTest(const BinGrid& g, uint32_t bin, int32_t a, int32_t b, const Shape* shapes, const Aabb* aabbs,
                        const uint8_t* body_flags) {
  const Aabb& A = aabbs[a];
  const Aabb& B = aabbs[b];
  if (!aabbOverlap(A, B)) return false;
  if (pairOwnerBin(g, A, B) != bin) return false;
  const Shape& sa = shapes[a];
  const Shape& sb = shapes[b];
  return pairAllowed(sa, sb, body_flags[sa.body], body_flags[sb.body]);
}

// Second stage: the pair may collide at all.
DVI_HD bool shapePairAllowed(int32_t a, int32_t b, const Shape* shapes, const uint8_t* body_flags) {
  const Shape& sa = shapes[a];
  const Shape& sb = shapes[b];
  return pairAllowed(sa, sb, body_flags[sa.body], body_flags[sb.body]);
}

// Direct pair test (large shapes against everything, and the brute-force oracle).
DVI_HD bool directPairTest(int32_t a, int32_t b, const Shape* shapes, const Aabb* aabbs, const uint8_t* body_flags) {
  if (!aabbOverlap(aabbs[a], aabbs[b])) return false;
  const Shape& sa = shapes[a];
  const Shape& sb = shapes[b];
  return pairAllowed(sa, sb, body_flags[sa.body], body_flags[sb.body]);
}

// True when the box is unbounded or not finite (planes, NaN from an exploded body): never binned.
DVI_HD bool aabbUnbounded(const Aabb& box) {
  const real h = kBroadPhaseHuge;
  // written so that NaN compares false and therefore reports "unbounded"
  return !(box.lo.x > -h && box.lo.y > -h && box.lo.z > -h && box.hi.x < h && box.hi.y < h && box.hi.z < h);
}

// Largest side of a bounded box.
DVI_HD real aabbMaxSide(const Aabb& box) {
  const real x = box.hi.x - box.lo.x, y = box.hi.y - box.lo.y, z = box.hi.z - box.lo.z;
  const real m = x > y ? x : y;
  return m > z ? m : z;
}

}  // namespace dvi
