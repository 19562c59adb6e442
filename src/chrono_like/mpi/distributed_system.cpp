#include "chrono_like/mpi/distributed_system.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "chrono_like/base/shape.h"
#include "chrono_like/collision/contact.h"

namespace dvi {

namespace {

// Alltoallv of plain records: out[q] to process q; returns what each process sent here, by source. Adds the bytes
// sent to other processes to *sent.
template <class T>
std::vector<std::vector<T>> exchangeAll(MPI_Comm comm, const std::vector<std::vector<T>>& out, int64_t* sent) {
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
  std::vector<char> sbuf, rbuf;
  int stot = 0, rtot = 0;
  for (int q = 0; q < n; ++q) {
    sdispl[size_t(q)] = stot;
    rdispl[size_t(q)] = rtot;
    stot += send_counts[size_t(q)];
    rtot += recv_counts[size_t(q)];
  }
  sbuf.resize(size_t(stot) + 1);
  rbuf.resize(size_t(rtot) + 1);
  for (int q = 0; q < n; ++q)
    if (!out[size_t(q)].empty())
      std::copy_n(reinterpret_cast<const char*>(out[size_t(q)].data()), send_counts[size_t(q)],
                  sbuf.data() + sdispl[size_t(q)]);
  MPI_Alltoallv(sbuf.data(), send_counts.data(), sdispl.data(), MPI_BYTE, rbuf.data(), recv_counts.data(),
                rdispl.data(), MPI_BYTE, comm);
  std::vector<std::vector<T>> in(static_cast<size_t>(n));
  for (int q = 0; q < n; ++q) {
    in[size_t(q)].resize(size_t(recv_counts[size_t(q)]) / sizeof(T));
    if (recv_counts[size_t(q)] > 0)
      std::copy_n(rbuf.data() + rdispl[size_t(q)], recv_counts[size_t(q)],
                  reinterpret_cast<char*>(in[size_t(q)].data()));
  }
  return in;
}

// Bounding radius of a body about its centre: the farthest reach of its shapes.
real bodyRadius(const BodyDesc& d) {
  real r = 0;
  for (const ShapeDesc& sd : d.shapes) {
    Shape s = sd.shape;
    s.hull_start = 0;
    s.hull_count = int32_t(sd.hull.size());
    r = std::max(r, length(s.local.p) + boundingRadius(s, sd.hull.data()));
  }
  return r;
}

}  // namespace

DistributedSystem::DistributedSystem(MPI_Comm comm, SystemConfig config, DecompositionSettings settings)
    : config_(config), settings_(settings) {
  if (config_.solver.type == SolverType::GaussSeidel)
    throw InputError(
        "solver gs: Gauss-Seidel is sequential and does not run over several processes (MPI); use apgd, "
        "jacobi or bb");
  if (config_.collision.backend != CollisionBackend::Native)
    throw InputError("collision backend 'bullet': not available over several processes (MPI)");
  if (!(settings_.rebalance_ratio > 1) || !std::isfinite(settings_.rebalance_ratio))
    throw InputError("rebalance ratio must be a finite number > 1");
  if (!(settings_.ghost_safety >= 1) || !std::isfinite(settings_.ghost_safety))
    throw InputError("ghost safety factor must be a finite number >= 1");
  System probe(config_);  // the configuration's own checks (dt, iterations)
  MPI_Comm_dup(comm, &comm_);
  MPI_Comm_rank(comm_, &rank_);
  MPI_Comm_size(comm_, &size_);
  group_ = std::make_unique<MpiGroup>(comm_);
  log_.sent.assign(size_t(size_), 0);
  log_.received.assign(size_t(size_), 0);
}

DistributedSystem::~DistributedSystem() {
  sys_.reset();
  group_.reset();
  int finalized = 0;
  MPI_Finalized(&finalized);
  if (!finalized && comm_ != MPI_COMM_NULL) MPI_Comm_free(&comm_);
}

int DistributedSystem::addBody(const BodyDesc& d) {
  const int id = int(descs_.size());
  if (started_) throw InputError("body " + std::to_string(id) + ": bodies are added before the first step (MPI)");
  System::validateBody(d, id);  // System::addBody's checks, with the same messages
  const bool immovable = (d.flags & (kBodyFixed | kBodyKinematic)) != 0;
  if (d.rolling_friction > 0 || d.spinning_friction > 0)
    throw InputError("body " + std::to_string(id) +
                     ": rolling or spinning friction does not run over several processes (MPI)");
  for (const ShapeDesc& s : d.shapes)
    if (!immovable && s.shape.type == ShapeType::Plane)
      throw InputError("body " + std::to_string(id) + ": a dynamic plane has no owner (MPI)");
  shape_start_.push_back(descs_.empty() ? 0 : shape_start_.back() + int32_t(descs_.back().shapes.size()));
  descs_.push_back(d);
  replicated_.push_back(immovable ? 1 : 0);
  radius_.push_back(bodyRadius(d));
  (immovable ? fixed_ : dynamic_).push_back(id);
  return id;
}

// The first step's decomposition: every process bisects the same initial positions.
void DistributedSystem::start() {
  const size_t n = descs_.size();
  state_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    const BodyDesc& d = descs_[i];
    const bool fixed = (d.flags & kBodyFixed) != 0;
    state_[i] = MotionState{d.pos, normalized(d.rot), fixed ? Vec3{0, 0, 0} : d.vel, fixed ? Vec3{0, 0, 0} : d.omega};
  }
  std::vector<Vec3> points;
  for (int32_t id : dynamic_) points.push_back(state_[size_t(id)].pos);
  tree_ = Bisection::build(points, size_);
  for (int32_t id : dynamic_)
    if (tree_.owner(state_[size_t(id)].pos) == rank_) owned_.push_back(id);
  local_of_.assign(n, -1);
  started_ = true;
}

