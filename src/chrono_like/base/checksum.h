// FNV-1a, 64 bits (Fowler, Noll, Vo; the parameters of http://www.isthe.com/chongo/tech/comp/fnv/): the checksum
// of the CES checkpoints (src/ces/machine.cpp). Not cryptographic: it catches an edited or damaged file (every
// single-byte change changes it), not a forger. hash = offset basis; for each byte: hash ^= byte, hash *= prime.
#pragma once

#include <cstddef>
#include <cstdint>

namespace dvi {

constexpr uint64_t kFnv64Offset = 14695981039346656037ull;
constexpr uint64_t kFnv64Prime = 1099511628211ull;

// FNV-1a 64 of n bytes; pass the result as `h` to continue over more bytes.
inline uint64_t fnv1a64(const void* data, size_t n, uint64_t h = kFnv64Offset) {
  const unsigned char* p = static_cast<const unsigned char*>(data);
  for (size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= kFnv64Prime;
  }
  return h;
}

}  // namespace dvi
