// Leaving out what a scene does not need (docs/MODEL.md §6): the normal-only CCP of a frictionless
// step against the full three-row problem (the existing, tested code path: with mu = 0 its tangential
// impulses are projected to 0, so both must reach the same solution), a mixed scene, and the stage list.
#include <catch2/catch.hpp>

#include <cmath>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "chrono_like/system.h"
#include "rows_test_util.h"

using namespace dvi;

namespace {

// Spheres r = 1 cm on a ground plane in a loose lattice: each rests on the one below inside the collision
// envelope, neighbours in a layer 2.3 r apart (+- jitter), so there are fewer contacts than degrees of
// freedom and the frictionless CCP has one solution (impulses and velocities).
void buildPile(System& sys, int n, real friction_a, real friction_b, unsigned seed = 5) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jit(-0.1, 0.1);
  BodyDesc g;
  g.mass = 0;
  g.flags = kBodyFixed;
  g.friction = friction_a;
  g.shapes.push_back(makePlane(Vec3{0, 1, 0}, 0));
  sys.addBody(g);
  const real r = real(0.01);
  const int side = 4;
  for (int i = 0; i < n; ++i) {
    const int layer = i / (side * side), c = i % (side * side);
    BodyDesc b;
    b.mass = real(0.0105);
    const real I = real(0.4) * b.mass * r * r;
    b.inertia = Vec3{I, I, I};
    b.friction = (i % 2) ? friction_b : friction_a;
    b.pos = Vec3{real((c % side) * 2.3 * r + jit(rng) * r), real(r * (1 + 2.001 * layer) - 0.0002 * r),
                 real((c / side) * 2.3 * r + jit(rng) * r)};
    b.vel = Vec3{0, real(-0.05), 0};
    b.shapes.push_back(makeSphere(r));
    sys.addBody(b);
  }
}

double relDiff(const std::vector<double>& a, const std::vector<double>& b) {
  double num = 0, den = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    num += (a[i] - b[i]) * (a[i] - b[i]);
    den += b[i] * b[i];
  }
  return std::sqrt(num / std::max(den, 1e-300));
}

std::vector<double> velocities(const System& s) {
  std::vector<double> v;
  for (size_t i = 0; i < s.bodies().count(); ++i)
    for (const Vec3& x : {s.bodies().vel[i], s.bodies().omega[i]}) {
      v.push_back(x.x);
      v.push_back(x.y);
      v.push_back(x.z);
    }
  return v;
}

}  // namespace

