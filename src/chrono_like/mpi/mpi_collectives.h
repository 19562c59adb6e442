// The few MPI collectives the decomposition and its drivers use, typed: a sum or a maximum over a communicator's
// processes, and an all-to-all of plain records.
#pragma once

#include <mpi.h>

#include <algorithm>
#include <cstdint>
#include <vector>

namespace dvi {

inline double mpiReduce(MPI_Comm comm, double v, MPI_Op op) {
  double out = v;
  MPI_Allreduce(&v, &out, 1, MPI_DOUBLE, op, comm);
  return out;
}
inline double mpiSum(MPI_Comm comm, double v) { return mpiReduce(comm, v, MPI_SUM); }
inline int64_t mpiSum(MPI_Comm comm, int64_t v) {
  int64_t out = v;
  MPI_Allreduce(&v, &out, 1, MPI_INT64_T, MPI_SUM, comm);
  return out;
}
inline double mpiMax(MPI_Comm comm, double v) { return mpiReduce(comm, v, MPI_MAX); }
inline double mpiMin(MPI_Comm comm, double v) { return mpiReduce(comm, v, MPI_MIN); }

// Alltoallv of plain records: out[q] to process q; returns what each process sent here, by source. Adds the bytes
// sent to other processes to *sent.
template <class T>
std::vector<std::vector<T>> mpiExchange(MPI_Comm comm, const std::vector<std::vector<T>>& out, int64_t* sent) {
  const int n = int(out.size());
  const size_t un = static_cast<size_t>(n);
  std::vector<int> send_counts(un), recv_counts(un), sdispl(un), rdispl(un);
  int self = 0;
  MPI_Comm_rank(comm, &self);
  for (int q = 0; q < n; ++q) {
    send_counts[size_t(q)] = int(out[size_t(q)].size() * sizeof(T));
    if (q != self) *sent += send_counts[size_t(q)];
  }
  MPI_Alltoall(send_counts.data(), 1, MPI_INT, recv_counts.data(), 1, MPI_INT, comm);
  int stot = 0, rtot = 0;
  for (int q = 0; q < n; ++q) {
    sdispl[size_t(q)] = stot;
    rdispl[size_t(q)] = rtot;
    stot += send_counts[size_t(q)];
    rtot += recv_counts[size_t(q)];
  }
  std::vector<char> sbuf(size_t(stot) + 1), rbuf(size_t(rtot) + 1);
  for (int q = 0; q < n; ++q)
    if (!out[size_t(q)].empty())
      std::copy_n(reinterpret_cast<const char*>(out[size_t(q)].data()), send_counts[size_t(q)],
                  sbuf.data() + sdispl[size_t(q)]);
  MPI_Alltoallv(sbuf.data(), send_counts.data(), sdispl.data(), MPI_BYTE, rbuf.data(), recv_counts.data(),
                rdispl.data(), MPI_BYTE, comm);
  std::vector<std::vector<T>> in(un);
  for (int q = 0; q < n; ++q) {
    in[size_t(q)].resize(size_t(recv_counts[size_t(q)]) / sizeof(T));
    if (recv_counts[size_t(q)] > 0)
      std::copy_n(rbuf.data() + rdispl[size_t(q)], recv_counts[size_t(q)],
                  reinterpret_cast<char*>(in[size_t(q)].data()));
  }
  return in;
}

}  // namespace dvi
