// The CES machine (machine.h): bodies, field, drive, feeder, post-step charge and status, checkpoints.
#include "ces/machine.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <istream>
#include <ostream>
#include <sstream>
#include <unordered_map>

#include "chrono_like/base/errors.h"
#include "chrono_like/base/checksum.h"

namespace dvi {
namespace ces {

namespace {

// The feeder's recent spawns, for its overlap test (CesMachine::emit): a candidate sphere overlaps a spawn when
// their centres are closer than the sum of their bounding radii (positions read live from the body arrays).
// Pairwise over the spawns, or through a uniform grid (a hash of cells about a bounding diameter across: each spawn
// is listed in every cell its bounding sphere's box touches, a candidate tests the spawns listed in the cells its
// own box touches; two spheres that overlap share a point, so they share that point's cell). The grid is linear in
// the spawns where the pairwise test is quadratic (a feed of 1e6 g/s spawns ~25,000 particles a 10 us step), but
// building it costs ~8 hash insertions per spawn, ~100x a pairwise test: for a few candidates the pairwise test is
// cheaper (an industrial feed's ~4 a step beside ~1000 spawns: the grid made the CES benchmark's machine part 5x).
// Same answer either way.
class SpawnIndex {
 public:
  static constexpr size_t kGridFrom = 64;  // candidates from which the grid pays
  // pos and bound are the live arrays: they grow as the feeder adds particles.
  SpawnIndex(const std::vector<Vec3>& pos, const std::vector<real>& bound, bool grid, double cell)
      : pos_(pos), bound_(bound), use_grid_(grid), cell_(cell) {}
  void insert(int32_t body) {
    const Vec3& q = pos_[size_t(body)];
    if (!isFinite(q)) return;  // never within a finite distance of a candidate
    if (!use_grid_) {
      list_.push_back(body);
      return;
    }
    cells(q, bound_[size_t(body)], [&](uint64_t k) {
      grid_[k].push_back(body);
      return true;
    });
  }
  bool overlaps(const Vec3& q, real r) const {
    auto near = [&](int32_t body) { return length(pos_[size_t(body)] - q) < bound_[size_t(body)] + r; };
    if (!use_grid_) return std::any_of(list_.begin(), list_.end(), near);
    bool hit = false;
    cells(q, r, [&](uint64_t k) {
      const auto it = grid_.find(k);
      if (it != grid_.end()) hit = std::any_of(it->second.begin(), it->second.end(), near);
      return !hit;
    });
    return hit;
  }

