// MetaImage (.mha, .mhd). The header is parsed here (vtkMetaImageReader drops
// TransformMatrix); voxels in one file (LOCAL or a named file, raw or zlib) are read here with
// every size checked, because metaio turns damaged compressed data into zeros without an error;
// data split over several files (LIST, patterns) or stored as text goes through
// vtkMetaImageReader. Written here too (vtkMetaImageWriter drops the direction). Positions are
// LPS (the MetaImage convention, as written by ITK and 3D Slicer).
#include <fmt/format.h>
#include <vtkDataArray.h>
#include <vtkErrorCode.h>
#include <vtkImageData.h>
#include <vtkMetaImageReader.h>
#include <vtkNew.h>
#include <vtkPointData.h>

#include <Eigen/Dense>
#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <sstream>

#include "base/error.h"
#include "io/compression.h"
#include "io/volume_formats.h"
#include "util/text.h"

namespace vx::volume_formats {
namespace {
namespace fs = std::filesystem;

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

/// A MetaImage header: its fields (keys as written) and where LOCAL data starts.
struct MetaHeader {
  fs::path path;                   ///< the header file, for messages
  HeaderFields fields;             ///< key -> value
  std::uintmax_t header_bytes{0};  ///< where LOCAL data starts

  /// The numbers of the first of `keys` present (nullopt when none is); throws vx::Error when
  /// the field holds fewer than `count` numbers (`what` names it).
  [[nodiscard]] std::optional<std::vector<double>> numbers(std::initializer_list<const char*> keys, std::size_t count,
                                                           const char* what) const {
    const auto s = fields.get(keys);
    if (!s) return std::nullopt;
    const auto v = to_doubles(*s);
    if (!v || v->size() < count)
      throw Error(fmt::format("{}: MetaImage field {} = '{}' must hold {} numbers", quoted(path), what, *s, count));
    return v;
  }
};

MetaHeader parse_meta_header(const fs::path& path) {
  const std::string text = read_file_prefix(path, 1 << 16);
  MetaHeader h;
  h.path = path;
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
      const bool text_line = std::all_of(
          line.begin(), line.end(), [](char c) { return std::isprint(static_cast<unsigned char>(c)) || c == '\t'; });
      throw Error(
          fmt::format("{} is not a valid MetaImage file: {} (a MetaImage header is text like "
                      "'ObjectType = Image'; the file may be damaged or of another format)",
                      quoted(path),
                      text_line ? "line '" + line.substr(0, 40) + "' is not 'Key = Value'"
                                : std::string("its header holds binary data, not 'Key = Value' lines")));
    }
    // metaio reads a field that is written twice twice, in order, and allocates by the first
    // (NDims = -6 then NDims = 3: a loop for ever, found by fuzzing); no writer repeats a field
    if (!h.fields.values.emplace(key, trim(line.substr(eq + 1))).second)
      throw Error(
          fmt::format("{} is not a valid MetaImage file: its header has the field {} twice (the file is "
                      "damaged; keep one line per field)",
                      quoted(path), key));
    if (key == "ElementDataFile") saw_data_file = true;
  }
  if (!saw_data_file)
    throw Error(quoted(path) +
                " is not a valid MetaImage file: its header has no 'ElementDataFile' line (the "
                "file is damaged or cut short)");
  h.header_bytes = pos;
  return h;
}

struct MetaType {
  const char* name;
  ScalarType type;
};
constexpr MetaType kMetaTypes[] = {
    {"MET_CHAR", ScalarType::i8},        {"MET_UCHAR", ScalarType::u8},  {"MET_SHORT", ScalarType::i16},
    {"MET_USHORT", ScalarType::u16},     {"MET_INT", ScalarType::i32},   {"MET_UINT", ScalarType::u32},
    {"MET_LONG", ScalarType::i32},       {"MET_ULONG", ScalarType::u32}, {"MET_LONG_LONG", ScalarType::i64},
    {"MET_ULONG_LONG", ScalarType::u64}, {"MET_FLOAT", ScalarType::f32}, {"MET_DOUBLE", ScalarType::f64}};

