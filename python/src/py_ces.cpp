// The CES machine from Python (py_system.h; dvisim/ces.py): a run is `dvisim run`'s (ces_run.h: runCesMachine, the
// same code and outputs, so its numbers are the CLI's bit for bit), and a sweep's design and statistics are
// `dvisim sweep`'s (sweep.h: grids, case ids, metrics, mean and Student-t confidence intervals).
#include <csignal>

#include "ces_run.h"
#include "chrono_like/io/run_control.h"
#include "py_system.h"
#include "sweep.h"

namespace dvipy {

namespace {

// runCesMachine with the GIL released. It installs the CLI's SIGINT/SIGTERM handlers (an interrupted run ends
// with exit code 4 and its results so far); Python's are put back afterwards, the stop request cleared.
int runCes(const dvi::ces::CesRunOptions& o) {
  struct sigaction old_int {
  }, old_term{};
  sigaction(SIGINT, nullptr, &old_int);
  sigaction(SIGTERM, nullptr, &old_term);
  int code = 0;
  std::exception_ptr failure;
  {
    py::gil_scoped_release nogil;
    try {
      code = dvi::ces::runCesMachine(o);
    } catch (...) { failure = std::current_exception(); }
  }
  sigaction(SIGINT, &old_int, nullptr);
  sigaction(SIGTERM, &old_term, nullptr);
  const bool stopped = dvi::stopRequested();
  dvi::g_stop_signal = 0;
  if (failure) std::rethrow_exception(failure);
  if (stopped) {
    PyErr_SetNone(PyExc_KeyboardInterrupt);
    throw py::error_already_set();
  }
  return code;
}

py::tuple meanCi(const std::vector<double>& x) {
  const dvi::sweep::MeanCi r = dvi::sweep::meanCi(x);
  return py::make_tuple(r.n, r.mean, r.half);
}

}  // namespace

void bindCes(py::module_& m) {
  m.def(
      "_run_ces",
      [](const std::string& scene, const std::vector<std::string>& sets, const std::string& backend,
         const std::string& time, const std::string& steps, const std::string& dt, const std::string& threads,
         const std::string& out) {
        dvi::ces::CesRunOptions o;
        o.scene = scene, o.sets = sets, o.backend = backend, o.time = time, o.steps = steps, o.dt = dt;
        o.threads = threads, o.out = out;
        return runCes(o);
      },
      py::arg("scene"), py::arg("sets"), py::arg("backend"), py::arg("time"), py::arg("steps"), py::arg("dt"),
      py::arg("threads"), py::arg("out"));
  m.def("_is_ces_scene", &dvi::ces::isCesScene);
  m.def("_mean_ci", &meanCi);
  m.def("_paired_difference", [](const std::map<int, double>& base, const std::map<int, double>& other) {
    const dvi::sweep::MeanCi r = dvi::sweep::pairedDifference(base, other);
    return py::make_tuple(r.n, r.mean, r.half);
  });
  m.def("_parse_grid", [](const std::string& spec) {
    const dvi::sweep::Factor f = dvi::sweep::parseGrid(spec);
    return py::make_tuple(f.key, f.values);
  });
  m.def("_case_id", &dvi::sweep::caseId);
  m.def("_run_metrics",
        [](const std::string& summary_text) { return dvi::sweep::runMetrics(nlohmann::json::parse(summary_text)); });
}

}  // namespace dvipy
