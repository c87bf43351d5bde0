#pragma once
/// @file surface_cache.h
/// The display surface cache: the probe app's decimated display surface (convert/
/// decimate_surface.h: vtkDecimatePro or vtkQuadricDecimation, then the embedding of the moved
/// vertices) kept by the content of what it was decimated from, so the second start of an organ
/// loads what the first computed (the folded organ: 550,508 -> 99,999 triangles in 9 to 10 s on
/// the development machine, quiet; docs/probe.md). It lives in the factor cache's folder
/// (factor_cache.h: the same option `--factor-cache`, environment variable and size limit over
/// every kind of cache file; cache_file.h).
///
/// One file per surface, `surface-<nodes>n-<target>t-<hash>.vxsurf`: a header (magic,
/// format version, the key), the arrays at 64-byte boundaries, a checksum; written to a
/// temporary name and renamed; read back through a mapping and checked (header, key, the
/// checksum, EmbeddedSurface::validate against the model's node count): a damaged file is
/// removed with a warning and the surface decimated. Nothing here may stop a run.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <ostream>
#include <string>

#include "base/content_hash.h"
#include "io/folder_cache.h"
#include "model/model.h"
#include "surface/surface.h"

namespace vx {

/// What a display surface is the decimation of: a 64-bit hash of everything it depends on (the
/// model's content, every array as the calibration key hashes it, and either the full surface
/// or what it is built from: convert/decimate_surface.h), the decimation's settings, the VTK
/// version and a format version.
struct SurfaceKey {
  std::uint64_t hash{0};
  std::int64_t model_nodes{0};  ///< for the file name (the hash holds the content)
  std::int64_t target{0};       ///< triangles wanted
  /// A file-name-safe name: "surface-327231n-100000t-0123456789abcdef".
  [[nodiscard]] std::string name() const;
  [[nodiscard]] bool operator==(const SurfaceKey&) const = default;
};

/// A hash started with what every display surface key holds: the format version, the VTK
/// version, the model's content, the target and the feature angle.
[[nodiscard]] ContentHash surface_key_hash(const Model& model, int target_triangles, double feature_angle_deg);
/// Feeds `surface` to `h` (method, node count, vertices, triangles, embedding).
void add_surface_content(ContentHash& h, const EmbeddedSurface& surface);

/// What the cache keeps: the display surface, and the size of the full one it was decimated from
/// (for the log).
struct CachedSurface {
  EmbeddedSurface surface;
  std::int64_t source_triangles{0};
  std::int64_t source_vertices{0};
};

/// The file form of `cached` under `key`. Throws vx::Error when the stream fails.
void write_surface_cache_file(std::ostream& out, const SurfaceKey& key, const CachedSurface& cached);

/// Reads what write_surface_cache_file wrote (`bytes` bytes at `data`): the surface finalized
/// and validated. Nothing with `why` when it is not the surface of `key` or is damaged.
[[nodiscard]] std::optional<CachedSurface> read_surface_cache_file(const unsigned char* data, std::size_t bytes,
                                                                   const SurfaceKey& key, std::string* why);

struct SurfaceCacheSettings {
  std::filesystem::path folder;
  /// the folder's cache files (factors, calibrations, surfaces) together at most this many
  /// bytes; the least recently used go first
  std::uint64_t max_bytes{std::uint64_t(8) << 30};
  /// surfaces decimated faster than this are not kept, s
  double min_seconds{0.25};
};

/// Display surfaces in a folder (folder_cache.h does the folder's bookkeeping). Thread-safe.
class SurfaceCache {
 public:
  explicit SurfaceCache(SurfaceCacheSettings settings);
  /// The surface of `key`, or nothing (not there, or unreadable: then removed with a warning).
  [[nodiscard]] std::optional<CachedSurface> load(const SurfaceKey& key);
  /// Offers the surface of `key`, just made in `seconds` (wall time).
  void store(const SurfaceKey& key, const CachedSurface& cached, double seconds);
  [[nodiscard]] const SurfaceCacheSettings& settings() const { return settings_; }
  [[nodiscard]] std::filesystem::path file_of(const SurfaceKey& key) const { return folder_.file_of(key.name()); }
  /// hits: surfaces loaded; skipped: made faster than min_seconds (folder_cache.h)
  using Counters = FolderCacheCounters;
  [[nodiscard]] Counters counters() const { return folder_.counters(); }

 private:
  SurfaceCacheSettings settings_;
  FolderCache folder_;
};

/// The surface cache of a command-line option (`--factor-cache`), in the factor cache's folder:
/// "" the default folder (default_factor_cache_folder(), folder_cache.h, or none), "off" none, anything else a
/// folder. Null: no cache. $VOXELASTIC_FACTOR_CACHE_MIN_S sets min_seconds.
[[nodiscard]] std::shared_ptr<SurfaceCache> make_surface_cache(const std::string& option);

}  // namespace vx
