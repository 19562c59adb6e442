// ComputeAabbs, BroadPhase and NarrowPhase on the device. The per-element work is the DVI_HD code of
// narrowphase.h and broadphase_kernels.h (the functions BroadPhaseBins and NativeCollision call on the
// CPU); between the kernels run CUB scans, radix sorts and run-length encodings, the GPU form of the CPU's
// count -> scan -> write -> sort -> encode passes. The pair list comes out sorted by (a, b) and the contacts
// by (shape_a, shape_b, feature), exactly as on the CPU.
#include <cuda_runtime.h>
#include <cooperative_groups.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>

#include <thrust/iterator/transform_iterator.h>

#include "chrono_like/collision/broadphase_kernels.h"
#include "chrono_like/collision/narrowphase.h"
#include "gpu/cub_call.cuh"
#include "gpu/gpu_state.cuh"

namespace dvi::gpu {

namespace {

__global__ void aabbKernel(int n, const Shape* shapes, const Vec3* pos, const Quat* rot, const Vec3* vel,
                           const Vec3* omega, const Vec3* hull, real envelope_rel, real h_sweep, real* sweep,
                           Aabb* out) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const Shape s = shapes[i];
  const Pose body{pos[s.body], rot[s.body]};
  const real sw = shapeSweep(s, hull, vel[s.body], omega[s.body], h_sweep);
  sweep[i] = sw;
  out[i] = shapeAabb(s, shapeWorldPose(body, s), hull, shapeMargin(s, envelope_rel, sw));
}

// ---- broad phase: classification and grid (the rule of broadphase.h, on the device) ----

// Pair reuse (broadphase_kernels.h): *moved = 1 when a shape's box left the grown box of the last build or its
// body's flags changed (every such thread stores the same value; *moved was 0 before).
__global__ void pairsHoldKernel(int n, const Shape* shapes, const Aabb* box, const Aabb* fat, const uint8_t* flags,
                                const uint8_t* fat_flags, int32_t* moved) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i < n && !pairsStillHold(box[i], fat[i], flags[shapes[i].body], fat_flags[i])) *moved = 1;
}

// The boxes of a build grown by m, and the body flags they were built with.
__global__ void fatBoxKernel(int n, const Shape* shapes, const Aabb* box, const uint8_t* flags, real m, Aabb* fat,
                             uint8_t* fat_flags) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  fat[i] = fatAabb(box[i], m);
  fat_flags[i] = flags[shapes[i].body];
}

__global__ void extentKernel(int n, const Shape* shapes, const Aabb* box, real* ext) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  ext[i] = (shapes[i].type == ShapeType::Plane || aabbUnbounded(box[i])) ? real(-1) : aabbMaxSide(box[i]);
}

__global__ void toDoubleKernel(int n, const real* in, double* out) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i < n) out[i] = double(in[i]);
}

// First index in sorted[0, n) whose value is > x (strict=true) or >= x (strict=false).
__device__ int searchSorted(const real* sorted, int n, real x, bool strict) {
  int lo = 0, hi = n;
  while (lo < hi) {
    const int mid = (lo + hi) / 2;
    if (strict ? !(x < sorted[mid]) : sorted[mid] < x)
      lo = mid + 1;
    else
      hi = mid;
  }
  return lo;
}

// The bin edge without sorting the extents. With lo the least bounded extent, split the bounded extents at
// pivot = large_factor x lo into S (<= pivot: count cS, sum, largest hS) and B (> pivot: count cB, least lB).
// When S holds more than half of them, the median m lies in S, so large_factor x m >= pivot keeps all of S;
// when moreover lB > large_factor x hS, no extent of B is <= large_factor x m: the mean extent is S's mean and
// edge = bin_size_factor x mean. With bin_size_factor >= 1, no extent of S exceeds large_factor x edge
// (>= large_factor x lo); when lB also exceeds it, the shapes treated apart are exactly B's, and when there are
// at most max_large of them edgeKernel's rule ends there. Those conditions are checked here; where one fails,
// the caller sorts the extents (edgeKernel). A pile or mix in a box (walls in B) takes this path. The mean
// differs from edgeKernel's in the sum's order only. (The 64-bit radix sort of the extents, its prefix sums and
// edgeKernel took ~85 us of a 100k-sphere step on an H200; ncu, docs/GPU_PERFORMANCE.md.)
__device__ bool edgeFromSplit(int64_t cS, int64_t cB, double sumS, real hS, real lB, const BroadPhaseSettings& s,
                              real* edge) {
  if (cS + cB == 0) {
    *edge = 0;
    return true;
  }
  if (!(s.bin_size_factor >= real(1)) || cS <= cB || !(lB > s.large_factor * hS)) return false;
  const real e = real(double(s.bin_size_factor) * sumS / double(cS));
  if (cB > 0 && !(lB > s.large_factor * e)) return false;
  if (cB > int64_t(s.max_large > 0 ? s.max_large : 0)) return false;
  *edge = e;
  return true;
}

// Bin edge before the max_bins growth: median of the bounded extents, mean of those <= large_factor x
// median, capped so that at most max_large bounded shapes are treated apart (as BroadPhaseBins::run).
__global__ void edgeKernel(int n, const real* se, const double* prefix, BroadPhaseSettings s, BroadParams* p) {
  const int first = searchSorted(se, n, real(0), false);  // entries < 0 are the unbounded shapes
  const int cnt = n - first;
  real edge = 0;
  if (cnt > 0) {
    const real median = se[first + cnt / 2];
    const real cut = s.large_factor * median;
    const int upper = searchSorted(se, n, cut, true);
    const double sum = prefix[upper - 1] - (first > 0 ? prefix[first - 1] : 0.0);
    const int c = upper - first;
    edge = c > 0 ? real(double(s.bin_size_factor) * sum / double(c)) : real(0);
    if (edge > real(0)) {
      const real thr = s.large_factor * edge;
      const int big = n - searchSorted(se, n, thr, true);
      const int max_large = s.max_large > 0 ? s.max_large : 0;
      if (big > max_large) edge = se[n - 1 - max_large] / s.large_factor;
    }
    // whether next step can do without the sort (edgeFromSplit on these extents)
    const int up = searchSorted(se, n, s.large_factor * se[first], true);
    const double sumS = prefix[up - 1] - (first > 0 ? prefix[first - 1] : 0.0);
    real unused = 0;
    p->needs_sort = edgeFromSplit(up - first, n - up, sumS, se[up - 1],
                                  up < n ? se[up] : std::numeric_limits<real>::max(), s, &unused)
                        ? 0
                        : 1;
  } else {
    p->needs_sort = 0;
  }
  p->edge = edge;
}

struct ExtentMin {  // of the bounded extents (those >= 0); the largest real when there is none
  __host__ __device__ real operator()(real e) const { return e < real(0) ? std::numeric_limits<real>::max() : e; }
};
struct ExtentSplit {  // edgeFromSplit's sums
  double sumS;
  real hS, lB;
  int64_t cS, cB;
};
struct ExtentToSplit {
  const real* lo;  // ExtentMin's result, on the device
  real large_factor;
  __device__ ExtentSplit operator()(real e) const {
    ExtentSplit t{0, std::numeric_limits<real>::lowest(), std::numeric_limits<real>::max(), 0, 0};
    if (e < real(0)) return t;
    if (e <= large_factor * *lo) {
      t.sumS = double(e);
      t.hS = e;
      t.cS = 1;
    } else {
      t.lB = e;
      t.cB = 1;
    }
    return t;
  }
};
struct ExtentSplitMerge {
  __host__ __device__ ExtentSplit operator()(const ExtentSplit& a, const ExtentSplit& b) const {
    return ExtentSplit{a.sumS + b.sumS, a.hS > b.hS ? a.hS : b.hS, a.lB < b.lB ? a.lB : b.lB, a.cS + b.cS, a.cB + b.cB};
  }
};

