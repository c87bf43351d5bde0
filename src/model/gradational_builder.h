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
  /// 3 (default): a volume model; 2: a 2D (quadtree) model of a one-voxel-thick grid
  /// (gradational_builder_2d.h, docs/model.md section 12.1). Last, so that positional
  /// initialisers of the fields above keep meaning.
  int dimensions{3};
};

/// What the builder did, for reports.
struct BuildReport {
  std::int64_t tissue_voxels{0};
  std::vector<std::int64_t> elements_per_level;  ///< level 0 first
  double build_s{0.0};                           ///< wall time, s
};

/// Builds the model for `grid`: the volume builder, or the 2D builder (gradational_builder_2d.h)
/// when settings.dimensions is 2. Throws vx::Error when the grid holds no tissue, is
/// inconsistent, or (2D) is more than one voxel thick.
[[nodiscard]] Model build_model(const VoxelGrid& grid, const BuildSettings& settings = {},
                                BuildReport* report = nullptr);

}  // namespace vx
