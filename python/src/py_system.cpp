// dvisim.System (py_system.h): configuration, stepping, the state as numpy views, contacts, forces, force fields.
#include "py_system.h"

#include <chrono>
#include <cmath>
#include <cstring>

#include "chrono_like/bullet/bullet_collision_backend.h"
#include "chrono_like/io/run_control.h"
#include "gpu/gpu_factory.h"
#include "parse.h"

namespace dvipy {

// One contact of the last step, as the structured array System.contacts() returns.
struct ContactRecord {
  int32_t body_a, body_b;
  real point_a[3], point_b[3];  // world contact points on A and on B
  real normal[3];               // unit, from A to B
  real distance;                // signed, negative = penetration
  real impulse[3];              // normal, then the two tangential impulses (N s)
};

}  // namespace dvipy

namespace dvipy {

void PySystem::checkIdle() const {
  if (stepping.load()) throw std::runtime_error("dvisim.System: a step is running in another thread");
}

void PySystem::checkGrowable(size_t add) {
  checkIdle();
  const dvi::BodyArrays& b = sys->bodies();
  if (live_views > 0 && b.count() + add > b.pos.capacity())
    throw dvi::InputError("adding " + std::to_string(add) + " bodies would move the state arrays while " +
                          std::to_string(live_views) +
                          " numpy view(s) of them are alive: delete the views (del) or copy them first");
}

namespace {

struct ViewKeep {
  PyObject* owner;
  PySystem* system;
};

}  // namespace

py::array realView(PySystem& s, py::handle owner, real* data, size_t count, size_t cols, bool writeable) {
  auto* keep = new ViewKeep{owner.ptr(), &s};
  Py_INCREF(owner.ptr());
  ++s.live_views;
  py::capsule base(keep, [](void* p) {
    auto* k = static_cast<ViewKeep*>(p);
    --k->system->live_views;
    Py_DECREF(k->owner);
    delete k;
  });
  std::vector<py::ssize_t> shape{py::ssize_t(count), py::ssize_t(cols)};
  std::vector<py::ssize_t> strides{py::ssize_t(cols * sizeof(real)), py::ssize_t(sizeof(real))};
  // A null pointer (no bodies yet) gives an empty array; numpy wants some address.
  static real empty_data[4] = {0, 0, 0, 0};
  py::array a(py::dtype::of<real>(), shape, strides, data ? data : empty_data, base);
  if (!writeable) py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return a;
}

void makeEngine(PySystem& s, const std::string& backend_in) {
  std::string name;
  const bool have_gpu = dvi::gpuAvailable(&name);
  const std::string backend = backend_in == "auto" ? (have_gpu ? "gpu" : "cpu") : backend_in;
  if (backend == "gpu" && !have_gpu)
    throw dvi::InputError("backend gpu: no usable GPU device" + (name.empty() ? std::string() : " (" + name + ")"));
  const dvi::SystemConfig& cfg = s.settings.system;
  s.sys = backend == "gpu" ? dvi::makeGpuSystem(cfg, dvi::makeBulletCollision)
                           : std::make_unique<dvi::System>(cfg, dvi::makeBulletCollision);
}

std::unique_ptr<PySystem> makeSystem(const std::string& settings_json, const std::string& backend_in) {
  dvi::requireOneOf("--backend", backend_in, {"auto", "cpu", "gpu"});
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(settings_json);
  } catch (const nlohmann::json::exception& e) {
    throw dvi::InputError(std::string("dvisim.System: settings: ") + e.what());
  }
  auto s = std::make_unique<PySystem>();
  s->settings = dvi::parseSceneSettings(j, "dvisim.System", "settings");
  makeEngine(*s, backend_in);
  return s;
}

