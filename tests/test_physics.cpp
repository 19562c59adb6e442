// Whole-engine physics tests on the CPU backend, each against an analytic answer.
#include <omp.h>

#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <vector>

#include "chrono_like/system.h"

using namespace dvi;

namespace {

const real g = real(9.81);
constexpr double kPi = 3.14159265358979323846;

BodyDesc ground() {
  BodyDesc b;
  b.mass = 0;
  b.flags = kBodyFixed;
  b.friction = 1;
  b.shapes.push_back(makePlane(Vec3{0, 1, 0}, 0));
  return b;
}

BodyDesc box(Vec3 half, real mass, Vec3 pos, real friction) {
  BodyDesc b;
  b.pos = pos;
  b.mass = mass;
  b.inertia = Vec3{mass / 3 * (half.y * half.y + half.z * half.z), mass / 3 * (half.x * half.x + half.z * half.z),
                   mass / 3 * (half.x * half.x + half.y * half.y)};
  b.friction = friction;
  b.shapes.push_back(makeBox(half));
  return b;
}

BodyDesc sphere(real r, real mass, Vec3 pos, real friction) {
  BodyDesc b;
  b.pos = pos;
  b.mass = mass;
  real I = real(0.4) * mass * r * r;  // solid sphere
  b.inertia = Vec3{I, I, I};
  b.friction = friction;
  b.shapes.push_back(makeSphere(r));
  return b;
}

// Settings of the resting tests: h = 1 ms, APGD with at most `iterations` iterations a step.
SystemConfig apgdConfig(int iterations) {
  SystemConfig cfg;
  cfg.step.dt = real(1e-3);
  cfg.solver.type = SolverType::APGD;
  cfg.solver.max_iterations = iterations;
  return cfg;
}

// Sum of the contact forces acting on body `on` from body `from` (all contacts between the two).
Vec3 forceBetween(const System& sys, int from, int on) {
  Vec3 f{0, 0, 0};
  const ContactArrays& c = sys.contacts();
  for (size_t k = 0; k < c.count(); ++k) {
    if (c.body_a[k] == from && c.body_b[k] == on) f += sys.contactForce(k);
    if (c.body_b[k] == from && c.body_a[k] == on) f -= sys.contactForce(k);
  }
  return f;
}

}  // namespace

TEST_CASE("free fall follows the semi-implicit Euler solution of y'' = -g", "[physics]") {
  SystemConfig cfg;
  cfg.step.dt = real(1e-3);
  System sys(cfg);
  int b = sys.addBody(sphere(real(0.1), 1, Vec3{0, 10, 0}, real(0.5)));
  const int n = 500;
  sys.advance(n);
  // Semi-implicit Euler: v_k = -g h k, y_n = y0 - g h^2 n(n+1)/2 (exact for the discrete scheme),
  // within g h t / 2 of the continuous y0 - g t^2 / 2.
  const real h = cfg.step.dt, t = n * h;
  CHECK(sys.bodies().pos[b].y == Approx(10 - g * h * h * n * (n + 1) / 2).epsilon(1e-12));
  CHECK(sys.bodies().pos[b].y == Approx(10 - g * t * t / 2).margin(g * h * t));
  CHECK(sys.bodies().vel[b].y == Approx(-g * t).epsilon(1e-12));
  CHECK(sys.lastStats().contacts == 0);
}

TEST_CASE("a box resting on a plane carries m g", "[physics]") {
  SystemConfig cfg = apgdConfig(100);
  System sys(cfg);
  int gr = sys.addBody(ground());
  const real m = 2;
  int b = sys.addBody(box(Vec3{real(0.1), real(0.05), real(0.1)}, m, Vec3{0, real(0.0505), 0}, real(0.5)));
  sys.advance(300);
  Vec3 f = forceBetween(sys, gr, b);
  CHECK(f.y == Approx(m * g).epsilon(0.01));
  CHECK(std::fabs(f.x) < 1e-3 * m * g);
  CHECK(std::fabs(f.z) < 1e-3 * m * g);
  CHECK(sys.bodies().pos[b].y == Approx(0.05).margin(0.002));
  CHECK(length(sys.bodies().vel[b]) < 1e-3);
}

