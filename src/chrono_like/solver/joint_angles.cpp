// Cone-twist and 6-DoF joint angles and their rate vectors (joint_angles.h states the definitions).
#include "chrono_like/solver/joint_angles.h"

#include <algorithm>
#include <cmath>

namespace dvi {

namespace {

constexpr real kPi = real(3.14159265358979323846);

Vec3 unitAxis(int k) { return k == 0 ? Vec3{1, 0, 0} : (k == 1 ? Vec3{0, 1, 0} : Vec3{0, 0, 1}); }
real clampUnit(real x) { return std::min(real(1), std::max(real(-1), x)); }

// The elliptic swing limit: F and its gradient with respect to u (frame B coordinates), joint_angles.h.
void swingLimit(Vec3 u, real sin_t, real swing1, real swing2, ConeAngles& c, const Vec3 eb[3]) {
  const real theta = c.swing;
  const real G = std::sqrt((u.z / swing2) * (u.z / swing2) + (u.y / swing1) * (u.y / swing1));
  const real h = theta / sin_t;  // theta / sin(theta)
  const real F = h * G;
  const real dh = (sin_t - theta * std::cos(theta)) / (sin_t * sin_t);  // dh/dtheta; dtheta/du.x = -1/sin(theta)
  const Vec3 grad{-G * dh / sin_t, h * u.y / (swing1 * swing1 * G), h * u.z / (swing2 * swing2 * G)};
  const Vec3 gb = cross(u, grad);  // dF/dt = gb . Omega (frame B)
  const Vec3 g = eb[0] * gb.x + eb[1] * gb.y + eb[2] * gb.z;
  const real n = length(g);
  c.swing_limit = F > 0 ? theta / F : kPi;
  if (!(n > real(1e-12))) return;  // keeps the defaults below
  c.swing_c = (real(1) - F) / n;   // dC/dt = -dF/dt / n = (wB - wA) . g / n
  c.swing_g = g / n;
}

}  // namespace

ConeAngles coneAngles(Quat qfa, Quat qfb, real swing1, real swing2) {
  ConeAngles c;
  Vec3 eb[3];
  for (int k = 0; k < 3; ++k) eb[k] = rotate(qfb, unitAxis(k));
  const Vec3 xa = rotate(qfa, Vec3{1, 0, 0});
  const Vec3 u{dot(xa, eb[0]), dot(xa, eb[1]), dot(xa, eb[2])};  // frame A's x axis in frame B
  const real sin_t = std::sqrt(u.y * u.y + u.z * u.z);
  c.swing = std::atan2(sin_t, u.x);
  c.u_y = u.y;
  c.u_z = u.z;
  c.u_y_g = cross(eb[1], xa);  // d(xA . yB)/dt = (wA - wB) . (xA x yB)
  c.u_z_g = cross(eb[2], xa);
  // Swing: far from the limit at theta ~ 0 (no direction), past it at theta ~ pi.
  const real smin = std::min(swing1, swing2);
  c.swing_g = eb[2];
  c.swing_c = u.x > 0 ? smin - c.swing : -(c.swing - smin);
  c.swing_limit = smin;
  if (sin_t > real(1e-9)) swingLimit(u, sin_t, swing1, swing2, c, eb);
  // Twist: qT = conj(qC) qAB, qC the shortest arc from x to u.
  if (real(1) + u.x > real(1e-9)) {
    const Quat qc = normalized(Quat{real(1) + u.x, 0, -u.z, u.y});
    Quat qt = conj(qc) * (conj(qfb) * qfa);
    if (qt.w < 0) qt = Quat{-qt.w, -qt.x, -qt.y, -qt.z};
    c.twist = real(2) * std::atan2(qt.x, qt.w);
    c.twist_g = (xa + eb[0]) * (real(-1) / (real(1) + u.x));
  } else {
    c.twist_g = eb[0] * real(-1);
  }
  return c;
}

EulerAngles eulerAngles(Quat qfa, Quat qfb, const int order[3]) {
  Vec3 ea[3], eb[3];
  for (int k = 0; k < 3; ++k) {
    ea[k] = rotate(qfa, unitAxis(k));
    eb[k] = rotate(qfb, unitAxis(k));
  }
  const int i = order[0], j = order[1], k = order[2];
  // R = R_A^T R_B = R_k(c) R_j(b) R_i(a) (extrinsic i, j, k); s = +1 for a cyclic order (Shoemake, "Euler angle
  // conversion", Graphics Gems IV, 1994: the parity sign).
  const real s = ((j - i + 3) % 3 == 1) ? real(1) : real(-1);
  auto R = [&](int r, int col) { return dot(ea[r], eb[col]); };
  const real b = std::asin(clampUnit(-s * R(k, i)));
  const real a = std::atan2(s * R(k, j), R(k, k));
  const real c = std::atan2(s * R(j, i), R(i, i));
  EulerAngles e;
  e.angle[i] = -a;  // Bullet's angles are those of A relative to B: the negated ones
  e.angle[j] = -b;
  e.angle[k] = -c;
  // wB - wA = c' a_k + b' n_j + a' b_i (n_j: frame A's axis j turned by c about a_k).
  const Vec3 ui = eb[i], uk = ea[k];
  const Vec3 uj = ea[j] * std::cos(c) + cross(ea[k], ea[j]) * std::sin(c);
  real D = dot(ui, cross(uj, uk));  // = cos(b) up to sign: gimbal lock at |b| = pi/2
  if (std::fabs(D) < real(1e-6)) D = std::copysign(real(1e-6), D);
  e.g[i] = cross(uj, uk) * (real(-1) / D);
  e.g[j] = cross(uk, ui) * (real(-1) / D);
  e.g[k] = cross(ui, uj) * (real(-1) / D);
  return e;
}

}  // namespace dvi