 private:
  static constexpr int64_t kSpan = int64_t(1) << 20;  // cell coordinates clamped to +-2^20 (21 bits each in the key)
  int64_t coord(double x) const {
    const double c = std::floor(x / cell_);
    return int64_t(c < double(-kSpan) ? double(-kSpan) : c > double(kSpan) ? double(kSpan) : c);
  }
  static uint64_t key(int64_t ix, int64_t iy, int64_t iz) {
    return uint64_t(ix + kSpan) << 42 | uint64_t(iy + kSpan) << 21 | uint64_t(iz + kSpan);
  }
  // The cells of the box of a sphere at q of radius r (widened a little against the rounding of the test).
  template <class Visit>
  void cells(const Vec3& q, real r, Visit&& visit) const {
    const double w = double(r) * (1 + 1e-6) + 1e-12;
    const int64_t x0 = coord(double(q.x) - w), x1 = coord(double(q.x) + w), y0 = coord(double(q.y) - w),
                  y1 = coord(double(q.y) + w), z0 = coord(double(q.z) - w), z1 = coord(double(q.z) + w);
    for (int64_t ix = x0; ix <= x1; ++ix)
      for (int64_t iy = y0; iy <= y1; ++iy)
        for (int64_t iz = z0; iz <= z1; ++iz)
          if (!visit(key(ix, iy, iz))) return;
  }
  const std::vector<Vec3>& pos_;
  const std::vector<real>& bound_;
  bool use_grid_;
  double cell_;
  std::vector<int32_t> list_;
  std::unordered_map<uint64_t, std::vector<int32_t>> grid_;
};

constexpr int16_t kGroupParticle = 1, kGroupMachine = 2;
constexpr real kBinDrop = real(0.05);  // m below the collection plane where collected particles are kept

ShapeDesc machineShape(ShapeDesc s) {
  s.shape.group = kGroupMachine;
  s.shape.mask = kGroupParticle;
  return s;
}

// Cylinder shapes have their axis along local y; the machine's cylinders lie along world z.
Quat axisZ() { return quatFromAxisAngle(Vec3{1, 0, 0}, real(1.5707963267948966)); }

// Binary I/O of plain values and vectors (checkpoints).
template <class T>
void put(std::ostream& o, const T& v) {
  o.write(reinterpret_cast<const char*>(&v), sizeof(T));
}
template <class T>
void putVec(std::ostream& o, const std::vector<T>& v) {
  put(o, uint64_t(v.size()));
  if (!v.empty()) o.write(reinterpret_cast<const char*>(v.data()), std::streamsize(v.size() * sizeof(T)));
}
template <class T>
void get(std::istream& i, T& v) {
  i.read(reinterpret_cast<char*>(&v), sizeof(T));
  if (!i) throw InputError("checkpoint: truncated file");
}
// Bytes left in the stream (a checkpoint is read from a file or a string: both can seek).
inline uint64_t bytesLeft(std::istream& i) {
  const std::streampos here = i.tellg();
  if (here < 0) return 0;
  i.seekg(0, std::ios::end);
  const std::streampos end = i.tellg();
  i.seekg(here);
  return end > here ? uint64_t(end - here) : 0;
}
template <class T>
void getVec(std::istream& i, std::vector<T>& v) {
  uint64_t n = 0;
  get(i, n);
  // A length beyond what the file holds is refused before anything is allocated for it.
  if (n > bytesLeft(i) / sizeof(T))
    throw InputError("checkpoint: corrupt array length " + std::to_string(n) + " (truncated file)");
  v.resize(size_t(n));
  if (n) i.read(reinterpret_cast<char*>(v.data()), std::streamsize(n * sizeof(T)));
  if (!i) throw InputError("checkpoint: truncated file");
}
template <class... T>
void getVecs(std::istream& i, std::vector<T>&... v) {
  (getVec(i, v), ...);
}

// A provider with one row: body 0's x velocity = 1.
class ProbeRow : public RowProvider {
 public:
  void rows(const BodyArrays&, const StepContext&, std::vector<ConstraintRow>& out) override {
    ConstraintRow r;
    r.a = 0;
    r.Ja[0] = 1;
    r.bias = -1;
    out.push_back(r);
  }
};

}  // namespace

bool coreSolvesConstraintRows() {
  SystemConfig c;
  c.step.dt = real(1e-3);
  c.step.gravity = Vec3{0, 0, 0};
  System s(c);
  BodyDesc d;
  d.shapes.push_back(makeSphere(real(0.1)));
  s.addBody(d);
  s.addRowProvider(std::make_shared<ProbeRow>());
  s.step();
  return !s.constraintRows().empty() && std::fabs(s.bodies().vel[0].x - real(1)) < real(1e-6);
}

// ---------------------------------------------------------------------------------------------------
// Plug-ins
// ---------------------------------------------------------------------------------------------------

void CesForceField::apply(const BodyArrays& b, const StepContext& step, Vec3* force, Vec3* torque) {
  const real dt = step.dt;
  const CesParticles& p = m_.p_;
  const CesModel& model = m_.model_;
  const int64_t n = int64_t(std::min(p.count(), b.count()));
  const Vec3 w_drum = b.omega[size_t(model.drum_body)];
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < n; ++i) {
    const size_t k = size_t(i);
    if (p.status[k] != kStatusInFlight || (b.flags[k] & kBodyFixed)) continue;
    const Vec3 F = cesParticleForce(model, p.electro[k], b.pos[k], b.rot[k], b.vel[k], p.charge[k], p.radius[k],
                                    p.bound[k], p.mass[k], dt);
    force[i] += F;
    torque[i] += cesParticleTorque(model, p.electro[k], b.pos[k], b.rot[k], b.vel[k], b.omega[k], w_drum, F,
                                   p.radius[k], p.mass[k], p.moment[k], dt);
  }
}

bool CesForceField::applyOnDevice(const DeviceBodyRefs& b, const StepContext& step, Vec3* force, Vec3* torque) {
  if (!m_.dev_) return false;
  m_.dev_->forces(b, step.dt, force, torque);
  return true;
}

void DrumDrive::rows(const BodyArrays& b, const StepContext& step, std::vector<ConstraintRow>& out) {
  const real dt = step.dt;
  dt_ = dt;
  const Vec3 p = b.pos[size_t(body_)];
  const Vec3 err = p - centre_;
  const real e[3] = {err.x, err.y, err.z};
  for (int k = 0; k < 3; ++k) {  // centre fixed: v_k + C_k / h = 0
    ConstraintRow r;
    r.a = body_;
    r.Ja[k] = 1;
    r.bias = e[k] / dt;
    out.push_back(r);
  }
  // Axis along z: the rotation vector theta = a x z brings the drum's axis a onto z; w_k = theta_k / h.
  const Vec3 a = rotate(b.rot[size_t(body_)], Vec3{0, 1, 0});
  const Vec3 theta = cross(a, Vec3{0, 0, 1});
  const real th[2] = {theta.x, theta.y};
  for (int k = 0; k < 2; ++k) {
    ConstraintRow r;
    r.a = body_;
    r.Ja[3 + k] = 1;
    r.bias = -th[k] / dt;
    out.push_back(r);
  }
  ConstraintRow drive;  // rheonomic: omega_z = omega(t)
  drive.a = body_;
  drive.Ja[5] = 1;
  drive.bias = -real(omega(step.end()));
  out.push_back(drive);
}

void DrumDrive::impulses(const real* lambda, size_t count) {
  if (count >= 6 && dt_ > 0) torque_ = double(lambda[5]) / double(dt_);
}

// ---------------------------------------------------------------------------------------------------
// Construction
// ---------------------------------------------------------------------------------------------------

CesMachine::CesMachine(const CesConfig& cfg, System& sys) : cfg_(cfg), sys_(sys), feeder_(cfg_) {
  if (sys_.bodies().count() != 0) throw InputError("CES machine: the system must be empty");
  if (cfg_.materials.size() > size_t(kMaxMaterials)) throw InputError("CES machine: at most 64 materials");
  if (cfg_.extra_electrodes.size() + 2 > size_t(kMaxElectrodes))
    throw InputError("CES machine: at most 6 extra electrodes");
  if (!(cfg_.step.dt > 0 && std::isfinite(cfg_.step.dt)))
    throw InputError("CES machine: the time step (ces.time_step_s) must be positive and finite");
  // The machine's step into the System (see cesDefaultStep); the machine reads it from the System from here on.
  sys_.mutableConfig().step.dt = cfg_.step.dt;
  sys_.mutableConfig().step.gyroscopic = cfg_.step.gyroscopic;
  // Pair coefficients under the product rule (Bullet's, the core's default): f_particle^2 = mu_pp and
  // f_particle f_part = mu_(particle, part).
  particle_friction_ = real(std::sqrt(cfg_.mu_particle_particle));

  std::vector<ElectrodeConfig> supplied;  // the enabled wire and tube (both at the supply's voltage)
  if (cfg_.wire.enabled) supplied.push_back(cfg_.wire);
  if (cfg_.tube.enabled) supplied.push_back(cfg_.tube);
  setupField(supplied);
  setupModel(supplied);

  // The machine's bodies, in this order (body indices, and so the trajectories, depend on it): drum, brush,
  // electrodes, end walls.
  addDrumBody();
  addBrushBody();
  addElectrodeBodies();
  addEndWalls();
  n_machine_ = int(sys_.bodies().count());

  field_ = std::make_shared<CesForceField>(*this);
#ifdef DVISIM_HAVE_CUDA
  DeviceBodyRefs refs;
  if (sys_.deviceBodies(refs)) dev_ = makeCesDevice(model_);
#endif
  host_forces_ = sys_.backendName() != "cpu" && !dev_;
  sys_.addForceField(field_);  // without CesDevice a device backend runs it as a host plug-in
}

// Field: the model's solution (two-cylinder, charge simulation or corona) behind model_.field.
void CesMachine::setupField(const std::vector<ElectrodeConfig>& supplied) {
  const real R = real(cfg_.drumRadius());
  if (cfg_.field_model == "two_cylinder") {
    const ElectrodeConfig& e = cfg_.tube;
    model_.field.model = 0;
    if (!makeTwoCylinderField(R, real(e.diameter / 2), real(e.distance), real(e.angle), real(cfg_.voltage), 0, 0,
                              model_.field.tc))
      throw InputError("ces.electrode.tube: the two-cylinder field needs the tube outside the drum");
  } else if (cfg_.field_model == "csm") {
    model_.field.model = 1;
    csm_.addCylinder(0, 0, R, 0);
    std::vector<ElectrodeConfig> all = supplied;
    all.insert(all.end(), cfg_.extra_electrodes.begin(), cfg_.extra_electrodes.end());
    for (const ElectrodeConfig& x : all)
      csm_.addCylinder(real(x.distance * std::cos(x.angle)), real(x.distance * std::sin(x.angle)), real(x.diameter / 2),
                       real(x.voltage));
    csm_.solve();
    model_.field.csm = csm_.view();
  } else {  // corona: wire + optional tube on the supply
    setupCoronaField();
  }
}

// The corona model: the wire and the optional tube on the supply, solved on a grid.
void CesMachine::setupCoronaField() {
  const real R = real(cfg_.drumRadius());
  model_.field.model = 2;
  CoronaSetup st;
  auto cyl = [](const ElectrodeConfig& e) {
    return CoronaCylinder{real(e.distance * std::cos(e.angle)), real(e.distance * std::sin(e.angle)),
                          real(e.diameter / 2), e.enabled};
  };
  st.drum = CoronaCylinder{0, 0, R, true};
  st.wire = cyl(cfg_.wire);
  st.tube = cyl(cfg_.tube);
  st.U = real(cfg_.voltage);
  st.ion_mobility = real(cfg_.ion_mobility);
  st.rel_air_density = real(cfg_.rel_air_density);
  st.roughness = real(cfg_.roughness);
  // The box covers every place a particle reaches before it is collected or lost: the drum, the
  // electrodes, the trajectories down to below the collection plane (outside it the box's edge value is
  // used; the field there is a small fraction of the drum's).
  const real h = real(cfg_.corona_grid);
  st.box_x0 = -R - real(0.10);
  st.box_x1 = real(0.45);
  st.box_y0 = std::min(real(cfg_.collection_y) - real(0.02), -R - real(0.02));
  st.box_y1 = R + real(0.10);
  for (const ElectrodeConfig* e : {&cfg_.wire, &cfg_.tube})
    if (e->enabled) {
      st.box_x1 = std::max(st.box_x1, real(e->distance * std::cos(e->angle) + e->diameter / 2) + real(0.02));
      st.box_y1 = std::max(st.box_y1, real(e->distance * std::sin(e->angle) + e->diameter / 2) + real(0.02));
    }
  st.spacing = h;
  const CoronaSolution& sol = corona_field_.solve(st);
  model_.field.grid = corona_field_.view();
  corona_.ionised = sol.ionised;
  corona_.onset_voltage = double(sol.onset_voltage);
  corona_.wire_field_on = double(sol.wire_field_on);
  corona_.current_per_m = double(sol.current_per_m);
}

// The rest of the model the force field and the classification read: drum, brush, electrodes, air, domain,
// materials.
void CesMachine::setupModel(const std::vector<ElectrodeConfig>& supplied) {
  const real R = real(cfg_.drumRadius()), W = real(cfg_.drum_width);
  model_.drum = DrumGeometry{0, 0, R, 0, W / 2, real(cfg_.image_cutoff)};
  model_.polarity = cfg_.voltage < 0 ? real(-1) : cfg_.voltage > 0 ? real(1) : real(0);
  model_.ion_mobility = real(cfg_.ion_mobility);
  model_.pin_dy = -R * real(std::cos(20.0 * 3.14159265358979323846 / 180.0));  // within 20 deg of the lowest point
  // The brush's axis: its bristle tips (radius rb) brush_gap from the drum (its rigid core is the body, addBrushBody).
  const real rb = real(cfg_.brush_diameter / 2), db = R + rb + real(cfg_.brush_gap);
  model_.brush = CylinderXY{db * real(std::cos(cfg_.brush_angle)), db * real(std::sin(cfg_.brush_angle)), rb};
  model_.brush_omega = real(cfg_.omegaBrush());
  model_.brush_tau = real(cfg_.brush_discharge_time);
  model_.brush_sweep_tau = real(cfg_.brush_sweep_time);
  model_.n_electrodes = 0;
  auto addElectrode = [&](const ElectrodeConfig& x) {
    model_.electrodes[model_.n_electrodes++] =
        CylinderXY{real(x.distance * std::cos(x.angle)), real(x.distance * std::sin(x.angle)), real(x.diameter / 2)};
  };
  for (const ElectrodeConfig& x : supplied) addElectrode(x);
  for (const ElectrodeConfig& x : cfg_.extra_electrodes) addElectrode(x);
  model_.air_density = real(cfg_.air_density);
  model_.air_viscosity = real(cfg_.air_viscosity);
  model_.contact_tol = real(1.1);  // a sphere within 1.1 r of the drum's surface touches it (true distance + 0.1 r)
  model_.rolling_drum = real(cfg_.mu_rolling_drum);
  model_.gravity = sys_.config().step.gravity;
  model_.collect_y = real(cfg_.collection_y);
  model_.domain_x_lo = real(-1);
  model_.domain_x_hi = real(1);
  model_.domain_y_hi = real(1);
  model_.domain_half_z = W / 2 + real(0.01);
  model_.n_materials = int32_t(cfg_.materials.size());
  for (size_t k = 0; k < cfg_.materials.size(); ++k) {
    model_.kind[k] = int32_t(cfg_.materials[k].kind);
    model_.eps_r[k] = real(cfg_.materials[k].eps_r);
    model_.tau[k] = real(cfg_.materials[k].relaxation_time);
  }
}

// Drum: kinematic, or (rheonomic) a dynamic body driven at its speed by a constraint row (DrumDrive).
void CesMachine::addDrumBody() {
  const real R = real(cfg_.drumRadius()), W = real(cfg_.drum_width);
  std::string drive = cfg_.drum_drive;
  if (drive == "auto") drive = coreSolvesConstraintRows() ? "rheonomic" : "kinematic";
  if (drive == "rheonomic" && !coreSolvesConstraintRows())
    throw InputError(
        "ces.drum.drive: rheonomic needs a core that solves constraint rows (this build does not); use kinematic");
  BodyDesc d;
  d.rot = axisZ();
  d.omega = Vec3{0, 0, real(cfg_.omegaDrum())};
  d.friction = real(cfg_.mu_particle_drum) / particle_friction_;
  d.shapes.push_back(machineShape(makeCylinder(R, W / 2)));
  if (drive == "rheonomic") {
    const real M = real(cfg_.drum_mass);
    d.mass = M;
    d.inertia =
        Vec3{M * (6 * R * R + W * W) / 12, M * R * R, M * (6 * R * R + W * W) / 12};  // thin shell, axis local y
    d.has_gravity = true;  // the truss carries its weight: no gravity on the drum
    d.gravity = Vec3{0, 0, 0};
  } else {
    d.mass = 0;
    d.flags = kBodyKinematic;
  }
  drum_ = addBody(d, -1, nullptr, 0);
  model_.drum_body = drum_;
  if (drive == "rheonomic") {
    drive_ = std::make_shared<DrumDrive>(drum_, Vec3{0, 0, 0}, cfg_.omegaDrum());
    sys_.addRowProvider(drive_);
  }
}

// Brush: a kinematic cylinder of its rigid core's radius (rc) on the axis setupModel placed.
void CesMachine::addBrushBody() {
  const real rc = real(cfg_.brush_core_diameter / 2), W = real(cfg_.drum_width);
  BodyDesc d;
  d.pos = Vec3{model_.brush.cx, model_.brush.cy, 0};
  d.rot = axisZ();
  d.omega = Vec3{0, 0, real(cfg_.omegaBrush())};
  d.mass = 0;
  d.flags = kBodyKinematic;
  d.friction = real(cfg_.mu_particle_brush) / particle_friction_;
  d.shapes.push_back(machineShape(makeCylinder(rc, W / 2)));
  brush_ = addBody(d, -1, nullptr, 0);
}

// Electrodes: fixed cylinders, in model_.electrodes' order.
void CesMachine::addElectrodeBodies() {
  const real W = real(cfg_.drum_width);
  for (int k = 0; k < model_.n_electrodes; ++k) {
    BodyDesc d;
    d.pos = Vec3{model_.electrodes[k].cx, model_.electrodes[k].cy, 0};
    d.rot = axisZ();
    d.mass = 0;
    d.flags = kBodyFixed;
    d.friction = real(cfg_.mu_particle_wall) / particle_friction_;
    d.shapes.push_back(machineShape(makeCylinder(model_.electrodes[k].R, W / 2)));
    addBody(d, -1, nullptr, 0);
  }
}

// End walls: solid beyond z = +-W/2.
void CesMachine::addEndWalls() {
  const real W = real(cfg_.drum_width);
  for (int side = -1; side <= 1; side += 2) {
    BodyDesc d;
    d.mass = 0;
    d.flags = kBodyFixed;
    d.friction = real(cfg_.mu_particle_wall) / particle_friction_;
    d.shapes.push_back(machineShape(makePlane(Vec3{0, 0, real(-side)}, -W / 2)));
    addBody(d, -1, nullptr, 0);
  }
}

int CesMachine::addBody(const BodyDesc& d, int material, const ParticleSpec* spec, real charge) {
  const int id = sys_.addBody(d);
  p_.status.push_back(material < 0 ? kStatusMachine : kStatusInFlight);
  p_.material.push_back(material);
  p_.charge.push_back(charge);
  p_.flags.push_back(0);
  p_.radius.push_back(spec ? spec->radius : real(0));
  p_.bound.push_back(spec ? spec->bound : real(0));
  p_.mass_fg.push_back(spec ? spec->mass_fg : 0);
  p_.mass.push_back(spec ? real(double(spec->mass_fg) * kFemtogram) : real(0));
  p_.moment.push_back(spec ? std::min(spec->inertia.x, std::min(spec->inertia.y, spec->inertia.z)) : real(0));
  if (spec) {
    ParticleSpec s = *spec;
    compositeParts(s, cfg_.materials[size_t(material)]);
    p_.electro.push_back(makeParticleElectro(s, cfg_.materials[size_t(material)]));
    specs_.push_back(std::move(s));
  } else {
    p_.electro.push_back(ParticleElectro{});
  }
  return id;
}

double CesMachine::tubeSurfaceField() const {
  if (!cfg_.tube.enabled) return std::nan("");
  const double cx = cfg_.tube.distance * std::cos(cfg_.tube.angle), cy = cfg_.tube.distance * std::sin(cfg_.tube.angle);
  const double rs = cfg_.tube.diameter / 2 * (1 + 1e-4);  // just outside: region 0
  double emax = 0;
  for (int k = 0; k < 360; ++k) {
    const double a = 2 * 3.14159265358979323846 * k / 360;
    const FieldSample f = field(Vec3{real(cx + rs * std::cos(a)), real(cy + rs * std::sin(a)), real(0)});
    emax = std::max(emax, double(length(f.E)));
  }
  return emax;
}

int CesMachine::addParticle(const ParticleSpec& spec, Vec3 pos, Quat rot, Vec3 vel, Vec3 omega, real charge) {
  if (spec.material < 0 || size_t(spec.material) >= cfg_.materials.size())
    throw InputError("CES machine: particle material " + std::to_string(spec.material) + " out of range");
  BodyDesc d;
  d.pos = pos;
  d.rot = rot;
  d.vel = vel;
  d.omega = omega;
  d.mass = real(double(spec.mass_fg) * kFemtogram);
  d.inertia = spec.inertia;
  d.friction = particle_friction_;
  d.shapes.push_back(particleShapeDesc(spec));
  return addBody(d, spec.material, &spec, charge);
}

// ---------------------------------------------------------------------------------------------------
// Step
// ---------------------------------------------------------------------------------------------------

void CesMachine::emit() {
  std::vector<ParticleSpec> due;
  const double t = time(), h = sys_.config().step.dt;  // the step about to run
  feeder_.emit(t, h, due);
  // Forget spawns older than 50 ms: they have left the outlet.
  const BodyArrays& b = sys_.bodies();
  const real R = real(cfg_.drumRadius());
  const real ux = real(std::cos(cfg_.feed_angle)), uy = real(std::sin(cfg_.feed_angle));
  const real dir = cfg_.drum_rpm >= 0 ? real(1) : real(-1);
  const Vec3 tangent{dir * uy, -dir * ux, 0};  // the drum surface's direction of motion at the outlet
  const int64_t keep = std::max<int64_t>(1, int64_t(std::llround(0.05 / h)));
  recent_.erase(
      std::remove_if(recent_.begin(), recent_.end(), [&](const RecentSpawn& r) { return steps_ - r.step > keep; }),
      recent_.end());
  if (due.empty()) return;
  double bound_sum = 0;
  for (const RecentSpawn& r : recent_) bound_sum += double(p_.bound[size_t(r.body)]);
  for (const ParticleSpec& s : due) bound_sum += double(s.bound);
  // A few candidates (an industrial feed spawns ~4 a step beside ~1000 recent spawns) test every recent spawn; a
  // burst of many uses the grid, where the pairwise test would be quadratic. Both give the same answer.
  SpawnIndex index(b.pos, p_.bound, due.size() >= SpawnIndex::kGridFrom,
                   std::fmax(2.0 * bound_sum / double(recent_.size() + due.size()), 1e-9));  // the mean diameter
  auto insert = [&](int32_t body) { index.insert(body); };
  for (const RecentSpawn& r : recent_) insert(r.body);
  for (const ParticleSpec& s : due) {
    const Quat rot = feeder_.randomRotation();
    const double z = feeder_.uniform(-cfg_.feed_width / 2, cfg_.feed_width / 2);
    const double jitter = feeder_.uniform(-0.002, 0.002);
    Vec3 pos{};
    for (int attempt = 0;; ++attempt) {
      // Outlet line at feed.height above the drum, the particle's lowest point on it; moved outward by a
      // bounding diameter per attempt until it overlaps no recent spawn (deterministic).
      const real rad = R + real(cfg_.feed_height) + s.bound * real(1 + 2 * attempt);
      pos = Vec3{rad * ux + real(jitter) * tangent.x, rad * uy + real(jitter) * tangent.y, real(z)};
      const bool free = !index.overlaps(pos, s.bound);
      if (free || attempt > 50) break;
    }
    const int id = addParticle(s, pos, rot, real(cfg_.feed_speed) * tangent, Vec3{0, 0, 0});
    recent_.push_back(RecentSpawn{id, steps_});
    insert(id);
  }
}

void CesMachine::setCharge(int body, real q) {
  p_.charge[size_t(body)] = q;
  if (dev_ && size_t(body) < dev_uploaded_) dev_->setCharge(body, q);
}

void CesMachine::syncCharges() const {
  if (!dev_ || !charges_stale_) return;
  std::vector<real> q;
  dev_->downloadCharges(q);
  std::copy(q.begin(), q.begin() + std::ptrdiff_t(std::min(q.size(), dev_uploaded_)), p_.charge.begin());
  std::vector<uint8_t> f;
  dev_->downloadFlags(f);
  std::copy(f.begin(), f.begin() + std::ptrdiff_t(std::min(f.size(), dev_uploaded_)), p_.flags.begin());
  charges_stale_ = false;
}

// A machine step with CesDevice: the host reads and edits only the bodies named here.
void CesMachine::stepDevice() {
  std::vector<int32_t> ids{drum_, brush_};                     // their omega is set below
  for (const RecentSpawn& r : recent_) ids.push_back(r.body);  // the feeder's overlap test
  sys_.syncBodiesToHost(ids);
  // The host's charges and flags of earlier particles may be stale here: append() uploads only the new
  // ones, and syncCharges() fetches the first dev_uploaded_ when an output asks.
  emit();
  if (!drive_) sys_.mutableBodies().omega[size_t(drum_)] = Vec3{0, 0, real(cfg_.omegaDrum())};
  sys_.mutableBodies().omega[size_t(brush_)] = Vec3{0, 0, real(cfg_.omegaBrush())};
  sys_.markBodiesDirty({drum_, brush_});
  dev_->append(p_, dev_uploaded_);
  dev_uploaded_ = p_.count();
  sys_.step();
  charges_stale_ = true;
  ++steps_;
  postStepDevice();
}

void CesMachine::postStepDevice() {
  DeviceBodyRefs refs;
  sys_.deviceBodies(refs);
  std::vector<std::pair<int32_t, uint8_t>> changed;
  dev_->postStep(refs, sys_.stepContext().dt, changed);  // the step just taken
  DeviceContactRefs contacts;
  if (sys_.deviceContacts(contacts)) dev_->exchangeCharges(contacts, sys_.stepContext().dt);
  if (changed.empty()) return;
  std::vector<int32_t> ids;
  ids.reserve(changed.size());
  for (const auto& c : changed) ids.push_back(c.first);
  sys_.syncBodiesToHost(ids);
  for (const auto& c : changed) settle(size_t(c.first), c.second);
  sys_.markBodiesDirty(ids);
}

void CesMachine::step() {
  if (dev_) {
    stepDevice();
    return;
  }
  if (host_forces_) sys_.syncToHost();
  emit();
  if (!drive_) sys_.mutableBodies().omega[size_t(drum_)] = Vec3{0, 0, real(cfg_.omegaDrum())};
  sys_.mutableBodies().omega[size_t(brush_)] = Vec3{0, 0, real(cfg_.omegaBrush())};
  if (host_forces_) sys_.markHostDirty();  // the drive's omega (the field runs inside the step)
  sys_.step();
  if (host_forces_) sys_.syncToHost();
  ++steps_;
  postStep();
  if (host_forces_) sys_.markHostDirty();
}

void CesMachine::postStep() {
  BodyArrays& b = sys_.mutableBodies();
  const int64_t n = int64_t(p_.count());
  const real h = sys_.stepContext().dt;  // the step just taken
  const CesModel& m = model_;
  std::vector<uint8_t> next(size_t(n), kStatusMachine);
  const int threads = sys_.effectiveThreads();
#pragma omp parallel for schedule(static) num_threads(threads)
  for (int64_t i = 0; i < n; ++i) {
    const size_t k = size_t(i);
    next[k] = p_.status[k];
    if (p_.status[k] != kStatusInFlight) continue;
    p_.charge[k] =
        cesChargeUpdate(m, p_.electro[k], b.pos[k], b.rot[k], p_.charge[k], p_.radius[k], p_.bound[k], h, p_.flags[k]);
    next[k] = cesClassify(m, b.pos[k]);
  }
  for (int64_t i = n_machine_; i < n; ++i)
    if (next[size_t(i)] != p_.status[size_t(i)]) settle(size_t(i), next[size_t(i)]);
  exchangeContactCharges(h);
}

void CesMachine::exchangeContactCharges(real h) {
  const ContactArrays& c = sys_.contacts();
  const int64_t nc = int64_t(c.count());
  ExchangeScratch& x = exchange_;
  x.held.assign(p_.count(), 0);
  std::vector<uint8_t>& held = x.held;
  for (int64_t k = 0; k < nc; ++k) {
    const int32_t i = heldParticle(p_.status.data(), c.body_a.data(), c.body_b.data(), c.dist.data(), k);
    if (i >= 0) held[size_t(i)] = 1;
  }
  x.partners.assign(p_.count(), 0);
  x.pairs.clear();
  std::vector<int32_t>& partners = x.partners;
  std::vector<int64_t>& pairs = x.pairs;
  for (int64_t k = 0; k < nc; ++k)
    if (exchangesCharge(p_.status.data(), held.data(), c.body_a.data(), c.body_b.data(), c.dist.data(), k)) {
      pairs.push_back(k);
      ++partners[size_t(c.body_a[size_t(k)])];
      ++partners[size_t(c.body_b[size_t(k)])];
    }
  if (pairs.empty()) return;
  x.dq.assign(p_.count(), real(0));
  std::vector<real>& dq = x.dq;
  for (const int64_t k : pairs) {
    const int32_t a = c.body_a[size_t(k)], b = c.body_b[size_t(k)];
    const real f = exchangeFlux(p_.electro.data(), p_.radius.data(), p_.charge.data(), partners.data(), a, b, h);
    dq[size_t(a)] -= f;
    dq[size_t(b)] += f;
  }
  for (size_t i = 0; i < dq.size(); ++i) p_.charge[i] += dq[i];
}

void CesMachine::settle(size_t k, uint8_t next) {
  BodyArrays& b = sys_.mutableBodies();
  p_.status[k] = next;
  if (next == kStatusLost) ++lost_;
  if (next == kStatusCollected) {
    // Crossing point of the collection plane on the step's straight path x - h v .. x.
    const real h = sys_.stepContext().dt;  // the step just taken
    const Vec3 x1 = b.pos[k], x0 = x1 - h * b.vel[k];
    const double f = x0.y > x1.y ? double((x0.y - model_.collect_y) / (x0.y - x1.y)) : 1.0;
    const double fc = std::min(1.0, std::max(0.0, f));
    CollectedParticle c;
    c.body = int32_t(k);
    c.material = p_.material[k];
    c.kind = cfg_.materials[size_t(c.material)].kind;
    c.mass_fg = p_.mass_fg[k];
    c.metal_mass_fraction = compositeMassFraction(k);
    c.x = double(x0.x) + fc * double(x1.x - x0.x) - cfg_.collection_x0;
    c.z = double(x0.z) + fc * double(x1.z - x0.z);
    const double dt = sys_.config().step.dt;  // h in double, as time() counts it
    c.t = time() - dt + fc * dt;
    collected_.push_back(c);
    b.pos[k].y = model_.collect_y - kBinDrop;  // into the bin, out of everyone's way
  }
  b.flags[k] = uint8_t(b.flags[k] | kBodyFixed);  // collected or lost: frozen for good
  b.vel[k] = b.omega[k] = Vec3{0, 0, 0};
}

float CesMachine::compositeMassFraction(size_t k) const {
  const ParticleSpec& s = specs_[k - size_t(n_machine_)];
  return s.mass_fg > 0 ? float(double(s.metal_fg) / double(s.mass_fg)) : 0.0f;
}

bool CesMachine::heldUp(size_t k) const {
  if (p_.status[k] != kStatusInFlight) return false;
  const Vec3 p = sys_.bodies().pos[k];
  if (amongBristles(model_, p, p_.bound[k])) return true;
  const Quat rot = sys_.bodies().rot[k];
  return (p_.flags[k] & kFlagPinned) &&
         touchesDrum(model_, p, drumSupport(model_, p_.electro[k], p, rot), p_.radius[k]);
}

MassBalance CesMachine::balance() const {
  syncCharges();  // the flags
  MassBalance r;
  for (const ParticleSpec& s : specs_) r.fed_fg += s.mass_fg;  // the feeder's and any added by hand
  for (size_t k = size_t(n_machine_); k < p_.count(); ++k) {
    ++r.fed;
    const int64_t mg = p_.mass_fg[k];
    switch (p_.status[k]) {
      case kStatusCollected: r.collected_fg += mg, ++r.collected; break;
      case kStatusLost: r.lost_fg += mg, ++r.lost; break;
      default:
        if (heldUp(k))
          r.held_up_fg += mg, ++r.held_up;
        else
          r.in_flight_fg += mg, ++r.in_flight;
        break;
    }
  }
  return r;
}

// ---------------------------------------------------------------------------------------------------
// Checkpoints
// ---------------------------------------------------------------------------------------------------

namespace {

constexpr size_t kMagicBytes = 8, kHeaderBytes = 16, kTrailerBytes = 8;

// The checked parts of a checkpoint file (machine.h): the metadata and the state bytes.
struct CheckpointParts {
  std::string meta, state;
};

CheckpointParts openCheckpoint(const std::string& f) {
  if (f.size() < kMagicBytes || std::memcmp(f.data(), "DVICES", 6) != 0)
    throw InputError("checkpoint: not a dvisim CES checkpoint");
  if (std::memcmp(f.data(), kCesCheckpointMagic, kMagicBytes) != 0)
    throw InputError("checkpoint: format " + f.substr(0, kMagicBytes) + " is not the current " + kCesCheckpointMagic +
                     " (written by another version of dvisim; rerun from the start)");
  if (f.size() < kHeaderBytes + kTrailerBytes)
    throw InputError("checkpoint: truncated file (" + std::to_string(f.size()) + " bytes)");
  uint64_t stored = 0;
  std::memcpy(&stored, f.data() + f.size() - kTrailerBytes, 8);
  if (fnv1a64(f.data(), f.size() - kTrailerBytes) != stored)
    throw InputError("checkpoint: checksum mismatch (the file was edited, truncated or damaged)");
  uint64_t n = 0;
  std::memcpy(&n, f.data() + kMagicBytes, 8);
  if (n > f.size() - kHeaderBytes - kTrailerBytes)
    throw InputError("checkpoint: corrupt metadata length " + std::to_string(n));
  CheckpointParts p;
  p.meta = f.substr(kHeaderBytes, size_t(n));
  p.state = f.substr(kHeaderBytes + size_t(n), f.size() - kHeaderBytes - kTrailerBytes - size_t(n));
  return p;
}

}  // namespace

std::string cesCheckpointMeta(const std::string& bytes) { return openCheckpoint(bytes).meta; }

void resealCesCheckpoint(std::string& f) {
  if (f.size() < kHeaderBytes + kTrailerBytes) return;
  const uint64_t h = fnv1a64(f.data(), f.size() - kTrailerBytes);
  std::memcpy(&f[f.size() - kTrailerBytes], &h, 8);
}

void CheckpointSystem::saveCore(std::ostream& o) const {
  put(o, time_);
  put(o, steps_);
  putVec(o, prev_keys_);
  putVec(o, prev_gamma_);
  putVec(o, rows_);
  putVec(o, row_lambda_);
  putVec(o, prev_normal_);
}

void CheckpointSystem::loadCore(std::istream& i, bool with_normals) {
  double time = 0;
  int64_t steps = 0;
  std::vector<uint64_t> keys;
  std::vector<real> gamma, lambda;
  std::vector<ConstraintRow> rows;
  std::vector<Vec3> normals;
  get(i, time);
  get(i, steps);
  getVecs(i, keys, gamma, rows, lambda);
  if (with_normals) getVec(i, normals);
  if (with_normals && normals.size() != keys.size()) throw InputError("checkpoint: corrupt warm-start normals");
  for (const Vec3& v : normals)
    if (!(std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z)))
      throw InputError("checkpoint: corrupt warm-start normal");
  // The warm-start cache is looked up by binary search and read 3 impulses a contact; rows name bodies.
  if (!(time >= 0 && time <= double(int64_t(1) << 40) * double(real(config().step.dt))) || steps < 0 ||
      steps > (int64_t(1) << 40))
    throw InputError("checkpoint: corrupt core clock");
  if (gamma.size() != 3 * keys.size() || !std::is_sorted(keys.begin(), keys.end()))
    throw InputError("checkpoint: corrupt warm-start cache");
  // impulses (N s) of particles and of the drum's drive: 1e6 is far beyond either, and keeps the solve finite
  for (real g : gamma)
    if (!(std::fabs(g) <= real(1e6))) throw InputError("checkpoint: corrupt warm-start impulse");
  if (!lambda.empty() && lambda.size() != rows.size()) throw InputError("checkpoint: corrupt constraint impulses");
  for (real l : lambda)
    if (!(std::fabs(l) <= real(1e6))) throw InputError("checkpoint: corrupt constraint impulse");
  const int32_t n = int32_t(bodies().count());
  for (const ConstraintRow& r : rows) {
    bool ok = r.a >= -1 && r.a < n && r.b >= -1 && r.b < n && std::isfinite(r.bias) && !(r.lo > r.hi) &&
              !std::isnan(r.lo) && !std::isnan(r.hi);
    for (int k = 0; k < 6; ++k) ok = ok && std::isfinite(r.Ja[k]) && std::isfinite(r.Jb[k]);
    if (!ok) throw InputError("checkpoint: corrupt constraint row");
  }
  time_ = time;
  steps_ = steps;
  prev_keys_ = std::move(keys);
  prev_gamma_ = std::move(gamma);
  prev_normal_ = std::move(normals);
  rows_ = std::move(rows);
  row_lambda_ = std::move(lambda);
}

