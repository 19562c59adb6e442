// [gpu] tests: the GPU system against the CPU backend on the same inputs. They run on a machine with a CUDA
// device and skip with a message elsewhere (CI builds them, with or without nvcc, and runs them as skips).
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <memory>
#include <sstream>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "device_check.h"
#include "chrono_like/collision/narrowphase.h"
#include "chrono_like/system.h"
#include "gpu/gpu_factory.h"
#if defined(DVISIM_HAVE_CUDA)
#include "gpu_testing.h"
#include "rows_test_util.h"
#endif

using namespace dvi;

namespace {

constexpr bool kDouble = sizeof(real) == 8;

using dvi::testing::haveDevice;

Quat randomRotation(std::mt19937& rng) {
  std::normal_distribution<double> n(0, 1);
  Quat q{real(n(rng)), real(n(rng)), real(n(rng)), real(n(rng))};
  return normalized(q);
}

// A random convex hull: points on a jittered sphere of radius r.
std::vector<Vec3> randomHull(std::mt19937& rng, real r) {
  std::normal_distribution<double> n(0, 1);
  std::uniform_real_distribution<double> u(0.8, 1.0);
  std::vector<Vec3> pts;
  for (int i = 0; i < 12; ++i) {
    Vec3 p{real(n(rng)), real(n(rng)), real(n(rng))};
    pts.push_back(normalized(p) * real(r * u(rng)));
  }
  return pts;
}

ShapeDesc randomShape(ShapeType t, real r, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0.6, 1.0);
  auto f = [&] { return real(r * u(rng)); };
  switch (t) {
    case ShapeType::Sphere: return makeSphere(f());
    case ShapeType::Ellipsoid: return makeEllipsoid(Vec3{f(), f(), f()});
    case ShapeType::Box: return makeBox(Vec3{f() * real(0.8), f() * real(0.8), f() * real(0.8)});
    case ShapeType::Cylinder: return makeCylinder(f() * real(0.8), f() * real(0.8));
    case ShapeType::Capsule: return makeCapsule(f() * real(0.6), f() * real(0.5));
    case ShapeType::Cone: return makeCone(f() * real(0.8), f() * real(1.5));
    case ShapeType::ConvexHull: return makeConvexHull(randomHull(rng, f()));
    default: return makePlane(Vec3{0, 1, 0}, 0);
  }
}

// A lattice pile of mixed convex bodies (spheres, ellipsoids, boxes, cylinders, capsules, cones, hulls) over a
// ground plane, spaced so that neighbours start inside each other's collision envelope.
void buildPile(System& sys, int n, unsigned seed, bool mixed = true, double spacing = 1.9) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.02, 0.02);
  BodyDesc g;
  g.mass = 0;
  g.flags = kBodyFixed;
  g.friction = real(0.5);
  g.shapes.push_back(makePlane(Vec3{0, 1, 0}, 0));
  sys.addBody(g);
  const real r = real(0.01);
  const int side = std::max(1, int(std::cbrt(double(n) / 4)));  // a column about 4x as tall as it is wide
  const real d = real(spacing) * r;
  const ShapeType types[7] = {ShapeType::Sphere,  ShapeType::Ellipsoid, ShapeType::Box,       ShapeType::Cylinder,
                              ShapeType::Capsule, ShapeType::Cone,      ShapeType::ConvexHull};
  for (int i = 0; i < n; ++i) {
    const int ix = i % side, iz = (i / side) % side, iy = i / (side * side);
    BodyDesc b;
    b.pos = Vec3{real(ix * d + jitter(rng) * r), real(r + iy * d), real(iz * d + jitter(rng) * r)};
    b.rot = randomRotation(rng);
    const ShapeType t = mixed ? types[i % 7] : ShapeType::Sphere;
    b.shapes.push_back(randomShape(t, r, rng));
    const real m = real(2500) * real(4.0 / 3.0 * M_PI) * r * r * r * real(0.5);
    b.mass = m;
    const real I = real(0.4) * m * r * r;
    b.inertia = Vec3{I, I * real(1.1), I * real(0.9)};
    b.friction = real(0.5);
    b.vel = Vec3{real(jitter(rng)), real(-0.1), real(jitter(rng))};
    sys.addBody(b);
  }
}

// A CPU system and a GPU system of one configuration, each holding buildPile(n, seed, mixed, spacing).
struct CpuGpuPile {
  System cpu;
  std::unique_ptr<System> gpu;
  CpuGpuPile(const SystemConfig& cfg, int n, unsigned seed, bool mixed, double spacing)
      : cpu(cfg), gpu(makeGpuSystem(cfg)) {
    buildPile(cpu, n, seed, mixed, spacing);
    buildPile(*gpu, n, seed, mixed, spacing);
  }
  // One step of each, the GPU's state then copied to its host arrays.
  void step() {
    cpu.step();
    gpu->step();
    gpu->syncToHost();
  }
};

SystemConfig pileConfig() {
  SystemConfig c;
  c.step.dt = real(1e-3);
  c.solver.type = SolverType::APGD;
  c.solver.max_iterations = 50;
  c.solver.tolerance = 0;  // a fixed count: the backends compared iterate for iterate
  // The GPU's GJK choice on both backends (CollisionSettings::gjk: Auto resolves to All on the CPU, Polytopes on the
  // GPU): GJK and MPR agree on a pair's contact only to their tolerances, so the contacts are the same only under the
  // same choice.
  c.collision.gjk = resolvedGjk(GjkUse::Auto, true);
  // Real storage of APGD's vectors on both backends (the GPU's default is float, VectorStorage): these tests
  // compare the two backends' algorithms to rounding. Float storage has its own test below, and the 1 s
  // statistics test runs each backend's default.
  c.solver.storage = VectorStorage::Real;
  return c;
}

double relDiff(const std::vector<real>& a, const std::vector<real>& b) {
  double num = 0, den = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    num += double(a[i] - b[i]) * double(a[i] - b[i]);
    den += double(b[i]) * double(b[i]);
  }
  return den > 0 ? std::sqrt(num / den) : std::sqrt(num);
}

std::vector<real> flatten(const std::vector<Vec3>& v) {
  std::vector<real> out;
  for (const Vec3& x : v) out.insert(out.end(), {x.x, x.y, x.z});
  return out;
}

struct PileStats {
  double mean_height = 0, kinetic = 0;
};

