// Error types. Bad input (a malformed scene, NaN, a negative mass, an unknown key, a missing file, an
// unsupported shape) raises InputError with a one-line message naming the problem; the command-line
// program turns it into exit code 2. The other failures a run can end with have their own types, so that the
// program can tell them apart by type (exit codes: src/chrono_like/io/run_control.h):
//   SimulationDiverged  the state became non-finite (exit code 3)
//   DeviceError         the GPU failed or ran out of memory (exit code 5, like std::bad_alloc)
#pragma once

#include <stdexcept>
#include <string>

namespace dvi {

struct InputError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct SimulationDiverged : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct DeviceError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

}  // namespace dvi
