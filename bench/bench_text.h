// The text helpers of the benchmarks' reports that need nothing but the standard library, so that the example
// corpus driver (bench/dropin_corpus/harness/corpus_main.cpp, which links no part of dvisim) shares them with the
// benchmarks (bench_util.h includes this).
#pragma once

#include <cctype>
#include <ctime>
#include <fstream>
#include <stdexcept>
#include <string>

namespace dvi::benchutil {

// A file-name-safe form of s (a device name): lowercase letters and digits, other runs as one '-', at most 48
// characters; "unknown" when nothing is left.
inline std::string slug(const std::string& s) {
  std::string o;
  for (char c : s) {
    if (std::isalnum((unsigned char)c))
      o += char(std::tolower((unsigned char)c));
    else if (!o.empty() && o.back() != '-')
      o += '-';
  }
  while (!o.empty() && o.back() == '-') o.pop_back();
  if (o.size() > 48) o.resize(48);
  return o.empty() ? "unknown" : o;
}

// The time now, UTC, formatted by strftime's fmt.
inline std::string utcNow(const char* fmt) {
  std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char b[64];
  std::strftime(b, sizeof b, fmt, &tm);
  return b;
}

// Writes text to path (replacing it); std::runtime_error when that fails.
inline void writeFile(const std::string& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary);
  f << text;
  if (!f) throw std::runtime_error("cannot write " + path);
}

}  // namespace dvi::benchutil