void CesMachine::save(std::ostream& file, const std::string& meta) const {
  syncCharges();
  std::ostringstream o(std::ios::binary);
  o.write(kCesCheckpointMagic, kMagicBytes);
  put(o, uint64_t(meta.size()));
  o.write(meta.data(), std::streamsize(meta.size()));
  put(o, steps_);
  const Feeder::State fs = feeder_.state();
  put(o, fs.rng);
  put(o, fs.owed_kg);
  put(o, fs.fed_total_fg);
  putVec(o, fs.fed_fg);
  // Particle specs (hull points inline).
  put(o, uint64_t(specs_.size()));
  for (const ParticleSpec& s : specs_) {
    put(o, s.material);
    put(o, s.shape);
    put(o, s.dims);
    putVec(o, s.hull);
    put(o, s.mass_fg);
    put(o, s.inertia);
    put(o, s.radius);
    put(o, s.bound);
  }
  putVec(o, p_.status);
  putVec(o, p_.material);
  putVec(o, p_.charge);
  putVec(o, p_.flags);
  putVec(o, collected_);
  putVec(o, recent_);
  const BodyArrays& b = sys_.bodies();
  putVec(o, b.pos);
  putVec(o, b.rot);
  putVec(o, b.vel);
  putVec(o, b.omega);
  putVec(o, b.flags);
  const auto* cs = dynamic_cast<const CheckpointSystem*>(&sys_);
  put(o, uint8_t(cs ? 2 : 0));  // 2: the core with its contacts' normals (1: without, an earlier file)
  if (cs) cs->saveCore(o);
  std::string f = o.str();
  f.append(kTrailerBytes, '\0');
  resealCesCheckpoint(f);
  file.write(f.data(), std::streamsize(f.size()));
  if (!o || !file) throw std::runtime_error("checkpoint: write error");
}