// A cube hull (half extent h) with a margin m is its corners swept by a sphere of radius m (Shape::margin, Bullet's
// collision margin): its bottom face lies m below the corners, so it rests with its centre at h + m, and carries m g.
TEST_CASE("a cube hull with a margin rests one margin above its points", "[physics][hull]") {
  for (const real margin : {real(0), real(0.0078125), real(0.03125)}) {
    SystemConfig cfg = apgdConfig(100);
    System sys(cfg);
    const int gr = sys.addBody(ground());
    const real h = real(0.05), m = 2;
    BodyDesc b = box(Vec3{h, h, h}, m, Vec3{0, h + margin + real(0.0005), 0}, real(0.5));
    std::vector<Vec3> pts;
    for (int i = 0; i < 8; ++i) pts.push_back(Vec3{i & 1 ? h : -h, i & 2 ? h : -h, i & 4 ? h : -h});
    b.shapes[0] = makeConvexHull(pts, Pose{{0, 0, 0}, {1, 0, 0, 0}}, margin);
    CHECK(b.shapes[0].shape.size == Approx(h + margin));
    const int id = sys.addBody(b);
    sys.advance(300);
    INFO("margin " << margin << ": y " << sys.bodies().pos[size_t(id)].y);
    CHECK(sys.bodies().pos[size_t(id)].y == Approx(h + margin).margin(2e-4));
    CHECK(forceBetween(sys, gr, id).y == Approx(m * g).epsilon(0.01));
    CHECK(length(sys.bodies().vel[size_t(id)]) < 1e-3);
  }
}

TEST_CASE("a negative or non-finite hull margin, or a margin on another shape, is refused", "[physics][hull]") {
  SystemConfig cfg;
  System sys(cfg);
  std::vector<Vec3> pts;
  for (int i = 0; i < 8; ++i) pts.push_back(Vec3{real(i & 1), real(i >> 1 & 1), real(i >> 2 & 1)});
  for (const real bad : {real(-0.01), real(NAN), real(INFINITY)}) {
    BodyDesc b = box(Vec3{1, 1, 1}, 1, Vec3{0, 0, 0}, real(0.5));
    b.shapes[0] = makeConvexHull(pts, Pose{{0, 0, 0}, {1, 0, 0, 0}}, bad);
    CHECK_THROWS_WITH(sys.addBody(b), Catch::Contains("margin"));
    CHECK_THROWS_AS(sys.addBody(b), InputError);
  }
  BodyDesc s = sphere(real(0.1), 1, Vec3{0, 0, 0}, real(0.5));
  s.shapes[0].shape.margin = 0.01f;
  CHECK_THROWS_WITH(sys.addBody(s), Catch::Contains("only convex hulls"));
  BodyDesc ok = box(Vec3{1, 1, 1}, 1, Vec3{0, 0, 0}, real(0.5));
  ok.shapes[0] = makeConvexHull(pts, Pose{{0, 0, 0}, {1, 0, 0, 0}}, real(0.01));
  CHECK(sys.addBody(ok) == 0);
}

TEST_CASE("a box on a 30 degree incline slides with g(sin - mu cos) and sticks above tan 30", "[physics]") {
  // The incline is the ground plane with gravity tilted by 30 degrees about z: same mechanics.
  const real theta = real(M_PI / 6);
  for (real mu : {real(0.5), real(0.7)}) {
    SystemConfig cfg = apgdConfig(100);
    cfg.step.gravity = Vec3{g * std::sin(theta), -g * std::cos(theta), 0};
    System sys(cfg);
    sys.addBody(ground());  // friction 1: the product rule gives the box's mu
    int b = sys.addBody(box(Vec3{real(0.1), real(0.05), real(0.1)}, 1, Vec3{0, real(0.05), 0}, mu));
    sys.advance(200);  // settle the contact, then measure the acceleration over 0.5 s
    const real v0 = sys.bodies().vel[b].x;
    sys.advance(500);
    const real a = (sys.bodies().vel[b].x - v0) / real(0.5);
    if (mu < std::tan(theta)) {
      const real expected = g * (std::sin(theta) - mu * std::cos(theta));  // Coulomb sliding friction
      CHECK(a == Approx(expected).epsilon(0.02));
    } else {
      CHECK(std::fabs(sys.bodies().vel[b].x) < 1e-3);
      CHECK(std::fabs(a) < 1e-3);
    }
    CHECK(std::fabs(sys.bodies().vel[b].y) < 1e-3);
  }
}

TEST_CASE("a sphere launched sliding ends rolling at 5/7 of its speed", "[physics]") {
  // Sliding friction decelerates v and spins up w until v = w r; with I = 2/5 m r^2 that happens at
  // v = 5/7 v0 (momentum about the contact point is conserved). Rolling friction is absent.
  SystemConfig cfg;
  cfg.step.dt = real(1e-3);
  cfg.solver.max_iterations = 100;
  System sys(cfg);
  sys.addBody(ground());
  const real r = real(0.05), v0 = 2;
  BodyDesc s = sphere(r, 1, Vec3{0, r, 0}, real(0.3));
  s.vel = Vec3{v0, 0, 0};
  int b = sys.addBody(s);
  sys.advance(1500);  // sliding ends at t = 2 v0 / (7 mu g) = 0.19 s
  const Vec3 v = sys.bodies().vel[b], w = sys.bodies().omega[b];
  CHECK(v.x == Approx(5 * v0 / 7).epsilon(0.01));
  CHECK(-w.z * r == Approx(v.x).epsilon(0.01));  // rolling without slip: v = -w_z r
}

