// DICOM series in and out: round trips in every transfer syntax the writer offers, file order,
// orientation, gantry tilt, enhanced multi-frame CT, and every kind of bad input.

#include "io/dicom_series.h"

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
#include <fstream>
#include <optional>
#include <random>

#include <unistd.h>

#include "base/error.h"
#include "convert/phantom.h"
#include "io/dicom_common.h"

namespace fs = std::filesystem;
using vx::Volume;

namespace {

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
float pattern_hu(int i, int j, int k) { return float(-1000 + (i * 37 + j * 101 + k * 211) % 2600); }

Volume pattern_volume(const Eigen::Vector3i& dims, const Eigen::Vector3d& spacing, const Eigen::Vector3d& origin,
                      const Eigen::Matrix3d& direction = Eigen::Matrix3d::Identity()) {
  Volume v;
  v.geometry.dims = dims;
  v.geometry.spacing_mm = spacing;
  v.geometry.origin_mm = origin;
  v.geometry.direction = direction;
  v.hu.resize(std::size_t(v.geometry.voxel_count()));
  for (int k = 0; k < dims.z(); ++k)
    for (int j = 0; j < dims.y(); ++j)
      for (int i = 0; i < dims.x(); ++i)
        v.hu[std::size_t(i + dims.x() * (j + dims.y() * k))] = pattern_hu(i, j, k);
  return v;
}

void expect_same_volume(const Volume& expected, const Volume& actual) {
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
std::optional<float> value_at(const Volume& v, const Eigen::Vector3d& lps) {
  const Eigen::Vector3d x = v.geometry.lps_to_index(lps);
  const Eigen::Vector3d r = x.array().round();
  if ((x - r).cwiseAbs().maxCoeff() > 1e-4) return std::nullopt;
  const Eigen::Vector3i i = r.cast<int>();
  if ((i.array() < 0).any() || (i.array() >= v.geometry.dims.array()).any()) return std::nullopt;
  return v.at(i.x(), i.y(), i.z());
}

std::vector<fs::path> files_in(const fs::path& dir) {
  std::vector<fs::path> files;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file()) files.push_back(e.path());
  std::sort(files.begin(), files.end());
  return files;
}

std::string uid(const char* root = SITE_INSTANCE_UID_ROOT) {
  char buf[100];
  return dcmGenerateUniqueIdentifier(buf, root);
}

std::string ds3(const Eigen::Vector3d& v) {
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

void write_slice(const fs::path& path, const SliceSpec& s) {
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
    if (s.pixel_rep) ds->putAndInsertSint16(DCM_PixelPaddingValue, Sint16(*s.padding));
    else ds->putAndInsertUint16(DCM_PixelPaddingValue, Uint16(*s.padding));
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
void write_stack(const fs::path& dir, int slices, double dz, SliceSpec spec, const std::string& prefix = "s") {
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
std::string error_of(F&& f) {
  try {
    f();
  } catch (const vx::Error& e) {
    return e.what();
  } catch (const std::exception& e) {
    return std::string("UNEXPECTED EXCEPTION TYPE: ") + e.what();
  }
  return "NO ERROR";
}

#define EXPECT_ERROR_HAS(call, ...)                                                        \
  do {                                                                                     \
    const std::string message_ = error_of([&] { (void)(call); });                          \
    for (const std::string& part_ : std::vector<std::string>{__VA_ARGS__})                 \
      EXPECT_NE(message_.find(part_), std::string::npos) << "message: " << message_        \
                                                         << "\nexpected to contain: " << part_; \
  } while (0)

std::string transfer_syntax_of(const fs::path& file) {
  DcmFileFormat ff;
  if (ff.loadFile(file.c_str()).bad()) return "unreadable";
  OFString s;
  ff.getMetaInfo()->findAndGetOFString(DCM_TransferSyntaxUID, s);
  return s.c_str();
}

// ---------------------------------------------------------------- round trips

class DicomRoundTrip : public DicomSeries, public ::testing::WithParamInterface<std::pair<const char*, const char*>> {};

TEST_P(DicomRoundTrip, VoxelExactInEveryTransferSyntax) {
  const auto [syntax, expected_uid] = GetParam();
  const Volume v = pattern_volume({20, 16, 6}, {0.7, 0.9, 2.5}, {-12.5, 30.25, -100.0});
  vx::DicomWriteSettings settings;
  settings.transfer_syntax = syntax;
  vx::write_dicom_series(v, dir_ / "series", settings);
  const auto files = files_in(dir_ / "series");
  ASSERT_EQ(files.size(), 6u);
  for (const auto& f : files) EXPECT_EQ(transfer_syntax_of(f), expected_uid) << f;
  expect_same_volume(v, vx::read_dicom_series({dir_ / "series"}));
}

INSTANTIATE_TEST_SUITE_P(
    Syntaxes, DicomRoundTrip,
    ::testing::Values(std::pair{"explicit-little", UID_LittleEndianExplicitTransferSyntax},
                      std::pair{"implicit-little", UID_LittleEndianImplicitTransferSyntax},
                      std::pair{"rle", UID_RLELosslessTransferSyntax},
                      std::pair{"jpeg-lossless", UID_JPEGProcess14SV1TransferSyntax},
                      std::pair{"jpeg-ls-lossless", UID_JPEGLSLosslessTransferSyntax},
                      std::pair{"jpeg2000-lossless", UID_JPEG2000LosslessOnlyTransferSyntax}),
    [](const auto& info) {
      std::string n = info.param.first;
      std::replace(n.begin(), n.end(), '-', '_');
      return n;
    });

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

// ---------------------------------------------------------------- enhanced and hand-made inputs

/// An Enhanced CT Image Storage file: frames in the order given, positions per frame.
void write_enhanced(const fs::path& path, int rows, int cols, const std::vector<int>& frame_slices, double dz,
                    const std::vector<std::vector<Uint16>>& slice_pixels, E_TransferSyntax xfer) {
  DcmFileFormat file;
  DcmDataset* ds = file.getDataset();
  ds->putAndInsertString(DCM_SOPClassUID, UID_EnhancedCTImageStorage);
  ds->putAndInsertString(DCM_SOPInstanceUID, uid().c_str());
  ds->putAndInsertString(DCM_Modality, "CT");
  ds->putAndInsertString(DCM_SeriesInstanceUID, uid(SITE_SERIES_UID_ROOT).c_str());
  ds->putAndInsertString(DCM_ImageType, "ORIGINAL\\PRIMARY\\AXIAL\\NONE");
  ds->putAndInsertString(DCM_NumberOfFrames, std::to_string(frame_slices.size()).c_str());
  ds->putAndInsertUint16(DCM_SamplesPerPixel, 1);
  ds->putAndInsertString(DCM_PhotometricInterpretation, "MONOCHROME2");
  ds->putAndInsertUint16(DCM_Rows, Uint16(rows));
  ds->putAndInsertUint16(DCM_Columns, Uint16(cols));
  ds->putAndInsertUint16(DCM_BitsAllocated, 16);
  ds->putAndInsertUint16(DCM_BitsStored, 16);
  ds->putAndInsertUint16(DCM_HighBit, 15);
  ds->putAndInsertUint16(DCM_PixelRepresentation, 0);
  DcmItem* shared = nullptr;
  ds->findOrCreateSequenceItem(DCM_SharedFunctionalGroupsSequence, shared, 0);
  DcmItem* m = nullptr;
  shared->findOrCreateSequenceItem(DCM_PixelMeasuresSequence, m, 0);
  m->putAndInsertString(DCM_PixelSpacing, "0.5\\0.75");
  m->putAndInsertString(DCM_SliceThickness, "1");
  shared->findOrCreateSequenceItem(DCM_PlaneOrientationSequence, m, 0);
  m->putAndInsertString(DCM_ImageOrientationPatient, "1\\0\\0\\0\\1\\0");
  shared->findOrCreateSequenceItem(DCM_PixelValueTransformationSequence, m, 0);
  m->putAndInsertString(DCM_RescaleSlope, "1");
  m->putAndInsertString(DCM_RescaleIntercept, "-1024");
  std::vector<Uint16> all;
  for (std::size_t f = 0; f < frame_slices.size(); ++f) {
    const int k = frame_slices[f];
    DcmItem* per = nullptr;
    ds->findOrCreateSequenceItem(DCM_PerFrameFunctionalGroupsSequence, per, long(f));
    per->findOrCreateSequenceItem(DCM_PlanePositionSequence, m, 0);
    m->putAndInsertString(DCM_ImagePositionPatient, ds3(Eigen::Vector3d(-5, 7, 40 + dz * k)).c_str());
    std::vector<Uint16> px = slice_pixels[std::size_t(k)];
    if (k == 2) {
      // this frame overrides the shared rescale: stored = (hu + 2000) / 2
      per->findOrCreateSequenceItem(DCM_PixelValueTransformationSequence, m, 0);
      m->putAndInsertString(DCM_RescaleSlope, "2");
      m->putAndInsertString(DCM_RescaleIntercept, "-2000");
      for (auto& p : px) p = Uint16((int(p) - 1024 + 2000) / 2);
    }
    all.insert(all.end(), px.begin(), px.end());
  }
  ds->putAndInsertUint16Array(DCM_PixelData, all.data(), unsigned(all.size()));
  if (xfer != EXS_LittleEndianExplicit) {
    DcmRLERepresentationParameter rle;
    ASSERT_TRUE(ds->chooseRepresentation(xfer, &rle).good());
  }
  ASSERT_TRUE(file.saveFile(path.c_str(), xfer).good());
}

TEST_F(DicomSeries, EnhancedMultiFrameCtWithPerFrameRescale) {
  const int rows = 6, cols = 7, slices = 5;
  std::vector<std::vector<Uint16>> px(slices);
  for (int k = 0; k < slices; ++k)
    for (int p = 0; p < rows * cols; ++p) px[std::size_t(k)].push_back(Uint16(1024 + 2 * (p * 3 + k * 50)));  // even HU
  for (const E_TransferSyntax xfer : {EXS_LittleEndianExplicit, EXS_RLELossless}) {
    const fs::path folder = dir_ / (xfer == EXS_RLELossless ? "rle" : "raw");
    fs::create_directories(folder);
    write_enhanced(folder / "enhanced.dcm", rows, cols, {3, 0, 4, 2, 1}, 1.25, px, xfer);
    const Volume r = vx::read_dicom_series({folder / "enhanced.dcm"});
    ASSERT_EQ(r.geometry.dims, Eigen::Vector3i(cols, rows, slices));
    EXPECT_NEAR(r.geometry.spacing_mm.x(), 0.75, 1e-12);  // column spacing
    EXPECT_NEAR(r.geometry.spacing_mm.y(), 0.5, 1e-12);   // row spacing
    EXPECT_NEAR(r.geometry.spacing_mm.z(), 1.25, 1e-9);
    EXPECT_LT((r.geometry.origin_mm - Eigen::Vector3d(-5, 7, 40)).norm(), 1e-9);
    for (int k = 0; k < slices; ++k)
      for (int p = 0; p < rows * cols; ++p)
        ASSERT_EQ(r.hu[std::size_t(k * rows * cols + p)], float(2 * (p * 3 + k * 50))) << "slice " << k << " pixel " << p;
  }
}

TEST_F(DicomSeries, SignedPixelsHighBitsAndPaddingValue) {
  // 12 bits stored, signed, junk above the high bit; -2000 marks padding
  SliceSpec s;
  s.pixel_rep = 1;
  s.bits_stored = 12;
  s.slope = 1;
  s.intercept = 0;
  s.padding = -2000;
  s.rows = 2;
  s.cols = 3;
  const std::vector<int> values = {-1024, -2000, 0, 2047, -2048, 40};
  for (int v : values) s.pixels.push_back(Uint16((Uint16(v) & 0x0FFF) | 0xA000));
  write_stack(dir_ / "signed", 3, 1.0, s);
  const Volume r = vx::read_dicom_series({dir_ / "signed"});
  ASSERT_EQ(r.geometry.dims, Eigen::Vector3i(3, 2, 3));
  const std::vector<float> expected = {-1024, -1000, 0, 2047, -2048, 40};
  for (int k = 0; k < 3; ++k)
    for (int p = 0; p < 6; ++p) EXPECT_EQ(r.hu[std::size_t(6 * k + p)], expected[std::size_t(p)]) << p;
}

TEST_F(DicomSeries, RescaleSlopeAndInterceptAreAppliedInFloatingPoint) {
  SliceSpec s;
  s.slope = 0.5;
  s.intercept = -1000.25;
  s.rows = 1;
  s.cols = 4;
  s.pixels = {0, 1, 2001, 65535};
  write_stack(dir_ / "rescale", 2, 3.0, s);
  const Volume r = vx::read_dicom_series({dir_ / "rescale"});
  EXPECT_FLOAT_EQ(r.hu[0], -1000.25f);
  EXPECT_FLOAT_EQ(r.hu[1], -999.75f);
  EXPECT_FLOAT_EQ(r.hu[2], 0.25f);
  EXPECT_FLOAT_EQ(r.hu[3], 31767.25f);
}

TEST_F(DicomSeries, PicksTheLargestCtSeriesOrTheOneAsked) {
  SliceSpec small, large;
  small.series_uid = "1.2.826.0.1.3680043.9.7777.1";
  large.series_uid = "1.2.826.0.1.3680043.9.7777.2";
  write_stack(dir_ / "mixed", 4, 1.0, small, "small");
  write_stack(dir_ / "mixed", 9, 2.0, large, "large");
  EXPECT_EQ(vx::read_dicom_series({dir_ / "mixed"}).geometry.dims.z(), 9);
  vx::ReadOptions options;
  options.series_uid = small.series_uid;
  const Volume r = vx::read_dicom_series({dir_ / "mixed"}, options);
  EXPECT_EQ(r.geometry.dims.z(), 4);
  EXPECT_NEAR(r.geometry.spacing_mm.z(), 1.0, 1e-9);
  options.series_uid = "1.2.3.999";
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "mixed"}, options), "1.2.3.999", small.series_uid,
                   large.series_uid, "--series");
}

TEST_F(DicomSeries, NonCtNeedsAnyModality) {
  SliceSpec mr;
  mr.sop_class = UID_MRImageStorage;
  mr.modality = "MR";
  mr.slope = 1;
  mr.intercept = 0;
  write_stack(dir_ / "mr", 5, 3.0, mr);
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "mr"}), "no CT series", "MR", "--modality any");
  vx::ReadOptions options;
  options.any_modality = true;
  const Volume r = vx::read_dicom_series({dir_ / "mr"}, options);
  EXPECT_EQ(r.geometry.dims, Eigen::Vector3i(10, 8, 5));
  EXPECT_EQ(r.hu[3], 1024.0f + 3);
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

