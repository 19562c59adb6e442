// The domain decomposition over MPI (chrono_like/mpi/distributed_system.h), run under `mpirun -np 2` (CTest label
// mpi). Each test steps the same scene with a DistributedSystem and, on every process, with one plain System (the
// one-process reference), and compares: every body's trajectory, the contact count (the sum over the processes of
// the contacts each owns), the impulse of a contact across the split, and the bodies' moves between processes.
//
// Tolerances: the two runs differ only in the order in which the solver's sums and the shared bodies' velocity
// changes are added (solver/process_group.h), a relative rounding of ~1e-16 per addition. Where the solve stops
// at a tolerance (the default), that rounding can move a stop or backtracking test by an iteration, and the bodies
// then differ by what the unfinished iterations leave (measured: 5e-11 m over 200 steps of the pile, 4e-8 m for
// rolling rows whose contacts are statically indeterminate); with a fixed iteration count they differ by rounding
// only (6e-15 m). The pile is held to 1e-6 of the sphere radius (5e-8 m), the fixed-count run to 1e-9 m. What the
// tests are there to catch is far above both: without the exchange of the shared bodies' velocity changes the pile
// ends 3 m apart, without the warm start 4e-4 m, and with warm-start impulses left behind when their body changes
// process the rolling rows 4e-7 m.
#define CATCH_CONFIG_RUNNER
#include <catch2/catch.hpp>
#include <mpi.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <vector>

#include "chrono_like/mpi/distributed_system.h"
#include "chrono_like/system.h"
#include "gpu/gpu_factory.h"

using namespace dvi;

namespace {

int worldRank() {
  int r = 0;
  MPI_Comm_rank(MPI_COMM_WORLD, &r);
  return r;
}
int worldSize() {
  int s = 1;
  MPI_Comm_size(MPI_COMM_WORLD, &s);
  return s;
}
int64_t sumOverRanks(int64_t v) {
  int64_t out = 0;
  MPI_Allreduce(&v, &out, 1, MPI_INT64_T, MPI_SUM, MPI_COMM_WORLD);
  return out;
}

constexpr real kRadius = real(0.05);

BodyDesc ground() {
  BodyDesc g;
  g.flags = kBodyFixed;
  g.mass = 0;
  g.shapes.push_back(makePlane(Vec3{0, 1, 0}, 0));
  return g;
}

BodyDesc sphere(Vec3 pos, Vec3 vel) {
  BodyDesc b;
  b.pos = pos;
  b.vel = vel;
  b.mass = real(1);
  const real i = real(0.4) * kRadius * kRadius;
  b.inertia = Vec3{i, i, i};
  b.friction = real(0.5);
  b.shapes.push_back(makeSphere(kRadius));
  return b;
}

// A pile: nx x ny x nz spheres on a jittered lattice just above the ground, spacing 2.05 radii, falling.
std::vector<BodyDesc> pile(int nx, int ny, int nz) {
  std::vector<BodyDesc> scene{ground()};
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> jitter(-0.004, 0.004);
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i)
      for (int k = 0; k < nz; ++k) {
        const Vec3 p{real(i * 0.1025 + jitter(rng)), real(kRadius * 1.02 + j * 0.1025), real(k * 0.1025 + jitter(rng))};
        scene.push_back(sphere(p, Vec3{real(jitter(rng) * 50), 0, real(jitter(rng) * 50)}));
      }
  return scene;
}

// fixed_iterations > 0: that many APGD iterations a step (tolerance 0), so the warm start carries over more.
SystemConfig config(int fixed_iterations = 0) {
  SystemConfig c;
  c.step.dt = 2e-3;
  c.threads = 1;
  if (fixed_iterations > 0) {
    c.solver.max_iterations = fixed_iterations;
    c.solver.min_iterations = 0;
    c.solver.tolerance = 0;
  }
  return c;
}

std::vector<MotionState> oneRankState(const System& s) {
  std::vector<MotionState> out(s.bodies().count());
  for (size_t i = 0; i < out.size(); ++i)
    out[i] = MotionState{s.bodies().pos[i], s.bodies().rot[i], s.bodies().vel[i], s.bodies().omega[i]};
  return out;
}