namespace {

// A force field written in Python: fn(t, positions, velocities) returns the forces (N, 3), or (forces, torques),
// added to each body's for this step. The step runs without the GIL; the call takes it.
class PyField : public dvi::ForceField {
 public:
  PyField(py::function fn, PySystem* owner) : fn_(std::move(fn)), owner_(owner) {}
  ~PyField() override {
    py::gil_scoped_acquire gil;
    fn_ = py::function();
  }
  void apply(const dvi::BodyArrays& b, const dvi::StepContext& step, dvi::Vec3* force, dvi::Vec3* torque) override {
    py::gil_scoped_acquire gil;
    try {
      const size_t n = b.count();
      auto view = [&](const dvi::Vec3* p) {
        py::array a(py::dtype::of<real>(), {py::ssize_t(n), py::ssize_t(3)},
                    {py::ssize_t(3 * sizeof(real)), py::ssize_t(sizeof(real))}, reinterpret_cast<const real*>(p));
        return a;  // a copy: the callback may keep it
      };
      py::object r = fn_(double(step.t), view(b.pos.data()), view(b.vel.data()));
      py::object f = r, t = py::none();
      if (py::isinstance<py::tuple>(r) && py::len(r) == 2) f = r[py::int_(0)], t = r[py::int_(1)];
      addInto(f, n, force, "forces");
      if (!t.is_none()) addInto(t, n, torque, "torques");
    } catch (py::error_already_set& e) {
      owner_->field_error = std::make_shared<py::object>(e.value());
      throw std::runtime_error("force field callback raised");
    }
  }

 private:
  static void addInto(const py::object& o, size_t n, dvi::Vec3* out, const char* what) {
    py::array_t<real, py::array::c_style | py::array::forcecast> a;
    try {
      a = py::array_t<real, py::array::c_style | py::array::forcecast>::ensure(o);
    } catch (py::error_already_set&) {}
    if (!a || a.ndim() != 2 || size_t(a.shape(0)) != n || a.shape(1) != 3)
      throw dvi::InputError(std::string("force field: the callback must return ") + what + " of shape (" +
                            std::to_string(n) + ", 3)");
    const real* p = a.data();
    for (size_t i = 0; i < 3 * n; ++i)
      if (!std::isfinite(double(p[i])))
        throw dvi::InputError(std::string("force field: ") + what + " of body " + std::to_string(i / 3) +
                              " is not finite");
    for (size_t i = 0; i < n; ++i) out[i] = out[i] + dvi::Vec3{p[3 * i], p[3 * i + 1], p[3 * i + 2]};
  }
  py::function fn_;
  PySystem* owner_;
};

}  // namespace

void stepSystem(PySystem& s, long long n) {
  if (n < 0) throw dvi::InputError("step: the number of steps must be >= 0, got " + std::to_string(n));
  if (s.stepping.exchange(true)) throw std::runtime_error("dvisim.System: a step is running in another thread");
  std::exception_ptr failure;
  bool interrupted = false;
  {
    py::gil_scoped_release nogil;
    auto last_check = std::chrono::steady_clock::now();
    const bool host_state = s.sys->backendName() == "cpu";
    try {
      for (long long k = 0; k < n; ++k) {
        const auto t0 = std::chrono::steady_clock::now();
        s.sys->step();
        s.wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        const dvi::StepStats& st = s.sys->lastStats();
        s.log.add(st);
        s.contacts_sum += st.contacts;
        s.iterations_sum += st.iterations;
        s.max_penetration = std::fmax(s.max_penetration, st.max_penetration);
        if (host_state) dvi::checkFiniteState(s.sys->stepCount(), s.sys->time(), s.sys->bodies());
        // Ctrl-C: Python's handler only sets a flag; look at it every 0.2 s (taking the GIL each step could wait
        // on another thread's turn) and end step() with KeyboardInterrupt after the step that completed.
        if (std::chrono::steady_clock::now() - last_check > std::chrono::milliseconds(200)) {
          last_check = std::chrono::steady_clock::now();
          py::gil_scoped_acquire gil;
          if (PyErr_CheckSignals() != 0) {
            interrupted = true;
            break;
          }
        }
      }
    } catch (...) { failure = std::current_exception(); }
  }
  s.stepping = false;
  if (s.field_error) {
    py::object e = *s.field_error;
    s.field_error.reset();
    PyErr_SetObject(reinterpret_cast<PyObject*>(Py_TYPE(e.ptr())), e.ptr());
    throw py::error_already_set();
  }
  if (failure) std::rethrow_exception(failure);
  if (interrupted) throw py::error_already_set();  // the signal handler's exception (KeyboardInterrupt)
}

