// The CES machine configuration: a JSON document (scenes/schema/ces.schema.json) whose top level holds
// the machine under the key "ces". Every key is checked: an unknown key, a wrong type, a non-finite or
// out-of-range number is an InputError naming the key path ("ces.electrode.voltage_kV: ...").
//
// Units are in the key names (mm, kV, rpm, g/s, deg); CesConfig holds SI values (m, V, rad/s, kg/s,
// rad), converted once here. Defaults are the machine of docs/CES.md, held here only (CesConfig); the embedded
// default document (defaultCesJson(), identical to scenes/ces_default.json, tested) is what
// `dvisim run` runs without a scene.
//
// Sign conventions (docs/CES.md): the drum axis is z, gravity is -y, the electrodes lie at angles
// electrode.{wire,tube}.angle_deg counter-clockwise from +x. drum.rpm > 0 turns the drum clockwise seen from +z, so
// that its top moves toward the electrode (+x): omega_z = -2 pi rpm / 60. brush.rpm uses the same
// convention; with both positive the two surfaces move against each other where they meet (the brush
// sweeps the drum).
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "chrono_like/base/math.h"
#include "chrono_like/system.h"

namespace dvi {
namespace ces {

// Composite: non-liberated metal in a plastic matrix, a metal fraction per particle (feeder.h compositeParts).
// The mass accounting (splitters.h) has the first three kinds; a composite's mass counts as metal and plastic
// in proportion to its parts.
enum class MaterialKind : int32_t { Metal = 0, Plastic = 1, Middling = 2, Composite = 3 };
constexpr int kMaterialKinds = 3;              // metal, plastic, middling: the kinds the mass is accounted in
const char* materialKindName(MaterialKind k);  // "metal" | "plastic" | "middling" | "composite"

enum class ParticleShape : int32_t { Sphere = 0, Flake, Wire, Ellipsoid, Fragment, Count };
constexpr int kParticleShapes = int(ParticleShape::Count);
const char* particleShapeName(ParticleShape s);  // "sphere" | "flake" | "wire" | "ellipsoid" | "fragment"

struct MaterialConfig {
  std::string name;
  MaterialKind kind = MaterialKind::Plastic;
  double mass_fraction = 1;                     // share of the fed mass (normalised over the materials)
  double density_min = 946, density_max = 946;  // kg/m^3, uniform
  double eps_r = 2.5;                           // relative permittivity (inf for a metal)
  // s, charge relaxation through the drum contact tau = eps0 eps_r / sigma (inf: none). Given directly
  // (relaxation_time_s) or through the effective conductivity (conductivity_S_m).
  double relaxation_time = 0;
  double conductivity = -1;                                // S/m as given (-1: not given)
  double shape_weight[kParticleShapes] = {1, 0, 0, 0, 0};  // relative frequency of each shape (by count)
  // Composites: the metal's volume fraction, uniform over [metal_fraction_min, metal_fraction_max]
  // (ces.feed.materials[].metal_fraction), the metal's and the matrix's densities; density_min/max are then the
  // mixture's at the two fractions. conductivity (or 1e-14 S/m) is the matrix's, eps_r the matrix's.
  double metal_fraction_min = 0, metal_fraction_max = 0;
  double metal_density = 8900, matrix_density = 1850;  // kg/m^3 (copper; FR-4 glass-epoxy)
  // S, surface conductivity of an insulating particle (surface_conductivity_S, 0: none): the charge also leaks
  // along the surface to the drum, 1/tau = 1/tau_bulk + 2 sigma_s / (r eps0 eps_r) (charging.h).
  double surface_conductivity = 0;
};

// The defaults of a metal, plastic or middling material before its keys are read (docs/CES.md, "Charges"):
// metal: copper-like, 8400-8900 kg/m^3 [spec], a conductor (eps_r = inf, tau = 0); plastic: 946 kg/m^3 and
// eps_r = 2.5 [spec], an insulator that keeps its charge (tau = inf); middling: a plastic whose charge relaxes
// through the drum contact with tau = 0.5 s [assumed].
inline MaterialConfig defaultMaterial(MaterialKind kind) {
  MaterialConfig m;
  m.kind = kind;
  if (kind == MaterialKind::Metal) {
    m.density_min = 8400, m.density_max = 8900;
    m.eps_r = std::numeric_limits<double>::infinity();
    m.relaxation_time = 0;
  } else {
    m.relaxation_time = kind == MaterialKind::Plastic ? std::numeric_limits<double>::infinity() : 0.5;
  }
  return m;
}

// A cylindrical electrode (axis along z): the corona wire, the static tube, or a further electrode of the
// charge-simulation model. The wire and the tube are on the machine's one supply (CesConfig::voltage).
struct ElectrodeConfig {
  bool enabled = true;
  double diameter = 0.038;  // m
  double distance = 0.230;  // m, centre distance from the drum axis
  double angle = 0;         // rad, counter-clockwise from +x
  double voltage = -35000;  // V (extra electrodes only; the wire and tube take the supply's)
};

// The machine's step: ces.time_step_s (dt, 2e-4 s) and ces.solver.gyroscopic (the gyroscopic term w x I w, on:
// the explicit form once spun a tumbling 1 mm wire from 1e3 to 1e11 rad/s in 0.1 s at h = 2e-4 s). Gravity is the
// System's default.
inline StepSettings cesDefaultStep() {
  StepSettings s;
  s.dt = 2e-4;
  return s;
}
// The machine's solver: ces.solver.type (APGD) and ces.solver.iterations, a fixed count (max_iterations 30,
// tolerance 0).
inline SolverSettings cesDefaultSolver() {
  SolverSettings s;
  s.type = SolverType::APGD;
  s.max_iterations = 30;
  s.tolerance = 0;
  return s;
}

struct CesConfig {
  // Run.
  double duration = 2.0;  // s of machine time
  uint64_t seed = 1;
  // The System's step and solver parts (system.h), parsed straight into them; the rest of the System's
  // configuration is makeCesSystem's (apps/dvisim/ces_run.h).
  StepSettings step = cesDefaultStep();
  SolverSettings solver = cesDefaultSolver();

