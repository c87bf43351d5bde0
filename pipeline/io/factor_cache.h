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
#include <string>

#include "io/folder_cache.h"
#include "sim/sparse_factor.h"

namespace vx {

struct FactorCacheSettings {
  std::filesystem::path folder;
  /// the folder's factors together at most this many bytes; the least recently used go first
  std::uint64_t max_bytes{std::uint64_t(8) << 30};
  /// factors computed faster than this are not kept (reading them back would cost as much), s
  double min_factor_s{1.0};
};

/// The factor cache of a command-line option (`--factor-cache`): "" the default folder
/// (default_factor_cache_folder(), folder_cache.h, or none), "off" none, anything else a folder
/// (created when used). Null: no cache. $VOXELASTIC_FACTOR_CACHE_MIN_S sets min_factor_s (0: keep every factor).
[[nodiscard]] std::shared_ptr<FactorCache> make_factor_cache(const std::string& option);

/// A FactorCache in a folder (folder_cache.h: the folder's bookkeeping; here what a file
/// holds: SparseFactor::write and read). Thread-safe (one lock around each call).
class FolderFactorCache final : public FactorCache {
 public:
  explicit FolderFactorCache(FactorCacheSettings settings);

  bool load(const FactorKey& key, SparseFactor& factor) override;
  void store(const FactorKey& key, const SparseFactor& factor) override;

  [[nodiscard]] const FactorCacheSettings& settings() const { return settings_; }
  /// The file of `key`.
  [[nodiscard]] std::filesystem::path file_of(const FactorKey& key) const { return folder_.file_of(key.name()); }

  /// hits: factors loaded; skipped: computed faster than min_factor_s (folder_cache.h)
  using Counters = FolderCacheCounters;
  [[nodiscard]] Counters counters() const { return folder_.counters(); }

 private:
  FactorCacheSettings settings_;
  FolderCache folder_;
};

}  // namespace vx
