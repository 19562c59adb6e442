// Binned broad phase on the CPU (OpenMP). See broadphase.h for the rules (bin edge, large shapes) and
// broadphase_kernels.h for the per-element steps shared with the GPU.
//
// Determinism: every pass either writes to positions fixed by an exclusive scan (count/write, the stable
// radix sort, the run-length encoding) or produces a set of pairs that is unique by construction (the
// owner-bin rule; large shapes tested once per pair) and then sorted by (a, b) with a key-based sort. So
// the output does not depend on the thread count or the schedule.
#include "chrono_like/collision/broadphase.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace dvi {

namespace {

int bitsFor(uint32_t max_value) {
  int b = 0;
  while (b < 32 && (uint64_t(1) << b) <= uint64_t(max_value)) ++b;
  return b;
}

// Grid dimensions for an edge; returns the total bin count as a double (may exceed any integer range).
double gridDims(const Vec3& ext, double edge, double dims[3]) {
  const double e[3] = {double(ext.x), double(ext.y), double(ext.z)};
  double total = 1;
  for (int d = 0; d < 3; ++d) {
    dims[d] = std::max(1.0, std::ceil(e[d] / edge));
    total *= dims[d];
  }
  return total;
}

// Orders one shape's pairs by b (a handful: insertion sort; a big shape's many: std::sort).
void sortByB(ShapePair* s, int32_t m) {
  if (m > 32) {
    std::sort(s, s + m, [](const ShapePair& x, const ShapePair& y) { return x.b < y.b; });
    return;
  }
  for (int32_t k = 1; k < m; ++k) {
    const ShapePair x = s[k];
    int32_t q = k - 1;
    while (q >= 0 && s[q].b > x.b) {
      s[q + 1] = s[q];
      --q;
    }
    s[q + 1] = x;
  }
}

// The sorted entries of one build, as testBinnedPairs reads them.
struct BinRun {
  const uint32_t* bin;      // entry_bin_, sorted
  const int32_t* shape;     // sorted_shape_
  const uint8_t* mask;      // sorted_mask_
  const int32_t* next_mov;  // next_movable_
  int32_t n;
};

// Stage 1 for an immovable shape at sorted position q0 (box A): the movable shapes after it in its bin, through the
// next-movable chain, whose boxes overlap A and whose pair this bin owns, into cand; returns their number and adds
// the shapes tested to `tests`.
int32_t movableCandidates(const BinRun& r, int32_t q0, const Aabb& A, const Aabb* box, std::vector<int32_t>& cand,
                          int64_t& tests) {
  const uint32_t bin = r.bin[q0];
  const uint8_t ms = r.mask[q0];
  int32_t w = 0;
  for (int32_t q = q0 + 1; q < r.n && r.bin[q] == bin; ++q) {
    q = r.next_mov[q];
    if (q >= r.n || r.bin[q] != bin) break;
    if (cand.size() <= size_t(w)) cand.resize(size_t(w) + 16);
    const int32_t b = r.shape[q];
    cand[size_t(w)] = b;
    w += binCandidate(A, box[b], ms, r.mask[q]) ? 1 : 0;
    ++tests;
  }
  return w;
}

}  // namespace

void BroadPhaseBins::run(const ShapeArrays& shapes, const BodyArrays& bodies, std::vector<ShapePair>& out_pairs,
                         BroadPhaseStats* stats) {
  if (shapes.aabb.size() < shapes.count()) throw std::invalid_argument("BroadPhaseBins::run: shapes.aabb not computed");
  run(shapes, shapes.aabb.data(), bodies, out_pairs, stats);
}

void BroadPhaseBins::run(const ShapeArrays& shapes, const Aabb* box, const BodyArrays& bodies,
                         std::vector<ShapePair>& out_pairs, BroadPhaseStats* stats) {
  const Pass in{shapes.shape.data(), box, bodies.flags.data(), int32_t(shapes.count()),
                std::max(1, omp_get_max_threads())};
  BroadPhaseStats st;
  real edge = classify(in);
  splitBinnedLarge(in, edge);
  st.large_shapes = int32_t(large_.size());
  Aabb bounds{{0, 0, 0}, {0, 0, 0}};
  const BinGrid grid = makeGrid(in, edge, bounds, st);
  st.bin_edge = edge;
  // large shapes that can touch a binned shape at all (indices into large_)
  large_active_.clear();
  if (!binned_.empty())
    for (int32_t i = 0; i < int32_t(large_.size()); ++i)
      if (aabbOverlap(box[large_[size_t(i)]], bounds)) large_active_.push_back(i);
  const int32_t ne = binned_.empty() ? 0 : writeEntries(in, grid, st);
  const int32_t nchunks = testBinnedPairs(in, ne, st);
  pairLargeShapes(in);
  writeOutput(in, nchunks, out_pairs);
  st.pairs = int64_t(out_pairs.size());
  if (stats) *stats = st;
}

