#include "sim/sparse_factor.h"
// The factor as bytes (sparse_factor.h write / read): the factor cache's file form.

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include "base/cache_file_format.h"

namespace vx {

namespace {

constexpr char kMagic[8] = {'V', 'X', 'F', 'A', 'C', 'T', 'O', 'R'};
/// 3: the values' bytes (8: double, 4: single, SparseFactor::use_single_precision_sweeps)
/// before them.
constexpr std::uint32_t kFormatVersion = 3;

/// An array of T in place (aligned for T) and its count; null on failure.
template <typename T>
std::pair<const T*, std::size_t> typed_array(CacheFileReader& r, const char* what) {
  const auto [p, n] = r.array(sizeof(T), -1, what);
  if (!p) return {nullptr, 0};
  if (reinterpret_cast<std::uintptr_t>(p) % alignof(T) != 0) {
    r.fail("the data is not aligned");
    return {nullptr, 0};
  }
  return {reinterpret_cast<const T*>(p), n};
}

/// Copies an array of any count.
template <typename T>
void copy(CacheFileReader& r, std::vector<T>& v, const char* what) {
  const auto [p, n] = typed_array<T>(r, what);
  if (p) v.assign(p, p + n);
}

/// Views an array (with `keep`) or copies it.
template <typename T>
void share(CacheFileReader& r, SharedArray<T>& v, const std::shared_ptr<const void>& keep, const char* what) {
  const auto [p, n] = typed_array<T>(r, what);
  if (!p) return;
  if (keep)
    v.view(p, n, keep);
  else
    v.own(std::vector<T>(p, p + n));
}

/// True when v holds 0 .. v.size()-1 each once.
bool is_permutation(const std::vector<int>& v) {
  std::vector<std::uint8_t> seen(v.size(), 0);
  for (int x : v) {
    if (x < 0 || std::size_t(x) >= v.size() || seen[std::size_t(x)]) return false;
    seen[std::size_t(x)] = 1;
  }
  return true;
}

}  // namespace

std::string FactorKey::name() const {
  char hex[17];
  static constexpr char kDigits[] = "0123456789abcdef";
  for (int i = 0; i < 16; ++i) hex[i] = kDigits[(hash >> (60 - 4 * i)) & 0xF];
  hex[16] = 0;
  return std::string(SparseFactor::to_string(SparseFactor::Backend(backend))) + "-" + std::to_string(rows) + "n-" +
         std::to_string(nonzeros) + "nz-" + hex + (single ? "-single" : "");
}

std::uint64_t SparseFactor::stored_bytes() const {
  const auto b = [](const auto& v) { return std::uint64_t(v.size() * sizeof(v[0])); };
  return 64 + b(perm_) + b(values_) + b(values_single_) +
         (supernodal_ ? b(super_) + b(rows_) + b(row_start_) + b(value_start_) : b(outer_) + b(inner_) + b(inv_d_));
}

SparseFactor SparseFactor::file_copy() const {
  // write()'s members only: the values and row indices shared (SharedArray), the rest a few MB
  SparseFactor c;
  c.size_ = size_;
  c.backend_ = backend_;
  c.supernodal_ = supernodal_;
  c.perm_ = perm_;
  c.values_ = values_;
  c.values_single_ = values_single_;
  if (supernodal_) {
    c.super_ = super_;
    c.rows_ = rows_;
    c.row_start_ = row_start_;
    c.value_start_ = value_start_;
  } else {
    c.outer_ = outer_;
    c.inner_ = inner_;
    c.inv_d_ = inv_d_;
  }
  return c;
}

void SparseFactor::write(std::ostream& out) const {
  CacheFileWriter w(out);
  w.header(kMagic, kFormatVersion);
  w.value(std::uint32_t(sizeof(int)));
  w.value(std::uint8_t(backend_));
  w.value(std::uint8_t(supernodal_ ? 1 : 0));
  w.value(std::int64_t(size_));
  w.array(perm_);
  const bool single = single_precision_sweeps();
  w.value(std::uint8_t(single ? sizeof(float) : sizeof(double)));
  if (single)
    w.array(values_single_);
  else
    w.array(values_);
  if (supernodal_) {
    w.array(super_);
    w.array(rows_);
    w.array(row_start_);
    w.array(value_start_);
  } else {
    w.array(outer_);
    w.array(inner_);
    w.array(inv_d_);
  }
  w.finish("sparse factor: writing the factor failed (disk full?)");
}

bool SparseFactor::read(const unsigned char* data, std::size_t bytes, std::shared_ptr<const void> keep,
                        std::string* why) {
  const auto t0 = std::chrono::steady_clock::now();
  reset();
  CacheFileReader r(data, bytes);
  std::uint32_t int_bytes = 0;
  std::uint8_t backend = 0, supernodal = 0, value_bytes = 0;
  std::int64_t n = 0;
  r.header(kMagic, kFormatVersion, "not a voxelastic factor file");
  r.value(int_bytes, "the header");
  r.value(backend, "the header");
  r.value(supernodal, "the header");
  r.value(n, "the header");
  if (r.ok() && (int_bytes != sizeof(int) || backend > std::uint8_t(Backend::eigen_amd) || supernodal > 1 || n < 0 ||
                 n > std::numeric_limits<int>::max()))
    r.fail("a header this build cannot read");
  copy(r, perm_, "the permutation");
  r.value(value_bytes, "the values' precision");
  if (r.ok() && value_bytes != sizeof(double) && !(value_bytes == sizeof(float) && supernodal == 1))
    r.fail("values of a precision this build cannot read");
  if (value_bytes == sizeof(float))
    share(r, values_single_, keep, "the values");
  else
    share(r, values_, keep, "the values");
  if (supernodal) {
    copy(r, super_, "the supernodes");
    share(r, rows_, keep, "the row indices");
    copy(r, row_start_, "the row starts");
    copy(r, value_start_, "the value starts");
  } else {
    copy(r, outer_, "the column starts");
    copy(r, inner_, "the row indices");
    copy(r, inv_d_, "the diagonal");
  }
  r.finish("the factor");
  // the structure: whatever a solve indexes must be in range
  const int size = int(n);
  if (r.ok() && (perm_.size() != std::size_t(size) || !is_permutation(perm_)))
    r.fail("the permutation is not one of the matrix's rows");
  if (r.ok() && supernodal) {
    const std::size_t ns = super_.empty() ? 0 : super_.size() - 1;
    bool good = !super_.empty() && super_.front() == 0 && super_.back() == size && row_start_.size() == ns + 1 &&
                value_start_.size() == ns + 1 && row_start_.front() == 0 && value_start_.front() == 0 &&
                row_start_.back() == std::int64_t(rows_.size()) &&
                value_start_.back() == std::int64_t(values_.size() + values_single_.size());
    for (std::size_t q = 0; good && q < ns; ++q) {
      const std::int64_t nscol = std::int64_t(super_[q + 1]) - super_[q];
      const std::int64_t nsrow = row_start_[q + 1] - row_start_[q];
      good = nscol > 0 && nsrow >= nscol && value_start_[q + 1] - value_start_[q] == nsrow * nscol;
      // a supernode's rows: its own columns, then rows below them, ascending and in range
      for (std::int64_t k = 0; good && k < nsrow; ++k) {
        const int row = rows_[std::size_t(row_start_[q] + k)];
        good = k < nscol ? row == super_[q] + int(k)
                         : row >= super_[q + 1] && row < size && row > rows_[std::size_t(row_start_[q] + k - 1)];
      }
    }
    if (!good) r.fail("the supernodes do not tile the matrix");
  } else if (r.ok()) {
    bool good = outer_.size() == std::size_t(size) + 1 && outer_.front() == 0 &&
                outer_.back() == std::int64_t(inner_.size()) && inner_.size() == values_.size() &&
                inv_d_.size() == std::size_t(size);
    for (int j = 0; good && j < size; ++j) {
      good = outer_[std::size_t(j)] <= outer_[std::size_t(j) + 1] && inv_d_[std::size_t(j)] > 0 &&
             std::isfinite(inv_d_[std::size_t(j)]);
      for (std::int64_t p = outer_[std::size_t(j)]; good && p < outer_[std::size_t(j) + 1]; ++p)
        good = inner_[std::size_t(p)] > j && inner_[std::size_t(p)] < size;
    }
    if (!good) r.fail("the columns are not a lower triangle of the matrix");
  }
  size_ = size;
  supernodal_ = supernodal != 0;
  if (r.ok() && supernodal_ && !index_supernodes()) r.fail("a diagonal entry is not positive");
  if (!r.ok()) {
    if (why) *why = r.error();
    reset();
    return false;
  }
  backend_ = Backend(backend);
  finish();
  from_cache_ = true;
  factor_s_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

}  // namespace vx
