// Limits on what the loaders accept (JSON scenes, CES documents and checkpoints, .bullet files) and the
// checks that enforce them, shared by scene.cpp, src/ces/ and the CLI. Every refusal is one InputError
// line naming the file or key and the limit (exit code 2 in the CLI); docs/HARDENING.md lists them.
//
// Header-only on purpose: the loaders of several folders include it and it adds no source file to the
// library's build lists.
#pragma once

#include <fcntl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "chrono_like/base/errors.h"

namespace dvi {

struct InputLimits {
  uint64_t max_json_bytes = uint64_t(256) << 20;  // a JSON scene or CES document
  uint64_t max_binary_bytes = uint64_t(1) << 30;  // a .bullet file or a CES checkpoint
  int max_json_depth = 64;                        // nesting of arrays and objects in a JSON document
  int max_compound_depth = 8;                     // compound shapes inside compound shapes
  int64_t max_bodies = int64_t(1) << 26;          // bodies of one scene (the schema's largest pile)
  int64_t max_steps = int64_t(1) << 40;           // steps of one run (the --steps limit)
  // Memory a scene body takes once built (its Bullet body, shape and motion state, the engine's arrays and
  // the outputs): 1.8-1.9 KB measured with 100,000 spheres or boxes (peak RSS of `dvisim run`).
  double bytes_per_body = 2048;
};

// The process's limits. The fuzz targets lower them (tests/fuzz/fuzz_support.h); nothing else changes them.
inline InputLimits& inputLimits() {
  static InputLimits limits;
  return limits;
}

namespace inputcheck {

inline std::string number(double x) {
  char b[32];
  std::snprintf(b, sizeof b, "%.10g", x);
  return b;
}

// What a path names, for "is not a regular file" (a FIFO would block a read forever, a device never ends).
inline const char* fileKind(mode_t m) {
  if (S_ISFIFO(m)) return "a FIFO";
  if (S_ISCHR(m)) return "a character device";
  if (S_ISBLK(m)) return "a block device";
  if (S_ISSOCK(m)) return "a socket";
  if (S_ISDIR(m)) return "a directory";
  return "not a regular file";
}

}  // namespace inputcheck

// Reads a whole regular file of at most max_bytes. `what` starts every error ("scene.json", "--resume DIR:
// checkpoint/state.bin"). Refuses FIFOs, devices and sockets by name before opening them, and opens without
// blocking, so a path that turns into a FIFO in between cannot hang the read either.
inline std::string readRegularFile(const std::string& path, const std::string& what, uint64_t max_bytes,
                                   const char* directory_note = "") {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    if (errno == ENOENT || errno == ENOTDIR) throw InputError(what + ": no such file");
    throw InputError(what + ": cannot open (" + std::strerror(errno) + ")");
  }
  if (S_ISDIR(st.st_mode)) throw InputError(what + ": is a directory" + directory_note);
  if (!S_ISREG(st.st_mode))
    throw InputError(what + ": is " + inputcheck::fileKind(st.st_mode) +
                     ", not a regular file (refused: reading it may never end)");
  auto tooLarge = [&](uint64_t size) {
    return InputError(what + ": is " + std::to_string(size) + " bytes, more than the limit of " +
                      std::to_string(max_bytes) + " bytes");
  };
  if (uint64_t(st.st_size) > max_bytes) throw tooLarge(uint64_t(st.st_size));
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd < 0) throw InputError(what + ": cannot open (" + std::strerror(errno) + ")");
  struct FdCloser {
    int fd;
    ~FdCloser() { ::close(fd); }
  } closer{fd};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode))
    throw InputError(what + ": is " + inputcheck::fileKind(st.st_mode) +
                     ", not a regular file (refused: reading it may never end)");
  std::string out;
  out.reserve(size_t(st.st_size));
  char buf[1 << 16];
  for (;;) {
    const ssize_t n = ::read(fd, buf, sizeof buf);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw InputError(what + ": read error (" + std::strerror(errno) + ")");
    if (n == 0) break;
    out.append(buf, size_t(n));
    if (out.size() > max_bytes) throw tooLarge(out.size());  // it grew while we read it
  }
  return out;
}

// Steps of a run of `time` seconds at `dt`: round(time / dt), refused (with the number) when it does not fit
// the step limit (time 1e30 s, dt 1e-300 s would overflow the counter and never end).
inline int64_t checkedStepCount(double time, double dt, const std::string& what) {
  const double n = std::round(time / dt);
  const int64_t limit = inputLimits().max_steps;
  if (!(n >= 0 && n <= double(limit)))
    throw InputError(what + ": " + inputcheck::number(time) + " s at a time step of " + inputcheck::number(dt) +
                     " s is " + inputcheck::number(n) + " steps, more than the limit of " + std::to_string(limit));
  return int64_t(n);
}

