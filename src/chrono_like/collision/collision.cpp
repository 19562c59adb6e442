// Native collision backend: AABBs -> binning broad phase -> analytic/MPR narrow phase, on the CPU with
// OpenMP. The per-element work is the DVI_HD code the GPU backend runs (narrowphase.h,
// broadphase_kernels.h).
#include "chrono_like/collision/collision.h"
#include "chrono_like/base/parallel_for.h"

#include <omp.h>

#include <algorithm>

#include "chrono_like/collision/broadphase_kernels.h"
#include "chrono_like/collision/narrowphase.h"

namespace dvi {

namespace {

// Narrow-phase results are gathered per block of pairs, and blocks are concatenated in order, so the
// contact order depends only on the pair order, never on the thread count.
constexpr int64_t kPairsPerBlock = 2048;

struct PairContact {
  ContactPoint point;
  int32_t pair;
};

class NativeCollision final : public CollisionDetector {
 public:
  explicit NativeCollision(const BroadPhaseSettings& s) : broad_(s) {}
  const char* name() const override { return "native"; }

  void detect(const BodyArrays& bodies, ShapeArrays& shapes, const CollisionSettings& config, const StepContext& step,
              ContactArrays& out, CollisionTimes& times) override {
    const bool free_given = v_free_ && w_free_;
    const Vec3* vel = free_given ? v_free_ : bodies.vel.data();
    const Vec3* omega = free_given ? w_free_ : bodies.omega.data();
    double t0 = omp_get_wtime();
    computeAabbs(bodies, shapes, config, step, vel, omega);
    double t1 = omp_get_wtime();
    broadPhase(bodies, shapes, config, times);
    double t2 = omp_get_wtime();
    narrowPhase(bodies, shapes, config, step, vel, omega, out);
    double t3 = omp_get_wtime();
    times.aabbs = t1 - t0;
    times.broad = t2 - t1;
    times.narrow = t3 - t2;
    times.pairs = int64_t(pairs_.size());
  }

 private:
  // ComputeAabbs: reads bodies.pos/rot, the free velocities, shapes.shape; writes shapes.sweep, shapes.aabb. A fixed
  // body at rest in the pose of the last step keeps its shapes' boxes (a static mesh's thousands of triangles): its
  // sweep is 0 and shapes are never edited, only appended, so the box is a function of the pose and the envelope.
  void computeAabbs(const BodyArrays& bodies, ShapeArrays& shapes, const CollisionSettings& config,
                    const StepContext& step, const Vec3* vel, const Vec3* omega) {
    const int64_t ns = int64_t(shapes.count()), nb = int64_t(bodies.count());
    const Shape* sh = shapes.shape.data();
    const Vec3* hull = shapes.hull_points.data();
    const bool reuse =
        int64_t(shapes.aabb.size()) == ns && int64_t(box_pose_.size()) == nb && box_env_ == config.envelope_rel;
    shapes.aabb.resize(size_t(ns));
    shapes.sweep.resize(size_t(ns));
    box_pose_.resize(size_t(nb));
    box_keep_.resize(size_t(nb));
    box_env_ = config.envelope_rel;
    uint8_t* keep = box_keep_.data();
    parallelFor(int64_t(nb), ompTeam(), [&](int64_t b) {
      const Pose now{bodies.pos[b], bodies.rot[b]};
      const Pose& last = box_pose_[size_t(b)];
      const Vec3 zero{0, 0, 0};
      keep[b] = reuse && (bodies.flags[b] & kBodyFixed) && samePose(now, last) && sameVec(vel[b], zero) &&
                sameVec(omega[b], zero);
      box_pose_[size_t(b)] = now;
    });
    const real h_sweep = config.speculative ? step.dt : real(0);
    parallelFor(int64_t(ns), ompTeam(), [&](int64_t i) {
      const Shape& s = sh[i];
      if (keep[s.body]) return;
      Pose body{bodies.pos[s.body], bodies.rot[s.body]};
      const real sweep = shapeSweep(s, hull, vel[s.body], omega[s.body], h_sweep);
      shapes.sweep[i] = sweep;
      shapes.aabb[i] = shapeAabb(s, shapeWorldPose(body, s), hull, shapeMargin(s, config.envelope_rel, sweep));
    });
  }

  // BroadPhase: reads shapes.aabb, shapes.shape, bodies.flags, fat_, fat_flags_; writes pairs_ (and fat_,
  // fat_flags_ when it builds). Last step's pairs are kept while every box is inside its grown box
  // (broadphase_kernels.h: pairsStillHold); else a build on the boxes grown by pair_margin x the last edge.
  void broadPhase(const BodyArrays& bodies, const ShapeArrays& shapes, const CollisionSettings& config,
                  CollisionTimes& times) {
    const int64_t ns = int64_t(shapes.count());
    const Shape* sh = shapes.shape.data();
    const real f = config.broadphase.pair_margin;
    const uint8_t* flags = bodies.flags.data();
    bool keep = f > real(0) && built_ && int64_t(fat_.size()) == ns;
    if (keep) {
      keep = parallelSum(ns, ompTeam(), [&](int64_t i) {
               return pairsStillHold(shapes.aabb[i], fat_[i], flags[sh[i].body], fat_flags_[i]) ? 0 : 1;
             }) == 0;
    }
    if (!keep) {
      const real m = f > real(0) ? f * last_edge_ : real(0);
      fat_.resize(size_t(ns));
      fat_flags_.resize(size_t(ns));
      parallelFor(int64_t(ns), ompTeam(), [&](int64_t i) {
        fat_[i] = fatAabb(shapes.aabb[i], m);
        fat_flags_[i] = flags[sh[i].body];
      });
      broad_.run(shapes, fat_.data(), bodies, pairs_, &last_stats_);
      last_edge_ = last_stats_.bin_edge;
      built_ = true;
    }
    times.broad_stats = last_stats_;
    times.pairs_reused = keep;
  }

