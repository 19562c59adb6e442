// CCP solvers (DESIGN §3). A solver sees only the Schur product y = N x (N = D^T M^-1 D, never formed),
// the projection onto the product of friction cones, the right-hand side r and, for Jacobi, the
// inverse of N's 3x3 diagonal blocks (Chrono::Multicore's ChSolverMulticore interface). It does not know
// how contacts were assembled, so the same solver code serves the CPU and GPU problems.
//
//   min 1/2 g^T N g + r^T g   over g in Y = product of cones {(gn, gu, gw): sqrt(gu^2+gw^2) <= mu gn}
//
// Error measure common to every solver: the projected-gradient residual
//   res(g) = || (g - P(g - a (N g + r))) / a ||   with a fixed a (settings.residual_alpha)
#pragma once

#include <string>
#include <vector>

#include "hd.h"

namespace dvi {

enum class SolverType { Jacobi, GaussSeidel, APGD, BB };
const char* solverName(SolverType t);
bool parseSolver(const std::string& s, SolverType& out);

struct SolverSettings {
  int max_iterations = 50;
  real tolerance = real(0);      // stop when the residual falls below it (0: run all iterations)
  real jacobi_omega = real(0.3); // Jacobi over-relaxation with block scaling (Chrono's default 0.3..1)
  real gs_omega = real(1.0);     // Gauss-Seidel relaxation
  real residual_alpha = real(1e-4);  // a in the residual; scaled by the problem (see CcpProblem)
  bool record_history = false;   // keep the residual of every iteration
};

struct SolverStats {
  int iterations = 0;
  real residual = 0;
  std::vector<real> history;  // residual after each iteration when record_history
};

// The operator interface a solver works on. Vectors are plain arrays of size() reals, laid out in blocks
// of 3 per contact (normal, tangent u, tangent w).
class CcpProblem {
 public:
  virtual ~CcpProblem() = default;
  virtual int size() const = 0;
  virtual const real* rhs() const = 0;                   // r
  virtual void schur(const real* x, real* y) const = 0;  // y = N x
  virtual void project(real* x) const = 0;               // x <- P_Y(x)
  virtual void applyBlockInverse(const real* x, real* y) const = 0;  // y = B^-1 x, B = block diag of N
  virtual int threads() const { return 1; }
};

// Projected gradient residual, shared by every solver and the tests.
real ccpResidual(const CcpProblem& p, const real* gamma, real alpha, std::vector<real>& scratch);

// Each solver improves gamma in place (it arrives warm-started).
SolverStats solveJacobi(const CcpProblem& p, real* gamma, const SolverSettings& s);
SolverStats solveApgd(const CcpProblem& p, real* gamma, const SolverSettings& s);
SolverStats solveBB(const CcpProblem& p, real* gamma, const SolverSettings& s);

// Projected Gauss-Seidel needs row access, which only the contact problem provides; see contact_problem.h.

}  // namespace dvi