void DistributedSystem::step() {
  using Clock = std::chrono::steady_clock;
  auto since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
  if (!started_) start();
  std::vector<std::vector<Record>> ghosts;
  auto t = Clock::now();
  exchangeGhosts(ghosts);
  prof_.ghosts_s += since(t);
  t = Clock::now();
  buildLocal(ghosts);
  setLocalWarmStart();
  prof_.build_s += since(t);
  t = Clock::now();
  sys_->step();
  prof_.step_s += since(t);
  for (int k = 0; k < kStageCount; ++k) prof_.stages_s[size_t(k)] += sys_->lastStats().stage_seconds[size_t(k)];
  t = Clock::now();
  readBack();
  prof_.readback_s += since(t);
  t = Clock::now();
  migrate();
  rebalanceIfNeeded();
  prof_.migrate_s += since(t);
  time_ += config_.step.dt;
  ++steps_;
}

DecompositionProfile DistributedSystem::profile() const {
  DecompositionProfile p = prof_;
  p.group = group_->traffic();
  return p;
}

// The ghost width (DecompositionSettings::ghost_safety): two bodies farther apart than this make no contact in
// this step. A pair is collided with at most max(envelope, sweep_a + sweep_b) (narrowphase.h: pairEnvelope), the sweep
// h (|v_free| + |w| reach) from the velocities after the step's forces (here gravity: |v_free| <= |v| + h |g|).
real DistributedSystem::ghostWidth() const {
  const real h = real(config_.step.dt);
  real rmax = 0, sweep = 0;
  for (int32_t id : dynamic_) rmax = std::max(rmax, radius_[size_t(id)]);
  for (int32_t id : owned_) {
    const BodyDesc& d = descs_[size_t(id)];
    const MotionState& s = state_[size_t(id)];
    const Vec3 g = d.has_gravity ? d.gravity : config_.step.gravity;
    sweep = std::max(sweep, h * (length(s.vel) + h * length(g) + length(s.omega) * radius_[size_t(id)]));
  }
  sweep = real(group_->max(double(sweep)));
  return settings_.ghost_safety * (2 * rmax + config_.collision.envelope_rel * rmax + 2 * sweep);
}

// Each owned body within the ghost width of another process's box goes there as a ghost.
void DistributedSystem::exchangeGhosts(std::vector<std::vector<Record>>& ghosts) {
  const real width = ghostWidth();
  std::vector<std::vector<Record>> out(static_cast<size_t>(size_));
  for (int32_t id : owned_) {
    const MotionState& s = state_[size_t(id)];
    for (int q = 0; q < size_; ++q)
      if (q != rank_ && tree_.distance(s.pos, q) <= width) out[size_t(q)].push_back(Record{id, s});
  }
  ghosts = exchangeAll(comm_, out, &prof_.ghost_bytes);
  // What this process sent, by process, for the group's lists (buildLocal).
  group_->sentTo().assign(size_t(size_), {});
  for (int q = 0; q < size_; ++q)
    for (const Record& r : out[size_t(q)]) group_->sentTo()[size_t(q)].push_back(r.id);  // global ids for now
}

