// Reading and writing volumes in the formats medical imaging tools exchange.
//
// Every reader returns geometry in LPS mm with the voxel order of the file (x fastest);
// every writer is atomic. VTK does the heavy lifting where it keeps the geometry; where a
// VTK 9.1 class loses it, this file parses or writes the header itself:
// - .vti: vtkXMLImageData{Reader,Writer}; VTK 9.1 keeps the direction matrix.
// - .mha/.mhd: the header is parsed here (vtkMetaImageReader drops TransformMatrix); voxels
//   in one file (raw or zlib) are read here with every size checked, because metaio turns
//   damaged compressed data into zeros without an error; data split over several files goes
//   through vtkMetaImageReader. Written here (vtkMetaImageWriter drops the direction).
// - .nii/.nii.gz: vtkNIFTIImage{Reader,Writer}; RAS <-> LPS and the reader's slice reversal
//   (qfac = -1) are undone here so voxel order matches the file.
// - .nrrd/.nhdr: read and written here. vtkNrrdReader (9.1) takes a first axis of 9 or
//   fewer samples for vector components, ignores orientation and reads only the first slice
//   of gzip data, so it cannot be trusted with CT volumes.
// - a folder (or a .dcm file): the DICOM series reader/writer in dicom_series.cpp.

#include "io/volume_io.h"

#include <fmt/format.h>
#include <vtkCellData.h>
#include <vtkDataArray.h>
#include <vtkErrorCode.h>
#include <vtkFloatArray.h>
#include <vtkImageData.h>
#include <vtkInformation.h>
#include <vtkStreamingDemandDrivenPipeline.h>
#include <vtkMatrix3x3.h>
#include <vtkMatrix4x4.h>
#include <vtkMetaImageReader.h>
#include <vtkNIFTIImageHeader.h>
#include <vtkNIFTIImageReader.h>
#include <vtkNIFTIImageWriter.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkShortArray.h>
#include <vtkSmartPointer.h>
#include <vtkType.h>
#include <vtkXMLImageDataReader.h>
#include <vtkXMLImageDataWriter.h>
#include <zlib.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <optional>
#include <sstream>

#include "base/error.h"
#include "io/dicom_common.h"
#include "io/dicom_series.h"
#include "util/atomic_file.h"
#include "util/text.h"
#include "util/vtk_messages.h"

namespace vx {
namespace {
namespace fs = std::filesystem;

constexpr const char* kSupported =
    ".vti, .mha, .mhd, .nii, .nii.gz, .nrrd, .nhdr, or a DICOM series (a folder, a path "
    "ending in '/', or one .dcm file of the series)";
constexpr const char* kWritable = ".vti, .mha, .nii.gz, .nii, .nrrd, or a folder path ending in '/' (DICOM)";

bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

std::vector<std::string> split_ws(const std::string& s) {
  std::istringstream in(s);
  std::vector<std::string> out;
  for (std::string w; in >> w;) out.push_back(w);
  return out;
}

/// Parses a whole string as a finite-or-not double; nullopt when it is not a number.
std::optional<double> to_double(const std::string& text) {
  const std::string s = trim(text);
  if (s.empty()) return std::nullopt;
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size()) return std::nullopt;
  return v;
}

/// Whitespace-separated numbers; nullopt unless all of them parse.
std::optional<std::vector<double>> to_doubles(const std::string& s) {
  std::vector<double> out;
  for (const auto& w : split_ws(s)) {
    const auto v = to_double(w);
    if (!v) return std::nullopt;
    out.push_back(*v);
  }
  return out;
}

// ---------------------------------------------------------------------------------------
// VTK messages: errors become vx::Error, nothing is printed by VTK itself.

/// VTK's messages while one file is read or written: collected by vtk_messages.h (nothing
/// reaches the console), reported here as this file's errors and warnings.
class VtkMessages {
 public:
  [[nodiscard]] bool failed() const { return !capture_.errors().empty(); }
  /// The first few error messages (first lines), joined; the pipeline's generic "Algorithm X
  /// returned failure" only when nothing more specific was said.
  [[nodiscard]] std::string errors() const {
    const auto& all = capture_.errors();
    std::vector<std::string> lines;
    for (const auto& e : all) {
      const std::string line = trim(e.substr(0, e.find('\n')));
      const bool generic = line.rfind("Algorithm ", 0) == 0 && line.find("returned failure") != std::string::npos;
      if (!line.empty() && !generic && std::find(lines.begin(), lines.end(), line) == lines.end())
        lines.push_back(line);
    }
    if (lines.empty() && !all.empty()) lines.push_back(trim(all[0].substr(0, all[0].find('\n'))));
    std::string out;
    for (std::size_t i = 0; i < lines.size() && i < 3; ++i) {
      std::string line = lines[i];
      while (!line.empty() && (line.back() == '.' || line.back() == ' ')) line.pop_back();
      out += (i ? "; " : "") + line;
    }
    return out;
  }
  /// Prints the warnings (deduplicated) to stderr, naming the file.
  void print_warnings(const fs::path& path) const {
    std::vector<std::string> seen;
    for (const auto& w : capture_.warnings()) {
      const std::string line = trim(w.substr(0, w.find('\n')));
      if (line.empty() || std::find(seen.begin(), seen.end(), line) != seen.end()) continue;
      seen.push_back(line);
      std::fprintf(stderr, "volume: warning: %s: %s\n", path.string().c_str(), line.c_str());
    }
  }

 private:
  VtkMessageCapture capture_;
};

/// Captures what third-party code writes to std::cerr (metaio reports there) while alive.
class CerrCapture {
 public:
  CerrCapture() : old_(std::cerr.rdbuf(buffer_.rdbuf())) {}
  ~CerrCapture() { std::cerr.rdbuf(old_); }
  CerrCapture(const CerrCapture&) = delete;
  CerrCapture& operator=(const CerrCapture&) = delete;
  [[nodiscard]] std::string text() const { return trim(buffer_.str()); }

 private:
  std::ostringstream buffer_;
  std::streambuf* old_;
};

// ---------------------------------------------------------------------------------------
// Shared helpers

std::uintmax_t file_size_or_zero(const fs::path& path) {
  std::error_code ec;
  const auto n = fs::file_size(path, ec);
  return ec ? 0 : n;
}

/// Voxel count of `dims`, refusing sizes no machine here holds (a damaged header, usually).
std::size_t checked_voxel_count(const Eigen::Vector3i& dims, const fs::path& path) {
  const double n = double(dims.x()) * double(dims.y()) * double(dims.z());
  constexpr double kMaxVoxels = 8.0e9;  // 32 GB of float HU
  if (n > kMaxVoxels)
    throw Error(fmt::format("{}: the header describes {}x{}x{} = {:.3g} voxels, more than voxelastic handles ({:.0e}); "
                            "the header is damaged, or crop/downsample the volume first",
                            quoted(path), dims.x(), dims.y(), dims.z(), n, kMaxVoxels));
  return std::size_t(n);
}

std::string read_file_prefix(const fs::path& path, std::size_t max_bytes) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open " + quoted(path) + " for reading (check its permissions)");
  std::string s(max_bytes, '\0');
  in.read(s.data(), std::streamsize(max_bytes));
  s.resize(std::size_t(in.gcount()));
  return s;
}

std::vector<char> read_file_bytes(const fs::path& path, std::uintmax_t offset, std::uintmax_t count) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open " + quoted(path) + " for reading (check its permissions)");
  in.seekg(std::streamoff(offset));
  std::vector<char> data(count);
  in.read(data.data(), std::streamsize(count));
  if (std::uintmax_t(in.gcount()) != count)
    throw Error(fmt::format("{} is truncated: expected {} bytes of voxel data from byte {}, found {} "
                            "(the file was cut short; copy or export it again)",
                            quoted(path), count, offset, in.gcount()));
  return data;
}

/// True when every value is an integer that int16 holds (then files store int16).
bool fits_int16(const std::vector<float>& hu) {
  for (float v : hu)
    if (!(v >= -32768.0f && v <= 32767.0f) || v != std::nearbyint(v)) return false;
  return true;
}

