// CCP solver tests (tag [solver]): cone projection, the matrix-free contact operators against dense
// matrices built from the definitions, every solver against a dense reference (itself checked against the
// KKT conditions), analytic single-contact cases, and bitwise determinism across thread counts.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "chrono_like/solver/cone.h"
#include "chrono_like/solver/contact_problem.h"
#include "chrono_like/solver/solver.h"
#include "reference_solver.h"

using namespace dvi;

namespace {

struct Scene {
  BodyArrays bodies;
  ContactArrays contacts;
  std::vector<Vec3> vf, wf;
  StepContext step = makeStepContext(real(1e-3));  // the step the problem is built for (build's argument)
  SolverSettings solver;                           // recovery_rel, min_bounce_speed
  ContactProblemSettings ps;
};

int addBody(Scene& s, Vec3 pos, Quat q, real mass, Vec3 inertia, bool fixed = false) {
  const size_t i = s.bodies.count();
  s.bodies.resize(i + 1);
  s.bodies.pos[i] = pos;
  s.bodies.rot[i] = q;
  s.bodies.inv_mass[i] = fixed ? 0 : 1 / mass;
  s.bodies.inv_inertia[i] = fixed ? Vec3{0, 0, 0} : Vec3{1 / inertia.x, 1 / inertia.y, 1 / inertia.z};
  s.bodies.flags[i] = fixed ? kBodyFixed : 0;
  s.vf.push_back({0, 0, 0});
  s.wf.push_back({0, 0, 0});
  return int(i);
}

void addContact(Scene& s, int a, int b, Vec3 n, Vec3 pa, Vec3 pb, real mu, real size = 0.1) {
  const size_t k = s.contacts.count();
  s.contacts.resize(k + 1);
  s.contacts.body_a[k] = a;
  s.contacts.body_b[k] = b;
  s.contacts.normal[k] = n;
  s.contacts.pa[k] = pa;
  s.contacts.pb[k] = pb;
  s.contacts.dist[k] = dot(pb - pa, n);
  s.contacts.mu[k] = mu;
  s.contacts.size[k] = size;
}

Quat randomQuat(std::mt19937_64& rng) {
  std::normal_distribution<double> N(0, 1);
  return normalized(Quat{N(rng), N(rng), N(rng), N(rng)});
}
Vec3 randomUnit(std::mt19937_64& rng) {
  std::normal_distribution<double> N(0, 1);
  return normalized(Vec3{N(rng), N(rng), N(rng)});
}

// Random scene: body 0 fixed, nb - 1 free bodies with random masses, inertias and rotations, nc contacts
// between random pairs (never two fixed bodies), random normals, lever arms, gaps, free velocities.
Scene randomScene(uint64_t seed, int nb, int nc, bool local_pairs = false) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> U(0, 1);
  Scene s;
  addBody(s, {0, 0, 0}, quatIdentity(), 0, {0, 0, 0}, true);
  for (int i = 1; i < nb; ++i) {
    int b = addBody(s, {U(rng) * 4, U(rng) * 4, U(rng) * 4}, randomQuat(rng), 0.5 + U(rng),
                    {0.05 + 0.1 * U(rng), 0.05 + 0.1 * U(rng), 0.05 + 0.1 * U(rng)});
    s.vf[b] = {U(rng) - 0.5, U(rng) - 0.5, U(rng) - 0.5};
    s.wf[b] = {U(rng) - 0.5, U(rng) - 0.5, U(rng) - 0.5};
  }
  for (int k = 0; k < nc; ++k) {
    int a, b;
    if (local_pairs) {  // neighbours in index, as a sorted narrow phase would give
      b = 1 + int(U(rng) * (nb - 1));
      a = U(rng) < 0.1 ? 0 : std::max(0, b - 1 - int(U(rng) * 20));
      if (a == b) a = 0;
    } else {
      b = 1 + int(U(rng) * (nb - 1));
      a = int(U(rng) * nb);
      if (a == b) a = 0;
    }
    const Vec3 n = randomUnit(rng);
    const Vec3 pb = s.bodies.pos[b] + randomUnit(rng) * 0.1;
    // dist >= 0 keeps b_n >= 0, so the CCP is bounded below even where D is rank deficient
    const Vec3 pa = pb - n * (0.001 * U(rng));
    addContact(s, a, b, n, pa, pb, real(U(rng) < 0.15 ? 0.0 : 0.8 * U(rng)));
  }
  s.step = makeStepContext(real(1e-2));
  s.solver.recovery_rel = 1;
  s.ps.threads = 1;
  return s;
}

refsolver::DenseCcp dense(const Scene& s) {
  return refsolver::denseFromScene(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step.dt, s.solver.recovery_rel);
}

double maxAbsDiff(const real* a, const real* b, size_t n) {
  double m = 0;
  for (size_t i = 0; i < n; ++i) m = std::max(m, std::fabs(double(a[i]) - double(b[i])));
  return m;
}
double maxAbs(const std::vector<double>& a) {
  double m = 0;
  for (double v : a) m = std::max(m, std::fabs(v));
  return m;
}

const SolverType kAll[] = {SolverType::Jacobi, SolverType::GaussSeidel, SolverType::APGD, SolverType::BB};

SolverStats runSolver(SolverType t, const CcpProblem& p, real* g, const SolverSettings& s) {
  switch (t) {
    case SolverType::Jacobi: return solveJacobi(p, g, s);
    case SolverType::APGD: return solveApgd(p, g, s);
    case SolverType::BB: return solveBB(p, g, s);
    case SolverType::GaussSeidel: return static_cast<const ContactProblem&>(p).solveGaussSeidel(g, s);
  }
  return {};
}

// Iterations each solver needs to reach ~1e-10 on the small test problems.
SolverSettings tightSettings(SolverType t) {
  SolverSettings s;
  s.tolerance = 1e-11;
  s.max_iterations = t == SolverType::Jacobi ? 200000 : t == SolverType::GaussSeidel ? 50000 : 20000;
  s.jacobi_omega = 0.3;
  s.record_history = true;
  return s;
}

}  // namespace

