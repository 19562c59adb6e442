// Loops that run on an OpenMP team only where one is worth it.
#pragma once

#include <omp.h>

namespace dvi {

// f(i) for i in [0, n): on an OpenMP team of `threads` (schedule static) when threads > 1, else as a plain loop
// that enters no OpenMP region. libgomp's GOMP_parallel costs ~0.4 us even under `if (false)` or num_threads(1) (it
// allocates a team of one and wakes its barrier with a futex call); a tiny scene's step crossed ~30 such regions,
// most of its time. The results do not depend on the path (each i is independent).
template <class I, class F>
inline void parallelFor(I n, int threads, F&& f) {
  if (threads > 1 && n > 1) {
#pragma omp parallel for schedule(static) num_threads(threads)
    for (I i = 0; i < n; ++i) f(i);
  } else {
    for (I i = 0; i < n; ++i) f(i);
  }
}

// The sum of f(i) (an integer: counts, or flags summed and tested > 0) over [0, n), as parallelFor.
template <class I, class F>
inline long long parallelSum(I n, int threads, F&& f) {
  long long s = 0;
  if (threads > 1 && n > 1) {
#pragma omp parallel for schedule(static) num_threads(threads) reduction(+ : s)
    for (I i = 0; i < n; ++i) s += f(i);
  } else {
    for (I i = 0; i < n; ++i) s += f(i);
  }
  return s;
}

// f(i, acc) over [0, n) with a per-thread accumulator (init at start), the accumulators merged by merge(total, acc);
// for reductions whose merge does not depend on the order (max, min, integer sums and flags).
template <class I, class T, class F, class M>
inline T parallelReduce(I n, int threads, T init, F&& f, M&& merge) {
  if (threads > 1 && n > 1) {
    T total = init;
#pragma omp parallel num_threads(threads)
    {
      T acc = init;
#pragma omp for schedule(static) nowait
      for (I i = 0; i < n; ++i) f(i, acc);
#pragma omp critical(dvi_parallel_reduce)
      merge(total, acc);
    }
    return total;
  }
  T acc = init;
  for (I i = 0; i < n; ++i) f(i, acc);
  return acc;
}

// The team an unqualified `omp parallel` would get (the System sets it with omp_set_num_threads).
inline int ompTeam() { return omp_get_max_threads(); }

}  // namespace dvi