void check_volume_for_writing(const Volume& v, const fs::path& path) {
  const GridGeometry& g = v.geometry;
  if ((g.dims.array() <= 0).any())
    throw Error(fmt::format("cannot write {}: the volume is empty ({}x{}x{} voxels)", quoted(path), g.dims.x(),
                            g.dims.y(), g.dims.z()));
  if (std::int64_t(v.hu.size()) != g.voxel_count())
    throw Error(fmt::format("cannot write {}: the volume holds {} values for {}x{}x{} = {} voxels", quoted(path),
                            v.hu.size(), g.dims.x(), g.dims.y(), g.dims.z(), g.voxel_count()));
  if (!g.spacing_mm.allFinite() || (g.spacing_mm.array() <= 0).any())
    throw Error(fmt::format("cannot write {}: voxel spacing ({}, {}, {}) mm must be positive and finite",
                            quoted(path), g.spacing_mm.x(), g.spacing_mm.y(), g.spacing_mm.z()));
  if (!g.origin_mm.allFinite() || !g.direction.allFinite())
    throw Error("cannot write " + quoted(path) + ": the origin or direction is not finite");
  if (std::abs(g.direction.determinant()) < 1e-9)
    throw Error("cannot write " + quoted(path) + ": the direction matrix is singular");
}

/// A geometry from a 3x3 affine A (columns: one voxel step along each index axis, LPS mm)
/// and the position of voxel 0.
GridGeometry geometry_from_affine(const Eigen::Vector3i& dims, const Eigen::Matrix3d& A, const Eigen::Vector3d& t) {
  GridGeometry g;
  g.dims = dims;
  g.origin_mm = t;
  for (int c = 0; c < 3; ++c) {
    const double s = A.col(c).norm();
    g.spacing_mm[c] = s;
    g.direction.col(c) = s > 0 ? Eigen::Vector3d(A.col(c) / s) : Eigen::Vector3d::Unit(c);
  }
  return g;
}

/// Converts `n` values of type T (native byte order) to float HU with value*slope + intercept.
template <typename T>
void convert_values(const T* in, std::size_t n, double slope, double intercept, std::vector<float>& out) {
  out.resize(n);
  if (slope == 1.0 && intercept == 0.0) {
    for (std::size_t i = 0; i < n; ++i) out[i] = float(in[i]);
  } else {
    for (std::size_t i = 0; i < n; ++i) out[i] = float(double(in[i]) * slope + intercept);
  }
}

std::vector<float> vtk_array_to_float(vtkDataArray* array, std::size_t n, double slope, double intercept) {
  std::vector<float> out;
  void* p = array->GetVoidPointer(0);
  switch (array->GetDataType()) {
    vtkTemplateMacro(convert_values(static_cast<const VTK_TT*>(p), n, slope, intercept, out));
    default:
      throw Error(fmt::format("unsupported voxel type '{}'", array->GetDataTypeAsString()));
  }
  return out;
}

/// Common checks on what a reader produced; also cleans a direction matrix that is
/// orthonormal up to the float precision of the file.
void finish_volume(Volume& v, const fs::path& path) {
  GridGeometry& g = v.geometry;
  if ((g.dims.array() <= 0).any() || v.hu.empty())
    throw Error(fmt::format("{} holds an empty volume ({}x{}x{} voxels); export the volume again", quoted(path),
                            g.dims.x(), g.dims.y(), g.dims.z()));
  if (std::int64_t(v.hu.size()) != g.voxel_count())
    throw Error(fmt::format("{}: read {} voxel values for {}x{}x{} voxels (corrupt file?)", quoted(path),
                            v.hu.size(), g.dims.x(), g.dims.y(), g.dims.z()));
  if (!g.spacing_mm.allFinite() || (g.spacing_mm.array() <= 0).any())
    throw Error(fmt::format("{}: voxel spacing ({}, {}, {}) mm is not positive; fix the header's spacing",
                            quoted(path), g.spacing_mm.x(), g.spacing_mm.y(), g.spacing_mm.z()));
  if (!g.origin_mm.allFinite() || !g.direction.allFinite())
    throw Error(quoted(path) + ": the origin or orientation in the header is not a finite number");
  if (!g.direction_is_orthonormal()) {
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(g.direction, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const Eigen::Matrix3d nearest = svd.matrixU() * svd.matrixV().transpose();
    const double deviation = (nearest - g.direction).cwiseAbs().maxCoeff();
    if (deviation > 1e-3)
      throw Error(fmt::format(
          "{}: the voxel axes are not perpendicular (sheared grid, deviation {:.3g}); voxelastic needs an "
          "orthogonal grid: resample the volume (e.g. in 3D Slicer) and try again",
          quoted(path), deviation));
    g.direction = nearest;
  }
  std::size_t bad = 0;
  for (float x : v.hu) bad += std::isfinite(x) ? 0 : 1;
  if (bad)
    throw Error(fmt::format("{} holds {} voxel values that are not finite numbers (NaN or infinity); replace "
                            "them (e.g. by -1000 HU) and try again",
                            quoted(path), bad));
}

/// Reverses the slice (k) order of `hu` in place.
void reverse_slices(std::vector<float>& hu, const Eigen::Vector3i& dims) {
  const std::size_t slice = std::size_t(dims.x()) * std::size_t(dims.y());
  for (int k = 0, m = dims.z() - 1; k < m; ++k, --m)
    std::swap_ranges(hu.begin() + std::ptrdiff_t(slice * k), hu.begin() + std::ptrdiff_t(slice * (k + 1)),
                     hu.begin() + std::ptrdiff_t(slice * m));
}

/// Scalar types of raw voxel data (NRRD, MetaImage).
enum class ScalarType { i8, u8, i16, u16, i32, u32, i64, u64, f32, f64 };

int scalar_bytes(ScalarType t) {
  switch (t) {
    case ScalarType::i8: case ScalarType::u8: return 1;
    case ScalarType::i16: case ScalarType::u16: return 2;
    case ScalarType::i32: case ScalarType::u32: case ScalarType::f32: return 4;
    case ScalarType::i64: case ScalarType::u64: case ScalarType::f64: return 8;
  }
  return 0;
}

template <typename T>
void convert_raw(const char* bytes, std::size_t n, bool swap, std::vector<float>& out) {
  out.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    unsigned char b[sizeof(T)];
    std::memcpy(b, bytes + i * sizeof(T), sizeof(T));
    if (swap) std::reverse(b, b + sizeof(T));
    T value;
    std::memcpy(&value, b, sizeof(T));
    out[i] = float(value);
  }
}

std::vector<float> raw_to_float(const char* bytes, std::size_t n, ScalarType t, bool swap) {
  std::vector<float> out;
  switch (t) {
    case ScalarType::i8: convert_raw<std::int8_t>(bytes, n, swap, out); break;
    case ScalarType::u8: convert_raw<std::uint8_t>(bytes, n, swap, out); break;
    case ScalarType::i16: convert_raw<std::int16_t>(bytes, n, swap, out); break;
    case ScalarType::u16: convert_raw<std::uint16_t>(bytes, n, swap, out); break;
    case ScalarType::i32: convert_raw<std::int32_t>(bytes, n, swap, out); break;
    case ScalarType::u32: convert_raw<std::uint32_t>(bytes, n, swap, out); break;
    case ScalarType::i64: convert_raw<std::int64_t>(bytes, n, swap, out); break;
    case ScalarType::u64: convert_raw<std::uint64_t>(bytes, n, swap, out); break;
    case ScalarType::f32: convert_raw<float>(bytes, n, swap, out); break;
    case ScalarType::f64: convert_raw<double>(bytes, n, swap, out); break;
  }
  return out;
}

/// zlib-compresses `data` (zlib format for MetaImage, gzip format for NRRD).
std::vector<unsigned char> deflate_bytes(const void* data, std::size_t size, bool gzip) {
  z_stream zs{};
  if (deflateInit2(&zs, 6, Z_DEFLATED, gzip ? 15 + 16 : 15, 8, Z_DEFAULT_STRATEGY) != Z_OK)
    throw Error("zlib: cannot start compression");
  std::vector<unsigned char> out(deflateBound(&zs, uLong(size)) + 64);
  zs.next_in = static_cast<Bytef*>(const_cast<void*>(data));
  zs.avail_in = uInt(size);
  zs.next_out = out.data();
  zs.avail_out = uInt(out.size());
  const int rc = deflate(&zs, Z_FINISH);
  const std::size_t produced = zs.total_out;
  deflateEnd(&zs);
  if (rc != Z_STREAM_END) throw Error("zlib: compression failed");
  out.resize(produced);
  return out;
}