__global__ void edgeFromSplitKernel(const ExtentSplit* st, BroadPhaseSettings s, BroadParams* p) {
  const ExtentSplit t = *st;
  real edge = 0;
  p->needs_sort = edgeFromSplit(t.cS, t.cB, t.sumS, t.hS, t.lB, s, &edge) ? 0 : 1;
  p->edge = edge;
}

__global__ void classifyKernel(int n, const real* ext, const Aabb* box, BroadPhaseSettings s, const BroadParams* p,
                               int32_t* is_binned, Aabb* bound_in) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i > n) return;
  if (i == n) {  // sentinel for the exclusive scan
    is_binned[n] = 0;
    return;
  }
  const real edge = p->edge;
  const real thr = s.large_factor * edge;
  const bool large = ext[i] < real(0) || (edge > real(0) && ext[i] > thr);
  is_binned[i] = large ? 0 : 1;
  bound_in[i] =
      large ? Aabb{{real(FLT_MAX), real(FLT_MAX), real(FLT_MAX)}, {-real(FLT_MAX), -real(FLT_MAX), -real(FLT_MAX)}}
            : box[i];
}

__global__ void splitKernel(int n, const int32_t* is_binned, const int32_t* pos, int32_t* binned, int32_t* large) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n) return;
  if (is_binned[i])
    binned[pos[i]] = i;
  else
    large[i - pos[i]] = i;
}

struct AabbMerge {
  __device__ Aabb operator()(const Aabb& a, const Aabb& b) const { return Aabb{vmin(a.lo, b.lo), vmax(a.hi, b.hi)}; }
};

__device__ double gridDimsDev(Vec3 ext, double edge, double dims[3]) {
  const double e[3] = {double(ext.x), double(ext.y), double(ext.z)};
  double total = 1;
  for (int d = 0; d < 3; ++d) {
    dims[d] = fmax(1.0, ceil(e[d] / edge));
    total *= dims[d];
  }
  return total;
}

__global__ void gridKernel(int n, const int32_t* pos, const Aabb* bounds, BroadPhaseSettings s, BroadParams* p) {
  const int nb = pos[n];
  p->binned = nb;
  p->large = n - nb;
  p->bins = 0;
  p->grid = BinGrid{{0, 0, 0}, real(1), {1, 1, 1}};
  p->bounds = Aabb{{0, 0, 0}, {0, 0, 0}};
  if (nb == 0) return;
  const Aabb b = *bounds;
  p->bounds = b;
  const Vec3 span = b.hi - b.lo;
  real edge = p->edge;
  if (!(edge > real(0)) || !isfinite(double(edge))) {
    const double m = double(maxComponent(span));
    edge = m > 0 ? real(m / cbrt(double(nb))) : real(1);
  }
  const long long mb = s.max_bins < 2147483647LL ? s.max_bins : 2147483647LL;
  const double max_bins = double(mb > 1 ? mb : 1);
  double dims[3];
  double e = double(edge);
  double total = gridDimsDev(span, e, dims);
  while (total > max_bins) {
    e *= fmax(1.0001, cbrt(total / max_bins));
    total = gridDimsDev(span, e, dims);
  }
  p->edge = real(e);
  p->grid.origin = b.lo;
  p->grid.inv_edge = real(1) / real(e);
  for (int d = 0; d < 3; ++d) p->grid.n[d] = int32_t(dims[d]);
  p->bins = int64_t(total);
}

// ---- broad phase: entries ----

__global__ void entryCountKernel(int nb, const int32_t* binned, const Aabb* box, const BroadParams* p,
                                 uint64_t* count) {
  const int j = blockIdx.x * blockDim.x + threadIdx.x;
  if (j > nb) return;
  count[j] = j < nb ? uint64_t(aabbBinCount(p->grid, box[binned[j]])) : 0;
}

__global__ void entryWriteKernel(int nb, const int32_t* binned, const Aabb* box, const BroadParams* p,
                                 const uint64_t* off, uint32_t* bin, int32_t* shape) {
  const int j = blockIdx.x * blockDim.x + threadIdx.x;
  if (j >= nb) return;
  const uint64_t o = off[j];
  aabbWriteBins(p->grid, box[binned[j]], binned[j], bin + o, shape + o, nullptr);
}

// ---- broad phase: pairs. Slot s of the count/write passes is
//   [0, ne)            sorted bin entry s against the entries after it in the same bin (a thread per entry,
//                      not per bin: a 100k-sphere pile has ~26 entries and ~330 pair tests per occupied bin,
//                      which one thread per bin took 0.53 ms per pass for on an H200)
//   [ne, ne+nb)        binned shape s-ne against every large shape that can touch the binned region
//   [ne+nb, ne+nb+nl)  large shape against the large shapes after it

struct PairSlots {
  int64_t ne;
  int32_t nb, nl;
  const uint32_t* entry_bin;  // sorted by bin
  const int32_t* entry_shape;
  const int32_t* binned;
  const int32_t* large;
  const Shape* shapes;
  const Aabb* box;
  const uint8_t* flags;
  const BroadParams* p;
};

// Visits the pairs of slot s in a fixed order; emit(a, b) with a < b.
template <class Emit>
__device__ void visitSlot(const PairSlots& S, int64_t s, Emit&& emit) {
  if (s < S.ne) {
    // Entry p of a bin of k entries tests the entries at cyclic distance 1 .. k/2 after it (at distance k/2,
    // when k is even, from the lower position only): every pair once, and every entry ~k/2 tests. (Testing the
    // entries after it only, entry p did k - 1 - p: a warp over one bin ran k - 1 rounds at half its lanes.)
    // Entries of one bin keep increasing shape order (stable sort of the per-shape writes): the lower position
    // holds the lower shape.
    const uint32_t bin = S.entry_bin[s];
    int64_t lo = s, hi = s + 1;
    while (lo > 0 && S.entry_bin[lo - 1] == bin) --lo;
    while (hi < S.ne && S.entry_bin[hi] == bin) ++hi;
    const int64_t k = hi - lo, p = s - lo, half = k / 2;
    const int32_t me = S.entry_shape[s];
    const BinGrid g = S.p->grid;
    for (int64_t d = 1; d <= half; ++d) {
      if (2 * d == k && p >= half) break;
      const int64_t q = p + d < k ? p + d : p + d - k;
      const int32_t other = S.entry_shape[lo + q];
      const int32_t a = p < q ? me : other, b = p < q ? other : me;
      if (binPairTest(g, bin, a, b, S.shapes, S.box, S.flags)) emit(a, b);
    }
  } else if (s < S.ne + S.nb) {
    const int32_t a = S.binned[s - S.ne];
    const Aabb bounds = S.p->bounds;
    for (int32_t k = 0; k < S.nl; ++k) {
      const int32_t l = S.large[k];
      if (!aabbOverlap(S.box[l], bounds)) continue;  // cannot touch any binned shape
      if (directPairTest(a, l, S.shapes, S.box, S.flags)) emit(a < l ? a : l, a < l ? l : a);
    }
  } else {
    const int32_t i = int32_t(s - S.ne - S.nb);
    const int32_t a = S.large[i];
    for (int32_t k = i + 1; k < S.nl; ++k)
      if (directPairTest(a, S.large[k], S.shapes, S.box, S.flags)) emit(a, S.large[k]);
  }
}

// A pair's key: (a, b) in 2 x sh bits (sh = bitsFor(shapes - 1)), so that sorting the keys by their 2 sh low bits
// orders the pairs by (a, b) in fewer radix passes than a 32-bit shift (5 instead of 7 at 100k shapes).
__device__ __forceinline__ uint64_t packPair(int32_t a, int32_t b, int sh) {
  return (uint64_t(uint32_t(a)) << sh) | uint32_t(b);
}
__device__ __forceinline__ void unpackPair(uint64_t key, int sh, int32_t& a, int32_t& b) {
  a = int32_t(key >> sh);
  b = int32_t(key & ((uint64_t(1) << sh) - 1));
}

