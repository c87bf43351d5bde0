// Volume files: round trips of every writable format (voxel- and geometry-exact), hand-written
// NIfTI / NRRD / MetaImage / VTI files with known positions, and clear errors for bad input.
#include "io/volume_io.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "base/error.h"
#include "convert/phantom.h"
#include "io/compression.h"

namespace fs = std::filesystem;
using vx::Error;
using vx::GridGeometry;
using vx::Volume;

namespace {

class VolumeIo : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_volume_io_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  [[nodiscard]] fs::path path(const std::string& name) const { return dir_ / name; }
  fs::path dir_;
};

/// A 7 x 5 x 4 volume with anisotropic spacing, an origin off zero and a rotated grid;
/// every voxel has its own value (integers: files store int16; else float).
Volume test_volume(bool integral, bool left_handed = false) {
  Volume v;
  GridGeometry& g = v.geometry;
  g.dims = {7, 5, 4};
  g.spacing_mm = {0.7, 1.3, 2.5};
  g.origin_mm = {-12.5, 30.25, 101.0};
  g.direction = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, -2, 3).normalized()).toRotationMatrix();
  if (left_handed) g.direction.col(2) = -g.direction.col(2);
  v.hu.resize(std::size_t(g.voxel_count()));
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 5; ++j)
      for (int i = 0; i < 7; ++i) {
        const double value = -1000.0 + i + 10.0 * j + 100.0 * k + (integral ? 0.0 : 0.25 + 0.001 * i);
        v.hu[std::size_t(i + 7 * (j + 5 * k))] = float(value);
      }
  return v;
}

/// Expects the same voxels (bit-exact) and the same geometry within `tol_mm` (positions) and
/// `tol_dir` (direction cosines).
void expect_same(const Volume& a, const Volume& b, double tol_mm, double tol_dir) {
  ASSERT_EQ(a.geometry.dims, b.geometry.dims);
  ASSERT_EQ(a.hu.size(), b.hu.size());
  std::size_t differ = 0;
  for (std::size_t i = 0; i < a.hu.size(); ++i) differ += a.hu[i] != b.hu[i];
  EXPECT_EQ(differ, 0u) << "first values " << a.hu[0] << " vs " << b.hu[0];
  EXPECT_LT((a.geometry.spacing_mm - b.geometry.spacing_mm).cwiseAbs().maxCoeff(), tol_mm)
      << b.geometry.spacing_mm.transpose();
  EXPECT_LT((a.geometry.origin_mm - b.geometry.origin_mm).cwiseAbs().maxCoeff(), tol_mm)
      << b.geometry.origin_mm.transpose();
  EXPECT_LT((a.geometry.direction - b.geometry.direction).cwiseAbs().maxCoeff(), tol_dir) << b.geometry.direction;
  // the far corner lands in the same place
  const Eigen::Vector3d far = (a.geometry.dims.cast<double>() - Eigen::Vector3d::Ones());
  EXPECT_LT((a.geometry.index_to_lps(far) - b.geometry.index_to_lps(far)).norm(), 3 * tol_mm);
}

/// Runs `f`, expects a vx::Error whose message holds every one of `needles`.
void expect_error(const std::function<void()>& f, const std::vector<std::string>& needles) {
  try {
    f();
    ADD_FAILURE() << "no vx::Error thrown";
  } catch (const Error& e) {
    const std::string msg = e.what();
    for (const auto& n : needles) EXPECT_NE(msg.find(n), std::string::npos) << "'" << n << "' not in: " << msg;
  }
}

void write_bytes(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary);
  out.write(bytes.data(), std::streamsize(bytes.size()));
}

std::string int16_bytes(const std::vector<std::int16_t>& v, bool big_endian = false) {
  std::string s(v.size() * 2, '\0');
  for (std::size_t i = 0; i < v.size(); ++i) {
    const auto u = std::uint16_t(v[i]);
    s[2 * i + (big_endian ? 1 : 0)] = char(u & 0xff);
    s[2 * i + (big_endian ? 0 : 1)] = char(u >> 8);
  }
  return s;
}

// ---------------------------------------------------------------------------------------

TEST(VolumeFormat, FromPath) {
  EXPECT_EQ(vx::volume_format("a/b.vti"), "vti");
  EXPECT_EQ(vx::volume_format("b.MHA"), "mha");
  EXPECT_EQ(vx::volume_format("b.mhd"), "mha");
  EXPECT_EQ(vx::volume_format("b.nii"), "nifti");
  EXPECT_EQ(vx::volume_format("b.nii.gz"), "nifti");
  EXPECT_EQ(vx::volume_format("b.nrrd"), "nrrd");
  EXPECT_EQ(vx::volume_format("b.nhdr"), "nrrd");
  EXPECT_EQ(vx::volume_format("series/"), "dicom");
  EXPECT_EQ(vx::volume_format("x/slice001.dcm"), "dicom");
  EXPECT_EQ(vx::volume_format(fs::temp_directory_path()), "dicom");  // an existing folder
  EXPECT_EQ(vx::volume_format("b.png"), "");
  EXPECT_EQ(vx::volume_format("b.gz"), "");
  EXPECT_EQ(vx::volume_format(""), "");
}

TEST_F(VolumeIo, RoundTripEveryFileFormat) {
  struct Case {
    const char* name;
    double tol_mm, tol_dir;
  };
  // VTI, MetaImage and NRRD keep doubles as text (shortest round-trip form); NIfTI stores
  // float32, so positions are exact to float precision only
  const Case cases[] = {{"v.vti", 1e-9, 1e-12},
                        {"v.mha", 1e-12, 1e-15},
                        {"v.nrrd", 1e-12, 1e-15},
                        {"v.nii.gz", 2e-5, 1e-6},
                        {"v.nii", 2e-5, 1e-6}};
  for (bool integral : {true, false})
    for (bool left_handed : {false, true})
      for (const Case& c : cases) {
        SCOPED_TRACE(std::string(c.name) + (integral ? " int16" : " float") + (left_handed ? " left-handed" : ""));
        const Volume v = test_volume(integral, left_handed);
        const fs::path p = path(c.name);
        vx::write_volume(v, p);
        const Volume r = vx::read_volume(p);
        expect_same(v, r, c.tol_mm, c.tol_dir);
        EXPECT_NEAR(r.geometry.direction.determinant(), left_handed ? -1.0 : 1.0, 1e-6);
        fs::remove(p);
      }
  // no temporary files left behind
  EXPECT_TRUE(fs::is_empty(dir_));
}

