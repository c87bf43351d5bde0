#include "io/surface_cache.h"

#include <fmt/core.h>
#include <vtkVersionMacros.h>

#include <chrono>
#include <cstring>
#include <fstream>
#include <system_error>
#include <utility>

#include "base/error.h"
#include "io/cache_file.h"
#include "io/factor_cache.h"
#include "physics/calibration_key.h"
#include "util/atomic_file.h"
#include "util/log.h"

namespace vx {
namespace fs = std::filesystem;

namespace {

constexpr const char* kExtension = ".vxsurf";
constexpr char kMagic[8] = {'V', 'X', 'S', 'U', 'R', 'F', '\n', '\0'};
/// Raised when the file form or what decimate_surface makes of the same input changes.
constexpr std::uint32_t kFormatVersion = 1;

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

template <typename Derived>
void add_matrix(ContentHash& h, const Eigen::DenseBase<Derived>& m) {
  h.add_value(std::int64_t(m.rows()));
  h.add_value(std::int64_t(m.cols()));
  if (m.size() > 0) h.add(m.derived().data(), std::size_t(m.size()) * sizeof(typename Derived::Scalar));
}

template <typename T>
void add_vector(ContentHash& h, const std::vector<T>& v) {
  h.add_value(std::uint64_t(v.size()));
  if (!v.empty()) h.add(v.data(), v.size() * sizeof(T));
}

void write_header(CacheFileWriter& w, const SurfaceKey& key) {
  w.bytes(kMagic, sizeof kMagic);
  w.value(kFormatVersion);
  w.value(std::uint32_t(0));
  w.value(key.hash);
  w.value(key.model_nodes);
  w.value(key.target);
}

}  // namespace

std::string SurfaceKey::name() const {
  return fmt::format("surface-{}n-{}t-{:016x}", model_nodes, target, hash);
}

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
  h.add_value(std::int32_t(s.method));
  h.add_value(std::int32_t(s.model_nodes));
  add_matrix(h, s.rest_vertices);
  add_matrix(h, s.triangles);
  add_vector(h, s.embed_offsets);
  add_vector(h, s.embed_nodes);
  add_vector(h, s.embed_weights);
}

void write_surface_cache_file(std::ostream& out, const SurfaceKey& key, const CachedSurface& cached) {
  const EmbeddedSurface& s = cached.surface;
  CacheFileWriter w(out);
  write_header(w, key);
  w.value(cached.source_triangles);
  w.value(cached.source_vertices);
  w.value(std::int32_t(s.method));
  w.value(std::int32_t(s.model_nodes));
  w.array(s.rest_vertices.data(), std::size_t(s.rest_vertices.size()), sizeof(double));
  w.array(s.triangles.data(), std::size_t(s.triangles.size()), sizeof(int));
  w.array(s.embed_offsets);
  w.array(s.embed_nodes);
  w.array(s.embed_weights);
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
  if (version != kFormatVersion) return fail(fmt::format("format version {} (this build reads {})", version, kFormatVersion));
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
  if (nodes != key.model_nodes) return fail(fmt::format("embedded in {} nodes, the model has {}", nodes, key.model_nodes));
  {
    const auto [p, n] = r.array(sizeof(double), -1, "vertices");
    if (p && n % 3 != 0) r.fail("vertices: not a whole number of points");
    if (r.ok()) {
      s.rest_vertices.resize(3, Eigen::Index(n / 3));
      if (n > 0) std::memcpy(s.rest_vertices.data(), p, n * sizeof(double));
    }
  }
  {
    const auto [p, n] = r.array(sizeof(int), -1, "triangles");
    if (p && n % 3 != 0) r.fail("triangles: not a whole number of triangles");
    if (r.ok()) {
      s.triangles.resize(3, Eigen::Index(n / 3));
      if (n > 0) std::memcpy(s.triangles.data(), p, n * sizeof(int));
    }
  }
  r.copy(s.embed_offsets, s.rest_vertices.cols() + 1, "embedding offsets");
  r.copy(s.embed_nodes, -1, "embedding nodes");
  r.copy(s.embed_weights, std::int64_t(s.embed_nodes.size()), "embedding weights");
  r.finish();
  if (!r.ok()) return fail(r.error());
  if (const std::string bad = s.validate(); !bad.empty()) return fail(bad);
  s.finalize();
  return c;
}

SurfaceCache::SurfaceCache(SurfaceCacheSettings settings) : settings_(std::move(settings)) {}

fs::path SurfaceCache::file_of(const SurfaceKey& key) const { return settings_.folder / (key.name() + kExtension); }

SurfaceCache::Counters SurfaceCache::counters() const {
  std::lock_guard lock(mutex_);
  return counters_;
}

void SurfaceCache::complain(const std::string& what) {
  if (!complained_) {
    complained_ = true;
    log::warn("display surface cache: {} (the surface is decimated as without a cache; --factor-cache off silences this)",
              what);
  } else {
    log::debug("display surface cache: {}", what);
  }
}

std::optional<CachedSurface> SurfaceCache::load(const SurfaceKey& key) {
  std::lock_guard lock(mutex_);
  const fs::path file = file_of(key);
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(file, ec);
  if (ec) {
    ++counters_.misses;
    return std::nullopt;
  }
  std::string why;
  const std::shared_ptr<const void> mapping = map_cache_file(file, std::size_t(size), why);
  std::optional<CachedSurface> s;
  if (mapping) s = read_surface_cache_file(static_cast<const unsigned char*>(mapping.get()), std::size_t(size), key, &why);
  if (!s) {
    ++counters_.misses;
    ++counters_.damaged;
    fs::remove(file, ec);
    complain(fmt::format("{} could not be read ({}); removed it", file.string(), why));
    return std::nullopt;
  }
  ++counters_.hits;
  touch_cache_file(file);  // recently used: kept longest
  return s;
}

void SurfaceCache::store(const SurfaceKey& key, const CachedSurface& cached, double seconds) {
  std::lock_guard lock(mutex_);
  if (seconds < settings_.min_seconds) {
    ++counters_.skipped;
    return;
  }
  const fs::path file = file_of(key);
  try {
    std::error_code ec;
    fs::create_directories(settings_.folder, ec);
    if (ec) throw Error(fmt::format("cannot create {} ({})", settings_.folder.string(), ec.message()));
    write_atomically(
        file,
        [&](const fs::path& tmp) {
          std::ofstream out(tmp, std::ios::binary);
          if (!out) throw Error(fmt::format("cannot write {}", tmp.string()));
          write_surface_cache_file(out, key, cached);
          out.close();
          if (!out) throw Error(fmt::format("writing {} failed (disk full?)", tmp.string()));
        },
        Durability::process_crash);
  } catch (const std::exception& e) {
    complain(fmt::format("the display surface could not be kept: {}", e.what()));
    return;
  }
  ++counters_.stored;
  (void)evict_cache_files(settings_.folder, settings_.max_bytes, file);
}

std::shared_ptr<SurfaceCache> make_surface_cache(const std::string& option) {
  if (option == "off") return nullptr;
  const std::optional<fs::path> folder =
      option.empty() ? default_factor_cache_folder() : std::optional<fs::path>(fs::path(option));
  if (!folder) return nullptr;
  SurfaceCacheSettings s;
  s.folder = *folder;
  s.min_seconds = cache_min_seconds(s.min_seconds);
  return std::make_shared<SurfaceCache>(std::move(s));
}

}  // namespace vx