// The next free place of an append-only list whose length is *counter, taken by every lane that calls this at
// once with one atomic for the group (cooperative_groups::coalesced_threads); the order within the list is free.
__device__ __forceinline__ unsigned long long warpAggregatedSlot(unsigned long long* counter) {
  namespace cg = cooperative_groups;
  const cg::coalesced_group g = cg::coalesced_threads();
  unsigned long long base = 0;
  if (g.thread_rank() == 0) base = atomicAdd(counter, static_cast<unsigned long long>(g.size()));
  return g.shfl(base, 0) + g.thread_rank();
}

// One pass over the slots: each pair found takes the next place of a counter, aggregated over the warp's lanes
// that emit at once (one atomic a group), and is written when it fits in cap. The keys are sorted afterwards,
// so the order they land in does not matter; the count is exact either way (the caller re-runs with room for
// it when it exceeds cap). Counting in a pass of its own and scanning the counts cost 80 us of a 100k-sphere
// step on an H200 (ncu).
__global__ void pairEmitKernel(PairSlots S, int64_t slots, int sh, uint64_t cap, unsigned long long* counter,
                               uint64_t* keys) {
  const int64_t s = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (s >= slots) return;
  visitSlot(S, s, [&](int32_t a, int32_t b) {
    const uint64_t w = warpAggregatedSlot(counter);
    if (w < cap) keys[w] = packPair(a, b, sh);
  });
}

// ---- narrow phase ----

struct NarrowArgs {
  const uint64_t* pairs;
  const Shape* shapes;
  const Vec3* pos;
  const Quat* rot;
  const Vec3* vel;  // the bodies' velocities after this step's forces (v_free, w_free): keepSpeculative
  const Vec3* omega;
  const Vec3* hull;
  const real* sweep;
  real envelope_rel;
  real h;
  int shift;         // of the pair keys (packPair)
  bool manifold;     // CollisionSettings::mpr_manifold
  GjkUse gjk;        // CollisionSettings::gjk, resolved for the GPU (resolvedGjk)
  const Aabb* aabb;  // the shapes' boxes of this step (ComputeAabbs): pairs whose boxes are apart are skipped
  LastNormals last;  // last step's contacts for MPR's temporal coherence (CollisionSettings::mpr_coherence); n = 0: off
};

struct PairPoses {
  int32_t a, b;
  Shape sa, sb;
  Pose wa, wb;
  real envelope;  // the pair's (sweep-widened) envelope, and its plain one (narrowphase.h)
  real plain;
};

__device__ PairPoses pairPoses(const NarrowArgs& A, int64_t i) {
  PairPoses P;
  const uint64_t key = A.pairs[i];
  unpackPair(key, A.shift, P.a, P.b);
  P.sa = A.shapes[P.a];
  P.sb = A.shapes[P.b];
  P.wa = shapeWorldPose(Pose{A.pos[P.sa.body], A.rot[P.sa.body]}, P.sa);
  P.wb = shapeWorldPose(Pose{A.pos[P.sb.body], A.rot[P.sb.body]}, P.sb);
  const int32_t ba = P.sa.body, bb = P.sb.body;
  const PairMotion m{A.pos[ba], A.vel[ba], A.omega[ba], A.pos[bb], A.vel[bb], A.omega[bb]};
  P.envelope = pairEnvelope(P.sa, P.sb, A.envelope_rel, A.sweep[P.a], A.sweep[P.b], A.h, m);
  P.plain = plainEnvelope(P.sa, P.sb, A.envelope_rel);
  return P;
}

// keepSpeculativePoints on the pair's n points (n = np::kMprDeferred is returned as it is). Every pass that makes a
// pair's points (count, deep, write, multi) calls it, so they agree on the count; the first point keeps its MPR
// mark only where it is MPR's own first point (a moved point's mark is cleared), so the multi pass's
// mprManifoldAgain starts only from that point.
__device__ int keepPoints(const NarrowArgs& A, const PairPoses& P, ContactPoint* pts, int n) {
  if (n <= 0) return n;
  const int32_t ba = P.sa.body, bb = P.sb.body;
  const PairMotion m{A.pos[ba], A.vel[ba], A.omega[ba], A.pos[bb], A.vel[bb], A.omega[bb]};
  return keepSpeculativePoints(pts, n, P.plain, A.h, m);
}

__device__ int collidePair(const NarrowArgs& A, int64_t i, int32_t& a, int32_t& b, ContactPoint* pts,
                           np::MprDeferred* defer = nullptr) {
  const PairPoses P = pairPoses(A, i);
  a = P.a;
  b = P.b;
  const PairHistory H{A.last, P.a, P.b, real(1)};
  return keepPoints(A, P, pts,
                    collideShapes(P.sa, P.wa, P.sb, P.wb, A.hull, P.envelope, pts, defer, A.manifold, A.gjk, nullptr,
                                  A.last.n > 0 ? &H : nullptr));
}

// Count pass: contacts per pair, keeping the first point. A deep MPR pair (mpr.h: mprBegin's answer 2) is left
// to narrowDeepKernel: its state goes to deferred[i] and its index to the deep list. The restarts of such a
// pair cost up to ~25 MPR passes in one thread; one such thread set the length of the whole pass (3.7 ms of the
// CES industrial feed's step on an H200, with 1.7 of 32 lanes active on average).
// Appends i to list (warp-aggregated: one atomic per group of lanes that append at once); the order is free,
// every result goes to index i.
__device__ __forceinline__ void appendIndex(int64_t i, int64_t* list, unsigned long long* list_count) {
  list[warpAggregatedSlot(list_count)] = i;
}

// The count pass's first point of a touching pair for the write pass, without 80 B for every pair (with pairs
// kept between steps most pairs do not touch). slot[i] says where pair i's point is: a sphere pair's is
// recomputed by the write pass (kSphereAgain: two loads and a few operations); a general pair's is kept at its
// place j in the general list, in room for last step's general pairs and half again (cap); past that, -1, and
// the write pass recomputes the pair with those of several contacts.
constexpr int32_t kSphereAgain = -2;
struct FirstPoints {
  ContactPoint* pts;  // by place in the general list
  int32_t* slot;      // by pair (read only where the pair has one contact)
  int64_t cap;
};

// Shape-pair classes: (ta, tb) with ta <= tb, the closed-form classes (pairUsesMpr false) first, then MPR's. The
// first pass gives each pair it cannot settle its class; the pairs are then placed class by class in the general
// list (narrowScatterKernel), so that a warp collides pairs of one class (one branch of the support mappings and of
// the dispatch instead of all of them in turn), and the closed-form classes run in a kernel without MPR's code.
constexpr int kTypes = int(ShapeType::Count);
constexpr int kClosedClasses = kTypes * kTypes;
constexpr int kClasses = 2 * kClosedClasses;
constexpr uint8_t kNoClass = 0xFF;
static_assert(kClasses < kNoClass, "a class fits in a byte");
// list_count's entries: [0] general pairs, [1] pairs of several contacts (write pass), [2] and [3] the MPR and
// multi kernels' work counters, [4] the closed-form pairs at the general list's head, [5] the closed kernel's counter
constexpr int kListCounts = 6;

__device__ __forceinline__ int pairClass(ShapeType a, ShapeType b) {
  const int ta = int(a) < int(b) ? int(a) : int(b), tb = int(a) < int(b) ? int(b) : int(a);
  return (pairUsesMpr(a, b) ? kClosedClasses : 0) + ta * kTypes + tb;
}

