// The time step from one source (SystemConfig::step.dt, each step's StepContext): two different steps through the
// `dvisim` command line (a scene's settings.dt and --dt; the CES run's --dt), the CES machine and the Bullet drop-in
// world, each checked against the analytic free fall of the semi-implicit (symplectic) Euler step the engine takes
// (docs/MODEL.md §2: v+ = v + h g, x+ = x + h v+): after N steps of h from rest,
//   v_N = -g N h,   y_N = y_0 - g h^2 N (N + 1) / 2.
// A step read from anywhere but the one source (a default, a stale copy) moves the body by a different amount.
#include <catch2/catch.hpp>

#include <cmath>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include <nlohmann/json.hpp>

#include "bullet_test_world.h"
#include "ces/ces_config.h"
#include "ces/feeder.h"
#include "ces/machine.h"
#include "chrono_like/system.h"
#include "cli_test_util.h"
#include "device_check.h"
#include "gpu/gpu_factory.h"

using namespace dvi;
using namespace dvi::ces;
using namespace clitest;
using json = nlohmann::json;

namespace {

// The analytic state after n steps of h from rest at height y0 under gravity g (pointing down).
struct Fall {
  double y, v;
};
Fall symplecticEulerFall(double y0, double g, double h, int64_t n) {
  const double N = double(n);
  return Fall{y0 - g * h * h * N * (N + 1) / 2, -g * N * h};
}

// Rounding of the engine's numbers: double unless built with DVISIM_SINGLE_PRECISION.
constexpr double kTol = std::is_same<real, float>::value ? 2e-5 : 1e-10;

const double kG = double(real(9.81));  // the default gravity, in the engine's precision

// One sphere in free fall (no ground), 1 m up, step 1e-3 s unless the command line says otherwise.
const char* kFallScene = R"({
  "name": "fall",
  "settings": { "dt": 0.001, "steps": 10 },
  "bodies": [ { "name": "ball", "shape": { "type": "sphere", "radius": 0.1 }, "mass": 1, "position": [0, 1, 0] } ]
})";

// Column `col` of body `id` in a bodies.csv (id,x,y,z,qw,qx,qy,qz,vx,vy,vz,...).
double csvValue(const std::string& csv, int id, int col) {
  std::istringstream in(csv);
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream ls(line);
    for (std::string x; std::getline(ls, x, ',');) f.push_back(x);
    if (!f.empty() && std::stoi(f[0]) == id) return std::stod(f[size_t(col)]);
  }
  FAIL("body " << id << " not in bodies.csv");
  return 0;
}

}  // namespace

TEST_CASE("dt: the dvisim CLI steps a free fall with the scene's dt and with --dt", "[dt][cli]") {
  const fs::path d = tempDir("dt_cli");
  spit(d / "fall.json", kFallScene);
  const std::string scene = quote((d / "fall.json").string());
  struct Case {
    std::string args;
    double dt;
    int64_t steps;
  };
  // The scene's settings.dt (1e-3, 10 steps), --dt (4e-3, 25 steps), --set settings.dt (2.5e-3, 8 steps).
  for (const Case& c : {Case{"", 1e-3, 10}, Case{" --dt 0.004 --steps 25", 4e-3, 25},
                        Case{" --set settings.dt=0.0025 --steps 8", 2.5e-3, 8}}) {
    const fs::path out = d / ("out" + std::to_string(c.steps));
    const CliResult r = runCli("run " + scene + " --backend cpu" + c.args + " --out " + quote(out.string()));
    INFO("dvisim run" << c.args << "\n" << r.out << r.err);
    REQUIRE(r.code == 0);
    const json j = json::parse(slurp(out / "summary.json"));
    CHECK(j["steps"] == c.steps);
    CHECK(j["dt"].get<double>() == double(real(c.dt)));
    CHECK(j["sim_time"].get<double>() == Approx(double(c.steps) * c.dt).epsilon(1e-12));
    const std::string csv = slurp(out / "bodies.csv");
    const Fall f = symplecticEulerFall(1.0, kG, double(real(c.dt)), c.steps);
    CHECK(std::fabs(csvValue(csv, 0, 2) - f.y) <= kTol);  // y
    CHECK(std::fabs(csvValue(csv, 0, 9) - f.v) <= kTol);  // vy
  }
  fs::remove_all(d);
}

