// Validation of JSON documents (scenes, the CES machine config): every problem is one InputError line
// "<origin>: <key path>: <what>, got <value>" (exit code 2 in the CLI). Shared by scene.cpp and
// ces/ces_config.cpp.
#pragma once

#include <cmath>
#include <initializer_list>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <utility>
#include <vector>

#include "chrono_like/base/errors.h"
#include "chrono_like/base/math.h"
#include "chrono_like/io/input_limits.h"

namespace dvi {
namespace jsoncheck {

using nlohmann::json;

// The start of a value as JSON text, for messages. Stops after ~48 characters, so its recursion is bounded
// by that and not by the nesting of the value (json::dump() recurses once per level).
inline void describeInto(const json& v, std::string& out) {
  if (out.size() > 48) return;
  if (v.is_array() || v.is_object()) {
    out += v.is_array() ? '[' : '{';
    bool first = true;
    for (auto it = v.begin(); it != v.end() && out.size() <= 48; ++it) {
      if (!first) out += ',';
      first = false;
      if (v.is_object()) out += json(it.key()).dump(-1, ' ', false, json::error_handler_t::replace) + ":";
      describeInto(*it, out);
    }
    out += v.is_array() ? ']' : '}';
    return;
  }
  if (v.is_string() && v.get_ref<const std::string&>().size() > 64) {
    // the first 64 bytes, cut back to a UTF-8 character boundary (dump() throws on a broken sequence)
    const std::string& str = v.get_ref<const std::string&>();
    size_t n = 64;
    while (n > 0 && (static_cast<unsigned char>(str[n]) & 0xC0) == 0x80) --n;
    out += json(str.substr(0, n)).dump(-1, ' ', false, json::error_handler_t::replace);
    return;
  }
  out += v.dump(-1, ' ', false, json::error_handler_t::replace);
}
inline std::string describe(const json& v) {
  std::string s;
  describeInto(v, s);
  if (s.size() > 48) s = s.substr(0, 45) + "...";
  return s;
}

inline const char* typeName(const json& v) {
  if (v.is_null()) return "null";
  if (v.is_boolean()) return "boolean";
  if (v.is_number()) return "number";
  if (v.is_string()) return "string";
  if (v.is_array()) return "array";
  return "object";
}

inline std::string num(double x) {
  std::ostringstream o;
  o.precision(10);
  o << x;
  return o.str();
}

// Reports problems as "<origin>: <path>: <what>" (one line, an InputError: exit code 2 in the CLI).
struct JsonCheck {
  std::string origin;
  // Where numbers are stored in a narrower type (Bullet's btScalar is a float): the largest magnitude a number
  // may have and the smallest positive value (the smallest normal float) that positive() and nonNegative()
  // accept, so that nothing rounds to infinity or zero on the way (a mass of 5e-324 or 1e39 would make a body
  // static). `stored_as` names the type in the messages.
  double max_magnitude = std::numeric_limits<double>::max();
  double min_positive = std::numeric_limits<double>::denorm_min();
  const char* stored_as = "double";

  [[noreturn]] void fail(const std::string& path, const std::string& what) const {
    throw InputError(origin + ": " + (path.empty() ? std::string() : path + ": ") + what);
  }