  // Drum (grounded). drive: "auto" (rheonomic constraint when the core solves constraint rows, else
  // kinematic), "kinematic" or "rheonomic".
  double drum_diameter = 0.320, drum_width = 0.300, drum_rpm = 44.8;
  std::string drum_drive = "auto";
  double drum_mass = 30;  // kg, for the rheonomic drive (a steel shell; any large value works)

  // The electrodes on the one high-voltage supply: a thin corona wire (ionising) and a static tube
  // (shaping the field). voltage = 0 is the supply off.
  double voltage = -35000;                                            // V
  ElectrodeConfig wire{true, 0.00025, 0.205, 1.3089969389957472, 0};  // 75 deg: ions end before conductors leave
  ElectrodeConfig tube{true, 0.038, 0.230, 0.5235987755982988, 0};
  // Field model: "corona" (the steady ionised field of the wire with the tube, field_corona.h; Laplace
  // below onset), "csm" (Laplace field of the wire, the tube and extra_electrodes, no ions) or
  // "two_cylinder" (exact Laplace field of the drum and the tube alone; the wire must be disabled).
  std::string field_model = "corona";
  std::vector<ElectrodeConfig> extra_electrodes;

  // Corona: ion mobility (Pauthenier's charging time), the air's relative density and the wire's
  // roughness factor (Peek's onset field), the solver's grid spacing; the image-force cutoff.
  double ion_mobility = 2.1e-4;  // m^2/(V s), negative ions in air
  double rel_air_density = 1.0;  // delta, 1 at 20 C and 101.3 kPa
  double roughness = 1.0;        // Peek's m (1: smooth wire)
  double corona_grid = 0.001;    // m, grid spacing of the ionised-field solver
  double image_cutoff = 0.005;   // m, image force acts within this distance of the drum surface

