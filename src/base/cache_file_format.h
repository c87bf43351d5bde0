#pragma once
/// @file cache_file_format.h
/// The checked binary form of every cache file (the factor's, sparse_factor.h; the
/// calibration's and the display surface's, pipeline/io/cache_file.h): a header of values, then
/// arrays, each as its count and, from the next multiple of kCacheAlign bytes from the start, its
/// values; last the hash of all that precedes (content_hash.h). Native byte order: read back on
/// the machine that wrote it. The writer and the reader know nothing of what a file holds.

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include "base/content_hash.h"
#include "base/huge_pages.h"

namespace vx {

/// Writes values and arrays, each array at a multiple of kCacheAlign bytes from the start, and
/// feeds everything to the checksum. Throws vx::Error when the stream fails (finish()).
class CacheFileWriter {
 public:
  static constexpr std::size_t kCacheAlign = 64;
  explicit CacheFileWriter(std::ostream& out) : out_(out) {}
  void bytes(const void* p, std::size_t n);
  template <typename T>
  void value(const T& v) {
    bytes(&v, sizeof v);
  }
  /// A file's first 12 bytes: its kind's 8-byte magic and the version of its form.
  void header(const char (&magic)[8], std::uint32_t version) {
    bytes(magic, sizeof magic);
    value(version);
  }
  /// The count, zeros up to the next boundary, the values.
  void array(const void* data, std::size_t count, std::size_t item_bytes);
  /// The values of a contiguous container (a std::vector, an Eigen matrix, a shared array).
  template <typename V>
  void array(const V& v) {
    array(v.data(), std::size_t(v.size()), sizeof(*v.data()));
  }
  /// The checksum (not hashed itself); throws vx::Error(`failure`) when the stream failed.
  void finish(const char* failure = "writing the cache file failed (disk full?)");
  /// Bytes written so far.
  [[nodiscard]] std::size_t size() const { return at_; }

 private:
  std::ostream& out_;
  ContentHash hash_;
  std::size_t at_{0};
};

/// Reads what CacheFileWriter wrote, from memory; the first failure sticks (error()).
class CacheFileReader {
 public:
  CacheFileReader(const unsigned char* data, std::size_t size) : data_(data), size_(size) {}
  /// The next n bytes (null on failure).
  const unsigned char* bytes(std::size_t n, const char* what);
  template <typename T>
  bool value(T& v, const char* what) {
    const unsigned char* p = bytes(sizeof v, what);
    if (p) std::memcpy(&v, p, sizeof v);
    return p != nullptr;
  }
  /// Reads what CacheFileWriter::header wrote: fails with `not_this` where the magic is
  /// another's, or with "format version N, this build reads M".
  void header(const char (&magic)[8], std::uint32_t version, const char* not_this);
  /// An array's values in place and their count; null on failure. `expected` >= 0: fails
  /// unless the count is that.
  std::pair<const unsigned char*, std::size_t> array(std::size_t item_bytes, std::int64_t expected, const char* what);
  /// Copies an array of `expected` (>= 0, or -1: any) items into `v`.
  template <typename T>
  void copy(std::vector<T>& v, std::int64_t expected, const char* what) {
    const auto [p, n] = array(sizeof(T), expected, what);
    if (!p) return;
    v.clear();
    v.reserve(n);
    prefer_huge_pages(v.data(), n * sizeof(T));  // fresh memory: most of the load's cost
    v.resize(n);
    if (n > 0) std::memcpy(v.data(), p, n * sizeof(T));
  }
  /// Copies an array into the matrix `m` (an Eigen matrix), `rows` x `cols` (cols = -1: any
  /// count divisible by rows); another count fails as "<what>: not a whole number of <unit>".
  template <typename M>
  void matrix(M& m, std::int64_t rows, std::int64_t cols, const char* what, const char* unit = "columns") {
    using Scalar = typename M::Scalar;
    const auto [p, n] = array(sizeof(Scalar), cols >= 0 ? rows * cols : -1, what);
    if (!p) return;
    if (n % std::size_t(rows) != 0) {
      fail(std::string(what) + ": not a whole number of " + unit);
      return;
    }
    m.resize(rows, std::int64_t(n / std::size_t(rows)));
    prefer_huge_pages(m.data(), n * sizeof(Scalar));  // before the first touch
    if (n > 0) std::memcpy(m.data(), p, n * sizeof(Scalar));
  }
  /// Copies `count` items of `item_bytes` each to `out` (a buffer already of that size).
  void copy_to(void* out, std::size_t count, std::size_t item_bytes, const char* what);
  /// Reads the checksum and checks it against what was read, and that nothing follows it (else
  /// "N bytes after the end of <what>").
  void finish(const char* what = "the data");
  void fail(std::string why) {
    if (error_.empty()) error_ = std::move(why);
  }
  [[nodiscard]] const std::string& error() const { return error_; }
  [[nodiscard]] bool ok() const { return error_.empty(); }

 private:
  const unsigned char* data_;
  std::size_t size_;
  std::size_t at_{0};
  ContentHash hash_;
  std::string error_;
};

}  // namespace vx