// ---- 1. classify: extents of bounded shapes (-1 marks planes and unbounded / non-finite boxes); the bin edge
//         (0 where no shape is bounded) ----
real BroadPhaseBins::classify(const Pass& in) {
  const int32_t n = in.n;
  extent_.resize(size_t(n));
  real* ext = extent_.data();
  int32_t n_bounded = 0;
#pragma omp parallel for schedule(static) reduction(+ : n_bounded)
  for (int32_t i = 0; i < n; ++i) {
    const bool unb = in.sh[i].type == ShapeType::Plane || aabbUnbounded(in.box[i]);
    ext[i] = unb ? real(-1) : aabbMaxSide(in.box[i]);
    n_bounded += unb ? 0 : 1;
  }
  if (n_bounded == 0) return 0;
  // median of the bounded extents, estimated on a strided sample of at most about kSample of them (exact
  // below that; deterministic), then the mean of all extents <= large_factor x median
  constexpr int32_t kSample = 4096;
  const int32_t stride = std::max<int32_t>(1, n_bounded / kSample);
  extent_sel_.clear();
  for (int32_t i = 0, skip = 0; i < n; ++i)
    if (ext[i] >= real(0)) {
      if (skip == 0) extent_sel_.push_back(ext[i]);
      if (++skip == stride) skip = 0;
    }
  const size_t mid = extent_sel_.size() / 2;
  std::nth_element(extent_sel_.begin(), extent_sel_.begin() + std::ptrdiff_t(mid), extent_sel_.end());
  const real median = extent_sel_[mid];
  const real cut = settings_.large_factor * median;
  // blocked sum (block partials added in order): the same value for any thread count
  constexpr int32_t kBlock = 8192;
  const int32_t nblocks = (n + kBlock - 1) / kBlock;
  block_sum_.assign(size_t(nblocks), 0.0);
  block_cnt_.assign(size_t(nblocks), 0);
#pragma omp parallel for schedule(static)
  for (int32_t k = 0; k < nblocks; ++k) {
    double sum = 0;
    int64_t cnt = 0;
    for (int32_t i = k * kBlock, e = std::min(n, (k + 1) * kBlock); i < e; ++i)
      if (ext[i] >= real(0) && ext[i] <= cut) {
        sum += double(ext[i]);
        ++cnt;
      }
    block_sum_[size_t(k)] = sum;
    block_cnt_[size_t(k)] = cnt;
  }
  double sum = 0;
  int64_t cnt = 0;
  for (int32_t k = 0; k < nblocks; ++k) {
    sum += block_sum_[size_t(k)];
    cnt += block_cnt_[size_t(k)];
  }
  real edge = cnt > 0 ? real(double(settings_.bin_size_factor) * sum / double(cnt)) : real(0);
  if (!(edge > real(0))) return edge;
  // cap the number of bounded shapes treated apart
  const real thr = settings_.large_factor * edge;
  int32_t big = 0;
#pragma omp parallel for schedule(static) reduction(+ : big)
  for (int32_t i = 0; i < n; ++i) big += ext[i] > thr ? 1 : 0;
  const int32_t max_large = std::max<int32_t>(0, settings_.max_large);
  if (big > max_large) {
    extent_sel_.clear();
    for (int32_t i = 0; i < n; ++i)
      if (ext[i] > thr) extent_sel_.push_back(ext[i]);
    std::nth_element(extent_sel_.begin(), extent_sel_.begin() + max_large, extent_sel_.end(),
                     [](real x, real y) { return x > y; });
    edge = extent_sel_[size_t(max_large)] / settings_.large_factor;  // only extents above that stay large
  }
  return edge;
}

// The binned and the large shapes (both lists in increasing shape order).
void BroadPhaseBins::splitBinnedLarge(const Pass& in, real edge) {
  binned_.clear();
  large_.clear();
  const real* ext = extent_.data();
  const real thr = settings_.large_factor * edge;
  const bool have_edge = edge > real(0);
  for (int32_t i = 0; i < in.n; ++i) {
    if (ext[i] < real(0) || (have_edge && ext[i] > thr))
      large_.push_back(i);
    else
      binned_.push_back(i);
  }
}

