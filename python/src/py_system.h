// The Python face of dvi::System (python/dvisim, docs/PYTHON.md): the engine, its state as numpy arrays viewing the
// engine's flat arrays (BodyArrays: Vec3 and Quat are packed reals, so positions are an (N, 3) array in place), the
// contacts as a structured array, external forces and a Python force field.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "chrono_like/io/scene.h"
#include "chrono_like/system.h"

namespace dvipy {

namespace py = pybind11;
using dvi::real;

// A System and what the Python side needs beside it: the run totals (summary()), how many numpy views of its arrays
// are alive (adding bodies may move the arrays: refused while views exist that it would leave dangling), and
// whether a step runs (step() releases the GIL: another thread may not change the bodies meanwhile).
struct PySystem {
  std::unique_ptr<dvi::System> sys;
  dvi::SceneSettings settings;  // the run settings (steps, frames) of a scene, else the defaults
  std::string scene_source;     // the scene file ("" without one)
  dvi::StageLog log;
  int64_t contacts_sum = 0, iterations_sum = 0;
  real max_penetration = 0;
  double wall_s = 0;
  int live_views = 0;
  std::atomic<bool> stepping{false};
  std::shared_ptr<py::object> field_error;  // the exception a Python force field raised in this step

  void checkIdle() const;          // RuntimeError while a step runs in another thread
  void checkGrowable(size_t add);  // InputError when adding `add` bodies would move arrays that views still see
};

// A numpy view of `count` x `cols` reals at `data`, kept valid by holding the System's Python object.
py::array realView(PySystem& s, py::handle owner, real* data, size_t count, size_t cols, bool writeable);

void bindSystem(py::module_& m);
void bindBodies(py::class_<PySystem>& c);        // py_bodies.cpp: add_body, add_spheres, add_mesh, ...
void bindSceneMethods(py::class_<PySystem>& c);  // py_scene.cpp: run(), summary()
void bindScene(py::module_& m);                  // py_scene.cpp: scenes
void bindCes(py::module_& m);                    // py_ces.cpp: the CES machine and the sweep statistics

// n steps with the GIL released; the run totals updated; a Python force field's exception raised again.
void stepSystem(PySystem& s, long long n);

// A System from a configuration (the scene "settings" object as JSON text, validated by parseSceneSettings) on
// `backend` (auto|cpu|gpu). InputError for a bad key or value.
// s.sys for s.settings on `backend` ("auto", "cpu", "gpu": checked by the caller); InputError for gpu without a device.
void makeEngine(PySystem& s, const std::string& backend);
std::unique_ptr<PySystem> makeSystem(const std::string& settings_json, const std::string& backend);

}  // namespace dvipy
