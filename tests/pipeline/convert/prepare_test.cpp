// From a volume to the voxel grid: component removal, hole filling, crop geometry, resampling.

#include "convert/prepare.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>
#include <numbers>

#include "base/error.h"
#include "model/gradational_builder.h"

using vx::Volume;
using vx::VoxelGrid;

namespace {

constexpr float kAir = -1000.0f, kTissue = 40.0f;

Volume air_volume(const Eigen::Vector3i& dims, const Eigen::Vector3d& spacing = {1, 1, 1},
                  const Eigen::Vector3d& origin = {0, 0, 0},
                  const Eigen::Matrix3d& direction = Eigen::Matrix3d::Identity()) {
  Volume v;
  v.geometry.dims = dims;
  v.geometry.spacing_mm = spacing;
  v.geometry.origin_mm = origin;
  v.geometry.direction = direction;
  v.hu.assign(std::size_t(v.geometry.voxel_count()), kAir);
  return v;
}

float& at(Volume& v, int i, int j, int k) {
  const auto& d = v.geometry.dims;
  return v.hu[std::size_t(i + d.x() * (j + d.y() * k))];
}

/// Sets [lo, hi) to `hu`.
void fill_box(Volume& v, const Eigen::Vector3i& lo, const Eigen::Vector3i& hi, float hu = kTissue) {
  for (int k = lo.z(); k < hi.z(); ++k)
    for (int j = lo.y(); j < hi.y(); ++j)
      for (int i = lo.x(); i < hi.x(); ++i) at(v, i, j, k) = hu;
}

vx::PrepareOptions soft_tissue(bool largest = false, bool holes = false, bool crop = false, double voxel_mm = 0) {
  vx::PrepareOptions o;
  o.range = {-200.0, std::numeric_limits<double>::infinity()};
  o.largest_component = largest;
  o.fill_holes = holes;
  o.crop = crop;
  o.voxel_mm = voxel_mm;
  return o;
}

TEST(PrepareGrid, KeepsTheLargestSixConnectedComponent) {
  Volume v = air_volume({20, 20, 20});
  fill_box(v, {2, 2, 2}, {7, 7, 7});        // 125 voxels
  fill_box(v, {10, 10, 10}, {13, 13, 13});  // 27 voxels
  at(v, 7, 7, 7) = kTissue;                 // touches the big box only at a corner: its own component
  vx::PrepareReport report;
  const VoxelGrid g = vx::prepare_grid(v, soft_tissue(true), &report);
  EXPECT_EQ(report.thresholded_voxels, 153);
  EXPECT_EQ(report.components, 3);
  EXPECT_EQ(report.removed_voxels, 28);
  EXPECT_EQ(report.tissue_voxels, 125);
  EXPECT_EQ(g.count(), 125);
  EXPECT_EQ(g.at(4, 4, 4), 1);
  EXPECT_EQ(g.at(11, 11, 11), 0);
  EXPECT_EQ(g.at(7, 7, 7), 0);
  // without the option nothing is removed
  vx::PrepareReport plain;
  EXPECT_EQ(vx::prepare_grid(v, soft_tissue(false), &plain).count(), 153);
  EXPECT_EQ(plain.components, 0);
  EXPECT_EQ(plain.removed_voxels, 0);
}

TEST(PrepareGrid, FillsClosedCavitiesButNotOpenOnes) {
  Volume v = air_volume({24, 12, 12});
  // a closed box: 7^3 voxels hollowed by a 5^3 = 125-voxel cavity
  fill_box(v, {1, 1, 1}, {8, 8, 8});
  fill_box(v, {2, 2, 2}, {7, 7, 7}, kAir);
  // an open box: same, with a tunnel from the cavity to the outside
  fill_box(v, {12, 1, 1}, {19, 8, 8});
  fill_box(v, {13, 2, 2}, {18, 7, 7}, kAir);
  fill_box(v, {15, 4, 7}, {16, 5, 8}, kAir);  // one-voxel hole in the top face
  vx::PrepareReport report;
  const VoxelGrid g = vx::prepare_grid(v, soft_tissue(false, true), &report);
  EXPECT_EQ(report.filled_voxels, 125);
  EXPECT_EQ(g.at(4, 4, 4), 1);
  EXPECT_EQ(g.at(15, 4, 4), 0);
  EXPECT_EQ(report.tissue_voxels, report.thresholded_voxels + 125);
}

TEST(PrepareGrid, AirLeavingThroughADiagonalGapIsNotACavity) {
  // a box with walls 2 voxels thick around a 4^3 = 64-voxel cavity; the cavity reaches the
  // outside only through two wall voxels that touch at a corner: (7,4,4) opens onto the cavity,
  // (8,5,5) onto the outside. Tissue is 6-connected, so that corner is a gap, not a wall.
  Volume v = air_volume({12, 12, 12});
  fill_box(v, {1, 1, 1}, {9, 9, 9});
  fill_box(v, {3, 3, 3}, {7, 7, 7}, kAir);
  at(v, 7, 4, 4) = kAir;
  at(v, 8, 5, 5) = kAir;
  vx::PrepareReport report;
  const VoxelGrid g = vx::prepare_grid(v, soft_tissue(false, true), &report);
  EXPECT_EQ(report.filled_voxels, 0);
  EXPECT_EQ(g.at(4, 4, 4), 0);
  EXPECT_EQ(g.at(7, 4, 4), 0);
  // close the gap and the same cavity (64 voxels, plus the pocket (7,4,4)) is filled
  at(v, 8, 5, 5) = kTissue;
  vx::PrepareReport closed;
  EXPECT_EQ(vx::prepare_grid(v, soft_tissue(false, true), &closed).at(4, 4, 4), 1);
  EXPECT_EQ(closed.filled_voxels, 65);
}

TEST(PrepareGrid, CropKeepsEveryVoxelInPlaceWithAnAirMargin) {
  const Eigen::Matrix3d d = Eigen::AngleAxisd(0.7, Eigen::Vector3d(-1, 2, 0.5).normalized()).toRotationMatrix();
  Volume v = air_volume({20, 15, 12}, {0.7, 0.9, 1.3}, {-40, 25, 110}, d);
  fill_box(v, {5, 3, 2}, {9, 6, 8});
  at(v, 9, 4, 4) = kTissue;  // a bump, so the box is not just the block
  vx::PrepareReport report;
  const VoxelGrid g = vx::prepare_grid(v, soft_tissue(false, false, true), &report);
  EXPECT_EQ(report.crop_lo, Eigen::Vector3i(4, 2, 1));
  EXPECT_EQ(report.crop_hi, Eigen::Vector3i(11, 7, 9));
  ASSERT_EQ(g.dims(), Eigen::Vector3i(7, 5, 8));
  EXPECT_EQ(g.geometry().spacing_mm, v.geometry.spacing_mm);
  EXPECT_EQ(g.geometry().direction, v.geometry.direction);
  EXPECT_EQ(g.count(), 4 * 3 * 6 + 1);
  // same patient position before and after, voxel by voxel
  for (int k = 0; k < 8; ++k)
    for (int j = 0; j < 5; ++j)
      for (int i = 0; i < 7; ++i) {
        const Eigen::Vector3i src = Eigen::Vector3i(i, j, k) + report.crop_lo;
        const Eigen::Vector3d before = v.geometry.index_to_lps(src.cast<double>());
        const Eigen::Vector3d after = g.geometry().index_to_lps(Eigen::Vector3d(i, j, k));
        ASSERT_LT((before - after).norm(), 1e-9);
        const bool tissue = v.at(src.x(), src.y(), src.z()) >= -200;
        EXPECT_EQ(g.at(i, j, k), tissue ? 1 : 0);
        const bool border = i == 0 || j == 0 || k == 0 || i == 6 || j == 4 || k == 7;
        if (border) {
          EXPECT_EQ(g.at(i, j, k), 0);
        }
      }
}

TEST(PrepareGrid, CropPadsTissueTouchingTheVolumeBorder) {
  Volume v = air_volume({6, 6, 6}, {1, 1, 1}, {10, 20, 30});
  fill_box(v, {0, 0, 0}, {6, 3, 2});
  vx::PrepareReport report;
  const VoxelGrid g = vx::prepare_grid(v, soft_tissue(false, false, true), &report);
  EXPECT_EQ(report.crop_lo, Eigen::Vector3i(-1, -1, -1));
  EXPECT_EQ(report.crop_hi, Eigen::Vector3i(7, 4, 3));
  EXPECT_EQ(g.dims(), Eigen::Vector3i(8, 5, 4));
  EXPECT_LT((g.geometry().origin_mm - Eigen::Vector3d(9, 19, 29)).norm(), 1e-12);
  EXPECT_EQ(g.count(), 36);
  EXPECT_EQ(g.at(0, 1, 1), 0);
  EXPECT_EQ(g.at(1, 1, 1), 1);
}

TEST(PrepareGrid, ResamplingHalvesDimsKeepsTheCentreAndTheTissueVolume) {
  // a sphere of radius 12 mm, off the voxel lattice, in a 64^3 grid of 1 mm voxels, resampled to 2 mm
  const Eigen::Matrix3d d = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  Volume v = air_volume({64, 64, 64}, {1, 1, 1}, -(d * Eigen::Vector3d::Constant(31.5)), d);
  const Eigen::Vector3d sphere_centre(31.5 + 0.3, 31.5 - 0.45, 31.5 + 0.2);  // in voxel indices
  // partial volume, as in a scan: each voxel holds tissue HU in proportion to its part inside (4^3 samples)
  for (int k = 0; k < 64; ++k)
    for (int j = 0; j < 64; ++j)
      for (int i = 0; i < 64; ++i) {
        int inside = 0;
        for (int c = 0; c < 64; ++c) {
          const Eigen::Vector3d sub = Eigen::Vector3d(c % 4, (c / 4) % 4, c / 16) * 0.25 - Eigen::Vector3d::Constant(0.375);
          inside += (Eigen::Vector3d(i, j, k) + sub - sphere_centre).norm() < 12.0;
        }
        at(v, i, j, k) = kAir + (kTissue - kAir) * float(inside) / 64.0f;
      }
  vx::PrepareOptions options = soft_tissue();
  options.range.lo = -480;  // halfway between air and tissue: averaging keeps the boundary in place
  vx::PrepareReport fine_report, coarse_report;
  const VoxelGrid fine = vx::prepare_grid(v, options, &fine_report);
  options.voxel_mm = 2.0;
  const VoxelGrid coarse = vx::prepare_grid(v, options, &coarse_report);
  EXPECT_EQ(coarse_report.input_dims, Eigen::Vector3i(64, 64, 64));
  EXPECT_EQ(coarse_report.resampled_dims, Eigen::Vector3i(32, 32, 32));
  ASSERT_EQ(coarse.dims(), Eigen::Vector3i(32, 32, 32));
  EXPECT_EQ(coarse.geometry().spacing_mm, Eigen::Vector3d(2, 2, 2));
  // the grid centre stays at the patient origin
  const Eigen::Vector3d centre = coarse.geometry().index_to_lps(Eigen::Vector3d::Constant(15.5));
  EXPECT_LT(centre.norm(), 1e-9);
  EXPECT_LT((coarse.geometry().lattice_to_lps({0, 0, 0}) - v.geometry.lattice_to_lps({0, 0, 0})).norm(), 1e-9);
  const double exact = 4.0 / 3.0 * std::numbers::pi * 12 * 12 * 12;  // 7238 mm^3
  const double fine_mm3 = double(fine.count()) * 1.0;
  const double coarse_mm3 = double(coarse.count()) * 8.0;
  // measured: fine 7245 mm^3 (+0.1%), coarse 7288 mm^3 (+0.7%)
  EXPECT_NEAR(fine_mm3, exact, 0.01 * exact);
  EXPECT_NEAR(coarse_mm3, exact, 0.015 * exact) << "fine " << fine_mm3 << " coarse " << coarse_mm3;
}

TEST(PrepareGrid, ResamplingAnisotropicVoxelsToIsotropic) {
  // 0.5 x 0.5 x 2 mm to 1 mm: shrinks x and y, grows z (linear interpolation, exact for a ramp)
  Volume v = air_volume({40, 40, 10}, {0.5, 0.5, 2.0}, {0, 0, 0});
  for (int k = 0; k < 10; ++k)
    for (int j = 0; j < 40; ++j)
      for (int i = 0; i < 40; ++i) at(v, i, j, k) = float(100 * k);  // 50 HU per mm along z
  vx::PrepareOptions options = soft_tissue();
  options.range = {250.0, 650.0};  // z from 5 mm (index 2.5) to 13 mm (index 6.5)
  options.voxel_mm = 1.0;
  options.crop = true;
  vx::PrepareReport report;
  const VoxelGrid g = vx::prepare_grid(v, options, &report);
  EXPECT_EQ(report.resampled_dims, Eigen::Vector3i(20, 20, 20));
  // new z centres: z = 9 - 9.5 + n = n - 0.5 mm; tissue where 250 <= 50 z <= 650: n = 6..13
  ASSERT_EQ(g.dims(), Eigen::Vector3i(22, 22, 10));
  EXPECT_EQ(report.crop_lo.z(), 5);
  EXPECT_EQ(report.crop_hi.z(), 15);
  EXPECT_EQ(g.count(), 20 * 20 * 8);
}

TEST(PrepareGrid, NoTissueSaysWhichRangeAndWhatTheVolumeHolds) {
  Volume v = air_volume({4, 4, 4});
  at(v, 1, 1, 1) = -300;
  try {
    (void)vx::prepare_grid(v, soft_tissue());
    FAIL() << "expected vx::Error";
  } catch (const vx::Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("-200 HU and above"), std::string::npos) << m;
    EXPECT_NE(m.find("-1000 to -300 HU"), std::string::npos) << m;
  }
  vx::PrepareOptions bad = soft_tissue();
  bad.voxel_mm = -1;
  EXPECT_THROW((void)vx::prepare_grid(v, bad), vx::Error);
  bad = soft_tissue();
  bad.range = {100, 50};
  EXPECT_THROW((void)vx::prepare_grid(v, bad), vx::Error);
}