/// Inflates a zlib or gzip stream that must give exactly `expected` bytes.
std::vector<char> inflate_bytes(const char* data, std::size_t size, std::size_t expected, const fs::path& path) {
  // deflate shrinks data at most ~1032:1: a header promising more is damaged
  if (double(expected) > 1100.0 * double(size) + 4096.0)
    throw Error(fmt::format("{}: {} bytes of compressed data cannot hold the {} bytes of voxels the header promises "
                            "(damaged header or cut-short file; copy or export it again)",
                            quoted(path), size, expected));
  std::vector<char> out(expected);
  z_stream zs{};
  if (inflateInit2(&zs, 15 + 32) != Z_OK) throw Error("zlib: cannot start decompression");
  std::size_t done_in = 0, done_out = 0;
  int rc = Z_OK;
  // feed in chunks: z_stream counters are 32-bit
  while (rc == Z_OK) {
    const std::size_t in_chunk = std::min<std::size_t>(size - done_in, 1u << 30);
    const std::size_t out_chunk = std::min<std::size_t>(expected - done_out, 1u << 30);
    zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data + done_in));
    zs.avail_in = uInt(in_chunk);
    zs.next_out = reinterpret_cast<Bytef*>(out.data() + done_out);
    zs.avail_out = uInt(out_chunk);
    rc = inflate(&zs, Z_NO_FLUSH);
    done_in += in_chunk - zs.avail_in;
    done_out += out_chunk - zs.avail_out;
    if (rc == Z_OK && in_chunk - zs.avail_in == 0 && out_chunk - zs.avail_out == 0) break;
    if (rc == Z_BUF_ERROR) break;
  }
  inflateEnd(&zs);
  if (done_out != expected || (rc != Z_STREAM_END && rc != Z_OK))
    throw Error(fmt::format("{}: compressed voxel data is damaged or cut short ({}; got {} of {} bytes); copy or "
                            "export the file again",
                            quoted(path), rc == Z_DATA_ERROR ? "invalid data" : "incomplete stream", done_out,
                            expected));
  return out;
}

// ---------------------------------------------------------------------------------------
// .vti

Volume read_vti(const fs::path& path) {
  VtkMessages messages;
  vtkNew<vtkXMLImageDataReader> reader;
  if (!reader->CanReadFile(path.c_str()))
    throw Error(quoted(path) + " is not a VTK XML image file (.vti): its header is missing or damaged; "
                               "export it again");
  reader->SetFileName(path.c_str());
  // the header first: a damaged one must not make VTK allocate terabytes
  reader->UpdateInformation();
  if (!messages.failed()) {
    int e[6] = {0, -1, 0, -1, 0, -1};
    reader->GetOutputInformation(0)->Get(vtkStreamingDemandDrivenPipeline::WHOLE_EXTENT(), e);
    (void)checked_voxel_count({e[1] - e[0] + 1, e[3] - e[2] + 1, e[5] - e[4] + 1}, path);
    reader->Update();
  }
  if (messages.failed() || reader->GetErrorCode() != vtkErrorCode::NoError)
    throw Error(fmt::format("cannot read {} as a VTK image (.vti): {} (the file is damaged or cut short; "
                            "export it again)",
                            quoted(path),
                            messages.failed() ? messages.errors()
                                              : vtkErrorCode::GetStringFromErrorCode(reader->GetErrorCode())));
  vtkImageData* image = reader->GetOutput();
  int extent[6];
  image->GetExtent(extent);
  const Eigen::Vector3i dims(extent[1] - extent[0] + 1, extent[3] - extent[2] + 1, extent[5] - extent[4] + 1);
  if ((dims.array() <= 0).any())
    throw Error(quoted(path) + " holds no voxels (empty extent); export the volume again");
  vtkPointData* pd = image->GetPointData();
  vtkDataArray* array = pd->GetScalars();
  if (!array && pd->GetNumberOfArrays() > 0) array = pd->GetArray(0);
  if (!array) {
    const bool cells = image->GetCellData() && image->GetCellData()->GetNumberOfArrays() > 0;
    throw Error(quoted(path) + " has no point-data array (voxel values)" +
                (cells ? std::string(" (it has cell data only: convert it with ParaView's 'Cell Data to Point "
                                     "Data', or save the image with point scalars)")
                       : std::string("; save the image with its scalars")));
  }
  if (array->GetNumberOfComponents() != 1)
    throw Error(fmt::format("{}: array '{}' has {} components per voxel; voxelastic needs one value (HU) per "
                            "voxel: extract one component (e.g. ParaView 'Extract Component') first",
                            quoted(path), array->GetName() ? array->GetName() : "", array->GetNumberOfComponents()));
  const std::size_t n = std::size_t(dims.x()) * std::size_t(dims.y()) * std::size_t(dims.z());
  if (std::size_t(array->GetNumberOfTuples()) != n)
    throw Error(fmt::format("{}: array has {} values for {} voxels (damaged file; export it again)", quoted(path),
                            array->GetNumberOfTuples(), n));
  Volume v;
  const double* sp = image->GetSpacing();
  const double* o = image->GetOrigin();
  Eigen::Matrix3d D;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) D(r, c) = image->GetDirectionMatrix()->GetElement(r, c);
  const Eigen::Vector3d spacing(sp[0], sp[1], sp[2]);
  // a negative spacing is a flipped axis
  Eigen::Matrix3d A = D * spacing.asDiagonal();
  const Eigen::Vector3d first(extent[0], extent[2], extent[4]);
  const Eigen::Vector3d t = Eigen::Vector3d(o[0], o[1], o[2]) + A * first;
  v.geometry = geometry_from_affine(dims, A, t);
  v.hu = vtk_array_to_float(array, n, 1.0, 0.0);
  messages.print_warnings(path);
  return v;
}

void write_vti(const Volume& v, const fs::path& tmp) {
  const GridGeometry& g = v.geometry;
  vtkNew<vtkImageData> image;
  image->SetDimensions(g.dims.x(), g.dims.y(), g.dims.z());
  image->SetSpacing(g.spacing_mm.x(), g.spacing_mm.y(), g.spacing_mm.z());
  image->SetOrigin(g.origin_mm.x(), g.origin_mm.y(), g.origin_mm.z());
  double d[9];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) d[3 * r + c] = g.direction(r, c);
  image->SetDirectionMatrix(d);
  const vtkIdType n = vtkIdType(v.hu.size());
  vtkSmartPointer<vtkDataArray> array;
  if (fits_int16(v.hu)) {
    auto a = vtkSmartPointer<vtkShortArray>::New();
    a->SetNumberOfValues(n);
    for (vtkIdType i = 0; i < n; ++i) a->SetValue(i, short(v.hu[std::size_t(i)]));
    array = a;
  } else {
    auto a = vtkSmartPointer<vtkFloatArray>::New();
    a->SetNumberOfValues(n);
    std::copy(v.hu.begin(), v.hu.end(), a->GetPointer(0));
    array = a;
  }
  array->SetName("HU");
  image->GetPointData()->SetScalars(array);

  VtkMessages messages;
  vtkNew<vtkXMLImageDataWriter> writer;
  writer->SetInputData(image);
  writer->SetFileName(tmp.c_str());
  writer->SetCompressorTypeToZLib();
  writer->SetDataModeToAppended();
  writer->EncodeAppendedDataOff();
  writer->SetHeaderTypeToUInt64();
  const int ok = writer->Write();
  if (!ok || messages.failed() || writer->GetErrorCode() != vtkErrorCode::NoError)
    throw Error("VTK image writer failed: " +
                (messages.failed() ? messages.errors()
                                   : std::string(vtkErrorCode::GetStringFromErrorCode(writer->GetErrorCode()))));
}

// ---------------------------------------------------------------------------------------
// MetaImage (.mha/.mhd)

struct MetaHeader {
  std::map<std::string, std::string> fields;  ///< key -> value, keys as written
  std::uintmax_t header_bytes{0};             ///< where LOCAL data starts
};