TEST_CASE("dt: the CES CLI's --dt sets ces.time_step_s as a number, which the run and its checkpoint use",
          "[dt][cli][ces]") {
  const fs::path d = tempDir("dt_ces_cli");
  const std::string base =
      "run --backend cpu --set field.model=\\\"csm\\\" --set output.plots=false "
      "--set feed.mass_flow_g_s=0";
  for (const auto& [dt, steps] : {std::pair<double, int64_t>{1e-4, 20}, std::pair<double, int64_t>{3e-4, 7}}) {
    const fs::path out = d / ("out" + std::to_string(steps));
    std::ostringstream arg;
    arg.precision(17);
    arg << dt;
    const CliResult r =
        runCli(base + " --dt " + arg.str() + " --steps " + std::to_string(steps) + " --out " + quote(out.string()));
    INFO(r.out << r.err);
    REQUIRE(r.code == 0);
    const json j = json::parse(slurp(out / "summary.json"));
    CHECK(j["dt"].get<double>() == dt);  // exactly the number given
    CHECK(j["steps"] == steps);
    CHECK(j["sim_time"].get<double>() == Approx(double(steps) * dt).epsilon(1e-12));
    const json cfg = json::parse(slurp(out / "checkpoint" / "ces_config.json"));
    CHECK(cfg["ces"]["time_step_s"].get<double>() == dt);
  }
  // Two settings of the one step: refused by name.
  expectInputError(base + " --dt 1e-4 --set time_step_s=2e-4 --steps 1 --out " + quote((d / "x").string()),
                   "--dt and --set time_step_s");
  expectInputError(base + " --dt 0 --steps 1 --out " + quote((d / "x").string()), "--dt");
  fs::remove_all(d);
}

TEST_CASE("dt: the CES machine steps with its configuration's time_step_s, a dropped particle falls as analytic",
          "[dt][ces]") {
  // No field (supply off), no air (viscosity 1e-30 Pa s, density 0: drag ~1e-36 N), no feed: a particle 0.35 m left of
  // the drum axis, clear of every machine part, falls freely.
  for (const auto& [dt, steps] : {std::pair<double, int64_t>{1e-4, 200}, std::pair<double, int64_t>{4e-4, 50}}) {
    INFO("time_step_s " << dt);
    std::ostringstream set;
    set.precision(17);
    set << "time_step_s=" << dt;
    const CesConfig cfg =
        parseCesDocument(json::parse(defaultCesJson()),
                         {"feed.mass_flow_g_s=0", "electrode.voltage_kV=0", "electrode.wire.enabled=false",
                          "field.model=two_cylinder", "air.viscosity_Pa_s=1e-30", "air.density_kg_m3=0", set.str()},
                         "<test>");
    REQUIRE(cfg.step.dt == dt);
    System sys(SystemConfig{});  // its own dt (1e-3) differs: the machine's step is the configuration's
    CesMachine m(cfg, sys);
    CHECK(sys.config().step.dt == dt);
    SplitMix64 rng;
    const ParticleSpec s = makeParticleSpec(0, ParticleShape::Sphere, 1e-3, 946, rng);
    const double y0 = 0.3;
    const int id = m.addParticle(s, Vec3{real(-0.35), real(y0), 0}, Quat{1, 0, 0, 0}, Vec3{0, 0, 0}, Vec3{0, 0, 0});
    for (int64_t k = 0; k < steps; ++k) m.step();
    CHECK(m.steps() == steps);
    CHECK(sys.stepCount() == steps);
    CHECK(sys.stepContext().dt == real(dt));
    CHECK(m.time() == Approx(double(steps) * dt).epsilon(1e-12));
    CHECK(sys.time() == Approx(double(steps) * dt).epsilon(1e-6));
    const Fall f = symplecticEulerFall(double(real(y0)), kG, double(real(dt)), steps);
    CHECK(std::fabs(double(sys.bodies().pos[size_t(id)].y) - f.y) <= kTol);
    CHECK(std::fabs(double(sys.bodies().vel[size_t(id)].y) - f.v) <= kTol);
    CHECK(m.particles().status[size_t(id)] == kStatusInFlight);
  }
}