TEST(PrepareGrid, ReportSummaryAndJson) {
  Volume v = air_volume({10, 10, 10}, {0.5, 0.5, 1.0});
  fill_box(v, {2, 2, 2}, {6, 6, 6});
  fill_box(v, {3, 3, 3}, {5, 5, 5}, kAir);  // 8-voxel cavity
  at(v, 8, 8, 8) = kTissue;
  vx::PrepareReport report;
  (void)vx::prepare_grid(v, soft_tissue(true, true, true), &report);
  const std::string s = report.summary();
  EXPECT_NE(s.find("input: 10 x 10 x 10 voxels of 0.5 x 0.5 x 1 mm"), std::string::npos) << s;
  EXPECT_NE(s.find("threshold: 57 tissue voxels"), std::string::npos) << s;
  EXPECT_NE(s.find("kept 1 of 2 components, removed 1 voxels"), std::string::npos) << s;
  EXPECT_NE(s.find("holes filled: 8 voxels"), std::string::npos) << s;
  EXPECT_NE(s.find("-> 6 x 6 x 6"), std::string::npos) << s;
  EXPECT_NE(s.find("tissue: 64 voxels"), std::string::npos) << s;
  // for a caller that prints the model's statistics (convert): the final count and the cropped
  // size are the model's, said there; the threshold's count differs from it here, so it stays
  const std::string lean = report.summary(false);
  EXPECT_EQ(lean.find("tissue: 64"), std::string::npos) << lean;
  EXPECT_EQ(lean.find("-> 6 x 6 x 6"), std::string::npos) << lean;
  EXPECT_NE(lean.find("threshold: 57 tissue voxels"), std::string::npos) << lean;
  nlohmann::json j;
  report.to_json(j);
  EXPECT_EQ(j.at("tissue_voxels").get<int>(), 64);
  EXPECT_EQ(j.at("filled_voxels").get<int>(), 8);
  EXPECT_EQ(j.at("crop_lo"), nlohmann::json::array({1, 1, 1}));
  EXPECT_EQ(j.at("input_spacing_mm")[0].get<double>(), 0.5);
}

}  // namespace

