#include "model/gradational_builder.h"
#include "model/voxel_shapes.h"

#include <gtest/gtest.h>

#include <cmath>

#include "base/error.h"
#include "support/builder_checks.h"

using namespace vx;
using vx::testing::expect_exact_cover;
using vx::testing::expect_nodes_shared;
using vx::testing::make_grid;
using vx::testing::max_neighbour_level_jump;

namespace {

VoxelGrid full_cube(int n) {
  return make_grid({n, n, n}, [](int, int, int) { return true; });
}

/// Elements per level of an all-tissue cube of n voxels: the shell of groups at each level.
std::vector<std::int64_t> cube_shells(int n) {
  std::vector<std::int64_t> shells;
  // the last level (g = 2) is 8 groups of one cell each
  for (int g = n / 2; g >= 2; g /= 2) shells.push_back(std::int64_t(g) * g * g - std::int64_t(g - 2) * (g - 2) * (g - 2));
  return shells;
}

}  // namespace

TEST(GradationalBuilder, PaperCube128Shells) {
  // paper 3.2 / docs/model.md section 3: 23816, 5768, 1352, 296, 56 and 8 elements, level 0 outward in
  const VoxelGrid grid = full_cube(128);
  BuildReport report;
  const Model m = build_model(grid, {}, &report);
  const std::vector<std::int64_t> expected = {23816, 5768, 1352, 296, 56, 8};
  EXPECT_EQ(m.elements_per_level(), expected);
  EXPECT_EQ(report.elements_per_level, expected);
  EXPECT_EQ(m.num_elements(), 31296);
  EXPECT_EQ(report.tissue_voxels, 128LL * 128 * 128);
  EXPECT_EQ(m.covered_voxels(), 128LL * 128 * 128);
  // vertex entries about 26 n^2 (paper 3.2), against 8 n^3 for the voxel-level model
  const double n2 = 128.0 * 128.0;
  EXPECT_NEAR(double(m.num_vertex_entries()) / (26.0 * n2), 1.0, 0.05) << m.num_vertex_entries();
  EXPECT_EQ(m.num_vertex_entries(), 408432);  // 0.959 * 26 n^2 (regression pin)
  // cost against the voxel-level model falls by about 3/n (8 n^3 / 26 n^2 = n / 3.25)
  EXPECT_NEAR(8.0 * 128 * 128 * 128 / double(m.num_vertex_entries()), 128.0 / 3.25, 128.0 / 3.25 * 0.05);
  EXPECT_EQ(m.validate(), "");
}

TEST(GradationalBuilder, CubeShellsAtSeveralSizes) {
  // face elements of every shell carry 13 vertices (9 dense on the outer face, 4 corners inside),
  // so entries tend to 6 faces * 13 * n^2 (1/4 + 1/16 + ...) = 26 n^2 from below; edges,
  // corners and the truncated series make small cubes fall short
  double previous = 0;
  for (int n : {8, 16, 32, 64}) {
    const Model m = build_model(full_cube(n));
    EXPECT_EQ(m.elements_per_level(), cube_shells(n)) << "n = " << n;
    const double ratio = double(m.num_vertex_entries()) / (26.0 * n * n);
    EXPECT_GT(ratio, previous) << "n = " << n;
    EXPECT_LT(ratio, 1.0) << "n = " << n;
    if (n >= 32) {
      EXPECT_GT(ratio, 0.84) << "n = " << n;
    }
    previous = ratio;
  }
}

TEST(GradationalBuilder, LevelZeroFaceElementHasThirteenVertices) {
  const Model m = build_model(full_cube(16));
  // the level-0 element whose group sits at the middle of the x = 0 face
  int found = 0;
  for (int e = 0; e < m.num_elements(); ++e) {
    const Eigen::Vector3i a = m.element_anchor.col(e);
    if (m.element_level[e] == 0 && a.x() == 0 && a.y() == 6 && a.z() == 6) {
      EXPECT_EQ(m.num_vertices(e), 13);
      EXPECT_EQ(m.element_cells[e], 0xFF);
      ++found;
    }
  }
  EXPECT_EQ(found, 1);
}

