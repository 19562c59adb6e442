// dvisim bench dropin --out DIR [--quick] [--record] [--engines bullet,cpu,gpu] [--steps N] [--threads N]
//
// The drop-in world against stock Bullet on the kind of scenes Bullet's own benchmark demo runs
// (examples/Benchmarks/BenchmarkDemo.cpp of the Bullet repository, rebuilt here from its public description in our
// own code): each scene is built once per engine from the same Bullet objects, the world constructed on the one
// line a Bullet app changes (btDiscreteDynamicsWorld or dvi::DviDynamicsWorld), stepped with Bullet's
// stepSimulation(1/60) and timed per step; the engines of one scene run in alternating rounds so that they see
// the same machine state.
//
//   boxes     3000 boxes (2 m) falling in a 10 x 30 x 10 block onto a ground box
//   pyramid   a pyramid of 1015 boxes (layers 14 x 14 .. 1 x 1) resting on the ground
//   ragdolls  ragdolls of 11 capsules each as Bullet's RagdollDemo builds them: cone-twist joints (neck, hips,
//             shoulders) and hinges with limits (spine, knees, elbows), falling onto the ground
//   hulls     1000 convex hulls of 14 vertices falling in a 10 x 10 x 10 block
//   terrain   500 boxes and hulls falling onto a static triangle-mesh terrain of 2 x 40 x 40 triangles
//   hinge     two bodies on a hinge (a box swinging under a fixed one, as Bullet's TestHingeTorque): the per-step
//             fixed cost of a tiny scene (not in the default list: --scenes hinge)
//   boxes100k 100,000 boxes (1 m) in 50 x 50 columns of 40 resting on the ground (not in the default list:
//             --scenes boxes100k; at most 10 timed steps, Bullet needs seconds a step), the GPU drop-in's scale
//
// Per scene and engine: ms per step (wall time of stepSimulation), contacts, the deepest penetration over the
// timed steps (Bullet's manifold points, which the drop-in world fills too), and the drift of the scene's
// reference: the pyramid's top box height change, the largest joint violation for the ragdolls (ours; Bullet's
// joint error is not exposed), the mean height otherwise. Ratios ours / Bullet are the result, never an absolute
// CPU time.
//
// Writes DIR/dropin.csv and DIR/dropin.md; --record also writes bench/results/dropin_<device>_<date>.{md,csv}.
#include <btBulletDynamicsCommon.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "bench_common.h"
#include "bench_util.h"
#include "chrono_like/base/errors.h"
#include "chrono_like/bullet/bullet_world.h"
#include "gpu/gpu_factory.h"

namespace {

using namespace dvi::benchutil;

struct DropinOptions : BenchBasics {
  std::string steps, load = "0";
  std::vector<std::string> engines, scenes;
};

// `dvisim bench dropin`: its name, description and the texts of its common options.
const BenchSpec kBench{"dropin",
                       "Bullet's benchmark scenes on stock Bullet and on the drop-in world (CPU, GPU), side by side",
                       "dropin.csv, dropin.md",
                       "A quarter of the bodies and few steps (CI smoke test)",
                       "md,csv",
                       "OpenMP threads of our CPU drop-in (0: the default)"};

// Everything one world owns: Bullet's collision configuration, dispatcher, broad phase and solver, the world
// and the bodies, shapes, meshes and constraints of the scene (destroyed in reverse order).
struct World {
  std::unique_ptr<btDefaultCollisionConfiguration> config;
  std::unique_ptr<btCollisionDispatcher> dispatcher;
  std::unique_ptr<btDbvtBroadphase> broadphase;
  std::unique_ptr<btSequentialImpulseConstraintSolver> solver;
  std::unique_ptr<btDiscreteDynamicsWorld> world;
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btTriangleIndexVertexArray>> meshes;
  std::vector<std::unique_ptr<btRigidBody>> bodies;
  std::vector<std::unique_ptr<btTypedConstraint>> constraints;
  std::vector<btScalar> mesh_vertices;
  std::vector<int> mesh_indices;
  btRigidBody* reference = nullptr;  // the body whose height is the scene's drift (pyramid: the top box)
  dvi::DviDynamicsWorld* ours = nullptr;

  ~World() {
    if (world) {
      for (auto& c : constraints) world->removeConstraint(c.get());
      for (auto& b : bodies) world->removeRigidBody(b.get());
    }
    constraints.clear();
    world.reset();
  }

