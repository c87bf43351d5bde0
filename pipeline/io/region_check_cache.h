#pragma once
/// @file region_check_cache.h
/// The region check cache: the estimate of how much the regional solves over-stiffen a press
/// (sim/region_stiffening.h, the run's region check) kept by the content it is estimated from,
/// so the second start of an organ on the same support with the same tool loads what the first
/// solved (the folded organ held at its stem: 10 s of one core beside the run's first seconds,
/// which took a sixth of the run's samples and slowed its physics 1.2x over a 10 s press;
/// docs/bench.md). It lives in the factor cache's folder (factor_cache.h: the same option
/// `--factor-cache`, environment variable and size limit over every kind of cache file;
/// cache_file.h).
///
/// One file per estimate, `regioncheck-<free nodes>n-<hash>.vxregion`: a header (magic, format
/// version, the key), the estimate's numbers, a checksum; written to a temporary name and
/// renamed; read back and checked (header, key, checksum, the numbers' ranges): a damaged file is
/// removed with a warning and the estimate solved. Nothing here may stop a run.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <ostream>
#include <string>

#include "io/folder_cache.h"
#include "sim/region_stiffening.h"

namespace vx {

/// The file name of the estimate of `key` on a model of `free_nodes` free nodes (without the
/// extension): "regioncheck-326564n-0123456789abcdef".
[[nodiscard]] std::string region_check_name(std::uint64_t key, int free_nodes);

/// The file form of `estimate` under `key`. Throws vx::Error when the stream fails.
void write_region_check_file(std::ostream& out, std::uint64_t key, int free_nodes,
                             const RegionStiffeningEstimate& estimate);
/// Reads what write_region_check_file wrote (`bytes` bytes at `data`). Nothing with `why` when it
/// is not the estimate of `key` or is damaged.
[[nodiscard]] std::optional<RegionStiffeningEstimate> read_region_check_file(const unsigned char* data,
                                                                             std::size_t bytes, std::uint64_t key,
                                                                             int free_nodes, std::string* why);

struct RegionCheckCacheSettings {
  std::filesystem::path folder;
  /// the folder's cache files (factors, calibrations, surfaces, estimates) together at most this
  /// many bytes; the least recently used go first
  std::uint64_t max_bytes{std::uint64_t(8) << 30};
  /// estimates solved faster than this are not kept, s
  double min_seconds{0.25};
};

/// Region check estimates in a folder (folder_cache.h does the folder's bookkeeping). Thread-safe
/// (the region check runs on a thread of its own).
class RegionCheckCache final : public RegionStiffeningCache {
 public:
  explicit RegionCheckCache(RegionCheckCacheSettings settings);

  std::optional<RegionStiffeningEstimate> load(std::uint64_t key, int free_nodes) override;
  void store(std::uint64_t key, int free_nodes, const RegionStiffeningEstimate& estimate) override;

  [[nodiscard]] const RegionCheckCacheSettings& settings() const { return settings_; }
  [[nodiscard]] std::filesystem::path file_of(std::uint64_t key, int free_nodes) const {
    return folder_.file_of(region_check_name(key, free_nodes));
  }
  /// hits: estimates loaded; skipped: solved faster than min_seconds (folder_cache.h)
  using Counters = FolderCacheCounters;
  [[nodiscard]] Counters counters() const { return folder_.counters(); }

 private:
  RegionCheckCacheSettings settings_;
  FolderCache folder_;
};

/// The region check cache of a command-line option (`--factor-cache`), in the factor cache's
/// folder: "" the default folder (default_factor_cache_folder(), folder_cache.h, or none), "off"
/// none, anything else a folder. Null: no cache. $VOXELASTIC_FACTOR_CACHE_MIN_S sets min_seconds.
[[nodiscard]] std::shared_ptr<RegionCheckCache> make_region_check_cache(const std::string& option);

}  // namespace vx
