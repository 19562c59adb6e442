// Fuzz target: a JSON scene as text -> dvi::Scene::fromJsonText (scene.cpp), then the scene imports into a
// System (fuzz_support.h). Seeds: corpus/scene_json/ (the repository's scenes/*.json).
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  fuzz::init();
  const std::string text(reinterpret_cast<const char*>(data), size);
  return fuzz::run("fuzz_scene_json", [&] {
    const dvi::Scene scene = dvi::Scene::fromJsonText(text, "fuzz.json");
    fuzz::checkScene("fuzz_scene_json", scene);
  });
}
