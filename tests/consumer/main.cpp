// Drops a sphere on a plane through the installed library; exits 0 when it comes to rest on it.
#include <cmath>
#include <cstdio>

#include "chrono_like/system.h"

int main() {
  dvi::System sys;
  dvi::BodyDesc ground;
  ground.mass = 0;
  ground.flags = dvi::kBodyFixed;
  ground.shapes.push_back(dvi::makePlane({0, 1, 0}, 0));
  sys.addBody(ground);
  dvi::BodyDesc ball;
  ball.pos = {0, 0.2, 0};
  ball.inertia = {0.004, 0.004, 0.004};
  ball.shapes.push_back(dvi::makeSphere(0.1));
  int b = sys.addBody(ball);
  sys.advance(1000);
  double y = sys.bodies().pos[b].y;
  std::printf("sphere rests at y = %.4f (radius 0.1)\n", y);
  return std::fabs(y - 0.1) < 0.005 ? 0 : 1;
}
