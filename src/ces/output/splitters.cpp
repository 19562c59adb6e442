// Splitter statistics and the mass distribution (splitters.h).
#include "ces/output/splitters.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace dvi {
namespace ces {

const char* binName(int bin) {
  switch (bin) {
    case kBinNonconductor: return "nonconductor";
    case kBinMiddling: return "middling";
    case kBinConductor: return "conductor";
  }
  return "?";
}

namespace {

int binOf(double x, double s1, double s2) { return x < s1 ? kBinNonconductor : x < s2 ? kBinMiddling : kBinConductor; }

std::vector<double> gridPositions(double lo, double hi, int n) {
  std::vector<double> p(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) p[size_t(i)] = lo + (hi - lo) * double(i) / double(n - 1);
  return p;
}

// Adds a collected particle's mass to a row per kind: a composite's metal part as metal, the rest as plastic.
void addMass(std::array<int64_t, kMaterialKinds>& row, const CollectedParticle& p) {
  if (p.kind == MaterialKind::Composite) {
    const int64_t metal = metalFg(p);
    row[size_t(MaterialKind::Metal)] += metal;
    row[size_t(MaterialKind::Plastic)] += p.mass_fg - metal;
  } else {
    row[size_t(p.kind)] += p.mass_fg;
  }
}

double ratio(int64_t a, int64_t b) { return b > 0 ? double(a) / double(b) : 0.0; }

// Grade, recovery and score of a cell from its masses.
void finishCell(SplitterCell& c, const SplitterBasis& basis) {
  const auto& f = c.mass.fg;
  const int M = int(MaterialKind::Metal), P = int(MaterialKind::Plastic);
  std::array<int64_t, kMaterialKinds> fed{};
  int64_t all = 0;
  for (int k = 0; k < kMaterialKinds; ++k) {
    fed[size_t(k)] =
        basis.fed_fg[size_t(k)] > 0 ? basis.fed_fg[size_t(k)] : f[0][size_t(k)] + f[1][size_t(k)] + f[2][size_t(k)];
    all += fed[size_t(k)];
  }
  const int64_t metal = fed[size_t(M)], plastic = fed[size_t(P)];
  c.grade_metal = ratio(f[kBinConductor][M], c.mass.total(kBinConductor));
  c.recovery_metal = ratio(f[kBinConductor][M], metal);
  c.grade_plastic = ratio(f[kBinNonconductor][P], c.mass.total(kBinNonconductor));
  c.recovery_plastic = ratio(f[kBinNonconductor][P], plastic);
  c.middling_fraction = ratio(c.mass.total(kBinMiddling), all);
  c.score = 0.5 * ((c.recovery_metal - ratio(f[kBinConductor][P], plastic)) +
                   (c.recovery_plastic - ratio(f[kBinNonconductor][M], metal)));
  c.meets_targets = c.grade_metal >= basis.target_conductor && c.grade_plastic >= basis.target_nonconductor &&
                    (basis.target_conductor <= 0 || c.mass.total(kBinConductor) > 0) &&
                    (basis.target_nonconductor <= 0 || c.mass.total(kBinNonconductor) > 0);
}

// The best cell (splitters.h): the largest recovery sum among the cells that meet both targets, else the
// cell closest to them.
void pickBest(SplitterTable& t, const SplitterBasis& basis) {
  auto shortfall = [&](const SplitterCell& c) {
    return std::min(c.grade_metal - basis.target_conductor, c.grade_plastic - basis.target_nonconductor);
  };
  auto better = [&](const SplitterCell& a, const SplitterCell& b) {  // a strictly better than b
    if (a.meets_targets != b.meets_targets) return a.meets_targets;
    const double ra = a.recovery_metal + a.recovery_plastic, rb = b.recovery_metal + b.recovery_plastic;
    if (a.meets_targets) return ra > rb;
    const double sa = shortfall(a), sb = shortfall(b);
    return sa > sb || (sa == sb && ra > rb);
  };
  t.best = 0;
  for (size_t k = 1; k < t.cells.size(); ++k)
    if (better(t.cells[k], t.cells[t.best])) t.best = k;
  t.targets_met = !t.cells.empty() && t.cells[t.best].meets_targets;
}

// Every splitter pair s1 <= s2 of the grid, its masses from massOf(i, j) (grid indices), and the best cell.
template <class MassOf>
SplitterTable splitterGrid(double lo, double hi, int n, const SplitterBasis& basis, MassOf massOf) {
  SplitterTable t;
  t.positions = gridPositions(lo, hi, n);
  for (int i = 0; i < n; ++i)
    for (int j = i; j < n; ++j) {
      SplitterCell cell{};
      cell.s1 = t.positions[size_t(i)];
      cell.s2 = t.positions[size_t(j)];
      cell.mass = massOf(i, j, cell.s1, cell.s2);
      finishCell(cell, basis);
      t.cells.push_back(cell);
    }
  pickBest(t, basis);
  return t;
}

}  // namespace

BinMasses binDirect(const std::vector<CollectedParticle>& c, double s1, double s2) {
  BinMasses m;
  for (const CollectedParticle& p : c) addMass(m.fg[size_t(binOf(p.x, s1, s2))], p);
  return m;
}

SplitterCell splitterCell(const std::vector<CollectedParticle>& c, double s1, double s2, const SplitterBasis& basis) {
  SplitterCell cell{};
  cell.s1 = s1;
  cell.s2 = s2;
  cell.mass = binDirect(c, s1, s2);
  finishCell(cell, basis);
  return cell;
}

SplitterTable splittersDirect(const std::vector<CollectedParticle>& c, double lo, double hi, int n,
                              const SplitterBasis& basis) {
  return splitterGrid(lo, hi, n, basis, [&](int, int, double s1, double s2) { return binDirect(c, s1, s2); });
}

SplitterTable splittersCumulative(const std::vector<CollectedParticle>& c, double lo, double hi, int n,
                                  const SplitterBasis& basis) {
  const std::vector<double> positions = gridPositions(lo, hi, n);
  std::vector<const CollectedParticle*> sorted;
  for (const CollectedParticle& p : c) sorted.push_back(&p);
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const CollectedParticle* a, const CollectedParticle* b) { return a->x < b->x; });
  // prefix[k][kind] = mass of the first k particles in x order.
  std::vector<std::array<int64_t, kMaterialKinds>> prefix(sorted.size() + 1);
  for (size_t k = 0; k < sorted.size(); ++k) {
    prefix[k + 1] = prefix[k];
    addMass(prefix[k + 1], *sorted[k]);
  }
  // below[i] = prefix at the first particle with x >= positions[i] (mass with x < s).
  std::vector<std::array<int64_t, kMaterialKinds>> below(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    const double s = positions[size_t(i)];
    const size_t k = size_t(std::lower_bound(sorted.begin(), sorted.end(), s,
                                             [](const CollectedParticle* p, double v) { return p->x < v; }) -
                            sorted.begin());
    below[size_t(i)] = prefix[k];
  }
  const auto& all = prefix.back();
  return splitterGrid(lo, hi, n, basis, [&](int i, int j, double, double) {
    BinMasses m;
    for (int k = 0; k < kMaterialKinds; ++k) {
      m.fg[kBinNonconductor][size_t(k)] = below[size_t(i)][size_t(k)];
      m.fg[kBinMiddling][size_t(k)] = below[size_t(j)][size_t(k)] - below[size_t(i)][size_t(k)];
      m.fg[kBinConductor][size_t(k)] = all[size_t(k)] - below[size_t(j)][size_t(k)];
    }
    return m;
  });
}