PileStats pileStats(const System& sys) {
  const BodyArrays& b = sys.bodies();
  PileStats s;
  int cnt = 0;
  for (size_t i = 0; i < b.count(); ++i) {
    if (b.inv_mass[i] == 0) continue;
    s.mean_height += double(b.pos[i].y);
    const double m = 1.0 / double(b.inv_mass[i]);
    s.kinetic += 0.5 * m * double(length2(b.vel[i]));
    const Vec3 wl = rotateInv(b.rot[i], b.omega[i]);
    s.kinetic += 0.5 * (double(wl.x * wl.x / b.inv_inertia[i].x) + double(wl.y * wl.y / b.inv_inertia[i].y) +
                        double(wl.z * wl.z / b.inv_inertia[i].z));
    ++cnt;
  }
  if (cnt) s.mean_height /= cnt;
  return s;
}

}  // namespace

TEST_CASE("GPU availability is reported without a device or a CUDA build", "[gpu]") {
  std::string why;
  const bool ok = gpuAvailable(&why);
  CHECK(!why.empty());
  if (!ok) {
    CHECK_THROWS_AS(makeGpuSystem(SystemConfig{}), InputError);
    WARN("no CUDA device: skipping (" << why << ")");
  } else {
    auto sys = makeGpuSystem(SystemConfig{});
    CHECK(sys->backendName() == "gpu");
    INFO("device: " << sys->deviceName());
  }
}

#if defined(DVISIM_HAVE_CUDA)

TEST_CASE("GPU narrow phase equals the CPU's on random pairs of every shape combination", "[gpu]") {
  if (!haveDevice()) return;
  std::mt19937 rng(42);
  const ShapeType types[8] = {ShapeType::Sphere,  ShapeType::Ellipsoid, ShapeType::Box,        ShapeType::Cylinder,
                              ShapeType::Capsule, ShapeType::Cone,      ShapeType::ConvexHull, ShapeType::Plane};
  const int per_combo = 300;
  const real r = real(0.01);
  std::vector<Shape> A, B;
  std::vector<Pose> WA, WB;
  std::vector<Vec3> hull;
  std::vector<real> env;
  std::uniform_real_distribution<double> u(0, 1);
  std::normal_distribution<double> nd(0, 1);
  auto add = [&](ShapeDesc sd) {
    if (sd.shape.type == ShapeType::ConvexHull) {
      sd.shape.hull_start = int32_t(hull.size());
      sd.shape.hull_count = int32_t(sd.hull.size());
      hull.insert(hull.end(), sd.hull.begin(), sd.hull.end());
    }
    return sd.shape;
  };
  for (int ta = 0; ta < 8; ++ta)
    for (int tb = ta; tb < 8; ++tb) {
      if (types[ta] == ShapeType::Plane) continue;  // plane-plane never collides
      for (int k = 0; k < per_combo; ++k) {
        Shape a = add(randomShape(types[ta], r, rng));
        Shape b = add(randomShape(types[tb], r, rng));
        Pose wa{Vec3{0, 0, 0}, randomRotation(rng)};
        Pose wb;
        if (types[tb] == ShapeType::Plane) {
          // plane through a point near a's surface, random normal
          Vec3 nrm = normalized(Vec3{real(nd(rng)), real(nd(rng)), real(nd(rng))});
          b.dims = nrm;
          b.plane_d = real((u(rng) - 0.3) * r);
          wb = Pose{Vec3{0, 0, 0}, quatIdentity()};
        } else {
          Vec3 dir = normalized(Vec3{real(nd(rng)), real(nd(rng)), real(nd(rng))});
          Quat qb = randomRotation(rng);
          if (k % 4 == 3) {  // stacked along a's y axis with a's orientation: flat faces meet (mpr.h: mprManifold)
            qb = wa.q;
            dir = rotate(wa.q, Vec3{0, 1, 0});
          }
          wb = Pose{dir * real((0.8 + 1.2 * u(rng)) * r), qb};
        }
        // half the pairs in swapped order, so both argument orders are exercised
        if (k % 2 && types[tb] != ShapeType::Plane) {
          std::swap(a, b);
          std::swap(wa, wb);
        }
        A.push_back(a);
        B.push_back(b);
        WA.push_back(wa);
        WB.push_back(wb);
        env.push_back(real(0.05) * std::fmin(a.size, b.size));
      }
    }
  std::vector<int> counts;
  std::vector<ContactPoint> pts;
  gpu::collidePairsOnDevice(A, WA, B, WB, hull, env, counts, pts);
  REQUIRE(counts.size() == A.size());

  // Tolerances. Closed-form pairs (sphere with sphere/box/cylinder/capsule, capsule-capsule, box-box, anything
  // with a plane) agree to rounding: normal angle 1e-9 rad, depth and points 1e-9 x size in double (the two
  // compilers contract a*b+c into FMA differently). MPR pairs agree on the normal (1e-3 rad) and the depth
  // (1e-6 x size: MPR's tolerance is 1e-9 x size, but its normal is found to about 1e-4): the points
  // agree along the normal, but where the Minkowski difference is flat near the contact (a box face, a
  // cylinder cap) the support vertices tie and rounding picks the tie, so the reported point may slide
  // tangentially within the contact patch. That slide is reported, not failed (docs/GPU_PERFORMANCE.md,
  // narrow phase). In float every tolerance is 1e-2.
  auto closedForm = [](ShapeType a, ShapeType b) {
    if (a > b) std::swap(a, b);
    if (b == ShapeType::Plane) return true;
    if (a == ShapeType::Sphere)
      return b == ShapeType::Sphere || b == ShapeType::Box || b == ShapeType::Cylinder || b == ShapeType::Capsule;
    return (a == ShapeType::Box && b == ShapeType::Box) || (a == ShapeType::Capsule && b == ShapeType::Capsule);
  };
  int count_mismatch = 0, point_mismatch = 0, compared = 0, with_contacts = 0, slid = 0;
  double worst_closed = 0, worst_mpr_angle = 0, worst_mpr_depth = 0, worst_slide = 0;
  std::map<std::string, std::array<double, 4>> combo;  // pairs, count mismatches, point mismatches, worst slide
  for (size_t i = 0; i < A.size(); ++i) {
    ContactPoint cpu[kMaxContactsPerPair];
    const int nc = collideShapes(A[i], WA[i], B[i], WB[i], hull.data(), env[i], cpu);
    const ShapeType t0 = std::min(A[i].type, B[i].type), t1 = std::max(A[i].type, B[i].type);
    const bool closed = closedForm(t0, t1);
    auto& cs = combo[std::string(shapeTypeName(t0)) + "-" + shapeTypeName(t1)];
    cs[0] += 1;
    if (nc > 0) ++with_contacts;
    if (nc != counts[i]) {
      ++count_mismatch;
      cs[1] += 1;
      continue;
    }
    const double size = std::fmin(double(A[i].size), double(B[i].size));
    for (int k = 0; k < nc; ++k) {
      const ContactPoint* gp = nullptr;  // matched by feature index (the persistent key)
      for (int j = 0; j < nc; ++j)
        if (pts[i * kMaxContactsPerPair + j].feature == cpu[k].feature) gp = &pts[i * kMaxContactsPerPair + j];
      ++compared;
      bool bad = !gp;
      if (gp) {
        const ContactPoint& g = *gp;
        // angle between the unit normals from their chord (acos of the dot product turns a one-ulp
        // difference into ~1.5e-8 rad): 2 asin(|n_gpu - n_cpu| / 2)
        const double chord = std::fmin(2.0, double(length(g.normal - cpu[k].normal)));
        const double ang = 2 * std::asin(chord / 2);
        const double dl = std::fabs(double(g.dist - cpu[k].dist)) / size;
        const double dp = std::fmax(double(length(g.pa - cpu[k].pa)), double(length(g.pb - cpu[k].pb))) / size;
        const double dn = std::fmax(std::fabs(double(dot(g.pa - cpu[k].pa, cpu[k].normal))),
                                    std::fabs(double(dot(g.pb - cpu[k].pb, cpu[k].normal)))) /
                          size;
        if (closed) {
          worst_closed = std::fmax(worst_closed, std::fmax(ang, std::fmax(dl, dp)));
          bad = ang > (kDouble ? 1e-9 : 1e-2) || dl > (kDouble ? 1e-9 : 1e-2) || dp > (kDouble ? 1e-9 : 1e-2);
        } else {
          worst_mpr_angle = std::fmax(worst_mpr_angle, ang);
          worst_mpr_depth = std::fmax(worst_mpr_depth, dl);
          worst_slide = std::fmax(worst_slide, dp);
          cs[3] = std::fmax(cs[3], dp);
          if (dp > (kDouble ? 1e-6 : 1e-2)) ++slid;
          bad = ang > (kDouble ? 1e-3 : 1e-2) || dl > (kDouble ? 1e-6 : 1e-2) || dn > (kDouble ? 1e-3 : 1e-2);
        }
      }
      if (bad) {
        ++point_mismatch;
        cs[2] += 1;
      }
    }
  }
  std::ostringstream detail;
  for (const auto& [name, c] : combo)
    if (c[1] > 0 || c[2] > 0 || c[3] > 1e-6)
      detail << "\n  " << name << ": " << c[0] << " pairs, " << c[1] << " count / " << c[2]
             << " point mismatches, largest tangential slide " << c[3] << " x size";
  WARN("narrow phase GPU vs CPU: " << A.size() << " pairs, " << with_contacts << " touching, " << compared
                                   << " points compared; count mismatches " << count_mismatch << ", point mismatches "
                                   << point_mismatch << "; closed form worst error " << worst_closed
                                   << "; MPR worst normal angle " << worst_mpr_angle << " rad, depth "
                                   << worst_mpr_depth << " x size, " << slid << " points slid (largest " << worst_slide
                                   << " x size)" << detail.str());
  CHECK(with_contacts > int(A.size()) / 4);
  // a pair whose distance sits on the envelope boundary may flip by rounding
  CHECK(count_mismatch <= int(A.size()) / 500);
  CHECK(point_mismatch <= compared / 500);
}