  btCollisionShape* keep(btCollisionShape* s) {
    shapes.emplace_back(s);
    return s;
  }
  btRigidBody* add(btCollisionShape* shape, btScalar mass, const btTransform& t) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) shape->calculateLocalInertia(mass, inertia);
    btRigidBody::btRigidBodyConstructionInfo info(mass, nullptr, shape, inertia);
    info.m_startWorldTransform = t;
    bodies.emplace_back(new btRigidBody(info));
    world->addRigidBody(bodies.back().get());
    return bodies.back().get();
  }
  btRigidBody* add(btCollisionShape* shape, btScalar mass, const btVector3& p) {
    return add(shape, mass, btTransform(btQuaternion::getIdentity(), p));
  }
  void join(btTypedConstraint* c) {
    constraints.emplace_back(c);
    world->addConstraint(c, true);
  }
};

// The one line an app changes: stock Bullet or the drop-in world on the CPU or GPU backend.
std::unique_ptr<World> makeWorld(const std::string& engine, int threads) {
  auto w = std::make_unique<World>();
  w->config = std::make_unique<btDefaultCollisionConfiguration>();
  w->dispatcher = std::make_unique<btCollisionDispatcher>(w->config.get());
  w->broadphase = std::make_unique<btDbvtBroadphase>();
  w->solver = std::make_unique<btSequentialImpulseConstraintSolver>();
  if (engine == "bullet") {
    w->world = std::make_unique<btDiscreteDynamicsWorld>(w->dispatcher.get(), w->broadphase.get(), w->solver.get(),
                                                         w->config.get());
  } else {
    dvi::DviWorldConfig c;
    c.backend = engine == "gpu" ? dvi::WorldBackend::Gpu : dvi::WorldBackend::Cpu;
    if (engine == "cpu-si") c.effort = dvi::SolverEffort::BulletIterations;
    if (engine == "cpu-apgd") c.effort = dvi::SolverEffort::Converged;
    if (engine == "cpu-btc") c.effort = dvi::SolverEffort::BulletThenConverged;
    c.make_gpu_system = dvi::makeGpuSystem;
    c.gpu_available = dvi::gpuAvailable;
    c.system.threads = threads;
    auto* ours =
        new dvi::DviDynamicsWorld(w->dispatcher.get(), w->broadphase.get(), w->solver.get(), w->config.get(), c);
    w->ours = ours;
    w->world.reset(ours);
  }
  w->world->setGravity(btVector3(0, -10, 0));
  return w;
}

void groundBox(World& w, btScalar half = 250) {
  w.add(w.keep(new btBoxShape(btVector3(half, 1, half))), 0, btVector3(0, -1, 0));
}

// 3000 boxes of 2 m in a 10 x 30 x 10 block, 0.05 m apart, falling from 2 m.
void sceneBoxes(World& w, int scale) {
  groundBox(w);
  btCollisionShape* box = w.keep(new btBoxShape(btVector3(1, 1, 1)));
  const int nx = 10, ny = 30 / scale, nz = 10;
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i)
      for (int k = 0; k < nz; ++k)
        w.add(box, 1, btVector3(btScalar(2.05 * (i - nx / 2)), btScalar(3 + 2.05 * j), btScalar(2.05 * (k - nz / 2))));
}

// A pyramid of boxes (2 m) resting on the ground: layers n x n, n = base .. 1, each centred on the one below.
void scenePyramid(World& w, int scale) {
  groundBox(w);
  btCollisionShape* box = w.keep(new btBoxShape(btVector3(1, 1, 1)));
  const int base = scale > 1 ? 7 : 14;
  for (int layer = 0; layer < base; ++layer) {
    const int n = base - layer;
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k)
        w.reference = w.add(
            box, 1, btVector3(btScalar(2.0 * i - (n - 1)), btScalar(1 + 2.0 * layer), btScalar(2.0 * k - (n - 1))));
  }
}

