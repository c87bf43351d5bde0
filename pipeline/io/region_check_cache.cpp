#include "io/region_check_cache.h"

#include <fmt/core.h>

#include <cmath>
#include <utility>

#include "io/cache_file.h"

namespace vx {

namespace {

constexpr FolderCacheWords kWords{"region check cache", "region check", ".vxregion",
                                  "the region check solves its estimate as without a cache"};
constexpr char kMagic[8] = {'V', 'X', 'R', 'E', 'G', 'N', '\n', '\0'};
/// Raised when the file form changes (what the estimate computes is in its key:
/// region_stiffening.cpp, kEstimateVersion).
constexpr std::uint32_t kFormatVersion = 1;

/// The estimate's numbers in the one order the file holds them: f(value).
template <typename E, typename F>
void for_each_number(E& e, F&& f) {
  f(e.load_nodes);
  f(e.region_nodes);
  f(e.far_nodes);
  f(e.iterations_full);
  f(e.iterations_region);
  f(e.compliance_full_mm_n);
  f(e.compliance_region_mm_n);
  f(e.force_ratio);
  f(e.seconds);
}

}  // namespace

std::string region_check_name(std::uint64_t key, int free_nodes) {
  return fmt::format("regioncheck-{}n-{:016x}", free_nodes, key);
}

void write_region_check_file(std::ostream& out, std::uint64_t key, int free_nodes,
                             const RegionStiffeningEstimate& estimate) {
  CacheFileWriter w(out);
  w.header(kMagic, kFormatVersion);
  w.value(key);
  w.value(std::int32_t(free_nodes));
  for_each_number(estimate, [&w](const auto& v) { w.value(v); });
  w.finish();
}

std::optional<RegionStiffeningEstimate> read_region_check_file(const unsigned char* data, std::size_t bytes,
                                                               std::uint64_t key, int free_nodes, std::string* why) {
  const auto fail = [&](std::string what) -> std::optional<RegionStiffeningEstimate> {
    if (why) *why = std::move(what);
    return std::nullopt;
  };
  CacheFileReader r(data, bytes);
  r.header(kMagic, kFormatVersion, "not a region check file");
  std::uint64_t stored_key = 0;
  std::int32_t stored_nodes = 0;
  r.value(stored_key, "the key");
  r.value(stored_nodes, "the key");
  if (!r.ok()) return fail(r.error());
  if (stored_key != key || stored_nodes != free_nodes)
    return fail("the file holds another model's or support's estimate");
  RegionStiffeningEstimate e;
  for_each_number(e, [&r](auto& v) { r.value(v, "the estimate"); });
  r.finish();
  if (!r.ok()) return fail(r.error());
  const bool counts = e.load_nodes > 0 && e.region_nodes >= 0 && e.far_nodes > 0 &&
                      std::int64_t(e.region_nodes) + e.far_nodes == free_nodes && e.iterations_full >= 0 &&
                      e.iterations_region >= 0;
  const bool numbers = std::isfinite(e.compliance_full_mm_n) && std::isfinite(e.compliance_region_mm_n) &&
                       e.compliance_region_mm_n > 0 && e.compliance_full_mm_n > 0 && std::isfinite(e.force_ratio) &&
                       e.force_ratio > 0 && std::isfinite(e.seconds) && e.seconds >= 0;
  if (!counts || !numbers) return fail("its numbers are out of range");
  e.valid = true;
  return e;
}

RegionCheckCache::RegionCheckCache(RegionCheckCacheSettings settings)
    : settings_(std::move(settings)), folder_(kWords, settings_.folder, settings_.max_bytes) {}

std::optional<RegionStiffeningEstimate> RegionCheckCache::load(std::uint64_t key, int free_nodes) {
  std::optional<RegionStiffeningEstimate> e;
  folder_.load(region_check_name(key, free_nodes), fmt::format("{} free nodes", free_nodes),
               [&](const unsigned char* data, std::size_t bytes, const std::shared_ptr<const void>&, std::string& why) {
                 e = read_region_check_file(data, bytes, key, free_nodes, &why);
                 return e.has_value();
               });
  return e;
}

void RegionCheckCache::store(std::uint64_t key, int free_nodes, const RegionStiffeningEstimate& estimate) {
  folder_.store({.name = region_check_name(key, free_nodes),
                 .seconds = estimate.seconds,
                 .min_seconds = settings_.min_seconds,
                 .made = fmt::format("solved in {:.2f} s", estimate.seconds),
                 .next_start = "this organ on this support"},
                [&](std::ostream& out) { write_region_check_file(out, key, free_nodes, estimate); });
}

std::shared_ptr<RegionCheckCache> make_region_check_cache(const std::string& option) {
  return make_folder_cache<RegionCheckCache>(option, &RegionCheckCacheSettings::min_seconds);
}

}  // namespace vx
