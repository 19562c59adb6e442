// What a CES field model returns at a point: the potential and the electric field.
#pragma once

#include "chrono_like/base/math.h"

namespace dvi {
namespace ces {

// region: 0 = in the gas outside every conductor (phi, E from the model); k >= 1 = inside (or on) the
// k-th conductor of the model, where the electrostatic field is E = 0 and phi is that conductor's
// potential. E.z is always 0: the models are 2D (infinitely long cylinders along z); whether a point
// beyond the drum's width feels the field is decided by the force model (forces.h).
struct FieldSample {
  real phi;  // V
  Vec3 E;    // V/m
  int region;
};

}  // namespace ces
}  // namespace dvi