  const json& object(const json& v, const std::string& path) const {
    if (!v.is_object()) fail(path, std::string("expected an object, got ") + typeName(v) + " " + describe(v));
    return v;
  }
  const json& array(const json& v, const std::string& path) const {
    if (!v.is_array()) fail(path, std::string("expected an array, got ") + typeName(v) + " " + describe(v));
    return v;
  }
  void keys(const json& o, const std::string& path, std::initializer_list<const char*> allowed) const {
    for (auto it = o.begin(); it != o.end(); ++it) {
      bool ok = false;
      for (const char* a : allowed) ok = ok || it.key() == a;
      if (!ok) {
        std::string list;
        for (const char* a : allowed) list += std::string(list.empty() ? "" : ", ") + a;
        fail(path.empty() ? it.key() : path + "." + it.key(), "unknown key (allowed: " + list + ")");
      }
    }
  }
  double number(const json& v, const std::string& path) const {
    const double x = finiteNumber(v, path);
    if (std::fabs(x) > max_magnitude)
      fail(path, "out of range: the magnitude must be <= " + num(max_magnitude) + " (stored as " + stored_as +
                     "), got " + describe(v));
    return x;
  }
  // Any finite number (for values that are not stored as given: a direction is normalised first).
  double finiteNumber(const json& v, const std::string& path) const {
    if (v.is_string() && (v.get<std::string>() == "nan" || v.get<std::string>() == "NaN"))
      fail(path, "non-finite number " + describe(v));
    if (!v.is_number()) fail(path, std::string("expected a finite number, got ") + typeName(v) + " " + describe(v));
    const double x = v.get<double>();
    if (!std::isfinite(x)) fail(path, "non-finite number " + describe(v));
    return x;
  }
  double positive(const json& v, const std::string& path) const {
    const double x = number(v, path);
    if (!(x > 0)) fail(path, "must be > 0, got " + num(x));
    if (x < min_positive)
      fail(path, "must be >= " + num(min_positive) + " (stored as " + stored_as + "), got " + describe(v));
    return x;
  }
  double nonNegative(const json& v, const std::string& path) const {
    const double x = number(v, path);
    if (x < 0) fail(path, "must be >= 0, got " + num(x));
    if (x > 0 && x < min_positive)
      fail(path, "must be 0 or >= " + num(min_positive) + " (stored as " + stored_as + "), got " + describe(v));
    return x;
  }
  int64_t integer(const json& v, const std::string& path, int64_t lo, int64_t hi) const {
    const double x = number(v, path);
    if (x != std::floor(x)) fail(path, "expected an integer, got " + describe(v));
    if (x < double(lo) || x > double(hi))
      fail(path, "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " + describe(v));
    return int64_t(x);
  }
  bool boolean(const json& v, const std::string& path) const {
    if (!v.is_boolean()) fail(path, std::string("expected true or false, got ") + typeName(v) + " " + describe(v));
    return v.get<bool>();
  }
  std::string string(const json& v, const std::string& path) const {
    if (!v.is_string()) fail(path, std::string("expected a string, got ") + typeName(v) + " " + describe(v));
    return v.get<std::string>();
  }
  std::string oneOf(const json& v, const std::string& path, std::initializer_list<const char*> choices) const {
    const std::string s = string(v, path);
    std::string list;
    for (const char* c : choices) {
      if (s == c) return s;
      list += std::string(list.empty() ? "" : "|") + c;
    }
    fail(path, "unknown value \"" + s + "\" (expected " + list + ")");
  }
  // A string naming one of `choices` (name, value): its value; else the same message as oneOf.
  template <class E>
  E named(const json& v, const std::string& path, std::initializer_list<std::pair<const char*, E>> choices) const {
    const std::string s = string(v, path);
    std::string list;
    for (const auto& c : choices) {
      if (s == c.first) return c.second;
      list += std::string(list.empty() ? "" : "|") + c.first;
    }
    fail(path, "unknown value \"" + s + "\" (expected " + list + ")");
  }
  Vec3 vec3(const json& v, const std::string& path) const {
    if (!v.is_array() || v.size() != 3) fail(path, std::string("expected an array of 3 numbers, got ") + describe(v));
    return Vec3{real(number(v[0], path + "[0]")), real(number(v[1], path + "[1]")), real(number(v[2], path + "[2]"))};
  }
  Vec3 positiveVec3(const json& v, const std::string& path) const {
    if (!v.is_array() || v.size() != 3) fail(path, std::string("expected an array of 3 numbers, got ") + describe(v));
    return Vec3{real(positive(v[0], path + "[0]")), real(positive(v[1], path + "[1]")),
                real(positive(v[2], path + "[2]"))};
  }
  // A direction (a plane normal, a rotation axis): 3 finite numbers, not all zero, returned as a unit vector.
  // Scaled by the largest component before its length is taken, so [1e300, 1e300, 0] (whose length overflows)
  // and [1e-200, 1e-200, 0] (whose squares underflow) both give their direction instead of a zero vector.
  Vec3 direction(const json& v, const std::string& path) const {
    if (!v.is_array() || v.size() != 3) fail(path, std::string("expected an array of 3 numbers, got ") + describe(v));
    double c[3];
    for (int i = 0; i < 3; ++i) c[i] = finiteNumber(v[size_t(i)], path + "[" + std::to_string(i) + "]");
    const double m = std::fmax(std::fabs(c[0]), std::fmax(std::fabs(c[1]), std::fabs(c[2])));
    if (!(m > 0)) fail(path, "has zero length");
    const double x = c[0] / m, y = c[1] / m, z = c[2] / m, l = std::sqrt(x * x + y * y + z * z);
    if (!(l > 0) || !std::isfinite(l)) fail(path, "has no finite non-zero length");
    return Vec3{real(x / l), real(y / l), real(z / l)};
  }
  Quat rotation(const json& v, const std::string& path) const {
    if (v.is_array()) {
      if (v.size() != 4) fail(path, "expected a quaternion [w, x, y, z] or {axis, angle_deg}, got " + describe(v));
      double c[4];
      for (int i = 0; i < 4; ++i) c[i] = finiteNumber(v[size_t(i)], path + "[" + std::to_string(i) + "]");
      // scaled by the largest component first, as direction() does
      const double m =
          std::fmax(std::fmax(std::fabs(c[0]), std::fabs(c[1])), std::fmax(std::fabs(c[2]), std::fabs(c[3])));
      if (!(m > 0)) fail(path, "quaternion has zero length");
      for (double& x : c) x /= m;
      const double n = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2] + c[3] * c[3]);
      return Quat{real(c[0] / n), real(c[1] / n), real(c[2] / n), real(c[3] / n)};
    }
    if (v.is_object()) {
      keys(v, path, {"axis", "angle_deg", "angle"});
      if (!v.contains("axis")) fail(path + ".axis", "missing");
      const Vec3 axis = direction(v["axis"], path + ".axis");
      if (v.contains("angle_deg") == v.contains("angle")) fail(path, "give exactly one of angle_deg, angle (radians)");
      const real angle = v.contains("angle") ? real(number(v["angle"], path + ".angle"))
                                             : real(number(v["angle_deg"], path + ".angle_deg") * M_PI / 180.0);
      return quatFromAxisAngle(axis, angle);
    }
    fail(path, std::string("expected a quaternion [w, x, y, z] or {axis, angle_deg}, got ") + describe(v));
  }
  // An object whose keys are all in `allowed` (unknown keys are errors).
  const json& object(const json& o, const std::string& path, std::initializer_list<const char*> allowed) const {
    object(o, path);
    keys(o, path, allowed);
    return o;
  }
  double range(const json& v, const std::string& path, double lo, double hi, bool lo_open = false) const {
    const double x = number(v, path);
    if (lo_open ? !(x > lo) : !(x >= lo))
      fail(path, std::string("must be ") + (lo_open ? "> " : ">= ") + num(lo) + ", got " + num(x));
    if (!(x <= hi)) fail(path, "must be <= " + num(hi) + ", got " + num(x));
    return x;
  }
  // A number >= 0 or the string "inf".
  double nonNegativeOrInf(const json& v, const std::string& path) const {
    if (v.is_string() && v.get<std::string>() == "inf") return std::numeric_limits<double>::infinity();
    if (v.is_string()) fail(path, "expected a number >= 0 or \"inf\", got " + describe(v));
    return nonNegative(v, path);
  }
  // [lo, hi] with 0 < lo <= hi (or lo >= 0 when allow_zero).
  void interval(const json& v, const std::string& path, double& lo, double& hi, bool allow_zero = false) const {
    if (!v.is_array() || v.size() != 2) fail(path, "expected [min, max], got " + describe(v));
    lo = allow_zero ? nonNegative(v[0], path + "[0]") : positive(v[0], path + "[0]");
    hi = allow_zero ? nonNegative(v[1], path + "[1]") : positive(v[1], path + "[1]");
    if (hi < lo) fail(path, "max " + num(hi) + " is below min " + num(lo));
  }
};