real maxPositionDifference(const std::vector<MotionState>& a, const std::vector<MotionState>& b) {
  real d = 0;
  for (size_t i = 0; i < a.size(); ++i) d = std::max(d, length(a[i].pos - b[i].pos));
  return d;
}

// Statistics of a state, from the state alone (the same function for both runs).
struct PileStats {
  double mean_height = 0, kinetic = 0;
};
PileStats statsOf(const std::vector<MotionState>& s, const std::vector<BodyDesc>& scene) {
  PileStats p;
  int n = 0;
  for (size_t i = 0; i < s.size(); ++i) {
    if (scene[i].flags & kBodyFixed) continue;
    p.mean_height += double(s[i].pos.y);
    p.kinetic += 0.5 * double(scene[i].mass) * double(dot(s[i].vel, s[i].vel));
    ++n;
  }
  p.mean_height /= n;
  return p;
}

struct Runs {
  std::vector<BodyDesc> scene;
  System one;
  DistributedSystem many;
  explicit Runs(std::vector<BodyDesc> bodies, DecompositionSettings d = {}, SystemConfig c = config())
      : scene(std::move(bodies)), one(c), many(MPI_COMM_WORLD, c, d) {
    for (const BodyDesc& b : scene) {
      one.addBody(b);
      many.addBody(b);
    }
  }
  // One step of both runs; returns the largest difference of a body's position between them after it.
  real step() {
    one.step();
    many.step();
    return maxPositionDifference(many.gatherState(), oneRankState(one));
  }
};

}  // namespace

TEST_CASE("Bisection: the median cut along the longest axis and one owner per point", "[mpi]") {
  std::vector<Vec3> pts;
  for (int i = 0; i < 10; ++i) pts.push_back(Vec3{real(i), real(0.1 * (i % 3)), 0});  // x is the longest axis
  const Bisection b = Bisection::build(pts, 2);
  int low = 0;
  for (const Vec3& p : pts) low += b.owner(p) == 0 ? 1 : 0;
  CHECK(low == 5);                       // the median splits 10 points 5/5
  CHECK(b.boxHigh(0).x == Approx(4.5));  // halfway between the 5th and 6th x
  CHECK(b.distance(Vec3{real(6), 0, 0}, 0) == Approx(1.5));
  CHECK(b.distance(Vec3{real(6), 0, 0}, 1) == 0);
  const Bisection four = Bisection::build(pts, 4);  // 10 points into 4 boxes: 2 + 3 on the low half, 2 + 3 high
  std::vector<int> count(4, 0);
  for (const Vec3& p : pts) ++count[size_t(four.owner(p))];
  CHECK(count == std::vector<int>{2, 3, 2, 3});
  CHECK_THROWS_AS(Bisection::build(pts, 0), InputError);
}

