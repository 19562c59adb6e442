// Small fixed-size vector, quaternion and 3x3 matrix types usable in host and device code.
// Plain aggregates (no constructors with side effects) so arrays of them can live in device memory
// and be copied with memcpy.
#pragma once

#include <cmath>

#include "chrono_like/base/hd.h"

namespace dvi {

struct Vec3 {  // 24 bytes in double, 12 in float
  real x, y, z;
};

struct Quat {  // unit quaternion w + xi + yj + zk; 32 bytes in double
  real w, x, y, z;
};

struct Mat33 {  // row-major
  Vec3 r0, r1, r2;
};

DVI_HD Vec3 vec3(real x, real y, real z) { return Vec3{x, y, z}; }
DVI_HD Vec3 operator+(Vec3 a, Vec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
DVI_HD Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
DVI_HD Vec3 operator-(Vec3 a) { return {-a.x, -a.y, -a.z}; }
DVI_HD Vec3 operator*(Vec3 a, real s) { return {a.x * s, a.y * s, a.z * s}; }
DVI_HD Vec3 operator*(real s, Vec3 a) { return {a.x * s, a.y * s, a.z * s}; }
DVI_HD Vec3 operator/(Vec3 a, real s) { return {a.x / s, a.y / s, a.z / s}; }
DVI_HD Vec3& operator+=(Vec3& a, Vec3 b) {
  a.x += b.x;
  a.y += b.y;
  a.z += b.z;
  return a;
}
DVI_HD Vec3& operator-=(Vec3& a, Vec3 b) {
  a.x -= b.x;
  a.y -= b.y;
  a.z -= b.z;
  return a;
}
DVI_HD Vec3& operator*=(Vec3& a, real s) {
  a.x *= s;
  a.y *= s;
  a.z *= s;
  return a;
}
DVI_HD Vec3 mul(Vec3 a, Vec3 b) { return {a.x * b.x, a.y * b.y, a.z * b.z}; }  // component-wise
DVI_HD real dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
DVI_HD Vec3 cross(Vec3 a, Vec3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
DVI_HD real length2(Vec3 a) { return dot(a, a); }
// p in the closed box [lo, hi] (each axis).
DVI_HD bool insideBox(Vec3 p, Vec3 lo, Vec3 hi) {
  return p.x >= lo.x && p.x <= hi.x && p.y >= lo.y && p.y <= hi.y && p.z >= lo.z && p.z <= hi.z;
}
DVI_HD real length(Vec3 a) { return std::sqrt(dot(a, a)); }
DVI_HD Vec3 vmin(Vec3 a, Vec3 b) { return {std::fmin(a.x, b.x), std::fmin(a.y, b.y), std::fmin(a.z, b.z)}; }
DVI_HD Vec3 vmax(Vec3 a, Vec3 b) { return {std::fmax(a.x, b.x), std::fmax(a.y, b.y), std::fmax(a.z, b.z)}; }
DVI_HD Vec3 vabs(Vec3 a) { return {std::fabs(a.x), std::fabs(a.y), std::fabs(a.z)}; }
DVI_HD real maxComponent(Vec3 a) { return std::fmax(a.x, std::fmax(a.y, a.z)); }
DVI_HD real minComponent(Vec3 a) { return std::fmin(a.x, std::fmin(a.y, a.z)); }
DVI_HD Vec3 normalized(Vec3 a) {
  real l = length(a);
  return l > real(0) ? a / l : Vec3{real(1), real(0), real(0)};
}
DVI_HD bool isFinite(Vec3 a) { return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z); }

// Two unit vectors completing n to a right-handed orthonormal basis (n, u, w).
// Branch-free construction of Duff et al., "Building an Orthonormal Basis, Revisited", JCGT 6(1), 2017.
DVI_HD void tangentBasis(Vec3 n, Vec3& u, Vec3& w) {
  real s = std::copysign(real(1), n.z);
  real a = real(-1) / (s + n.z);
  real b = n.x * n.y * a;
  u = Vec3{real(1) + s * n.x * n.x * a, s * b, -s * n.x};
  w = Vec3{b, s + n.y * n.y * a, -n.y};
}

DVI_HD Quat quatIdentity() { return Quat{real(1), real(0), real(0), real(0)}; }
DVI_HD Quat operator*(Quat a, Quat b) {
  return {a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z, a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
          a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x, a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w};
}
DVI_HD Quat conj(Quat q) { return {q.w, -q.x, -q.y, -q.z}; }
DVI_HD Quat normalized(Quat q) {
  real l = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  return {q.w / l, q.x / l, q.y / l, q.z / l};
}
// v' = q v q*, expanded (t = 2 q_v x v; v' = v + w t + q_v x t).
DVI_HD Vec3 rotate(Quat q, Vec3 v) {
  Vec3 qv{q.x, q.y, q.z};
  Vec3 t = real(2) * cross(qv, v);
  return v + q.w * t + cross(qv, t);
}
DVI_HD Vec3 rotateInv(Quat q, Vec3 v) { return rotate(conj(q), v); }
// Exponential map: rotation by the vector phi (axis * angle), exact for any angle.
DVI_HD Quat quatFromRotationVector(Vec3 phi) {
  real angle = length(phi);
  if (angle < real(1e-12)) return normalized(Quat{real(1), phi.x / 2, phi.y / 2, phi.z / 2});
  real s = std::sin(angle / 2) / angle;
  return Quat{std::cos(angle / 2), phi.x * s, phi.y * s, phi.z * s};
}
DVI_HD Quat quatFromAxisAngle(Vec3 axis, real angle) { return quatFromRotationVector(normalized(axis) * angle); }

DVI_HD Mat33 matFromQuat(Quat q) {
  real xx = q.x * q.x, yy = q.y * q.y, zz = q.z * q.z;
  real xy = q.x * q.y, xz = q.x * q.z, yz = q.y * q.z;
  real wx = q.w * q.x, wy = q.w * q.y, wz = q.w * q.z;
  return {{1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)},
          {2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)},
          {2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)}};
}
DVI_HD Vec3 operator*(const Mat33& m, Vec3 v) { return {dot(m.r0, v), dot(m.r1, v), dot(m.r2, v)}; }
DVI_HD Vec3 mulTransposed(const Mat33& m, Vec3 v) { return m.r0 * v.x + m.r1 * v.y + m.r2 * v.z; }

// Rigid transform: x_world = p + R(q) x_local.
struct Pose {
  Vec3 p;
  Quat q;
};
DVI_HD Vec3 transformPoint(const Pose& t, Vec3 x) { return t.p + rotate(t.q, x); }
// Exact (bitwise-value) equality: whether a value the application or the last step wrote is unchanged.
DVI_HD bool sameVec(Vec3 a, Vec3 b) { return a.x == b.x && a.y == b.y && a.z == b.z; }
DVI_HD bool samePose(const Pose& a, const Pose& b) {
  return sameVec(a.p, b.p) && a.q.w == b.q.w && a.q.x == b.q.x && a.q.y == b.q.y && a.q.z == b.q.z;
}
DVI_HD Vec3 inverseTransformPoint(const Pose& t, Vec3 x) { return rotateInv(t.q, x - t.p); }
DVI_HD Pose compose(const Pose& a, const Pose& b) { return Pose{transformPoint(a, b.p), a.q * b.q}; }

// Axis-aligned bounding box.
struct Aabb {
  Vec3 lo, hi;
};

}  // namespace dvi
