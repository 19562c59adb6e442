// Joint angles of Bullet's cone-twist and generic 6-DoF constraints, each with its rate vector g: the world vector
// with d(angle)/dt = (wB - wA).g, the Jacobian row of the angle (joints.cpp turns them into limit, lock and motor
// rows). The definitions follow Bullet's own (checked against Bullet by tests/test_bullet_world.cpp):
//
// Cone-twist (btConeTwistConstraint::calcAngleInfo2, computeConeLimitInfo, computeTwistLimitInfo): the rotation of
// joint frame A relative to joint frame B, qAB = conj(qFB) qFA, splits into a swing qC (the shortest arc taking
// x to u, u = frame A's x axis in frame B) and a twist about x, qAB = qC qT. The swing angle theta = acos(u.x)
// lies inside an ellipse in the swing's rotation vector phi = theta n (n = x cross u / |x cross u|):
//   F = sqrt((phi.y / swing2)^2 + (phi.z / swing1)^2) = theta / sin(theta) sqrt((u.z / swing2)^2 + (u.y / swing1)^2)
// and F <= 1 is Bullet's elliptic limit (swingLimit of computeConeLimitInfo: F = theta / swingLimit). The limit row
// is C = (1 - F) / |g| >= 0 with g from dF/dt = (u x grad_u F) . Omega, Omega = R_B^T (wA - wB) the angular velocity
// of A relative to B in frame B (du/dt = Omega x u); its direction is the ellipse normal (Bullet's
// adjustSwingAxisToUseEllipseNormal). The twist psi (signed; Bullet limits |psi|) has the rate
//   d psi/dt = (wA - wB) . (xA + xB) / (1 + xA . xB)
// (derivative of the swing-twist decomposition: psi' = Omega . (x + u) / (1 + x . u), from qAB' = Omega qAB / 2 and
// the exponential-map derivative of qC; xA, xB the frames' x axes in the world).
//
// 6-DoF (btGeneric6DofConstraint: XYZ; btGeneric6DofSpring2Constraint: its RotateOrder): Bullet's angles phi of
// order (i, j, k) are those of A relative to B: R_A^T R_B = R_k(-phi_k) R_j(-phi_j) R_i(-phi_i) (extrinsic
// rotations about i, then j, then k of frame A). The rates follow from
//   wB - wA = -(phi_k' a_k + phi_j' n_j + phi_i' b_i),  a_k = frame A's axis k, b_i = frame B's axis i,
//   n_j = frame A's axis j turned about a_k by -phi_k (Bullet's "line of nodes" m_calculatedAxis[j])
// by the dual basis: g_m = -(u_p x u_q) / (u_m . (u_p x u_q)) for (m, p, q) cyclic over (b_i, n_j, a_k);
// the middle angle's gimbal lock (|phi_j| = pi/2) makes the dual basis singular, as in Bullet.
#pragma once

#include "chrono_like/base/math.h"

namespace dvi {

struct ConeAngles {
  real swing = 0;         // theta, radians in [0, pi]
  real swing_limit = 0;   // Bullet's swingLimit in the swing's direction (theta / F)
  real swing_c = 0;       // (1 - F) / |g|: >= 0 inside the cone, about the angle to the limit
  Vec3 swing_g{0, 0, 1};  // d swing_c / dt = (wB - wA) . swing_g at the limit (unit vector)
  real twist = 0;         // psi, radians in (-pi, pi]
  Vec3 twist_g{1, 0, 0};  // d psi / dt = (wB - wA) . twist_g
  real u_y = 0, u_z = 0;  // the components of frame A's x axis along frame B's y and z (swing about z and y locked)
  Vec3 u_y_g{0, 0, 1}, u_z_g{0, 1, 0};  // their rate vectors
};
// qfa, qfb: the joint frames' world orientations; swing1, swing2 > 0 the ellipse's half-axes (Bullet's spans).
ConeAngles coneAngles(Quat qfa, Quat qfb, real swing1, real swing2);

struct EulerAngles {
  real angle[3] = {0, 0, 0};  // Bullet's getAngle(0..2)
  Vec3 g[3];                  // d angle[m] / dt = (wB - wA) . g[m]
};
// order: the axes (0 x, 1 y, 2 z) in Bullet's rotate order, {0, 1, 2} for RO_XYZ.
EulerAngles eulerAngles(Quat qfa, Quat qfb, const int order[3]);

}  // namespace dvi