MetaHeader parse_meta_header(const fs::path& path) {
  const std::string text = read_file_prefix(path, 1 << 16);
  MetaHeader h;
  std::size_t pos = 0;
  bool saw_data_file = false;
  while (pos < text.size() && !saw_data_file) {
    std::size_t nl = text.find('\n', pos);
    const bool last = nl == std::string::npos;
    if (last) nl = text.size();
    const std::string line = trim(text.substr(pos, nl - pos));
    pos = last ? text.size() : nl + 1;
    if (line.empty()) continue;
    const auto eq = line.find('=');
    const std::string key = eq == std::string::npos ? "" : trim(line.substr(0, eq));
    const bool key_ok = !key.empty() && std::all_of(key.begin(), key.end(), [](char c) {
      return std::isalnum(static_cast<unsigned char>(c)) || c == '_';
    });
    if (!key_ok) {
      const bool text_line = std::all_of(line.begin(), line.end(), [](char c) {
        return std::isprint(static_cast<unsigned char>(c)) || c == '\t';
      });
      throw Error(fmt::format("{} is not a valid MetaImage file: {} (a MetaImage header is text like "
                              "'ObjectType = Image'; the file may be damaged or of another format)",
                              quoted(path),
                              text_line ? "line '" + line.substr(0, 40) + "' is not 'Key = Value'"
                                        : std::string("its header holds binary data, not 'Key = Value' lines")));
    }
    h.fields[key] = trim(line.substr(eq + 1));
    if (key == "ElementDataFile") saw_data_file = true;
  }
  if (!saw_data_file)
    throw Error(quoted(path) + " is not a valid MetaImage file: its header has no 'ElementDataFile' line (the "
                               "file is damaged or cut short)");
  h.header_bytes = pos;
  return h;
}

struct MetaType {
  const char* name;
  ScalarType type;
};
constexpr MetaType kMetaTypes[] = {
    {"MET_CHAR", ScalarType::i8},       {"MET_UCHAR", ScalarType::u8},  {"MET_SHORT", ScalarType::i16},
    {"MET_USHORT", ScalarType::u16},    {"MET_INT", ScalarType::i32},   {"MET_UINT", ScalarType::u32},
    {"MET_LONG", ScalarType::i32},      {"MET_ULONG", ScalarType::u32}, {"MET_LONG_LONG", ScalarType::i64},
    {"MET_ULONG_LONG", ScalarType::u64}, {"MET_FLOAT", ScalarType::f32}, {"MET_DOUBLE", ScalarType::f64}};

Volume read_mha(const fs::path& path) {
  const MetaHeader h = parse_meta_header(path);
  auto field = [&](std::initializer_list<const char*> keys) -> std::optional<std::string> {
    for (const char* k : keys)
      if (auto it = h.fields.find(k); it != h.fields.end()) return it->second;
    return std::nullopt;
  };
  auto numbers = [&](std::initializer_list<const char*> keys, std::size_t count,
                     const char* what) -> std::optional<std::vector<double>> {
    const auto s = field(keys);
    if (!s) return std::nullopt;
    const auto v = to_doubles(*s);
    if (!v || v->size() < count)
      throw Error(fmt::format("{}: MetaImage field {} = '{}' must hold {} numbers", quoted(path), what, *s, count));
    return v;
  };

  const auto ndims_v = numbers({"NDims"}, 1, "NDims");
  if (!ndims_v) throw Error(quoted(path) + ": MetaImage header has no NDims line (damaged file?)");
  const int ndims = int((*ndims_v)[0]);
  if (ndims != 2 && ndims != 3)
    throw Error(fmt::format("{}: MetaImage has NDims = {}; voxelastic reads 3D volumes (or one 2D slice)",
                            quoted(path), ndims));
  const auto dim_v = numbers({"DimSize"}, std::size_t(ndims), "DimSize");
  if (!dim_v) throw Error(quoted(path) + ": MetaImage header has no DimSize line (damaged file?)");
  Eigen::Vector3i dims(1, 1, 1);
  for (int i = 0; i < ndims; ++i) {
    const double d = (*dim_v)[std::size_t(i)];
    if (!(d >= 1 && d <= 1e6 && d == std::floor(d)))
      throw Error(fmt::format("{}: MetaImage DimSize '{}' is not a list of positive sizes (damaged header?)",
                              quoted(path), *field({"DimSize"})));
    dims[i] = int(d);
  }
  if (const auto ch = numbers({"ElementNumberOfChannels"}, 1, "ElementNumberOfChannels"); ch && (*ch)[0] != 1)
    throw Error(fmt::format("{}: MetaImage has {} channels per voxel; voxelastic needs one value (HU) per voxel: "
                            "extract one channel first",
                            quoted(path), (*ch)[0]));
  const auto type = field({"ElementType"});
  if (!type) throw Error(quoted(path) + ": MetaImage header has no ElementType line (damaged file?)");
  std::optional<ScalarType> scalar;
  for (const auto& t : kMetaTypes)
    if (*type == t.name) scalar = t.type;
  if (!scalar)
    throw Error(fmt::format("{}: MetaImage ElementType '{}' is not a scalar type voxelastic reads (use MET_SHORT, "
                            "MET_FLOAT, ...; vector types are not volumes of HU)",
                            quoted(path), *type));

  // geometry, in LPS (the MetaImage convention, as written by ITK and 3D Slicer)
  Eigen::Vector3d spacing(1, 1, 1), offset_mm(0, 0, 0);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  if (auto s = numbers({"ElementSpacing", "ElementSize"}, std::size_t(ndims), "ElementSpacing"))
    for (int i = 0; i < ndims; ++i) spacing[i] = (*s)[std::size_t(i)];
  if (auto o = numbers({"Offset", "Position", "Origin"}, std::size_t(ndims), "Offset"))
    for (int i = 0; i < ndims; ++i) offset_mm[i] = (*o)[std::size_t(i)];
  if (auto m = numbers({"TransformMatrix", "Rotation", "Orientation"}, std::size_t(ndims * ndims),
                       "TransformMatrix")) {
    // each group of NDims numbers is the direction of one index axis (ITK's convention)
    for (int axis = 0; axis < ndims; ++axis)
      for (int r = 0; r < ndims; ++r) D(r, axis) = (*m)[std::size_t(axis * ndims + r)];
  }
  if (ndims == 2) D.col(2) = D.col(0).cross(D.col(1));
  for (int i = 0; i < 3; ++i)
    if (spacing[i] == 0)
      throw Error(fmt::format("{}: MetaImage ElementSpacing is zero along axis {}; fix the header", quoted(path), i));
  const Eigen::Matrix3d A = D * spacing.asDiagonal();

  // the voxels: one data file (LOCAL or a named file), raw or zlib, is read here with every
  // size checked (metaio fills damaged compressed data with zeros and reports success);
  // data spread over several files (LIST, patterns) or stored as text goes to vtkMetaImageReader
  const std::string data_file = *field({"ElementDataFile"});
  const bool compressed = lower(field({"CompressedData"}).value_or("false")) == "true";
  const bool binary = lower(field({"BinaryData"}).value_or("true")) == "true";
  const bool msb = lower(field({"BinaryDataByteOrderMSB", "ElementByteOrderMSB"}).value_or("false")) == "true";
  const std::size_t n = checked_voxel_count(dims, path);
  const std::uintmax_t raw_bytes = std::uintmax_t(n) * std::uintmax_t(scalar_bytes(*scalar));
  const bool one_file = data_file.rfind("LIST", 0) != 0 && data_file.find('%') == std::string::npos &&
                        split_ws(data_file).size() == 1;
  if (binary && one_file) {
    fs::path data_path = path;
    std::uintmax_t offset = h.header_bytes;
    if (data_file != "LOCAL") {
      data_path = fs::path(data_file).is_absolute() ? fs::path(data_file) : path.parent_path() / data_file;
      std::error_code ec;
      if (!fs::is_regular_file(data_path, ec))
        throw Error(fmt::format("{}: its voxel data file {} does not exist (keep the .mhd header and its data file "
                                "together)",
                                quoted(path), quoted(data_path)));
      offset = 0;
      if (const auto hs = numbers({"HeaderSize"}, 1, "HeaderSize")) {
        if ((*hs)[0] >= 0) offset = std::uintmax_t((*hs)[0]);
        else if (!compressed && file_size_or_zero(data_path) >= raw_bytes)  // -1: the data ends the file
          offset = file_size_or_zero(data_path) - raw_bytes;
      }
    }
    const std::uintmax_t fsize = file_size_or_zero(data_path);
    const std::uintmax_t have = fsize > offset ? fsize - offset : 0;
    std::vector<char> raw;
    if (!compressed) {
      if (have < raw_bytes)
        throw Error(fmt::format("{} is truncated: the header promises {} bytes of voxel data, {} holds {} (copy or "
                                "export it again)",
                                quoted(path), raw_bytes, data_path == path ? "the file" : quoted(data_path), have));
      raw = read_file_bytes(data_path, offset, raw_bytes);
    } else {
      std::uintmax_t packed_bytes = have;
      if (const auto cs = numbers({"CompressedDataSize"}, 1, "CompressedDataSize")) {
        if (have < (*cs)[0])
          throw Error(fmt::format("{} is truncated: the header promises {} bytes of compressed voxel data, the "
                                  "file holds {} (copy or export it again)",
                                  quoted(path), (*cs)[0], have));
        packed_bytes = std::uintmax_t((*cs)[0]);
      }
      if (packed_bytes == 0) throw Error(quoted(path) + " is truncated: no voxel data after the header");
      const std::vector<char> packed = read_file_bytes(data_path, offset, packed_bytes);
      raw = inflate_bytes(packed.data(), packed.size(), std::size_t(raw_bytes), data_path);
    }
    Volume v;
    v.geometry = geometry_from_affine(dims, A, offset_mm);
    v.hu = raw_to_float(raw.data(), n, *scalar, msb != (std::endian::native == std::endian::big));
    return v;
  }

  VtkMessages messages;
  CerrCapture cerr_text;  // metaio reports on std::cerr
  vtkNew<vtkMetaImageReader> reader;
  reader->SetFileName(path.c_str());
  reader->Update();
  const std::string metaio_text = cerr_text.text();
  if (messages.failed() || reader->GetErrorCode() != vtkErrorCode::NoError)
    throw Error(fmt::format("cannot read the voxels of {}: {}{} (damaged file? export it again)", quoted(path),
                            messages.failed() ? messages.errors() : "read error",
                            metaio_text.empty() ? "" : " [" + metaio_text + "]"));
  vtkImageData* image = reader->GetOutput();
  int extent[6];
  image->GetExtent(extent);
  const Eigen::Vector3i got(extent[1] - extent[0] + 1, extent[3] - extent[2] + 1, extent[5] - extent[4] + 1);
  vtkDataArray* array = image->GetPointData()->GetScalars();
  if (got != dims || !array || std::size_t(array->GetNumberOfTuples()) != n)
    throw Error(fmt::format("cannot read the voxels of {}{}", quoted(path),
                            metaio_text.empty() ? "" : ": " + metaio_text));
  if (array->GetNumberOfComponents() != 1)
    throw Error(fmt::format("{}: {} values per voxel; voxelastic needs one (HU)", quoted(path),
                            array->GetNumberOfComponents()));
  Volume v;
  v.geometry = geometry_from_affine(dims, A, offset_mm);
  v.hu = vtk_array_to_float(array, n, 1.0, 0.0);
  messages.print_warnings(path);
  return v;
}

