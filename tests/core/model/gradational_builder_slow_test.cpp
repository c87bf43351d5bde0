// Larger grids: the builder stays linear and the paper's count holds at 256^3.
#include <gtest/gtest.h>

#include "model/gradational_builder.h"
#include "model/voxel_shapes.h"
#include "support/builder_checks.h"

using namespace vx;

TEST(GradationalBuilderSlow, Sphere128ReductionAndCover) {
  // a sphere 128 voxels across (radius 63.5 in a grid with a 2-voxel air margin)
  const VoxelGrid g = vx::ball_grid(132, 63.5);
  BuildReport report;
  const Model m = build_model(g, {}, &report);
  vx::testing::expect_exact_cover(m, g);
  EXPECT_LE(vx::testing::max_neighbour_level_jump(m), 1);
  // the figure: about 19k elements and 270k vertex entries
  EXPECT_NEAR(double(m.num_elements()), 19000.0, 19000.0 * 0.03);
  EXPECT_NEAR(double(m.num_vertex_entries()), 270000.0, 270000.0 * 0.03);
  // against 8 vertex entries per voxel for the voxel-level model
  EXPECT_GT(8.0 * double(g.count()) / double(m.num_vertex_entries()), 30.0);
}

TEST(GradationalBuilderSlow, Cube256) {
  GridGeometry geo;
  geo.dims = {256, 256, 256};
  VoxelGrid g(geo);
  std::fill(g.data().begin(), g.data().end(), 1);
  const Model m = build_model(g);
  const std::vector<std::int64_t> expected = {
      128LL * 128 * 128 - 126LL * 126 * 126, 64 * 64 * 64 - 62 * 62 * 62, 32 * 32 * 32 - 30 * 30 * 30,
      16 * 16 * 16 - 14 * 14 * 14, 8 * 8 * 8 - 6 * 6 * 6, 4 * 4 * 4 - 2 * 2 * 2, 8};
  EXPECT_EQ(m.elements_per_level(), expected);
  EXPECT_NEAR(double(m.num_vertex_entries()) / (26.0 * 256 * 256), 1.0, 0.03);
}