// A ragdoll as Bullet's RagdollDemo builds one (its public description, in our own code): pelvis, spine, head,
// upper/lower legs and arms as capsules (metres, arms horizontal), cone-twist joints at the neck (swing pi/4, pi/4,
// twist pi/2), hips (pi/4, pi/4, 0) and shoulders (pi/2, pi/2, 0), hinges at the spine (-pi/4 .. pi/2), knees
// (0 .. pi/2) and elbows (-pi/2 .. 0), damping 0.05 / 0.85. Every joint frame is given in the world (pivot and
// axes) and read into both bodies, so that each joint starts at its zero angles.
void ragdoll(World& w, const btVector3& at) {
  struct Part {
    btScalar r, h;
    btVector3 p;
  };
  const Part parts[11] = {
      {0.15f, 0.20f, {0, 1.0f, 0}},       {0.15f, 0.28f, {0, 1.2f, 0}},       {0.10f, 0.05f, {0, 1.6f, 0}},
      {0.07f, 0.45f, {-0.18f, 0.65f, 0}}, {0.05f, 0.37f, {-0.18f, 0.2f, 0}},  {0.07f, 0.45f, {0.18f, 0.65f, 0}},
      {0.05f, 0.37f, {0.18f, 0.2f, 0}},   {0.05f, 0.33f, {-0.35f, 1.45f, 0}}, {0.04f, 0.25f, {-0.7f, 1.45f, 0}},
      {0.05f, 0.33f, {0.35f, 1.45f, 0}},  {0.04f, 0.25f, {0.7f, 1.45f, 0}}};
  btRigidBody* b[11];
  for (int i = 0; i < 11; ++i) {
    btCollisionShape* s = w.keep(new btCapsuleShape(parts[i].r, parts[i].h));
    btTransform t(btQuaternion::getIdentity(), at + parts[i].p);
    if (i >= 7) t.setRotation(btQuaternion(btVector3(0, 0, 1), btScalar(M_PI / 2)));  // arms horizontal
    b[i] = w.add(s, 1, t);
    b[i]->setDamping(0.05f, 0.85f);
  }
  // Local frames of bodies i and j for a joint frame given in the world (pivot p, axes q).
  auto frames = [&](int i, int j, const btVector3& p, const btQuaternion& q, btTransform& fa, btTransform& fb) {
    const btTransform world(q, at + p);
    fa = b[i]->getCenterOfMassTransform().inverse() * world;
    fb = b[j]->getCenterOfMassTransform().inverse() * world;
  };
  auto cone = [&](int i, int j, const btVector3& p, const btQuaternion& q, btScalar s1, btScalar s2, btScalar tw) {
    btTransform fa, fb;
    frames(i, j, p, q, fa, fb);
    auto* c = new btConeTwistConstraint(*b[i], *b[j], fa, fb);
    c->setLimit(s1, s2, tw);
    w.join(c);
  };
  auto hinge = [&](int i, int j, const btVector3& p, const btQuaternion& q, btScalar lo, btScalar hi) {
    btTransform fa, fb;
    frames(i, j, p, q, fa, fb);
    auto* h = new btHingeConstraint(*b[i], *b[j], fa, fb);
    h->setLimit(lo, hi);
    w.join(h);
  };
  const btScalar pi = btScalar(M_PI);
  const btQuaternion lateral(btVector3(0, 1, 0), pi / 2);  // hinge axis (z) along the body's left-right axis (x)
  const btQuaternion up(btVector3(0, 0, 1), pi / 2), down(btVector3(0, 0, 1), -pi / 2);  // twist axis (x) up, down
  const btQuaternion left(btVector3(0, 0, 1), pi), right = btQuaternion::getIdentity();  // twist axis along an arm
  const btQuaternion vertical(btVector3(1, 0, 0), -pi / 2);                              // hinge axis (z) along y
  hinge(0, 1, {0, 1.1f, 0}, lateral, -pi / 4, pi / 2);                                   // spine
  cone(1, 2, {0, 1.5f, 0}, up, pi / 4, pi / 4, pi / 2);                                  // neck
  cone(0, 3, {-0.18f, 0.9f, 0}, down, pi / 4, pi / 4, 0);                                // hips
  cone(0, 5, {0.18f, 0.9f, 0}, down, pi / 4, pi / 4, 0);
  hinge(3, 4, {-0.18f, 0.42f, 0}, lateral, 0, pi / 2);  // knees
  hinge(5, 6, {0.18f, 0.42f, 0}, lateral, 0, pi / 2);
  cone(1, 7, {-0.18f, 1.45f, 0}, left, pi / 2, pi / 2, 0);  // shoulders
  cone(1, 9, {0.18f, 1.45f, 0}, right, pi / 2, pi / 2, 0);
  hinge(7, 8, {-0.55f, 1.45f, 0}, vertical, -pi / 2, 0);  // elbows
  hinge(9, 10, {0.55f, 1.45f, 0}, vertical, -pi / 2, 0);
}

void sceneRagdolls(World& w, int scale) {
  groundBox(w);
  const int n = scale > 1 ? 3 : 8;  // n x n ragdolls, 2 layers
  for (int layer = 0; layer < 2; ++layer)
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k)
        ragdoll(w, btVector3(btScalar(2.0 * (i - n / 2)), btScalar(0.5 + 2.5 * layer), btScalar(2.0 * (k - n / 2))));
}

// A convex hull of 14 vertices (a flattened, irregular rock of ~1 m).
btCollisionShape* rockHull() {
  auto* h = new btConvexHullShape();
  const btScalar v[14][3] = {{0.5f, 0, 0},         {-0.5f, 0.05f, 0},     {0, 0.35f, 0},        {0, -0.3f, 0.1f},
                             {0, 0, 0.45f},        {0.1f, 0, -0.5f},      {0.35f, 0.25f, 0.2f}, {-0.3f, 0.2f, -0.25f},
                             {0.3f, -0.2f, -0.3f}, {-0.35f, -0.2f, 0.3f}, {0.2f, 0.3f, -0.3f},  {-0.2f, 0.3f, 0.3f},
                             {0.4f, -0.1f, 0.3f},  {-0.4f, -0.15f, -0.2f}};
  for (const auto& p : v) h->addPoint(btVector3(p[0], p[1], p[2]), false);
  h->recalcLocalAabb();
  return h;
}