// This step's System: the fixed and kinematic bodies, the owned ones and the ghosts, in global order (so every
// pair is collided in the order one process collides it), with their exact states.
void DistributedSystem::buildLocal(const std::vector<std::vector<Record>>& ghosts) {
  for (int32_t id : local_ids_) local_of_[size_t(id)] = -1;
  local_ids_ = fixed_;
  local_ids_.insert(local_ids_.end(), owned_.begin(), owned_.end());
  for (const auto& l : ghosts)
    for (const Record& r : l) {
      local_ids_.push_back(r.id);
      state_[size_t(r.id)] = r.s;
    }
  std::sort(local_ids_.begin(), local_ids_.end());
  const size_t nl = local_ids_.size();
  for (size_t i = 0; i < nl; ++i) local_of_[size_t(local_ids_[i])] = int32_t(i);
  std::vector<uint8_t> owned(nl, 0), dynamic(nl, 0);
  for (int32_t id : owned_) owned[size_t(local_of_[size_t(id)])] = 1;
  for (size_t i = 0; i < nl; ++i) dynamic[i] = replicated_[size_t(local_ids_[i])] ? 0 : 1;
  std::vector<std::vector<int32_t>> sent = std::move(group_->sentTo());
  group_->setBodies(local_ids_, std::move(owned), std::move(dynamic));
  for (int q = 0; q < size_; ++q) {
    for (int32_t id : sent[size_t(q)]) group_->sentTo()[size_t(q)].push_back(local_of_[size_t(id)]);
    for (const Record& r : ghosts[size_t(q)]) group_->ghostsFrom()[size_t(q)].push_back(local_of_[size_t(r.id)]);
  }
  group_->markShared();
  sys_ = std::make_unique<System>(config_);
  for (int32_t id : local_ids_) {
    BodyDesc d = descs_[size_t(id)];
    const MotionState& s = state_[size_t(id)];
    d.pos = s.pos;
    d.rot = s.rot;
    d.vel = s.vel;
    d.omega = s.omega;
    sys_->addBody(d);
  }
  BodyArrays& b = sys_->mutableBodies();
  for (size_t i = 0; i < nl; ++i) b.rot[i] = state_[size_t(local_ids_[i])].rot;  // exactly (addBody normalizes)
  sys_->setProcessGroup(group_.get());
}

// The pair's smaller dynamic global id (the contact's owning body), or -1 for two fixed or kinematic bodies.
int32_t DistributedSystem::pairOwner(int32_t a, int32_t b) const {
  const bool da = !replicated_[size_t(a)], db = !replicated_[size_t(b)];
  if (da && db) return std::min(a, b);
  return da ? a : (db ? b : -1);
}

