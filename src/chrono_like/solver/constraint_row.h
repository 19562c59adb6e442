// Generic constraint rows, the System's extension point for joints, motors and rheonomic drives (BuildRows /
// Solve): plug-ins (the Bullet drop-in world's joints, the CES drum drive) implement RowProvider; the core never
// knows what the rows model. Force fields, the other extension point, are in force_field.h.
//
// Constraint rows (docs/MODEL.md §2-3; Tasora & Anitescu, "A matrix-free cone complementarity approach for solving
// large-scale, nonsmooth, rigid body dynamics", CMAME 200 (2011), eq. 14 for bilateral rows): row i acts
// on bodies a and b with Jacobian rows Ja, Jb (linear part first, then angular, world frame) and impulse
// l_i, solved together with the contacts as part of one CCP:
//   w_i = Ja . (va, wa) + Jb . (vb, wb) + bias_i   (velocity after the step)
//   lo_i < l_i < hi_i  =>  w_i = 0;   l_i = lo_i  =>  w_i >= 0;   l_i = hi_i  =>  w_i <= 0
// A bilateral (holonomic) joint row has lo = -inf, hi = +inf and bias = C / h (position-error feedback,
// clamped by the provider); a rheonomic drive J v = s(t) has bias = -s(t); a motor with torque limit F has
// lo = -F h, hi = F h; a unilateral limit has lo = 0, hi = +inf.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include "chrono_like/base/data.h"
#include "chrono_like/base/hd.h"
#include "chrono_like/base/math.h"
#include "chrono_like/base/step_context.h"

namespace dvi {

struct ConstraintRow {
  int32_t a = -1, b = -1;  // body indices; -1 for "the ground" (no body)
  real Ja[6] = {0, 0, 0, 0, 0, 0};
  real Jb[6] = {0, 0, 0, 0, 0, 0};
  real bias = 0;
  real lo = -std::numeric_limits<real>::infinity();
  real hi = std::numeric_limits<real>::infinity();
};

// Produces the rows of this step from the current state (positions, velocities at the start of the
// step). Called once per step, in BuildRows, before the solve, with the step's context: step.dt is h (the
// position-error feedback C / h), step.end() the time at the end of the step (a rheonomic drive's s(t)).
class RowProvider {
 public:
  virtual ~RowProvider() = default;
  virtual void rows(const BodyArrays& bodies, const StepContext& step, std::vector<ConstraintRow>& out) = 0;
  // Called after the solve with the impulses of the rows this provider produced (in order), e.g. to
  // report joint reaction forces or a drive torque. Default: ignore.
  virtual void impulses(const real* /*lambda*/, size_t /*count*/) {}
  // The bodies rows() reads, when it reads only a few: a device backend then copies just those to the host
  // before calling rows() (instead of every body). false (the default): any body.
  virtual bool bodiesRead(std::vector<int32_t>& /*ids*/) const { return false; }
};

}  // namespace dvi
