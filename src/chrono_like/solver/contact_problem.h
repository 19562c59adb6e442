// The contact CCP of one step, assembled on the CPU: Jacobian blocks of every contact, the right-hand
// side r = D^T v_free + b, and the matrix-free operators a CcpProblem must provide.
//
// Sign convention: the normal n points from body A to body B; the normal impulse gn >= 0 pushes B along
// +n and A along -n. For contact k with tangents (u, w) = tangentBasis(n):
//   D_k^T v = [n; u; w] . (vB + wB x rB - vA - wA x rA),  rA = pa - xA, rB = pb - xB
//   b_k     = (max(dist/h, -v_rec), 0, 0)   with v_rec = recovery_rel * size (speed relative to body size);
//             on an impact of bodies with restitution, b_k,n = min(that, e v_n-) (jacobian.h: contactNormalBias)
//
// Layout (double; see jacobian.h), per contact: ContactJacobian 104 B (n, u, rA, rB, a, b), r 24 B, mu 8 B,
// eta 8 B, N_kk^-1 48 B, 2 adjacency entries 8 B = 200 B; per body: BodyInverseMass 56 B, BodyDelta 48 B,
// CSR offset 4 B. One Schur product reads per contact about 2 x (104 + 24 + 4) B in the per-body gather
// (pass a) and 104 + 24 B plus two BodyDelta gathers in the per-contact pass (b).
//
// Fixed and kinematic bodies (inverse mass and inertia 0) take no part in the Schur product (their
// velocity change is 0) but their v_free enters r.
//
// Constraint rows (constraint_row.h) follow the contacts as blocks of three rows (the last block padded
// with rows lo = hi = 0 on no body). A row stores its full Jacobian (12 reals): there are few of them
// (joints, drives), so they are not compressed.
//
// Rolling and spinning friction (cone.h: projectRollingCone): a contact with mu_s > 0 or mu_r > 0 gets a rolling
// block of three angular rows, spinning about n and rolling about u and w, with Jacobians
//   D_s = [0; n],  D_u = [0; u],  D_w = [0; w] on B and minus that on A
// (the relative angular velocity wB - wA along n, u, w; Tasora & Anitescu, Meccanica 48 (2013), eq. 10). These
// rolling blocks are the first row blocks (blocks nc .. nc + nroll - 1, in contact order), built here from the
// contacts, and the provider rows follow them; each is projected together with its contact (BlockSet::roll). The
// rows are scaled by the contact's size l (rollingRows), so the solution holds the angular impulses divided by l.
#pragma once

#include <cstdint>
#include <vector>

#include "chrono_like/base/data.h"
#include "chrono_like/solver/constraint_row.h"
#include "chrono_like/solver/jacobian.h"
#include "chrono_like/solver/process_group.h"
#include "chrono_like/solver/row_kernels.h"
#include "chrono_like/solver/solver.h"

namespace dvi {

// How one build of the problem runs this step. The step itself (h: StepContext::dt) and the solver settings
// (recovery_rel, min_bounce_speed) are build()'s own arguments, passed by the System, not copied here.
struct ContactProblemSettings {
  int threads = 0;  // OpenMP threads; 0 = OpenMP's default (omp_get_max_threads()). Problems
                    // under kSerialContacts contacts solve serially (threads() == 1).
  // Every contact is frictionless (mu = 0): assemble the normal rows only, packed three per block
  // (jacobian.h); the solution vector is then in the normal layout (toSolverLayout / fromSolverLayout).
  bool normal_only = false;
  // VectorStorage::Float with APGD: the Jacobians rounded to float (roundJacobian), as the GPU's are.
  bool float_jacobians = false;
  // What only some solvers read, assembled only where wanted: the Jacobi
  // solver's coupling-aware steps (jacobiSteps(): the column norms, row sums and per-body sums behind them), and
  // the blocks' inverses N_kk^-1 (blockInverses(): BlockScaling::Inverse3x3 of Jacobi and Gauss-Seidel). Both
  // default on; System::buildProblem turns off what its solver does not read. Asking a problem built without
  // them throws std::logic_error.
  bool jacobi_steps = true;
  bool block_inverses = true;
  // Gauss-Seidel's exact coordinate steps on each friction cone (gsContactBlock) read the contacts' diagonal
  // blocks N_kk; without them its contact steps are the scalar block steps alone. Default on; System::buildProblem
  // turns it off for the other solvers.
  bool gs_blocks = true;
};

class ContactProblem final : public CcpProblem {
 public:
  // Reads bodies.{pos, inv_mass, inv_inertia, rot, flags, restitution} (and vel, omega where a contact's
  // restitution is > 0), contacts.*, and the free velocities (after external forces, before contact impulses);
  // step: the step's context (its h, StepContext::dt, in the bias dist / h); solver: recovery_rel and
  // min_bounce_speed (SystemConfig::solver). Writes the Jacobian blocks, r and the body -> contact adjacency.
  // rows: constraint rows solved with the contacts (may be null or empty); their impulses follow the
  // contacts' in the solution vector (3 per block, the padding rows last).
  // rolling: 2 per contact, (mu_s, mu_r) in metres, or null (no rolling or spinning friction); a contact with
  // either > 0 gets a rolling block (above), whose impulses come after the contacts' (3 each) and before the rows'.
  void build(const BodyArrays& bodies, const ContactArrays& contacts, const Vec3* v_free, const Vec3* w_free,
             const StepContext& step, const SolverSettings& solver, const ContactProblemSettings& settings,
             const std::vector<ConstraintRow>* rows = nullptr, const real* rolling = nullptr);

