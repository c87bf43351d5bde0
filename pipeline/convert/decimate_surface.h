#pragma once
/// @file decimate_surface.h
/// A lighter surface for display: the rest-state surface decimated with VTK (vertex removal
/// that keeps its topology), each kept vertex with its embedding row of the full surface, so the
/// decimated surface moves exactly as the full one does at those vertices (affine motion of the
/// nodes exactly affinely), at a cost per frame proportional to its own size. A 350,000-triangle
/// brain becomes 100,000 triangles.

#include <Eigen/Core>
#include <atomic>
#include <functional>
#include <memory>
#include <string>

#include "base/error.h"
#include "convert/iso_surface.h"
#include "model/model.h"
#include "model/voxel_grid.h"
#include "surface/surface.h"

namespace vx {

class SurfaceCache;

/// How far to decimate.
struct DecimationSettings {
  /// Triangles wanted; a surface with at most this many is kept as it is; 0 = never decimate.
  int target_triangles{100000};
  /// vtkDecimatePro's feature angle, degrees: edges sharper than this keep their vertices. 10
  /// met the target within 10 % on a folded test surface (1 mm voxels, 2 mm sulci, 3.5x fewer
  /// triangles) with the least distance (0.42 mm; 15: 0.73 mm; 5 stopped 28 % above the target).
  double feature_angle_deg{10.0};
  /// When set and it turns true, a decimation under way stops (VTK's abort flag, which the
  /// filters read every 10,000 edge collapses) and decimate_surface throws DecimationCancelled:
  /// an app that quits before its background decimation ends (the probe app's first start of an
  /// organ). Null: never.
  const std::atomic<bool>* cancel{nullptr};
};

/// Thrown by decimate_surface when DecimationSettings::cancel turned true: nothing was kept.
class DecimationCancelled : public Error {
 public:
  DecimationCancelled() : Error("display surface: the decimation was cancelled") {}
};

/// What decimate_surface did.
struct DecimationReport {
  bool decimated{false};  ///< false: the surface was kept (small enough, 2D, or target 0)
  int triangles_before{0};
  int triangles_after{0};
  int vertices_before{0};
  int vertices_after{0};
  double decimate_s{0.0};  ///< wall time of the VTK decimation
  double embed_s{0.0};     ///< wall time of embedding the decimated vertices
  std::string method;      ///< the VTK filter that made it
  std::string embedding;   ///< "the full surface's" (kept vertices) or "embed_surface" (moved ones)
  bool from_cache{false};  ///< loaded from the display surface cache (io/surface_cache.h)
  bool preview{false};     ///< preview_surface's quick stand-in, the decimation still to come
  /// a preview made without the full surface (stage_display_surface_of_grid on a large
  /// iso-surface): extract_coarse_iso_surface on blocks of this many voxels a side; 0: not so.
  /// triangles_before is then the full surface's estimate (two per tissue voxel face).
  int preview_blocks{0};
  double build_s{0.0};  ///< display_surface_of_grid: wall time of building the full surface, s
  double cache_s{0.0};  ///< wall time of the key and the load (from_cache), s
  /// One line for a log, e.g. "display surface decimated 350768 -> 100002 triangles in 1.9 s".
  [[nodiscard]] std::string summary() const;
};

/// The display surface of `full` (embedded in `model`): `full` itself when it has at most
/// `settings.target_triangles` triangles, the target is 0, or it is a 2D slice sheet; else its
/// rest vertices and triangles decimated to the target by vtkDecimatePro with its topology
/// preserved (vertices removed, the others kept where they are: on the full surface), or, when
/// that stops more than 10 % above the target, by vtkQuadricDecimation (volume preserved; it may
/// pinch a narrow slit), keeping `full.method`. Kept vertices keep their embedding rows of
/// `full` (so the decimated surface moves exactly as the full one at those vertices, at no
/// embedding cost); moved ones (quadric) are embedded with embed_surface.
/// Triangles stay counter-clockwise seen from outside. Throws vx::Error when `full` does not
/// belong to `model` or VTK fails. With a `cache` (may be null) the decimation of the same model,
/// surface and settings is loaded from it when it holds one (the same arrays: what this function
/// computed and kept there at an earlier start), else computed and offered to it.
[[nodiscard]] EmbeddedSurface decimate_surface(const Model& model, const EmbeddedSurface& full,
                                               const DecimationSettings& settings = {},
                                               DecimationReport* report = nullptr, SurfaceCache* cache = nullptr);

/// The display surface of `model` built from `grid` (make_surface(model, grid, nullptr,
/// method, iso): the grid the model was built from) and decimated by decimate_surface. With a
/// `cache` (may be null), loaded from it when it holds the same (the key: the model, the grid,
/// the method, the iso-surface and decimation settings, the VTK version), so a second start of
/// an organ neither builds nor decimates its surface (the folded organ: 4 + 10 s, quiet, to
/// 0.2 s); else built, decimated and offered to it. `report->build_s` is the full surface's
/// time; `report->from_cache` says it was loaded.
[[nodiscard]] EmbeddedSurface display_surface_of_grid(const Model& model, const VoxelGrid& grid, SurfaceMethod method,
                                                      const DecimationSettings& settings, DecimationReport* report,
                                                      SurfaceCache* cache, const IsoSurfaceSettings& iso = {});

/// A quick stand-in for decimate_surface's surface, to show while it runs (the probe app's
/// first start of an organ, where the decimation takes 10 s): the rest surface clustered on a
/// uniform grid of bins sized for about `settings.target_triangles` triangles
/// (vtkQuadricClustering, Lindstrom 2000), each bin's vertex the one of `full`'s vertices in it
/// that best fits the bin's quadric, so every vertex keeps its embedding row of `full` (it moves
/// exactly as the full surface does there). Not closed or manifold in general, and coarser than
/// decimate_surface's (a bin of about 1.3 mm at 1 mm voxels): for the seconds until that one is
/// ready. `full` itself when decimate_surface would keep it. `report->preview` is set.
/// Throws vx::Error when `full` does not belong to `model` or VTK fails.
[[nodiscard]] EmbeddedSurface preview_surface(const Model& model, const EmbeddedSurface& full,
                                              const DecimationSettings& settings = {},
                                              DecimationReport* report = nullptr);

/// display_surface_of_grid in two parts, for an app that opens before the decimation ends.
struct StagedDisplaySurface {
  /// The display surface when it is final (loaded from the cache, or small enough to show
  /// whole), else preview_surface's stand-in for it.
  EmbeddedSurface shown;
  /// Of `shown`: from_cache, decimated, or preview (with the full surface's build_s).
  DecimationReport report;
  /// Empty when `shown` is final. Else the decimation still to do: the full surface built again
  /// (it is not kept meanwhile: 80 MB on the folded organ) and decimated, offered to the cache
  /// under display_surface_of_grid's key (the next start loads it): the same surface
  /// display_surface_of_grid returns, bit for bit. Runs on any thread (no VTK global state: its
  /// messages are caught per filter); holds what it needs (the model, the grid, the cache);
  /// throws DecimationCancelled when `settings.cancel` turns true.
  std::function<EmbeddedSurface(DecimationReport*)> finish;
};

/// The display surface of display_surface_of_grid, staged: loaded from `cache` (may be null)
/// when it holds it, else the decimation left to StagedDisplaySurface::finish, with a preview to
/// show meanwhile. The preview: for an iso-surface estimated at more than 4 times the target
/// (two triangles per tissue voxel face), extract_coarse_iso_surface on blocks of
/// floor(sqrt(estimate / target)) voxels, embedded and clustered to the target (preview_surface)
/// when above 1.5 times it, so the full surface is not built on the way (0.9-1 s of the folded
/// organ's first start with a display). Else, or when the blocks leave under a quarter of the
/// triangles they should (tissue thinner than half a block), the full surface built here and
/// preview_surface of it (or the full surface itself, final, when small enough). Throws vx::Error.
[[nodiscard]] StagedDisplaySurface stage_display_surface_of_grid(std::shared_ptr<const Model> model,
                                                                 const VoxelGrid& grid, SurfaceMethod method,
                                                                 const DecimationSettings& settings,
                                                                 std::shared_ptr<SurfaceCache> cache,
                                                                 const IsoSurfaceSettings& iso = {});

/// Distances between two triangle meshes (LPS mm): every vertex of each to the nearest point on
/// the other's triangles (vtkStaticCellLocator). `max_mm` is the symmetric vertex-sampled
/// Hausdorff distance; `mean_mm` the mean over both vertex sets.
struct MeshDistance {
  double max_mm{0.0};
  double mean_mm{0.0};
  double max_a_to_b_mm{0.0};  ///< vertices of a to b
  double max_b_to_a_mm{0.0};  ///< vertices of b to a
};
[[nodiscard]] MeshDistance mesh_distance_mm(const Eigen::Matrix3Xd& a_vertices, const Eigen::Matrix3Xi& a_triangles,
                                            const Eigen::Matrix3Xd& b_vertices, const Eigen::Matrix3Xi& b_triangles);

}  // namespace vx