SplitterTable splitterAnalysis(const std::vector<CollectedParticle>& c, double lo, double hi, int n,
                               const SplitterBasis& basis) {
  SplitterTable a = splittersDirect(c, lo, hi, n, basis);
  const SplitterTable b = splittersCumulative(c, lo, hi, n, basis);
  if (a.cells.size() != b.cells.size()) throw std::logic_error("splitters: the two methods give different table sizes");
  for (size_t k = 0; k < a.cells.size(); ++k)
    if (!(a.cells[k].mass == b.cells[k].mass))
      throw std::logic_error(
          "splitters: direct binning and cumulative sums differ at s1 = " + std::to_string(a.cells[k].s1 * 1e3) +
          " mm, s2 = " + std::to_string(a.cells[k].s2 * 1e3) + " mm");
  if (a.best != b.best) throw std::logic_error("splitters: the two methods pick different best settings");
  return a;
}

Distribution massDistribution(const std::vector<CollectedParticle>& c, double bin) {
  Distribution d;
  d.bin = bin;
  if (c.empty()) return d;
  double lo = c.front().x, hi = c.front().x;
  for (const CollectedParticle& p : c) lo = std::min(lo, p.x), hi = std::max(hi, p.x);
  d.lo = std::floor(lo / bin) * bin;
  const size_t nb = size_t(std::floor((hi - d.lo) / bin)) + 1;
  d.fg.assign(nb, {0, 0, 0});
  for (const CollectedParticle& p : c) {
    const size_t k = std::min(nb - 1, size_t(std::max(0.0, std::floor((p.x - d.lo) / bin))));
    addMass(d.fg[k], p);
  }
  return d;
}

