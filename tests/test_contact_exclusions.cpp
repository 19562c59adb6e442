// Contact exclusions (System::setContactExclusions, collision/contact.h: contactExcluded): pairs of bodies and bodies
// without contacts that the step leaves out, on both backends (the Bullet drop-in world's disableCollisionsBetween-
// LinkedBodies and CF_NO_CONTACT_RESPONSE). Checked by what the bodies do (a box resting on another falls through
// it once the pair is excluded, and only that pair), against the lookup's brute-force definition, and GPU against
// CPU.
#include <catch2/catch.hpp>

#include <algorithm>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "chrono_like/base/errors.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/system.h"
#include "device_check.h"
#include "gpu/gpu_factory.h"

using namespace dvi;

namespace {

// A ground plane (body 0), a box resting on it (1) and a box resting on that one (2); 1 m boxes.
void stack(System& s) {
  BodyDesc g;
  g.mass = 0;
  g.flags = kBodyFixed;
  g.shapes.push_back(makePlane(Vec3{0, 1, 0}, 0));
  s.addBody(g);
  for (int i = 0; i < 2; ++i) {
    BodyDesc b;
    b.pos = Vec3{0, real(0.5 + i), 0};
    b.mass = 1;
    b.inertia = Vec3{real(1) / 6, real(1) / 6, real(1) / 6};
    b.shapes.push_back(makeBox(Vec3{real(0.5), real(0.5), real(0.5)}));
    s.addBody(b);
  }
}

// Heights of boxes 1 and 2 after 0.5 s under the given exclusions.
std::pair<real, real> heights(System& s, const std::vector<std::pair<int32_t, int32_t>>& pairs,
                              std::vector<uint8_t> flags) {
  stack(s);
  s.setContactExclusions(pairs, std::move(flags));
  s.advance(int(0.5 / s.config().step.dt));
  s.syncToHost();
  return {s.bodies().pos[1].y, s.bodies().pos[2].y};
}

}  // namespace

TEST_CASE("contact exclusions: the lookup is its brute-force definition", "[exclusions]") {
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> body(0, 40);
  std::vector<std::pair<int32_t, int32_t>> pairs;
  std::vector<uint64_t> keys;
  for (int i = 0; i < 60; ++i) {
    const int a = body(rng), b = body(rng);
    if (a == b) continue;
    pairs.emplace_back(a, b);
    keys.push_back(bodyPairKey(a, b));
  }
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  std::vector<uint8_t> flags(30, 0);
  flags[7] = flags[19] = 1;
  for (int a = 0; a <= 40; ++a)
    for (int b = 0; b <= 40; ++b) {
      bool listed = false;
      for (const auto& p : pairs) listed = listed || (p.first == a && p.second == b) || (p.first == b && p.second == a);
      const bool flagged = (a < 30 && flags[size_t(a)]) || (b < 30 && flags[size_t(b)]);
      CHECK(contactExcluded(a, b, keys.data(), int64_t(keys.size()), flags.data(), 30) == (listed || flagged));
      CHECK(contactExcluded(a, b, keys.data(), int64_t(keys.size()), nullptr, 0) == listed);
    }
}

TEST_CASE("contact exclusions: an excluded pair passes through, the others still touch", "[exclusions]") {
  SystemConfig cfg;
  cfg.step.dt = real(1) / 240;
  {
    System s(cfg);
    const auto h = heights(s, {}, {});
    CHECK(h.first == Approx(0.5).margin(0.01));  // both rest
    CHECK(h.second == Approx(1.5).margin(0.01));
  }
  {
    System s(cfg);  // box 2 no longer touches box 1: it falls onto the ground, through box 1
    const auto h = heights(s, {{2, 1}}, {});
    CHECK(h.first == Approx(0.5).margin(0.01));
    CHECK(h.second == Approx(0.5).margin(0.02));
  }
  {
    System s(cfg);  // box 1 makes no contacts at all: it falls through the ground, box 2 through it onto the ground
    const auto h = heights(s, {}, {0, 1, 0});
    CHECK(h.first < -0.5);
    CHECK(h.second == Approx(0.5).margin(0.02));
  }
  System s(cfg);
  CHECK_THROWS_AS(s.setContactExclusions({{1, 1}}, {}), InputError);
  CHECK_THROWS_AS(s.setContactExclusions({{-1, 2}}, {}), InputError);
}

TEST_CASE("contact exclusions on the GPU backend: as on the CPU", "[exclusions][gpu]") {
  if (!dvi::testing::haveDevice()) return;
  SystemConfig cfg;
  cfg.step.dt = real(1) / 240;
  for (int c = 0; c < 3; ++c) {
    const std::vector<std::pair<int32_t, int32_t>> pairs =
        c == 1 ? std::vector<std::pair<int32_t, int32_t>>{{2, 1}} : std::vector<std::pair<int32_t, int32_t>>{};
    const std::vector<uint8_t> flags = c == 2 ? std::vector<uint8_t>{0, 1, 0} : std::vector<uint8_t>{};
    System cpu(cfg);
    auto gpu = makeGpuSystem(cfg);
    const auto hc = heights(cpu, pairs, flags);
    const auto hg = heights(*gpu, pairs, flags);
    INFO("case " << c << ": CPU " << hc.first << ", " << hc.second << "; GPU " << hg.first << ", " << hg.second);
    CHECK(hg.first == Approx(hc.first).margin(0.01));
    CHECK(hg.second == Approx(hc.second).margin(0.01));
  }
}