namespace {

// A particle record as the feeder makes it (makeParticleSpec): a diameter 2 x radius and a density mass / volume
// within the configuration's ranges, and for the shapes the feeder builds from the diameter alone (all but the
// fragment) the same dimensions, moments and bound; a fragment's hull within its bound and moments that a body
// of its mass and bound can have. Anything else (a moment of 1e-300 makes the next solve non-finite) is refused.
bool plausibleSpec(const ParticleSpec& s, const CesConfig& cfg) {
  constexpr double kPi = 3.14159265358979323846;
  const double tol = 1e-5;  // rounding of the stored values (real may be float)
  const double d = 2 * double(s.radius), m = double(s.mass_fg) * kFemtogram;
  if (!(s.mass_fg > 0 && d >= cfg.diameter_min * (1 - tol) && d <= cfg.diameter_max * (1 + tol))) return false;
  const MaterialConfig& mat = cfg.materials[size_t(s.material)];
  const double V = kPi * d * d * d / 6, rho = m / V, slack = kFemtogram / V;  // mass_fg is rounded to 1 fg
  if (!(rho >= mat.density_min * (1 - tol) - slack && rho <= mat.density_max * (1 + tol) + slack)) return false;
  auto close = [&](double a, double b) {
    return std::fabs(a - b) <= tol * std::fmax(std::fabs(a), std::fabs(b)) + 1e-30;
  };
  if (s.shape != ParticleShape::Fragment) {
    SplitMix64 unused{1};
    const ParticleSpec e = makeParticleSpec(s.material, s.shape, d, rho, unused);
    return s.hull.empty() && close(s.dims.x, e.dims.x) && close(s.dims.y, e.dims.y) && close(s.dims.z, e.dims.z) &&
           close(s.inertia.x, e.inertia.x) && close(s.inertia.y, e.inertia.y) && close(s.inertia.z, e.inertia.z) &&
           close(s.bound, e.bound);
  }
  if (s.hull.size() < 4 || s.hull.size() > 64 || !(s.bound >= s.radius * real(1 - tol) && s.bound <= 10 * s.radius))
    return false;
  for (const Vec3& p : s.hull)
    if (!(isFinite(p) && length(p) <= s.bound * real(1 + tol))) return false;
  const double I[3] = {s.inertia.x, s.inertia.y, s.inertia.z}, r = double(s.radius), b = double(s.bound);
  for (int k = 0; k < 3; ++k)  // a moment is at most m b^2; the triangle inequality of principal moments
    if (!(I[k] >= 0.01 * m * r * r && I[k] <= m * b * b * (1 + tol) &&
          I[(k + 1) % 3] + I[(k + 2) % 3] >= I[k] * (1 - tol)))
      return false;
  return true;
}

}  // namespace

