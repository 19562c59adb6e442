// CCP solvers on the CcpProblem operator interface (docs/MODEL.md §4): the algorithms of solver_algorithms.h
// (shared with the GPU backend) instantiated with OpenMP loops. Every vector operation is a fused loop
// over blocks; reductions go through detail::blockReduce so results are bitwise identical for any thread
// count.
#include "chrono_like/solver/solver.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>

#include "chrono_like/solver/solver_algorithms.h"

namespace dvi {

const char* solverName(SolverType t) {
  switch (t) {
    case SolverType::Jacobi: return "jacobi";
    case SolverType::GaussSeidel: return "gs";
    case SolverType::APGD: return "apgd";
    case SolverType::BB: return "bb";
  }
  return "?";
}

bool parseSolver(const std::string& s0, SolverType& out) {
  std::string s = s0;
  for (char& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  if (s == "jacobi")
    out = SolverType::Jacobi;
  else if (s == "gs" || s == "gauss-seidel" || s == "gaussseidel" || s == "pgs")
    out = SolverType::GaussSeidel;
  else if (s == "apgd" || s == "nesterov")
    out = SolverType::APGD;
  else if (s == "bb" || s == "spg" || s == "barzilai-borwein")
    out = SolverType::BB;
  else
    return false;
  return true;
}

namespace {

// Scratch kept per calling thread; it only grows, so a solve allocates at most on its first call for a
// given size, and iterations never do.
struct Workspace {
  std::vector<real> v[9];
  std::vector<double> part;
  real* get(int i, int64_t n) {
    if (int64_t(v[i].size()) < n) v[i].resize(size_t(n));
    return v[i].data();
  }
};
Workspace& workspace() {
  thread_local Workspace w;
  return w;
}

// Threads of a solve: serial below kSerialContacts (bitwise identical, see solver.h).
int solverThreads(const CcpProblem& p) { return p.size() / 3 < kSerialContacts ? 1 : std::max(1, p.threads()); }

// The OpenMP execution backend of the algorithm templates (solver_algorithms.h): every map is a static
// parallel loop over blocks, every reduction a detail::blockReduce (bitwise identical for any thread count).
// A problem shared by several processes (CcpProblem::processGroup) maps over its own blocks and sums each
// reduction over the processes (one collective per reduction); the block count and the largest diagonal are the
// whole problem's.
class CpuOps {
 public:
  static constexpr bool kDeviceLoop = false;
  explicit CpuOps(const CcpProblem& p)
      : p_(p), T_(solverThreads(p)), nb_(p.size() / 3), ws_(workspace()), group_(p.processGroup()) {
    total_ = nb_;
    max_diag_ = p.maxDiagonal();
    if (group_) {
      double v[1] = {double(nb_)};
      group_->sum(v, 1);
      total_ = int64_t(v[0]);
      // A process without blocks has no diagonal (its problem says 1): the largest of the others', or 1 where no
      // process has any (ContactProblem::maxDiagonal's rule).
      const double d = group_->max(nb_ > 0 ? double(p.maxDiagonal()) : 0.0);
      max_diag_ = d > 0 ? real(d) : real(1);
    }
  }
  int64_t blocks() const { return nb_; }
  int64_t totalBlocks() const { return total_; }
  BlockSet blockSet() const { return p_.blockSet(); }
  const real* rhs() const { return p_.rhs(); }
  const real* blockSteps() const { return p_.blockSteps(); }
  const real* jacobiSteps() const { return p_.jacobiSteps(); }
  const real* blockInverses() const { return p_.blockInverses(); }
  real maxDiagonal() const { return max_diag_; }
  real* vec(int i) { return ws_.get(i, 3 * nb_); }
  void schur(const real* x, real* y) { p_.schur(x, y); }
  template <class F>
  void map(const F& f) {
    const int64_t nb = nb_;
    if (T_ > 1) {  // one thread: a plain loop, no OpenMP region (detail::blockReduce)
#pragma omp parallel for schedule(static) num_threads(T_)
      for (int64_t k = 0; k < nb; ++k) f(k);
    } else {
      for (int64_t k = 0; k < nb; ++k) f(k);
    }
  }
  template <int M, class F>
  void reduce(const F& f, double* out) {
    detail::blockReduce<M>(nb_, T_, ws_.part, out, [&](int64_t k, double* acc) { f(k, acc); });
    if (group_) group_->sum(out, M);
  }
  template <int M, class F>
  void reduceLater(const F& f, double* out) {  // on the host the sum is there at once
    reduce<M>(f, out);
  }
  void fetch() {}
  void copy(const real* src, real* dst) {
    if (src != dst) map(kern::Copy{src, dst});
  }

 private:
  const CcpProblem& p_;
  int T_;
  int64_t nb_;
  Workspace& ws_;
  const ProcessGroup* group_;
  int64_t total_ = 0;
  real max_diag_ = 1;
};

}  // namespace

void CcpProblem::project(real* x) const {
  CpuOps ops(*this);
  ops.map(kern::Project{blockSet(), x});
}

void CcpProblem::applyBlockInverse(const real* x, real* y) const {
  const real* binv = blockInverses();
  CpuOps ops(*this);
  ops.map([=](int64_t k) {
    const real* B = binv + 6 * k;  // symmetric [00, 11, 22, 01, 02, 12]
    const real x0 = x[3 * k], x1 = x[3 * k + 1], x2 = x[3 * k + 2];
    y[3 * k] = B[0] * x0 + B[3] * x1 + B[4] * x2;
    y[3 * k + 1] = B[3] * x0 + B[1] * x1 + B[5] * x2;
    y[3 * k + 2] = B[4] * x0 + B[5] * x1 + B[2] * x2;
  });
}

real residualAlpha(const CcpProblem& p, const SolverSettings& s) {
  const real d = p.maxDiagonal();
  return d > real(0) ? s.residual_alpha / d : s.residual_alpha;
}

real ccpResidual(const CcpProblem& p, const real* gamma, real alpha, std::vector<real>& scratch) {
  const int64_t n = p.size();
  if (n == 0) return 0;
  if (int64_t(scratch.size()) < n) scratch.resize(size_t(n));
  p.schur(gamma, scratch.data());
  CpuOps ops(p);
  return algo::residualGivenNx(ops, gamma, scratch.data(), alpha);
}

real ccpResidualScale(const CcpProblem& p, real alpha) {
  if (p.size() == 0) return 0;
  CpuOps ops(p);
  return algo::residualScale(ops, alpha);
}

SolverStats solveJacobi(const CcpProblem& p, real* gamma, const SolverSettings& s) {
  CpuOps ops(p);
  return algo::jacobi(ops, gamma, s);
}

SolverStats solveApgd(const CcpProblem& p, real* gamma, const SolverSettings& s) {
  CpuOps ops(p);
  return algo::apgd(ops, gamma, s);
}

SolverStats solveBB(const CcpProblem& p, real* gamma, const SolverSettings& s) {
  CpuOps ops(p);
  return algo::bb(ops, gamma, s);
}

}  // namespace dvi
