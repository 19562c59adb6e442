// Bodies the solver tests build their scenes from: a fixed ground plane, a solid cube and a solid ball with
// their principal inertias (Goldstein, "Classical Mechanics", 3rd ed., table of moments of inertia).
#pragma once

#include "chrono_like/system.h"

namespace testbodies {

inline dvi::BodyDesc groundPlane(dvi::real mu) {
  dvi::BodyDesc b;
  b.mass = 0;
  b.flags = dvi::kBodyFixed;
  b.friction = mu;
  b.shapes.push_back(dvi::makePlane(dvi::Vec3{0, 1, 0}, 0));
  return b;
}

// A solid cube of half size a: I = m (2a)^2 / 6 about each axis.
inline dvi::BodyDesc cube(dvi::real a, dvi::real mass, dvi::Vec3 pos, dvi::real mu) {
  dvi::BodyDesc b;
  b.pos = pos;
  b.mass = mass;
  const dvi::real I = mass * a * a * 2 / 3;
  b.inertia = dvi::Vec3{I, I, I};
  b.friction = mu;
  b.shapes.push_back(dvi::makeBox(dvi::Vec3{a, a, a}));
  return b;
}

// A solid ball of radius r: I = 2/5 m r^2.
inline dvi::BodyDesc ball(dvi::real r, dvi::real mass, dvi::Vec3 pos, dvi::real mu) {
  dvi::BodyDesc b;
  b.pos = pos;
  b.mass = mass;
  const dvi::real I = dvi::real(0.4) * mass * r * r;
  b.inertia = dvi::Vec3{I, I, I};
  b.friction = mu;
  b.shapes.push_back(dvi::makeSphere(r));
  return b;
}

}  // namespace testbodies