namespace {
// One (then a warm-started second) step of the same pile on both backends; compares contacts, impulses and
// the new state.
void compareOneStep(bool mixed) {
  const SystemConfig cfg = pileConfig();
  CpuGpuPile pile(cfg, 10000, 7, mixed, 1.7);
  auto& [cpu, gpu] = pile;
  for (int s = 0; s < 2; ++s) {
    pile.step();
    const ContactArrays& cc = cpu.contacts();
    const ContactArrays& gc = gpu->contacts();
    INFO((mixed ? "mixed" : "spheres") << " step " << s << ": contacts CPU " << cc.count() << ", GPU " << gc.count());
    REQUIRE(cc.count() > 5000);
    REQUIRE(gc.count() == cc.count());
    REQUIRE(gc.key == cc.key);
    const double en = relDiff(flatten(gc.normal), flatten(cc.normal));
    {  // the contact whose normal differs most: what kind of pair, which point of its manifold
      size_t worst = 0;
      double wd = -1;
      for (size_t k = 0; k < cc.count(); ++k) {
        const double d = double(length(gc.normal[k] - cc.normal[k]));
        if (d > wd) wd = d, worst = k;
      }
      if (wd > 0) {
        const ShapeArrays& sh = cpu.shapes();
        WARN((mixed ? "mixed" : "spheres")
             << " step " << s << ": largest normal difference " << wd << " at contact " << worst << " ("
             << shapeTypeName(sh.shape[size_t(cc.shape_a[worst])].type) << "-"
             << shapeTypeName(sh.shape[size_t(cc.shape_b[worst])].type) << ", feature " << (cc.key[worst] & 0xFF)
             << ", dist CPU " << cc.dist[worst] << " GPU " << gc.dist[worst] << ")");
      }
    }
    const double ed = relDiff(gc.dist, cc.dist);
    const double eg = relDiff(gpu->impulses(), cpu.impulses());
    const double ev = relDiff(flatten(gpu->bodies().vel), flatten(cpu.bodies().vel));
    const double ew = relDiff(flatten(gpu->bodies().omega), flatten(cpu.bodies().omega));
    const double ep = relDiff(flatten(gpu->bodies().pos), flatten(cpu.bodies().pos));
    WARN((mixed ? "mixed" : "spheres") << " step " << s << " (" << cc.count() << " contacts, iterations CPU "
                                       << cpu.lastStats().iterations << " GPU " << gpu->lastStats().iterations
                                       << "): relative differences normals " << en << ", dist " << ed << ", impulses "
                                       << eg << ", v " << ev << ", omega " << ew << ", pos " << ep << "; residual CPU "
                                       << cpu.lastStats().residual << " GPU " << gpu->lastStats().residual);
    // Step 0 to rounding. Step 1 starts from states 5e-19 apart, and an MPR pair resting along a line (a capsule's
    // side on a cylinder's cap, kept parallel by the flat-feature manifold, mpr.h) has an ill-conditioned normal:
    // the depth does not change as it turns about the line, and the two builds' roundings put it 1.1e-4 rad
    // apart at the same depth (the random-pairs test above allows 1e-3 rad for MPR normals). The impulses then
    // differ by 3.7e-7 (H200, 4b90844): float tolerance, as this comparison allows.
    const double tol = kDouble ? (s == 0 ? 1e-9 : 1e-6) : 2e-3;
    CHECK(eg < tol);
    CHECK(ev < tol);
    CHECK(ew < tol);
    CHECK(ep < tol);
  }
}
}  // namespace