TEST_CASE("the bottom contact of a 10-box stack carries the whole weight", "[physics]") {
  SystemConfig cfg = apgdConfig(200);
  System sys(cfg);
  int gr = sys.addBody(ground());
  const real m = 1, hh = real(0.05);
  int bottom = -1, top = -1;
  for (int i = 0; i < 10; ++i) {
    int b = sys.addBody(box(Vec3{real(0.1), hh, real(0.1)}, m, Vec3{0, hh + 2 * hh * i, 0}, real(0.5)));
    if (i == 0) bottom = b;
    top = b;
  }
  sys.advance(500);
  Vec3 f = forceBetween(sys, gr, bottom);
  CHECK(f.y == Approx(10 * m * g).epsilon(0.02));
  CHECK(sys.bodies().pos[top].y == Approx(hh + 18 * hh).margin(0.01));
  CHECK(std::fabs(sys.bodies().pos[top].x) < 1e-3);
}

TEST_CASE("the final state hashes the same with 1 and 2 OpenMP threads", "[physics][determinism]") {
  auto run = [](int threads) {
    SystemConfig cfg = apgdConfig(30);
    cfg.threads = threads;
    cfg.min_bodies_per_thread = 1;  // force the threads on this small scene
    System sys(cfg);
    sys.addBody(ground());
    int i = 0;
    for (int x = 0; x < 8; ++x)
      for (int y = 0; y < 8; ++y)
        for (int z = 0; z < 8; ++z, ++i) {
          Vec3 p{real(0.025) * x + real(0.002) * (y % 2), real(0.012) + real(0.025) * y, real(0.025) * z};
          if (i % 3 == 0)
            sys.addBody(sphere(real(0.01), real(0.004), p, real(0.5)));
          else if (i % 3 == 1)
            sys.addBody(box(Vec3{real(0.009), real(0.008), real(0.01)}, real(0.004), p, real(0.5)));
          else {
            BodyDesc c = sphere(real(0.01), real(0.004), p, real(0.5));
            c.shapes[0] = makeCylinder(real(0.01), real(0.008));
            c.inertia = Vec3{real(1.5e-7), real(2e-7), real(1.5e-7)};
            sys.addBody(c);
          }
        }
    sys.advance(150);
    return sys.stateHash();
  };
  const uint64_t one = run(1), two = run(2);
  CHECK(one == two);
}

TEST_CASE("a torque-free tumbling body: energy never grows, principal spins are kept (implicit gyroscopic term)",
          "[physics]") {
  // Euler's equations conserve kinetic energy and |L| exactly; backward Euler on the gyroscopic term may
  // only dissipate (Catto, GDC 2015), while the explicit term gains energy at every step.
  auto run = [](Vec3 w0, int steps, real h, real& e0, real& e1, Vec3& w_end) {
    SystemConfig cfg;
    cfg.step.dt = h;
    cfg.step.gravity = Vec3{0, 0, 0};
    System sys(cfg);
    BodyDesc d;
    d.mass = 1;
    d.inertia = Vec3{1, 2, 3};
    d.omega = w0;
    d.pos = Vec3{0, 0, 0};
    d.shapes.push_back(makeBox(Vec3{real(0.1), real(0.2), real(0.3)}));
    sys.addBody(d);
    auto energy = [&] {
      const Vec3 wl = rotateInv(sys.bodies().rot[0], sys.bodies().omega[0]);
      return real(0.5) * (wl.x * wl.x * 1 + wl.y * wl.y * 2 + wl.z * wl.z * 3);
    };
    e0 = energy();
    real emax = e0;
    for (int i = 0; i < steps; ++i) {
      sys.step();
      emax = std::max(emax, energy());
    }
    e1 = emax;
    w_end = rotateInv(sys.bodies().rot[0], sys.bodies().omega[0]);
  };
  real e0, e1;
  Vec3 w;
  // near the unstable intermediate axis, fast: h |w| = 0.5 per step
  run(Vec3{real(0.5), real(50), real(0.5)}, 2000, real(0.01), e0, e1, w);
  CHECK(std::isfinite(e1));
  CHECK(e1 <= e0 * (1 + 1e-12));
  // a spin about a principal axis has w x I w = 0: kept exactly
  run(Vec3{0, 0, real(30)}, 500, real(0.01), e0, e1, w);
  CHECK(w.z == Approx(30).epsilon(1e-12));
  CHECK(std::fabs(w.x) + std::fabs(w.y) < 1e-12);
}

