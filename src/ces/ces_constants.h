// Physical constants and the default machine of the corona electrostatic separator (docs/CES.md).
//
// Coordinates of the CES model: the drum axis is the z axis of the machine, the field problems are
// solved in the (x, y) cross-section with y up (gravity along -y), angles are measured
// counter-clockwise from +x. Every quantity is in SI units (m, kg, s, V, C) unless its name says
// otherwise (rpm, deg, mm are only used for the human-facing defaults and converted by helpers).
#pragma once

#include <limits>

#include "chrono_like/base/hd.h"

namespace dvi {
namespace ces {

// Vacuum permittivity, CODATA 2018 recommended value (Tiesinga et al., Rev. Mod. Phys. 93, 025010,
// 2021): eps0 = 8.8541878128(13) e-12 F/m. Air at 1 atm has eps_r = 1.00059; the CES literature
// uses eps0 for air and so do we.
constexpr real kEps0 = real(8.8541878128e-12);
constexpr real kPi = real(3.14159265358979323846);
// Elementary charge, exact in the 2019 SI (BIPM SI Brochure, 9th ed., 2019).
constexpr real kElementaryCharge = real(1.602176634e-19);
// 1 / (2 pi eps0): potential of a line charge per unit of lambda and ln-distance (V m / C).
constexpr real kInv2PiEps0 = real(1) / (real(2) * kPi * kEps0);

DVI_HD constexpr real degToRad(real deg) { return deg * kPi / real(180); }
DVI_HD constexpr real rpmToRadPerSec(real rpm) { return rpm * real(2) * kPi / real(60); }

// Machine constants. Values marked [spec] are the project's specification (drum, particles, air, from the
// public Chrono CES demo machine); [assumed] values are placeholders. The electrodes of the default machine
// (corona wire and static tube) are in scenes/ces_default.json and docs/CES.md; electrode_* here is the
// single tube of the old demo machine.
struct CesMachineParams {
  // --- drum (grounded, phi = 0) ---
  real drum_diameter = real(0.320);  // m [spec]
  real drum_width = real(0.300);     // m, extent along z; electric forces act for |z| <= width/2 [spec]
  real drum_rpm = real(44.8);        // rev/min [spec]
  real drum_center_x = real(0);      // m, axis position in the cross-section [assumed: origin]
  real drum_center_y = real(0);      // m
  real drum_friction = real(0.5);    // particle-drum Coulomb friction [spec]

  // --- static electrode (tube, phi = U) ---
  real electrode_diameter = real(0.038);  // m [spec]
  real electrode_distance = real(0.267);  // m, centre distance L from the drum axis [spec]
  real electrode_angle_deg = real(30);    // deg above the horizontal, alpha [spec]
  real electrode_voltage = real(-35000);  // V, U [spec]

  // --- brush (rotating cylinder that sweeps insulators off the drum) ---
  real brush_diameter = real(0.106);       // m [spec]
  real brush_angle_deg = real(-135);       // deg, direction of the brush axis from the drum axis [assumed]
  real brush_rpm = real(-120);             // rev/min, sign = sense of rotation [assumed]
  real brush_discharge_time = real(1e-3);  // s, relaxation time of a particle's charge in brush contact [assumed]

  // --- air ---
  real air_viscosity = real(1.81e-5);  // Pa s, eta [spec]
  real air_density = real(1.225);      // kg/m^3, rho [spec]

  // --- particles and materials ---
  real particle_diameter_min = real(0.5e-3);  // m [spec]
  real particle_diameter_max = real(1.0e-3);  // m [spec]
  real metal_density_min = real(8400);        // kg/m^3 [spec]
  real metal_density_max = real(8900);        // kg/m^3 [spec]
  real plastic_density = real(946);           // kg/m^3 [spec]
  real plastic_eps_r = real(2.5);             // relative permittivity of the insulator [spec]
  real particle_friction = real(0.2);         // particle-particle Coulomb friction [spec]
  // Charge relaxation time constants tau = eps/sigma through the drum contact (infinite
  // for plastics, ~0 for metals, in between for non-liberated middlings).
  real metal_relaxation_time = real(0);                                  // s
  real plastic_relaxation_time = std::numeric_limits<real>::infinity();  // s
  real middling_relaxation_time = real(0.5);                             // s [assumed]

  // --- electric force model ---
  real image_force_cutoff = real(5e-3);  // m, image force acts for charge-to-drum-surface distance <= cutoff [assumed]

  // --- integration ---
  real time_step = real(1e-4);  // s, h in [1e-4, 1e-3] [spec]

  // Derived helpers.
  DVI_HD real drumRadius() const { return drum_diameter / 2; }
  DVI_HD real electrodeRadius() const { return electrode_diameter / 2; }
  DVI_HD real brushRadius() const { return brush_diameter / 2; }
  DVI_HD real drumOmega() const { return rpmToRadPerSec(drum_rpm); }
  DVI_HD real electrodeAngle() const { return degToRad(electrode_angle_deg); }
};

}  // namespace ces
}  // namespace dvi