// ---- 2. grid over the binned shapes: their bounds, and the edge grown until the bins fit max_bins ----
BinGrid BroadPhaseBins::makeGrid(const Pass& in, real& edge, Aabb& bounds, BroadPhaseStats& st) {
  BinGrid grid{{0, 0, 0}, real(1), {1, 1, 1}};
  const int32_t nb = int32_t(binned_.size());
  if (nb == 0) return grid;
  real lx = std::numeric_limits<real>::max(), ly = lx, lz = lx;
  real hx = -lx, hy = -lx, hz = -lx;
  const int32_t* bl = binned_.data();
  const Aabb* box = in.box;
#pragma omp parallel for schedule(static) reduction(min : lx, ly, lz) reduction(max : hx, hy, hz)
  for (int32_t j = 0; j < nb; ++j) {
    const Aabb& b = box[bl[j]];
    lx = std::min(lx, b.lo.x);
    ly = std::min(ly, b.lo.y);
    lz = std::min(lz, b.lo.z);
    hx = std::max(hx, b.hi.x);
    hy = std::max(hy, b.hi.y);
    hz = std::max(hz, b.hi.z);
  }
  bounds = Aabb{{lx, ly, lz}, {hx, hy, hz}};
  const Vec3 span = bounds.hi - bounds.lo;
  if (!(edge > real(0)) || !std::isfinite(double(edge))) {
    // degenerate sizes (all points): about one shape per bin
    const double m = double(maxComponent(span));
    edge = m > 0 ? real(m / std::cbrt(double(nb))) : real(1);
  }
  const double max_bins =
      double(std::max<int64_t>(1, std::min<int64_t>(settings_.max_bins, std::numeric_limits<int32_t>::max())));
  double dims[3];
  double e = double(edge);
  double total = gridDims(span, e, dims);
  while (total > max_bins) {
    e *= std::max(1.0001, std::cbrt(total / max_bins));
    total = gridDims(span, e, dims);
  }
  edge = real(e);
  grid.origin = bounds.lo;
  grid.inv_edge = real(1) / edge;
  for (int d = 0; d < 3; ++d) grid.n[d] = int32_t(dims[d]);
  st.bins = int64_t(total);
  for (int d = 0; d < 3; ++d) st.grid[d] = grid.n[d];
  return grid;
}

// ---- 3.-5. the (bin, shape) entries of the binned shapes, sorted by bin; returns their number ----
int32_t BroadPhaseBins::writeEntries(const Pass& in, const BinGrid& grid, BroadPhaseStats& st) {
  const int32_t nb = int32_t(binned_.size());
  const int32_t* bl = binned_.data();
  const Aabb* box = in.box;
  // 3. count -> exclusive scan -> write (bin, shape) entries, in increasing shape order
  counts_.resize(size_t(nb));
  offsets_.resize(size_t(nb) + 1);
  int32_t* cnt = counts_.data();
#pragma omp parallel for schedule(static)
  for (int32_t j = 0; j < nb; ++j) cnt[j] = aabbBinCount(grid, box[bl[j]]);
  int64_t acc = 0;
  for (int32_t j = 0; j < nb; ++j) {
    offsets_[size_t(j)] = int32_t(acc);
    acc += cnt[j];
    if (acc > std::numeric_limits<int32_t>::max())
      throw std::length_error("BroadPhaseBins: more than 2^31 bin entries");
  }
  offsets_[size_t(nb)] = int32_t(acc);
  const int32_t ne = int32_t(acc);
  st.bin_entries = ne;
  entry_bin_.resize(size_t(ne));
  entry_shape_.resize(size_t(ne));
  entry_mask_.resize(size_t(ne));
  {
    uint32_t* eb = entry_bin_.data();
    int32_t* es = entry_shape_.data();
    uint8_t* em = entry_mask_.data();
    const int32_t* off = offsets_.data();
    const Shape* sh = in.sh;
    const uint8_t* flags = in.flags;
#pragma omp parallel for schedule(static)
    for (int32_t j = 0; j < nb; ++j) {
      const int32_t w = aabbWriteBins(grid, box[bl[j]], bl[j], eb + off[j], es + off[j], em + off[j]);
      if (flags[sh[bl[j]].body] & (kBodyFixed | kBodyKinematic))
        for (int32_t k = 0; k < w; ++k) em[off[j] + k] |= kMaskImmovable;
    }
  }

  // 4. stable radix sort by bin: entry_bin_ sorted, entry_perm_[sorted position] = written entry. Stability
  //    keeps each bin's shapes in increasing order.
  sortEntriesByBin(uint32_t(st.bins - 1));

  // 5. bin runs: the shape at each sorted position, the sorted position of each written entry (so a shape finds
  //    its place in each of its bins), and the number of occupied bins (run heads)
  sorted_shape_.resize(size_t(ne));
  sorted_mask_.resize(size_t(ne));
  entry_pos_.resize(size_t(ne));
  const uint32_t* eb = entry_bin_.data();
  const int32_t* perm = entry_perm_.data();
  const int32_t* es = entry_shape_.data();
  const uint8_t* em = entry_mask_.data();
  int32_t* ss = sorted_shape_.data();
  uint8_t* sm = sorted_mask_.data();
  int32_t* pos = entry_pos_.data();
  int64_t heads = 0;
#pragma omp parallel for schedule(static) reduction(+ : heads)
  for (int32_t q = 0; q < ne; ++q) {
    const int32_t e = perm[q];
    ss[q] = es[e];
    sm[q] = em[e];
    pos[e] = q;
    heads += (q == 0 || eb[q] != eb[q - 1]) ? 1 : 0;
  }
  st.occupied_bins = heads;
  nextMovableEntries(ne);
  return ne;
}