/// What the header says about the voxels: their grid, type and place in LPS.
struct MetaImage {
  Eigen::Vector3i dims{1, 1, 1};
  ScalarType scalar{ScalarType::i16};
  Eigen::Matrix3d affine{Eigen::Matrix3d::Identity()};  ///< columns: one voxel step along each index axis, LPS mm
  Eigen::Vector3d offset_mm{0, 0, 0};                   ///< voxel 0, LPS mm
};

/// The grid and the voxel type, checked.
void read_grid_and_type(const MetaHeader& h, int& ndims, MetaImage& image) {
  const fs::path& path = h.path;
  const auto ndims_v = h.numbers({"NDims"}, 1, "NDims");
  if (!ndims_v) throw Error(quoted(path) + ": MetaImage header has no NDims line (damaged file?)");
  const double nd = (*ndims_v)[0];
  if (nd != 2 && nd != 3)
    throw Error(fmt::format("{}: MetaImage has NDims = {}; voxelastic reads 3D volumes (or one 2D slice)", quoted(path),
                            *h.fields.get({"NDims"})));
  ndims = int(nd);
  const auto dim_v = h.numbers({"DimSize"}, std::size_t(ndims), "DimSize");
  if (!dim_v) throw Error(quoted(path) + ": MetaImage header has no DimSize line (damaged file?)");
  for (int i = 0; i < ndims; ++i) {
    const double d = (*dim_v)[std::size_t(i)];
    if (!(d >= 1 && d <= 1e6 && d == std::floor(d)))
      throw Error(fmt::format("{}: MetaImage DimSize '{}' is not a list of positive sizes (damaged header?)",
                              quoted(path), *h.fields.get({"DimSize"})));
    image.dims[i] = int(d);
  }
  if (const auto ch = h.numbers({"ElementNumberOfChannels"}, 1, "ElementNumberOfChannels"); ch && (*ch)[0] != 1)
    throw Error(
        fmt::format("{}: MetaImage has {} channels per voxel; voxelastic needs one value (HU) per voxel: "
                    "extract one channel first",
                    quoted(path), (*ch)[0]));
  const auto type = h.fields.get({"ElementType"});
  if (!type) throw Error(quoted(path) + ": MetaImage header has no ElementType line (damaged file?)");
  std::optional<ScalarType> scalar;
  for (const auto& t : kMetaTypes)
    if (*type == t.name) scalar = t.type;
  if (!scalar)
    throw Error(
        fmt::format("{}: MetaImage ElementType '{}' is not a scalar type voxelastic reads (use MET_SHORT, "
                    "MET_FLOAT, ...; vector types are not volumes of HU)",
                    quoted(path), *type));
  image.scalar = *scalar;
}

/// The header's image: grid and type, then the geometry in LPS.
MetaImage read_meta_image(const MetaHeader& h) {
  MetaImage image;
  int ndims = 3;
  read_grid_and_type(h, ndims, image);
  Eigen::Vector3d spacing(1, 1, 1);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  if (auto s = h.numbers({"ElementSpacing", "ElementSize"}, std::size_t(ndims), "ElementSpacing"))
    for (int i = 0; i < ndims; ++i) spacing[i] = (*s)[std::size_t(i)];
  if (auto o = h.numbers({"Offset", "Position", "Origin"}, std::size_t(ndims), "Offset"))
    for (int i = 0; i < ndims; ++i) image.offset_mm[i] = (*o)[std::size_t(i)];
  if (auto m =
          h.numbers({"TransformMatrix", "Rotation", "Orientation"}, std::size_t(ndims * ndims), "TransformMatrix")) {
    // each group of NDims numbers is the direction of one index axis (ITK's convention)
    for (int axis = 0; axis < ndims; ++axis)
      for (int r = 0; r < ndims; ++r) D(r, axis) = (*m)[std::size_t(axis * ndims + r)];
  }
  if (ndims == 2) D.col(2) = D.col(0).cross(D.col(1));
  for (int i = 0; i < 3; ++i)
    if (spacing[i] == 0)
      throw Error(fmt::format("{}: MetaImage ElementSpacing is zero along axis {}; fix the header", quoted(h.path), i));
  image.affine = D * spacing.asDiagonal();
  return image;
}

