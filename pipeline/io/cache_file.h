#pragma once
/// @file cache_file.h
/// What the caches of one folder share (the factor cache, factor_cache.h, and the calibration
/// cache, calibration_cache.h, keep their files side by side in it): a file mapped for reading,
/// the folder's size limit over all its cache files (the least recently used go first), and the
/// binary form of arrays with a checksum (CacheFileWriter, CacheFileReader: a header, each array
/// at a 64-byte boundary, the hash of all that precedes last; native byte order, read back on
/// the machine that wrote it).

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <memory>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include "base/content_hash.h"
#include "base/huge_pages.h"

namespace vx {

/// The extensions of the files a cache folder holds (".vxfactor", ".vxcalib", ".vxsurf"): the size limit
/// counts them all, and nothing else in the folder.
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

/// Writes values and arrays, each array at a multiple of kCacheAlign bytes from the start, and
/// feeds everything to the checksum. Throws vx::Error when the stream fails (finish()).
class CacheFileWriter {
 public:
  static constexpr std::size_t kCacheAlign = 64;
  explicit CacheFileWriter(std::ostream& out) : out_(out) {}
  void bytes(const void* p, std::size_t n);
  template <typename T>
  void value(const T& v) {
    bytes(&v, sizeof v);
  }
  /// The count, zeros up to the next boundary, the values.
  void array(const void* data, std::size_t count, std::size_t item_bytes);
  template <typename T>
  void array(const std::vector<T>& v) {
    array(v.data(), v.size(), sizeof(T));
  }
  /// The checksum (not hashed itself); throws vx::Error when the stream failed.
  void finish();
  /// Bytes written so far.
  [[nodiscard]] std::size_t size() const { return at_; }

 private:
  std::ostream& out_;
  ContentHash hash_;
  std::size_t at_{0};
};

/// Reads what CacheFileWriter wrote, from memory; the first failure sticks (error()).
class CacheFileReader {
 public:
  CacheFileReader(const unsigned char* data, std::size_t size) : data_(data), size_(size) {}
  /// The next n bytes (null on failure).
  const unsigned char* bytes(std::size_t n, const char* what);
  template <typename T>
  bool value(T& v, const char* what) {
    const unsigned char* p = bytes(sizeof v, what);
    if (p) std::memcpy(&v, p, sizeof v);
    return p != nullptr;
  }
  /// An array's values in place (aligned for an item of `item_bytes`) and their count; null
  /// on failure. `expected` >= 0: fails unless the count is that.
  std::pair<const unsigned char*, std::size_t> array(std::size_t item_bytes, std::int64_t expected, const char* what);
  /// Copies an array of `expected` (>= 0, or -1: any) items into `v`.
  template <typename T>
  void copy(std::vector<T>& v, std::int64_t expected, const char* what) {
    const auto [p, n] = array(sizeof(T), expected, what);
    if (!p) return;
    v.clear();
    v.reserve(n);
    prefer_huge_pages(v.data(), n * sizeof(T));  // fresh memory: most of the load's cost
    v.resize(n);
    if (n > 0) std::memcpy(v.data(), p, n * sizeof(T));
  }
  /// Copies `count` items of `item_bytes` each to `out` (a buffer already of that size).
  void copy_to(void* out, std::size_t count, std::size_t item_bytes, const char* what);
  /// Reads the checksum and checks it against what was read, and that nothing follows it.
  void finish();
  void fail(std::string why) {
    if (error_.empty()) error_ = std::move(why);
  }
  [[nodiscard]] const std::string& error() const { return error_; }
  [[nodiscard]] bool ok() const { return error_.empty(); }

 private:
  const unsigned char* data_;
  std::size_t size_;
  std::size_t at_{0};
  ContentHash hash_;
  std::string error_;
};

}  // namespace vx