void sceneHulls(World& w, int scale) {
  groundBox(w);
  btCollisionShape* hull = w.keep(rockHull());
  const int n = 10, ny = 10 / scale;
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k)
        w.add(hull, 1, btVector3(btScalar(1.2 * (i - n / 2)), btScalar(2 + 1.2 * j), btScalar(1.2 * (k - n / 2))));
}

// A 40 x 40 cell terrain (2 triangles a cell, 2 m cells, heights from two sines) as a btBvhTriangleMeshShape,
// with boxes and hulls falling onto it.
void sceneTerrain(World& w, int scale) {
  const int cells = 40;
  const btScalar cell = 2;
  for (int i = 0; i <= cells; ++i)
    for (int k = 0; k <= cells; ++k) {
      const btScalar x = cell * (i - cells / 2), z = cell * (k - cells / 2);
      w.mesh_vertices.insert(w.mesh_vertices.end(), {x, btScalar(1.5 * std::sin(0.2 * x) * std::cos(0.15 * z)), z});
    }
  for (int i = 0; i < cells; ++i)
    for (int k = 0; k < cells; ++k) {
      const int a = i * (cells + 1) + k, b = a + 1, c = a + cells + 1, d = c + 1;
      w.mesh_indices.insert(w.mesh_indices.end(), {a, b, d, a, d, c});
    }
  auto* mesh =
      new btTriangleIndexVertexArray(int(w.mesh_indices.size() / 3), w.mesh_indices.data(), 3 * sizeof(int),
                                     int(w.mesh_vertices.size() / 3), w.mesh_vertices.data(), 3 * sizeof(btScalar));
  w.meshes.emplace_back(mesh);
  w.add(w.keep(new btBvhTriangleMeshShape(mesh, true)), 0, btVector3(0, 0, 0));
  btCollisionShape* box = w.keep(new btBoxShape(btVector3(0.5f, 0.5f, 0.5f)));
  btCollisionShape* hull = w.keep(rockHull());
  const int n = 10, ny = 5 / scale;
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k)
        w.add((i + j + k) % 2 ? box : hull, 1,
              btVector3(btScalar(3.0 * (i - n / 2)), btScalar(4 + 1.5 * j), btScalar(3.0 * (k - n / 2))));
}

// 100,000 boxes of 1 m in 50 x 50 columns of 40, each column resting on the ground from the first step (every
// box touches the ones above and below), 0.05 m between columns (--quick: 4 layers).
// Two bodies on a hinge: a fixed box and a 1 kg box hanging from it by a hinge about z, released at 90 degrees.
void sceneHinge(World& w, int) {
  btCollisionShape* box = w.keep(new btBoxShape(btVector3(0.5f, 0.1f, 0.1f)));
  btRigidBody* base = w.add(box, 0, btVector3(0, 5, 0));
  btRigidBody* link = w.add(box, 1, btVector3(1.2f, 5, 0));
  link->setActivationState(DISABLE_DEACTIVATION);
  w.join(new btHingeConstraint(*base, *link, btVector3(0.6f, 0, 0), btVector3(-0.6f, 0, 0), btVector3(0, 0, 1),
                               btVector3(0, 0, 1)));
}

void sceneBoxes100k(World& w, int scale) {
  groundBox(w, 500);
  btCollisionShape* box = w.keep(new btBoxShape(btVector3(0.5f, 0.5f, 0.5f)));
  const int n = 50, ny = scale > 1 ? 4 : 40;
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k)
        w.add(box, 1, btVector3(btScalar(1.05 * (i - n / 2)), btScalar(0.5 + 1.0 * j), btScalar(1.05 * (k - n / 2))));
}

using SceneBuilder = std::function<void(World&, int)>;
const std::map<std::string, SceneBuilder>& sceneBuilders() {
  static const std::map<std::string, SceneBuilder> m{
      {"boxes", sceneBoxes},     {"pyramid", scenePyramid},     {"ragdolls", sceneRagdolls}, {"hulls", sceneHulls},
      {"terrain", sceneTerrain}, {"boxes100k", sceneBoxes100k}, {"hinge", sceneHinge}};
  return m;
}

