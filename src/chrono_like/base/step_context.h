// The context of one time step, handed to the stages and to the plug-ins (force_field.h: ForceField,
// solver/constraint_row.h: RowProvider) and to the collision backends (collision/collision.h). The System makes
// one at the start of every step from its configuration (system.h: StepSettings::dt) and its clock; the
// plug-ins read the step from here instead of keeping their own copy.
#pragma once

#include <cstdint>

#include "chrono_like/base/hd.h"

namespace dvi {

struct StepContext {
  real dt = 0;       // [s] the step h (SystemConfig::step.dt in the engine's precision)
  real inv_dt = 0;   // [1/s] 1 / h
  double t = 0;      // [s] simulated time at the start of the step
  int64_t step = 0;  // index of the step: 0 for the first one
  // [s] simulated time at the end of the step, t + h (the time a rheonomic constraint row is written for).
  double end() const { return t + double(dt); }
};

// A step of h at time t, the step-th one.
inline StepContext makeStepContext(real h, double t = 0, int64_t step = 0) {
  StepContext c;
  c.dt = h;
  c.inv_dt = real(1) / h;
  c.t = t;
  c.step = step;
  return c;
}

}  // namespace dvi