TEST_CASE("MPI: a sphere pile split over the processes follows the one-process run", "[mpi]") {
  Runs r(pile(12, 3, 8));  // 288 spheres, x the longest axis: the split runs through the pile
  const int steps = 200;
  real worst = 0;
  int64_t contact_mismatch = 0, sum_mismatch = 0, contacts_last = 0;
  for (int s = 0; s < steps; ++s) {
    worst = std::max(worst, r.step());
    const int64_t owned_contacts = sumOverRanks(int64_t(r.many.local()->contacts().count()));
    contact_mismatch += owned_contacts != r.one.lastStats().contacts ? 1 : 0;
    sum_mismatch += sumOverRanks(int64_t(r.many.ownedIds().size())) != int64_t(r.many.dynamicCount()) ? 1 : 0;
    contacts_last = owned_contacts;
  }
  const std::vector<MotionState> all = r.many.gatherState();
  const PileStats a = statsOf(all, r.scene), b = statsOf(oneRankState(r.one), r.scene);
  if (worldRank() == 0)
    std::printf(
        "pile 288 spheres x 200 steps on %d processes: max position difference %.3e m, contacts %lld (one "
        "process %lld), mean height %.9f / %.9f m, kinetic energy %.9e / %.9e J\n",
        worldSize(), double(worst), (long long)contacts_last, (long long)r.one.lastStats().contacts, a.mean_height,
        b.mean_height, a.kinetic, b.kinetic);
  CHECK(worst < real(1e-6) * kRadius);
  // On one process nothing is summed in another order: the rebuilt System, its warm start by global key and the
  // exchange-free solve reproduce the plain System bit for bit (CTest mpi_pile_one_process).
  if (worldSize() == 1) CHECK(worst == 0);
  CHECK(contact_mismatch == 0);
  CHECK(sum_mismatch == 0);
  CHECK(contacts_last > 300);  // a pile in contact, not free fall
  CHECK(a.mean_height == Approx(b.mean_height).epsilon(1e-9));
  CHECK(a.kinetic == Approx(b.kinetic).epsilon(1e-6));
  // Both processes own part of it.
  CHECK(r.many.ownedIds().size() > 0);
  // The local System lives from one rebuild to the next: a body must come from beyond the halo to force one.
  if (worldRank() == 0)
    std::printf("pile: %lld local Systems built in %d steps\n", (long long)r.many.migrations().rebuilds, steps);
  CHECK(r.many.migrations().rebuilds >= 1);
  CHECK(r.many.migrations().rebuilds <= steps / 10);
}

TEST_CASE("MPI: Jacobi and BB over the processes follow the one-process run", "[mpi]") {
  // Jacobi's step bounds each row of N by the column norms of every contact of its bodies (contact_problem.h:
  // computeJacobiSteps), contacts of other processes included; BB reduces like APGD. A fixed count of iterations
  // (BB: 100, so that the solve leaves little for a rounding-flipped branch to change).
  for (SolverType type : {SolverType::Jacobi, SolverType::BB}) {
    SystemConfig c = config(type == SolverType::BB ? 100 : 30);
    c.solver.type = type;
    Runs r(pile(8, 2, 6), DecompositionSettings{}, c);
    real worst = 0;
    int64_t contact_mismatch = 0;
    for (int s = 0; s < 100; ++s) {
      worst = std::max(worst, r.step());
      contact_mismatch +=
          sumOverRanks(int64_t(r.many.local()->contacts().count())) != r.one.lastStats().contacts ? 1 : 0;
    }
    if (worldRank() == 0)
      std::printf("%s: pile of 96 x 100 steps, max position difference %.3e m, contacts %lld\n", solverName(type),
                  double(worst), (long long)r.one.lastStats().contacts);
    // BB's line search and best-iterate tests branch on sums, so rounding can pick another trial step now and then
    // (measured: 1.6e-8 m over 100 steps, where Jacobi, without such branches, stays at 1e-14 m): the pile's bound.
    CHECK(worst < (type == SolverType::BB ? real(1e-6) * kRadius : real(1e-9)));
    CHECK(contact_mismatch == 0);
    CHECK(r.one.lastStats().contacts > 100);
  }
}

TEST_CASE("MPI: a frictionless pile solves its normal rows alone over the processes", "[mpi]") {
  // Every contact frictionless: the problem is normal-only (one row per contact, jacobian.h), decided for all
  // processes together, with the normal-row Schur product and its exchange. Its blocks pack three contacts each in
  // every process's own order, so the block steps (APGD's preconditioner) are not one process's: the iterates
  // differ (4.7e-7 m after 100 steps at 30 iterations) and agree where the solve has converged (100 iterations:
  // 1.8e-14 m; one process: bit for bit).
  std::vector<BodyDesc> scene = pile(8, 2, 6);
  for (BodyDesc& b : scene) b.friction = 0;
  Runs r(std::move(scene), DecompositionSettings{}, config(100));
  real worst = 0;
  int normal_only = 0;
  for (int s = 0; s < 100; ++s) {
    worst = std::max(worst, r.step());
    normal_only += r.many.local()->lastStats().normal_only && r.one.lastStats().normal_only ? 1 : 0;
  }
  if (worldRank() == 0)
    std::printf("frictionless pile: %d normal-only steps of 100, max position difference %.3e m\n", normal_only,
                double(worst));
  CHECK(normal_only > 50);
  CHECK(worst < real(1e-9));
}