/// ITK's three-letter code for a direction matrix ("RAI" for the identity in LPS).
std::string meta_orientation_code(const Eigen::Matrix3d& D) {
  std::string code;
  for (int c = 0; c < 3; ++c) {
    Eigen::Index r = 0;
    D.col(c).cwiseAbs().maxCoeff(&r);
    const bool pos = D(r, c) > 0;
    code += r == 0 ? (pos ? 'R' : 'L') : r == 1 ? (pos ? 'A' : 'P') : (pos ? 'I' : 'S');
  }
  return code;
}

std::string format_numbers(std::initializer_list<double> values, const char* sep = " ") {
  std::string s;
  for (double v : values) s += (s.empty() ? "" : sep) + fmt::format("{}", v == 0.0 ? 0.0 : v);
  return s;
}

/// The voxels as int16 (`as_short`: every value integral and in range) or float32, deflated
/// (zlib stream, or gzip when `gzip`).
std::vector<unsigned char> deflate_voxels(const Volume& v, bool as_short, bool gzip) {
  if (!as_short) return deflate_bytes(v.hu.data(), v.hu.size() * 4, gzip);
  std::vector<std::int16_t> s(v.hu.size());
  for (std::size_t i = 0; i < s.size(); ++i) s[i] = std::int16_t(v.hu[i]);
  return deflate_bytes(s.data(), s.size() * 2, gzip);
}

void write_mha(const Volume& v, const fs::path& tmp) {
  const GridGeometry& g = v.geometry;
  const bool as_short = fits_int16(v.hu);
  const std::vector<unsigned char> packed = deflate_voxels(v, as_short, false);
  const Eigen::Matrix3d& D = g.direction;
  std::string header;
  header += "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n";
  header += "CompressedData = True\n";
  header += fmt::format("CompressedDataSize = {}\n", packed.size());
  // one group per index axis: its direction in LPS
  header += "TransformMatrix = " +
            format_numbers({D(0, 0), D(1, 0), D(2, 0), D(0, 1), D(1, 1), D(2, 1), D(0, 2), D(1, 2), D(2, 2)}) + "\n";
  header += "Offset = " + format_numbers({g.origin_mm.x(), g.origin_mm.y(), g.origin_mm.z()}) + "\n";
  header += "CenterOfRotation = 0 0 0\n";
  header += "AnatomicalOrientation = " + meta_orientation_code(D) + "\n";
  header += "ElementSpacing = " + format_numbers({g.spacing_mm.x(), g.spacing_mm.y(), g.spacing_mm.z()}) + "\n";
  header += fmt::format("DimSize = {} {} {}\n", g.dims.x(), g.dims.y(), g.dims.z());
  header += std::string("ElementType = ") + (as_short ? "MET_SHORT" : "MET_FLOAT") + "\n";
  header += "ElementDataFile = LOCAL\n";
  std::ofstream out(tmp, std::ios::binary);
  out.write(header.data(), std::streamsize(header.size()));
  out.write(reinterpret_cast<const char*>(packed.data()), std::streamsize(packed.size()));
  out.close();
  if (!out) throw Error("write error (disk full?)");
}

// ---------------------------------------------------------------------------------------
// NIfTI (.nii, .nii.gz): RAS on disk, LPS here.

const Eigen::Matrix3d kRasToLps = Eigen::Vector3d(-1, -1, 1).asDiagonal();

Volume read_nifti(const fs::path& path) {
  VtkMessages messages;
  vtkNew<vtkNIFTIImageReader> reader;
  if (!reader->CanReadFile(path.c_str()))
    throw Error(quoted(path) + " is not a NIfTI file: its 348-byte header is missing or damaged (export it "
                               "again; if it is gzip-compressed it must end in .nii.gz)");
  reader->SetFileName(path.c_str());
  // the header first: a damaged one must not make VTK allocate terabytes
  reader->UpdateInformation();
  if (!messages.failed()) {
    const int* e = reader->GetDataExtent();
    (void)checked_voxel_count({e[1] - e[0] + 1, e[3] - e[2] + 1, e[5] - e[4] + 1}, path);
    reader->Update();
  }
  if (messages.failed() || reader->GetErrorCode() != vtkErrorCode::NoError)
    throw Error(fmt::format("cannot read {} as NIfTI: {} (the file is damaged or cut short; export it again)",
                            quoted(path),
                            messages.failed() ? messages.errors()
                                              : vtkErrorCode::GetStringFromErrorCode(reader->GetErrorCode())));
  if (reader->GetTimeDimension() > 1)
    throw Error(fmt::format("{} is a 4D NIfTI with {} volumes; voxelastic reads one 3D volume: extract one "
                            "(e.g. 'fslroi in out 0 1') first",
                            quoted(path), reader->GetTimeDimension()));
  vtkImageData* image = reader->GetOutput();
  int extent[6];
  image->GetExtent(extent);
  const Eigen::Vector3i dims(extent[1] - extent[0] + 1, extent[3] - extent[2] + 1, extent[5] - extent[4] + 1);
  vtkDataArray* array = image->GetPointData()->GetScalars();
  if ((dims.array() <= 0).any() || !array)
    throw Error(quoted(path) + " holds no voxels (empty NIfTI image)");
  if (array->GetNumberOfComponents() != 1)
    throw Error(fmt::format("{}: {} values per voxel (vector, complex or RGB NIfTI); voxelastic needs one value "
                            "(HU) per voxel",
                            quoted(path), array->GetNumberOfComponents()));
  const std::size_t n = std::size_t(dims.prod());
  if (std::size_t(array->GetNumberOfTuples()) != n) throw Error(quoted(path) + ": voxel data incomplete");

  // the affine from VTK's (possibly slice-reversed) index to RAS: sform if present, else qform
  // (nibabel's order), else scaling only (NIfTI "method 1")
  vtkMatrix4x4* m = reader->GetSFormMatrix() ? reader->GetSFormMatrix() : reader->GetQFormMatrix();
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  if (m)
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) R(r, c) = m->GetElement(r, c);
      t[r] = m->GetElement(r, 3);
    }
  const double* sp = image->GetSpacing();
  Eigen::Matrix3d A = R * Eigen::Vector3d(sp[0], sp[1], sp[2]).asDiagonal();
  // spatial units: mm unless the header says metres or microns
  double unit_mm = 1.0;
  switch (reader->GetNIFTIHeader()->GetXYZTUnits() & 0x07) {
    case 1: unit_mm = 1000.0; break;  // NIFTI_UNITS_METER
    case 3: unit_mm = 0.001; break;   // NIFTI_UNITS_MICRON
    default: break;                   // NIFTI_UNITS_MM or unknown
  }
  A *= unit_mm;
  t *= unit_mm;

  Volume v;
  const double slope = reader->GetRescaleSlope(), intercept = reader->GetRescaleIntercept();
  const bool scaled = slope != 0.0 && std::isfinite(slope) && std::isfinite(intercept);
  v.hu = vtk_array_to_float(array, n, scaled ? slope : 1.0, scaled ? intercept : 0.0);
  if (reader->GetQFac() < 0) {
    // the reader reversed the slices (qfac = -1 or a left-handed sform); restore the file's order
    reverse_slices(v.hu, dims);
    t += A.col(2) * double(dims.z() - 1);
    A.col(2) = -A.col(2);
  }
  v.geometry = geometry_from_affine(dims, kRasToLps * A, kRasToLps * t);
  messages.print_warnings(path);
  return v;
}

