#include "chrono_like/system.h"
#include "chrono_like/base/parallel_for.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <numeric>
#include <sstream>
#include <type_traits>

#include "chrono_like/collision/collision.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/collision/narrowphase.h"
#include "chrono_like/integrate.h"
#include "chrono_like/solver/contact_problem.h"

namespace dvi {

const char* stageName(StageType s) {
  switch (s) {
    case StageType::IntegrateForces: return "IntegrateForces";
    case StageType::ComputeAabbs: return "ComputeAabbs";
    case StageType::BroadPhase: return "BroadPhase";
    case StageType::NarrowPhase: return "NarrowPhase";
    case StageType::BuildRows: return "BuildRows";
    case StageType::WarmStart: return "WarmStart";
    case StageType::Solve: return "Solve";
    case StageType::IntegrateVelocities: return "IntegrateVelocities";
    case StageType::IntegratePositions: return "IntegratePositions";
    default: return "?";
  }
}

const char* stagePartName(StagePart p) {
  switch (p) {
    case StagePart::ForceFields: return "IntegrateForces.ForceFields";
    case StagePart::Gyroscopic: return "IntegrateForces.Gyroscopic";
    case StagePart::Mpr: return "NarrowPhase.Mpr";
    case StagePart::ConstraintRows: return "BuildRows.ConstraintRows";
    case StagePart::FrictionRows: return "BuildRows.FrictionRows";
    case StagePart::RollingSpinningRows: return "BuildRows.RollingSpinningRows";
    default: return "?";
  }
}

StageType stageOfPart(StagePart p) {
  switch (p) {
    case StagePart::ForceFields:
    case StagePart::Gyroscopic: return StageType::IntegrateForces;
    case StagePart::Mpr: return StageType::NarrowPhase;
    default: return StageType::BuildRows;
  }
}

namespace {

// Runs `body` and records its wall time under stage `s`.
template <class F>
void timed(StepStats& stats, StageType s, F&& body) {
  double t0 = omp_get_wtime();
  body();
  stats.stage_seconds[int(s)] += omp_get_wtime() - t0;
  stats.stage_ran[int(s)] = true;
}

bool finite(real x) { return std::isfinite(x); }
bool finite(Quat q) { return finite(q.w) && finite(q.x) && finite(q.y) && finite(q.z); }

// Smallest half-dimension of a shape: scales its envelope and recovery speed. Planes have none.
real shapeSize(const Shape& s) {
  switch (s.type) {
    case ShapeType::Sphere: return s.dims.x;
    case ShapeType::Cylinder: return fmin(s.dims.x, s.dims.y);
    case ShapeType::Capsule: return s.dims.x;
    case ShapeType::Cone: return fmin(s.dims.x, real(0.5) * s.dims.y);
    case ShapeType::Plane: return real(1e30);
    case ShapeType::ConvexHull: return minComponent(s.dims) + real(s.margin);  // the swept hull's
    default: return minComponent(s.dims);
  }
}

void validateShape(const ShapeDesc& d, int body_index) {
  const Shape& s = d.shape;
  auto fail = [&](const std::string& what) {
    throw InputError("body " + std::to_string(body_index) + ": " + shapeTypeName(s.type) + " shape " + what);
  };
  if (int(s.type) < 0 || s.type >= ShapeType::Count)
    throw InputError("body " + std::to_string(body_index) + ": unsupported shape type");
  if (!isFinite(s.dims) || !isFinite(s.local.p) || !finite(s.local.q) || !finite(s.plane_d))
    fail("has a non-finite dimension or pose");
  // The sphere-swept margin is a convex hull's only (Shape::margin): refused on other types rather than ignored.
  if (s.type == ShapeType::ConvexHull && !(std::isfinite(s.margin) && s.margin >= 0))
    fail("has a negative or non-finite margin " + std::to_string(s.margin));
  if (s.type != ShapeType::ConvexHull && s.margin != 0)
    fail("has a margin " + std::to_string(s.margin) + " (only convex hulls take one)");
  switch (s.type) {
    case ShapeType::Sphere:
      if (!(s.dims.x > 0)) fail("has a non-positive radius " + std::to_string(s.dims.x));
      break;
    case ShapeType::Cylinder:
    case ShapeType::Cone:
      if (!(s.dims.x > 0) || !(s.dims.y > 0)) fail("has a non-positive radius or height");
      break;
    case ShapeType::Capsule:
      if (!(s.dims.x > 0) || s.dims.y < 0) fail("has a non-positive radius or negative length");
      break;
    case ShapeType::Box:
    case ShapeType::Ellipsoid:
      if (!(minComponent(s.dims) > 0)) fail("has a non-positive dimension");
      break;
    case ShapeType::ConvexHull:
      if (d.hull.size() < 4) fail("needs at least 4 points, got " + std::to_string(d.hull.size()));
      for (const Vec3& p : d.hull)
        if (!isFinite(p)) fail("has a non-finite point");
      break;
    case ShapeType::Plane:
      if (std::fabs(length(s.dims) - 1) > real(1e-6)) fail("normal is not a unit vector");
      break;
    default: break;
  }
}

}  // namespace

System::System(SystemConfig config, CollisionFactory bullet_collision)
    : config_(config), problem_(std::make_unique<ContactProblem>()) {
  if (!(real(config_.step.dt) > 0) || !std::isfinite(real(config_.step.dt)))
    throw InputError("time step dt must be positive, got " + std::to_string(real(config_.step.dt)));
  if (config_.solver.max_iterations < 0) throw InputError("solver iterations must be >= 0");
  if (config_.collision.backend == CollisionBackend::Native)
    collision_ = makeNativeCollision(config_.collision.broadphase);
  else if (bullet_collision)
    collision_ = bullet_collision();
  else
    throw InputError("collision backend 'bullet': this System was made without Bullet's collision backend");
}

System::~System() = default;

std::string System::deviceName() const {
  std::ifstream f("/proc/cpuinfo");
  std::string line, model = "CPU";
  while (std::getline(f, line))
    if (line.rfind("model name", 0) == 0) {
      model = line.substr(line.find(':') + 2);
      break;
    }
  return model + " (" + std::to_string(effectiveThreads()) + " threads)";
}

int System::effectiveThreads() const {
  // 0: OpenMP's default team size (OMP_NUM_THREADS, else the cores), as read outside any parallel region.
  const int requested = config_.threads > 0 ? config_.threads : omp_get_max_threads();
  const int64_t per = std::max(1, config_.min_bodies_per_thread);
  // the work grows with the shapes as much as with the bodies (a static mesh is one body of thousands of triangles)
  const int64_t items = std::max<int64_t>(int64_t(bodies_.count()), int64_t(shapes_.count()));
  const int64_t useful = std::max<int64_t>(1, items / per);
  return int(std::min<int64_t>(requested, useful));
}

void System::validateBody(const BodyDesc& d, int index) {
  auto fail = [&](const std::string& what) { throw InputError("body " + std::to_string(index) + ": " + what); };
  if (!isFinite(d.pos)) fail("non-finite position");
  if (!finite(d.rot)) fail("non-finite rotation");
  if (!isFinite(d.vel) || !isFinite(d.omega)) fail("non-finite velocity");
  if (!std::isfinite(d.mass)) fail("non-finite mass");
  if (d.mass < 0) fail("negative mass " + std::to_string(d.mass));
  const bool immovable = (d.flags & (kBodyFixed | kBodyKinematic)) != 0;
  if (!immovable && d.mass == 0) fail("zero mass on a dynamic body (use a fixed body for static geometry)");
  if (!immovable && !(minComponent(d.inertia) > 0 && isFinite(d.inertia))) fail("non-positive or non-finite inertia");
  if (!std::isfinite(d.friction) || d.friction < 0) fail("negative or non-finite friction");
  if (!std::isfinite(d.restitution) || d.restitution < 0) fail("negative or non-finite restitution");
  if (!std::isfinite(d.rolling_friction) || d.rolling_friction < 0) fail("negative or non-finite rolling friction");
  if (!std::isfinite(d.spinning_friction) || d.spinning_friction < 0) fail("negative or non-finite spinning friction");
  if (d.shapes.empty()) fail("has no collision shape");
  for (const ShapeDesc& s : d.shapes) validateShape(s, index);
  real qn = std::sqrt(d.rot.w * d.rot.w + d.rot.x * d.rot.x + d.rot.y * d.rot.y + d.rot.z * d.rot.z);
  if (!(qn > 0)) fail("zero rotation quaternion");
}

int System::addBody(const BodyDesc& d) {
  const int index = int(bodies_.count());
  validateBody(d, index);
  const bool immovable = (d.flags & (kBodyFixed | kBodyKinematic)) != 0;
  const size_t n = bodies_.count();
  bodies_.resize(n + 1);
  bodies_.pos[n] = d.pos;
  bodies_.rot[n] = normalized(d.rot);
  bodies_.vel[n] = (d.flags & kBodyFixed) ? Vec3{0, 0, 0} : d.vel;
  bodies_.omega[n] = (d.flags & kBodyFixed) ? Vec3{0, 0, 0} : d.omega;
  bodies_.inv_mass[n] = immovable ? 0 : 1 / d.mass;
  bodies_.inv_inertia[n] = immovable ? Vec3{0, 0, 0} : Vec3{1 / d.inertia.x, 1 / d.inertia.y, 1 / d.inertia.z};
  bodies_.force[n] = bodies_.torque[n] = Vec3{0, 0, 0};
  bodies_.gravity[n] = d.has_gravity ? d.gravity : config_.step.gravity;
  bodies_.friction[n] = d.friction;
  bodies_.restitution[n] = d.restitution;
  bodies_.rolling_friction[n] = d.rolling_friction;
  bodies_.spinning_friction[n] = d.spinning_friction;
  bodies_.flags[n] = d.flags;
  bodies_.shape_start[n] = int32_t(shapes_.count());
  bodies_.shape_count[n] = int32_t(d.shapes.size());
  real body_size = real(1e30);
  for (const ShapeDesc& sd : d.shapes) {
    Shape s = sd.shape;
    s.body = int32_t(n);
    s.local.q = normalized(s.local.q);
    if (s.type == ShapeType::ConvexHull) {
      s.hull_start = int32_t(shapes_.hull_points.size());
      s.hull_count = int32_t(sd.hull.size());
      shapes_.hull_points.insert(shapes_.hull_points.end(), sd.hull.begin(), sd.hull.end());
    }
    if (!(s.size > 0)) s.size = shapeSize(s);
    if (s.group == 0 && s.mask == 0) s.group = 1, s.mask = -1;
    body_size = fmin(body_size, s.size);
    shapes_.shape.push_back(s);
  }
  bodies_.size[n] = body_size;
  shapes_.aabb.resize(shapes_.count());
  return index;
}

bool System::hasGyroscopicBodies() const {
  const size_t nb = bodies_.count();
  for (size_t i = 0; i < nb; ++i)
    if (needsGyroscopic(bodies_.inv_inertia[i], bodies_.flags[i])) return true;
  return false;
}

bool System::planParts() {
  auto part = [&](StagePart p, bool ran, const char* why) {
    stats_.part_ran[int(p)] = ran;
    stats_.part_reason[int(p)] = ran ? nullptr : why;
  };
  const bool prune = config_.prune;
  part(StagePart::ForceFields, !fields_.empty() || !prune, "no force field in the scene");
  part(StagePart::ConstraintRows, !row_providers_.empty() || !prune, "no joint or row provider in the scene");
  // Gyroscopic term: only dynamic bodies with non-spherical inertia need it.
  const size_t nb = bodies_.count();
  const bool gyro = config_.step.gyroscopic && nb > 0 && (!prune || hasGyroscopicBodies());
  part(StagePart::Gyroscopic, gyro,
       !config_.step.gyroscopic ? "switched off (SystemConfig::step.gyroscopic)"
                                : "every dynamic body has spherical inertia");
  // MPR: the shape types present decide whether any pair can need it (pairUsesMpr). It is a per-pair choice of
  // the narrow phase, not a switch: prune = false does not force it on pairs with a closed form.
  for (; typed_shapes_ < shapes_.count(); ++typed_shapes_)
    shape_types_ |= 1u << unsigned(shapes_.shape[typed_shapes_].type);
  bool mpr = false;
  for (int a = 0; a < int(ShapeType::Count); ++a)
    for (int b = a; b < int(ShapeType::Count); ++b)
      if ((shape_types_ >> a & 1u) && (shape_types_ >> b & 1u) && pairUsesMpr(ShapeType(a), ShapeType(b))) mpr = true;
  if (config_.collision.backend == CollisionBackend::Bullet) mpr = false;
  part(StagePart::Mpr, mpr,
       config_.collision.backend == CollisionBackend::Bullet
           ? "Bullet's collision backend (GJK/EPA)"
           : "every pair of shape types in the scene has a closed form");
  // Rolling blocks: decided per contact in BuildRows (combineRolling); here only whether any body asks for them.
  part(StagePart::RollingSpinningRows, false, "no body has rolling or spinning friction");
  return gyro;
}

bool System::hasRollingBodies() const {
  const size_t nb = bodies_.count();
  for (size_t i = 0; i < nb; ++i)
    if (bodies_.rolling_friction[i] > 0 || bodies_.spinning_friction[i] > 0) return true;
  return false;
}

// Each contact's rolling and spinning coefficient from its bodies', by the friction rule: Product is Bullet's rule,
// mu_r = r_a f_b + r_b f_a capped at 10 (btManifoldResult::calculateCombinedRollingFriction and ...SpinningFriction,
// with f the bodies' Coulomb coefficients); Min is Chrono's (ChMaterialCompositionStrategy::CombineRollingFriction);
// Average their mean.
bool System::combineRolling(int64_t nc) {
  roll_coef_.resize(size_t(2 * nc));
  const FrictionCombine rule = config_.collision.friction_combine;
  const BodyArrays& B = bodies_;
  bool any = false;
  if (nc == 0) return false;
  any = parallelSum(nc, nc >= kSerialContacts ? ompTeam() : 1, [&](int64_t k) {
          const int32_t a = contacts_.body_a[k], b = contacts_.body_b[k];
          const real ra[2] = {B.spinning_friction[a], B.rolling_friction[a]};
          const real rb[2] = {B.spinning_friction[b], B.rolling_friction[b]};
          bool some = false;
          for (int j = 0; j < 2; ++j) {
            const real c = rule == FrictionCombine::Product
                               ? fmin(ra[j] * B.friction[b] + rb[j] * B.friction[a], real(10))
                           : rule == FrictionCombine::Min ? fmin(ra[j], rb[j])
                                                          : real(0.5) * (ra[j] + rb[j]);
            roll_coef_[size_t(2 * k + j)] = c;
            some = some || c > 0;
          }
          return some;
        }) > 0;
  return any;
}

void System::step() {
  stats_ = StepStats{};
  beginStep();
  // The stages read omp_get_max_threads(); the caller's setting is restored after the step.
  // threads 0: the team adapts to the machine's load (thread_governor.h); an explicit count stands.
  const int caller_threads = omp_get_max_threads();
  const int full = effectiveThreads();
  const int team = config_.threads == 0 ? governor_.choose(full) : full;
  omp_set_num_threads(team);
  const auto t0 = std::chrono::steady_clock::now();
  planParts();

  timed(stats_, StageType::IntegrateForces, [&] { integrateForces(); });
  detectCollisions();
  buildAndSolve();
  integrate();
  if (config_.threads == 0)
    governor_.record(team, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  stats_.threads = team;
  omp_set_num_threads(caller_threads);
  endStep();
}

void System::integrateForces() {
  const int64_t n = int64_t(bodies_.count());
  v_free_.resize(size_t(n));
  w_free_.resize(size_t(n));
  const real h = ctx_.dt;
  const bool gyro = stats_.part_ran[int(StagePart::Gyroscopic)];
  const bool skip_spherical = config_.prune;
  for (const auto& f : fields_) f->apply(bodies_, ctx_, bodies_.force.data(), bodies_.torque.data());
  parallelFor(int64_t(n), ompTeam(), [&](int64_t i) {
    integrateBodyForces(bodies_.vel[i], bodies_.omega[i], bodies_.rot[i], bodies_.inv_mass[i], bodies_.inv_inertia[i],
                        bodies_.force[i], bodies_.torque[i], bodies_.gravity[i], bodies_.flags[i], gyro, skip_spherical,
                        h, v_free_[i], w_free_[i]);
  });
}

void System::detectCollisions() {
  CollisionTimes t;
  collision_->setFreeVelocities(v_free_.data(), w_free_.data());
  const bool last = config_.solver.warm_start && prev_normal_.size() == prev_keys_.size();
  collision_->setLastNormals(
      LastNormals{prev_keys_.data(), prev_normal_.data(), last ? int64_t(prev_keys_.size()) : int64_t(0)});
  collision_->detect(bodies_, shapes_, config_.collision, ctx_, contacts_, t);
  stats_.stage_seconds[int(StageType::ComputeAabbs)] = t.aabbs;
  stats_.stage_seconds[int(StageType::BroadPhase)] = t.broad;
  stats_.stage_seconds[int(StageType::NarrowPhase)] = t.narrow;
  stats_.stage_ran[int(StageType::ComputeAabbs)] = stats_.stage_ran[int(StageType::BroadPhase)] =
      stats_.stage_ran[int(StageType::NarrowPhase)] = true;
  stats_.pairs = t.pairs;
  stats_.pairs_reused = t.pairs_reused;
  if (group_)  // a domain decomposition: only the contacts this process owns (exactly one process keeps each)
    contacts_.keepIf([&](size_t k) { return group_->ownsContact(contacts_.body_a[k], contacts_.body_b[k]); });
  if (hasExclusions()) {
    const uint64_t* keys = excluded_pairs_.data();
    const int64_t nk = int64_t(excluded_pairs_.size()), nf = int64_t(no_contact_.size());
    const uint8_t* flags = no_contact_.empty() ? nullptr : no_contact_.data();
    contacts_.keepIf(
        [&](size_t k) { return !contactExcluded(contacts_.body_a[k], contacts_.body_b[k], keys, nk, flags, nf); });
  }
  stats_.contacts = int64_t(contacts_.count());
  if (group_) {
    group_->takeOwnerChanges();  // read in place here (a device backend copies them)
    group_->setTouchedCopies(touchedCopies());
  }
}

// The copies of other processes' bodies that this process's contacts touch, and the current ones in the group's listed
// region (ProcessGroup::setTouchedCopies).
std::vector<int32_t> System::touchedCopies() const {
  const std::vector<int32_t>& owner = group_->bodyOwners();
  const int self = group_->rank();
  std::vector<int32_t> out;
  for (size_t k = 0; k < contacts_.count(); ++k)
    for (int32_t b : {contacts_.body_a[k], contacts_.body_b[k]})
      if (owner[size_t(b)] >= 0 && owner[size_t(b)] != self) out.push_back(b);
  Vec3 lo, hi;
  if (group_->listedRegion(lo, hi))
    for (size_t i = 0; i < bodies_.count(); ++i)
      if (owner[i] >= 0 && owner[i] != self && insideBox(bodies_.pos[i], lo, hi)) out.push_back(int32_t(i));
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

void System::motionBounds(real& vmax, real& wmax) const {
  vmax = wmax = 0;
  for (size_t i = 0; i < bodies_.count(); ++i) {
    const bool mine = group_ ? group_->ownsBody(int32_t(i)) : !(bodies_.flags[i] & (kBodyFixed | kBodyKinematic));
    if (!mine) continue;
    vmax = std::max(vmax, length(bodies_.vel[i]));
    wmax = std::max(wmax, length(bodies_.omega[i]));
  }
}

std::vector<int32_t> System::ownedBodiesOutside(Vec3 lo, Vec3 hi) const {
  std::vector<int32_t> out;
  for (size_t i = 0; i < bodies_.count(); ++i) {
    const bool mine = group_ ? group_->ownsBody(int32_t(i)) : !(bodies_.flags[i] & (kBodyFixed | kBodyKinematic));
    if (mine && !insideBox(bodies_.pos[i], lo, hi)) out.push_back(int32_t(i));
  }
  return out;
}

std::vector<ContactImpulse> System::contactImpulsesOf(const std::vector<int32_t>& bodies) const {
  std::vector<ContactImpulse> out;
  if (gamma_.size() < 3 * contacts_.count()) return out;  // no solve in the last step
  for (size_t k = 0; k < contacts_.count(); ++k) {
    const int32_t a = contacts_.body_a[k], b = contacts_.body_b[k];
    if (!std::binary_search(bodies.begin(), bodies.end(), a) && !std::binary_search(bodies.begin(), bodies.end(), b))
      continue;
    out.push_back(ContactImpulse{
        contacts_.key[k], a, b, {gamma_[3 * k], gamma_[3 * k + 1], gamma_[3 * k + 2]}, contacts_.normal[k]});
  }
  std::sort(out.begin(), out.end(), [](const ContactImpulse& x, const ContactImpulse& y) { return x.key < y.key; });
  return out;
}

void System::setContactExclusions(const std::vector<std::pair<int32_t, int32_t>>& pairs,
                                  std::vector<uint8_t> no_contact) {
  excluded_pairs_.clear();
  for (const auto& p : pairs) {
    if (p.first < 0 || p.second < 0 || p.first == p.second)
      throw InputError("contact exclusion: invalid body pair (" + std::to_string(p.first) + ", " +
                       std::to_string(p.second) + ")");
    excluded_pairs_.push_back(bodyPairKey(p.first, p.second));
  }
  std::sort(excluded_pairs_.begin(), excluded_pairs_.end());
  excluded_pairs_.erase(std::unique(excluded_pairs_.begin(), excluded_pairs_.end()), excluded_pairs_.end());
  bool any = false;
  for (uint8_t f : no_contact) any = any || f != 0;
  no_contact_ = any ? std::move(no_contact) : std::vector<uint8_t>{};
  ++exclusions_version_;
}

void System::setProcessGroup(ProcessGroup* group) {
  if (group && config_.solver.type == SolverType::GaussSeidel)
    throw InputError(
        "solver gs: Gauss-Seidel is sequential and does not run over several processes (MPI); use apgd, "
        "jacobi or bb");
  if (group && config_.collision.backend != CollisionBackend::Native)
    throw InputError("collision backend 'bullet': not available over several processes (MPI)");
  group_ = group;
  problem_->setProcessGroup(group);
}

void System::setWarmStart(std::vector<uint64_t> sorted_keys, std::vector<real> impulses, std::vector<Vec3> normals) {
  if (impulses.size() != 3 * sorted_keys.size() || !std::is_sorted(sorted_keys.begin(), sorted_keys.end()))
    throw InputError("warm start: keys must be sorted, with 3 impulses each");
  if (!normals.empty() && normals.size() != sorted_keys.size())
    throw InputError("warm start: " + std::to_string(normals.size()) + " normals for " +
                     std::to_string(sorted_keys.size()) + " keys");
  prev_keys_ = std::move(sorted_keys);
  prev_gamma_ = std::move(impulses);
  prev_roll_.clear();
  prev_normal_ = std::move(normals);
}

void System::addWarmStart(const std::vector<uint64_t>& keys, const std::vector<real>& impulses,
                          const std::vector<Vec3>& normals) {
  if (impulses.size() != 3 * keys.size() || !std::is_sorted(keys.begin(), keys.end()))
    throw InputError("warm start: keys must be sorted, with 3 impulses each");
  if (!normals.empty() && normals.size() != keys.size())
    throw InputError("warm start: " + std::to_string(normals.size()) + " normals for " + std::to_string(keys.size()) +
                     " keys");
  if (keys.empty()) return;
  // The normals stay where the table had them (or was empty) and the added entries bring theirs.
  const bool with_normals = !normals.empty() && prev_normal_.size() == prev_keys_.size();
  std::vector<uint64_t> k;
  std::vector<real> g;
  std::vector<Vec3> nr;
  size_t i = 0, j = 0;
  while (i < prev_keys_.size() || j < keys.size()) {  // a merge; the added entry wins a tie
    const bool add = j < keys.size() && (i == prev_keys_.size() || keys[j] <= prev_keys_[i]);
    if (add && i < prev_keys_.size() && keys[j] == prev_keys_[i]) ++i;
    const uint64_t key = add ? keys[j] : prev_keys_[i];
    const real* src = add ? &impulses[3 * j] : &prev_gamma_[3 * i];
    k.push_back(key);
    g.insert(g.end(), src, src + 3);
    if (with_normals) nr.push_back(add ? normals[j] : prev_normal_[i]);
    (add ? j : i)++;
  }
  prev_keys_ = std::move(k);
  prev_gamma_ = std::move(g);
  prev_roll_.clear();
  prev_normal_ = std::move(nr);
}

void System::collectRows() {
  const size_t before = rows_.size();
  rows_.clear();
  provider_rows_.clear();
  for (const auto& p : row_providers_) {  // each provider appends its rows; remember how many
    const size_t n0 = rows_.size();
    p->rows(bodies_, ctx_, rows_);
    provider_rows_.push_back(rows_.size() - n0);
  }
  if (rows_.size() != before) row_lambda_.clear();  // the rows changed: no warm start for them
}

void System::buildAndSolve() {
  const int64_t nc = int64_t(contacts_.count());
  solution_ = nullptr;
  if (stats_.part_ran[int(StagePart::ConstraintRows)])
    timed(stats_, StageType::BuildRows, [&] { collectRows(); });
  else
    rows_.clear();
  const int64_t nrows = int64_t(rows_.size());
  if (group_ && nrows > 0) throw InputError("constraint rows (joints, drives) do not run over several processes (MPI)");
  const int64_t nblk = nc + (nrows + 2) / 3;
  // Over several processes a process without contacts still takes part in the solve's reductions and exchanges.
  if (nblk == 0 && !group_) {
    gamma_.clear();
    prev_keys_.clear();
    prev_gamma_.clear();
    prev_roll_.clear();
    prev_normal_.clear();
    row_lambda_.clear();
    stats_.part_ran[int(StagePart::FrictionRows)] = false;
    stats_.part_reason[int(StagePart::FrictionRows)] = "no contacts";
    leaveOut(StageType::BuildRows, "no contacts and no constraint rows");
    leaveOut(StageType::WarmStart, "no contacts and no constraint rows");
    leaveOut(StageType::Solve, "no contacts and no constraint rows");
    return;
  }
  timed(stats_, StageType::BuildRows, [&] { buildProblem(nc); });
  // The impulse vector: 3 per contact, 3 per rolling block, then the rows (3 per block).
  const int64_t nroll = problem_->rollingBlocks();
  const int64_t row0 = 3 * (nc + nroll);
  gamma_.assign(size_t(row0 + 3 * ((nrows + 2) / 3)), real(0));
  if (config_.solver.warm_start && int64_t(row_lambda_.size()) == nrows)
    for (int64_t i = 0; i < nrows; ++i) gamma_[size_t(row0 + i)] = row_lambda_[size_t(i)];
  if (!config_.solver.warm_start)
    leaveOut(StageType::WarmStart, "switched off (SystemConfig::solver.warm_start)");
  else if (prev_keys_.empty())
    leaveOut(StageType::WarmStart, "no contacts in the previous step");
  if (config_.solver.warm_start && !prev_keys_.empty())
    timed(stats_, StageType::WarmStart, [&] { warmStartContacts(nc, nroll); });
  timed(stats_, StageType::Solve, [&] {
    // A normal-only problem solves in its own layout (1 impulse per contact): in and out of gamma_.
    real* x = gamma_.data();
    if (problem_->normalOnly()) {
      x_.resize(size_t(problem_->size()));
      problem_->toSolverLayout(gamma_.data(), x_.data());
      x = x_.data();
    }
    SolverStats s;
    switch (config_.solver.type) {
      case SolverType::Jacobi: s = solveJacobi(*problem_, x, config_.solver); break;
      case SolverType::GaussSeidel: s = solveGaussSeidelThenApgd(x); break;
      case SolverType::APGD: s = solveApgdRowStop(x); break;
      case SolverType::BB: s = solveBB(*problem_, x, config_.solver); break;
    }
    if (problem_->normalOnly()) problem_->fromSolverLayout(x, gamma_.data());
    solution_ = x;
    recordSolve(s);
  });
  row_lambda_.assign(gamma_.begin() + row0, gamma_.begin() + row0 + nrows);
  for (size_t p = 0, offset = 0; p < row_providers_.size(); offset += provider_rows_[p], ++p)
    row_providers_[p]->impulses(row_lambda_.data() + offset, provider_rows_[p]);
  cacheImpulsesByKey(nc);
}

// APGD to its stop; then, where some constraint row's velocity error times the step is still above
// SolverSettings::row_stop, one more APGD from there (warm, so the momentum builds up again at once) to the tighter
// relative tolerance row_stop_tolerance, for at most row_stop_iterations more (and within max_iterations). The
// iterations reported are both runs', the residual the last one's, judged against `tolerance`.
SolverStats System::solveApgdRowStop(real* x) const {
  const SolverSettings& cfg = config_.solver;
  SolverStats s = solveApgd(*problem_, x, cfg);
  if (!(cfg.row_stop > 0) || group_ || !(s.relative_residual > cfg.row_stop_tolerance) ||
      s.iterations >= cfg.max_iterations)
    return s;
  std::vector<real> y(size_t(problem_->size()));
  if (!(problem_->maxRowVelocityError(x, y.data()) * real(ctx_.dt) > cfg.row_stop)) return s;
  SolverSettings more = cfg;
  more.min_iterations = 0;
  more.tolerance = cfg.row_stop_tolerance;
  more.max_iterations = std::min(cfg.row_stop_iterations, cfg.max_iterations - s.iterations);
  SolverStats t = solveApgd(*problem_, x, more);
  t.iterations += s.iterations;
  t.trials += s.trials;
  t.speculated += s.speculated;
  if (cfg.record_history) t.history.insert(t.history.begin(), s.history.begin(), s.history.end());
  finishStats(t, cfg);
  return t;
}

// Gauss-Seidel, finished by APGD where it reached its cap above the tolerance (SolverSettings::gs_apgd_finish);
// the iterations reported are both solvers'.
SolverStats System::solveGaussSeidelThenApgd(real* x) const {
  const SolverSettings& cfg = config_.solver;
  SolverStats s = problem_->solveGaussSeidel(x, cfg);
  if (cfg.gs_apgd_finish <= 0 || !(cfg.tolerance > 0) || s.relative_residual <= cfg.tolerance) return s;
  SolverSettings a = cfg;
  a.type = SolverType::APGD;
  a.min_iterations = 0;
  a.max_iterations = cfg.gs_apgd_finish;
  const int gs_iterations = s.iterations;
  s = solveApgd(*problem_, x, a);
  s.iterations += gs_iterations;
  return s;
}

// BuildRows after the row collection: each contact's friction, size and rolling coefficients, the step's parts, and
// the contact problem.
void System::buildProblem(int64_t nc) {
  const FrictionCombine rule = config_.collision.friction_combine;
  struct Max {
    real pen = 0, mu = 0;
  };
  const Max mx = parallelReduce(
      nc, ompTeam(), Max{},
      [&](int64_t k, Max& m) {
        real fa = bodies_.friction[contacts_.body_a[k]], fb = bodies_.friction[contacts_.body_b[k]];
        contacts_.mu[k] = rule == FrictionCombine::Product ? fa * fb
                          : rule == FrictionCombine::Min   ? fmin(fa, fb)
                                                           : real(0.5) * (fa + fb);
        contacts_.size[k] = fmin(shapes_.shape[contacts_.shape_a[k]].size, shapes_.shape[contacts_.shape_b[k]].size);
        m.pen = fmax(m.pen, -contacts_.dist[k]);
        m.mu = fmax(m.mu, contacts_.mu[k]);
      },
      [](Max& t, const Max& m) {
        t.pen = fmax(t.pen, m.pen);
        t.mu = fmax(t.mu, m.mu);
      });
  const real max_pen = mx.pen, max_mu = mx.mu;
  stats_.max_penetration = max_pen;
  // Rolling blocks only for contacts with rolling or spinning friction (docs/MODEL.md §6).
  if (group_ && hasRollingBodies())
    throw InputError("rolling or spinning friction does not run over several processes (MPI)");
  const bool rolling_bodies = nc > 0 && hasRollingBodies();
  const bool rolling = rolling_bodies && combineRolling(nc);
  stats_.part_ran[int(StagePart::RollingSpinningRows)] = rolling;
  stats_.part_reason[int(StagePart::RollingSpinningRows)] =
      rolling ? nullptr
              : (rolling_bodies ? "no contact with rolling or spinning friction this step"
                                : "no body has rolling or spinning friction");
  // Friction rows only where mu > 0 (docs/MODEL.md §6): a step whose contacts are all frictionless solves the
  // normal rows alone (jacobian.h); the solution is the same (its tangential impulses would be 0).
  // Over several processes the choice is the whole problem's: some contact anywhere, none with mu > 0.
  const bool normal_only = group_ ? config_.prune && group_->any(nc > 0) && !group_->any(max_mu > 0)
                                  : config_.prune && nc > 0 && !(max_mu > 0) && !rolling;
  stats_.normal_only = normal_only;
  stats_.part_ran[int(StagePart::FrictionRows)] = nc > 0 && !normal_only;
  stats_.part_reason[int(StagePart::FrictionRows)] = nc == 0       ? "no contacts"
                                                     : normal_only ? "no contact with mu > 0 this step"
                                                                   : nullptr;
  ContactProblemSettings ps;
  ps.threads = omp_get_max_threads();
  ps.normal_only = normal_only;
  // Only the Jacobi solver reads the Jacobi steps; the block inverses only Jacobi's and Gauss-Seidel's Inverse3x3.
  const SolverType type = config_.solver.type;
  ps.jacobi_steps = type == SolverType::Jacobi;
  ps.block_inverses = (type == SolverType::Jacobi || type == SolverType::GaussSeidel) &&
                      config_.solver.block_scaling == BlockScaling::Inverse3x3;
  ps.gs_blocks = type == SolverType::GaussSeidel;
  ps.float_jacobians =
      config_.solver.type == SolverType::APGD && floatStorage(config_.solver, false) && !std::is_same_v<real, float>;
  problem_->build(bodies_, contacts_, v_free_.data(), w_free_.data(), ctx_, config_.solver, ps, &rows_,
                  rolling ? roll_coef_.data() : nullptr);
}

// WarmStart: each contact's (and its rolling block's) impulses from last step's by persistent key.
// A contact's key is looked up first just after the previous contact's match (contacts mostly come in last
// step's order), then by binary search.
void System::warmStartContacts(int64_t nc, int64_t nroll) {
  const size_t np = prev_keys_.size();
  if (nc == 0) return;
  // Contacts [lo, hi), `next` carried from one contact to the next (a thread's own in the team).
  auto range = [&](int64_t lo, int64_t hi) {
    size_t next = np;  // where the previous contact's key matched, plus one
    for (int64_t k = lo; k < hi; ++k) {
      const uint64_t key = contacts_.key[k];
      size_t j = next;
      if (j >= np || prev_keys_[j] != key) {
        j = size_t(std::lower_bound(prev_keys_.begin(), prev_keys_.end(), key) - prev_keys_.begin());
        if (j == np || prev_keys_[j] != key) continue;
      }
      next = j + 1;
      for (int r = 0; r < 3; ++r) gamma_[3 * k + r] = prev_gamma_[3 * j + r];
      const int32_t q = nroll > 0 ? problem_->rollingIndex(k) : -1;
      if (q >= 0 && !prev_roll_.empty())
        for (int r = 0; r < 3; ++r) gamma_[size_t(3 * (nc + q) + r)] = prev_roll_[3 * j + r];
    }
  };
  // A small problem (or one thread) enters no OpenMP region (base/parallel_for.h: a region costs ~0.4 us even for
  // a team of one); the result is the same either way (each contact's copy is independent).
  const int team = ompTeam();
  if (team <= 1 || nc < kSerialContacts) return range(0, nc);
#pragma omp parallel num_threads(team)
  {
    const int64_t t = omp_get_thread_num(), T = omp_get_num_threads();
    range(nc * t / T, nc * (t + 1) / T);
  }
}

// This step's contact impulses, sorted by key, for the next step's warm start.
void System::cacheImpulsesByKey(int64_t nc) {
  std::vector<size_t> order(static_cast<size_t>(nc));
  std::iota(order.begin(), order.end(), size_t(0));
  if (!std::is_sorted(contacts_.key.begin(), contacts_.key.end()))
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return contacts_.key[a] < contacts_.key[b]; });
  prev_keys_.resize(size_t(nc));
  prev_gamma_.resize(size_t(3 * nc));
  prev_normal_.resize(size_t(nc));
  const bool rolling = problem_->rollingBlocks() > 0;
  prev_roll_.assign(rolling ? size_t(3 * nc) : size_t(0), real(0));
  for (size_t i = 0; i < size_t(nc); ++i) {
    prev_keys_[i] = contacts_.key[order[i]];
    prev_normal_[i] = contacts_.normal[order[i]];
    for (int r = 0; r < 3; ++r) prev_gamma_[3 * i + r] = gamma_[3 * order[i] + r];
    const int32_t q = rolling ? problem_->rollingIndex(int64_t(order[i])) : -1;
    if (q >= 0)
      for (int r = 0; r < 3; ++r) prev_roll_[3 * i + r] = gamma_[size_t(3 * (nc + q) + r)];
  }
}

int32_t System::rollingIndex(size_t k) const {
  return k < contacts_.count() && !gamma_.empty() ? problem_->rollingIndex(int64_t(k)) : -1;
}

Vec3 System::rollingImpulse(size_t k) const {
  const int32_t q = rollingIndex(k);
  if (q < 0) return Vec3{0, 0, 0};
  Vec3 u, w;
  tangentBasis(contacts_.normal[k], u, w);
  const real* g = &gamma_[3 * (contacts_.count() + size_t(q))];
  // the problem's rolling unknowns are the angular impulses divided by a length (contact_problem.h)
  return (contacts_.normal[k] * g[0] + u * g[1] + w * g[2]) * problem_->rollingLength(q);
}

void System::integrate() {
  const int64_t n = int64_t(bodies_.count());
  timed(stats_, StageType::IntegrateVelocities, [&] {
    parallelFor(int64_t(n), ompTeam(), [&](int64_t i) {
      bodies_.vel[i] = v_free_[i];
      bodies_.omega[i] = w_free_[i];
    });
    // Over several processes every process applies (and exchanges) its share, with or without contacts.
    if ((gamma_.empty() || !solution_) && !group_) return;
    problem_->applyImpulses(solution_, bodies_.vel.data(), bodies_.omega.data());
  });
  timed(stats_, StageType::IntegratePositions, [&] {
    const real h = ctx_.dt;
    parallelFor(int64_t(n), ompTeam(), [&](int64_t i) {
      integrateBodyPosition(bodies_.pos[i], bodies_.rot[i], bodies_.vel[i], bodies_.omega[i], bodies_.flags[i], h);
      bodies_.force[i] = bodies_.torque[i] = Vec3{0, 0, 0};
    });
  });
}

Vec3 System::contactForce(size_t k) const {
  Vec3 u, w;
  tangentBasis(contacts_.normal[k], u, w);
  const real* g = &gamma_[3 * k];
  return (contacts_.normal[k] * g[0] + u * g[1] + w * g[2]) / ctx_.dt;  // the last step's h
}

uint64_t System::stateHash() const {
  uint64_t h = 1469598103934665603ull;  // FNV-1a (Fowler, Noll, Vo)
  auto mix = [&](const void* p, size_t bytes) {
    const unsigned char* c = static_cast<const unsigned char*>(p);
    for (size_t i = 0; i < bytes; ++i) h = (h ^ c[i]) * 1099511628211ull;
  };
  mix(bodies_.pos.data(), bodies_.pos.size() * sizeof(Vec3));
  mix(bodies_.rot.data(), bodies_.rot.size() * sizeof(Quat));
  mix(bodies_.vel.data(), bodies_.vel.size() * sizeof(Vec3));
  mix(bodies_.omega.data(), bodies_.omega.size() * sizeof(Vec3));
  return h;
}

}  // namespace dvi