TEST_CASE("MPI: bodies cross the split both ways and are owned once", "[mpi]") {
  // Two rows of spheres on the ground, one rolling towards +x, the other towards -x, along a strip 2.4 m long: the
  // split (x, at the median) is crossed in both directions.
  std::vector<BodyDesc> scene{ground()};
  for (int row = 0; row < 2; ++row)
    for (int i = 0; i < 24; ++i) {
      const real vx = row == 0 ? real(2) : real(-2);
      scene.push_back(sphere(Vec3{real(i * 0.1), kRadius, real(row * 0.3)}, Vec3{vx, 0, 0}));
    }
  Runs r(std::move(scene), DecompositionSettings{real(100), real(1.5)},
         config(10));  // no re-balance: the moves are migrations; fixed count
  real worst = 0;
  int64_t sum_mismatch = 0;
  for (int s = 0; s < 200; ++s) {
    worst = std::max(worst, r.step());
    sum_mismatch += sumOverRanks(int64_t(r.many.ownedIds().size())) != int64_t(r.many.dynamicCount()) ? 1 : 0;
  }
  const MigrationLog& log = r.many.migrations();
  const int other = 1 - worldRank();
  if (worldSize() == 2) {
    std::printf("rank %d: %lld bodies sent to rank %d, %lld received; max position difference %.3e m\n", worldRank(),
                (long long)log.sent[size_t(other)], other, (long long)log.received[size_t(other)], double(worst));
    CHECK(log.sent[size_t(other)] > 0);
    CHECK(log.received[size_t(other)] > 0);
    // What one process sent the other received.
    CHECK(sumOverRanks(log.sent[size_t(other)]) == sumOverRanks(log.received[size_t(other)]));
  }
  CHECK(log.rebalances == 0);
  CHECK(sum_mismatch == 0);
  CHECK(worst < real(1e-9));
}

TEST_CASE("MPI: a drifting pile is re-balanced and still follows the one-process run", "[mpi]") {
  // A block of spheres on the ground, the left half sliding to the right into the other: the low box empties, the
  // owned counts drift apart past the ratio 1.2, and the bisection is computed again.
  std::vector<BodyDesc> scene{ground()};
  for (int i = 0; i < 16; ++i)
    for (int k = 0; k < 3; ++k)
      scene.push_back(sphere(Vec3{real(i * 0.11), kRadius, real(k * 0.11)}, Vec3{i < 8 ? real(3) : real(0), 0, 0}));
  Runs r(std::move(scene), DecompositionSettings{}, config(10));
  real worst = 0;
  int64_t sum_mismatch = 0;
  for (int s = 0; s < 150; ++s) {
    worst = std::max(worst, r.step());
    sum_mismatch += sumOverRanks(int64_t(r.many.ownedIds().size())) != int64_t(r.many.dynamicCount()) ? 1 : 0;
  }
  if (worldRank() == 0)
    std::printf("drifting block: %lld re-balances, max position difference %.3e m\n",
                (long long)r.many.migrations().rebalances, double(worst));
  if (worldSize() > 1) CHECK(r.many.migrations().rebalances > 0);
  CHECK(sum_mismatch == 0);
  CHECK(worst < real(1e-9));
}