TEST_F(DicomSeries, LocalizerImagesAreLeftOut) {
  SliceSpec s;
  s.series_uid = uid(SITE_SERIES_UID_ROOT);
  write_stack(dir_ / "withscout", 5, 1.0, s);
  SliceSpec scout = s;
  scout.image_type = "ORIGINAL\\PRIMARY\\LOCALIZER";
  scout.row = {0, 1, 0};
  scout.col = {0, 0, -1};
  scout.rows = 30;
  write_slice(dir_ / "withscout" / "scout.dcm", scout);
  EXPECT_EQ(vx::read_dicom_series({dir_ / "withscout"}).geometry.dims, Eigen::Vector3i(10, 8, 5));
}

TEST_F(DicomSeries, OneSliceFileStandsForItsSeries) {
  const Volume v = pattern_volume({5, 4, 6}, {1, 1, 1}, {0, 0, 0});
  vx::write_dicom_series(v, dir_ / "series");
  expect_same_volume(v, vx::read_dicom_series({files_in(dir_ / "series")[2]}));
  // only the file's own folder is searched, not its subfolders
  SliceSpec s;
  s.series_uid = uid(SITE_SERIES_UID_ROOT);
  write_stack(dir_ / "flat", 4, 1.0, s);
  s.position = {0, 0, 4};
  write_stack(dir_ / "flat" / "sub", 4, 1.0, s, "t");
  EXPECT_EQ(vx::read_dicom_series({dir_ / "flat" / "s1.dcm"}).geometry.dims.z(), 4);
  EXPECT_EQ(vx::read_dicom_series({dir_ / "flat"}).geometry.dims.z(), 8);
}