// --set KEY=VALUE: VALUE as JSON, or as a string when it does not parse (a bare word: settings.solver=gs).
// The offset of the first byte of `s` that does not belong to a well-formed UTF-8 sequence (RFC 3629: no overlong
// forms, no surrogates, nothing above U+10FFFF), or npos when all of it is valid UTF-8.
inline size_t invalidUtf8At(const std::string& s) {
  const size_t n = s.size();
  for (size_t i = 0; i < n;) {
    const unsigned char c = static_cast<unsigned char>(s[i]);
    size_t len = 0;
    unsigned char lo = 0x80, hi = 0xBF;  // the range of the second byte
    if (c < 0x80)
      len = 1;
    else if (c >= 0xC2 && c <= 0xDF)
      len = 2;
    else if (c >= 0xE0 && c <= 0xEF)
      len = 3, lo = c == 0xE0 ? 0xA0 : 0x80, hi = c == 0xED ? 0x9F : 0xBF;
    else if (c >= 0xF0 && c <= 0xF4)
      len = 4, lo = c == 0xF0 ? 0x90 : 0x80, hi = c == 0xF4 ? 0x8F : 0xBF;
    else
      return i;
    if (len > 1) {
      if (i + len > n) return i;
      const unsigned char c1 = static_cast<unsigned char>(s[i + 1]);
      if (c1 < lo || c1 > hi) return i;
      for (size_t k = 2; k < len; ++k)
        if ((static_cast<unsigned char>(s[i + k]) & 0xC0) != 0x80) return i;
    }
    i += len;
  }
  return std::string::npos;
}

