#include "io/factor_cache.h"

#include <system_error>
#include <utility>

#include "io/cache_file.h"
#include "util/log.h"
#include "util/thread_priority.h"

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
  wait_for_writes();  // a factor stored is found (a write begun is finished first)
  return folder_.load(key.name(), fmt::format("{} rows", key.rows),
                      [&](const unsigned char* data, std::size_t bytes, const std::shared_ptr<const void>& mapping,
                          std::string& why) { return factor.read(data, bytes, mapping, &why); });
}

FolderFactorCache::~FolderFactorCache() { wait_for_writes(); }

void FolderFactorCache::wait_for_writes() {
  std::vector<std::thread> writes;
  {
    std::lock_guard lock(writes_mutex_);
    writes.swap(writes_);
  }
  for (std::thread& t : writes) t.join();
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
  // on both threads); FolderCache::store keeps the folder locked meanwhile, so a load waits
  auto copy = std::make_shared<const SparseFactor>(factor.file_copy());
  const auto write = [this, offer = std::move(offer), copy = std::move(copy)](bool beside) {
    if (beside) {
      (void)set_this_thread_name("vx-factor-write");  // as the run's other threads, for top -H and perf
      if (settings_.writer_nice != 0) (void)set_this_thread_nice(settings_.writer_nice);
    }
    folder_.store(offer, [&](std::ostream& out) { copy->write(out); });
  };
  std::lock_guard lock(writes_mutex_);
  try {
    writes_.emplace_back(write, true);  // copies `write`: it is still whole should this throw
  } catch (const std::system_error& e) {
    // no thread to be had: written here, as without background writes (a store never stops a run)
    log::debug(fmt::format("factor cache: no thread for the write ({}); writing it now", e.what()));
    write(false);
  }
}

}  // namespace vx
