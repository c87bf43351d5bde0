// The slices of a DICOM series laid out (pipeline/io/dicom_slice_layout.cpp): sorted along the
// slice normal whatever the file order, oblique and reversed stacks, gantry tilt resampled,
// slices placed by instance number when asked, and duplicate, missing, uneven and mixed slices.
#include <gtest/gtest.h>

#include "io/dicom_series.h"
#include "support/dicom_files.h"

using namespace dicom_files;

namespace {

TEST_F(DicomSeries, ShuffledFilesAndNestedFoldersReadInSliceOrder) {
  const Volume v = pattern_volume({12, 9, 15}, {1.0, 1.0, 1.5}, {5, -7, 3});
  vx::write_dicom_series(v, dir_ / "written");
  auto files = files_in(dir_ / "written");
  std::mt19937 rng(7);
  std::shuffle(files.begin(), files.end(), rng);
  // copy under meaningless names into nested folders, so name order says nothing
  std::vector<fs::path> copies;
  for (std::size_t n = 0; n < files.size(); ++n) {
    const fs::path sub = dir_ / "shuffled" / (n % 2 ? "a" : "b") / (n % 3 ? "x" : "y");
    fs::create_directories(sub);
    copies.push_back(sub / ("IM" + std::to_string(rng() % 100000) + "_" + std::to_string(n)));
    fs::copy_file(files[n], copies.back());
  }
  expect_same_volume(v, vx::read_dicom_series({dir_ / "shuffled"}));
  expect_same_volume(v, vx::read_dicom_series(copies));
}

TEST_F(DicomSeries, ObliqueOrientationKeepsGeometry) {
  const Eigen::Matrix3d d = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Volume v = pattern_volume({11, 13, 7}, {0.75, 0.5, 1.25}, {-30.5, 12.0, 88.125}, d);
  vx::write_dicom_series(v, dir_ / "oblique", {});
  expect_same_volume(v, vx::read_dicom_series({dir_ / "oblique"}));
}

TEST_F(DicomSeries, SlicesAgainstTheNormalComeBackReversedInTheSamePlace) {
  // direction k = -(row x col): the reader orders slices along the normal, so k is reversed,
  // but every voxel keeps its patient position and value
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = -1;
  const Volume v = pattern_volume({6, 5, 4}, {1, 1, 2}, {0, 0, 10}, d);
  vx::write_dicom_series(v, dir_ / "reversed");
  const Volume r = vx::read_dicom_series({dir_ / "reversed"});
  ASSERT_EQ(r.geometry.dims, v.geometry.dims);
  EXPECT_NEAR(r.geometry.direction(2, 2), 1.0, 1e-12);
  EXPECT_NEAR(r.geometry.origin_mm.z(), 4.0, 1e-9);  // the last written slice, z = 10 - 3*2
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 5; ++j)
      for (int i = 0; i < 6; ++i) {
        const auto value = value_at(r, v.geometry.index_to_lps(Eigen::Vector3d(i, j, k)));
        ASSERT_TRUE(value.has_value());
        EXPECT_EQ(*value, v.at(i, j, k));
      }
}

TEST_F(DicomSeries, GantryTiltIsResampledOntoAnOrthogonalGrid) {
  // each slice starts one column further along the row: a tilt of atan(0.8 / 2) = 21.8 degrees
  const double col_spacing = 0.8, dz = 2.0;
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  const Eigen::Vector3d step(col_spacing, 0, dz);
  d.col(2) = step.normalized();
  const Volume v = pattern_volume({10, 6, 5}, {col_spacing, 0.5, step.norm()}, {1, 2, 3}, d);
  vx::write_dicom_series(v, dir_ / "tilt");
  const Volume r = vx::read_dicom_series({dir_ / "tilt"});
  EXPECT_TRUE(r.geometry.direction_is_orthonormal());
  EXPECT_LT((r.geometry.direction - Eigen::Matrix3d::Identity()).norm(), 1e-9);
  ASSERT_EQ(r.geometry.dims, Eigen::Vector3i(10 + 4, 6, 5));  // grown by the 4-column shear
  EXPECT_NEAR(r.geometry.spacing_mm.z(), dz, 1e-9);
  EXPECT_LT((r.geometry.origin_mm - Eigen::Vector3d(1, 2, 3)).norm(), 1e-6);
  // every input voxel is found at its place with its value; the rest is air
  std::size_t found = 0, air = 0;
  for (int k = 0; k < 5; ++k)
    for (int j = 0; j < 6; ++j)
      for (int i = 0; i < 14; ++i) {
        const Eigen::Vector3d src = v.geometry.lps_to_index(r.geometry.index_to_lps(Eigen::Vector3d(i, j, k)));
        const Eigen::Vector3i s = src.array().round().cast<int>();
        ASSERT_LT((src - s.cast<double>()).norm(), 1e-6);
        if (s.x() >= 0 && s.x() < 10) {
          EXPECT_EQ(r.at(i, j, k), v.at(s.x(), s.y(), s.z()));
          ++found;
        } else {
          EXPECT_EQ(r.at(i, j, k), -1000.0f);
          ++air;
        }
      }
  EXPECT_EQ(found, 10u * 6 * 5);
  EXPECT_EQ(air, 4u * 6 * 5);
}

