#pragma once
/// @file volume.h
/// A scalar CT-like volume in Hounsfield units with its geometry in patient space (LPS mm).

#include <vector>

#include "model/voxel_grid.h"

namespace vx {

/// Voxel values in HU (float), x fastest, same indexing and geometry as VoxelGrid.
struct Volume {
  GridGeometry geometry;
  std::vector<float> hu;  ///< voxel_count() values

  [[nodiscard]] float at(int i, int j, int k) const {
    const auto& d = geometry.dims;
    return hu[std::size_t(i + std::int64_t(d.x()) * (j + std::int64_t(d.y()) * k))];
  }
};

}  // namespace vx