// ---- 5b. next_movable_[q]: the first sorted position >= q of q's bin run whose shape is movable, or the run's end
//          (an immovable shape walks only these: immovable pairs never collide, and on a static mesh they are most
//          of every bin). Backward scans over blocks of positions, then the runs that cross a block's end are
//          resolved from the next block's first position, last block first. ----
void BroadPhaseBins::nextMovableEntries(int32_t ne) {
  next_movable_.resize(size_t(ne));
  int32_t* nm = next_movable_.data();
  const uint32_t* eb = entry_bin_.data();
  const uint8_t* sm = sorted_mask_.data();
  constexpr int32_t kBlock = 16384, kOpen = -1;
  const int32_t nblocks = (ne + kBlock - 1) / kBlock;
#pragma omp parallel for schedule(static)
  for (int32_t k = 0; k < nblocks; ++k) {
    const int32_t begin = k * kBlock, end = std::min(ne, begin + kBlock);
    for (int32_t q = end - 1; q >= begin; --q) {
      const bool run_ends = q + 1 == ne || eb[q + 1] != eb[q];
      if (!(sm[q] & kMaskImmovable))
        nm[q] = q;
      else if (run_ends)
        nm[q] = q + 1;
      else
        nm[q] = q + 1 == end ? kOpen : nm[q + 1];
    }
  }
  for (int32_t k = nblocks - 2; k >= 0; --k) {
    const int32_t end = (k + 1) * kBlock;
    for (int32_t q = end - 1; q >= k * kBlock && nm[q] == kOpen; --q) nm[q] = nm[end];
  }
}

