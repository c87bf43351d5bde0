// The voxel shapes benchmarks and tests share: which voxels a ball of radius r in an n^3 grid holds.
#include "model/voxel_shapes.h"

#include <gtest/gtest.h>

#include "base/error.h"

using namespace vx;

TEST(BallGrid, CentredOnTheGridWithVoxelCentresWithinTheRadius) {
  // odd n: the centre is a voxel; radius 2 reaches the face neighbours 2 away, not the edge ones
  const VoxelGrid odd = ball_grid(5, 2.0);
  EXPECT_EQ(odd.at(2, 2, 2), 1);
  EXPECT_EQ(odd.at(0, 2, 2), 1);
  EXPECT_EQ(odd.at(0, 0, 2), 0);
  EXPECT_EQ(odd.count(), 33);  // 1 + 6 + 12 (distance sqrt 2) + 8 (sqrt 3) + 6 (2)
  // even n: the centre lies between voxels; radius 1 holds the 8 around it (distance sqrt 0.75)
  const VoxelGrid even = ball_grid(4, 1.0);
  EXPECT_EQ(even.count(), 8);
  EXPECT_EQ(even.at(1, 1, 1), 1);
  EXPECT_EQ(even.at(2, 2, 2), 1);
  EXPECT_EQ(even.at(0, 1, 1), 0);
}

TEST(BallGrid, GeometryAndBadSizes) {
  const VoxelGrid g = ball_grid(6, 2.5, 0.5);
  EXPECT_EQ(g.dims(), Eigen::Vector3i(6, 6, 6));
  EXPECT_EQ(g.geometry().spacing_mm, Eigen::Vector3d::Constant(0.5));
  EXPECT_EQ(g.geometry().origin_mm, Eigen::Vector3d::Zero());
  EXPECT_THROW((void)ball_grid(0, 1.0), Error);
  EXPECT_THROW((void)ball_grid(4, 1.0, 0.0), Error);
}
