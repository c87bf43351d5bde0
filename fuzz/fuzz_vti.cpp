// libFuzzer target: one .vti file through read_volume() (docs/robustness.md).
#include "fuzz_support.h"
#include "io/volume_io.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::filesystem::path file = vx::fuzz::scratch() / "input.vti";
  vx::fuzz::write_file(file, data, size);
  return vx::fuzz::run([&] { (void)vx::read_volume(file); });
}