// The first pass's answer for pair i: the sphere pairs are collided here (collideSphereSphere, collideShapes' first
// case, in a kernel of few registers), pairs whose boxes are apart (skipByBoxes) get no contact; -1 for both. Any
// other pair's class is returned, for the general kernels.
__device__ int settleOrClassify(const NarrowArgs& A, int64_t i, int64_t* count, FirstPoints first) {
  int32_t a, b;
  unpackPair(A.pairs[i], A.shift, a, b);
  const ShapeType ta = A.shapes[a].type, tb = A.shapes[b].type;
  if (skipByBoxes(ta, tb, A.aabb[a], A.aabb[b])) {
    count[i] = 0;
    return -1;
  }
  if (ta != ShapeType::Sphere || tb != ShapeType::Sphere) return pairClass(ta, tb);
  const PairPoses P = pairPoses(A, i);
  ContactPoint pts[kMaxContactsPerPair];
  const int n = keepPoints(A, P, pts, np::collideSphereSphere(P.sa, P.wa, P.sb, P.wb, P.envelope, pts));
  count[i] = n;
  if (n >= 1) first.slot[i] = kSphereAgain;
  return -1;
}

// First pass over every pair (settleOrClassify). With classes (cls set): each other pair's class goes to cls[i]
// and the classes' counts to class_count (a block's histogram in shared memory, then one atomic per class);
// without: the pair is appended to the general list in any order. (collideShapes in one kernel takes 255
// registers, one block of 256 per SM: the 100k-sphere pile's count pass took 91 us on an H200, ncu.)
__global__ void narrowClassifyKernel(NarrowArgs A, int64_t np, int64_t* count, FirstPoints first, int64_t* general,
                                     unsigned long long* general_count, uint8_t* cls, unsigned long long* class_count) {
  __shared__ unsigned int hist[kClasses];
  const bool classes = cls != nullptr;  // the same in every thread: the barriers below are reached by all
  if (classes) {
    for (int k = int(threadIdx.x); k < kClasses; k += int(blockDim.x)) hist[k] = 0;
    __syncthreads();
  }
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  int c = -1;
  if (i < np)
    c = settleOrClassify(A, i, count, first);
  else if (i == np)
    count[np] = 0;
  if (!classes) {
    if (c >= 0) appendIndex(i, general, general_count);
    return;
  }
  if (i < np) cls[i] = c >= 0 ? uint8_t(c) : kNoClass;
  if (c >= 0) atomicAdd(&hist[c], 1u);
  __syncthreads();
  for (int k = int(threadIdx.x); k < kClasses; k += int(blockDim.x))
    if (hist[k] != 0) atomicAdd(&class_count[k], static_cast<unsigned long long>(hist[k]));
}

// The classes' start places in the general list (class_count[kClasses + k]; the fill cursors after them zeroed),
// the general list's length and its closed-form head (list_count[0] and [4]). One thread: kClasses entries.
__global__ void narrowClassScanKernel(unsigned long long* class_count, unsigned long long* list_count) {
  if (threadIdx.x != 0 || blockIdx.x != 0) return;
  unsigned long long sum = 0;
  for (int k = 0; k < kClasses; ++k) {
    if (k == kClosedClasses) list_count[4] = sum;
    class_count[kClasses + k] = sum;
    class_count[2 * kClasses + k] = 0;
    sum += class_count[k];
  }
  list_count[0] = sum;
}

// Places every classified pair in its class's part of the general list: the lanes of a warp with the same class
// take their places with one atomic (the order inside a class is free: every result goes to index i).
__global__ void narrowScatterKernel(const uint8_t* cls, int64_t np, unsigned long long* class_count, int64_t* list) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= np) return;
  const int c = cls[i];
  if (c == kNoClass) return;
  const unsigned lane = threadIdx.x & 31u;
  const unsigned peers = __match_any_sync(__activemask(), c);
  const int leader = __ffs(int(peers)) - 1;
  unsigned long long base = 0;
  if (int(lane) == leader)
    base = atomicAdd(&class_count[2 * kClasses + c], static_cast<unsigned long long>(__popc(peers)));
  base = __shfl_sync(peers, base, leader);
  list[class_count[kClasses + c] + base + __popc(peers & ((1u << lane) - 1u))] = int64_t(i);
}

// The next 32 items of a list for the calling warp (all its lanes call it together): a fixed grid takes work
// from the list as it goes, so pairs of very different cost (MPR) do not leave threads with long fixed shares.
__device__ __forceinline__ int64_t warpTake(unsigned long long* next) {
  const unsigned lane = threadIdx.x & 31u;
  unsigned long long base = 0;
  if (lane == 0) base = atomicAdd(next, 32ull);
  return int64_t(__shfl_sync(0xffffffffu, base, 0)) + lane;
}

// Count pass, the closed-form classes at the general list's head (list_count[4] of them, a fixed grid taking them
// by warps): collideShapesClosedForm, the same points as collideShapes without MPR's code in the kernel.
__global__ void narrowClosedKernel(NarrowArgs A, const int64_t* general, const unsigned long long* list_count,
                                   unsigned long long* next, int64_t* count, FirstPoints first) {
  const int64_t m = int64_t(list_count[4]);
  for (;;) {
    const int64_t j = warpTake(next);
    if (j - int64_t(threadIdx.x & 31u) >= m) break;
    if (j >= m) continue;
    const int64_t i = general[j];
    const PairPoses P = pairPoses(A, i);
    ContactPoint pts[kMaxContactsPerPair];
    const int n = keepPoints(A, P, pts, collideShapesClosedForm(P.sa, P.wa, P.sb, P.wb, A.hull, P.envelope, pts));
    count[i] = n;
    if (n >= 1) {
      if (j < first.cap) first.pts[j] = pts[0];
      first.slot[i] = j < first.cap ? int32_t(j) : -1;
    }
  }
}

// Count pass, the general list (its length and the work counter are on the device): contacts per pair, keeping
// the first point. A deep MPR pair (mpr.h: mprBegin's answer 2) is left to narrowDeepKernel: its state and index
// go to slot k of the deferred and deep lists, k < deep_cap (the lists' room, last step's count and more); past
// that, the thread finishes it itself (finishDeferredMpr, the same arithmetic). The restarts of such a pair cost
// up to ~25 MPR passes in one thread; one such thread set the length of the whole pass (3.7 ms of the CES
// industrial feed's step on an H200, with 1.7 of 32 lanes active on average).
// With classes, the list's closed-form head (list_count[4] pairs, narrowClosedKernel's) is skipped.
__global__ void narrowCountKernel(NarrowArgs A, const int64_t* general, const unsigned long long* list_count,
                                  bool classes, unsigned long long* next, int64_t* count, FirstPoints first,
                                  np::MprDeferred* deferred, int32_t* deep, int32_t* deep_count, int32_t deep_cap) {
  const int64_t m = int64_t(list_count[0]);
  const int64_t head = classes ? int64_t(list_count[4]) : 0;
  for (;;) {
    const int64_t j = head + warpTake(next);
    if (j - int64_t(threadIdx.x & 31u) >= m) break;  // the warp's whole batch is past the end
    if (j >= m) continue;
    const int64_t i = general[j];
    ContactPoint pts[kMaxContactsPerPair];
    int32_t a, b;
    np::MprDeferred d;
    int n = collidePair(A, i, a, b, pts, &d);
    if (n == np::kMprDeferred) {
      const int32_t k = atomicAdd(deep_count, 1);  // slot order is free: results go to index i
      if (k < deep_cap) {
        deferred[k] = d;
        deep[k] = int32_t(i);
        count[i] = 0;
        first.slot[i] = j < first.cap ? int32_t(j) : -1;  // where narrowDeepKernel puts its point
        continue;
      }
      const PairPoses P = pairPoses(A, i);
      n = keepPoints(A, P, pts, finishDeferredMpr(P.sa, P.wa, P.sb, P.wb, A.hull, P.envelope, d, pts, A.manifold));
    }
    count[i] = n;
    if (n >= 1) {
      if (j < first.cap) first.pts[j] = pts[0];
      first.slot[i] = j < first.cap ? int32_t(j) : -1;
    }
  }
}

