// The extension module dvisim._dvisim (python/dvisim/__init__.py wraps it; docs/PYTHON.md). Errors: the engine's
// InputError is dvisim.InputError, a ValueError with the CLI's one-line message; a diverged simulation, a solver
// failure and a device error are RuntimeErrors; std::bad_alloc is MemoryError (pybind11's own translation).
#include "chrono_like/solver/solver.h"
#include "py_system.h"

namespace py = pybind11;

PYBIND11_MODULE(_dvisim, m) {
  m.doc() = "dvisim: DVI multibody engine for dense granular flows (the C++ core; use the dvisim package)";
  py::register_exception<dvi::InputError>(m, "InputError", PyExc_ValueError);
  py::register_exception<dvi::SimulationDiverged>(m, "SimulationDiverged", PyExc_RuntimeError);
  py::register_exception<dvi::SolverError>(m, "SolverError", PyExc_RuntimeError);
  py::register_exception<dvi::DeviceError>(m, "DeviceError", PyExc_RuntimeError);
  m.attr("real_itemsize") = sizeof(dvi::real);
  dvipy::bindSystem(m);
  dvipy::bindScene(m);
  dvipy::bindCes(m);
}
