// libFuzzer target: a folder of DICOM files through series assembly (grouping, sorting along
// the normal, duplicates, gaps, tilt, frames), as `voxelastic convert FOLDER/` reads it. The
// input is the files one after another, separated by kSeparator (docs/robustness.md).
#include <cstring>

#include "fuzz_support.h"
#include "io/dicom_series.h"

namespace {
constexpr char kSeparator[] = "\n--voxelastic-fuzz-file--\n";
constexpr std::size_t kMaxFiles = 16;
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::filesystem::path dir = vx::fuzz::scratch() / "series";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const std::size_t sep = std::strlen(kSeparator);
  std::size_t start = 0, files = 0;
  while (files < kMaxFiles) {
    const auto* end = static_cast<const std::uint8_t*>(
        size - start >= sep ? ::memmem(data + start, size - start, kSeparator, sep) : nullptr);
    const std::size_t stop = end ? std::size_t(end - data) : size;
    vx::fuzz::write_file(dir / ("f" + std::to_string(files++) + ".dcm"), data + start, stop - start);
    if (!end) break;
    start = stop + sep;
  }
  vx::ReadOptions options;
  options.max_volume_bytes = vx::fuzz::kMaxVolumeBytes;
  options.any_modality = true;
  return vx::fuzz::run([&] { (void)vx::read_dicom_series({dir}, options); });
}