namespace {

// The (N, k) array `o` as reals, checked: shape, finite.
py::array_t<real, py::array::c_style | py::array::forcecast> bodyArray(const py::object& o, size_t n, int cols,
                                                                       const std::string& what) {
  py::array_t<real, py::array::c_style | py::array::forcecast> a;
  if (py::isinstance<py::array>(o) && py::array(o.cast<py::array>()).dtype().kind() == 'O')
    throw dvi::InputError(what + ": expected numbers, got an array of objects");
  try {
    a = py::array_t<real, py::array::c_style | py::array::forcecast>::ensure(o);
  } catch (py::error_already_set&) {}
  if (!a) throw dvi::InputError(what + ": expected an array of numbers");
  if (a.ndim() != 2 || size_t(a.shape(0)) != n || a.shape(1) != cols)
    throw dvi::InputError(what + ": expected shape (" + std::to_string(n) + ", " + std::to_string(cols) + ")");
  for (py::ssize_t i = 0; i < a.size(); ++i)
    if (!std::isfinite(double(a.data()[i])))
      throw dvi::InputError(what + ": body " + std::to_string(i / cols) + " has a non-finite value");
  return a;
}

// Copies `o` into one of the body arrays (pos, rot, vel, omega); a device backend re-uploads.
template <class T>
void setBodies(std::vector<T>& dst, const py::object& o, const std::string& what) {
  constexpr int cols = int(sizeof(T) / sizeof(real));
  auto a = bodyArray(o, dst.size(), cols, what);
  std::memcpy(static_cast<void*>(dst.data()), a.data(), dst.size() * sizeof(T));
}

py::array contactsArray(PySystem& s) {
  s.checkIdle();
  s.sys->syncToHost();
  const dvi::ContactArrays& c = s.sys->contacts();
  const std::vector<real>& g = s.sys->impulses();
  const size_t n = c.count();
  auto out = py::array_t<ContactRecord>(py::ssize_t(n));
  ContactRecord* r = out.mutable_data();
  for (size_t k = 0; k < n; ++k) {
    r[k].body_a = c.body_a[k], r[k].body_b = c.body_b[k];
    const dvi::Vec3 v[3] = {c.pa[k], c.pb[k], c.normal[k]};
    real* dst[3] = {r[k].point_a, r[k].point_b, r[k].normal};
    for (int q = 0; q < 3; ++q) dst[q][0] = v[q].x, dst[q][1] = v[q].y, dst[q][2] = v[q].z;
    r[k].distance = c.dist[k];
    for (int q = 0; q < 3; ++q) r[k].impulse[q] = 3 * k + 2 < g.size() ? g[3 * k + size_t(q)] : real(0);
  }
  return out;
}

py::dict lastStats(const PySystem& s) {
  const dvi::StepStats& st = s.sys->lastStats();
  py::dict d;
  d["contacts"] = st.contacts, d["pairs"] = st.pairs, d["iterations"] = st.iterations;
  d["residual"] = double(st.residual), d["relative_residual"] = double(st.relative_residual);
  d["converged"] = st.converged, d["max_penetration"] = double(st.max_penetration), d["threads"] = st.threads;
  return d;
}

py::object deviceRefs(PySystem& s) {
  s.checkIdle();
  dvi::DeviceBodyRefs r;
  if (!s.sys->deviceBodies(r)) return py::none();
  py::dict d;
  d["positions"] = reinterpret_cast<uintptr_t>(r.pos), d["rotations"] = reinterpret_cast<uintptr_t>(r.rot);
  d["velocities"] = reinterpret_cast<uintptr_t>(r.vel), d["angular_velocities"] = reinterpret_cast<uintptr_t>(r.omega);
  d["count"] = r.count, d["stream"] = reinterpret_cast<uintptr_t>(r.stream), d["itemsize"] = sizeof(real);
  return d;
}

template <class T>
py::array stateView(PySystem& s, py::handle self, std::vector<T>& v) {
  s.checkIdle();
  s.sys->syncToHost();
  const bool host = s.sys->backendName() == "cpu";  // a device backend's host copy: read-only (set_state writes)
  return realView(s, self, reinterpret_cast<real*>(v.data()), v.size(), sizeof(T) / sizeof(real), host);
}

// The read-only property `name`: a view of the state array `member` of the bodies (stateView).
template <class T>
void defStateView(py::class_<PySystem>& c, const char* name, std::vector<T> dvi::BodyArrays::*member) {
  c.def_property_readonly(name, [member](py::object self) {
    PySystem& s = self.cast<PySystem&>();
    return stateView(s, self, s.sys->mutableBodies().*member);
  });
}

void bindState(py::class_<PySystem>& c) {
  defStateView(c, "positions", &dvi::BodyArrays::pos);
  defStateView(c, "rotations", &dvi::BodyArrays::rot);
  defStateView(c, "velocities", &dvi::BodyArrays::vel);
  defStateView(c, "angular_velocities", &dvi::BodyArrays::omega);
  c.def(
      "set_state",
      [](PySystem& s, py::object pos, py::object rot, py::object vel, py::object omega) {
        s.checkIdle();
        s.sys->syncToHost();
        dvi::BodyArrays& b = s.sys->mutableBodies();
        if (!pos.is_none()) setBodies(b.pos, pos, "positions");
        if (!rot.is_none()) setBodies(b.rot, rot, "rotations");
        if (!vel.is_none()) setBodies(b.vel, vel, "velocities");
        if (!omega.is_none()) setBodies(b.omega, omega, "angular_velocities");
        s.sys->markHostDirty();
      },
      py::arg("positions") = py::none(), py::arg("rotations") = py::none(), py::arg("velocities") = py::none(),
      py::arg("angular_velocities") = py::none());
  c.def(
      "apply_forces",
      [](PySystem& s, py::object f, py::object t) {
        s.checkIdle();
        s.sys->syncToHost();
        dvi::BodyArrays& b = s.sys->mutableBodies();
        auto add = [&](std::vector<dvi::Vec3>& dst, const py::object& o, const char* what) {
          auto a = bodyArray(o, dst.size(), 3, what);
          for (size_t i = 0; i < dst.size(); ++i)
            dst[i] = dst[i] + dvi::Vec3{a.data()[3 * i], a.data()[3 * i + 1], a.data()[3 * i + 2]};
        };
        add(b.force, f, "forces");
        if (!t.is_none()) add(b.torque, t, "torques");
        s.sys->markHostDirty();
      },
      py::arg("forces"), py::arg("torques") = py::none());
}

}  // namespace

