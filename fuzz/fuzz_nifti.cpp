// libFuzzer target: one NIfTI file through read_volume() (docs/robustness.md). The first byte
// picks the form: odd, the rest is gzip-compressed here and read as .nii.gz (so the fuzzer
// mutates the header, not the deflate bits); even, the rest is a .nii.
#include "fuzz_support.h"
#include "io/compression.h"
#include "io/volume_io.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const bool gz = data[0] & 1;
  const std::filesystem::path file = vx::fuzz::scratch() / (gz ? "input.nii.gz" : "input.nii");
  if (gz) {
    const auto packed = vx::deflate_bytes(data + 1, size - 1, /*gzip=*/true);
    vx::fuzz::write_file(file, packed.data(), packed.size());
  } else {
    vx::fuzz::write_file(file, data + 1, size - 1);
  }
  return vx::fuzz::run([&] { (void)vx::read_volume(file); });
}