std::string distributionCsv(const Distribution& d) {
  std::string o = "x_lo_mm,x_hi_mm,metal_kg,plastic_kg,middling_kg\n";
  char buf[160];
  for (size_t k = 0; k < d.fg.size(); ++k) {
    std::snprintf(buf, sizeof buf, "%.6g,%.6g,%.9g,%.9g,%.9g\n", (d.lo + double(k) * d.bin) * 1e3,
                  (d.lo + double(k + 1) * d.bin) * 1e3, double(d.fg[k][0]) * kFemtogram,
                  double(d.fg[k][1]) * kFemtogram, double(d.fg[k][2]) * kFemtogram);
    o += buf;
  }
  return o;
}

std::string splittersCsv(const SplitterTable& t) {
  std::string o =
      "s1_mm,s2_mm,nonconductor_metal_kg,nonconductor_plastic_kg,nonconductor_middling_kg,middling_metal_kg,"
      "middling_plastic_kg,middling_middling_kg,conductor_metal_kg,conductor_plastic_kg,conductor_middling_kg,"
      "grade_metal,recovery_metal,grade_plastic,recovery_plastic,middling_fraction,score,meets_targets\n";
  char buf[512];
  for (const SplitterCell& c : t.cells) {
    const auto& f = c.mass.fg;
    std::snprintf(buf, sizeof buf,
                  "%.6g,%.6g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f,%d\n",
                  c.s1 * 1e3, c.s2 * 1e3, double(f[0][0]) * kFemtogram, double(f[0][1]) * kFemtogram,
                  double(f[0][2]) * kFemtogram, double(f[1][0]) * kFemtogram, double(f[1][1]) * kFemtogram,
                  double(f[1][2]) * kFemtogram, double(f[2][0]) * kFemtogram, double(f[2][1]) * kFemtogram,
                  double(f[2][2]) * kFemtogram, c.grade_metal, c.recovery_metal, c.grade_plastic, c.recovery_plastic,
                  c.middling_fraction, c.score, c.meets_targets ? 1 : 0);
    o += buf;
  }
  return o;
}

std::vector<GradeRecoveryPoint> gradeRecoveryCurve(const SplitterTable& t) {
  // Cells (0, j) have s1 = positions[0]: their conductor product is x' >= positions[j]; cells (i, n-1) have
  // s2 = positions[n-1]: their nonconductor product is x' < positions[i].
  const size_t n = t.positions.size();
  std::vector<GradeRecoveryPoint> g(n);
  auto cellIndex = [n](size_t i, size_t j) { return i * n - i * (i - 1) / 2 + (j - i); };  // i <= j, i major
  for (size_t i = 0; i < n; ++i) {
    const SplitterCell& c = t.cells[cellIndex(0, i)];
    const SplitterCell& d = t.cells[cellIndex(i, n - 1)];
    g[i] = GradeRecoveryPoint{t.positions[i], c.grade_metal, c.recovery_metal, d.grade_plastic, d.recovery_plastic};
  }
  return g;
}

std::string gradeRecoveryCsv(const std::vector<GradeRecoveryPoint>& g) {
  std::string o = "s_mm,conductor_grade,conductor_recovery,nonconductor_grade,nonconductor_recovery\n";
  char buf[200];
  for (const GradeRecoveryPoint& p : g) {
    std::snprintf(buf, sizeof buf, "%.6g,%.6f,%.6f,%.6f,%.6f\n", p.s * 1e3, p.grade_metal, p.recovery_metal,
                  p.grade_plastic, p.recovery_plastic);
    o += buf;
  }
  return o;
}

}  // namespace ces
}  // namespace dvi
