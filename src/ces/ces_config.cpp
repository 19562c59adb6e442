// CES configuration: strict JSON parsing (see ces_config.h) and the embedded default machine.
#include "ces/ces_config.h"

#include "chrono_like/io/input_limits.h"
#include "chrono_like/io/json_check.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "ces/ces_constants.h"
#include "ces/charging.h"
#include "ces/field/breakdown.h"
#include "chrono_like/base/errors.h"

namespace dvi {
namespace ces {

using nlohmann::json;

const char* materialKindName(MaterialKind k) {
  switch (k) {
    case MaterialKind::Metal: return "metal";
    case MaterialKind::Plastic: return "plastic";
    case MaterialKind::Middling: return "middling";
    case MaterialKind::Composite: return "composite";
  }
  return "?";
}

const char* particleShapeName(ParticleShape s) {
  switch (s) {
    case ParticleShape::Sphere: return "sphere";
    case ParticleShape::Flake: return "flake";
    case ParticleShape::Wire: return "wire";
    case ParticleShape::Ellipsoid: return "ellipsoid";
    case ParticleShape::Fragment: return "fragment";
    default: return "?";
  }
}

double CesConfig::omegaDrum() const { return -double(rpmToRadPerSec(real(drum_rpm))); }
double CesConfig::omegaBrush() const { return -double(rpmToRadPerSec(real(brush_rpm))); }

// Keep identical to scenes/ces_default.json (tests/test_ces_machine.cpp compares the two).
const char* defaultCesJson() {
  return R"JSON({
  "$schema": "schema/ces.schema.json",
  "name": "ces-default",
  "description": "Roll-type corona-electrostatic separator (docs/CES.md): corona wire and static tube on one supply; copper, plastic and non-liberated copper-plastic composites of 0.5-1 mm",
  "ces": {
    "duration_s": 2.0,
    "time_step_s": 0.0002,
    "seed": 1,
    "solver": { "type": "apgd", "iterations": 30, "gyroscopic": true },
    "drum": { "diameter_mm": 320, "width_mm": 300, "rpm": 44.8, "drive": "auto", "mass_kg": 30 },
    "electrode": {
      "voltage_kV": -35,
      "wire": { "enabled": true, "angle_deg": 75, "distance_mm": 205, "diameter_mm": 0.25 },
      "tube": { "enabled": true, "angle_deg": 30, "distance_mm": 230, "diameter_mm": 38 }
    },
    "field": { "model": "corona", "extra_electrodes": [] },
    "corona": { "ion_mobility_m2_Vs": 2.1e-4, "rel_air_density": 1.0, "roughness": 1.0, "grid_mm": 1.0, "image_cutoff_mm": 5 },
    "brush": { "diameter_mm": 106, "core_diameter_mm": 66, "angle_deg": -135, "rpm": 120, "gap_mm": 0,
               "discharge_time_s": 0.001, "sweep_time_s": 0.002 },
    "air": { "viscosity_Pa_s": 1.81e-5, "density_kg_m3": 1.225 },
    "friction": { "particle_particle": 0.2, "particle_drum": 0.5, "particle_brush": 0.5, "particle_wall": 0.3,
                  "rolling_drum": 0 },
    "feed": {
      "mass_flow_g_s": 0.5,
      "start_s": 0,
      "duration_s": 0.6,
      "angle_deg": 100,
      "height_mm": 4,
      "speed_m_s": 0.2,
      "width_mm": 280,
      "diameter_mm": [0.5, 1.0],
      "materials": [
        { "name": "copper", "kind": "metal", "mass_fraction": 0.4, "density_kg_m3": [8400, 8900],
          "eps_r": "inf", "relaxation_time_s": 0,
          "shapes": { "sphere": 0.4, "wire": 0.3, "flake": 0.3 } },
        { "name": "plastic", "kind": "plastic", "mass_fraction": 0.5, "density_kg_m3": [946, 946],
          "eps_r": 2.5, "conductivity_S_m": 1e-14,
          "shapes": { "sphere": 0.3, "flake": 0.2, "ellipsoid": 0.3, "fragment": 0.2 } },
        { "name": "composite", "kind": "composite", "mass_fraction": 0.1, "metal_fraction": [0.05, 0.6],
          "density_kg_m3": 1850, "metal_density_kg_m3": 8900, "eps_r": 4.4, "conductivity_S_m": 1e-14,
          "shapes": { "fragment": 0.5, "flake": 0.5 } }
      ]
    },
    "collection": { "y_mm": -350, "x0_mm": 0 },
    "splitters": { "s1_mm": 0, "s2_mm": 200, "range_mm": [-200, 500], "positions": 71,
                   "grade_targets": { "conductor": 0.95, "nonconductor": 0.95 } },
    "output": { "frames": 0, "histogram_bin_mm": 2, "plots": true, "checkpoint_every_s": 0 }
  }
}
)JSON";
}