// ---- 6. pair tests, in chunks of consecutive binned shapes. Shape s visits each of its bins from its own place
//         in the bin's run and tests the shapes after it (all > s): every pair sharing a bin is tested once per
//         shared bin, and kept only by the bin owning its overlap's min corner. s is also tested against the
//         large shapes: (s, l) pairs with s < l join s's output; (l, s) pairs with l < s belong to l's segment
//         and are only counted here, written in step 8. Returns the number of chunks. ----
int32_t BroadPhaseBins::testBinnedPairs(const Pass& in, int32_t ne, BroadPhaseStats& st) {
  const int32_t nb = int32_t(binned_.size());
  const int32_t na = int32_t(large_active_.size());
  const int nthreads = in.nthreads;
  chunk_begin_.clear();
  {
    const int32_t k0 = std::max<int32_t>(1, std::min<int32_t>(nb / 512, 32 * nthreads));
    for (int32_t c = 0; c <= k0; ++c) chunk_begin_.push_back(int32_t(int64_t(nb) * c / k0));
    for (int32_t l : large_)  // large segments go between chunks
      chunk_begin_.push_back(int32_t(std::lower_bound(binned_.begin(), binned_.end(), l) - binned_.begin()));
    std::sort(chunk_begin_.begin(), chunk_begin_.end());
    chunk_begin_.erase(std::unique(chunk_begin_.begin(), chunk_begin_.end()), chunk_begin_.end());
  }
  const int32_t nchunks = int32_t(chunk_begin_.size()) - 1;
  if (int32_t(chunk_pairs_.size()) < nchunks) chunk_pairs_.resize(size_t(nchunks));
  lh_count_.assign(size_t(std::max(0, nchunks)) * size_t(na), 0);
  const Shape* sh = in.sh;
  const Aabb* box = in.box;
  const uint8_t* flags = in.flags;
  const int32_t* bl = binned_.data();
  const int32_t* cb = chunk_begin_.data();
  const int32_t* off = offsets_.data();
  const uint32_t* eb = entry_bin_.data();
  const int32_t* ss = sorted_shape_.data();
  const int32_t* pos = entry_pos_.data();
  const int32_t* la = large_active_.data();
  const int32_t* lg = large_.data();
  const uint8_t* sm = sorted_mask_.data();
  const int32_t* nm = next_movable_.data();
  if (int(cand_.size()) < nthreads) cand_.resize(size_t(nthreads));
  if (int(lhc_local_.size()) < nthreads) lhc_local_.resize(size_t(nthreads));
  int64_t tests = 0;
#pragma omp parallel num_threads(nthreads) reduction(+ : tests)
  {
    std::vector<int32_t>& cand = cand_[size_t(omp_get_thread_num())];
#pragma omp for schedule(dynamic, 1)
    for (int32_t c = 0; c < nchunks; ++c) {
      std::vector<ShapePair> buf;  // the chunk's buffer, swapped in so no two threads share a vector header
      buf.swap(chunk_pairs_[size_t(c)]);
      buf.clear();
      // (l, s) counts of this chunk, kept in the thread's scratch and stored once (no false sharing)
      std::vector<int64_t>& lhc_v = lhc_local_[size_t(omp_get_thread_num())];
      lhc_v.assign(size_t(na), 0);
      int64_t* lhc = lhc_v.data();
      for (int32_t j = cb[c]; j < cb[c + 1]; ++j) {
        const int32_t s = bl[j];
        const Aabb A = box[s];
        const size_t seg = buf.size();
        for (int32_t e = off[j]; e < off[j + 1]; ++e) {
          const int32_t q0 = pos[e];
          const uint32_t bin = eb[q0];
          const uint8_t ms = sm[q0];
          int32_t w = 0;
          if (ms & kMaskImmovable) {
            w = movableCandidates(BinRun{eb, ss, sm, nm, ne}, q0, A, box, cand, tests);
          } else {
            int32_t q1 = q0 + 1;
            while (q1 < ne && eb[q1] == bin) ++q1;
            if (q1 == q0 + 1) continue;
            tests += q1 - q0 - 1;
            if (cand.size() < size_t(q1 - q0)) cand.resize(size_t(q1 - q0));
            // stage 1, branch free: overlap and ownership; compacts the survivors into cand
            int32_t* cd = cand.data();
            for (int32_t q = q0 + 1; q < q1; ++q) {
              const int32_t b = ss[q];
              cd[w] = b;
              w += binCandidate(A, box[b], ms, sm[q]) ? 1 : 0;
            }
          }
          const int32_t* cd = cand.data();
          // stage 2: the filter (bodies, immovable pairs, groups)
          for (int32_t i = 0; i < w; ++i)
            if (shapePairAllowed(s, cd[i], sh, flags)) buf.push_back(ShapePair{s, cd[i]});
        }
        for (int32_t k = 0; k < na; ++k) {
          const int32_t l = lg[la[k]];
          if (directPairTest(s, l, sh, box, flags)) {
            if (s < l)
              buf.push_back(ShapePair{s, l});
            else
              ++lhc[k];
          }
        }
        sortByB(buf.data() + seg, int32_t(buf.size() - seg));
      }
      std::copy(lhc, lhc + na, lh_count_.data() + size_t(c) * size_t(na));
      chunk_pairs_[size_t(c)].swap(buf);
    }
  }
  st.bin_pair_tests = tests;
  return nchunks;
}

