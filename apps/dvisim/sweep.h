// `dvisim sweep` (sweep.cpp): the design of experiments (full-factorial grids, linspace ranges, a CSV list of
// settings, replicate seeds), the case names, the metrics read back from a run's summary.json and their
// statistics (mean and Student-t 95% confidence half-width). Pure functions, header-only, so that
// tests/test_sweep.cpp checks them directly; sweep.cpp runs the cases.
#pragma once

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "chrono_like/base/errors.h"
#include "parse.h"

namespace dvi::sweep {

// One swept key and its levels, each level as the text handed to `dvisim run --set KEY=VALUE`.
struct Factor {
  std::string key;
  std::vector<std::string> values;
};
// One setting of the design: (key, value) pairs in the order the keys were given.
using Setting = std::vector<std::pair<std::string, std::string>>;

inline std::string trimmed(const std::string& s) {
  const size_t a = s.find_first_not_of(" \t\r\n"), b = s.find_last_not_of(" \t\r\n");
  return a == std::string::npos ? std::string() : s.substr(a, b - a + 1);
}

inline std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string t; std::getline(ss, t, sep);) out.push_back(trimmed(t));
  if (!s.empty() && s.back() == sep) out.push_back("");
  return out;
}

// A linspace level: shortest text that reads back as the same double (up to 15 significant digits).
inline std::string formatLevel(double x) {
  char b[64];
  for (int p = 6; p <= 17; ++p) {
    std::snprintf(b, sizeof b, "%.*g", p, x);
    if (std::strtod(b, nullptr) == x || p == 15) break;
  }
  return b;
}

// "KEY=v1,v2,v3" (levels as typed) or "KEY=lo:hi:n" (n >= 2 evenly spaced levels from lo to hi, both included).
inline Factor parseGrid(const std::string& spec) {
  const std::string opt = "--grid " + spec;
  const size_t eq = spec.find('=');
  if (eq == std::string::npos) throw InputError(opt + ": expected KEY=v1,v2,... or KEY=lo:hi:n");
  Factor f{trimmed(spec.substr(0, eq)), {}};
  const std::string rhs = trimmed(spec.substr(eq + 1));
  if (f.key.empty()) throw InputError(opt + ": empty key");
  if (rhs.empty()) throw InputError(opt + ": empty list of levels");
  if (rhs.find(',') == std::string::npos && rhs.find(':') != std::string::npos) {
    const std::vector<std::string> r = split(rhs, ':');
    if (r.size() != 3) throw InputError(opt + ": a range is lo:hi:n");
    const double lo = parseReal(opt + " (lo)", r[0]), hi = parseReal(opt + " (hi)", r[1]);
    const long long n = parseInt(opt + " (n)", r[2], 2, 100000);
    for (long long i = 0; i < n; ++i)
      f.values.push_back(formatLevel(i == n - 1 ? hi : lo + (hi - lo) * double(i) / double(n - 1)));
  } else {
    f.values = split(rhs, ',');
  }
  std::set<std::string> seen;
  for (const std::string& v : f.values) {
    if (v.empty()) throw InputError(opt + ": empty level in the list");
    if (!seen.insert(v).second) throw InputError(opt + ": level '" + v + "' given twice");
  }
  return f;
}

// --list FILE's text: a header of keys, then one row per setting (plain comma-separated values, no quoting).
inline std::vector<Setting> parseList(const std::string& text, const std::string& origin) {
  std::vector<std::vector<std::string>> lines;
  std::stringstream ss(text);
  for (std::string l; std::getline(ss, l);)
    if (!trimmed(l).empty()) lines.push_back(split(trimmed(l), ','));
  if (lines.empty())
    throw InputError("--list " + origin + ": empty file (expected a header of keys and one row per setting)");
  const std::vector<std::string>& keys = lines[0];
  std::set<std::string> seen;
  for (const std::string& k : keys)
    if (k.empty() || !seen.insert(k).second)
      throw InputError("--list " + origin + ": empty or repeated key '" + k + "' in the header");
  if (lines.size() < 2) throw InputError("--list " + origin + ": empty list (a header and no settings)");
  std::vector<Setting> rows;
  for (size_t r = 1; r < lines.size(); ++r) {
    if (lines[r].size() != keys.size())
      throw InputError("--list " + origin + ": row " + std::to_string(r) + " has " + std::to_string(lines[r].size()) +
                       " values for " + std::to_string(keys.size()) + " keys");
    Setting s;
    for (size_t k = 0; k < keys.size(); ++k) {
      if (lines[r][k].empty())
        throw InputError("--list " + origin + ": row " + std::to_string(r) + ": empty value of " + keys[k]);
      s.emplace_back(keys[k], lines[r][k]);
    }
    rows.push_back(std::move(s));
  }
  return rows;
}

// The full factorial of `rows` (the --list settings; none: one empty setting) and the grid factors, in order:
// the list rows vary slowest, the last factor fastest.
inline std::vector<Setting> expandDesign(const std::vector<Setting>& rows, const std::vector<Factor>& factors) {
  std::vector<Setting> cur = rows.empty() ? std::vector<Setting>{Setting{}} : rows;
  for (const Factor& f : factors) {
    std::vector<Setting> next;
    for (const Setting& s : cur)
      for (const std::string& v : f.values) {
        Setting t = s;
        t.emplace_back(f.key, v);
        next.push_back(std::move(t));
      }
    cur = std::move(next);
  }
  return cur;
}