// Where our drop-in's sub-steps spent their time (DviDynamicsWorld::PhaseTimes), ms per sub-step.
std::string phaseLine(const dvi::DviDynamicsWorld::PhaseTimes& t) {
  const double n = double(std::max<int64_t>(1, t.substeps));
  char line[256];
  std::snprintf(line, sizeof line,
                "ms per sub-step: sync-in %.2f, step %.2f, sync-out %.2f (sleeping %.2f, AABBs %.2f), contacts %.2f; "
                "step's stages:",
                1e3 * t.sync_in / n, 1e3 * t.step / n, 1e3 * t.sync_out / n, 1e3 * t.sleeping / n, 1e3 * t.aabbs / n,
                1e3 * t.contacts / n);
  std::string s = line;
  for (int i = 0; i < dvi::kStageCount; ++i) {
    std::snprintf(line, sizeof line, " %s %.2f", dvi::stageName(dvi::StageType(i)), 1e3 * t.stages[size_t(i)] / n);
    s += line;
  }
  return s;
}

struct Result {
  std::string scene, engine, status = "ok";
  size_t bodies = 0, constraints = 0;
  long steps = 0;
  double wall = 0;      // s over the timed steps
  double contacts = 0;  // manifold points at distance < 0, mean over the timed steps
  double max_pen = 0;   // deepest manifold point over the timed steps, m
  double drift = 0;     // see the header
  double msPerStep() const { return steps > 0 ? 1e3 * wall / double(steps) : 0; }
  std::string phases;  // ours: where a sub-step's time goes (phaseLine)
  double sweeps = 0;   // ours: solver iterations per timed step, mean
  int64_t missed = 0;  // ours: timed sub-steps whose solve ended above the tolerance (0.15)
  double worst = 0;    // ours: the worst relative residual of a timed sub-step
};

// Manifold points at negative distance and the deepest one (the same read for every engine: the drop-in world
// fills Bullet's manifolds).
void manifoldStats(btDiscreteDynamicsWorld& w, double& points, double& deepest) {
  btDispatcher* d = w.getDispatcher();
  points = 0;
  deepest = 0;
  for (int m = 0; m < d->getNumManifolds(); ++m) {
    const btPersistentManifold* pm = d->getManifoldByIndexInternal(m);
    for (int c = 0; c < pm->getNumContacts(); ++c) {
      const double dist = pm->getContactPoint(c).getDistance();
      if (dist < 0) {
        points += 1;
        deepest = std::max(deepest, -dist);
      }
    }
  }
}

double meanHeight(const World& w) {
  double s = 0;
  int n = 0;
  for (const auto& b : w.bodies)
    if (b->getInvMass() > 0) s += b->getCenterOfMassPosition().y(), ++n;
  return n ? s / n : 0;
}

// Other runs sharing the cores while the benchmark runs (--load N): N child processes, each in a session of its own
// (as another user's program), each stepping our CPU drop-in world on the pyramid with the benchmark's --threads,
// killed when the benchmark ends. Two runs of an OpenMP program on the same cores is the case where a fixed team
// collapses in its barriers (base/thread_governor.h).
class Loader {
 public:
  Loader(int n, int threads) {
    for (int i = 0; i < n; ++i) {
      const pid_t pid = fork();
      if (pid == 0) {
        setsid();
        auto w = makeWorld("cpu", threads);
        sceneBuilders().at("pyramid")(*w, 1);
        for (auto& b : w->bodies) b->forceActivationState(DISABLE_DEACTIVATION);       // a resting pyramid would sleep
        for (;;) w->world->stepSimulation(btScalar(1.0 / 60), 1, btScalar(1.0 / 60));  // until killed
      }
      if (pid < 0) throw std::runtime_error("--load: fork failed");
      pids_.push_back(pid);
    }
  }
  ~Loader() {
    for (pid_t p : pids_) kill(p, SIGKILL);
    for (pid_t p : pids_) waitpid(p, nullptr, 0);
  }
  Loader(const Loader&) = delete;
  Loader& operator=(const Loader&) = delete;

 private:
  std::vector<pid_t> pids_;
};

// What every scene of a run shares.
struct DropinRun {
  int threads, scale, warmup, rounds;
  long steps;
  bool have_gpu;
  std::string gpu_name;
};

