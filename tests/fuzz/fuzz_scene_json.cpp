// Fuzz target: a JSON scene as text -> dvi::Scene::fromJsonText (scene.cpp), then the scene imports into a
// System (fuzz_support.h). Seeds: corpus/scene_json/ (the repository's scenes/*.json).
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  return fuzz::runSceneTarget("fuzz_scene_json", data, size,
                              [](const std::string& bytes) { return dvi::Scene::fromJsonText(bytes, "fuzz.json"); });
}