// "0007-seed2": the setting's index (zero-padded to the width of the largest index, at least 3) and the seed.
inline std::string caseId(size_t setting, size_t settings, long long seed) {
  int width = 3;
  for (size_t m = settings > 0 ? settings - 1 : 0; m >= 1000; m /= 10) ++width;
  char b[64];
  std::snprintf(b, sizeof b, "%0*zu-seed%lld", width, setting, seed);
  return b;
}

// Every number under `j` (nested objects and arrays), named by its dotted path below `prefix`.
inline void flattenNumbers(const nlohmann::json& j, const std::string& prefix, std::map<std::string, double>& out) {
  if (j.is_number()) {
    out[prefix] = j.get<double>();
  } else if (j.is_object()) {
    for (auto it = j.begin(); it != j.end(); ++it)
      flattenNumbers(*it, prefix.empty() ? it.key() : prefix + "." + it.key(), out);
  } else if (j.is_array()) {
    for (size_t i = 0; i < j.size(); ++i)
      flattenNumbers(j[i], prefix.empty() ? std::to_string(i) : prefix + "." + std::to_string(i), out);
  }
}

// A run's metrics: summary["ces"]["metrics"] (name -> number) when present, else every number under
// summary["ces"], else (a plain scene) every number of the summary.
inline std::map<std::string, double> runMetrics(const nlohmann::json& summary) {
  std::map<std::string, double> m;
  if (summary.contains("ces") && summary["ces"].is_object()) {
    const nlohmann::json& c = summary["ces"];
    flattenNumbers(c.contains("metrics") && c["metrics"].is_object() ? c["metrics"] : c, "", m);
  } else {
    flattenNumbers(summary, "", m);
  }
  return m;
}

// P(|T| < t) for Student's t with nu degrees of freedom, by the finite series for integer nu of
// Abramowitz & Stegun, Handbook of Mathematical Functions (1964), 26.7.3 (nu odd) and 26.7.4 (nu even).
inline double studentA(double t, int nu) {
  const double th = std::atan(t / std::sqrt(double(nu))), c2 = std::cos(th) * std::cos(th), s = std::sin(th);
  double sum = 0, term = 1;
  if (nu % 2 == 0) {
    for (int k = 2; k <= nu; k += 2) {  // 1 + 1/2 c^2 + (1*3)/(2*4) c^4 + ... up to c^(nu-2)
      sum += term;
      term *= c2 * double(k - 1) / double(k);
    }
    return s * sum;
  }
  if (nu == 1) return 2 / M_PI * th;
  for (int k = 3; k <= nu; k += 2) {  // cos + 2/3 cos^3 + (2*4)/(3*5) cos^5 + ... up to cos^(nu-2)
    sum += term;
    term *= c2 * double(k - 1) / double(k);
  }
  return 2 / M_PI * (th + s * std::sqrt(c2) * sum);
}

// t_{0.975, nu}: the two-sided 95% quantile, P(|T_nu| < t) = 0.95, by bisection on studentA.
inline double tQuantile975(int nu) {
  double lo = 0, hi = 1000;  // t_{0.975,1} = 12.706
  for (int i = 0; i < 200 && hi - lo > 1e-13 * hi; ++i) {
    const double mid = 0.5 * (lo + hi);
    (studentA(mid, nu) < 0.95 ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

struct MeanCi {
  size_t n = 0;
  double mean = NAN;
  double half = NAN;  // 95% confidence half-width; NaN for n < 2
};

// Mean and the Student-t 95% confidence half-width t_{0.975,n-1} s / sqrt(n), s the sample standard deviation
// (divisor n-1): Montgomery & Runger, Applied Statistics and Probability for Engineers, 6th ed. (2014), sec. 8-2
// (confidence interval on the mean of a normal distribution, variance unknown).
inline MeanCi meanCi(const std::vector<double>& x) {
  MeanCi r;
  r.n = x.size();
  if (x.empty()) return r;
  double sum = 0;
  for (double v : x) sum += v;
  r.mean = sum / double(x.size());
  if (x.size() < 2) return r;
  double ss = 0;
  for (double v : x) ss += (v - r.mean) * (v - r.mean);
  const double sd = std::sqrt(ss / double(x.size() - 1));
  r.half = tQuantile975(int(x.size() - 1)) * sd / std::sqrt(double(x.size()));
  return r;
}

// A setting against the baseline with common random numbers: replicate seed s runs every setting from the same
// random input (the same feed, the same generated bodies), so the difference of a metric taken seed by seed has a
// much smaller spread than either value, and its confidence interval resolves effects the per-setting intervals do
// not (paired comparison; Law, Simulation Modeling and Analysis, 5th ed. (2015), sec. 11.2 "common random numbers";
// Montgomery & Runger, sec. 10-4, the paired t-test). `base` and `other` map seed -> value; seeds present in both.
inline MeanCi pairedDifference(const std::map<int, double>& base, const std::map<int, double>& other) {
  std::vector<double> d;
  for (const auto& kv : other) {
    auto it = base.find(kv.first);
    if (it != base.end()) d.push_back(kv.second - it->second);
  }
  return meanCi(d);
}

}  // namespace dvi::sweep
