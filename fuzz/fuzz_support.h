#pragma once
// What every fuzz target shares: the input written to a file of the right name in a private
// scratch folder (the readers take paths), the run with the expected outcome (a result, or a
// vx::Error: a clear message), and any other exception or a crash turned into a finding.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>

#include "base/error.h"
#include "util/log.h"

namespace vx::fuzz {

/// The scratch folder of this fuzzing process (in /dev/shm when there is one: no disk wear).
inline const std::filesystem::path& scratch() {
  static const std::filesystem::path dir = [] {
    const std::filesystem::path root = std::filesystem::exists("/dev/shm") ? "/dev/shm" : "/tmp";
    std::filesystem::path d = root / ("voxelastic-fuzz-" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    vx::log::set_level(vx::log::Level::error);  // warnings of damaged files are the normal case here
    return d;
  }();
  return dir;
}

/// The largest volume a reader may allocate under fuzzing: a quarter of the 1 GiB malloc limit
/// scripts/fuzz.sh gives libFuzzer, so a declared size that the reader accepts (compressed DICOM
/// pixel data can declare any image size in a few bytes) is never reported as out-of-memory.
inline constexpr std::uint64_t kMaxVolumeBytes = std::uint64_t(256) << 20;

/// Writes `size` bytes to `path`.
inline void write_file(const std::filesystem::path& path, const std::uint8_t* data, std::size_t size) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), std::streamsize(size));
}

/// Runs `f`: returning or throwing vx::Error (bad input, clearly said) is fine; any other
/// exception is an internal error, reported and aborted on so libFuzzer keeps the input.
template <class F>
int run(F&& f) {
  try {
    f();
  } catch (const vx::Error&) {
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fuzz: internal error (not a vx::Error): %s\n", e.what());
    std::abort();
  }
  return 0;
}

}  // namespace vx::fuzz
