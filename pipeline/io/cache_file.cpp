#include "io/cache_file.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <system_error>
#include <vector>

#include "util/log.h"

namespace vx {
namespace fs = std::filesystem;

bool is_cache_file(const fs::path& file) {
  const fs::path ext = file.extension();
  return ext == ".vxfactor" || ext == ".vxorder" || ext == ".vxcalib" || ext == ".vxsurf" || ext == ".vxregion";
}

std::shared_ptr<const void> map_cache_file(const fs::path& file, std::size_t size, std::string& why) {
  if (size == 0) {
    why = "it is empty";
    return nullptr;
  }
  const int fd = ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    why = std::string("it cannot be opened: ") + std::strerror(errno);
    return nullptr;
  }
  void* p = ::mmap(nullptr, size, PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd, 0);
  const int err = errno;
  ::close(fd);  // the mapping keeps the file
  if (p == MAP_FAILED) {
    why = std::string("it cannot be mapped: ") + std::strerror(err);
    return nullptr;
  }
  return std::shared_ptr<const void>(p, [size](const void* q) { ::munmap(const_cast<void*>(q), size); });
}

int evict_cache_files(const fs::path& folder, std::uint64_t max_bytes, const fs::path& keep) {
  struct Entry {
    fs::path path;
    fs::file_time_type time;
    std::uintmax_t bytes;
  };
  std::vector<Entry> entries;
  std::uint64_t total = 0;
  std::error_code ec;
  for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    if (!it->is_regular_file(ec) || !is_cache_file(it->path())) continue;
    Entry e{it->path(), it->last_write_time(ec), it->file_size(ec)};
    if (ec) continue;
    total += e.bytes;
    entries.push_back(std::move(e));
  }
  std::sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) { return a.time < b.time; });
  int removed = 0;
  for (const Entry& e : entries) {
    if (total <= max_bytes) break;
    if (e.path == keep) continue;
    if (fs::remove(e.path, ec)) {
      total -= e.bytes;
      ++removed;
      log::debug("cache: removed {} (the folder is over {:.0f} MB)", e.path.string(), double(max_bytes) / 1e6);
    }
  }
  return removed;
}

void touch_cache_file(const fs::path& file) {
  std::error_code ec;
  fs::last_write_time(file, fs::file_time_type::clock::now(), ec);
}

double cache_min_seconds(double fallback) {
  const char* min = std::getenv("VOXELASTIC_FACTOR_CACHE_MIN_S");
  if (!min || !*min) return fallback;
  char* end = nullptr;
  const double v = std::strtod(min, &end);
  if (end && *end == 0 && v >= 0) return v;
  log::warn("VOXELASTIC_FACTOR_CACHE_MIN_S='{}' is not a number of seconds >= 0; keeping {} s", min, fallback);
  return fallback;
}

}  // namespace vx
