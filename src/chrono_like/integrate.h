// Per-body integration, written once for host and device (DESIGN §3, eqs. 8-14 of Critelli et al. 2015):
// semi-implicit Euler on velocities, then positions with the updated velocities and the rotation
// updated by the exponential map of h*omega (exact for any angle; keeps the quaternion unit).
#pragma once

#include "data.h"
#include "math.h"

namespace dvi {

// v_free = v + h (f/m + g);  w_free = w + h I_w^-1 (tau - w x I_w w)   (dynamic bodies)
// The gyroscopic term w x I w vanishes for spherical inertia and is skipped there. Kinematic bodies
// keep their prescribed velocity; fixed bodies have none.
DVI_HD void integrateBodyForces(Vec3 v, Vec3 w, Quat q, real inv_mass, Vec3 inv_inertia, Vec3 force, Vec3 torque,
                                Vec3 gravity, uint8_t flags, bool gyroscopic, real h, Vec3& v_free, Vec3& w_free) {
  if (flags & kBodyFixed) {
    v_free = Vec3{0, 0, 0};
    w_free = Vec3{0, 0, 0};
    return;
  }
  if (flags & kBodyKinematic) {
    v_free = v;
    w_free = w;
    return;
  }
  v_free = v + h * (inv_mass * force + gravity);
  Vec3 wl = rotateInv(q, w);  // body frame
  Vec3 tl = rotateInv(q, torque);
  const bool spherical = inv_inertia.x == inv_inertia.y && inv_inertia.y == inv_inertia.z;
  if (gyroscopic && !spherical) {
    Vec3 Iw{wl.x / inv_inertia.x, wl.y / inv_inertia.y, wl.z / inv_inertia.z};
    tl -= cross(wl, Iw);
  }
  w_free = rotate(q, wl + h * mul(inv_inertia, tl));
}

DVI_HD void integrateBodyPosition(Vec3& x, Quat& q, Vec3 v, Vec3 w, uint8_t flags, real h) {
  if (flags & kBodyFixed) return;
  x += h * v;
  q = normalized(quatFromRotationVector(h * w) * q);  // w is in the world frame: left-multiply
}

}  // namespace dvi
