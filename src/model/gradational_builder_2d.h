#pragma once
// The 2D (quadtree) builder behind build_model (private to src/model: call build_model with
// settings.dimensions = 2).

#include "model/gradational_builder.h"

namespace vx {

/// The 2D (quadtree) analogue of the builder for a grid one voxel thick (dims z = 1),
/// gradational_builder_2d.cpp: 2x2 groups of square cells, the same shell rules (edges for
/// faces, rings for shells), dense vertices at the cell corners of surface-boundary edges,
/// shared nodes between levels. Nodes on the slice's centre plane (model.h). `grid` has been
/// checked by build_model (consistent, one slice, tissue in it); fills report's
/// elements_per_level.
[[nodiscard]] Model build_model_2d(const VoxelGrid& grid, const BuildSettings& settings, BuildReport& report);

}  // namespace vx