/// The voxel bytes of one data file (LOCAL or named), raw or zlib, every size checked.
std::vector<char> read_one_file_voxels(const MetaHeader& h, const std::string& data_file, bool compressed,
                                       std::uintmax_t raw_bytes) {
  const fs::path& path = h.path;
  fs::path data_path = path;
  std::uintmax_t offset = h.header_bytes;
  if (data_file != "LOCAL") {
    data_path = fs::path(data_file).is_absolute() ? fs::path(data_file) : path.parent_path() / data_file;
    std::error_code ec;
    if (!fs::is_regular_file(data_path, ec))
      throw Error(
          fmt::format("{}: its voxel data file {} does not exist (keep the .mhd header and its data file "
                      "together)",
                      quoted(path), quoted(data_path)));
    offset = 0;
    if (const auto hs = h.numbers({"HeaderSize"}, 1, "HeaderSize")) {
      const double v = (*hs)[0];
      if (!(v == -1 || (v >= 0 && v == std::floor(v) && v < 1e15)))
        throw Error(
            fmt::format("{}: MetaImage HeaderSize = {} is not a byte count (a whole number >= 0, or -1 for "
                        "'the data ends the file')",
                        quoted(path), *h.fields.get({"HeaderSize"})));
      if (v >= 0)
        offset = std::uintmax_t(v);
      else if (!compressed && file_size_or_zero(data_path) >= raw_bytes)  // -1: the data ends the file
        offset = file_size_or_zero(data_path) - raw_bytes;
    }
  }
  const std::uintmax_t fsize = file_size_or_zero(data_path);
  const std::uintmax_t have = fsize > offset ? fsize - offset : 0;
  if (!compressed) {
    if (have < raw_bytes)
      throw Error(
          fmt::format("{} is truncated: the header promises {} bytes of voxel data, {} holds {} (copy or "
                      "export it again)",
                      quoted(path), raw_bytes, data_path == path ? "the file" : quoted(data_path), have));
    return read_file_bytes(data_path, offset, raw_bytes);
  }
  std::uintmax_t packed_bytes = have;
  if (const auto cs = h.numbers({"CompressedDataSize"}, 1, "CompressedDataSize")) {
    const double c = (*cs)[0];
    if (!(c >= 1 && c == std::floor(c)))
      throw Error(
          fmt::format("{}: MetaImage CompressedDataSize = {} is not a byte count (a whole number >= 1); fix "
                      "the header or leave the line out",
                      quoted(path), *h.fields.get({"CompressedDataSize"})));
    if (double(have) < c)
      throw Error(
          fmt::format("{} is truncated: the header promises {} bytes of compressed voxel data, the "
                      "file holds {} (copy or export it again)",
                      quoted(path), (*cs)[0], have));
    packed_bytes = std::uintmax_t((*cs)[0]);
  }
  if (packed_bytes == 0) throw Error(quoted(path) + " is truncated: no voxel data after the header");
  const std::vector<char> packed = read_file_bytes(data_path, offset, packed_bytes);
  return inflate_bytes(packed.data(), packed.size(), std::size_t(raw_bytes), data_path);
}

/// The voxels through vtkMetaImageReader (data spread over several files, or text).
std::vector<float> read_voxels_with_vtk(const fs::path& path, const Eigen::Vector3i& dims, std::size_t n,
                                        VtkMessages& messages) {
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
  vtkDataArray* array = image->GetPointData()->GetScalars();
  if (extent_dims(extent) != dims || !array || std::size_t(array->GetNumberOfTuples()) != n)
    throw Error(
        fmt::format("cannot read the voxels of {}{}", quoted(path), metaio_text.empty() ? "" : ": " + metaio_text));
  if (array->GetNumberOfComponents() != 1)
    throw Error(fmt::format("{}: {} values per voxel; voxelastic needs one (HU)", quoted(path),
                            array->GetNumberOfComponents()));
  return vtk_array_to_float(array, n, 1.0, 0.0);
}