// Measured on an H100 (double): 1.3e-15 (impulses) and 1.4e-15 (velocities) after the first step, 1.1e-14
// after the warm-started second.
TEST_CASE("one step of a 10,000-sphere pile: GPU impulses and velocities equal the CPU's", "[gpu]") {
  if (!haveDevice()) return;
  compareOneStep(false);
}

// Mixed shapes go through MPR, whose support ties and branch tests resolve by rounding: the device is built
// without FMA contraction (DVISIM_CUDA_FMAD=OFF) so it rounds as the host does; with FMA the MPR point could
// slide within a flat patch and the impulses differed by 1.3e-5 (measured on an H100).
TEST_CASE("one step of a 10,000-body mixed pile: GPU impulses and velocities equal the CPU's", "[gpu]") {
  if (!haveDevice()) return;
  compareOneStep(true);
}

// Friction rows only where mu > 0 (docs/MODEL.md §6): a frictionless pile solves the normal rows only, packed three
// per block (jacobian.h), on both backends through the same functors; every solver the GPU has.
TEST_CASE("frictionless 10,000-sphere pile: the GPU's normal-only CCP equals the CPU's", "[gpu][pruning]") {
  if (!haveDevice()) return;
  for (SolverType t : {SolverType::APGD, SolverType::Jacobi, SolverType::BB}) {
    SystemConfig cfg = pileConfig();
    cfg.solver.type = t;
    CpuGpuPile pile(cfg, 10000, 7, false, 1.7);
    auto& [cpu, gpu] = pile;
    for (System* s : {&cpu, gpu.get()}) {
      for (real& f : s->mutableBodies().friction) f = 0;
      s->markHostDirty();
    }
    for (int step = 0; step < 3; ++step) {
      pile.step();
      INFO(solverName(t) << " step " << step << ": contacts CPU " << cpu.contacts().count() << ", GPU "
                         << gpu->contacts().count());
      REQUIRE(cpu.contacts().count() > 5000);
      REQUIRE(gpu->contacts().key == cpu.contacts().key);
      CHECK(cpu.lastStats().normal_only);
      CHECK(gpu->lastStats().normal_only);
      CHECK_FALSE(gpu->lastStats().part_ran[int(StagePart::FrictionRows)]);
      const double eg = relDiff(gpu->impulses(), cpu.impulses());
      const double ev = relDiff(flatten(gpu->bodies().vel), flatten(cpu.bodies().vel));
      // Frictionless normals pass through the sphere centres: omega stays at rounding level (~1e-17), so it is
      // compared as a surface speed |omega| r against the velocities' scale, not relative to itself.
      double dw = 0, vmax = 0;
      for (size_t i = 0; i < cpu.bodies().count(); ++i) {
        dw = std::max(dw, double(length(gpu->bodies().omega[i] - cpu.bodies().omega[i])) * 0.01);
        vmax = std::max(vmax, double(length(cpu.bodies().vel[i])));
      }
      const double ew = dw / vmax;
      WARN("frictionless " << solverName(t) << " step " << step << ": relative differences impulses " << eg << ", v "
                           << ev << ", omega " << ew << "; iterations CPU " << cpu.lastStats().iterations << " GPU "
                           << gpu->lastStats().iterations);
      double tang = 0;
      for (size_t k = 0; k < gpu->contacts().count(); ++k)
        tang = std::max(
            {tang, std::fabs(double(gpu->impulses()[3 * k + 1])), std::fabs(double(gpu->impulses()[3 * k + 2]))});
      CHECK(tang == 0);
      const double tol = kDouble ? 1e-9 : 2e-3;
      CHECK(eg < tol);
      CHECK(ev < tol);
      CHECK(ew < tol);
    }
  }
}

// Each backend with its default storage of APGD's vectors: float on the GPU, real on the CPU.
TEST_CASE("one second of a 10,000-body mixed pile: GPU and CPU statistics agree within 2%", "[gpu]") {
  if (!haveDevice()) return;
  SystemConfig cfg = pileConfig();
  cfg.solver.storage = VectorStorage::Auto;
  const int n = 10000;  // the one-step test's pile; 2,000 bodies (one realisation of a chaotic flow) differed by 2.1%
  CpuGpuPile pile(cfg, n, 7, true, 1.7);
  auto& [cpu, gpu] = pile;
  // Under compute-sanitizer (scripts/device/run_device.sh sanitize sets DVISIM_SANITIZER_RUN=1) the kernels run
  // 10-1000x slower (racecheck): the run is cut to 30 steps, which execute every kernel of the step, and the
  // statistics, which need the whole second, are not judged (the sanitizer's report is that run's verdict).
  const bool sanitizer_run = std::getenv("DVISIM_SANITIZER_RUN") != nullptr;
  const int steps = sanitizer_run ? 30 : int(std::lround(1.0 / double(cfg.step.dt)));
  // The flow is chaotic (rounding differences grow until single trajectories differ), so the statistics are
  // time averages: kinetic energy over the whole second, mean height over its second half (sampled every 10
  // steps); an instantaneous height of the still-flowing pile differed by 2.1% on an H200.
  double ke_cpu = 0, ke_gpu = 0, h_cpu = 0, h_gpu = 0, z_cpu = 0, z_gpu = 0;  // z: contacts per body (packing)
  int nh = 0;
  for (int s = 0; s < steps; ++s) {
    cpu.step();
    gpu->step();
    if (s % 10 == 9) {
      gpu->syncToHost();
      const PileStats a = pileStats(cpu), b = pileStats(*gpu);
      ke_cpu += a.kinetic;
      ke_gpu += b.kinetic;
      if (2 * s >= steps) {
        h_cpu += a.mean_height;
        h_gpu += b.mean_height;
        z_cpu += double(cpu.contacts().count()) / n;
        z_gpu += double(gpu->lastStats().contacts) / n;
        ++nh;
      }
    }
  }
  gpu->syncToHost();
  const PileStats a = pileStats(cpu), b = pileStats(*gpu);
  WARN("1 s of " << n << " bodies: mean height over the last 0.5 s CPU " << h_cpu / nh << " GPU " << h_gpu / nh
                 << "; mean kinetic energy CPU " << ke_cpu * 10 / steps << " GPU " << ke_gpu * 10 / steps
                 << "; final height CPU " << a.mean_height << " GPU " << b.mean_height << ", final KE CPU " << a.kinetic
                 << " GPU " << b.kinetic << "; contacts per body CPU " << z_cpu / nh << " GPU " << z_gpu / nh);
  if (sanitizer_run) {
    WARN("DVISIM_SANITIZER_RUN: 30 steps under the sanitizer, statistics not judged");
    return;
  }
  REQUIRE(nh > 10);
  CHECK(z_gpu == Approx(z_cpu).epsilon(0.02));
  CHECK(h_gpu == Approx(h_cpu).epsilon(0.02));
  CHECK(ke_gpu == Approx(ke_cpu).epsilon(0.02));
}

