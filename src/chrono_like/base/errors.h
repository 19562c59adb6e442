// Error types. Bad input (a malformed scene, NaN, a negative mass, an unknown key, a missing file, an
// unsupported shape) raises InputError with a one-line message naming the problem; the command-line
// program turns it into exit code 2.
#pragma once

#include <stdexcept>
#include <string>

namespace dvi {

struct InputError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

}  // namespace dvi
