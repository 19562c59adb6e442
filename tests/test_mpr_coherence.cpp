// MPR's temporal coherence (CollisionSettings::mpr_coherence; mpr.h: mprBeginOverlap): last step's normal of a pair
// found by binary search over the sorted contact keys (contact.h: lastPairNormal), and a run resumed from the
// contacts' impulses with their normals (System::setWarmStart; the checkpoint piece DVIMPI02) stepping bitwise as the
// run that wrote them, on a pile whose flat plates rest deep in ellipsoids (the pairs coherence acts on). The
// agreement of the coherent contacts with the full search is checked on the CES feed (test_ces_narrow_work.cpp).
#include <catch2/catch.hpp>

#include <cstdint>
#include <vector>

#include "chrono_like/checkpoint_piece.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/system.h"

using namespace dvi;

namespace {
bool same(const Vec3& a, const Vec3& b) { return a.x == b.x && a.y == b.y && a.z == b.z; }
}  // namespace

TEST_CASE("lastPairNormal: a pair's first contact by binary search, oriented as the pair is collided",
          "[narrowphase][coherence]") {
  const std::vector<uint64_t> keys{contactKey(1, 2, 0), contactKey(1, 2, 3), contactKey(1, 5, 1), contactKey(3, 4, 2),
                                   contactKey(7, 9, 0)};
  const std::vector<Vec3> normals{{0, 1, 0}, {0, 0.8, 0.6}, {1, 0, 0}, {0, 0, 1}, {0.6, 0, 0.8}};
  const LastNormals last{keys.data(), normals.data(), int64_t(keys.size())};
  Vec3 n{9, 9, 9};
  REQUIRE(lastPairNormal(PairHistory{last, 1, 2, real(1)}, n));
  CHECK(same(n, Vec3{0, 1, 0}));  // the pair's lowest feature
  REQUIRE(lastPairNormal(PairHistory{last, 3, 4, real(-1)}, n));
  CHECK(same(n, Vec3{0, 0, -1}));  // collided in the opposite order: negated
  REQUIRE(lastPairNormal(PairHistory{last, 7, 9, real(1)}, n));
  CHECK(same(n, Vec3{0.6, 0, 0.8}));                                 // the last key
  CHECK_FALSE(lastPairNormal(PairHistory{last, 1, 3, real(1)}, n));  // between two pairs' keys
  CHECK_FALSE(lastPairNormal(PairHistory{last, 2, 1, real(1)}, n));  // the reversed pair is another key
  CHECK_FALSE(lastPairNormal(PairHistory{last, 0, 1, real(1)}, n));  // before the first key
  CHECK_FALSE(lastPairNormal(PairHistory{last, 8, 1, real(1)}, n));  // after the last
  CHECK_FALSE(lastPairNormal(PairHistory{LastNormals{}, 1, 2, real(1)}, n));
}

namespace {

// Flat plates (1 mm thick) laid on fixed ellipsoids, each pressed 0.1 mm into its ellipsoid (10% of its thickness,
// five times MPR's deep threshold), a second plate on top of the first: the deep pairs recover slowly (at most
// recovery_rel x their size per second), so they stay deep for the steps below.
void buildPlates(System& sys) {
  for (int i = 0; i < 4; ++i) {
    const real x = real(0.05) * real(i);
    BodyDesc e;
    e.pos = Vec3{x, 0, 0};
    e.mass = 0;
    e.flags = kBodyFixed;
    e.shapes.push_back(makeEllipsoid(Vec3{0.02, 0.01, 0.015}));
    sys.addBody(e);
    for (int k = 0; k < 2; ++k) {
      BodyDesc p;
      p.pos = Vec3{x + real(0.002) * real(i), real(0.01 + 0.0004 + 0.0009 * k), real(0.001) * real(k)};
      p.rot = Quat{real(0.9998), real(0.02) * real(i % 2), 0, real(0.01)};
      p.rot = normalized(p.rot);
      p.mass = real(0.001);
      p.inertia = Vec3{1e-8, 2e-8, 1e-8};
      p.shapes.push_back(makeBox(Vec3{0.01, 0.0005, 0.008}));
      sys.addBody(p);
    }
  }
}

SystemConfig platesConfig() {
  SystemConfig c;
  c.step.dt = real(1e-3);
  c.threads = 1;
  return c;
}

}  // namespace

