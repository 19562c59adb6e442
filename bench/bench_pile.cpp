// Benchmark: a pile of N spheres (r = 1 cm, mu = 0.5, h = 1e-3 s) stepped by our CPU backend and by
// Bullet's btDiscreteDynamicsWorld side by side in one run, on this host. Not a test: it prints ratios.
//
//   dvisim_bench pile [--n 100000] [--steps 10] [--warmup 20] [--iterations 10] [--solver apgd]
//                     [--threads 0] [--bullet-iterations 10] [--no-bullet] [--csv FILE]
//
// Bullet's tolerances are absolute lengths (0.04 m margin), so it is given the same pile in centimetres
// (BulletPeer with length_scale = 100) and its results are converted back; penetration is compared
// relative to the sphere radius.
#include <btBulletDynamicsCommon.h>
#include <omp.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/bullet/bullet_peer.h"
#include "chrono_like/system.h"

namespace {

struct Args {
  long n = 100000;
  // Defaults: the same iteration count for both engines (Bullet's default of 10), and 20 warm-up steps so
  // the columns have started to settle. Measured on the 2-core machine (2026-11-21, quiet): ours 240 ms,
  // Bullet 1390 ms per step, penetration 0.80 of Bullet's; with --iterations 20: 333 ms, 0.22 of Bullet's.
  int steps = 10, warmup = 20, iterations = 10, threads = 0, bullet_iterations = 10;
  std::string solver = "apgd", csv;
  bool bullet = true;
};

// A dense pile: spheres on a jittered lattice inside a box of four walls on a ground plane. Columns are
// stacked with a 0.1% gap, so most spheres touch the ones above and below from the first steps; across,
// the pitch is 2.1 r and the jitter +-0.04 r, so no two spheres overlap at the start (an initial overlap
// would measure how fast each engine pushes it out, not the penetration the step itself allows).
struct Pile {
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btRigidBody>> owned;
  std::vector<btRigidBody*> bodies;
};

Pile makePile(long n, double r, double mu) {
  Pile p;
  const int side = int(std::ceil(std::cbrt(double(n) / 2.0)));  // footprint side; height ~ 2 x side
  const double pitch = 2.0 * r * 1.05;                          // across (x, z)
  const double vpitch = 2.0 * r * 1.001;                        // along a column (y)
  const double width = side * pitch;
  auto add = [&](btCollisionShape* s, double mass, btVector3 pos) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) s->calculateLocalInertia(btScalar(mass), inertia);
    btRigidBody::btRigidBodyConstructionInfo info(btScalar(mass), nullptr, s, inertia);
    info.m_startWorldTransform.setOrigin(pos);
    info.m_friction = btScalar(std::sqrt(mu));  // Bullet's product rule: sqrt(mu)^2 = mu
    p.owned.emplace_back(new btRigidBody(info));
    p.bodies.push_back(p.owned.back().get());
  };
  p.shapes.emplace_back(new btStaticPlaneShape(btVector3(0, 1, 0), 0));
  add(p.shapes.back().get(), 0, btVector3(0, 0, 0));
  const double wall_h = 2.5 * side * vpitch, t = 0.05;
  p.shapes.emplace_back(new btBoxShape(btVector3(btScalar(t), btScalar(wall_h), btScalar(width / 2 + 2 * t))));
  add(p.shapes.back().get(), 0, btVector3(btScalar(-t - 0.5 * r), btScalar(wall_h), btScalar(width / 2)));
  add(p.shapes.back().get(), 0, btVector3(btScalar(width + t), btScalar(wall_h), btScalar(width / 2)));
  p.shapes.emplace_back(new btBoxShape(btVector3(btScalar(width / 2 + 2 * t), btScalar(wall_h), btScalar(t))));
  add(p.shapes.back().get(), 0, btVector3(btScalar(width / 2), btScalar(wall_h), btScalar(-t - 0.5 * r)));
  add(p.shapes.back().get(), 0, btVector3(btScalar(width / 2), btScalar(wall_h), btScalar(width + t)));
  p.shapes.emplace_back(new btSphereShape(btScalar(r)));
  const double mass = 2500.0 * 4.0 / 3.0 * M_PI * r * r * r;  // glass beads
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> jitter(-0.04 * r, 0.04 * r);
  for (long i = 0; i < n; ++i) {
    long layer = i / (long(side) * side), in = i % (long(side) * side);
    double x = (in % side + 0.5) * pitch - 0.5 * r + jitter(rng);
    double z = (in / side + 0.5) * pitch - 0.5 * r + jitter(rng);
    double y = r * 1.001 + layer * vpitch;
    add(p.shapes.back().get(), mass, btVector3(btScalar(x), btScalar(y), btScalar(z)));
  }
  return p;
}

double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

// The command line into a; false (with the message printed) on bad input.
// Means over the timed steps: ms per step and contacts; the deepest penetration (m).
struct Timed {
  double ms = 0, contacts = 0, pen = 0;
};

// a.warmup untimed steps of engine (our System or the Bullet peer), then a.steps timed ones, each followed by
// after_step() (for the caller's own sums).
template <class Engine, class AfterStep>
Timed timeSteps(Engine& engine, const Args& a, AfterStep after_step) {
  Timed r;
  for (int s = 0; s < a.warmup + a.steps; ++s) {
    const double t0 = now();
    engine.step();
    const double dt = now() - t0;
    if (s < a.warmup) continue;
    r.ms += 1e3 * dt / a.steps;
    r.contacts += double(engine.lastStats().contacts) / a.steps;
    r.pen = std::max(r.pen, double(engine.lastStats().max_penetration));
    after_step();
  }
  return r;
}

