#pragma once
/// @file prepare.h
/// From a volume to the voxel grid the model is built from: threshold, keep the largest
/// connected component, fill internal holes, crop to the tissue, resample. Every step is
/// reported so the console and the stats file can say what happened.

#include <nlohmann/json_fwd.hpp>
#include <string>

#include "convert/threshold.h"
#include "io/volume.h"
#include "model/voxel_grid.h"

namespace vx {

struct PrepareOptions {
  HuRange range;                  ///< tissue HU window
  bool largest_component{false};  ///< keep only the largest 6-connected tissue component
  bool fill_holes{false};         ///< fill cavities not connected to the outside
  bool crop{true};                ///< crop the grid to the tissue bounding box (+1 voxel margin)
  double voxel_mm{0.0};           ///< resample the volume to this isotropic voxel size first; 0 = keep
};

struct PrepareReport {
  Eigen::Vector3i input_dims{0, 0, 0};
  Eigen::Vector3d input_spacing_mm{0, 0, 0};
  Eigen::Vector3i resampled_dims{0, 0, 0};   ///< equal to input_dims without resampling
  std::int64_t thresholded_voxels{0};        ///< tissue voxels right after thresholding
  int components{0};                         ///< tissue components found (when asked)
  std::int64_t removed_voxels{0};            ///< dropped with the smaller components
  std::int64_t filled_voxels{0};             ///< added by hole filling
  Eigen::Vector3i crop_lo{0, 0, 0};          ///< crop box in (resampled) input voxels, lo inclusive
  Eigen::Vector3i crop_hi{0, 0, 0};          ///< hi exclusive
  std::int64_t tissue_voxels{0};             ///< final count
  /// One human-readable line per step, for the console.
  [[nodiscard]] std::string summary() const;
  /// The same as JSON (for the stats file).
  void to_json(nlohmann::json& j) const;
};

/// Runs the steps; throws vx::Error when no tissue remains (saying which HU range was used
/// and the volume's HU range, so the user can fix the threshold).
[[nodiscard]] VoxelGrid prepare_grid(const Volume& volume, const PrepareOptions& options,
                                     PrepareReport* report = nullptr);

}  // namespace vx
