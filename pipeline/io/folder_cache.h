#pragma once
/// @file folder_cache.h
/// A cache kept as one file per key in a folder: what the factor cache (factor_cache.h) and the
/// calibration cache (calibration_cache.h) share, so that each of them says only what its file
/// holds (a reader and a writer) and the words of its messages. Here: the folder an option
/// names, the file of a key, the lookup (the file mapped and handed to the cache's reader; a
/// file it refuses is removed and counted damaged), the store (not kept below a threshold of
/// seconds or over the folder's limit, written to a temporary name and renamed, the least
/// recently used cache files of the folder dropped after), the counters and the one warning.
/// Nothing here may stop a run: a folder that cannot be used says so once as a warning and
/// the run goes on as without a cache. Thread-safe (one lock around each call). A store may be
/// written on a thread of its own (store_beside: a large model's first start does not wait for
/// its files); a load first waits for the writes begun, and so does the destructor.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <ostream>
#include <string>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

#include "io/cache_file.h"

namespace vx {

/// The default folder of the caches: $VOXELASTIC_FACTOR_CACHE when set (a folder; "off" or
/// empty: no cache), else $XDG_CACHE_HOME/voxelastic/factors, else
/// $HOME/.cache/voxelastic/factors; none when there is no home either.
[[nodiscard]] std::optional<std::filesystem::path> default_factor_cache_folder();

/// The folder of a command-line option (`--factor-cache`): "" the default folder (or none, as
/// above), "off" none, anything else that folder.
[[nodiscard]] std::optional<std::filesystem::path> cache_folder_of_option(const std::string& option);

/// A cache of a command-line option (cache_folder_of_option): `Cache` made from its `Settings`
/// with the option's folder, their `min_seconds` member (the seconds below which nothing is
/// kept) from $VOXELASTIC_FACTOR_CACHE_MIN_S when that holds a number >= 0, then `adjust`
/// (may be null) given the settings. Null: no cache.
template <class Cache, class Settings>
[[nodiscard]] std::shared_ptr<Cache> make_folder_cache(const std::string& option, double Settings::*min_seconds,
                                                       std::type_identity_t<void (*)(Settings&)> adjust = nullptr) {
  const std::optional<std::filesystem::path> folder = cache_folder_of_option(option);
  if (!folder) return nullptr;
  Settings s;
  s.folder = *folder;
  s.*min_seconds = cache_min_seconds(s.*min_seconds);
  if (adjust) adjust(s);
  return std::make_shared<Cache>(std::move(s));
}

/// What a folder cache did (FolderCache::counters()).
struct FolderCacheCounters {
  int hits{0};     ///< loaded
  int misses{0};   ///< looked up and not found (or not readable)
  int stored{0};   ///< written
  int skipped{0};  ///< not written: computed faster than the cache's threshold
  int damaged{0};  ///< files found unreadable and removed
  int evicted{0};  ///< cache files removed to keep the folder under its limit
};

/// The words of a cache's messages ("factor cache: loaded the factor (...)").
struct FolderCacheWords {
  const char* cache;      ///< "factor cache"
  const char* item;       ///< "factor"
  const char* extension;  ///< of its files: ".vxfactor" (cache_file.h, is_cache_file, lists them)
  const char* fallback;   ///< what the run does instead: "the solver factors as without a cache"
};

/// The folder and its bookkeeping; a cache holds one and gives it a reader and a writer.
class FolderCache {
 public:
  using Counters = FolderCacheCounters;
  /// Reads a file of `bytes` bytes at `data` (kept mapped as long as `mapping` lives); false
  /// with `why` when it is not what the key asks for or is damaged.
  using Reader = std::function<bool(const unsigned char* data, std::size_t bytes,
                                    const std::shared_ptr<const void>& mapping, std::string& why)>;
  /// Writes the file's content (throws on failure).
  using Writer = std::function<void(std::ostream& out)>;

  /// `max_bytes`: every cache file of the folder together at most this many bytes.
  FolderCache(FolderCacheWords words, std::filesystem::path folder, std::uint64_t max_bytes);
  /// Waits for the writes begun (store_beside): what a run stored is on disk when its cache is gone.
  ~FolderCache();
  FolderCache(const FolderCache&) = delete;
  FolderCache& operator=(const FolderCache&) = delete;

  /// The file of the key named `name` (its extension added).
  [[nodiscard]] std::filesystem::path file_of(const std::string& name) const;
  [[nodiscard]] Counters counters() const;

  /// Looks up `name` and reads it with `read`; true when read (the file then counts as just
  /// used). `detail` describes it in the log line ("12 rows"). Waits for the writes begun first,
  /// so that what was stored is found.
  bool load(const std::string& name, const std::string& detail, const Reader& read);

  /// What a store offers.
  struct Offer {
    std::string name;            ///< the key's name
    double seconds{0};           ///< what computing it took, s
    double min_seconds{0};       ///< not kept when computed faster than this, s
    std::uint64_t bytes{0};      ///< its size when known before writing (over the limit: not kept); 0: unknown
    std::string made;            ///< how it was made, for the log line ("factored in 21.0 s")
    const char* next_start{""};  ///< whose next start loads it ("this model")
  };
  /// Keeps what `write` writes under offer.name (or skips it, see Offer), then keeps the folder
  /// under its limit.
  void store(const Offer& offer, const Writer& write);
  /// The same on a thread of its own, named `thread_name` (for top -H and perf) at nice `nice`
  /// (0: the caller's; a real-time run goes first), and returns at once; `write` must own or
  /// share what it writes. Written here when no thread can be had, or when it would be skipped.
  void store_beside(Offer offer, Writer write, const char* thread_name, int nice);
  /// No store from now on (each is skipped); returns once the stores begun have ended. For a
  /// process that ends without waiting for a thread that may still offer one (its file is never
  /// left half written).
  void close();

 private:
  /// Waits for the writes begun so far (a load, the destructor).
  void wait_for_writes();
  /// A warning the first time the folder cannot be used, debug lines after (locked).
  void complain(const std::string& what);

  FolderCacheWords words_;
  std::filesystem::path folder_;
  std::uint64_t max_bytes_;
  mutable std::mutex mutex_;
  Counters counters_;
  bool complained_{false};
  bool closed_{false};  ///< close(): stores are skipped (locked)
  std::mutex writes_mutex_;
  std::vector<std::thread> writes_;  ///< store_beside's threads (joined by wait_for_writes)
};

}  // namespace vx