  // NarrowPhase: reads pairs_, poses, velocities, shapes; writes the contact arrays (speculative points of
  // pairs that do not close within the step left out: narrowphase.h keepSpeculative).
  void narrowPhase(const BodyArrays& bodies, const ShapeArrays& shapes, const CollisionSettings& config,
                   const StepContext& step, const Vec3* vel, const Vec3* omega, ContactArrays& out) {
    const Shape* sh = shapes.shape.data();
    const Vec3* hull = shapes.hull_points.data();
    const int64_t np = int64_t(pairs_.size());
    const int64_t nblocks = (np + kPairsPerBlock - 1) / kPairsPerBlock;
    const GjkUse gjk = resolvedGjk(config.gjk, false);
    if (int64_t(blocks_.size()) < nblocks) blocks_.resize(size_t(nblocks));
    auto block = [&](int64_t blk) {
      std::vector<PairContact>& buf = blocks_[blk];
      buf.clear();
      const int64_t end = std::min(np, (blk + 1) * kPairsPerBlock);
      ContactPoint pts[kMaxContactsPerPair];
      for (int64_t p = blk * kPairsPerBlock; p < end; ++p) {
        const Shape& a = sh[pairs_[p].a];
        const Shape& b = sh[pairs_[p].b];
        if (skipByBoxes(a.type, b.type, shapes.aabb[pairs_[p].a], shapes.aabb[pairs_[p].b])) continue;
        Pose wa = shapeWorldPose(Pose{bodies.pos[a.body], bodies.rot[a.body]}, a);
        Pose wb = shapeWorldPose(Pose{bodies.pos[b.body], bodies.rot[b.body]}, b);
        const PairMotion m{bodies.pos[a.body], vel[a.body], omega[a.body],
                           bodies.pos[b.body], vel[b.body], omega[b.body]};
        const real envelope =
            pairEnvelope(a, b, config.envelope_rel, shapes.sweep[pairs_[p].a], shapes.sweep[pairs_[p].b], step.dt, m);
        const PairHistory history{last_, pairs_[p].a, pairs_[p].b, real(1)};
        int n = collideShapes(a, wa, b, wb, hull, envelope, pts, nullptr, config.mpr_manifold, gjk, nullptr,
                              config.mpr_coherence && last_.n > 0 ? &history : nullptr);
        n = keepSpeculativePoints(pts, n, plainEnvelope(a, b, config.envelope_rel), step.dt, m);
        for (int k = 0; k < n; ++k) buf.push_back(PairContact{pts[k], int32_t(p)});
      }
    };
    if (nblocks > 1 && ompTeam() > 1) {
#pragma omp parallel for schedule(dynamic, 1)
      for (int64_t blk = 0; blk < nblocks; ++blk) block(blk);
    } else {
      for (int64_t blk = 0; blk < nblocks; ++blk) block(blk);
    }
    writeContacts(sh, nblocks, out);
  }

  // The blocks' contacts into the contact arrays, in pair order.
  void writeContacts(const Shape* sh, int64_t nblocks, ContactArrays& out) {
    offsets_.assign(size_t(nblocks) + 1, 0);
    for (int64_t blk = 0; blk < nblocks; ++blk) offsets_[blk + 1] = offsets_[blk] + int64_t(blocks_[blk].size());
    out.resize(size_t(offsets_[nblocks]));
    parallelFor(int64_t(nblocks), ompTeam(), [&](int64_t blk) {
      int64_t k = offsets_[blk];
      for (const PairContact& c : blocks_[blk]) {
        const ShapePair& pr = pairs_[c.pair];
        out.shape_a[k] = pr.a;
        out.shape_b[k] = pr.b;
        out.body_a[k] = sh[pr.a].body;
        out.body_b[k] = sh[pr.b].body;
        out.normal[k] = c.point.normal;
        out.pa[k] = c.point.pa;
        out.pb[k] = c.point.pb;
        out.dist[k] = c.point.dist;
        out.key[k] = contactKey(pr.a, pr.b, c.point.feature);
        ++k;
      }
    });
  }

  // box reuse of fixed bodies at rest: each body's pose at the last ComputeAabbs, whether its boxes were kept, and
  // the relative envelope they were computed with
  std::vector<Pose> box_pose_;
  std::vector<uint8_t> box_keep_;
  real box_env_ = -1;
  BroadPhaseBins broad_;
  std::vector<ShapePair> pairs_;
  // pair reuse: the grown boxes and body flags of the last build, its bin edge and statistics
  std::vector<Aabb> fat_;
  std::vector<uint8_t> fat_flags_;
  real last_edge_ = 0;
  bool built_ = false;
  BroadPhaseStats last_stats_;
  std::vector<std::vector<PairContact>> blocks_;
  std::vector<int64_t> offsets_;
};

}  // namespace

std::unique_ptr<CollisionDetector> makeNativeCollision(const BroadPhaseSettings& settings) {
  return std::make_unique<NativeCollision>(settings);
}

}  // namespace dvi
