#include "chrono_like/mpi/distributed_system.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "chrono_like/base/shape.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/mpi/mpi_collectives.h"

namespace dvi {

namespace {

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

DistributedSystem::DistributedSystem(MPI_Comm comm, SystemConfig config, DecompositionSettings settings,
                                     LocalFactory make_local)
    : config_(config), settings_(settings), make_local_(std::move(make_local)) {
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
  if (!(settings_.halo_factor >= 1) || !std::isfinite(settings_.halo_factor))
    throw InputError("halo factor must be a finite number >= 1");
  if (!make_local_) make_local_ = [](const SystemConfig& c) { return std::make_unique<System>(c); };
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
  owner_.assign(n, kReplicated);
  for (size_t i = 0; i < n; ++i) {
    const BodyDesc& d = descs_[i];
    const bool fixed = (d.flags & kBodyFixed) != 0;
    state_[i] = MotionState{d.pos, normalized(d.rot), fixed ? Vec3{0, 0, 0} : d.vel, fixed ? Vec3{0, 0, 0} : d.omega};
    if (!restored_.empty() && !replicated_[i]) state_[i] = restored_[i];
    gmax_ = std::max(gmax_, length(d.has_gravity ? d.gravity : config_.step.gravity));
  }
  restored_.clear();
  std::vector<Vec3> points;
  for (int32_t id : dynamic_) {
    points.push_back(state_[size_t(id)].pos);
    rmax_ = std::max(rmax_, radius_[size_t(id)]);
  }
  tree_ = Bisection::build(points, size_);
  owned_count_ = 0;
  for (int32_t id : dynamic_) {
    owner_[size_t(id)] = tree_.owner(state_[size_t(id)].pos);
    owned_count_ += owner_[size_t(id)] == rank_ ? 1 : 0;
  }
  owned_stale_ = true;
  local_of_.assign(n, -1);
  started_ = true;
  width_ = ghostWidth();
  setListedRegion();
}

// The next step's exchange holds every current copy within the ghost width of this process's box (listedRegion): its
// owner then sends no record for it after the step (refreshCopies: exchangedWith).
void DistributedSystem::setListedRegion() {
  const Vec3 w{width_, width_, width_};
  group_->setListedRegion(tree_.boxLow(rank_) - w, tree_.boxHigh(rank_) + w);
}

void DistributedSystem::step() {
  using Clock = std::chrono::steady_clock;
  if (!started_) start();
  if (!sys_ || rebuild_pending_) rebuild(sys_ && !host_states_);  // after a step the last System stays readable
  const auto t = Clock::now();
  sys_->step();
  prof_.step_s += std::chrono::duration<double>(Clock::now() - t).count();
  for (int k = 0; k < kStageCount; ++k) prof_.stages_s[size_t(k)] += sys_->lastStats().stage_seconds[size_t(k)];
  afterStep();
  time_ += config_.step.dt;
  ++steps_;
}

DecompositionProfile DistributedSystem::profile() const {
  DecompositionProfile p = prof_;
  p.group = group_->traffic();
  return p;
}

// The ghost width (DecompositionSettings::ghost_safety): two bodies farther apart than this make no contact in
// the coming step. A pair is collided with at most max(envelope, sweep_a + sweep_b) (narrowphase.h: pairEnvelope), the
// sweep h (|v_free| + |w| reach) from the velocities after the step's forces (here gravity: |v_free| <= |v| + h |g|),
// bounded with the fastest owned body's |v| and |w| and the largest body.
real DistributedSystem::ghostWidth() const {
  const real h = real(config_.step.dt);
  real vmax = 0, wmax = 0;
  if (sys_) {
    sys_->motionBounds(vmax, wmax);
  } else {
    for (int32_t id : dynamic_)
      if (owner_[size_t(id)] == rank_) {
        vmax = std::max(vmax, length(state_[size_t(id)].vel));
        wmax = std::max(wmax, length(state_[size_t(id)].omega));
      }
  }
  const real sweep = real(group_->max(double(h * (vmax + h * gmax_ + wmax * rmax_))));
  return settings_.ghost_safety * (2 * rmax_ + config_.collision.envelope_rel * rmax_ + 2 * sweep);
}

// A new local System (collective): the fixed and kinematic bodies, the owned ones and the copies of the neighbours'
// bodies within the halo, in global order (so every pair is collided in the order one process collides it), with
// their exact states; the copies farther than the ghost width parked. read_local: first the current System's owned
// states and contacts to the host (else they are there already: the first build, or after migrateAll).
void DistributedSystem::rebuild(bool read_local) {
  using Clock = std::chrono::steady_clock;
  const auto t = Clock::now();
  if (read_local) readLocal();
  const real halo = settings_.halo_factor * width_;
  std::vector<std::vector<Record>> out(static_cast<size_t>(size_));
  for (int32_t id : dynamic_) {
    if (owner_[size_t(id)] != rank_) continue;
    const MotionState& s = state_[size_t(id)];
    for (int q = 0; q < size_; ++q)
      if (q != rank_ && tree_.distance(s.pos, q) <= halo) out[size_t(q)].push_back(Record{id, s});
  }
  const auto in = mpiExchange(comm_, out, &prof_.ghost_bytes);
  for (int32_t id : local_ids_) local_of_[size_t(id)] = -1;
  local_ids_ = fixed_;
  for (int32_t id : dynamic_)
    if (owner_[size_t(id)] == rank_) local_ids_.push_back(id);
  for (int q = 0; q < size_; ++q)
    for (const Record& r : in[size_t(q)]) {
      local_ids_.push_back(r.id);
      state_[size_t(r.id)] = r.s;
      owner_[size_t(r.id)] = q;
    }
  std::sort(local_ids_.begin(), local_ids_.end());
  const size_t nl = local_ids_.size();
  for (size_t i = 0; i < nl; ++i) local_of_[size_t(local_ids_[i])] = int32_t(i);
  sys_.reset();
  sys_ = make_local_(config_);
  std::vector<int32_t> owners(nl);
  fresh_.clear();
  for (size_t i = 0; i < nl; ++i) {
    const int32_t id = local_ids_[i];
    BodyDesc d = descs_[size_t(id)];
    MotionState s = state_[size_t(id)];
    owners[i] = replicated_[size_t(id)] ? kReplicated : owner_[size_t(id)];
    if (owners[i] >= 0 && owners[i] != rank_) {
      if (tree_.distance(s.pos, rank_) <= width_)
        fresh_.push_back(int32_t(i));
      else
        owners[i] = kNoOwner;  // parked until a refresh (setLocalState)
    }
    d.pos = s.pos;
    d.rot = s.rot;
    d.vel = s.vel;
    d.omega = s.omega;
    sys_->addBody(d);
  }
  for (size_t i = 0; i < nl; ++i) {  // exactly (addBody normalizes); the parked copies keep their masses
    const bool parked = owners[i] == kNoOwner;
    setLocalState(int32_t(i), state_[size_t(local_ids_[i])], parked);
  }
  sys_->markHostDirty();
  current_stamp_.assign(nl, 0);
  stamp_ = 0;
  group_->setBodies(local_ids_, std::move(owners));
  sys_->setProcessGroup(group_.get());
  setLocalWarmStart(warm_, true);
  warm_.clear();
  rebuild_pending_ = host_states_ = false;
  ++log_.rebuilds;
  prof_.build_s += std::chrono::duration<double>(Clock::now() - t).count();
}

// The owned bodies' states and the impulses of this process's contacts by global key (added to warm_) from the local
// System to the host.
void DistributedSystem::readLocal() {
  sys_->syncToHost();
  const BodyArrays& b = sys_->bodies();
  for (size_t i = 0; i < local_ids_.size(); ++i) {
    const int32_t id = local_ids_[i];
    if (replicated_[size_t(id)] || owner_[size_t(id)] == rank_)
      state_[size_t(id)] = MotionState{b.pos[i], b.rot[i], b.vel[i], b.omega[i]};
  }
  std::vector<int32_t> all(local_ids_.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = int32_t(i);
  const std::vector<WarmEntry> mine = warmEntries(sys_->contactImpulsesOf(all));
  warm_.insert(warm_.end(), mine.begin(), mine.end());  // after the entries that arrived this step
}

// Contacts of the local System under global keys, each with its owning body.
std::vector<DistributedSystem::WarmEntry> DistributedSystem::warmEntries(
    const std::vector<ContactImpulse>& contacts) const {
  const BodyArrays& b = sys_->bodies();
  std::vector<WarmEntry> out;
  out.reserve(contacts.size());
  for (const ContactImpulse& c : contacts) {
    const int32_t ga = local_ids_[size_t(c.body_a)], gb = local_ids_[size_t(c.body_b)];
    const int32_t la_shape = int32_t(c.key >> 36), lb_shape = int32_t((c.key >> 8) & 0xFFFFFFFu);
    const int32_t sa = shape_start_[size_t(ga)] + (la_shape - b.shape_start[size_t(c.body_a)]);
    const int32_t sb = shape_start_[size_t(gb)] + (lb_shape - b.shape_start[size_t(c.body_b)]);
    out.push_back(WarmEntry{contactKey(sa, sb, int32_t(c.key & 0xFF)),
                            ga,
                            gb,
                            pairOwner(ga, gb),
                            {c.gamma[0], c.gamma[1], c.gamma[2]},
                            c.normal});
  }
  return out;
}

// The pair's smaller dynamic global id (the contact's owning body), or -1 for two fixed or kinematic bodies.
int32_t DistributedSystem::pairOwner(int32_t a, int32_t b) const {
  const bool da = !replicated_[size_t(a)], db = !replicated_[size_t(b)];
  if (da && db) return std::min(a, b);
  return da ? a : (db ? b : -1);
}

// Impulses by global key into the local System's warm start, under its shape indices (replace: as the whole table,
// else added to it).
void DistributedSystem::setLocalWarmStart(const std::vector<WarmEntry>& entries, bool replace) {
  if (!config_.solver.warm_start || entries.empty()) return;
  const ShapeArrays& shapes = sys_->shapes();
  std::vector<std::pair<uint64_t, const WarmEntry*>> keyed;
  for (const WarmEntry& e : entries) {
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
  std::vector<Vec3> normals(keyed.size());
  for (size_t i = 0; i < keyed.size(); ++i) {
    keys[i] = keyed[i].first;
    for (int r = 0; r < 3; ++r) gamma[3 * i + size_t(r)] = keyed[i].second->gamma[r];
    normals[i] = keyed[i].second->normal;
  }
  if (replace)
    sys_->setWarmStart(std::move(keys), std::move(gamma), std::move(normals));
  else
    sys_->addWarmStart(keys, gamma, normals);
}

// After the local step (collective): the next step's ghost width; the owned bodies near a face of this process's box
// to the host; those that left it to their new owners; the copies refreshed for the next step; a re-balance or a
// rebuild where needed.
void DistributedSystem::afterStep() {
  using Clock = std::chrono::steady_clock;
  auto since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
  auto t = Clock::now();
  warm_.clear();  // holds this step's arrivals from here to a rebuild
  width_ = ghostWidth();
  setListedRegion();
  prof_.width_s += since(t);
  std::vector<int32_t> near_locals;
  std::vector<Record> near = nearFaceBodies(near_locals);
  prof_.readback_s += since(t);
  t = Clock::now();
  bool need_rebuild = false;
  std::vector<int32_t> arrived;
  migrate(near, near_locals, arrived, need_rebuild);
  std::sort(arrived.begin(), arrived.end());
  prof_.migrate_s += since(t);
  t = Clock::now();
  refreshCopies(near, arrived, need_rebuild);
  prof_.ghosts_s += since(t);
  t = Clock::now();
  const bool rebalanced = rebalanceIfNeeded();
  prof_.migrate_s += since(t);
  rebuild_pending_ = rebalanced || group_->any(need_rebuild);  // rebuilt at the next step's start
}

// The owned bodies farther than the ghost width inside this process's box from none of its faces (the only ones that
// can be copies elsewhere or leave the box), with their states, read from the local System.
std::vector<DistributedSystem::Record> DistributedSystem::nearFaceBodies(std::vector<int32_t>& locals) {
  const Vec3 lo = tree_.boxLow(rank_), hi = tree_.boxHigh(rank_);
  const Vec3 w{width_, width_, width_};
  const double t0 = MPI_Wtime();
  locals = sys_->ownedBodiesOutside(lo + w, hi - w);
  const double t1 = MPI_Wtime();
  sys_->syncBodiesToHost(locals);
  prof_.select_s += t1 - t0;
  prof_.near_sync_s += MPI_Wtime() - t1;
  const BodyArrays& b = sys_->bodies();
  std::vector<Record> out;
  out.reserve(locals.size());
  for (int32_t l : locals)  // state_ of an owned body is read only after syncOwned (or of one that leaves: migrate)
    out.push_back(Record{local_ids_[size_t(l)],
                         MotionState{b.pos[size_t(l)], b.rot[size_t(l)], b.vel[size_t(l)], b.omega[size_t(l)]}});
  return out;
}

// Each near-face body whose centre left this process's box goes to the box's owner, with the impulses of the contacts
// it owns (the new owner solves them from the next step on). On return `near` holds this process's near-face bodies
// after the moves.
void DistributedSystem::migrate(std::vector<Record>& near, const std::vector<int32_t>& near_locals,
                                std::vector<int32_t>& arrived_ids, bool& need_rebuild) {
  std::vector<std::vector<Record>> out(static_cast<size_t>(size_));
  std::vector<std::vector<WarmEntry>> out_warm(static_cast<size_t>(size_));
  std::vector<int32_t> leaving;  // local indices
  size_t kept = 0;               // near is compacted in place to the bodies that stay
  for (size_t j = 0; j < near.size(); ++j) {
    const int q = tree_.owner(near[j].s.pos);
    if (q == rank_) {
      if (kept != j) near[kept] = near[j];
      ++kept;
      continue;
    }
    out[size_t(q)].push_back(near[j]);
    state_[size_t(near[j].id)] = near[j].s;  // a copy here from now on, parked with this state unless refreshed
    leaving.push_back(near_locals[j]);
    owner_[size_t(near[j].id)] = q;
    group_->setOwner(near_locals[j], q);
    ++log_.sent[size_t(q)];
    --owned_count_;
  }
  if (!leaving.empty()) {
    for (const WarmEntry& e : warmEntries(sys_->contactImpulsesOf(leaving)))
      if (e.owner >= 0 && owner_[size_t(e.owner)] != rank_) out_warm[size_t(owner_[size_t(e.owner)])].push_back(e);
  }
  std::vector<Record> in;
  const std::vector<WarmEntry> arrived = exchangeMoves(out, out_warm, in);
  std::vector<int32_t> dirty;
  near.resize(kept);
  for (const Record& r : in) {
    near.push_back(r);
    arrived_ids.push_back(r.id);
    const int32_t l = local_of_[size_t(r.id)];
    if (l < 0) {  // not held here: a rebuild adds it
      need_rebuild = true;
      continue;
    }
    group_->setOwner(l, rank_);
    setLocalState(l, r.s, false);
    dirty.push_back(l);
  }
  if (!dirty.empty()) sys_->markBodiesDirty(dirty);
  if (!arrived.empty()) {
    warm_.insert(warm_.end(), arrived.begin(), arrived.end());  // kept for a rebuild this step
    setLocalWarmStart(arrived, false);
  }
  owned_stale_ = owned_stale_ || !leaving.empty() || !in.empty();
  // A body that left is a copy here now: parked by refreshCopies unless its new owner refreshes it.
  fresh_.insert(fresh_.end(), leaving.begin(), leaving.end());
}

// A local body's state written to the local System's host arrays (markBodiesDirty uploads it): a refreshed or arrived
// body takes its own flags again; a parked one is fixed and at rest.
void DistributedSystem::setLocalState(int32_t l, const MotionState& s, bool parked) {
  BodyArrays& b = sys_->mutableBodies();
  const int32_t id = local_ids_[size_t(l)];
  b.pos[size_t(l)] = s.pos;
  b.rot[size_t(l)] = s.rot;
  b.vel[size_t(l)] = parked ? Vec3{0, 0, 0} : s.vel;
  b.omega[size_t(l)] = parked ? Vec3{0, 0, 0} : s.omega;
  b.flags[size_t(l)] = parked ? uint8_t(descs_[size_t(id)].flags | kBodyFixed) : descs_[size_t(id)].flags;
}

// Each owned near-face body within the ghost width of another process's box goes there: the copy takes its state and
// owner; a copy that no record refreshes is parked; a record of a body not held here asks for a rebuild.
// A copy that took part in its body's velocity-change exchange this step came out of it with the owner's very state
// (the same forces, the same summed velocity change, the same integration): its owner sends no record, unless the
// body changed owner this step (the record names the new one).
void DistributedSystem::refreshCopies(const std::vector<Record>& near, const std::vector<int32_t>& arrived,
                                      bool& need_rebuild) {
  const double t0 = MPI_Wtime();
  std::vector<std::vector<Record>> out(static_cast<size_t>(size_));
  for (const Record& r : near) {
    const int32_t l = local_of_[size_t(r.id)];
    const bool moved = std::binary_search(arrived.begin(), arrived.end(), r.id);
    for (int q = 0; q < size_; ++q)
      if (q != rank_ && tree_.distance(r.s.pos, q) <= width_ && (moved || l < 0 || !group_->exchangedWith(l, q)))
        out[size_t(q)].push_back(r);
  }
  const double t1 = MPI_Wtime();
  const auto in = mpiExchange(comm_, out, &prof_.ghost_bytes);
  const double t2 = MPI_Wtime();
  // The copies current after this step: exchanged ones (without a record) and refreshed ones, each stamped once.
  const uint32_t stamp = ++stamp_;
  std::vector<int32_t> now, dirty;
  auto current = [&](int32_t l) {
    if (current_stamp_[size_t(l)] == stamp) return;
    current_stamp_[size_t(l)] = stamp;
    now.push_back(l);
  };
  for (int32_t l : group_->exchangeBodies()) {
    const int32_t o = group_->bodyOwners()[size_t(l)];
    if (o >= 0 && o != rank_) current(l);
  }
  for (int q = 0; q < size_; ++q)
    for (const Record& r : in[size_t(q)]) {
      const int32_t l = local_of_[size_t(r.id)];
      owner_[size_t(r.id)] = q;
      if (l < 0) {
        need_rebuild = true;
        state_[size_t(r.id)] = r.s;
        continue;
      }
      group_->setOwner(l, q);
      setLocalState(l, r.s, false);
      current(l);
      dirty.push_back(l);
    }
  const double t3 = MPI_Wtime();
  for (int32_t l : fresh_)  // refreshed last step, not now, and not own: parked
    if (current_stamp_[size_t(l)] != stamp && group_->bodyOwners()[size_t(l)] != rank_) {
      current_stamp_[size_t(l)] = stamp;  // parked once, however often fresh_ names it
      group_->setOwner(l, kNoOwner);
      setLocalState(l, state_[size_t(local_ids_[size_t(l)])], true);
      dirty.push_back(l);
    }
  sys_->markBodiesDirty(dirty);  // every body once (a record per body, parked ones not refreshed)
  fresh_ = std::move(now);
  prof_.ghosts_pack_s += t1 - t0;
  prof_.ghosts_mpi_s += t2 - t1;
  prof_.ghosts_apply_s += t3 - t2;
  prof_.ghosts_park_s += MPI_Wtime() - t3;
}

// A new bisection of the current positions when the owned counts drift apart (DecompositionSettings), every body
// moved to its new box, and a new local System.
bool DistributedSystem::rebalanceIfNeeded() {
  double counts[2] = {double(owned_count_), double(owned_count_)};
  const double t0 = MPI_Wtime();
  const double most = group_->max(counts[0]);
  group_->sum(counts + 1, 1);
  prof_.migrate_mpi_s += MPI_Wtime() - t0;
  const double mean = counts[1] / size_;
  // No bisection does better than ceil(mean) a process (2 bodies on 3 processes re-balanced every step before).
  if (!(mean > 0) || most <= double(settings_.rebalance_ratio) * mean || most <= std::ceil(mean)) return false;
  readLocal();
  const std::vector<MotionState> all = gatherState();
  std::vector<Vec3> points;
  for (int32_t id : dynamic_) points.push_back(all[size_t(id)].pos);
  tree_ = Bisection::build(points, size_);
  ++log_.rebalances;
  migrateAll();
  host_states_ = true;  // the owned states are on the host now; the System is rebuilt from them
  return true;
}

// Every owned body whose centre is outside this process's (new) box to the box's owner, with the warm-start entries of
// the contacts it owns (from warm_, read by readLocal).
void DistributedSystem::migrateAll() {
  std::vector<std::vector<Record>> out(static_cast<size_t>(size_));
  std::vector<std::vector<WarmEntry>> out_warm(static_cast<size_t>(size_));
  for (int32_t id : dynamic_) {
    if (owner_[size_t(id)] != rank_) continue;
    const int q = tree_.owner(state_[size_t(id)].pos);
    if (q == rank_) continue;
    owner_[size_t(id)] = q;
    out[size_t(q)].push_back(Record{id, state_[size_t(id)]});
    ++log_.sent[size_t(q)];
    --owned_count_;
  }
  std::vector<WarmEntry> kept_warm;
  for (const WarmEntry& e : warm_) {
    const int q = e.owner >= 0 ? owner_[size_t(e.owner)] : rank_;
    (q != rank_ && q >= 0 ? out_warm[size_t(q)] : kept_warm).push_back(e);
  }
  std::vector<Record> in;
  const std::vector<WarmEntry> arrived = exchangeMoves(out, out_warm, in);
  kept_warm.insert(kept_warm.end(), arrived.begin(), arrived.end());
  warm_ = std::move(kept_warm);
  owned_stale_ = true;
}

// The moves' two all-to-alls (bodies, and the impulses of the contacts they own): the bodies that arrive become this
// process's (their states in state_, in `in`); returns the impulses that arrive.
std::vector<DistributedSystem::WarmEntry> DistributedSystem::exchangeMoves(
    const std::vector<std::vector<Record>>& out, const std::vector<std::vector<WarmEntry>>& out_warm,
    std::vector<Record>& in) {
  const double t0 = MPI_Wtime();
  const auto recs = mpiExchange(comm_, out, &prof_.migrate_bytes);
  const auto warm = mpiExchange(comm_, out_warm, &prof_.migrate_bytes);
  prof_.migrate_mpi_s += MPI_Wtime() - t0;
  std::vector<WarmEntry> arrived;
  for (int q = 0; q < size_; ++q) {
    log_.received[size_t(q)] += int64_t(recs[size_t(q)].size());
    for (const Record& r : recs[size_t(q)]) {
      owner_[size_t(r.id)] = rank_;
      state_[size_t(r.id)] = r.s;
      ++owned_count_;
      in.push_back(r);
    }
    arrived.insert(arrived.end(), warm[size_t(q)].begin(), warm[size_t(q)].end());
  }
  return arrived;
}

const std::vector<int32_t>& DistributedSystem::ownedIds() const {
  if (owned_stale_) {
    owned_.clear();
    for (int32_t id : dynamic_)
      if (started_ ? owner_[size_t(id)] == rank_ : false) owned_.push_back(id);
    owned_stale_ = false;
  }
  return owned_;
}

// The owned bodies' current states from the local System into state_.
void DistributedSystem::syncOwned() const {
  if (!sys_ || host_states_) return;
  std::vector<int32_t> mine;
  for (size_t i = 0; i < local_ids_.size(); ++i)
    if (owner_[size_t(local_ids_[i])] == rank_ || replicated_[size_t(local_ids_[i])]) mine.push_back(int32_t(i));
  sys_->syncBodiesToHost(mine);
  const BodyArrays& b = sys_->bodies();
  for (int32_t l : mine)
    state_[size_t(local_ids_[size_t(l)])] =
        MotionState{b.pos[size_t(l)], b.rot[size_t(l)], b.vel[size_t(l)], b.omega[size_t(l)]};
}

MotionState DistributedSystem::stateOf(int32_t id) const {
  if (id < 0 || size_t(id) >= descs_.size())
    throw InputError("body " + std::to_string(id) + ": no such body (" + std::to_string(descs_.size()) + " bodies)");
  if (!started_) {
    const BodyDesc& d = descs_[size_t(id)];
    return MotionState{d.pos, normalized(d.rot), d.vel, d.omega};
  }
  if (!replicated_[size_t(id)] && owner_[size_t(id)] != rank_)
    throw InputError("body " + std::to_string(id) + ": owned by another process");
  const int32_t l = local_of_[size_t(id)];
  if (sys_ && l >= 0 && !host_states_) {
    sys_->syncBodiesToHost({l});
    const BodyArrays& b = sys_->bodies();
    return MotionState{b.pos[size_t(l)], b.rot[size_t(l)], b.vel[size_t(l)], b.omega[size_t(l)]};
  }
  return state_[size_t(id)];
}

std::vector<MotionState> DistributedSystem::ownedStates() const {
  std::vector<MotionState> out;
  if (!started_) return out;
  syncOwned();
  for (int32_t id : ownedIds()) out.push_back(state_[size_t(id)]);
  return out;
}

CheckpointPiece DistributedSystem::checkpointPiece() const {
  CheckpointPiece p;
  p.ids = ownedIds();
  p.states = ownedStates();
  std::vector<WarmEntry> entries = warm_;  // this step's arrivals (or, after a re-balance, every entry)
  if (sys_ && !host_states_) {
    std::vector<int32_t> all(local_ids_.size());
    for (size_t i = 0; i < all.size(); ++i) all[i] = int32_t(i);
    const std::vector<WarmEntry> mine = warmEntries(sys_->contactImpulsesOf(all));
    entries.insert(entries.end(), mine.begin(), mine.end());
  }
  for (const WarmEntry& e : entries)
    p.impulses.push_back(ContactImpulse{e.key, e.body_a, e.body_b, {e.gamma[0], e.gamma[1], e.gamma[2]}, e.normal});
  return p;
}

void DistributedSystem::restore(const std::vector<MotionState>& states, const std::vector<ContactImpulse>& impulses,
                                double time, int64_t steps) {
  if (started_) throw InputError("restore: only before the first step");
  if (states.size() != descs_.size())
    throw InputError("restore: " + std::to_string(states.size()) + " states for " + std::to_string(descs_.size()) +
                     " bodies");
  restored_ = states;
  start();
  warm_.clear();
  for (const ContactImpulse& c : impulses) {  // the entries of the contacts whose owning body is this process's
    const int32_t o = pairOwner(c.body_a, c.body_b);
    if (o >= 0 ? owner_[size_t(o)] != rank_ : rank_ != 0) continue;
    warm_.push_back(WarmEntry{c.key, c.body_a, c.body_b, o, {c.gamma[0], c.gamma[1], c.gamma[2]}, c.normal});
  }
  time_ = time;
  steps_ = steps;
}

std::vector<MotionState> DistributedSystem::gatherState() const {
  if (!started_) {
    std::vector<MotionState> all(descs_.size());
    for (size_t i = 0; i < all.size(); ++i) all[i] = stateOf(int32_t(i));
    return all;
  }
  syncOwned();
  std::vector<MotionState> all = state_;
  std::vector<Record> mine;
  for (int32_t id : ownedIds()) mine.push_back(Record{id, state_[size_t(id)]});
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
