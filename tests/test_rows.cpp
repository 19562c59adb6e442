// Generic constraint rows (constraint_row.h) solved with the contacts: checks against closed forms.
#include <catch2/catch.hpp>

#include <cmath>
#include <memory>
#include <vector>

#include "chrono_like/system.h"
#include "rows_test_util.h"

using namespace dvi;
using namespace rowstest;

TEST_CASE("a body held by three bilateral rows carries its weight: impulse m g h, no motion", "[rows]") {
  for (SolverType t : {SolverType::APGD, SolverType::Jacobi, SolverType::BB, SolverType::GaussSeidel}) {
    SystemConfig cfg;
    cfg.step.dt = real(0.01);
    cfg.solver.type = t;
    cfg.solver.max_iterations = 200;
    cfg.solver.tolerance = 0;  // a fixed count: the answer to 1e-6
    System sys(cfg);
    const real m = 2;
    const int b = sys.addBody(freeBox(Vec3{0, 1, 0}, m));
    auto pin = std::make_shared<PinToGround>(b, Vec3{0, 1, 0});
    sys.addRowProvider(pin);
    sys.step();
    // Gravity pulls -y: the y row pushes +y with m g h (Ja = +e_y on the body, as "b" side).
    CHECK(pin->last[1] == Approx(m * 9.81 * cfg.step.dt).epsilon(1e-6));
    CHECK(std::fabs(pin->last[0]) < 1e-9);
    CHECK(std::fabs(pin->last[2]) < 1e-9);
    CHECK(length(sys.bodies().vel[b]) < 1e-9);
    REQUIRE(sys.rowImpulses().size() == 3);
  }
}

TEST_CASE("a velocity drive with a torque limit: exact target when reachable, limit-bounded otherwise", "[rows]") {
  // A free wheel (inertia I about z) driven by one row w_z = target with |impulse| <= tau h:
  // omega after one step = min(target, tau h / I) (Tasora & Anitescu 2011, box-bounded rows).
  const real I = real(0.5), h = real(0.01);
  for (real tau : {real(1000), real(10)}) {
    SystemConfig cfg;
    cfg.step.dt = h;
    cfg.step.gravity = Vec3{0, 0, 0};
    cfg.solver.tolerance = real(1e-10);  // the answer to 1e-6 (relative residual)
    System sys(cfg);
    BodyDesc d = freeBox(Vec3{0, 0, 0}, 1);
    d.inertia = Vec3{I, I, I};
    const int b = sys.addBody(d);
    auto drive = std::make_shared<SpinDrive>(b, real(3), tau);
    sys.addRowProvider(drive);
    sys.step();
    const real expect = std::fmin(real(3), tau * h / I);
    CHECK(sys.bodies().omega[b].z == Approx(expect).epsilon(1e-6));
  }
}