TEST_F(VolumeIo, TwoDimensionalImagesReadAsOneSlice) {
  // a 2D image (NRRD dimension 2, MetaImage NDims 2) is a one-slice volume: its pixels, its
  // in-plane spacing, a 1 mm slice (the 2D model's thickness, docs/model.md section 12)
  const int nx = 5, ny = 3;
  std::string raw;
  for (int k = 0; k < nx * ny; ++k) {
    const std::int16_t v = std::int16_t(10 * k - 40);
    raw.append(reinterpret_cast<const char*>(&v), 2);
  }
  std::ofstream(dir_ / "i.nrrd", std::ios::binary)
      << "NRRD0004\ntype: short\ndimension: 2\nspace: left-posterior-superior\nsizes: 5 3\n"
         "space directions: (0.5,0,0) (0,0.7,0)\nspace origin: (1,2,3)\nendian: little\nencoding: raw\n\n"
      << raw;
  std::ofstream(dir_ / "i.mha", std::ios::binary)
      << "ObjectType = Image\nNDims = 2\nDimSize = 5 3\nElementSpacing = 0.5 0.7\nOffset = 1 2\n"
         "ElementType = MET_SHORT\nBinaryData = True\nBinaryDataByteOrderMSB = False\nElementDataFile = LOCAL\n"
      << raw;
  for (const char* name : {"i.nrrd", "i.mha"}) {
    SCOPED_TRACE(name);
    const Volume v = vx::read_volume(dir_ / name);
    EXPECT_EQ(v.geometry.dims, Eigen::Vector3i(nx, ny, 1));
    EXPECT_NEAR(v.geometry.spacing_mm.x(), 0.5, 1e-9);
    EXPECT_NEAR(v.geometry.spacing_mm.y(), 0.7, 1e-9);
    EXPECT_NEAR(v.geometry.spacing_mm.z(), 1.0, 1e-9);
    ASSERT_EQ(v.hu.size(), std::size_t(nx * ny));
    for (int k = 0; k < nx * ny; ++k) EXPECT_EQ(v.hu[std::size_t(k)], float(10 * k - 40));
  }
}

TEST_F(VolumeIo, IntegralVolumesAreStoredAsInt16) {
  // 7*5*4 = 140 voxels: int16 data is 280 bytes, float 560; compression aside the .nii
  // (no compression) tells the type from its size: 352-byte header + data
  Volume v = test_volume(true);
  vx::write_volume(v, path("i.nii"));
  EXPECT_EQ(fs::file_size(path("i.nii")), 352u + 280u);
  v = test_volume(false);
  vx::write_volume(v, path("f.nii"));
  EXPECT_EQ(fs::file_size(path("f.nii")), 352u + 560u);
}

TEST_F(VolumeIo, DicomSeriesRoundTrip) {
  // a folder path ending in '/' is a DICOM series (one file per slice); DICOM stores positions
  // as 16-character decimal strings
  const Volume v = test_volume(true);
  const fs::path folder = path("series");
  vx::write_volume(v, folder.string() + "/");
  ASSERT_TRUE(fs::is_directory(folder));
  std::size_t files = 0;
  for (const auto& e : fs::directory_iterator(folder)) files += e.is_regular_file();
  EXPECT_EQ(files, 4u);
  const Volume r = vx::read_volume(folder.string() + "/");
  expect_same(v, r, 1e-5, 1e-6);
  const Volume r2 = vx::read_volume(folder);  // the folder without '/'
  EXPECT_EQ(r2.hu, v.hu);
}

TEST_F(VolumeIo, WrittenHeadersFollowTheFormatConventions) {
  // LPS geometry: i along LPS +y (anterior -> posterior), j along LPS -x, k along +z; voxel 0 at
  // LPS (10, 20, 30); spacing 0.5 x 2 x 3
  Volume v = test_volume(true);
  v.geometry.direction << 0, -1, 0, 1, 0, 0, 0, 0, 1;
  v.geometry.origin_mm = {10, 20, 30};
  v.geometry.spacing_mm = {0.5, 2, 3};
  // NIfTI: the sform rows map (i, j, k, 1) to RAS = (-x, -y, z) of LPS
  vx::write_volume(v, path("h.nii"));
  std::ifstream in(path("h.nii"), std::ios::binary);
  std::string h(352, '\0');
  in.read(h.data(), 352);
  auto f32 = [&](std::size_t at) {
    float x;
    std::memcpy(&x, h.data() + at, 4);
    return x;
  };
  auto i16 = [&](std::size_t at) {
    std::int16_t x;
    std::memcpy(&x, h.data() + at, 2);
    return x;
  };
  EXPECT_EQ(i16(70), 4);     // datatype int16
  EXPECT_EQ(i16(252), 1);    // qform_code: scanner
  EXPECT_GT(i16(254), 0);    // sform_code
  EXPECT_EQ(h[123] & 7, 2);  // mm
  EXPECT_EQ(f32(76), 1.0f);  // qfac: right-handed grid
  const float srow[12] = {0, 2, 0, -10, -0.5f, 0, 0, -20, 0, 0, 3, 30};
  for (int e = 0; e < 12; ++e) EXPECT_NEAR(f32(280 + 4 * std::size_t(e)), srow[e], 1e-6) << "srow element " << e;
  EXPECT_NEAR(f32(268), -10, 1e-6);  // qoffset
  EXPECT_NEAR(f32(272), -20, 1e-6);
  EXPECT_NEAR(f32(276), 30, 1e-6);
  // MetaImage: TransformMatrix lists the direction of axis i, then j, then k
  vx::write_volume(v, path("h.mha"));
  std::ifstream mha(path("h.mha"), std::ios::binary);
  std::string text(600, '\0');
  mha.read(text.data(), 600);
  EXPECT_NE(text.find("\nTransformMatrix = 0 1 0 -1 0 0 0 0 1\n"), std::string::npos) << text;
  EXPECT_NE(text.find("\nOffset = 10 20 30\n"), std::string::npos);
  EXPECT_NE(text.find("\nElementSpacing = 0.5 2 3\n"), std::string::npos);
  EXPECT_NE(text.find("\nElementType = MET_SHORT\n"), std::string::npos);
  // NRRD: space directions are the index axes scaled by the spacing, in LPS
  vx::write_volume(v, path("h.nrrd"));
  std::ifstream nrrd(path("h.nrrd"), std::ios::binary);
  text.assign(600, '\0');
  nrrd.read(text.data(), 600);
  EXPECT_NE(text.find("\nspace directions: (0,0.5,0) (-2,0,0) (0,0,3)\n"), std::string::npos) << text;
  EXPECT_NE(text.find("\nspace origin: (10,20,30)\n"), std::string::npos);
}

TEST_F(VolumeIo, FailedWriteKeepsTheOldFileAndLeavesNoTemporary) {
  const Volume good = test_volume(true);
  vx::write_volume(good, path("keep.nii.gz"));
  const auto before = fs::file_size(path("keep.nii.gz"));
  Volume sheared = test_volume(true);
  sheared.geometry.direction(0, 1) = 0.3;  // not a rotation: NIfTI's qform cannot hold it
  expect_error([&] { vx::write_volume(sheared, path("keep.nii.gz")); }, {"keep.nii.gz", "orthonormal"});
  EXPECT_EQ(fs::file_size(path("keep.nii.gz")), before);
  EXPECT_EQ(vx::read_volume(path("keep.nii.gz")).hu, good.hu);
  std::size_t files = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir_)) ++files;
  EXPECT_EQ(files, 1u);
}