// Last step's impulses of the contacts this process may own now, under this step's local shape indices.
void DistributedSystem::setLocalWarmStart() {
  if (!config_.solver.warm_start || warm_.empty()) return;
  const ShapeArrays& shapes = sys_->shapes();
  std::vector<std::pair<uint64_t, const WarmEntry*>> keyed;
  for (const WarmEntry& e : warm_) {
    const int32_t la = local_of_[size_t(e.body_a)], lb = local_of_[size_t(e.body_b)];
    if (la < 0 || lb < 0) continue;
    const int32_t ga = int32_t(e.key >> 36), gb = int32_t((e.key >> 8) & 0xFFFFFFFu);
    const int32_t sa = sys_->bodies().shape_start[size_t(la)] + (ga - shape_start_[size_t(e.body_a)]);
    const int32_t sb = sys_->bodies().shape_start[size_t(lb)] + (gb - shape_start_[size_t(e.body_b)]);
    if (size_t(sa) >= shapes.count() || size_t(sb) >= shapes.count()) continue;
    keyed.emplace_back(contactKey(sa, sb, int32_t(e.key & 0xFF)), &e);
  }
  std::sort(keyed.begin(), keyed.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
  std::vector<uint64_t> keys(keyed.size());
  std::vector<real> gamma(3 * keyed.size());
  for (size_t i = 0; i < keyed.size(); ++i) {
    keys[i] = keyed[i].first;
    for (int r = 0; r < 3; ++r) gamma[3 * i + size_t(r)] = keyed[i].second->gamma[r];
  }
  sys_->setWarmStart(std::move(keys), std::move(gamma));
}

// The step's outcome: the owned and replicated bodies' states, and the owned contacts' impulses by global key.
void DistributedSystem::readBack() {
  const BodyArrays& b = sys_->bodies();
  for (size_t i = 0; i < local_ids_.size(); ++i) {
    const int32_t id = local_ids_[i];
    if (replicated_[size_t(id)] || std::binary_search(owned_.begin(), owned_.end(), id))
      state_[size_t(id)] = MotionState{b.pos[i], b.rot[i], b.vel[i], b.omega[i]};
  }
  const ContactArrays& c = sys_->contacts();
  const std::vector<real>& g = sys_->impulses();
  warm_.clear();
  if (g.size() < 3 * c.count()) return;  // no solve this step
  for (size_t k = 0; k < c.count(); ++k) {
    const int32_t la = c.body_a[k], lb = c.body_b[k];
    const int32_t ga = local_ids_[size_t(la)], gb = local_ids_[size_t(lb)];
    const int32_t sa = shape_start_[size_t(ga)] + (c.shape_a[k] - b.shape_start[size_t(la)]);
    const int32_t sb = shape_start_[size_t(gb)] + (c.shape_b[k] - b.shape_start[size_t(lb)]);
    WarmEntry e{contactKey(sa, sb, int32_t(c.key[k] & 0xFF)),
                ga,
                gb,
                pairOwner(ga, gb),
                {g[3 * k], g[3 * k + 1], g[3 * k + 2]}};
    warm_.push_back(e);
  }
}

// Each owned body whose centre left this process's box goes to the box's owner, with the warm-start entries of the
// contacts it owns.
void DistributedSystem::migrate() {
  std::vector<std::vector<Record>> out(static_cast<size_t>(size_));
  std::vector<std::vector<WarmEntry>> out_warm(static_cast<size_t>(size_));
  std::vector<int32_t> kept;
  std::vector<int> dest(descs_.size(), -1);
  for (int32_t id : owned_) {
    const int q = tree_.owner(state_[size_t(id)].pos);
    if (q == rank_) {
      kept.push_back(id);
      continue;
    }
    dest[size_t(id)] = q;
    out[size_t(q)].push_back(Record{id, state_[size_t(id)]});
    ++log_.sent[size_t(q)];
  }
  std::vector<WarmEntry> kept_warm;
  for (const WarmEntry& e : warm_) {
    const int q = e.owner >= 0 ? dest[size_t(e.owner)] : -1;
    (q >= 0 ? out_warm[size_t(q)] : kept_warm).push_back(e);
  }
  const auto in = exchangeAll(comm_, out, &prof_.migrate_bytes);
  const auto in_warm = exchangeAll(comm_, out_warm, &prof_.migrate_bytes);
  for (int q = 0; q < size_; ++q) {
    log_.received[size_t(q)] += int64_t(in[size_t(q)].size());
    for (const Record& r : in[size_t(q)]) {
      kept.push_back(r.id);
      state_[size_t(r.id)] = r.s;
    }
    kept_warm.insert(kept_warm.end(), in_warm[size_t(q)].begin(), in_warm[size_t(q)].end());
  }
  std::sort(kept.begin(), kept.end());
  owned_ = std::move(kept);
  warm_ = std::move(kept_warm);
}

// A new bisection of the current positions when the owned counts drift apart (DecompositionSettings), and the
// bodies moved to their new boxes.
void DistributedSystem::rebalanceIfNeeded() {
  double counts[2] = {double(owned_.size()), double(owned_.size())};
  const double most = group_->max(counts[0]);
  group_->sum(counts + 1, 1);
  const double mean = counts[1] / size_;
  if (!(mean > 0) || most <= double(settings_.rebalance_ratio) * mean) return;
  const std::vector<MotionState> all = gatherState();
  std::vector<Vec3> points;
  for (int32_t id : dynamic_) points.push_back(all[size_t(id)].pos);
  tree_ = Bisection::build(points, size_);
  ++log_.rebalances;
  migrate();
}

MotionState DistributedSystem::stateOf(int32_t id) const {
  if (id < 0 || size_t(id) >= descs_.size())
    throw InputError("body " + std::to_string(id) + ": no such body (" + std::to_string(descs_.size()) + " bodies)");
  const bool mine = replicated_[size_t(id)] || !started_ || std::binary_search(owned_.begin(), owned_.end(), id);
  if (!mine) throw InputError("body " + std::to_string(id) + ": owned by another process");
  if (!started_) {
    const BodyDesc& d = descs_[size_t(id)];
    return MotionState{d.pos, normalized(d.rot), d.vel, d.omega};
  }
  return state_[size_t(id)];
}

std::vector<MotionState> DistributedSystem::gatherState() const {
  std::vector<MotionState> all = state_;
  if (!started_) return all;
  std::vector<Record> mine;
  for (int32_t id : owned_) mine.push_back(Record{id, state_[size_t(id)]});
  std::vector<int> counts(static_cast<size_t>(size_)), displ(static_cast<size_t>(size_));
  int bytes = int(mine.size() * sizeof(Record));
  MPI_Allgather(&bytes, 1, MPI_INT, counts.data(), 1, MPI_INT, comm_);
  int total = 0;
  for (int q = 0; q < size_; ++q) {
    displ[size_t(q)] = total;
    total += counts[size_t(q)];
  }
  std::vector<Record> every(size_t(total) / sizeof(Record) + 1);
  MPI_Allgatherv(mine.data(), bytes, MPI_BYTE, every.data(), counts.data(), displ.data(), MPI_BYTE, comm_);
  for (size_t i = 0; i < size_t(total) / sizeof(Record); ++i) all[size_t(every[i].id)] = every[i].s;
  return all;
}

}  // namespace dvi
