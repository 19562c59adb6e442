// The per-particle operations of the CES plug-in, written once as DVI_HD functions over plain data: the
// field at a point, the force on a particle (Coulomb or the conductor's lift, image, drag, the brush's
// sweep), the charge update of one step (ion charging, relaxation through a grounded contact, brush
// discharge) and the particle's status (in flight / collected / lost). The CPU calls them from OpenMP loops (machine.cpp),
// the CUDA kernels (ces_device.cu) on a device copy of CesModel whose field arrays point to device memory.
//
// Every formula lives in forces.h / charging.h / shape_charging.h / field_*.h with its reference; this file only decides
// where each applies (docs/CES.md, "Charges" and "Forces").
#pragma once

#include <cmath>
#include <cstdint>

#include "ces/charging.h"
#include "ces/field/field_corona.h"
#include "ces/field/field_csm.h"
#include "ces/field/field_two_cylinder.h"
#include "ces/forces.h"
#include "ces/shape_charging.h"

namespace dvi {
namespace ces {

constexpr int kMaxMaterials = 64;
constexpr int kMaxElectrodes = 8;

// Field model: the exact two-cylinder solution or a charge-simulation model (field_csm.h), both Laplace
// fields without ions, or the steady ionised field of the corona wire sampled on a grid (field_corona.h:
// the Laplace field below onset, with ion density 0).
struct FieldView {
  int32_t model;  // 0: two-cylinder, 1: CSM, 2: corona grid
  TwoCylinderField tc;
  CsmFieldView csm;
  GridFieldView grid;
};

DVI_HD FieldSample evalField(const FieldView& f, Vec3 p) {
  return f.model == 0 ? evalTwoCylinder(f.tc, p) : f.model == 1 ? evalCsm(f.csm, p) : evalGrid(f.grid, p);
}

// Ion number density (1/m^3) at p: the corona model's; zero in the Laplace models.
DVI_HD real ionDensity(const FieldView& f, Vec3 p) { return f.model == 2 ? ionDensityAt(f.grid, p) : real(0); }

// A grounded or energised cylinder (axis along z) a particle can touch: the brush, an electrode.
struct CylinderXY {
  real cx, cy, R;
};

DVI_HD real distanceToCylinderSurface(const CylinderXY& c, Vec3 p) { return std::hypot(p.x - c.cx, p.y - c.cy) - c.R; }

// Per-particle flags (CesParticles::flags).
enum ParticleFlag : uint8_t {
  kFlagPinned = 1,  // touched the drum near its lowest point (see CesModel::pin_dy): held by electric forces
};

// Everything the kernels read. Plain data: copyable to the device as one struct.
struct CesModel {
  FieldView field;
  DrumGeometry drum;  // axis, radius, width, image-force cutoff (forces.h)
  real polarity;      // sign of the corona ions = sign of the supply voltage (0: supply off)
  real ion_mobility;  // m^2/(V s), of the corona's ions (Pauthenier's charging time)
  real pin_dy;        // a particle touching the drum with y - y_axis < pin_dy is pinned (kFlagPinned)
  // The brush: a rigid core (the collision body, not here) set with bristles up to `brush` (the circle of the
  // bristle tips, reaching the drum). A particle touching that circle or inside it is among the bristles:
  // discharged with brush_tau and swept toward the bristles' velocity omega_b z x (p - c) with brush_sweep_tau.
  CylinderXY brush;
  real brush_omega;      // rad/s about +z
  real brush_tau;        // s, discharge time constant among the bristles
  real brush_sweep_tau;  // s, velocity relaxation time toward the bristles' velocity
  int32_t n_electrodes;
  CylinderXY electrodes[kMaxElectrodes];
  real air_density, air_viscosity;
  real contact_tol;   // touching the drum: the centre within the shape's support + (contact_tol - 1) r (touchesDrum);
                      // the brush's bristles or an electrode: within contact_tol x the bounding radius
  real rolling_drum;  // mu_r of the particles on the drum (forces.h drumRollingTorque; 0: none)
  int32_t drum_body;  // the drum's body index (its angular velocity, for the rolling resistance)
  Vec3 gravity;       // m/s^2 (the rolling resistance's normal force)
  // Collection plane and the domain outside which a particle is lost.
  real collect_y;
  real domain_x_lo, domain_x_hi, domain_y_hi, domain_half_z;
  // Per material.
  int32_t n_materials;
  int32_t kind[kMaxMaterials];  // MaterialKind (0 metal, 1 plastic, 2 middling)
  real eps_r[kMaxMaterials];
  real tau[kMaxMaterials];  // charge relaxation time through a grounded contact, eps0 eps_r / sigma
};

constexpr int32_t kKindMetal = 0;  // MaterialKind::Metal (ces_config.h), as a plain int for the kernels

// Particle status (per body; machine parts have kStatusMachine).
enum ParticleStatus : uint8_t { kStatusMachine = 0, kStatusInFlight = 1, kStatusCollected = 2, kStatusLost = 3 };

// The drum's outward normal at p (radial in the cross-section; +x on the axis).
DVI_HD Vec3 drumNormal(const DrumGeometry& g, Vec3 p) {
  const real dx = p.x - g.cx, dy = p.y - g.cy, rho = std::hypot(dx, dy);
  return rho > real(0) ? Vec3{dx / rho, dy / rho, real(0)} : Vec3{1, 0, 0};
}

// True when a particle touches the drum: inside the drum's width, its centre no further from the surface than
// its true distance in contact, the support h of its shape along the drum's normal (shapeSupport), plus
// (contact_tol - 1) x its volume-equivalent radius r (a sphere: within contact_tol x r, as it always was).
DVI_HD bool touchesDrum(const CesModel& m, Vec3 p, real h, real r) {
  return insideDrumWidth(m.drum, p) && distanceToDrumSurface(m.drum, p) <= h + (m.contact_tol - real(1)) * r;
}

// The support of particle pe (orientation rot) along the drum's normal at p.
DVI_HD real drumSupport(const CesModel& m, const ParticleElectro& pe, Vec3 p, Quat rot) {
  return shapeSupport(pe, rotateInv(rot, drumNormal(m.drum, p)));
}

// True when a particle with bounding radius `bound` at p is among the brush's bristles: its centre within the
// contact tolerance of the bristle tips' circle, or inside it.
DVI_HD bool amongBristles(const CesModel& m, Vec3 p, real bound) {
  return distanceToCylinderSurface(m.brush, p) <= m.contact_tol * bound;
}

// Velocity of the bristles at p (rigid rotation of the brush about its axis).
DVI_HD Vec3 bristleVelocity(const CesModel& m, Vec3 p) {
  return Vec3{-m.brush_omega * (p.y - m.brush.cy), m.brush_omega * (p.x - m.brush.cx), real(0)};
}

// Force on particle pe (shape_charging.h: its shape's and material's constants) of mass `mass`,
// volume-equivalent radius r, bounding radius bound, charge q, at p with orientation rot and velocity v, for a
// step h: Schiller-Naumann drag of the volume-equivalent sphere in still air; among the brush's bristles their
// sweep (forces.h: bristleSweepForce); inside the drum width the electric force, with u the drum's normal in the
// body frame:
//  - a conductor (pe.conductor: metal, or a composite above percolation) touching the drum: the lift k_L(u) q E
//    of its shape lying in that orientation (shape_charging.h: the sphere's Lebedev-Skal'skaya k_L = 0.832, a
//    plate's 1/2, a lying wire's (pi^2 + 3)/18 = 0.715 ...), which already holds its image in the drum;
//  - a conductor in flight: q E (its image in the drum is below 0.1 q E a diameter away and is left out,
//    so the force does not drop below the contact value as it lifts off);
//  - insulators: q E plus the image force of their charge toward the drum at the shape's true distance, no more
//    than a flat sheet's on its footprint (imageForceShape).
DVI_HD Vec3 cesParticleForce(const CesModel& m, const ParticleElectro& pe, Vec3 p, Quat rot, Vec3 v, real q, real r,
                             real bound, real mass, real h) {
  Vec3 F = dragForceSphere(Vec3{0, 0, 0}, v, real(2) * r, m.air_density, m.air_viscosity);
  if (amongBristles(m, p, bound)) F += bristleSweepForce(mass, v, bristleVelocity(m, p), h, m.brush_sweep_tau);
  if (q == real(0) || !insideDrumWidth(m.drum, p)) return F;
  const FieldSample s = evalField(m.field, p);
  const Vec3 n = drumNormal(m.drum, p), u = rotateInv(rot, n);
  const real support = shapeSupport(pe, u), d = distanceToDrumSurface(m.drum, p);
  if (pe.conductor) {
    const bool touching = d <= support + (m.contact_tol - real(1)) * r;
    return F + (touching ? weighted(pe.lift, u) : real(1)) * coulombForce(q, s.E);
  }
  F += coulombForce(q, s.E);
  if (d <= m.drum.imageCutoff) F += (-imageForceShape(q, d, support, weighted(pe.foot, u))) * n;
  return F;
}

// Torque on a particle touching the drum: its rolling resistance (forces.h: drumRollingTorque), with F the
// particle's other forces (cesParticleForce) and w_drum the drum's angular velocity. moment: the particle's
// smallest principal moment of inertia.
DVI_HD Vec3 cesParticleTorque(const CesModel& m, const ParticleElectro& pe, Vec3 p, Quat rot, Vec3 v, Vec3 w,
                              Vec3 w_drum, Vec3 F, real r, real mass, real moment, real h) {
  if (!(m.rolling_drum > real(0)) || !touchesDrum(m, p, drumSupport(m, pe, p, rot), r)) return Vec3{0, 0, 0};
  return drumRollingTorque(m.drum, p, v, w, w_drum, F, m.gravity, mass, r, moment, m.rolling_drum, h);
}

// Induced charge of particle pe (orientation rot) resting on an earthed conductor whose outward normal is n, in
// the field E there: eps0 (E.n) qcoef(u), u = R^T n (shape_charging.h; a sphere's is the Félici charge).
DVI_HD real inducedCharge(const ParticleElectro& pe, Quat rot, Vec3 E, Vec3 n) {
  return kEps0 * dot(E, n) * weighted(pe.qcoef, rotateInv(rot, n));
}

// One step h of a particle's charge q (pe, orientation rot, volume-equivalent radius r, bounding radius bound);
// flags gains kFlagPinned when the particle touches the drum near its lowest point. In this order:
//  1. ion (field) charging wherever the corona's ions are (ion density N > 0, inside the drum width):
//     Pauthenier's law with the LOCAL field and ion density, the saturation charge of the particle's equivalent
//     ellipsoid in its orientation (shape_charging.h; a sphere's 4 pi eps0 r^2 |E| p), tau_c = 4 eps0/(N e mu),
//     in the ions' polarity, for every material;
//  2. drum contact (true distance, touchesDrum): relaxation with the particle's tau = eps0 eps_r / sigma toward
//     its induced charge in the local field (inducedCharge): a metal (tau = 0) takes it at once, so it leaves
//     the drum with the sign of E.n (opposite to the electrode's) and any ion charge goes to earth; an insulator
//     (tau ~ hours) keeps its ion charge; a middling or composite moves toward the induced charge in its time;
//  3. contact with an electrode: the same relaxation toward the induced charge of that electrode
//     (outward normal of the electrode: a conductor touching it is recharged and repelled);
//  4. among the brush's bristles: discharge with the brush time constant.
// Away from ions and contacts the charge does not change.
DVI_HD real cesChargeUpdate(const CesModel& m, const ParticleElectro& pe, Vec3 p, Quat rot, real q, real r, real bound,
                            real h, uint8_t& flags) {
  const bool inside = insideDrumWidth(m.drum, p);
  const bool drum = touchesDrum(m, p, drumSupport(m, pe, p, rot), r);
  const real N = inside && m.polarity != real(0) ? ionDensity(m.field, p) : real(0);
  if (N > real(0) || drum) {
    const FieldSample s = evalField(m.field, p);
    if (N > real(0) && s.region == 0) {
      const real qs = pauthenierSaturationChargeEllipsoid(pe.semi, pe.depol, rotateInv(rot, s.E), pe.eps_r);
      const real tc = pauthenierTimeConstant(N, m.ion_mobility);
      q = m.polarity * pauthenierChargeUpdate(q * m.polarity, qs, h, tc);
    }
    if (drum) {
      q = relaxCharge(q, inducedCharge(pe, rot, s.E, drumNormal(m.drum, p)), h, pe.tau);
      if (p.y - m.drum.cy < m.pin_dy) flags = uint8_t(flags | kFlagPinned);
    }
  }
  for (int k = 0; k < m.n_electrodes; ++k) {
    const CylinderXY& e = m.electrodes[k];
    if (!inside || distanceToCylinderSurface(e, p) > m.contact_tol * bound) continue;
    const real dx = p.x - e.cx, dy = p.y - e.cy, rho = std::hypot(dx, dy);
    if (!(rho > real(0))) continue;
    const Vec3 n{dx / rho, dy / rho, real(0)};
    // The field just outside the electrode, at the particle centre (region 0 there).
    const FieldSample s = evalField(m.field, p);
    q = relaxCharge(q, inducedCharge(pe, rot, s.E, n), h, pe.tau);
  }
  if (amongBristles(m, p, bound)) q = brushDischarge(q, h, m.brush_tau);
  return q;
}

// A sphere of radius r of material mat (the model's per-material eps_r, tau and kind): the particle the
// material-indexed forms below take.
DVI_HD ParticleElectro sphereElectro(const CesModel& m, int mat, real r) {
  ParticleElectro pe;
  shapeElectro(kShapeSphere, Vec3{r, r, r}, pe);
  pe.eps_r = m.eps_r[mat];
  pe.tau = m.tau[mat];
  pe.conductor = m.kind[mat] == kKindMetal ? 1 : 0;
  pe.metal_fraction = m.kind[mat] == kKindMetal ? real(1) : real(0);
  return pe;
}

// The same for a sphere of material mat and radius r (any orientation), as the model had it before the shapes.
DVI_HD Vec3 cesParticleForce(const CesModel& m, int mat, Vec3 p, Vec3 v, real q, real r, real bound, real mass,
                             real h) {
  return cesParticleForce(m, sphereElectro(m, mat, r), p, Quat{1, 0, 0, 0}, v, q, r, bound, mass, h);
}
DVI_HD real cesChargeUpdate(const CesModel& m, int mat, Vec3 p, real q, real r, real bound, real h, uint8_t& flags) {
  return cesChargeUpdate(m, sphereElectro(m, mat, r), p, Quat{1, 0, 0, 0}, q, r, bound, h, flags);
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

// Charge exchange between touching in-flight particles after a step (charging.h: contactChargeFlux), in three
// passes over the step's contacts, the same on both backends: the particles a machine part holds (heldParticle:
// touching the drum, an electrode, the brush or a wall, whose charge the relaxations of cesChargeUpdate set: their
// potential is the part's, not q / C), the partner counts n of the others (exchangesCharge), then each pair's flux
// from the charges before the exchange (exchangeFlux: minus to body a, plus to body b).
DVI_HD int32_t heldParticle(const uint8_t* status, const int32_t* body_a, const int32_t* body_b, const real* dist,
                            int64_t k) {
  if (!(dist[k] <= real(0))) return -1;
  const int32_t a = body_a[k], b = body_b[k];
  if (status[a] == kStatusMachine && status[b] == kStatusInFlight) return b;
  if (status[b] == kStatusMachine && status[a] == kStatusInFlight) return a;
  return -1;
}
DVI_HD bool exchangesCharge(const uint8_t* status, const uint8_t* held, const int32_t* body_a, const int32_t* body_b,
                            const real* dist, int64_t k) {
  const int32_t a = body_a[k], b = body_b[k];
  return status[a] == kStatusInFlight && status[b] == kStatusInFlight && !held[a] && !held[b] &&
         firstTouchingPointOfPair(body_a, body_b, dist, k);
}
DVI_HD real exchangeFlux(const ParticleElectro* pe, const real* radius, const real* charge, const int32_t* partners,
                         int32_t a, int32_t b, real h) {
  const int32_t m = partners[a] > partners[b] ? partners[a] : partners[b];
  return contactChargeFlux(charge[a], charge[b], radius[a], radius[b], pe[a].tau, pe[b].tau, h, m);
}

}  // namespace ces
}  // namespace dvi
