#include "chrono_like/mpi/mpi_group.h"

namespace dvi {

namespace {
constexpr int kTagShares = 101, kTagSums = 102;
}

MpiGroup::MpiGroup(MPI_Comm comm) : comm_(comm) {
  MPI_Comm_rank(comm_, &rank_);
  MPI_Comm_size(comm_, &size_);
  ghosts_from_.resize(size_t(size_));
  sent_to_.resize(size_t(size_));
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
  double out = v;
  MPI_Allreduce(&v, &out, 1, MPI_DOUBLE, MPI_MAX, comm_);
  traffic_.reduce_s += MPI_Wtime() - t0;
  ++traffic_.reductions;
  return out;
}

void MpiGroup::setBodies(std::vector<int32_t> ids, std::vector<uint8_t> owned, std::vector<uint8_t> dynamic) {
  ids_ = std::move(ids);
  owned_ = std::move(owned);
  dynamic_ = std::move(dynamic);
  shared_.assign(ids_.size(), 0);
  ghosts_from_.assign(size_t(size_), {});
  sent_to_.assign(size_t(size_), {});
}

void MpiGroup::markShared() {
  for (const auto& l : ghosts_from_)
    for (int32_t i : l) shared_[size_t(i)] = 1;
  for (const auto& l : sent_to_)
    for (int32_t i : l) shared_[size_t(i)] = 1;
}

bool MpiGroup::ownsContact(int32_t a, int32_t b) const {
  const bool da = dynamic_[size_t(a)] != 0, db = dynamic_[size_t(b)] != 0;
  if (!da && !db) return rank_ == 0;
  const int32_t pick = da && db ? (ids_[size_t(a)] < ids_[size_t(b)] ? a : b) : (da ? a : b);
  return owned_[size_t(pick)] != 0;
}

void MpiGroup::exchangeDeltas(BodyDelta* delta) const {
  const double t0 = MPI_Wtime();
  const int bytes = int(sizeof(BodyDelta));
  // Round 1: the ghosts' shares to their owners.
  requests_.clear();
  for (int q = 0; q < size_; ++q) {
    const auto& from = ghosts_from_[size_t(q)];
    const auto& to = sent_to_[size_t(q)];
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
    const auto& to = sent_to_[size_t(q)];
    for (size_t j = 0; j < to.size(); ++j) {
      BodyDelta& d = delta[to[j]];
      d.v = d.v + in_[size_t(q)][j].v;
      d.w = d.w + in_[size_t(q)][j].w;
    }
  }
  // Round 2: the owners' sums back to the processes holding the ghosts.
  requests_.clear();
  for (int q = 0; q < size_; ++q) {
    const auto& from = ghosts_from_[size_t(q)];
    const auto& to = sent_to_[size_t(q)];
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
    const auto& from = ghosts_from_[size_t(q)];
    for (size_t j = 0; j < from.size(); ++j) delta[from[j]] = in_[size_t(q)][j];
  }
  traffic_.exchange_s += MPI_Wtime() - t0;
  ++traffic_.exchanges;
}

}  // namespace dvi