  // Brush (grounded, rotating): a rigid core of brush_core_diameter (the body particles collide with) set with
  // bristles out to brush_diameter, whose tips are brush_gap from the drum (0: they touch it). Among the
  // bristles a particle is discharged (brush_discharge_time) and swept toward their velocity
  // (brush_sweep_time). brush_core_diameter = brush_diameter is a smooth rigid cylinder.
  double brush_diameter = 0.106, brush_core_diameter = 0.066, brush_angle = -2.356194490192345, brush_rpm = 120,
         brush_gap = 0;
  double brush_discharge_time = 1e-3;  // s
  double brush_sweep_time = 2e-3;      // s

  // Air.
  double air_viscosity = 1.81e-5, air_density = 1.225;

  // Pair friction coefficients (converted to per-body values under the product rule).
  double mu_particle_particle = 0.2, mu_particle_drum = 0.5, mu_particle_brush = 0.5, mu_particle_wall = 0.3;
  // Rolling resistance of the particles on the drum, mu_r = the tangent of the steepest slope a particle rests on
  // by it alone (forces.h drumRollingTorque; 0: particles roll freely).
  double mu_rolling_drum = 0;

  // Feed: a vibrating conveyor's outlet, a line across the drum width above the drum.
  double feed_mass_flow = 0.5e-3;                       // kg/s
  double feed_start = 0, feed_duration = 0.6;           // s
  double feed_angle = 1.7453292519943295;               // rad, direction of the outlet from the drum axis (100 deg)
  double feed_height = 0.004;                           // m, above the drum surface
  double feed_speed = 0.2;                              // m/s, along the drum's surface motion
  double feed_width = 0.280;                            // m, along z
  double diameter_min = 0.5e-3, diameter_max = 1.0e-3;  // m, volume-equivalent diameter, uniform
  std::vector<MaterialConfig> materials;

  // Collection plane y = collection_y; positions along it are x - collection_x0.
  double collection_y = -0.35, collection_x0 = 0;

  // Splitters (virtual): bins nonconductor x' < s1 <= middling < s2 <= conductor.
  double s1 = 0.0, s2 = 0.200;
  double splitter_lo = -0.200, splitter_hi = 0.500;
  int splitter_positions = 71;
  // Grade targets of the optimiser: the conductor product's metal grade and the nonconductor product's
  // plastic grade that the best setting must reach (0: none).
  double grade_target_conductor = 0.95, grade_target_nonconductor = 0.95;

  // Outputs.
  int frames = 0;
  double histogram_bin = 0.002;  // m
  bool plots = true;
  double checkpoint_every = 0;  // s of machine time between checkpoints (0: none; one is always written at the end)

  double omegaDrum() const;  // rad/s about +z
  double omegaBrush() const;
  double drumRadius() const { return drum_diameter / 2; }
};

// The default machine document (scenes/ces_default.json), embedded.
const char* defaultCesJson();

// True when `doc` is a CES scene (an object with the key "ces").
bool isCesDocument(const nlohmann::json& doc);

// Parses a whole scene document {"$schema", "name", "description", "ces": {...}} after applying the
// overrides KEY=VALUE (KEY relative to "ces", e.g. electrode.voltage_kV=-30, or starting with "ces.").
// `origin` names the file in error messages. The document is checked for its nesting depth before it is copied
// (copying a document nested 100,000 deep overflows the stack), and its run for a step count within the limit.
CesConfig parseCesDocument(const nlohmann::json& document, const std::vector<std::string>& overrides,
                           const std::string& origin);

// |U| / V_b of the supplied electrode (wire or tube) nearest to breakdown: V_b the uniform-field breakdown voltage
// of its gap to the drum (field/breakdown.h). parseCesDocument refuses >= 1; real gaps spark over lower.
double sparkoverMargin(const CesConfig& cfg);

// Applies one override to the document (exposed for the checkpoint, which stores the final document).
void applyCesOverride(nlohmann::json& doc, const std::string& assignment);

}  // namespace ces
}  // namespace dvi