// The worlds of one scene, one an engine, warmed up (none where the engine has no device or refused the scene, its
// row saying why); rs gets each engine's row.
std::vector<std::unique_ptr<World>> buildWorlds(const std::string& scene, const std::vector<std::string>& engines,
                                                const DropinRun& p, int scene_warmup, std::vector<Result>& rs,
                                                std::string& cpu_device) {
  std::vector<std::unique_ptr<World>> worlds;
  for (const std::string& engine : engines) {
    Result r;
    r.scene = scene;
    r.engine = engine;
    if (engine == "gpu" && !p.have_gpu) {
      r.status = "no GPU (" + p.gpu_name + ")";
      rs.push_back(r);
      worlds.emplace_back();
      continue;
    }
    try {
      auto w = makeWorld(engine, p.threads);
      sceneBuilders().at(scene)(*w, p.scale);
      r.bodies = w->bodies.size();
      r.constraints = w->constraints.size();
      for (int s = 0; s < scene_warmup; ++s) w->world->stepSimulation(btScalar(1.0 / 60), 1, btScalar(1.0 / 60));
      if (w->ours && cpu_device.empty() && engine.rfind("cpu", 0) == 0) cpu_device = w->ours->system().deviceName();
      if (w->ours) w->ours->resetPhaseTimes();
      worlds.push_back(std::move(w));
    } catch (const std::exception& e) {
      r.status = std::string("refused: ") + e.what();
      worlds.emplace_back();
    }
    rs.push_back(r);
  }
  return worlds;
}

// One scene on every engine, the engines' steps interleaved in alternating rounds (A B C, then C B A): each
// engine's row (time, contacts, depth, drift, the solver's effort), printed.
std::vector<Result> measureScene(const std::string& scene, const std::vector<std::string>& engines, const DropinRun& p,
                                 std::string& cpu_device) {
  const bool large = scene == "boxes100k";
  const long scene_steps = large ? std::min(p.steps, 10L) : p.steps;
  const int scene_warmup = large ? std::min(p.warmup, 2) : p.warmup;
  const int rounds = p.rounds;
  std::vector<Result> rs;
  std::vector<std::unique_ptr<World>> worlds = buildWorlds(scene, engines, p, scene_warmup, rs, cpu_device);
  std::vector<double> h0(worlds.size(), 0);
  for (size_t i = 0; i < worlds.size(); ++i)
    if (worlds[i])
      h0[i] = scene == "pyramid" && worlds[i]->reference ? worlds[i]->reference->getCenterOfMassPosition().y()
                                                         : meanHeight(*worlds[i]);
  const long per_round = (scene_steps + rounds - 1) / rounds;
  for (int round = 0; round < rounds; ++round)
    for (size_t j = 0; j < worlds.size(); ++j) {
      const size_t i = round % 2 == 0 ? j : worlds.size() - 1 - j;  // A B C, then C B A
      if (!worlds[i]) continue;
      for (long s = 0; s < per_round && rs[i].steps < scene_steps; ++s) {
        const auto t0 = Clock::now();
        worlds[i]->world->stepSimulation(btScalar(1.0 / 60), 1, btScalar(1.0 / 60));
        rs[i].wall += std::chrono::duration<double>(Clock::now() - t0).count();
        double pts = 0, deep = 0;
        manifoldStats(*worlds[i]->world, pts, deep);
        rs[i].contacts += pts;
        rs[i].max_pen = std::max(rs[i].max_pen, deep);
        ++rs[i].steps;
        if (worlds[i]->ours) {
          const dvi::StepStats& st = worlds[i]->ours->system().lastStats();
          rs[i].sweeps += st.iterations;
          rs[i].missed += st.converged ? 0 : 1;
          rs[i].worst = std::max(rs[i].worst, double(st.relative_residual));
        }
      }
    }
  for (size_t i = 0; i < worlds.size(); ++i) {
    if (!worlds[i]) continue;
    rs[i].contacts /= double(std::max(1L, rs[i].steps));
    rs[i].sweeps /= double(std::max(1L, rs[i].steps));
    if (worlds[i]->ours) rs[i].phases = phaseLine(worlds[i]->ours->phaseTimes());
    if ((scene == "ragdolls" || scene == "hinge") && worlds[i]->ours) {
      const dvi::JointViolation v = worlds[i]->ours->maxJointViolation();
      rs[i].drift = std::max(double(v.linear), double(v.angular));
    } else if (scene == "ragdolls" || scene == "hinge") {
      rs[i].drift = std::nan("");  // Bullet does not expose its joint error
    } else if (scene == "pyramid" && worlds[i]->reference) {
      rs[i].drift = worlds[i]->reference->getCenterOfMassPosition().y() - h0[i];
    } else {
      rs[i].drift = meanHeight(*worlds[i]) - h0[i];
    }
  }
  for (const Result& r : rs) {
    std::printf("  %-9s %-7s %6zu bodies %5zu joints: %s", r.scene.c_str(), r.engine.c_str(), r.bodies, r.constraints,
                r.status.c_str());
    if (r.status == "ok")
      std::printf(" %9.2f ms/step, %7.0f contact points, deepest %.4f m, drift %s", r.msPerStep(), r.contacts,
                  r.max_pen, std::isnan(r.drift) ? "-" : num(r.drift, "%+.4f").c_str());
    std::printf("\n");
    if (r.status == "ok" && !r.phases.empty())
      std::printf(
          "    solver: %.1f iterations a step, %lld steps above the tolerance, worst relative residual %.3f\n"
          "    %s\n",
          r.sweeps, (long long)r.missed, r.worst, r.phases.c_str());
    std::fflush(stdout);
  }
  return rs;
}