TEST(GradationalBuilder, CoversEveryTissueVoxelOnceAndSharesNodes) {
  const VoxelGrid cube = full_cube(32);
  const VoxelGrid sphere = ball_grid(40, 17.3);
  // a torus-like ring and an irregular blob with holes and thin parts
  const VoxelGrid ring = make_grid({44, 44, 20}, [](int i, int j, int k) {
    const double x = i - 21.5, y = j - 21.5, z = k - 9.5;
    const double q = std::sqrt(x * x + y * y) - 13.0;
    return q * q + z * z <= 36.0;
  });
  const VoxelGrid blob = make_grid({37, 29, 23}, [](int i, int j, int k) {
    const unsigned h = (unsigned(i) * 73856093u) ^ (unsigned(j) * 19349663u) ^ (unsigned(k) * 83492791u);
    const double x = i - 18.0, y = j - 14.0, z = k - 11.0;
    return x * x / 300.0 + y * y / 150.0 + z * z / 100.0 < 1.0 && (h % 11 != 0);
  });
  for (const VoxelGrid* g : {&cube, &sphere, &ring, &blob})
    for (Layout r : {Layout::gradational, Layout::uniform, Layout::voxel}) {
      SCOPED_TRACE(std::string("resolution ") + to_string(r) + ", grid " + std::to_string(g->dims().x()));
      BuildSettings s;
      s.layout = r;
      const Model m = build_model(*g, s);
      EXPECT_EQ(m.validate(), "");
      expect_exact_cover(m, *g);
      expect_nodes_shared(m);
      EXPECT_LE(max_neighbour_level_jump(m), 1);
      EXPECT_NEAR(m.total_volume_mm3(), double(g->count()), 1e-9);
    }
}

TEST(GradationalBuilder, DiagonalOnlyGroups) {
  // two voxels touching at one corner: one element of 15 vertices (8 + 8 - the shared corner)
  VoxelGrid corner = make_grid({2, 2, 2}, [](int i, int j, int k) { return i == j && j == k; });
  Model m = build_model(corner);
  ASSERT_EQ(m.num_elements(), 1);
  EXPECT_EQ(m.element_cells[0], (1 << 0) | (1 << 7));
  EXPECT_EQ(m.num_vertices(0), 15);
  EXPECT_EQ(m.num_nodes(), 15);
  // two voxels sharing an edge only: 8 + 8 - 2
  VoxelGrid edge = make_grid({2, 2, 2}, [](int i, int j, int k) { return k == 0 && i == j; });
  m = build_model(edge);
  ASSERT_EQ(m.num_elements(), 1);
  EXPECT_EQ(m.num_vertices(0), 14);
  // four voxels on the two diagonals of a 2x2x2 group that touch only along edges
  VoxelGrid checker = make_grid({2, 2, 2}, [](int i, int j, int k) { return (i + j + k) % 2 == 0; });
  m = build_model(checker);
  ASSERT_EQ(m.num_elements(), 1);
  EXPECT_EQ(m.element_cells[0], 0b10010110 ^ 0xFF);
  // every lattice point of the group but the four corners no cell touches: (2,0,0), (0,2,0),
  // (0,0,2) and (2,2,2)
  EXPECT_EQ(m.num_vertices(0), 27 - 4);
  expect_nodes_shared(m);
}

TEST(GradationalBuilder, PartlyFilledGroups) {
  // an L of three voxels in one group: every lattice point of its closure is a vertex (all faces
  // are surface boundary), 8 points per z-plane
  VoxelGrid ell = make_grid({2, 2, 2}, [](int i, int j, int) { return !(i == 1 && j == 1); });
  Model m = build_model(ell);
  ASSERT_EQ(m.num_elements(), 1);
  EXPECT_EQ(m.num_vertices(0), 24);  // 8 points per plane, three planes (z = 0, 1, 2)
  // a single voxel at an odd position belongs to group 0 as its cell (1,1,1)
  VoxelGrid one = make_grid({3, 3, 3}, [](int i, int j, int k) { return i == 1 && j == 1 && k == 1; });
  m = build_model(one);
  ASSERT_EQ(m.num_elements(), 1);
  EXPECT_EQ(m.element_cells[0], 1 << 7);
  EXPECT_EQ(m.element_anchor.col(0), Eigen::Vector3i(0, 0, 0));
  EXPECT_EQ(m.num_vertices(0), 8);
  // its rest offsets are the unit cube's corners about the voxel centre
  for (int i = 0; i < 8; ++i) EXPECT_NEAR(m.rest_offsets.col(i).cwiseAbs().maxCoeff(), 0.5, 1e-12);
}

TEST(GradationalBuilder, PartlyFilledGroupsAtHigherLevels) {
  // a cube of odd size: level >= 1 groups straddle the removed shell and hold 1, 2 or 4 cells
  const VoxelGrid g = full_cube(30);
  const Model m = build_model(g);
  int partial = 0;
  for (int e = 0; e < m.num_elements(); ++e)
    if (m.element_level[e] >= 1 && m.element_cells[e] != 0xFF) ++partial;
  EXPECT_GT(partial, 0);
  expect_exact_cover(m, g);
  expect_nodes_shared(m);
  EXPECT_LE(max_neighbour_level_jump(m), 1);
}

