// The contact CCP of one step, assembled on the CPU: Jacobian blocks of every contact, the right-hand
// side r = D^T v_free + b, and the matrix-free operators a CcpProblem must provide.
//
// Sign convention: the normal n points from body A to body B; the normal impulse gn >= 0 pushes B along
// +n and A along -n. For contact k with tangents (u, w) = tangentBasis(n):
//   D_k^T v = [n; u; w] . (vB + wB x rB - vA - wA x rA),  rA = pa - xA, rB = pb - xB
//   b_k     = (max(dist/h, -v_rec), 0, 0)   with v_rec = recovery_rel * size (speed relative to body size)
#pragma once

#include <vector>

#include "data.h"
#include "solver.h"

namespace dvi {

struct ContactProblemSettings {
  real dt = real(1e-3);
  real recovery_rel = real(10);  // largest separating speed asked for a penetration: recovery_rel x size per s
  int threads = 1;
};

class ContactProblem final : public CcpProblem {
 public:
  // Reads bodies.{pos, inv_mass, inv_inertia, rot}, contacts.*, and the free velocities (after external
  // forces, before contact impulses). Writes the Jacobian blocks, r and the body -> contact adjacency.
  void build(const BodyArrays& bodies, const ContactArrays& contacts, const Vec3* v_free, const Vec3* w_free,
             const ContactProblemSettings& settings);

  int size() const override;
  const real* rhs() const override;
  void schur(const real* x, real* y) const override;
  void project(real* x) const override;
  void applyBlockInverse(const real* x, real* y) const override;
  int threads() const override;

  // Velocity change of every body from impulses gamma: dv = M^-1 D gamma (adds into dv, dw).
  void applyImpulses(const real* gamma, Vec3* dv, Vec3* dw) const;

  // Projected Gauss-Seidel, the sequential CPU reference solver.
  SolverStats solveGaussSeidel(real* gamma, const SolverSettings& s) const;
};

}  // namespace dvi