// A run's frame count: at most one frame a step, the start included (steps + 1); each frame is a file (a file a
// process under MPI), so a million frames of a 50-step run would be a million files of 51 distinct states. Refused
// with both numbers before anything is written.
inline void checkFrameCount(int64_t frames, int64_t steps, const std::string& what) {
  if (frames <= steps + 1) return;
  throw InputError(what + ": " + std::to_string(frames) + " frames for a run of " + std::to_string(steps) +
                   " steps; at most " + std::to_string(steps + 1) + " (one a step, from step 0)");
}

// Bytes this process can still use: the smallest of the physical memory, the address-space and data limits
// (ulimit -v / -d) and the cgroup's memory.max.
inline double availableMemoryBytes() {
  double have = double(::sysconf(_SC_PHYS_PAGES)) * double(::sysconf(_SC_PAGESIZE));
  if (!(have > 0)) have = std::numeric_limits<double>::infinity();
  for (int resource : {RLIMIT_AS, RLIMIT_DATA}) {
    struct rlimit rl {};
    if (::getrlimit(resource, &rl) == 0 && rl.rlim_cur != RLIM_INFINITY) have = std::fmin(have, double(rl.rlim_cur));
  }
  std::ifstream cg("/sys/fs/cgroup/memory.max");
  double cg_max = 0;
  if (cg >> cg_max && cg_max > 0) have = std::fmin(have, cg_max);
  return have;
}

// A scene of `bodies` bodies: within the body limit and, at bytes_per_body, within the memory this process
// can use. Checked before anything is built: Bullet's allocator returns null when memory runs out and its
// constructors then write through it.
inline void checkBodyBudget(int64_t bodies, const std::string& what) {
  const InputLimits& l = inputLimits();
  if (bodies > l.max_bodies)
    throw InputError(what + ": " + std::to_string(bodies) + " bodies, more than the limit of " +
                     std::to_string(l.max_bodies));
  const double need = double(bodies) * l.bytes_per_body, have = availableMemoryBytes();
  if (need > have)
    throw InputError(what + ": " + std::to_string(bodies) + " bodies need about " + inputcheck::number(need / 1e9) +
                     " GB of memory, more than the " + inputcheck::number(have / 1e9) + " GB this process may use");
}

// A JSON document nested at most `max_depth` arrays/objects deep (the root is level 1). nlohmann's parser is
// iterative, but copying, comparing and printing a document recurse once per level: a document nested
// 100,000 deep overflows the stack in any of them. This walk recurses at most max_depth levels.
namespace inputcheck {
inline std::string shortPath(const std::string& p) {
  return p.size() <= 120 ? p : p.substr(0, 80) + "..." + p.substr(p.size() - 37);
}
inline void depthWalk(const nlohmann::json& v, int depth, int max_depth, std::string& path, const std::string& origin) {
  if (!v.is_structured()) return;
  if (depth > max_depth)
    throw InputError(origin + ": " + shortPath(path.empty() ? "(document)" : path) + ": nested deeper than " +
                     std::to_string(max_depth) + " levels of arrays and objects (the limit)");
  const size_t keep = path.size();
  if (v.is_array()) {
    for (size_t i = 0; i < v.size(); ++i) {
      path += "[" + std::to_string(i) + "]";
      depthWalk(v[i], depth + 1, max_depth, path, origin);
      path.resize(keep);
    }
  } else {
    for (auto it = v.begin(); it != v.end(); ++it) {
      const std::string& k = it.key();
      path += (path.empty() ? "" : ".") + (k.size() <= 40 ? k : k.substr(0, 37) + "...");
      depthWalk(*it, depth + 1, max_depth, path, origin);
      path.resize(keep);
    }
  }
}
}  // namespace inputcheck

inline void checkJsonDepth(const nlohmann::json& doc, const std::string& origin,
                           int max_depth = inputLimits().max_json_depth) {
  std::string path;
  inputcheck::depthWalk(doc, 1, max_depth, path, origin);
}