// Deep MPR pairs, kDeepLanes lanes each (grid-stride over the deep list): lane l runs restart l of a round, every
// lane takes the round's results in index order (mprKeepShallower, as mprRunRound on the CPU), and lane 0 places
// the contact. The same arithmetic as finishDeferredMpr, so the GPU's contacts equal the CPU's.
constexpr int kDeepLanes = np::kMprRoundTries;
static_assert(32 % kDeepLanes == 0, "lane groups must tile a warp");

__device__ np::MprResult deepRound(const np::MprShape& SA, const np::MprShape& SB, const Vec3* hull,
                                   const np::MprRound& round, np::MprResult best, int lane, unsigned mask, int base) {
  np::MprResult mine;
  mine.n = Vec3{0, 0, 0};
  mine.depth = real(INFINITY);
  if (lane < round.n) mine = np::mprRestart(SA, SB, hull, round.dir[lane], best.depth);
  np::MprResult s = best;
  for (int k = 0; k < kDeepLanes; ++k) {
    np::MprResult r;
    r.n.x = __shfl_sync(mask, mine.n.x, base + k);
    r.n.y = __shfl_sync(mask, mine.n.y, base + k);
    r.n.z = __shfl_sync(mask, mine.n.z, base + k);
    r.depth = __shfl_sync(mask, mine.depth, base + k);
    if (k < round.n) np::mprKeepShallower(s, r);
  }
  return s;
}

__global__ void __launch_bounds__(128)
    narrowDeepKernel(NarrowArgs A, const np::MprDeferred* deferred, const int32_t* deep, const int32_t* deep_count,
                     int32_t deep_cap, int64_t* count, FirstPoints first) {
  const int lane = int(threadIdx.x % kDeepLanes), base = int(threadIdx.x % 32) - lane;
  const unsigned mask = ((1u << kDeepLanes) - 1u) << base;
  const int64_t groups = int64_t(gridDim.x) * blockDim.x / kDeepLanes;
  const int32_t nd = *deep_count < deep_cap ? *deep_count : deep_cap;
  for (int64_t g = (int64_t(blockIdx.x) * blockDim.x + threadIdx.x) / kDeepLanes; g < nd; g += groups) {
    const int64_t i = deep[g];
    const PairPoses P = pairPoses(A, i);
    np::MprDeferred d = deferred[g];
    np::MprShape SA, SB;
    const Shape *fa, *fb;
    deferredMprShapes(P.sa, P.wa, P.sb, P.wb, A.hull, P.envelope, d.swapped != 0, SA, SB, fa, fb);
    d.best = deepRound(SA, SB, A.hull, d.round, d.best, lane, mask, base);
    if (np::mprTiltRound(SA, *fa, *fb, d.best, d.round))
      d.best = deepRound(SA, SB, A.hull, d.round, d.best, lane, mask, base);
    if (lane == 0) {
      ContactPoint pts[kMaxContactsPerPair];
      int m = np::mprFinish(SA, SB, A.hull, d.best, P.envelope, pts, A.manifold);
      if (d.swapped) {
        np::flipContacts(pts, m);
        markFlippedMpr(pts, m);
      }
      m = keepPoints(A, P, pts, m);
      count[i] = m;
      const int32_t k = first.slot[i];  // set by the count pass
      if (m >= 1 && k >= 0) first.pts[k] = pts[0];
    }
  }
}

struct ContactOut {
  int32_t *shape_a, *shape_b, *body_a, *body_b;
  Vec3 *normal, *pa, *pb;
  real* dist;
  uint64_t* key;
};

__device__ __forceinline__ void writeContacts(const NarrowArgs& A, int32_t a, int32_t b, const ContactPoint* pts, int n,
                                              int64_t k, const ContactOut& out) {
  const int32_t ba = A.shapes[a].body, bb = A.shapes[b].body;
  for (int j = 0; j < n; ++j, ++k) {
    out.shape_a[k] = a;
    out.shape_b[k] = b;
    out.body_a[k] = ba;
    out.body_b[k] = bb;
    out.normal[k] = pts[j].normal;
    out.pa[k] = pts[j].pa;
    out.pb[k] = pts[j].pb;
    out.dist[k] = pts[j].dist;
    out.key[k] = contactKey(a, b, pts[j].feature);
  }
}

// Write pass, one thread per pair: a pair of one contact copies the count pass's point (a kernel of few
// registers); a pair of more, or one whose point found no room (FirstPoints), goes to the multi list for
// narrowMultiKernel.
__global__ void narrowWriteKernel(NarrowArgs A, int64_t np, const int64_t* count, const int64_t* off, FirstPoints first,
                                  ContactOut out, int64_t* multi, unsigned long long* multi_count) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= np) return;
  const int64_t n = count[i];
  if (n == 0) return;
  const int32_t k = n == 1 ? first.slot[i] : -1;
  if (k == kSphereAgain) {
    int32_t a, b;
    unpackPair(A.pairs[i], A.shift, a, b);
    const PairPoses P = pairPoses(A, i);
    ContactPoint pts[kMaxContactsPerPair];
    keepPoints(A, P, pts, np::collideSphereSphere(P.sa, P.wa, P.sb, P.wb, P.envelope, pts));
    writeContacts(A, a, b, pts, 1, off[i], out);
    return;
  }
  if (k < 0) {
    appendIndex(i, multi, multi_count);
    return;
  }
  int32_t a, b;
  unpackPair(A.pairs[i], A.shift, a, b);
  writeContacts(A, a, b, first.pts + k, 1, off[i], out);
}

// Write pass, pairs of several contacts (a fixed grid taking the multi list by warps): all their points again
// (deterministic: the same points as the count pass).
// A pair whose first point the count pass kept and marked as MPR's (mprFinish) gets its other points from it
// (mprManifoldAgain: the flat-feature manifold without MPR again, the same arithmetic).
__global__ void narrowMultiKernel(NarrowArgs A, const int64_t* multi, const unsigned long long* multi_count,
                                  unsigned long long* next, const int64_t* count, const int64_t* off, FirstPoints first,
                                  ContactOut out) {
  const int64_t m = int64_t(*multi_count);
  for (;;) {
    const int64_t j = warpTake(next);
    if (j - int64_t(threadIdx.x & 31u) >= m) break;
    if (j >= m) continue;
    const int64_t i = multi[j];
    ContactPoint pts[kMaxContactsPerPair];
    int32_t a, b;
    const int32_t k = first.slot[i];
    const int32_t mark = k >= 0 ? first.pts[k].pad_ : 0;
    if (mark == np::kMprFirst || mark == kMprFirstSwapped) {
      unpackPair(A.pairs[i], A.shift, a, b);
      const PairPoses P = pairPoses(A, i);
      keepPoints(A, P, pts, mprManifoldAgain(P.sa, P.wa, P.sb, P.wb, A.hull, P.envelope, first.pts[k], pts));
    } else {
      collidePair(A, i, a, b, pts);
    }
    writeContacts(A, a, b, pts, int(count[i]), off[i], out);
  }
}

// Blocks of kBlock threads of a kernel resident per SM (at least 1), asked once and kept in *cached.
template <class K>
int residentBlocks(K* kernel, int* cached) {
  if (*cached > 0) return *cached;
  int n = 0;
  DVI_CUDA(cudaOccupancyMaxActiveBlocksPerMultiprocessor(&n, reinterpret_cast<const void*>(kernel), kBlock, 0));
  *cached = std::max(1, n);
  return *cached;
}

}  // namespace

void computeAabbs(DeviceState& d, const SystemConfig& cfg, const StepContext& step) {
  const int n = int(d.shapes.count);
  if (n == 0) return;
  aabbKernel<<<blocksFor(n), kBlock, 0, d.stream>>>(
      n, d.shapes.shape.data(), d.bodies.pos.data(), d.bodies.rot.data(), d.bodies.v_free.data(),
      d.bodies.w_free.data(), d.shapes.hull.data(), cfg.collision.envelope_rel,
      cfg.collision.speculative ? step.dt : real(0), d.shapes.sweep.data(), d.shapes.aabb.data());
  DVI_CUDA_LAUNCH("aabbKernel");
}