TEST_F(DicomSeries, ManySlicesWithProgressAndSkippedNonDicomFiles) {
  const Volume v = pattern_volume({16, 16, 90}, {1, 1, 1}, {0, 0, 0});
  vx::write_dicom_series(v, dir_ / "many", {.transfer_syntax = "rle"});
  std::ofstream(dir_ / "many" / "README.txt") << "notes about this scan\n";
  expect_same_volume(v, vx::read_dicom_series({dir_ / "many"}));
}

// ---------------------------------------------------------------- bad input

TEST_F(DicomSeries, TruncatedFileIsNamed) {
  const Volume v = pattern_volume({32, 32, 4}, {1, 1, 1}, {0, 0, 0});
  vx::write_dicom_series(v, dir_ / "s");
  const fs::path victim = files_in(dir_ / "s")[1];
  fs::resize_file(victim, fs::file_size(victim) * 6 / 10);  // inside the pixel data
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "s"}), victim.filename().string(), "truncated");
  fs::resize_file(victim, 300);  // inside the header
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "s"}), victim.filename().string(), "truncated");
}

TEST_F(DicomSeries, NotDicomFiles) {
  std::ofstream(dir_ / "notes.txt") << "this is not an image\n";
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "notes.txt"}), "notes.txt", "not a DICOM file");
  std::ofstream bin(dir_ / "noise.bin", std::ios::binary);
  std::mt19937 rng(3);
  for (int i = 0; i < 5000; ++i) bin.put(char(rng()));
  bin.close();
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_}), "none of them DICOM");
  // random bytes behind a DICOM preamble: a broken DICOM file
  std::ofstream fake(dir_ / "fake.dcm", std::ios::binary);
  fake << std::string(128, '\0') << "DICM";
  for (int i = 0; i < 3000; ++i) fake.put(char(rng()));
  fake.close();
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "fake.dcm"}), "fake.dcm");
}

