#include "model/voxel_shapes.h"

#include <string>

#include "base/error.h"

namespace vx {

VoxelGrid ball_grid(int n, double radius_voxels, double voxel_mm) {
  if (n < 1 || !(voxel_mm > 0))
    throw Error("ball grid: " + std::to_string(n) + " voxels per axis of " + std::to_string(voxel_mm) +
                " mm: the grid needs at least one voxel of positive size");
  GridGeometry g;
  g.dims = {n, n, n};
  g.spacing_mm = Eigen::Vector3d::Constant(voxel_mm);
  VoxelGrid grid(g);
  const double c = 0.5 * (n - 1), r = radius_voxels;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i)
        grid.set(i, j, k, (i - c) * (i - c) + (j - c) * (j - c) + (k - c) * (k - c) <= r * r ? 1 : 0);
  return grid;
}

}  // namespace vx