// A checkpoint is input like a scene file: every count is checked against the bytes left before anything is
// allocated, every index and enum against its range, every number for finiteness and plausibility (a particle of
// 1e30 m, a moment of inertia of 1e-300, a velocity of 1e300 m/s or a feeder debt of 1e30 kg would make the next
// step non-finite or allocate without bound), and the whole file must be consumed. Problems are InputErrors
// "checkpoint: ...".
void CesMachine::load(std::istream& file, std::string* meta) {
  std::string bytes;
  {
    std::ostringstream all(std::ios::binary);
    all << file.rdbuf();
    bytes = all.str();
  }
  CheckpointParts parts = openCheckpoint(bytes);
  bytes.clear();
  bytes.shrink_to_fit();
  std::istringstream in(std::move(parts.state), std::ios::binary);
  if (int(sys_.bodies().count()) != n_machine_ || !specs_.empty())
    throw InputError("checkpoint: the machine is not fresh");
  // The sections in the order save() writes them.
  loadClockAndFeeder(in);
  loadParticleRecords(in);
  loadParticleState(in);
  loadBodyArrays(in);
  loadCoreAndEnd(in);
  sys_.markHostDirty();
  dev_uploaded_ = 0;  // CesDevice: every particle's state goes up again before the next step
  charges_stale_ = false;
  if (meta) *meta = std::move(parts.meta);
}