TEST_F(DicomSeries, MissingPixelData) {
  SliceSpec s;
  s.series_uid = uid(SITE_SERIES_UID_ROOT);
  write_stack(dir_ / "s", 4, 1.0, s);
  s.pixel_data = false;
  s.position = {0, 0, 4};
  write_slice(dir_ / "s" / "nopixels.dcm", s);
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "s"}), "nopixels.dcm", "no pixel data");
}

TEST_F(DicomSeries, InconsistentRowsAndColumns) {
  SliceSpec s;
  s.series_uid = uid(SITE_SERIES_UID_ROOT);
  write_stack(dir_ / "s", 4, 1.0, s);
  s.rows = 9;
  s.position = {0, 0, 4};
  write_slice(dir_ / "s" / "odd.dcm", s);
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "s"}), "odd.dcm", "mixes image sizes", "10 x 9");
}

TEST_F(DicomSeries, SingleSliceEmptyFolderAndMissingPath) {
  // one slice is a one-slice volume (a 2D model): its pixels and orientation as given, its depth
  // 1 mm when the file names no SliceThickness or SpacingBetweenSlices (a warning says so)
  SliceSpec one;
  write_stack(dir_ / "one", 1, 1.0, one);
  const vx::Volume v = vx::read_dicom_series({dir_ / "one"});
  EXPECT_EQ(v.geometry.dims.z(), 1);
  EXPECT_EQ(v.geometry.dims.x(), one.cols);
  EXPECT_EQ(v.geometry.dims.y(), one.rows);
  EXPECT_NEAR(v.geometry.spacing_mm.x(), one.col_spacing, 1e-9);
  EXPECT_NEAR(v.geometry.spacing_mm.y(), one.row_spacing, 1e-9);
  EXPECT_NEAR(v.geometry.spacing_mm.z(), 1.0, 1e-12);
  EXPECT_LT((v.geometry.origin_mm - one.position).norm(), 1e-9);
  fs::create_directories(dir_ / "empty");
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "empty"}), "holds no files");
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "nowhere"}), "nowhere", "does not exist");
  EXPECT_ERROR_HAS(vx::read_dicom_series({}), "no input");
}

TEST_F(DicomSeries, CorruptRleSegmentOffsetsAreAClearErrorNotACrash) {
  // the fuzz finding of stop 24 (fuzz_dicom_series): an RLE fragment whose second segment offset
  // points before the first (0xffffffb0) made DCMTK's decoder read outside its buffer (SIGSEGV);
  // a single image reaches the decoder since one-slice series are read
  const Volume v = pattern_volume({6, 5, 1}, {1, 1, 1}, {0, 0, 0});
  vx::write_dicom_series(v, dir_ / "rle", {.transfer_syntax = "rle"});
  const std::vector<fs::path> files = files_in(dir_ / "rle");
  ASSERT_EQ(files.size(), 1u);
  EXPECT_EQ(vx::read_dicom_series({dir_ / "rle"}).hu, v.hu);  // the valid file reads
  std::string bytes;
  {
    std::ifstream in(files.front(), std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  // the pixel data's first fragment after the (empty) offset table: FE FF 00 E0, its length, the
  // RLE header (segment count, then offsets)
  const std::string item("\xfe\xff\x00\xe0", 4);
  const std::size_t table = bytes.rfind(std::string("\xe0\x7f\x10\x00", 4));
  ASSERT_NE(table, std::string::npos);
  const std::size_t first = bytes.find(item, bytes.find(item, table) + 4);
  ASSERT_NE(first, std::string::npos);
  const std::size_t header = first + 8;
  ASSERT_EQ(bytes.substr(header, 8), std::string("\x02\x00\x00\x00\x40\x00\x00\x00", 8));  // 2 segments at 64
  bytes.replace(header + 8, 4, std::string("\xb0\xff\xff\xff", 4));
  std::ofstream(files.front(), std::ios::binary | std::ios::trunc) << bytes;
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "rle"}), "RLE fragment 1 is corrupt", "segment 1");
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