// The large/binned split from the edge in B.params, the binned shapes' bounds and the grid (into B.params).
static void classifyAndGrid(DeviceState& d, const BroadPhaseSettings& s, int n, const Aabb* box) {
  BroadScratch& B = d.broad;
  cudaStream_t st = d.stream;
  B.entry_shape.resize(n + 1);  // reused as the binned flags (n + 1 for the scan)
  B.counts_sel.resize(n + 1);
  B.bound_in.resize(n + 1);
  classifyKernel<<<blocksFor(n + 1), kBlock, 0, st>>>(n, B.ext.data(), box, s, B.params.data(), B.entry_shape.data(),
                                                      B.bound_in.data());
  DVI_CUDA_LAUNCH("classifyKernel");
  cubRun(d, "cub::DeviceScan::ExclusiveSum (binned flags)", [&](void* t, size_t& b) {
    return cub::DeviceScan::ExclusiveSum(t, b, B.entry_shape.data(), B.counts_sel.data(), n + 1, st);
  });
  B.binned.resize(n);
  B.large.resize(n);
  splitKernel<<<blocksFor(n), kBlock, 0, st>>>(n, B.entry_shape.data(), B.counts_sel.data(), B.binned.data(),
                                               B.large.data());
  DVI_CUDA_LAUNCH("splitKernel");
  const Aabb empty{{real(FLT_MAX), real(FLT_MAX), real(FLT_MAX)}, {-real(FLT_MAX), -real(FLT_MAX), -real(FLT_MAX)}};
  cubRun(d, "cub::DeviceReduce::Reduce (bounds)", [&](void* t, size_t& b) {
    return cub::DeviceReduce::Reduce(t, b, B.bound_in.data(), B.bound_in.data() + n, n, AabbMerge{}, empty, st);
  });
  gridKernel<<<1, 1, 0, st>>>(n, B.counts_sel.data(), B.bound_in.data() + n, s, B.params.data());
  DVI_CUDA_LAUNCH("gridKernel");
}

// The bin edge from the sorted extents (edgeKernel: median, cut, max_large), into B.params.
static void edgeFromSortedExtents(DeviceState& d, const BroadPhaseSettings& s, int n) {
  BroadScratch& B = d.broad;
  cudaStream_t st = d.stream;
  B.ext_sorted.resize(n);
  B.ext_prefix.resize(n);
  cubRun(d, "cub::DeviceRadixSort::SortKeys (extents)", [&](void* t, size_t& b) {
    return cub::DeviceRadixSort::SortKeys(t, b, B.ext.data(), B.ext_sorted.data(), n, 0, int(sizeof(real) * 8), st);
  });
  toDoubleKernel<<<blocksFor(n), kBlock, 0, st>>>(n, B.ext_sorted.data(), B.ext_prefix.data());
  DVI_CUDA_LAUNCH("toDoubleKernel");
  cubRun(d, "cub::DeviceScan::InclusiveSum (extents)", [&](void* t, size_t& b) {
    return cub::DeviceScan::InclusiveSum(t, b, B.ext_prefix.data(), B.ext_prefix.data(), n, st);
  });
  edgeKernel<<<1, 1, 0, st>>>(n, B.ext_sorted.data(), B.ext_prefix.data(), s, B.params.data());
  DVI_CUDA_LAUNCH("edgeKernel");
}

// The bin edge from the split of the extents at large_factor x the least (edgeFromSplitKernel), into B.params;
// needs_sort there when the split cannot decide it.
static void edgeFromExtentSplit(DeviceState& d, const BroadPhaseSettings& s, int n) {
  BroadScratch& B = d.broad;
  cudaStream_t st = d.stream;
  B.ext_stats.resize(sizeof(ExtentSplit) + sizeof(real));
  auto* split = reinterpret_cast<ExtentSplit*>(B.ext_stats.data());
  real* lo = reinterpret_cast<real*>(B.ext_stats.data() + sizeof(ExtentSplit));
  const auto mins = thrust::make_transform_iterator(B.ext.data(), ExtentMin{});
  cubRun(d, "cub::DeviceReduce::Min (extents)",
         [&](void* t, size_t& b) { return cub::DeviceReduce::Min(t, b, mins, lo, n, st); });
  const auto parts = thrust::make_transform_iterator(B.ext.data(), ExtentToSplit{lo, s.large_factor});
  const ExtentSplit none{0, std::numeric_limits<real>::lowest(), std::numeric_limits<real>::max(), 0, 0};
  cubRun(d, "cub::DeviceReduce::Reduce (extents split)", [&](void* t, size_t& b) {
    return cub::DeviceReduce::Reduce(t, b, parts, split, n, ExtentSplitMerge{}, none, st);
  });
  edgeFromSplitKernel<<<1, 1, 0, st>>>(split, s, B.params.data());
  DVI_CUDA_LAUNCH("edgeFromSplitKernel");
}

// Stage 1, classification and grid. The bin edge from the extents' statistics where they decide it, else (and
// from then on, while the scene needs it) from the sorted extents; a wrong guess costs one more pass. Returns the
// parameters read back.
static BroadParams classifyShapes(DeviceState& d, const BroadPhaseSettings& s, int n, const Aabb* box,
                                  const Shape* shapes) {
  BroadScratch& B = d.broad;
  cudaStream_t st = d.stream;
  B.params.resize(1);
  B.ext.resize(n);
  extentKernel<<<blocksFor(n), kBlock, 0, st>>>(n, shapes, box, B.ext.data());
  DVI_CUDA_LAUNCH("extentKernel");
  bool by_sort = B.edge_by_sort;
  BroadParams P{};
  for (;;) {
    if (by_sort)
      edgeFromSortedExtents(d, s, n);
    else
      edgeFromExtentSplit(d, s, n);
    classifyAndGrid(d, s, n, box);
    P = d.readValue(B.params.data());
    if (by_sort || !P.needs_sort) break;
    by_sort = true;  // the statistics could not decide the edge: once more from the sorted extents
  }
  B.edge_by_sort = P.needs_sort != 0;
  B.last_edge = P.edge;
  return P;
}

// Stage 2: count -> scan -> write (bin, shape) entries -> sort by bin -> run-length encode (the occupied bins,
// with stats only). Returns the entries' count.
static int64_t binEntries(DeviceState& d, const BroadParams& P, const Aabb* box, bool stats) {
  BroadScratch& B = d.broad;
  cudaStream_t st = d.stream;
  const int nb = P.binned;
  int64_t ne = 0;
  B.num_runs.resize(1);
  DVI_CUDA(cudaMemsetAsync(B.num_runs.data(), 0, sizeof(int32_t), st));
  if (nb > 1) {
    B.entry_count.resize(nb + 1);
    B.entry_off.resize(nb + 1);
    entryCountKernel<<<blocksFor(nb + 1), kBlock, 0, st>>>(nb, B.binned.data(), box, B.params.data(),
                                                           B.entry_count.data());
    DVI_CUDA_LAUNCH("entryCountKernel");
    cubRun(d, "cub::DeviceScan::ExclusiveSum (bin entries)", [&](void* t, size_t& b) {
      return cub::DeviceScan::ExclusiveSum(t, b, B.entry_count.data(), B.entry_off.data(), nb + 1, st);
    });
    ne = int64_t(d.readValue(B.entry_off.data() + nb));
    if (ne > int64_t(INT32_MAX))
      throw std::length_error("GPU broad phase: " + std::to_string(ne) + " bin entries exceed 2^31");
    B.entry_bin.resize(ne);
    B.entry_bin_sorted.resize(ne);
    B.entry_shape.resize(ne);
    B.entry_shape_sorted.resize(ne);
    entryWriteKernel<<<blocksFor(nb), kBlock, 0, st>>>(nb, B.binned.data(), box, B.params.data(), B.entry_off.data(),
                                                       B.entry_bin.data(), B.entry_shape.data());
    DVI_CUDA_LAUNCH("entryWriteKernel");
    const int bits = bitsFor(uint64_t(P.bins > 0 ? P.bins - 1 : 0));
    cubRun(d, "cub::DeviceRadixSort::SortPairs (bin entries)", [&](void* t, size_t& b) {
      return cub::DeviceRadixSort::SortPairs(t, b, B.entry_bin.data(), B.entry_bin_sorted.data(), B.entry_shape.data(),
                                             B.entry_shape_sorted.data(), int(ne), 0, bits, st);
    });
    if (stats) {  // occupied bins, for the statistics only
      B.run_bin.resize(ne);
      B.run_len.resize(ne);
      cubRun(d, "cub::DeviceRunLengthEncode::Encode (bins)", [&](void* t, size_t& b) {
        return cub::DeviceRunLengthEncode::Encode(t, b, B.entry_bin_sorted.data(), B.run_bin.data(), B.run_len.data(),
                                                  B.num_runs.data(), int(ne), st);
      });
    }
  }
  return ne;
}

