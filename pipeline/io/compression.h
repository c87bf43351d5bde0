#pragma once
/// @file compression.h
/// Private to pipeline/io: zlib (deflate) compression of voxel data, for the MetaImage (zlib
/// stream) and NRRD (gzip) readers and writers. Decompression checks every size: damaged or
/// cut-short data is an error naming the file, never zeros.

#include <cstddef>
#include <filesystem>
#include <vector>

namespace vx {

/// zlib-compresses `size` bytes at `data`: a zlib stream, or gzip when `gzip` (MetaImage
/// writes zlib, NRRD gzip). Throws vx::Error when zlib fails.
[[nodiscard]] std::vector<unsigned char> deflate_bytes(const void* data, std::size_t size, bool gzip);

/// Inflates a zlib or gzip stream of `size` bytes that must give exactly `expected` bytes.
/// Throws vx::Error naming `path` when the header promises more than the data can hold, or the
/// stream is damaged or cut short.
[[nodiscard]] std::vector<char> inflate_bytes(const char* data, std::size_t size, std::size_t expected,
                                              const std::filesystem::path& path);

}  // namespace vx
