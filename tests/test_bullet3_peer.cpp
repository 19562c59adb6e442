// [bullet3] The Bullet 3 OpenCL peer of the scaling benchmark (bench/scaling/bullet3_peer.h) on an OpenCL CPU
// device (pocl: `apt-get install pocl-opencl-icd`), so it runs without a GPU. Where this build has no peer or
// no OpenCL CPU device exists (CI installs neither) the tests skip with a message, as the [gpu] tests do.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "scaling/bullet3_peer.h"
#include "scaling/scaling_scenes.h"

using namespace dvi;
using namespace dvi::bench;

namespace {

bool havePeerAndCpuDevice() {
  std::string why;
  if (!bullet3PeerBuilt(&why)) {
    WARN("skipping: " << why);
    return false;
  }
  if (!findOpenClDevice(OpenClDeviceType::Cpu, &why)) {
    WARN("no OpenCL CPU device: skipping (" << why << ")");
    return false;
  }
  return true;
}

Bullet3PeerSettings cpuSettings() {
  Bullet3PeerSettings s;
  s.device = OpenClDeviceType::Cpu;
  return s;
}

}  // namespace

TEST_CASE("Bullet 3 peer: the bodies read back before a step are the scene's", "[bullet3]") {
  if (!havePeerAndCpuDevice()) return;
  const SceneSpec spec = makePileSpec(200);
  Bullet3Peer peer(spec, cpuSettings());
  REQUIRE(peer.bodyCount() == spec.bodies.size());
  std::vector<Vec3> pos, vel;
  std::vector<Quat> rot;
  peer.readBodies(pos, rot, vel);
  REQUIRE(pos.size() == spec.bodies.size());
  double worst = 0;
  for (size_t i = 0; i < pos.size(); ++i) {
    worst = std::max(worst, double(length(pos[i] - spec.bodies[i].pos)));
    REQUIRE(length(vel[i]) == 0);
  }
  CHECK(worst < 1e-6);                                     // float storage in centimetres: ~1e-7 m at these heights
  CHECK(deepestPenetration(spec, pos, rot) < real(1e-6));  // the scene starts without overlaps
}

TEST_CASE("Bullet 3 peer: a pile of 200 spheres comes to rest on the ground", "[bullet3]") {
  if (!havePeerAndCpuDevice()) return;
  const SceneSpec spec = makePileSpec(200);
  const double r = double(spec.ref_length);
  Bullet3Peer peer(spec, cpuSettings());
  const int steps = 400;  // 0.4 s at h = 1 ms
  for (int k = 0; k < steps; ++k) peer.step();
  CHECK(peer.lastStats().contacts > int64_t(spec.bodies.size()));  // every sphere rests on something
  std::vector<Vec3> pos, vel;
  std::vector<Quat> rot;
  peer.readBodies(pos, rot, vel);
  double lowest = 1e9, fastest = 0;
  for (size_t i = 0; i < pos.size(); ++i) {
    REQUIRE(std::isfinite(double(pos[i].x + pos[i].y + pos[i].z)));
    REQUIRE(std::isfinite(double(vel[i].x + vel[i].y + vel[i].z)));
    lowest = std::min(lowest, double(pos[i].y));
    fastest = std::max(fastest, double(length(vel[i])));
    // Inside the container (the walls' inner faces at 0 and width), above the ground.
    CHECK(pos[i].x > -0.5 * r);
    CHECK(pos[i].z > -0.5 * r);
    CHECK(pos[i].x < spec.width + 0.5 * r);
    CHECK(pos[i].z < spec.width + 0.5 * r);
  }
  const double pen = double(deepestPenetration(spec, pos, rot));
  INFO("lowest centre " << lowest / r << " r, fastest " << fastest << " m/s, deepest penetration " << pen / r << " r");
  // The bottom layer lies on the ground; free fall over the run would be g t = 3.9 m/s, at rest is far below.
  CHECK(lowest > 0.5 * r);
  CHECK(lowest < 1.1 * r);
  CHECK(fastest < 0.1);
  // Bullet 3 lets stacks sink at h = 1 ms (4 PGS iterations; its position correction assumes a 1/60 s step):
  // measured on pocl after 400 steps, 0.28 r deepest, the lowest centre at 0.84 r, 0.05 m/s fastest (after 1500
  // steps 0.62 r, 0.69 r, 0.02 m/s). A sphere pushed through another or through the ground is more than r.
  CHECK(pen < 0.5 * r);
}

TEST_CASE("Bullet 3 peer: running out of broad-phase pairs is an error, not a truncation", "[bullet3]") {
  if (!havePeerAndCpuDevice()) return;
  const SceneSpec spec = makePileSpec(200);
  Bullet3PeerSettings s = cpuSettings();
  // Room for the ground's pair with every sphere and little more: once the spheres settle onto each other
  // (within a few steps; they start 0.1% of r apart) the pairs outnumber the capacity.
  s.pairs_per_body = 1;
  Bullet3Peer peer(spec, s);
  try {
    for (int k = 0; k < 100; ++k) peer.step();
    FAIL("100 steps with a pair capacity of one per body did not fail");
  } catch (const Bullet3Error& e) { CHECK(std::string(e.what()).find("ran out of") != std::string::npos); }
}

TEST_CASE("Bullet 3 peer: bad settings are input errors", "[bullet3]") {
  std::string why;
  if (!bullet3PeerBuilt(&why)) {
    WARN("skipping: " << why);
    return;
  }
  const SceneSpec spec = makePileSpec(10);
  Bullet3PeerSettings s = cpuSettings();
  s.length_scale = 0;
  CHECK_THROWS_AS(Bullet3Peer(spec, s), InputError);
  s = cpuSettings();
  s.pairs_per_body = 0;
  CHECK_THROWS_AS(Bullet3Peer(spec, s), InputError);
  CHECK_THROWS_AS(parseOpenClDeviceType("fpga"), InputError);
}
