#pragma once
/// @file cache_file.h
/// What the caches of one folder share (the factor cache, factor_cache.h, and the calibration
/// cache, calibration_cache.h, keep their files side by side in it): a file mapped for reading,
/// the folder's size limit over all its cache files (the least recently used go first). The
/// files' binary form with its checksum (CacheFileWriter, CacheFileReader) is the core's,
/// base/cache_file_format.h, which the factor's own file form uses too.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>

#include "base/cache_file_format.h"

namespace vx {

/// The extensions of the files a cache folder holds (".vxfactor", ".vxorder", ".vxcalib", ".vxsurf", ".vxregion"): the
/// size limit counts them all, and nothing else in the folder.
[[nodiscard]] bool is_cache_file(const std::filesystem::path& file);

/// `file` (`size` bytes) mapped read-only and private, its pages brought in at once (from the
/// page cache, without a copy); null with `why` on failure. The mapping lives as long as the
/// pointer.
[[nodiscard]] std::shared_ptr<const void> map_cache_file(const std::filesystem::path& file, std::size_t size,
                                                         std::string& why);

/// Removes the least recently used cache files of `folder` (by modification time: a load
/// touches its file) until they hold at most `max_bytes` together; never `keep` (the file just
/// written). Returns the number removed.
int evict_cache_files(const std::filesystem::path& folder, std::uint64_t max_bytes, const std::filesystem::path& keep);

/// Marks `file` as just used (its modification time: the eviction above keeps it longest).
void touch_cache_file(const std::filesystem::path& file);

/// The seconds below which computed work is not kept (`fallback` unless
/// $VOXELASTIC_FACTOR_CACHE_MIN_S holds a number >= 0; another value is warned about once).
[[nodiscard]] double cache_min_seconds(double fallback);

}  // namespace vx
