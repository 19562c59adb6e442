// Physical constants of the corona electrostatic separator (docs/CES.md). The default machine (drum, electrodes,
// brush, air, materials, the time step) is the configuration's: ces/ces_config.h (CesConfig, defaultMaterial).
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

}  // namespace ces
}  // namespace dvi