/// ElementDataFile = LIST [2D|3D]: the lines after the header name one file per slice (or per
/// volume), which metaio reads line by line into fixed buffers (an empty line made it read before
/// its buffer: a SIGSEGV, found by fuzzing) and skips when missing. Each must be a short name of a
/// file that exists (`folder`: the header's, where relative names point).
void check_list_lines(const MetaHeader& h, const std::vector<std::string>& words, const Eigen::Vector3i& dims,
                      const fs::path& folder) {
  const int ndims = int((*h.numbers({"NDims"}, 1, "NDims"))[0]);
  int file_dims = words.size() == 2 ? words[1][0] - '0' : 0;  // metaio's rule
  if (file_dims == 0 || file_dims > ndims) file_dims = ndims - 1;
  std::size_t files = 1;
  for (int i = ndims; i > file_dims; --i) files *= std::size_t(dims[i - 1]);
  // a name per line, 1024 bytes at most as metaio reads them; never more than the file holds
  const std::string text = read_file_prefix(
      h.path, std::size_t(std::min<std::uintmax_t>(h.header_bytes + files * 1024 + 1, file_size_or_zero(h.path))));
  std::size_t pos = std::size_t(h.header_bytes);
  for (std::size_t f = 0; f < files; ++f) {
    const std::size_t nl = pos < text.size() ? text.find('\n', pos) : std::string::npos;
    const std::string name = nl == std::string::npos ? std::string() : trim(text.substr(pos, nl - pos));
    const bool printable =
        std::all_of(name.begin(), name.end(), [](char c) { return std::isprint(static_cast<unsigned char>(c)) != 0; });
    std::error_code ec;
    const fs::path file = fs::path(name).is_absolute() ? fs::path(name) : folder / name;
    std::string problem;
    if (nl == std::string::npos)
      problem = "is missing";
    else if (name.empty())
      problem = "is empty";
    else if (!printable || name.size() > 500)
      problem = "is not a file name";
    else if (!fs::is_regular_file(file, ec))
      problem = "names " + quoted(file) + ", which does not exist";
    if (!problem.empty())
      throw Error(
          fmt::format("{}: ElementDataFile = LIST needs {} file names, one per line after the header; "
                      "line {} of the list {} (the header is damaged or a file is missing)",
                      quoted(h.path), files, f + 1, problem));
    pos = nl + 1;
  }
}

