// Per-contact Jacobian blocks of the contact CCP and the per-element operations on them (docs/MODEL.md §3),
// written once as DVI_HD functions: the OpenMP loops of contact_problem.cpp call them, and so will the
// CUDA kernels.
//
// Contact k between bodies A and B, normal n from A to B, tangents (u, w), w = n x u (right-handed),
// lever arms rA = pa - xA, rB = pb - xB. The 6-by-3 Jacobian blocks (columns d_j in {n, u, w}) are
//   D_kB = [ d_j ; rB x d_j ],   D_kA = -[ d_j ; rA x d_j ]
// so D_k^T v = [n; u; w] . ((vB + wB x rB) - (vA + wA x rA)) is the relative velocity at the contact.
//
// Compact storage. Instead of the 2 x 3 angular parts r x d_j (18 reals) and their M^-1 images (18 more)
// Chrono::Multicore keeps, a contact stores n, u, rA, rB (12 reals); w = n x u and the cross products are
// recomputed in registers (a few flops against 288 bytes of memory traffic). The impulse g of a contact
// acts on body B as the force P = n gn + u gu + w gw at rB, i.e. (P, rB x P), and on A as minus that at
// rA, so M^-1 D x is formed per body as dv = m^-1 sum P, dw = I^-1_world sum r x P: the world inverse
// inertia (6 reals, symmetric) is applied once per body, not once per contact.
#pragma once

#include <cmath>
#include <cstdint>

#include "chrono_like/base/hd.h"
#include "chrono_like/base/math.h"