// Refuses a string that is not valid UTF-8 (JSON text must be; a name would otherwise fail only when the results
// are written): "<what>: not valid UTF-8 (byte 0xNN at offset K)".
inline void requireUtf8(const std::string& s, const std::string& what) {
  const size_t at = invalidUtf8At(s);
  if (at == std::string::npos) return;
  char b[64];
  std::snprintf(b, sizeof b, "byte 0x%02x at offset %zu", unsigned(static_cast<unsigned char>(s[at])), at);
  throw InputError(what + ": not valid UTF-8 (" + b + ")");
}

// `what` names the value in a refusal ("--set KEY"): a value nested deeper than the JSON limit is refused as the
// parser meets it (parseJsonGated), never built.
inline json parseSetValue(const std::string& text, const std::string& what) {
  try {
    return parseJsonGated(text, what);
  } catch (const json::exception&) { return json(text); }
}

// Assigns value at the dotted path `key` below root (array elements by index). A missing intermediate
// object is created where create(depth, name) allows it, else an error; a missing leaf is added (the
// document's parser then rejects unknown keys). Errors name the key as `shown`.
template <class MayCreate>
void setByPath(json& root, const std::string& key, const std::string& shown, json value, MayCreate create) {
  // Names and strings are UTF-8 from the start: checked here, not by the JSON writer at the end of a run.
  const bool key_ok = invalidUtf8At(key) == std::string::npos;
  requireUtf8(key, "--set " + (key_ok ? shown : std::string("KEY")) + ": the key");
  if (value.is_string()) requireUtf8(value.get_ref<const std::string&>(), "--set " + shown + ": the value");
  std::vector<std::string> parts;
  std::stringstream ss(key);
  for (std::string p; std::getline(ss, p, '.');) {
    if (p.empty()) throw InputError("--set " + shown + ": empty key component");
    parts.push_back(p);
    // each component may create an object level: as many as a document may nest
    if (parts.size() > size_t(inputLimits().max_json_depth))
      throw InputError("--set " + (key_ok && shown.size() <= 80 ? shown : std::string("KEY")) +
                       ": the key has more than " + std::to_string(inputLimits().max_json_depth) +
                       " components (the nesting limit)");
  }
  json* cur = &root;
  for (size_t i = 0; i < parts.size(); ++i) {
    const std::string& p = parts[i];
    const bool last = i + 1 == parts.size();
    if (cur->is_array()) {
      char* end = nullptr;
      const long idx = std::strtol(p.c_str(), &end, 10);
      if (*end || idx < 0 || size_t(idx) >= cur->size())
        throw InputError("--set " + shown + ": no element '" + p + "' (array of " + std::to_string(cur->size()) + ")");
      cur = &(*cur)[size_t(idx)];
    } else if (cur->is_object()) {
      if (!cur->contains(p) && !last) {
        if (!create(i, p)) throw InputError("--set " + shown + ": unknown key '" + p + "'");
        (*cur)[p] = json::object();
      }
      cur = &(*cur)[p];
    } else {
      throw InputError("--set " + shown + ": '" + parts[i - 1] + "' is not an object or array");
    }
  }
  *cur = std::move(value);
}

}  // namespace jsoncheck
}  // namespace dvi
