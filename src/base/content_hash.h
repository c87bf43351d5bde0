#pragma once
/// @file content_hash.h
/// A 64-bit hash of bytes fed in pieces, for content keys and checksums (the factor cache:
/// sparse_factor.h): the XXH64 round (Collet's xxHash, multiply-rotate per 8-byte word) in
/// one lane, about 6 GB/s, the same value on every machine of the same byte order. Not
/// cryptographic: it finds a changed matrix or a damaged file, not an attacker.

#include <cstddef>
#include <cstdint>
#include <cstring>

namespace vx {

class ContentHash {
 public:
  explicit ContentHash(std::uint64_t seed = 0) : h_(seed + kP5) {}

  /// Feeds `bytes` bytes at `data`; pieces may be any size (the value depends only on the
  /// concatenation).
  void add(const void* data, std::size_t bytes) {
    const auto* p = static_cast<const unsigned char*>(data);
    total_ += bytes;
    if (fill_ > 0) {  // complete the pending word first
      const std::size_t take = bytes < std::size_t(8 - fill_) ? bytes : std::size_t(8 - fill_);
      std::memcpy(buf_ + fill_, p, take);
      fill_ += int(take);
      p += take;
      bytes -= take;
      if (fill_ < 8) return;
      word(buf_);
      fill_ = 0;
    }
    for (; bytes >= 8; bytes -= 8, p += 8) word(p);
    std::memcpy(buf_, p, bytes);
    fill_ = int(bytes);
  }
  /// Feeds one value's bytes.
  template <typename T>
  void add_value(const T& v) {
    add(&v, sizeof v);
  }

  /// Feeds a vector's count (64 bits) and its values.
  template <typename V>
  void add_vector(const V& v) {
    add_value(std::uint64_t(v.size()));
    if (!v.empty()) add(v.data(), v.size() * sizeof(*v.data()));
  }
  /// Feeds a matrix's rows and columns (64 bits each) and its values as stored (an Eigen matrix
  /// or vector that owns its storage, not an expression).
  template <typename M>
  void add_matrix(const M& m) {
    add_value(std::int64_t(m.rows()));
    add_value(std::int64_t(m.cols()));
    if (m.size() > 0) add(m.data(), std::size_t(m.size()) * sizeof(*m.data()));
  }

  /// The hash of everything fed so far (feeding may go on).
  [[nodiscard]] std::uint64_t value() const {
    std::uint64_t h = h_ + total_;
    for (int i = 0; i < fill_; ++i) h = rotl(h ^ (buf_[i] * kP5), 11) * kP1;
    h ^= h >> 33;
    h *= kP2;
    h ^= h >> 29;
    h *= kP3;
    h ^= h >> 32;
    return h;
  }

 private:
  static constexpr std::uint64_t kP1 = 0x9E3779B185EBCA87ULL, kP2 = 0xC2B2AE3D27D4EB4FULL, kP3 = 0x165667B19E3779F9ULL,
                                 kP4 = 0x85EBCA77C2B2AE63ULL, kP5 = 0x27D4EB2F165667C5ULL;
  static std::uint64_t rotl(std::uint64_t x, int r) { return (x << r) | (x >> (64 - r)); }
  void word(const unsigned char* p) {
    std::uint64_t k;
    std::memcpy(&k, p, 8);
    k *= kP2;
    k = rotl(k, 31);
    k *= kP1;
    h_ ^= k;
    h_ = rotl(h_, 27) * kP1 + kP4;
  }

  std::uint64_t h_;
  std::uint64_t total_{0};
  unsigned char buf_[8]{};
  int fill_{0};
};

}  // namespace vx