TEST_F(VolumeIo, DicomFilesWithoutExtensionAreRecognised) {
  // scanners often write files named IM0001 etc.: the 'DICM' magic tells them apart
  const fs::path sample = fs::path(VX_SAMPLES_DIR) / "dicom";
  ASSERT_TRUE(fs::is_directory(sample));
  int i = 0;
  for (const auto& e : fs::directory_iterator(sample))
    if (e.path().extension() == ".dcm") fs::copy_file(e.path(), path("IM" + std::to_string(1000 + i++)));
  ASSERT_GT(i, 1);
  const Volume v = vx::read_volume(path("IM1000"));
  EXPECT_EQ(v.geometry.dims.z(), i);
  EXPECT_EQ(v.hu, vx::read_volume(sample).hu);
}

// ---------------------------------------------------------------------------------------
// NIfTI: a file written here byte by byte, with positions known in RAS

/// A NIfTI-1 single file: 348-byte header, 4 bytes of extension flag, int16 or uint16 data.
struct NiftiFile {
  std::int16_t dim[3]{3, 4, 2};
  float pixdim[4]{1.0f, 1.0f, 1.0f, 1.0f};  ///< pixdim[0] = qfac
  std::int16_t datatype{4};                 ///< 4 = int16, 512 = uint16
  float scl_slope{0.0f}, scl_inter{0.0f};
  std::int16_t qform_code{0}, sform_code{0};
  float quatern[3]{0, 0, 0}, qoffset[3]{0, 0, 0};
  float srow[3][4]{{0, 0, 0, 0}, {0, 0, 0, 0}, {0, 0, 0, 0}};
  char xyzt_units{2};  ///< mm

  [[nodiscard]] std::string bytes(const std::vector<std::int16_t>& data) const {
    std::string h(352, '\0');
    auto put = [&h](std::size_t at, const void* p, std::size_t n) { std::memcpy(h.data() + at, p, n); };
    const std::int32_t sizeof_hdr = 348;
    put(0, &sizeof_hdr, 4);
    const std::int16_t dims[8] = {3, dim[0], dim[1], dim[2], 1, 1, 1, 1};
    put(40, dims, 16);
    put(70, &datatype, 2);
    const std::int16_t bitpix = 16;
    put(72, &bitpix, 2);
    const float pd[8] = {pixdim[0], pixdim[1], pixdim[2], pixdim[3], 1, 1, 1, 1};
    put(76, pd, 32);
    const float vox_offset = 352;
    put(108, &vox_offset, 4);
    put(112, &scl_slope, 4);
    put(116, &scl_inter, 4);
    put(123, &xyzt_units, 1);
    put(252, &qform_code, 2);
    put(254, &sform_code, 2);
    put(256, quatern, 12);
    put(268, qoffset, 12);
    put(280, srow, 48);
    put(344, "n+1", 4);
    return h + int16_bytes(data);
  }
};

/// Values 0..n-1 in file order.
std::vector<std::int16_t> ramp(int n) {
  std::vector<std::int16_t> v(std::size_t(n), 0);
  for (int i = 0; i < n; ++i) v[std::size_t(i)] = std::int16_t(i);
  return v;
}

TEST_F(VolumeIo, NiftiQformRasIsConvertedToLps) {
  // identity rotation, voxel (0,0,0) at RAS (10, 20, 30) mm, spacing 0.5 x 0.75 x 2:
  // voxel (i,j,k) is at RAS (10 + 0.5 i, 20 + 0.75 j, 30 + 2 k) = LPS (-10 - 0.5 i, -20 - 0.75 j, 30 + 2 k)
  NiftiFile f;
  f.pixdim[1] = 0.5f;
  f.pixdim[2] = 0.75f;
  f.pixdim[3] = 2.0f;
  f.qform_code = 1;
  f.qoffset[0] = 10;
  f.qoffset[1] = 20;
  f.qoffset[2] = 30;
  write_bytes(path("q.nii"), f.bytes(ramp(24)));
  const Volume v = vx::read_volume(path("q.nii"));
  ASSERT_EQ(v.geometry.dims, Eigen::Vector3i(3, 4, 2));
  EXPECT_LT((v.geometry.index_to_lps({0, 0, 0}) - Eigen::Vector3d(-10, -20, 30)).norm(), 1e-6);
  EXPECT_LT((v.geometry.index_to_lps({2, 3, 1}) - Eigen::Vector3d(-11, -22.25, 32)).norm(), 1e-6);
  EXPECT_LT((v.geometry.spacing_mm - Eigen::Vector3d(0.5, 0.75, 2)).norm(), 1e-6);
  EXPECT_LT((v.geometry.direction - Eigen::Matrix3d(Eigen::Vector3d(-1, -1, 1).asDiagonal())).norm(), 1e-9);
  // voxel order is the file's
  EXPECT_EQ(v.at(0, 0, 0), 0.0f);
  EXPECT_EQ(v.at(2, 0, 0), 2.0f);
  EXPECT_EQ(v.at(0, 3, 0), 9.0f);
  EXPECT_EQ(v.at(2, 3, 1), 23.0f);
}

TEST_F(VolumeIo, NiftiNegativeQfacKeepsFileSliceOrder) {
  // qfac = -1: slice k of the file is at RAS z = 30 - 2 k. VTK's reader reverses the slices;
  // read_volume must give them back in file order, with a left-handed direction.
  NiftiFile f;
  f.pixdim[0] = -1.0f;
  f.pixdim[3] = 2.0f;
  f.qform_code = 1;
  f.qoffset[0] = 10;
  f.qoffset[1] = 20;
  f.qoffset[2] = 30;
  write_bytes(path("qfac.nii"), f.bytes(ramp(24)));
  const Volume v = vx::read_volume(path("qfac.nii"));
  EXPECT_EQ(v.at(0, 0, 0), 0.0f);
  EXPECT_EQ(v.at(0, 0, 1), 12.0f);  // file slice 1
  EXPECT_LT((v.geometry.index_to_lps({0, 0, 0}) - Eigen::Vector3d(-10, -20, 30)).norm(), 1e-6);
  EXPECT_LT((v.geometry.index_to_lps({1, 2, 1}) - Eigen::Vector3d(-11, -22, 28)).norm(), 1e-6);
  EXPECT_NEAR(v.geometry.direction.determinant(), -1.0, 1e-9);
}

TEST_F(VolumeIo, NiftiSformWinsAndRescaleGivesHu) {
  // sform: i runs along RAS -y (anterior->posterior) 1.5 mm, j along RAS +x 1 mm, k along +z 3 mm
  // (a rotation by -90 degrees about z); a qform that disagrees must lose to the sform.
  // Stored uint16 with HU = 1 * value - 1024.
  NiftiFile f;
  f.datatype = 512;
  f.scl_slope = 1.0f;
  f.scl_inter = -1024.0f;
  f.pixdim[1] = 1.5f;
  f.pixdim[3] = 3.0f;
  f.qform_code = 1;  // identity at 0: wrong on purpose
  f.sform_code = 1;
  const float s[3][4] = {{0, 1, 0, -5}, {-1.5f, 0, 0, 7}, {0, 0, 3, -40}};
  std::memcpy(f.srow, s, sizeof s);
  std::vector<std::int16_t> data = ramp(24);
  for (auto& x : data) x = std::int16_t(x + 1000);
  write_bytes(path("s.nii"), f.bytes(data));
  const Volume v = vx::read_volume(path("s.nii"));
  // voxel (2,3,1): RAS = (-5 + 3, 7 - 3, -40 + 3) = (-2, 4, -37) -> LPS (2, -4, -37)
  EXPECT_LT((v.geometry.index_to_lps({2, 3, 1}) - Eigen::Vector3d(2, -4, -37)).norm(), 1e-5);
  EXPECT_LT((v.geometry.spacing_mm - Eigen::Vector3d(1.5, 1, 3)).norm(), 1e-6);
  EXPECT_EQ(v.at(0, 0, 0), 1000.0f - 1024.0f);
  EXPECT_EQ(v.at(2, 3, 1), 1023.0f - 1024.0f);
}

