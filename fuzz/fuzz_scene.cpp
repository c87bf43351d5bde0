// libFuzzer target: scene JSON through parse_scene(), the strict reader with JSON paths in
// its messages (docs/robustness.md). Paths resolve against an empty folder.
#include <string>

#include "fuzz_support.h"
#include "scene/scene.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  return vx::fuzz::run([&] { (void)vx::parse_scene(text, vx::fuzz::scratch(), "fuzz.json"); });
}