TEST_CASE("GPU system runs every solver and keeps bodies added between steps", "[gpu]") {
  if (!haveDevice()) return;
  for (SolverType t : {SolverType::Jacobi, SolverType::APGD, SolverType::BB}) {
    SystemConfig cfg = pileConfig();
    cfg.solver.type = t;
    CpuGpuPile pile(cfg, 500, 3, false, 1.8);  // spheres: closed-form narrow phase, so this compares the solvers
    auto& [cpu, gpu] = pile;
    for (int s = 0; s < 5; ++s) {
      cpu.step();
      gpu->step();
    }
    gpu->syncToHost();
    const double ev = relDiff(flatten(gpu->bodies().vel), flatten(cpu.bodies().vel));
    INFO("solver " << solverName(t) << ": velocity difference after 5 steps " << ev);
    CHECK(ev < (kDouble ? 1e-6 : 1e-2));
    // an emitter adds a body mid-run: the device state of the others must survive the upload
    BodyDesc extra;
    extra.pos = Vec3{0, 1, 0};
    extra.mass = 1;
    extra.shapes.push_back(makeSphere(real(0.01)));
    cpu.addBody(extra);
    gpu->addBody(extra);
    pile.step();
    const double ep = relDiff(flatten(gpu->bodies().pos), flatten(cpu.bodies().pos));
    CHECK(ep < (kDouble ? 1e-6 : 1e-3));
  }
}

// APGD's scalar decisions (backtracking, restart, best iterate, stop) run on the device in ApgdControl, the
// struct the CPU loop calls on the host (solver_algorithms.h). With a tolerance the device loop stops in
// batches of trials: the iteration count of every step must equal the CPU's. The four ways of launching the
// trials must give bitwise the same state: all trials in one cooperative kernel with each thread's blocks kept in
// registers (the default at this size), the same kernel reading them from memory every trial, each trial as one
// CUDA graph, and each trial's kernels one by one.
TEST_CASE("GPU APGD on the device: tolerance stops equal the CPU's, persistent, graph and kernel launches agree",
          "[gpu]") {
  if (!haveDevice()) return;
  SystemConfig cfg = pileConfig();
  cfg.solver.max_iterations = 100;
  cfg.solver.tolerance = 0;
  real r100 = 0;
  {
    System probe(cfg);
    buildPile(probe, 2000, 5, false, 1.7);
    probe.step();
    r100 = probe.lastStats().relative_residual;
  }
  REQUIRE(r100 > 0);
  cfg.solver.tolerance = 3 * r100;  // relative; reached before iteration 100 in the first step
  SystemConfig persistent_cfg = cfg;
  persistent_cfg.gpu.persistent_max_blocks = int64_t(1) << 40;
  System cpu(cfg);
  auto persistent = makeGpuSystem(persistent_cfg);
  SystemConfig uncached_cfg = persistent_cfg;
  uncached_cfg.gpu.apgd_register_cache = false;
  auto uncached = makeGpuSystem(uncached_cfg);
  SystemConfig graphs_cfg = cfg;
  graphs_cfg.gpu.persistent_max_blocks = 0;
  auto graphs = makeGpuSystem(graphs_cfg);
  SystemConfig plain_cfg = graphs_cfg;
  plain_cfg.gpu.graphs = false;
  auto plain = makeGpuSystem(plain_cfg);
  const std::vector<System*> all{&cpu, persistent.get(), uncached.get(), graphs.get(), plain.get()};
  for (System* sys : all) buildPile(*sys, 2000, 5, false, 1.7);
  for (int s = 0; s < 5; ++s) {
    for (System* sys : all) sys->step();
    INFO("step " << s << ": iterations CPU " << cpu.lastStats().iterations << ", GPU persistent "
                 << persistent->lastStats().iterations << ", GPU graphs " << graphs->lastStats().iterations
                 << ", GPU kernels " << plain->lastStats().iterations << " (tolerance " << cfg.solver.tolerance << ")");
    if (s == 0) CHECK(cpu.lastStats().iterations < 100);
    CHECK(persistent->lastStats().iterations == cpu.lastStats().iterations);
    CHECK(uncached->lastStats().iterations == cpu.lastStats().iterations);
    CHECK(graphs->lastStats().iterations == cpu.lastStats().iterations);
    CHECK(plain->lastStats().iterations == cpu.lastStats().iterations);
  }
  for (System* sys : all) sys->syncToHost();
  CHECK(relDiff(flatten(graphs->bodies().vel), flatten(plain->bodies().vel)) == 0);
  CHECK(relDiff(flatten(graphs->bodies().pos), flatten(plain->bodies().pos)) == 0);
  CHECK(relDiff(flatten(persistent->bodies().vel), flatten(plain->bodies().vel)) == 0);
  CHECK(relDiff(flatten(persistent->bodies().pos), flatten(plain->bodies().pos)) == 0);
  CHECK(relDiff(flatten(uncached->bodies().vel), flatten(plain->bodies().vel)) == 0);
  CHECK(relDiff(flatten(uncached->bodies().pos), flatten(plain->bodies().pos)) == 0);
  const double ev = relDiff(flatten(graphs->bodies().vel), flatten(cpu.bodies().vel));
  INFO("velocity difference GPU vs CPU after 5 steps " << ev);
  CHECK(ev < (kDouble ? 1e-9 : 1e-2));
}