TEST_F(VolumeIo, NiftiMetreUnitsAreScaledToMm) {
  // xyzt_units = metres: pixdim 0.001 m = 1 mm
  NiftiFile f;
  f.xyzt_units = 1;
  f.pixdim[1] = f.pixdim[2] = f.pixdim[3] = 0.001f;
  f.qform_code = 1;
  f.qoffset[2] = 0.05f;  // 50 mm superior
  write_bytes(path("m.nii"), f.bytes(ramp(24)));
  const Volume v = vx::read_volume(path("m.nii"));
  EXPECT_LT((v.geometry.spacing_mm - Eigen::Vector3d(1, 1, 1)).norm(), 1e-4);
  EXPECT_LT((v.geometry.origin_mm - Eigen::Vector3d(0, 0, 50)).norm(), 1e-4);
}

// ---------------------------------------------------------------------------------------
// NRRD written by hand

TEST_F(VolumeIo, NrrdAttachedRasRaw) {
  // 3 x 4 x 2 (a first axis of 3 samples: vtkNrrdReader would take it for vector components)
  const std::string header =
      "NRRD0004\n# hand-written\ntype: short\ndimension: 3\nspace: right-anterior-superior\nsizes: 3 4 2\n"
      "space directions: (0.5,0,0) (0,0.75,0) (0,0,2)\nkinds: domain domain domain\nendian: little\n"
      "encoding: raw\nspace origin: (10,20,30)\n\n";
  write_bytes(path("a.nrrd"), header + int16_bytes(ramp(24)));
  const Volume v = vx::read_volume(path("a.nrrd"));
  ASSERT_EQ(v.geometry.dims, Eigen::Vector3i(3, 4, 2));
  EXPECT_LT((v.geometry.index_to_lps({2, 3, 1}) - Eigen::Vector3d(-11, -22.25, 32)).norm(), 1e-12);
  EXPECT_LT((v.geometry.spacing_mm - Eigen::Vector3d(0.5, 0.75, 2)).norm(), 1e-12);
  EXPECT_EQ(v.at(2, 3, 1), 23.0f);
  EXPECT_EQ(v.at(1, 2, 0), 7.0f);
}

TEST_F(VolumeIo, NrrdDetachedHeaderBigEndianLps) {
  // .nhdr + .raw, LPS space, axes permuted: i along -y (posterior->anterior), j along +x
  const std::string header =
      "NRRD0005\ntype: int16\ndimension: 3\nspace: left-posterior-superior\nsizes: 3 4 2\n"
      "space directions: (0,-2,0) (1,0,0) (0,0,1.25)\nendian: big\nencoding: raw\n"
      "space origin: (-1.5,4,100)\ndata file: d.raw\n";
  write_bytes(path("d.nhdr"), header);
  std::vector<std::int16_t> data = ramp(24);
  for (auto& x : data) x = std::int16_t(-1000 + 3 * x);
  write_bytes(path("d.raw"), int16_bytes(data, /*big_endian=*/true));
  const Volume v = vx::read_volume(path("d.nhdr"));
  EXPECT_LT((v.geometry.index_to_lps({2, 3, 1}) - Eigen::Vector3d(-1.5 + 3, 4 - 4, 101.25)).norm(), 1e-12);
  EXPECT_EQ(v.at(0, 0, 0), -1000.0f);
  EXPECT_EQ(v.at(2, 3, 1), -1000.0f + 3 * 23);
  EXPECT_NEAR(v.geometry.direction.determinant(), 1.0, 1e-12);
}

TEST_F(VolumeIo, NrrdAsciiAndGzip) {
  std::string values;
  for (int i = 0; i < 8; ++i) values += std::to_string(i * 10 - 5) + (i % 4 == 3 ? "\n" : " ");
  write_bytes(path("t.nrrd"),
              "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nspacings: 2 3 4\nencoding: "
              "ascii\n\n" +
                  values);
  const Volume v = vx::read_volume(path("t.nrrd"));
  EXPECT_EQ(v.at(1, 1, 1), 65.0f);
  EXPECT_EQ(v.geometry.spacing_mm, Eigen::Vector3d(2, 3, 4));
  // gzip: written by write_volume (tested in the round trip), read back with a byte check here
  Volume big = test_volume(true);
  vx::write_volume(big, path("g.nrrd"));
  const std::string head = [&] {
    std::ifstream in(path("g.nrrd"), std::ios::binary);
    std::string s(400, '\0');
    in.read(s.data(), 400);
    return s;
  }();
  EXPECT_NE(head.find("encoding: gzip"), std::string::npos);
  EXPECT_NE(head.find("space: left-posterior-superior"), std::string::npos);
  EXPECT_EQ(vx::read_volume(path("g.nrrd")).hu, big.hu);
}

// ---------------------------------------------------------------------------------------
// MetaImage and VTI written by hand: their orientation conventions

TEST_F(VolumeIo, MetaImageTransformMatrixIsOneAxisPerGroup) {
  // TransformMatrix groups: axis i -> (0,1,0), axis j -> (-1,0,0), axis k -> (0,0,1) in LPS
  const std::string header =
      "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
      "TransformMatrix = 0 1 0 -1 0 0 0 0 1\nOffset = 5 -6 7.5\nElementSpacing = 0.5 2 3\nDimSize = 3 4 2\n"
      "ElementType = MET_SHORT\nElementDataFile = LOCAL\n";
  write_bytes(path("m.mha"), header + int16_bytes(ramp(24)));
  const Volume v = vx::read_volume(path("m.mha"));
  // voxel (2,3,1) = (5,-6,7.5) + 2*0.5*(0,1,0) + 3*2*(-1,0,0) + 1*3*(0,0,1) = (-1, -5, 10.5)
  EXPECT_LT((v.geometry.index_to_lps({2, 3, 1}) - Eigen::Vector3d(-1, -5, 10.5)).norm(), 1e-12);
  EXPECT_EQ(v.at(2, 3, 1), 23.0f);
  EXPECT_EQ(v.at(1, 0, 0), 1.0f);
}

