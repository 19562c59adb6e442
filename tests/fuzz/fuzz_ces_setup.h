// The CES machine the checkpoint fuzz target restores into, and make_seeds.cpp writes its seed from: the default
// machine with the two-cylinder field (the tube alone, an exact formula: no corona grid and no charge-simulation
// solve, whose dense LU took seconds per input under the fuzzing instrumentation, so a fresh machine per input
// is cheap), a feed of 20 g/s from t = 0 (particles of every shape within a few steps) and one thread.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "ces/ces_config.h"
#include "ces_run.h"
#include "ces/machine.h"

namespace fuzz {

inline const dvi::ces::CesConfig& checkpointConfig() {
  static const dvi::ces::CesConfig cfg =
      dvi::ces::parseCesDocument(nlohmann::json::parse(dvi::ces::defaultCesJson()),
                                 {"field.model=\"two_cylinder\"", "electrode.wire.enabled=false",
                                  "feed.mass_flow_g_s=20", "feed.start_s=0", "duration_s=0.01"},
                                 "<fuzz ces machine>");
  return cfg;
}

struct CesRig {
  std::unique_ptr<dvi::System> system = dvi::ces::makeCesSystem(checkpointConfig(), "cpu", 1, "native");
  dvi::ces::CesMachine machine{checkpointConfig(), *system};
};

}  // namespace fuzz
