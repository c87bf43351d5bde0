#pragma once
/// @file voxel_shapes.h
/// Voxel grids of simple shapes, for benchmarks and tests: one generator each, so every
/// benchmark and test that speaks of "a ball of radius r in an n^3 grid" means the same voxels.

#include "model/voxel_grid.h"

namespace vx {

/// A ball in an n x n x n grid of cubic voxels of edge `voxel_mm` (origin: voxel (0,0,0)'s
/// centre at (0,0,0) mm, identity direction). Voxel (i,j,k) is tissue when its centre lies
/// within `radius_voxels` of the grid's centre c = (n - 1) / 2 on each axis (between two voxels
/// for even n): (i - c)^2 + (j - c)^2 + (k - c)^2 <= radius_voxels^2, in voxel units.
/// Throws vx::Error unless n >= 1 and voxel_mm > 0.
[[nodiscard]] VoxelGrid ball_grid(int n, double radius_voxels, double voxel_mm = 1.0);

}  // namespace vx
