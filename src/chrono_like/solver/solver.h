// CCP solvers (docs/MODEL.md §4). A solver sees only the Schur product y = N x (N = D^T M^-1 D, never formed),
// the friction cones, the right-hand side r and the per-contact block scalings (Chrono::Multicore's
// ChSolverMulticore interface). It does not know how contacts were assembled, so the same solver code
// serves the CPU and GPU problems.
//
//   min 1/2 g^T N g + r^T g   over g in Y = product of cones {(gn, gu, gw): sqrt(gu^2+gw^2) <= mu gn}
//
// Error measure common to every solver: the projected-gradient residual
//   res(g) = || (g - P(g - a (N g + r))) / a ||_2,   a = settings.residual_alpha / p.maxDiagonal()
// i.e. a fixed fraction of the largest diagonal entry of N, so a N is dimensionless and the residual is a
// velocity (m/s) whatever the masses (a fixed a in kg would mean a N ~ 100 for mm grains and ~1e-6 for a
// drum). For a small fraction (default 1e-4) it approaches the norm of the gradient projected on the
// tangent cone of Y at g: the contact velocity error of the contacts that push or stick.
//
// Convergence is judged on the RELATIVE residual res(g) / res(0): the residual divided by the residual of
// the zero impulse, res(0) = || P_Y(-a r) / a || (for the contacts || P_Y(-r) ||: the approach velocity the
// contacts would have with no impulse at all). It is the CCP's analogue of the relative residual
// ||b - A x|| / ||b|| of a linear solve started from x = 0 (Barrett et al., "Templates for the Solution of
// Linear Systems", SIAM 1994, sec. 4.2, stopping criterion 2), so one number means "converged" for mm grains
// at h = 1e-4 s (res(0) ~ g h sqrt(contacts) ~ 1e-3 m/s) and metre boxes at h = 1/60 s (~ 0.2 m/s) alike; it
// costs one reduction over r per solve. res(0) = 0 means g = 0 solves the CCP (every contact separates): the
// stop threshold is then 0, met by the zero start. SolverStats keeps the absolute residual too.
//
// Determinism: every reduction sums fixed blocks of contacts (kReduceBlock) and then the block partials in
// order, so results are bitwise identical for any thread count.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "chrono_like/base/hd.h"
#include "chrono_like/solver/process_group.h"
#include "chrono_like/solver/solver_kernels.h"

