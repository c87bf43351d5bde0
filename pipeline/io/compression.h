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
/// writes zlib, NRRD gzip). Any size: zlib's 32-bit counters are fed `chunk` bytes at a time
/// (at most 1 GiB; smaller only to test the chunking). Throws vx::Error when zlib fails or
/// consumes less than all of the input.
[[nodiscard]] std::vector<unsigned char> deflate_bytes(const void* data, std::size_t size, bool gzip,
                                                       std::size_t chunk = std::size_t(1) << 30);

/// Inflates a zlib or gzip stream of `size` bytes that must give exactly `expected` bytes.
/// Throws vx::Error naming `path` when the header promises more than the data can hold, or the
/// stream is damaged or cut short.
[[nodiscard]] std::vector<char> inflate_bytes(const char* data, std::size_t size, std::size_t expected,
                                              const std::filesystem::path& path,
                                              std::size_t chunk = std::size_t(1) << 30);

}  // namespace vx