bool isCesDocument(const json& doc) { return doc.is_object() && doc.contains("ces"); }

namespace {

using jsoncheck::describe;
using jsoncheck::num;
using Checker = jsoncheck::JsonCheck;

constexpr double kMm = 1e-3;
constexpr double kDeg = 3.14159265358979323846 / 180.0;

// An extra electrode of the charge-simulation model (its own voltage).
ElectrodeConfig parseElectrode(const Checker& c, const json& e, const std::string& p, const ElectrodeConfig& def) {
  c.object(e, p, {"diameter_mm", "distance_mm", "angle_deg", "voltage_kV"});
  ElectrodeConfig out = def;
  if (e.contains("diameter_mm")) out.diameter = c.positive(e["diameter_mm"], p + ".diameter_mm") * kMm;
  if (e.contains("distance_mm")) out.distance = c.positive(e["distance_mm"], p + ".distance_mm") * kMm;
  if (e.contains("angle_deg")) out.angle = c.range(e["angle_deg"], p + ".angle_deg", -360, 360) * kDeg;
  if (e.contains("voltage_kV")) out.voltage = c.range(e["voltage_kV"], p + ".voltage_kV", -500, 500) * 1e3;
  return out;
}

// The wire or the tube (on the supply: no voltage of its own).
ElectrodeConfig parseSupplied(const Checker& c, const json& e, const std::string& p, const ElectrodeConfig& def) {
  c.object(e, p, {"enabled", "diameter_mm", "distance_mm", "angle_deg"});
  ElectrodeConfig out = def;
  if (e.contains("enabled")) out.enabled = c.boolean(e["enabled"], p + ".enabled");
  if (e.contains("diameter_mm")) out.diameter = c.positive(e["diameter_mm"], p + ".diameter_mm") * kMm;
  if (e.contains("distance_mm")) out.distance = c.positive(e["distance_mm"], p + ".distance_mm") * kMm;
  if (e.contains("angle_deg")) out.angle = c.range(e["angle_deg"], p + ".angle_deg", -360, 360) * kDeg;
  return out;
}

// A material's shapes: {name: weight}, at least one weight positive.
void parseShapes(const Checker& c, const json& shapes, const std::string& p, MaterialConfig& out) {
  const json& s = c.object(shapes, p + ".shapes", {"sphere", "flake", "wire", "ellipsoid", "fragment"});
  double sum = 0;
  for (int k = 0; k < kParticleShapes; ++k) {
    const char* name = particleShapeName(ParticleShape(k));
    out.shape_weight[k] = s.contains(name) ? c.nonNegative(s[name], p + ".shapes." + name) : 0.0;
    sum += out.shape_weight[k];
  }
  if (!(sum > 0)) c.fail(p + ".shapes", "needs at least one shape with a positive weight");
}

// A material's surface_conductivity_S (S, >= 0, at most 1; 0 when not given).
double parseSurfaceConductivity(const Checker& c, const json& m, const std::string& p) {
  return m.contains("surface_conductivity_S")
             ? c.range(m["surface_conductivity_S"], p + ".surface_conductivity_S", 0, 1)
             : 0.0;
}

// A composite (non-liberated) material: metal at a volume fraction uniform over metal_fraction [min, max] in a
// matrix of density_kg_m3 (one number), eps_r and conductivity_S_m (FR-4 glass-epoxy by default: 1850 kg/m^3,
// eps_r 4.4, 1e-14 S/m); the metal of metal_density_kg_m3 (copper, 8900). Its relaxation time follows from the
// fraction (charging.h: compositeRelaxationTime), so relaxation_time_s is refused.
MaterialConfig parseComposite(const Checker& c, const json& m, const std::string& p, const std::string& kind) {
  MaterialConfig out;
  out.kind = MaterialKind::Composite;
  out.name = m.contains("name") ? c.string(m["name"], p + ".name") : kind;
  out.eps_r = 4.4;
  out.conductivity = 1e-14;
  out.metal_fraction_min = 0.05, out.metal_fraction_max = 0.6;
  if (!m.contains("mass_fraction")) c.fail(p + ".mass_fraction", "missing");
  out.mass_fraction = c.range(m["mass_fraction"], p + ".mass_fraction", 0, 1);
  if (m.contains("relaxation_time_s"))
    c.fail(p + ".relaxation_time_s",
           "a composite's relaxation time follows from its metal fraction; give the "
           "matrix's conductivity_S_m instead");
  if (m.contains("metal_fraction")) {
    const json& f = m["metal_fraction"];
    if (f.is_number())
      out.metal_fraction_min = out.metal_fraction_max = c.range(f, p + ".metal_fraction", 0, 1);
    else
      c.interval(f, p + ".metal_fraction", out.metal_fraction_min, out.metal_fraction_max, true);
    if (!(out.metal_fraction_max <= 1))
      c.fail(p + ".metal_fraction", "must be <= 1, got " + num(out.metal_fraction_max));
  }
  if (m.contains("density_kg_m3")) out.matrix_density = c.positive(m["density_kg_m3"], p + ".density_kg_m3");
  if (m.contains("metal_density_kg_m3"))
    out.metal_density = c.positive(m["metal_density_kg_m3"], p + ".metal_density_kg_m3");
  if (!(out.metal_density > out.matrix_density))
    c.fail(p + ".metal_density_kg_m3", "must exceed the matrix's density_kg_m3 (" + num(out.matrix_density) + ")");
  if (m.contains("eps_r")) { out.eps_r = c.range(m["eps_r"], p + ".eps_r", 1, 1e6); }
  if (m.contains("conductivity_S_m"))
    out.conductivity = c.range(m["conductivity_S_m"], p + ".conductivity_S_m", 0, 1e3);
  out.relaxation_time = double(relaxationTime(real(out.eps_r), real(out.conductivity)));  // the matrix's
  // The mixture's density at the two fractions: the feeder draws it uniformly, i.e. the fraction uniformly.
  out.density_min = out.matrix_density + out.metal_fraction_min * (out.metal_density - out.matrix_density);
  out.density_max = out.matrix_density + out.metal_fraction_max * (out.metal_density - out.matrix_density);
  out.shape_weight[int(ParticleShape::Fragment)] = 1, out.shape_weight[0] = 0;
  if (m.contains("shapes")) parseShapes(c, m["shapes"], p, out);
  return out;
}

MaterialConfig parseMaterial(const Checker& c, const json& m, const std::string& p) {
  c.object(m, p,
           {"name", "kind", "mass_fraction", "density_kg_m3", "eps_r", "relaxation_time_s", "conductivity_S_m",
            "shapes", "metal_fraction", "metal_density_kg_m3", "surface_conductivity_S"});
  MaterialConfig out;
  if (!m.contains("kind")) c.fail(p + ".kind", "missing (metal|plastic|middling|composite)");
  const std::string kind = c.oneOf(m["kind"], p + ".kind", {"metal", "plastic", "middling", "composite"});
  out.kind = kind == "metal"       ? MaterialKind::Metal
             : kind == "plastic"   ? MaterialKind::Plastic
             : kind == "composite" ? MaterialKind::Composite
                                   : MaterialKind::Middling;
  if (out.kind == MaterialKind::Composite) {
    out = parseComposite(c, m, p, kind);
    out.surface_conductivity = parseSurfaceConductivity(c, m, p);
    return out;
  }
  out = defaultMaterial(out.kind);  // by kind: docs/CES.md, "Charges"
  out.surface_conductivity = parseSurfaceConductivity(c, m, p);
  out.name = m.contains("name") ? c.string(m["name"], p + ".name") : kind;
  for (const char* k : {"metal_fraction", "metal_density_kg_m3"})
    if (m.contains(k)) c.fail(p + "." + k, "only a composite material has it (kind \"composite\")");
  if (!m.contains("mass_fraction")) c.fail(p + ".mass_fraction", "missing");
  out.mass_fraction = c.range(m["mass_fraction"], p + ".mass_fraction", 0, 1);
  if (m.contains("density_kg_m3")) {
    const json& r = m["density_kg_m3"];
    if (r.is_number())
      out.density_min = out.density_max = c.positive(r, p + ".density_kg_m3");
    else
      c.interval(r, p + ".density_kg_m3", out.density_min, out.density_max);
  }
  if (m.contains("eps_r")) {
    out.eps_r = c.nonNegativeOrInf(m["eps_r"], p + ".eps_r");
    if (!(out.eps_r >= 1)) c.fail(p + ".eps_r", "relative permittivity must be >= 1, got " + num(out.eps_r));
  }
  if (m.contains("relaxation_time_s") && m.contains("conductivity_S_m"))
    c.fail(p + ".conductivity_S_m", "give either relaxation_time_s or conductivity_S_m, not both");
  if (m.contains("relaxation_time_s"))
    out.relaxation_time = c.nonNegativeOrInf(m["relaxation_time_s"], p + ".relaxation_time_s");
  if (m.contains("conductivity_S_m")) {
    // tau = eps0 eps_r / sigma (Haus & Melcher, "Electromagnetic Fields and Energy", 1989, §7.7).
    out.conductivity = c.nonNegativeOrInf(m["conductivity_S_m"], p + ".conductivity_S_m");
    out.relaxation_time =
        std::isinf(out.conductivity) ? 0.0 : double(relaxationTime(real(out.eps_r), real(out.conductivity)));
    if (std::isinf(out.eps_r) && !std::isinf(out.conductivity)) out.relaxation_time = 0.0;  // a metal
  }
  if (m.contains("shapes")) parseShapes(c, m["shapes"], p, out);
  return out;
}

}  // namespace