TEST_F(VolumeIo, VtiDirectionAndExtentOffset) {
  // ASCII VTI: extent starting at i = 2, a direction turning i onto +y and j onto -x
  std::string values;
  for (int i = 0; i < 8; ++i) values += std::to_string(100 + i) + " ";
  const std::string xml =
      "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\">\n"
      "<ImageData WholeExtent=\"2 3 0 1 0 1\" Origin=\"1 2 3\" Spacing=\"0.5 2 4\" Direction=\"0 -1 0 1 0 0 0 0 1\">\n"
      "<Piece Extent=\"2 3 0 1 0 1\"><PointData Scalars=\"v\">\n"
      "<DataArray type=\"Int16\" Name=\"v\" format=\"ascii\">" +
      values + "</DataArray>\n</PointData><CellData/></Piece></ImageData></VTKFile>\n";
  write_bytes(path("h.vti"), xml);
  const Volume v = vx::read_volume(path("h.vti"));
  ASSERT_EQ(v.geometry.dims, Eigen::Vector3i(2, 2, 2));
  // VTK: x = origin + D * (spacing .* (i, j, k)), rows of Direction as written;
  // voxel 0 is extent (2,0,0): (1,2,3) + (0,1,0)*1.0 = (1,3,3)
  EXPECT_LT((v.geometry.origin_mm - Eigen::Vector3d(1, 3, 3)).norm(), 1e-12);
  EXPECT_LT((v.geometry.index_to_lps({1, 1, 1}) - Eigen::Vector3d(1 - 2, 3 + 0.5, 3 + 4)).norm(), 1e-12);
  EXPECT_EQ(v.at(1, 1, 1), 107.0f);
}

TEST(VolumeSamples, BundledPhantomSamples) {
  // samples/*.vti and *.nrrd are `voxelastic phantom NAME --size 64` (see samples/README.md)
  for (const char* name : {"sphere", "block-lesion"}) {
    SCOPED_TRACE(name);
    vx::PhantomSettings s;
    s.name = name;
    s.size = 64;
    vx::PhantomShape shape;
    const Volume expected = vx::make_phantom(s, &shape);
    // .vti for ParaView, the same volume as .nrrd for 3D Slicer (it lists no .vti among volumes)
    for (const char* ext : {".vti", ".nrrd"}) {
      const fs::path file = fs::path(VX_SAMPLES_DIR) / (std::string(name) + "64" + ext);
      ASSERT_TRUE(fs::exists(file)) << file;
      EXPECT_LT(fs::file_size(file), 1u << 20);
      const Volume v = vx::read_volume(file);
      EXPECT_EQ(v.geometry, expected.geometry) << ext;
      EXPECT_EQ(v.hu, expected.hu) << ext;
    }
  }
}

// ---------------------------------------------------------------------------------------
// bad input: a vx::Error that says what, where and how to fix

TEST_F(VolumeIo, MissingFileAndUnknownExtension) {
  expect_error([&] { (void)vx::read_volume(path("nope.vti")); }, {"nope.vti", "no such file"});
  write_bytes(path("x.xyz"), "hello");
  expect_error([&] { (void)vx::read_volume(path("x.xyz")); },
               {"x.xyz", "unknown volume format", ".vti", ".nii.gz", ".nrrd", "DICOM"});
  expect_error([&] { vx::write_volume(test_volume(true), path("x.png")); }, {"x.png", "unknown", ".mha"});
  expect_error([&] { vx::write_volume(test_volume(true), path("x.mhd")); }, {".mha instead"});
  expect_error([&] { vx::write_volume(test_volume(true), path("missing_dir/x.vti")); }, {"does not exist"});
  write_bytes(path("empty.nii"), "");
  expect_error([&] { (void)vx::read_volume(path("empty.nii")); }, {"empty.nii", "empty"});
  EXPECT_FALSE(fs::exists(path("x.png")));
  EXPECT_FALSE(fs::exists(path("x.mhd")));
}

TEST_F(VolumeIo, TruncatedVti) {
  vx::write_volume(test_volume(false), path("t.vti"));
  const auto size = fs::file_size(path("t.vti"));
  fs::resize_file(path("t.vti"), size - 60);  // cut into the compressed voxel data
  expect_error([&] { (void)vx::read_volume(path("t.vti")); }, {"t.vti", "export it again"});
  fs::resize_file(path("t.vti"), 200);  // cut into the XML header
  expect_error([&] { (void)vx::read_volume(path("t.vti")); }, {"t.vti"});
}

TEST_F(VolumeIo, GarbageAndTruncatedMetaImage) {
  std::string garbage(4096, '\0');
  for (std::size_t i = 0; i < garbage.size(); ++i) garbage[i] = char((i * 7919u + 13u) % 251u);
  write_bytes(path("g.mha"), garbage);
  expect_error([&] { (void)vx::read_volume(path("g.mha")); }, {"g.mha", "not a valid MetaImage"});
  // a good header, then half the voxel data
  const std::string header =
      "ObjectType = Image\nNDims = 3\nBinaryData = True\nDimSize = 3 4 2\nElementType = MET_SHORT\n"
      "ElementDataFile = LOCAL\n";
  write_bytes(path("t.mha"), header + int16_bytes(ramp(12)));
  expect_error([&] { (void)vx::read_volume(path("t.mha")); }, {"t.mha", "truncated", "48 bytes"});
  // compressed data that is not zlib
  write_bytes(path("z.mha"),
              "ObjectType = Image\nNDims = 3\nDimSize = 3 4 2\nElementType = MET_SHORT\n"
              "CompressedData = True\nCompressedDataSize = 40\nElementDataFile = LOCAL\n" +
                  garbage.substr(0, 40));
  expect_error([&] { (void)vx::read_volume(path("z.mha")); }, {"z.mha"});
}

TEST_F(VolumeIo, GarbageNiftiAndNrrd) {
  write_bytes(path("g.nii.gz"), "this is not gzip at all, nor NIfTI");
  expect_error([&] { (void)vx::read_volume(path("g.nii.gz")); }, {"g.nii.gz", "NIfTI"});
  write_bytes(path("g.nrrd"), "PNG\x89 something else");
  expect_error([&] { (void)vx::read_volume(path("g.nrrd")); }, {"g.nrrd", "not a NRRD file"});
  // header fine, raw data short
  write_bytes(path("s.nrrd"),
              "NRRD0004\ntype: short\ndimension: 3\nsizes: 3 4 2\nencoding: raw\n\n" + int16_bytes(ramp(20)));
  expect_error([&] { (void)vx::read_volume(path("s.nrrd")); }, {"s.nrrd", "truncated"});
  // gzip data cut short
  vx::write_volume(test_volume(false), path("c.nrrd"));
  fs::resize_file(path("c.nrrd"), fs::file_size(path("c.nrrd")) - 100);
  expect_error([&] { (void)vx::read_volume(path("c.nrrd")); }, {"c.nrrd", "compressed voxel data"});
}

TEST_F(VolumeIo, AbsurdSizesInDamagedHeadersAreRefusedBeforeAllocating) {
  NiftiFile f;
  f.dim[0] = f.dim[1] = f.dim[2] = 30000;  // 2.7e13 voxels
  write_bytes(path("huge.nii"), f.bytes(ramp(24)));
  expect_error([&] { (void)vx::read_volume(path("huge.nii")); }, {"huge.nii", "30000x30000x30000", "damaged"});
  write_bytes(path("huge.mha"),
              "NDims = 3\nDimSize = 100000 100000 100000\nElementType = MET_SHORT\n"
              "CompressedData = True\nElementDataFile = LOCAL\n" +
                  std::string(100, 'x'));
  expect_error([&] { (void)vx::read_volume(path("huge.mha")); }, {"huge.mha", "voxels"});
  // a plausible size, but far more than 100 compressed bytes can hold
  write_bytes(path("big.nrrd"),
              "NRRD0004\ntype: short\ndimension: 3\nsizes: 512 512 400\nencoding: gzip\n\n" + std::string(100, 'x'));
  expect_error([&] { (void)vx::read_volume(path("big.nrrd")); }, {"big.nrrd", "cannot hold"});
}

