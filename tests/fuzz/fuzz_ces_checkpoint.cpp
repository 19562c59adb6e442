// Fuzz target: the bytes of a CES checkpoint (checkpoint/state.bin) -> dvi::ces::CesMachine::load (machine.cpp)
// into a fresh machine (fuzz_ces_setup.h), then two machine steps: a checkpoint the reader accepts must be one
// the machine can run on. Seeds: corpus/ces_checkpoint/ (written by make_seeds.cpp from a short run).
#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>

#include "fuzz_ces_setup.h"
#include "fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  fuzz::init();
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  return fuzz::run("fuzz_ces_checkpoint", [&] {
    fuzz::CesRig rig;
    std::istringstream in(bytes, std::ios::binary);
    rig.machine.load(in);
    try {
      rig.machine.step();
      rig.machine.step();
    } catch (const std::exception& e) {
      fuzz::finding("fuzz_ces_checkpoint", std::string("a restored machine does not step: ") + e.what());
    }
  });
}
