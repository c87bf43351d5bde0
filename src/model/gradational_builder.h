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
  /// (build_model_2d). Last, so that positional initialisers of the fields above keep meaning.
  int dimensions{3};
};

/// What the builder did, for reports.
struct BuildReport {
  std::int64_t tissue_voxels{0};
  std::vector<std::int64_t> elements_per_level;  ///< level 0 first
  double build_s{0.0};                           ///< wall time, s
};

/// Builds the model for `grid`: the volume builder, or the 2D builder (build_model_2d) when
/// settings.dimensions is 2. Throws vx::Error when the grid holds no tissue.
[[nodiscard]] Model build_model(const VoxelGrid& grid, const BuildSettings& settings = {},
                                BuildReport* report = nullptr);

/// The 2D (quadtree) analogue of the builder for a grid one voxel thick (dims z = 1),
/// gradational_builder_2d.cpp: 2x2 groups of square cells, the same shell rules (edges for
/// faces, rings for shells), dense vertices at the cell corners of surface-boundary edges,
/// shared nodes between levels. Nodes on the slice's centre plane (model.h). Groundwork for
/// the paper's 2D model (issue #18): the physics, scenes and apps do not take 2D models yet. Throws vx::Error
/// for a thicker grid or one without tissue.
[[nodiscard]] Model build_model_2d(const VoxelGrid& grid, const BuildSettings& settings = {},
                                   BuildReport* report = nullptr);

}  // namespace vx
