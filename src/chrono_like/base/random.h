// Deterministic random numbers: SplitMix64 (Steele, Lea, Flood, "Fast splittable pseudorandom number generators",
// OOPSLA 2014). The same sequence on every platform and standard library, so scenes, feeds and benchmarks built
// from a seed are reproducible; its one word of state is what a checkpoint stores.
#pragma once

#include <cstdint>

namespace dvi {

struct SplitMix64 {
  uint64_t s = 1;
  uint64_t next() {
    uint64_t z = (s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
  }
  double uniform() { return double(next() >> 11) * (1.0 / 9007199254740992.0); }  // [0, 1)
  double uniform(double a, double b) { return a + (b - a) * uniform(); }
};

}  // namespace dvi
