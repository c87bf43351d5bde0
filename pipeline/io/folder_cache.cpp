#include "io/folder_cache.h"

#include <chrono>
#include <cstdlib>
#include <fstream>
#include <system_error>
#include <utility>

#include "base/error.h"
#include "io/cache_file.h"
#include "util/atomic_file.h"
#include "util/log.h"
#include "util/thread_priority.h"

namespace vx {
namespace fs = std::filesystem;

namespace {

/// A file's size for a log line: "12 MB", or "84 bytes" for a small one.
std::string size_text(double bytes) {
  return bytes >= 1e6 ? fmt::format("{:.0f} MB", bytes / 1e6) : fmt::format("{:.0f} bytes", bytes);
}

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

std::optional<fs::path> cache_folder_of_option(const std::string& option) {
  if (option == "off") return std::nullopt;
  return option.empty() ? default_factor_cache_folder() : std::optional<fs::path>(fs::path(option));
}

FolderCache::FolderCache(FolderCacheWords words, fs::path folder, std::uint64_t max_bytes)
    : words_(words), folder_(std::move(folder)), max_bytes_(max_bytes) {}

FolderCache::~FolderCache() { wait_for_writes(); }

void FolderCache::wait_for_writes() {
  std::vector<std::thread> writes;
  {
    std::lock_guard lock(writes_mutex_);
    writes.swap(writes_);
  }
  for (std::thread& t : writes) t.join();
}

void FolderCache::close() {
  wait_for_writes();
  std::lock_guard lock(mutex_);  // (a store() under way holds it to its end)
  closed_ = true;
}

void FolderCache::store_beside(Offer offer, Writer write, const char* thread_name, int nice) {
  if (offer.seconds < offer.min_seconds) {  // skipped: nothing to write
    store(offer, write);
    return;
  }
  // FolderCache::store keeps the folder locked while it writes, so a load waits for it too
  const auto work = [this, offer = std::move(offer), write = std::move(write), thread_name, nice](bool beside) {
    if (beside) {
      (void)set_this_thread_name(thread_name);
      if (nice != 0) (void)set_this_thread_nice(nice);
    }
    store(offer, write);
  };
  std::lock_guard lock(writes_mutex_);
  try {
    writes_.emplace_back(work, true);  // copies `work`: it is still whole should this throw
  } catch (const std::system_error& e) {
    // no thread to be had: written here, as store() would (a store never stops a run)
    log::debug(fmt::format("{}: no thread for the write ({}); writing it now", words_.cache, e.what()));
    work(false);
  }
}

fs::path FolderCache::file_of(const std::string& name) const { return folder_ / (name + words_.extension); }

FolderCache::Counters FolderCache::counters() const {
  std::lock_guard lock(mutex_);
  return counters_;
}

void FolderCache::complain(const std::string& what) {
  if (!complained_) {
    complained_ = true;
    log::warn("{}: {} ({}; --factor-cache off silences this)", words_.cache, what, words_.fallback);
  } else {
    log::debug("{}: {}", words_.cache, what);
  }
}

bool FolderCache::load(const std::string& name, const std::string& detail, const Reader& read) {
  wait_for_writes();  // what was stored is found (a write begun is finished first)
  std::lock_guard lock(mutex_);
  const fs::path file = file_of(name);
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(file, ec);
  if (ec) {
    ++counters_.misses;
    log::debug("{}: no {} {} in {}", words_.cache, words_.item, name, folder_.string());
    return false;
  }
  const auto t0 = std::chrono::steady_clock::now();
  std::string why;
  const std::shared_ptr<const void> mapping = map_cache_file(file, std::size_t(size), why);
  if (!mapping || !read(static_cast<const unsigned char*>(mapping.get()), std::size_t(size), mapping, why)) {
    ++counters_.misses;
    ++counters_.damaged;
    fs::remove(file, ec);
    complain(fmt::format("{} could not be read ({}); removed it", file.string(), why));
    return false;
  }
  ++counters_.hits;
  touch_cache_file(file);  // recently used: kept longest
  log::info("{}: loaded the {} ({}, {}) from {} in {:.2f} s", words_.cache, words_.item, detail,
            size_text(double(size)), file.string(), seconds_since(t0));
  return true;
}

void FolderCache::store(const Offer& offer, const Writer& write) {
  std::lock_guard lock(mutex_);
  if (closed_ || offer.seconds < offer.min_seconds) {
    ++counters_.skipped;
    return;
  }
  if (offer.bytes > max_bytes_) {
    complain(fmt::format("the {} ({:.0f} MB) is larger than the cache's limit ({:.0f} MB); not kept", words_.item,
                         double(offer.bytes) / 1e6, double(max_bytes_) / 1e6));
    return;
  }
  const fs::path file = file_of(offer.name);
  const auto t0 = std::chrono::steady_clock::now();
  std::uint64_t bytes = offer.bytes;
  try {
    std::error_code ec;
    fs::create_directories(folder_, ec);
    if (ec) throw Error(fmt::format("cannot create {} ({})", folder_.string(), ec.message()));
    // a cache: a crash of the machine may lose the file (the checksum then finds it damaged)
    write_atomically(
        file,
        [&](const fs::path& tmp) {
          std::ofstream out(tmp, std::ios::binary);
          if (!out) throw Error(fmt::format("cannot write {}", tmp.string()));
          write(out);
          out.close();
          if (!out) throw Error(fmt::format("writing {} failed (disk full?)", tmp.string()));
        },
        Durability::process_crash);
    if (bytes == 0) bytes = fs::file_size(file, ec);
  } catch (const std::exception& e) {
    complain(fmt::format("the {} could not be kept: {}", words_.item, e.what()));
    return;
  }
  ++counters_.stored;
  log::info("{}: kept the {} ({}, {}) in {} ({:.2f} s); the next start of {} loads it", words_.cache, words_.item,
            size_text(double(bytes)), offer.made, file.string(), seconds_since(t0), offer.next_start);
  counters_.evicted += evict_cache_files(folder_, max_bytes_, file);
}

}  // namespace vx
