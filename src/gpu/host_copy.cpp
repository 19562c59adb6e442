#include "gpu/host_copy.h"

#include <omp.h>

#include <cstdint>
#include <cstring>
#include <vector>

namespace dvi {

void copyInParallel(const HostCopy* parts, int n) {
  constexpr size_t kChunk = size_t(1) << 20;
  std::vector<HostCopy> chunks;
  for (int k = 0; k < n; ++k)
    for (size_t at = 0; at < parts[k].bytes; at += kChunk) {
      const size_t len = parts[k].bytes - at < kChunk ? parts[k].bytes - at : kChunk;
      chunks.push_back({static_cast<char*>(parts[k].dst) + at, static_cast<const char*>(parts[k].src) + at, len});
    }
  const int64_t nc = int64_t(chunks.size());
#pragma omp parallel for schedule(dynamic, 1) if (nc > 1)
  for (int64_t i = 0; i < nc; ++i) std::memcpy(chunks[size_t(i)].dst, chunks[size_t(i)].src, chunks[size_t(i)].bytes);
}

}  // namespace dvi
