// Adding bodies from Python (py_system.h): one body of any shapes, spheres in bulk, a static triangle mesh. The Python
// side (dvisim/__init__.py) turns its arguments into checked float64 arrays; System::addBody validates the rest.
#include <cmath>

#include "chrono_like/bullet/triangle_mesh.h"
#include "py_system.h"

namespace dvipy {

namespace {

using F64 = py::array_t<double, py::array::c_style | py::array::forcecast>;

dvi::Vec3 vec3(const F64& a, size_t i = 0) {
  const double* p = a.data() + 3 * i;
  return {real(p[0]), real(p[1]), real(p[2])};
}
dvi::Quat quat(const F64& a, size_t i = 0) {
  const double* p = a.data() + 4 * i;
  return {real(p[0]), real(p[1]), real(p[2]), real(p[3])};
}

void need(const F64& a, py::ssize_t n, const char* what) {
  if (a.size() != n) throw dvi::InputError(std::string(what) + ": expected " + std::to_string(n) + " numbers");
}

// A shape from its tuple (type, dims (3), position (3), rotation (4), hull points (M, 3) or None, margin).
dvi::ShapeDesc shapeOf(const py::tuple& t) {
  if (t.size() != 6) throw dvi::InputError("shape: expected a dvisim shape (Sphere, Box, ...)");
  const std::string type = t[0].cast<std::string>();
  const F64 dims = F64::ensure(t[1]), pos = F64::ensure(t[2]), rot = F64::ensure(t[3]);
  need(dims, 3, "shape dimensions"), need(pos, 3, "shape position"), need(rot, 4, "shape rotation");
  const dvi::Pose local{vec3(pos), quat(rot)};
  const dvi::Vec3 d = vec3(dims);
  if (type == "sphere") return dvi::makeSphere(d.x, local);
  if (type == "box") return dvi::makeBox(d, local);
  if (type == "cylinder") return dvi::makeCylinder(d.x, d.y, local);
  if (type == "capsule") return dvi::makeCapsule(d.x, d.y, local);
  if (type == "cone") return dvi::makeCone(d.x, d.y, local);
  if (type == "ellipsoid") return dvi::makeEllipsoid(d, local);
  if (type == "plane") return dvi::makePlane(d, t[5].cast<real>());
  if (type == "hull") {
    const F64 p = F64::ensure(t[4]);
    if (!p || p.ndim() != 2 || p.shape(1) != 3 || p.shape(0) < 4)
      throw dvi::InputError("hull: expected points of shape (M, 3), M >= 4");
    std::vector<dvi::Vec3> pts(size_t(p.shape(0)));
    for (size_t i = 0; i < pts.size(); ++i) pts[i] = vec3(p, i);
    return dvi::makeConvexHull(std::move(pts), local, t[5].cast<real>());
  }
  throw dvi::InputError("shape: unknown type '" + type + "'");
}

// add_body's arguments, all checked float64 arrays: position (3), rotation (4), velocity (3), angular velocity (3),
// mass, inertia (3), material (friction, restitution, rolling, spinning), gravity (3, or empty: the system's).
int addBody(PySystem& s, const py::list& shapes, const F64& pos, const F64& rot, const F64& vel, const F64& omega,
            double mass, const F64& inertia, const F64& material, int flags, const F64& gravity) {
  s.checkGrowable(1);
  need(pos, 3, "position"), need(rot, 4, "rotation"), need(vel, 3, "velocity"), need(omega, 3, "angular_velocity");
  need(inertia, 3, "inertia"), need(material, 4, "material");
  dvi::BodyDesc d;
  d.pos = vec3(pos), d.rot = quat(rot), d.vel = vec3(vel), d.omega = vec3(omega);
  d.mass = real(mass), d.inertia = vec3(inertia), d.flags = uint8_t(flags);
  const double* m = material.data();
  d.friction = real(m[0]), d.restitution = real(m[1]), d.rolling_friction = real(m[2]);
  d.spinning_friction = real(m[3]);
  if (gravity.size() == 3) d.has_gravity = true, d.gravity = vec3(gravity);
  for (const py::handle h : shapes) d.shapes.push_back(shapeOf(h.cast<py::tuple>()));
  if (d.shapes.empty()) throw dvi::InputError("add_body: a body needs at least one shape");
  const int id = s.sys->addBody(d);
  s.sys->markHostDirty();
  return id;
}

// n spheres: positions (n, 3), radii, masses (n), velocities (n, 3), material (4), flags. Returns their ids.
py::array_t<int32_t> addSpheres(PySystem& s, const F64& pos, const F64& radii, const F64& mass, const F64& vel,
                                const F64& material, int flags) {
  const size_t n = size_t(radii.size());
  need(pos, py::ssize_t(3 * n), "positions"), need(mass, py::ssize_t(n), "masses");
  need(vel, py::ssize_t(3 * n), "velocities"), need(material, 4, "material");
  s.checkGrowable(n);
  auto ids = py::array_t<int32_t>(py::ssize_t(n));
  dvi::BodyDesc d;
  const double* m = material.data();
  d.friction = real(m[0]), d.restitution = real(m[1]), d.rolling_friction = real(m[2]);
  d.spinning_friction = real(m[3]), d.flags = uint8_t(flags);
  d.shapes.resize(1);
  for (size_t i = 0; i < n; ++i) {
    const real r = real(radii.data()[i]);
    d.pos = vec3(pos, i), d.vel = vec3(vel, i), d.mass = flags ? 0 : real(mass.data()[i]);
    const real inertia = real(0.4) * d.mass * r * r;  // solid sphere, 2/5 m r^2
    d.inertia = flags ? dvi::Vec3{1, 1, 1} : dvi::Vec3{inertia, inertia, inertia};
    d.shapes[0] = dvi::makeSphere(r);
    ids.mutable_data()[i] = s.sys->addBody(d);
  }
  s.sys->markHostDirty();
  return ids;
}

// A fixed body of triangles: vertices (V, 3) in the body frame, triangles (T, 3) of vertex indices. Degenerate
// triangles are left out (makeTriangle); none left: InputError.
int addMesh(PySystem& s, const F64& vertices,
            const py::array_t<int64_t, py::array::c_style | py::array::forcecast>& tri, const F64& pos, const F64& rot,
            const F64& material) {
  if (vertices.ndim() != 2 || vertices.shape(1) != 3) throw dvi::InputError("add_mesh: vertices must be (V, 3)");
  if (tri.ndim() != 2 || tri.shape(1) != 3) throw dvi::InputError("add_mesh: triangles must be (T, 3)");
  need(pos, 3, "position"), need(rot, 4, "rotation"), need(material, 4, "material");
  s.checkGrowable(1);
  dvi::BodyDesc d;
  d.pos = vec3(pos), d.rot = quat(rot), d.mass = 0, d.flags = dvi::kBodyFixed;
  d.friction = real(material.data()[0]), d.restitution = real(material.data()[1]);
  const int64_t nv = vertices.shape(0);
  for (py::ssize_t t = 0; t < tri.shape(0); ++t) {
    dvi::Vec3 v[3];
    for (int k = 0; k < 3; ++k) {
      const int64_t i = tri.data()[3 * t + k];
      if (i < 0 || i >= nv)
        throw dvi::InputError("add_mesh: triangle " + std::to_string(t) + " names vertex " + std::to_string(i) +
                              " of " + std::to_string(nv));
      v[k] = vec3(vertices, size_t(i));
    }
    dvi::ShapeDesc sd;
    if (dvi::makeTriangle(v[0], v[1], v[2], dvi::Pose{{0, 0, 0}, {1, 0, 0, 0}}, sd)) d.shapes.push_back(sd);
  }
  if (d.shapes.empty()) throw dvi::InputError("add_mesh: no triangle with a nonzero area");
  const int id = s.sys->addBody(d);
  s.sys->markHostDirty();
  return id;
}

}  // namespace

void bindBodies(py::class_<PySystem>& c) {
  c.def("_add_body", &addBody);
  c.def("_add_spheres", &addSpheres);
  c.def("_add_mesh", &addMesh);
}

}  // namespace dvipy
