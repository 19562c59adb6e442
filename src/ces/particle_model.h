// The per-particle operations of the CES plug-in, written once as DVI_HD functions over plain data
// (DESIGN §2 "single source"): the field at a point, the force on a particle (Coulomb + image + drag),
// the charge update of one step (corona charging, relaxation through a grounded contact, brush
// discharge) and the particle's status (in flight / collected / lost). The CPU calls them from OpenMP
// loops (machine.cpp); a CUDA kernel can call them on a device copy of CesModel (the CSM charges would
// then point to device memory).
//
// Every formula lives in forces.h / charging.h / field_*.h with its reference; this file only decides
// where each applies (docs/CES.md, "Where each force and charge applies").
#pragma once

#include <cmath>
#include <cstdint>

#include "ces/charging.h"
#include "ces/field_csm.h"
#include "ces/field_two_cylinder.h"
#include "ces/forces.h"

namespace dvi {
namespace ces {

constexpr int kMaxMaterials = 64;
constexpr int kMaxElectrodes = 8;

// Field model: the exact two-cylinder solution or a charge-simulation model (field_csm.h).
struct FieldView {
  int32_t model;  // 0: two-cylinder, 1: CSM
  TwoCylinderField tc;
  CsmFieldView csm;
};

DVI_HD FieldSample evalField(const FieldView& f, Vec3 p) {
  return f.model == 0 ? evalTwoCylinder(f.tc, p) : evalCsm(f.csm, p);
}

// A grounded or energised cylinder (axis along z) a particle can touch: the brush, an electrode.
struct CylinderXY {
  real cx, cy, R;
};

DVI_HD real distanceToCylinderSurface(const CylinderXY& c, Vec3 p) { return std::hypot(p.x - c.cx, p.y - c.cy) - c.R; }

// Everything the kernels read. Plain data: copyable to the device as one struct.
struct CesModel {
  FieldView field;
  DrumGeometry drum;         // axis, radius, width, image-force cutoff (forces.h)
  real polarity;             // sign of the corona ions (sign of the corona electrode's potential)
  real corona_ex, corona_ey; // unit vector from the drum axis toward the corona electrode
  real corona_cos_half;      // cos of the corona zone's half angle
  real corona_depth;         // m, distance to the drum surface within which particles are charged
  real corona_tau;           // s, Pauthenier's charging time constant (0: at once)
  real corona_field;         // V/m, charging field of the ionised zone (Pauthenier uses max(|E|, this))
  CylinderXY brush;
  real brush_tau;            // s, discharge time constant in brush contact
  int32_t n_electrodes;
  CylinderXY electrodes[kMaxElectrodes];
  real air_density, air_viscosity;
  real contact_tol;          // a particle touches a surface when its centre is within contact_tol x its bounding radius
  // Collection plane and the domain outside which a particle is lost.
  real collect_y;
  real domain_x_lo, domain_x_hi, domain_y_hi, domain_half_z;
  // Per material.
  int32_t n_materials;
  int32_t kind[kMaxMaterials];  // MaterialKind
  real eps_r[kMaxMaterials];
  real tau[kMaxMaterials];      // charge relaxation time through a grounded contact
};

// Particle status (per body; machine parts have kStatusMachine).
enum ParticleStatus : uint8_t { kStatusMachine = 0, kStatusInFlight = 1, kStatusCollected = 2, kStatusLost = 3 };

// Force on a particle of volume-equivalent radius r, charge q, at p with velocity v: Coulomb + image force
// (forces.h: zero outside the drum width, image force only near the drum) + Schiller-Naumann drag of the
// volume-equivalent sphere in still air.
DVI_HD Vec3 cesParticleForce(const CesModel& m, Vec3 p, Vec3 v, real q, real r) {
  Vec3 F = dragForceSphere(Vec3{0, 0, 0}, v, real(2) * r, m.air_density, m.air_viscosity);
  if (q != real(0)) {
    const FieldSample s = evalField(m.field, p);
    F += electricForce(m.drum, p, q, r, s.E);
  }
  return F;
}

// True when a particle with bounding radius `bound` at p touches the drum (centre within the contact
// tolerance of the surface, inside the drum's width).
DVI_HD bool touchesDrum(const CesModel& m, Vec3 p, real bound) {
  return insideDrumWidth(m.drum, p) && distanceToDrumSurface(m.drum, p) <= m.contact_tol * bound;
}

// In the corona zone: near the drum surface, within the zone's angle around the electrode direction.
DVI_HD bool inCoronaZone(const CesModel& m, Vec3 p) {
  if (!insideDrumWidth(m.drum, p)) return false;
  const real dx = p.x - m.drum.cx, dy = p.y - m.drum.cy;
  const real rho = std::hypot(dx, dy);
  if (!(rho > real(0)) || rho - m.drum.R > m.corona_depth) return false;
  return (dx * m.corona_ex + dy * m.corona_ey) >= m.corona_cos_half * rho;
}

// One step h of a particle's charge q (material mat, volume-equivalent radius r, bounding radius bound):
//  1. corona zone: field charging by the corona ions toward Pauthenier's saturation charge (polarity of
//     the corona) in the charging field max(|E|, corona_field), every material (a conductor gives its ion
//     charge to the drum in step 2);
//  2. drum contact: relaxation with the material's tau toward the induced (Félici) charge in the local
//     field (tau = 0 metals: the Félici charge at once; tau = inf plastics: unchanged);
//  3. contact with an electrode: the same relaxation toward the induced charge of that electrode
//     (outward normal of the electrode: a conductor touching it is recharged and repelled);
//  4. brush contact: discharge with the brush time constant.
// Charges never change in free flight.
DVI_HD real cesChargeUpdate(const CesModel& m, int mat, Vec3 p, real q, real r, real bound, real h) {
  const real eps = m.eps_r[mat], tau = m.tau[mat];
  const bool corona = inCoronaZone(m, p);
  const bool drum = touchesDrum(m, p, bound);
  if (corona || drum) {
    const FieldSample s = evalField(m.field, p);
    if (corona) {
      const real qs = pauthenierSaturationCharge(r, std::fmax(length(s.E), m.corona_field), eps);
      real qm = q * m.polarity;
      if (qm < real(0)) qm = real(0);
      q = m.polarity * pauthenierChargeUpdate(qm, qs, h, m.corona_tau);
    }
    if (drum) {
      const real dx = p.x - m.drum.cx, dy = p.y - m.drum.cy, rho = std::hypot(dx, dy);
      const Vec3 n{dx / rho, dy / rho, real(0)};
      q = relaxCharge(q, feliciCharge(r, s.E, n), h, tau);
    }
  }
  for (int k = 0; k < m.n_electrodes; ++k) {
    const CylinderXY& e = m.electrodes[k];
    if (!insideDrumWidth(m.drum, p) || distanceToCylinderSurface(e, p) > m.contact_tol * bound) continue;
    const real dx = p.x - e.cx, dy = p.y - e.cy, rho = std::hypot(dx, dy);
    if (!(rho > real(0))) continue;
    const Vec3 n{dx / rho, dy / rho, real(0)};
    // The field just outside the electrode, at the particle centre (region 0 there).
    const FieldSample s = evalField(m.field, p);
    q = relaxCharge(q, feliciCharge(r, s.E, n), h, tau);
  }
  if (distanceToCylinderSurface(m.brush, p) <= m.contact_tol * bound) q = brushDischarge(q, h, m.brush_tau);
  return q;
}

// Status after a step: collected once the centre is below the collection plane, lost when it leaves
// the machine's domain (or its state is not finite) without crossing it.
DVI_HD uint8_t cesClassify(const CesModel& m, Vec3 p) {
  if (!isFinite(p)) return kStatusLost;
  if (p.y < m.collect_y) return (p.x >= m.domain_x_lo && p.x <= m.domain_x_hi) ? kStatusCollected : kStatusLost;
  if (p.x < m.domain_x_lo || p.x > m.domain_x_hi || p.y > m.domain_y_hi || std::fabs(p.z - m.drum.zc) > m.domain_half_z)
    return kStatusLost;
  return kStatusInFlight;
}

}  // namespace ces
}  // namespace dvi
