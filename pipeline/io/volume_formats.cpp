#include "io/volume_formats.h"

#include <fmt/format.h>
#include <vtkAlgorithm.h>
#include <vtkDataArray.h>
#include <vtkErrorCode.h>
#include <vtkFloatArray.h>
#include <vtkShortArray.h>
#include <vtkType.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "base/error.h"
#include "io/compression.h"
#include "util/log.h"
#include "util/text.h"

namespace vx::volume_formats {
namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------
// header text

std::optional<std::string> HeaderFields::get(std::initializer_list<const char*> keys) const {
  for (const char* k : keys)
    if (auto it = values.find(k); it != values.end()) return it->second;
  return std::nullopt;
}

std::vector<std::string> split_ws(const std::string& s) {
  std::istringstream in(s);
  std::vector<std::string> out;
  for (std::string w; in >> w;) out.push_back(w);
  return out;
}

std::optional<double> to_double(const std::string& text) {
  const std::string s = trim(text);
  if (s.empty()) return std::nullopt;
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size()) return std::nullopt;
  return v;
}

std::optional<std::vector<double>> to_doubles(const std::string& s) {
  std::vector<double> out;
  for (const auto& w : split_ws(s)) {
    const auto v = to_double(w);
    if (!v) return std::nullopt;
    out.push_back(*v);
  }
  return out;
}

std::string format_numbers(std::initializer_list<double> values, const char* sep) {
  std::string s;
  for (double v : values) s += (s.empty() ? "" : sep) + fmt::format("{}", v == 0.0 ? 0.0 : v);
  return s;
}

// ---------------------------------------------------------------------------------------
// files

std::uintmax_t file_size_or_zero(const std::filesystem::path& path) {
  std::error_code ec;
  const auto n = fs::file_size(path, ec);
  return ec ? 0 : n;
}

std::size_t checked_voxel_count(const Eigen::Vector3i& dims, const std::filesystem::path& path) {
  if ((dims.array() <= 0).any())
    throw Error(fmt::format("{}: the header describes an empty or reversed grid of {}x{}x{} voxels; the header is "
                            "damaged (export the volume again)",
                            quoted(path), dims.x(), dims.y(), dims.z()));
  const double n = double(dims.x()) * double(dims.y()) * double(dims.z());
  constexpr double kMaxVoxels = 8.0e9;  // 32 GB of float HU
  if (n > kMaxVoxels)
    throw Error(fmt::format("{}: the header describes {}x{}x{} = {:.3g} voxels, more than voxelastic handles ({:.0e}); "
                            "the header is damaged, or crop/downsample the volume first",
                            quoted(path), dims.x(), dims.y(), dims.z(), n, kMaxVoxels));
  return std::size_t(n);
}

std::string read_file_prefix(const std::filesystem::path& path, std::size_t max_bytes) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open " + quoted(path) + " for reading (check its permissions)");
  std::string s(max_bytes, '\0');
  in.read(s.data(), std::streamsize(max_bytes));
  s.resize(std::size_t(in.gcount()));
  return s;
}

