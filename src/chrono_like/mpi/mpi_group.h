// The ProcessGroup (solver/process_group.h) of a domain decomposition over MPI: collectives on a communicator, the
// velocity-change exchange of the shared bodies with the neighbouring processes, and the contact ownership rule.
// DistributedSystem fills its per-step lists.
#pragma once

#include <mpi.h>

#include <cstdint>
#include <vector>

#include "chrono_like/solver/process_group.h"

namespace dvi {

// What the solver's collectives cost on this process since construction: MPI_Wtime seconds and bytes sent.
struct GroupTraffic {
  double exchange_s = 0, reduce_s = 0;  // exchangeDeltas; sum and max
  int64_t exchanges = 0, reductions = 0;
  int64_t exchange_bytes = 0;  // velocity changes sent to the neighbours (both rounds)
};

class MpiGroup final : public ProcessGroup {
 public:
  explicit MpiGroup(MPI_Comm comm);
  void sum(double* v, int n) const override;
  double max(double v) const override;
  bool shared(int32_t body) const override { return shared_[size_t(body)] != 0; }
  // Two rounds with the neighbours: each ghost's share to its owner, which adds them (in rank order) to its own;
  // then the owner's sum back to every process holding the body as a ghost.
  void exchangeDeltas(BodyDelta* delta) const override;
  // The owner of the pair's dynamic body with the smaller global id keeps the contact; a pair of two fixed or
  // kinematic bodies is process 0's.
  bool ownsContact(int32_t body_a, int32_t body_b) const override;

  // The step's local bodies: global id, owned here, dynamic (neither fixed nor kinematic); clears the lists.
  void setBodies(std::vector<int32_t> ids, std::vector<uint8_t> owned, std::vector<uint8_t> dynamic);
  // Per process q: the local indices of the ghosts that q owns, in q's order, and of the owned bodies q holds as
  // ghosts, in the order sent (both processes list a body at the same place).
  std::vector<std::vector<int32_t>>& ghostsFrom() { return ghosts_from_; }
  std::vector<std::vector<int32_t>>& sentTo() { return sent_to_; }
  void markShared();  // shared_ from the two lists (after they are filled)
  const GroupTraffic& traffic() const { return traffic_; }

 private:
  MPI_Comm comm_;
  int rank_ = 0, size_ = 1;
  std::vector<int32_t> ids_;
  std::vector<uint8_t> owned_, dynamic_, shared_;
  std::vector<std::vector<int32_t>> ghosts_from_, sent_to_;
  mutable std::vector<std::vector<BodyDelta>> out_, in_;  // message buffers per process
  mutable std::vector<MPI_Request> requests_;
  mutable GroupTraffic traffic_;
};

}  // namespace dvi
