// Several processes solving one CCP together, each with its own share of the contacts (a domain decomposition:
// chrono_like/mpi/distributed_system.h). What the System, the contact problem and the solver ask of them, on either
// backend; the System holds none unless a distributed driver hands one down (System::setProcessGroup).
//
// Contact ownership: every local body has an owner (a process, or kReplicated for the fixed and kinematic bodies every
// process holds, or kNoOwner for a copy that is out of date) and a key that orders the bodies the same way on every
// process (the global id). contactOwner() picks the process that keeps a contact; the others drop it.
//
// The product N x = D^T M^-1 D x (docs/MODEL.md §4) is a gather over each body's contacts (pass (a)) and a pass over
// the contacts (pass (b)). A body whose contacts lie on several processes gets each process's share of M^-1 D x in
// pass (a). After the contacts are known, each process names the copies of other processes' bodies its contacts touch,
// and its current copies in listedRegion (setTouchedCopies, one collective a step); from then on the exchange list
// holds those copies and the own bodies that other processes hold so, and exchangeCompact (or a backend reading the
// others' shares itself: exchangeTerms) sums their shares over the processes holding them (every one the same sum), so
// pass (b) reads the same velocity change everywhere. Every scalar reduction of the solvers (dot products, norms, step tests)
// is summed over the processes (sum). The iterates then equal one process's up to the order of summation.
#pragma once

#include <cstdint>
#include <vector>

#include "chrono_like/base/hd.h"
#include "chrono_like/solver/jacobian.h"

namespace dvi {

constexpr int32_t kReplicated = -1;  // a fixed or kinematic body: on every process, owned by none
constexpr int32_t kNoOwner = -2;     // a copy not refreshed this step: none of its contacts is kept

// The process that keeps the contact between bodies of owners oa, ob and keys ka, kb: the owner of the dynamic body
// with the smaller key (of the only dynamic one); process 0 for two replicated bodies; kNoOwner where either copy is
// out of date (its owner keeps the contact, with the body where it really is).
DVI_HD int32_t contactOwner(int32_t oa, int32_t ob, int32_t ka, int32_t kb) {
  if (oa == kNoOwner || ob == kNoOwner) return kNoOwner;
  const bool da = oa >= 0, db = ob >= 0;
  if (da && db) return ka < kb ? oa : ob;
  if (da || db) return da ? oa : ob;
  return 0;
}

class ProcessGroup {
 public:
  virtual ~ProcessGroup() = default;
  virtual int rank() const = 0;
  // v[0 .. n) summed over the processes, in place; every process gets the same sums.
  virtual void sum(double* v, int n) const = 0;
  // The largest v over the processes.
  virtual double max(double v) const = 0;
  // Whether any process's `local` is true.
  bool any(bool local) const { return max(local ? 1.0 : 0.0) > 0; }

  // Per local body: its owner (a process, kReplicated or kNoOwner) and its key. bodiesVersion() changes when the
  // local bodies do (a device backend uploads both arrays again); between, takeOwnerChanges() names the bodies whose
  // owner changed since the last call (a device backend copies just those).
  virtual const std::vector<int32_t>& bodyOwners() const = 0;
  virtual const std::vector<int32_t>& bodyKeys() const = 0;
  virtual uint64_t bodiesVersion() const = 0;
  virtual std::vector<int32_t> takeOwnerChanges() = 0;
  bool ownsContact(int32_t body_a, int32_t body_b) const {
    const std::vector<int32_t>& o = bodyOwners();
    const std::vector<int32_t>& k = bodyKeys();
    return contactOwner(o[size_t(body_a)], o[size_t(body_b)], k[size_t(body_a)], k[size_t(body_b)]) == rank();
  }
  bool ownsBody(int32_t body) const { return bodyOwners()[size_t(body)] == rank(); }

  // Collective, once a step after the contacts are filtered: the copies of other processes' bodies (local indices,
  // ascending, owner >= 0 and not this process) that take part in the step's exchange: those this process's contacts
  // touch and the current ones whose centre lies in listedRegion. Sets the exchange list.
  virtual void setTouchedCopies(const std::vector<int32_t>& copies) = 0;
  // Where every current copy joins the exchange, touched or not (false: nowhere). A copy in the exchange comes out of
  // the step with its owner's very state (the same summed velocity change, the same integration), so its owner needs
  // to send it no state after the step (DistributedSystem: this process's box grown by the ghost width).
  virtual bool listedRegion(Vec3& lo, Vec3& hi) const = 0;
  // The bodies (local indices, ascending) whose velocity changes are exchanged this step.
  virtual const std::vector<int32_t>& exchangeBodies() const = 0;
  // Body i takes part in the exchange: pass (a) computes its share even where no local contact touches it.
  virtual bool shared(int32_t body) const = 0;
  // compact[j], the share of exchangeBodies()[j] in, the sum over the processes out (every process the same).
  virtual void exchangeCompact(BodyDelta* compact) const = 0;
  // For a backend that sums the shares itself, reading them from the other processes' memory (the GPU's peer
  // exchange, gpu/gpu_peer_exchange.cu). Collective, once a step after setTouchedCopies: per listed body j its terms
  // [start[j], start[j + 1]) in rank order, each the process (rank) and the position of the body in that process's
  // exchange list (index; this process's own term: j).
  virtual void exchangeTerms(std::vector<int32_t>& start, std::vector<int32_t>& rank, std::vector<int32_t>& index) = 0;
  // Per exchange of that kind: returns once every process this one shares listed bodies with has called it as
  // often (each calls it when its shares are in place); `bytes` (the shares the others read) is counted as sent.
  virtual void awaitNeighbours(int64_t bytes) const = 0;
  // Collective: every process's bytes, by rank.
  virtual std::vector<std::vector<uint8_t>> allgatherBytes(const std::vector<uint8_t>& mine) const = 0;
  virtual int size() const = 0;
  // Every process runs on this host (they can share device memory).
  virtual bool oneHost() const = 0;
  // The same on a full per-body array (delta[i] for every local body i).
  void exchangeDeltas(BodyDelta* delta) const {
    const std::vector<int32_t>& ids = exchangeBodies();
    compact_.resize(ids.size());
    for (size_t j = 0; j < ids.size(); ++j) compact_[j] = delta[ids[j]];
    exchangeCompact(compact_.data());
    for (size_t j = 0; j < ids.size(); ++j) delta[ids[j]] = compact_[j];
  }

 private:
  mutable std::vector<BodyDelta> compact_;
};

}  // namespace dvi
