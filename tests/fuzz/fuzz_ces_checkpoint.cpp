// Fuzz target: the bytes of a CES checkpoint (checkpoint/state.bin) -> dvi::ces::CesMachine::load (machine.cpp)
// into a fresh machine (fuzz_ces_setup.h), then two machine steps: a checkpoint the reader accepts must be one
// the machine can run on. A checkpoint carries a checksum (format DVICES03), so almost every mutation is refused
// by it: each input is loaded as it is and then resealed (resealCesCheckpoint: the checksum recomputed), so that
// the mutations reach the field checks as well. Seeds: corpus/ces_checkpoint/ (written by make_seeds.cpp from a
// short run).
#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>

#include "fuzz_ces_setup.h"
#include "fuzz_support.h"

namespace {

void loadAndStep(const std::string& bytes) {
  fuzz::CesRig rig;
  std::istringstream in(bytes, std::ios::binary);
  rig.machine.load(in);
  try {
    rig.machine.step();
    rig.machine.step();
  } catch (const std::exception& e) {
    fuzz::finding("fuzz_ces_checkpoint", std::string("a restored machine does not step: ") + e.what());
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  fuzz::init();
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  fuzz::run("fuzz_ces_checkpoint", [&] { loadAndStep(bytes); });
  std::string sealed = bytes;
  dvi::ces::resealCesCheckpoint(sealed);
  if (sealed != bytes) fuzz::run("fuzz_ces_checkpoint", [&] { loadAndStep(sealed); });
  return 0;
}