TEST_CASE("frictionless pile: the normal-only CCP gives the three-row problem's impulses and velocities",
          "[pruning][solver]") {
  const bool dbl = sizeof(real) == 8;
  for (SolverType t : {SolverType::Jacobi, SolverType::GaussSeidel, SolverType::APGD, SolverType::BB}) {
    SECTION(solverName(t)) {
      SystemConfig cfg;
      cfg.solver.type = t;
      cfg.solver.max_iterations = t == SolverType::Jacobi ? 20000 : 4000;
      cfg.solver.tolerance = real(dbl ? 1e-11 : 1e-5);
      cfg.threads = 1;
      SystemConfig full = cfg;
      full.prune = false;
      System a(cfg), b(full);
      buildPile(a, 40, 0, 0);
      buildPile(b, 40, 0, 0);
      for (int step = 0; step < 3; ++step) {  // the later steps are warm-started (through the 3-per-contact layout)
        a.step();
        b.step();
        INFO(solverName(t) << " step " << step << ": iterations " << a.lastStats().iterations << " / "
                           << b.lastStats().iterations << ", residual " << a.lastStats().residual << " / "
                           << b.lastStats().residual);
        REQUIRE(a.contacts().count() >= 40);  // 16 on the ground, 24 between the layers
        REQUIRE(a.contacts().key == b.contacts().key);
        CHECK(a.lastStats().normal_only);
        CHECK_FALSE(b.lastStats().normal_only);
        CHECK_FALSE(a.lastStats().part_ran[int(StagePart::FrictionRows)]);
        CHECK(b.lastStats().part_ran[int(StagePart::FrictionRows)]);
        const std::vector<real>& ga = a.impulses();
        const std::vector<real>& gb = b.impulses();
        REQUIRE(ga.size() == gb.size());
        std::vector<double> na, nb;
        double tang = 0, tang_a = 0, nmax = 0;
        for (size_t k = 0; k < a.contacts().count(); ++k) {
          na.push_back(ga[3 * k]);
          nb.push_back(gb[3 * k]);
          nmax = std::max(nmax, double(gb[3 * k]));
          tang = std::max({tang, std::fabs(double(gb[3 * k + 1])), std::fabs(double(gb[3 * k + 2]))});
          tang_a = std::max({tang_a, std::fabs(double(ga[3 * k + 1])), std::fabs(double(ga[3 * k + 2]))});
        }
        CHECK(nmax > 0);
        CHECK(tang == 0);    // the three-row problem with mu = 0: the cone projection zeroes them
        CHECK(tang_a == 0);  // the normal-only problem reports them as 0
        const double eg = relDiff(na, nb), ev = relDiff(velocities(a), velocities(b));
        INFO("relative differences: normal impulses " << eg << ", velocities " << ev);
        CHECK(eg < (dbl ? 1e-6 : 1e-2));
        CHECK(ev < (dbl ? 1e-8 : 1e-3));
      }
    }
  }
}

TEST_CASE("a pruned frictional or mixed pile steps exactly as the unpruned one", "[pruning][physics]") {
  // Product rule: a contact touching a mu = 0 body is frictionless, two mu = 0.5 bodies give 0.25. A step with
  // any mu > 0 contact keeps the three rows for every contact, so the pruned run is the unpruned one up to the
  // gyroscopic term of spheres that prune = false evaluates (w x I w = 0 up to rounding), and the frictionless
  // contacts have no tangential impulse.
  SystemConfig cfg;
  cfg.threads = 1;
  SystemConfig full = cfg;
  full.prune = false;
  System a(cfg), b(full);
  buildPile(a, 48, 0, real(0.5));
  buildPile(b, 48, 0, real(0.5));
  int mixed_steps = 0;
  for (int s = 0; s < 20; ++s) {
    a.step();
    b.step();
    CHECK_FALSE(a.lastStats().normal_only);
    bool has0 = false, has_mu = false;
    for (size_t k = 0; k < a.contacts().count(); ++k) {
      const real mu = a.contacts().mu[k];
      has0 = has0 || mu == 0;
      has_mu = has_mu || mu > 0;
      if (mu == 0) {
        CHECK(a.impulses()[3 * k + 1] == 0);
        CHECK(a.impulses()[3 * k + 2] == 0);
      }
    }
    mixed_steps += has0 && has_mu;
  }
  CHECK(mixed_steps == 20);
  const double ev = relDiff(velocities(a), velocities(b));
  INFO("velocity difference pruned / unpruned " << ev);
  CHECK(ev < (sizeof(real) == 8 ? 1e-9 : 1e-3));
  CHECK(a.lastStats().part_ran[int(StagePart::FrictionRows)]);
  // The bodies moved and stay above the ground (the scene did something).
  real ymin = 1;
  for (size_t i = 1; i < a.bodies().count(); ++i) ymin = std::fmin(ymin, a.bodies().pos[i].y);
  CHECK(ymin > real(0.009));
}