// dropin.csv (returned in csv) and the report's table with the goals and where our sub-steps spend their time.
std::string dropinTables(const std::vector<Result>& results, std::string& csv_text) {
  // Ratios to Bullet, per scene.
  auto bulletMs = [&](const std::string& scene) {
    for (const Result& r : results)
      if (r.scene == scene && r.engine == "bullet" && r.status == "ok") return r.msPerStep();
    return 0.0;
  };
  std::ostringstream csv, md;
  csv << "scene,engine,bodies,constraints,steps,ms_per_step,ratio_to_bullet,contact_points,max_penetration_m,drift,"
         "status\n";
  md << "| scene | engine | bodies | joints | ms/step | ours / Bullet | contact points | deepest (m) | drift | "
        "iterations/step | steps above tol. |\n"
     << "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n";
  std::map<std::string, std::pair<int, int>> met;  // engine -> (scenes at <= 1.0x Bullet, scenes)
  for (const Result& r : results) {
    const double b = bulletMs(r.scene);
    const double ratio = r.status == "ok" && b > 0 && r.engine != "bullet" ? r.msPerStep() / b : 0;
    if (r.engine.rfind("cpu", 0) == 0 && ratio > 0) ++met[r.engine].second, met[r.engine].first += ratio <= 1.0;
    csv << r.scene << "," << r.engine << "," << r.bodies << "," << r.constraints << "," << r.steps << ","
        << num(r.msPerStep(), "%.4f") << "," << (ratio > 0 ? num(ratio, "%.3f") : "") << "," << num(r.contacts, "%.1f")
        << "," << num(r.max_pen, "%.5f") << "," << (std::isnan(r.drift) ? std::string() : num(r.drift, "%.5f")) << ","
        << csvField(r.status) << "\n";
    char line[512];
    if (r.status == "ok")
      std::snprintf(line, sizeof line, "| %s | %s | %zu | %zu | %.3f | %s | %.0f | %.4f | %s | %s | %s |\n",
                    r.scene.c_str(), r.engine.c_str(), r.bodies, r.constraints, r.msPerStep(),
                    ratio > 0 ? num(ratio, "%.2fx").c_str() : "-", r.contacts, r.max_pen,
                    std::isnan(r.drift) ? "-" : num(r.drift, "%+.4f").c_str(),
                    r.engine == "bullet" ? "-" : num(r.sweeps, "%.1f").c_str(),
                    r.engine == "bullet" ? "-" : std::to_string(r.missed).c_str());
    else
      std::snprintf(line, sizeof line, "| %s | %s | | | %s | | | | | | |\n", r.scene.c_str(), r.engine.c_str(),
                    r.status.c_str());
    md << line;
  }
  char goal[256];
  md << "\n";
  for (const auto& [engine, m] : met) {
    std::snprintf(goal, sizeof goal,
                  "Goal: our CPU drop-in (%s) at <= 1.0x Bullet's time on every scene: %s (%d of %d)\n", engine.c_str(),
                  m.first == m.second ? "MET" : "NOT MET", m.first, m.second);
    md << goal;
  }
  for (const Result& r : results)
    if (r.scene == "boxes100k" && r.engine == "gpu" && r.status == "ok" && bulletMs(r.scene) > 0) {
      const double speedup = bulletMs(r.scene) / r.msPerStep();
      std::snprintf(goal, sizeof goal, "Goal: our GPU drop-in >= 50x Bullet at 100k bodies: %s (%.1fx)\n",
                    speedup >= 50 ? "MET" : "NOT MET", speedup);
      md << goal;
    }
  bool phases = false;  // where our sub-steps spend their time (DviDynamicsWorld::PhaseTimes)
  for (const Result& r : results) {
    if (r.phases.empty()) continue;
    if (!phases) md << "\nOur sub-steps, where the time goes:\n\n";
    phases = true;
    md << "- " << r.scene << " " << r.engine << ": " << r.phases << "\n";
  }
  csv_text = csv.str();
  return md.str();
}