void applyCesOverride(json& doc, const std::string& assignment) {
  const size_t eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0)
    throw InputError("--set " + assignment + ": expected KEY=VALUE (e.g. electrode.voltage_kV=-30)");
  std::string key = assignment.substr(0, eq);
  const std::string text = assignment.substr(eq + 1);
  const std::string shown = key;
  if (key.rfind("ces.", 0) == 0) key = key.substr(4);
  if (!doc.contains("ces") || !doc["ces"].is_object())
    throw InputError("--set " + shown + ": the scene has no ces object");
  // A missing intermediate object is created (its keys are then checked by the parser); a missing leaf
  // is added and checked the same way, so an unknown key is still an error.
  jsoncheck::setByPath(doc["ces"], key, shown, jsoncheck::parseSetValue(text, "--set " + shown),
                       [](size_t, const std::string&) { return true; });
}

namespace {

bool has(const json& o, const char* k) { return o.contains(k); }

// The run itself: duration, time step (their step count checked) and seed.
void parseCesRun(const Checker& c, const json& j, CesConfig& cfg, const std::string& origin) {
  if (has(j, "duration_s")) cfg.duration = c.range(j["duration_s"], "ces.duration_s", 0, 1e6);
  if (has(j, "time_step_s")) cfg.step.dt = c.range(j["time_step_s"], "ces.time_step_s", 0, 0.01, true);
  checkedStepCount(cfg.duration, cfg.step.dt, origin + ": ces.duration_s");
  if (has(j, "seed")) cfg.seed = uint64_t(c.integer(j["seed"], "ces.seed", 0, int64_t(1) << 53));
}

void parseCesSolver(const Checker& c, const json& j, CesConfig& cfg) {
  if (!has(j, "solver")) return;
  const json& s = c.object(j["solver"], "ces.solver", {"type", "iterations", "gyroscopic"});
  if (has(s, "gyroscopic")) cfg.step.gyroscopic = c.boolean(s["gyroscopic"], "ces.solver.gyroscopic");
  if (has(s, "type"))
    cfg.solver.type = c.named<SolverType>(s["type"], "ces.solver.type",
                                          {{"jacobi", SolverType::Jacobi},
                                           {"gs", SolverType::GaussSeidel},
                                           {"apgd", SolverType::APGD},
                                           {"bb", SolverType::BB}});
  if (has(s, "iterations"))  // a fixed count (the tolerance stays 0)
    cfg.solver.max_iterations = int(c.integer(s["iterations"], "ces.solver.iterations", 1, 100000));
}

void parseCesDrum(const Checker& c, const json& j, CesConfig& cfg) {
  if (!has(j, "drum")) return;
  const json& s = c.object(j["drum"], "ces.drum", {"diameter_mm", "width_mm", "rpm", "drive", "mass_kg"});
  if (has(s, "diameter_mm")) cfg.drum_diameter = c.positive(s["diameter_mm"], "ces.drum.diameter_mm") * kMm;
  if (has(s, "width_mm")) cfg.drum_width = c.positive(s["width_mm"], "ces.drum.width_mm") * kMm;
  if (has(s, "rpm")) cfg.drum_rpm = c.range(s["rpm"], "ces.drum.rpm", -1000, 1000);
  if (has(s, "drive")) cfg.drum_drive = c.oneOf(s["drive"], "ces.drum.drive", {"auto", "kinematic", "rheonomic"});
  if (has(s, "mass_kg")) cfg.drum_mass = c.positive(s["mass_kg"], "ces.drum.mass_kg");
}

// The supply and its two electrodes; both electrodes take the supply's voltage.
void parseCesElectrode(const Checker& c, const json& j, CesConfig& cfg) {
  if (has(j, "electrode")) {
    const json& s = c.object(j["electrode"], "ces.electrode", {"voltage_kV", "wire", "tube"});
    // 0 is the supply off; the sign is the corona's polarity (negative corona is usual).
    if (has(s, "voltage_kV")) cfg.voltage = c.range(s["voltage_kV"], "ces.electrode.voltage_kV", -500, 500) * 1e3;
    if (has(s, "wire")) cfg.wire = parseSupplied(c, s["wire"], "ces.electrode.wire", cfg.wire);
    if (has(s, "tube")) cfg.tube = parseSupplied(c, s["tube"], "ces.electrode.tube", cfg.tube);
  }
  cfg.wire.voltage = cfg.tube.voltage = cfg.voltage;
}

// The field model, its extra electrodes, and whether the model fits the electrodes given.
void parseCesField(const Checker& c, const json& j, CesConfig& cfg) {
  if (has(j, "field")) {
    const json& s = c.object(j["field"], "ces.field", {"model", "extra_electrodes"});
    if (has(s, "model")) cfg.field_model = c.oneOf(s["model"], "ces.field.model", {"corona", "csm", "two_cylinder"});
    if (has(s, "extra_electrodes")) {
      const json& a = s["extra_electrodes"];
      if (!a.is_array()) c.fail("ces.field.extra_electrodes", "expected an array, got " + describe(a));
      for (size_t i = 0; i < a.size(); ++i)
        cfg.extra_electrodes.push_back(
            parseElectrode(c, a[i], "ces.field.extra_electrodes[" + std::to_string(i) + "]", ElectrodeConfig{}));
    }
  }
  if (cfg.field_model != "csm" && !cfg.extra_electrodes.empty())
    c.fail("ces.field.extra_electrodes", "only the csm field model takes extra electrodes; use \"model\": \"csm\"");
  if (cfg.field_model == "two_cylinder" && (cfg.wire.enabled || !cfg.tube.enabled))
    c.fail("ces.field.model", "two_cylinder is the tube alone: set electrode.wire.enabled = false and keep the tube");
  if (cfg.field_model == "corona" && !cfg.wire.enabled)
    c.fail("ces.field.model",
           "the corona model needs the corona wire (electrode.wire.enabled); use csm or two_cylinder without it");
  if (cfg.field_model == "csm" && !cfg.wire.enabled && !cfg.tube.enabled && cfg.extra_electrodes.empty())
    c.fail("ces.electrode", "no electrode: enable the wire or the tube");
}

void parseCesCorona(const Checker& c, const json& j, CesConfig& cfg) {
  if (!has(j, "corona")) return;
  const json& s = c.object(j["corona"], "ces.corona",
                           {"ion_mobility_m2_Vs", "rel_air_density", "roughness", "grid_mm", "image_cutoff_mm"});
  if (has(s, "ion_mobility_m2_Vs"))
    cfg.ion_mobility = c.range(s["ion_mobility_m2_Vs"], "ces.corona.ion_mobility_m2_Vs", 0, 1, true);
  if (has(s, "rel_air_density"))
    cfg.rel_air_density = c.range(s["rel_air_density"], "ces.corona.rel_air_density", 0, 10, true);
  if (has(s, "roughness")) cfg.roughness = c.range(s["roughness"], "ces.corona.roughness", 0, 1, true);
  if (has(s, "grid_mm")) cfg.corona_grid = c.range(s["grid_mm"], "ces.corona.grid_mm", 0.05, 20) * kMm;
  if (has(s, "image_cutoff_mm"))
    cfg.image_cutoff = c.nonNegative(s["image_cutoff_mm"], "ces.corona.image_cutoff_mm") * kMm;
}

void parseCesBrush(const Checker& c, const json& j, CesConfig& cfg) {
  if (!has(j, "brush")) return;
  const json& s =
      c.object(j["brush"], "ces.brush",
               {"diameter_mm", "core_diameter_mm", "angle_deg", "rpm", "gap_mm", "discharge_time_s", "sweep_time_s"});
  if (has(s, "diameter_mm")) cfg.brush_diameter = c.positive(s["diameter_mm"], "ces.brush.diameter_mm") * kMm;
  cfg.brush_core_diameter = has(s, "core_diameter_mm")
                                ? c.positive(s["core_diameter_mm"], "ces.brush.core_diameter_mm") * kMm
                                : cfg.brush_diameter;  // no bristles named: a smooth cylinder
  if (cfg.brush_core_diameter > cfg.brush_diameter)
    c.fail("ces.brush.core_diameter_mm", "larger than diameter_mm (the diameter over the bristle tips)");
  if (has(s, "angle_deg")) cfg.brush_angle = c.range(s["angle_deg"], "ces.brush.angle_deg", -360, 360) * kDeg;
  if (has(s, "rpm")) cfg.brush_rpm = c.range(s["rpm"], "ces.brush.rpm", -10000, 10000);
  if (has(s, "gap_mm")) cfg.brush_gap = c.nonNegative(s["gap_mm"], "ces.brush.gap_mm") * kMm;
  if (has(s, "discharge_time_s"))
    cfg.brush_discharge_time = c.nonNegative(s["discharge_time_s"], "ces.brush.discharge_time_s");
  if (has(s, "sweep_time_s")) cfg.brush_sweep_time = c.nonNegative(s["sweep_time_s"], "ces.brush.sweep_time_s");
}

void parseCesAir(const Checker& c, const json& j, CesConfig& cfg) {
  if (!has(j, "air")) return;
  const json& s = c.object(j["air"], "ces.air", {"viscosity_Pa_s", "density_kg_m3"});
  if (has(s, "viscosity_Pa_s")) cfg.air_viscosity = c.positive(s["viscosity_Pa_s"], "ces.air.viscosity_Pa_s");
  if (has(s, "density_kg_m3")) cfg.air_density = c.nonNegative(s["density_kg_m3"], "ces.air.density_kg_m3");
}

void parseCesFriction(const Checker& c, const json& j, CesConfig& cfg) {
  if (has(j, "friction")) {
    const json& s = c.object(j["friction"], "ces.friction",
                             {"particle_particle", "particle_drum", "particle_brush", "particle_wall", "rolling_drum"});
    if (has(s, "particle_particle"))
      cfg.mu_particle_particle = c.nonNegative(s["particle_particle"], "ces.friction.particle_particle");
    if (has(s, "particle_drum")) cfg.mu_particle_drum = c.nonNegative(s["particle_drum"], "ces.friction.particle_drum");
    if (has(s, "particle_brush"))
      cfg.mu_particle_brush = c.nonNegative(s["particle_brush"], "ces.friction.particle_brush");
    if (has(s, "particle_wall")) cfg.mu_particle_wall = c.nonNegative(s["particle_wall"], "ces.friction.particle_wall");
    if (has(s, "rolling_drum")) cfg.mu_rolling_drum = c.nonNegative(s["rolling_drum"], "ces.friction.rolling_drum");
  }
  if (!(cfg.mu_particle_particle > 0))
    c.fail("ces.friction.particle_particle",
           "must be > 0 (the other pairs are expressed through it under the product rule)");
}

// The feed and its materials; at least one material, and a feed no wider than the drum.
void parseCesFeed(const Checker& c, const json& j, CesConfig& cfg) {
  if (has(j, "feed")) {
    const json& s = c.object(j["feed"], "ces.feed",
                             {"mass_flow_g_s", "start_s", "duration_s", "angle_deg", "height_mm", "speed_m_s",
                              "width_mm", "diameter_mm", "materials"});
    if (has(s, "mass_flow_g_s"))
      cfg.feed_mass_flow = c.range(s["mass_flow_g_s"], "ces.feed.mass_flow_g_s", 0, 1e6) * 1e-3;
    if (has(s, "start_s")) cfg.feed_start = c.nonNegative(s["start_s"], "ces.feed.start_s");
    if (has(s, "duration_s")) cfg.feed_duration = c.nonNegative(s["duration_s"], "ces.feed.duration_s");
    if (has(s, "angle_deg")) cfg.feed_angle = c.range(s["angle_deg"], "ces.feed.angle_deg", -360, 360) * kDeg;
    if (has(s, "height_mm")) cfg.feed_height = c.positive(s["height_mm"], "ces.feed.height_mm") * kMm;
    if (has(s, "speed_m_s")) cfg.feed_speed = c.range(s["speed_m_s"], "ces.feed.speed_m_s", -100, 100);
    if (has(s, "width_mm")) cfg.feed_width = c.positive(s["width_mm"], "ces.feed.width_mm") * kMm;
    if (has(s, "diameter_mm")) {
      c.interval(s["diameter_mm"], "ces.feed.diameter_mm", cfg.diameter_min, cfg.diameter_max);
      cfg.diameter_min *= kMm;
      cfg.diameter_max *= kMm;
    }
    if (has(s, "materials")) {
      const json& a = s["materials"];
      if (!a.is_array() || a.empty()) c.fail("ces.feed.materials", "expected a non-empty array, got " + describe(a));
      double sum = 0;
      for (size_t i = 0; i < a.size(); ++i) {
        cfg.materials.push_back(parseMaterial(c, a[i], "ces.feed.materials[" + std::to_string(i) + "]"));
        sum += cfg.materials.back().mass_fraction;
      }
      if (!(sum > 0)) c.fail("ces.feed.materials", "the mass fractions sum to 0");
      if (cfg.materials.size() > 64) c.fail("ces.feed.materials", "at most 64 materials");
    }
  }
  if (cfg.materials.empty()) c.fail("ces.feed.materials", "missing (at least one material)");
  if (cfg.feed_width > cfg.drum_width)
    c.fail("ces.feed.width_mm", "wider than the drum (" + num(cfg.drum_width / kMm) + " mm)");
}

void parseCesCollection(const Checker& c, const json& j, CesConfig& cfg) {
  if (has(j, "collection")) {
    const json& s = c.object(j["collection"], "ces.collection", {"y_mm", "x0_mm"});
    if (has(s, "y_mm")) cfg.collection_y = c.range(s["y_mm"], "ces.collection.y_mm", -1e5, 1e5) * kMm;
    if (has(s, "x0_mm")) cfg.collection_x0 = c.range(s["x0_mm"], "ces.collection.x0_mm", -1e5, 1e5) * kMm;
  }
  if (!(cfg.collection_y < -cfg.drumRadius()))
    c.fail("ces.collection.y_mm",
           "the collection plane must lie below the drum (y < " + num(-cfg.drumRadius() / kMm) + " mm)");
}

void parseCesSplitters(const Checker& c, const json& j, CesConfig& cfg) {
  if (has(j, "splitters")) {
    const json& s =
        c.object(j["splitters"], "ces.splitters", {"s1_mm", "s2_mm", "range_mm", "positions", "grade_targets"});
    if (has(s, "grade_targets")) {
      const json& g = c.object(s["grade_targets"], "ces.splitters.grade_targets", {"conductor", "nonconductor"});
      if (has(g, "conductor"))
        cfg.grade_target_conductor = c.range(g["conductor"], "ces.splitters.grade_targets.conductor", 0, 1);
      if (has(g, "nonconductor"))
        cfg.grade_target_nonconductor = c.range(g["nonconductor"], "ces.splitters.grade_targets.nonconductor", 0, 1);
    }
    if (has(s, "s1_mm")) cfg.s1 = c.range(s["s1_mm"], "ces.splitters.s1_mm", -1e5, 1e5) * kMm;
    if (has(s, "s2_mm")) cfg.s2 = c.range(s["s2_mm"], "ces.splitters.s2_mm", -1e5, 1e5) * kMm;
    if (has(s, "range_mm")) {
      const json& r = s["range_mm"];
      if (!r.is_array() || r.size() != 2) c.fail("ces.splitters.range_mm", "expected [min, max], got " + describe(r));
      cfg.splitter_lo = c.range(r[0], "ces.splitters.range_mm[0]", -1e5, 1e5) * kMm;
      cfg.splitter_hi = c.range(r[1], "ces.splitters.range_mm[1]", -1e5, 1e5) * kMm;
      if (!(cfg.splitter_hi > cfg.splitter_lo)) c.fail("ces.splitters.range_mm", "max must exceed min");
    }
    if (has(s, "positions"))
      cfg.splitter_positions = int(c.integer(s["positions"], "ces.splitters.positions", 2, 10000));
  }
  if (cfg.s2 < cfg.s1) c.fail("ces.splitters.s2_mm", "must be >= s1_mm (" + num(cfg.s1 / kMm) + ")");
}

void parseCesOutput(const Checker& c, const json& j, CesConfig& cfg) {
  if (!has(j, "output")) return;
  const json& s = c.object(j["output"], "ces.output", {"frames", "histogram_bin_mm", "plots", "checkpoint_every_s"});
  if (has(s, "frames")) cfg.frames = int(c.integer(s["frames"], "ces.output.frames", 0, 1000000));
  if (has(s, "histogram_bin_mm"))
    cfg.histogram_bin = c.positive(s["histogram_bin_mm"], "ces.output.histogram_bin_mm") * kMm;
  if (has(s, "plots")) cfg.plots = c.boolean(s["plots"], "ces.output.plots");
  if (has(s, "checkpoint_every_s"))
    cfg.checkpoint_every = c.nonNegative(s["checkpoint_every_s"], "ces.output.checkpoint_every_s");
}

// Geometry: the electrodes outside the drum and apart from each other.
void checkCesElectrodeGeometry(const Checker& c, const CesConfig& cfg) {
  auto electrodeOk = [&](const ElectrodeConfig& e, const std::string& p) {
    if (!(e.distance > cfg.drumRadius() + e.diameter / 2))
      c.fail(p + ".distance_mm", "the electrode must lie outside the drum (distance > drum radius + electrode radius)");
  };
  if (cfg.wire.enabled) electrodeOk(cfg.wire, "ces.electrode.wire");
  if (cfg.tube.enabled) electrodeOk(cfg.tube, "ces.electrode.tube");
  for (size_t i = 0; i < cfg.extra_electrodes.size(); ++i)
    electrodeOk(cfg.extra_electrodes[i], "ces.field.extra_electrodes[" + std::to_string(i) + "]");
  if (cfg.wire.enabled && cfg.tube.enabled) {
    const double dx = cfg.wire.distance * std::cos(cfg.wire.angle) - cfg.tube.distance * std::cos(cfg.tube.angle);
    const double dy = cfg.wire.distance * std::sin(cfg.wire.angle) - cfg.tube.distance * std::sin(cfg.tube.angle);
    if (!(std::hypot(dx, dy) > (cfg.wire.diameter + cfg.tube.diameter) / 2))
      c.fail("ces.electrode.wire", "the wire and the tube overlap");
  }
}

// Spark-over: a supply at or above the uniform-field breakdown voltage of an electrode's gap to the drum
// certainly sparks over (field/breakdown.h) and is refused, naming the voltage and the gap.
void checkCesSparkover(const Checker& c, const CesConfig& cfg) {
  auto gapOk = [&](const ElectrodeConfig& e, double voltage, const std::string& vkey, const std::string& name) {
    const double gap = electrodeDrumGap(cfg.drumRadius(), e.distance, e.diameter);
    const double vb = uniformBreakdownVoltage(gap, cfg.rel_air_density);
    if (std::abs(voltage) >= vb) {
      std::ostringstream m;
      m << std::abs(voltage) / 1e3 << " kV across the " << gap / kMm << " mm gap from the " << name
        << " to the drum is beyond the air's breakdown voltage " << vb / 1e3
        << " kV (uniform field, Paschen/Dakin; a real gap sparks over lower): lower the voltage or widen the gap";
      c.fail(vkey, m.str());
    }
  };
  if (cfg.wire.enabled) gapOk(cfg.wire, cfg.voltage, "ces.electrode.voltage_kV", "corona wire");
  if (cfg.tube.enabled) gapOk(cfg.tube, cfg.voltage, "ces.electrode.voltage_kV", "tube");
  for (size_t i = 0; i < cfg.extra_electrodes.size(); ++i) {
    const std::string p = "ces.field.extra_electrodes[" + std::to_string(i) + "]";
    gapOk(cfg.extra_electrodes[i], cfg.extra_electrodes[i].voltage, p + ".voltage_kV", "electrode " + p);
  }
}

}  // namespace