TEST_CASE("the stage list reflects the scene", "[pruning]") {
  auto ran = [](const System& s, StagePart p) { return s.lastStats().part_ran[int(p)]; };
  auto why = [](const System& s, StagePart p) {
    const char* r = s.lastStats().part_reason[int(p)];
    return std::string(r ? r : "");
  };
  SECTION("frictionless spheres: no friction rows, rows, fields, gyroscopic term or MPR") {
    System s;
    buildPile(s, 16, 0, 0);
    s.step();
    s.step();
    for (StagePart p : {StagePart::ForceFields, StagePart::Gyroscopic, StagePart::Mpr, StagePart::ConstraintRows,
                        StagePart::FrictionRows, StagePart::RollingSpinningRows}) {
      INFO(stagePartName(p));
      CHECK_FALSE(ran(s, p));
      CHECK_FALSE(why(s, p).empty());
    }
    CHECK(why(s, StagePart::FrictionRows) == "no contact with mu > 0 this step");
    CHECK(s.lastStats().stage_ran[int(StageType::Solve)]);
    CHECK(s.lastStats().stage_ran[int(StageType::WarmStart)]);
    CHECK(std::string(stagePartName(StagePart::FrictionRows)) == "BuildRows.FrictionRows");
    CHECK(stageOfPart(StagePart::Mpr) == StageType::NarrowPhase);
  }
  SECTION("prune = false runs every part the engine has") {
    SystemConfig cfg;
    cfg.prune = false;
    System s(cfg);
    buildPile(s, 16, 0, 0);
    s.step();
    for (StagePart p :
         {StagePart::ForceFields, StagePart::Gyroscopic, StagePart::ConstraintRows, StagePart::FrictionRows})
      CHECK(ran(s, p));
    CHECK_FALSE(ran(s, StagePart::RollingSpinningRows));  // not in the engine
    CHECK_FALSE(ran(s, StagePart::Mpr));                  // a per-pair choice: spheres have a closed form
  }
  SECTION("a box brings the gyroscopic term, an ellipsoid MPR, a joint the constraint rows, friction its rows") {
    System s;
    buildPile(s, 4, real(0.5), real(0.5));
    s.step();
    CHECK(ran(s, StagePart::FrictionRows));
    CHECK_FALSE(ran(s, StagePart::Gyroscopic));
    const int cube = s.addBody(rowstest::freeBox(Vec3{1, 1, 1}, 1));  // a cube's inertia is spherical
    s.step();
    CHECK_FALSE(ran(s, StagePart::Gyroscopic));
    BodyDesc flat = rowstest::freeBox(Vec3{-1, 1, -1}, 1);
    flat.inertia = Vec3{1, 2, 3};
    s.addBody(flat);
    s.step();
    CHECK(ran(s, StagePart::Gyroscopic));
    CHECK_FALSE(ran(s, StagePart::Mpr));  // sphere-box and box-plane have closed forms
    BodyDesc e;
    e.pos = Vec3{2, 1, 2};
    e.mass = 1;
    e.shapes.push_back(makeEllipsoid(Vec3{real(0.1), real(0.05), real(0.08)}));
    s.addBody(e);
    s.step();
    CHECK(ran(s, StagePart::Mpr));
    CHECK_FALSE(ran(s, StagePart::ConstraintRows));
    s.addRowProvider(std::make_shared<rowstest::PinToGround>(cube, Vec3{1, 1, 1}));
    s.step();
    CHECK(ran(s, StagePart::ConstraintRows));
    CHECK(s.constraintRows().size() == 3);
  }
  SECTION("no contacts: BuildRows, WarmStart and Solve are left out with a reason") {
    System s;
    BodyDesc b;
    b.pos = Vec3{0, 5, 0};
    b.shapes.push_back(makeSphere(real(0.1)));
    s.addBody(b);
    s.step();
    for (StageType t : {StageType::BuildRows, StageType::WarmStart, StageType::Solve}) {
      CHECK_FALSE(s.lastStats().stage_ran[int(t)]);
      REQUIRE(s.lastStats().stage_reason[int(t)] != nullptr);
    }
    CHECK(s.lastStats().stage_ran[int(StageType::NarrowPhase)]);
    CHECK(why(s, StagePart::FrictionRows) == "no contacts");
  }
}