TEST_CASE("MPI: a contact across the split is solved once with the one-process impulse", "[mpi]") {
  // Two spheres on the ground, pressed into each other across the split (at x = 0) and closing at 2 m/s.
  std::vector<BodyDesc> scene{ground(), sphere(Vec3{real(-0.049), kRadius, 0}, Vec3{1, 0, 0}),
                              sphere(Vec3{real(0.049), kRadius, real(0.002)}, Vec3{-1, 0, 0})};
  Runs r(std::move(scene));
  for (int s = 0; s < 5; ++s) {
    r.one.step();
    r.many.step();
    // The one-process impulse of the pair (bodies 1 and 2).
    const ContactArrays& c1 = r.one.contacts();
    Vec3 j_one{0, 0, 0};
    int pair_one = 0;
    for (size_t k = 0; k < c1.count(); ++k)
      if (c1.body_a[k] == 1 && c1.body_b[k] == 2) {
        const std::vector<real>& g = r.one.impulses();
        j_one = Vec3{g[3 * k], g[3 * k + 1], g[3 * k + 2]};
        ++pair_one;
      }
    // The processes' contacts: the pair's on exactly one of them.
    const System& loc = *r.many.local();
    const std::vector<int32_t>& ids = r.many.localIds();
    double j_many[3] = {0, 0, 0};
    int64_t pair_many = 0;
    for (size_t k = 0; k < loc.contacts().count(); ++k)
      if (ids[size_t(loc.contacts().body_a[k])] == 1 && ids[size_t(loc.contacts().body_b[k])] == 2) {
        for (int i = 0; i < 3; ++i) j_many[i] = double(loc.impulses()[3 * k + size_t(i)]);
        ++pair_many;
      }
    MPI_Allreduce(MPI_IN_PLACE, j_many, 3, MPI_DOUBLE, MPI_SUM, MPI_COMM_WORLD);
    const int64_t total = sumOverRanks(int64_t(loc.contacts().count()));
    if (worldRank() == 0 && s == 0)
      std::printf("straddling pair: impulse %.12e (one process %.12e) N s, contacts %lld (one process %lld)\n",
                  j_many[0], double(j_one.x), (long long)total, (long long)c1.count());
    CHECK(pair_one == 1);
    CHECK(sumOverRanks(pair_many) == 1);
    CHECK(total == int64_t(c1.count()));
    if (s == 0) CHECK(j_one.x > 0);  // they hit in the first step (and part after it)
    CHECK(j_many[0] == Approx(double(j_one.x)).epsilon(1e-12));
    CHECK(std::fabs(j_many[1] - double(j_one.y)) <= 1e-12 * double(j_one.x));
    CHECK(std::fabs(j_many[2] - double(j_one.z)) <= 1e-12 * double(j_one.x));
  }
  // The two spheres lie on different processes (the contact straddles the split).
  if (worldSize() == 2) CHECK(r.many.ownedIds().size() == 1);
  // On 3 processes one box stays empty: no bisection does better, so none is made again (it was, every step).
  CHECK(r.many.migrations().rebalances == 0);
}

// The places a device sums the shares from (ProcessGroup::exchangeTerms, the GPU's peer exchange): every term of a
// listed body names a process holding it and the place of the same body (the same global key) in that process's list,
// the terms in rank order with this process's own at its own place.
TEST_CASE("MPI: each exchange term names the same body in the other process's list", "[mpi]") {
  Runs r(pile(12, 3, 8));
  for (int s = 0; s < 30; ++s) r.many.step();
  MpiGroup& g = r.many.group();
  std::vector<int32_t> start, rank, index;
  g.exchangeTerms(start, rank, index);
  const std::vector<int32_t>& list = g.exchangeBodies();
  std::vector<uint8_t> mine(list.size() * sizeof(int32_t));
  for (size_t j = 0; j < list.size(); ++j) {
    const int32_t key = g.bodyKeys()[size_t(list[j])];
    std::memcpy(mine.data() + j * sizeof(int32_t), &key, sizeof key);
  }
  const std::vector<std::vector<uint8_t>> lists = g.allgatherBytes(mine);
  auto keyAt = [&](int q, int32_t place) {
    int32_t key = -1;
    const std::vector<uint8_t>& l = lists[size_t(q)];
    if (place >= 0 && size_t(place + 1) * sizeof(int32_t) <= l.size())
      std::memcpy(&key, l.data() + size_t(place) * sizeof(int32_t), sizeof key);
    return key;
  };
  int64_t terms = 0, wrong = 0, shared_terms = 0;
  REQUIRE(start.size() == list.size() + 1);
  for (size_t j = 0; j < list.size(); ++j) {
    bool own = false;
    for (int32_t t = start[j]; t < start[j + 1]; ++t) {
      ++terms;
      const int q = rank[size_t(t)];
      own = own || (q == worldRank() && index[size_t(t)] == int32_t(j));
      if (t > start[j] && rank[size_t(t) - 1] >= q) ++wrong;  // rank order, each process once
      if (keyAt(q, index[size_t(t)]) != g.bodyKeys()[size_t(list[j])]) ++wrong;
      shared_terms += q != worldRank() ? 1 : 0;
    }
    wrong += own ? 0 : 1;
  }
  const int64_t all_wrong = sumOverRanks(wrong), all_shared = sumOverRanks(shared_terms);
  if (worldRank() == 0)
    std::printf("exchange terms on %d processes: %lld terms from other processes, %lld wrong\n", worldSize(),
                (long long)all_shared, (long long)all_wrong);
  CHECK(all_wrong == 0);
  if (worldSize() > 1) CHECK(all_shared > 0);  // the split runs through the pile: bodies are shared
  (void)terms;
}

