// The corona electrostatic separator as a plug-in of a dvi::System (docs/CES.md).
//
// Bodies (added in this order, before any particle):
//   drum      cylinder, axis z, grounded; turned at omega(t) either as a kinematic body (omega set each
//             step) or, when the core solves constraint rows, as a dynamic body held by a rheonomic
//             RowProvider (DrumDrive: revolute joint to the fixed truss + angular-velocity drive, which
//             reports the drive torque). drum.drive = auto picks the rheonomic one when available.
//   brush     kinematic cylinder, the brush's rigid core (brush.core_diameter_mm), turning at brush.rpm; its
//             bristles (out to brush.diameter_mm, brush.gap_mm from the drum) are no body: a zone where
//             particles are discharged and swept (particle_model.h: amongBristles)
//   electrodes fixed cylinders (the static electrode and, with the CSM field, the extra electrodes)
//   walls     two fixed planes at the drum's ends (z = +-width/2)
// Machine parts only collide with particles (collision group 2, mask 1; particles group 1).
// Particles are appended by the feeder (System::addBody) in feed order.
//
// One machine step (CesMachine::step):
//   1. Feeder: emit the particles due in this step.
//   2. Drive: the drum's (and brush's) prescribed angular velocity.
//   3. System::step(); in its IntegrateForces stage the CesForceField adds Coulomb + image + drag to every
//      particle in flight. On the GPU backend it does so on the device (CesDevice, ces_device.cu, the same
//      cesParticleForce), and the machine copies only the bodies it reads or edits (the recent spawns, the
//      drum and the brush, the particles that change status). A device backend without the CES kernels
//      gets the old path: all bodies synced to the host, the field applied there by the System's host plug-in
//      path (with the System's StepContext, as every ForceField), the host marked dirty.
//   4. Post-step (CesParticles; on the device with CesDevice): charge update (ions, drum contact, electrode
//      contact, brush), the pinned flag, and status:
//      a particle whose centre crosses the collection plane is collected: its crossing point is recorded
//      and the body is frozen (kBodyFixed, zero velocity) 5 cm below the plane, in the "bin"; one that leaves
//      the domain is lost (frozen where it is). Bodies are never removed: the body count only grows, and
//      fed = collected + in flight + held up + lost holds exactly (masses in whole femtograms).
//
// The step: the constructor writes the configuration's step (ces.time_step_s, CesConfig::step.dt) into the
// System's (SystemConfig::step.dt); from then on the machine reads it from the System only: the step's context
// (System::stepContext) after a step, the System's configuration for the step about to run and for the clock.
//
// Per-particle state lives here, in arrays indexed by body (machine parts included, status kStatusMachine).
#pragma once

#include <cmath>
#include <cstdint>
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

#include "ces/ces_config.h"
#include "ces/ces_device.h"
#include "ces/feeder.h"
#include "ces/particle_model.h"
#include "chrono_like/system.h"

namespace dvi {
namespace ces {

// Per-body state of the plug-in (structure of arrays, index = body).
struct CesParticles {
  std::vector<uint8_t> status;           // ParticleStatus
  std::vector<int32_t> material;         // index into CesConfig::materials (-1 for machine parts)
  std::vector<real> charge;              // C
  std::vector<uint8_t> flags;            // ParticleFlag bits (kFlagPinned)
  std::vector<real> radius;              // volume-equivalent radius, m
  std::vector<real> bound;               // bounding radius, m
  std::vector<int64_t> mass_fg;          // femtograms
  std::vector<real> mass;                // kg, the same mass (the brush's sweep force)
  std::vector<real> moment;              // kg m^2, the smallest principal moment of inertia (the rolling resistance)
  std::vector<ParticleElectro> electro;  // shape and material electrostatics (shape_charging.h; zero for parts)
  size_t count() const { return status.size(); }
};

// A particle that crossed the collection plane: where (x' = x - collection.x0, z) and when.
struct CollectedParticle {
  int32_t body;
  int32_t material;
  MaterialKind kind;
  float metal_mass_fraction;  // a composite's metal share of its mass (set from its spec; unused for the others)
  int64_t mass_fg;
  double x, z, t;
};
static_assert(sizeof(CollectedParticle) == 48, "the checkpoint stores CollectedParticle as it is (DVICES03)");

// The metal part of a collected particle's mass, in whole femtograms: a metal's whole mass, a composite's share
// (rounded: its plastic part is the rest, so the two add up to its mass exactly), none of the others'.
inline int64_t metalFg(const CollectedParticle& c) {
  if (c.kind == MaterialKind::Metal) return c.mass_fg;
  if (c.kind != MaterialKind::Composite) return 0;
  const double w = double(c.metal_mass_fraction);
  const int64_t m = int64_t(std::llround(double(c.mass_fg) * (w > 0 ? (w < 1 ? w : 1.0) : 0.0)));
  return m;
}

// Where every fed particle is: collected (crossed the collection plane), lost (left the machine's domain
// otherwise; must be 0), held up (neither, and at this moment among the brush's bristles, or in contact
// with the drum after having been carried, touching it, to within 20 degrees of its lowest point, where
// only electric forces hold a particle: material the brush has not yet removed), or in flight (the rest:
// falling, bouncing, or riding the drum before its lowest point). Masses in whole femtograms.
struct MassBalance {
  int64_t fed_fg = 0, collected_fg = 0, in_flight_fg = 0, held_up_fg = 0, lost_fg = 0;
  int64_t fed = 0, collected = 0, in_flight = 0, held_up = 0, lost = 0;  // particle counts
  bool closes() const {
    return fed_fg == collected_fg + in_flight_fg + held_up_fg + lost_fg &&
           fed == collected + in_flight + held_up + lost;
  }
};

class CesMachine;

// The corona of the "corona" field model (field_corona.h); NaN and not ionised for the Laplace models.
struct CoronaInfo {
  bool ionised = false;
  double onset_voltage = std::nan("");  // V (signed like the supply)
  double wire_field_on = std::nan("");  // V/m, Peek's onset field at the wire surface
  double current_per_m = std::nan("");  // A/m, corona current per metre of wire
};

// Coulomb + image + drag on every particle in flight (IntegrateForces).
class CesForceField : public ForceField {
 public:
  explicit CesForceField(const CesMachine& m) : m_(m) {}
  void apply(const BodyArrays& bodies, const StepContext& step, Vec3* force, Vec3* torque) override;
  // On a device backend with the CES kernels (CesDevice): the same forces, computed there.
  bool applyOnDevice(const DeviceBodyRefs& bodies, const StepContext& step, Vec3* force, Vec3* torque) override;

