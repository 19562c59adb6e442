// Small RowProviders for the constraint-row tests (CPU and GPU).
#pragma once

#include <vector>

#include "chrono_like/solver/constraint_row.h"
#include "chrono_like/system.h"

namespace rowstest {

using namespace dvi;

inline BodyDesc freeBox(Vec3 pos, real m) {
  BodyDesc d;
  d.pos = pos;
  d.mass = m;
  const real s = real(0.1);
  d.inertia = Vec3{m * s * s / 6, m * s * s / 6, m * s * s / 6};
  d.shapes.push_back(makeBox(Vec3{s / 2, s / 2, s / 2}));
  return d;
}

// Holds the centre of mass of body b at p with three bilateral rows (ground on side a), position error
// fed back as C / h (Baumgarte with full correction).
struct PinToGround : RowProvider {
  int b;
  Vec3 p;
  real last[3] = {0, 0, 0};
  PinToGround(int body, Vec3 at) : b(body), p(at) {}
  void rows(const BodyArrays& bodies, const StepContext& step, std::vector<ConstraintRow>& out) override {
    const real dt = step.dt;
    const Vec3 c = bodies.pos[b] - p;
    const real cv[3] = {c.x, c.y, c.z};
    for (int j = 0; j < 3; ++j) {
      ConstraintRow r;
      r.a = -1;
      r.b = b;
      r.Jb[j] = 1;
      r.bias = cv[j] / dt;
      out.push_back(r);
    }
  }
  void impulses(const real* l, size_t n) override {
    for (size_t j = 0; j < n && j < 3; ++j) last[j] = l[j];
  }
};

// A pendulum link: the point of body b at local offset (0, L, 0) (world frame, no rotation assumed
// small) held at the world point p: rows C = x_b + R r - p, J = [I, -[R r]x] (Tasora & Anitescu 2011).
struct BallJointToGround : RowProvider {
  int b;
  Vec3 local, p;
  BallJointToGround(int body, Vec3 r_local, Vec3 at) : b(body), local(r_local), p(at) {}
  void rows(const BodyArrays& bodies, const StepContext& step, std::vector<ConstraintRow>& out) override {
    const real dt = step.dt;
    const Vec3 r = rotate(bodies.rot[b], local);
    const Vec3 c = bodies.pos[b] + r - p;
    const real cv[3] = {c.x, c.y, c.z};
    const Vec3 e[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (int j = 0; j < 3; ++j) {
      ConstraintRow row;
      row.a = -1;
      row.b = b;
      // d/dt (x + r) . e_j = v . e_j + (w x r) . e_j = v . e_j + w . (r x e_j)
      const Vec3 ang = cross(r, e[j]);
      row.Jb[j] = 1;
      row.Jb[3] = ang.x;
      row.Jb[4] = ang.y;
      row.Jb[5] = ang.z;
      row.bias = cv[j] / dt;
      out.push_back(row);
    }
  }
};

// Drives the z angular velocity of body b to `target` with an impulse bounded by tau h.
struct SpinDrive : RowProvider {
  int b;
  real target, tau;
  SpinDrive(int body, real w, real torque) : b(body), target(w), tau(torque) {}
  void rows(const BodyArrays&, const StepContext& step, std::vector<ConstraintRow>& out) override {
    const real dt = step.dt;
    ConstraintRow r;
    r.a = -1;
    r.b = b;
    r.Jb[5] = 1;
    r.bias = -target;
    r.lo = -tau * dt;
    r.hi = tau * dt;
    out.push_back(r);
  }
};

}  // namespace rowstest