// The step count and the feeder's state.
void CesMachine::loadClockAndFeeder(std::istream& in) {
  get(in, steps_);
  if (steps_ < 0 || steps_ > (int64_t(1) << 40))
    throw InputError("checkpoint: corrupt step count " + std::to_string(steps_));
  Feeder::State fs;
  get(in, fs.rng);
  get(in, fs.owed_kg);
  get(in, fs.fed_total_fg);
  getVec(in, fs.fed_fg);
  if (fs.fed_fg.size() != cfg_.materials.size())
    throw InputError("checkpoint: the materials differ from the configuration");
  // The feeder emits while its debt is >= 0 and stops below 0: a saved debt is <= 0 and above minus one particle.
  // (masses in whole femtograms: 1 kg is 1e18 fg, and the balance adds them up in 64 bits)
  int64_t fed_sum = 0;
  for (int64_t f : fs.fed_fg)
    if (f < 0 || f > int64_t(4e18) || __builtin_add_overflow(fed_sum, f, &fed_sum))
      throw InputError("checkpoint: corrupt feeder state");
  if (!(std::isfinite(fs.owed_kg) && fs.owed_kg <= 0 && fs.owed_kg > -1.0) || fs.fed_total_fg != fed_sum)
    throw InputError("checkpoint: corrupt feeder state");
  feeder_.setState(fs);
}