TEST_F(DicomSeries, LossyJpeg2000DecodesCloseToTheOriginal) {
  // JPEG 2000 lossy (1.2.840.10008.1.2.4.91, 8:1): four 64 x 64 slices through a sphere come
  // back within a few HU (measured: mean 5.9 HU, worst 55 HU at the edge of the sphere)
  vx::PhantomSettings ps;
  ps.name = "sphere";
  ps.size = 64;
  Volume v = vx::make_phantom(ps);
  const std::size_t slice = 64 * 64;
  v.hu = std::vector<float>(v.hu.begin() + std::ptrdiff_t(30 * slice), v.hu.begin() + std::ptrdiff_t(34 * slice));
  v.geometry.dims.z() = 4;
  vx::write_dicom_series(v, dir_ / "lossy", {.transfer_syntax = "jpeg2000"});
  for (const auto& f : files_in(dir_ / "lossy")) EXPECT_EQ(transfer_syntax_of(f), UID_JPEG2000TransferSyntax);
  const Volume back = vx::read_dicom_series({dir_ / "lossy"});
  ASSERT_EQ(back.geometry.dims, v.geometry.dims);
  double sum = 0, worst = 0;
  for (std::size_t p = 0; p < v.hu.size(); ++p) {
    const double e = std::abs(double(back.hu[p]) - double(v.hu[p]));
    sum += e;
    worst = std::max(worst, e);
  }
  EXPECT_LT(sum / double(v.hu.size()), 10.0);  // mean error, HU (air -1000, tissue 40)
  EXPECT_LT(worst, 120.0);
  EXPECT_GT(worst, 0.0);  // it is lossy
  // the same voxels from lossless JPEG 2000 as from the uncompressed series
  vx::write_dicom_series(v, dir_ / "j2k", {.transfer_syntax = "jpeg2000-lossless"});
  vx::write_dicom_series(v, dir_ / "raw");
  expect_same_volume(vx::read_dicom_series({dir_ / "raw"}), vx::read_dicom_series({dir_ / "j2k"}));
}

TEST_F(DicomSeries, DamagedJpeg2000IsNamed) {
  // a JPEG 2000 encapsulated file whose codestream is cut short after its first markers
  const fs::path folder = dir_ / "j2k";
  fs::create_directories(folder);
  const std::string series = uid(SITE_SERIES_UID_ROOT);
  for (int k = 0; k < 2; ++k) {
    DcmFileFormat file;
    DcmDataset* ds = file.getDataset();
    ds->putAndInsertString(DCM_SOPClassUID, UID_CTImageStorage);
    ds->putAndInsertString(DCM_SOPInstanceUID, uid().c_str());
    ds->putAndInsertString(DCM_Modality, "CT");
    ds->putAndInsertString(DCM_SeriesInstanceUID, series.c_str());
    ds->putAndInsertString(DCM_ImagePositionPatient, k ? "0\\0\\1" : "0\\0\\0");
    ds->putAndInsertString(DCM_ImageOrientationPatient, "1\\0\\0\\0\\1\\0");
    ds->putAndInsertString(DCM_PixelSpacing, "1\\1");
    ds->putAndInsertUint16(DCM_SamplesPerPixel, 1);
    ds->putAndInsertString(DCM_PhotometricInterpretation, "MONOCHROME2");
    ds->putAndInsertUint16(DCM_Rows, 4);
    ds->putAndInsertUint16(DCM_Columns, 4);
    ds->putAndInsertUint16(DCM_BitsAllocated, 16);
    ds->putAndInsertUint16(DCM_BitsStored, 16);
    ds->putAndInsertUint16(DCM_HighBit, 15);
    ds->putAndInsertUint16(DCM_PixelRepresentation, 0);
    auto* pixel_data = new DcmPixelData(DCM_PixelData);
    auto* sequence = new DcmPixelSequence(DcmTag(DCM_PixelData, EVR_OB));
    sequence->insert(new DcmPixelItem(DcmTag(DCM_Item, EVR_OB)));  // empty offset table
    auto* fragment = new DcmPixelItem(DcmTag(DCM_Item, EVR_OB));
    Uint8 bytes[16] = {0xFF, 0x4F, 0xFF, 0x51};
    fragment->putUint8Array(bytes, 16);
    sequence->insert(fragment);
    pixel_data->putOriginalRepresentation(EXS_JPEG2000LosslessOnly, nullptr, sequence);
    ds->insert(pixel_data);
    ASSERT_TRUE(file.saveFile((folder / ("j" + std::to_string(k) + ".dcm")).c_str(), EXS_JPEG2000LosslessOnly).good());
  }
  EXPECT_ERROR_HAS(vx::read_dicom_series({folder}), "cannot decode", "j0.dcm", "JPEG 2000");
}

// ---------------------------------------------------------------- hostile and real inputs (issue #17)

/// Loads `file`, lets `edit` change its data set, saves it in the same transfer syntax.
template <class F>
void edit_file(const fs::path& file, F&& edit) {
  DcmFileFormat ff;
  ASSERT_TRUE(ff.loadFile(file.c_str()).good()) << file;
  ff.loadAllDataIntoMemory();
  edit(ff.getDataset());
  ASSERT_TRUE(ff.saveFile(file.c_str(), ff.getDataset()->getOriginalXfer()).good()) << file;
}

TEST_F(DicomSeries, NumberOfFramesMustBeWhatThePixelDataHolds) {
  SliceSpec spec;
  write_stack(dir_ / "s", 3, 1.0, spec);
  const fs::path victim = files_in(dir_ / "s")[1];
  // 99999999 frames of 8 x 10: the header pass looped once per declared frame, memory growing
  edit_file(victim, [](DcmDataset* ds) { ds->putAndInsertString(DCM_NumberOfFrames, "99999999"); });
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "s"}), victim.filename().string(), "declares 99999999 frames",
                   "pixel data holds 160 bytes");
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 5.0);
  edit_file(victim, [](DcmDataset* ds) { ds->putAndInsertString(DCM_NumberOfFrames, "-1"); });
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "s"}), victim.filename().string(), "NumberOfFrames (0028,0008) '-1'",
                   "not a positive count");
  edit_file(victim, [](DcmDataset* ds) { ds->putAndInsertString(DCM_NumberOfFrames, "1"); });
  EXPECT_EQ(vx::read_dicom_series({dir_ / "s"}).geometry.dims, Eigen::Vector3i(10, 8, 3));
}

