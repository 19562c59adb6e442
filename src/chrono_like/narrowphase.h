// Narrow phase: contact points between two convex shapes, written once for host and device.
//
// Pairs with a closed form (sphere, plane, box, capsule, cylinder cases) use it; every other pair of
// convex support functions uses Minkowski Portal Refinement (Snethen, "XenoCollide: Complex Collision
// Made Simple", Game Programming Gems 7, 2008). Points are reported while the shapes are closer than
// the collision envelope, so contacts exist before they touch and the solver sees them one step early.
#pragma once

#include "contact.h"
#include "math.h"
#include "shape.h"

namespace dvi {

// World pose of a shape attached to a body at pose `body`.
DVI_HD Pose shapeWorldPose(const Pose& body, const Shape& s) { return compose(body, s.local); }

// Support point of shape s (in its own frame) in local direction d, margin excluded.
DVI_HD Vec3 supportLocal(const Shape& s, Vec3 d, const Vec3* hull_points);

// World AABB of the shape at world pose `world`, grown by `envelope` on every side. Planes return an
// unbounded box (callers treat them as large bodies).
DVI_HD Aabb shapeAabb(const Shape& s, const Pose& world, const Vec3* hull_points, real envelope);

// Speculative contacts (E. Catto, "Continuous Collision", GDC 2013): a bound on how far any point of shape s
// moves in one step of length h, from its body's velocity v and angular velocity w. A pair is collided with
// an envelope of at least the sum of the two sweeps, so a contact exists before a fast body reaches a thin
// obstacle; the contact's bias dist/h (jacobian.h contactBias) lets it push only if the bodies would close
// the gap within the step, so a speculative contact costs nothing physically (no tunnelling, no early stop).
DVI_HD real shapeSweep(const Shape& s, const Vec3* hull_points, Vec3 v, Vec3 w, real h) {
  if (s.type == ShapeType::Plane) return h * length(v);
  return h * (length(v) + length(w) * (length(s.local.p) + boundingRadius(s, hull_points)));
}

// AABB growth of a shape: its relative collision envelope, or its sweep when that is larger.
DVI_HD real shapeMargin(const Shape& s, real envelope_rel, real sweep) { return fmax(envelope_rel * s.size, sweep); }

// Envelope of a pair: the relative envelope of the smaller shape, or the sum of the sweeps when the pair can
// cross a large part of its thickness in one step (sweeps above half the sum of the two sizes). Slower pairs
// keep the plain envelope: the cone complementarity's relaxation makes an active, sliding contact separate at
// mu |u_t| (Anitescu, "Optimization-based simulation of nonsmooth rigid multibody dynamics", Math. Program.
// 105, 2006; Tasora & Anitescu, CMAME 200, 2011), and a wide speculative envelope would keep such a contact
// active, and pushing, well beyond touching (it lifted a charged particle off the CES drum). Never more than
// the two AABB margins together, so every pair within it is found by the broad phase.
DVI_HD real pairEnvelope(const Shape& a, const Shape& b, real envelope_rel, real sweep_a, real sweep_b) {
  const real envelope = envelope_rel * fmin(a.size, b.size), sweep = sweep_a + sweep_b;
  return sweep > real(0.5) * (a.size + b.size) ? fmax(envelope, sweep) : envelope;
}

namespace np {
struct MprDeferred;
}

// Collides shape a at world pose wa with shape b at wb. Writes up to kMaxContactsPerPair points with
// signed distance < envelope into out[], normals pointing from a to b, and returns how many. With `defer`, a
// deep MPR pair is left unfinished: its state goes to *defer, the answer is np::kMprDeferred (-1), and
// finishDeferredMpr completes it (the GPU narrow phase runs those apart, a lane per restart: mpr.h).
// `manifold`: MPR pairs of two flat features get up to 4 more points (mpr.h: mprManifold;
// SystemConfig::mpr_manifold).
DVI_HD int collideShapes(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb,
                         const Vec3* hull_points, real envelope, ContactPoint* out,
                         np::MprDeferred* defer = nullptr, bool manifold = true);

}  // namespace dvi

#include "narrowphase_impl.h"
