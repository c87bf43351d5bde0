// libFuzzer target: one DICOM file, header and pixels (every transfer syntax the reader
// decodes), as `voxelastic convert FILE.dcm` reads it (docs/robustness.md).
#include "fuzz_support.h"
#include "io/dicom_series.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::filesystem::path dir = vx::fuzz::scratch() / "one";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const std::filesystem::path file = dir / "input.dcm";
  vx::fuzz::write_file(file, data, size);
  vx::ReadOptions options;
  options.max_volume_bytes = vx::fuzz::kMaxVolumeBytes;
  options.any_modality = true;  // go as far as the file lets us
  return vx::fuzz::run([&] { (void)vx::read_dicom_series({file}, options); });
}
