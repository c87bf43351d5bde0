#pragma once
/// @file gradational_builder.h
/// Builds the elastic model from a binary voxel grid (docs/model.md section 3, paper 3.1).

#include <cstdint>
#include <functional>
#include <vector>

#include "model/model.h"
#include "model/voxel_grid.h"

namespace vx {

/// How to build a model.
struct BuildSettings {
  Layout layout{Layout::gradational};
  /// Largest element level for the gradational layout (cells of 2^max_level voxels);
  /// -1 means no limit. Level max_level takes every remaining group.
  int max_level{-1};
  /// Called with a fraction in [0,1] as the build advances (may be empty).
  std::function<void(double)> progress;
};

/// What the builder did, for reports.
struct BuildReport {
  std::int64_t tissue_voxels{0};
  std::vector<std::int64_t> elements_per_level;  ///< level 0 first
  double build_s{0.0};                           ///< wall time, s
};

/// Builds the model for `grid`. Throws vx::Error when the grid holds no tissue.
[[nodiscard]] Model build_model(const VoxelGrid& grid, const BuildSettings& settings = {},
                                BuildReport* report = nullptr);

}  // namespace vx