void write_nifti(const Volume& v, const fs::path& tmp) {
  const GridGeometry& g = v.geometry;
  if (!g.direction_is_orthonormal())
    throw Error("NIfTI stores orientation as a rotation: the volume's direction matrix is not orthonormal");
  // NIfTI wants a rotation (det +1) in RAS; a left-handed grid is stored with qfac = -1: hand
  // VTK the slices reversed, and it reverses them back while writing.
  Eigen::Matrix3d R = kRasToLps * g.direction;  // LPS->RAS is the same flip
  Eigen::Vector3d t = kRasToLps * g.origin_mm;
  const bool left_handed = R.determinant() < 0;
  std::vector<float> values = v.hu;
  if (left_handed) {
    reverse_slices(values, g.dims);
    t += R.col(2) * g.spacing_mm.z() * double(g.dims.z() - 1);
    R.col(2) = -R.col(2);
  }
  vtkNew<vtkImageData> image;
  image->SetDimensions(g.dims.x(), g.dims.y(), g.dims.z());
  image->SetSpacing(g.spacing_mm.x(), g.spacing_mm.y(), g.spacing_mm.z());
  image->SetOrigin(0, 0, 0);
  const vtkIdType n = vtkIdType(values.size());
  vtkSmartPointer<vtkDataArray> array;
  if (fits_int16(values)) {
    auto a = vtkSmartPointer<vtkShortArray>::New();
    a->SetNumberOfValues(n);
    for (vtkIdType i = 0; i < n; ++i) a->SetValue(i, short(values[std::size_t(i)]));
    array = a;
  } else {
    auto a = vtkSmartPointer<vtkFloatArray>::New();
    a->SetNumberOfValues(n);
    std::copy(values.begin(), values.end(), a->GetPointer(0));
    array = a;
  }
  array->SetName("HU");
  image->GetPointData()->SetScalars(array);

  vtkNew<vtkMatrix4x4> m;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m->SetElement(r, c, R(r, c));
    m->SetElement(r, 3, t[r]);
  }
  vtkNew<vtkNIFTIImageHeader> header;
  header->SetXYZTUnits(2);  // NIFTI_UNITS_MM
  header->SetDescrip("voxelastic (HU)");
  VtkMessages messages;
  vtkNew<vtkNIFTIImageWriter> writer;
  writer->SetNIFTIVersion(1);
  writer->SetNIFTIHeader(header);
  writer->SetRescaleSlope(1.0);
  writer->SetRescaleIntercept(0.0);
  writer->SetQFac(left_handed ? -1.0 : 1.0);
  writer->SetQFormMatrix(m);
  writer->SetSFormMatrix(m);
  writer->SetInputData(image);
  writer->SetFileName(tmp.c_str());
  writer->Write();
  if (messages.failed() || writer->GetErrorCode() != vtkErrorCode::NoError)
    throw Error("NIfTI writer failed: " +
                (messages.failed() ? messages.errors()
                                   : std::string(vtkErrorCode::GetStringFromErrorCode(writer->GetErrorCode()))));
}

// ---------------------------------------------------------------------------------------
// NRRD (.nrrd, .nhdr)

std::optional<ScalarType> nrrd_type(const std::string& t) {
  static const std::map<std::string, ScalarType> names = {
      {"signed char", ScalarType::i8},         {"int8", ScalarType::i8},
      {"int8_t", ScalarType::i8},              {"uchar", ScalarType::u8},
      {"unsigned char", ScalarType::u8},       {"uint8", ScalarType::u8},
      {"uint8_t", ScalarType::u8},             {"short", ScalarType::i16},
      {"short int", ScalarType::i16},          {"signed short", ScalarType::i16},
      {"signed short int", ScalarType::i16},   {"int16", ScalarType::i16},
      {"int16_t", ScalarType::i16},            {"ushort", ScalarType::u16},
      {"unsigned short", ScalarType::u16},     {"unsigned short int", ScalarType::u16},
      {"uint16", ScalarType::u16},             {"uint16_t", ScalarType::u16},
      {"int", ScalarType::i32},                {"signed int", ScalarType::i32},
      {"int32", ScalarType::i32},              {"int32_t", ScalarType::i32},
      {"uint", ScalarType::u32},               {"unsigned int", ScalarType::u32},
      {"uint32", ScalarType::u32},             {"uint32_t", ScalarType::u32},
      {"longlong", ScalarType::i64},           {"long long", ScalarType::i64},
      {"long long int", ScalarType::i64},      {"signed long long", ScalarType::i64},
      {"signed long long int", ScalarType::i64}, {"int64", ScalarType::i64},
      {"int64_t", ScalarType::i64},            {"ulonglong", ScalarType::u64},
      {"unsigned long long", ScalarType::u64}, {"unsigned long long int", ScalarType::u64},
      {"uint64", ScalarType::u64},             {"uint64_t", ScalarType::u64},
      {"float", ScalarType::f32},              {"double", ScalarType::f64}};
  auto it = names.find(t);
  if (it == names.end()) return std::nullopt;
  return it->second;
}

/// "(1.5,0,0)" -> {1.5, 0, 0}; nullopt for "none" or a malformed vector.
std::optional<std::vector<double>> nrrd_vector(const std::string& s) {
  const std::string t = trim(s);
  if (t.size() < 2 || t.front() != '(' || t.back() != ')') return std::nullopt;
  std::vector<double> out;
  std::stringstream in(t.substr(1, t.size() - 2));
  for (std::string item; std::getline(in, item, ',');) {
    const auto v = to_double(item);
    if (!v) return std::nullopt;
    out.push_back(*v);
  }
  return out;
}

/// Splits "(a,b,c) none (d,e,f)" into its vectors and 'none's (spaces inside brackets allowed).
std::vector<std::string> nrrd_vector_list(const std::string& s) {
  std::vector<std::string> out;
  std::string cur;
  int depth = 0;
  for (char c : s) {
    if (c == '(') ++depth;
    if (c == ')') --depth;
    if (std::isspace(static_cast<unsigned char>(c)) && depth == 0) {
      if (!cur.empty()) out.push_back(cur);
      cur.clear();
    } else if (!std::isspace(static_cast<unsigned char>(c))) {
      cur += c;
    }
  }
  if (!cur.empty()) out.push_back(cur);
  return out;
}

