// Shared by the fuzz targets (tests/fuzz/fuzz_*.cpp): the outcome policy and the limits they run under.
//
// Policy: dvi::InputError is the expected outcome for bad input. Any other exception escaping, a crash, a
// sanitizer report or a hang is a finding: the target prints what escaped and aborts, which libFuzzer reports
// as a crash (and the replay executables as a failed CTest).
//
// Oracle: an input the loader accepts must be usable. A scene must import into a System (System::addBody
// checks every body) without any exception: the loader, not the engine, is where bad input is refused.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>
#include <typeinfo>

#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/base/errors.h"
#include "chrono_like/io/input_limits.h"
#include "chrono_like/io/scene.h"
#include "chrono_like/system.h"

namespace fuzz {

// Smaller limits than a user gets, so that each input runs in milliseconds and within libFuzzer's 2 GB
// (the limits themselves are what is tested: every refusal is an InputError either way).
inline void init() {
  static const bool done = [] {
    dvi::InputLimits& l = dvi::inputLimits();
    l.max_bodies = 2000;
    l.max_json_bytes = l.max_binary_bytes = uint64_t(1) << 20;
    return true;
  }();
  (void)done;
}

[[noreturn]] inline void finding(const char* target, const std::string& what) {
  std::fprintf(stderr, "\n%s: FINDING: %s\n", target, what.c_str());
  std::fflush(stderr);
  std::abort();
}

// Runs f(); InputError is fine, anything else escaping is a finding.
template <class F>
int run(const char* target, F&& f) {
  try {
    f();
  } catch (const dvi::InputError& e) {
    if (std::getenv("DVISIM_FUZZ_VERBOSE")) std::fprintf(stderr, "%s: InputError: %s\n", target, e.what());
  } catch (const std::exception& e) {
    finding(target, std::string("exception ") + typeid(e).name() + " escaped: " + e.what());
  } catch (...) { finding(target, "an exception of unknown type escaped"); }
  return 0;
}

// The oracle for a loaded scene: a step count, and every body imports into a System.
inline void checkScene(const char* target, const dvi::Scene& scene) {
  (void)scene.settings.stepCount();  // may refuse (InputError), must not overflow
  dvi::SystemConfig cfg = scene.settings.system;
  cfg.threads = 1;
  dvi::System system(cfg);
  try {
    const std::vector<int> ids = dvi::importBullet(system, scene.bodies());
    if (ids.size() != scene.bodyCount()) finding(target, "importBullet returned a different body count");
  } catch (const std::exception& e) { finding(target, std::string("a loaded scene does not import: ") + e.what()); }
}

// The whole of a scene target: init, then load(the input as a string) -> a Scene, checked by checkScene, under run.
template <class Load>
int runSceneTarget(const char* target, const uint8_t* data, size_t size, Load load) {
  init();
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  return run(target, [&] { checkScene(target, load(bytes)); });
}

}  // namespace fuzz
