#pragma once
/// @file iso_surface.h
/// The surfaces `voxelastic convert --surface` writes: the paper's voxel surface (core) or a
/// smoothed iso-surface (VTK flying edges + windowed sinc) embedded in the model's elements.

#include <Eigen/Core>
#include <limits>

#include "io/volume.h"
#include "model/model.h"
#include "model/voxel_grid.h"
#include "surface/surface.h"

namespace vx {

/// How to extract the iso-surface.
struct IsoSurfaceSettings {
  /// Iso value on the HU volume, used when a volume is given: the tissue threshold (the lower
  /// bound of the HU window). NaN (the default) extracts the boundary of the binary grid
  /// instead (iso 0.5 between tissue and outside voxel centres), which is what the model holds.
  double iso_hu{std::numeric_limits<double>::quiet_NaN()};
  /// Windowed-sinc smoothing (vtkWindowedSincPolyDataFilter) iterations; 0 = no smoothing.
  /// The defaults (20, 0.01) were the most accurate of iterations {10, 20, 40} x pass band
  /// {0.1, 0.05, 0.01, 0.001} on the sphere, ellipsoid and torus phantoms at sizes 48 and 96
  /// (mean distance 0.03 to 0.07 voxel; the response is not monotonic in either setting).
  int smoothing_iterations{20};
  /// Windowed-sinc pass band (0..2, smaller = smoother), on normalized coordinates.
  double pass_band{0.01};
};

/// A triangle mesh at rest, in LPS mm.
struct TriangleMesh {
  Eigen::Matrix3Xd vertices_mm;  ///< 3 x V
  Eigen::Matrix3Xi triangles;    ///< 3 x T, counter-clockwise seen from outside
};

/// The smoothed iso-surface of the tissue, closed (the grid border counts as outside) and
/// oriented outward. With `hu` and a finite `settings.iso_hu` the HU values are contoured
/// (vtkFlyingEdges3D), limited to one voxel around the grid's tissue so that only what the
/// model holds appears; `hu` must then have the grid's geometry. Otherwise the binary grid is
/// contoured (vtkDiscreteFlyingEdges3D). Then windowed-sinc smoothing.
/// Throws vx::Error when the grid is empty or the volume does not match it.
[[nodiscard]] TriangleMesh extract_iso_surface(const VoxelGrid& grid, const Volume* hu = nullptr,
                                               const IsoSurfaceSettings& settings = {});

/// A coarse stand-in for extract_iso_surface's binary surface (no HU values): the grid's tissue
/// averaged over blocks of factor^3 voxels and contoured where half a block is tissue
/// (vtkFlyingEdges3D), then smoothed as `settings` says; about factor^2 times fewer triangles,
/// in a fraction of the time. Closed and oriented outward. Details narrower than a block (a sulcus
/// under `factor` voxels wide) close up. The probe app's display preview on a first start.
/// Throws vx::Error when the grid is empty, the factor is below 1 or VTK fails.
[[nodiscard]] TriangleMesh extract_coarse_iso_surface(const VoxelGrid& grid, int factor,
                                                      const IsoSurfaceSettings& settings = {});

/// The surface of a model for `convert --surface-method paper|iso` (or staircase):
/// paper/staircase: make_voxel_surface(model, grid, ...); iso: extract_iso_surface then
/// embed_surface. `grid` is the grid the model was built from. Throws vx::Error.
[[nodiscard]] EmbeddedSurface make_surface(const Model& model, const VoxelGrid& grid, const Volume* hu,
                                           SurfaceMethod method, const IsoSurfaceSettings& settings = {});

}  // namespace vx