double sparkoverMargin(const CesConfig& cfg) {
  double margin = 0;
  for (const ElectrodeConfig* e : {&cfg.wire, &cfg.tube}) {
    if (!e->enabled) continue;
    const double vb =
        uniformBreakdownVoltage(electrodeDrumGap(cfg.drumRadius(), e->distance, e->diameter), cfg.rel_air_density);
    margin = std::max(margin, vb > 0 ? std::abs(cfg.voltage) / vb : std::numeric_limits<double>::infinity());
  }
  return margin;
}

CesConfig parseCesDocument(const json& document, const std::vector<std::string>& overrides, const std::string& origin) {
  Checker c{origin};
  if (!document.is_object()) throw InputError(origin + ": expected a JSON object at the top level");
  checkJsonDepth(document, origin);
  json doc = document;
  c.object(doc, "(document)", {"$schema", "name", "description", "ces"});
  if (!doc.contains("ces")) throw InputError(origin + ": ces: missing (a CES scene needs the machine under \"ces\")");
  for (const std::string& o : overrides) applyCesOverride(doc, o);
  if (!overrides.empty()) checkJsonDepth(doc, origin);
  const json& j = c.object(doc["ces"], "ces",
                           {"duration_s", "time_step_s", "seed", "solver", "drum", "electrode", "field", "corona",
                            "brush", "air", "friction", "feed", "collection", "splitters", "output"});
  CesConfig cfg;
  // One section at a time, in this order: a section's checks may read the sections before it.
  parseCesRun(c, j, cfg, origin);
  using Section = void (*)(const Checker&, const json&, CesConfig&);
  for (const Section parse :
       {parseCesSolver, parseCesDrum, parseCesElectrode, parseCesField, parseCesCorona, parseCesBrush, parseCesAir,
        parseCesFriction, parseCesFeed, parseCesCollection, parseCesSplitters, parseCesOutput})
    parse(c, j, cfg);
  checkCesElectrodeGeometry(c, cfg);
  checkCesSparkover(c, cfg);
  return cfg;
}

}  // namespace ces
}  // namespace dvi