// ---- 7. large shapes against each other (sorted by construction) ----
void BroadPhaseBins::pairLargeShapes(const Pass& in) {
  const int32_t nl = int32_t(large_.size());
  large_large_.clear();
  ll_count_.assign(size_t(nl), 0);
  for (int32_t i = 0; i < nl; ++i)
    for (int32_t j = i + 1; j < nl; ++j)
      if (directPairTest(large_[size_t(i)], large_[size_t(j)], in.sh, in.box, in.flags)) {
        large_large_.push_back(ShapePair{large_[size_t(i)], large_[size_t(j)]});
        ++ll_count_[size_t(i)];
      }
}

// ---- 8. output layout in (a, b) order: chunk segments and large-shape segments by head, then copy ----
void BroadPhaseBins::writeOutput(const Pass& in, int32_t nchunks, std::vector<ShapePair>& out_pairs) {
  const int32_t nb = int32_t(binned_.size());
  const int32_t nl = int32_t(large_.size());
  const int32_t na = int32_t(large_active_.size());
  const int32_t* bl = binned_.data();
  // per large shape: its (l, binned) count; per (chunk, active large): the write cursor
  lh_total_.assign(size_t(nl), 0);
  for (int32_t k = 0; k < na; ++k) {
    int64_t t = 0;
    for (int32_t c = 0; c < nchunks; ++c) t += lh_count_[size_t(c) * size_t(na) + size_t(k)];
    lh_total_[size_t(large_active_[size_t(k)])] = t;
  }
  chunk_off_.resize(size_t(std::max(0, nchunks)));
  large_off_.resize(size_t(nl));
  int64_t total = 0;
  int32_t li = 0;
  auto emitLarge = [&](int32_t upto_binned) {  // large shapes whose index is below binned_[upto_binned]
    while (li < nl && (upto_binned >= nb || large_[size_t(li)] < bl[upto_binned])) {
      large_off_[size_t(li)] = total;
      total += lh_total_[size_t(li)] + ll_count_[size_t(li)];
      ++li;
    }
  };
  for (int32_t c = 0; c < nchunks; ++c) {
    emitLarge(chunk_begin_[size_t(c)]);
    chunk_off_[size_t(c)] = total;
    total += int64_t(chunk_pairs_[size_t(c)].size());
  }
  emitLarge(nb);
  if (total > std::numeric_limits<int32_t>::max()) throw std::length_error("BroadPhaseBins: more than 2^31 pairs");
  out_pairs.resize(size_t(total));
  ShapePair* out = out_pairs.data();

  // write cursors of the (l, s) pairs: segment start + the counts of the earlier chunks
  lh_cursor_.resize(lh_count_.size());
  for (int32_t k = 0; k < na; ++k) {
    int64_t w = large_off_[size_t(large_active_[size_t(k)])];
    for (int32_t c = 0; c < nchunks; ++c) {
      const size_t idx = size_t(c) * size_t(na) + size_t(k);
      lh_cursor_[idx] = w;
      w += lh_count_[idx];
    }
  }
  writeLargeBinnedPairs(in, nchunks, out);
  mergeLargeLargePairs(out);
}

// The (l, s) pairs of step 6 (l < s), written at their cursors, and each chunk's pairs copied into place.
void BroadPhaseBins::writeLargeBinnedPairs(const Pass& in, int32_t nchunks, ShapePair* out) {
  const int32_t na = int32_t(large_active_.size());
  const int32_t* bl = binned_.data();
  const int32_t* cb = chunk_begin_.data();
  const int32_t* la = large_active_.data();
  const int32_t* lg = large_.data();
#pragma omp parallel for schedule(dynamic, 1)
  for (int32_t c = 0; c < nchunks; ++c) {
    const std::vector<ShapePair>& buf = chunk_pairs_[size_t(c)];
    std::copy(buf.begin(), buf.end(), out + chunk_off_[size_t(c)]);
    int64_t* cur = lh_cursor_.data() + size_t(c) * size_t(na);
    const int64_t* lhc = lh_count_.data() + size_t(c) * size_t(na);
    int64_t any = 0;
    for (int32_t k = 0; k < na; ++k) any += lhc[k];
    if (any == 0) continue;
    for (int32_t j = cb[c]; j < cb[c + 1]; ++j) {  // the same tests as step 6, now writing (l, s)
      const int32_t s = bl[j];
      for (int32_t k = 0; k < na; ++k) {
        const int32_t l = lg[la[k]];
        if (l < s && directPairTest(s, l, in.sh, in.box, in.flags)) out[cur[k]++] = ShapePair{l, s};
      }
    }
  }
}