 private:
  const CesMachine& m_;
};

// Rheonomic drive of the drum: 3 rows fix its centre, 2 keep its axis along z, 1 prescribes omega_z(t)
// (Psi/h + dPsi/dt, docs/ARCHITECTURE.md). The drive row's impulse / h is the drive torque.
class DrumDrive : public RowProvider {
 public:
  DrumDrive(int body, Vec3 centre, double omega) : body_(body), centre_(centre), omega_(omega) {}
  void rows(const BodyArrays& bodies, const StepContext& step, std::vector<ConstraintRow>& out) override;
  void impulses(const real* lambda, size_t count) override;
  bool bodiesRead(std::vector<int32_t>& ids) const override {  // the drum alone
    ids.push_back(body_);
    return true;
  }
  double torque() const { return torque_; }  // N m about z, last step
  double omega(double /*t*/) const { return omega_; }

 private:
  int body_;
  Vec3 centre_;
  double omega_;
  real dt_ = 0;  // the step of the last rows() (StepContext::dt), for impulses(): torque = impulse / h
  double torque_ = 0;
};

// True when System::step() solves the rows of a RowProvider (probed on a one-body system).
bool coreSolvesConstraintRows();

class CesMachine {
 public:
  // Builds the machine's bodies and field in `sys` (which must be empty) and registers the plug-ins.
  CesMachine(const CesConfig& cfg, System& sys);

  void step();
  // [s] machine time: steps() steps of the System's step (in double, the step as given: StepSettings::dt).
  double time() const { return double(steps_) * sys_.config().step.dt; }
  int64_t steps() const { return steps_; }
  const CesConfig& config() const { return cfg_; }
  System& system() { return sys_; }
  const System& system() const { return sys_; }
  const CesModel& model() const { return model_; }
  // The particles' state; on a device backend the charges are fetched from the device first.
  const CesParticles& particles() const {
    syncCharges();
    return p_;
  }
  // True when the field, charging and classification run on the device (CesDevice, GPU backend).
  bool deviceParticles() const { return dev_ != nullptr; }
  const std::vector<ParticleSpec>& specs() const { return specs_; }  // particle k is body firstParticleBody() + k
  int firstParticleBody() const { return n_machine_; }
  const std::vector<CollectedParticle>& collected() const { return collected_; }
  // On a device backend the positions are the host's copy (synced at the end of a run).
  MassBalance balance() const;
  // Particle body k is held up (MassBalance) at the host's positions.
  bool heldUp(size_t k) const;
  // Particle body k's metal share of its mass (its spec's metal_fg / mass_fg; CollectedParticle).
  float compositeMassFraction(size_t k) const;
  // Particles in the machine now (in flight or held up), in O(1) (balance() walks every particle):
  // fed - collected - lost.
  int64_t particlesInFlight() const { return int64_t(p_.count()) - n_machine_ - int64_t(collected_.size()) - lost_; }
  int64_t feederMassFg() const {
    return feeder_.fedMassFg();
  }  // what the feeder delivered (excludes particles added by hand)
  int drumBody() const { return drum_; }
  int brushBody() const { return brush_; }
  bool rheonomicDrive() const { return drive_ != nullptr; }
  double driveTorque() const { return drive_ ? drive_->torque() : 0.0; }
  double drumOmega() const { return cfg_.omegaDrum(); }
  const CoronaInfo& coronaInfo() const { return corona_; }
  // Exact field at a point (region 0 in the gas).
  FieldSample field(Vec3 p) const { return evalField(model_.field, p); }
  // The largest field on the static tube's surface (V/m; NaN without a tube), sampled at 360 points just outside
  // it: a static electrode whose surface field passes Peek's onset field of its radius (peekOnsetField) would
  // ionise, the precursor of spark-over on it (field/breakdown.h; docs/CES.md, "Spark-over").
  double tubeSurfaceField() const;

