// Fuzz target: a CES machine document as JSON text -> dvi::ces::parseCesDocument (ces_config.cpp), the way
// `dvisim run` reads one (malformed JSON is an InputError there too). Lines at the start of the form
// "#set KEY=VALUE" are passed as --set overrides. Seeds: corpus/ces_config/ (scenes/ces_default.json and
// variants).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "ces/ces_config.h"
#include "chrono_like/io/input_limits.h"
#include "fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  fuzz::init();
  std::string text(reinterpret_cast<const char*>(data), size);
  std::vector<std::string> sets;
  while (text.rfind("#set ", 0) == 0) {
    const size_t nl = text.find('\n');
    sets.push_back(text.substr(5, nl == std::string::npos ? std::string::npos : nl - 5));
    text = nl == std::string::npos ? std::string() : text.substr(nl + 1);
  }
  return fuzz::run("fuzz_ces_config", [&] {
    nlohmann::json doc;
    try {  // as the CLI parses it: the size and nesting limits before the DOM is built (an InputError)
      doc = dvi::parseJsonGated(text, "fuzz.json");
    } catch (const nlohmann::json::exception&) {
      return;  // the CLI reports "malformed JSON" (an InputError)
    }
    const dvi::ces::CesConfig cfg = dvi::ces::parseCesDocument(doc, sets, "fuzz.json");
    // what the machine relies on
    if (!(cfg.step.dt > 0 && std::isfinite(cfg.duration) && cfg.duration >= 0 && !cfg.materials.empty()))
      fuzz::finding("fuzz_ces_config", "an accepted configuration without a positive time step or a material");
    (void)dvi::checkedStepCount(cfg.duration, cfg.step.dt, "fuzz");
  });
}