// Stage 3, pairs: emit (into the key buffer's capacity) -> sort by (a, b). Returns the pairs' count.
static int64_t emitPairs(DeviceState& d, const BroadParams& P, int n, int64_t ne, const Aabb* box,
                         const Shape* shapes) {
  BroadScratch& B = d.broad;
  cudaStream_t st = d.stream;
  const int nb = P.binned, nl = P.large;
  const int64_t slots = ne + nb + nl;
  const int sh = bitsFor(uint64_t(n - 1));
  d.pair_shift = sh;
  PairSlots S{ne,
              nb,
              nl,
              B.entry_bin_sorted.data(),
              B.entry_shape_sorted.data(),
              B.binned.data(),
              B.large.data(),
              shapes,
              box,
              d.bodies.flags.data(),
              B.params.data()};
  if (nb <= 1) S.ne = 0;
  B.pair_counter.resize(1);
  if (B.pair_key.capacity() == 0) B.pair_key.reserve(size_t(8) * size_t(n) + 1024);  // the first step's guess
  int64_t np = 0;
  for (;;) {  // at most twice: a second pass has room for the exact count of the first
    const uint64_t cap = B.pair_key.capacity();
    DVI_CUDA(cudaMemsetAsync(B.pair_counter.data(), 0, sizeof(unsigned long long), st));
    if (slots > 0) {
      pairEmitKernel<<<blocksFor(slots), kBlock, 0, st>>>(S, slots, sh, cap, B.pair_counter.data(), B.pair_key.data());
      DVI_CUDA_LAUNCH("pairEmitKernel");
    }
    np = int64_t(d.readValue(B.pair_counter.data()));
    if (uint64_t(np) <= cap) break;
    B.pair_key.reserve(size_t(np));
  }
  B.pair_key.resize(np);
  B.pair_key_sorted.resize(np);
  if (np > 0) {
    cubRun(d, "cub::DeviceRadixSort::SortKeys (pairs)", [&](void* t, size_t& b) {
      return cub::DeviceRadixSort::SortKeys(t, b, B.pair_key.data(), B.pair_key_sorted.data(), np, 0, 2 * sh, st);
    });
  }
  return np;
}

void broadPhase(DeviceState& d, const SystemConfig& cfg, BroadPhaseStats* stats, const Aabb* boxes) {
  const int n = int(d.shapes.count);
  BroadScratch& B = d.broad;
  d.pairs = 0;
  if (n < 2) return;
  const BroadPhaseSettings s = cfg.collision.broadphase;
  const Aabb* box = boxes ? boxes : d.shapes.aabb.data();
  const Shape* shapes = d.shapes.shape.data();
  const BroadParams P = classifyShapes(d, s, n, box, shapes);
  const int nb = P.binned, nl = P.large;
  const int64_t ne = binEntries(d, P, box, stats != nullptr);
  const int64_t np = emitPairs(d, P, n, ne, box, shapes);
  d.pairs = np;
  if (stats) {
    *stats = BroadPhaseStats{};
    stats->bins = P.bins;
    stats->bin_entries = ne;
    stats->large_shapes = nl;
    stats->pairs = np;
    stats->bin_edge = P.edge;
    stats->occupied_bins = nb > 1 ? d.readValue(B.num_runs.data()) : (nb == 1 ? 1 : 0);
    for (int k = 0; k < 3; ++k) stats->grid[k] = P.grid.n[k];
  }
}

bool broadPhaseStep(DeviceState& d, const SystemConfig& cfg) {
  const int n = int(d.shapes.count);
  BroadScratch& B = d.broad;
  cudaStream_t st = d.stream;
  const real f = cfg.collision.broadphase.pair_margin;
  if (f > real(0) && B.built && int64_t(B.fat.size()) == n && n >= 2) {
    B.moved.resize(1);
    DVI_CUDA(cudaMemsetAsync(B.moved.data(), 0, sizeof(int32_t), st));
    pairsHoldKernel<<<blocksFor(n), kBlock, 0, st>>>(n, d.shapes.shape.data(), d.shapes.aabb.data(), B.fat.data(),
                                                     d.bodies.flags.data(), B.fat_flags.data(), B.moved.data());
    DVI_CUDA_LAUNCH("pairsHoldKernel");
    if (d.readValue(B.moved.data()) == 0) return true;
  }
  B.fat.resize(n);
  B.fat_flags.resize(n);
  if (n > 0) {
    fatBoxKernel<<<blocksFor(n), kBlock, 0, st>>>(n, d.shapes.shape.data(), d.shapes.aabb.data(), d.bodies.flags.data(),
                                                  f > real(0) ? f * B.last_edge : real(0), B.fat.data(),
                                                  B.fat_flags.data());
    DVI_CUDA_LAUNCH("fatBoxKernel");
  }
  broadPhase(d, cfg, nullptr, B.fat.data());
  B.built = true;
  return false;
}

// Pairs whose bodies the scene excludes (collision/contact.h: contactExcluded) make no contacts: their count is zeroed
// before the scan, so the write passes skip them.
__global__ void excludePairsKernel(const uint64_t* pairs, int shift, int64_t np, const Shape* shapes,
                                   const uint64_t* keys, int64_t n_keys, const uint8_t* no_contact, int64_t n_flags,
                                   int64_t* count) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= np || count[i] == 0) return;
  int32_t a, b;
  unpackPair(pairs[i], shift, a, b);
  if (contactExcluded(shapes[a].body, shapes[b].body, keys, n_keys, no_contact, n_flags)) count[i] = 0;
}

// The classified pairs in class order in the general list (its closed-form head first), then that head collided.
void closedFormsInClassOrder(DeviceState& d, const NarrowArgs& A, int64_t np, const FirstPoints& first) {
  NarrowScratch& N = d.narrow;
  cudaStream_t st = d.stream;
  narrowClassScanKernel<<<1, 32, 0, st>>>(N.class_count.data(), N.list_count.data());
  DVI_CUDA_LAUNCH("narrowClassScanKernel");
  narrowScatterKernel<<<blocksFor(np), kBlock, 0, st>>>(N.cls.data(), np, N.class_count.data(), N.list.data());
  DVI_CUDA_LAUNCH("narrowScatterKernel");
  const int64_t closed_resident =
      int64_t(d.multiprocessors) * residentBlocks(narrowClosedKernel, &N.closed_blocks_per_sm);
  narrowClosedKernel<<<unsigned(std::min<int64_t>(blocksFor(np), closed_resident)), kBlock, 0, st>>>(
      A, N.list.data(), N.list_count.data(), N.list_count.data() + 5, N.count.data(), first);
  DVI_CUDA_LAUNCH("narrowClosedKernel");
}

