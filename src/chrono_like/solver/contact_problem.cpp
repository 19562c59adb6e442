// Assembly of the contact CCP and its matrix-free operators (docs/MODEL.md §3; layout in contact_problem.h and
// jacobian.h). The per-element work is in jacobian.h and cone.h, shared with the CUDA kernels.
#include "chrono_like/solver/contact_problem.h"
#include "chrono_like/base/parallel_for.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "chrono_like/base/errors.h"
#include "chrono_like/solver/cone.h"
#include "chrono_like/solver/row_kernels.h"
#include "chrono_like/solver/solver_kernels.h"

namespace dvi {

// parallelReduce's merge for a maximum (exact, so the result does not depend on the team).
static void maxInto(real& total, const real& part) { total = std::max(total, part); }

namespace {
bool movable(const BodyInverseMass& B) {
  return B.m != 0 || B.I[0] != 0 || B.I[1] != 0 || B.I[2] != 0 || B.I[3] != 0 || B.I[4] != 0 || B.I[5] != 0;
}
}  // namespace

namespace {
const BodyInverseMass kNoBody{0, {0, 0, 0, 0, 0, 0}};

// Gauss-Seidel: contact J's impulses changed by dg; dl += M^-1 D_J dg on its movable bodies.
inline void applyContactChange(const ContactJacobian& J, const real* dg, const BodyInverseMass* inv, BodyDelta* dl) {
  for (int side = 0; side < 2; ++side) {
    const int32_t i = side ? J.b : J.a;
    const BodyInverseMass& M = inv[i];
    if (!movable(M)) continue;
    Vec3 F{0, 0, 0}, Tq{0, 0, 0};
    accumulateContactImpulse(J, side, dg, F, Tq);
    const BodyDelta d = bodyDeltaFromImpulse(M, F, Tq);
    dl[i].v += d.v;
    dl[i].w += d.w;
  }
}
}  // namespace

void ContactProblem::build(const BodyArrays& bodies, const ContactArrays& contacts, const Vec3* v_free,
                           const Vec3* w_free, const StepContext& step, const SolverSettings& solver,
                           const ContactProblemSettings& settings, const std::vector<ConstraintRow>* rows,
                           const real* rolling) {
  threads_ = settings.threads > 0 ? settings.threads : omp_get_max_threads();
  const int T = threads_;
  const int64_t nb = int64_t(bodies.count());
  nc_ = int64_t(contacts.count());
  const int64_t nc = nc_;
  nroll_ = 0;
  roll_.clear();
  roll_mu_.clear();
  if (rolling && !settings.normal_only) {
    for (int64_t k = 0; k < nc; ++k)
      if (rolling[2 * k] > 0 || rolling[2 * k + 1] > 0) ++nroll_;
    if (nroll_ > 0) { rows = rollingRows(bodies, contacts, rolling, settings.float_jacobians, rows); }
  }
  const int64_t nrows = rows ? int64_t(rows->size()) : 0;
  nrb_ = (nrows + 2) / 3;
  nprov_ = nrows - 3 * nroll_;
  normal_only_ = settings.normal_only;
  ncb_ = normal_only_ ? (nc + 2) / 3 : nc;
  const int64_t ncb = ncb_;
  const int64_t nblk = ncb + nrb_;
  jac_.resize(size_t(nc));
  rhs_.resize(size_t(3 * nblk));
  mu_.resize(size_t(nc));
  eta_.resize(size_t(nblk));
  have_jacobi_steps_ = settings.jacobi_steps;
  have_block_inverses_ = settings.block_inverses;
  gs_deltas_of_ = nullptr;
  nkk_.resize(settings.gs_blocks && !normal_only_ ? size_t(6 * nc) : 0);
  // Sized in full either way (the normal-only and row blocks' assembly writes them all; the contacts' skips the
  // unwanted): binv_ feeds blockInverses(), colnorm_ and rowsum_ the Jacobi steps.
  binv_.resize(size_t(6 * nblk));
  jeta_.resize(size_t(nblk));
  colnorm_.resize(size_t(6 * nblk));
  rowsum_.resize(size_t(3 * nblk));
  inv_.resize(size_t(nb));
  delta_.assign(size_t(nb), BodyDelta{{0, 0, 0}, {0, 0, 0}});

  const bool have_flags = bodies.flags.size() == size_t(nb);
  parallelFor(int64_t(nb), T, [&](int64_t i) {
    const bool fixed = have_flags && (bodies.flags[i] & (kBodyFixed | kBodyKinematic));
    inv_[i] = fixed ? kNoBody : makeBodyInverseMass(bodies.inv_mass[i], bodies.inv_inertia[i], bodies.rot[i]);
  });

  const bool have_restitution = bodies.restitution.size() == bodies.count();
  const ContactBiasInputs bias_in{step.dt,
                                  solver.recovery_rel,
                                  solver.min_bounce_speed,
                                  have_restitution ? bodies.restitution.data() : nullptr,
                                  bodies.vel.data(),
                                  bodies.omega.data(),
                                  v_free,
                                  w_free};
  real max_diag = assembleContacts(bodies, contacts, v_free, w_free, bias_in, settings.float_jacobians);
  max_diag = assembleBoxesAndRows(rows, nb, v_free, w_free, max_diag);
  max_diag_ = max_diag > 0 ? max_diag : real(1);
  buildAdjacency(nb);
  if (have_jacobi_steps_) computeJacobiSteps(nb);
  // A rolling pair is projected as one (cone.h): the solvers' fixed points are the CCP's only where the step's
  // scaling is one scalar on the whole pair (the projection is Euclidean), so both blocks take the smaller of their
  // two steps (each is a valid bound, so their minimum is too).
  for (int64_t k = 0; k < nc && nroll_ > 0; ++k) {
    const int32_t p = roll_[size_t(k)];
    if (p < 0) continue;
    eta_[size_t(k)] = eta_[size_t(p)] = std::min(eta_[size_t(k)], eta_[size_t(p)]);
    if (have_jacobi_steps_) jeta_[size_t(k)] = jeta_[size_t(p)] = std::min(jeta_[size_t(k)], jeta_[size_t(p)]);
  }
  // Small problems run serially (solver.h: kSerialContacts); bitwise identical to the parallel path.
  if (nblk < kSerialContacts) threads_ = 1;
}

// Each contact's Jacobian, right-hand side (relative free velocity + bias: jacobian.h contactNormalBias, with
// restitution), diagonal block, its inverse, block step, column norms and row sums (the normal-only blocks are
// assembled in assembleBoxesAndRows). Returns the largest diagonal entry.
real ContactProblem::assembleContacts(const BodyArrays& bodies, const ContactArrays& contacts, const Vec3* v_free,
                                      const Vec3* w_free, const ContactBiasInputs& bias_in, bool float_jacobians) {
  const int T = threads_;
  const int64_t nc = nc_;
  real max_diag = 0;
  auto contact = [&](int64_t k, real& max_diag) {
    const int32_t a = contacts.body_a[k], b = contacts.body_b[k];
    ContactJacobian J =
        makeContactJacobian(contacts.normal[k], contacts.pa[k], contacts.pb[k], bodies.pos[a], bodies.pos[b], a, b);
    if (float_jacobians) J = roundJacobian(J);
    jac_[k] = J;
    mu_[k] = contacts.mu[k];
    if (normal_only_) {  // block data per block of three contacts, below
      rhs_[k] = contactNormalVelocity(J, v_free[a], w_free[a], v_free[b], w_free[b]) +
                contactNormalBias(J, contacts.dist[k], contacts.size[k], bias_in);
      return;
    }
    real* rk = rhs_.data() + 3 * k;
    contactRelativeVelocity(J, v_free[a], w_free[a], v_free[b], w_free[b], rk);
    rk[0] += contactNormalBias(J, contacts.dist[k], contacts.size[k], bias_in);
    real N[6];
    contactDiagonalBlock(J, inv_[a], inv_[b], N);
    if (have_block_inverses_) invertSymmetric3(N, binv_.data() + 6 * k);
    if (!nkk_.empty()) std::copy(N, N + 6, nkk_.data() + 6 * k);
    eta_[k] = blockStepFromDiagonal(N);
    if (have_jacobi_steps_) {
      contactColumnNorms(J, inv_[a], inv_[b], colnorm_.data() + 6 * k);
      blockRowSums(N, rowsum_.data() + 3 * k);  // absolute row sums of N_kk itself
    }
    max_diag = std::max(max_diag, std::max(N[0], std::max(N[1], N[2])));  // max is exact: deterministic
  };
  max_diag = std::max(max_diag, parallelReduce(nc, T, real(0), contact, maxInto));

  return max_diag;
}

// The box bounds of the normal-only contact blocks (then assembled three contacts a block) and of the constraint
// rows, three per block after the contacts. Returns max_diag raised to the blocks' largest diagonal entry.
real ContactProblem::assembleBoxesAndRows(const std::vector<ConstraintRow>* rows, int64_t nb, const Vec3* v_free,
                                          const Vec3* w_free, real max_diag) {
  const int T = threads_;
  const int64_t nc = nc_, ncb = ncb_;
  const int64_t nrows = rows ? int64_t(rows->size()) : 0;
  const int64_t nbox = normal_only_ ? 3 * ncb : 0;  // box entries of the contacts' normal blocks
  lo_.assign(size_t(nbox + 3 * nrb_), real(0));
  hi_.assign(size_t(nbox + 3 * nrb_), real(0));
  if (normal_only_) {  // blocks of three normal rows, each in [0, inf); padding rows in [0, 0]
    auto block = [&](int64_t q, real& max_diag) {
      const int cnt = int(std::min<int64_t>(3, nc - 3 * q));
      for (int j = cnt; j < 3; ++j) rhs_[size_t(3 * q + j)] = 0;
      for (int j = 0; j < cnt; ++j) hi_[size_t(3 * q + j)] = std::numeric_limits<real>::infinity();
      const real d = assembleNormalBlock(jac_.data() + 3 * q, cnt, inv_.data(), binv_.data() + 6 * q, eta_.data() + q,
                                         colnorm_.data() + 6 * q, rowsum_.data() + 3 * q);
      max_diag = std::max(max_diag, d);
    };
    max_diag = std::max(max_diag, parallelReduce(ncb, T, real(0), block, maxInto));
  }

  // Constraint rows, three per block after the contacts; the last block is padded with empty rows.
  rows_.assign(size_t(3 * nrb_), ConstraintRow{});
  for (int64_t i = 0; i < 3 * nrb_; ++i) {
    ConstraintRow& R = rows_[size_t(i)];
    if (i < nrows) {
      R = (*rows)[size_t(i)];
      for (int32_t c : {R.a, R.b})
        if (c < -1 || c >= nb)
          throw InputError("constraint row " + std::to_string(i) + ": body index " + std::to_string(c) +
                           " out of range");
      if (R.a == R.b && R.a >= 0)
        throw InputError("constraint row " + std::to_string(i) + ": both sides are body " + std::to_string(R.a));
      bool finite = std::isfinite(R.bias) && !std::isnan(R.lo) && !std::isnan(R.hi) && R.lo <= R.hi;
      for (int j = 0; j < 6; ++j) finite = finite && std::isfinite(R.Ja[j]) && std::isfinite(R.Jb[j]);
      if (!finite)
        throw InputError("constraint row " + std::to_string(i) + ": non-finite Jacobian or bias, or lo > hi");
      lo_[size_t(nbox + i)] = R.lo;
      hi_[size_t(nbox + i)] = R.hi;
    } else {
      R.lo = R.hi = 0;
    }
  }
  for (int64_t q = 0; q < nrb_; ++q) {
    const int64_t k = ncb + q;
    const real d =
        assembleRowBlock(rows_.data() + 3 * q, inv_.data(), v_free, w_free, rhs_.data() + 3 * k, binv_.data() + 6 * k,
                         eta_.data() + k, colnorm_.data() + 6 * k, rowsum_.data() + 3 * k);
    max_diag = std::max(max_diag, d);
  }

  return max_diag;
}

const std::vector<ConstraintRow>* ContactProblem::rollingRows(const BodyArrays& bodies, const ContactArrays& contacts,
                                                              const real* rolling, bool float_jacobians,
                                                              const std::vector<ConstraintRow>* rows) {
  const int64_t nc = nc_;
  const size_t nprov = rows ? rows->size() : 0;
  roll_.assign(size_t(nc), -1);
  roll_mu_.resize(size_t(2 * nroll_));
  roll_len_.resize(size_t(nroll_));
  all_rows_.resize(size_t(3 * nroll_) + nprov);
  const real inf = std::numeric_limits<real>::infinity();
  int64_t q = 0;
  for (int64_t k = 0; k < nc; ++k) {
    if (!(rolling[2 * k] > 0 || rolling[2 * k + 1] > 0)) continue;
    const int32_t a = contacts.body_a[k], b = contacts.body_b[k];
    // The contact's own (n, u, w): the same tangent as its friction rows (rounded as they are).
    ContactJacobian J =
        makeContactJacobian(contacts.normal[k], contacts.pa[k], contacts.pb[k], bodies.pos[a], bodies.pos[b], a, b);
    if (float_jacobians) J = roundJacobian(J);
    // The rows are scaled by the contact's size l (its smaller shape's radius or half-dimension): the unknowns are
    // the angular impulses divided by l, forces like the contact's own, so the pair's diagonal blocks are of one
    // magnitude (l^2 I^-1 against m^-1 + r^2 I^-1) and sharing the smaller step (build) costs little; the bounds
    // become mu_s / l and mu_r / l.
    const real l = contacts.size[k] > 0 && contacts.size[k] < real(1e29) ? contacts.size[k] : real(1);
    const Vec3 d[3] = {J.n * l, J.u * l, contactW(J) * l};
    for (int j = 0; j < 3; ++j) {
      ConstraintRow& R = all_rows_[size_t(3 * q + j)];
      R = ConstraintRow{};
      R.a = a;
      R.b = b;
      const real da[6] = {0, 0, 0, -d[j].x, -d[j].y, -d[j].z}, db[6] = {0, 0, 0, d[j].x, d[j].y, d[j].z};
      for (int i = 0; i < 6; ++i) R.Ja[i] = da[i], R.Jb[i] = db[i];
      R.lo = -inf;  // bounded with the contact's normal impulse by the pair projection, not by a box
      R.hi = inf;
    }
    roll_[size_t(k)] = int32_t(nc + q);
    roll_mu_[size_t(2 * q)] = rolling[2 * k] / l;
    roll_mu_[size_t(2 * q + 1)] = rolling[2 * k + 1] / l;
    roll_len_[size_t(q)] = l;
    ++q;
  }
  for (size_t i = 0; i < nprov; ++i) all_rows_[size_t(3 * nroll_) + i] = (*rows)[i];
  return &all_rows_;
}

void ContactProblem::buildAdjacency(int64_t nb) {
  const int64_t nc = nc_;
  // Body -> entry adjacency (CSR over the bodies that can move and touch a contact or row); entries
  // 2 k + side for contacts and 2 nc + 2 i + side for rows, listed in increasing order, so the gather in
  // schur() sums in a fixed order.
  std::vector<int32_t> count(size_t(nb) + 1, 0);
  for (int64_t k = 0; k < nc; ++k) {
    const ContactJacobian& J = jac_[k];
    if (movable(inv_[J.a])) ++count[J.a];
    if (movable(inv_[J.b])) ++count[J.b];
  }
  for (const ConstraintRow& R : rows_) {
    if (R.a >= 0 && movable(inv_[R.a])) ++count[R.a];
    if (R.b >= 0 && movable(inv_[R.b])) ++count[R.b];
  }
  active_.clear();
  adj_start_.clear();
  std::vector<int32_t> fill(size_t(nb), 0);
  int32_t total = 0;
  for (int64_t i = 0; i < nb; ++i) {
    // A body shared with other processes is gathered even without a contact here (a zero share, process_group.h).
    if (count[i] == 0 && !(group_ && movable(inv_[i]) && group_->shared(int32_t(i)))) continue;
    active_.push_back(int32_t(i));
    adj_start_.push_back(total);
    fill[i] = total;
    total += count[i];
  }
  adj_start_.push_back(total);
  adj_.resize(size_t(total));
  for (int64_t k = 0; k < nc; ++k) {
    const ContactJacobian& J = jac_[k];
    if (movable(inv_[J.a])) adj_[fill[J.a]++] = int32_t(2 * k);
    if (movable(inv_[J.b])) adj_[fill[J.b]++] = int32_t(2 * k + 1);
  }
  for (int64_t i = 0; i < int64_t(rows_.size()); ++i) {
    const ConstraintRow& R = rows_[size_t(i)];
    if (R.a >= 0 && movable(inv_[R.a])) adj_[fill[R.a]++] = int32_t(2 * nc + 2 * i);
    if (R.b >= 0 && movable(inv_[R.b])) adj_[fill[R.b]++] = int32_t(2 * nc + 2 * i + 1);
  }
}

void ContactProblem::computeJacobiSteps(int64_t nb) {
  const int T = threads_;
  const int64_t nc = nc_, ncb = ncb_;
  // Jacobi steps (solver.h: jacobiSteps): row (k, i) of N has absolute sum <= |row i of N_kk| + sum over
  // the two bodies c of contact k of |D_kic|_{M^-1} (Q_c - q_kc), Q_c = sum over the contacts l of c and
  // j of |D_ljc|_{M^-1}, q_kc contact k's own share (Cauchy-Schwarz in the M_c^-1 inner product for the
  // other contacts' blocks), so t_k = 1 / max_i of that bound gives rho(diag(t) N) <= 1. A contact that
  // shares no body gets the block step eta_k. For a row block (whose rows may act on different bodies)
  // the own share is not subtracted: a larger, still valid bound.
  bodyq_.assign(size_t(nb), real(0));
  const int64_t na = int64_t(active_.size());
  const EntryLayout L = layout();
  parallelFor(int64_t(na), T, [&](int64_t j) {
    real q = 0;
    for (int32_t e = adj_start_[j]; e < adj_start_[j + 1]; ++e) q += entryColumnSum(adj_[e], L, colnorm_.data());
    bodyq_[size_t(active_[j])] = q;
  });
  if (group_) shareBodySums(bodyq_);  // Q_c over every process's contacts of a shared body
  if (normal_only_) {
#pragma omp parallel for schedule(static) num_threads(T)
    for (int64_t q = 0; q < ncb; ++q)
      jeta_[q] = normalBlockJacobiStep(jac_.data() + 3 * q, int(std::min<int64_t>(3, nc - 3 * q)),
                                       colnorm_.data() + 6 * q, rowsum_.data() + 3 * q, bodyq_.data());
  } else {
#pragma omp parallel for schedule(static) num_threads(T)
    for (int64_t k = 0; k < nc; ++k)
      jeta_[k] = contactJacobiStep(colnorm_.data() + 6 * k, rowsum_.data() + 3 * k, bodyq_[size_t(jac_[k].a)],
                                   bodyq_[size_t(jac_[k].b)]);
  }
  for (int64_t q = 0; q < nrb_; ++q)
    jeta_[ncb + q] = rowBlockJacobiStep(rows_.data() + 3 * q, colnorm_.data() + 6 * (ncb + q),
                                        rowsum_.data() + 3 * (ncb + q), bodyq_.data());
}

// A per-body sum over the contacts, completed with the other processes' shares of the shared bodies (through the
// velocity-change exchange, one value per body).
void ContactProblem::shareBodySums(std::vector<real>& per_body) const {
  std::vector<BodyDelta> d(per_body.size(), BodyDelta{{0, 0, 0}, {0, 0, 0}});
  for (size_t i = 0; i < per_body.size(); ++i) d[i].v.x = per_body[i];
  group_->exchangeDeltas(d.data());
  for (size_t i = 0; i < per_body.size(); ++i) per_body[i] = d[i].v.x;
}

int ContactProblem::size() const { return int(3 * (ncb_ + nrb_)); }

void ContactProblem::toSolverLayout(const real* g3, real* x) const {
  const int64_t n = size();
  if (!normal_only_) {
    if (g3 != x) std::copy(g3, g3 + n, x);
    return;
  }
  const kern::ToNormalLayout f{g3, x, nc_, ncb_};
  for (int64_t i = 0; i < n; ++i) f(i);
}

void ContactProblem::fromSolverLayout(const real* x, real* g3) const {
  const int64_t n = 3 * (nc_ + nrb_);
  if (!normal_only_) {
    if (g3 != x) std::copy(x, x + n, g3);
    return;
  }
  const kern::FromNormalLayout f{x, g3, nc_, ncb_};
  for (int64_t i = 0; i < n; ++i) f(i);
}
const real* ContactProblem::rhs() const { return rhs_.data(); }
const real* ContactProblem::blockInverses() const {
  if (!have_block_inverses_) throw std::logic_error("ContactProblem: built without block inverses");
  return binv_.data();
}
const real* ContactProblem::jacobiSteps() const {
  if (!have_jacobi_steps_) throw std::logic_error("ContactProblem: built without Jacobi steps");
  return jeta_.data();
}
int ContactProblem::threads() const { return threads_; }

void ContactProblem::gatherBodyDeltas(const real* x) const {
  gs_deltas_of_ = nullptr;
  const int64_t na = int64_t(active_.size());
  const EntryLayout L = layout();
  parallelFor(int64_t(na), (threads_ > 1) ? threads_ : 1, [&](int64_t j) {
    const int32_t i = active_[j];
    Vec3 F{0, 0, 0}, Tq{0, 0, 0};
    for (int32_t e = adj_start_[j]; e < adj_start_[j + 1]; ++e)
      accumulateEntryImpulse(adj_[e], L, jac_.data(), rows_.data(), x, F, Tq);
    delta_[i] = bodyDeltaFromImpulse(inv_[i], F, Tq);
  });
  if (group_) group_->exchangeDeltas(delta_.data());  // shares summed over the processes
}

void ContactProblem::schur(const real* x, real* y) const {
  gatherBodyDeltas(x);  // pass (a): per body, a gather
  const int64_t nc = nc_;
  const BodyDelta* dl = delta_.data();
  if (normal_only_) {
    parallelFor(int64_t(nc), (threads_ > 1) ? threads_ : 1, [&](int64_t k) {  // pass (b): per contact, the normal row
      const ContactJacobian& J = jac_[k];
      y[k] = contactNormalVelocity(J, dl[J.a].v, dl[J.a].w, dl[J.b].v, dl[J.b].w);
    });
    for (int64_t k = nc; k < 3 * ncb_; ++k) y[k] = 0;  // padding rows
  } else {
    parallelFor(int64_t(nc), (threads_ > 1) ? threads_ : 1, [&](int64_t k) {  // pass (b): per contact
      const ContactJacobian& J = jac_[k];
      const BodyDelta& A = dl[J.a];
      const BodyDelta& B = dl[J.b];
      contactRelativeVelocity(J, A.v, A.w, B.v, B.w, y + 3 * k);
    });
  }
  for (int64_t i = 0; i < int64_t(rows_.size()); ++i) y[3 * ncb_ + i] = rowFromDeltas(rows_[size_t(i)], dl);
}

real ContactProblem::maxRowVelocityError(const real* x, real* y) const {
  if (nprov_ <= 0) return 0;
  schur(x, y);
  real worst = 0;
  for (int64_t i = 3 * nroll_; i < 3 * nroll_ + nprov_; ++i) {
    const ConstraintRow& R = rows_[size_t(i)];
    const int64_t j = 3 * ncb_ + i;
    const real grad = y[j] + rhs_[size_t(j)];
    if ((x[j] <= R.lo && grad > 0) || (x[j] >= R.hi && grad < 0)) continue;  // held at a bound
    real lin = 0, ang = 0;
    for (const real* J : {R.Ja, R.Jb}) {
      lin = std::max(lin, std::sqrt(J[0] * J[0] + J[1] * J[1] + J[2] * J[2]));
      ang = std::max(ang, std::sqrt(J[3] * J[3] + J[4] * J[4] + J[5] * J[5]));
    }
    const real unit = lin > 0 ? lin : ang;
    if (unit > 0) worst = std::max(worst, std::fabs(grad) / unit);
  }
  return worst;
}

void ContactProblem::applyImpulses(const real* gamma, Vec3* dv, Vec3* dw) const {
  if (gamma != gs_deltas_of_ || !gamma) gatherBodyDeltas(gamma);
  const int64_t na = int64_t(active_.size());
  parallelFor(int64_t(na), (threads_ > 1) ? threads_ : 1, [&](int64_t j) {
    const int32_t i = active_[j];
    dv[i] += delta_[i].v;
    dw[i] += delta_[i].w;
  });
}

// Gauss-Seidel's block gradient y = (N gamma + r)_k from the maintained body velocity changes delta_.
void ContactProblem::gsBlockGradient(int64_t k, real* y) const {
  const BodyDelta* dl = delta_.data();
  const int64_t nc = nc_, ncb = ncb_;
  if (k < ncb && !normal_only_) {
    const ContactJacobian& J = jac_[k];
    contactRelativeVelocity(J, dl[J.a].v, dl[J.a].w, dl[J.b].v, dl[J.b].w, y);
  } else if (k < ncb) {  // three normal rows (padding rows: 0)
    for (int j = 0; j < 3; ++j) {
      const int64_t c = 3 * k + j;
      y[j] = c < nc ? contactNormalVelocity(jac_[c], dl[jac_[c].a].v, dl[jac_[c].a].w, dl[jac_[c].b].v, dl[jac_[c].b].w)
                    : real(0);
    }
  } else {
    for (int j = 0; j < 3; ++j) y[j] = rowFromDeltas(rows_[size_t(3 * (k - ncb) + j)], dl);
  }
  for (int j = 0; j < 3; ++j) y[j] += rhs_[3 * k + j];
}

// Gauss-Seidel: block k's impulses changed by dg; delta_ += M^-1 D_k dg on its bodies.
void ContactProblem::gsApplyBlockChange(int64_t k, const real* dg) const {
  BodyDelta* dl = delta_.data();
  const int64_t nc = nc_, ncb = ncb_;
  if (k < ncb && normal_only_) {
    for (int j = 0; j < 3; ++j) {
      const int64_t c = 3 * k + j;
      if (dg[j] == 0 || c >= nc) continue;
      for (int side = 0; side < 2; ++side) {
        const int32_t i = side ? jac_[c].b : jac_[c].a;
        if (!movable(inv_[i])) continue;
        Vec3 F{0, 0, 0}, Tq{0, 0, 0};
        accumulateContactNormalImpulse(jac_[c], side, dg[j], F, Tq);
        const BodyDelta d = bodyDeltaFromImpulse(inv_[i], F, Tq);
        dl[i].v += d.v;
        dl[i].w += d.w;
      }
    }
  } else if (k < ncb) {
    const ContactJacobian& J = jac_[k];
    applyContactChange(J, dg, inv_.data(), dl);
  } else {
    for (int j = 0; j < 3; ++j) {
      if (dg[j] == 0) continue;
      const ConstraintRow& R = rows_[size_t(3 * (k - ncb) + j)];
      for (int side = 0; side < 2; ++side) {
        const int32_t i = side ? R.b : R.a;
        if (i < 0 || !movable(inv_[i])) continue;
        Vec3 F{0, 0, 0}, Tq{0, 0, 0};
        accumulateRowImpulse(side ? R.Jb : R.Ja, dg[j], F, Tq);
        const BodyDelta d = bodyDeltaFromImpulse(inv_[i], F, Tq);
        dl[i].v += d.v;
        dl[i].w += d.w;
      }
    }
  }
}

// Gauss-Seidel on the constraint rows of block k (not a rolling block), one row at a time: each row's impulse takes
// the exact minimiser along its coordinate, l' = clamp(l - w (J dv + r) / N_jj, lo, hi) with N_jj = J M^-1 J^T its
// diagonal entry (projected SOR, Cottle, Pang & Stone, "The Linear Complementarity Problem", 1992, sec. 5.2; the
// row-by-row update of Bullet's sequential impulses), and dv updated before the next row. A box bound is separable per
// row, so these are exact coordinate steps of the same problem (its fixed points unchanged), where one scalar step
// for the whole block (1 / its Gershgorin bound) crawls along chains of joints.
void ContactProblem::gsRowSweep(int64_t k, real* gamma, real w) const {
  const BlockSet bs = blockSet();
  for (int j = 0; j < 3; ++j) {
    const int64_t r = 3 * (k - ncb_) + j;
    const ConstraintRow& R = rows_[size_t(r)];
    if (isPaddingRow(R)) continue;
    real d = 0;
    if (R.a >= 0) d += rowInner(R.Ja, R.Ja, inv_[size_t(R.a)]);
    if (R.b >= 0) d += rowInner(R.Jb, R.Jb, inv_[size_t(R.b)]);
    if (!(d > 0)) continue;  // a row on immovable bodies
    real& g = gamma[3 * k + j];
    const real y = rowFromDeltas(R, delta_.data()) + rhs_[size_t(3 * k + j)];
    const int64_t box = 3 * (k - bs.nc) + j;
    const real gn = clampRow(g - w * y / d, bs.lo[box], bs.hi[box]);
    real dg[3] = {0, 0, 0};
    dg[j] = gn - g;
    g = gn;
    if (dg[j] != 0) gsApplyBlockChange(k, dg);
  }
}

// Exact coordinate steps of one friction cone's block (N its diagonal block N_kk, packed nn, uu, ww, nu, nw, uw;
// y = (N gamma + r)_k kept current as g moves): the normal impulse to the minimiser of the problem along it over
// g_n >= |g_t| / mu, then each tangent impulse to its minimiser over the disk |g_t| <= mu g_n (the other tangent
// held), each step relaxed by w. These are the row-by-row steps of Bullet's sequential impulses (normal row, then
// the friction rows, each with its exact diagonal) on the cone's own feasible set: each lowers the problem's
// objective and leaves a solution unmoved (Cottle, Pang & Stone 1992, sec. 5.2, for one coordinate over an
// interval), so the fixed points stay the CCP's. The scalar projected step that follows them in gsContactBlock
// keeps the cone's coupled directions moving (coordinate steps alone can stall on the cone's curved boundary).
static void coneCoordinateSteps(real mu, const real* N, real w, real* g, real* y) {
  const int col[3][3] = {{0, 3, 4}, {3, 1, 5}, {4, 5, 2}};  // N's entries of column j
  auto move = [&](int j, real target) {
    const real d = target - g[j];
    g[j] = target;
    for (int i = 0; i < 3; ++i) y[i] += N[col[j][i]] * d;
  };
  if (N[0] > 0) {
    const real lo = mu > 0 ? std::sqrt(g[1] * g[1] + g[2] * g[2]) / mu : real(0);
    move(0, std::max(lo, g[0] - w * y[0] / N[0]));
  }
  for (int j = 1; j < 3; ++j) {
    if (!(N[j] > 0)) continue;
    const real o = g[3 - j], r = mu * g[0];
    const real b = std::sqrt(std::max(real(0), r * r - o * o));
    move(j, std::min(b, std::max(-b, g[j] - w * y[j] / N[j])));
  }
}

// Gauss-Seidel on contact k (a plain friction cone, Scalar scaling): its exact coordinate steps (where the problem
// holds N_kk), then the scalar block step g' = P(g - w eta_k y), and the impulse's change into delta_.
void ContactProblem::gsContactBlock(int64_t k, real* gamma, real w) const {
  BodyDelta* dl = delta_.data();
  const ContactJacobian& J = jac_[size_t(k)];
  real y[3];
  contactRelativeVelocity(J, dl[J.a].v, dl[J.a].w, dl[J.b].v, dl[J.b].w, y);
  real* g = gamma + 3 * k;
  for (int j = 0; j < 3; ++j) y[j] += rhs_[size_t(3 * k + j)];
  real gn[3] = {g[0], g[1], g[2]};
  if (!nkk_.empty()) coneCoordinateSteps(mu_[size_t(k)], nkk_.data() + 6 * k, w, gn, y);
  const real t = w * eta_[size_t(k)];
  for (int j = 0; j < 3; ++j) gn[j] -= t * y[j];
  projectConeBlock(mu_[size_t(k)], gn);
  const real dg[3] = {gn[0] - g[0], gn[1] - g[1], gn[2] - g[2]};
  g[0] = gn[0];
  g[1] = gn[1];
  g[2] = gn[2];
  if (dg[0] == 0 && dg[1] == 0 && dg[2] == 0) return;
  applyContactChange(J, dg, inv_.data(), dl);
}

// One Gauss-Seidel sweep over the contact blocks alone, for problems whose contacts are all plain friction cones
// under Scalar scaling (no rolling block, not normal-only): the general sweep's operations in the same order (so
// the same iterates). It is a drop-in world's hot loop.
void ContactProblem::gsContactSweep(real* gamma, real w) const {
  for (int64_t k = 0; k < nc_; ++k) gsContactBlock(k, gamma, w);
}

// Whether Gauss-Seidel computes the residual after sweep `iterations` (no history kept): only where the tolerance
// can stop the solve, i.e. from min_iterations on, and then every few sweeps (min_iterations / 2, at most 5), since
// the residual's pass costs about half a sweep: a solve with Bullet's 10 sweeps as its minimum checks after sweeps
// 10, 15, 20, ... and overshoots the tolerance by at most 4 sweeps.
static bool gsCheckDue(const SolverSettings& s, int iterations) {
  if (!(s.tolerance > 0) || iterations < s.min_iterations) return false;
  const int every = std::min(5, std::max(1, s.min_iterations / 2));
  return (iterations - s.min_iterations) % every == 0;
}

// One Gauss-Seidel sweep over every block: the contacts (gsContactBlock, or with Inverse3x3 scaling, normal-only
// blocks and rolling pairs the block step g' = P(g - w S y)), then the provider rows row by row (gsRowSweep).
void ContactProblem::gsSweep(real* gamma, real w, bool full) const {
  const BlockSet bs = blockSet();
  const int64_t nblk = ncb_ + nrb_, row0 = ncb_ + nroll_;
  // Block b's values after its scaled step, before the projection.
  auto blockStep = [&](int64_t b, real* gn) {
    const real* g = gamma + 3 * b;
    real y[3];
    gsBlockGradient(b, y);
    if (full) {
      const Vec3 sy = symMul(binv_.data() + 6 * b, Vec3{y[0], y[1], y[2]});
      gn[0] = g[0] - w * sy.x;
      gn[1] = g[1] - w * sy.y;
      gn[2] = g[2] - w * sy.z;
    } else {
      const real t = w * eta_[b];
      for (int j = 0; j < 3; ++j) gn[j] = g[j] - t * y[j];
    }
  };
  // Block b's projected values into gamma, and their change into delta_.
  auto commit = [&](int64_t b, const real* gn) {
    real* g = gamma + 3 * b;
    const real dg[3] = {gn[0] - g[0], gn[1] - g[1], gn[2] - g[2]};
    g[0] = gn[0];
    g[1] = gn[1];
    g[2] = gn[2];
    if (dg[0] != 0 || dg[1] != 0 || dg[2] != 0) gsApplyBlockChange(b, dg);
  };
  const bool plain = !full && !normal_only_ && nroll_ == 0;  // every contact a plain cone: gsContactSweep
  if (plain) gsContactSweep(gamma, w);
  for (int64_t k = plain ? ncb_ : 0; k < nblk; ++k) {
    if (isRollingBlock(bs, k)) continue;  // updated with its contact (a rolling pair is one Gauss-Seidel unit)
    if (k >= row0 && !full) {
      gsRowSweep(k, gamma, w);
      continue;
    }
    const int64_t p = rollingPartner(bs, k);
    if (p < 0 && k < ncb_ && !full && !normal_only_) {
      gsContactBlock(k, gamma, w);
      continue;
    }
    real gk[3];
    blockStep(k, gk);
    if (p < 0) {
      projectBlock(bs, k, gk);
      commit(k, gk);
      continue;
    }
    real gp[3];
    blockStep(p, gp);
    projectUnit(bs, k, p, gk, gp);
    commit(k, gk);
    commit(p, gp);
  }
}

// Projected block Gauss-Seidel (Anitescu & Tasora, Comput. Optim. Appl. 47 (2010); Tasora & Anitescu,
// CMAME 200 (2011)): sweep the contacts in order; for contact k
//   y_k = D_k^T dv + r_k,   g_k' = P(g_k - w S_k y_k),   dv += M^-1 D_k (g_k' - g_k)
// with dv = M^-1 D g kept up to date, so each block costs O(1). S_k = eta_k I3 (Scalar, default) or
// N_kk^-1 (Inverse3x3). With Scalar scaling the provider rows (joints, drives) go row by row instead (gsRowSweep),
// and a plain cone's step is preceded by its exact coordinate steps (gsContactBlock). dv is formed exactly from the
// warm start; the history uses the maintained dv, the final residual a fresh Schur product. With
// gs_row_tolerance the solve stops only where the provider rows' own relative residual (against their res(0)) is
// at or below it too; the reported residual is the whole problem's.
SolverStats ContactProblem::solveGaussSeidel(real* gamma, const SolverSettings& s) const {
  // Row by row over one process's contacts: not an algorithm that splits over processes (process_group.h).
  if (group_) throw InputError("solver gs: Gauss-Seidel does not run over several processes (use apgd)");
  SolverStats st;
  const int64_t nblk = ncb_ + nrb_;
  if (nblk == 0) return st;
  const real a = residualAlpha(*this, s), inv_a = real(1) / a;
  const real w = s.gs_omega;
  const bool full = s.block_scaling == BlockScaling::Inverse3x3;
  const BlockSet bs = blockSet();
  std::vector<double> part;
  project(gamma);
  gatherBodyDeltas(gamma);             // delta_ = M^-1 D gamma on the active bodies, 0 elsewhere
  const int64_t row0 = ncb_ + nroll_;  // the provider rows' first block
  // The squared residual over blocks [lo, hi) (rolling blocks with their contact), from the maintained deltas.
  auto residual2 = [&](int64_t lo, int64_t hi) {
    double sum;
    detail::blockReduce<1>(hi - lo, threads_, part, &sum, [&](int64_t i, double* acc) {
      const int64_t k = lo + i;
      if (isRollingBlock(bs, k)) return;  // with its contact
      const int64_t p = rollingPartner(bs, k);
      real y[3], yp[3] = {0, 0, 0};
      gsBlockGradient(k, y);
      if (p >= 0) gsBlockGradient(p, yp);
      acc[0] += unitResidual2(bs, k, p, gamma + 3 * k, y, p >= 0 ? gamma + 3 * p : nullptr, yp, a, inv_a);
    });
    return sum;
  };
  // With a row tolerance the rows' residual is checked on its own, against the rows' res(0).
  const bool split = s.gs_row_tolerance > 0 && s.tolerance > 0 && nrb_ > 0;
  real row_thr = 0;
  if (split) {
    const real zero[3] = {0, 0, 0};
    double z = 0;
    for (int64_t k = row0; k < nblk; ++k)
      z += unitResidual2(bs, k, -1, zero, rhs_.data() + 3 * k, zero, nullptr, a, inv_a);
    row_thr = s.gs_row_tolerance * real(std::sqrt(z));
  }
  bool rows_ok = true;  // the rows' residual at the last check met row_thr
  auto residualFromDeltas = [&]() {
    if (!split) return real(std::sqrt(residual2(0, nblk)));
    const double rows = residual2(row0, nblk);
    rows_ok = real(std::sqrt(rows)) <= row_thr;
    return real(std::sqrt((row0 > 0 ? residual2(0, row0) : 0.0) + rows));
  };
  st.residual_scale = ccpResidualScale(*this, a);
  const real thr = stopThreshold(s, st.residual_scale);
  // A fixed count (no tolerance, no history: Bullet's effort) needs no residual before the sweeps; the one after
  // them comes from the maintained deltas too (each saved a pass of the ~12 a 10-sweep solve made).
  const bool fixed_count = !(s.tolerance > 0) && !s.record_history;
  // With a tolerance the warm start's residual is checked (a start at the solution stops at once); after it, only
  // where the tolerance can stop the solve (gsCheckDue).
  real res = fixed_count ? real(INFINITY) : residualFromDeltas();
  bool res_fresh = false;  // res is that of the current gamma
  if (s.record_history) st.history.push_back(res);
  if (!(reachedStop(res, thr, 0, s.min_iterations) && rows_ok)) {
    for (int it = 0; it < s.max_iterations; ++it) {
      gsSweep(gamma, w, full);
      ++st.iterations;
      res_fresh = s.record_history || gsCheckDue(s, st.iterations);
      if (res_fresh) {
        res = residualFromDeltas();
        if (s.record_history) st.history.push_back(res);
        if (reachedStop(res, thr, st.iterations, s.min_iterations) && rows_ok) break;
      }
    }
  }
  std::vector<real> scratch;  // with a history, a fresh Schur product (which recomputes delta_ from gamma)
  st.residual = s.record_history ? ccpResidual(*this, gamma, a, scratch) : res_fresh ? res : residualFromDeltas();
  gs_deltas_of_ = gamma;  // delta_ = M^-1 D gamma: applyImpulses(gamma) needs no gather
  finishStats(st, s);
  return st;
}

}  // namespace dvi