namespace dvi {

enum class SolverType { Jacobi, GaussSeidel, APGD, BB };

// Raised when a solver meets a non-finite value (NaN or inf in r, N x or an iterate): the step stops with
// this error instead of propagating NaN into the bodies.
struct SolverError : std::runtime_error {
  using std::runtime_error::runtime_error;
};
const char* solverName(SolverType t);
bool parseSolver(const std::string& s, SolverType& out);

// How Jacobi and Gauss-Seidel scale a block's gradient.
//  Scalar:     g_k <- P(g_k - w eta_k (N g + r)_k), eta_k = 1 / (Gershgorin bound of N_kk). One scalar per
//              contact, so the fixed points are exactly the CCP's solutions (default).
//  Inverse3x3: g_k <- P(g_k - w N_kk^-1 (N g + r)_k), the Chrono-style block Jacobi. The Euclidean
//              projection of an N_kk^-1-scaled step has other fixed points than the CCP wherever a contact
//              slides (on the cone surface) or separates with a tangential pull, and it is not a descent
//              step: on random frictional scenes (tests) both Jacobi and Gauss-Seidel diverge with it. Use
//              it only for frictionless or sticking contacts; kept for comparison with Chrono.
enum class BlockScaling { Scalar, Inverse3x3 };

// Storage of APGD's iterates and their Schur products (the 7 vectors of its loop, the bulk of each
// iteration's memory traffic). Arithmetic and reductions are in real either way. Float storage rounds every
// stored iterate and Schur product to float: the GPU keeps float vectors (half the traffic); the CPU rounds
// its real vectors in place, the same values, so CI tests the GPU's float arithmetic. The residual then
// carries float rounding (its 2-norm over the contacts stays near 1e-7 |N g| sqrt(3 contacts)): ask for
// Real where a tolerance below that matters. Jacobi, Gauss-Seidel and BB always store real.
enum class VectorStorage {
  Auto,  // Float on the GPU backend, Real on the CPU backend
  Real,
  Float,
};

// APGD: which of the next trial's steps the test pass computes ahead (kern::ApgdSpeculation). The iterates are
// bitwise the same under each; only the work differs. A used speculation saves the next trial's step pass (a
// read of the iterates and their Schur buffers, and on the GPU a grid-wide barrier); each speculated outcome
// costs a write of the iterate in every trial. About 1 trial in 10 is rejected (backtracking) in the sphere
// piles of bench/, and about one accepted trial in 50 restarts the momentum (no speculation then).
enum class ApgdSpeculation {
  None,
  Accepted,  // the accepted outcome's step (a rejected trial then runs its step pass again)
  Both,      // the accepted and the rejected outcome's (one more iterate buffer than Accepted)
  Auto,      // Accepted (H100, sphere piles of 10k-1M: Both was 4-5% slower than Accepted, its two
             // projections a block on the test pass's path costing more than the rejected trials' steps)
};

// The defaults, chosen by measurement (docs/ARCHITECTURE.md, Solve stage): the tolerance on the relative
// residual, and the iteration cap that bounds the cost of a solve that does not reach it. With the floor of 50
// iterations below, 0.15 costs a sphere pile what the fixed 50 APGD iterations did (0.1 cost 7-17% more on the
// impact steps of a 100k pile: 50 iterations reach 0.07-0.13 there), and the stiff stacks that fell at 50
// iterations take up to a few hundred iterations on their first steps to reach it, and then hold.
constexpr real kDefaultTolerance = real(0.15);
constexpr int kDefaultMaxIterations = 1000;
// The tolerance stop comes no sooner than the old fixed count: a tolerance of 0.1 alone stopped some impacts,
// joints and cylinder stacks before 50 iterations with deeper penetrations than the fixed 50 gave (tests).
constexpr int kDefaultMinIterations = 50;

// The solver part of the System's configuration (system.h: SystemConfig::solver), and what every solver
// algorithm reads. ContactProblem reads recovery_rel and min_bounce_speed (contact_problem.h).
struct SolverSettings {
  SolverType type = SolverType::APGD;  // the algorithm; default APGD
  // Start each contact's impulse from the last step's impulse of the contact with the same persistent key (and
  // the constraint rows' from theirs). Default true.
  bool warm_start = true;
  // [1/s] largest speed at which a penetration is pushed out: recovery_rel x the contact's size per second (the
  // right-hand side's max(dist/h, -v_rec), contact_problem.h). Default 10.
  real recovery_rel = real(10);
  // [m/s] restitution acts only on impacts approaching faster than this (jacobian.h: contactNormalBias). Default
  // 0.2, Bullet's btContactSolverInfo::m_restitutionVelocityThreshold (Chrono's min_bounce_speed is 0.15); the
  // drop-in world copies its world's value. Only read where some body has restitution > 0.
  real min_bounce_speed = real(0.2);
  // A solve stops at the first iterate whose relative residual (above) is <= tolerance, or after
  // max_iterations. tolerance 0 runs all max_iterations (the fixed count of `--iterations N`); the result is
  // still judged against kDefaultTolerance (SolverStats::converged).
  int max_iterations = kDefaultMaxIterations;  // [iterations] default kDefaultMaxIterations (1000)
  real tolerance = kDefaultTolerance;          // [1, relative residual] default kDefaultTolerance (0.15)
  int min_iterations = kDefaultMinIterations;  // the tolerance stops no sooner (unless the residual is 0); 50
  // Jacobi relaxation. With Scalar scaling the step is omega / (Gershgorin row bound of the whole N), so
  // any omega in (0, 1] decreases the objective at every iteration (omega < 2 converges); with Inverse3x3
  // Chrono's 0.3 is the usual choice.
  real jacobi_omega = real(1.0);
  real gs_omega = real(1.0);  // Gauss-Seidel relaxation
  // Gauss-Seidel with a tolerance: a solve that reaches max_iterations above it goes on with APGD from where it
  // stopped, to the tolerance or at most this many more iterations (0: it stops there). Gauss-Seidel converges
  // slowly along the problem's ill-conditioned directions (long lever arms, mass ratios); APGD's rate depends on the
  // square root of the condition number instead (Nesterov 1983; Mazhar et al., ACM TOG 34 (2015)).
  int gs_apgd_finish = 0;
  // Gauss-Seidel: the relative residual the constraint-row blocks (joints) must reach as well, each part measured
  // against its own res(0) (0: none beyond `tolerance`). A joint's rows are equalities whose unsolved part the next
  // step sees as position error; contacts at rest are bounded by the ground, and stop at `tolerance`.
  real gs_row_tolerance = 0;
  // APGD on the CPU: a solve that met its stop goes on where some constraint row's velocity error (the projected
  // residual of the row alone, per unit of its Jacobian's linear part, else its angular part) times the step is above
  // row_stop [m, or rad for an angular row] (0: no such check): once more, warm from where it stopped, to the relative
  // tolerance row_stop_tolerance, for at most row_stop_iterations (System::solveApgdRowStop). The relative residual
  // is the whole problem's: a joint with a long lever arm (badly conditioned rows), or rows next to a large pull that
  // dominates res(0), can hold its share of it as millimetres of drift per step while the rest is far below the
  // tolerance.
  real row_stop = 0;
  real row_stop_tolerance = real(0.003);
  // Rows that fight each other or a contact (a ragdoll's limits on the ground) may never reach it: 200 held
  // ConstraintDemo and Dof6Spring2Setup as an unbounded run did, 100 did not hold the pulled chain (one run each).
  int row_stop_iterations = 200;
  real residual_alpha = real(1e-4);                   // a in the residual, as a fraction of 1 / max diag(N) (see above)
  bool record_history = false;                        // keep the residual of every iteration
  BlockScaling block_scaling = BlockScaling::Scalar;  // Jacobi and Gauss-Seidel
  VectorStorage storage = VectorStorage::Auto;        // APGD (see VectorStorage)
  ApgdSpeculation apgd_speculation = ApgdSpeculation::Auto;
};

// The storage a backend uses: Auto resolved to the backend's default.
inline bool floatStorage(const SolverSettings& s, bool gpu_backend) {
  return s.storage == VectorStorage::Float || (s.storage == VectorStorage::Auto && gpu_backend);
}

struct SolverStats {
  int iterations = 0;
  int trials = 0;              // APGD: steps tested (iterations plus backtracks)
  int speculated = 0;          // APGD: trials whose step the previous trial's test pass had computed (apgd_speculation)
  real residual = 0;           // absolute residual of the result (m/s for contacts)
  real residual_scale = 0;     // res(0), the residual of the zero impulse (the relative residual's scale)
  real relative_residual = 0;  // residual / residual_scale (0 when both are 0; kHugeResidual when only the scale is)
  bool converged = true;       // relative_residual <= tolerance (kDefaultTolerance when the tolerance is 0)
  std::vector<real> history;   // when record_history: [0] the projected warm start's residual, [i] after
                               // iteration i (iterations + 1 entries)
};

// Contacts per block of every deterministic reduction (3 reals each).
constexpr int kReduceBlock = 1024;
// Problems with fewer contacts run serially (no OpenMP parallel region: the barriers dominate small
// problems). Results are bitwise identical either way.
constexpr int64_t kSerialContacts = 2048;

// The operator interface a solver works on. Vectors are plain arrays of size() reals, laid out in blocks
// of 3: first the contacts (normal, tangent u, tangent w; projected onto their friction cone), then the
// blocks of generic constraint rows (constraint_row.h; each row projected onto its box [lo, hi]). See
// solver_kernels.h.
class CcpProblem {
 public:
  virtual ~CcpProblem() = default;
  virtual int size() const = 0;                          // 3 x blocks
  virtual BlockSet blockSet() const = 0;                 // how each block is projected
  virtual const real* rhs() const = 0;                   // r
  virtual void schur(const real* x, real* y) const = 0;  // y = N x
  virtual int threads() const { return 1; }
  // Scalar step eta_k of every block (size() / 3): 1 / (Gershgorin bound of the diagonal block N_kk).
  // APGD and BB use diag(eta_k I3) as their (cone-preserving) diagonal preconditioner.
  virtual const real* blockSteps() const = 0;
  // Scalar Jacobi step of every block (size() / 3): 1 / (an upper bound of the largest absolute row sum
  // of N over the rows of block k, coupling to every other block included), so that the spectral
  // radius of diag(step) N is <= 1 and the Jacobi update is a descent step. The default (blockSteps())
  // ignores the coupling and is only safe for problems whose blocks do not share bodies.
  virtual const real* jacobiSteps() const { return blockSteps(); }
  // N_kk^-1 of every block, 6 reals each (symmetric [00, 11, 22, 01, 02, 12]).
  virtual const real* blockInverses() const = 0;
  // Largest diagonal entry of N (scales the residual's alpha).
  virtual real maxDiagonal() const = 0;
  // The processes that solve this problem together (process_group.h), each its own blocks; null: this process
  // alone. The CPU solvers then sum every reduction over them and take the largest diagonal of all.
  virtual const ProcessGroup* processGroup() const { return nullptr; }

