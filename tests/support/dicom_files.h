#pragma once
/// @file dicom_files.h
/// Test helpers for the DICOM reader's tests (tests/pipeline/io/dicom_*_test.cpp): a scratch
/// folder per test (the DicomSeries fixture), volumes with a voxel pattern, slices and stacks
/// written with DCMTK, files edited in place, and EXPECT_ERROR_HAS for the reader's messages.
#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcmetinf.h>
#include <dcmtk/dcmdata/dcpixel.h>
#include <dcmtk/dcmdata/dcpixseq.h>
#include <dcmtk/dcmdata/dcpxitem.h>
#include <dcmtk/dcmdata/dcrlerp.h>
#include <dcmtk/dcmdata/dcsequen.h>
#include <dcmtk/dcmdata/dcuid.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

#include "base/error.h"
#include "convert/phantom.h"
#include "io/dicom_common.h"
#include "io/dicom_series.h"

namespace dicom_files {

namespace fs = std::filesystem;
using vx::Volume;

/// A fresh, empty scratch folder per test, removed afterwards.
class DicomSeries : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name = std::string(info->test_suite_name()) + "_" + info->name();
    std::replace(name.begin(), name.end(), '/', '_');
    dir_ = fs::path(VX_BINARY_DIR) / "test_scratch" / "dicom_series_test" / name;
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  fs::path dir_;
};

/// Integer HU values that differ from voxel to voxel (-1000 .. 1599).
inline float pattern_hu(int i, int j, int k) { return float(-1000 + (i * 37 + j * 101 + k * 211) % 2600); }

inline Volume pattern_volume(const Eigen::Vector3i& dims, const Eigen::Vector3d& spacing, const Eigen::Vector3d& origin,
                             const Eigen::Matrix3d& direction = Eigen::Matrix3d::Identity()) {
  Volume v;
  v.geometry.dims = dims;
  v.geometry.spacing_mm = spacing;
  v.geometry.origin_mm = origin;
  v.geometry.direction = direction;
  v.hu.resize(std::size_t(v.geometry.voxel_count()));
  for (int k = 0; k < dims.z(); ++k)
    for (int j = 0; j < dims.y(); ++j)
      for (int i = 0; i < dims.x(); ++i) v.hu[std::size_t(i + dims.x() * (j + dims.y() * k))] = pattern_hu(i, j, k);
  return v;
}

inline void expect_same_volume(const Volume& expected, const Volume& actual) {
  const auto& a = expected.geometry;
  const auto& b = actual.geometry;
  ASSERT_EQ(a.dims, b.dims);
  EXPECT_LT((a.spacing_mm - b.spacing_mm).cwiseAbs().maxCoeff(), 1e-6) << b.spacing_mm.transpose();
  EXPECT_LT((a.origin_mm - b.origin_mm).cwiseAbs().maxCoeff(), 1e-6) << b.origin_mm.transpose();
  EXPECT_LT((a.direction - b.direction).cwiseAbs().maxCoeff(), 1e-9) << b.direction;
  ASSERT_EQ(expected.hu.size(), actual.hu.size());
  std::size_t differ = 0;
  for (std::size_t p = 0; p < expected.hu.size(); ++p) differ += expected.hu[p] != actual.hu[p];
  EXPECT_EQ(differ, 0u) << "voxels with another value";
}

/// The value of `v` at the voxel whose centre is at `lps`, if there is one (within 1e-4 voxel).
inline std::optional<float> value_at(const Volume& v, const Eigen::Vector3d& lps) {
  const Eigen::Vector3d x = v.geometry.lps_to_index(lps);
  const Eigen::Vector3d r = x.array().round();
  if ((x - r).cwiseAbs().maxCoeff() > 1e-4) return std::nullopt;
  const Eigen::Vector3i i = r.cast<int>();
  if ((i.array() < 0).any() || (i.array() >= v.geometry.dims.array()).any()) return std::nullopt;
  return v.at(i.x(), i.y(), i.z());
}

inline std::vector<fs::path> files_in(const fs::path& dir) {
  std::vector<fs::path> files;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file()) files.push_back(e.path());
  std::sort(files.begin(), files.end());
  return files;
}

inline std::string uid(const char* root = SITE_INSTANCE_UID_ROOT) {
  char buf[100];
  return dcmGenerateUniqueIdentifier(buf, root);
}

inline std::string ds3(const Eigen::Vector3d& v) {
  char buf[128];
  std::snprintf(buf, sizeof buf, "%.10g\\%.10g\\%.10g", v.x(), v.y(), v.z());
  return buf;
}

/// One hand-made image file, for inputs the writer never produces.
struct SliceSpec {
  int rows{8}, cols{10};
  Eigen::Vector3d position{0, 0, 0};
  Eigen::Vector3d row{1, 0, 0}, col{0, 1, 0};
  double row_spacing{0.8}, col_spacing{0.6};
  double slope{1.0}, intercept{-1024.0};
  int pixel_rep{0}, bits_stored{16};
  std::string series_uid;
  std::string sop_instance;
  std::string sop_class{UID_CTImageStorage};
  std::string modality{"CT"};
  std::string image_type{"ORIGINAL\\PRIMARY\\AXIAL"};
  std::optional<long> padding;
  std::vector<Uint16> pixels;  ///< rows * cols stored words; empty = a ramp
  bool pixel_data{true}, position_present{true};
  int instance{1};
};