TEST_CASE("MPI: what does not run over several processes is refused", "[mpi]") {
  SystemConfig gs = config();
  gs.solver.type = SolverType::GaussSeidel;
  CHECK_THROWS_AS(DistributedSystem(MPI_COMM_WORLD, gs), InputError);
  DistributedSystem d(MPI_COMM_WORLD, config());
  BodyDesc rolling = sphere(Vec3{0, 1, 0}, Vec3{0, 0, 0});
  rolling.rolling_friction = real(0.01);
  CHECK_THROWS_AS(d.addBody(rolling), InputError);
  BodyDesc bad = sphere(Vec3{0, 1, 0}, Vec3{0, 0, 0});
  bad.mass = -1;
  CHECK_THROWS_AS(d.addBody(bad), InputError);
}

namespace {

// The scene on one GPU a process (this process's rank on device rank mod the devices) against the plain CPU System:
// the largest position difference over `steps` steps and the steps whose contact counts differ. Real storage of
// APGD's vectors, so the two backends compare to rounding (the GPU's float storage has its own tests).
struct GpuRun {
  real worst = 0;
  int64_t contact_mismatch = 0, contacts = 0, rebuilds = 0;
};
GpuRun gpuAgainstCpu(const std::vector<BodyDesc>& scene, SystemConfig c, int steps, DecompositionSettings d = {}) {
  c.solver.storage = VectorStorage::Real;
  System one(c);
  DistributedSystem many(MPI_COMM_WORLD, c, d, [](const SystemConfig& cc) { return makeGpuSystem(cc); });
  for (const BodyDesc& b : scene) {
    one.addBody(b);
    many.addBody(b);
  }
  GpuRun g;
  for (int s = 0; s < steps; ++s) {
    one.step();
    many.step();
    g.worst = std::max(g.worst, maxPositionDifference(many.gatherState(), oneRankState(one)));
    g.contacts = sumOverRanks(many.local()->lastStats().contacts);
    g.contact_mismatch += g.contacts != one.lastStats().contacts ? 1 : 0;
  }
  g.rebuilds = many.migrations().rebuilds;
  return g;
}

// Whether every process has a device (each says for itself; all skip when one has none).
bool everyProcessHasGpu() {
  std::string why;
  const int64_t have = gpuAvailable(&why) && selectGpu(worldRank()) >= 0 ? 1 : 0;
  const bool all = sumOverRanks(have) == worldSize();
  if (!all && worldRank() == 0) std::printf("skipped: a process has no CUDA device (%s)\n", why.c_str());
  return all;
}

}  // namespace

