// One DICOM file's header (pipeline/io/dicom_header.cpp): files that are not DICOM or are cut
// short, a frame count the pixel data does not hold, an element longer than the file, and series
// descriptions in other character sets.
#include <gtest/gtest.h>

#include "io/dicom_series.h"
#include "support/dicom_files.h"

using namespace dicom_files;

namespace {

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
  const std::string modality(
      "\x08\x00\x60\x00"
      "CS\x02\x00",
      8);
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

TEST_F(DicomSeries, SeriesDescriptionsAreConvertedToUtf8AndMadePrintable) {
  SliceSpec spec;
  write_stack(dir_ / "cs", 2, 1.0, spec);
  for (const fs::path& f : files_in(dir_ / "cs"))
    edit_file(f, [](DcmDataset* ds) {
      ds->putAndInsertString(DCM_SpecificCharacterSet, "ISO_IR 100");
      ds->putAndInsertString(DCM_SeriesDescription,
                             "Kn\xE4"
                             "chel \x1b[31mrot");  // Latin-1, an escape sequence
    });
  // the series list (asking for a series that is not there) shows the description
  const std::string message = error_of([&] { (void)vx::read_dicom_series({dir_ / "cs"}, {.series_uid = "1.2.3"}); });
  EXPECT_NE(message.find("'Kn\xC3\xA4"
                         "chel ?[31mrot'"),
            std::string::npos)
      << message;
}

}  // namespace