Volume read_nrrd(const fs::path& path) {
  const std::string text = read_file_prefix(path, 1 << 20);
  if (text.rfind("NRRD000", 0) != 0)
    throw Error(quoted(path) + " is not a NRRD file: it does not start with the 'NRRD000x' magic line (damaged "
                               "file or another format)");
  std::map<std::string, std::string> f;
  std::size_t pos = text.find('\n');
  std::size_t data_start = std::string::npos;
  while (pos != std::string::npos && pos < text.size()) {
    ++pos;
    std::size_t nl = text.find('\n', pos);
    const bool last = nl == std::string::npos;
    std::string line = text.substr(pos, (last ? text.size() : nl) - pos);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) {
      data_start = last ? text.size() : nl + 1;
      break;
    }
    pos = last ? std::string::npos : nl;
    if (line[0] == '#') continue;
    if (line.find(":=") != std::string::npos) continue;  // key/value pairs: not needed
    const auto colon = line.find(": ");
    if (colon == std::string::npos)
      throw Error(fmt::format("{}: NRRD header line '{}' is not 'field: value' (damaged header?)", quoted(path),
                              line.substr(0, 60)));
    f[lower(line.substr(0, colon))] = trim(line.substr(colon + 2));
  }
  auto get = [&](std::initializer_list<const char*> keys) -> std::optional<std::string> {
    for (const char* k : keys)
      if (auto it = f.find(k); it != f.end()) return it->second;
    return std::nullopt;
  };
  auto need = [&](const char* key) -> std::string {
    auto v = get({key});
    if (!v) throw Error(fmt::format("{}: NRRD header has no '{}:' field (required)", quoted(path), key));
    return *v;
  };

  const auto type = nrrd_type(need("type"));
  if (!type)
    throw Error(fmt::format("{}: NRRD type '{}' is not a scalar type voxelastic reads", quoted(path), need("type")));
  const int ndim = std::atoi(need("dimension").c_str());
  const auto sizes_v = to_doubles(need("sizes"));
  if (ndim < 2 || ndim > 4 || !sizes_v || int(sizes_v->size()) != ndim)
    throw Error(fmt::format("{}: NRRD dimension {} with sizes '{}': voxelastic reads 3D volumes (or one 2D "
                            "slice)",
                            quoted(path), ndim, need("sizes")));
  std::vector<long long> sizes;
  for (double s : *sizes_v) {
    if (!(s >= 1 && s <= 1e7 && s == std::floor(s)))
      throw Error(fmt::format("{}: NRRD sizes '{}' must be positive integers", quoted(path), need("sizes")));
    sizes.push_back((long long)s);
  }

  // which axes are spatial: 'space directions' says none for the others, else 'kinds'
  std::vector<bool> spatial(std::size_t(ndim), true);
  std::vector<std::optional<std::vector<double>>> dirs(static_cast<std::size_t>(ndim));
  const auto space_dirs = get({"space directions"});
  if (space_dirs) {
    const auto items = nrrd_vector_list(*space_dirs);
    if (int(items.size()) != ndim)
      throw Error(fmt::format("{}: NRRD 'space directions' has {} entries for dimension {}", quoted(path),
                              items.size(), ndim));
    for (int a = 0; a < ndim; ++a) {
      if (items[std::size_t(a)] == "none") {
        spatial[std::size_t(a)] = false;
        continue;
      }
      dirs[std::size_t(a)] = nrrd_vector(items[std::size_t(a)]);
      if (!dirs[std::size_t(a)] || dirs[std::size_t(a)]->size() != 3)
        throw Error(fmt::format("{}: NRRD space direction '{}' is not a 3-vector like (1,0,0)", quoted(path),
                                items[std::size_t(a)]));
    }
  } else if (const auto kinds = get({"kinds"})) {
    const auto k = split_ws(*kinds);
    for (int a = 0; a < ndim && a < int(k.size()); ++a)
      spatial[std::size_t(a)] = k[std::size_t(a)] == "domain" || k[std::size_t(a)] == "space" ||
                                k[std::size_t(a)] == "???" || k[std::size_t(a)] == "none";
  }
  std::vector<int> axes;
  for (int a = 0; a < ndim; ++a) {
    if (spatial[std::size_t(a)]) {
      axes.push_back(a);
    } else if (sizes[std::size_t(a)] > 1) {
      throw Error(fmt::format("{}: NRRD axis {} holds {} values per voxel (vector, colour or time data); "
                              "voxelastic needs one value (HU) per voxel",
                              quoted(path), a, sizes[std::size_t(a)]));
    }
  }
  if (axes.size() < 2 || axes.size() > 3)
    throw Error(fmt::format("{}: NRRD has {} spatial axes; voxelastic reads 3D volumes", quoted(path), axes.size()));

  // space -> LPS
  Eigen::Matrix3d to_lps = Eigen::Matrix3d::Identity();
  if (const auto space = get({"space"})) {
    const std::string s = lower(*space);
    if (s == "left-posterior-superior" || s == "lps") {
    } else if (s == "right-anterior-superior" || s == "ras") {
      to_lps = kRasToLps;
    } else if (s == "left-anterior-superior" || s == "las") {
      to_lps = Eigen::Vector3d(1, -1, 1).asDiagonal();
    } else if (s == "scanner-xyz" || s == "3d-right-handed") {
      std::fprintf(stderr, "volume: warning: %s: NRRD space '%s' has no anatomical meaning; taken as LPS\n",
                   path.string().c_str(), space->c_str());
    } else {
      throw Error(fmt::format("{}: NRRD space '{}' is not supported (use left-posterior-superior, "
                              "right-anterior-superior or left-anterior-superior; time spaces are 4D data)",
                              quoted(path), *space));
    }
  }
  double unit_mm = 1.0;
  if (const auto units = get({"space units"})) {
    std::string u = units->substr(0, units->find(' '));
    u.erase(std::remove(u.begin(), u.end(), '"'), u.end());
    if (u == "m") unit_mm = 1000.0;
    else if (u == "cm") unit_mm = 10.0;
    else if (u == "um" || u == "micron") unit_mm = 0.001;
    else if (u != "mm" && !u.empty())
      throw Error(fmt::format("{}: NRRD space units '{}' are not a length unit voxelastic knows (mm, cm, m, um)",
                              quoted(path), u));
  }

  Eigen::Vector3i dims(1, 1, 1);
  Eigen::Matrix3d A = Eigen::Matrix3d::Identity();
  std::optional<std::vector<double>> spacings;
  if (const auto sp = get({"spacings"})) {
    std::vector<double> v;
    for (const auto& w : split_ws(*sp)) v.push_back(lower(w) == "nan" ? 1.0 : to_double(w).value_or(1.0));
    spacings = v;
  }
  for (std::size_t i = 0; i < axes.size(); ++i) {
    const int a = axes[i];
    dims[int(i)] = int(sizes[std::size_t(a)]);
    if (dirs[std::size_t(a)]) {
      const auto& d = *dirs[std::size_t(a)];
      A.col(int(i)) = to_lps * Eigen::Vector3d(d[0], d[1], d[2]) * unit_mm;
    } else {
      const double s = spacings && std::size_t(a) < spacings->size() ? (*spacings)[std::size_t(a)] : 1.0;
      A.col(int(i)) = Eigen::Vector3d::Unit(int(i)) * s * unit_mm;
    }
  }
  if (axes.size() == 2) A.col(2) = A.col(0).normalized().cross(A.col(1).normalized());
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  if (const auto so = get({"space origin"})) {
    const auto o = nrrd_vector(*so);
    if (!o || o->size() != 3)
      throw Error(fmt::format("{}: NRRD space origin '{}' is not a 3-vector like (0,0,0)", quoted(path), *so));
    origin = to_lps * Eigen::Vector3d((*o)[0], (*o)[1], (*o)[2]) * unit_mm;
  }

  // the voxel bytes
  std::string encoding = lower(get({"encoding"}).value_or("raw"));
  if (encoding == "gz") encoding = "gzip";
  if (encoding == "txt" || encoding == "text") encoding = "ascii";
  if (encoding != "raw" && encoding != "gzip" && encoding != "ascii")
    throw Error(fmt::format("{}: NRRD encoding '{}' is not supported (raw, gzip or ascii); re-save it with one "
                            "of those (e.g. 'unu save -e gzip')",
                            quoted(path), encoding));
  const std::size_t bytes = std::size_t(scalar_bytes(*type));
  const std::size_t n = checked_voxel_count(dims, path);
  const bool big = lower(get({"endian"}).value_or("little")) == "big";
  const bool swap = bytes > 1 && big != (std::endian::native == std::endian::big);
  fs::path data_path = path;
  std::uintmax_t offset = 0;
  if (const auto df = get({"data file", "datafile"})) {
    if (df->rfind("LIST", 0) == 0 || split_ws(*df).size() > 1)
      throw Error(fmt::format("{}: NRRD data split over several files ('{}') is not supported; save it as one "
                              ".nrrd file",
                              quoted(path), *df));
    data_path = fs::path(*df).is_absolute() ? fs::path(*df) : path.parent_path() / *df;
    std::error_code ec;
    if (!fs::is_regular_file(data_path, ec))
      throw Error(fmt::format("{}: its data file {} does not exist (keep the .nhdr and its data file together)",
                              quoted(path), quoted(data_path)));
  } else {
    if (data_start == std::string::npos)
      throw Error(quoted(path) + ": NRRD header does not end with a blank line and names no data file (a "
                                 "detached header needs 'data file: NAME')");
    offset = data_start;
  }
  const std::uintmax_t fsize = file_size_or_zero(data_path);
  if (const auto ls = get({"line skip", "lineskip"}); ls && std::atoll(ls->c_str()) > 0) {
    const std::string head = read_file_prefix(data_path, std::size_t(std::min<std::uintmax_t>(fsize, 1 << 24)));
    long long lines = std::atoll(ls->c_str());
    std::size_t p = std::size_t(offset);
    while (lines-- > 0) {
      p = head.find('\n', p);
      if (p == std::string::npos) throw Error(quoted(data_path) + ": fewer lines than NRRD 'line skip' asks for");
      ++p;
    }
    offset = p;
  }
  long long byte_skip = 0;
  if (const auto bs = get({"byte skip", "byteskip"})) byte_skip = std::atoll(bs->c_str());

  Volume v;
  if (encoding == "ascii") {
    std::ifstream in(data_path, std::ios::binary);
    in.seekg(std::streamoff(offset));
    v.hu.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      double x;
      if (!(in >> x))
        throw Error(fmt::format("{}: ASCII NRRD data ends after {} of {} values (truncated file?)",
                                quoted(data_path), i, n));
      v.hu[i] = float(x);
    }
  } else {
    const std::uintmax_t want = std::uintmax_t(n) * bytes;
    std::vector<char> raw;
    if (encoding == "raw") {
      if (byte_skip == -1) {
        if (fsize < want)
          throw Error(fmt::format("{} is truncated: {} bytes for {} bytes of voxel data", quoted(data_path), fsize,
                                  want));
        offset = fsize - want;
      } else {
        offset += std::uintmax_t(std::max(0LL, byte_skip));
      }
      if (fsize < offset + want)
        throw Error(fmt::format("{} is truncated: it holds {} bytes of voxel data, the header promises {} (copy or "
                                "export it again)",
                                quoted(data_path), fsize > offset ? fsize - offset : 0, want));
      raw = read_file_bytes(data_path, offset, want);
    } else {
      if (fsize <= offset) throw Error(quoted(data_path) + " is truncated: no voxel data after the NRRD header");
      const std::vector<char> packed = read_file_bytes(data_path, offset, fsize - offset);
      const std::size_t skip = std::size_t(std::max(0LL, byte_skip));
      raw = inflate_bytes(packed.data(), packed.size(), std::size_t(want) + skip, data_path);
      raw.erase(raw.begin(), raw.begin() + std::ptrdiff_t(skip));
    }
    v.hu = raw_to_float(raw.data(), n, *type, swap);
  }
  v.geometry = geometry_from_affine(dims, A, origin);
  return v;
}