// Last step's contacts as the narrow phase's LastNormals: those the warm start keeps (keepImpulsesForWarmStart),
// or those handed over with normals (GpuSystem::setWarmStart: a resumed checkpoint) where there are none; none
// without warm start or with CollisionSettings::mpr_coherence off (the CPU backend's rule, System::detectCollisions).
LastNormals lastNormals(const DeviceState& d, const SystemConfig& cfg) {
  if (!cfg.collision.mpr_coherence || !cfg.solver.warm_start) return LastNormals{};
  if (d.prev_count > 0)
    return LastNormals{d.solver.prev_key.data(), d.solver.prev_normal.data(), int64_t(d.prev_count)};
  if (d.extra_normals) return LastNormals{d.extra_key.data(), d.extra_normal.data(), int64_t(d.extra_count)};
  return LastNormals{};
}

// The narrow-phase kernels' view of this step's pairs, shapes and bodies.
NarrowArgs narrowArgs(DeviceState& d, const SystemConfig& cfg, const StepContext& step) {
  return NarrowArgs{d.broad.pair_key_sorted.data(),
                    d.shapes.shape.data(),
                    d.bodies.pos.data(),
                    d.bodies.rot.data(),
                    d.bodies.v_free.data(),
                    d.bodies.w_free.data(),
                    d.shapes.hull.data(),
                    d.shapes.sweep.data(),
                    cfg.collision.envelope_rel,
                    step.dt,
                    d.pair_shift,
                    cfg.collision.mpr_manifold,
                    resolvedGjk(cfg.collision.gjk, true),
                    d.shapes.aabb.data(),
                    lastNormals(d, cfg)};
}

void narrowPhase(DeviceState& d, const SystemConfig& cfg, const StepContext& step) {
  const int64_t np = d.pairs;
  cudaStream_t st = d.stream;
  NarrowScratch& N = d.narrow;
  if (np == 0) {
    d.contacts.resize(0);
    return;
  }
  N.count.resize(np + 1);
  N.off.resize(np + 1);
  // first points of general pairs: room for last step's general pairs and half again (at least 1024, at most
  // every pair)
  const int64_t first_cap =
      std::min<int64_t>({np, std::max<int64_t>(1024, N.general_last + N.general_last / 2), int64_t(INT32_MAX)});
  N.first.resize(size_t(first_cap));
  N.first_slot.resize(np);
  const NarrowArgs A = narrowArgs(d, cfg, step);
  // Deep MPR pairs' room: last step's count and half again (at least 64, at most every pair); the ones past it
  // are finished in the count pass (slower, the same contacts).
  const int64_t deep_cap = std::min<int64_t>(np, std::max<int64_t>(64, N.deep_last + N.deep_last / 2));
  N.deferred.resize(size_t(deep_cap));
  N.deep.resize(size_t(deep_cap));
  N.deep_count.resize(1);
  N.list.resize(np);
  N.list_count.resize(kListCounts);
  DVI_CUDA(cudaMemsetAsync(N.deep_count.data(), 0, sizeof(int32_t), st));
  DVI_CUDA(cudaMemsetAsync(N.list_count.data(), 0, kListCounts * sizeof(unsigned long long), st));
  const bool classes = cfg.gpu.narrow_classes;
  if (classes) {
    N.cls.resize(np);
    N.class_count.resize(3 * kClasses);
    DVI_CUDA(cudaMemsetAsync(N.class_count.data(), 0, kClasses * sizeof(unsigned long long), st));
  }
  const FirstPoints first{N.first.data(), N.first_slot.data(), first_cap};
  narrowClassifyKernel<<<blocksFor(np + 1), kBlock, 0, st>>>(A, np, N.count.data(), first, N.list.data(),
                                                             N.list_count.data(), classes ? N.cls.data() : nullptr,
                                                             classes ? N.class_count.data() : nullptr);
  DVI_CUDA_LAUNCH("narrowClassifyKernel");
  if (classes) closedFormsInClassOrder(d, A, np, first);
  // the general kernel's grid: what fits on the device at once, striding over the list (its length is on the device)
  const int64_t general_resident =
      int64_t(d.multiprocessors) * residentBlocks(narrowCountKernel, &N.count_blocks_per_sm);
  const unsigned general_grid = unsigned(std::min<int64_t>(blocksFor(np), general_resident));
  narrowCountKernel<<<general_grid, kBlock, 0, st>>>(A, N.list.data(), N.list_count.data(), classes,
                                                     N.list_count.data() + 2, N.count.data(), first, N.deferred.data(),
                                                     N.deep.data(), N.deep_count.data(), int32_t(deep_cap));
  DVI_CUDA_LAUNCH("narrowCountKernel");
  // A fixed grid (the deep count stays on the device): up to 4 blocks of 128 threads per multiprocessor.
  narrowDeepKernel<<<unsigned(std::min<int64_t>(blocksFor(deep_cap * kDeepLanes, 128), 4 * d.multiprocessors)), 128, 0,
                     st>>>(A, N.deferred.data(), N.deep.data(), N.deep_count.data(), int32_t(deep_cap), N.count.data(),
                           first);
  DVI_CUDA_LAUNCH("narrowDeepKernel");
  if (d.excluded_count > 0 || d.no_contact_count > 0) {
    excludePairsKernel<<<blocksFor(np), kBlock, 0, st>>>(
        d.broad.pair_key_sorted.data(), d.pair_shift, np, d.shapes.shape.data(), d.excluded.data(), d.excluded_count,
        d.no_contact_count > 0 ? d.no_contact.data() : nullptr, d.no_contact_count, N.count.data());
    DVI_CUDA_LAUNCH("excludePairsKernel");
  }
  cubRun(d, "cub::DeviceScan::ExclusiveSum (contacts)", [&](void* t, size_t& b) {
    return cub::DeviceScan::ExclusiveSum(t, b, N.count.data(), N.off.data(), np + 1, st);
  });
  // the contact count, the general pairs' count and the deep pairs' count in one read-back (pinned)
  char* hs = reinterpret_cast<char*>(d.host_scalars);
  DVI_CUDA(cudaMemcpyAsync(hs, N.off.data() + np, sizeof(int64_t), cudaMemcpyDeviceToHost, st));
  DVI_CUDA(cudaMemcpyAsync(hs + 8, N.list_count.data(), sizeof(unsigned long long), cudaMemcpyDeviceToHost, st));
  DVI_CUDA(cudaMemcpyAsync(hs + 16, N.deep_count.data(), sizeof(int32_t), cudaMemcpyDeviceToHost, st));
  DVI_CUDA(cudaStreamSynchronize(st));
  int64_t nc = 0;
  unsigned long long general = 0;
  int32_t deep = 0;
  std::memcpy(&nc, hs, sizeof nc);
  std::memcpy(&general, hs + 8, sizeof general);
  std::memcpy(&deep, hs + 16, sizeof deep);
  N.deep_last = deep;
  N.general_last = int64_t(general);
  d.contacts.resize(size_t(nc));
  if (nc == 0) return;
  DeviceContacts& c = d.contacts;
  ContactOut out{c.shape_a.data(), c.shape_b.data(), c.body_a.data(), c.body_b.data(), c.normal.data(),
                 c.pa.data(),      c.pb.data(),      c.dist.data(),   c.key.data()};
  narrowWriteKernel<<<blocksFor(np), kBlock, 0, st>>>(A, np, N.count.data(), N.off.data(), first, out, N.list.data(),
                                                      N.list_count.data() + 1);
  DVI_CUDA_LAUNCH("narrowWriteKernel");
  const int64_t multi_resident = int64_t(d.multiprocessors) * residentBlocks(narrowMultiKernel, &N.multi_blocks_per_sm);
  const unsigned multi_grid = unsigned(std::min<int64_t>(blocksFor(np), multi_resident));
  narrowMultiKernel<<<multi_grid, kBlock, 0, st>>>(A, N.list.data(), N.list_count.data() + 1, N.list_count.data() + 3,
                                                   N.count.data(), N.off.data(), first, out);
  DVI_CUDA_LAUNCH("narrowMultiKernel");
}

}  // namespace dvi::gpu
