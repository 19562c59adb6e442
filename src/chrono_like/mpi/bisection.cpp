#include "chrono_like/mpi/bisection.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "chrono_like/base/errors.h"

namespace dvi {

namespace {
real& axisOf(Vec3& v, int a) { return a == 0 ? v.x : (a == 1 ? v.y : v.z); }
real axisOf(const Vec3& v, int a) { return a == 0 ? v.x : (a == 1 ? v.y : v.z); }
}  // namespace

Bisection Bisection::build(const std::vector<Vec3>& points, int parts) {
  if (parts < 1) throw InputError("bisection: parts must be >= 1, got " + std::to_string(parts));
  Bisection b;
  b.lo_.resize(size_t(parts));
  b.hi_.resize(size_t(parts));
  std::vector<int32_t> idx(points.size());
  for (size_t i = 0; i < idx.size(); ++i) idx[i] = int32_t(i);
  const real inf = std::numeric_limits<real>::infinity();
  b.split(points, idx, 0, idx.size(), parts, 0, Vec3{-inf, -inf, -inf}, Vec3{inf, inf, inf});
  return b;
}

// Node for points idx[begin, end) in the box [lo, hi] with `parts` parts numbered from first_part.
int Bisection::split(const std::vector<Vec3>& points, std::vector<int32_t>& idx, size_t begin, size_t end, int parts,
                     int first_part, Vec3 lo, Vec3 hi) {
  const int me = int(nodes_.size());
  nodes_.emplace_back();
  if (parts == 1) {
    nodes_[size_t(me)].part = first_part;
    lo_[size_t(first_part)] = lo;
    hi_[size_t(first_part)] = hi;
    return me;
  }
  // The longest axis of the points' extent (x where there are none).
  const real inf = std::numeric_limits<real>::infinity();
  Vec3 pmin{inf, inf, inf}, pmax{-inf, -inf, -inf};
  for (size_t i = begin; i < end; ++i) {
    pmin = vmin(pmin, points[size_t(idx[i])]);
    pmax = vmax(pmax, points[size_t(idx[i])]);
  }
  const Vec3 ext = pmax - pmin;
  const int axis = end > begin ? (ext.x >= ext.y && ext.x >= ext.z ? 0 : (ext.y >= ext.z ? 1 : 2)) : 0;
  // The median: sort along the axis (ties by index, so every process sorts alike).
  std::sort(idx.begin() + long(begin), idx.begin() + long(end), [&](int32_t a, int32_t b) {
    const real xa = axisOf(points[size_t(a)], axis), xb = axisOf(points[size_t(b)], axis);
    return xa < xb || (xa == xb && a < b);
  });
  const int low_parts = parts / 2;
  const size_t n = end - begin, n_low = size_t(uint64_t(n) * uint64_t(low_parts) / uint64_t(parts));
  real cut = 0;
  if (n_low > 0 && n_low < n)
    cut = real(0.5) *
          (axisOf(points[size_t(idx[begin + n_low - 1])], axis) + axisOf(points[size_t(idx[begin + n_low])], axis));
  else if (n > 0)
    cut = n_low == 0 ? axisOf(points[size_t(idx[begin])], axis)
                     : std::nextafter(axisOf(points[size_t(idx[end - 1])], axis), inf);
  // The points strictly below the cut form the low side (owner() asks the same question).
  size_t mid = begin;
  while (mid < end && axisOf(points[size_t(idx[mid])], axis) < cut) ++mid;
  Vec3 lo_hi = hi, hi_lo = lo;
  axisOf(lo_hi, axis) = cut;
  axisOf(hi_lo, axis) = cut;
  const int low = split(points, idx, begin, mid, low_parts, first_part, lo, lo_hi);
  const int high = split(points, idx, mid, end, parts - low_parts, first_part + low_parts, hi_lo, hi);
  Node& node = nodes_[size_t(me)];
  node.axis = axis;
  node.cut = cut;
  node.low = low;
  node.high = high;
  return me;
}

int Bisection::owner(Vec3 p) const {
  if (nodes_.empty()) return 0;
  int n = 0;
  while (nodes_[size_t(n)].part < 0) {
    const Node& node = nodes_[size_t(n)];
    n = axisOf(p, node.axis) < node.cut ? node.low : node.high;
  }
  return nodes_[size_t(n)].part;
}

real Bisection::distance(Vec3 p, int q) const {
  const Vec3 lo = lo_[size_t(q)], hi = hi_[size_t(q)];
  real d2 = 0;
  for (int a = 0; a < 3; ++a) {
    const real x = axisOf(p, a);
    const real out = std::max({axisOf(lo, a) - x, x - axisOf(hi, a), real(0)});
    d2 += out * out;
  }
  return std::sqrt(d2);
}

}  // namespace dvi