/// A truncated RT plan: a DICOM file cut inside its (0008,xxxx) elements, so its series is unknown.
void write_truncated_rt_plan(const fs::path& path) {
  DcmFileFormat file;
  DcmDataset* ds = file.getDataset();
  ds->putAndInsertString(DCM_SOPClassUID, UID_RTPlanStorage);
  ds->putAndInsertString(DCM_SOPInstanceUID, uid().c_str());
  ds->putAndInsertString(DCM_StudyDescription, std::string(3000, 'p').c_str());
  ds->putAndInsertString(DCM_Modality, "RTPLAN");
  ds->putAndInsertString(DCM_SeriesInstanceUID, uid(SITE_SERIES_UID_ROOT).c_str());
  ASSERT_TRUE(file.saveFile(path.c_str(), EXS_LittleEndianExplicit).good());
  fs::resize_file(path, 1200);  // inside the study description
}

/// A colour secondary capture, JPEG baseline (YBR_FULL_422), in a series of its own. Its JPEG
/// bytes are a stand-in: nothing decodes another series' pixels.
void write_colour_jpeg_capture(const fs::path& path) {
  DcmFileFormat file;
  DcmDataset* ds = file.getDataset();
  ds->putAndInsertString(DCM_SOPClassUID, UID_SecondaryCaptureImageStorage);
  ds->putAndInsertString(DCM_SOPInstanceUID, uid().c_str());
  ds->putAndInsertString(DCM_Modality, "OT");
  ds->putAndInsertString(DCM_SeriesInstanceUID, uid(SITE_SERIES_UID_ROOT).c_str());
  ds->putAndInsertUint16(DCM_SamplesPerPixel, 3);
  ds->putAndInsertString(DCM_PhotometricInterpretation, "YBR_FULL_422");
  ds->putAndInsertUint16(DCM_PlanarConfiguration, 0);
  ds->putAndInsertUint16(DCM_Rows, 16);
  ds->putAndInsertUint16(DCM_Columns, 16);
  ds->putAndInsertUint16(DCM_BitsAllocated, 8);
  ds->putAndInsertUint16(DCM_BitsStored, 8);
  ds->putAndInsertUint16(DCM_HighBit, 7);
  ds->putAndInsertUint16(DCM_PixelRepresentation, 0);
  auto* pixel_data = new DcmPixelData(DCM_PixelData);
  auto* sequence = new DcmPixelSequence(DcmTag(DCM_PixelData, EVR_OB));
  sequence->insert(new DcmPixelItem(DcmTag(DCM_Item, EVR_OB)));
  auto* fragment = new DcmPixelItem(DcmTag(DCM_Item, EVR_OB));
  Uint8 jpeg[64] = {0xFF, 0xD8, 0xFF, 0xE0};
  jpeg[62] = 0xFF;
  jpeg[63] = 0xD9;
  fragment->putUint8Array(jpeg, 64);
  sequence->insert(fragment);
  pixel_data->putOriginalRepresentation(EXS_JPEGProcess1, nullptr, sequence);
  ds->insert(pixel_data);
  ASSERT_TRUE(file.saveFile(path.c_str(), EXS_JPEGProcess1).good());
}

TEST_F(DicomSeries, AFieldFolderWithUnrelatedUnreadableFilesStillGivesTheSeries) {
  // a good CT series beside a truncated RT plan and a colour JPEG secondary capture (3D Slicer
  // imports the series and lists what it skipped)
  const Volume v = pattern_volume({12, 10, 5}, {0.8, 0.8, 2.0}, {-4, 6, 20});
  vx::write_dicom_series(v, dir_ / "field");
  const auto slices = files_in(dir_ / "field");
  ASSERT_EQ(slices.size(), 5u);
  write_truncated_rt_plan(dir_ / "field" / "RTPLAN.dcm");
  write_colour_jpeg_capture(dir_ / "field" / "SC_colour.dcm");
  const fs::path one = slices[1];
  for (const fs::path& input : {one, dir_ / "field"}) {
    ::testing::internal::CaptureStderr();
    const Volume read = vx::read_dicom_series({input});
    const std::string said = ::testing::internal::GetCapturedStderr();
    expect_same_volume(v, read);
    EXPECT_NE(said.find("warning: DICOM: skipped 1 unreadable DICOM file"), std::string::npos) << said;
    EXPECT_NE(said.find("RTPLAN.dcm"), std::string::npos) << said;
  }
  // a missing slice of the series itself is still caught, by the spacing check
  fs::remove(slices[2]);
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "field"}), "misses 1 slice");
  // a file named on its own that cannot be read is an error, not a skip
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "field" / "RTPLAN.dcm"}), "RTPLAN.dcm", "truncated");
}