bool parseArgs(int argc, char** argv, Args& a) {
  if (argc < 2 || std::strcmp(argv[1], "pile") != 0) {
    std::fprintf(stderr,
                 "usage: dvisim_bench pile [--n N] [--steps S] [--warmup W] [--iterations I] [--solver S] "
                 "[--threads T] [--bullet-iterations I] [--no-bullet] [--csv FILE]\n");
    return false;
  }
  for (int i = 2; i < argc; ++i) {
    std::string k = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "dvisim_bench: error: %s needs a value\n", k.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (k == "--n")
      a.n = std::atol(next().c_str());
    else if (k == "--steps")
      a.steps = std::atoi(next().c_str());
    else if (k == "--warmup")
      a.warmup = std::atoi(next().c_str());
    else if (k == "--iterations")
      a.iterations = std::atoi(next().c_str());
    else if (k == "--solver")
      a.solver = next();
    else if (k == "--threads")
      a.threads = std::atoi(next().c_str());
    else if (k == "--bullet-iterations")
      a.bullet_iterations = std::atoi(next().c_str());
    else if (k == "--no-bullet")
      a.bullet = false;
    else if (k == "--csv")
      a.csv = next();
    else {
      std::fprintf(stderr, "dvisim_bench: error: unknown option %s\n", k.c_str());
      return false;
    }
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  Args a;
  if (!parseArgs(argc, argv, a)) return 2;
  const double r = 0.01, mu = 0.5, h = 1e-3;
  Pile pile = makePile(a.n, r, mu);
  std::printf("pile: %ld spheres r = %.3f m, mu = %.2f, h = %.0e s, %d warm-up + %d timed steps\n", a.n, r, mu, h,
              a.warmup, a.steps);

  // Our CPU backend.
  dvi::SystemConfig cfg;
  cfg.step.dt = h;
  cfg.threads = a.threads;
  if (!dvi::parseSolver(a.solver, cfg.solver.type)) {
    std::fprintf(stderr, "dvisim_bench: error: unknown solver %s\n", a.solver.c_str());
    return 2;
  }
  cfg.solver.max_iterations = a.iterations;
  dvi::System sys(cfg);
  dvi::importBullet(sys, pile.bodies);
  std::vector<double> stage_ms(dvi::kStageCount, 0.0);
  const Timed ours = timeSteps(sys, a, [&] {
    for (int k = 0; k < dvi::kStageCount; ++k) stage_ms[k] += 1e3 * sys.lastStats().stage_seconds[k] / a.steps;
  });
  const double ours_ms = ours.ms, ours_contacts = ours.contacts, ours_pen = ours.pen;
  std::printf("\n%-34s %12s %12s %16s\n", "engine", "ms/step", "contacts", "max pen / r");
  std::printf("%-34s %12.1f %12.0f %16.4f\n",
              ("dvisim cpu " + a.solver + " " + std::to_string(a.iterations) + " it, " +
               std::to_string(cfg.threads > 0 ? cfg.threads : omp_get_max_threads()) + " thr")
                  .c_str(),
              ours_ms, ours_contacts, ours_pen / r);
  std::printf("  stages (ms/step):");
  for (int k = 0; k < dvi::kStageCount; ++k) std::printf(" %s %.1f", dvi::stageName(dvi::StageType(k)), stage_ms[k]);
  std::printf("\n");

  double bullet_ms = 0, bullet_contacts = 0, bullet_pen = 0;
  if (a.bullet) {
    dvi::BulletPeerSettings bs;
    bs.dt = h;
    bs.solver_iterations = a.bullet_iterations;
    bs.length_scale = 100;  // centimetres: Bullet's absolute tolerances break 1 cm spheres in metres
    dvi::BulletPeer peer(pile.bodies, bs);
    const Timed b = timeSteps(peer, a, [] {});
    bullet_ms = b.ms, bullet_contacts = b.contacts, bullet_pen = b.pen;
    std::printf("%-34s %12.1f %12.0f %16.4f\n",
                ("bullet 2 SI " + std::to_string(a.bullet_iterations) + " it, 1 thr, cm units").c_str(), bullet_ms,
                bullet_contacts, bullet_pen / r);
    std::printf(
        "\nratio bullet/dvisim: time %.2fx faster, relative penetration %.2f (dvisim / bullet; <= 1 is better)\n",
        bullet_ms / ours_ms, bullet_pen > 0 ? ours_pen / bullet_pen : 0.0);
    std::printf(
        "note: Bullet ran the same pile in centimetres (length_scale 100); its numbers are converted to metres.\n");
  }
  if (!a.csv.empty()) {
    std::ofstream f(a.csv);
    f << "engine,n,steps,ms_per_step,contacts,max_penetration_rel\n";
    f << "dvisim_cpu," << a.n << "," << a.steps << "," << ours_ms << "," << ours_contacts << "," << ours_pen / r
      << "\n";
    if (a.bullet)
      f << "bullet," << a.n << "," << a.steps << "," << bullet_ms << "," << bullet_contacts << "," << bullet_pen / r
        << "\n";
  }
  return 0;
}
