#include "model/lattice_origin.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

#include <Eigen/Geometry>

#include "base/error.h"
#include "support/builder_checks.h"

using namespace vx;
using vx::testing::expect_exact_cover;
using vx::testing::make_grid;

namespace {

/// An n-voxel cube of tissue with `margin` air voxels before it and one after, 1 mm voxels.
VoxelGrid cube_with_margin(int n, int margin) {
  const int d = n + margin + 1;
  return make_grid({d, d, d}, [=](int i, int j, int k) {
    return i >= margin && j >= margin && k >= margin && i < margin + n && j < margin + n && k < margin + n;
  });
}

/// Patient positions (LPS mm) of the centres of the tissue voxels, sorted.
std::vector<std::array<double, 3>> tissue_centres(const VoxelGrid& g) {
  std::vector<std::array<double, 3>> out;
  for (int k = 0; k < g.dims().z(); ++k)
    for (int j = 0; j < g.dims().y(); ++j)
      for (int i = 0; i < g.dims().x(); ++i)
        if (g.at(i, j, k)) {
          const Eigen::Vector3d p = g.geometry().index_to_lps(Eigen::Vector3d(i, j, k));
          out.push_back({std::round(p.x() * 1e6), std::round(p.y() * 1e6), std::round(p.z() * 1e6)});
        }
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace

TEST(LatticeOrigin, PaddingKeepsEveryVoxelWhereItIs) {
  GridGeometry geo;
  geo.dims = {5, 4, 3};
  geo.spacing_mm = {0.7, 0.8, 1.5};
  geo.origin_mm = {-12.0, 30.5, 7.25};
  geo.direction = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  VoxelGrid g(geo);
  g.set(0, 0, 0, 1);
  g.set(4, 3, 2, 1);
  g.set(2, 1, 1, 1);
  const VoxelGrid p = pad_low(g, {3, 0, 2});
  EXPECT_EQ(p.dims(), Eigen::Vector3i(8, 4, 5));
  EXPECT_EQ(p.count(), 3);
  EXPECT_EQ(p.at(3, 0, 2), 1);
  EXPECT_EQ(p.at(7, 3, 4), 1);
  EXPECT_EQ(tissue_centres(p), tissue_centres(g));
  EXPECT_THROW((void)pad_low(g, {-1, 0, 0}), Error);
}

TEST(LatticeOrigin, The88VoxelCubeOfTheIssueLosesItsSurplusElements) {
  // issue #15: an 88-voxel cube cropped with a 1-voxel margin gets 14,974 elements; other
  // alignments of its corner give fewer
  const VoxelGrid cropped = cube_with_margin(88, 1);
  EXPECT_EQ(build_model(cropped).num_elements(), 14974);
  // this builder's groups start at the grid's first voxel: the cube's corner at voxel 2 (shift 1
  // from the cropped grid) is best, 14,043 elements; at 4 (shift 3) 14,289, at 3 (shift 2) 14,811
  std::int64_t best_entries = INT64_MAX;
  for (int margin = 1; margin <= 4; ++margin)
    best_entries = std::min(best_entries, build_model(cube_with_margin(88, margin)).num_vertex_entries());
  EXPECT_EQ(build_model(cube_with_margin(88, 4)).num_elements(), 14289);
  LatticeShiftReport r;
  const Eigen::Vector3i shift = choose_lattice_shift(cropped, {}, 4, &r);
  EXPECT_EQ(shift, Eigen::Vector3i(1, 1, 1));
  EXPECT_EQ(r.builds, 10);
  EXPECT_EQ(r.elements_unshifted, 14974);
  EXPECT_EQ(r.elements_chosen, 14043);  // 6.2 % fewer elements
  EXPECT_EQ(r.entries_chosen, best_entries);
  EXPECT_LT(double(r.entries_chosen), 0.97 * double(r.entries_unshifted));
  const Model m = build_model(pad_low(cropped, shift));
  EXPECT_EQ(m.num_vertex_entries(), r.entries_chosen);
  EXPECT_EQ(m.covered_voxels(), 88 * 88 * 88);
  // same tissue, same place: the bounding box of the nodes is the cube's, in mm
  const Model m0 = build_model(cropped);
  EXPECT_TRUE(m.rest_positions.rowwise().minCoeff().isApprox(m0.rest_positions.rowwise().minCoeff()));
  EXPECT_TRUE(m.rest_positions.rowwise().maxCoeff().isApprox(m0.rest_positions.rowwise().maxCoeff()));
}

TEST(LatticeOrigin, NeverWorseThanUnshiftedAndStillAnExactCover) {
  // an off-centre ball: the chosen shift never gives more entries than none, and the model
  // of the shifted grid covers every tissue voxel once
  const VoxelGrid g = make_grid({41, 37, 45}, [](int i, int j, int k) {
    return std::hypot(i - 19.3, j - 17.6, k - 22.1) < 16.2;
  });
  for (const int period : {1, 2, 4, 8}) {
    LatticeShiftReport r;
    const Eigen::Vector3i s = choose_lattice_shift(g, {}, period, &r);
    EXPECT_LE(r.entries_chosen, r.entries_unshifted) << period;
    EXPECT_TRUE((s.array() >= 0).all() && (s.array() < period).all()) << period;
    EXPECT_EQ(r.builds, 1 + 3 * (period - 1)) << period;
    const VoxelGrid padded = pad_low(g, s);
    const Model m = build_model(padded);
    EXPECT_EQ(m.num_vertex_entries(), r.entries_chosen);
    expect_exact_cover(m, padded);
  }
  EXPECT_THROW((void)choose_lattice_shift(g, {}, 3), Error);
}

TEST(LatticeOrigin, VoxelLayoutAndTwoDimensions) {
  const VoxelGrid g = cube_with_margin(10, 1);
  BuildSettings voxel;
  voxel.layout = Layout::voxel;
  LatticeShiftReport r;
  EXPECT_EQ(choose_lattice_shift(g, voxel, 4, &r), Eigen::Vector3i::Zero());
  EXPECT_EQ(r.builds, 1);

  // a one-slice grid: a 2D model; the third axis is never shifted (a slice stays one voxel thick)
  const VoxelGrid slice = make_grid({45, 45, 1}, [](int i, int j, int) { return i >= 1 && j >= 1 && i < 43 && j < 43; });
  BuildSettings flat;
  flat.dimensions = 2;
  const Eigen::Vector3i s = choose_lattice_shift(slice, flat, 4, &r);
  EXPECT_EQ(s.z(), 0);
  EXPECT_EQ(r.builds, 7);
  EXPECT_LE(r.entries_chosen, r.entries_unshifted);
}
