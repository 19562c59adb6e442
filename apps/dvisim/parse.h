// Command-line value parsing of the dvisim CLI (its commands, the CES run, dvisim sweep and dvisim bench): one-line
// InputError (exit code 2) that names the option and the bad value.
#pragma once

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <initializer_list>
#include <string>

#include "chrono_like/base/errors.h"

namespace dvi {

// True when v is a plain decimal number: [+-] digits [. digits] [e|E [+-] digits], at least one digit before the
// exponent, nothing else. strtod alone also takes hexadecimal ("0x10" is 16), "inf", "nan" and leading spaces.
inline bool isDecimalNumber(const std::string& v) {
  size_t i = 0, digits = 0;
  if (i < v.size() && (v[i] == '+' || v[i] == '-')) ++i;
  for (; i < v.size() && std::isdigit(static_cast<unsigned char>(v[i])); ++i) ++digits;
  if (i < v.size() && v[i] == '.')
    for (++i; i < v.size() && std::isdigit(static_cast<unsigned char>(v[i])); ++i) ++digits;
  if (digits == 0) return false;
  if (i < v.size() && (v[i] == 'e' || v[i] == 'E')) {
    ++i;
    if (i < v.size() && (v[i] == '+' || v[i] == '-')) ++i;
    size_t exp_digits = 0;
    for (; i < v.size() && std::isdigit(static_cast<unsigned char>(v[i])); ++i) ++exp_digits;
    if (exp_digits == 0) return false;
  }
  return i == v.size();
}

inline double parseReal(const std::string& opt, const std::string& v) {
  if (!isDecimalNumber(v)) throw InputError(opt + ": expected a finite decimal number, got '" + v + "'");
  const double x = std::strtod(v.c_str(), nullptr);
  if (!std::isfinite(x)) throw InputError(opt + ": expected a finite number, got '" + v + "'");
  return x;
}

inline long long parseInt(const std::string& opt, const std::string& v, long long lo, long long hi) {
  size_t i = (!v.empty() && (v[0] == '+' || v[0] == '-')) ? 1 : 0;
  bool digits = i < v.size();
  for (; i < v.size(); ++i) digits = digits && std::isdigit(static_cast<unsigned char>(v[i]));
  if (!digits) throw InputError(opt + ": expected an integer, got '" + v + "'");
  const long long x = std::strtoll(v.c_str(), nullptr, 10);  // out of range: LLONG_MIN/MAX, refused below
  if (x < lo || x > hi)
    throw InputError(opt + ": must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " + v);
  return x;
}

// An option's value that must be one of `choices`; else InputError "unknown NAME 'v' (expected a|b|c)", NAME
// being the option without its "--".
inline void requireOneOf(const std::string& opt, const std::string& v, std::initializer_list<const char*> choices) {
  std::string list;
  for (const char* c : choices) {
    if (v == c) return;
    list += std::string(list.empty() ? "" : "|") + c;
  }
  throw InputError("unknown " + opt.substr(2) + " '" + v + "' (expected " + list + ")");
}

}  // namespace dvi
