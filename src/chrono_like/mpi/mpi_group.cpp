#include "chrono_like/mpi/mpi_group.h"

#include <algorithm>

#include "chrono_like/base/errors.h"
#include "chrono_like/mpi/mpi_collectives.h"

namespace dvi {

namespace {
constexpr int kTagShares = 101;
}

MpiGroup::MpiGroup(MPI_Comm comm) : comm_(comm) {
  MPI_Comm_rank(comm_, &rank_);
  MPI_Comm_size(comm_, &size_);
  pairs_.resize(size_t(size_));
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
  for (auto& l : pairs_) l.clear();
  term_start_.assign(1, 0);
  term_rank_.clear();
  term_idx_.clear();
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
  const size_t np = static_cast<size_t>(size_);
  std::vector<std::vector<int32_t>> out(np);  // keys, ascending per owner (copies are ascending)
  for (int32_t i : copies) {
    const int32_t q = owners_[size_t(i)];
    if (q < 0 || q == rank_ || q >= size_) throw std::logic_error("MpiGroup::setTouchedCopies: not another's body");
    out[size_t(q)].push_back(keys_[size_t(i)]);
  }
  const std::vector<std::vector<int32_t>> in = mpiExchange(comm_, out, &traffic_.exchange_bytes);
  // The list: the touched copies and the own bodies others touch, ascending; each one's processes (participants).
  list_ = copies;
  std::vector<std::pair<int32_t, int32_t>> own_touched;  // (own body, a process that touches it)
  for (int q = 0; q < size_; ++q)
    for (int32_t key : in[size_t(q)]) {
      const auto it = std::lower_bound(keys_.begin(), keys_.end(), key);
      if (it == keys_.end() || *it != key || owners_[size_t(it - keys_.begin())] != rank_)
        throw std::logic_error("MpiGroup::setTouchedCopies: process " + std::to_string(q) + " touches body " +
                               std::to_string(key) + ", which this process does not own");
      own_touched.emplace_back(int32_t(it - keys_.begin()), q);
      list_.push_back(own_touched.back().first);
    }
  std::sort(list_.begin(), list_.end());
  list_.erase(std::unique(list_.begin(), list_.end()), list_.end());
  for (size_t j = 0; j < list_.size(); ++j) pos_[size_t(list_[j])] = int32_t(j);
  std::vector<std::vector<int32_t>> part(list_.size());  // per listed body: its processes
  for (size_t j = 0; j < list_.size(); ++j) part[j].push_back(rank_);
  for (int32_t i : copies) part[size_t(pos_[size_t(i)])].push_back(owners_[size_t(i)]);
  for (const auto& [i, q] : own_touched) part[size_t(pos_[size_t(i)])].push_back(q);
  // An owner tells each process touching a body the other processes that touch it (none between two processes).
  std::vector<std::vector<int32_t>> more(np);  // (key, process) pairs
  for (size_t j = 0; j < list_.size(); ++j) {
    if (owners_[size_t(list_[j])] != rank_ || part[j].size() <= 2) continue;
    for (size_t a = 1; a < part[j].size(); ++a)
      for (size_t b = 1; b < part[j].size(); ++b)
        if (a != b)
          more[size_t(part[j][a])].insert(more[size_t(part[j][a])].end(), {keys_[size_t(list_[j])], part[j][b]});
  }
  const std::vector<std::vector<int32_t>> more_in = mpiExchange(comm_, more, &traffic_.exchange_bytes);
  for (const auto& l : more_in)
    for (size_t m = 0; m + 1 < l.size(); m += 2) {
      const auto it = std::lower_bound(keys_.begin(), keys_.end(), l[m]);
      part[size_t(pos_[size_t(it - keys_.begin())])].push_back(l[m + 1]);
    }
  setPairs(part);
  traffic_.exchange_s += MPI_Wtime() - t0;
  traffic_.touched_s += MPI_Wtime() - t0;
}

// From each listed body's processes: per other process q, the listed bodies both hold (ascending key: q lists them
// in the same order), and per body the terms of its sum in rank order (this process's own share: index -1).
void MpiGroup::setPairs(std::vector<std::vector<int32_t>>& part) {
  for (auto& l : pairs_) l.clear();
  term_start_.assign(1, 0);
  term_rank_.clear();
  term_idx_.clear();
  for (size_t j = 0; j < list_.size(); ++j) {
    std::vector<int32_t>& p = part[j];
    std::sort(p.begin(), p.end());
    p.erase(std::unique(p.begin(), p.end()), p.end());
    for (int32_t q : p) {
      term_rank_.push_back(q);
      if (q == rank_) {
        term_idx_.push_back(-1);
        continue;
      }
      term_idx_.push_back(int32_t(pairs_[size_t(q)].size()));
      pairs_[size_t(q)].push_back(int32_t(j));
    }
    term_start_.push_back(int32_t(term_rank_.size()));
  }
}

bool MpiGroup::exchangedWith(int32_t body, int q) const {
  const int32_t j = pos_[size_t(body)];
  if (j < 0) return false;
  for (int32_t t = term_start_[size_t(j)]; t < term_start_[size_t(j) + 1]; ++t)
    if (term_rank_[size_t(t)] == q) return true;
  return false;
}

void MpiGroup::exchangeCompact(BodyDelta* delta) const {
  const double t0 = MPI_Wtime();
  const int bytes = int(sizeof(BodyDelta));
  // One round: every process sends its shares of the bodies it holds with each neighbour to that neighbour.
  requests_.clear();
  for (int q = 0; q < size_; ++q) {
    const auto& pl = pairs_[size_t(q)];
    if (pl.empty()) continue;
    in_[size_t(q)].resize(pl.size());
    requests_.emplace_back();
    MPI_Irecv(in_[size_t(q)].data(), int(pl.size()) * bytes, MPI_BYTE, q, kTagShares, comm_, &requests_.back());
    auto& out = out_[size_t(q)];
    out.resize(pl.size());
    for (size_t m = 0; m < pl.size(); ++m) out[m] = delta[pl[m]];
    traffic_.exchange_bytes += int64_t(out.size()) * bytes;
    requests_.emplace_back();
    MPI_Isend(out.data(), int(out.size()) * bytes, MPI_BYTE, q, kTagShares, comm_, &requests_.back());
  }
  MPI_Waitall(int(requests_.size()), requests_.data(), MPI_STATUSES_IGNORE);
  // Each body's shares summed in rank order: the same sum on every process that holds it.
  for (size_t j = 0; j < list_.size(); ++j) {
    BodyDelta sum{{0, 0, 0}, {0, 0, 0}};
    for (int32_t t = term_start_[j]; t < term_start_[j + 1]; ++t) {
      const BodyDelta& s =
          term_idx_[size_t(t)] < 0 ? delta[j] : in_[size_t(term_rank_[size_t(t)])][size_t(term_idx_[size_t(t)])];
      sum.v = sum.v + s.v;
      sum.w = sum.w + s.w;
    }
    delta[j] = sum;
  }
  traffic_.exchange_s += MPI_Wtime() - t0;
  ++traffic_.exchanges;
}

}  // namespace dvi
