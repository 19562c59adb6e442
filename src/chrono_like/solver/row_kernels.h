// Per-element operations on generic constraint rows (constraint_row.h), written once as DVI_HD functions:
// ContactProblem (CPU) and the GPU backend's BuildRows / Schur kernels call these. A row block holds
// three rows (the last block of a step is padded with rows that have lo = hi = 0 and no bodies).
#pragma once

#include <cstdint>

#include "chrono_like/base/hd.h"
#include "chrono_like/solver/constraint_row.h"
#include "chrono_like/solver/jacobian.h"

namespace dvi {

DVI_HD bool isPaddingRow(const ConstraintRow& R) { return R.a < 0 && R.b < 0 && R.lo == 0 && R.hi == 0; }

// Assembles row block R[0..2]: right-hand side r_j = Ja . (va, wa)_free + Jb . (vb, wb)_free + bias_j, the
// diagonal block N_ij = sum over the bodies both rows act on of Ji^T M^-1 Jj, its inverse, the block step,
// the column norms (for the Jacobi bound) and the absolute row sums; returns the largest diagonal entry.
// inv of a fixed or kinematic body is zero (it takes no part in N, but its velocity enters r).
DVI_HD real assembleRowBlock(const ConstraintRow* R, const BodyInverseMass* inv, const Vec3* v_free, const Vec3* w_free,
                             real* rhs, real* binv, real* eta, real* colnorm, real* rowsum) {
  const BodyInverseMass none{0, {0, 0, 0, 0, 0, 0}};
  real N[6];
  const int ii[6] = {0, 1, 2, 0, 0, 1}, jj[6] = {0, 1, 2, 1, 2, 2};
  for (int e = 0; e < 6; ++e) {
    const ConstraintRow& A = R[ii[e]];
    const ConstraintRow& B = R[jj[e]];
    real v = 0;
    for (int sa = 0; sa < 2; ++sa)
      for (int sb = 0; sb < 2; ++sb) {
        const int32_t ca = sa ? A.b : A.a, cb = sb ? B.b : B.a;
        if (ca >= 0 && ca == cb) v += rowInner(sa ? A.Jb : A.Ja, sb ? B.Jb : B.Ja, inv[ca]);
      }
    N[e] = v;
  }
  for (int j = 0; j < 3; ++j) {
    const ConstraintRow& Rj = R[j];
    real v = Rj.bias;
    if (Rj.a >= 0) v += rowDot(Rj.Ja, v_free[Rj.a], w_free[Rj.a]);
    if (Rj.b >= 0) v += rowDot(Rj.Jb, v_free[Rj.b], w_free[Rj.b]);
    rhs[j] = isPaddingRow(Rj) ? real(0) : v;
    const BodyInverseMass& Ma = Rj.a >= 0 ? inv[Rj.a] : none;
    const BodyInverseMass& Mb = Rj.b >= 0 ? inv[Rj.b] : none;
    colnorm[j] = sqrt(fmax(real(0), rowInner(Rj.Ja, Rj.Ja, Ma)));
    colnorm[3 + j] = sqrt(fmax(real(0), rowInner(Rj.Jb, Rj.Jb, Mb)));
  }
  invertSymmetric3(N, binv);
  *eta = blockStepFromDiagonal(N);
  blockRowSums(N, rowsum);
  return fmax(N[0], fmax(N[1], N[2]));
}

// Jacobi step of a row block: the bound of contactJacobiStep without subtracting the block's own share
// (its rows may act on different bodies), a larger and still valid bound. Q[c] is the column-norm sum of
// body c (0 for no body).
DVI_HD real rowBlockJacobiStep(const ConstraintRow* R, const real* colnorm, const real* rowsum, const real* bodyq) {
  real g = 0;
  for (int i = 0; i < 3; ++i) {
    const real qa = R[i].a >= 0 ? bodyq[R[i].a] : real(0);
    const real qb = R[i].b >= 0 ? bodyq[R[i].b] : real(0);
    g = fmax(g, rowsum[i] + colnorm[i] * qa + colnorm[3 + i] * qb);
  }
  return g > real(0) ? real(1) / g : real(0);
}

// y = J . (dv, dw) of one row from the bodies' velocity changes.
DVI_HD real rowFromDeltas(const ConstraintRow& R, const BodyDelta* dl) {
  real v = 0;
  if (R.a >= 0) v += rowDot(R.Ja, dl[R.a].v, dl[R.a].w);
  if (R.b >= 0) v += rowDot(R.Jb, dl[R.b].v, dl[R.b].w);
  return v;
}

// Where the unknowns of a problem lie in its solution vector x: contact k's impulses at x[3k..3k+2] (three
// rows) or, in a normal-only problem (frictionless contacts, jacobian.h), its normal impulse at x[k], the
// contacts' normal rows packed three per block; constraint row i at x[3 rb0 + i] in block rb0 + i / 3.
struct EntryLayout {
  int64_t nc = 0;   // contacts
  int64_t rb0 = 0;  // first constraint-row block: nc, or ceil(nc / 3) when normal_only
  bool normal_only = false;
};

// Column norm of adjacency entry ent (2 k + side for contact k, 2 nc + 2 i + side for row i) summed over
// its columns: the entry's share of its body's Q (contactJacobiStep).
DVI_HD real entryColumnSum(int32_t ent, const EntryLayout& L, const real* colnorm) {
  if (ent < 2 * L.nc) {
    const int64_t k = int64_t(ent >> 1);
    if (L.normal_only) return colnorm[6 * (k / 3) + 3 * (ent & 1) + k % 3];
    const real* cn = colnorm + 6 * k + 3 * (ent & 1);
    return cn[0] + cn[1] + cn[2];
  }
  const int64_t i = (int64_t(ent) - 2 * L.nc) >> 1;
  return colnorm[6 * (L.rb0 + i / 3) + 3 * (ent & 1) + i % 3];
}

// Adds row entry ent's (ent >= 2 nc) impulse on its body to (F, T), through the row's full Jacobian.
DVI_HD void accumulateRowEntryImpulse(int32_t ent, const EntryLayout& L, const ConstraintRow* rows, const real* x,
                                      Vec3& F, Vec3& T) {
  const int64_t r = (int64_t(ent) - 2 * L.nc) >> 1;
  const ConstraintRow& R = rows[r];
  accumulateRowImpulse((ent & 1) ? R.Jb : R.Ja, x[3 * L.rb0 + r], F, T);
}

// Adds adjacency entry ent's impulse on its body to (F, T): contacts through their compact Jacobian,
// rows through their full one; x in the layout L. JT: ContactJacobian, or ContactJacobianF (jacobian.h).
template <class JT>
DVI_HD void accumulateEntryImpulse(int32_t ent, const EntryLayout& L, const JT* jac, const ConstraintRow* rows,
                                   const real* x, Vec3& F, Vec3& T) {
  if (ent >= 2 * L.nc) return accumulateRowEntryImpulse(ent, L, rows, x, F, T);
  const int32_t k = ent >> 1;
  const ContactJacobian J = loadJacobian(jac[k]);
  if (L.normal_only)
    accumulateContactNormalImpulse(J, ent & 1, x[k], F, T);
  else
    accumulateContactImpulse(J, ent & 1, x + 3 * int64_t(k), F, T);
}

// accumulateEntryImpulse with the contact side's float record of entry ent (EntryJacobianF, kept in the order of
// the adjacency entries; unused for rows): the same sums as with ContactJacobianF, bit for bit.
DVI_HD void accumulateEntryImpulse(int32_t ent, const EntryJacobianF& e, const EntryLayout& L,
                                   const ConstraintRow* rows, const real* x, Vec3& F, Vec3& T) {
  if (ent >= 2 * L.nc) return accumulateRowEntryImpulse(ent, L, rows, x, F, T);
  const int32_t k = ent >> 1;
  if (L.normal_only)
    accumulateEntryNormalImpulse(e, ent & 1, x[k], F, T);
  else
    accumulateEntryContactImpulse(e, ent & 1, x + 3 * int64_t(k), F, T);
}

}  // namespace dvi