// ------------------------------------------------------------------------------------------- cone
TEST_CASE("cone projection: Moreau decomposition, idempotence, special cases", "[solver]") {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> N(0, 1);
  std::uniform_real_distribution<double> U(0, 1);
  for (int trial = 0; trial < 20000; ++trial) {
    const real mu = trial % 7 == 0 ? 0 : real(2 * U(rng));
    const real x[3] = {real(N(rng)), real(N(rng)), real(N(rng))};
    real p[3] = {x[0], x[1], x[2]};
    projectConeBlock(mu, p);
    const double sc = 1 + std::fabs(x[0]) + std::fabs(x[1]) + std::fabs(x[2]);
    // in the cone
    REQUIRE(std::hypot(p[1], p[2]) <= mu * p[0] + 1e-14 * sc);
    REQUIRE(p[0] >= 0);
    // q = x - p is in the polar cone {mu |q_t| <= -q_n} (for mu = 0: q_t free, q_n <= 0) and orthogonal to p
    const real q[3] = {x[0] - p[0], x[1] - p[1], x[2] - p[2]};
    if (mu > 0)
      REQUIRE(mu * std::hypot(q[1], q[2]) <= -q[0] + 1e-14 * sc);
    else
      REQUIRE(q[0] <= 1e-15 * sc);
    REQUIRE(std::fabs(p[0] * q[0] + p[1] * q[1] + p[2] * q[2]) <= 1e-14 * sc * sc);
    // idempotent
    real pp[3] = {p[0], p[1], p[2]};
    projectConeBlock(mu, pp);
    REQUIRE(maxAbsDiff(pp, p, 3) <= 1e-15 * sc);
    // closest point: no random point of the cone is closer
    for (int j = 0; j < 5; ++j) {
      const double n = 3 * U(rng), t = mu * n * U(rng), ang = 6.283185307179586 * U(rng);
      const double y[3] = {n, t * std::cos(ang), t * std::sin(ang)};
      const double dp = std::hypot(std::hypot(x[0] - p[0], x[1] - p[1]), x[2] - p[2]);
      const double dy = std::hypot(std::hypot(x[0] - y[0], x[1] - y[1]), x[2] - y[2]);
      REQUIRE(dp <= dy + 1e-12);
    }
  }
  SECTION("inside unchanged, polar to zero, mu = 0") {
    real a[3] = {1, 0.3, -0.2};
    projectConeBlock(0.5, a);
    CHECK(a[0] == 1);
    CHECK(a[1] == real(0.3));
    CHECK(a[2] == real(-0.2));
    real b[3] = {-1, 0.3, 0.2};  // mu |t| = 0.18 <= 1
    projectConeBlock(0.5, b);
    CHECK((b[0] == 0 && b[1] == 0 && b[2] == 0));
    real c[3] = {-0.5, 3, 4};
    projectConeBlock(0, c);
    CHECK((c[0] == 0 && c[1] == 0 && c[2] == 0));
    real d[3] = {2, 3, 4};
    projectConeBlock(0, d);
    CHECK((d[0] == 2 && d[1] == 0 && d[2] == 0));
    // on the boundary side: (gn, gt) = (0, 1), mu = 1 -> gn' = 1/2, gt' = 1/2
    real e[3] = {0, 0.6, 0.8};
    projectConeBlock(1, e);
    CHECK(e[0] == Approx(0.5).epsilon(1e-14));
    CHECK(e[1] == Approx(0.3).epsilon(1e-14));
    CHECK(e[2] == Approx(0.4).epsilon(1e-14));
  }
}

// ------------------------------------------------------------------------------------------- operators
TEST_CASE("contact problem operators equal the dense D^T M^-1 D", "[solver]") {
  Scene s = randomScene(11, 7, 15);
  ContactProblem cp;
  cp.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
  const refsolver::DenseCcp P = dense(s);
  REQUIRE(cp.size() == P.n);
  const double scaleN = maxAbs(P.N);
  // r
  CHECK(maxAbsDiff(cp.rhs(), std::vector<real>(P.r.begin(), P.r.end()).data(), P.n) <= 1e-13 * (1 + maxAbs(P.r)));
  // N x
  std::mt19937_64 rng(3);
  std::normal_distribution<double> G(0, 1);
  for (int t = 0; t < 3; ++t) {
    std::vector<real> x(P.n), y(P.n);
    std::vector<double> xd(P.n);
    for (int i = 0; i < P.n; ++i) x[i] = real(xd[i] = G(rng));
    cp.schur(x.data(), y.data());
    std::vector<double> yd = P.mul(xd);
    CHECK(maxAbsDiff(y.data(), std::vector<real>(yd.begin(), yd.end()).data(), P.n) <= 1e-12 * scaleN);
    // block inverse
    std::vector<real> z(P.n);
    cp.applyBlockInverse(x.data(), z.data());
    for (int k = 0; k < P.n / 3; ++k)
      for (int i = 0; i < 3; ++i) {
        double s2 = 0;
        for (int j = 0; j < 3; ++j) s2 += P.N[size_t(3 * k + i) * P.n + 3 * k + j] * z[3 * k + j];
        CHECK(s2 == Approx(x[3 * k + i]).margin(1e-9 * (1 + std::fabs(x[3 * k + i]))));
      }
  }
  // max diagonal
  double md = 0;
  for (int i = 0; i < P.n; ++i) md = std::max(md, P.N[size_t(i) * P.n + i]);
  CHECK(cp.maxDiagonal() == Approx(md).epsilon(1e-12));
  // applyImpulses: D^T (M^-1 D g) through the dense N equals D^T of the body changes
  std::vector<real> g(P.n);
  for (auto& v : g) v = real(G(rng));
  std::vector<Vec3> dv(s.bodies.count(), Vec3{0, 0, 0}), dw(s.bodies.count(), Vec3{0, 0, 0});
  cp.applyImpulses(g.data(), dv.data(), dw.data());
  CHECK((dv[0].x == 0 && dw[0].y == 0));  // the fixed body does not move
  // Velocity change projected on each contact must equal N g.
  std::vector<double> gd(g.begin(), g.end());
  std::vector<double> Ng = P.mul(gd);
  for (size_t k = 0; k < s.contacts.count(); ++k) {
    Vec3 n = s.contacts.normal[k], u, w;
    tangentBasis(n, u, w);
    const int a = s.contacts.body_a[k], b = s.contacts.body_b[k];
    const Vec3 rel = (dv[b] + cross(dw[b], s.contacts.pb[k] - s.bodies.pos[b])) -
                     (dv[a] + cross(dw[a], s.contacts.pa[k] - s.bodies.pos[a]));
    CHECK(dot(n, rel) == Approx(Ng[3 * k]).margin(1e-12 * scaleN * 10));
    CHECK(dot(u, rel) == Approx(Ng[3 * k + 1]).margin(1e-12 * scaleN * 10));
    CHECK(dot(w, rel) == Approx(Ng[3 * k + 2]).margin(1e-12 * scaleN * 10));
  }
}

