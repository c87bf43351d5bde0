#include "io/surface_cache.h"

#include <fmt/core.h>
#include <vtkVersionMacros.h>

#include <cstring>
#include <type_traits>
#include <utility>

#include "io/cache_file.h"
#include "physics/calibration_key.h"

namespace vx {
namespace fs = std::filesystem;

namespace {

constexpr FolderCacheWords kWords{"display surface cache", "display surface", ".vxsurf",
                                  "the surface is built and decimated as without a cache"};
constexpr char kMagic[8] = {'V', 'X', 'S', 'U', 'R', 'F', '\n', '\0'};
/// Raised when the file form or what decimate_surface makes of the same input changes.
constexpr std::uint32_t kFormatVersion = 1;

void write_header(CacheFileWriter& w, const SurfaceKey& key) {
  w.header(kMagic, kFormatVersion);
  w.value(std::uint32_t(0));
  w.value(key.hash);
  w.value(key.model_nodes);
  w.value(key.target);
}

/// The surface's content in the one order in which the key hashes it and the file holds it:
/// f(part) for the method and the node count (int32) and each array.
template <typename F>
void for_each_surface_part(const EmbeddedSurface& s, F&& f) {
  f(std::int32_t(s.method));
  f(std::int32_t(s.model_nodes));
  f(s.rest_vertices);
  f(s.triangles);
  f(s.embed_offsets);
  f(s.embed_nodes);
  f(s.embed_weights);
}

}  // namespace

std::string SurfaceKey::name() const { return fmt::format("surface-{}n-{}t-{:016x}", model_nodes, target, hash); }

ContentHash surface_key_hash(const Model& model, int target_triangles, double feature_angle_deg) {
  ContentHash h;
  h.add_value(kFormatVersion);
  const char vtk[] = VTK_VERSION;
  h.add(vtk, sizeof vtk);
  add_model_content(h, model);
  h.add_value(std::int32_t(target_triangles));
  h.add_value(feature_angle_deg);
  return h;
}

void add_surface_content(ContentHash& h, const EmbeddedSurface& s) {
  for_each_surface_part(s, [&h](const auto& v) {
    using V = std::decay_t<decltype(v)>;
    if constexpr (std::is_arithmetic_v<V>)
      h.add_value(v);
    else if constexpr (std::is_base_of_v<Eigen::EigenBase<V>, V>)
      h.add_matrix(v);
    else
      h.add_vector(v);
  });
}

void write_surface_cache_file(std::ostream& out, const SurfaceKey& key, const CachedSurface& cached) {
  const EmbeddedSurface& s = cached.surface;
  CacheFileWriter w(out);
  write_header(w, key);
  w.value(cached.source_triangles);
  w.value(cached.source_vertices);
  for_each_surface_part(s, [&w](const auto& v) {
    if constexpr (std::is_arithmetic_v<std::decay_t<decltype(v)>>)
      w.value(v);
    else
      w.array(v);
  });
  w.finish();
}

std::optional<CachedSurface> read_surface_cache_file(const unsigned char* data, std::size_t bytes,
                                                     const SurfaceKey& key, std::string* why) {
  const auto fail = [&](std::string what) -> std::optional<CachedSurface> {
    if (why) *why = std::move(what);
    return std::nullopt;
  };
  CacheFileReader r(data, bytes);
  const unsigned char* magic = r.bytes(sizeof kMagic, "magic");
  if (!magic || std::memcmp(magic, kMagic, sizeof kMagic) != 0) return fail("not a display surface file");
  std::uint32_t version = 0, reserved = 0;
  SurfaceKey stored;
  r.value(version, "format version");
  r.value(reserved, "reserved");
  r.value(stored.hash, "key");
  r.value(stored.model_nodes, "key");
  r.value(stored.target, "key");
  if (!r.ok()) return fail(r.error());
  if (version != kFormatVersion)
    return fail(fmt::format("format version {} (this build reads {})", version, kFormatVersion));
  if (!(stored == key)) return fail("the file holds another surface's decimation");
  CachedSurface c;
  EmbeddedSurface& s = c.surface;
  std::int32_t method = 0, nodes = 0;
  r.value(c.source_triangles, "source size");
  r.value(c.source_vertices, "source size");
  r.value(method, "method");
  r.value(nodes, "model nodes");
  if (!r.ok()) return fail(r.error());
  if (method < 0 || method > std::int32_t(SurfaceMethod::iso)) return fail("unknown surface method");
  s.method = SurfaceMethod(method);
  s.model_nodes = nodes;
  if (nodes != key.model_nodes)
    return fail(fmt::format("embedded in {} nodes, the model has {}", nodes, key.model_nodes));
  r.matrix(s.rest_vertices, 3, -1, "vertices", "points");
  r.matrix(s.triangles, 3, -1, "triangles", "triangles");
  r.copy(s.embed_offsets, s.rest_vertices.cols() + 1, "embedding offsets");
  r.copy(s.embed_nodes, -1, "embedding nodes");
  r.copy(s.embed_weights, std::int64_t(s.embed_nodes.size()), "embedding weights");
  r.finish();
  if (!r.ok()) return fail(r.error());
  if (const std::string bad = s.validate(); !bad.empty()) return fail(bad);
  s.finalize();
  return c;
}

SurfaceCache::SurfaceCache(SurfaceCacheSettings settings)
    : settings_(std::move(settings)), folder_(kWords, settings_.folder, settings_.max_bytes) {}

std::optional<CachedSurface> SurfaceCache::load(const SurfaceKey& key) {
  std::optional<CachedSurface> s;
  folder_.load(key.name(), fmt::format("{} nodes", key.model_nodes),
               [&](const unsigned char* data, std::size_t bytes, const std::shared_ptr<const void>&, std::string& why) {
                 s = read_surface_cache_file(data, bytes, key, &why);
                 return s.has_value();
               });
  return s;
}

void SurfaceCache::store(const SurfaceKey& key, const CachedSurface& cached, double seconds) {
  folder_.store({.name = key.name(),
                 .seconds = seconds,
                 .min_seconds = settings_.min_seconds,
                 .made = fmt::format("built and decimated in {:.2f} s", seconds),
                 .next_start = "this organ"},
                [&](std::ostream& out) { write_surface_cache_file(out, key, cached); });
}

std::shared_ptr<SurfaceCache> make_surface_cache(const std::string& option) {
  return make_folder_cache<SurfaceCache>(option, &SurfaceCacheSettings::min_seconds);
}

}  // namespace vx
