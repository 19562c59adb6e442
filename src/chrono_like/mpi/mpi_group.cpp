#include "chrono_like/mpi/mpi_group.h"

#include <algorithm>

#include "chrono_like/base/errors.h"
#include "chrono_like/mpi/mpi_collectives.h"

namespace dvi {

namespace {
constexpr int kTagShares = 101, kTagSums = 102;
}

MpiGroup::MpiGroup(MPI_Comm comm) : comm_(comm) {
  MPI_Comm_rank(comm_, &rank_);
  MPI_Comm_size(comm_, &size_);
  copies_of_.resize(size_t(size_));
  touched_by_.resize(size_t(size_));
  out_.resize(size_t(size_));
  in_.resize(size_t(size_));
}

void MpiGroup::sum(double* v, int n) const {
  const double t0 = MPI_Wtime();
  MPI_Allreduce(MPI_IN_PLACE, v, n, MPI_DOUBLE, MPI_SUM, comm_);
  traffic_.reduce_s += MPI_Wtime() - t0;
  ++traffic_.reductions;
}

double MpiGroup::max(double v) const {
  const double t0 = MPI_Wtime();
  const double out = mpiMax(comm_, v);
  traffic_.reduce_s += MPI_Wtime() - t0;
  ++traffic_.reductions;
  return out;
}

void MpiGroup::setBodies(std::vector<int32_t> keys, std::vector<int32_t> owners) {
  if (keys.size() != owners.size() || !std::is_sorted(keys.begin(), keys.end()))
    throw std::logic_error("MpiGroup::setBodies: one owner per key, keys ascending");
  keys_ = std::move(keys);
  owners_ = std::move(owners);
  ++version_;
  changed_.clear();
  list_.clear();
  pos_.assign(keys_.size(), -1);
  for (auto& l : copies_of_) l.clear();
  for (auto& l : touched_by_) l.clear();
}

void MpiGroup::setOwner(int32_t body, int32_t owner) {
  int32_t& o = owners_[size_t(body)];
  if (o == owner) return;
  o = owner;
  changed_.push_back(body);
}

std::vector<int32_t> MpiGroup::takeOwnerChanges() {
  std::vector<int32_t> out;
  out.swap(changed_);
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

void MpiGroup::setTouchedCopies(const std::vector<int32_t>& copies) {
  const double t0 = MPI_Wtime();
  for (int32_t i : list_) pos_[size_t(i)] = -1;
  std::vector<std::vector<int32_t>> out(
      static_cast<size_t>(size_));  // keys, ascending per owner (copies are ascending)
  for (int32_t i : copies) {
    const int32_t q = owners_[size_t(i)];
    if (q < 0 || q == rank_ || q >= size_) throw std::logic_error("MpiGroup::setTouchedCopies: not another's body");
    out[size_t(q)].push_back(keys_[size_t(i)]);
  }
  const std::vector<std::vector<int32_t>> in = mpiExchange(comm_, out, &traffic_.exchange_bytes);
  // The list: the touched copies and the own bodies others touch, ascending.
  list_ = copies;
  std::vector<std::vector<int32_t>> touched(static_cast<size_t>(size_));
  for (int q = 0; q < size_; ++q)
    for (int32_t key : in[size_t(q)]) {
      const auto it = std::lower_bound(keys_.begin(), keys_.end(), key);
      if (it == keys_.end() || *it != key || owners_[size_t(it - keys_.begin())] != rank_)
        throw std::logic_error("MpiGroup::setTouchedCopies: process " + std::to_string(q) + " touches body " +
                               std::to_string(key) + ", which this process does not own");
      touched[size_t(q)].push_back(int32_t(it - keys_.begin()));
      list_.push_back(touched[size_t(q)].back());
    }
  std::sort(list_.begin(), list_.end());
  list_.erase(std::unique(list_.begin(), list_.end()), list_.end());
  for (size_t j = 0; j < list_.size(); ++j) pos_[size_t(list_[j])] = int32_t(j);
  for (int q = 0; q < size_; ++q) {
    copies_of_[size_t(q)].clear();
    touched_by_[size_t(q)].clear();
    for (int32_t i : touched[size_t(q)]) touched_by_[size_t(q)].push_back(pos_[size_t(i)]);
  }
  for (int32_t i : copies) copies_of_[size_t(owners_[size_t(i)])].push_back(pos_[size_t(i)]);
  traffic_.shared_bodies += int64_t(list_.size());
  traffic_.exchange_s += MPI_Wtime() - t0;
}

void MpiGroup::exchangeCompact(BodyDelta* delta) const {
  const double t0 = MPI_Wtime();
  const int bytes = int(sizeof(BodyDelta));
  // Round 1: the copies' shares to their owners.
  requests_.clear();
  for (int q = 0; q < size_; ++q) {
    const auto& from = copies_of_[size_t(q)];
    const auto& to = touched_by_[size_t(q)];
    if (!to.empty()) {
      in_[size_t(q)].resize(to.size());
      requests_.emplace_back();
      MPI_Irecv(in_[size_t(q)].data(), int(to.size()) * bytes, MPI_BYTE, q, kTagShares, comm_, &requests_.back());
    }
    if (!from.empty()) {
      auto& out = out_[size_t(q)];
      out.resize(from.size());
      for (size_t j = 0; j < from.size(); ++j) out[j] = delta[from[j]];
      traffic_.exchange_bytes += int64_t(out.size()) * bytes;
      requests_.emplace_back();
      MPI_Isend(out.data(), int(out.size()) * bytes, MPI_BYTE, q, kTagShares, comm_, &requests_.back());
    }
  }
  MPI_Waitall(int(requests_.size()), requests_.data(), MPI_STATUSES_IGNORE);
  for (int q = 0; q < size_; ++q) {  // in rank order: the same sums on every run
    const auto& to = touched_by_[size_t(q)];
    for (size_t j = 0; j < to.size(); ++j) {
      BodyDelta& d = delta[to[j]];
      d.v = d.v + in_[size_t(q)][j].v;
      d.w = d.w + in_[size_t(q)][j].w;
    }
  }
  // Round 2: the owners' sums back to the processes that sent shares.
  requests_.clear();
  for (int q = 0; q < size_; ++q) {
    const auto& from = copies_of_[size_t(q)];
    const auto& to = touched_by_[size_t(q)];
    if (!from.empty()) {
      in_[size_t(q)].resize(from.size());
      requests_.emplace_back();
      MPI_Irecv(in_[size_t(q)].data(), int(from.size()) * bytes, MPI_BYTE, q, kTagSums, comm_, &requests_.back());
    }
    if (!to.empty()) {
      auto& out = out_[size_t(q)];
      out.resize(to.size());
      for (size_t j = 0; j < to.size(); ++j) out[j] = delta[to[j]];
      traffic_.exchange_bytes += int64_t(out.size()) * bytes;
      requests_.emplace_back();
      MPI_Isend(out.data(), int(out.size()) * bytes, MPI_BYTE, q, kTagSums, comm_, &requests_.back());
    }
  }
  MPI_Waitall(int(requests_.size()), requests_.data(), MPI_STATUSES_IGNORE);
  for (int q = 0; q < size_; ++q) {
    const auto& from = copies_of_[size_t(q)];
    for (size_t j = 0; j < from.size(); ++j) delta[from[j]] = in_[size_t(q)][j];
  }
  traffic_.exchange_s += MPI_Wtime() - t0;
  ++traffic_.exchanges;
}

}  // namespace dvi
