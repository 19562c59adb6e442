// dvisim bench stability --out DIR [--quick] [--record] [--threads N]
//
// The stability suite: stiff and extreme cases, each stepped by our CPU backend (APGD), our
// GPU backend when there is a device, and Bullet's own btDiscreteDynamicsWorld (sequential impulse, at its
// default 10 iterations and at 100 iterations; ours at the solver's default stop), each with a stated pass criterion
// and a verdict. Every engine steps the same Bullet bodies (ours through importBullet, Bullet through the
// BulletPeer; small grains are given to Bullet in scaled units, stated per case).
//
// Metrics, the same for every engine, sampled after steps:
//  - pen_rel: the deepest penetration relative to the pair's size, max over contacts of max(0, -dist) / size,
//    where dist and size (the smaller of the two shapes' smallest half dimensions) come from OUR collision
//    detection run on the engine's poses (a probe System that only detects contacts), so Bullet's and our
//    penetrations are measured by one rule.
//  - energy_growth: (max_t E(t) - E(0)) / E_scale, E = sum 1/2 m v^2 + 1/2 w_b^T I w_b - m g.x over the moving
//    bodies, E_scale = max(kinetic E(0), sum m |g| L) with L the case's length; > 0 means energy was injected.
//  - max_speed (m/s) over the moving bodies; nan: a non-finite state or a SolverError (a failed verdict, not a
//    crash).
// Outputs: DIR/stability.csv, DIR/stability.md (case, engine, criterion, measured, verdict) and a summary on
// stdout listing every FAIL of our engine. --record also writes bench/results/stability_<device>_<date>.{md,csv}.
#include <CLI/CLI.hpp>
#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "bench_common.h"
#include "bench_util.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/bullet/bullet_peer.h"
#include "chrono_like/solver/solver.h"
#include "chrono_like/system.h"
#include "gpu/gpu_factory.h"