TEST_F(DicomSeries, AnElementLongerThanTheFileIsNeverLoaded) {
  // found by fuzzing: a value beyond the header read limit loads on first access, and DCMTK
  // allocated its declared length (1.4 to 3.7 GB) before finding the file too short
  SliceSpec spec;
  write_stack(dir_ / "s", 3, 1.0, spec);
  write_slice(dir_ / "s" / "damaged.dcm", spec);
  std::string bytes;
  {
    std::ifstream in(dir_ / "s" / "damaged.dcm", std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  // Modality (0008,0060) CS "CT": its 2-byte length becomes 65520, far beyond the file
  const std::string modality("\x08\x00\x60\x00" "CS\x02\x00", 8);
  const auto at = bytes.find(modality);
  ASSERT_NE(at, std::string::npos);
  bytes[at + 6] = char(0xF0);
  bytes[at + 7] = char(0xFF);
  std::ofstream(dir_ / "s" / "damaged.dcm", std::ios::binary) << bytes;
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "s" / "damaged.dcm"}), "damaged.dcm",
                   "element (0008,0060) declares 65520 bytes");
  // in a folder it is skipped, named, and the series reads
  ::testing::internal::CaptureStderr();
  EXPECT_EQ(vx::read_dicom_series({dir_ / "s"}).geometry.dims, Eigen::Vector3i(10, 8, 3));
  EXPECT_NE(::testing::internal::GetCapturedStderr().find("damaged.dcm"), std::string::npos);
}

TEST_F(DicomSeries, ModalityLutSequenceGivesTheValues) {
  // no rescale, a Modality LUT instead: stored v -> lut[v - 1000], a non-linear table
  SliceSpec spec;
  write_stack(dir_ / "lut", 3, 1.5, spec);
  std::vector<Uint16> lut(200);
  for (std::size_t e = 0; e < lut.size(); ++e) lut[e] = Uint16((e * e) % 3000);
  for (const fs::path& f : files_in(dir_ / "lut"))
    edit_file(f, [&](DcmDataset* ds) {
      delete ds->remove(DCM_RescaleSlope);
      delete ds->remove(DCM_RescaleIntercept);
      DcmItem* item = nullptr;
      ASSERT_TRUE(ds->findOrCreateSequenceItem(DCM_ModalityLUTSequence, item, -2).good());
      const Uint16 descriptor[3] = {200, 1000, 16};  // entries, first stored value mapped, bits
      item->putAndInsertUint16Array(DCM_LUTDescriptor, descriptor, 3);
      item->putAndInsertUint16Array(DCM_LUTData, lut.data(), unsigned(lut.size()));
      item->putAndInsertString(DCM_ModalityLUTType, "HU");
    });
  ::testing::internal::CaptureStderr();
  const Volume v = vx::read_dicom_series({dir_ / "lut"});
  EXPECT_EQ(::testing::internal::GetCapturedStderr().find("no RescaleSlope"), std::string::npos);
  // stored values are 1024 + p (p = column + 10 row): lut[24 + p]; beyond the table, its last entry
  for (int j = 0; j < 8; ++j)
    for (int i = 0; i < 10; ++i) EXPECT_EQ(v.at(i, j, 1), float(lut[std::size_t(24 + i + 10 * j)])) << i << "," << j;
}

TEST_F(DicomSeries, SeriesDescriptionsAreConvertedToUtf8AndMadePrintable) {
  SliceSpec spec;
  write_stack(dir_ / "cs", 2, 1.0, spec);
  for (const fs::path& f : files_in(dir_ / "cs"))
    edit_file(f, [](DcmDataset* ds) {
      ds->putAndInsertString(DCM_SpecificCharacterSet, "ISO_IR 100");
      ds->putAndInsertString(DCM_SeriesDescription, "Kn\xE4" "chel \x1b[31mrot");  // Latin-1, an escape sequence
    });
  // the series list (asking for a series that is not there) shows the description
  const std::string message = error_of([&] { (void)vx::read_dicom_series({dir_ / "cs"}, {.series_uid = "1.2.3"}); });
  EXPECT_NE(message.find("'Kn\xC3\xA4" "chel ?[31mrot'"), std::string::npos) << message;
}

// ---------------------------------------------------------------- the writer

TEST_F(DicomSeries, WriterRefusesBadOutputsAndLeavesNothingBehind) {
  const Volume v = pattern_volume({4, 4, 3}, {1, 1, 1}, {0, 0, 0});
  std::ofstream(dir_ / "afile") << "x";
  EXPECT_ERROR_HAS(vx::write_dicom_series(v, dir_ / "afile" / "series"), "is a file, not a folder");
  EXPECT_ERROR_HAS(vx::write_dicom_series(v, dir_ / "nowhere" / "series"), "does not exist");
  // a folder we may not write into (root may write anywhere, but not into /proc)
  fs::create_directories(dir_ / "readonly");
  fs::permissions(dir_ / "readonly", fs::perms::owner_read | fs::perms::owner_exec);
  if (::access((dir_ / "readonly").c_str(), W_OK) != 0)
    EXPECT_ERROR_HAS(vx::write_dicom_series(v, dir_ / "readonly" / "series"), "not writable");
  fs::permissions(dir_ / "readonly", fs::perms::owner_all);
  EXPECT_ERROR_HAS(vx::write_dicom_series(v, "/proc/voxelastic_series"), "/proc/voxelastic_series");
  EXPECT_ERROR_HAS(vx::write_dicom_series(v, dir_ / "afile"), "is a file");
  fs::create_directories(dir_ / "busy");
  std::ofstream(dir_ / "busy" / "thesis.docx") << "x";
  EXPECT_ERROR_HAS(vx::write_dicom_series(v, dir_ / "busy"), "holds other files", "thesis.docx");
  EXPECT_TRUE(fs::exists(dir_ / "busy" / "thesis.docx"));
  EXPECT_ERROR_HAS(vx::write_dicom_series(v, dir_ / "x", {.transfer_syntax = "jpeg2000-hq"}), "jpeg2000-hq",
                   "jpeg2000-lossless", "rle");
  Volume bad = v;
  bad.hu[5] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_ERROR_HAS(vx::write_dicom_series(bad, dir_ / "nan"), "NaN");
  // nothing half-written anywhere
  for (const auto& e : fs::directory_iterator(dir_)) EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir_ / "nan"));
  EXPECT_FALSE(fs::exists(dir_ / "x"));
}