// Every particle's spec, each checked and its body added (at rest; loadBodyArrays sets its state).
void CesMachine::loadParticleRecords(std::istream& in) {
  uint64_t ns = 0;
  get(in, ns);
  if (ns > bytesLeft(in) / 64)
    throw InputError("checkpoint: corrupt particle count " + std::to_string(ns));  // >= 64 bytes each
  for (uint64_t k = 0; k < ns; ++k) {
    ParticleSpec s;
    get(in, s.material);
    get(in, s.shape);
    get(in, s.dims);
    getVec(in, s.hull);
    get(in, s.mass_fg);
    get(in, s.inertia);
    get(in, s.radius);
    get(in, s.bound);
    const std::string what = "checkpoint: particle " + std::to_string(k) + ": ";
    if (s.material < 0 || size_t(s.material) >= cfg_.materials.size() || int(s.shape) < 0 ||
        int(s.shape) >= kParticleShapes)
      throw InputError(what + "corrupt record (material or shape out of range)");
    if (!plausibleSpec(s, cfg_))
      throw InputError(what +
                       "corrupt record (its size, mass, shape dimensions or moments are not what the feeder makes)");
    try {
      addParticle(s, Vec3{0, 0, 0}, Quat{1, 0, 0, 0}, Vec3{0, 0, 0}, Vec3{0, 0, 0});
    } catch (const InputError& e) { throw InputError(what + e.what()); }
  }
}

