// DICOM series in and out (io/dicom_series.h): round trips in every transfer syntax the writer
// offers; the files grouped into series and one chosen (the largest CT, the one asked, localizers
// left out, unreadable neighbours passed over); the writer; the bundled sample. One file's header,
// the slice layout and the pixels have tests of their own (dicom_header_test.cpp,
// dicom_slice_layout_test.cpp, dicom_pixels_test.cpp).
#include <gtest/gtest.h>

#include "io/dicom_series.h"
#include "support/dicom_files.h"

using namespace dicom_files;

namespace {

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
