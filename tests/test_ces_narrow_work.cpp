// The narrow phase's work on the CES feed's own contacts: the default machine at the industrial feed (20,000
// particles/s) on the CPU backend with the GPU's GJK choice, 0.2 s of machine time (~4,000 particles on the drum and
// in flight); every touching pair of the last step is collided again with the host's support counters (gjk.h:
// NarrowWork): the mean supports per pair of each class of particles on the machine's cylinders and of the
// particle pairs that go through MPR, and the share of "deep" MPR pairs (mpr.h: the restarts that cost ~10x a first
// pass), are bounded. The particle-against-drum classes have closed forms
// (narrowphase_impl.h: collideConvexBigCylinder, collideSmoothBigCylinder) and must stay near zero: when the
// ellipsoids on the drum went through MPR, a third of them were deep and they set the GPU narrow phase's length
// (docs/GPU_PERFORMANCE.md, "The CES feed").
#include <catch2/catch.hpp>

#include <algorithm>
#include <cstdio>
#include <map>
#include <set>
#include <utility>

#include <nlohmann/json.hpp>

#include "ces/ces_config.h"
#include "ces/machine.h"
#include "chrono_like/collision/collision.h"
#include "chrono_like/collision/narrowphase.h"
#include "chrono_like/system.h"

using namespace dvi;
using namespace dvi::ces;

namespace {

struct ClassCensus {
  int pairs = 0, deep = 0, max_supports = 0;
  double supports = 0;
  double mean() const { return pairs > 0 ? supports / pairs : 0; }
};

// Each (type, type) class (smaller type first) of the touching pairs of sys's last step.
std::map<std::pair<ShapeType, ShapeType>, ClassCensus> census(const System& sys) {
  const ShapeArrays& sh = sys.shapes();
  const BodyArrays& bodies = sys.bodies();
  const ContactArrays& c = sys.contacts();
  const CollisionSettings& cs = sys.config().collision;
  std::set<std::pair<int32_t, int32_t>> touching;
  for (size_t k = 0; k < c.count(); ++k) touching.insert({c.shape_a[k], c.shape_b[k]});
  std::map<std::pair<ShapeType, ShapeType>, ClassCensus> out;
  ContactPoint pts[kMaxContactsPerPair];
  for (const auto& [ia, ib] : touching) {
    const Shape &a = sh.shape[size_t(ia)], &b = sh.shape[size_t(ib)];
    const Pose wa = shapeWorldPose(Pose{bodies.pos[size_t(a.body)], bodies.rot[size_t(a.body)]}, a);
    const Pose wb = shapeWorldPose(Pose{bodies.pos[size_t(b.body)], bodies.rot[size_t(b.body)]}, b);
    const real env = plainEnvelope(a, b, cs.envelope_rel);
    NarrowWork w;
    collideShapes(a, wa, b, wb, sh.hull_points.data(), env, pts, nullptr, cs.mpr_manifold, cs.gjk, &w);
    np::MprDeferred d;
    const bool deep =
        collideShapes(a, wa, b, wb, sh.hull_points.data(), env, pts, &d, cs.mpr_manifold, cs.gjk) == np::kMprDeferred;
    const auto key = int(a.type) <= int(b.type) ? std::make_pair(a.type, b.type) : std::make_pair(b.type, a.type);
    ClassCensus& k = out[key];
    k.pairs += 1;
    k.deep += deep ? 1 : 0;
    k.supports += double(w.total());
    k.max_supports = std::max(k.max_supports, int(w.total()));
  }
  return out;
}

// Measured means (supports per touching pair) when this test was written. The classes of particles against a
// machine cylinder (the drum, the brush: hundreds of pairs each) are bounded one by one; the pairs of two particles
// that go to MPR (a few dozen a class, too few for a stable mean each) together. A bound is 1.3x the measured mean
// and 2 more, as in test_narrow_work.cpp.
struct Measured {
  ShapeType a, b;
  double mean;
};
const Measured kOnCylinder[] = {
    {ShapeType::Sphere, ShapeType::Cylinder, 0.0},
    {ShapeType::Ellipsoid, ShapeType::Cylinder, 0.4},
    {ShapeType::Box, ShapeType::Cylinder, 0.3},
    {ShapeType::Cylinder, ShapeType::ConvexHull, 0.5},
};
constexpr double kParticleMprMean = 58.3;
double budget(double measured) { return 1.3 * measured + 2; }

}  // namespace

TEST_CASE("narrow phase work on the CES feed: supports per pair and deep pairs per class stay within bounds",
          "[ces][narrowphase][work]") {
  const CesConfig cfg = parseCesDocument(nlohmann::json::parse(defaultCesJson()), {"feed.mass_flow_g_s=8"}, "<test>");
  SystemConfig sc;
  sc.step.dt = real(cfg.step.dt);
  sc.solver.max_iterations = cfg.solver.max_iterations;
  sc.collision.gjk = resolvedGjk(GjkUse::Auto, true);  // the GPU's choice: the work the GPU does
  System sys(sc);
  CesMachine machine(cfg, sys);
  for (int s = 0; s < 1000; ++s) machine.step();
  const auto classes = census(sys);
  int pairs = 0, deep = 0, on_cylinder = 0, mpr_pairs = 0;
  double mpr_supports = 0;
  for (const auto& [key, k] : classes) {
    std::printf("ces work %-11s %-11s pairs %5d  supports mean %6.1f max %4d  deep %d\n", shapeTypeName(key.first),
                shapeTypeName(key.second), k.pairs, k.mean(), k.max_supports, k.deep);
    pairs += k.pairs;
    deep += k.deep;
    INFO(shapeTypeName(key.first) << "-" << shapeTypeName(key.second) << ": " << k.pairs << " pairs");
    if (key.second == ShapeType::Cylinder ||
        (key.first == ShapeType::Cylinder && key.second == ShapeType::ConvexHull)) {
      if (k.pairs < 200) continue;  // wires on wires: a few pairs
      const Measured* m = nullptr;
      for (const Measured& x : kOnCylinder)
        if (x.a == key.first && x.b == key.second) m = &x;
      REQUIRE(m != nullptr);  // a new class on the machine's cylinders: measure it and add it to the table
      CHECK(k.mean() <= budget(m->mean));
      CHECK(k.deep <= k.pairs / 100);
      on_cylinder += k.pairs;
    } else if (pairUsesMpr(key.first, key.second)) {
      mpr_pairs += k.pairs;
      mpr_supports += k.supports;
    }
  }
  const double mpr_mean = mpr_pairs > 0 ? mpr_supports / mpr_pairs : 0;
  std::printf(
      "ces work: %d touching pairs, %d deep; %d on the machine's cylinders; %d particle pairs through MPR, "
      "%.1f supports a pair\n",
      pairs, deep, on_cylinder, mpr_pairs, mpr_mean);
  CHECK(deep <= pairs / 100);  // before the ellipsoids' closed form: 397 of 5,200 (a third of those on the drum)
  CHECK(mpr_mean <= budget(kParticleMprMean));
  CHECK(pairs > 2000);        // the feed is on the drum
  CHECK(on_cylinder > 1000);  // particles resting on the drum
  CHECK(mpr_pairs > 100);
}
