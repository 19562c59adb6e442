// The vibrating feeder: a multidisperse emitter with a constant mass flow (docs/CES.md, Feed).
//
// Each particle has a volume-equivalent diameter d uniform in [d_min, d_max], a material chosen so that
// the fed mass follows the materials' mass fractions (the material furthest below its share of the mass
// fed so far comes next: deterministic, exact in the long run), a density uniform in the material's
// range and a shape drawn by the material's shape weights:
//   sphere    radius d/2
//   flake     box, half extents (a, a/4, a)                 (a plate 1/4 as thick as wide)
//   wire      cylinder, length = 4 x its diameter
//   ellipsoid semi-axes (a, 0.5 a, 0.7 a)
//   fragment  convex hull of 10 random points on a random ellipsoid, in its principal frame
// every one scaled to the volume pi d^3 / 6, with the exact volume and inertia of its shape.
// Masses are whole femtograms (1e-15 kg), so every mass sum of the run (fed, collected, per bin) is an
// exact integer and the mass balance closes exactly.
//
// Random numbers: SplitMix64 (chrono_like/base/random.h), identical on every platform; its state is part of the
// checkpoint.
#pragma once

#include <cstdint>
#include <vector>

#include "ces/ces_config.h"
#include "ces/shape_charging.h"
#include "chrono_like/base/random.h"
#include "chrono_like/system.h"

namespace dvi {
namespace ces {

constexpr double kFemtogram = 1e-15;  // kg, the unit of every particle mass

// One fed particle: enough to rebuild its body (for a checkpoint) and to account for it.
struct ParticleSpec {
  int32_t material = 0;
  ParticleShape shape = ParticleShape::Sphere;
  Vec3 dims{0, 0, 0};      // sphere: (r, 0, 0); flake: half extents; wire: (r, half height, 0); ellipsoid: semi-axes
  std::vector<Vec3> hull;  // fragment: points in the principal frame (centroid at the origin)
  int64_t mass_fg = 0;     // mass in femtograms
  Vec3 inertia{0, 0, 0};   // principal moments, kg m^2
  real radius = 0;         // volume-equivalent radius (charge, drag)
  real bound = 0;          // bounding radius about the centre of mass
  // Set from the rest by compositeParts (not stored in a checkpoint: a composite's metal fraction follows from its
  // density). Volume fraction of metal (1 for a metal, 0 for plastics and middlings) and the metal's mass.
  double metal_fraction = 0;
  int64_t metal_fg = 0;
};

// A composite (non-liberated) particle is metal of density rho_m at volume fraction phi in a matrix of density
// rho_p, rho = phi rho_m + (1 - phi) rho_p (the mixture's volume average): the feeder draws rho uniform over
// [rho(phi_min), rho(phi_max)] (MaterialConfig), i.e. phi uniform over [phi_min, phi_max], and phi is read back
// from the particle's mass and volume, phi = (rho - rho_p) / (rho_m - rho_p). Its metal mass is
// metal_fg = round(mass_fg phi rho_m / rho), its plastic mass the rest (exact integers: the balance still closes).
// Metals: phi = 1, all metal; plastics and middlings: 0.
void compositeParts(ParticleSpec& s, const MaterialConfig& mat);

// The particle's electrostatic constants (shape_charging.h): its shape's (in the principal frame; a fragment by
// the ellipsoid of its moments of inertia, of its volume) and its material's: a metal conducts (tau of the
// material); plastics and middlings have their eps_r and tau; a composite its Maxwell Garnett permittivity and
// GEM relaxation time at its metal fraction (charging.h), and conducts (lifted like a metal) from the
// percolation threshold up.
ParticleElectro makeParticleElectro(const ParticleSpec& s, const MaterialConfig& mat);

// Emission: the owed mass grows by mass_flow x h each step; while it is >= 0 a particle is emitted and
// its mass subtracted, so the fed mass tracks mass_flow x t within one particle mass.
//
// Builds a particle of the given material, shape, volume-equivalent diameter and density.
ParticleSpec makeParticleSpec(int material, ParticleShape shape, double diameter, double density, SplitMix64& rng);

// The collision shape of a spec (body frame = principal frame).
ShapeDesc particleShapeDesc(const ParticleSpec& s);

// The expected mass (kg) of one fed particle under cfg's feed distributions, exactly (no sampling):
// every shape is scaled to the volume pi d^3 / 6, d ~ U[d_min, d_max] and rho ~ U[rho_min, rho_max] are
// drawn independently, so material k's mean mass is m_k = (pi/6) E[d^3] E[rho_k] with
// E[d^3] = (d_max^4 - d_min^4) / (4 (d_max - d_min)) (the third moment of the uniform distribution).
// The materials follow their mass fractions f_k (drawNext), so particles of k are fed at f_k mdot / m_k
// per second and the mean over all particles is 1 / sum_k (f_k / m_k) (f normalised). The femtogram
// rounding of each mass (< 1e-7 relative) is left out. Used by `dvisim bench ces` to set the mass flow
// of a particle rate; tested against a large sample drawn through Feeder::emit.
double expectedParticleMass(const CesConfig& cfg);

// The feed rate (kg/s) that covers the drum with one layer: the particles, each resting on its largest face,
// cover in total the area the drum's surface carries through the feed line per second,
//     mdot_mono = v W m / E[A],  v = |omega| R the drum's surface speed, W = feed.width, m = expectedParticleMass,
// E[A] = E[d^2] sum_k n_k sum_s w_ks c_s the mean footprint (n_k the count share of material k, w_ks its shape
// weights), with the footprint c_s d^2 of each shape of volume-equivalent diameter d lying flat: sphere pi/4,
// flake (box 2a x a/2 x 2a) 4a^2 = 4 (pi/12)^(2/3) = 1.638, wire (cylinder r, length 8r) 16 r^2 = 1.212,
// ellipsoid (a, 0.5a, 0.7a) on its smallest axis 0.7 pi a^2 = 1.107; a fragment (the hull of points on a random
// ellipsoid) as the ellipsoid. Coverage = feed / mdot_mono is the layer's area fraction at the drum's speed;
// a random layer of discs jams at ~0.82 of the area (docs/CES.md, "Crowding"). Where particles are fed, slower
// than the drum (feed.speed_m_s), the layer is denser by up to v / feed speed.
double expectedFootprintArea(const CesConfig& cfg);  // m^2
double monolayerMassFlow(const CesConfig& cfg);      // kg/s

class Feeder {
 public:
  explicit Feeder(const CesConfig& cfg);

  // Appends to `out` the particles due in the step [t, t + h).
  // Stops when the feed window [start, start + duration) is over.
  void emit(double t, double h, std::vector<ParticleSpec>& out);
  // Draws a random orientation (Shoemake, "Uniform random rotations", Graphics Gems III, 1992).
  Quat randomRotation();
  double uniform(double a, double b) { return rng_.uniform(a, b); }

  int64_t fedMassFg() const { return fed_total_fg_; }

  // Checkpoint state.
  struct State {
    uint64_t rng = 1;
    double owed_kg = 0;
    int64_t fed_total_fg = 0;
    std::vector<int64_t> fed_fg;  // per material
  };
  State state() const;
  void setState(const State& s);

 private:
  ParticleSpec drawNext();

  const CesConfig& cfg_;
  SplitMix64 rng_;
  double owed_kg_ = 0;
  int64_t fed_total_fg_ = 0;
  std::vector<int64_t> fed_fg_;
  std::vector<double> fraction_;  // normalised mass fractions
};

}  // namespace ces
}  // namespace dvi