TEST(PrepareGrid, LatticeOriginMovesTheFirstVoxelNotTheTissue) {
  // docs/model.md 3.5: a 20-voxel cube of tissue at voxel 5 of a tilted 30^3 volume; with the
  // crop's 1-voxel margin the model has more entries than with the best origin, which pads the
  // grid on its low side and keeps every voxel at its patient position
  const Eigen::Matrix3d d = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, -1, 2).normalized()).toRotationMatrix();
  Volume v = air_volume({30, 30, 30}, {0.8, 0.8, 1.1}, {-10, 5, 60}, d);
  fill_box(v, {5, 5, 5}, {25, 25, 25});
  vx::PrepareOptions plain = soft_tissue(false, false, true);
  vx::PrepareReport r0;
  const VoxelGrid g0 = vx::prepare_grid(v, plain, &r0);
  EXPECT_EQ(r0.lattice_shift, Eigen::Vector3i::Zero());
  EXPECT_EQ(r0.entries_unshifted, 0);  // not chosen

  vx::PrepareOptions best = plain;
  best.lattice_period = 4;
  vx::PrepareReport r;
  const VoxelGrid g = vx::prepare_grid(v, best, &r);
  const vx::Model m0 = vx::build_model(g0), m = vx::build_model(g);
  EXPECT_EQ(r.entries_unshifted, m0.num_vertex_entries());
  EXPECT_EQ(r.entries_chosen, m.num_vertex_entries());
  EXPECT_LT(m.num_vertex_entries(), m0.num_vertex_entries());
  EXPECT_EQ(r.elements_chosen, m.num_elements());
  EXPECT_FALSE(r.lattice_shift.isZero());
  EXPECT_EQ(r.crop_lo, r0.crop_lo - r.lattice_shift);
  EXPECT_EQ(g.dims(), g0.dims() + r.lattice_shift);
  EXPECT_EQ(g.count(), 20 * 20 * 20);
  EXPECT_EQ(m.covered_voxels(), m0.covered_voxels());
  // the same voxel at the same place: grid index + shift
  for (const Eigen::Vector3i& ijk : {Eigen::Vector3i(1, 1, 1), Eigen::Vector3i(20, 7, 13)}) {
    const Eigen::Vector3d before = g0.geometry().index_to_lps(ijk.cast<double>());
    const Eigen::Vector3d after = g.geometry().index_to_lps((ijk + r.lattice_shift).cast<double>());
    EXPECT_LT((before - after).norm(), 1e-9);
    EXPECT_EQ(g.at(ijk.x() + r.lattice_shift.x(), ijk.y() + r.lattice_shift.y(), ijk.z() + r.lattice_shift.z()),
              g0.at(ijk.x(), ijk.y(), ijk.z()));
  }
  EXPECT_NE(r.summary().find("lattice origin:"), std::string::npos);
  nlohmann::json j;
  r.to_json(j);
  EXPECT_EQ(j.at("lattice_origin").at("entries_chosen"), r.entries_chosen);
}