TEST_F(DicomSeries, FractionalGantryTiltInterpolatesLinearly) {
  // a shift of 0.3 column per slice, values linear along the row: bilinear sampling is exact
  Volume v;
  auto& g = v.geometry;
  g.dims = {12, 4, 6};
  g.spacing_mm = {1.0, 1.0, 0};
  const Eigen::Vector3d step(0.3, 0, 1.5);
  g.direction.col(2) = step.normalized();
  g.spacing_mm.z() = step.norm();
  for (int k = 0; k < 6; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 12; ++i) v.hu.push_back(float(10 * i + 100 * j + 1000 * k));
  vx::write_dicom_series(v, dir_ / "tilt");
  const Volume r = vx::read_dicom_series({dir_ / "tilt"});
  ASSERT_EQ(r.geometry.dims, Eigen::Vector3i(12 + 2, 4, 6));  // 5 * 0.3 = 1.5 columns -> 2 more
  int checked = 0;
  for (int k = 0; k < 6; ++k)
    for (int i = 0; i < 14; ++i) {
      const Eigen::Vector3d src = v.geometry.lps_to_index(r.geometry.index_to_lps(Eigen::Vector3d(i, 1, k)));
      if (src.x() < 0 || src.x() > 11) continue;  // edges: clamped or air
      EXPECT_NEAR(r.at(i, 1, k), 10 * src.x() + 100 * 1 + 1000 * k, 1e-3) << i << " " << k;
      ++checked;
    }
  EXPECT_GT(checked, 60);
}

TEST_F(DicomSeries, SecondaryCaptureWithoutGeometryIsPlacedByInstanceNumberWhenAsked) {
  SliceSpec sc;
  sc.sop_class = UID_SecondaryCaptureImageStorage;
  sc.modality = "OT";
  sc.position_present = false;
  write_stack(dir_ / "sc", 3, 1.0, sc);
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "sc"}), "no CT series", "--modality any");
  vx::ReadOptions options;
  options.any_modality = true;
  const Volume r = vx::read_dicom_series({dir_ / "sc"}, options);
  EXPECT_EQ(r.geometry.dims.z(), 3);
}

TEST_F(DicomSeries, DuplicateMissingAndUnevenSlices) {
  SliceSpec s;
  s.series_uid = uid(SITE_SERIES_UID_ROOT);
  write_stack(dir_ / "dup", 5, 2.0, s);
  s.position = {0, 0, 4};  // where s2 already is
  write_slice(dir_ / "dup" / "again.dcm", s);
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "dup"}), "same position", "again.dcm", "s2.dcm");

  // an exact copy of a file is the same image, not a conflict
  fs::remove(dir_ / "dup" / "again.dcm");
  fs::copy_file(dir_ / "dup" / "s3.dcm", dir_ / "dup" / "s3_copy.dcm");
  EXPECT_EQ(vx::read_dicom_series({dir_ / "dup"}).geometry.dims.z(), 5);

  write_stack(dir_ / "gap", 6, 2.0, {});
  fs::remove(dir_ / "gap" / "s3.dcm");
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "gap"}), "misses 1 slice", "s2.dcm", "s4.dcm");

  SliceSpec u;
  u.series_uid = uid(SITE_SERIES_UID_ROOT);
  write_stack(dir_ / "uneven", 5, 2.0, u);
  u.position = {0, 0, 8 + 1.3};
  write_slice(dir_ / "uneven" / "s5.dcm", u);
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "uneven"}), "non-uniform slice spacing", "1.300", "s5.dcm");
}

TEST_F(DicomSeries, MixedOrientationsAndMissingPosition) {
  SliceSpec s;
  s.series_uid = uid(SITE_SERIES_UID_ROOT);
  write_stack(dir_ / "orient", 4, 1.0, s);
  SliceSpec t = s;
  t.row = {0.8, 0.6, 0};
  t.col = {-0.6, 0.8, 0};
  t.position = {0, 0, 4};
  write_slice(dir_ / "orient" / "turned.dcm", t);
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "orient"}), "mixes slice orientations", "turned.dcm");

  SliceSpec p;
  p.series_uid = uid(SITE_SERIES_UID_ROOT);
  write_stack(dir_ / "nopos", 3, 1.0, p);
  p.position_present = false;
  write_slice(dir_ / "nopos" / "lost.dcm", p);
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "nopos"}), "lost.dcm", "ImagePositionPatient");
}

}  // namespace
