// Bodies the solver tests build their scenes from: a fixed ground plane, a solid cube and a solid ball with
// their principal inertias (Goldstein, "Classical Mechanics", 3rd ed., table of moments of inertia).
#pragma once

#include <cmath>

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

// bench stability's particle case: 2x2 balls (r = 1 cm, 1000 kg/m^3) in a tight box of four fixed walls (mu 0.7) and a
// fifth ball `ratio` times heavier resting on them; returns the heavy ball's body index (the ground is the caller's).
inline int addParticleBox(dvi::System& s, double ratio) {
  using dvi::real;
  using dvi::Vec3;
  const double r = 0.01, w = 4 * r * 1.001, t = 0.01, h = 4 * r;
  for (int k = 0; k < 4; ++k) {
    const bool xw = k < 2;
    const double c0 = (k % 2 == 0) ? -t : w + t;
    dvi::BodyDesc b;
    b.mass = 0;
    b.flags = dvi::kBodyFixed;
    b.friction = real(0.7);
    b.pos = xw ? Vec3{real(c0), real(h), real(w / 2)} : Vec3{real(w / 2), real(h), real(c0)};
    b.shapes.push_back(dvi::makeBox(xw ? Vec3{real(t), real(h), real(w)} : Vec3{real(w), real(h), real(t)}));
    s.addBody(b);
  }
  const double m = 1000 * 4.0 / 3.0 * 3.14159265358979 * r * r * r;
  for (int i = 0; i < 4; ++i)
    s.addBody(ball(real(r), real(m),
                   Vec3{real(r * (1.0005 + 2.001 * (i % 2))), real(r * 1.0005), real(r * (1.0005 + 2.001 * (i / 2)))},
                   real(0.7)));
  return s.addBody(ball(real(r), real(m * ratio),
                        Vec3{real(w / 2), real(r * (1.001 + std::sqrt(2.0) * 1.001)), real(w / 2)}, real(0.7)));
}

}  // namespace testbodies
