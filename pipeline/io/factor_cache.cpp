#include "io/factor_cache.h"

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <system_error>
#include <utility>
#include <vector>

#include "base/error.h"
#include "io/cache_file.h"
#include "util/atomic_file.h"
#include "util/log.h"

namespace vx {
namespace fs = std::filesystem;

namespace {

constexpr const char* kExtension = ".vxfactor";

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

std::optional<fs::path> default_factor_cache_folder() {
  if (const char* env = std::getenv("VOXELASTIC_FACTOR_CACHE")) {
    const std::string v(env);
    if (v.empty() || v == "off") return std::nullopt;
    return fs::path(v);
  }
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg) return fs::path(xdg) / "voxelastic" / "factors";
  if (const char* home = std::getenv("HOME"); home && *home)
    return fs::path(home) / ".cache" / "voxelastic" / "factors";
  return std::nullopt;
}

std::shared_ptr<FactorCache> make_factor_cache(const std::string& option) {
  std::optional<fs::path> folder;
  if (option == "off") return nullptr;
  folder = option.empty() ? default_factor_cache_folder() : std::optional<fs::path>(fs::path(option));
  if (!folder) return nullptr;
  FactorCacheSettings s;
  s.folder = *folder;
  s.min_factor_s = cache_min_seconds(s.min_factor_s);
  return std::make_shared<FolderFactorCache>(std::move(s));
}

FolderFactorCache::FolderFactorCache(FactorCacheSettings settings) : settings_(std::move(settings)) {}

fs::path FolderFactorCache::file_of(const FactorKey& key) const { return settings_.folder / (key.name() + kExtension); }

FolderFactorCache::Counters FolderFactorCache::counters() const {
  std::lock_guard lock(mutex_);
  return counters_;
}

void FolderFactorCache::complain(const std::string& what) {
  if (!complained_) {
    complained_ = true;
    log::warn("factor cache: {} (the solver factors as without a cache; --factor-cache off silences this)", what);
  } else {
    log::debug("factor cache: {}", what);
  }
}

bool FolderFactorCache::load(const FactorKey& key, SparseFactor& factor) {
  std::lock_guard lock(mutex_);
  const fs::path file = file_of(key);
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(file, ec);
  if (ec) {
    ++counters_.misses;
    log::debug("factor cache: no factor {} in {}", key.name(), settings_.folder.string());
    return false;
  }
  const auto t0 = std::chrono::steady_clock::now();
  std::string why;
  std::shared_ptr<const void> mapping = map_cache_file(file, std::size_t(size), why);
  if (!mapping || !factor.read(static_cast<const unsigned char*>(mapping.get()), std::size_t(size), mapping, &why)) {
    ++counters_.misses;
    ++counters_.damaged;
    fs::remove(file, ec);
    complain(fmt::format("{} could not be read ({}); removed it", file.string(), why));
    return false;
  }
  ++counters_.hits;
  touch_cache_file(file);  // recently used: kept longest
  log::info("factor cache: loaded the factor ({} rows, {:.0f} MB) from {} in {:.2f} s", key.rows, double(size) / 1e6,
            file.string(), seconds_since(t0));
  return true;
}

void FolderFactorCache::store(const FactorKey& key, const SparseFactor& factor) {
  std::lock_guard lock(mutex_);
  if (factor.factor_seconds() < settings_.min_factor_s) {
    ++counters_.skipped;
    return;
  }
  const std::uint64_t bytes = factor.stored_bytes();
  if (bytes > settings_.max_bytes) {
    complain(fmt::format("the factor ({:.0f} MB) is larger than the cache's limit ({:.0f} MB); not kept",
                         double(bytes) / 1e6, double(settings_.max_bytes) / 1e6));
    return;
  }
  const fs::path file = file_of(key);
  const auto t0 = std::chrono::steady_clock::now();
  try {
    std::error_code ec;
    fs::create_directories(settings_.folder, ec);
    if (ec) throw Error(fmt::format("cannot create {} ({})", settings_.folder.string(), ec.message()));
    // a cache: a crash of the machine may lose the file (the checksum then finds it damaged)
    write_atomically(
        file,
        [&](const fs::path& tmp) {
          std::ofstream out(tmp, std::ios::binary);
          if (!out) throw Error(fmt::format("cannot write {}", tmp.string()));
          factor.write(out);
          out.close();
          if (!out) throw Error(fmt::format("writing {} failed (disk full?)", tmp.string()));
        },
        Durability::process_crash);
  } catch (const std::exception& e) {
    complain(fmt::format("the factor could not be kept: {}", e.what()));
    return;
  }
  ++counters_.stored;
  log::info(
      "factor cache: kept the factor ({:.0f} MB, factored in {:.1f} s) in {} ({:.2f} s); the next start of this "
      "model loads it",
      double(bytes) / 1e6, factor.factor_seconds(), file.string(), seconds_since(t0));
  evict(file);
}

void FolderFactorCache::evict(const fs::path& keep) {
  counters_.evicted += evict_cache_files(settings_.folder, settings_.max_bytes, keep);
}

}  // namespace vx