inline void write_slice(const fs::path& path, const SliceSpec& s) {
  DcmFileFormat file;
  DcmDataset* ds = file.getDataset();
  ds->putAndInsertString(DCM_SOPClassUID, s.sop_class.c_str());
  ds->putAndInsertString(DCM_SOPInstanceUID, (s.sop_instance.empty() ? uid() : s.sop_instance).c_str());
  ds->putAndInsertString(DCM_Modality, s.modality.c_str());
  ds->putAndInsertString(DCM_SeriesInstanceUID, s.series_uid.c_str());
  ds->putAndInsertString(DCM_StudyInstanceUID, "1.2.3.4");
  ds->putAndInsertString(DCM_ImageType, s.image_type.c_str());
  ds->putAndInsertString(DCM_InstanceNumber, std::to_string(s.instance).c_str());
  if (s.position_present) ds->putAndInsertString(DCM_ImagePositionPatient, ds3(s.position).c_str());
  const std::string iop = ds3(s.row) + "\\" + ds3(s.col);
  ds->putAndInsertString(DCM_ImageOrientationPatient, iop.c_str());
  const std::string spacing = std::to_string(s.row_spacing) + "\\" + std::to_string(s.col_spacing);
  ds->putAndInsertString(DCM_PixelSpacing, spacing.c_str());
  ds->putAndInsertString(DCM_RescaleSlope, std::to_string(s.slope).c_str());
  ds->putAndInsertString(DCM_RescaleIntercept, std::to_string(s.intercept).c_str());
  ds->putAndInsertUint16(DCM_SamplesPerPixel, 1);
  ds->putAndInsertString(DCM_PhotometricInterpretation, "MONOCHROME2");
  ds->putAndInsertUint16(DCM_Rows, Uint16(s.rows));
  ds->putAndInsertUint16(DCM_Columns, Uint16(s.cols));
  ds->putAndInsertUint16(DCM_BitsAllocated, 16);
  ds->putAndInsertUint16(DCM_BitsStored, Uint16(s.bits_stored));
  ds->putAndInsertUint16(DCM_HighBit, Uint16(s.bits_stored - 1));
  ds->putAndInsertUint16(DCM_PixelRepresentation, Uint16(s.pixel_rep));
  if (s.padding) {
    if (s.pixel_rep)
      ds->putAndInsertSint16(DCM_PixelPaddingValue, Sint16(*s.padding));
    else
      ds->putAndInsertUint16(DCM_PixelPaddingValue, Uint16(*s.padding));
  }
  if (s.pixel_data) {
    std::vector<Uint16> px = s.pixels;
    if (px.empty())
      for (int p = 0; p < s.rows * s.cols; ++p) px.push_back(Uint16(1024 + p));
    ds->putAndInsertUint16Array(DCM_PixelData, px.data(), unsigned(px.size()));
  }
  ASSERT_TRUE(file.saveFile(path.c_str(), EXS_LittleEndianExplicit).good()) << path;
}

/// A stack of hand-made slices along z (spacing dz), one file each.
inline void write_stack(const fs::path& dir, int slices, double dz, SliceSpec spec, const std::string& prefix = "s") {
  fs::create_directories(dir);
  if (spec.series_uid.empty()) spec.series_uid = uid(SITE_SERIES_UID_ROOT);
  const Eigen::Vector3d normal = spec.row.cross(spec.col);
  const Eigen::Vector3d start = spec.position;
  for (int k = 0; k < slices; ++k) {
    SliceSpec s = spec;
    s.position = start + normal * (dz * k);
    s.instance = k + 1;
    write_slice(dir / (prefix + std::to_string(k) + ".dcm"), s);
  }
}

template <class F>
inline std::string error_of(F&& f) {
  try {
    f();
  } catch (const vx::Error& e) {
    return e.what();
  } catch (const std::exception& e) {
    return std::string("UNEXPECTED EXCEPTION TYPE: ") + e.what();
  }
  return "NO ERROR";
}

#define EXPECT_ERROR_HAS(call, ...)                                         \
  do {                                                                      \
    const std::string message_ = error_of([&] { (void)(call); });           \
    for (const std::string& part_ : std::vector<std::string>{__VA_ARGS__})  \
      EXPECT_NE(message_.find(part_), std::string::npos)                    \
          << "message: " << message_ << "\nexpected to contain: " << part_; \
  } while (0)

inline std::string transfer_syntax_of(const fs::path& file) {
  DcmFileFormat ff;
  if (ff.loadFile(file.c_str()).bad()) return "unreadable";
  OFString s;
  ff.getMetaInfo()->findAndGetOFString(DCM_TransferSyntaxUID, s);
  return s.c_str();
}

/// Loads `file`, lets `edit` change its data set, saves it in the same transfer syntax.
template <class F>
inline void edit_file(const fs::path& file, F&& edit) {
  DcmFileFormat ff;
  ASSERT_TRUE(ff.loadFile(file.c_str()).good()) << file;
  ff.loadAllDataIntoMemory();
  edit(ff.getDataset());
  ASSERT_TRUE(ff.saveFile(file.c_str(), ff.getDataset()->getOriginalXfer()).good()) << file;
}

}  // namespace dicom_files