void write_nrrd(const Volume& v, const fs::path& tmp) {
  const GridGeometry& g = v.geometry;
  const bool as_short = fits_int16(v.hu);
  const std::vector<unsigned char> packed = deflate_voxels(v, as_short, true);
  const Eigen::Matrix3d A = g.direction * g.spacing_mm.asDiagonal();
  auto vec = [](const Eigen::Vector3d& x) { return fmt::format("({})", format_numbers({x[0], x[1], x[2]}, ",")); };
  std::string header = "NRRD0004\n# written by voxelastic; values in HU, positions in LPS mm\n";
  header += std::string("type: ") + (as_short ? "short" : "float") + "\n";
  header += "dimension: 3\nspace: left-posterior-superior\n";
  header += fmt::format("sizes: {} {} {}\n", g.dims.x(), g.dims.y(), g.dims.z());
  header += "space directions: " + vec(A.col(0)) + " " + vec(A.col(1)) + " " + vec(A.col(2)) + "\n";
  header += "kinds: domain domain domain\n";
  header += std::string("endian: ") + (std::endian::native == std::endian::big ? "big" : "little") + "\n";
  header += "encoding: gzip\n";
  header += "space units: \"mm\" \"mm\" \"mm\"\n";
  header += "space origin: " + vec(g.origin_mm) + "\n\n";
  std::ofstream out(tmp, std::ios::binary);
  out.write(header.data(), std::streamsize(header.size()));
  out.write(reinterpret_cast<const char*>(packed.data()), std::streamsize(packed.size()));
  out.close();
  if (!out) throw Error("write error (disk full?)");
}

/// "dir/" -> "dir"
fs::path without_trailing_slash(const fs::path& path) {
  std::string s = path.string();
  while (s.size() > 1 && s.back() == '/') s.pop_back();
  return s;
}

}  // namespace

std::string volume_format(const fs::path& path) {
  const std::string s = path.string();
  if (s.empty()) return "";
  if (s.back() == '/') return "dicom";
  std::error_code ec;
  if (fs::is_directory(path, ec)) return "dicom";
  const std::string name = lower(path.filename().string());
  if (ends_with(name, ".vti")) return "vti";
  if (ends_with(name, ".mha") || ends_with(name, ".mhd")) return "mha";
  if (ends_with(name, ".nii") || ends_with(name, ".nii.gz")) return "nifti";
  if (ends_with(name, ".nrrd") || ends_with(name, ".nhdr")) return "nrrd";
  if (ends_with(name, ".dcm")) return "dicom";
  return "";
}

Volume read_volume(const fs::path& path, const ReadOptions& options) {
  const std::string format = volume_format(path);
  std::error_code ec;
  if (format == "dicom") {
    if (!fs::exists(without_trailing_slash(path), ec))
      throw Error("cannot read " + quoted(path) + ": no such folder or file (check the path)");
    return read_dicom_series({path}, options);
  }
  if (!fs::exists(path, ec))
    throw Error("cannot read " + quoted(path) + ": no such file (check the path and the current folder)");
  if (!fs::is_regular_file(path, ec))
    throw Error("cannot read " + quoted(path) + ": not a regular file");
  if (format.empty()) {
    // DICOM files often have no extension: recognise them by their magic
    if (dicom::has_dicm_magic(path)) return read_dicom_series({path}, options);
    throw Error(fmt::format("cannot read {}: unknown volume format '{}' (supported: {})", quoted(path),
                            path.extension().string(), kSupported));
  }
  if (file_size_or_zero(path) == 0) throw Error("cannot read " + quoted(path) + ": the file is empty");
  Volume v;
  if (format == "vti") v = read_vti(path);
  else if (format == "mha") v = read_mha(path);
  else if (format == "nifti") v = read_nifti(path);
  else v = read_nrrd(path);
  finish_volume(v, path);
  return v;
}

void write_volume(const Volume& volume, const fs::path& path) {
  const std::string format = volume_format(path);
  if (format == "dicom") {
    if (lower(path.filename().string()).ends_with(".dcm"))
      throw Error("cannot write " + quoted(path) + ": a DICOM series is a folder of files: give a folder path "
                                                   "ending in '/' (e.g. out/series/)");
    check_volume_for_writing(volume, path);
    write_dicom_series(volume, without_trailing_slash(path));
    return;
  }
  if (format.empty())
    throw Error(fmt::format("cannot write {}: unknown volume format '{}' (writable: {})", quoted(path),
                            path.extension().string(), kWritable));
  const std::string name = lower(path.filename().string());
  if (name.ends_with(".mhd"))
    throw Error("cannot write " + quoted(path) + ": .mhd needs a separate data file; write a single-file .mha "
                                                 "instead");
  if (name.ends_with(".nhdr"))
    throw Error("cannot write " + quoted(path) + ": .nhdr needs a separate data file; write a single-file .nrrd "
                                                 "instead");
  check_volume_for_writing(volume, path);
  write_atomically(path, [&](const fs::path& tmp) {
    if (format == "vti") write_vti(volume, tmp);
    else if (format == "mha") write_mha(volume, tmp);
    else if (format == "nifti") write_nifti(volume, tmp);
    else write_nrrd(volume, tmp);
  });
}

}  // namespace vx
