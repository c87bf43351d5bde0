// The 2D (quadtree) builder against the same brute-force checks as the volume builder
// (tests/support/builder_checks.h): every tissue pixel covered exactly once, every node on an
// element's region one of its vertices, neighbour levels within one; and the quadtree analogue
// of the paper's shell counts (docs/model.md section 12).

#include "model/gradational_builder.h"

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

BuildSettings settings_2d(Layout layout = Layout::gradational) {
  BuildSettings s;
  s.layout = layout;
  s.dimensions = 2;
  return s;
}

VoxelGrid full_square(int n) {
  return make_grid({n, n, 1}, [](int, int, int) { return true; });
}

VoxelGrid disk(int n) {
  const double c = 0.5 * n, r = 0.5 * n - 0.5;
  return make_grid({n, n, 1}, [=](int i, int j, int) {
    const double x = i + 0.5 - c, y = j + 0.5 - c;
    return x * x + y * y <= r * r;
  });
}

/// Elements per level of an all-tissue square of n pixels: the ring of groups at each level
/// (g^2 - (g - 2)^2 groups of a g x g group grid), the last level the 4 groups of one cell.
std::vector<std::int64_t> square_rings(int n) {
  std::vector<std::int64_t> rings;
  for (int g = n / 2; g >= 2; g /= 2) rings.push_back(std::int64_t(g) * g - std::int64_t(g - 2) * (g - 2));
  return rings;
}

}  // namespace

TEST(GradationalBuilder2d, SquareRingsAtSeveralSizes) {
  // the quadtree analogue of the paper's 128 cube (23816, 5768, ... 8): rings of 4 (g - 1) groups
  for (int n : {8, 16, 32, 64, 128}) {
    BuildReport report;
    const Model m = build_model(full_square(n), settings_2d(), &report);
    EXPECT_EQ(m.dimensions, 2);
    EXPECT_EQ(m.elements_per_level(), square_rings(n)) << "n = " << n;
    EXPECT_EQ(report.elements_per_level, square_rings(n)) << "n = " << n;
    EXPECT_EQ(m.covered_voxels(), std::int64_t(n) * n);
    EXPECT_EQ(m.validate(), "");
    expect_exact_cover(m, full_square(n));
    expect_nodes_shared(m);
    EXPECT_LE(max_neighbour_level_jump(m), 1) << "n = " << n;
  }
  // n = 128: 252 + 124 + 60 + 28 + 12 + 4 = 480 elements for 16384 pixels
  EXPECT_EQ(build_model(full_square(128), settings_2d()).num_elements(), 480);
}

TEST(GradationalBuilder2d, ElementsAndEntriesGrowLikeTheOutlineNotTheArea) {
  // a disk of diameter n pixels: the pixel layout has about pi n^2 / 4 elements, the gradational
  // one a ring per level: measured 92, 180, 416, 808 and 1700 elements (2.9 to 3.3 n) and
  // 456 ... 8776 vertex entries (14 to 17 n) at n = 32 ... 512; the digitised outline makes
  // single doublings scatter (2.0 to 2.3), so the growth is read over the whole range
  std::vector<double> elements, entries;
  const std::vector<int> sizes = {32, 64, 128, 256, 512};
  for (int n : sizes) {
    const VoxelGrid g = disk(n);
    const Model m = build_model(g, settings_2d());
    if (n <= 256) {
      expect_exact_cover(m, g);
      expect_nodes_shared(m);
    }
    EXPECT_LE(max_neighbour_level_jump(m), 1) << "n = " << n;
    EXPECT_EQ(m.validate(), "");
    EXPECT_GT(double(m.num_elements()) / n, 2.5) << "n = " << n;
    EXPECT_LT(double(m.num_elements()) / n, 3.6) << "n = " << n;
    elements.push_back(double(m.num_elements()));
    entries.push_back(double(m.num_vertex_entries()));
    const Model pixels = build_model(g, settings_2d(Layout::voxel));
    EXPECT_EQ(pixels.num_elements(), g.count());
    EXPECT_EQ(pixels.num_vertex_entries(), 4 * g.count());
    if (n == 512) {
      // 820 k pixel entries against 8.8 k: the reduction grows like n
      EXPECT_GT(double(pixels.num_vertex_entries()) / double(m.num_vertex_entries()), 80.0);
    }
  }
  // log-log slope over a factor 16 in n: 1 (like the outline), not 2 (like the area)
  const double span = std::log(double(sizes.back()) / sizes.front());
  EXPECT_NEAR(std::log(elements.back() / elements.front()) / span, 1.0, 0.1);
  EXPECT_NEAR(std::log(entries.back() / entries.front()) / span, 1.0, 0.1);
}

TEST(GradationalBuilder2d, UniformAndVoxelLayoutsCoverEveryPixelOnce) {
  const VoxelGrid g = make_grid({23, 17, 1}, [](int i, int j, int) { return (i * 7 + j * 3) % 11 != 0 && i + j > 4; });
  for (Layout layout : {Layout::gradational, Layout::uniform, Layout::voxel}) {
    const Model m = build_model(g, settings_2d(layout));
    expect_exact_cover(m, g);
    expect_nodes_shared(m);
    EXPECT_EQ(m.covered_voxels(), g.count());
    EXPECT_EQ(m.validate(), "");
    if (layout == Layout::uniform) {
      EXPECT_EQ(m.num_levels(), 1);
    }
  }
}

