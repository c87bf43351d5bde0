// Raw voxel bytes to float HU: every scalar type NRRD and MetaImage files store, in either byte
// order (the files' voxels are copied value by value, so no alignment is assumed).
#include "io/volume_formats.h"

#include <algorithm>
#include <cstdint>
#include <cstring>

namespace vx::volume_formats {

int scalar_bytes(ScalarType t) {
  switch (t) {
    case ScalarType::i8: case ScalarType::u8: return 1;
    case ScalarType::i16: case ScalarType::u16: return 2;
    case ScalarType::i32: case ScalarType::u32: case ScalarType::f32: return 4;
    case ScalarType::i64: case ScalarType::u64: case ScalarType::f64: return 8;
  }
  return 0;
}

namespace {

/// `n` values of type T at `bytes`, each byte-reversed when `swap`, as float.
template <typename T>
void convert_raw(const char* bytes, std::size_t n, bool swap, std::vector<float>& out) {
  out.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    unsigned char b[sizeof(T)];
    std::memcpy(b, bytes + i * sizeof(T), sizeof(T));
    if (swap) std::reverse(b, b + sizeof(T));
    T value;
    std::memcpy(&value, b, sizeof(T));
    out[i] = float(value);
  }
}

}  // namespace

std::vector<float> raw_to_float(const char* bytes, std::size_t n, ScalarType t, bool swap) {
  std::vector<float> out;
  switch (t) {
    case ScalarType::i8: convert_raw<std::int8_t>(bytes, n, swap, out); break;
    case ScalarType::u8: convert_raw<std::uint8_t>(bytes, n, swap, out); break;
    case ScalarType::i16: convert_raw<std::int16_t>(bytes, n, swap, out); break;
    case ScalarType::u16: convert_raw<std::uint16_t>(bytes, n, swap, out); break;
    case ScalarType::i32: convert_raw<std::int32_t>(bytes, n, swap, out); break;
    case ScalarType::u32: convert_raw<std::uint32_t>(bytes, n, swap, out); break;
    case ScalarType::i64: convert_raw<std::int64_t>(bytes, n, swap, out); break;
    case ScalarType::u64: convert_raw<std::uint64_t>(bytes, n, swap, out); break;
    case ScalarType::f32: convert_raw<float>(bytes, n, swap, out); break;
    case ScalarType::f64: convert_raw<double>(bytes, n, swap, out); break;
  }
  return out;
}

}  // namespace vx::volume_formats