namespace {

using namespace dvi::benchutil;

constexpr double kPi = 3.14159265358979323846;
constexpr double kDensity = 2500;

struct StabOptions : BenchBasics {};

// `dvisim bench stability`: its name, description and the texts of its common options.
const BenchSpec kBench{"stability",
                       "Stiff and extreme cases on our backends and Bullet, each with a criterion and a verdict",
                       "stability.csv, stability.md", "Shorter runs and smaller scenes (CI smoke test)"};

struct Metrics {
  bool nan = false;
  std::string error;
  double pen_rel = 0;       // max over all samples
  double late_pen_rel = 0;  // max over samples at t >= settle time
  double energy_growth = 0, max_speed = 0, wall_s = 0;
  int steps_done = 0;
  std::vector<Vec3> final_pos, start_pos;
  std::vector<double> min_y;  // lowest y of each body over the run
};

struct Verdict {
  std::string measured;
  bool pass = false;
};

struct Case {
  std::string name, criterion, bullet_units = "m";
  std::function<void(BtBodies&)> build;
  double dt = 1e-3;
  int steps = 100;
  // Ours runs every case at the solver's default stop (relative tolerance and iteration cap, SolverSettings).
  // A case may hand-set them only with the reason in `why` (the row's note shows it).
  int iterations = 0;     // > 0: the iteration cap (a fixed count when tolerance is 0 too)
  double tolerance = -1;  // >= 0: a hand-set relative tolerance
  std::string why;
  Vec3 gravity{0, real(-9.81), 0};
  double bullet_scale = 1;
  double settle_t = 0;   // late_pen_rel from this time on
  double length = 0.01;  // L of the energy scale
  std::function<Verdict(const Metrics&)> judge;
  std::string skip;   // non-empty: not run, the reason
  bool huge = false;  // the 1e6 pile: GPU only, penetration from the engine's own statistics
};

struct Row {
  std::string name, engine, device, criterion, measured, verdict, note;
  Metrics m;
  double dt = 0;
  int steps = 0, bodies = 0;
};

// ---------- measuring ----------

// Our collision detection on an engine's poses: dist and size of every contact, nothing solved.
struct Probe {
  std::unique_ptr<dvi::System> sys;
  std::vector<int> ids;
  std::vector<bool> moving;
  explicit Probe(const std::vector<btRigidBody*>& bodies, int threads) {
    dvi::SystemConfig c;
    c.step.dt = real(1e-9);
    c.step.gravity = Vec3{0, 0, 0};
    c.solver.type = dvi::SolverType::Jacobi;
    c.solver.max_iterations = 1;
    c.solver.warm_start = false;
    c.threads = threads;
    sys = std::make_unique<dvi::System>(c);
    ids = dvi::importBullet(*sys, bodies);
    for (btRigidBody* b : bodies) moving.push_back(b->getInvMass() > 0);
  }
  double penetrationRel(const Runner& r) {
    dvi::BodyArrays& b = sys->mutableBodies();
    for (size_t i = 0; i < ids.size(); ++i) {
      if (!moving[i]) continue;
      const size_t k = size_t(ids[i]);
      b.pos[k] = r.pos(i), b.rot[k] = r.rot(i), b.vel[k] = Vec3{0, 0, 0}, b.omega[k] = Vec3{0, 0, 0};
    }
    sys->step();
    const dvi::ContactArrays& c = sys->contacts();
    const dvi::BodyArrays& bb = sys->bodies();
    double worst = 0;
    for (size_t k = 0; k < c.dist.size(); ++k) {
      if (bb.inv_mass[size_t(c.body_a[k])] <= 0 && bb.inv_mass[size_t(c.body_b[k])] <= 0) continue;
      if (c.size[k] > 0) worst = std::max(worst, double(-c.dist[k]) / double(c.size[k]));
    }
    return worst;
  }
};

double energyOf(const Runner& r, const std::vector<btRigidBody*>& bodies, Vec3 g, double* kinetic = nullptr) {
  double e = 0, ke = 0;
  for (size_t i = 0; i < bodies.size(); ++i) {
    const btRigidBody* b = bodies[i];
    if (b->getInvMass() <= 0) continue;
    const double m = 1.0 / double(b->getInvMass());
    const btVector3 inv_i = b->getInvInertiaDiagLocal();
    const Vec3 v = r.vel(i), wb = dvi::rotateInv(r.rot(i), r.omega(i));
    const double iw[3] = {inv_i.x() > 0 ? 1.0 / inv_i.x() : 0, inv_i.y() > 0 ? 1.0 / inv_i.y() : 0,
                          inv_i.z() > 0 ? 1.0 / inv_i.z() : 0};
    const double k =
        0.5 * m * double(dvi::dot(v, v)) + 0.5 * (iw[0] * wb.x * wb.x + iw[1] * wb.y * wb.y + iw[2] * wb.z * wb.z);
    ke += k;
    e += k - m * double(dvi::dot(g, r.pos(i)));
  }
  if (kinetic) *kinetic = ke;
  return e;
}

Metrics runCase(const Case& c, Runner& r, const std::vector<btRigidBody*>& bodies, int threads) {
  Metrics m;
  Probe probe(bodies, threads);
  const size_t n = bodies.size();
  double mg = 0;
  for (btRigidBody* b : bodies)
    if (b->getInvMass() > 0) mg += double(dvi::length(c.gravity)) / double(b->getInvMass());
  double ke0 = 0;
  r.sync();
  const double e0 = energyOf(r, bodies, c.gravity, &ke0);
  const double e_scale = std::max({ke0, mg * c.length, 1e-30});
  double e_max = e0;
  for (size_t i = 0; i < n; ++i) m.start_pos.push_back(r.pos(i)), m.min_y.push_back(double(r.pos(i).y));
  const int stride = n <= 400 ? 1 : 10;
  for (int s = 1; s <= c.steps; ++s) {
    try {
      r.step();
    } catch (const dvi::SolverError& e) {
      m.nan = true, m.error = std::string("SolverError: ") + e.what();
      break;
    } catch (const std::exception& e) {
      m.error = e.what();
      break;
    }
    m.wall_s += r.last_step_s;
    m.steps_done = s;
    if (s % stride != 0 && s != c.steps) continue;
    r.sync();
    bool finite = true;
    for (size_t i = 0; i < n && finite; ++i) {
      if (bodies[i]->getInvMass() <= 0) continue;
      const Vec3 p = r.pos(i), v = r.vel(i);
      if (!finite3(p) || !finite3(v) || !finite3(r.omega(i))) finite = false;
      m.max_speed = std::max(m.max_speed, double(dvi::length(v)));
      m.min_y[i] = std::min(m.min_y[i], double(p.y));
    }
    if (!finite) {
      m.nan = true, m.error = "non-finite state at step " + std::to_string(s);
      break;
    }
    e_max = std::max(e_max, energyOf(r, bodies, c.gravity));
    const double pen = probe.penetrationRel(r);
    m.pen_rel = std::max(m.pen_rel, pen);
    if (double(s) * c.dt >= c.settle_t - 1e-12) m.late_pen_rel = std::max(m.late_pen_rel, pen);
  }
  m.energy_growth = (e_max - e0) / e_scale;
  r.sync();
  for (size_t i = 0; i < n; ++i) m.final_pos.push_back(r.pos(i));
  return m;
}

// ---------- the cases ----------

std::string fmt(const char* f, double a) {
  char b[96];
  std::snprintf(b, sizeof b, f, a);
  return b;
}
std::string fmt(const char* f, double a, double b2) {
  char b[160];
  std::snprintf(b, sizeof b, f, a, b2);
  return b;
}

double boxMass(double hx, double hy, double hz) { return kDensity * 8 * hx * hy * hz; }
double sphereMass(double r) { return kDensity * 4.0 / 3.0 * kPi * r * r * r; }
Quat aboutZ(double a) { return Quat{real(std::cos(a / 2)), 0, 0, real(std::sin(a / 2))}; }

// Common failure line: NaN, solver error, exception.
bool broken(const Metrics& m, Verdict& v) {
  if (m.nan || !m.error.empty()) {
    v.measured = (m.nan ? "NaN/solver error: " : "error: ") + m.error;
    v.pass = false;
    return true;
  }
  return false;
}

// Ground plane (friction mu_ground) + a stack of n boxes of half size a, the top one `ratio` times heavier.
void buildStack(BtBodies& s, int n, double a, double ratio, double mu) {
  s.add(new btStaticPlaneShape(btVector3(0, 1, 0), 0), 0, Vec3{0, 0, 0}, real(mu));
  btCollisionShape* box = s.own(new btBoxShape(btVector3(btScalar(a), btScalar(a), btScalar(a))));
  const double m = boxMass(a, a, a);
  for (int i = 0; i < n; ++i) {
    const double y = a * (1.0002 + 2.0002 * i);
    s.addShared(box, i == n - 1 ? m * ratio : m, Vec3{0, real(y), 0}, real(mu));
  }
}

// The solver settings of ours for a case: the defaults unless the case hand-sets them (Case::why).
void applySolver(const Case& c, dvi::SolverSettings& s) {
  if (c.iterations > 0) s.max_iterations = c.iterations;
  if (c.tolerance >= 0)
    s.tolerance = real(c.tolerance);
  else if (c.iterations > 0)
    s.tolerance = 0;  // a fixed count
}

// The cases of makeCases: mass ratios in a stack and between particles, tall stacks.
void massAndStackCases(std::vector<Case>& cases, bool quick) {
  // 1. Mass ratios in a stack: 10 boxes of 10 cm (4 from 1e4 on), the top one R times heavier; h = 1/60 s.
  for (double ratio : {1e2, 1e4, 1e6}) {
    Case c;
    c.name = "stack_mass_ratio_" + fmt("%.0e", ratio);
    const double a = 0.05;
    const int nb = ratio < 1e3 ? 10 : 4;
    c.build = [=](BtBodies& s) { buildStack(s, nb, a, ratio, 0.7); };
    c.dt = 1.0 / 60, c.steps = quick ? 60 : 180, c.length = a;
    c.criterion = std::to_string(nb) + " boxes (10 cm), top " + fmt("%.0e", ratio) +
                  "x heavier, h = 1/60 s: top box moves < 10% of its half size, penetration < 5% of the half size";
    c.judge = [a](const Metrics& m) {
      Verdict v;
      if (broken(m, v)) return v;
      const double d = double(dvi::length(m.final_pos.back() - m.start_pos.back())) / a;
      v.measured = fmt("top moved %.3g half sizes, pen %.3g", d, m.pen_rel);
      v.pass = d < 0.1 && m.pen_rel < 0.05;
      return v;
    };
    cases.push_back(c);
  }
  // 2. Mass ratios between particles: 2x2 spheres (r = 1 cm) in a tight box, one R times heavier on top.
  for (double ratio : {1e2, 1e4, 1e6}) {
    Case c;
    c.name = "particle_mass_ratio_" + fmt("%.0e", ratio);
    const double r = 0.01;
    c.build = [=](BtBodies& s) {
      s.add(new btStaticPlaneShape(btVector3(0, 1, 0), 0), 0, Vec3{0, 0, 0}, real(0.7));
      const double w = 4 * r * 1.001, t = 0.01, h = 4 * r;
      for (int k = 0; k < 4; ++k) {  // walls: inner faces x = 0, w and z = 0, w
        const bool xw = k < 2;
        const double c0 = (k % 2 == 0) ? -t : w + t;
        btCollisionShape* wall = new btBoxShape(xw ? btVector3(btScalar(t), btScalar(h), btScalar(w))
                                                   : btVector3(btScalar(w), btScalar(h), btScalar(t)));
        s.add(wall, 0, xw ? Vec3{real(c0), real(h), real(w / 2)} : Vec3{real(w / 2), real(h), real(c0)}, real(0.7));
      }
      btCollisionShape* sph = s.own(new btSphereShape(btScalar(r)));
      const double m = sphereMass(r);
      for (int i = 0; i < 4; ++i)
        s.addShared(sph, m,
                    Vec3{real(r * (1.0005 + 2.001 * (i % 2))), real(r * 1.0005), real(r * (1.0005 + 2.001 * (i / 2)))},
                    real(0.7));
      s.addShared(sph, m * ratio, Vec3{real(w / 2), real(r * (1.001 + std::sqrt(2.0) * 1.001)), real(w / 2)},
                  real(0.7));
    };
    c.dt = 1e-3, c.steps = quick ? 300 : 1000, c.length = r, c.bullet_scale = 100, c.bullet_units = "cm";
    c.criterion = "2x2 spheres (r 1 cm) in a box, one " + fmt("%.0e", ratio) +
                  "x heavier on top, h = 1e-3 s: heavy sphere sinks < 5% of r, penetration < 5% of r";
    c.judge = [r](const Metrics& m) {
      Verdict v;
      if (broken(m, v)) return v;
      const double sink = (double(m.start_pos.back().y) - double(m.final_pos.back().y)) / r;
      v.measured = fmt("heavy sank %.3g r, pen %.3g", sink, m.pen_rel);
      v.pass = std::fabs(sink) < 0.05 && m.pen_rel < 0.05;
      return v;
    };
    cases.push_back(c);
  }
  // 3. Tall stacks at h = 1/60 s.
  for (int n : {30, 100}) {
    Case c;
    c.name = "tall_stack_" + std::to_string(n);
    const double a = 0.05;
    c.build = [=](BtBodies& s) { buildStack(s, n, a, 1.0, 0.7); };
    c.dt = 1.0 / 60, c.steps = quick ? 60 : 180, c.length = a;
    c.criterion = std::to_string(n) + " boxes (10 cm), h = 1/60 s, " + (quick ? "1 s" : "3 s") +
                  ": top box moves < 10% of its half size, penetration < 5% of the half size";
    c.judge = [a](const Metrics& m) {
      Verdict v;
      if (broken(m, v)) return v;
      const double d = double(dvi::length(m.final_pos.back() - m.start_pos.back())) / a;
      v.measured = fmt("top moved %.3g half sizes, pen %.3g", d, m.pen_rel);
      v.pass = d < 0.1 && m.pen_rel < 0.05;
      return v;
    };
    cases.push_back(c);
  }
}

// The cases of makeCases: particles from 0.1 mm to 10 cm in one scene.
void scaleRangeCase(std::vector<Case>& cases, bool quick) {
  // 4. Particles from 0.1 mm to 10 cm in one scene: a graded stack of cubes (10 cm, 1 cm, 1 mm, 0.1 mm) on the
  //    ground and spheres of 0.1 mm .. 10 cm diameter resting on the ground, h = 1e-3 s.
  {
    Case c;
    c.name = "size_range_0.1mm_10cm";
    c.build = [](BtBodies& s) {
      s.add(new btStaticPlaneShape(btVector3(0, 1, 0), 0), 0, Vec3{0, 0, 0}, real(0.7));
      double y = 0;
      for (double a : {0.05, 0.005, 0.0005, 0.00005}) {
        s.add(new btBoxShape(btVector3(btScalar(a), btScalar(a), btScalar(a))), boxMass(a, a, a),
              Vec3{0, real(y + a * 1.001), 0}, real(0.7));
        y += 2 * a * 1.001;
      }
      double x = 0.1;
      for (double r : {0.05, 0.005, 0.0005, 0.00005}) {
        s.add(new btSphereShape(btScalar(r)), sphereMass(r), Vec3{real(x + r), real(r * 1.001), 0}, real(0.7));
        x += 2 * r + 0.01;
      }
    };
    c.dt = 1e-3, c.steps = quick ? 300 : 1000, c.length = 0.05, c.settle_t = 0;
    c.bullet_scale = 100, c.bullet_units = "cm";
    // Each cube starts 0.1% of its size above the one below, so the stack first closes its gaps (0.11 mm in
    // all, 2.2 sizes of the 0.1 mm cube): bodies are judged against their analytic rest positions (cube i at
    // y = 2 sum_{j<i} a_j + a_i, spheres at y = r), not against where they started.
    c.criterion =
        "cubes and spheres of 0.1 mm..10 cm, h = 1e-3 s: every body ends within 10% of its size of its "
        "analytic rest position, penetration < 5% of the pair's size";
    c.judge = [](const Metrics& m) {
      Verdict v;
      if (broken(m, v)) return v;
      const double sizes[] = {0, 0.05, 0.005, 0.0005, 0.00005, 0.05, 0.005, 0.0005, 0.00005};
      const char* names[] = {"",
                             "10 cm cube",
                             "1 cm cube",
                             "1 mm cube",
                             "0.1 mm cube",
                             "10 cm sphere",
                             "1 cm sphere",
                             "1 mm sphere",
                             "0.1 mm sphere"};
      double worst = 0;
      size_t wi = 1;
      double below = 0;  // height of the cubes below cube i
      for (size_t i = 1; i < m.final_pos.size() && i < 9; ++i) {
        Vec3 rest = m.start_pos[i];
        if (i <= 4) {
          rest.y = real(below + sizes[i]);
          below += 2 * sizes[i];
        } else {
          rest.y = real(sizes[i]);
        }
        const double d = double(dvi::length(m.final_pos[i] - rest)) / sizes[i];
        if (d > worst) worst = d, wi = i;
      }
      v.measured = std::string("worst: ") + names[wi] + fmt(" moved %.3g sizes, pen %.3g", worst, m.pen_rel);
      v.pass = worst < 0.1 && m.pen_rel < 0.05;
      return v;
    };
    cases.push_back(c);
  }
}

// The cases of makeCases: 0.1 mm particles at h = 1e-4 s.
void finePileCase(std::vector<Case>& cases, bool quick) {
  // 5. 0.1 mm particles at h = 1e-4 s: a collapsing pile of spheres of 0.1 mm diameter in a box.
  {
    Case c;
    c.name = "tiny_0.1mm_h1e-4";
    const double r = 5e-5;
    const int side = quick ? 3 : 6, layers = quick ? 4 : 8;
    c.build = [=](BtBodies& s) {
      s.add(new btStaticPlaneShape(btVector3(0, 1, 0), 0), 0, Vec3{0, 0, 0}, real(0.7));
      const double pitch = 2.1 * r, w = side * pitch, t = 10 * r, h = layers * 2 * r;
      for (int k = 0; k < 4; ++k) {
        const bool xw = k < 2;
        const double c0 = (k % 2 == 0) ? -t : w + t;
        btCollisionShape* wall = new btBoxShape(xw ? btVector3(btScalar(t), btScalar(h), btScalar(w + 2 * t))
                                                   : btVector3(btScalar(w + 2 * t), btScalar(h), btScalar(t)));
        s.add(wall, 0, xw ? Vec3{real(c0), real(h), real(w / 2)} : Vec3{real(w / 2), real(h), real(c0)}, real(0.7));
      }
      btCollisionShape* sph = s.own(new btSphereShape(btScalar(r)));
      uint64_t st = 12345;
      auto rnd = [&] {
        st = st * 6364136223846793005ull + 1442695040888963407ull;
        return double(st >> 11) / 9007199254740992.0;
      };
      for (int l = 0; l < layers; ++l)
        for (int i = 0; i < side * side; ++i)
          s.addShared(sph, sphereMass(r),
                      Vec3{real((i % side + 0.5) * pitch + (rnd() - 0.5) * 0.1 * r), real(r * (1.001 + 2.002 * l)),
                           real((i / side + 0.5) * pitch + (rnd() - 0.5) * 0.1 * r)},
                      real(0.7));
    };
    c.dt = 1e-4, c.steps = quick ? 300 : 1000, c.length = r, c.settle_t = 0;
    c.bullet_scale = 1e4, c.bullet_units = "x1e4 (0.5 units)";
    c.criterion = std::to_string(side * side * layers) +
                  " spheres of 0.1 mm diameter in a box, h = 1e-4 s: penetration < 5% of r, energy growth < 10% of "
                  "m g r, max speed < 0.5 m/s";
    c.judge = [](const Metrics& m) {
      Verdict v;
      if (broken(m, v)) return v;
      v.measured =
          fmt("pen %.3g, energy growth %.3g", m.pen_rel, m.energy_growth) + fmt(", vmax %.3g m/s", m.max_speed);
      v.pass = m.pen_rel < 0.05 && m.energy_growth < 0.1 && m.max_speed < 0.5;
      return v;
    };
    cases.push_back(c);
  }
}

// The cases of makeCases: impacts on a thin wall, friction from 0 to 2.
void impactAndFrictionCases(std::vector<Case>& cases, bool quick) {
  // 6. Impacts at 10-100 m/s on a thin wall (2 mm, fixed), sphere r = 1 cm, no gravity, h = 1e-3 s.
  for (double speed : {10.0, 30.0, 100.0}) {
    Case c;
    c.name = "impact_" + fmt("%.0f", speed) + "mps_thin_wall";
    const double r = 0.01;
    c.build = [=](BtBodies& s) {
      s.add(new btBoxShape(btVector3(0.001f, 0.1f, 0.1f)), 0, Vec3{0, 0, 0}, real(0.5));
      s.add(new btSphereShape(btScalar(r)), sphereMass(r), Vec3{real(-0.001 - r - 0.047), 0, 0}, real(0.5),
            Vec3{real(speed), 0, 0});
    };
    c.dt = 1e-3, c.steps = 60, c.length = r, c.gravity = Vec3{0, 0, 0};
    c.bullet_scale = 100, c.bullet_units = "cm";
    c.criterion = "sphere r 1 cm at " + fmt("%.0f", speed) +
                  " m/s onto a 2 mm fixed wall, h = 1e-3 s: stays on its side (no tunnelling), speed never above "
                  "1.05 x the impact speed";
    c.judge = [speed](const Metrics& m) {
      Verdict v;
      if (broken(m, v)) return v;
      const double x = double(m.final_pos.back().x);
      const bool tunnel = x > 0;
      v.measured = std::string(tunnel ? "TUNNELLED" : "bounced/stopped") +
                   fmt(", final x %.3g m, vmax %.3g m/s", x, m.max_speed);
      v.pass = !tunnel && m.max_speed <= 1.05 * speed;
      return v;
    };
    cases.push_back(c);
  }
  // 7. Friction from 0 to 2: a 10 cm box on a 30-degree incline (gravity tilted), 1 s.
  for (double mu : {0.0, 0.5, 1.0, 2.0}) {
    Case c;
    c.name = "friction_mu_" + fmt("%g", mu);
    const double a = 0.05, th = kPi / 6, g = 9.81;
    c.build = [=](BtBodies& s) {
      s.add(new btStaticPlaneShape(btVector3(0, 1, 0), 0), 0, Vec3{0, 0, 0}, real(1.0));
      s.add(new btBoxShape(btVector3(btScalar(a), btScalar(a), btScalar(a))), boxMass(a, a, a),
            Vec3{0, real(a * 1.0005), 0}, real(mu));
    };
    c.gravity = Vec3{real(g * std::sin(th)), real(-g * std::cos(th)), 0};
    const double T = quick ? 0.5 : 1.0;
    c.dt = 1e-3, c.steps = int(std::lround(T / c.dt)), c.length = a;
    const double acc = std::max(0.0, g * (std::sin(th) - mu * std::cos(th)));
    const double expect = 0.5 * acc * T * T;
    c.criterion = "box on a 30 deg incline, mu = " + fmt("%g", mu) + ", " + fmt("%g s", T) +
                  (acc > 0 ? ": slides " + fmt("%.4g m", expect) + " (analytic) within 5%"
                           : ": sticks (moves < 1% of its half size)");
    c.judge = [=](const Metrics& m) {
      Verdict v;
      if (broken(m, v)) return v;
      const double d = double(m.final_pos.back().x - m.start_pos.back().x);
      if (acc > 0) {
        v.measured = fmt("slid %.4g m (analytic %.4g)", d, expect);
        v.pass = std::fabs(d - expect) <= 0.05 * expect;
      } else {
        v.measured = fmt("moved %.3g half sizes", std::fabs(d) / a);
        v.pass = std::fabs(d) / a < 0.01;
      }
      return v;
    };
    cases.push_back(c);
  }
}

// The cases of makeCases: initially overlapping bodies, thin plates and needles.
void overlapAndThinCases(std::vector<Case>& cases, bool quick) {
  // 8. Initially overlapping bodies: 27 spheres r = 1 cm on a lattice of pitch 1.5 cm (0.5 cm overlaps, bottom
  //    layer 0.25 cm into the ground) and two boxes overlapping by a quarter of their size.
  {
    Case c;
    c.name = "initial_overlap";
    const double r = 0.01;
    c.build = [=](BtBodies& s) {
      s.add(new btStaticPlaneShape(btVector3(0, 1, 0), 0), 0, Vec3{0, 0, 0}, real(0.7));
      btCollisionShape* sph = s.own(new btSphereShape(btScalar(r)));
      for (int i = 0; i < 27; ++i)
        s.addShared(sph, sphereMass(r),
                    Vec3{real(1.5 * r * (i % 3)), real(0.75 * r + 1.5 * r * (i / 9)), real(1.5 * r * ((i / 3) % 3))},
                    real(0.7));
      const double a = 0.02;
      btCollisionShape* box = s.own(new btBoxShape(btVector3(btScalar(a), btScalar(a), btScalar(a))));
      s.addShared(box, boxMass(a, a, a), Vec3{0.2f, real(a), 0}, real(0.7));
      s.addShared(box, boxMass(a, a, a), Vec3{0.2f, real(2.5 * a), real(0.3 * a)}, real(0.7));
    };
    c.dt = 1e-3, c.steps = quick ? 500 : 1000, c.length = r, c.settle_t = 0.4;
    c.bullet_scale = 100, c.bullet_units = "cm";
    c.criterion =
        "27 spheres overlapping by 25% of their diameter and 2 boxes by 25%: penetration < 5% of size "
        "from t = 0.4 s on, max speed < 1 m/s (no explosion)";
    c.judge = [](const Metrics& m) {
      Verdict v;
      if (broken(m, v)) return v;
      v.measured = fmt("pen after 0.4 s %.3g, vmax %.3g m/s", m.late_pen_rel, m.max_speed) +
                   fmt(", energy growth %.3g", m.energy_growth);
      v.pass = m.late_pen_rel < 0.05 && m.max_speed < 1.0;
      return v;
    };
    cases.push_back(c);
  }
  // 9. Thin plates and needles: two 20 x 0.2 x 20 cm plates dropped flat from 2 and 4 cm (the second onto the
  //    first) and a needle (cylinder r = 1 mm, 10 cm long) dropped lying from 2 cm, h = 1e-3 s.
  {
    Case c;
    c.name = "thin_plates_needle";
    const double t = 0.001;
    c.build = [=](BtBodies& s) {
      s.add(new btStaticPlaneShape(btVector3(0, 1, 0), 0), 0, Vec3{0, 0, 0}, real(0.7));
      btCollisionShape* plate = s.own(new btBoxShape(btVector3(0.1f, btScalar(t), 0.1f)));
      s.addShared(plate, boxMass(0.1, t, 0.1), Vec3{0, real(t + 0.02), 0}, real(0.7));
      s.addShared(plate, boxMass(0.1, t, 0.1), Vec3{0.03f, real(3 * t + 0.04), 0.02f}, real(0.7));
      s.add(new btCylinderShape(btVector3(0.001f, 0.05f, 0.001f)), kDensity * kPi * 1e-6 * 0.1, Vec3{0.3f, 0.021f, 0},
            real(0.7), Vec3{0, 0, 0}, aboutZ(kPi / 2));
    };
    c.dt = 1e-3, c.steps = quick ? 500 : 1000, c.length = t, c.settle_t = 0.4;
    c.criterion =
        "plates 2 mm thick and a 2 mm needle dropped onto the ground and onto each other: nothing passes "
        "through (order kept, above ground), penetration < 5% of the thin half size from t = 0.4 s on";
    c.judge = [t](const Metrics& m) {
      Verdict v;
      if (broken(m, v)) return v;
      const double y1 = double(m.final_pos[1].y), y2 = double(m.final_pos[2].y), yn = double(m.final_pos[3].y);
      const bool order = y1 > 0 && y2 > y1 + t && yn > 0;
      v.measured = fmt("plates at y %.4g, %.4g m", y1, y2) + fmt(", needle %.4g m, late pen %.3g", yn, m.late_pen_rel);
      v.pass = order && m.late_pen_rel < 0.05;
      return v;
    };
    cases.push_back(c);
  }
}

// The cases of makeCases: a 1e6-body pile (GPU, full mode).
void hugePileCase(std::vector<Case>& cases, bool quick, bool have_gpu) {
  // 10. A 1e6-body pile: full mode, on the GPU only.
  {
    Case c;
    c.name = "pile_1e6";
    c.huge = true;
    c.dt = 1e-3, c.steps = 100, c.length = 0.01;
    c.criterion =
        "1e6 spheres (r 1 cm) in a box, h = 1e-3 s, 100 steps: no NaN, penetration < 5% of r, max speed < 1 m/s";
    if (quick)
      c.skip = "skipped: --quick (full mode only)";
    else if (!have_gpu)
      c.skip = "skipped: needs the GPU backend (no GPU in this run)";
    c.judge = [](const Metrics& m) {
      Verdict v;
      if (broken(m, v)) return v;
      v.measured = fmt("pen %.3g, vmax %.3g m/s", m.pen_rel, m.max_speed);
      v.pass = m.pen_rel < 0.05 && m.max_speed < 1.0;
      return v;
    };
    cases.push_back(c);
  }
}

std::vector<Case> makeCases(bool quick, bool have_gpu) {
  std::vector<Case> cases;
  massAndStackCases(cases, quick);
  scaleRangeCase(cases, quick);
  finePileCase(cases, quick);
  impactAndFrictionCases(cases, quick);
  overlapAndThinCases(cases, quick);
  hugePileCase(cases, quick, have_gpu);
  return cases;
}

// The 1e6 pile on the GPU: penetration from the engine's own statistics (max_penetration / r), speeds sampled.
Metrics runHugePile(const Case& c, int threads) {
  (void)threads;
  Metrics m;
  BtBodies s;
  const double r = 0.01;
  const long n = 1000000, side = 80;
  const double pitch = 2.1 * r, w = side * pitch;
  s.add(new btStaticPlaneShape(btVector3(0, 1, 0), 0), 0, Vec3{0, 0, 0}, real(0.7));
  const long layers = (n + side * side - 1) / (side * side);
  const double h = layers * 2 * r;
  for (int k = 0; k < 4; ++k) {
    const bool xw = k < 2;
    const double c0 = (k % 2 == 0) ? -0.05 : w + 0.05;
    btCollisionShape* wall =
        new btBoxShape(xw ? btVector3(0.05f, btScalar(h), btScalar(w)) : btVector3(btScalar(w), btScalar(h), 0.05f));
    s.add(wall, 0, xw ? Vec3{real(c0), real(h), real(w / 2)} : Vec3{real(w / 2), real(h), real(c0)}, real(0.7));
  }
  btCollisionShape* sph = s.own(new btSphereShape(btScalar(r)));
  for (long i = 0; i < n; ++i) {
    const long l = i / (side * side), in = i % (side * side);
    s.addShared(sph, sphereMass(r),
                Vec3{real((in % side + 0.5) * pitch + 0.0004 * ((i * 7) % 5 - 2)), real(r * (1.001 + 2.002 * l)),
                     real((in / side + 0.5) * pitch)},
                real(0.7));
  }
  dvi::SystemConfig cfg;
  cfg.step.dt = real(c.dt);
  cfg.solver.type = dvi::SolverType::APGD;
  applySolver(c, cfg.solver);
  OursRunner run(s.bodies, cfg, true);
  for (int k = 1; k <= c.steps; ++k) {
    try {
      run.step();
    } catch (const dvi::SolverError& e) {
      m.nan = true, m.error = e.what();
      break;
    } catch (const std::exception& e) {
      m.error = e.what();
      break;
    }
    m.wall_s += run.last_step_s;
    m.steps_done = k;
    m.pen_rel = std::max(m.pen_rel, double(run.sys->lastStats().max_penetration) / r);
    if (k % 20 == 0 || k == c.steps) {
      run.sync();
      for (size_t i = 5; i < s.bodies.size(); ++i) {
        const Vec3 v = run.vel(i);
        if (!finite3(v) || !finite3(run.pos(i))) {
          m.nan = true, m.error = "non-finite state";
          break;
        }
        m.max_speed = std::max(m.max_speed, double(dvi::length(v)));
      }
      if (m.nan) break;
    }
  }
  return m;
}

// ---------- outputs ----------

const char* kCsvHeader =
    "case,engine,criterion,measured,verdict,max_penetration_rel,late_penetration_rel,energy_growth,max_speed_mps,nan,"
    "dt_s,steps,steps_done,bodies,wall_s,device,note";

std::string csvText(const std::vector<Row>& rows) {
  std::ostringstream o;
  o << kCsvHeader << "\n";
  for (const Row& r : rows) {
    const bool ran = r.verdict != "SKIP";
    auto v = [&](double x) { return ran ? num(x) : std::string(); };
    o << r.name << "," << r.engine << "," << csvField(r.criterion) << "," << csvField(r.measured) << "," << r.verdict
      << "," << v(r.m.pen_rel) << "," << v(r.m.late_pen_rel) << "," << v(r.m.energy_growth) << "," << v(r.m.max_speed)
      << "," << (ran ? (r.m.nan ? "1" : "0") : "") << "," << num(r.dt) << "," << r.steps << ","
      << (ran ? std::to_string(r.m.steps_done) : "") << "," << r.bodies << "," << v(r.m.wall_s) << ","
      << csvField(r.device) << "," << csvField(r.note) << "\n";
  }
  return o.str();
}

std::string mdCell(std::string s) {
  for (char& c : s)
    if (c == '|' || c == '\n') c = '/';
  return s;
}

std::string mdTable(const std::vector<Row>& rows) {
  std::ostringstream o;
  o << "| case | engine | criterion | measured | verdict |\n| --- | --- | --- | --- | --- |\n";
  for (const Row& r : rows)
    o << "| " << r.name << " | " << r.engine << " | " << mdCell(r.criterion) << " | " << mdCell(r.measured) << " | "
      << (r.verdict == "FAIL" ? "**FAIL**" : r.verdict) << " |\n";
  return o.str();
}

std::string summaryText(const std::vector<Row>& rows) {
  std::ostringstream o;
  int ours = 0, ours_pass = 0, bl = 0, bl_pass = 0;
  std::vector<const Row*> fails, bullet_fails;
  for (const Row& r : rows) {
    if (r.verdict == "SKIP") continue;
    const bool is_ours = r.engine == "cpu" || r.engine == "gpu";
    (is_ours ? ours : bl)++;
    if (r.verdict == "PASS")
      (is_ours ? ours_pass : bl_pass)++;
    else
      (is_ours ? fails : bullet_fails).push_back(&r);
  }
  o << "Summary: our engine passes " << ours_pass << " of " << ours << " runs; Bullet passes " << bl_pass << " of "
    << bl << ".\n";
  if (fails.empty())
    o << "Our engine: no failures.\n";
  else {
    o << "FAILURES of our engine (" << fails.size() << "):\n";
    for (const Row* r : fails) o << "  - " << r->name << " [" << r->engine << "]: " << r->measured << "\n";
  }
  if (!bullet_fails.empty()) {
    o << "Bullet fails:";
    for (const Row* r : bullet_fails) o << " " << r->name << "[" << r->engine << "]";
    o << "\n";
  }
  return o.str();
}

// One case on one engine (ours on the CPU or GPU when bullet_iters is 0, else Bullet at that many iterations): its
// row with the verdict, or the error it ended with. cpu_device: set by the CPU run.
Row runEngine(const Case& c, const std::string& engine, int bullet_iters, int threads, std::string& cpu_device) {
  Row r;
  r.name = c.name, r.engine = engine, r.criterion = c.criterion, r.dt = c.dt, r.steps = c.steps;
  try {
    BtBodies s;
    c.build(s);
    r.bodies = int(s.bodies.size());
    std::unique_ptr<Runner> run;
    if (bullet_iters == 0) {
      dvi::SystemConfig cfg;
      cfg.step.dt = real(c.dt);
      cfg.step.gravity = c.gravity;
      cfg.solver.type = dvi::SolverType::APGD;
      applySolver(c, cfg.solver);
      cfg.threads = threads;
      run = std::make_unique<OursRunner>(s.bodies, cfg, engine == "gpu");
      const dvi::SolverSettings& ss = cfg.solver;
      r.note = ss.tolerance > 0 ? "APGD to relative residual " + fmt("%.0e", double(ss.tolerance)) + ", at most " +
                                      std::to_string(ss.max_iterations) + " iterations"
                                : "APGD " + std::to_string(ss.max_iterations) + " iterations";
      r.note += c.why.empty() ? " (defaults)" : " (hand-set: " + c.why + ")";
    } else {
      dvi::BulletPeerSettings bs;
      bs.dt = real(c.dt);
      bs.gravity = c.gravity;
      bs.solver_iterations = bullet_iters;
      bs.length_scale = real(c.bullet_scale);
      run = std::make_unique<BulletRunner>(s.bodies, bs);
      r.note = "Bullet in " + c.bullet_units + ", " + std::to_string(bullet_iters) + " iterations, no CCD";
    }
    r.device = run->device();
    if (engine == "cpu") cpu_device = r.device;
    r.m = runCase(c, *run, s.bodies, threads);
    if (const auto* ours = dynamic_cast<const OursRunner*>(run.get())) {
      const dvi::ConvergenceLog& cl = ours->sys->convergence();
      r.note += "; " + std::to_string(cl.steps_not_converged) + "/" + std::to_string(cl.steps) +
                " steps missed the tolerance, worst relative residual " +
                fmt("%.2g", double(cl.worst_relative_residual));
    }
    const Verdict v = c.judge(r.m);
    r.measured = v.measured, r.verdict = v.pass ? "PASS" : "FAIL";
  } catch (const std::exception& ex) {
    r.measured = std::string("error: ") + ex.what(), r.verdict = "FAIL", r.m.error = ex.what();
  }
  return r;
}

int runStability(const StabOptions& o) {
  const int threads = benchThreads(o.threads);
  prepareOutDir(o.out, "stability.csv");
  const std::string results_dir = o.record ? resultsDir() : std::string();
  std::string gpu_name;
  const bool have_gpu = dvi::gpuAvailable(&gpu_name);
  std::printf("bench stability%s: our CPU backend (APGD 100 iterations)%s, Bullet (10 and 100 iterations)\n",
              o.quick ? " --quick" : "", have_gpu ? (", our GPU (" + gpu_name + ")").c_str() : ", no GPU in this run");
  std::fflush(stdout);

  std::vector<Row> rows;
  std::string cpu_device;
  const auto t_all = Clock::now();
  for (const Case& c : makeCases(o.quick, have_gpu)) {
    struct Eng {
      std::string name;
      int bullet_iters;  // 0: ours
    };
    std::vector<Eng> engines = {{"cpu", 0}};
    if (have_gpu) engines.push_back({"gpu", 0});
    engines.push_back({"bullet", 10});
    engines.push_back({"bullet100", 100});
    if (!c.skip.empty() || c.huge) {
      Row r;
      r.name = c.name, r.criterion = c.criterion, r.dt = c.dt, r.steps = c.steps;
      if (!c.skip.empty()) {
        r.engine = c.huge ? "gpu" : "all", r.verdict = "SKIP", r.measured = c.skip;
      } else {
        r.engine = "gpu";
        r.bodies = 1000005;
        r.m = runHugePile(c, int(threads));
        const Verdict v = c.judge(r.m);
        r.measured = v.measured, r.verdict = v.pass ? "PASS" : "FAIL", r.device = gpu_name;
        r.note = "Bullet not run at 1e6 bodies (hours per step on one thread)";
      }
      rows.push_back(r);
      std::printf("  %-28s %-9s %-4s  %s\n", r.name.c_str(), r.engine.c_str(), r.verdict.c_str(), r.measured.c_str());
      writeFile(o.out + "/stability.csv", csvText(rows));
      continue;
    }
    for (const Eng& e : engines) {
      const Row r = runEngine(c, e.name, e.bullet_iters, threads, cpu_device);
      rows.push_back(r);
      std::printf("  %-28s %-9s %-4s  %s  (%.2f s)\n", r.name.c_str(), r.engine.c_str(), r.verdict.c_str(),
                  r.measured.c_str(), r.m.wall_s);
      std::fflush(stdout);
      writeFile(o.out + "/stability.csv", csvText(rows));
    }
  }
  const double total = std::chrono::duration<double>(Clock::now() - t_all).count();
  const std::string summary = summaryText(rows);
  const std::string device = have_gpu ? gpu_name : cpu_device;
  std::ostringstream md;
  md << "# Stability on stiff and extreme cases" << (o.quick ? " (--quick)" : "") << "\n\n"
     << "Written by `dvisim bench stability` (bench/stability/bench_stability.cpp).\n\n"
     << "- device: " << device << "\n- commit: " << commitId() << "\n- date: " << utcNow("%Y-%m-%dT%H:%M:%SZ")
     << "\n- engines: cpu/gpu = ours, APGD at the solver's default stop (relative tolerance, iteration cap) unless the "
        "row's note says why not; bullet = btDiscreteDynamicsWorld at its default 10 "
        "sequential-impulse iterations, bullet100 = 100 iterations; Bullet without CCD, small grains in scaled units "
        "(see stability.csv `note`).\n"
     << "- penetration is measured for every engine by our collision detection on the engine's poses, relative to the "
        "pair's size (the smaller smallest half dimension); energy growth is relative to max(initial kinetic energy, "
        "sum m g L).\n\n"
     << mdTable(rows) << "\n"
     << summary << "\nTotal run time " << num(total, "%.1f") << " s.\n";
  writeFile(o.out + "/stability.csv", csvText(rows));
  writeFile(o.out + "/stability.md", md.str());
  std::printf("\n%s", summary.c_str());
  std::printf("results: %s/stability.csv, %s/stability.md (%.1f s)\n", o.out.c_str(), o.out.c_str(), total);
  if (o.record) {
    const std::string base = "stability_" + slug(device) + "_" + utcNow("%Y%m%d-%H%M%S");
    writeBenchRecord({results_dir}, base, {{"md", md.str()}, {"csv", csvText(rows)}}, writeFile);
  }
  return 0;
}

}  // namespace

void registerBenchStability(CLI::App& app, BenchRegistry& reg) {
  addBench<StabOptions>(app, reg, kBench, runStability);
}
