// Per-body integration, written once for host and device (docs/MODEL.md §2, eqs. 8-14 of Critelli et al. 2015):
// semi-implicit Euler on velocities, then positions with the updated velocities and the rotation
// updated by the exponential map of h*omega (exact for any angle; keeps the quaternion unit).
#pragma once

#include "chrono_like/base/data.h"
#include "chrono_like/base/math.h"

namespace dvi {

// One Newton step of the implicit gyroscopic update in the body frame (see integrateBodyForces).
DVI_HD Vec3 implicitGyroscopic(Vec3 w, Vec3 inv_inertia, real h) {
  const Vec3 I{real(1) / inv_inertia.x, real(1) / inv_inertia.y, real(1) / inv_inertia.z};
  const Vec3 Iw{I.x * w.x, I.y * w.y, I.z * w.z};
  const Vec3 f = h * cross(w, Iw);
  // J = diag(I) + h ([w]x diag(I) - [Iw]x), rows
  const real j00 = I.x, j01 = h * (-w.z * I.y + Iw.z), j02 = h * (w.y * I.z - Iw.y);
  const real j10 = h * (w.z * I.x - Iw.z), j11 = I.y, j12 = h * (-w.x * I.z + Iw.x);
  const real j20 = h * (-w.y * I.x + Iw.y), j21 = h * (w.x * I.y - Iw.x), j22 = I.z;
  // J^-1 f by Cramer's rule
  const real c00 = j11 * j22 - j12 * j21, c01 = j12 * j20 - j10 * j22, c02 = j10 * j21 - j11 * j20;
  const real det = j00 * c00 + j01 * c01 + j02 * c02;
  if (!(fabs(det) > real(0))) return w;
  const real inv = real(1) / det;
  const real x = (f.x * c00 + j01 * (j12 * f.z - f.y * j22) + j02 * (f.y * j21 - j11 * f.z)) * inv;
  const real y = (j00 * (f.y * j22 - j12 * f.z) + f.x * (j12 * j20 - j10 * j22) + j02 * (j10 * f.z - f.y * j20)) * inv;
  const real z = (j00 * (j11 * f.z - f.y * j21) + j01 * (f.y * j20 - j10 * f.z) + f.x * (j10 * j21 - j11 * j20)) * inv;
  return w - Vec3{x, y, z};
}

// v_free = v + h (f/m + g);  w_free = w_gyro + h I_w^-1 tau   (dynamic bodies)
// The gyroscopic term is integrated implicitly, in the body frame: w_gyro solves
//   I (w_gyro - w) + h w_gyro x (I w_gyro) = 0
// by one Newton step from w (E. Catto, "Numerical Methods", GDC 2015; Bullet's
// btRigidBody::computeGyroscopicImpulseImplicit_Body): with J = I + h ([w]x I - [I w]x),
//   w_gyro = w - J^-1 (h w x I w).
// The explicit form w + h I^-1 (-w x I w) gains energy at every step and blows up for small, fast
// tumbling bodies (a 1 mm wire spun from 1e3 to 1e11 rad/s in 0.1 s); the implicit one does not.
// The term vanishes for spherical inertia (w x I w = 0 for I = c 1) and is skipped there unless
// skip_spherical is false (SystemConfig::prune = false: the step then costs what it would without pruning).
// Kinematic bodies keep their prescribed velocity; fixed bodies have none.
DVI_HD void integrateBodyForces(Vec3 v, Vec3 w, Quat q, real inv_mass, Vec3 inv_inertia, Vec3 force, Vec3 torque,
                                Vec3 gravity, uint8_t flags, bool gyroscopic, bool skip_spherical, real h, Vec3& v_free,
                                Vec3& w_free) {
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
  if (gyroscopic && !(spherical && skip_spherical)) wl = implicitGyroscopic(wl, inv_inertia, h);
  w_free = rotate(q, wl + h * mul(inv_inertia, tl));
}

// Whether a body needs the gyroscopic term: dynamic, with non-spherical inertia.
DVI_HD bool needsGyroscopic(Vec3 inv_inertia, uint8_t flags) {
  if (flags & (kBodyFixed | kBodyKinematic)) return false;
  return !(inv_inertia.x == inv_inertia.y && inv_inertia.y == inv_inertia.z);
}

DVI_HD void integrateBodyPosition(Vec3& x, Quat& q, Vec3 v, Vec3 w, uint8_t flags, real h) {
  if (flags & kBodyFixed) return;
  x += h * v;
  q = normalized(quatFromRotationVector(h * w) * q);  // w is in the world frame: left-multiply
}

}  // namespace dvi
