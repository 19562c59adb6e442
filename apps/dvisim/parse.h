// Command-line value parsing of the dvisim CLI (its commands, the CES run, dvisim sweep and dvisim bench): one-line
// InputError (exit code 2) that names the option and the bad value.
#pragma once

#include <cmath>
#include <cstdlib>
#include <string>

#include "chrono_like/base/errors.h"

namespace dvi {

inline double parseReal(const std::string& opt, const std::string& v) {
  char* end = nullptr;
  const double x = std::strtod(v.c_str(), &end);
  if (v.empty() || *end || !std::isfinite(x)) throw InputError(opt + ": expected a finite number, got '" + v + "'");
  return x;
}

inline long long parseInt(const std::string& opt, const std::string& v, long long lo, long long hi) {
  char* end = nullptr;
  const long long x = std::strtoll(v.c_str(), &end, 10);
  if (v.empty() || *end) throw InputError(opt + ": expected an integer, got '" + v + "'");
  if (x < lo || x > hi)
    throw InputError(opt + ": must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " + v);
  return x;
}

}  // namespace dvi