TEST_F(VolumeIo, MultiComponentDataIsRefused) {
  write_bytes(path("rgb.nrrd"),
              "NRRD0004\ntype: uchar\ndimension: 4\nsizes: 3 2 2 2\nkinds: RGB-color domain "
              "domain domain\nencoding: raw\n\n" +
                  std::string(24, 'a'));
  expect_error([&] { (void)vx::read_volume(path("rgb.nrrd")); }, {"rgb.nrrd", "values per voxel"});
  write_bytes(path("v.mha"),
              "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementNumberOfChannels = 3\n"
              "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n" +
                  std::string(24, 'a'));
  expect_error([&] { (void)vx::read_volume(path("v.mha")); }, {"v.mha", "3 channels"});
  const std::string xml =
      "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\">\n"
      "<ImageData WholeExtent=\"0 1 0 0 0 0\" Origin=\"0 0 0\" Spacing=\"1 1 1\">\n"
      "<Piece Extent=\"0 1 0 0 0 0\"><PointData Vectors=\"v\">\n"
      "<DataArray type=\"Float32\" Name=\"v\" NumberOfComponents=\"3\" format=\"ascii\">1 2 3 4 5 6</DataArray>\n"
      "</PointData></Piece></ImageData></VTKFile>\n";
  write_bytes(path("vec.vti"), xml);
  expect_error([&] { (void)vx::read_volume(path("vec.vti")); }, {"vec.vti", "3 components"});
}

TEST_F(VolumeIo, EmptyVolumeIsRefused) {
  Volume empty;
  expect_error([&] { vx::write_volume(empty, path("e.vti")); }, {"e.vti", "empty"});
  EXPECT_FALSE(fs::exists(path("e.vti")));
  const std::string xml =
      "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\">\n"
      "<ImageData WholeExtent=\"0 -1 0 -1 0 -1\" Origin=\"0 0 0\" Spacing=\"1 1 1\">\n"
      "</ImageData></VTKFile>\n";
  write_bytes(path("e.vti"), xml);
  expect_error([&] { (void)vx::read_volume(path("e.vti")); }, {"e.vti"});
}

TEST_F(VolumeIo, FailedWriteLeavesOldFileAlone) {
  // an existing output stays as it was when writing fails (the folder is read-only)
  if (::geteuid() == 0) GTEST_SKIP() << "root ignores folder permissions";
  const Volume v = test_volume(true);
  vx::write_volume(v, path("keep.mha"));
  const auto before = fs::file_size(path("keep.mha"));
  fs::permissions(dir_, fs::perms::owner_read | fs::perms::owner_exec);
  expect_error([&] { vx::write_volume(test_volume(false), path("keep.mha")); }, {"keep.mha", "not writable"});
  fs::permissions(dir_, fs::perms::owner_all);
  EXPECT_EQ(fs::file_size(path("keep.mha")), before);
  EXPECT_EQ(vx::read_volume(path("keep.mha")).hu, v.hu);
}

}  // namespace

// ---------------------------------------------------------------------------------------
// hostile headers (issue #17): each of these crashed VTK, hung or allocated gigabytes before