TEST(GradationalBuilder, UniformAndVoxelLayouts) {
  const VoxelGrid g = ball_grid(24, 10.2);
  const std::int64_t voxels = g.count();
  BuildSettings s;
  s.layout = Layout::voxel;
  const Model vox = build_model(g, s);
  EXPECT_EQ(vox.num_elements(), voxels);
  EXPECT_EQ(vox.num_vertex_entries(), 8 * voxels);
  EXPECT_EQ(vox.num_levels(), 1);
  s.layout = Layout::uniform;
  const Model uni = build_model(g, s);
  EXPECT_EQ(uni.num_levels(), 1);
  // one element per 2x2x2 group holding tissue
  std::int64_t groups = 0;
  for (int k = 0; k < 12; ++k)
    for (int j = 0; j < 12; ++j)
      for (int i = 0; i < 12; ++i) {
        bool any = false;
        for (int c = 0; c < 8; ++c) any = any || g.at(2 * i + (c & 1), 2 * j + (c >> 1 & 1), 2 * k + (c >> 2 & 1));
        groups += any;
      }
  EXPECT_EQ(uni.num_elements(), groups);
  const Model grad = build_model(g);
  EXPECT_GT(grad.num_levels(), 1);
  EXPECT_LT(grad.num_elements(), uni.num_elements());
  EXPECT_LT(grad.num_vertex_entries(), uni.num_vertex_entries());
  EXPECT_LT(uni.num_vertex_entries(), vox.num_vertex_entries());
}

TEST(GradationalBuilder, ReductionAgainstVoxelModelGrowsLikeN) {
  // cost falls by about 3/n: the ratio 8*voxels/entries roughly doubles when n doubles
  double previous = 0;
  for (int n : {16, 32, 64}) {
    const VoxelGrid g = ball_grid(n, 0.4 * n);
    const Model m = build_model(g);
    const double ratio = 8.0 * double(g.count()) / double(m.num_vertex_entries());
    if (previous > 0) {
      EXPECT_GT(ratio / previous, 1.6) << "n = " << n;
      EXPECT_LT(ratio / previous, 2.4) << "n = " << n;
    }
    previous = ratio;
  }
}

TEST(GradationalBuilder, MaxLevelCapsElementSize) {
  const VoxelGrid g = full_cube(64);
  BuildSettings s;
  s.max_level = 2;
  const Model m = build_model(g, s);
  ASSERT_EQ(m.num_levels(), 3);
  EXPECT_EQ(m.elements_per_level()[0], 32 * 32 * 32 - 30 * 30 * 30);
  EXPECT_EQ(m.elements_per_level()[1], 16 * 16 * 16 - 14 * 14 * 14);
  EXPECT_EQ(m.elements_per_level()[2], 8 * 8 * 8);  // all remaining groups
  expect_exact_cover(m, g);
  expect_nodes_shared(m);
}

TEST(GradationalBuilder, GeometryAndSurfaceNodes) {
  GridGeometry geo;
  geo.dims = {6, 6, 6};
  geo.spacing_mm = {0.5, 0.7, 1.1};
  geo.origin_mm = {10, -20, 30};
  VoxelGrid g(geo);
  for (int k = 1; k < 5; ++k)
    for (int j = 1; j < 5; ++j)
      for (int i = 1; i < 5; ++i) g.set(i, j, k, 1);
  const Model m = build_model(g);
  for (int n = 0; n < m.num_nodes(); ++n) {
    const Eigen::Vector3i a = m.node_lattice.col(n);
    const Eigen::Vector3d expected = geo.origin_mm + geo.spacing_mm.cwiseProduct(a.cast<double>() - Eigen::Vector3d::Constant(0.5));
    EXPECT_LT((m.rest_positions.col(n) - expected).norm(), 1e-12);
    // nodes on the block's faces are surface nodes; the only interior lattice points are not
    const bool on_face = (a.array() == 1).any() || (a.array() == 5).any();
    EXPECT_EQ(m.node_surface[n], on_face ? 1 : 0) << a.transpose();
  }
  // rest offsets sum to zero per element
  for (int e = 0; e < m.num_elements(); ++e) {
    Eigen::Vector3d s = Eigen::Vector3d::Zero();
    for (int i = m.element_offsets[e]; i < m.element_offsets[e + 1]; ++i) s += m.rest_offsets.col(i);
    EXPECT_LT(s.norm(), 1e-12);
  }
}

TEST(GradationalBuilder, DeterministicAndRejectsEmpty) {
  const VoxelGrid g = ball_grid(20, 8.0);
  EXPECT_TRUE(same_model(build_model(g), build_model(g), 0.0));
  const VoxelGrid empty = make_grid({8, 8, 8}, [](int, int, int) { return false; });
  EXPECT_THROW((void)build_model(empty), Error);
  EXPECT_THROW((void)parse_layout("fine"), Error);
  EXPECT_EQ(parse_layout("voxel"), Layout::voxel);
}
