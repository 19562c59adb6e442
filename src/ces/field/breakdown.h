// Spark-over (electrical breakdown of the air) between a high-voltage electrode and the earthed drum
// (docs/CES.md, "Spark-over"). Host code: the configuration refuses a supply beyond the bound below, and the
// machine reports the margin.
//
// The bound. In a uniform field the breakdown voltage of air at 20 C follows Paschen's law; for gaps of
// millimetres to decimetres at about atmospheric pressure the measured curve is fitted by
//     V_b = 24.36 (p d) + 6.72 sqrt(p d)  kV,  p d in bar cm
// (W. Dakin, G. Luxa, G. Oppermann, J. Vigreux, G. Wind, H. Winkelnkemper, "Breakdown of gases in uniform
// fields: Paschen curves for nitrogen, air and sulfur hexafluoride", Electra 32 (1974) 61-82; the same fit in
// E. Kuffel, W. S. Zaengl, J. Kuffel, "High Voltage Engineering: Fundamentals", 2nd ed., Newnes 2000, ch. 5),
// i.e. ~3 kV/mm for gaps of a few cm (31 kV at 1 cm, 3.1 MV/m); p/p0 is taken as the relative air density
// delta (corona.rel_air_density). The electrodes of a roll separator make a NON-uniform field (a wire or a tube
// over a cylinder); the field's enhancement lowers the breakdown voltage of a gap below that of the uniform gap
// of the same spacing (Kuffel et al., ch. 5, the field-utilisation factor), so a supply at or above V_b of the
// narrowest electrode-drum gap certainly sparks over: it is refused. Below it a wire gap may still spark over
// (negative DC wire-plane gaps break down at a fraction of V_b that depends on the corona's space charge and
// the material on the roll; laboratory roll separators are set just below the threshold beyond which sparks
// occur with the material present, found on the machine: A. Mihalcioiu, doctoral thesis on corona-electrostatic
// separation, ch. 4, "High voltage measurement in corona electrostatic separators"): the margin |U| / V_b is
// reported, not a prediction of that threshold.
//
// A "static" electrode must not ionise (Dascalescu et al., J. Electrostatics 29 (1993) 211-225): its surface
// field is compared with Peek's onset field of a cylinder of its radius (field_corona.h: peekOnsetField), and a
// tube above it is flagged (it would run its own corona, the precursor of spark-over on a static electrode).
#pragma once

#include <cmath>

namespace dvi {
namespace ces {

// Uniform-field breakdown voltage of air (V, positive) across a gap of `gap` metres at the relative air
// density `rel_air_density` (Dakin et al. 1974, above).
inline double uniformBreakdownVoltage(double gap, double rel_air_density = 1.0) {
  const double pd = rel_air_density * gap * 100.0;  // bar cm (p0 = 1.01325 bar ~ 1 bar: within 1.3%)
  if (!(pd > 0)) return 0;
  return (24.36 * pd + 6.72 * std::sqrt(pd)) * 1e3;
}

// Surface-to-surface gap (m) between the drum (radius R, axis at the origin) and a cylindrical electrode of
// diameter `diameter` whose axis is `distance` from the drum's.
inline double electrodeDrumGap(double drum_radius, double distance, double diameter) {
  return distance - drum_radius - diameter / 2;
}

}  // namespace ces
}  // namespace dvi