namespace {

/// The text of a file.
std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

/// `text` with its first `from` replaced by `to` (the test fails when `from` is not there).
std::string edited(std::string text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  EXPECT_NE(at, std::string::npos) << "'" << from << "' not in the file";
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

}  // namespace

TEST_F(VolumeIo, VtiReversedExtentsAreRefusedBeforeVtkReadsThem) {
  vx::write_volume(test_volume(true), path("good.vti"));
  const std::string good = read_text(path("good.vti"));
  ASSERT_NE(good.find("WholeExtent=\"0 6 0 4 0 3\""), std::string::npos);
  // the whole extent reversed along x (SIGSEGV in vtkXMLStructuredDataReader::ReadSubExtent)
  write_bytes(path("whole.vti"), edited(good, "WholeExtent=\"0 6", "WholeExtent=\"6 0"));
  expect_error([&] { (void)vx::read_volume(path("whole.vti")); },
               {"whole.vti", "WholeExtent", "reversed along axis x"});
  // a piece reversed along z, and a piece reaching outside the whole extent
  write_bytes(path("piece.vti"), edited(good, "Extent=\"0 6 0 4 0 3\"  ", "Extent=\"0 6 0 4 3 0\"  "));
  expect_error([&] { (void)vx::read_volume(path("piece.vti")); }, {"piece.vti", "reversed along axis z"});
  write_bytes(path("out.vti"), edited(good, "Piece Extent=\"0 6", "Piece Extent=\"0 9"));
  expect_error([&] { (void)vx::read_volume(path("out.vti")); }, {"out.vti", "outside WholeExtent"});
}

TEST_F(VolumeIo, VtiBlockHeadersOfTheWrongWidthOrByteOrderAreRefused) {
  vx::write_volume(test_volume(true), path("good.vti"));
  const std::string good = read_text(path("good.vti"));
  // 64-bit block headers read as 32-bit: a block size of 0 (SIGFPE in ReadCompressedData)
  write_bytes(path("u32.vti"), edited(good, "header_type=\"UInt64\"", "header_type=\"UInt32\""));
  expect_error([&] { (void)vx::read_volume(path("u32.vti")); }, {"u32.vti", "header_type", "damaged"});
  // little-endian sizes read as big-endian: terabytes (std::bad_alloc)
  write_bytes(path("be.vti"), edited(good, "byte_order=\"LittleEndian\"", "byte_order=\"BigEndian\""));
  expect_error([&] { (void)vx::read_volume(path("be.vti")); }, {"be.vti", "byte_order"});
  // the original still reads
  expect_same(test_volume(true), vx::read_volume(path("good.vti")), 1e-9, 1e-9);
}

TEST_F(VolumeIo, VtiArrayElementsAreCheckedLikeDataArrays) {
  // found by the CI's fuzz smoke run: VTK reads an <Array> element like a <DataArray>, the
  // header check skipped it, and its block header (4 TB in one block) reached VTK's allocator
  // (std::bad_alloc, an internal error)
  vx::write_volume(test_volume(true), path("good.vti"));
  const std::string good = read_text(path("good.vti"));
  ASSERT_NE(good.find("<DataArray"), std::string::npos);
  const std::string renamed = edited(good, "<DataArray", "<Array");  // appended: a self-closed element
  write_bytes(path("array.vti"), renamed);
  // the same element under its other name is checked: a good one still reads ...
  expect_same(test_volume(true), vx::read_volume(path("array.vti")), 1e-9, 1e-9);
  // ... and a damaged block header is refused before VTK allocates
  write_bytes(path("array_be.vti"), edited(renamed, "byte_order=\"LittleEndian\"", "byte_order=\"BigEndian\""));
  expect_error([&] { (void)vx::read_volume(path("array_be.vti")); }, {"array_be.vti", "byte_order"});
  // field data arrays are read by VTK too: one that claims a billion doubles from the HU array's
  // block header is refused
  const auto image = good.find("<ImageData");
  ASSERT_NE(image, std::string::npos);
  const auto image_end = good.find('>', image);
  std::string field = good;
  field.insert(image_end + 1,
               "\n<FieldData><DataArray type=\"Float64\" Name=\"f\" NumberOfTuples=\"1000000000\" "
               "format=\"appended\" offset=\"0\"/></FieldData>");
  write_bytes(path("field.vti"), field);
  expect_error([&] { (void)vx::read_volume(path("field.vti")); }, {"field.vti", "array 'f'"});
}

TEST_F(VolumeIo, VtiTrulyBigEndianAndUncompressedStillReads) {
  // a hand-made big-endian file: uncompressed appended raw data, 32-bit block header
  const std::vector<std::int16_t> values = ramp(24);
  std::string data = int16_bytes(values, /*big_endian=*/true);
  const std::uint32_t n = std::uint32_t(data.size());
  const std::string size_be{char(n >> 24), char(n >> 16), char(n >> 8), char(n)};
  const std::string xml =
      "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"BigEndian\" "
      "header_type=\"UInt32\">\n<ImageData WholeExtent=\"0 2 0 3 0 1\" Origin=\"1 2 3\" Spacing=\"0.5 1 2\">\n"
      "<Piece Extent=\"0 2 0 3 0 1\"><PointData Scalars=\"HU\">\n"
      "<DataArray type=\"Int16\" Name=\"HU\" format=\"appended\" offset=\"0\"/>\n"
      "</PointData><CellData></CellData></Piece></ImageData>\n<AppendedData encoding=\"raw\">\n_";
  write_bytes(path("be.vti"), xml + size_be + data + "\n</AppendedData></VTKFile>\n");
  const Volume v = vx::read_volume(path("be.vti"));
  ASSERT_EQ(v.geometry.dims, Eigen::Vector3i(3, 4, 2));
  EXPECT_EQ(v.at(2, 3, 1), 23.0f);
  EXPECT_EQ(v.at(1, 0, 0), 1.0f);
  // the same file one byte short of its data
  write_bytes(path("short.vti"), xml + size_be + data.substr(0, data.size() - 1));
  expect_error([&] { (void)vx::read_volume(path("short.vti")); }, {"short.vti"});
}

TEST_F(VolumeIo, NiftiZeroDimensionIsRefusedBeforeVtkReadsIt) {
  // dim[2] or dim[3] = 0 crashed vtkNIFTIImageReader inside gzread (.nii and .nii.gz)
  for (const int axis : {1, 2}) {
    NiftiFile f;
    f.dim[axis] = 0;
    write_bytes(path("z.nii"), f.bytes(ramp(24)));
    expect_error([&] { (void)vx::read_volume(path("z.nii")); },
                 {"z.nii", "dim[" + std::to_string(axis + 1) + "] = 0", "at least one voxel"});
    const std::string raw = f.bytes(ramp(24));
    const auto packed = vx::deflate_bytes(raw.data(), raw.size(), /*gzip=*/true);
    write_bytes(path("z.nii.gz"), std::string(packed.begin(), packed.end()));
    expect_error([&] { (void)vx::read_volume(path("z.nii.gz")); }, {"z.nii.gz", "at least one voxel"});
  }
}

TEST_F(VolumeIo, NiftiUnknownDatatypeAndShortDataAreRefused) {
  NiftiFile f;
  f.datatype = 9999;  // VTK allocated 3.3 GB for this before failing
  write_bytes(path("t.nii"), f.bytes(ramp(24)));
  expect_error([&] { (void)vx::read_volume(path("t.nii")); }, {"t.nii", "datatype 9999", "not a known data type"});
  f.datatype = 128;  // RGB24
  write_bytes(path("rgb.nii"), f.bytes(ramp(24)));
  expect_error([&] { (void)vx::read_volume(path("rgb.nii")); }, {"rgb.nii", "RGB24", "one value"});
  NiftiFile g;
  write_bytes(path("short.nii"), g.bytes(ramp(20)));  // 24 voxels declared
  expect_error([&] { (void)vx::read_volume(path("short.nii")); }, {"short.nii", "truncated", "48 bytes"});
}

TEST_F(VolumeIo, NiftiQformAndSformThatDisagreeFollowTheQformAndSaySo) {
  // qform: identity at RAS (10, 20, 30); sform (code 2, aligned-anatomical): shifted by 5 mm.
  // 3D Slicer and ITK take the qform unless the sform is scanner-anatomical (code 1).
  NiftiFile f;
  f.qform_code = 1;
  f.qoffset[0] = 10;
  f.qoffset[1] = 20;
  f.qoffset[2] = 30;
  f.sform_code = 2;
  const float s[3][4] = {{1, 0, 0, 15}, {0, 1, 0, 20}, {0, 0, 1, 30}};
  std::memcpy(f.srow, s, sizeof s);
  write_bytes(path("qs.nii"), f.bytes(ramp(24)));
  ::testing::internal::CaptureStderr();
  const Volume v = vx::read_volume(path("qs.nii"));
  const std::string said = ::testing::internal::GetCapturedStderr();
  EXPECT_LT((v.geometry.index_to_lps({0, 0, 0}) - Eigen::Vector3d(-10, -20, 30)).norm(), 1e-6);
  EXPECT_NE(said.find("qform (code 1) and sform (code 2) disagree"), std::string::npos) << said;
  EXPECT_NE(said.find("by up to 5 mm"), std::string::npos) << said;
  // sform code 1 (scanner-anatomical): the sform, still with the warning
  f.sform_code = 1;
  write_bytes(path("qs1.nii"), f.bytes(ramp(24)));
  ::testing::internal::CaptureStderr();
  const Volume w = vx::read_volume(path("qs1.nii"));
  EXPECT_NE(::testing::internal::GetCapturedStderr().find("following the sform"), std::string::npos);
  EXPECT_LT((w.geometry.index_to_lps({0, 0, 0}) - Eigen::Vector3d(-15, -20, 30)).norm(), 1e-6);
  // when they agree, nothing is said
  const float same[3][4] = {{1, 0, 0, 10}, {0, 1, 0, 20}, {0, 0, 1, 30}};
  std::memcpy(f.srow, same, sizeof same);
  f.sform_code = 2;
  write_bytes(path("agree.nii"), f.bytes(ramp(24)));
  ::testing::internal::CaptureStderr();
  (void)vx::read_volume(path("agree.nii"));
  EXPECT_EQ(::testing::internal::GetCapturedStderr().find("disagree"), std::string::npos);
}

TEST_F(VolumeIo, MetaImageCompressedDataSizeMustBeAByteCount) {
  // -1 became 2^64 - 1 bytes (std::bad_alloc), NaN undefined behaviour
  for (const char* bad : {"-1", "nan", "2.5", "0"}) {
    write_bytes(path("c.mha"), std::string("ObjectType = Image\nNDims = 3\nDimSize = 3 4 2\nElementType = MET_SHORT\n"
                                           "CompressedData = True\nCompressedDataSize = ") +
                                   bad + "\nElementDataFile = LOCAL\n" + std::string(40, 'x'));
    expect_error([&] { (void)vx::read_volume(path("c.mha")); }, {"c.mha", "CompressedDataSize", "byte count"});
  }
  write_bytes(path("n.mha"), "NDims = nan\nDimSize = 3 4 2\nElementType = MET_SHORT\nElementDataFile = LOCAL\n");
  expect_error([&] { (void)vx::read_volume(path("n.mha")); }, {"n.mha", "NDims = nan"});
}

TEST_F(VolumeIo, MetaImageFieldWrittenTwiceIsRefused) {
  // found by fuzzing: metaio read the first NDims (-6) and looped for ever where this reader
  // had checked the second (3); text voxels, so the file would have gone to metaio
  const std::string tail = "DimSize = 2 2 2\nElementType = MET_SHORT\nBinaryData = False\nElementDataFile = LOCAL\n" +
                           std::string(8, '1') + "\n";
  write_bytes(path("twice.mha"), "ObjectType = Image\nNDims = -6.125 -6.125 -6.125\nNDims = 3\n" + tail);
  expect_error([&] { (void)vx::read_volume(path("twice.mha")); }, {"twice.mha", "NDims twice"});
  // the same header with one NDims is read
  write_bytes(path("once.mha"),
              "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\n"
              "BinaryData = False\nElementDataFile = LOCAL\n1 2 3 4 5 6 7 8\n");
  const Volume v = vx::read_volume(path("once.mha"));
  ASSERT_EQ(v.hu.size(), 8u);
  EXPECT_FLOAT_EQ(v.hu[7], 8.0f);
}

TEST(Compression, AnySizeIsFedToZlibInChunksAndComesBackWhole) {
  // zlib's counters are 32-bit: a volume over 4 GiB must be fed in chunks (it was cast to uInt and
  // written truncated). The same loop, with chunks of a few bytes, on a small buffer:
  std::vector<unsigned char> data(200000);
  for (std::size_t i = 0; i < data.size(); ++i) data[i] = static_cast<unsigned char>((i * 7) ^ (i >> 7));
  for (const bool gzip : {false, true}) {
    const auto whole = vx::deflate_bytes(data.data(), data.size(), gzip);
    const auto chunked = vx::deflate_bytes(data.data(), data.size(), gzip, 7);
    const auto back =
        vx::inflate_bytes(reinterpret_cast<const char*>(chunked.data()), chunked.size(), data.size(), "chunked", 5);
    ASSERT_EQ(back.size(), data.size());
    EXPECT_EQ(std::memcmp(back.data(), data.data(), data.size()), 0);
    const auto back_whole =
        vx::inflate_bytes(reinterpret_cast<const char*>(whole.data()), whole.size(), data.size(), "w");
    EXPECT_EQ(std::memcmp(back_whole.data(), data.data(), data.size()), 0);
  }
  // an empty input is an empty stream, not an error
  EXPECT_FALSE(vx::deflate_bytes(data.data(), 0, true, 3).empty());
}

TEST_F(VolumeIo, MetaImageHeadersForMetaioAreCheckedFirst) {
  // found by fuzzing: a binary ElementDataFile overflowed a buffer inside metaio (strlen), and
  // damaged compressed data split over files made metaio's inflate loop for ever
  write_bytes(path("bin.mha"), std::string("ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\n"
                                           "ElementDataFile = LOCA\x01\xff\xfe x y\n") +
                                   std::string(16, 'x'));
  expect_error([&] { (void)vx::read_volume(path("bin.mha")); }, {"bin.mha", "ElementDataFile", "not printable"});
  write_bytes(path("list.mha"),
              "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\n"
              "CompressedData = True\nElementDataFile = LIST\na.zraw\nb.zraw\n");
  expect_error([&] { (void)vx::read_volume(path("list.mha")); }, {"list.mha", "compressed", "several files"});
  // a file pattern whose step is 0 (metaio divides by it: SIGFPE), and words that are no pattern
  write_bytes(path("pat.mha"),
              "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\n"
              "ElementDataFile = slice%03d.raw 1 2 0\n");
  expect_error([&] { (void)vx::read_volume(path("pat.mha")); }, {"pat.mha", "ElementDataFile", "step not 0"});
  write_bytes(path("words.mha"),
              "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\n"
              "ElementDataFile = c LO~~Elem%ntType = MET_SHORT\n");
  expect_error([&] { (void)vx::read_volume(path("words.mha")); }, {"words.mha", "neither a file name"});
  // text voxels need at least two characters each in the file
  write_bytes(path("text.mha"),
              "ObjectType = Image\nNDims = 3\nDimSize = 100 100 100\nBinaryData = False\n"
              "ElementType = MET_SHORT\nElementDataFile = LOCAL\n1 2 3\n");
  expect_error([&] { (void)vx::read_volume(path("text.mha")); }, {"text.mha", "more than the files beside it hold"});
}

TEST_F(VolumeIo, MetaImageListNamesAFileOnEveryLine) {
  // found by fuzzing: metaio takes any ElementDataFile that starts with LIST for a list, and an
  // empty line in the list made it read before its buffer (SIGSEGV); a missing file it skips,
  // leaving zeros. A good list is read slice by slice:
  const std::string head = "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\n";
  write_bytes(path("s0.raw"), std::string("\x01\x02\x03\x04", 4));
  write_bytes(path("s1.raw"), std::string("\x05\x06\x07\x08", 4));
  write_bytes(path("good.mhd"), head + "ElementDataFile = LIST\ns0.raw\ns1.raw\n");
  const Volume v = vx::read_volume(path("good.mhd"));
  ASSERT_EQ(v.hu.size(), 8u);
  for (int i = 0; i < 8; ++i) EXPECT_FLOAT_EQ(v.hu[std::size_t(i)], float(i + 1));
  write_bytes(path("empty.mhd"), head + "ElementDataFile = LIST\n\ns1.raw\n");
  expect_error([&] { (void)vx::read_volume(path("empty.mhd")); }, {"empty.mhd", "2 file names", "line 1", "is empty"});
  write_bytes(path("gone.mhd"), head + "ElementDataFile = LIST\ns0.raw\ns9.raw\n");
  expect_error([&] { (void)vx::read_volume(path("gone.mhd")); }, {"gone.mhd", "line 2", "s9.raw", "does not exist"});
  write_bytes(path("short.mhd"), head + "ElementDataFile = LIST\ns0.raw\n");
  expect_error([&] { (void)vx::read_volume(path("short.mhd")); }, {"short.mhd", "line 2", "is missing"});
  write_bytes(path("glued.mhd"), head + "ElementDataFile = LIST5cBinary\ns0.raw\ns1.raw\n");
  expect_error([&] { (void)vx::read_volume(path("glued.mhd")); }, {"glued.mhd", "neither a file name"});
  // a pattern's field width is two digits at most (metaio prints the name into a fixed buffer)
  write_bytes(path("wide.mhd"), head + "ElementDataFile = s%0999d.raw 0 1 1\n");
  expect_error([&] { (void)vx::read_volume(path("wide.mhd")); }, {"wide.mhd", "neither a file name"});
}
