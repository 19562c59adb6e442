// Results on the collection plane: the mass distribution per material kind (the paper's Fig. 5) and the
// virtual splitters. Splitters s1 <= s2 (positions x' along the plane, from collection.x0) make three bins:
//   nonconductor  x' <  s1      middling  s1 <= x' < s2      conductor  x' >= s2
// For every pair (s1, s2) of `positions` with s1 <= s2 the table holds the mass of each kind in each bin,
// computed two independent ways (cross-checked, exactly, since masses are whole femtograms):
//   * direct binning: every particle assigned to its bin for every pair;
//   * cumulative sums: particles sorted by x', prefix sums of mass per kind, the bins as differences of
//     the prefix sum at s1 and s2 (binary search).
// A composite particle (MaterialKind::Composite) counts in every table as its two parts: its metal part
// (metalFg, machine.h) as metal, the rest as plastic, so grades and recoveries are of the metal and the plastic
// wherever they are, liberated or not.
// Grade and recovery (B. A. Wills, T. Napier-Munn, "Mineral Processing Technology", 7th ed., 2006, §1.7),
// recovery relative to the FED mass of the kind (so material held up on the drum or in the brush, or still in
// flight, counts as not recovered):
//   grade of metal in the conductor bin      G_m = metal_c / (all)_c
//   recovery of metal to the conductor bin   R_m = metal_c / metal_fed   (likewise plastic, nonconductor bin)
//   score = 1/2 [ (R_metal->c - R_plastic->c) + (R_plastic->n - R_metal->n) ]   (mean Newton efficiency, Wills §1.7)
// The best setting maximises R_m + R_p subject to the grade targets G_m >= t_c and G_p >= t_n (an empty product has
// grade 0); the middling bin takes what neither product can accept at its grade. When no setting meets both
// targets, the one closest to them (largest min(G_m - t_c, G_p - t_n)) is taken and targets_met is false.
// Ties go to the first pair in (s1, s2) order.
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

// What recoveries are relative to, and the optimiser's grade targets.
struct SplitterBasis {
  std::array<int64_t, kMaterialKinds> fed_fg{};  // fed mass per kind (0: the collected mass of that kind)
  double target_conductor = 0;                   // metal grade the conductor product must reach
  double target_nonconductor = 0;                // plastic grade the nonconductor product must reach
};

struct SplitterCell {
  double s1, s2;  // m
  BinMasses mass;
  double grade_metal, recovery_metal;      // conductor bin
  double grade_plastic, recovery_plastic;  // nonconductor bin
  double middling_fraction;                // middling bin mass / fed mass
  double score;                            // mean Newton efficiency
  bool meets_targets;
};

struct SplitterTable {
  std::vector<double> positions;    // m, evenly spaced over [lo, hi]
  std::vector<SplitterCell> cells;  // every (i, j) with i <= j, i major
  size_t best = 0;                  // index into cells
  bool targets_met = false;         // the best cell meets both grade targets
};

// Bins of one splitter setting, by direct assignment.
BinMasses binDirect(const std::vector<CollectedParticle>& c, double s1, double s2);

// One setting: its masses (direct binning), grade, recovery and score.
SplitterCell splitterCell(const std::vector<CollectedParticle>& c, double s1, double s2,
                          const SplitterBasis& basis = {});

SplitterTable splittersDirect(const std::vector<CollectedParticle>& c, double lo, double hi, int n,
                              const SplitterBasis& basis = {});
SplitterTable splittersCumulative(const std::vector<CollectedParticle>& c, double lo, double hi, int n,
                                  const SplitterBasis& basis = {});
// Both, compared cell by cell; throws std::logic_error naming the first cell that differs.
SplitterTable splitterAnalysis(const std::vector<CollectedParticle>& c, double lo, double hi, int n,
                               const SplitterBasis& basis = {});

// The grade-recovery curve of each product over the positions of t: the conductor product x' >= s and the
// nonconductor product x' < s, with s over the positions (a product depends on its own splitter alone).
struct GradeRecoveryPoint {
  double s;  // m
  double grade_metal, recovery_metal, grade_plastic, recovery_plastic;
};
std::vector<GradeRecoveryPoint> gradeRecoveryCurve(const SplitterTable& t);
std::string gradeRecoveryCsv(const std::vector<GradeRecoveryPoint>& g);

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