// Float storage rounds each contact Jacobian to float and recomputes the tangent from the rounded normal
// (jacobian.h: roundJacobian, ContactJacobianF); the GPU's gather reads each side of it from a per-entry record
// (EntryJacobianF) and isotropic bodies' inverse masses from two numbers (BodyInverseIso). Checked against the
// definitions: an orthonormal frame within float rounding of the real one, a rounding that is a fixed point (the
// real and float copies of one step define the same rows), the entry record adding exactly the contact record's
// impulse, which is (P, r x P) with P = n g0 + u g1 + w g2, and R diag(d) R^T.
TEST_CASE("float Jacobians and the gather's compact records keep the contact rows and inverse masses", "[solver]") {
  std::mt19937_64 rng(41);
  std::uniform_real_distribution<double> U(-1, 1);
  double worst_angle = 0, worst_frame = 0;
  for (int t = 0; t < 2000; ++t) {
    const Vec3 n = randomUnit(rng);
    const Vec3 xa{U(rng), U(rng), U(rng)}, xb{U(rng), U(rng), U(rng)};
    const Vec3 pa = xa + Vec3{U(rng), U(rng), U(rng)} * 0.05, pb = pa + n * (0.001 * U(rng));
    const ContactJacobian J = makeContactJacobian(n, pa, pb, xa, xb, 3, 7);
    const ContactJacobian R = roundJacobian(J);
    // the frame: unit, orthogonal, near the real one
    const Vec3 w = cross(R.n, R.u);
    worst_frame = std::max({worst_frame, std::fabs(length(R.n) - 1), std::fabs(length(R.u) - 1),
                            std::fabs(length(w) - 1), std::fabs(dot(R.n, R.u))});
    worst_angle = std::max(worst_angle, length(cross(R.n, J.n)));
    CHECK(length(R.rA - J.rA) <= 1e-7 * length(J.rA));
    CHECK(length(R.rB - J.rB) <= 1e-7 * length(J.rB));
    // a fixed point: rounding the rounded Jacobian changes no bit
    const ContactJacobian R2 = roundJacobian(R);
    CHECK(std::memcmp(&R2.n, &R.n, sizeof(Vec3)) == 0);
    CHECK(std::memcmp(&R2.u, &R.u, sizeof(Vec3)) == 0);
    CHECK(std::memcmp(&R2.rA, &R.rA, sizeof(Vec3)) == 0);
    CHECK(std::memcmp(&R2.rB, &R.rB, sizeof(Vec3)) == 0);
    // each side's entry record adds the contact record's impulse, bit for bit, and that is (P, r x P)
    const ContactJacobianF f = toFloatJacobian(J);
    const real g[3] = {real(U(rng) + 1), real(U(rng)), real(U(rng))};
    for (int side = 0; side < 2; ++side) {
      Vec3 F1{0.5, -0.25, 1}, T1{0.125, 2, -1}, F2 = F1, T2 = T1, F3 = F1, T3 = T1, F4 = F1, T4 = T1;
      accumulateContactImpulse(R, side, g, F1, T1);
      accumulateEntryContactImpulse(entryJacobian(f, side), side, g, F2, T2);
      CHECK(std::memcmp(&F1, &F2, sizeof(Vec3)) == 0);
      CHECK(std::memcmp(&T1, &T2, sizeof(Vec3)) == 0);
      accumulateContactNormalImpulse(R, side, g[0], F3, T3);
      accumulateEntryNormalImpulse(entryJacobian(f, side), side, g[0], F4, T4);
      CHECK(std::memcmp(&F3, &F4, sizeof(Vec3)) == 0);
      CHECK(std::memcmp(&T3, &T4, sizeof(Vec3)) == 0);
      const double s = side ? 1 : -1;
      const Vec3 P = R.n * g[0] + R.u * g[1] + w * g[2], r = side ? R.rB : R.rA;
      CHECK(length(F1 - (Vec3{0.5, -0.25, 1} + P * s)) < 1e-12);
      CHECK(length(T1 - (Vec3{0.125, 2, -1} + cross(r, P) * s)) < 1e-12);
    }
  }
  INFO("worst frame defect " << worst_frame << ", worst normal rotation " << worst_angle << " rad");
  CHECK(worst_frame < 2e-7);
  CHECK(worst_angle < 1e-7);

  // inverse masses: R diag(d) R^T, exactly d I for equal principal values, whose 16-byte form gives the same deltas
  for (int t = 0; t < 500; ++t) {
    const Quat q = randomQuat(rng);
    const Mat33 M = matFromQuat(q);
    const bool iso = t % 2 == 0;
    const Vec3 d = iso ? Vec3{2.5, 2.5, 2.5} : Vec3{1 + U(rng), 2 + U(rng), 4 + U(rng)};
    const BodyInverseMass B = makeBodyInverseMass(0.75, d, q);
    const int ii[6] = {0, 1, 2, 0, 0, 1}, jj[6] = {0, 1, 2, 1, 2, 2};
    const Vec3 rows[3] = {M.r0, M.r1, M.r2};
    for (int e = 0; e < 6; ++e) {
      const Vec3 ri = rows[ii[e]], rj = rows[jj[e]];
      const double ref = ri.x * d.x * rj.x + ri.y * d.y * rj.y + ri.z * d.z * rj.z;
      CHECK(B.I[e] == Approx(ref).margin(1e-14));
    }
    const BodyInverseIso I = isoInverse(B);
    CHECK(I.m == 0.75);
    if (!iso) {
      CHECK(std::isnan(I.i));
      continue;
    }
    CHECK((B.I[0] == 2.5 && B.I[1] == 2.5 && B.I[2] == 2.5 && B.I[3] == 0 && B.I[4] == 0 && B.I[5] == 0));
    REQUIRE(I.i == 2.5);
    const Vec3 F{U(rng), U(rng), U(rng)}, T{U(rng), U(rng), U(rng)};
    const BodyDelta full = bodyDeltaFromImpulse(B, F, T), compact = bodyDeltaFromImpulse(I, F, T);
    CHECK(std::memcmp(&full, &compact, sizeof(BodyDelta)) == 0);
  }
  CHECK(std::isnan(isoInverse(BodyInverseMass{1, {1, 1, 1, 0, 1e-30, 0}}).i));
  CHECK(isoInverse(BodyInverseMass{0, {0, 0, 0, 0, 0, 0}}).i == 0);  // fixed bodies
}

