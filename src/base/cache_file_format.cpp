#include "base/cache_file_format.h"

#include "base/error.h"

namespace vx {

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

void CacheFileWriter::finish(const char* failure) {
  const std::uint64_t sum = hash_.value();
  out_.write(reinterpret_cast<const char*>(&sum), sizeof sum);  // not hashed: the hash of what precedes
  at_ += sizeof sum;
  if (!out_) throw Error(failure);
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

void CacheFileReader::header(const char (&magic)[8], std::uint32_t version, const char* not_this) {
  if (const unsigned char* m = bytes(sizeof magic, "the header"); m && std::memcmp(m, magic, sizeof magic) != 0)
    fail(not_this);
  std::uint32_t v = 0;
  value(v, "the header");
  if (ok() && v != version)
    fail("format version " + std::to_string(v) + ", this build reads " + std::to_string(version));
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

void CacheFileReader::finish(const char* what) {
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
  if (error_.empty() && at_ != size_) fail(std::to_string(size_ - at_) + " bytes after the end of " + what);
}

}  // namespace vx