// The per-body particle arrays (status, material, charge, flags) and the collected and recent-spawn records.
void CesMachine::loadParticleState(std::istream& in) {
  std::vector<uint8_t> status;
  std::vector<int32_t> material;
  std::vector<real> charge;
  std::vector<uint8_t> pflags;
  getVecs(in, status, material, charge, pflags, collected_, recent_);
  if (status.size() != p_.count() || material.size() != p_.count() || charge.size() != p_.count() ||
      pflags.size() != p_.count())
    throw InputError("checkpoint: body count differs from the particle records");
  for (size_t i = 0; i < status.size(); ++i) {
    const bool machine = i < size_t(n_machine_);
    if (machine ? (status[i] != kStatusMachine || material[i] != p_.material[i])
                : (status[i] < kStatusInFlight || status[i] > kStatusLost || material[i] != p_.material[i]))
      throw InputError("checkpoint: body " + std::to_string(i) + ": corrupt status or material");
    if (!(std::fabs(charge[i]) <= real(1e-6)) ||
        (pflags[i] & ~uint8_t(kFlagPinned)))  // 1e-6 C: 1000x the Pauthenier limit of a 1 mm particle
      throw InputError("checkpoint: body " + std::to_string(i) + ": corrupt charge or flags");
  }
  const int64_t nbodies = int64_t(p_.count());
  for (const CollectedParticle& c : collected_)
    if (c.body < n_machine_ || c.body >= nbodies || c.material != p_.material[size_t(c.body)] || int(c.kind) < 0 ||
        int(c.kind) > int(MaterialKind::Composite) || c.mass_fg != p_.mass_fg[size_t(c.body)] || !std::isfinite(c.x) ||
        !std::isfinite(c.z) || !std::isfinite(c.t))
      throw InputError("checkpoint: corrupt collected-particle record");
  for (CollectedParticle& c : collected_) c.metal_mass_fraction = compositeMassFraction(size_t(c.body));
  for (const RecentSpawn& r : recent_)
    if (r.body < n_machine_ || r.body >= nbodies || r.step < 0 || r.step > steps_)
      throw InputError("checkpoint: corrupt recent-spawn record");
  p_.status = status;
  lost_ = int64_t(std::count(status.begin(), status.end(), uint8_t(kStatusLost)));
  p_.material = material;
  p_.charge = charge;
  p_.flags = pflags;
}

// The body arrays (positions, rotations, velocities, flags) of every body, machine parts included.
void CesMachine::loadBodyArrays(std::istream& in) {
  BodyArrays& b = sys_.mutableBodies();
  std::vector<Vec3> pos, vel, omega;
  std::vector<Quat> rot;
  std::vector<uint8_t> flags;
  getVec(in, pos);
  getVec(in, rot);
  getVec(in, vel);
  getVec(in, omega);
  getVec(in, flags);
  if (pos.size() != b.count() || rot.size() != b.count() || vel.size() != b.count() || omega.size() != b.count() ||
      flags.size() != b.count())
    throw InputError("checkpoint: body arrays have the wrong length");
  for (size_t i = 0; i < pos.size(); ++i) {
    const Quat& q = rot[i];
    const real qn = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
    // within 1 km of the machine (it spans about a metre), a unit rotation, speeds below 1 km/s and 1e6 rad/s; a
    // machine part keeps its kind (fixed, kinematic or dynamic), a particle is dynamic or frozen (collected or lost)
    if (!(isFinite(pos[i]) && maxComponent(vabs(pos[i])) <= real(1e3)) || !(std::fabs(qn - 1) < real(1e-3)) ||
        !(isFinite(vel[i]) && length(vel[i]) <= real(1e3)) || !(isFinite(omega[i]) && length(omega[i]) <= real(1e6)))
      throw InputError("checkpoint: body " + std::to_string(i) + ": corrupt position, rotation or velocity");
    const bool machine = i < size_t(n_machine_);
    if (machine ? flags[i] != b.flags[i] : (flags[i] != 0 && flags[i] != kBodyFixed))
      throw InputError("checkpoint: body " + std::to_string(i) + ": corrupt body flags");
  }
  b.pos = pos;
  b.rot = rot;
  b.vel = vel;
  b.omega = omega;
  b.flags = flags;
}

// The core's warm start (with a CheckpointSystem), then nothing may follow.
void CesMachine::loadCoreAndEnd(std::istream& in) {
  uint8_t has_core = 0;
  get(in, has_core);
  if (has_core > 2) throw InputError("checkpoint: corrupt core marker");
  auto* cs = dynamic_cast<CheckpointSystem*>(&sys_);
  if (has_core && cs) cs->loadCore(in, has_core == 2);
  if (!(has_core && !cs) && in.peek() != std::char_traits<char>::eof())  // a GPU run's file may carry a core it ignores
    throw InputError("checkpoint: " + std::to_string(bytesLeft(in)) + " bytes of garbage after the end");
}

}  // namespace ces
}  // namespace dvi
