#pragma once
/// @file factor_cache.h
/// The factor cache: the implicit solver's sparse Cholesky factor kept in a folder by the
/// content of the matrix it factors (sim/sparse_factor.h, FactorKey), so the second start of a
/// model loads in about a second what the first factored in tens (the folded organ: 21 s of
/// factorisation against a 0.7 GB file read back; docs/bench.md). A changed model, material,
/// support or step changes the matrix and so the key: a stale factor is never used.
///
/// One file per factor, `<backend>-<rows>n-<nonzeros>nz-<hash>.vxfactor`, written to a
/// temporary name and renamed; read back checked (header, structure, checksum: a damaged file
/// is removed and the factor computed). The folder is kept under a size limit by dropping the
/// factors used longest ago. Nothing here may stop a run: a cache that cannot be read or
/// written says so once as a warning and the solver factors as it would without it.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "sim/sparse_factor.h"

namespace vx {

struct FactorCacheSettings {
  std::filesystem::path folder;
  /// the folder's factors together at most this many bytes; the least recently used go first
  std::uint64_t max_bytes{std::uint64_t(8) << 30};
  /// factors computed faster than this are not kept (reading them back would cost as much), s
  double min_factor_s{1.0};
};

/// The default folder: $VOXELASTIC_FACTOR_CACHE when set (a folder; "off" or empty: no cache),
/// else $XDG_CACHE_HOME/voxelastic/factors, else $HOME/.cache/voxelastic/factors; none when
/// there is no home either.
[[nodiscard]] std::optional<std::filesystem::path> default_factor_cache_folder();

/// The factor cache of a command-line option (`--factor-cache`): "" the default folder (or none,
/// as above), "off" none, anything else a folder (created when used). Null: no cache.
/// $VOXELASTIC_FACTOR_CACHE_MIN_S sets min_factor_s (0: keep every factor).
[[nodiscard]] std::shared_ptr<FactorCache> make_factor_cache(const std::string& option);

/// A FactorCache in a folder. Thread-safe (one lock around each call).
class FolderFactorCache final : public FactorCache {
 public:
  explicit FolderFactorCache(FactorCacheSettings settings);

  bool load(const FactorKey& key, SparseFactor& factor) override;
  void store(const FactorKey& key, const SparseFactor& factor) override;

  [[nodiscard]] const FactorCacheSettings& settings() const { return settings_; }
  /// The file of `key`.
  [[nodiscard]] std::filesystem::path file_of(const FactorKey& key) const;

  struct Counters {
    int hits{0};     ///< factors loaded
    int misses{0};   ///< factors looked up and not found (or not readable)
    int stored{0};   ///< factors written
    int skipped{0};  ///< factors not written: computed faster than min_factor_s
    int damaged{0};  ///< files found unreadable and removed
    int evicted{0};  ///< files removed to keep the folder under max_bytes
  };
  [[nodiscard]] Counters counters() const;

 private:
  void evict(const std::filesystem::path& keep);
  /// A warning the first time the folder cannot be used, debug lines after.
  void complain(const std::string& what);

  FactorCacheSettings settings_;
  mutable std::mutex mutex_;
  Counters counters_;
  bool complained_{false};
};

}  // namespace vx
