#include "chrono_like/base/shape.h"

namespace dvi {

const char* shapeTypeName(ShapeType t) {
  switch (t) {
    case ShapeType::Sphere: return "sphere";
    case ShapeType::Ellipsoid: return "ellipsoid";
    case ShapeType::Box: return "box";
    case ShapeType::Cylinder: return "cylinder";
    case ShapeType::Capsule: return "capsule";
    case ShapeType::Cone: return "cone";
    case ShapeType::ConvexHull: return "convex_hull";
    case ShapeType::Plane: return "plane";
    case ShapeType::Triangle: return "triangle";
    default: return "unknown";
  }
}

}  // namespace dvi