TEST_CASE("dt: the drop-in world steps with Bullet's fixed step (sub-steps) and with a variable step", "[dt][dropin]") {
  // Bullet's stepSimulation(timeStep, maxSubSteps, fixedTimeStep) is the public setter: each internal step of h
  // writes h into SystemConfig::step.dt. Steps that are powers of two keep Bullet's float clock exact.
  struct Case {
    btScalar frame;
    int max_substeps;
    btScalar fixed;
    int frames;
    double h;
    int64_t steps;
  };
  const Case cases[] = {{btScalar(1) / 64, 10, btScalar(1) / 256, 6, 1.0 / 256, 24},        // 4 sub-steps a frame
                        {btScalar(0.01), 0, btScalar(0), 20, double(btScalar(0.01)), 20}};  // one step of 0.01 s
  for (const Case& c : cases) {
    INFO("h = " << c.h);
    TestWorld w(true);
    btRigidBody* ball = w.make(w.own(new btSphereShape(btScalar(0.1))), 1, btVector3(0, 1, 0));
    for (int i = 0; i < c.frames; ++i) w.world->stepSimulation(c.frame, c.max_substeps, c.fixed);
    const System& sys = w.dvi().system();
    CHECK(sys.stepCount() == c.steps);
    CHECK(sys.stepContext().dt == real(c.h));
    CHECK(sys.config().step.dt == double(real(c.h)));
    const double g = double(real(btScalar(9.81)));
    const Fall f = symplecticEulerFall(1.0, g, double(real(c.h)), c.steps);
    // Bullet's transform is float: its rounding, 1e-7 of a metre.
    CHECK(std::fabs(double(ball->getWorldTransform().getOrigin().y()) - f.y) <= 1e-6);
    CHECK(std::fabs(double(ball->getLinearVelocity().y()) - f.v) <= 1e-6);
  }
}

TEST_CASE("dt: the GPU backend steps with the System's step, changed between steps, as the CPU backend does",
          "[dt][gpu]") {
  // A ball 0.3 m up falls onto a plane: 150 steps of 1e-3 s in free fall (checked against the analytic answer), then
  // the step set to 4e-3 s between steps (as the drop-in world does) and 60 more: it lands and rests at y = r. The
  // GPU's speculative sweep, narrow phase and contact bias read h from the step's context; the CPU backend is the
  // reference (the same closed-form sphere-plane contact, APGD with a fixed iteration count in real storage).
  if (!dvi::testing::haveDevice()) return;
  SystemConfig c;
  c.step.dt = 1e-3;
  c.solver.type = SolverType::APGD;
  c.solver.max_iterations = 50;
  c.solver.tolerance = 0;
  c.solver.storage = VectorStorage::Real;
  const real r = real(0.1), y0 = real(0.3);
  auto build = [&](System& s) {
    BodyDesc ground;
    ground.mass = 0;
    ground.flags = kBodyFixed;
    ground.shapes.push_back(makePlane(Vec3{0, 1, 0}, 0));
    s.addBody(ground);
    BodyDesc ball;
    ball.pos = Vec3{0, y0, 0};
    ball.mass = 1;
    ball.inertia = Vec3{real(0.004), real(0.004), real(0.004)};
    ball.shapes.push_back(makeSphere(r));
    return s.addBody(ball);
  };
  System cpu(c);
  std::unique_ptr<System> gpu = makeGpuSystem(c);
  const int a = build(cpu), b = build(*gpu);
  cpu.advance(150);
  gpu->advance(150);
  gpu->syncToHost();
  const Fall f = symplecticEulerFall(double(y0), kG, double(real(1e-3)), 150);
  CHECK(std::fabs(double(gpu->bodies().pos[size_t(b)].y) - f.y) <= kTol);
  CHECK(std::fabs(double(gpu->bodies().vel[size_t(b)].y) - f.v) <= kTol);
  cpu.mutableConfig().step.dt = 4e-3;
  gpu->mutableConfig().step.dt = 4e-3;
  cpu.advance(60);
  gpu->advance(60);
  gpu->syncToHost();
  CHECK(gpu->stepContext().dt == real(4e-3));
  CHECK(gpu->time() == Approx(0.15 + 60 * 4e-3).epsilon(1e-9));
  const Vec3 pc = cpu.bodies().pos[size_t(a)], pg = gpu->bodies().pos[size_t(b)];
  const Vec3 vc = cpu.bodies().vel[size_t(a)], vg = gpu->bodies().vel[size_t(b)];
  CHECK(std::fabs(double(pc.y) - double(r)) < 1e-3);  // resting on the plane
  CHECK(std::fabs(double(pg.y) - double(pc.y)) <= 1e-9);
  CHECK(std::fabs(double(vg.y) - double(vc.y)) <= 1e-9);
}