// Float storage (VectorStorage::Float, the GPU's default): the APGD trials keep the gradient N g + r in float
// and read float Jacobians; the CPU rounds the same values in real. The two are not bitwise alike: their
// reductions sum in different orders, so the start's scale and Lipschitz bound differ in the last bit, and where a
// gradient lies next to a float rounding boundary the two round it to neighbouring floats. The first step (the
// same contacts, no warm start) then agrees to float rounding (H100, b57a6b7: v 2.4e-8, impulses 4.1e-6). The
// warm-started steps after it amplify any such difference: on the CPU alone, a 4e-16 relative change of h grows
// to 3e-8 in v after one warm-started step and 9e-7 after two (f78d305; 1.2e-7 and 1.7e-6 at b57a6b7), and the
// GPU run from its 2.4e-8 reached 2.5e-6 and 1.3e-3. So the first step is held to float tolerance and the next two
// to 1e-2 in v: returning a stale iterate (the warm start, as the first float version did) differs by 1e-1.
TEST_CASE("GPU float storage: the 10,000-body mixed pile follows the CPU's float storage", "[gpu]") {
  if (!haveDevice()) return;
  SystemConfig cfg = pileConfig();
  cfg.solver.storage = VectorStorage::Float;
  cfg.solver.max_iterations = 200;
  System cpu(cfg);
  auto gpu = makeGpuSystem(cfg);
  SystemConfig plain_cfg = cfg;  // trial by trial, kernel by kernel (the default here: one persistent kernel)
  plain_cfg.gpu.graphs = false;
  plain_cfg.gpu.persistent_max_blocks = 0;
  auto plain = makeGpuSystem(plain_cfg);
  SystemConfig contact_gather_cfg = cfg;  // the gather reading each contact's record and full inverse masses
  contact_gather_cfg.gpu.entry_gather = false;
  auto contact_gather = makeGpuSystem(contact_gather_cfg);
  for (System* sys : {&cpu, gpu.get(), plain.get(), contact_gather.get()}) buildPile(*sys, 10000, 7, true, 1.7);
  for (int s = 0; s < 3; ++s) {
    for (System* sys : {&cpu, gpu.get(), plain.get(), contact_gather.get()}) sys->step();
    gpu->syncToHost();
    plain->syncToHost();
    contact_gather->syncToHost();
    REQUIRE(gpu->contacts().count() == cpu.contacts().count());
    const double ev = relDiff(flatten(gpu->bodies().vel), flatten(cpu.bodies().vel));
    const double ew = relDiff(flatten(gpu->bodies().omega), flatten(cpu.bodies().omega));
    const double eg = relDiff(gpu->impulses(), cpu.impulses());
    WARN("float storage, step " << s << " (" << cpu.contacts().count() << " contacts, iterations CPU "
                                << cpu.lastStats().iterations << " GPU " << gpu->lastStats().iterations
                                << "): relative differences v " << ev << ", omega " << ew << ", impulses " << eg
                                << "; residual CPU " << cpu.lastStats().residual << " GPU " << gpu->lastStats().residual
                                << "; deepest penetration CPU " << cpu.lastStats().max_penetration << " GPU "
                                << gpu->lastStats().max_penetration);
    if (s == 0) {
      CHECK(ev < 1e-6);
      CHECK(ew < 1e-5);
      CHECK(eg < 1e-4);
    } else {
      CHECK(ev < 1e-2);
    }
    // one persistent kernel or kernel by kernel: the same float rounding, bitwise
    CHECK(relDiff(flatten(plain->bodies().vel), flatten(gpu->bodies().vel)) == 0);
    // the gather's entry records and isotropic inverse masses (gpu_entry_gather) add the same values in the same
    // order as the contact records: bitwise
    CHECK(relDiff(flatten(contact_gather->bodies().vel), flatten(gpu->bodies().vel)) == 0);
    CHECK(relDiff(flatten(contact_gather->bodies().omega), flatten(gpu->bodies().omega)) == 0);
  }
}

// SolverSettings::apgd_speculation on the device: the test pass writes the next trial's step for either outcome
// (in the register-cached persistent kernel, the plain one, and the trial-by-trial kernels), and a trial whose step
// was speculated leaves out its step pass and, in the persistent kernel, a grid-wide barrier. The oracle is the
// same path without speculation: bitwise the same trajectory, the same trials, and the steps left out exactly as
// counted (every rejected trial with Both, never with None; Auto is Accepted).
TEST_CASE("GPU APGD's speculated steps give bitwise the trajectory without speculation", "[gpu]") {
  if (!haveDevice()) return;
  const ApgdSpeculation kinds[4] = {ApgdSpeculation::None, ApgdSpeculation::Accepted, ApgdSpeculation::Both,
                                    ApgdSpeculation::Auto};
  // Under compute-sanitizer (DVISIM_SANITIZER_RUN, see the 1 s statistics test) racecheck ran past 120 s on the 24
  // systems: there the float storage only (every kernel of the three paths runs in it).
  const bool sanitizer_run = std::getenv("DVISIM_SANITIZER_RUN") != nullptr;
  for (const VectorStorage storage : {VectorStorage::Float, VectorStorage::Real}) {
    if (sanitizer_run && storage == VectorStorage::Real) break;
    for (int path = 0; path < 3; ++path) {  // register-cached persistent kernel, plain persistent, trial by trial
      SystemConfig cfg = pileConfig();
      cfg.solver.storage = storage;
      cfg.gpu.persistent_max_blocks = path < 2 ? int64_t(1) << 40 : 0;
      cfg.gpu.apgd_register_cache = path == 0;
      std::vector<std::unique_ptr<System>> sys;
      for (const ApgdSpeculation k : kinds) {
        SystemConfig c = cfg;
        c.solver.apgd_speculation = k;
        sys.push_back(makeGpuSystem(c));
        buildPile(*sys.back(), 3000, 11, true, 1.7);
      }
      int rejected = 0;
      for (int step = 0; step < 4; ++step) {
        for (auto& x : sys) x->step();
        const StepStats& none = sys[0]->lastStats();
        const int rej = none.trials - none.iterations;
        rejected += rej;
        INFO("storage " << (storage == VectorStorage::Real ? "real" : "float") << ", path " << path << ", step " << step
                        << ": trials " << none.trials << ", iterations " << none.iterations
                        << ", speculated (accepted, both, auto) " << sys[1]->lastStats().speculated << ", "
                        << sys[2]->lastStats().speculated << ", " << sys[3]->lastStats().speculated);
        CHECK(none.speculated == 0);
        CHECK(sys[1]->lastStats().speculated > none.iterations / 2);
        CHECK(sys[2]->lastStats().speculated == sys[1]->lastStats().speculated + rej);
        CHECK(sys[3]->lastStats().speculated == sys[1]->lastStats().speculated);  // Auto: the accepted outcome
        for (int m = 1; m < 4; ++m) {
          CHECK(sys[m]->lastStats().trials == none.trials);
          CHECK(sys[m]->lastStats().iterations == none.iterations);
        }
      }
      CHECK(rejected > 0);  // the rejected outcome was exercised
      for (auto& x : sys) x->syncToHost();
      for (int m = 1; m < 4; ++m) {
        CHECK(relDiff(flatten(sys[m]->bodies().vel), flatten(sys[0]->bodies().vel)) == 0);
        CHECK(relDiff(flatten(sys[m]->bodies().omega), flatten(sys[0]->bodies().omega)) == 0);
        CHECK(relDiff(flatten(sys[m]->bodies().pos), flatten(sys[0]->bodies().pos)) == 0);
      }
    }
  }
}

