#include "io/cache_file.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <system_error>

#include "base/error.h"
#include "util/log.h"

namespace vx {
namespace fs = std::filesystem;

bool is_cache_file(const fs::path& file) {
  const fs::path ext = file.extension();
  return ext == ".vxfactor" || ext == ".vxcalib" || ext == ".vxsurf";
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

void CacheFileWriter::bytes(const void* p, std::size_t n) {
  hash_.add(p, n);
  out_.write(static_cast<const char*>(p), std::streamsize(n));
  at_ += n;
}

void CacheFileWriter::array(const void* data, std::size_t count, std::size_t item_bytes) {
  value(std::uint64_t(count));
  static constexpr unsigned char kZeros[kCacheAlign] = {};
  bytes(kZeros, (kCacheAlign - at_ % kCacheAlign) % kCacheAlign);
  if (count > 0) bytes(data, count * item_bytes);
}

void CacheFileWriter::finish() {
  const std::uint64_t sum = hash_.value();
  out_.write(reinterpret_cast<const char*>(&sum), sizeof sum);  // not hashed: the hash of what precedes
  at_ += sizeof sum;
  if (!out_) throw Error("writing the cache file failed (disk full?)");
}

const unsigned char* CacheFileReader::bytes(std::size_t n, const char* what) {
  if (!error_.empty()) return nullptr;
  if (n > size_ - at_) {
    fail(std::string("truncated at ") + what);
    return nullptr;
  }
  const unsigned char* p = data_ + at_;
  hash_.add(p, n);
  at_ += n;
  return p;
}

std::pair<const unsigned char*, std::size_t> CacheFileReader::array(std::size_t item_bytes, std::int64_t expected,
                                                                    const char* what) {
  std::uint64_t n = 0;
  if (!value(n, what)) return {nullptr, 0};
  constexpr std::size_t align = CacheFileWriter::kCacheAlign;
  bytes((align - at_ % align) % align, what);
  if (!error_.empty()) return {nullptr, 0};
  if (expected >= 0 && n != std::uint64_t(expected)) {
    fail(std::string(what) + ": " + std::to_string(n) + " values where the model needs " + std::to_string(expected));
    return {nullptr, 0};
  }
  if (n > (size_ - at_) / item_bytes) {
    fail(std::string("truncated: the size of ") + what + " runs past the end of the file");
    return {nullptr, 0};
  }
  const unsigned char* p = bytes(std::size_t(n) * item_bytes, what);
  if (!p) return {nullptr, 0};
  return {p, std::size_t(n)};
}

void CacheFileReader::copy_to(void* out, std::size_t count, std::size_t item_bytes, const char* what) {
  const auto [p, n] = array(item_bytes, std::int64_t(count), what);
  if (p && n > 0) std::memcpy(out, p, n * item_bytes);
}

void CacheFileReader::finish() {
  if (!error_.empty()) return;
  const std::uint64_t expected = hash_.value();
  std::uint64_t sum = 0;
  if (sizeof sum > size_ - at_) {
    fail("truncated at the checksum");
    return;
  }
  std::memcpy(&sum, data_ + at_, sizeof sum);
  at_ += sizeof sum;
  if (sum != expected) fail("the checksum does not match (a damaged file)");
  if (error_.empty() && at_ != size_) fail(std::to_string(size_ - at_) + " bytes after the end of the data");
}

}  // namespace vx