  int size() const override;
  const real* rhs() const override;
  // y = D^T (M^-1 (D x)) in two deterministic parallel passes. Uses an internal body buffer: do not call
  // schur, applyImpulses or solveGaussSeidel of one problem from two threads at once.
  void schur(const real* x, real* y) const override;
  // Normal-only: no cone blocks; the contacts' normal blocks are boxes [0, inf) like the rows' boxes.
  BlockSet blockSet() const override {
    return BlockSet{normal_only_ ? 0 : nc_, mu_.data(), lo_.data(), hi_.data(), nroll_, roll_.data(), roll_mu_.data()};
  }
  // Rolling blocks: how many, and contact k's index among them (-1: none). Their impulses lie at
  // x[3 (nc + q) .. 3 (nc + q) + 2] for rolling block q.
  int64_t rollingBlocks() const { return nroll_; }
  int32_t rollingIndex(int64_t k) const {
    return nroll_ > 0 && roll_[size_t(k)] >= 0 ? roll_[size_t(k)] - int32_t(nc_) : -1;
  }
  // The rolling rows are scaled by a length l (the contact's size): x holds the angular impulses divided by l.
  real rollingLength(int32_t q) const { return roll_len_[size_t(q)]; }
  bool normalOnly() const { return normal_only_; }
  // The System's impulse vector (3 per contact, then the rows) to this problem's solution vector (size()
  // reals) and back; the identity unless normalOnly() (then the tangential impulses come back as 0).
  void toSolverLayout(const real* g3, real* x) const;
  void fromSolverLayout(const real* x, real* g3) const;
  EntryLayout layout() const { return EntryLayout{nc_, ncb_, normal_only_}; }
  int threads() const override;
  const real* blockInverses() const override;
  const real* blockSteps() const override { return eta_.data(); }
  const real* jacobiSteps() const override;
  real maxDiagonal() const override { return max_diag_; }
  // The processes sharing this problem (process_group.h; null: none), set before build(): their shared bodies
  // are gathered by every pass (a) and exchanged after it (schur, applyImpulses). The group outlives the problem's
  // use of it.
  void setProcessGroup(const ProcessGroup* group) { group_ = group; }
  const ProcessGroup* processGroup() const override { return group_; }

  // Velocity change of every body from impulses gamma: dv = M^-1 D gamma (adds into dv, dw). Right after
  // solveGaussSeidel(gamma), with gamma as it left it, the velocity changes it kept are used (no gather).
  void applyImpulses(const real* gamma, Vec3* dv, Vec3* dw) const;

  // The largest velocity error of a provider row (the rows after the rolling rows) at impulses x: the row's gradient
  // (N x + r), 0 where its impulse sits at a bound that the gradient pushes against (the residual's projection), per
  // unit of the row's Jacobian (its linear part, or its angular part for a purely angular row): m/s or rad/s. 0
  // without provider rows. y: scratch of size() reals.
  real maxRowVelocityError(const real* x, real* y) const;

  // Projected Gauss-Seidel, the sequential CPU reference solver.
  SolverStats solveGaussSeidel(real* gamma, const SolverSettings& s) const;

  // Read access for tests and the GPU upload.
  const std::vector<ContactJacobian>& jacobians() const { return jac_; }
  const std::vector<BodyInverseMass>& bodyInverseMasses() const { return inv_; }

