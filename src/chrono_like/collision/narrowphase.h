// Narrow phase: contact points between two convex shapes, written once for host and device.
//
// Pairs with a closed form (sphere, plane, box, capsule, cylinder cases) use it; every other pair of
// convex support functions uses Minkowski Portal Refinement (Snethen, "XenoCollide: Complex Collision
// Made Simple", Game Programming Gems 7, 2008). Points are reported while the shapes are closer than
// the collision envelope, so contacts exist before they touch; the envelope is widened to the step's sweep
// and the speculative points kept only for pairs that close within the step (keepSpeculative).
#pragma once

#include "chrono_like/base/math.h"
#include "chrono_like/base/shape.h"
#include "chrono_like/collision/contact.h"
#include "chrono_like/collision/gjk.h"

namespace dvi {

// World pose of a shape attached to a body at pose `body`.
DVI_HD Pose shapeWorldPose(const Pose& body, const Shape& s) { return compose(body, s.local); }

// Support point of shape s (in its own frame) in local direction d: the whole shape (a sphere's or capsule's radius
// and a convex hull's margin included), the collision envelope excluded.
DVI_HD Vec3 supportLocal(const Shape& s, Vec3 d, const Vec3* hull_points);

// World AABB of the shape at world pose `world`, grown by `envelope` on every side. Planes return an
// unbounded box (callers treat them as large bodies).
DVI_HD Aabb shapeAabb(const Shape& s, const Pose& world, const Vec3* hull_points, real envelope);

// Speculative contacts (E. Catto, "Continuous Collision", GDC 2013): a bound on how far any point of shape s
// moves in one step of length h, from its body's velocity v and angular velocity w (the velocities after this
// step's forces, so a body released from rest is swept by its fall too). A pair is collided with an envelope
// of at least the sum of the two sweeps (pairEnvelope), so every approach that could close the gap within the
// step is seen before it penetrates, however thin the obstacle.
DVI_HD real shapeSweep(const Shape& s, const Vec3* hull_points, Vec3 v, Vec3 w, real h) {
  if (s.type == ShapeType::Plane) return h * length(v);
  return h * (length(v) + length(w) * (length(s.local.p) + boundingRadius(s, hull_points)));
}

// AABB growth of a shape: its relative collision envelope, or its sweep when that is larger.
DVI_HD real shapeMargin(const Shape& s, real envelope_rel, real sweep) { return fmax(envelope_rel * s.size, sweep); }

// Plain envelope of a pair: the relative envelope of the smaller shape. Points closer than this are contacts
// whatever the bodies' motion.
DVI_HD real plainEnvelope(const Shape& a, const Shape& b, real envelope_rel) {
  return envelope_rel * fmin(a.size, b.size);
}

// The two bodies of a pair in this step: centres of mass and velocities after the step's forces.
struct PairMotion {
  Vec3 xa, va, wa;
  Vec3 xb, vb, wb;
};

// Envelope a pair is collided with. Two bounds on how far the pair's gap can close within the step, the smaller
// one taken, plus the plain envelope:
//  - the sum of the two sweeps, sweep_a + sweep_b (shapeSweep: each shape's own motion);
//  - the RELATIVE motion: a point of B moves relative to a point of A at most |v_b - v_a| + |w_a| L_a + |w_b| L_b,
//    L the shape's farthest point from its body's centre of mass, and |w| L h = sweep - |v| h by shapeSweep.
//    Bodies that move together (a falling block, particles riding a drum) have a small relative bound where
//    their own sweeps are large.
// A point at dist >= plain + h x (relative bound) has dist + h u_n >= plain, so keepSpeculative would drop it:
// this envelope loses no point that the sum of the sweeps would keep, and spares the narrow phase the pairs
// that are only near because everything moves. Never more than the two AABB margins together (shapeMargin),
// so every pair within it is found by the broad phase. h = 0 (speculative contacts off): the plain envelope.
DVI_HD real pairEnvelope(const Shape& a, const Shape& b, real envelope_rel, real sweep_a, real sweep_b, real h,
                         const PairMotion& m) {
  const real plain = plainEnvelope(a, b, envelope_rel);
  const real spin_a = fmax(real(0), sweep_a - h * length(m.va)), spin_b = fmax(real(0), sweep_b - h * length(m.vb));
  const real relative = plain + h * length(m.vb - m.va) + spin_a + spin_b;
  return fmin(fmax(plain, sweep_a + sweep_b), relative);
}

// Relative normal velocity of the two material points of contact c (positive: separating), u_n = n . (v_B(pb) -
// v_A(pa)) with v(p) = v + w x (p - x).
DVI_HD real contactApproachVelocity(const ContactPoint& c, const PairMotion& m) {
  const Vec3 ua = m.va + cross(m.wa, c.pa - m.xa), ub = m.vb + cross(m.wb, c.pb - m.xb);
  return dot(c.normal, ub - ua);
}

// The speculative-contact rule (Catto, GDC 2013): a point closer than the plain envelope is a contact; a point
// farther (found only because the sweeps widened the pair's envelope) is kept only when the pair's relative normal
// velocity brings it within the plain envelope during the step, dist + h u_n < plain. A kept speculative contact
// with gap dist > 0 gets the bias dist / h (jacobian.h contactBias): it pushes only if the bodies would otherwise
// penetrate, so it stops a fast body at the surface in the step it arrives instead of one step late and deep.
// The rule leaves out the speculative points of pairs that are not closing: an active contact of the cone
// complementarity separates a sliding pair at mu |u_t| (Anitescu, "Optimization-based simulation of nonsmooth
// rigid multibody dynamics", Math. Program. 105, 2006; Tasora & Anitescu, CMAME 200, 2011), so a contact kept
// active far beyond touching holds a pressed, sliding body off its support (a charged particle off the CES
// drum). Such a point is not lost: if the pair closes in a later step, it is kept then, before it touches.
DVI_HD bool keepSpeculative(const ContactPoint& c, real plain, real h, const PairMotion& m) {
  return c.dist < plain || c.dist + h * contactApproachVelocity(c, m) < plain;
}

// keepSpeculative over the n points of one pair, kept in order (their feature indices, and so their warm-start
// keys, unchanged); returns how many stay. A point that moves to a lower index loses its pad_ mark: only the point
// MPR wrote first (index 0, never moved) may carry np::kMprFirst (the GPU's write pass relies on it).
DVI_HD int keepSpeculativePoints(ContactPoint* pts, int n, real plain, real h, const PairMotion& m) {
  int kept = 0;
  for (int j = 0; j < n; ++j) {
    if (!keepSpeculative(pts[j], plain, h, m)) continue;
    if (kept != j) {
      pts[kept] = pts[j];
      pts[kept].pad_ = 0;
    }
    ++kept;
  }
  return kept;
}

namespace np {
struct MprDeferred;
}

// Collides shape a at world pose wa with shape b at wb. Writes up to kMaxContactsPerPair points with
// signed distance < envelope into out[], normals pointing from a to b, and returns how many. With `defer`, a
// deep MPR pair is left unfinished: its state goes to *defer, the answer is np::kMprDeferred (-1), and
// finishDeferredMpr completes it (the GPU narrow phase runs those apart, a lane per restart: mpr.h).
// `manifold`: MPR pairs of two flat features get up to 4 more points (mpr.h: mprManifold;
// CollisionSettings::mpr_manifold). `gjk`: which MPR pairs try GJK first (gjk.h: GjkUse; Auto counts as All).
// `work` (host only): the support mappings the pair cost are added to it (gjk.h: NarrowWork). `history`: last
// step's normal of the pair (contact.h: PairHistory; CollisionSettings::mpr_coherence), which lets a deep MPR pair
// that stays on its face skip the candidate restarts (mpr.h: mprBeginOverlap); null: none.
DVI_HD int collideShapes(const Shape& a, const Pose& wa, const Shape& b, const Pose& wb, const Vec3* hull_points,
                         real envelope, ContactPoint* out, np::MprDeferred* defer = nullptr, bool manifold = true,
                         GjkUse gjk = GjkUse::All, NarrowWork* work = nullptr, const PairHistory* history = nullptr);

// A pair whose current boxes (shapeAabb grown by shapeMargin: ComputeAabbs) are apart makes no contact: each box
// holds its shape grown by its margin, and a pair's envelope is never more than the two margins together
// (pairEnvelope), so shapes whose grown boxes are apart are farther apart than their envelope. The broad phase keeps
// pairs between steps while the boxes stay inside boxes grown by pair_margin (broadphase.h), so many of the pairs it
// hands on are apart by this test; both backends skip them before any narrow-phase work. Planes have unbounded
// boxes and are never skipped.
DVI_HD bool boxesApart(const Aabb& a, const Aabb& b) {
  return a.hi.x < b.lo.x || b.hi.x < a.lo.x || a.hi.y < b.lo.y || b.hi.y < a.lo.y || a.hi.z < b.lo.z || b.hi.z < a.lo.z;
}
// The skip both backends make: sphere pairs are not tested (their closed form costs less than reading two boxes:
// the GPU's 1M-sphere pile lost 0.7 ms of NarrowPhase to the boxes' reads), every other pair is.
DVI_HD bool skipByBoxes(ShapeType ta, ShapeType tb, const Aabb& a, const Aabb& b) {
  return !(ta == ShapeType::Sphere && tb == ShapeType::Sphere) && boxesApart(a, b);
}

}  // namespace dvi

#include "chrono_like/collision/narrowphase_impl.h"
