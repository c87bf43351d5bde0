// The pixels of a DICOM series to HU (pipeline/io/dicom_pixels.cpp): enhanced multi-frame CT with
// per-frame rescale, signed and padded pixels, rescale in floating point, a modality LUT, and
// pixel data that is missing, inconsistent, corrupt (RLE), lossy and damaged (JPEG 2000) or of a
// declared size over the memory limit.
#include <gtest/gtest.h>

#include <cstdint>
#include <fstream>

#include "io/dicom_series.h"
#include "support/dicom_files.h"
#include "util/system_memory.h"

using namespace dicom_files;

namespace {

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
        ASSERT_EQ(r.hu[std::size_t(k * rows * cols + p)], float(2 * (p * 3 + k * 50)))
            << "slice " << k << " pixel " << p;
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

TEST_F(DicomSeries, ADeclaredSizeTheDataCannotHoldOrOverTheMemoryLimitIsRefusedBeforeAllocating) {
  // the fuzz finding of stop 37 (fuzz_dicom_file): compressed pixel data holds any declared image
  // size in a few bytes, so a damaged Rows / Columns asked for a 1.68 GB volume, which Linux
  // grants and may kill the process for when the pages are touched
  const Volume v = pattern_volume({6, 5, 1}, {1, 1, 1}, {0, 0, 0});
  vx::write_dicom_series(v, dir_ / "rle", {.transfer_syntax = "rle"});
  const std::vector<fs::path> files = files_in(dir_ / "rle");
  ASSERT_EQ(files.size(), 1u);
  // the volume's bytes against the limit, before anything is allocated
  vx::ReadOptions limited;
  limited.max_volume_bytes = 6 * 5 * sizeof(float);  // exactly the volume: it reads
  EXPECT_EQ(vx::read_dicom_series({dir_ / "rle"}, limited).hu, v.hu);
  limited.max_volume_bytes -= 1;
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "rle"}, limited), "6 x 5 x 1 volume", "more than the limit set",
                   "Rows / Columns");
  // an RLE run holds at most 128 bytes in 2: this fragment cannot hold a 16384 x 25622 image
  edit_file(files.front(), [](DcmDataset* ds) {
    ASSERT_TRUE(ds->putAndInsertUint16(DCM_Rows, 25622).good());
    ASSERT_TRUE(ds->putAndInsertUint16(DCM_Columns, 16384).good());
  });
  EXPECT_ERROR_HAS(vx::read_dicom_series({dir_ / "rle"}), "16384 x 25622 pixels (839581696 bytes)",
                   "its RLE data can hold at most", "damaged");
}

TEST(SystemMemory, PhysicalMemoryIsWhatTheKernelReports) {
  std::ifstream meminfo("/proc/meminfo");
  std::string key;
  std::uint64_t kib = 0;
  while (meminfo >> key && key != "MemTotal:") meminfo.ignore(256, '\n');
  ASSERT_TRUE(meminfo >> kib) << "no MemTotal in /proc/meminfo";
  EXPECT_EQ(vx::physical_memory_bytes(), kib * 1024);
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

}  // namespace
