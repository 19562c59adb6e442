// Euclidean projection onto one friction cone (docs/MODEL.md §3), a per-element DVI_HD operation shared by the
// CPU solvers and, later, the CUDA kernels.
//
//   K_mu = {(gn, gu, gw) : sqrt(gu^2 + gw^2) <= mu gn}          (a second-order cone, half-angle atan(mu))
//   K_mu° = {(gn, gt) : mu |gt| <= -gn}                          (its polar cone)
//
// Reference: the closed form is the projection onto a second-order cone written in the (gn, |gt|) plane,
// as used by Anitescu & Tasora, "An iterative approach for cone complementarity problems for nonsmooth
// dynamics", Comput. Optim. Appl. 47 (2010), and Tasora & Anitescu, CMAME 200 (2011). With gt = |(gu, gw)|:
//   gt <= mu gn          inside K: unchanged
//   mu gt <= -gn         inside the polar cone: projects to the apex 0
//   otherwise            onto the boundary ray (1, mu) of the (gn, gt) half plane:
//                        gn' = (mu gt + gn) / (mu^2 + 1),  gt' = mu gn'  along the same tangent direction.
// mu = 0 is the frictionless case: gt' = 0, gn' = max(gn, 0). It is exact: x = P_K(x) + P_K°(x) with the two
// parts orthogonal (Moreau), which the tests check.
#pragma once

#include <cmath>

#include "chrono_like/base/hd.h"

namespace dvi {

DVI_HD void projectCone(real mu, real& gn, real& gu, real& gw) {
  if (!(mu > real(0))) {  // frictionless (mu <= 0 treated as 0)
    gu = real(0);
    gw = real(0);
    gn = gn > real(0) ? gn : real(0);
    return;
  }
  // The two tests on squares (no square root on the common inside / separated paths):
  // gt <= mu gn  <=>  gn >= 0 and gt^2 <= mu^2 gn^2;   mu gt <= -gn  <=>  gn <= 0 and mu^2 gt^2 <= gn^2.
  const real t2 = gu * gu + gw * gw;
  const real mu2 = mu * mu, gn2 = gn * gn;
  if (gn >= real(0) && t2 <= mu2 * gn2) return;  // inside (covers gt = 0 with gn >= 0)
  if (gn <= real(0) && mu2 * t2 <= gn2) {        // polar cone (covers gt = 0 with gn < 0)
    gn = real(0);
    gu = real(0);
    gw = real(0);
    return;
  }
  // Here gt > 0 and mu gt + gn > 0.
  const real gt = std::sqrt(t2);
  const real n = (mu * gt + gn) / (mu2 + real(1));
  const real s = mu * n / gt;
  gn = n;
  gu *= s;
  gw *= s;
}

// Projects the block g[0..2] = (gn, gu, gw) in place.
DVI_HD void projectConeBlock(real mu, real* g) { projectCone(mu, g[0], g[1], g[2]); }

// Squared contribution of one contact to the projected-gradient residual (docs/MODEL.md §4):
// |(g - P(g - a grad)) / a|^2 for the block g with gradient grad = (N g + r)_k.
// inv_a = 1 / a is passed too, to keep divisions out of the solvers' loops.
DVI_HD real projectedGradientResidual2(real mu, const real* g, const real* grad, real a, real inv_a) {
  real t0 = g[0] - a * grad[0], t1 = g[1] - a * grad[1], t2 = g[2] - a * grad[2];
  projectCone(mu, t0, t1, t2);
  const real e0 = (g[0] - t0) * inv_a, e1 = (g[1] - t1) * inv_a, e2 = (g[2] - t2) * inv_a;
  return e0 * e0 + e1 * e1 + e2 * e2;
}

// ---- rolling and spinning friction (Tasora & Anitescu, "A complementarity-based rolling friction model for rigid
// contacts", Meccanica 48 (2013) 1643-1659; Chrono's ChContactNSCrolling) ----
// A contact with rolling or spinning friction has, besides (gn, gu, gw), the angular impulses of a rolling block
// (gs, gr1, gr2): spinning about the normal and rolling about the two tangents, bounded by the same normal impulse:
//   K = {(gn, gt, gs, gr) : |gt| <= mu gn,  |gs| <= mu_s gn,  |gr| <= mu_r gn}     (mu_s, mu_r: lengths, metres)
// the intersection of three second-order cones sharing gn. Chrono projects onto the three cones one after the other
// (not the Euclidean projection); here it is the exact one, so APGD's and BB's projected steps keep their theory:
// for a fixed gn = t >= 0 the nearest point keeps each part's direction and clips its length to its radius c_i t,
// so t minimises phi(t) = (t - a)^2 + sum_i (m_i - c_i t)_+^2 (a the given gn, m_i = |part i|, c_i its coefficient).
// phi' / 2 = h(t) = t - a - sum_i c_i (m_i - c_i t)_+ is increasing and piecewise linear, with breakpoints m_i / c_i;
// with every part active its root is t_A = (a + sum c_i m_i) / (1 + sum c_i^2) <= t*, so dropping the parts whose
// breakpoint lies below t_A and solving again reaches the root t* in at most three rounds. t* <= 0: the apex 0.
// A part with c_i = 0 (no such friction) projects to 0, as the frictionless cone does.
DVI_HD void projectRollingCone(real mu, real mu_s, real mu_r, real* g, real* s) {
  const real c[3] = {mu > real(0) ? mu : real(0), mu_s > real(0) ? mu_s : real(0), mu_r > real(0) ? mu_r : real(0)};
  const real m[3] = {std::sqrt(g[1] * g[1] + g[2] * g[2]), std::fabs(s[0]), std::sqrt(s[1] * s[1] + s[2] * s[2])};
  bool active[3];
  for (int i = 0; i < 3; ++i) active[i] = c[i] > real(0) && m[i] > real(0);
  real t = 0;
  for (int round = 0; round < 4; ++round) {
    real num = g[0], den = 1;
    for (int i = 0; i < 3; ++i)
      if (active[i]) num += c[i] * m[i], den += c[i] * c[i];
    t = num / den;
    if (!(t > real(0))) break;  // h(0) >= 0: the apex (only possible in the first round, all parts active)
    bool dropped = false;
    for (int i = 0; i < 3; ++i)
      if (active[i] && m[i] <= c[i] * t) active[i] = false, dropped = true;
    if (!dropped) break;
  }
  if (!(t > real(0))) {
    g[0] = g[1] = g[2] = s[0] = s[1] = s[2] = real(0);
    return;
  }
  g[0] = t;
  auto clip = [](real len, real radius) { return len > radius ? radius / len : real(1); };
  const real f0 = c[0] > 0 ? clip(m[0], c[0] * t) : real(0);
  const real f1 = c[1] > 0 ? clip(m[1], c[1] * t) : real(0);
  const real f2 = c[2] > 0 ? clip(m[2], c[2] * t) : real(0);
  g[1] *= f0;
  g[2] *= f0;
  s[0] *= f1;
  s[1] *= f2;
  s[2] *= f2;
}

}  // namespace dvi
