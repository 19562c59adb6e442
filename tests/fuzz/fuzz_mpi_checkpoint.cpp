// Fuzz target: the bytes of a distributed run's checkpoint piece (checkpoint/piece_pR.bin) -> dvi::decodePiece
// (src/chrono_like/checkpoint_piece.cpp, part of the core library: no MPI). A piece carries a checksum (format
// DVIMPI02, DVIMPI01 still read), so each input is decoded as it is and then resealed (the checksum recomputed) to reach the field
// checks. Oracle: a piece the reader accepts encodes back to the very same bytes. Seeds: corpus/mpi_checkpoint/ (a
// piece of `mpirun -np 2 dvisim run scenes/pile.json --steps 60`).
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>

#include "chrono_like/base/checksum.h"
#include "chrono_like/checkpoint_piece.h"
#include "fuzz_support.h"

namespace {

void decodeAndCompare(const std::string& bytes) {
  const dvi::CheckpointPiece p = dvi::decodePiece(bytes, "piece", size_t(1) << 20);
  if (dvi::encodePiece(p) != bytes) fuzz::finding("fuzz_mpi_checkpoint", "an accepted piece does not encode back");
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  fuzz::init();
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  fuzz::run("fuzz_mpi_checkpoint", [&] { decodeAndCompare(bytes); });
  if (bytes.size() >= 16) {  // resealed: the trailing FNV-1a 64 of the bytes before it
    std::string sealed = bytes;
    const uint64_t h = dvi::fnv1a64(sealed.data(), sealed.size() - 8);
    std::memcpy(&sealed[sealed.size() - 8], &h, 8);
    if (sealed != bytes) fuzz::run("fuzz_mpi_checkpoint", [&] { decodeAndCompare(sealed); });
  }
  return 0;
}