namespace dvi {

// Hot per-contact record read by every Schur product: 104 bytes in double (52 in float).
struct ContactJacobian {
  Vec3 n;        // normal, unit, from A to B
  Vec3 u;        // first tangent (tangentBasis(n)); the second is w = n x u
  Vec3 rA, rB;   // contact points relative to the centres of mass of A and B, world
  int32_t a, b;  // body indices
};

// Inverse mass of one body in world coordinates: 56 bytes in double. Zero for fixed and kinematic bodies.
struct BodyInverseMass {
  real m;     // inverse mass
  real I[6];  // world inverse inertia R diag(invI) R^T, symmetric: xx, yy, zz, xy, xz, yz
};

// Velocity change of one body: 48 bytes in double.
struct BodyDelta {
  Vec3 v, w;
};

// Symmetric 3x3 stored as [00, 11, 22, 01, 02, 12].
DVI_HD Vec3 symMul(const real* S, Vec3 x) {
  return Vec3{S[0] * x.x + S[3] * x.y + S[4] * x.z, S[3] * x.x + S[1] * x.y + S[5] * x.z,
              S[4] * x.x + S[5] * x.y + S[2] * x.z};
}

DVI_HD Vec3 contactW(const ContactJacobian& J) { return cross(J.n, J.u); }

DVI_HD ContactJacobian makeContactJacobian(Vec3 normal, Vec3 pa, Vec3 pb, Vec3 xA, Vec3 xB, int32_t a, int32_t b) {
  ContactJacobian J;
  Vec3 u, w;
  tangentBasis(normal, u, w);
  J.n = normal;
  J.u = u;
  J.rA = pa - xA;
  J.rB = pb - xB;
  J.a = a;
  J.b = b;
  return J;
}

// VectorStorage::Float: APGD's trials on the GPU read the contact Jacobians as float. Both backends then build the
// whole step's problem from the Jacobian rounded to float (roundJacobian), so every Schur product, GPU or CPU,
// float copy or real, applies the same operator; the rounding moves a normal by ~1e-7 rad. The tangent is not
// stored: it is tangentBasis of the rounded normal, recomputed where it is used (a few flops against 12 bytes
// read three times a trial), and roundJacobian sets it so, so the real Jacobian and the float record define the
// same rows bit for bit (the device does not fuse multiply-adds: src/CMakeLists.txt).
// 44 bytes, read in contact order by the Schur pass (b).
struct ContactJacobianF {
  float n[3], rA[3], rB[3];
  int32_t a, b;
};

// The first tangent of a contact with normal n (tangentBasis); the second is n x u.
DVI_HD Vec3 contactTangent(Vec3 n) {
  Vec3 u, w;
  tangentBasis(n, u, w);
  return u;
}

DVI_HD Vec3 toReal(const float* f) { return Vec3{real(f[0]), real(f[1]), real(f[2])}; }
DVI_HD void toFloat3(Vec3 v, float* f) {
  f[0] = float(v.x);
  f[1] = float(v.y);
  f[2] = float(v.z);
}

DVI_HD ContactJacobianF toFloatJacobian(const ContactJacobian& J) {
  ContactJacobianF f;
  toFloat3(J.n, f.n);
  toFloat3(J.rA, f.rA);
  toFloat3(J.rB, f.rB);
  f.a = J.a;
  f.b = J.b;
  return f;
}

DVI_HD ContactJacobian loadJacobian(const ContactJacobian& J) { return J; }
DVI_HD ContactJacobian loadJacobian(const ContactJacobianF& f) {
  ContactJacobian J;
  J.n = toReal(f.n);
  J.u = contactTangent(J.n);
  J.rA = toReal(f.rA);
  J.rB = toReal(f.rB);
  J.a = f.a;
  J.b = f.b;
  return J;
}

DVI_HD ContactJacobian roundJacobian(const ContactJacobian& J) { return loadJacobian(toFloatJacobian(J)); }

// One side of a float contact Jacobian, in the order of the body's adjacency entries (GPU gather, jacobian.h's
// float layout): the normal and this side's lever arm, 24 bytes read one after another by the body's thread
// instead of a 44-byte record of each contact read at random (2 to 3 sectors for the 24 bytes used).
struct EntryJacobianF {
  float n[3], r[3];
};

DVI_HD EntryJacobianF entryJacobian(const ContactJacobianF& f, int side) {
  EntryJacobianF e;
  const float* r = side ? f.rB : f.rA;
  for (int j = 0; j < 3; ++j) {
    e.n[j] = f.n[j];
    e.r[j] = r[j];
  }
  return e;
}

// World inverse inertia R diag(d) R^T of a body with principal inverse inertia d and rotation q. Equal principal
// values (spheres, cubes) give d.x I exactly whatever q: R R^T = I, which the rotated product would meet only to
// rounding, and the gather then reads the body as two numbers (BodyInverseIso).
DVI_HD BodyInverseMass makeBodyInverseMass(real inv_mass, Vec3 d, Quat q) {
  BodyInverseMass B;
  B.m = inv_mass;
  if (d.x == d.y && d.y == d.z) {
    B.I[0] = B.I[1] = B.I[2] = d.x;
    B.I[3] = B.I[4] = B.I[5] = real(0);
    return B;
  }
  Mat33 R = matFromQuat(q);
  auto e = [&](Vec3 ri, Vec3 rj) { return ri.x * d.x * rj.x + ri.y * d.y * rj.y + ri.z * d.z * rj.z; };
  B.I[0] = e(R.r0, R.r0);
  B.I[1] = e(R.r1, R.r1);
  B.I[2] = e(R.r2, R.r2);
  B.I[3] = e(R.r0, R.r1);
  B.I[4] = e(R.r0, R.r2);
  B.I[5] = e(R.r1, R.r2);
  return B;
}

// y = D_k^T [vA wA vB wB]: the (n, u, w) components of the relative velocity at the contact.
DVI_HD void contactRelativeVelocity(const ContactJacobian& J, Vec3 vA, Vec3 wA, Vec3 vB, Vec3 wB, real* y) {
  const Vec3 rel = (vB + cross(wB, J.rB)) - (vA + cross(wA, J.rA));
  y[0] = dot(J.n, rel);
  y[1] = dot(J.u, rel);
  y[2] = dot(contactW(J), rel);
}

// The world impulse of a contact with normal n and tangents u, w = n x u: P = n g0 + u g1 + w g2.
DVI_HD Vec3 contactWorldImpulse(Vec3 n, Vec3 u, const real* g) { return n * g[0] + u * g[1] + cross(n, u) * g[2]; }

// The world impulse P of a contact added to side `side` of it (lever arm r): +P on B, -P on A, with its moment
// (F += s P, T += s r x P, s = -1 on A, +1 on B).
DVI_HD void accumulateArmImpulse(Vec3 r, int side, Vec3 P, Vec3& F, Vec3& T) {
  if (side) {
    F += P;
    T += cross(r, P);
  } else {
    F -= P;
    T -= cross(r, P);
  }
}

DVI_HD void accumulateSidedImpulse(const ContactJacobian& J, int side, Vec3 P, Vec3& F, Vec3& T) {
  accumulateArmImpulse(side ? J.rB : J.rA, side, P, F, T);
}

// Adds the generalised impulse of contact k on one of its bodies (side 0 = A, 1 = B) to (F, T).
DVI_HD void accumulateContactImpulse(const ContactJacobian& J, int side, const real* g, Vec3& F, Vec3& T) {
  accumulateSidedImpulse(J, side, contactWorldImpulse(J.n, J.u, g), F, T);
}

// dv = m^-1 F, dw = I^-1 T.
DVI_HD BodyDelta bodyDeltaFromImpulse(const BodyInverseMass& B, Vec3 F, Vec3 T) {
  return BodyDelta{F * B.m, symMul(B.I, T)};
}

// The inverse mass of a body as the GPU gather reads it: 16 bytes in double. i is the world inverse inertia's
// value where it is i I (makeBodyInverseMass: equal principal values; fixed bodies, 0), else NaN and the gather
// reads the full BodyInverseMass.
struct BodyInverseIso {
  real m, i;
};

DVI_HD BodyInverseIso isoInverse(const BodyInverseMass& B) {
  const bool iso = B.I[3] == 0 && B.I[4] == 0 && B.I[5] == 0 && B.I[0] == B.I[1] && B.I[1] == B.I[2];
  return BodyInverseIso{B.m, iso ? B.I[0] : real(NAN)};
}

// bodyDeltaFromImpulse of an isotropic body: the same values (symMul's off-diagonal terms add zeros), but for
// the sign of a zero.
DVI_HD BodyDelta bodyDeltaFromImpulse(const BodyInverseIso& B, Vec3 F, Vec3 T) { return BodyDelta{F * B.m, T * B.i}; }

// Diagonal block N_kk = D_k^T M^-1 D_k (symmetric, [00, 11, 22, 01, 02, 12]). The linear parts give
// (mA + mB) I3 because (n, u, w) is orthonormal; the angular parts (r x d_i)^T I^-1 (r x d_j) of each side.
DVI_HD void contactDiagonalBlock(const ContactJacobian& J, const BodyInverseMass& A, const BodyInverseMass& B,
                                 real* N) {
  const Vec3 d[3] = {J.n, J.u, contactW(J)};
  const real m = A.m + B.m;
  Vec3 ca[3], cb[3], ia[3], ib[3];
  for (int j = 0; j < 3; ++j) {
    ca[j] = cross(J.rA, d[j]);
    cb[j] = cross(J.rB, d[j]);
    ia[j] = symMul(A.I, ca[j]);
    ib[j] = symMul(B.I, cb[j]);
  }
  auto e = [&](int i, int j) { return dot(ca[i], ia[j]) + dot(cb[i], ib[j]); };
  N[0] = m + e(0, 0);
  N[1] = m + e(1, 1);
  N[2] = m + e(2, 2);
  N[3] = e(0, 1);
  N[4] = e(0, 2);
  N[5] = e(1, 2);
}

// Inverse of a symmetric positive semi-definite 3x3 block, by the adjugate. A singular block (a contact
// between two bodies that cannot move, or a degenerate lever arm) is regularised by adding 1e-10 of its
// largest diagonal entry to the diagonal; an all-zero block (both bodies fixed) gets a zero inverse so
// block-scaled solvers leave that contact alone.
DVI_HD void invertSymmetric3(const real* N, real* Bi) {
  real s = fmax(N[0], fmax(N[1], N[2]));
  if (!(s > real(0))) {
    for (int i = 0; i < 6; ++i) Bi[i] = real(0);
    return;
  }
  real a = N[0], b = N[1], c = N[2], d = N[3], e = N[4], f = N[5];
  real c00 = b * c - f * f, c01 = e * f - d * c, c02 = d * f - b * e;
  real det = a * c00 + d * c01 + e * c02;
  if (!(det > real(1e-12) * s * s * s)) {
    const real eps = real(1e-10) * s;
    a += eps;
    b += eps;
    c += eps;
    c00 = b * c - f * f;
    c01 = e * f - d * c;
    c02 = d * f - b * e;
    det = a * c00 + d * c01 + e * c02;
  }
  const real inv = real(1) / det;
  Bi[0] = c00 * inv;
  Bi[1] = (a * c - e * e) * inv;
  Bi[2] = (a * b - d * d) * inv;
  Bi[3] = c01 * inv;
  Bi[4] = c02 * inv;
  Bi[5] = (d * e - a * f) * inv;
}

// Scalar step of one contact block: 1 / (Gershgorin bound of lambda_max(N_kk)) <= 1 / lambda_max. A
// scalar (the same for the three rows) keeps the fixed points of g <- P(g - eta (N g + r)) those of the
// CCP, because a positive multiple of a normal-cone vector stays in the normal cone (Tasora & Anitescu,
// CMAME 200 (2011), who use 3 / trace(N_kk)); the Gershgorin bound keeps each block step below 1 / L_k so
// the block Gauss-Seidel update decreases the objective. Zero for a zero block.
DVI_HD real blockStepFromDiagonal(const real* N) {
  const real g0 = fabs(N[0]) + fabs(N[3]) + fabs(N[4]);
  const real g1 = fabs(N[1]) + fabs(N[3]) + fabs(N[5]);
  const real g2 = fabs(N[2]) + fabs(N[4]) + fabs(N[5]);
  const real g = fmax(g0, fmax(g1, g2));
  return g > real(0) ? real(1) / g : real(0);
}

// b_k normal entry: dist / h, with the separating speed a penetration asks for clamped to v_rec = recovery_rel x
// size per second (Anitescu & Hart 2004's stabilisation; Chrono's contact_recovery_speed, "max speed of
// penetration recovery", is the absolute-length analogue). With dist > 0 (a speculative contact, narrowphase.h:
// keepSpeculative) the entry lets the gap close within the step and no further. A penetration is undone at no
// more than v_rec, and that speed stays in the body after the overlap is gone (it is a velocity-level bias, not a
// split impulse): a body lifts by at most v_rec^2 / (2 g). Speculative contacts keep penetrations from arising
// on impact, so the clamp acts on initial overlaps and solver residuals only.
DVI_HD real contactBias(real dist, real h, real recovery_rel, real size) {
  const real b = dist / h;
  const real lo = -recovery_rel * size;
  return b > lo ? b : lo;
}

// |D_kjc|_{M_c^-1} = sqrt(m_c + (r_c x d_j)^T I_c^-1 (r_c x d_j)) for side c (0 = A, 1 = B) and d_j in
// (n, u, w): out[3 c + j]. These are the square roots of each body's share of the diagonal of N_kk.
DVI_HD void contactColumnNorms(const ContactJacobian& J, const BodyInverseMass& A, const BodyInverseMass& B,
                               real* out) {
  const Vec3 d[3] = {J.n, J.u, contactW(J)};
  for (int j = 0; j < 3; ++j) {
    const Vec3 ca = cross(J.rA, d[j]), cb = cross(J.rB, d[j]);
    out[j] = sqrt(fmax(real(0), A.m + dot(ca, symMul(A.I, ca))));
    out[3 + j] = sqrt(fmax(real(0), B.m + dot(cb, symMul(B.I, cb))));
  }
}

// Absolute row sums of a symmetric 3x3 block [00, 11, 22, 01, 02, 12].
DVI_HD void blockRowSums(const real* N, real* rs) {
  rs[0] = fabs(N[0]) + fabs(N[3]) + fabs(N[4]);
  rs[1] = fabs(N[1]) + fabs(N[3]) + fabs(N[5]);
  rs[2] = fabs(N[2]) + fabs(N[4]) + fabs(N[5]);
}

// Jacobi step of contact k (CcpProblem::jacobiSteps): row (k, i) of N has absolute sum <= rs_i + sum over
// the two bodies c of |D_kic|_{M^-1} (Q_c - q_kc), with Q_c the sum of the column norms of every entry
// of body c (bodyq) and q_kc contact k's own share (Cauchy-Schwarz in the M_c^-1 inner product), so
// t_k = 1 / max_i of that bound gives rho(diag(t) N) <= 1.
DVI_HD real contactJacobiStep(const real* cn, const real* rs, real Qa, real Qb) {
  const real qa = fmax(real(0), Qa - (cn[0] + cn[1] + cn[2]));
  const real qb = fmax(real(0), Qb - (cn[3] + cn[4] + cn[5]));
  real g = 0;
  for (int i = 0; i < 3; ++i) g = fmax(g, rs[i] + cn[i] * qa + cn[3 + i] * qb);
  return g > real(0) ? real(1) / g : real(0);
}

// ---- frictionless contacts: the normal row only (docs/MODEL.md §6, "leave out what a scene does not need") ----
// A contact with mu = 0 has only its normal row: its tangential impulses are projected to 0 by the cone
// (cone.h, mu = 0), so dropping the rows u, w leaves the CCP's solution unchanged (Anitescu & Tasora 2010:
// the frictionless CCP is the LCP 0 <= gn _|_ N_nn gn + r_n >= 0). In a normal-only problem the normal rows
// of contacts 3q, 3q+1, 3q+2 form block q, each row projected onto [0, inf) (solver_kernels.h), so the
// solvers' block layout is unchanged.

// n . (relative velocity at the contact): the first row of contactRelativeVelocity.
DVI_HD real contactNormalVelocity(const ContactJacobian& J, Vec3 vA, Vec3 wA, Vec3 vB, Vec3 wB) {
  const Vec3 rel = (vB + cross(wB, J.rB)) - (vA + cross(wA, J.rA));
  return dot(J.n, rel);
}

// What the normal row's bias of a contact reads besides the contact itself (ContactProblem::build on the CPU,
// gpu/solver/gpu_rows.cu RowsF on the device): the step, the solver settings and the body arrays.
struct ContactBiasInputs {
  real h = 0;                                       // [s] the step
  real recovery_rel = 0;                            // [1/s] SolverSettings::recovery_rel
  real min_bounce_speed = 0;                        // [m/s] SolverSettings::min_bounce_speed
  const real* restitution = nullptr;                // per body (BodyArrays::restitution); null: every body 0
  const Vec3 *vel = nullptr, *omega = nullptr;      // per body, before this step's forces (BodyArrays::vel, omega)
  const Vec3 *v_free = nullptr, *w_free = nullptr;  // per body, after them (the rhs's D^T v_free)
};

// The normal entry b_k of contact k's right-hand side, r_n = D_n^T v_free + b_k; the CCP row is
// 0 <= gn _|_ v_n+ + b_k >= 0, i.e. the velocity after the step is v_n+ >= -b_k. One function for both backends.
//
// Without restitution (e = 0, the default) b_k = contactBias (position stabilisation and speculative gap), the
// value and the rounding the problem always had, so e = 0 results are bitwise unchanged.
//
// Restitution: Newton's impact law in the DVI step (Anitescu & Potra, "Formulating dynamic multi-rigid-body
// contact problems with friction as solvable linear complementarity problems", Nonlinear Dynamics 14, 1997;
// Chrono's ChContactNSC::ContIntLoadConstraint_C, "CASE: BOUNCE"): the row becomes
// 0 <= gn _|_ v_n+ + e v_n- >= 0, so the contact leaves at least at e times its approach speed, with
// e = e_a e_b (Bullet's btManifoldResult::calculateCombinedRestitution) and v_n- the relative normal velocity at
// the contact before the step (Chrono's and Bullet's choice: the velocity the bodies arrive with, not the free
// velocity, which already holds this step's gravity). It applies only to an impact:
// - approaching faster than min_bounce_speed, v_n- < -min_bounce_speed (Bullet's restitutionCurve with
//   m_restitutionVelocityThreshold; Chrono's min_bounce_speed): slow contacts (resting, sliding) stay inelastic;
// - and the contact closes within this step, v_n,free + b_pos < 0 (the speculative row is active with no
//   impulse): a speculative contact whose gap the body does not cross this step does not bounce early.
// Combination with position stabilisation: the row keeps the more demanding of the two targets,
// b_k = min(b_pos, e v_n-). For a speculative gap (b_pos = dist/h > 0 > e v_n-) that is the bounce, as in Chrono
// (the body rebounds from where it is, up to one step's travel |v_n-| h above the surface: an O(h) error in the
// rebound height, not in its speed); for an overlap it is the faster of the rebound and the bounded recovery
// speed, so a bounce never adds the recovery speed on top (Chrono picks the bounce instead of the recovery; the
// min differs only when the recovery asks for more, and then never injects more than max(e |v_n-|, v_rec)).
DVI_HD real contactNormalBias(const ContactJacobian& J, real dist, real size, const ContactBiasInputs& in) {
  const real b_pos = contactBias(dist, in.h, in.recovery_rel, size);
  const real e = in.restitution ? in.restitution[J.a] * in.restitution[J.b] : real(0);
  if (!(e > 0)) return b_pos;
  const real vn_pre = contactNormalVelocity(J, in.vel[J.a], in.omega[J.a], in.vel[J.b], in.omega[J.b]);
  if (!(vn_pre < -in.min_bounce_speed)) return b_pos;
  const real vn_free = contactNormalVelocity(J, in.v_free[J.a], in.w_free[J.a], in.v_free[J.b], in.w_free[J.b]);
  if (!(vn_free + b_pos < 0)) return b_pos;
  const real b_bounce = e * vn_pre;
  return b_bounce < b_pos ? b_bounce : b_pos;
}

// accumulateContactImpulse for the normal impulse gn alone.
DVI_HD void accumulateContactNormalImpulse(const ContactJacobian& J, int side, real gn, Vec3& F, Vec3& T) {
  accumulateSidedImpulse(J, side, J.n * gn, F, T);
}

// The same two from one side's float record (EntryJacobianF): bit for bit what they add with the contact's
// ContactJacobianF loaded (loadJacobian: the same conversions, the tangent recomputed by the same function).
DVI_HD void accumulateEntryContactImpulse(const EntryJacobianF& e, int side, const real* g, Vec3& F, Vec3& T) {
  const Vec3 n = toReal(e.n);
  accumulateArmImpulse(toReal(e.r), side, contactWorldImpulse(n, contactTangent(n), g), F, T);
}
DVI_HD void accumulateEntryNormalImpulse(const EntryJacobianF& e, int side, real gn, Vec3& F, Vec3& T) {
  accumulateArmImpulse(toReal(e.r), side, toReal(e.n) * gn, F, T);
}

// Entry N_ij = D_in^T M^-1 D_jn between the normal rows of contacts i and j: the sum over the bodies c they
// share of s_ic s_jc (m_c n_i . n_j + (r_ic x n_i)^T I_c^-1 (r_jc x n_j)), s = -1 on side A, +1 on B.
// Fixed and kinematic bodies (zero inverse mass) add nothing. For i = j it is N_kk[0] of contactDiagonalBlock.
DVI_HD real normalRowCoupling(const ContactJacobian& Ji, const ContactJacobian& Jj, const BodyInverseMass* inv) {
  real v = 0;
  for (int si = 0; si < 2; ++si)
    for (int sj = 0; sj < 2; ++sj) {
      const int32_t ci = si ? Ji.b : Ji.a, cj = sj ? Jj.b : Jj.a;
      if (ci != cj) continue;
      const BodyInverseMass& M = inv[ci];
      const Vec3 ai = cross(si ? Ji.rB : Ji.rA, Ji.n), aj = cross(sj ? Jj.rB : Jj.rA, Jj.n);
      const real e = M.m * dot(Ji.n, Jj.n) + dot(ai, symMul(M.I, aj));
      v += (si == sj) ? e : -e;
    }
  return v;
}

// Block q of a normal-only problem: the normal rows of the cnt (1..3) contacts J[0..cnt) (padding rows
// after them are empty). Writes the 3x3 diagonal block's inverse, its scalar step (blockStepFromDiagonal),
// its absolute row sums, and the column norms |D_jn|_{M_c^-1} per side (colnorm[j] side A, colnorm[3 + j]
// side B, the layout of a constraint-row block); returns the largest diagonal entry.
DVI_HD real assembleNormalBlock(const ContactJacobian* J, int cnt, const BodyInverseMass* inv, real* binv, real* eta,
                                real* colnorm, real* rowsum) {
  real N[6] = {0, 0, 0, 0, 0, 0};
  const int ii[6] = {0, 1, 2, 0, 0, 1}, jj[6] = {0, 1, 2, 1, 2, 2};
  for (int e = 0; e < 6; ++e)
    if (ii[e] < cnt && jj[e] < cnt) N[e] = normalRowCoupling(J[ii[e]], J[jj[e]], inv);
  for (int j = 0; j < 3; ++j) {
    colnorm[j] = colnorm[3 + j] = 0;
    if (j >= cnt) continue;
    const BodyInverseMass& A = inv[J[j].a];
    const BodyInverseMass& B = inv[J[j].b];
    const Vec3 ca = cross(J[j].rA, J[j].n), cb = cross(J[j].rB, J[j].n);
    colnorm[j] = sqrt(fmax(real(0), A.m + dot(ca, symMul(A.I, ca))));
    colnorm[3 + j] = sqrt(fmax(real(0), B.m + dot(cb, symMul(B.I, cb))));
  }
  invertSymmetric3(N, binv);
  *eta = blockStepFromDiagonal(N);
  blockRowSums(N, rowsum);
  return fmax(N[0], fmax(N[1], N[2]));
}

// Jacobi step of normal block q (CcpProblem::jacobiSteps), the bound of contactJacobiStep per row j:
// rowsum_j (this block, couplings to its other rows included) + sum over the sides c of
// |D_jc| (Q_c - |D_jc|). The other rows of the block are counted twice (in rowsum and in Q): a larger,
// still valid bound.
DVI_HD real normalBlockJacobiStep(const ContactJacobian* J, int cnt, const real* colnorm, const real* rowsum,
                                  const real* bodyq) {
  real g = 0;
  for (int j = 0; j < cnt; ++j) {
    const real qa = fmax(real(0), bodyq[J[j].a] - colnorm[j]);
    const real qb = fmax(real(0), bodyq[J[j].b] - colnorm[3 + j]);
    g = fmax(g, rowsum[j] + colnorm[j] * qa + colnorm[3 + j] * qb);
  }
  return g > real(0) ? real(1) / g : real(0);
}

// ---- generic constraint rows (constraint_row.h): J = (linear[3], angular[3]) per side ----

// J . (v, w)
DVI_HD real rowDot(const real* J, Vec3 v, Vec3 w) {
  return J[0] * v.x + J[1] * v.y + J[2] * v.z + J[3] * w.x + J[4] * w.y + J[5] * w.z;
}

// (F, T) += l (J_linear, J_angular): the generalised impulse of a row on one of its bodies.
DVI_HD void accumulateRowImpulse(const real* J, real l, Vec3& F, Vec3& T) {
  F += Vec3{J[0], J[1], J[2]} * l;
  T += Vec3{J[3], J[4], J[5]} * l;
}

// Ji^T M^-1 Jj for one body.
DVI_HD real rowInner(const real* Ji, const real* Jj, const BodyInverseMass& M) {
  const Vec3 ai{Ji[3], Ji[4], Ji[5]};
  const Vec3 aj{Jj[3], Jj[4], Jj[5]};
  return M.m * (Ji[0] * Jj[0] + Ji[1] * Jj[1] + Ji[2] * Jj[2]) + dot(ai, symMul(M.I, aj));
}

}  // namespace dvi