int runDropin(const DropinOptions& o) {
  const std::vector<std::string> engines = selectNames(
      "--engines", o.engines.empty() ? std::vector<std::string>{"bullet", "cpu", "cpu-si", "gpu"} : o.engines,
      {"bullet", "cpu", "cpu-si", "cpu-btc", "cpu-apgd", "gpu"});
  const std::vector<std::string> scenes =
      o.scenes.empty() ? std::vector<std::string>{"boxes", "pyramid", "ragdolls", "hulls", "terrain"}
                       : selectNames("--scenes", o.scenes,
                                     {"boxes", "pyramid", "ragdolls", "hulls", "terrain", "boxes100k", "hinge"});
  char* end = nullptr;
  const long threads = std::strtol(o.threads.c_str(), &end, 10);
  if (o.threads.empty() || *end || threads < 0 || threads > 4096)
    throw InputError("--threads: expected an integer >= 0");
  long steps = o.quick ? 10 : 150;
  if (!o.steps.empty()) {
    steps = std::strtol(o.steps.c_str(), &end, 10);
    if (*end || steps < 1 || steps > 100000) throw InputError("--steps: expected an integer in [1, 100000]");
  }
  const long load = std::strtol(o.load.c_str(), &end, 10);
  if (o.load.empty() || *end || load < 0 || load > 256) throw InputError("--load: expected an integer in [0, 256]");
  const int scale = o.quick ? 4 : 1;  // --quick: a quarter of the bodies (fewer layers)
  const int warmup = o.quick ? 2 : 30, rounds = o.quick ? 2 : 5;
  prepareOutDir(o.out, "dropin.csv");
  const std::string results_dir = o.record ? resultsDir() : std::string();
  std::string gpu_name;
  const bool have_gpu = dvi::gpuAvailable(&gpu_name);

  std::vector<Result> results;
  std::string cpu_device;
  const Loader loader{int(load), int(threads)};  // other runs on the cores, for the whole benchmark
  std::printf("bench dropin%s: %d warm-up steps, then %d alternating rounds, %ld timed steps per engine, h = 1/60 s\n",
              o.quick ? " --quick" : "", warmup, rounds, steps);
  const DropinRun run{int(threads), scale, warmup, rounds, steps, have_gpu, gpu_name};
  for (const std::string& scene : scenes)
    for (const Result& r : measureScene(scene, engines, run, cpu_device)) results.push_back(r);

  std::string csv;
  const std::string md = dropinTables(results, csv);
  std::printf("%s%s", md.c_str(), "");

  std::ostringstream head;
  head
      << "# Drop-in: Bullet's benchmark scenes on stock Bullet and on the drop-in world"
      << (o.quick ? " (--quick)" : "")
      << "\n\nWritten by the benchmark (`dvisim bench dropin`, bench/dropin/bench_dropin.cpp); do not edit by hand.\n\n"
      << "- CPU: " << (cpu_device.empty() ? "-" : cpu_device) << "\n- GPU: " << (have_gpu ? gpu_name : "none")
      << "\n- Bullet: " << btGetVersion() << ", btDiscreteDynamicsWorld, sequential impulses (10 iterations), 1 thread"
      << "\n- commit: " << commitId() << "\n- date: " << utcNow("%Y-%m-%dT%H:%M:%SZ") << "\n- steps: " << warmup
      << " warm-up, then " << steps << " timed per engine in " << rounds
      << " alternating rounds, stepSimulation(1/60, 1, 1/60); cpu and gpu: ours at its defaults; cpu-si: "
         "SolverEffort::BulletIterations (Bullet's 10 Gauss-Seidel sweeps); cpu-btc: BulletThenConverged (10 "
         "sweeps, then to the tolerance, at most 30); cpu-apgd: Converged (APGD, at least 50 iterations, the joint-row "
         "stop)\n"
      << "- load: " << load << " other runs of our CPU drop-in (pyramid) sharing the cores (--load)\n"
      << "- deepest: the deepest manifold point over the timed steps; drift: pyramid top box height change, ragdolls "
         "the largest joint violation (ours), else the mean height change over the timed steps (m)\n\n";
  const std::string text = head.str() + md;
  const bool gpu_ran = have_gpu && std::find(engines.begin(), engines.end(), "gpu") != engines.end();
  writeCsvMdResults(o, "dropin", gpu_ran ? gpu_name : cpu_device, results_dir, text, csv);
  return 0;
}

}  // namespace

void registerBenchDropin(CLI::App& app, BenchRegistry& reg) {
  auto [cmd, o] = addBench<DropinOptions>(app, reg, kBench, runDropin);
  cmd->add_option(
      "--engines", o->engines,
      "bullet,cpu,cpu-si,cpu-btc,cpu-apgd,gpu (default bullet,cpu,cpu-si,gpu; gpu is skipped without a device; "
      "cpu-si: SolverEffort::BulletIterations; cpu-btc: BulletThenConverged; cpu-apgd: Converged)");
  cmd->add_option("--scenes", o->scenes, "boxes,pyramid,ragdolls,hulls,terrain (the default), boxes100k and hinge");
  cmd->add_option("--steps", o->steps, "Timed steps per engine (default 150; --quick 10)");
  cmd->add_option("--load", o->load,
                  "Runs of our CPU drop-in (pyramid) to start beside the benchmark, sharing the cores (default 0)");
}
