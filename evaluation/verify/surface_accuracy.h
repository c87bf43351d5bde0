#pragma once
/// @file surface_accuracy.h
/// How close a surface mesh is to the analytic shape of a phantom: distances (mm and voxels),
/// bias, enclosed-volume error and normal error. Measured, not assumed.

#include <Eigen/Core>
#include <cstdint>
#include <string>

#include "convert/phantom.h"
#include "surface/surface.h"

namespace vx {

/// Figures of a mesh against a shape. Distances are |signed distance| to the shape's surface,
/// sampled at every vertex and every triangle centre.
struct SurfaceAccuracy {
  std::int64_t vertices{0};
  std::int64_t triangles{0};
  std::int64_t samples{0};             ///< vertices + triangle centres
  double mean_distance_mm{0};
  double max_distance_mm{0};
  double rms_distance_mm{0};
  double mean_signed_distance_mm{0};   ///< > 0: the surface lies outside the shape on average
  double mean_distance_voxels{0};      ///< mean_distance_mm / voxel size
  double max_distance_voxels{0};
  double volume_mm3{0};                ///< enclosed volume (divergence theorem)
  double true_volume_mm3{0};           ///< the shape's exact volume
  double volume_error_percent{0};      ///< 100 (volume - true) / true
  double mean_normal_error_deg{-1};    ///< angle between vertex normals and the shape's normals (-1: not measured)
  double max_normal_error_deg{-1};

  /// One line: "mean 0.123 mm (0.123 vox), max ..., volume +1.23 %, normals 4.5 deg".
  [[nodiscard]] std::string summary() const;
};

/// Measures `triangles` over `vertices` (3 x V, LPS mm) against `shape`; `voxel_mm` converts
/// distances to voxels; `normals` (3 x V unit vertex normals, optional) gives the normal error,
/// against the normalized gradient of the shape's signed distance.
[[nodiscard]] SurfaceAccuracy measure_surface_accuracy(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles,
                                                       const PhantomShape& shape, double voxel_mm,
                                                       const Eigen::Matrix3Xd* normals = nullptr);

/// The same for an embedded surface at rest (its rest normals included).
[[nodiscard]] SurfaceAccuracy measure_surface_accuracy(const EmbeddedSurface& surface, const PhantomShape& shape,
                                                       double voxel_mm);

}  // namespace vx