TEST_CASE("constraint rows on the GPU: a pendulum chain on a pile equals the CPU run", "[gpu]") {
  if (!haveDevice()) return;
  for (SolverType t : {SolverType::Jacobi, SolverType::APGD, SolverType::BB}) {
    SystemConfig cfg = pileConfig();
    cfg.solver.type = t;
    System cpu(cfg);
    auto gpu = makeGpuSystem(cfg);
    for (System* sys : {&cpu, gpu.get()}) {
      buildPile(*sys, 300, 5, false, 1.8);
      // three pendulum bobs hanging from ball joints above the pile, one swinging into it
      for (int i = 0; i < 3; ++i) {
        BodyDesc bob = rowstest::freeBox(Vec3{real(0.05) * i, real(0.3), 0}, real(0.05));
        bob.vel = Vec3{real(0.3), 0, 0};
        const int b = sys->addBody(bob);
        sys->addRowProvider(std::make_shared<rowstest::BallJointToGround>(b, Vec3{0, real(0.1), 0},
                                                                          Vec3{real(0.05) * i, real(0.4), 0}));
      }
    }
    // BB takes discrete decisions on computed values (the nonmonotone line search's acceptance test, the
    // best iterate), so a last-bit difference between the two reductions' orders can pick another step or
    // iterate, which the pendulums' impacts then amplify (H100: 1.7% after 20 steps; H200: 5% after 5 steps,
    // while Jacobi and APGD agree to 1e-15): BB is compared after its first step.
    const int steps = t == SolverType::BB ? 1 : 20;
    for (int s = 0; s < steps; ++s) {
      cpu.step();
      gpu->step();
    }
    gpu->syncToHost();
    const double ev = relDiff(flatten(gpu->bodies().vel), flatten(cpu.bodies().vel));
    const double eg = relDiff(gpu->rowImpulses(), cpu.rowImpulses());
    INFO("solver " << solverName(t) << ": velocity difference " << ev << ", row impulse difference " << eg);
    REQUIRE(cpu.rowImpulses().size() == 9);
    CHECK(ev < (kDouble ? 1e-6 : 1e-2));
    CHECK(eg < (kDouble ? 1e-6 : 1e-2));
  }
}

namespace {
// Particles in a box for the broad phase: n shapes with largest sides from side to side x spread (a log-uniform
// spread), a ground box, four high walls and a plane, plus `extra_large` boxes 30 x side wide at random places.
struct BroadScene {
  ShapeArrays shapes;
  BodyArrays bodies;
  void add(ShapeType t, Aabb box, uint8_t flags) {
    Shape s{};
    s.type = t;
    s.body = int32_t(bodies.flags.size());
    s.local = Pose{{0, 0, 0}, quatIdentity()};
    s.dims = {1, 1, 1};
    s.size = 1;
    s.group = 1;
    s.mask = -1;
    shapes.shape.push_back(s);
    shapes.aabb.push_back(box);
    bodies.flags.push_back(flags);
  }
};
BroadScene broadScene(uint32_t seed, int n, double spread, int extra_large) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> U(0, 1);
  BroadScene sc;
  const real side = real(0.02), L = real(0.02 * std::cbrt(double(n)) * 1.6);
  const real big = real(1e30);
  sc.add(ShapeType::Plane, Aabb{{-big, -big, -big}, {big, big, big}}, kBodyFixed);
  const real H = 4 * L;  // walls 4 x the box's side high: well above large_factor x the particles' bin edge
  sc.add(ShapeType::Box, Aabb{{-L, -L, -side}, {2 * L, 2 * L, 0}}, kBodyFixed);  // the ground, 3 x the box wide
  sc.add(ShapeType::Box, Aabb{{-side, -side, 0}, {0, L + side, H}}, kBodyFixed);
  sc.add(ShapeType::Box, Aabb{{L, -side, 0}, {L + side, L + side, H}}, kBodyFixed);
  sc.add(ShapeType::Box, Aabb{{-side, -side, 0}, {L + side, 0, H}}, kBodyFixed);
  sc.add(ShapeType::Box, Aabb{{-side, L, 0}, {L + side, L + side, H}}, kBodyFixed);
  for (int i = 0; i < n; ++i) {
    const real h = real(0.5 * side * std::pow(spread, U(rng)));
    const Vec3 c{real(U(rng) * L), real(U(rng) * L), real(U(rng) * L)};
    sc.add(ShapeType::Sphere, Aabb{c - Vec3{h, h, h}, c + Vec3{h, h, h}}, 0);
  }
  for (int i = 0; i < extra_large; ++i) {
    const real h = 15 * side;
    const Vec3 c{real(U(rng) * L), real(U(rng) * L), real(U(rng) * L)};
    sc.add(ShapeType::Box, Aabb{c - Vec3{h, h, side}, c + Vec3{h, h, side}}, kBodyFixed);
  }
  return sc;
}
}  // namespace

