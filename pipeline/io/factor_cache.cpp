#include "io/factor_cache.h"

#include <utility>

#include "util/log.h"

namespace vx {
namespace {

constexpr FolderCacheWords kWords{"factor cache", "factor", ".vxfactor", "the solver factors as without a cache"};

}  // namespace

std::shared_ptr<FactorCache> make_factor_cache(const std::string& option) {
  return make_folder_cache<FolderFactorCache>(option, &FactorCacheSettings::min_factor_s);
}

FolderFactorCache::FolderFactorCache(FactorCacheSettings settings)
    : settings_(std::move(settings)), folder_(kWords, settings_.folder, settings_.max_bytes) {}

bool FolderFactorCache::load(const FactorKey& key, SparseFactor& factor) {
  return folder_.load(key.name(), fmt::format("{} rows", key.rows),
                      [&](const unsigned char* data, std::size_t bytes, const std::shared_ptr<const void>& mapping,
                          std::string& why) { return factor.read(data, bytes, mapping, &why); });
}

void FolderFactorCache::store(const FactorKey& key, const SparseFactor& factor) {
  const double seconds = factor.factor_seconds();
  // a factor over the folder's limit is not written (its size is known before)
  folder_.store({.name = key.name(),
                 .seconds = seconds,
                 .min_seconds = settings_.min_factor_s,
                 .bytes = factor.stored_bytes(),
                 .made = fmt::format("factored in {:.1f} s", seconds),
                 .next_start = "this model"},
                [&](std::ostream& out) { factor.write(out); });
}

}  // namespace vx
