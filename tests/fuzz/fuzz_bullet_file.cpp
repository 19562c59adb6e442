// Fuzz target: the bytes of a .bullet file -> dvi::Scene::fromBulletBuffer (the checks of bullet_file_check.h,
// then Bullet's parser and importer on the checked copy, then ours), then the scene imports into a System.
// Seeds: corpus/bullet_file/ (files written by Bullet's serializer: make_seeds.cpp).
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  return fuzz::runSceneTarget("fuzz_bullet_file", data, size, [](const std::string& bytes) {
    return dvi::Scene::fromBulletBuffer(bytes, "fuzz.bullet");
  });
}