// The GPU broad phase finds the bin edge from a split of the extents (gpu_collision.cu: edgeFromSplit) where
// that decides it, else from the sorted extents as the CPU does; both must give the CPU's pairs and its bin edge
// (to the rounding of a differently ordered sum), on the first run (which guesses the split) and the second
// (which starts from the path the first found).
TEST_CASE("GPU broad phase: pairs and bin edge equal the CPU's with and without the extents' sort", "[gpu]") {
  if (!haveDevice()) return;
  struct Case {
    const char* name;
    double spread;
    int extra_large;
    bool sorted;
  };
  const Case cases[] = {{"equal spheres in a box (split)", 1.0, 0, false},
                        {"sizes over a factor 4 in a box (split)", 4.0, 0, false},
                        {"sizes over a factor 40 (sorted)", 40.0, 0, true},
                        {"100 large boxes, more than max_large (sorted, the edge grows)", 1.0, 100, true},
                        {"40 large boxes (split)", 1.0, 40, false}};
  for (const Case& c : cases)
    for (int steps : {1, 2}) {
      const BroadScene sc = broadScene(7, 3000, c.spread, c.extra_large);
      BroadPhaseSettings settings;
      BroadPhaseBins cpu(settings);
      std::vector<ShapePair> want, got;
      BroadPhaseStats cs, gs;
      cpu.run(sc.shapes, sc.bodies, want, &cs);
      bool sorted = false;
      gpu::broadPhaseOnDevice(sc.shapes, sc.bodies, settings, steps, got, gs, sorted);
      INFO(c.name << ", " << steps << " run(s): pairs CPU " << want.size() << " GPU " << got.size() << "; bin edge CPU "
                  << cs.bin_edge << " GPU " << gs.bin_edge << "; large CPU " << cs.large_shapes << " GPU "
                  << gs.large_shapes);
      REQUIRE(want.size() > 100);
      REQUIRE(got.size() == want.size());
      bool same = true;
      for (size_t i = 0; i < want.size(); ++i) same = same && want[i].a == got[i].a && want[i].b == got[i].b;
      CHECK(same);
      CHECK(sorted == c.sorted);
      CHECK(gs.large_shapes == cs.large_shapes);
      CHECK(std::fabs(double(gs.bin_edge) - double(cs.bin_edge)) <= (kDouble ? 1e-9 : 1e-4) * double(cs.bin_edge));
    }
}

#endif  // DVISIM_HAVE_CUDA

// A body with 512 or more adjacency entries is gathered by 32 blocks (gpu/solver/gpu_schur.cu: HeavyGatherKernel, a ticketed
// fixed-order sum of the blocks' partials) instead of one thread. A free plate under 2,025 spheres has ~2,000
// contacts: its velocity change in every Schur product comes from that kernel, and must equal the CPU's
// sequential sum to rounding.
TEST_CASE("a plate under 2,025 spheres: the GPU's heavy-body gather equals the CPU's", "[gpu]") {
  if (!haveDevice()) return;
  const SystemConfig cfg = pileConfig();
  System cpu(cfg);
  auto gpu = makeGpuSystem(cfg);  // the persistent APGD kernel (~4,000 contacts): heavy chunks inside it
  SystemConfig trials_cfg = cfg;  // trial by trial: HeavyGatherKernel
  trials_cfg.gpu.persistent_max_blocks = 0;
  auto trials = makeGpuSystem(trials_cfg);
  const real r = real(0.01);
  for (System* sys : {&cpu, gpu.get(), trials.get()}) {
    BodyDesc g;
    g.mass = 0;
    g.flags = kBodyFixed;
    g.friction = real(0.5);
    g.shapes.push_back(makePlane(Vec3{0, 1, 0}, 0));
    sys->addBody(g);
    BodyDesc plate;  // 1 m x 2 cm x 1 m, 50 kg, resting on the ground
    plate.pos = Vec3{0, r, 0};
    plate.shapes.push_back(makeBox(Vec3{real(0.5), r, real(0.5)}));
    plate.mass = real(50);
    plate.inertia = Vec3{real(50.0 / 12 * (1 + 0.0004)), real(50.0 / 12 * 2), real(50.0 / 12 * (1 + 0.0004))};
    plate.friction = real(0.5);
    sys->addBody(plate);
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> jitter(-0.1, 0.1);
    for (int i = 0; i < 45; ++i)
      for (int k = 0; k < 45; ++k) {
        BodyDesc b;
        // 2.2 r apart, each sinking up to 5% of r into the plate's top face
        b.pos = Vec3{real((i - 22) * 2.2 * 0.01), real(2 * r + r * (0.95 + 0.05 * jitter(rng))),
                     real((k - 22) * 2.2 * 0.01)};
        b.shapes.push_back(makeSphere(r));
        b.mass = real(2500 * 4.0 / 3.0 * M_PI * 1e-6);
        const real I = real(0.4) * b.mass * r * r;
        b.inertia = Vec3{I, I, I};
        b.friction = real(0.5);
        b.vel = Vec3{real(jitter(rng)), real(-0.2), real(jitter(rng))};
        sys->addBody(b);
      }
  }
  for (int s = 0; s < 2; ++s) {
    cpu.step();
    gpu->step();
    trials->step();
    gpu->syncToHost();
    trials->syncToHost();
    CHECK(relDiff(flatten(trials->bodies().vel), flatten(gpu->bodies().vel)) == 0);  // bitwise, both heavy paths
    const ContactArrays& cc = cpu.contacts();
    int on_plate = 0;
    for (size_t k = 0; k < cc.count(); ++k) on_plate += (cc.body_a[k] == 1 || cc.body_b[k] == 1) ? 1 : 0;
    REQUIRE(on_plate >= 2000);  // heavy: 512 adjacency entries or more
    REQUIRE(gpu->contacts().count() == cc.count());
    const double eg = relDiff(gpu->impulses(), cpu.impulses());
    const double ev = relDiff(flatten(gpu->bodies().vel), flatten(cpu.bodies().vel));
    const double ew = relDiff(flatten(gpu->bodies().omega), flatten(cpu.bodies().omega));
    const Vec3 dvp = gpu->bodies().vel[1] - cpu.bodies().vel[1];
    WARN("plate step " << s << ": " << on_plate << " contacts on the plate; relative differences impulses " << eg
                       << ", v " << ev << ", omega " << ew << "; plate velocity CPU (" << cpu.bodies().vel[1].x << ", "
                       << cpu.bodies().vel[1].y << ", " << cpu.bodies().vel[1].z << "), GPU differs by "
                       << length(dvp));
    const double tol = kDouble ? 1e-9 : 2e-3;
    CHECK(eg < tol);
    CHECK(ev < tol);
    CHECK(ew < tol);
    CHECK(double(length(dvp)) <= tol * (1e-3 + double(length(cpu.bodies().vel[1]))));
  }
}