  void project(real* x) const;                           // x <- P_Y(x)
  void applyBlockInverse(const real* x, real* y) const;  // y = B^-1 x, B = block diagonal of N
};

// relative_residual where the scale is 0 but the residual is not (never met: see the scale above).
constexpr real kHugeResidual = real(1e30);

// The tolerance a solve's result is judged against: s.tolerance, or kDefaultTolerance for a fixed count.
inline real judgedTolerance(const SolverSettings& s) { return s.tolerance > 0 ? s.tolerance : kDefaultTolerance; }

// Fills relative_residual and converged from residual and residual_scale (every solver, CPU and GPU).
inline void finishStats(SolverStats& st, const SolverSettings& s) {
  st.relative_residual =
      st.residual_scale > 0 ? st.residual / st.residual_scale : (st.residual > 0 ? kHugeResidual : real(0));
  st.converged = st.relative_residual <= judgedTolerance(s);
}

// The tolerance stop of every solver (and ApgdControl on the GPU): residual res at or below the threshold after
// at least min_iterations iterations, or an exact solution.
DVI_HD bool reachedStop(real res, real threshold, int iterations, int min_iterations) {
  return res <= threshold && (iterations >= min_iterations || res == real(0));
}

// The absolute stop threshold of a solve: tolerance x res(0).
inline real stopThreshold(const SolverSettings& s, real scale) {
  return s.tolerance > 0 ? s.tolerance * scale : real(0);
}

// The alpha the residual uses for this problem: s.residual_alpha / p.maxDiagonal().
real residualAlpha(const CcpProblem& p, const SolverSettings& s);

// Projected gradient residual, shared by every solver and the tests. scratch is resized as needed.
real ccpResidual(const CcpProblem& p, const real* gamma, real alpha, std::vector<real>& scratch);
// res(0), the residual of the zero impulse (the scale of the relative residual).
real ccpResidualScale(const CcpProblem& p, real alpha);

// Each solver improves gamma in place (it arrives warm-started). The warm start w is projected and then
// scaled along its ray to s w, s = argmin_{s >= 0} f(s w) = max(0, -r^T w / w^T N w) (no extra Schur
// product), so the start is never worse than both the warm start and zero: a warm start from a previous
// step's impulses on changed contact geometry cannot inject energy. APGD and BB work in the metric of
// the diagonal preconditioner diag(eta_k I3) (cone-preserving: eta_k is one scalar per contact), so
// contacts whose N entries differ by many orders of magnitude (mm grains, long lever arms) all progress.
// On a NaN or inf they throw SolverError. Scratch vectors
// live in a per-thread workspace that keeps its capacity between solves, so iterations never allocate.
SolverStats solveJacobi(const CcpProblem& p, real* gamma, const SolverSettings& s);
SolverStats solveApgd(const CcpProblem& p, real* gamma, const SolverSettings& s);
SolverStats solveBB(const CcpProblem& p, real* gamma, const SolverSettings& s);

namespace detail {
// Deterministic reduction of M sums over nc contacts: body(k, acc) adds contact k's terms to acc[0..M);
// each fixed block of kReduceBlock contacts is summed in order, then the block partials in order, so the
// result does not depend on the thread count. part is scratch (grown as needed, never shrunk).
template <int M, class Body>
void blockReduce(int64_t nc, int threads, std::vector<double>& part, double* out, Body body) {
  const int64_t nblk = (nc + kReduceBlock - 1) / kReduceBlock;
  if (int64_t(part.size()) < nblk * M) part.resize(size_t(nblk * M));
  double* pp = part.data();
  auto block = [&](int64_t bl) {
    double acc[M];
    for (int m = 0; m < M; ++m) acc[m] = 0;
    const int64_t k1 = (bl + 1) * kReduceBlock < nc ? (bl + 1) * kReduceBlock : nc;
    for (int64_t k = bl * kReduceBlock; k < k1; ++k) {
      double c[M];  // per-contact terms first, so acc stays in registers across the stores of body
      for (int m = 0; m < M; ++m) c[m] = 0;
      body(k, c);
      for (int m = 0; m < M; ++m) acc[m] += c[m];
    }
    for (int m = 0; m < M; ++m) pp[bl * M + m] = acc[m];
  };
  // One thread: a plain loop. An OpenMP region costs a GOMP_parallel call even under if (false) (base/parallel_for.h),
  // and the solver enters this once or more per iteration.
  if (threads > 1) {
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int64_t bl = 0; bl < nblk; ++bl) block(bl);
  } else {
    for (int64_t bl = 0; bl < nblk; ++bl) block(bl);
  }
  for (int m = 0; m < M; ++m) out[m] = 0;
  for (int64_t bl = 0; bl < nblk; ++bl)
    for (int m = 0; m < M; ++m) out[m] += pp[bl * M + m];
}
}  // namespace detail

// Projected Gauss-Seidel needs row access, which only the contact problem provides; see contact_problem.h.

}  // namespace dvi