TEST_CASE("MPR coherence: a run resumed from impulses with normals steps bitwise as the run that wrote them",
          "[narrowphase][coherence][checkpoint]") {
  System whole(platesConfig()), first(platesConfig());
  buildPlates(whole);
  buildPlates(first);
  whole.advance(20);
  first.advance(10);
  CheckpointPiece piece;
  std::vector<int32_t> all;
  const BodyArrays& b = first.bodies();
  for (size_t i = 0; i < b.count(); ++i) {
    all.push_back(int32_t(i));
    piece.ids.push_back(int32_t(i));
    piece.states.push_back(MotionState{b.pos[i], b.rot[i], b.vel[i], b.omega[i]});
  }
  piece.impulses = first.contactImpulsesOf(all);
  REQUIRE(piece.impulses.size() >= 8);
  const CheckpointPiece read = decodePiece(encodePiece(piece), "piece", b.count());
  REQUIRE(read.format == 2);
  REQUIRE(read.impulses.size() == piece.impulses.size());

  auto resume = [&](bool with_normals) {
    System s(platesConfig());
    buildPlates(s);
    BodyArrays& sb = s.mutableBodies();
    for (size_t k = 0; k < read.ids.size(); ++k) {
      const MotionState& m = read.states[k];
      const size_t i = size_t(read.ids[k]);
      sb.pos[i] = m.pos, sb.rot[i] = m.rot, sb.vel[i] = m.vel, sb.omega[i] = m.omega;
    }
    std::vector<uint64_t> keys;
    std::vector<real> gamma;
    std::vector<Vec3> normals;
    for (const ContactImpulse& c : read.impulses) {
      keys.push_back(c.key);
      gamma.insert(gamma.end(), c.gamma, c.gamma + 3);
      if (with_normals) normals.push_back(c.normal);
    }
    s.setWarmStart(keys, gamma, normals);
    s.setClock(first.time(), first.stepCount());
    s.advance(10);
    return s.stateHash();
  };
  CHECK(resume(true) == whole.stateHash());
  // Without the normals the resumed run's first narrow phase tests the deep pairs' candidates again: here that
  // changes the plates' contacts, which is why the checkpoint carries them.
  INFO("the scene must have deep pairs that keep last step's face");
  CHECK(resume(false) != whole.stateHash());
}

TEST_CASE("MPR coherence: a DVIMPI01 piece (no normals) is still read and encodes back as it was",
          "[narrowphase][coherence][checkpoint]") {
  CheckpointPiece p;
  p.format = 1;
  p.ids = {0};
  p.states = {MotionState{Vec3{0, 1, 0}, Quat{1, 0, 0, 0}, Vec3{0, 0, 0}, Vec3{0, 0, 0}}};
  p.impulses = {ContactImpulse{contactKey(0, 1, 0), 0, 1, {real(0.5), 0, 0}, Vec3{0, 1, 0}}};
  const std::string bytes = encodePiece(p);
  REQUIRE(bytes.compare(0, 8, kMpiCheckpointMagicV1, 8) == 0);
  const CheckpointPiece r = decodePiece(bytes, "piece", 2);
  CHECK(r.format == 1);
  REQUIRE(r.impulses.size() == 1);
  CHECK(same(r.impulses[0].normal, Vec3{0, 0, 0}));  // never taken for last step's normal (mprBeginOverlap)
  CHECK(encodePiece(r) == bytes);
  p.format = 2;
  const CheckpointPiece r2 = decodePiece(encodePiece(p), "piece", 2);
  CHECK(same(r2.impulses[0].normal, Vec3{0, 1, 0}));
}
