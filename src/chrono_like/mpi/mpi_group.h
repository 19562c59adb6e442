// The ProcessGroup (solver/process_group.h) of a domain decomposition over MPI: collectives on a communicator, the
// owners and keys of the local bodies, the step's list of shared bodies (from setTouchedCopies) and the velocity-change
// exchange over it with the neighbouring processes. DistributedSystem keeps the owners up to date.
#pragma once

#include <mpi.h>

#include <cstdint>
#include <utility>
#include <vector>

#include "chrono_like/solver/process_group.h"

namespace dvi {

// What the solver's collectives cost on this process since construction: MPI_Wtime seconds and bytes sent.
struct GroupTraffic {
  double exchange_s = 0, reduce_s = 0;  // exchangeCompact (with setTouchedCopies); sum and max
  double touched_s = 0;                 // of exchange_s: setTouchedCopies (once a step, at the end of NarrowPhase)
  int64_t peer_exchanges = 0;           // of exchanges: device to device (awaitNeighbours), the rest staged by MPI
  int64_t exchanges = 0, reductions = 0;
  int64_t exchange_bytes = 0;  // velocity changes sent to the neighbours, and the touched lists
};

class MpiGroup final : public ProcessGroup {
 public:
  explicit MpiGroup(MPI_Comm comm);
  int rank() const override { return rank_; }
  void sum(double* v, int n) const override;
  double max(double v) const override;
  const std::vector<int32_t>& bodyOwners() const override { return owners_; }
  const std::vector<int32_t>& bodyKeys() const override { return keys_; }
  uint64_t bodiesVersion() const override { return version_; }
  std::vector<int32_t> takeOwnerChanges() override;
  // Sends each copy's key to its owner and learns which own bodies the others touch (one all-to-all).
  void setTouchedCopies(const std::vector<int32_t>& copies) override;
  const std::vector<int32_t>& exchangeBodies() const override { return list_; }
  bool shared(int32_t body) const override { return pos_[size_t(body)] >= 0; }
  // One round with the neighbours: each process that holds a listed body sends its share to the others holding it
  // (the owner and the processes whose contacts touch it), and each adds the shares in rank order.
  void exchangeCompact(BodyDelta* compact) const override;
  // One all-to-all of each process's list places of the bodies it holds with the others (pairs_).
  void exchangeTerms(std::vector<int32_t>& start, std::vector<int32_t>& rank, std::vector<int32_t>& index) override;
  // An empty message to and from each neighbour (a process sharing listed bodies).
  void awaitNeighbours(int64_t bytes) const override;
  std::vector<std::vector<uint8_t>> allgatherBytes(const std::vector<uint8_t>& mine) const override;
  int size() const override { return size_; }
  bool listedRegion(Vec3& lo, Vec3& hi) const override {
    lo = region_lo_;
    hi = region_hi_;
    return has_region_;
  }
  void setListedRegion(Vec3 lo, Vec3 hi) {
    region_lo_ = lo;
    region_hi_ = hi;
    has_region_ = true;
  }
  bool oneHost() const override { return one_host_; }

  // The local bodies after the local System is (re)built: keys ascending (the global ids), owners as
  // ProcessGroup::bodyOwners. Clears the exchange list.
  void setBodies(std::vector<int32_t> keys, std::vector<int32_t> owners);
  // Whether process q took part in body `body`'s exchange this step (it holds the body and its contacts or the
  // owner's touch it): then q's copy came out of the step with the owner's very state.
  bool exchangedWith(int32_t body, int q) const;
  void setOwner(int32_t body, int32_t owner);
  const GroupTraffic& traffic() const { return traffic_; }

 private:
  MPI_Comm comm_;
  int rank_ = 0, size_ = 1;
  bool one_host_ = false;  // the shared-memory split of comm_ is comm_ itself
  bool has_region_ = false;
  Vec3 region_lo_{0, 0, 0}, region_hi_{0, 0, 0};
  std::vector<int32_t> keys_, owners_;
  uint64_t version_ = 0;
  std::vector<int32_t> changed_;     // owners changed since the last takeOwnerChanges (may repeat a body)
  std::vector<int32_t> list_, pos_;  // the exchange list; per body its place in it, or -1
  // Per process q: the places in list_ of the bodies both hold this step (keys ascending: both list a body at the
  // same place of their message); per listed body, its sum's terms in rank order (term_start_ CSR): the process and
  // the place in its message, -1 for this process's own share.
  std::vector<std::vector<int32_t>> pairs_;
  std::vector<int32_t> term_start_{0}, term_rank_, term_idx_;
  size_t findKeyFrom(int32_t key, size_t from) const;
  void groupParticipants(const std::vector<std::pair<int32_t, int32_t>>& touch, std::vector<int32_t>& start,
                         std::vector<int32_t>& procs) const;
  void setPairs(const std::vector<int32_t>& start, const std::vector<int32_t>& procs);
  mutable std::vector<std::vector<BodyDelta>> out_, in_;  // message buffers per process
  mutable std::vector<MPI_Request> requests_;
  mutable GroupTraffic traffic_;
};

}  // namespace dvi