std::vector<char> read_file_bytes(const std::filesystem::path& path, std::uintmax_t offset, std::uintmax_t count) {
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

void write_header_and_data(const std::filesystem::path& tmp, const std::string& header,
                           const std::vector<unsigned char>& data) {
  std::ofstream out(tmp, std::ios::binary);
  out.write(header.data(), std::streamsize(header.size()));
  out.write(reinterpret_cast<const char*>(data.data()), std::streamsize(data.size()));
  out.close();
  if (!out) throw Error("write error (disk full?)");
}

// ---------------------------------------------------------------------------------------
// voxels and geometry

bool fits_int16(const std::vector<float>& hu) {
  for (float v : hu)
    if (!(v >= -32768.0f && v <= 32767.0f) || v != std::nearbyint(v)) return false;
  return true;
}

std::vector<unsigned char> deflate_voxels(const Volume& v, bool as_short, bool gzip) {
  if (!as_short) return deflate_bytes(v.hu.data(), v.hu.size() * 4, gzip);
  std::vector<std::int16_t> s(v.hu.size());
  for (std::size_t i = 0; i < s.size(); ++i) s[i] = std::int16_t(v.hu[i]);
  return deflate_bytes(s.data(), s.size() * 2, gzip);
}

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

namespace {

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

}  // namespace

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

vtkSmartPointer<vtkDataArray> hu_array(const std::vector<float>& hu) {
  const vtkIdType n = vtkIdType(hu.size());
  vtkSmartPointer<vtkDataArray> array;
  if (fits_int16(hu)) {
    auto a = vtkSmartPointer<vtkShortArray>::New();
    a->SetNumberOfValues(n);
    for (vtkIdType i = 0; i < n; ++i) a->SetValue(i, short(hu[std::size_t(i)]));
    array = a;
  } else {
    auto a = vtkSmartPointer<vtkFloatArray>::New();
    a->SetNumberOfValues(n);
    std::copy(hu.begin(), hu.end(), a->GetPointer(0));
    array = a;
  }
  array->SetName("HU");
  return array;
}

void reverse_slices(std::vector<float>& hu, const Eigen::Vector3i& dims) {
  const std::size_t slice = std::size_t(dims.x()) * std::size_t(dims.y());
  for (int k = 0, m = dims.z() - 1; k < m; ++k, --m)
    std::swap_ranges(hu.begin() + std::ptrdiff_t(slice * k), hu.begin() + std::ptrdiff_t(slice * (k + 1)),
                     hu.begin() + std::ptrdiff_t(slice * m));
}

// ---------------------------------------------------------------------------------------
// VTK messages: errors become vx::Error, nothing is printed by VTK itself

std::string VtkMessages::errors() const {
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

std::string VtkMessages::reason(unsigned long error_code) const {
  return failed() ? errors() : std::string(vtkErrorCode::GetStringFromErrorCode(error_code));
}

void read_header_then_data(vtkAlgorithm& reader, const std::function<Eigen::Vector3i()>& header_dims,
                           const VtkMessages& messages, const fs::path& path, const char* what,
                           const std::function<void()>& before_data) {
  reader.UpdateInformation();
  if (!messages.failed()) {
    if (before_data) before_data();
    (void)checked_voxel_count(header_dims(), path);
    reader.Update();
  }
  if (messages.failed() || reader.GetErrorCode() != vtkErrorCode::NoError)
    throw Error(fmt::format("cannot read {} as {}: {} (the file is damaged or cut short; export it again)", quoted(path),
                            what, messages.reason(reader.GetErrorCode())));
}

void VtkMessages::print_warnings(const std::filesystem::path& path) const {
  std::vector<std::string> seen;
  for (const auto& w : capture_.warnings()) {
    const std::string line = trim(w.substr(0, w.find('\n')));
    if (line.empty() || std::find(seen.begin(), seen.end(), line) != seen.end()) continue;
    seen.push_back(line);
    log::warn("{}: {}", path.string(), line);
  }
}

// ---------------------------------------------------------------------------------------
// what a reader produced

void finish_volume(Volume& v, const fs::path& path) {
  GridGeometry& g = v.geometry;
  if ((g.dims.array() <= 0).any() || v.hu.empty())
    throw Error(fmt::format("{} holds an empty volume ({}x{}x{} voxels); export the volume again", quoted(path),
                            g.dims.x(), g.dims.y(), g.dims.z()));
  if (std::int64_t(v.hu.size()) != g.voxel_count())
    throw Error(fmt::format("{}: read {} voxel values for {}x{}x{} voxels (corrupt file?)", quoted(path), v.hu.size(),
                            g.dims.x(), g.dims.y(), g.dims.z()));
  if (!g.spacing_mm.allFinite() || (g.spacing_mm.array() <= 0).any())
    throw Error(fmt::format("{}: voxel spacing ({}, {}, {}) mm is not positive; fix the header's spacing", quoted(path),
                            g.spacing_mm.x(), g.spacing_mm.y(), g.spacing_mm.z()));
  if (!g.origin_mm.allFinite() || !g.direction.allFinite())
    throw Error(quoted(path) + ": the origin or orientation in the header is not a finite number");
  if (!g.direction_is_orthonormal()) {
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(g.direction, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const Eigen::Matrix3d nearest = svd.matrixU() * svd.matrixV().transpose();
    const double deviation = (nearest - g.direction).cwiseAbs().maxCoeff();
    if (deviation > 1e-3)
      throw Error(
          fmt::format("{}: the voxel axes are not perpendicular (sheared grid, deviation {:.3g}); voxelastic needs an "
                      "orthogonal grid: resample the volume (e.g. in 3D Slicer) and try again",
                      quoted(path), deviation));
    g.direction = nearest;
  }
  std::size_t bad = 0;
  for (float x : v.hu) bad += std::isfinite(x) ? 0 : 1;
  if (bad)
    throw Error(
        fmt::format("{} holds {} voxel values that are not finite numbers (NaN or infinity); replace "
                    "them (e.g. by -1000 HU) and try again",
                    quoted(path), bad));
}

}  // namespace vx::volume_formats