// ------------------------------------------------------------------------------------------- solvers
namespace {
void checkAgainstReference(const CcpProblem& p, const refsolver::DenseCcp& P, bool unique, bool with_gs,
                           const char* what) {
  const std::vector<double> ref = refsolver::solve(P);
  INFO(what);
  REQUIRE(refsolver::kktViolation(P, ref) < 1e-9);
  const double fref = P.objective(ref);
  const std::vector<double> uref = [&] {
    std::vector<double> u = P.mul(ref);
    for (int i = 0; i < P.n; ++i) u[i] += P.r[i];
    return u;
  }();
  const double gs = 1 + maxAbs(ref), us = 1e-3 + maxAbs(uref);
  for (SolverType t : kAll) {
    if (t == SolverType::GaussSeidel && !with_gs) continue;
    INFO(solverName(t));
    std::vector<real> g(P.n, 0);
    SolverSettings s = tightSettings(t);
    SolverStats st = runSolver(t, p, g.data(), s);
    std::vector<double> gd(g.begin(), g.end());
    // the residual history decreases overall and ends near the tolerance
    REQUIRE(st.history.size() >= 2);
    CHECK(st.history.back() < 1e-3 * st.history.front());
    CHECK(st.residual < 1e-9);
    std::vector<real> scratch;
    CHECK(ccpResidual(p, g.data(), residualAlpha(p, s), scratch) == Approx(st.residual).epsilon(1e-6).margin(1e-12));
    CHECK(refsolver::kktViolation(P, gd) < 1e-7);
    CHECK(P.objective(gd) == Approx(fref).epsilon(1e-8).margin(1e-12));
    std::vector<double> u = P.mul(gd);
    for (int i = 0; i < P.n; ++i) CHECK(std::fabs(u[i] + P.r[i] - uref[i]) <= 1e-6 * us);
    if (unique)
      for (int i = 0; i < P.n; ++i) CHECK(std::fabs(gd[i] - ref[i]) <= 1e-6 * gs);
  }
}
}  // namespace

TEST_CASE("every solver reaches the dense reference on a random SPD CCP", "[solver]") {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> G(0, 1);
  std::uniform_real_distribution<double> U(0, 1);
  const int nc = 15, n = 3 * nc, m = 60;
  refsolver::DenseCcp P;
  P.n = n;
  std::vector<double> A(size_t(m) * n);
  for (auto& v : A) v = G(rng);
  P.N.assign(size_t(n) * n, 0.0);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      double s = 0;
      for (int k = 0; k < m; ++k) s += A[size_t(k) * n + i] * A[size_t(k) * n + j];
      P.N[size_t(i) * n + j] = s / m + (i == j ? 0.05 : 0.0);
    }
  P.r.resize(n);
  for (auto& v : P.r) v = G(rng);
  P.mu.resize(nc);
  for (int k = 0; k < nc; ++k) P.mu[k] = k % 5 == 0 ? 0.0 : U(rng);
  refsolver::DenseProblem p(P);
  checkAgainstReference(p, P, true, false, "random SPD");
}

TEST_CASE("every solver reaches the dense reference on random contact scenes", "[solver]") {
  // 8 contacts on 5 free bodies: D has full column rank, the solution is unique
  Scene s = randomScene(21, 6, 8);
  ContactProblem cp;
  cp.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
  checkAgainstReference(cp, dense(s), true, true, "random scene, unique");
}

