#pragma once
/// @file factor_cache.h
/// The factor cache: the implicit solver's sparse Cholesky factor kept in a folder by the
/// content of the matrix it factors (sim/sparse_factor.h, FactorKey), so the second start of a
/// model loads in about a second what the first factored in tens (the folded organ: 21 s of
/// factorisation against a 0.7 GB file read back; docs/bench.md). A changed model, material,
/// support or step changes the matrix and so the key: a stale factor is never used.
///
/// Beside the factors, the fill-reducing orders by the matrix's pattern (`order-<rows>n-
/// <nonzeros>nz-<hash>.vxorder`): the first start of an organ already opened with another
/// material, step or damping takes METIS's order from there (METIS takes 5 to 7 s of the folded
/// organ's first start: 0.79x the wall time with the order kept; docs/bench.md) and factors the
/// same factor, bit for bit.
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
#include <vector>

#include "io/folder_cache.h"
#include "sim/sparse_factor.h"

namespace vx {

struct FactorCacheSettings {
  std::filesystem::path folder;
  /// the folder's factors together at most this many bytes; the least recently used go first
  std::uint64_t max_bytes{std::uint64_t(8) << 30};
  /// factors computed faster than this are not kept (reading them back would cost as much), s
  double min_factor_s{1.0};
  /// store() writes the factor on a thread of its own and returns at once (the folded organ's
  /// 450 MB took 2 s of its first start's path; docs/bench.md); false: store() writes it
  bool background_writes{false};
  /// that thread's nice value (a real-time run goes first)
  int writer_nice{10};
};

/// The factor cache of a command-line option (`--factor-cache`): "" the default folder
/// (default_factor_cache_folder(), folder_cache.h, or none), "off" none, anything else a folder
/// (created when used). Null: no cache. $VOXELASTIC_FACTOR_CACHE_MIN_S sets min_factor_s (0: keep every factor).
/// Its factors are written in the background (FactorCacheSettings::background_writes).
[[nodiscard]] std::shared_ptr<FactorCache> make_factor_cache(const std::string& option);

/// A FactorCache in a folder (folder_cache.h: the folder's bookkeeping; here what a file
/// holds: SparseFactor::write and read). Thread-safe (one lock around each call). With
/// background writes a load first waits for the writes begun (so a factor stored is found), and
/// so does the destructor: a run's factor is on disk when its cache is gone.
class FolderFactorCache final : public FactorCache {
 public:
  explicit FolderFactorCache(FactorCacheSettings settings);

  bool load(const FactorKey& key, SparseFactor& factor) override;
  void store(const FactorKey& key, const SparseFactor& factor) override;
  /// Orders are kept when finding them took at least min_factor_s, as factors are.
  bool load_order(const FactorKey& pattern, std::vector<int>& order) override;
  void store_order(const FactorKey& pattern, const SparseFactor& factor) override;
  void close() override {
    folder_.close();
    orders_.close();
  }

  [[nodiscard]] const FactorCacheSettings& settings() const { return settings_; }
  /// The file of `key`.
  [[nodiscard]] std::filesystem::path file_of(const FactorKey& key) const { return folder_.file_of(key.name()); }
  /// The order file of `pattern`.
  [[nodiscard]] std::filesystem::path order_file_of(const FactorKey& pattern) const {
    return orders_.file_of(order_name(pattern));
  }

  /// hits: factors loaded; skipped: computed faster than min_factor_s (folder_cache.h)
  using Counters = FolderCacheCounters;
  [[nodiscard]] Counters counters() const { return folder_.counters(); }
  /// The same for the orders.
  [[nodiscard]] Counters order_counters() const { return orders_.counters(); }

 private:
  static std::string order_name(const FactorKey& pattern);

  FactorCacheSettings settings_;
  FolderCache folder_;
  FolderCache orders_;
};

/// An order file: the pattern's key and the order (order[k]: the row factored k-th), with a
/// checksum (base/cache_file_format.h).
void write_order_file(std::ostream& out, const FactorKey& pattern, const std::vector<int>& order);
/// Reads what write_order_file wrote: false with `why` when it is another pattern's, damaged,
/// or not a permutation of the pattern's rows.
[[nodiscard]] bool read_order_file(const unsigned char* data, std::size_t bytes, const FactorKey& pattern,
                                   std::vector<int>& order, std::string* why);

}  // namespace vx
