#include "io/factor_cache.h"

#include <utility>

#include "io/cache_file.h"
#include "util/log.h"

namespace vx {
namespace {

constexpr FolderCacheWords kWords{"factor cache", "factor", ".vxfactor", "the solver factors as without a cache"};
constexpr FolderCacheWords kOrderWords{"factor cache", "order", ".vxorder",
                                       "METIS orders the matrix as without a cache"};
constexpr char kOrderMagic[8] = {'V', 'X', 'O', 'R', 'D', 'E', 'R', '\n'};
constexpr std::uint32_t kOrderVersion = 1;

}  // namespace

std::shared_ptr<FactorCache> make_factor_cache(const std::string& option) {
  return make_folder_cache<FolderFactorCache>(option, &FactorCacheSettings::min_factor_s,
                                              [](FactorCacheSettings& s) { s.background_writes = true; });
}

void write_order_file(std::ostream& out, const FactorKey& pattern, const std::vector<int>& order) {
  CacheFileWriter w(out);
  w.header(kOrderMagic, kOrderVersion);
  w.value(pattern.hash);
  w.value(pattern.rows);
  w.value(pattern.nonzeros);
  w.array(order);
  w.finish();
}

bool read_order_file(const unsigned char* data, std::size_t bytes, const FactorKey& pattern, std::vector<int>& order,
                     std::string* why) {
  const auto fail = [&](std::string what) {
    if (why) *why = std::move(what);
    order.clear();
    return false;
  };
  CacheFileReader r(data, bytes);
  r.header(kOrderMagic, kOrderVersion, "not an order file");
  FactorKey stored;
  r.value(stored.hash, "the key");
  r.value(stored.rows, "the key");
  r.value(stored.nonzeros, "the key");
  if (!r.ok()) return fail(r.error());
  if (stored.hash != pattern.hash || stored.rows != pattern.rows || stored.nonzeros != pattern.nonzeros)
    return fail("the file holds another matrix pattern's order");
  r.copy(order, pattern.rows, "the order");
  r.finish("the order");
  if (!r.ok()) return fail(r.error());
  std::vector<std::uint8_t> seen(order.size(), 0);
  for (const int row : order) {
    if (row < 0 || std::size_t(row) >= order.size() || seen[std::size_t(row)])
      return fail("the order is not a permutation of the matrix's rows");
    seen[std::size_t(row)] = 1;
  }
  return true;
}

FolderFactorCache::FolderFactorCache(FactorCacheSettings settings)
    : settings_(std::move(settings)),
      folder_(kWords, settings_.folder, settings_.max_bytes),
      orders_(kOrderWords, settings_.folder, settings_.max_bytes) {}

std::string FolderFactorCache::order_name(const FactorKey& pattern) {
  return fmt::format("order-{}n-{}nz-{:016x}", pattern.rows, pattern.nonzeros, pattern.hash);
}

bool FolderFactorCache::load_order(const FactorKey& pattern, std::vector<int>& order) {
  order.clear();
  return orders_.load(order_name(pattern), fmt::format("{} rows", pattern.rows),
                      [&](const unsigned char* data, std::size_t bytes, const std::shared_ptr<const void>&,
                          std::string& why) { return read_order_file(data, bytes, pattern, order, &why); });
}

void FolderFactorCache::store_order(const FactorKey& pattern, const SparseFactor& factor) {
  const double seconds = factor.order_seconds();
  const std::vector<int> order = factor.order();
  orders_.store({.name = order_name(pattern),
                 .seconds = seconds,
                 .min_seconds = settings_.min_factor_s,
                 .bytes = 64 + order.size() * sizeof(int),
                 .made = fmt::format("ordered in {:.1f} s", seconds),
                 .next_start = "this model with another material or step"},
                [&](std::ostream& out) { write_order_file(out, pattern, order); });
}

bool FolderFactorCache::load(const FactorKey& key, SparseFactor& factor) {
  return folder_.load(key.name(), fmt::format("{} rows", key.rows),
                      [&](const unsigned char* data, std::size_t bytes, const std::shared_ptr<const void>& mapping,
                          std::string& why) { return factor.read(data, bytes, mapping, &why); });
}

void FolderFactorCache::store(const FactorKey& key, const SparseFactor& factor) {
  const double seconds = factor.factor_seconds();
  // a factor over the folder's limit is not written (its size is known before)
  FolderCache::Offer offer{.name = key.name(),
                           .seconds = seconds,
                           .min_seconds = settings_.min_factor_s,
                           .bytes = factor.stored_bytes(),
                           .made = fmt::format("factored in {:.1f} s", seconds),
                           .next_start = "this model"};
  if (!settings_.background_writes || seconds < offer.min_seconds) {
    folder_.store(offer, [&](std::ostream& out) { factor.write(out); });
    return;
  }
  // the solver goes on with its factor while a copy that shares its arrays is written (read-only
  // on both threads)
  auto copy = std::make_shared<const SparseFactor>(factor.file_copy());
  folder_.store_beside(
      std::move(offer), [copy = std::move(copy)](std::ostream& out) { copy->write(out); }, "vx-factor-write",
      settings_.writer_nice);
}

}  // namespace vx
