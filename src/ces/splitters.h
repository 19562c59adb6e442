// Results on the collection plane: the mass distribution per material kind (the paper's Fig. 5) and the
// virtual splitters. Splitters s1 <= s2 (positions x' along the plane, from collection.x0) make three bins:
//   nonconductor  x' <  s1      middling  s1 <= x' < s2      conductor  x' >= s2
// For every pair (s1, s2) of `positions` with s1 <= s2 the table holds the mass of each kind in each bin,
// computed two independent ways (cross-checked, exactly, since masses are whole femtograms):
//   * direct binning: every particle assigned to its bin for every pair;
//   * cumulative sums: particles sorted by x', prefix sums of mass per kind, the bins as differences of
//     the prefix sum at s1 and s2 (binary search).
// Grade and recovery (B. A. Wills, T. Napier-Munn, "Mineral Processing Technology", 7th ed., 2006, §1.7):
//   grade of metal in the conductor bin      G_m = metal_c / (all)_c
//   recovery of metal to the conductor bin   R_m = metal_c / metal_total   (likewise plastic, nonconductor bin)
// The best setting maximises the mean Newton efficiency of the two products,
//   score = 1/2 [ (R_metal->c - R_plastic->c) + (R_plastic->n - R_metal->n) ]   (Wills §1.7, "separation efficiency"),
// ties to the first pair in (s1, s2) order.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "ces/machine.h"

namespace dvi {
namespace ces {

enum Bin : int { kBinNonconductor = 0, kBinMiddling = 1, kBinConductor = 2 };
const char* binName(int bin);  // "nonconductor" | "middling" | "conductor"

// fg[bin][kind]
struct BinMasses {
  std::array<std::array<int64_t, kMaterialKinds>, 3> fg{};
  int64_t total(int bin) const { return fg[size_t(bin)][0] + fg[size_t(bin)][1] + fg[size_t(bin)][2]; }
  bool operator==(const BinMasses& o) const { return fg == o.fg; }
};

struct SplitterCell {
  double s1, s2;  // m
  BinMasses mass;
  double grade_metal, recovery_metal;      // conductor bin
  double grade_plastic, recovery_plastic;  // nonconductor bin
  double score;
};

struct SplitterTable {
  std::vector<double> positions;   // m, evenly spaced over [lo, hi]
  std::vector<SplitterCell> cells; // every (i, j) with i <= j, i major
  size_t best = 0;                 // index into cells
};

// Bins of one splitter setting, by direct assignment.
BinMasses binDirect(const std::vector<CollectedParticle>& c, double s1, double s2);

// One setting: its masses (direct binning), grade, recovery and score.
SplitterCell splitterCell(const std::vector<CollectedParticle>& c, double s1, double s2);

SplitterTable splittersDirect(const std::vector<CollectedParticle>& c, double lo, double hi, int n);
SplitterTable splittersCumulative(const std::vector<CollectedParticle>& c, double lo, double hi, int n);
// Both, compared cell by cell; throws std::logic_error naming the first cell that differs.
SplitterTable splitterAnalysis(const std::vector<CollectedParticle>& c, double lo, double hi, int n);

// Mass per kind in bins of width `bin` over [lo, hi) of x' (fg[k][kind]); particles outside are dropped.
struct Distribution {
  double lo = 0, bin = 0;
  std::vector<std::array<int64_t, kMaterialKinds>> fg;
};
Distribution massDistribution(const std::vector<CollectedParticle>& c, double bin);

std::string distributionCsv(const Distribution& d);
std::string splittersCsv(const SplitterTable& t);

}  // namespace ces
}  // namespace dvi
