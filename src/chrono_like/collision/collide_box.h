// Box-box contact: separating-axis test over the 15 candidate axes, then a contact manifold by clipping the
// incident face against the side planes of the reference face (face contacts), or the closest points of the
// two edges (edge-edge contacts). Host and device code; included by narrowphase_impl.h.
//
// References: S. Gottschalk, M. Lin, D. Manocha, "OBBTree", SIGGRAPH 1996 (separating axes of two boxes);
// I. E. Sutherland, G. W. Hodgman, "Reentrant polygon clipping", CACM 17(1), 1974 (clipping);
// C. Ericson, "Real-Time Collision Detection", 2005, §5.1.9 (closest points of two segments).
#pragma once

#include "chrono_like/base/math.h"
#include "chrono_like/base/shape.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/collision/support.h"

namespace dvi {
namespace np {

// Closest points of segments p1 + s d1 and p2 + t d2, s, t in [0, 1] (Ericson §5.1.9).
DVI_HD void closestSegmentSegment(Vec3 p1, Vec3 d1, Vec3 p2, Vec3 d2, real& s, real& t) {
  Vec3 r = p1 - p2;
  real a = dot(d1, d1), e = dot(d2, d2), f = dot(d2, r);
  const real tiny = real(1e-30);
  if (a <= tiny && e <= tiny) {
    s = t = 0;
    return;
  }
  if (a <= tiny) {
    s = 0;
    t = clampr(f / e, 0, 1);
    return;
  }
  real c = dot(d1, r);
  if (e <= tiny) {
    t = 0;
    s = clampr(-c / a, 0, 1);
    return;
  }
  real b = dot(d1, d2);
  real den = a * e - b * b;
  s = den > real(1e-12) * a * e ? clampr((b * f - c * e) / den, 0, 1) : real(0);
  t = (b * s + f) / e;
  if (t < 0) {
    t = 0;
    s = clampr(-c / a, 0, 1);
  } else if (t > 1) {
    t = 1;
    s = clampr((b - c) / a, 0, 1);
  }
}

// A vertex of the clipped incident face with its feature: which incident corner it is, or which clipping plane
// crossed which incident edge, or which reference-face corner it is (the two side planes that made it), and the
// tag of the polygon edge that ends at it (an incident edge 0-3, or a clipping plane 4 + c).
struct ClipVertex {
  Vec3 p;
  int id;
  int edge;
};

// The feature of the point where clipping plane c (0, 1: +-u, 2, 3: +-v of the reference face) crosses the polygon
// edge tagged `edge`: an incident edge e gives 4 + 4c + e (4-19); a segment along another clipping plane c' gives
// the reference face's corner of the two planes, 20 + 2 (u plane) + (v plane) (20-23). Persistent while the boxes
// rest (Box2D's contact feature ids work the same way), so the warm start finds last step's impulse of each point
// whatever the order the clipping produced them in.
DVI_HD int clipFeature(int c, int edge) {
  if (edge < 4) return 4 + 4 * c + edge;
  const int c2 = edge - 4;
  const int uplane = c < 2 ? c : c2, vplane = c < 2 ? c2 : c;
  return 20 + 2 * (uplane & 1) + (vplane & 1);
}

// Sutherland-Hodgman: clips polygon in[0..n) to {x : dot(x, pn) <= po}, plane c of the reference face's sides.
// Returns the new count (<= cap).
DVI_HD int clipPolygon(const ClipVertex* in, int n, Vec3 pn, real po, int c, ClipVertex* outp, int cap) {
  int m = 0;
  if (n <= 0) return 0;
  ClipVertex prev = in[n - 1];
  real dprev = dot(prev.p, pn) - po;
  for (int i = 0; i < n; ++i) {
    const ClipVertex& cur = in[i];
    real dcur = dot(cur.p, pn) - po;
    if ((dprev <= 0) != (dcur <= 0)) {  // edge crosses the plane
      real t = dprev / (dprev - dcur);
      // leaving (prev inside): the edge up to the crossing is part of cur's edge; entering: it runs along plane c
      if (m < cap)
        outp[m++] = ClipVertex{prev.p + (cur.p - prev.p) * t, clipFeature(c, cur.edge), dprev <= 0 ? cur.edge : 4 + c};
    }
    if (dcur <= 0 && m < cap) outp[m++] = cur;
    prev = cur;
    dprev = dcur;
  }
  return m;
}

// Two boxes' axes and half extents, and what the separating-axis test found along the 15 candidate axes.
struct BoxBoxAxes {
  Vec3 ax[3], bx[3];                                                // the axes of box a and box b (world)
  real ea[3], eb[3];                                                // their half extents
  Vec3 t;                                                           // from a's centre to b's
  real sepA = real(-1e30), sepB = real(-1e30), sepE = real(-1e30);  // largest separation on a's, b's, edge axes
  int axisA = 0, axisB = 0, edgeI = -1, edgeJ = -1;                 // where (edgeI < 0: no usable edge axis)
  Vec3 edgeL{0, 0, 0};
};

// Separation along each candidate axis: |t.L| - (radius of a along L) - (radius of b along L). false as soon as
// one axis separates the boxes by the envelope or more (no contact). In a's frame, with R_ij = a_i . b_j and t_i =
// t . a_i (Gottschalk, Lin & Manocha, "OBBTree", SIGGRAPH 1996; Ericson, Real-Time Collision Detection, 4.4.1), the
// edge axis L = a_i x b_j has a_(i+1) . L = -R_(i+2)j and a_(i+2) . L = R_(i+1)j, b_(j+1) . L = R_i(j+2) and
// b_(j+2) . L = -R_i(j+1): its radii and t . L come from R without forming the dot products again.
DVI_HD bool boxBoxSeparatingAxes(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, real envelope,
                                 BoxBoxAxes& g) {
  const Mat33 Ra = matFromQuat(wa.q), Rb = matFromQuat(wb.q);
  for (int i = 0; i < 3; ++i) g.ax[i] = column(Ra, i), g.bx[i] = column(Rb, i);
  g.ea[0] = a.dims.x, g.ea[1] = a.dims.y, g.ea[2] = a.dims.z;
  g.eb[0] = b.dims.x, g.eb[1] = b.dims.y, g.eb[2] = b.dims.z;
  const Vec3* ax = g.ax;
  const Vec3* bx = g.bx;
  const real* ea = g.ea;
  const real* eb = g.eb;
  const Vec3 t = g.t = wb.p - wa.p;
  real R[3][3], absR[3][3], ta[3];
  for (int i = 0; i < 3; ++i) {
    ta[i] = dot(t, ax[i]);
    for (int j = 0; j < 3; ++j) {
      R[i][j] = dot(ax[i], bx[j]);
      absR[i][j] = std::fabs(R[i][j]) + real(1e-12);
    }
  }
  for (int i = 0; i < 3; ++i) {
    real s = std::fabs(ta[i]) - (ea[i] + eb[0] * absR[i][0] + eb[1] * absR[i][1] + eb[2] * absR[i][2]);
    if (s >= envelope) return false;
    if (s > g.sepA) {
      g.sepA = s;
      g.axisA = i;
    }
  }
  for (int j = 0; j < 3; ++j) {
    real s = std::fabs(dot(t, bx[j])) - (eb[j] + ea[0] * absR[0][j] + ea[1] * absR[1][j] + ea[2] * absR[2][j]);
    if (s >= envelope) return false;
    if (s > g.sepB) {
      g.sepB = s;
      g.axisB = j;
    }
  }
  for (int i = 0; i < 3; ++i) {
    const int i1 = (i + 1) % 3, i2 = (i + 2) % 3;
    for (int j = 0; j < 3; ++j) {
      const int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
      const Vec3 L = cross(ax[i], bx[j]);
      const real l2 = length2(L);
      if (l2 < real(1e-10)) continue;  // (nearly) parallel edges: covered by the face axes
      const real ra = ea[i1] * std::fabs(R[i2][j]) + ea[i2] * std::fabs(R[i1][j]);  // exact: no parallel-axis guard
      const real rb = eb[j1] * std::fabs(R[i][j2]) + eb[j2] * std::fabs(R[i][j1]);
      const real l = std::sqrt(l2);
      const real s = (std::fabs(ta[i2] * R[i1][j] - ta[i1] * R[i2][j]) - ra - rb) / l;
      if (s >= envelope) return false;
      if (s > g.sepE) {
        g.sepE = s;
        g.edgeI = i;
        g.edgeJ = j;
        g.edgeL = L / l;
      }
    }
  }
  return true;
}

// Face contact: the incident face of one box clipped to the reference face of the other (a's face axis when
// refIsA). Normals from a to b.
DVI_HD int boxBoxFaceContacts(const BoxBoxAxes& g, const Pose& wa, const Pose& wb, bool refIsA, real envelope,
                              ContactPoint* out) {
  // Reference face on box r, incident face on box i; nr points from r to i.
  const Vec3* rx = refIsA ? g.ax : g.bx;
  const Vec3* ix = refIsA ? g.bx : g.ax;
  const real* er = refIsA ? g.ea : g.eb;
  const real* ei = refIsA ? g.eb : g.ea;
  const Vec3 cr = refIsA ? wa.p : wb.p;
  const Vec3 ci = refIsA ? wb.p : wa.p;
  const int k = refIsA ? g.axisA : g.axisB;
  Vec3 nr = rx[k] * sgn1(dot(ci - cr, rx[k]));
  Vec3 refc = cr + nr * er[k];
  // Incident face: the face of box i most anti-parallel to nr.
  int j = 0;
  real bestd = -1;
  for (int q = 0; q < 3; ++q) {
    real d = std::fabs(dot(ix[q], nr));
    if (d > bestd) {
      bestd = d;
      j = q;
    }
  }
  Vec3 fn = ix[j] * (dot(ix[j], nr) > 0 ? real(-1) : real(1));
  Vec3 fc = ci + fn * ei[j];
  Vec3 p = ix[(j + 1) % 3] * ei[(j + 1) % 3];
  Vec3 q = ix[(j + 2) % 3] * ei[(j + 2) % 3];
  // Each clipping plane adds at most one vertex: the 4-gon becomes at most an 8-gon, so the manifold never
  // exceeds kMaxContactsPerPair = 8 points and needs no reduction.
  // The incident corners are features 0-3; edge e runs from corner e-1 to corner e.
  ClipVertex polyA[8], polyB[8];
  polyA[0] = ClipVertex{fc + p + q, 0, 0};
  polyA[1] = ClipVertex{fc - p + q, 1, 1};
  polyA[2] = ClipVertex{fc - p - q, 2, 2};
  polyA[3] = ClipVertex{fc + p - q, 3, 3};
  int n = 4;
  const int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
  Vec3 u = rx[k1], v = rx[k2];
  n = clipPolygon(polyA, n, u, dot(u, cr) + er[k1], 0, polyB, 8);
  n = clipPolygon(polyB, n, -u, -dot(u, cr) + er[k1], 1, polyA, 8);
  n = clipPolygon(polyA, n, v, dot(v, cr) + er[k2], 2, polyB, 8);
  n = clipPolygon(polyB, n, -v, -dot(v, cr) + er[k2], 3, polyA, 8);
  int m = 0;
  for (int i = 0; i < n; ++i) {
    real s = dot(polyA[i].p - refc, nr);
    if (!(s < envelope)) continue;
    // in feature order (the warm start's keys are sorted within a pair): insertion by feature
    int at = m;
    while (at > 0 && out[at - 1].feature > polyA[i].id) {
      out[at] = out[at - 1];
      --at;
    }
    Vec3 onRef = polyA[i].p - nr * s;
    if (refIsA)
      setContact(out[at], nr, onRef, polyA[i].p, s, polyA[i].id);
    else
      setContact(out[at], -nr, polyA[i].p, onRef, s, polyA[i].id);
    ++m;
  }
  return m;
}

// Edge-edge: the edge of a along ax[edgeI] and the edge of b along bx[edgeJ] that are extreme along L.
DVI_HD int boxBoxEdgeContact(const BoxBoxAxes& g, const Pose& wa, const Pose& wb, real envelope, ContactPoint* out) {
  const Vec3* ax = g.ax;
  const Vec3* bx = g.bx;
  const real* ea = g.ea;
  const real* eb = g.eb;
  const int edgeI = g.edgeI, edgeJ = g.edgeJ;
  Vec3 L = g.edgeL * sgn1(dot(g.t, g.edgeL));
  Vec3 pA = wa.p, pB = wb.p;
  for (int q = 0; q < 3; ++q) {
    if (q != edgeI) pA += ax[q] * (sgn1(dot(ax[q], L)) * ea[q]);
    if (q != edgeJ) pB -= bx[q] * (sgn1(dot(bx[q], L)) * eb[q]);
  }
  Vec3 dA = ax[edgeI] * (real(2) * ea[edgeI]), dB = bx[edgeJ] * (real(2) * eb[edgeJ]);
  pA -= ax[edgeI] * ea[edgeI];
  pB -= bx[edgeJ] * eb[edgeJ];
  real s, u;
  closestSegmentSegment(pA, dA, pB, dB, s, u);
  Vec3 qa = pA + dA * s, qb = pB + dB * u;
  real dist = dot(qb - qa, L);
  if (!(dist < envelope)) return 0;
  setContact(out[0], L, qa, qb, dist, 0);
  return 1;
}

// Box a (half extents a.dims) at wa, box b at wb. Normals from a to b.
DVI_HD_CALL int collideBoxBox(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, real envelope,
                              ContactPoint* out) {
  BoxBoxAxes g;
  if (!boxBoxSeparatingAxes(a, wa, b, wb, envelope, g)) return 0;
  // Prefer face axes (a over b) unless another axis separates clearly more: keeps the manifold's reference
  // face, and so the feature numbering, stable for resting boxes.
  // The tolerances are relative to the penetration (and a tiny fraction of the size), so the reported depth
  // exceeds the minimum over the 15 axes by at most 0.1 %.
  const real* ea = g.ea;
  const real* eb = g.eb;
  const real minExt = std::fmin(std::fmin(std::fmin(ea[0], ea[1]), std::fmin(ea[2], eb[0])), std::fmin(eb[1], eb[2]));
  bool refIsA = !(g.sepB > g.sepA + real(1e-3) * std::fabs(g.sepA) + real(1e-7) * minExt);
  real sepF = refIsA ? g.sepA : g.sepB;
  bool useEdge = g.edgeI >= 0 && g.sepE > sepF + real(1e-3) * std::fabs(sepF) + real(1e-7) * minExt;
  if (!useEdge) {
    const int m = boxBoxFaceContacts(g, wa, wb, refIsA, envelope, out);
    if (m > 0 || g.edgeI < 0) return m;
    // No face point (a grazing edge configuration): fall back to the edge contact.
  }
  return boxBoxEdgeContact(g, wa, wb, envelope, out);
}

}  // namespace np
}  // namespace dvi
