// How a run ends: the exit codes of the dvisim CLI, the stop flag that SIGINT and SIGTERM set, and the
// divergence check of the step loops (docs/HARDENING.md "Exit codes", "Signals").
//
//   0  done                    the run finished; its results are complete
//   1  failed                  anything else (an internal error); the results so far are written, status "failed"
//   2  bad input               a one-line "dvisim: error: ..." naming the problem; nothing was run or written
//   3  diverged                the state became non-finite; the message names the step and the body
//   4  interrupted             SIGINT or SIGTERM; the last state is checkpointed, summary status "interrupted"
//   5  out of memory / device  std::bad_alloc or a DeviceError (a GPU failure)
//
// Header-only: the CLI and the tests include it; it adds no source file to the library.
#pragma once

#include <signal.h>

#include <cmath>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <new>
#include <stdexcept>
#include <string>

#include "chrono_like/base/errors.h"
#include "chrono_like/solver/solver.h"
#include "chrono_like/system.h"

namespace dvi {

enum ExitCode : int {
  kExitDone = 0,
  kExitFailed = 1,
  kExitBadInput = 2,
  kExitDiverged = 3,
  kExitInterrupted = 4,
  kExitResources = 5,
};

// The signal that asked the run to stop (SIGINT, SIGTERM), 0 while none did. The handler only sets it; the step
// loops read it once a step.
inline volatile std::sig_atomic_t g_stop_signal = 0;

extern "C" inline void dviStopHandler(int sig) { g_stop_signal = sig; }

// Installs the handler for SIGINT and SIGTERM (SA_RESTART: reads and writes in progress go on).
inline void installStopHandlers() {
  struct sigaction sa {};
  sa.sa_handler = dviStopHandler;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
}

inline bool stopRequested() { return g_stop_signal != 0; }
inline const char* stopSignalName() {
  return g_stop_signal == SIGINT ? "SIGINT" : g_stop_signal == SIGTERM ? "SIGTERM" : "a signal";
}

// The exit code of a run that ended with exception `e` (the table above).
inline int exitCodeFor(const std::exception_ptr& e) {
  try {
    std::rethrow_exception(e);
  } catch (const InputError&) { return kExitBadInput; } catch (const SimulationDiverged&) {
    return kExitDiverged;
  } catch (const SolverError&) {
    return kExitDiverged;  // a solver that met a non-finite value: the state diverged
  } catch (const std::bad_alloc&) { return kExitResources; } catch (const DeviceError&) {
    return kExitResources;
  } catch (...) { return kExitFailed; }
}

// The summary.json "status" of a run that ended with exit code `code`.
inline const char* runStatusName(int code) {
  switch (code) {
    case kExitDone: return "done";
    case kExitDiverged: return "diverged";
    case kExitInterrupted: return "interrupted";
    default: return "failed";
  }
}

// One line for `e`: its what(), or "out of memory (std::bad_alloc)".
inline std::string exceptionMessage(const std::exception_ptr& e) {
  try {
    std::rethrow_exception(e);
  } catch (const std::bad_alloc&) { return "out of memory (std::bad_alloc)"; } catch (const std::exception& x) {
    return x.what();
  } catch (...) { return "unknown exception"; }
}

// The first body whose position, rotation or velocity is not finite (-1: none), and which of them.
inline int64_t firstNonFiniteBody(const BodyArrays& b, const char** what = nullptr) {
  for (size_t i = 0; i < b.count(); ++i) {
    const Quat& q = b.rot[i];
    const char* w = !isFinite(b.pos[i]) ? "position"
                    : !(std::isfinite(q.w) && std::isfinite(q.x) && std::isfinite(q.y) && std::isfinite(q.z))
                        ? "rotation"
                    : !isFinite(b.vel[i])   ? "velocity"
                    : !isFinite(b.omega[i]) ? "angular velocity"
                                            : nullptr;
    if (w) {
      if (what) *what = w;
      return int64_t(i);
    }
  }
  return -1;
}

// The one-line message of a run that diverged in step `step` (counted from 1) at time t: the body (the first
// non-finite one; while all are finite, as when the solver met the overflow first, the fastest one after this
// step's gravity and forces at time step dt) and the cause (the solver's message, if it threw).
inline std::string divergedMessage(int64_t step, double t, const BodyArrays& b, const std::string& cause = {},
                                   double dt = 0) {
  const char* what = nullptr;
  const int64_t body = firstNonFiniteBody(b, &what);
  char buf[160];
  std::snprintf(buf, sizeof buf, "the simulation diverged in step %lld (t = %.6g s)", (long long)step, t);
  std::string m = buf;
  if (body >= 0) m += ": body " + std::to_string(body) + " has a non-finite " + what;
  if (!cause.empty()) m += (body >= 0 ? " (" : ": ") + cause + (body >= 0 ? ")" : "");
  if (body < 0) {
    int64_t fastest = -1;
    double vmax = -1;
    for (size_t i = 0; i < b.count(); ++i) {
      if (!(b.inv_mass.size() == b.count() && b.inv_mass[i] > 0)) continue;  // fixed and kinematic bodies
      Vec3 v = b.vel[i];
      if (b.gravity.size() == b.count()) v = v + real(dt) * b.gravity[i];
      if (b.force.size() == b.count()) v = v + real(dt) * b.inv_mass[i] * b.force[i];
      const double speed = std::hypot(double(v.x), double(v.y), double(v.z));  // no overflow of the squares
      if (!(speed <= vmax)) vmax = speed, fastest = int64_t(i);
    }
    if (fastest >= 0) {
      std::snprintf(buf, sizeof buf, "; the fastest body is body %lld (%.3g m/s)", (long long)fastest, vmax);
      m += buf;
    }
  }
  m += "; try a smaller time step";
  return m;
}

// After a step: throws SimulationDiverged when a body's state is not finite.
inline void checkFiniteState(int64_t step, double t, const BodyArrays& b) {
  if (firstNonFiniteBody(b) >= 0) throw SimulationDiverged(divergedMessage(step, t, b));
}

}  // namespace dvi