// What a solver does not read is not assembled (ContactProblemSettings::jacobi_steps, block_inverses): asking for it
// throws. Gauss-Seidel keeps dv = M^-1 D gamma through its sweeps, and applyImpulses of its result uses that: it
// must equal a fresh gather of the same impulses (up to the rounding of the updates) on a scene whose contacts share
// bodies.
TEST_CASE("Gauss-Seidel's kept velocity changes equal a fresh gather, and unbuilt Jacobi steps are refused",
          "[solver]") {
  Scene s = randomScene(33, 12, 40, true);
  s.ps.jacobi_steps = false;
  s.ps.block_inverses = false;
  ContactProblem cp;
  cp.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
  CHECK_THROWS_AS(cp.jacobiSteps(), std::logic_error);
  CHECK_THROWS_AS(cp.blockInverses(), std::logic_error);
  SolverSettings st;
  st.type = SolverType::GaussSeidel;
  st.max_iterations = 10;
  st.tolerance = 0;
  st.record_history = false;
  std::vector<real> gam(size_t(cp.size()), 0);
  cp.solveGaussSeidel(gam.data(), st);
  const size_t nb = s.bodies.count();
  std::vector<Vec3> dv(nb, Vec3{0, 0, 0}), dw(nb, Vec3{0, 0, 0}), dv2 = dv, dw2 = dw;
  cp.applyImpulses(gam.data(), dv.data(), dw.data());  // the kept changes
  std::vector<real> copy = gam;
  cp.applyImpulses(copy.data(), dv2.data(), dw2.data());  // another vector: a fresh gather
  real scale = 0, worst = 0;
  for (size_t i = 0; i < nb; ++i) {
    scale = std::max(scale, std::max(length(dv2[i]), length(dw2[i])));
    worst = std::max(worst, std::max(length(dv[i] - dv2[i]), length(dw[i] - dw2[i])));
  }
  REQUIRE(scale > 0);
  CHECK(worst <= 1e-12 * scale);
  // The same problem built with them hands them out, each step positive and finite.
  s.ps.jacobi_steps = s.ps.block_inverses = true;
  ContactProblem full;
  full.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
  for (int k = 0; k < full.size() / 3; ++k) CHECK((full.jacobiSteps()[k] > 0 && std::isfinite(full.jacobiSteps()[k])));
  CHECK_NOTHROW(full.blockInverses());
}

// VectorStorage::Float (the GPU's default) on the CPU: APGD's Schur buffers hold the gradient N g + r rounded to
// float, the iterates stay real. Against the dense reference (an independent solver) the solution must reach
// float precision; Auto is real storage on the CPU (bitwise).
TEST_CASE("APGD with float storage reaches the dense reference to float precision", "[solver]") {
  if (sizeof(real) == sizeof(float)) return;  // a float build stores real = float anyway
  Scene sc = randomScene(21, 6, 8);
  ContactProblem cp;
  cp.build(sc.bodies, sc.contacts, sc.vf.data(), sc.wf.data(), sc.step, sc.solver, sc.ps);
  const refsolver::DenseCcp P = dense(sc);
  const std::vector<double> ref = refsolver::solve(P);
  REQUIRE(refsolver::kktViolation(P, ref) < 1e-9);
  const double gs = 1 + maxAbs(ref);
  std::vector<real> result[3];
  const VectorStorage kinds[3] = {VectorStorage::Real, VectorStorage::Float, VectorStorage::Auto};
  for (int m = 0; m < 3; ++m) {
    const bool rounded = kinds[m] == VectorStorage::Float;
    // error after 50, 100 and 400 iterations: float storage follows real storage until float rounding
    const int iters[3] = {50, 100, 400};
    for (int it : iters) {
      SolverSettings s;
      s.max_iterations = it;
      s.tolerance = 0;  // a fixed count
      s.storage = kinds[m];
      std::vector<real> g(size_t(P.n), 0);
      const SolverStats st = solveApgd(cp, g.data(), s);
      double err = 0;
      for (int i = 0; i < P.n; ++i) err = std::max(err, std::fabs(double(g[size_t(i)]) - ref[size_t(i)]) / gs);
      INFO((rounded ? "float" : "real") << " storage, " << it << " iterations: max |g - g_ref| / (1 + |g_ref|) " << err
                                        << ", residual " << st.residual);
      // measured: real 2.7e-4, 1.8e-6, 3.8e-10; float 2.7e-4, 1.9e-6, 2.3e-8
      CHECK(err < (it == 50 ? 5e-4 : it == 100 ? 4e-6 : rounded ? 1e-7 : 1e-9));
      if (it == 400) result[m] = g;
    }
  }
  CHECK(result[2] == result[0]);  // Auto is real storage on the CPU
  CHECK(result[1] != result[0]);  // float storage did round
}

// SolverSettings::apgd_speculation: the test pass computes the next trial's step for either outcome, and the next
// trial leaves out its step pass when the speculation came true. The oracle is the loop without speculation: every
// iterate, the residual history and the result must be bitwise the same, and the steps left out must be exactly
// the trials the counting predicts (every rejected trial with Both, never with None).
TEST_CASE("APGD's speculated steps give bitwise the iterates of the plain loop", "[solver]") {
  Scene sc = randomScene(21, 6, 8);
  ContactProblem cp;
  cp.build(sc.bodies, sc.contacts, sc.vf.data(), sc.wf.data(), sc.step, sc.solver, sc.ps);
  const ApgdSpeculation kinds[4] = {ApgdSpeculation::None, ApgdSpeculation::Accepted, ApgdSpeculation::Both,
                                    ApgdSpeculation::Auto};
  for (const VectorStorage storage : {VectorStorage::Real, VectorStorage::Float}) {
    std::vector<real> g[4];
    SolverStats st[4];
    for (int m = 0; m < 4; ++m) {
      SolverSettings s;
      s.max_iterations = 100;
      s.tolerance = 0;  // a fixed count
      s.storage = storage;
      s.record_history = true;
      s.apgd_speculation = kinds[m];
      g[m].assign(size_t(cp.size()), 0);
      st[m] = solveApgd(cp, g[m].data(), s);
    }
    INFO("storage " << (storage == VectorStorage::Real ? "real" : "float") << ": trials " << st[0].trials
                    << ", iterations " << st[0].iterations << ", speculated (accepted, both) " << st[1].speculated
                    << ", " << st[2].speculated);
    const int rejected = st[0].trials - st[0].iterations;
    REQUIRE(st[0].iterations == 100);
    REQUIRE(rejected > 0);  // the scene exercises the rejected outcome
    CHECK(st[0].speculated == 0);
    // accepted outcome: every accepted trial but the last (done) and the restarts with beta != 0
    CHECK(st[1].speculated > st[0].iterations / 2);
    CHECK(st[1].speculated <= st[0].iterations - 1);
    CHECK(st[2].speculated == st[1].speculated + rejected);  // and every rejected one (no 60-fold backtrack here)
    CHECK(st[3].speculated == st[1].speculated);             // Auto on the CPU: the accepted outcome
    for (int m = 1; m < 4; ++m) {
      CHECK(st[m].trials == st[0].trials);
      CHECK(st[m].iterations == st[0].iterations);
      CHECK(st[m].history == st[0].history);
      CHECK(g[m] == g[0]);
    }
  }
}