TEST(GradationalBuilder2d, NodesOnTheSliceCentrePlaneAndAreasTimesThickness) {
  GridGeometry geo;
  geo.dims = {16, 16, 1};
  geo.spacing_mm = {0.5, 0.5, 3.0};  // 3 mm slice
  geo.origin_mm = {10.0, -20.0, 42.0};
  VoxelGrid g(geo);
  for (int j = 0; j < 16; ++j)
    for (int i = 0; i < 16; ++i) g.set(i, j, 0, 1);
  const Model m = build_model(g, settings_2d());
  // voxel centres are at origin + index * spacing: the slice's centre plane is z = 42
  for (int n = 0; n < m.num_nodes(); ++n) EXPECT_DOUBLE_EQ(m.rest_positions(2, n), 42.0);
  // the square's corners: pixel corners at -0.25 mm and 7.75 mm from the origin in x and y
  EXPECT_DOUBLE_EQ(m.rest_positions.row(0).minCoeff(), 10.0 - 0.25);
  EXPECT_DOUBLE_EQ(m.rest_positions.row(0).maxCoeff(), 10.0 + 7.75);
  EXPECT_DOUBLE_EQ(m.rest_positions.row(1).minCoeff(), -20.0 - 0.25);
  EXPECT_NEAR(m.total_volume_mm3(), 8.0 * 8.0 * 3.0, 1e-9);  // area x thickness
  // element sizes are in-plane: the level-0 ring's elements span 2 pixels = 1 mm
  for (int e = 0; e < m.num_elements(); ++e)
    EXPECT_DOUBLE_EQ(m.element_size_mm[std::size_t(e)], 0.5 * m.element_edge_voxels(e));
  // every node on the outline is flagged, interior nodes are not
  int outline = 0;
  for (int n = 0; n < m.num_nodes(); ++n) {
    const Eigen::Vector3i a = m.node_lattice.col(n);
    const bool edge = a.x() == 0 || a.y() == 0 || a.x() == 16 || a.y() == 16;
    EXPECT_EQ(m.node_surface[std::size_t(n)] != 0, edge) << a.transpose();
    outline += edge;
  }
  EXPECT_EQ(outline, 64);  // every lattice point of the boundary (dense vertices on outline edges)
}

TEST(GradationalBuilder2d, RefusesThickGridsEmptySlicesAndBadSettings) {
  EXPECT_THROW((void)build_model(make_grid({8, 8, 2}, [](int, int, int) { return true; }), settings_2d()), Error);
  EXPECT_THROW((void)build_model(make_grid({8, 8, 1}, [](int, int, int) { return false; }), settings_2d()), Error);
  BuildSettings bad;
  bad.dimensions = 4;
  EXPECT_THROW((void)build_model(full_square(8), bad), Error);
  try {
    (void)build_model(make_grid({8, 8, 3}, [](int, int, int) { return true; }), settings_2d());
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("one voxel thick"), std::string::npos) << e.what();
  }
}

TEST(GradationalBuilder2d, VertexListGoesRoundTheElementCounterClockwise) {
  // the polygon through each element's vertex list, in order, is the element: its signed area
  // (shoelace, lattice units) is the area of its cells, for every layout
  for (const Layout layout : {Layout::gradational, Layout::uniform, Layout::voxel}) {
    const Model m = build_model(disk(64), settings_2d(layout));
    for (int e = 0; e < m.num_elements(); ++e) {
      const int b = m.element_offsets[std::size_t(e)], n = m.element_offsets[std::size_t(e) + 1] - b;
      double twice = 0;
      for (int k = 0; k < n; ++k) {
        const Eigen::Vector3i p = m.node_lattice.col(m.element_vertices[std::size_t(b + k)]);
        const Eigen::Vector3i q = m.node_lattice.col(m.element_vertices[std::size_t(b + (k + 1) % n)]);
        twice += double(p.x()) * q.y() - double(q.x()) * p.y();
      }
      const int w = m.element_cell_voxels[std::size_t(e)];
      const int cells = layout == Layout::voxel ? 1 : __builtin_popcount(m.element_cells[std::size_t(e)]);
      ASSERT_EQ(slice_element_parts(m, e).size(), 1u) << "a disk has no element of two corner-touching cells";
      EXPECT_DOUBLE_EQ(0.5 * twice, double(cells) * w * w) << to_string(layout) << " element " << e;
      // the fan from the first vertex (how VTK draws a polygon) has no triangle turned over, so it
      // covers the element exactly (an L starts at its inner corner)
      const Eigen::Vector3i p0 = m.node_lattice.col(m.element_vertices[std::size_t(b)]);
      for (int k = 1; k + 1 < n; ++k) {
        const Eigen::Vector3i p = m.node_lattice.col(m.element_vertices[std::size_t(b + k)]) - p0;
        const Eigen::Vector3i q = m.node_lattice.col(m.element_vertices[std::size_t(b + k + 1)]) - p0;
        EXPECT_GE(double(p.x()) * q.y() - double(q.x()) * p.y(), 0.0) << to_string(layout) << " element " << e;
      }
    }
  }
}