TEST_F(DicomSeries, WriterReplacesItsOwnEarlierSeriesAndAcceptsATrailingSlash) {
  const Volume a = pattern_volume({4, 4, 5}, {1, 1, 1}, {0, 0, 0});
  const Volume b = pattern_volume({6, 3, 2}, {2, 2, 2}, {1, 1, 1});
  vx::write_dicom_series(a, dir_ / "out/");
  EXPECT_EQ(files_in(dir_ / "out").size(), 5u);
  vx::write_dicom_series(b, dir_ / "out");
  EXPECT_EQ(files_in(dir_ / "out").size(), 2u);
  expect_same_volume(b, vx::read_dicom_series({dir_ / "out"}));
  fs::create_directories(dir_ / "empty");
  vx::write_dicom_series(a, dir_ / "empty");
  EXPECT_EQ(files_in(dir_ / "empty").size(), 5u);
}

TEST_F(DicomSeries, WriterMapsHuOutsideTheUsualRange) {
  // below -1024 and beyond 64511 HU: the intercept moves; a range over 65535 HU needs a slope
  Volume v = pattern_volume({3, 2, 2}, {1, 1, 1}, {0, 0, 0});
  v.hu[0] = -3024;
  v.hu[1] = 3071;
  vx::write_dicom_series(v, dir_ / "wide");
  expect_same_volume(v, vx::read_dicom_series({dir_ / "wide"}));
  v.hu[1] = 70000;
  vx::write_dicom_series(v, dir_ / "wider");
  const Volume r = vx::read_dicom_series({dir_ / "wider"});
  for (std::size_t p = 0; p < v.hu.size(); ++p) EXPECT_NEAR(r.hu[p], v.hu[p], 0.6 * (70000 + 3024) / 65535.0) << p;
}

TEST_F(DicomSeries, WrittenSeriesPassesDciodvfy) {
  if (!fs::exists("/usr/bin/dciodvfy")) GTEST_SKIP() << "dciodvfy (dicom3tools) not installed";
  const Eigen::Matrix3d d = Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const Volume v = pattern_volume({8, 6, 3}, {0.7, 0.8, 1.5}, {-3, 4, 5}, d);
  for (const char* syntax : {"explicit-little", "jpeg-ls-lossless"}) {
    const fs::path folder = dir_ / syntax;
    vx::write_dicom_series(v, folder, {.transfer_syntax = syntax});
    for (const fs::path& f : files_in(folder)) {
      const std::string command = "/usr/bin/dciodvfy '" + f.string() + "' 2>&1";
      FILE* pipe = ::popen(command.c_str(), "r");
      ASSERT_NE(pipe, nullptr);
      std::string out;
      char buf[512];
      while (std::fgets(buf, sizeof buf, pipe)) out += buf;
      ::pclose(pipe);
      EXPECT_NE(out.find("CTImage"), std::string::npos) << out;  // it recognised the IOD
      EXPECT_EQ(out.find("Error"), std::string::npos) << syntax << " " << f.filename() << ":\n" << out;
    }
  }
}

// ---------------------------------------------------------------- the bundled sample

/// The bundled sample: a 48 x 48 x 24 block (40 HU) with a spherical lesion (120 HU) in air,
/// 0.8 x 0.8 mm pixels, 1.5 mm slices. Regenerate with --gtest_also_run_disabled_tests.
Volume sample_volume() {
  Volume v;
  v.geometry.dims = {48, 48, 24};
  v.geometry.spacing_mm = {0.8, 0.8, 1.5};
  v.geometry.origin_mm = {-18.8, -18.8, -17.25};  // centred on the patient origin
  v.hu.resize(std::size_t(v.geometry.voxel_count()));
  for (int k = 0; k < 24; ++k)
    for (int j = 0; j < 48; ++j)
      for (int i = 0; i < 48; ++i) {
        const Eigen::Vector3d p = v.geometry.index_to_lps(Eigen::Vector3d(i, j, k));
        float hu = -1000.0f;
        if (std::abs(p.x()) < 14 && std::abs(p.y()) < 12 && std::abs(p.z()) < 13) hu = 40.0f;
        if ((p - Eigen::Vector3d(4, -2, 1)).norm() < 5.0) hu = 120.0f;
        v.hu[std::size_t(i + 48 * (j + 48 * k))] = hu;
      }
  return v;
}

TEST(DicomSample, DISABLED_WriteBundledSample) {
  vx::write_dicom_series(sample_volume(), fs::path(VX_SAMPLES_DIR) / "dicom",
                         {.patient_name = "VOXELASTIC^BLOCK_LESION", .series_description = "block with lesion",
                          .transfer_syntax = "rle"});
}

TEST(DicomSample, BundledSeriesReadsAsDescribed) {
  const fs::path folder = fs::path(VX_SAMPLES_DIR) / "dicom";
  ASSERT_TRUE(fs::is_directory(folder)) << folder;
  const Volume r = vx::read_dicom_series({folder});
  expect_same_volume(sample_volume(), r);
  EXPECT_EQ(r.at(10, 24, 12), 40.0f);  // x = -10.8 mm: in the block, away from the lesion
  EXPECT_EQ(r.at(0, 0, 0), -1000.0f);
  const Eigen::Vector3d lesion = r.geometry.lps_to_index({4, -2, 1}).array().round();
  EXPECT_EQ(r.at(int(lesion.x()), int(lesion.y()), int(lesion.z())), 120.0f);
}

}  // namespace