 private:
  // Pass (a): delta_[i] = M_i^-1 sum over the contacts of body i of D_ki x_k, for the active bodies.
  void gatherBodyDeltas(const real* x) const;
  // The passes of build(): contact blocks, box bounds and row blocks, body -> entry adjacency, Jacobi steps.
  real assembleContacts(const BodyArrays& bodies, const ContactArrays& contacts, const Vec3* v_free, const Vec3* w_free,
                        const ContactBiasInputs& bias_in, bool float_jacobians);
  real assembleBoxesAndRows(const std::vector<ConstraintRow>* rows, int64_t nb, const Vec3* v_free, const Vec3* w_free,
                            real max_diag);
  // The rolling rows of the contacts with rolling or spinning friction (roll_, roll_mu_ filled), then `rows`, in
  // all_rows_; returns &all_rows_.
  const std::vector<ConstraintRow>* rollingRows(const BodyArrays& bodies, const ContactArrays& contacts,
                                                const real* rolling, bool float_jacobians,
                                                const std::vector<ConstraintRow>* rows);
  void buildAdjacency(int64_t nb);
  void computeJacobiSteps(int64_t nb);
  void shareBodySums(std::vector<real>& per_body) const;  // with a group: the shared bodies' sums over processes
  // Gauss-Seidel's block k: its gradient from delta_, and delta_ updated by a change dg of its impulses.
  void gsBlockGradient(int64_t k, real* y) const;
  void gsApplyBlockChange(int64_t k, const real* dg) const;
  // Gauss-Seidel's sweep over the contact blocks where all are plain friction cones under Scalar scaling.
  void gsContactSweep(real* gamma, real w) const;
  // One Gauss-Seidel sweep over every block (Inverse3x3 block scaling where full).
  void gsSweep(real* gamma, real w, bool full) const;
  // Gauss-Seidel's update of contact block k, a plain friction cone under Scalar scaling.
  void gsContactBlock(int64_t k, real* gamma, real w) const;
  // Gauss-Seidel's update of provider row block k, row by row with each row's exact diagonal step.
  void gsRowSweep(int64_t k, real* gamma, real w) const;

  int threads_ = 1;
  const ProcessGroup* group_ = nullptr;
  bool have_jacobi_steps_ = false, have_block_inverses_ = false;  // built (ContactProblemSettings)
  // The impulses delta_ is current for, where Gauss-Seidel left it so (it keeps delta_ = M^-1 D gamma through its
  // sweeps): applyImpulses of those impulses then skips pass (a). Any other use of delta_ clears it.
  mutable const real* gs_deltas_of_ = nullptr;
  int64_t nc_ = 0;   // contacts
  int64_t ncb_ = 0;  // contact blocks: nc_, or ceil(nc_ / 3) when normal_only_
  bool normal_only_ = false;
  int64_t nrb_ = 0;                      // constraint-row blocks (3 rows each), the rolling blocks first
  int64_t nroll_ = 0;                    // rolling blocks (contacts with rolling or spinning friction)
  int64_t nprov_ = 0;                    // provider rows (rows_ after the 3 nroll_ rolling rows, before the padding)
  std::vector<int32_t> roll_;            // per contact: its rolling block (nc + q), or -1 (empty when nroll_ == 0)
  std::vector<real> roll_mu_;            // 2 per rolling block: mu_s / l, mu_r / l (l = roll_len_)
  std::vector<real> roll_len_;           // per rolling block: the length l its rows are scaled by [m]
  std::vector<ConstraintRow> all_rows_;  // the rolling rows, then the provider rows (when nroll_ > 0)
  std::vector<ConstraintRow> rows_;      // 3 per row block (padded)
  std::vector<real> lo_, hi_;            // 3 per box block (normal-only contact blocks, then row blocks)
  real max_diag_ = 1;
  std::vector<ContactJacobian> jac_;      // per contact
  std::vector<real> rhs_;                 // 3 per block
  std::vector<real> mu_;                  // per contact
  std::vector<real> eta_;                 // per block: scalar block step
  std::vector<real> binv_;                // 6 per block: N_kk^-1, symmetric
  std::vector<real> nkk_;                 // 6 per contact: N_kk, symmetric (gs_blocks; else empty)
  std::vector<real> jeta_;                // per block: Jacobi step (coupling-aware Gershgorin bound)
  std::vector<real> colnorm_;             // 6 per block: M^-1 norms of the Jacobian columns (build only)
  std::vector<real> rowsum_;              // 3 per block: absolute row sums of N_kk (build only)
  std::vector<real> bodyq_;               // per body: sum of its contacts' column norms (build only)
  std::vector<BodyInverseMass> inv_;      // per body
  std::vector<int32_t> adj_start_;        // CSR over the active bodies: entries of active body j are
  std::vector<int32_t> adj_;              //   adj_[adj_start_[j] .. adj_start_[j+1]), each 2 k + side for
                                          //   contact k, 2 nc + 2 i + side for constraint row i
  std::vector<int32_t> active_;           // bodies that can move and touch at least one contact
  mutable std::vector<BodyDelta> delta_;  // per body; zero for bodies that are not active
};

}  // namespace dvi