// Large-large pairs after each large segment's (l, s) run, merged into it (two sorted runs).
void BroadPhaseBins::mergeLargeLargePairs(ShapePair* out) {
  size_t p = 0;
  for (int32_t i = 0; i < int32_t(large_.size()); ++i) {
    if (ll_count_[size_t(i)] == 0) continue;
    ShapePair* seg = out + large_off_[size_t(i)];
    const int64_t m1 = lh_total_[size_t(i)];
    std::copy(large_large_.begin() + std::ptrdiff_t(p), large_large_.begin() + std::ptrdiff_t(p) + ll_count_[size_t(i)],
              seg + m1);
    p += size_t(ll_count_[size_t(i)]);
    if (m1 > 0)
      std::inplace_merge(seg, seg + m1, seg + m1 + ll_count_[size_t(i)],
                         [](const ShapePair& x, const ShapePair& y) { return x.b < y.b; });
  }
}

// Stable LSD radix sort of entry_bin_ by bin, producing entry_perm_ (sorted position -> written entry),
// with per-thread histograms over contiguous blocks (the same keys CUB's radix sort gets on the GPU). One
// pass when the bin index fits in 16 bits.
void BroadPhaseBins::sortEntriesByBin(uint32_t max_key) {
  const int64_t ne = int64_t(entry_bin_.size());
  const int bits = bitsFor(max_key);
  entry_perm_.resize(size_t(ne));
  if (ne < 2 || bits == 0) {
    for (int64_t i = 0; i < ne; ++i) entry_perm_[size_t(i)] = int32_t(i);
    return;
  }
  const int passes = (bits + 15) / 16;
  const int digit_bits = (bits + passes - 1) / passes;
  const int64_t radix = int64_t(1) << digit_bits;
  const uint32_t mask = uint32_t(radix - 1);
  const int nthreads = std::max(1, omp_get_max_threads());
  entry_bin_tmp_.resize(size_t(ne));
  entry_perm_tmp_.resize(size_t(ne));
  hist_.resize(size_t(radix) * size_t(nthreads));

  for (int pass = 0; pass < passes; ++pass) {
    const int shift = pass * digit_bits;
    const uint32_t* kin = entry_bin_.data();
    const int32_t* vin = entry_perm_.data();
    uint32_t* kout = entry_bin_tmp_.data();
    int32_t* vout = entry_perm_tmp_.data();
    int64_t* hist = hist_.data();
#pragma omp parallel num_threads(nthreads)
    {
      const int t = omp_get_thread_num();
      const int T = omp_get_num_threads();
      const int64_t b0 = ne * t / T, b1 = ne * (t + 1) / T;
      int64_t* h = hist + size_t(t) * size_t(radix);
      std::fill(h, h + radix, int64_t(0));
      for (int64_t i = b0; i < b1; ++i) ++h[(kin[i] >> shift) & mask];
#pragma omp barrier
#pragma omp single
      {
        // exclusive scan in (digit, thread) order: stable
        int64_t acc = 0;
        for (int64_t d = 0; d < radix; ++d)
          for (int k = 0; k < T; ++k) {
            int64_t& c = hist[size_t(k) * size_t(radix) + size_t(d)];
            const int64_t v = c;
            c = acc;
            acc += v;
          }
      }
      for (int64_t i = b0; i < b1; ++i) {
        const int64_t pos = h[(kin[i] >> shift) & mask]++;
        kout[pos] = kin[i];
        vout[pos] = pass == 0 ? int32_t(i) : vin[i];
      }
    }
    entry_bin_.swap(entry_bin_tmp_);
    entry_perm_.swap(entry_perm_tmp_);
  }
}

void broadPhaseBruteForce(const ShapeArrays& shapes, const BodyArrays& bodies, std::vector<ShapePair>& out_pairs) {
  out_pairs.clear();
  const int32_t n = int32_t(shapes.count());
  for (int32_t i = 0; i < n; ++i)
    for (int32_t j = i + 1; j < n; ++j) {
      const Shape& a = shapes.shape[size_t(i)];
      const Shape& b = shapes.shape[size_t(j)];
      if (aabbOverlap(shapes.aabb[size_t(i)], shapes.aabb[size_t(j)]) &&
          pairAllowed(a, b, bodies.flags[size_t(a.body)], bodies.flags[size_t(b.body)]))
        out_pairs.push_back(ShapePair{i, j});
    }
}

}  // namespace dvi