TEST_CASE("box resting on the ground with four contacts", "[solver]") {
  // Ground (fixed) and a box of half extents (0.5, 0.25, 0.3), mass 2, resting on its four bottom corners
  // with mu 0.5; gravity gives v_free = -g h. The impulses are not unique (four contacts, three
  // constrained DOFs), but the velocities are: the box stays (u = 0) and the normal impulses add up to
  // m g h.
  Scene s;
  const real m = 2, g = 9.81, h = 1e-3;
  const Vec3 half{0.5, 0.25, 0.3};
  addBody(s, {0, 0, 0}, quatIdentity(), 0, {0, 0, 0}, true);
  const Vec3 I{m / 3 * (half.y * half.y + half.z * half.z), m / 3 * (half.x * half.x + half.z * half.z),
               m / 3 * (half.x * half.x + half.y * half.y)};
  const Quat q = quatFromAxisAngle({0, 1, 0}, 0.3);  // turned about the vertical: still flat on the ground
  const Vec3 c{0.1, half.y, -0.2};
  addBody(s, c, q, m, I);
  s.vf[1] = {0, -g * h, 0};
  for (int sx = -1; sx <= 1; sx += 2)
    for (int sz = -1; sz <= 1; sz += 2) {
      const Vec3 p = c + rotate(q, Vec3{sx * half.x, -half.y, sz * half.z});
      addContact(s, 0, 1, {0, 1, 0}, {p.x, 0, p.z}, p, 0.5, 0.25);
    }
  s.step = makeStepContext(real(h));
  ContactProblem cp;
  cp.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
  const refsolver::DenseCcp P = dense(s);
  checkAgainstReference(cp, P, false, true, "box on 4 contacts");
  for (SolverType t : kAll) {
    INFO(solverName(t));
    std::vector<real> gam(P.n, 0);
    runSolver(t, cp, gam.data(), tightSettings(t));
    // Tangential impulses may hold each other in equilibrium (they are not unique either); their sum is 0.
    double sum_n = 0;
    Vec3 sum_t{0, 0, 0}, u, w;
    tangentBasis({0, 1, 0}, u, w);
    for (int k = 0; k < 4; ++k) sum_n += gam[3 * k], sum_t += u * gam[3 * k + 1] + w * gam[3 * k + 2];
    CHECK(sum_n == Approx(m * g * h).epsilon(1e-7));
    CHECK(length(sum_t) < 1e-10);
    std::vector<Vec3> dv(2, Vec3{0, 0, 0}), dw(2, Vec3{0, 0, 0});
    cp.applyImpulses(gam.data(), dv.data(), dw.data());
    CHECK(std::fabs(s.vf[1].y + dv[1].y) < 1e-9);
    CHECK(length(dw[1]) < 1e-8);
  }
}

namespace {
// A solid sphere (radius R, mass m) on fixed ground, contact point below the centre, normal +y.
Scene sphereOnGround(real m, real R, real mu, Vec3 v_free) {
  Scene s;
  addBody(s, {0, 0, 0}, quatIdentity(), 0, {0, 0, 0}, true);
  const real I = real(0.4) * m * R * R;
  addBody(s, {0, R, 0}, quatIdentity(), m, {I, I, I});
  s.vf[1] = v_free;
  addContact(s, 0, 1, {0, 1, 0}, {0, 0, 0}, {0, 0, 0}, mu, R);
  s.step = makeStepContext(real(1e-3));
  return s;
}
}  // namespace

TEST_CASE("sphere at rest on the ground: normal impulse m g h", "[solver]") {
  const real m = 0.7, R = 0.05, g = 9.81, h = 1e-3;
  for (real mu : {real(0), real(0.4)}) {
    Scene s = sphereOnGround(m, R, mu, {0, -g * h, 0});
    ContactProblem cp;
    cp.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
    for (SolverType t : kAll) {
      INFO(solverName(t) << " mu " << mu);
      std::vector<real> gam(3, 0);
      runSolver(t, cp, gam.data(), tightSettings(t));
      CHECK(gam[0] == Approx(m * g * h).epsilon(1e-9));
      CHECK(std::fabs(gam[1]) + std::fabs(gam[2]) < 1e-12);
    }
  }
}

