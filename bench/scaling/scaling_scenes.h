// Benchmark scenes shared by `dvisim bench ...` (bench/*/bench_*.cpp): a pile of N equal spheres and
// a multidisperse mix, described once (SceneSpec) and built for our System (CPU or GPU, through
// makeSphere/makeBox/...) and as Bullet bodies for the Bullet peer, so every engine steps the same bodies
// with the same masses, inertias and friction.
//
// Both scenes stand in a box of four fixed walls on a ground plane (y up), bodies on a lattice of columns
// that starts in contact along each column (0.1% gaps, well inside the collision envelope) and without
// any initial overlap (an overlap would measure how fast an engine pushes it out, not what a step allows).
// Jitter is deterministic (fixed seed), so every run builds the same scene.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "chrono_like/system.h"

class btCollisionShape;
class btRigidBody;

namespace dvi::bench {

enum class BodyKind { Sphere, Box, Cylinder, Ellipsoid, Hull };
const char* bodyKindName(BodyKind k);

struct BodySpec {
  BodyKind kind = BodyKind::Sphere;
  Vec3 dims{0, 0, 0};  // sphere: r; box: half extents; cylinder (axis y): r, half height; ellipsoid: semi axes;
                       // hull: the scale of the prototype along each axis
  int hull = -1;       // kind Hull: index into SceneSpec::hulls (points in the body frame, before scaling)
  Vec3 pos{0, 0, 0};
  Quat rot{1, 0, 0, 0};
  real mass = 0;
  Vec3 inertia{0, 0, 0};  // principal moments, body frame
};

struct SceneSpec {
  std::string name;     // "pile" or "mix"
  real friction = 0;    // every body's friction; the pair's coefficient is the product = mu
  real ref_length = 0;  // penetration is reported relative to this (pile: r; mix: smallest size)
  real width = 0, wall_height = 0, wall_thickness = 0;  // the container: [0, width]^2 in x, z
  std::vector<BodySpec> bodies;                         // the dynamic bodies
  std::vector<std::vector<Vec3>> hulls;
};

// Pile of n spheres, r = 1 cm, density 2500, mu = 0.5: columns 2.1 r apart (+-0.04 r jitter) across a
// square footprint, about twice as high as wide (bench/bench_pile.cpp's pile, as dvi bodies).
SceneSpec makePileSpec(long n, real mu = real(0.5));
// Multidisperse mix of n bodies: spheres, boxes, cylinders, ellipsoids and convex hulls in equal shares,
// sizes log-uniform over [0.5, 2] cm (a factor 4), rotated about the vertical by random angles, stacked in
// columns 4.2 cm apart, each body resting 0.1% of its size above the one below; density 2500, mu = 0.5.
SceneSpec makeMixSpec(long n, real mu = real(0.5));
// "pile" or "mix"; throws InputError for another name.
SceneSpec makeSceneSpec(const std::string& name, long n);

// The scene for an engine without cylinders and ellipsoids (Bullet 3's GPU pipeline): each cylinder becomes the
// convex hull of two kCylinderSides-gons on its caps, each ellipsoid the hull of a 42-vertex icosphere scaled to
// its semi-axes (two prototypes appended to hulls, scaled per body through dims). The points lie on the true
// surfaces, so the hulls are inside the shapes (a 24-gon has 99.1% of the radius across its sides, the
// icosphere's faces 93% of it). Masses, inertias, poses and every other body are unchanged. Measure such an
// engine's penetration on this scene, the shapes it simulated.
constexpr int kCylinderSides = 24;
SceneSpec withConvexHulls(const SceneSpec& spec);

// The container: the ground plane y = 0 and four fixed box walls whose inner faces are x = 0, x = width,
// z = 0 and z = width.
struct WallSpec {
  Vec3 centre, half;  // half extents
};
std::vector<WallSpec> containerWalls(const SceneSpec& spec);

// The ground, the walls and every body as the System takes them (ground first, then 4 walls, then the bodies).
constexpr int kStaticBodies = 5;  // the ground and the 4 walls, ahead of spec.bodies in every engine
std::vector<BodyDesc> bodyDescs(const SceneSpec& spec);
// Adds bodyDescs(spec) to `sys`.
void addToSystem(const SceneSpec& spec, System& sys);

// The deepest penetration (scene units, >= 0) of the scene with spec.bodies[i] at pos[i], rot[i]: the
// largest -distance over the contacts our native narrow phase finds, i.e. the measure of our engines'
// StepStats::max_penetration, applied to poses another engine computed (the Bullet 3 peer reads them back).
// Throws InputError when pos or rot do not have one entry per body or hold a non-finite number.
real deepestPenetration(const SceneSpec& spec, const std::vector<Vec3>& pos, const std::vector<Quat>& rot);

// The same scene as Bullet bodies (static ground plane and walls, then the dynamic bodies). Bullet's
// friction is the product of the two bodies' values, as ours. The shapes and bodies are owned here.
struct BulletScene {
  BulletScene();
  ~BulletScene();
  BulletScene(BulletScene&&) noexcept;
  BulletScene& operator=(BulletScene&&) noexcept;
  std::vector<btRigidBody*> bodies;
  struct Owned;
  std::unique_ptr<Owned> owned;
};
BulletScene makeBulletScene(const SceneSpec& spec);

// Bytes one matrix-free CCP iteration must move at least (docs/MODEL.md §8, docs/GPU_PERFORMANCE.md): each contact's
// Jacobian, impulse and right-hand side (about 200 B) and each body's velocity update (about 50 B).
inline double solverIterationBytes(double contacts, double bodies) { return contacts * 200.0 + bodies * 50.0; }

}  // namespace dvi::bench
