// The Bullet 3 peer where this build has none (bench/scaling/CMakeLists.txt says why, in DVISIM_BULLET3_MISSING):
// every entry point reports that, so the benchmark writes "not run" rows and the tests skip.
#include "bullet3_peer.h"

namespace dvi::bench {

namespace {
const char* const kMissing = "this build has no Bullet 3 OpenCL peer: " DVISIM_BULLET3_MISSING;
}

bool bullet3PeerBuilt(std::string* why) {
  if (why) *why = kMissing;
  return false;
}

bool findOpenClDevice(OpenClDeviceType, std::string* what) {
  if (what) *what = kMissing;
  return false;
}

struct Bullet3Peer::Impl {};

Bullet3Peer::Bullet3Peer(const SceneSpec&, const Bullet3PeerSettings&) { throw Bullet3Error(kMissing); }
Bullet3Peer::~Bullet3Peer() = default;
void Bullet3Peer::step() { throw Bullet3Error(kMissing); }
const Bullet3StepStats& Bullet3Peer::lastStats() const { throw Bullet3Error(kMissing); }
void Bullet3Peer::readBodies(std::vector<Vec3>&, std::vector<Quat>&, std::vector<Vec3>&) const {
  throw Bullet3Error(kMissing);
}
size_t Bullet3Peer::bodyCount() const { return 0; }
std::string Bullet3Peer::deviceName() const { return ""; }
std::string Bullet3Peer::description() const { return kMissing; }

}  // namespace dvi::bench