TEST_CASE("sphere sliding and sticking on the ground: CCP friction impulse", "[solver]") {
  // Closed form of the CCP for one sphere contact. N = diag(1/m, Ntt, Ntt), Ntt = 1/m + R^2/I = 3.5/m;
  // r = (-g h, v_t, 0). Sliding: g_t = -mu g_n (opposing v_t) and, in the CCP relaxation (Anitescu &
  // Tasora 2010), u_n = mu |u_t| instead of u_n = 0:
  //   g_n / m - g h = mu (v_t - Ntt mu g_n)  =>  g_n = (g h + mu v_t) / (1/m + mu^2 Ntt),  |g_t| = mu g_n,
  // valid while v_t > Ntt mu g_n. As mu v_t -> 0 this is the complementarity model's mu m g h; the extra
  // mu v_t is the relaxation's known normal "hop" (it is what the CCP solves, so it is what we check).
  // Sticking (v_t < Ntt mu m g h): g_n = m g h, g_t = -v_t / Ntt.
  const real m = 1.3, R = 0.1, g = 9.81, h = 1e-3, mu = 0.3;
  const real Ntt = 1 / m + R * R / (real(0.4) * m * R * R);
  // Every solver on the sphere with velocity v: check(normal impulse, friction impulse in the world frame). The
  // contact's tangent basis is tangentBasis((0,1,0)), in which the solvers return the friction.
  auto solveEach = [&](const char* label, Vec3 v, auto check) {
    Scene s = sphereOnGround(m, R, mu, v);
    ContactProblem cp;
    cp.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
    Vec3 u, w;
    tangentBasis({0, 1, 0}, u, w);
    for (SolverType t : kAll) {
      INFO(label << " " << solverName(t));
      std::vector<real> gam(3, 0);
      runSolver(t, cp, gam.data(), tightSettings(t));
      check(gam[0], u * gam[1] + w * gam[2]);
    }
  };
  {
    const real vt = 0.2;
    const real gn = (g * h + mu * vt) / (1 / m + mu * mu * Ntt);
    REQUIRE(vt > Ntt * mu * gn);
    solveEach("sliding", {vt, -g * h, 0}, [&](real g_n, Vec3 ft) {
      CHECK(g_n == Approx(gn).epsilon(1e-8));
      CHECK(ft.x == Approx(-mu * gn).epsilon(1e-8));
      CHECK(std::fabs(ft.z) < 1e-10);
    });
  }
  {
    const real vt = 0.5 * Ntt * mu * m * g * h;
    solveEach("sticking", {0, -g * h, vt}, [&](real g_n, Vec3 ft) {
      CHECK(g_n == Approx(m * g * h).epsilon(1e-8));
      CHECK(ft.z == Approx(-vt / Ntt).epsilon(1e-7));
      CHECK(std::fabs(ft.x) < 1e-12);
    });
  }
}

TEST_CASE("warm start at the solution stays there, Inverse3x3 scaling converges on a resting stack", "[solver]") {
  // Three spheres stacked on the ground, frictionless: every block of N is diagonal with equal normal
  // entries along the stack, the block inverse and the scalar step share fixed points here.
  Scene s;
  const real m = 1, R = 0.1, g = 9.81, h = 1e-3, I = real(0.4) * m * R * R;
  addBody(s, {0, 0, 0}, quatIdentity(), 0, {0, 0, 0}, true);
  for (int i = 0; i < 3; ++i) {
    int b = addBody(s, {0, R + 2 * R * i, 0}, quatIdentity(), m, {I, I, I});
    s.vf[b] = {0, -g * h, 0};
    const Vec3 p{0, 2 * R * i, 0};
    addContact(s, b - 1, b, {0, 1, 0}, p, p, 0.0, R);
  }
  ContactProblem cp;
  cp.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
  for (SolverType t : {SolverType::Jacobi, SolverType::GaussSeidel}) {
    INFO(solverName(t));
    SolverSettings st = tightSettings(t);
    st.block_scaling = BlockScaling::Inverse3x3;
    std::vector<real> gam(9, 0);
    runSolver(t, cp, gam.data(), st);
    CHECK(gam[0] == Approx(3 * m * g * h).epsilon(1e-8));
    CHECK(gam[3] == Approx(2 * m * g * h).epsilon(1e-8));
    CHECK(gam[6] == Approx(1 * m * g * h).epsilon(1e-8));
  }
  for (SolverType t : kAll) {
    INFO("warm " << solverName(t));
    std::vector<real> gam = {real(3 * m * g * h), 0, 0, real(2 * m * g * h), 0, 0, real(m * g * h), 0, 0};
    SolverSettings st;
    st.tolerance = 1e-9;
    SolverStats r = runSolver(t, cp, gam.data(), st);
    CHECK(r.iterations == 0);
    CHECK(r.residual < 1e-9);
  }
}

TEST_CASE("solvers are bitwise identical with 1 and 2 threads", "[solver]") {
  // 6000 contacts on 3999 free bodies (18000 unknowns < 23994 DOFs): a bounded problem, 6 reduction blocks
  Scene s = randomScene(99, 4000, 6000, true);
  s.ps.threads = 1;
  ContactProblem p1, p2;
  p1.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
  s.ps.threads = 2;
  p2.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
  REQUIRE(p1.threads() == 1);
  REQUIRE(p2.threads() == 2);
  const size_t n = size_t(p1.size());
  REQUIRE(std::memcmp(p1.rhs(), p2.rhs(), n * sizeof(real)) == 0);
  std::vector<real> x(n), y1(n), y2(n);
  std::mt19937_64 rng(1);
  std::normal_distribution<double> G(0, 1);
  for (auto& v : x) v = real(G(rng));
  p1.schur(x.data(), y1.data());
  p2.schur(x.data(), y2.data());
  REQUIRE(std::memcmp(y1.data(), y2.data(), n * sizeof(real)) == 0);
  for (SolverType t : kAll) {
    INFO(solverName(t));
    for (BlockScaling bs : {BlockScaling::Scalar, BlockScaling::Inverse3x3}) {
      INFO("inverse3x3 " << (bs == BlockScaling::Inverse3x3));
      if (bs == BlockScaling::Inverse3x3 && (t == SolverType::APGD || t == SolverType::BB)) continue;
      SolverSettings st;
      st.max_iterations = 25;
      st.tolerance = 0;  // a fixed count
      st.record_history = true;
      st.block_scaling = bs;
      std::vector<real> g1(n, 0), g2(n, 0);
      for (size_t i = 0; i < n; i += 3) g1[i] = g2[i] = real(0.01);  // a warm start
      SolverStats a = runSolver(t, p1, g1.data(), st);
      SolverStats b = runSolver(t, p2, g2.data(), st);
      CHECK(std::memcmp(g1.data(), g2.data(), n * sizeof(real)) == 0);
      CHECK(a.residual == b.residual);
      CHECK(a.iterations == b.iterations);
      CHECK(a.history == b.history);
      // (Inverse3x3 may diverge on frictional problems, see solver.h: only determinism is checked for it)
      if (bs == BlockScaling::Scalar) CHECK(a.history.back() < a.history.front());
    }
  }
}

