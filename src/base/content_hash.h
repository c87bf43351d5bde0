#pragma once
/// @file content_hash.h
/// A 64-bit hash of bytes fed in pieces, for content keys and checksums (the factor cache:
/// sparse_factor.h): XXH64 (Collet's xxHash), four independent lanes of multiply-rotate rounds
/// over 32-byte stripes, about 4x the speed of one lane (the checksums of a 450 MB factor and a
/// 115 MB calibration are on the start-up's path); the same value on every machine of the same
/// byte order, and the reference XXH64 value of the bytes (tested against its published values).
/// Not cryptographic: it finds a changed matrix or a damaged file, not an attacker.

#include <cstddef>
#include <cstdint>
#include <cstring>

namespace vx {

class ContentHash {
 public:
  explicit ContentHash(std::uint64_t seed = 0) : seed_(seed), v_{seed + kP1 + kP2, seed + kP2, seed, seed - kP1} {}

  /// Feeds `bytes` bytes at `data`; pieces may be any size (the value depends only on the
  /// concatenation).
  void add(const void* data, std::size_t bytes) {
    const auto* p = static_cast<const unsigned char*>(data);
    total_ += bytes;
    if (fill_ > 0) {  // complete the pending stripe first
      const std::size_t take = bytes < std::size_t(kStripe - fill_) ? bytes : std::size_t(kStripe - fill_);
      std::memcpy(buf_ + fill_, p, take);
      fill_ += int(take);
      p += take;
      bytes -= take;
      if (fill_ < kStripe) return;
      stripe(buf_);
      fill_ = 0;
    }
    for (; bytes >= std::size_t(kStripe); bytes -= kStripe, p += kStripe) stripe(p);
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
    std::uint64_t h;
    if (total_ >= std::uint64_t(kStripe)) {
      h = rotl(v_[0], 1) + rotl(v_[1], 7) + rotl(v_[2], 12) + rotl(v_[3], 18);
      for (const std::uint64_t v : v_) h = (h ^ round(0, v)) * kP1 + kP4;
    } else {
      h = seed_ + kP5;
    }
    h += total_;
    int i = 0;
    for (; i + 8 <= fill_; i += 8) h = rotl(h ^ round(0, read64(buf_ + i)), 27) * kP1 + kP4;
    if (i + 4 <= fill_) {
      std::uint32_t k;
      std::memcpy(&k, buf_ + i, 4);
      h = rotl(h ^ (std::uint64_t(k) * kP1), 23) * kP2 + kP3;
      i += 4;
    }
    for (; i < fill_; ++i) h = rotl(h ^ (buf_[i] * kP5), 11) * kP1;
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
  static constexpr int kStripe = 32;
  static std::uint64_t rotl(std::uint64_t x, int r) { return (x << r) | (x >> (64 - r)); }
  static std::uint64_t read64(const unsigned char* p) {
    std::uint64_t k;
    std::memcpy(&k, p, 8);
    return k;
  }
  static std::uint64_t round(std::uint64_t acc, std::uint64_t input) { return rotl(acc + input * kP2, 31) * kP1; }
  void stripe(const unsigned char* p) {
    v_[0] = round(v_[0], read64(p));
    v_[1] = round(v_[1], read64(p + 8));
    v_[2] = round(v_[2], read64(p + 16));
    v_[3] = round(v_[3], read64(p + 24));
  }

  std::uint64_t seed_;
  std::uint64_t v_[4];
  std::uint64_t total_{0};
  unsigned char buf_[kStripe]{};
  int fill_{0};
};

}  // namespace vx