/// What metaio (vtkMetaImageReader) gets to read is checked first: it copies header values into
/// fixed buffers (a long or binary ElementDataFile overflowed one, found by fuzzing) and
/// allocates the voxels before reading them. Values must be short printable text, and the
/// voxels must fit in what the header's folder holds (text: two characters a value at least;
/// compressed: deflate's ~1032:1 at most).
void check_before_metaio(const MetaHeader& h, const std::string& data_file, const Eigen::Vector3i& dims, bool binary,
                         bool compressed, std::size_t n, std::uintmax_t raw_bytes) {
  // metaio's inflate loops for ever on some damaged streams (found by fuzzing): compressed data
  // is read here only, from one file
  if (compressed)
    throw Error(
        fmt::format("{}: compressed voxel data spread over several files (ElementDataFile = {}) is not "
                    "supported; save the volume as one .mha (e.g. in 3D Slicer)",
                    quoted(h.path), data_file.substr(0, 60)));
  for (const auto& [key, value] : h.fields.values) {
    const bool text = std::all_of(value.begin(), value.end(),
                                  [](char c) { return std::isprint(static_cast<unsigned char>(c)) || c == '\t'; });
    if (!text || value.size() > 200)
      throw Error(fmt::format("{}: MetaImage field {} is {}; the header is damaged", quoted(h.path), key,
                              text ? "longer than 200 characters" : "not printable text"));
  }
  // ElementDataFile: one file, LIST [ND], or a pattern "name%03d.raw first last step" whose
  // numbers make one file per slice (metaio divides by the step: 0 was a SIGFPE, found by fuzzing)
  const std::vector<std::string> words = split_ws(data_file);
  const auto integer = [](const std::string& w, long& out) {
    char* end = nullptr;
    out = std::strtol(w.c_str(), &end, 10);
    return end != w.c_str() && *end == '\0' && std::abs(out) < 1000000;
  };
  // metaio takes any value that starts with LIST for a list ("LIST5c" too)
  const bool list = data_file.rfind("LIST", 0) == 0;
  bool form_ok = !list && words.size() == 1 && data_file.find('%') == std::string::npos;
  if (list)
    form_ok =
        words[0] == "LIST" && (words.size() == 1 || (words.size() == 2 && (words[1] == "2D" || words[1] == "3D")));
  if (words.size() == 4) {
    const auto pct = words[0].find('%');
    long first = 0, last = 0, step = 0;
    std::size_t k = pct == std::string::npos ? 0 : pct + 1;
    while (k < words[0].size() && std::isdigit(static_cast<unsigned char>(words[0][k]))) ++k;
    // a field width of two digits at most: metaio prints the name into a fixed buffer
    const bool one_conversion = pct != std::string::npos && k < words[0].size() && words[0][k] == 'd' &&
                                k - pct - 1 <= 2 && words[0].find('%', pct + 1) == std::string::npos;
    form_ok = one_conversion && integer(words[1], first) && integer(words[2], last) && integer(words[3], step) &&
              step != 0 && (last - first) / step >= 0 && (last - first) % step == 0 &&
              (last - first) / step + 1 <= 100000;
  }
  if (!form_ok)
    throw Error(
        fmt::format("{}: MetaImage ElementDataFile = {} is neither a file name, LOCAL, LIST nor a pattern "
                    "'name%03d.raw first last step' (step not 0); the header is damaged",
                    quoted(h.path), data_file.substr(0, 80)));
  const fs::path folder = h.path.has_parent_path() ? h.path.parent_path() : fs::path(".");
  if (list) check_list_lines(h, words, dims, folder);
  std::uintmax_t held = 0;
  std::error_code ec;
  for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec))
    if (it->is_regular_file(ec)) held += file_size_or_zero(it->path());
  const double needed = binary ? double(raw_bytes) : 2.0 * double(n);
  if (needed > (compressed ? 1100.0 : 1.0) * double(held) + 4096.0)
    throw Error(
        fmt::format("{}: the header promises {:.0f} bytes of voxels (ElementDataFile = {}), more than the "
                    "files beside it hold; the header is damaged or files are missing",
                    quoted(h.path), needed, data_file));
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

}  // namespace

Volume read_mha(const fs::path& path) {
  const MetaHeader h = parse_meta_header(path);
  const MetaImage image = read_meta_image(h);
  Volume v;
  v.geometry = geometry_from_affine(image.dims, image.affine, image.offset_mm);

  // the voxels: one data file (LOCAL or a named file), raw or zlib, is read here with every
  // size checked (metaio fills damaged compressed data with zeros and reports success);
  // data spread over several files (LIST, patterns) or stored as text goes to vtkMetaImageReader
  const std::string data_file = *h.fields.get({"ElementDataFile"});
  const bool compressed = lower(h.fields.get({"CompressedData"}).value_or("false")) == "true";
  const bool binary = lower(h.fields.get({"BinaryData"}).value_or("true")) == "true";
  const bool msb = lower(h.fields.get({"BinaryDataByteOrderMSB", "ElementByteOrderMSB"}).value_or("false")) == "true";
  const std::size_t n = checked_voxel_count(image.dims, path);
  const std::uintmax_t raw_bytes = std::uintmax_t(n) * std::uintmax_t(scalar_bytes(image.scalar));
  const bool one_file =
      data_file.rfind("LIST", 0) != 0 && data_file.find('%') == std::string::npos && split_ws(data_file).size() == 1;
  if (binary && one_file) {
    const std::vector<char> raw = read_one_file_voxels(h, data_file, compressed, raw_bytes);
    v.hu = raw_to_float(raw.data(), n, image.scalar, msb != (std::endian::native == std::endian::big));
    return v;
  }
  check_before_metaio(h, data_file, image.dims, binary, compressed, n, raw_bytes);
  VtkMessages messages;
  v.hu = read_voxels_with_vtk(path, image.dims, n, messages);
  messages.print_warnings(path);
  return v;
}

void write_mha(const Volume& v, const std::filesystem::path& tmp) {
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
  write_header_and_data(tmp, header, packed);
}

}  // namespace vx::volume_formats
