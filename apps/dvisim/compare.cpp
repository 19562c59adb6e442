// dvisim compare SCENE: steps one scene with Bullet's own btDiscreteDynamicsWorld and with dvisim's drop-in
// world (dvi::DviDynamicsWorld) on the CPU and, when a device is present, the GPU backend, side by side, and
// reports per-body and aggregate differences against Bullet (positions, velocities), each engine's energy,
// deepest penetration and run time, as text and compare.csv.
//
// Every engine gets the scene through Bullet's API: a .bullet file through btBulletWorldImporter (bodies and
// constraints), a .json scene (or the embedded default) through Scene, whose btRigidBody objects are added to
// the world. Penetration is read from each world's persistent manifolds (ours fills them too), so the three
// are measured the same way. Bullet runs in the scene's units (no rescaling: the comparison is of what a
// Bullet app would get).
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <btBulletDynamicsCommon.h>
#include <btBulletWorldImporter.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "chrono_like/bullet/bullet_world.h"
#include "chrono_like/io/scene.h"
#include "gpu/gpu_factory.h"
#include "cli_options.h"
#include "parse.h"

namespace {

using dvi::InputError;

struct CompareOptions : dvi::RunOverrides {
  std::string scene;
  std::vector<std::string> sets;
  std::string out = "dvisim-out";
};

struct BodyState {
  btVector3 x, v;
};

struct EngineResult {
  std::string name, device;
  bool ran = false;
  std::string skipped;  // why not
  std::vector<BodyState> bodies;
  double energy = 0, penetration = 0, wall = 0;
  int64_t steps = 0;
};

// One engine's world with the scene loaded into it.
struct EngineWorld {
  btDefaultCollisionConfiguration config;
  btCollisionDispatcher dispatcher{&config};
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  std::unique_ptr<btDiscreteDynamicsWorld> world;
  std::unique_ptr<btBulletWorldImporter> importer;
  dvi::Scene scene;  // owns the bodies of a JSON scene

