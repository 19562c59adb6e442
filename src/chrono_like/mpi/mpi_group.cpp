#include "chrono_like/mpi/mpi_group.h"

#include <algorithm>
#include <stdexcept>
#include <string>

#include "chrono_like/base/errors.h"
#include "chrono_like/mpi/mpi_collectives.h"

namespace dvi {

namespace {
constexpr int kTagShares = 101, kTagReady = 102;
}

MpiGroup::MpiGroup(MPI_Comm comm) : comm_(comm) {
  MPI_Comm_rank(comm_, &rank_);
  MPI_Comm_size(comm_, &size_);
  MPI_Comm node = MPI_COMM_NULL;
  MPI_Comm_split_type(comm_, MPI_COMM_TYPE_SHARED, rank_, MPI_INFO_NULL, &node);
  int node_size = 0;
  MPI_Comm_size(node, &node_size);
  MPI_Comm_free(&node);
  one_host_ = node_size == size_;
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
  // The list: the touched copies and the own bodies others touch, ascending; each one's processes (participants) as
  // (body, process) pairs, then grouped per listed body (flat arrays: a vector per body cost ~10 ms a step at 10
  // million bodies a process).
  std::vector<std::pair<int32_t, int32_t>> touch;  // (local body, process)
  touch.reserve(copies.size() + copies.size());
  for (int32_t i : copies) touch.emplace_back(i, owners_[size_t(i)]);
  list_ = copies;
  for (int q = 0; q < size_; ++q) {  // each process's keys ascending: one ascending run of own bodies per process
    const size_t run = list_.size();
    size_t from = 0;
    for (int32_t key : in[size_t(q)]) {
      from = findKeyFrom(key, from);
      if (from == keys_.size() || keys_[from] != key || owners_[from] != rank_)
        throw std::logic_error("MpiGroup::setTouchedCopies: process " + std::to_string(q) + " touches body " +
                               std::to_string(key) + ", which this process does not own");
      touch.emplace_back(int32_t(from), q);
      list_.push_back(int32_t(from));
    }
    std::inplace_merge(list_.begin(), list_.begin() + std::ptrdiff_t(run), list_.end());  // no sort of the whole
  }
  list_.erase(std::unique(list_.begin(), list_.end()), list_.end());
  for (size_t j = 0; j < list_.size(); ++j) pos_[size_t(list_[j])] = int32_t(j);
  for (auto& [i, q] : touch) i = pos_[size_t(i)];  // (listed place, process) from here on
  std::vector<int32_t> start, procs;
  groupParticipants(touch, start, procs);
  // An owner tells each process touching a body the other processes that touch it (none between two processes).
  std::vector<std::vector<int32_t>> more(np);  // (key, process) pairs
  for (size_t j = 0; j < list_.size(); ++j) {
    if (owners_[size_t(list_[j])] != rank_ || start[j + 1] - start[j] <= 2) continue;
    for (int32_t a = start[j]; a < start[j + 1]; ++a)
      for (int32_t b = start[j]; b < start[j + 1]; ++b)
        if (a != b && procs[size_t(a)] != rank_ && procs[size_t(b)] != rank_)
          more[size_t(procs[size_t(a)])].insert(more[size_t(procs[size_t(a)])].end(),
                                                {keys_[size_t(list_[j])], procs[size_t(b)]});
  }
  const std::vector<std::vector<int32_t>> more_in = mpiExchange(comm_, more, &traffic_.exchange_bytes);
  bool added = false;
  for (const auto& l : more_in)
    for (size_t m = 0; m + 1 < l.size(); m += 2) {
      const auto it = std::lower_bound(keys_.begin(), keys_.end(), l[m]);
      touch.emplace_back(pos_[size_t(it - keys_.begin())], l[m + 1]);
      added = true;
    }
  if (added) groupParticipants(touch, start, procs);
  setPairs(start, procs);
  traffic_.exchange_s += MPI_Wtime() - t0;
  traffic_.touched_s += MPI_Wtime() - t0;
}

// The first place at or after `from` whose key is not below `key` (keys_ ascending): a galloping search, as the keys
// looked up one after another are close (a binary search over all bodies each cost ~5 ms a step at 10 million).
size_t MpiGroup::findKeyFrom(int32_t key, size_t from) const {
  const size_t n = keys_.size();
  size_t step = 1, lo = from, hi = from;
  while (hi < n && keys_[hi] < key) {
    lo = hi + 1;
    hi = from + step;
    step *= 2;
  }
  const auto end = keys_.begin() + std::ptrdiff_t(std::min(hi, n));
  return size_t(std::lower_bound(keys_.begin() + std::ptrdiff_t(std::min(lo, n)), end, key) - keys_.begin());
}

// Per listed place j, its processes in rank order without repeats (this one among them): procs[start[j] ..
// start[j + 1]), from the (place, process) pairs (a counting sort by place, then each short run sorted).
void MpiGroup::groupParticipants(const std::vector<std::pair<int32_t, int32_t>>& touch, std::vector<int32_t>& start,
                                 std::vector<int32_t>& procs) const {
  const size_t n = list_.size();
  start.assign(n + 1, 0);
  for (size_t j = 0; j < n; ++j) start[j + 1] = 1;  // this process
  for (const auto& [j, q] : touch) ++start[size_t(j) + 1];
  for (size_t j = 0; j < n; ++j) start[j + 1] += start[j];
  procs.assign(size_t(start[n]), 0);
  std::vector<int32_t> fill(start.begin(), start.end() - 1);
  for (size_t j = 0; j < n; ++j) procs[size_t(fill[j]++)] = rank_;
  for (const auto& [j, q] : touch) procs[size_t(fill[size_t(j)]++)] = q;
  int32_t w = 0;  // compacted in place
  for (size_t j = 0; j < n; ++j) {
    const auto first = procs.begin() + start[j], last = procs.begin() + start[j + 1];
    std::sort(first, last);
    const int32_t kept = int32_t(std::unique(first, last) - first);
    start[j] = w;
    for (int32_t k = 0; k < kept; ++k) procs[size_t(w++)] = *(first + k);
  }
  start[n] = w;
  procs.resize(size_t(w));
}

// From each listed body's processes: per other process q, the listed bodies both hold (ascending key: q lists them
// in the same order), and per body the terms of its sum in rank order (this process's own share: index -1).
void MpiGroup::setPairs(const std::vector<int32_t>& start, const std::vector<int32_t>& procs) {
  for (auto& l : pairs_) l.clear();
  term_start_ = start;
  term_rank_ = procs;
  term_idx_.resize(procs.size());
  for (size_t j = 0; j + 1 < start.size(); ++j)
    for (int32_t t = start[j]; t < start[j + 1]; ++t) {
      const int32_t q = procs[size_t(t)];
      if (q == rank_) {
        term_idx_[size_t(t)] = -1;
        continue;
      }
      term_idx_[size_t(t)] = int32_t(pairs_[size_t(q)].size());
      pairs_[size_t(q)].push_back(int32_t(j));
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

void MpiGroup::exchangeTerms(std::vector<int32_t>& start, std::vector<int32_t>& rank, std::vector<int32_t>& index) {
  const double t0 = MPI_Wtime();
  const std::vector<std::vector<int32_t>> places = mpiExchange(comm_, pairs_, &traffic_.exchange_bytes);
  start = term_start_;
  rank = term_rank_;
  index.resize(term_rank_.size());
  for (size_t j = 0; j + 1 < term_start_.size(); ++j)
    for (int32_t t = term_start_[j]; t < term_start_[j + 1]; ++t) {
      const int32_t m = term_idx_[size_t(t)];
      const auto& from = places[size_t(term_rank_[size_t(t)])];
      if (m >= 0 && size_t(m) >= from.size())
        throw std::logic_error("MpiGroup::exchangeTerms: process " + std::to_string(term_rank_[size_t(t)]) +
                               " lists fewer shared bodies than this one");
      index[size_t(t)] = m < 0 ? int32_t(j) : from[size_t(m)];
    }
  traffic_.exchange_s += MPI_Wtime() - t0;
  traffic_.touched_s += MPI_Wtime() - t0;
}

void MpiGroup::awaitNeighbours(int64_t bytes) const {
  const double t0 = MPI_Wtime();
  requests_.clear();
  for (int q = 0; q < size_; ++q) {
    if (pairs_[size_t(q)].empty()) continue;
    requests_.emplace_back();
    MPI_Irecv(nullptr, 0, MPI_BYTE, q, kTagReady, comm_, &requests_.back());
    requests_.emplace_back();
    MPI_Isend(nullptr, 0, MPI_BYTE, q, kTagReady, comm_, &requests_.back());
  }
  MPI_Waitall(int(requests_.size()), requests_.data(), MPI_STATUSES_IGNORE);
  traffic_.exchange_bytes += bytes;
  traffic_.exchange_s += MPI_Wtime() - t0;
  ++traffic_.exchanges;
  ++traffic_.peer_exchanges;
}

std::vector<std::vector<uint8_t>> MpiGroup::allgatherBytes(const std::vector<uint8_t>& mine) const {
  const size_t np = static_cast<size_t>(size_);
  std::vector<int> counts(np), displ(np);
  int n = int(mine.size());
  MPI_Allgather(&n, 1, MPI_INT, counts.data(), 1, MPI_INT, comm_);
  int total = 0;
  for (size_t q = 0; q < np; ++q) {
    displ[q] = total;
    total += counts[q];
  }
  std::vector<uint8_t> all(size_t(total) + 1);
  MPI_Allgatherv(mine.data(), n, MPI_BYTE, all.data(), counts.data(), displ.data(), MPI_BYTE, comm_);
  std::vector<std::vector<uint8_t>> out(np);
  for (size_t q = 0; q < np; ++q) out[q].assign(all.begin() + displ[q], all.begin() + displ[q] + counts[q]);
  return out;
}

}  // namespace dvi
