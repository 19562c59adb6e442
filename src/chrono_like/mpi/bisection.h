// Recursive coordinate bisection (Berger & Bokhari, "A partitioning strategy for nonuniform problems on
// multiprocessors", IEEE Trans. Computers 36(5), 1987): the bodies' extent split along its longest axis at the
// median of the body positions, each half again, until there are `parts` boxes. The boxes tile space (the outer
// faces lie at infinity), so every point has exactly one owner. No MPI here: every process builds the same
// bisection from the same points.
#pragma once

#include <cstdint>
#include <vector>

#include "chrono_like/base/math.h"

namespace dvi {

class Bisection {
 public:
  Bisection() = default;
  // The bisection of `points` into `parts` >= 1 boxes; a box of k parts gets k/2 of them on the low side and
  // floor(n k_low / k) of its n points (ties at the cut go to the high side).
  static Bisection build(const std::vector<Vec3>& points, int parts);
  int parts() const { return int(lo_.size()); }
  // The part whose box holds p (p[axis] < cut: the low side).
  int owner(Vec3 p) const;
  // Distance from p to part q's box (0 inside it).
  real distance(Vec3 p, int q) const;
  Vec3 boxLow(int q) const { return lo_[size_t(q)]; }
  Vec3 boxHigh(int q) const { return hi_[size_t(q)]; }

 private:
  struct Node {
    int axis = 0;
    real cut = 0;
    int low = -1, high = -1;  // children (nodes_), or -1 for a leaf
    int part = -1;            // a leaf's part
  };
  int split(const std::vector<Vec3>& points, std::vector<int32_t>& idx, size_t begin, size_t end, int parts,
            int first_part, Vec3 lo, Vec3 hi);
  std::vector<Node> nodes_;
  std::vector<Vec3> lo_, hi_;  // each part's box
};

}  // namespace dvi
