#pragma once
/// @file prepare.h
/// From a volume to the voxel grid the model is built from: threshold, keep the largest
/// connected component, fill internal holes, crop to the tissue, resample. Every step is
/// reported so the console and the stats file can say what happened.

#include <nlohmann/json_fwd.hpp>
#include <string>

#include "convert/threshold.h"
#include "io/volume.h"
#include "model/gradational_builder.h"
#include "model/voxel_grid.h"

namespace vx {

struct PrepareOptions {
  HuRange range;                  ///< tissue HU window
  bool largest_component{false};  ///< keep only the largest 6-connected tissue component
  bool fill_holes{false};         ///< fill cavities not connected to the outside
  bool crop{true};                ///< crop the grid to the tissue bounding box (+1 voxel margin)
  double voxel_mm{0.0};           ///< resample the volume to this isotropic voxel size first; 0 = keep
  /// After cropping, move the grid's first voxel back by 0 .. lattice_period-1 air voxels per
  /// axis to where the model `lattice_build` describes has the fewest vertex entries
  /// (model/lattice_origin.h, docs/model.md section 3.5). 0 or 1: keep the 1-voxel margin.
  /// The commands and scenes use 4; the library's default keeps the grid as cropped.
  int lattice_period{0};
  BuildSettings lattice_build;    ///< the model the lattice origin is chosen for (layout, max_level, dimensions)
};

struct PrepareReport {
  Eigen::Vector3i input_dims{0, 0, 0};
  Eigen::Vector3d input_spacing_mm{0, 0, 0};
  Eigen::Vector3i resampled_dims{0, 0, 0};   ///< equal to input_dims without resampling
  double resampled_voxel_mm{0.0};            ///< the resampled voxels' size (0: not resampled)
  std::int64_t thresholded_voxels{0};        ///< tissue voxels right after thresholding
  int components{0};                         ///< tissue components found (when asked)
  std::int64_t removed_voxels{0};            ///< dropped with the smaller components
  std::int64_t filled_voxels{0};             ///< added by hole filling
  Eigen::Vector3i crop_lo{0, 0, 0};          ///< crop box in (resampled) input voxels, lo inclusive
  Eigen::Vector3i crop_hi{0, 0, 0};          ///< hi exclusive
  Eigen::Vector3i lattice_shift{0, 0, 0};    ///< air voxels added before the 1-voxel margin (crop_lo includes them)
  std::int64_t entries_unshifted{0};         ///< vertex entries with the 1-voxel margin (0: not chosen)
  std::int64_t entries_chosen{0};            ///< vertex entries at the chosen lattice origin
  std::int64_t elements_unshifted{0};
  std::int64_t elements_chosen{0};
  double lattice_s{0.0};                     ///< wall time spent choosing, s
  std::int64_t tissue_voxels{0};             ///< final count
  /// One human-readable line per step, for the console (no trailing newline); the final tissue
  /// count last unless `with_tissue` is false (a caller that prints the model's statistics,
  /// which hold it, says it once).
  [[nodiscard]] std::string summary(bool with_tissue = true) const;
  /// The same as JSON (for the stats file).
  void to_json(nlohmann::json& j) const;
};

/// Runs the steps; throws vx::Error when no tissue remains (saying which HU range was used
/// and the volume's HU range, so the user can fix the threshold).
[[nodiscard]] VoxelGrid prepare_grid(const Volume& volume, const PrepareOptions& options,
                                     PrepareReport* report = nullptr);

}  // namespace vx