  ~EngineWorld() {
    if (importer) importer->deleteAllData();  // removes its bodies and constraints from the world
    if (world)
      for (btRigidBody* b : scene.bodies()) world->removeRigidBody(b);
  }
};

// Bullet's loader trusts the file (docs/HARDENING.md). Scene::load has checked the bodies and shapes by then,
// but the importer below also reads what the scene leaves out (constraints, collision objects): it first runs
// in a child process, and a crash or hang there is refused as a corrupt file instead of ending this process.
void loadsWithoutCrashing(const std::string& path) {
  std::fflush(stdout);
  std::fflush(stderr);
  const pid_t pid = ::fork();
  if (pid < 0) throw std::runtime_error(std::string("fork: ") + std::strerror(errno));
  if (pid == 0) {
    const int null = ::open("/dev/null", O_WRONLY);  // Bullet prints its complaints
    if (null >= 0) ::dup2(null, 1), ::dup2(null, 2);
    ::alarm(60);
    btBulletWorldImporter importer(nullptr);
    const bool ok = importer.loadFile(path.c_str());
    ::_exit(ok ? 0 : 3);
  }
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {}
  if (WIFSIGNALED(status))
    throw InputError(path + ": corrupt .bullet file (Bullet's importer " +
                     (WTERMSIG(status) == SIGALRM ? std::string("did not finish in 60 s")
                                                  : "crashed on it: " + std::string(strsignal(WTERMSIG(status)))) +
                     ")");
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
    throw InputError(path + ": Bullet's importer could not read the file");
}

bool endsWith(const std::string& s, const std::string& e) {
  return s.size() >= e.size() && s.compare(s.size() - e.size(), e.size(), e) == 0;
}

void loadInto(EngineWorld& e, const CompareOptions& o, const dvi::Scene& settings_scene) {
  e.world->setGravity(btVector3(btScalar(settings_scene.settings.system.step.gravity.x),
                                btScalar(settings_scene.settings.system.step.gravity.y),
                                btScalar(settings_scene.settings.system.step.gravity.z)));
  if (endsWith(o.scene, ".bullet")) {
    e.importer = std::make_unique<btBulletWorldImporter>(e.world.get());
    if (!e.importer->loadFile(o.scene.c_str()))
      throw InputError(o.scene + ": Bullet's importer could not read the file");
    return;
  }
  e.scene = dvi::Scene::load(o.scene, o.sets);
  for (btRigidBody* b : e.scene.bodies()) e.world->addRigidBody(b);
}

std::vector<btRigidBody*> rigidBodies(btDiscreteDynamicsWorld& w) {
  std::vector<btRigidBody*> out;
  for (int i = 0; i < w.getNumCollisionObjects(); ++i)
    if (btRigidBody* b = btRigidBody::upcast(w.getCollisionObjectArray()[i])) out.push_back(b);
  return out;
}

double deepestPenetration(btDispatcher& d) {
  double deepest = 0;
  for (int i = 0; i < d.getNumManifolds(); ++i) {
    const btPersistentManifold* m = d.getManifoldByIndexInternal(i);
    for (int k = 0; k < m->getNumContacts(); ++k)
      deepest = std::fmax(deepest, -double(m->getContactPoint(k).getDistance()));
  }
  return deepest;
}

double energy(const std::vector<btRigidBody*>& bodies) {
  double e = 0;
  for (const btRigidBody* b : bodies) {
    if (b->getInvMass() == 0) continue;
    const double m = 1.0 / double(b->getInvMass());
    const btVector3 w = b->getAngularVelocity();
    const btVector3 Iw = b->getInvInertiaTensorWorld().inverse() * w;
    e += 0.5 * m * double(b->getLinearVelocity().length2()) + 0.5 * double(w.dot(Iw)) -
         m * double(b->getGravity().dot(b->getCenterOfMassPosition()));
  }
  return e;
}

EngineResult runEngine(const std::string& name, const CompareOptions& o, const dvi::Scene& s, double dt,
                       int64_t steps) {
  EngineResult r;
  r.name = name;
  EngineWorld e;
  if (name == "bullet") {
    e.world = std::make_unique<btDiscreteDynamicsWorld>(&e.dispatcher, &e.broadphase, &e.solver, &e.config);
    r.device = "Bullet 2 sequential impulse (CPU, 1 thread)";
  } else {
    dvi::DviWorldConfig c;
    c.backend = name == "gpu" ? dvi::WorldBackend::Gpu : dvi::WorldBackend::Cpu;
    c.make_gpu_system = dvi::makeGpuSystem;
    c.system = s.settings.system;
    auto w = std::make_unique<dvi::DviDynamicsWorld>(&e.dispatcher, &e.broadphase, &e.solver, &e.config, c);
    r.device = w->system().deviceName();
    e.world = std::move(w);
  }
  loadInto(e, o, s);
  const std::vector<btRigidBody*> bodies = rigidBodies(*e.world);
  const auto t0 = std::chrono::steady_clock::now();
  for (int64_t i = 0; i < steps; ++i) {
    e.world->stepSimulation(btScalar(dt), 0);
    r.penetration = std::fmax(r.penetration, deepestPenetration(e.dispatcher));
  }
  r.wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.steps = steps;
  for (const btRigidBody* b : bodies)
    r.bodies.push_back(BodyState{b->getCenterOfMassPosition(), b->getLinearVelocity()});
  r.energy = energy(bodies);
  r.ran = true;
  return r;
}

int runCompare(const CompareOptions& o) {
  if (o.scene.empty()) throw InputError("compare: a SCENE (.json or .bullet) is required");
  if (!std::filesystem::exists(o.scene)) throw InputError(o.scene + ": no such file");
  dvi::Scene s = dvi::Scene::load(o.scene, o.sets);  // validates the file and gives the settings
  if (endsWith(o.scene, ".bullet")) loadsWithoutCrashing(o.scene);
  if (!o.dt.empty()) s.settings.system.step.dt = dvi::real(dvi::parseReal("--dt", o.dt));
  if (!o.time.empty()) s.settings.time = dvi::real(dvi::parseReal("--time", o.time)), s.settings.steps = -1;
  if (!o.steps.empty()) s.settings.steps = dvi::parseInt("--steps", o.steps, 0, int64_t(1) << 40);
  if (!o.solver.empty()) s.applySettingOverride("settings.solver=" + o.solver);
  if (!o.iterations.empty()) s.applySettingOverride("settings.iterations=" + o.iterations);
  if (!(s.settings.system.step.dt > 0)) throw InputError("--dt: must be positive");
  const int64_t steps = s.settings.stepCount();
  if (steps < 0) throw InputError("--steps: must be >= 0");

  std::vector<EngineResult> results;
  results.push_back(runEngine("bullet", o, s, s.settings.system.step.dt, steps));
  results.push_back(runEngine("cpu", o, s, s.settings.system.step.dt, steps));
  std::string why;
  if (dvi::gpuAvailable(&why)) {
    results.push_back(runEngine("gpu", o, s, s.settings.system.step.dt, steps));
  } else {
    EngineResult g;
    g.name = "gpu";
    g.skipped = why;
    results.push_back(g);
  }

  const EngineResult& ref = results[0];
  std::filesystem::create_directories(o.out);
  const std::string csv_path = o.out + "/compare.csv";
  std::ofstream csv(csv_path);
  if (!csv) throw InputError(csv_path + ": cannot write");
  csv << "engine,body,x,y,z,vx,vy,vz,pos_diff,vel_diff,energy,max_penetration,wall_s\n";
  std::printf("compare %s: %zu bodies, %lld steps of %g s\n", o.scene.c_str(), ref.bodies.size(), (long long)steps,
              s.settings.system.step.dt);
  std::printf("%-7s %12s %12s %12s %12s %14s %12s %10s  %s\n", "engine", "max |dx|", "mean |dx|", "max |dv|",
              "mean |dv|", "energy (J)", "max pen", "wall (s)", "device");
  for (const EngineResult& r : results) {
    if (!r.ran) {
      std::printf("%-7s skipped: %s\n", r.name.c_str(), r.skipped.c_str());
      continue;
    }
    double max_dx = 0, sum_dx = 0, max_dv = 0, sum_dv = 0;
    for (size_t i = 0; i < r.bodies.size() && i < ref.bodies.size(); ++i) {
      const double dx = double((r.bodies[i].x - ref.bodies[i].x).length());
      const double dv = double((r.bodies[i].v - ref.bodies[i].v).length());
      max_dx = std::fmax(max_dx, dx);
      max_dv = std::fmax(max_dv, dv);
      sum_dx += dx;
      sum_dv += dv;
      const BodyState& b = r.bodies[i];
      char line[512];
      std::snprintf(line, sizeof line, "%s,%zu,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,,,\n", r.name.c_str(), i,
                    double(b.x.x()), double(b.x.y()), double(b.x.z()), double(b.v.x()), double(b.v.y()),
                    double(b.v.z()), dx, dv);
      csv << line;
    }
    const double n = std::max<double>(1, double(r.bodies.size()));
    char line[512];
    std::snprintf(line, sizeof line, "%s,all,,,,,,,%.9g,%.9g,%.9g,%.9g,%.6g\n", r.name.c_str(), max_dx, max_dv,
                  r.energy, r.penetration, r.wall);
    csv << line;
    std::printf("%-7s %12.3e %12.3e %12.3e %12.3e %14.6g %12.3e %10.3f  %s\n", r.name.c_str(), max_dx, sum_dx / n,
                max_dv, sum_dv / n, r.energy, r.penetration, r.wall, r.device.c_str());
  }
  std::printf("differences are against bullet; per-body values in %s\n", csv_path.c_str());
  return 0;
}

}  // namespace

// Registers `dvisim compare`; the returned function runs it (main.cpp calls it when the subcommand was given).
std::function<int()> addCompareCommand(CLI::App& app) {
  auto o = std::make_shared<CompareOptions>();
  CLI::App* cmd = app.add_subcommand("compare", "Step a scene with Bullet and our CPU/GPU backends side by side");
  cmd->add_option("scene", o->scene, "Scene file: .json or .bullet")->required();
  dvi::addRunOverrides(cmd, *o);
  dvi::addRepeatable(cmd, "--set", o->sets, "Override a scene value by dotted key (repeatable)");
  cmd->add_option("--out", o->out, "Output directory for compare.csv (default dvisim-out)");
  return [o] { return runCompare(*o); };
}