// The GPU backend under the decomposition: the owned contacts kept on the device, the shared bodies' velocity
// changes exchanged each Schur product (GPU to GPU where the processes share a host), APGD's trials on the device with
// their test sums reduced over the processes. Against the CPU System: the pile (tolerance stop and fixed count), the rows crossing the split both ways
// (migrations with their warm starts), Jacobi (the column sums exchanged) and a frictionless pile (normal rows).
TEST_CASE("MPI GPU: one GPU a process follows the one-process CPU run", "[mpi][gpu]") {
  if (!everyProcessHasGpu()) return;
  const GpuRun pile_run = gpuAgainstCpu(pile(12, 3, 8), config(), 200);
  std::vector<BodyDesc> rows{ground()};
  for (int row = 0; row < 2; ++row)
    for (int i = 0; i < 24; ++i)
      rows.push_back(sphere(Vec3{real(i * 0.1), kRadius, real(row * 0.3)}, Vec3{row == 0 ? real(2) : real(-2), 0, 0}));
  const GpuRun rows_run = gpuAgainstCpu(rows, config(10), 200, DecompositionSettings{real(100), real(1.5)});
  SystemConfig jac = config(30);
  jac.solver.type = SolverType::Jacobi;
  const GpuRun jacobi_run = gpuAgainstCpu(pile(8, 2, 6), jac, 100);
  std::vector<BodyDesc> smooth = pile(8, 2, 6);
  for (BodyDesc& b : smooth) b.friction = 0;
  const GpuRun smooth_run = gpuAgainstCpu(smooth, config(100), 100);
  if (worldRank() == 0)
    std::printf(
        "GPU over %d processes against the CPU: pile %.3e m (%lld contacts, %lld built), crossing rows %.3e m (%lld "
        "built), Jacobi %.3e m, frictionless %.3e m\n",
        worldSize(), double(pile_run.worst), (long long)pile_run.contacts, (long long)pile_run.rebuilds,
        double(rows_run.worst), (long long)rows_run.rebuilds, double(jacobi_run.worst), double(smooth_run.worst));
  CHECK(pile_run.worst < real(1e-6) * kRadius);
  CHECK(pile_run.contact_mismatch == 0);
  CHECK(pile_run.contacts > 300);
  CHECK(rows_run.worst < real(1e-9));
  CHECK(jacobi_run.worst < real(1e-9));
  CHECK(jacobi_run.contact_mismatch == 0);
  CHECK(smooth_run.worst < real(1e-9));
}

// The GPU's peer exchange (each process reading its neighbours' shares from their device memory) against the pinned
// host staging with MPI messages: the same sums in the same order, so bitwise the same trajectory, at the default
// float storage of APGD's vectors.
TEST_CASE("MPI GPU: the peer exchange gives the host staging's trajectory bit for bit", "[mpi][gpu]") {
  if (!everyProcessHasGpu()) return;
  std::vector<MotionState> end[2];
  int64_t peer[2] = {0, 0};
  for (int p = 0; p < 2; ++p) {
    SystemConfig c = config();
    c.gpu.peer_exchange = p == 1;
    DistributedSystem many(MPI_COMM_WORLD, c, {}, [](const SystemConfig& cc) { return makeGpuSystem(cc); });
    for (const BodyDesc& b : pile(12, 3, 8)) many.addBody(b);
    for (int s = 0; s < 100; ++s) many.step();
    end[p] = many.gatherState();
    peer[p] = sumOverRanks(many.profile().group.peer_exchanges);
  }
  const real d = maxPositionDifference(end[0], end[1]);
  if (worldRank() == 0)
    std::printf(
        "peer exchange on %d processes: %lld products device to device (staged run: %lld), trajectories "
        "differ by %.3e m\n",
        worldSize(), (long long)peer[1], (long long)peer[0], double(d));
  CHECK(peer[0] == 0);
  if (worldSize() > 1) CHECK(peer[1] > 0);  // one host: every GPU reaches the others (NVLink or PCIe)
  CHECK(d == 0);
}

// Catch2 inside MPI: every process runs the same tests (they are collective); the exit code is the worst of all.
int main(int argc, char** argv) {
  MPI_Init(&argc, &argv);
  int failed = Catch::Session().run(argc, argv);
  int worst = 0;
  MPI_Allreduce(&failed, &worst, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
  MPI_Finalize();
  return worst;
}