namespace {
// Objective f(g) = 1/2 g^T N g + r^T g through the problem's operator.
double objective(const CcpProblem& p, const std::vector<real>& g) {
  std::vector<real> Ng(g.size());
  p.schur(g.data(), Ng.data());
  double f = 0;
  for (size_t i = 0; i < g.size(); ++i) f += 0.5 * double(g[i]) * Ng[i] + double(p.rhs()[i]) * g[i];
  return f;
}
}  // namespace

TEST_CASE("disparate scales: no solver ends worse than its warm start or zero, residual drops", "[solver]") {
  // A mixed mm-grain pile as the narrow phase gives it: heavy and tiny bodies (inverse inertia 1e3 .. 1e8),
  // lever arms up to 20 x the body size (contact points off the surface), so diag(N) spans ~5 decades,
  // and a warm start from "last step" whose friction points the wrong way (rotated tangent bases).
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> U(0, 1);
  Scene s;
  addBody(s, {0, 0, 0}, quatIdentity(), 0, {0, 0, 0}, true);
  const int nb = 120;
  for (int i = 1; i < nb; ++i) {
    const bool tiny = i % 3 == 0;
    const real m = tiny ? real(5e-4) : real(0.05), I = tiny ? real(1e-8) : real(1e-4);
    int b = addBody(s, {U(rng) * 0.1, U(rng) * 0.1, U(rng) * 0.1}, randomQuat(rng), m, {I, I * 1.5, I * 0.7});
    s.vf[b] = {0.1 * (U(rng) - 0.5), -0.05, 0.1 * (U(rng) - 0.5)};
    s.wf[b] = {U(rng) - 0.5, U(rng) - 0.5, U(rng) - 0.5};
  }
  std::vector<real> warm;
  for (int k = 0; k < 400; ++k) {
    const int b = 1 + int(U(rng) * (nb - 1));
    int a = U(rng) < 0.2 ? 0 : std::max(0, b - 1 - int(U(rng) * 6));
    if (a == b) a = 0;
    const Vec3 n = randomUnit(rng);
    const real arm = b % 3 == 0 && U(rng) < 0.2 ? real(0.1) : real(0.004);  // a few off-surface points
    const Vec3 pb = s.bodies.pos[b] + randomUnit(rng) * arm;
    const Vec3 pa = pb + n * real(0.002 * U(rng));  // penetrating (dist < 0)
    addContact(s, a, b, n, pa, pb, real(0.2 + 0.4 * U(rng)), real(0.004));
    const real gn = real(2e-3 * U(rng));  // stale: about 100 x the impulses this step needs
    warm.insert(warm.end(), {gn, real(0.5 * gn * (U(rng) - 0.5)), real(0.5 * gn * (U(rng) - 0.5))});
  }
  s.step = makeStepContext(real(1e-3));
  s.solver.recovery_rel = 10;
  s.ps.threads = 2;
  ContactProblem cp;
  cp.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
  CHECK(cp.threads() == 1);  // a small problem runs serially
  std::vector<real> pw = warm;
  cp.project(pw.data());
  const double fw = objective(cp, pw);
  SolverSettings st;  // the defaults the system uses: 50 iterations
  std::vector<real> scratch;
  const real alpha = residualAlpha(cp, st);
  const real rw = ccpResidual(cp, pw.data(), alpha, scratch);
  for (SolverType t : {SolverType::Jacobi, SolverType::APGD, SolverType::BB}) {
    INFO(solverName(t));
    std::vector<real> g = warm;
    SolverStats r = runSolver(t, cp, g.data(), st);
    const double f = objective(cp, g);
    const real res = ccpResidual(cp, g.data(), alpha, scratch);
    INFO("f warm " << fw << " f out " << f << " res warm " << rw << " res out " << res);
    CHECK(f <= fw);
    CHECK(f <= 0);                 // no worse than the zero impulse: the solver injects no energy (before the fix: > 0)
    CHECK(res < real(1e-3) * rw);  // before the fix: 2e-3 .. 7e-3 (step set by the stiffest contact)
    CHECK(r.residual == Approx(res).epsilon(1e-9));
  }
}

TEST_CASE("solvers stop on non-finite values with SolverError", "[solver]") {
  Scene s = randomScene(3, 10, 20);
  s.vf[3].x = std::numeric_limits<real>::quiet_NaN();
  ContactProblem cp;
  cp.build(s.bodies, s.contacts, s.vf.data(), s.wf.data(), s.step, s.solver, s.ps);
  for (SolverType t : {SolverType::Jacobi, SolverType::APGD, SolverType::BB}) {
    INFO(solverName(t));
    std::vector<real> g(size_t(cp.size()), 0);
    CHECK_THROWS_AS(runSolver(t, cp, g.data(), SolverSettings{}), SolverError);
  }
  Scene s2 = randomScene(3, 10, 20);
  ContactProblem cp2;
  cp2.build(s2.bodies, s2.contacts, s2.vf.data(), s2.wf.data(), s2.step, s2.solver, s2.ps);
  for (SolverType t : {SolverType::Jacobi, SolverType::APGD, SolverType::BB}) {
    INFO("warm " << solverName(t));
    std::vector<real> g(size_t(cp2.size()), 0);
    g[4] = std::numeric_limits<real>::infinity();
    CHECK_THROWS_AS(runSolver(t, cp2, g.data(), SolverSettings{}), SolverError);
  }
}