  // Adds one particle (tests, or a custom feed). Returns its body index.
  int addParticle(const ParticleSpec& spec, Vec3 pos, Quat rot, Vec3 vel, Vec3 omega, real charge = 0);
  void setCharge(int body, real q);

  // Checkpoint: the machine state, the feeder, every particle's spec and the body arrays; with a
  // CheckpointSystem also the core's warm-start cache and clock, so that a resumed CPU run ends bitwise
  // where an uninterrupted one does (the core: clock, warm-start keys, impulses, constraint rows and impulses, and,
  // after the core marker 2, the contacts' normals; a file with marker 1, from before the normals, still loads).
  // load() expects a freshly built machine of the same configuration.
  // The file (format DVICES03, kCesCheckpointMagic):
  //   "DVICES03" | u64 n | n bytes `meta` (the CLI: the configuration the run was made with) | the state |
  //   u64 FNV-1a 64 (checksum.h) of every byte before it
  // load() verifies the checksum before it reads a field (any edit is refused), then validates every field as
  // well; `meta` returns the recorded metadata.
  void save(std::ostream& out, const std::string& meta = {}) const;
  void load(std::istream& in, std::string* meta = nullptr);

 private:
  friend class CesForceField;
  // Construction, in the constructor's order (the bodies' order fixes their indices).
  void setupField(const std::vector<ElectrodeConfig>& supplied);
  void setupCoronaField();
  void setupModel(const std::vector<ElectrodeConfig>& supplied);
  void addDrumBody();
  void addBrushBody();
  void addElectrodeBodies();
  void addEndWalls();
  // load(): the checkpoint's sections, each read and validated in the order save() writes them.
  void loadClockAndFeeder(std::istream& in);
  void loadParticleRecords(std::istream& in);
  void loadParticleState(std::istream& in);
  void loadBodyArrays(std::istream& in);
  void loadCoreAndEnd(std::istream& in);
  int addBody(const BodyDesc& d, int material, const ParticleSpec* spec, real charge);
  void emit();
  void postStep();
  // Touching in-flight particles share their charge (particle_model.h: exchangeFlux), on the host's contacts.
  void exchangeContactCharges(real h);
  struct ExchangeScratch {  // exchangeContactCharges' per-body and per-pair arrays, kept between steps
    std::vector<uint8_t> held;
    std::vector<int32_t> partners;
    std::vector<int64_t> pairs;
    std::vector<real> dq;
  } exchange_;
  void stepDevice();
  void postStepDevice();
  // Status change of particle body i (collected: its crossing point recorded; collected or lost: frozen).
  void settle(size_t i, uint8_t next);
  void syncCharges() const;

  CesConfig cfg_;
  System& sys_;
  CesModel model_{};
  CsmField csm_;
  CoronaField corona_field_;  // the corona model's solution (its grid backs model_.field.grid)
  CoronaInfo corona_;
  Feeder feeder_;
  std::shared_ptr<CesForceField> field_;
  std::shared_ptr<DrumDrive> drive_;
  mutable CesParticles p_;  // charges and flags refreshed from the device by syncCharges()
  std::vector<ParticleSpec> specs_;
  std::vector<CollectedParticle> collected_;
  struct RecentSpawn {
    int32_t body;
    int64_t step;
  };
  std::vector<RecentSpawn> recent_;  // particles emitted in the last 50 ms (spawn overlap test)
  int drum_ = -1, brush_ = -1, n_machine_ = 0;
  real particle_friction_ = 1;
  int64_t steps_ = 0;
  int64_t lost_ = 0;                // particles with kStatusLost (kept for particlesInFlight)
  bool host_forces_ = false;        // device backend without CesDevice: the per-particle work on the host (see above)
  std::unique_ptr<CesDevice> dev_;  // device backend: the per-particle work as kernels
  size_t dev_uploaded_ = 0;         // particles uploaded to dev_
  mutable bool charges_stale_ = false;
};

constexpr char kCesCheckpointMagic[9] = "DVICES03";

// The metadata a checkpoint file records (CesMachine::save's `meta`), after checking its format and checksum:
// InputError "checkpoint: ..." when it is not a checkpoint, of an older format, truncated or edited.
std::string cesCheckpointMeta(const std::string& bytes);
// Recomputes the trailing checksum of `bytes` in place (tests and the fuzz target: an edited field then reaches
// the field checks of load() instead of the checksum's refusal). Leaves anything shorter than a header alone.
void resealCesCheckpoint(std::string& bytes);

// A CPU System whose clock and warm-start cache can be saved and restored (for checkpoints).
class CheckpointSystem : public System {
 public:
  using System::System;
  void saveCore(std::ostream& out) const;
  void loadCore(std::istream& in, bool with_normals);  // with_normals: the core marker 2 (the normals follow)
};

}  // namespace ces
}  // namespace dvi