void bindSystem(py::module_& m) {
  PYBIND11_NUMPY_DTYPE(ContactRecord, body_a, body_b, point_a, point_b, normal, distance, impulse);
  py::class_<PySystem> c(m, "_System");
  c.def(py::init(&makeSystem), py::arg("settings_json"), py::arg("backend"));
  c.def("step", &stepSystem, py::arg("n") = 1);
  bindState(c);
  bindBodies(c);
  bindSceneMethods(c);
  c.def("contacts", &contactsArray);
  c.def("add_force_field", [](PySystem& s, py::function fn) {
    s.checkIdle();
    s.sys->addForceField(std::make_shared<PyField>(std::move(fn), &s));
  });
  c.def("last_stats", &lastStats);
  c.def("device_refs", &deviceRefs);
  c.def_property_readonly("body_count", [](const PySystem& s) { return s.sys->bodies().count(); });
  c.def_property_readonly("time", [](const PySystem& s) { return s.sys->time(); });
  c.def_property_readonly("step_count", [](const PySystem& s) { return s.sys->stepCount(); });
  c.def_property_readonly("dt", [](const PySystem& s) { return s.sys->config().step.dt; });
  c.def_property_readonly("backend", [](const PySystem& s) { return s.sys->backendName(); });
  c.def_property_readonly("device", [](const PySystem& s) { return s.sys->deviceName(); });
  c.def_property_readonly("live_views", [](const PySystem& s) { return s.live_views; });
  c.def("state_hash", [](const PySystem& s) { return s.sys->stateHash(); });
}

}  // namespace dvipy
