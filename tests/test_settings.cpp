// The settings are declared once (system.h: SystemConfig and its parts): scene files and CES files parse straight
// into those fields, and the per-step context carries the step to the plug-ins.
#include <catch2/catch.hpp>

#include <nlohmann/json.hpp>

#include "ces/ces_config.h"
#include "chrono_like/base/step_context.h"
#include "chrono_like/io/scene.h"
#include "chrono_like/system.h"

#include <omp.h>

using namespace dvi;
using nlohmann::json;

namespace {
SceneSettings parse(const char* text) { return parseSceneSettings(json::parse(text), "test"); }
}  // namespace

TEST_CASE("Settings: a scene's settings parse into the SystemConfig's fields", "[settings]") {
  const SceneSettings s = parse(R"({"dt": 0.002, "solver": "bb", "storage": "float", "collision": "bullet",
      "friction_combine": "min", "envelope_rel": 0.1, "recovery_rel": 5, "warm_start": false, "speculative": false,
      "mpr_manifold": false, "threads": 3, "gravity": [0, -1, 0]})");
  const SystemConfig& c = s.system;
  CHECK(c.step.dt == double(real(0.002)));
  CHECK(c.step.gravity.y == real(-1));
  CHECK(c.solver.type == SolverType::BB);
  CHECK(c.solver.storage == VectorStorage::Float);
  CHECK(c.solver.recovery_rel == real(5));
  CHECK_FALSE(c.solver.warm_start);
  CHECK(c.collision.backend == CollisionBackend::Bullet);
  CHECK(c.collision.friction_combine == FrictionCombine::Min);
  CHECK(c.collision.envelope_rel == real(0.1));
  CHECK_FALSE(c.collision.speculative);
  CHECK_FALSE(c.collision.mpr_manifold);
  CHECK(c.threads == 3);
}

TEST_CASE("Settings: an empty settings object gives SystemConfig's defaults", "[settings]") {
  const SystemConfig c = parse("{}").system, d;
  CHECK(c.step.dt == d.step.dt);
  CHECK(c.solver.type == d.solver.type);
  CHECK(c.solver.max_iterations == d.solver.max_iterations);
  CHECK(c.solver.tolerance == d.solver.tolerance);
  CHECK(c.solver.recovery_rel == d.solver.recovery_rel);
  CHECK(c.collision.envelope_rel == d.collision.envelope_rel);
  CHECK(c.collision.backend == d.collision.backend);
  CHECK(c.threads == d.threads);
}

TEST_CASE("Settings: iterations, max_iterations and tolerance combine into the stop in any order", "[settings]") {
  auto stop = [](const SceneSettings& s) {
    return std::make_pair(s.system.solver.max_iterations, s.system.solver.tolerance);
  };
  CHECK(stop(parse(R"({"iterations": 20})")) == std::make_pair(20, real(0)));  // a fixed count
  CHECK(stop(parse(R"({"iterations": 20, "tolerance": 0.01})")) == std::make_pair(20, real(0.01)));
  CHECK(stop(parse(R"({"iterations": 20, "max_iterations": 40})")) == std::make_pair(40, kDefaultTolerance));
  CHECK(stop(parse(R"({"max_iterations": 40})")) == std::make_pair(40, kDefaultTolerance));
  // The command line after the scene: --iterations keeps the scene's tolerance, --max-iterations the fixed count's
  // cap.
  SceneSettings a = parse(R"({"tolerance": 0.01})");
  a.setIterations(5);
  CHECK(stop(a) == std::make_pair(5, real(0.01)));
  SceneSettings b = parse(R"({"iterations": 20})");
  b.setMaxIterations(60);
  CHECK(stop(b) == std::make_pair(60, kDefaultTolerance));
  CHECK(b.iterations() == 20);
}

TEST_CASE("Settings: a CES document parses into the step and solver parts", "[settings][ces]") {
  const ces::CesConfig d = ces::parseCesDocument(json::parse(ces::defaultCesJson()), {}, "default");
  CHECK(d.step.dt == 2e-4);
  CHECK(d.solver.type == SolverType::APGD);
  CHECK(d.solver.max_iterations == 30);
  CHECK(d.solver.tolerance == 0);  // ces.solver.iterations is a fixed count
  CHECK(d.step.gyroscopic);
  const ces::CesConfig c = ces::parseCesDocument(
      json::parse(ces::defaultCesJson()),
      {"time_step_s=1e-4", "solver.type=jacobi", "solver.iterations=12", "solver.gyroscopic=false"}, "test");
  CHECK(c.step.dt == 1e-4);
  CHECK(c.solver.type == SolverType::Jacobi);
  CHECK(c.solver.max_iterations == 12);
  CHECK(c.solver.tolerance == 0);
  CHECK_FALSE(c.step.gyroscopic);
  CHECK_THROWS_WITH(ces::parseCesDocument(json::parse(ces::defaultCesJson()), {"solver.type=newton"}, "test"),
                    Catch::Contains("ces.solver.type") && Catch::Contains("unknown value \"newton\""));
}

TEST_CASE("Settings: the step context", "[settings]") {
  const StepContext c = makeStepContext(real(0.01), 2.0, 7);
  CHECK(c.dt == real(0.01));
  CHECK(c.inv_dt == real(1) / real(0.01));
  CHECK(c.step == 7);
  CHECK(c.end() == 2.0 + double(real(0.01)));
}

TEST_CASE("Settings: threads = 0 takes OpenMP's default team size (OMP_NUM_THREADS), not the core count",
          "[settings]") {
  // omp_set_num_threads sets the same value OMP_NUM_THREADS sets at start-up (the nthreads ICV).
  const int before = omp_get_max_threads();
  dvi::SystemConfig cfg;
  cfg.threads = 0;
  cfg.min_bodies_per_thread = 1;
  dvi::System sys(cfg);
  for (int i = 0; i < 64; ++i) {
    dvi::BodyDesc d;
    d.pos = dvi::Vec3{dvi::real(i), 0, 0};
    d.shapes.push_back(dvi::makeSphere(dvi::real(0.1)));
    sys.addBody(d);
  }
  omp_set_num_threads(1);
  CHECK(sys.effectiveThreads() == 1);
  omp_set_num_threads(3);
  CHECK(sys.effectiveThreads() == 3);
  cfg.threads = 2;
  dvi::System two(cfg);
  for (int i = 0; i < 64; ++i) {
    dvi::BodyDesc d;
    d.shapes.push_back(dvi::makeSphere(dvi::real(0.1)));
    two.addBody(d);
  }
  CHECK(two.effectiveThreads() == 2);  // an explicit count stands whatever the default is
  omp_set_num_threads(before);
}