namespace inputcheck {

// nlohmann's own DOM builder (what json::parse uses) behind a depth gate: the parser reports each value as it reads
// it (the SAX interface), and the gate refuses the first array or object that would open a level beyond max_depth
// before it is built, with the key path of that value. So no DOM deeper than the limit ever exists: copying,
// comparing or printing a document cannot recurse further than max_depth levels. The path keeps one entry a level
// (at most max_depth of them), its keys cut to 40 characters.
class DepthGateSax {
 public:
  using json = nlohmann::json;
  DepthGateSax(json& root, int max_depth, const std::string& origin)
      : dom_(root, true), max_depth_(max_depth), origin_(origin) {}
  bool null() { return value() && dom_.null(); }
  bool boolean(bool v) { return value() && dom_.boolean(v); }
  bool number_integer(json::number_integer_t v) { return value() && dom_.number_integer(v); }
  bool number_unsigned(json::number_unsigned_t v) { return value() && dom_.number_unsigned(v); }
  bool number_float(json::number_float_t v, const json::string_t& s) { return value() && dom_.number_float(v, s); }
  bool string(json::string_t& v) { return value() && dom_.string(v); }
  bool binary(json::binary_t& v) { return value() && dom_.binary(v); }
  bool start_object(std::size_t n) { return open(false) && dom_.start_object(n); }
  bool key(json::string_t& k) {
    levels_.back().key = k.size() <= 40 ? k : k.substr(0, 37) + "...";
    return dom_.key(k);
  }
  bool end_object() {
    levels_.pop_back();
    return dom_.end_object();
  }
  bool start_array(std::size_t n) { return open(true) && dom_.start_array(n); }
  bool end_array() {
    levels_.pop_back();
    return dom_.end_array();
  }
  template <class Exception>
  bool parse_error(std::size_t position, const std::string& token, const Exception& e) {
    return dom_.parse_error(position, token, e);
  }

 private:
  struct Level {
    bool array;
    int64_t index;    // the element being read (arrays)
    std::string key;  // the member being read (objects)
  };
  bool value() {
    if (!levels_.empty() && levels_.back().array) ++levels_.back().index;
    return true;
  }
  // A new array or object, at level levels_.size() + 1 (the root is level 1).
  bool open(bool array) {
    value();
    if (int(levels_.size()) >= max_depth_) {
      std::string path;
      for (const Level& l : levels_)
        path += l.array ? "[" + std::to_string(l.index) + "]" : (path.empty() ? "" : ".") + l.key;
      throw InputError(origin_ + ": " + shortPath(path.empty() ? "(document)" : path) + ": nested deeper than " +
                       std::to_string(max_depth_) + " levels of arrays and objects (the limit)");
    }
    levels_.push_back(Level{array, -1, {}});
    return true;
  }

  nlohmann::detail::json_sax_dom_parser<json> dom_;
  int max_depth_;
  const std::string& origin_;
  std::vector<Level> levels_;
};

}  // namespace inputcheck

// JSON text into a DOM, every limit checked before the DOM is built: the size first, the nesting while the parser
// reads (DepthGateSax: nothing deeper than max_depth is built). Malformed text throws nlohmann's parse_error; a
// limit, InputError "<origin>: ..." naming it. The one way every JSON input of the program is parsed (scenes, CES
// documents, --set values, checkpoint manifests and records, a sweep's own files).
inline nlohmann::json parseJsonGated(const std::string& text, const std::string& origin,
                                     int max_depth = inputLimits().max_json_depth,
                                     uint64_t max_bytes = inputLimits().max_json_bytes) {
  if (text.size() > max_bytes)
    throw InputError(origin + ": the document is " + std::to_string(text.size()) + " bytes, more than the limit of " +
                     std::to_string(max_bytes) + " bytes");
  nlohmann::json doc;
  inputcheck::DepthGateSax sax(doc, max_depth, origin);
  nlohmann::json::sax_parse(text, &sax);
  return doc;
}

// parseJsonGated with malformed text as InputError "<origin>: malformed JSON: <what the parser says>".
inline nlohmann::json parseJsonChecked(const std::string& text, const std::string& origin,
                                       int max_depth = inputLimits().max_json_depth,
                                       uint64_t max_bytes = inputLimits().max_json_bytes) {
  try {
    return parseJsonGated(text, origin, max_depth, max_bytes);
  } catch (const nlohmann::json::exception& e) {
    std::string what = e.what();
    const size_t p = what.find("] ");
    if (p != std::string::npos) what = what.substr(p + 2);
    if (what.find("overflow") != std::string::npos) what += " (non-finite numbers are not allowed)";
    throw InputError(origin + ": malformed JSON: " + what);
  }
}

}  // namespace dvi
