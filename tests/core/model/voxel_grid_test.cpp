#include "model/voxel_grid.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

using vx::GridGeometry;
using vx::VoxelGrid;

TEST(GridGeometry, IndexToLpsAndBack) {
  GridGeometry g;
  g.dims = {10, 20, 30};
  g.spacing_mm = {0.5, 0.75, 2.0};
  g.origin_mm = {-10, 5, 100};
  g.direction = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Vector3d ijk(3, 7, 11);
  const Eigen::Vector3d p = g.index_to_lps(ijk);
  // origin + D * (spacing .* ijk)
  const Eigen::Vector3d expected = g.origin_mm + g.direction * Eigen::Vector3d(1.5, 5.25, 22.0);
  EXPECT_LT((p - expected).norm(), 1e-12);
  EXPECT_LT((g.lps_to_index(p) - ijk).norm(), 1e-12);
  // lattice point (voxel corner) 0 is half a voxel before the centre of voxel 0
  EXPECT_LT((g.lattice_to_lps({0, 0, 0}) - g.index_to_lps({-0.5, -0.5, -0.5})).norm(), 1e-12);
  EXPECT_TRUE(g.direction_is_orthonormal());
  g.direction(0, 0) += 0.1;
  EXPECT_FALSE(g.direction_is_orthonormal());
  EXPECT_EQ(GridGeometry{}.voxel_count(), 0);
}

TEST(VoxelGrid, CountsAndBounds) {
  GridGeometry g;
  g.dims = {8, 6, 5};
  VoxelGrid grid(g);
  EXPECT_EQ(grid.data().size(), 240u);
  EXPECT_EQ(grid.count(), 0);
  Eigen::Vector3i lo, hi;
  grid.tissue_bounds(lo, hi);
  EXPECT_EQ(lo, Eigen::Vector3i::Zero());
  EXPECT_EQ(hi, Eigen::Vector3i::Zero());
  grid.set(2, 1, 3, 1);
  grid.set(5, 4, 1, 7);  // any non-zero is stored as 1
  EXPECT_EQ(grid.count(), 2);
  EXPECT_EQ(grid.at(5, 4, 1), 1);
  EXPECT_EQ(grid.at(-1, 0, 0), 0);  // outside reads as 0
  EXPECT_EQ(grid.at(8, 0, 0), 0);
  grid.tissue_bounds(lo, hi);
  EXPECT_EQ(lo, Eigen::Vector3i(2, 1, 1));
  EXPECT_EQ(hi, Eigen::Vector3i(6, 5, 4));
  EXPECT_EQ(grid.index(1, 2, 3), 1 + 8 * (2 + 6 * 3));
}
