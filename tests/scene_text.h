// Scene files as text for the tests of per-body scene keys (docs/SCENES.md).
#pragma once

#include <string>

namespace testscenes {

// A ground plane and a grid generator of two spheres (r 0.1 m, 1 m up); body_extra is appended to the ground's object
// and gen_extra to the generator's, e.g. R"(, "restitution": 0.5)".
inline std::string groundAndPair(const std::string& body_extra, const std::string& gen_extra) {
  return R"({ "name": "r", "bodies": [
      { "name": "ground", "shape": { "type": "plane", "normal": [0, 1, 0] }, "mass": 0)" +
         body_extra + R"( },
      { "generator": { "type": "grid", "counts": [2, 1, 1], "shape": { "type": "sphere", "radius": 0.1 },
        "origin": [0, 1, 0])" +
         gen_extra + R"( } } ] })";
}

}  // namespace testscenes