// Speculative contacts: a 1 cm sphere at 10, 30 and 100 m/s toward a fixed 2 mm wall, h = 1e-3 s, so it moves
// 1 to 10 sphere diameters per step. Without speculative contacts it ends in or beyond the wall (the check
// that the test can fail); with them it must stop on the near side (the plastic DVI impact leaves it at rest against
// the wall: its centre ends within the envelope of x = wall face - r) and never overlap the wall deeply.
TEST_CASE("speculative contacts: fast spheres do not tunnel through a thin wall", "[physics]") {
  const real r = real(0.005), t = real(0.001);  // sphere radius, wall half thickness; wall face at x = -t
  for (real speed : {real(10), real(30), real(100)}) {
    for (bool speculative : {false, true}) {
      SystemConfig cfg;
      cfg.step.gravity = Vec3{0, 0, 0};
      cfg.collision.speculative = speculative;
      System sys(cfg);
      BodyDesc wall = box(Vec3{t, real(0.05), real(0.05)}, 0, Vec3{0, 0, 0}, real(0.5));
      wall.flags = kBodyFixed;
      sys.addBody(wall);
      BodyDesc s = sphere(r, real(0.004), Vec3{real(-0.1), 0, 0}, real(0.5));
      s.vel = Vec3{speed, 0, 0};
      const int b = sys.addBody(s);
      real deepest = 0;
      for (int k = 0; k < 20; ++k) {
        sys.step();
        deepest = std::max(deepest, sys.lastStats().max_penetration);
      }
      const real x = sys.bodies().pos[size_t(b)].x;
      INFO("speed " << speed << " m/s, speculative " << speculative << ": final x " << x << ", deepest " << deepest);
      if (!speculative) {
        CHECK(x > -t - real(0.5) * r);  // tunnelled through, or stuck half-way in the wall
      } else {
        CHECK(x == Approx(double(-t - r)).margin(0.05 * r));
        CHECK(sys.bodies().vel[size_t(b)].x <= real(1e-6));
        CHECK(deepest < real(0.01) * r);
      }
    }
  }
}

// MPR gives one point per pair; flat features resting on each other need the rest of their overlap
// (mpr.h: mprManifold). Without it a stack of five cylinders standing on their caps sank 10 mm (their whole
// height) within 0.25 s, and tipped. Each stack here is offset 0.5 mm a level (stable: the offsets are far
// inside the 1 cm radius), so after 1 s it must stand at its rest height, upright, without penetration.
TEST_CASE("stacks of cylinders and hexagonal prisms standing on their flat faces hold", "[physics][manifold]") {
  for (int kind = 0; kind < 2; ++kind) {
    SystemConfig cfg;
    cfg.step.dt = real(1e-3);
    System sys(cfg);
    sys.addBody(ground());
    const real r = real(0.01), h = real(0.005);  // radius 1 cm, half height 0.5 cm
    const real m = real(2500 * kPi) * r * r * 2 * h;
    std::vector<int> ids;
    for (int i = 0; i < 5; ++i) {
      BodyDesc b;
      b.pos = Vec3{real(0.0005) * i, h + 2 * h * i * real(1.001), 0};
      b.mass = m;
      b.inertia = Vec3{m * (3 * r * r + 4 * h * h) / 12, m * r * r / 2, m * (3 * r * r + 4 * h * h) / 12};
      if (kind == 0) {
        b.shapes.push_back(makeCylinder(r, h));
      } else {
        std::vector<Vec3> pts;
        for (int k = 0; k < 6; ++k)
          for (real y : {-h, h})
            pts.push_back(Vec3{r * real(std::cos(k * kPi / 3)), y, r * real(std::sin(k * kPi / 3))});
        b.shapes.push_back(makeConvexHull(pts));
      }
      ids.push_back(sys.addBody(b));
    }
    real deepest = 0;
    for (int s = 0; s < 1000; ++s) {
      sys.step();
      deepest = std::max(deepest, sys.lastStats().max_penetration);
    }
    INFO((kind == 0 ? "cylinders" : "hexagonal prisms")
         << ": deepest penetration " << deepest << " m, top at " << sys.bodies().pos[size_t(ids.back())].y);
    CHECK(deepest < real(1e-4));  // 1% of a body's height (10 mm without the manifold)
    CHECK(std::fabs(double(sys.bodies().pos[size_t(ids.back())].y) - 9 * double(h)) < 3e-4);
    for (int id : ids) {
      const Quat q = sys.bodies().rot[size_t(id)];
      CHECK(2 * std::acos(std::min(1.0, std::fabs(double(q.w)))) < 0.05);  // tilt, rad
    }
  }
}
