// NRRD (.nrrd with the data attached, .nhdr with a detached data file), read and written here:
// vtkNrrdReader (VTK 9.1) takes a first axis of 9 or fewer samples for vector components,
// ignores orientation and reads only the first slice of gzip data, so it cannot be trusted with
// CT volumes. Reads raw, gzip and ASCII encodings, either byte order, 'space directions' (or
// 'spacings'), 'space origin', the anatomical spaces LPS, RAS and LAS, and length units.
#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>

#include "base/error.h"
#include "io/compression.h"
#include "io/volume_formats.h"
#include "util/log.h"
#include "util/text.h"

namespace vx::volume_formats {
namespace {
namespace fs = std::filesystem;

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

/// A key/value pair's value with the format's escapes undone ("\\n" a line break, "\\\\" a backslash).
std::string unescape_nrrd_value(const std::string& v) {
  std::string out;
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (v[i] == '\\' && i + 1 < v.size() && (v[i + 1] == 'n' || v[i + 1] == '\\')) {
      out += v[i + 1] == 'n' ? '\n' : '\\';
      ++i;
    } else {
      out += v[i];
    }
  }
  return out;
}

/// A NRRD header: its fields (names in lower case) and where the attached data starts.
struct NrrdHeader {
  fs::path path;                              ///< the header file, for messages
  HeaderFields fields;                        ///< field -> value
  std::map<std::string, std::string> key_values;  ///< 'key:=value' pairs, keys as written
  std::size_t data_start{std::string::npos};  ///< byte after the blank line ending the header (npos: none)

  /// The value of a field the format requires; throws vx::Error when it is missing.
  [[nodiscard]] std::string need(const char* key) const {
    auto v = fields.get({key});
    if (!v) throw Error(fmt::format("{}: NRRD header has no '{}:' field (required)", quoted(path), key));
    return *v;
  }
};

/// The header of `path`: the magic line, then 'field: value' lines up to a blank line
/// (comments and key/value pairs skipped).
NrrdHeader parse_nrrd_header(const fs::path& path) {
  const std::string text = read_file_prefix(path, 1 << 20);
  if (text.rfind("NRRD000", 0) != 0)
    throw Error(quoted(path) + " is not a NRRD file: it does not start with the 'NRRD000x' magic line (damaged "
                               "file or another format)");
  NrrdHeader h;
  h.path = path;
  std::size_t pos = text.find('\n');
  while (pos != std::string::npos && pos < text.size()) {
    ++pos;
    std::size_t nl = text.find('\n', pos);
    const bool last = nl == std::string::npos;
    std::string line = text.substr(pos, (last ? text.size() : nl) - pos);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) {
      h.data_start = last ? text.size() : nl + 1;
      break;
    }
    pos = last ? std::string::npos : nl;
    if (line[0] == '#') continue;
    if (const auto kv = line.find(":="); kv != std::string::npos) {  // key/value pairs (Slicer's Segment<k>_...)
      h.key_values[line.substr(0, kv)] = unescape_nrrd_value(line.substr(kv + 2));
      continue;
    }
    const auto colon = line.find(": ");
    if (colon == std::string::npos)
      throw Error(fmt::format("{}: NRRD header line '{}' is not 'field: value' (damaged header?)", quoted(path),
                              line.substr(0, 60)));
    h.fields.values[lower(line.substr(0, colon))] = trim(line.substr(colon + 2));
  }
  return h;
}

/// The axes of the file: their sizes, which of them are spatial, and their directions.
struct NrrdAxes {
  std::vector<long long> sizes;  ///< per axis of the file
  long long layers{1};           ///< values per voxel along a first, non-spatial axis (when allowed)
  std::vector<int> spatial;      ///< the spatial axes (2 or 3), in file order
  std::vector<std::optional<std::vector<double>>> directions;  ///< per axis: 'space directions' (file space)
};

/// `allow_layers`: a first, non-spatial axis of any size is the layer axis (Slicer's layered
/// segmentation: kinds "list domain domain domain"); otherwise a non-spatial axis must hold one value.
NrrdAxes read_axes(const NrrdHeader& h, bool allow_layers = false) {
  const fs::path& path = h.path;
  NrrdAxes out;
  const int ndim = std::atoi(h.need("dimension").c_str());
  const auto sizes_v = to_doubles(h.need("sizes"));
  if (ndim < 2 || ndim > 4 || !sizes_v || int(sizes_v->size()) != ndim)
    throw Error(fmt::format("{}: NRRD dimension {} with sizes '{}': voxelastic reads 3D volumes (or one 2D "
                            "slice)",
                            quoted(path), ndim, h.need("sizes")));
  for (double s : *sizes_v) {
    if (!(s >= 1 && s <= 1e7 && s == std::floor(s)))
      throw Error(fmt::format("{}: NRRD sizes '{}' must be positive integers", quoted(path), h.need("sizes")));
    out.sizes.push_back((long long)s);
  }

  // which axes are spatial: 'space directions' says none for the others, else 'kinds'
  std::vector<bool> spatial(std::size_t(ndim), true);
  out.directions.resize(std::size_t(ndim));
  if (const auto space_dirs = h.fields.get({"space directions"})) {
    const auto items = nrrd_vector_list(*space_dirs);
    if (int(items.size()) != ndim)
      throw Error(fmt::format("{}: NRRD 'space directions' has {} entries for dimension {}", quoted(path),
                              items.size(), ndim));
    for (int a = 0; a < ndim; ++a) {
      if (items[std::size_t(a)] == "none") {
        spatial[std::size_t(a)] = false;
        continue;
      }
      out.directions[std::size_t(a)] = nrrd_vector(items[std::size_t(a)]);
      if (!out.directions[std::size_t(a)] || out.directions[std::size_t(a)]->size() != 3)
        throw Error(fmt::format("{}: NRRD space direction '{}' is not a 3-vector like (1,0,0)", quoted(path),
                                items[std::size_t(a)]));
    }
  } else if (const auto kinds = h.fields.get({"kinds"})) {
    const auto k = split_ws(*kinds);
    for (int a = 0; a < ndim && a < int(k.size()); ++a)
      spatial[std::size_t(a)] = k[std::size_t(a)] == "domain" || k[std::size_t(a)] == "space" ||
                                k[std::size_t(a)] == "???" || k[std::size_t(a)] == "none";
  }
  for (int a = 0; a < ndim; ++a) {
    if (spatial[std::size_t(a)]) {
      out.spatial.push_back(a);
    } else if (allow_layers && a == 0) {
      out.layers = out.sizes[0];
    } else if (out.sizes[std::size_t(a)] > 1) {
      throw Error(fmt::format("{}: NRRD axis {} holds {} values per voxel (vector, colour or time data); "
                              "voxelastic needs one value (HU) per voxel",
                              quoted(path), a, out.sizes[std::size_t(a)]));
    }
  }
  if (out.spatial.size() < 2 || out.spatial.size() > 3)
    throw Error(fmt::format("{}: NRRD has {} spatial axes; voxelastic reads 3D volumes", quoted(path),
                            out.spatial.size()));
  return out;
}

/// From the file's 'space' to LPS (identity when it names none).
Eigen::Matrix3d space_to_lps(const NrrdHeader& h) {
  const auto space = h.fields.get({"space"});
  if (!space) return Eigen::Matrix3d::Identity();
  const std::string s = lower(*space);
  if (s == "left-posterior-superior" || s == "lps") return Eigen::Matrix3d::Identity();
  if (s == "right-anterior-superior" || s == "ras") return kRasToLps;
  if (s == "left-anterior-superior" || s == "las") return Eigen::Vector3d(1, -1, 1).asDiagonal();
  if (s == "scanner-xyz" || s == "3d-right-handed") {
    log::warn("{}: NRRD space '{}' has no anatomical meaning; taken as LPS", h.path.string(), *space);
    return Eigen::Matrix3d::Identity();
  }
  throw Error(fmt::format("{}: NRRD space '{}' is not supported (use left-posterior-superior, "
                          "right-anterior-superior or left-anterior-superior; time spaces are 4D data)",
                          quoted(h.path), *space));
}

/// The length of the file's space unit in mm (1 when it names none).
double space_unit_mm(const NrrdHeader& h) {
  const auto units = h.fields.get({"space units"});
  if (!units) return 1.0;
  std::string u = units->substr(0, units->find(' '));
  u.erase(std::remove(u.begin(), u.end(), '"'), u.end());
  if (u == "m") return 1000.0;
  if (u == "cm") return 10.0;
  if (u == "um" || u == "micron") return 0.001;
  if (u != "mm" && !u.empty())
    throw Error(fmt::format("{}: NRRD space units '{}' are not a length unit voxelastic knows (mm, cm, m, um)",
                            quoted(h.path), u));
  return 1.0;
}

/// The grid in LPS mm: voxels per axis, one voxel step along each index axis, voxel 0.
struct NrrdGrid {
  Eigen::Vector3i dims{1, 1, 1};
  Eigen::Matrix3d affine{Eigen::Matrix3d::Identity()};
  Eigen::Vector3d origin_mm{0, 0, 0};
};

NrrdGrid read_grid(const NrrdHeader& h, const NrrdAxes& axes) {
  const Eigen::Matrix3d to_lps = space_to_lps(h);
  const double unit_mm = space_unit_mm(h);
  NrrdGrid g;
  std::optional<std::vector<double>> spacings;
  if (const auto sp = h.fields.get({"spacings"})) {
    std::vector<double> v;
    for (const auto& w : split_ws(*sp)) v.push_back(lower(w) == "nan" ? 1.0 : to_double(w).value_or(1.0));
    spacings = v;
  }
  for (std::size_t i = 0; i < axes.spatial.size(); ++i) {
    const int a = axes.spatial[i];
    g.dims[int(i)] = int(axes.sizes[std::size_t(a)]);
    if (axes.directions[std::size_t(a)]) {
      const auto& d = *axes.directions[std::size_t(a)];
      g.affine.col(int(i)) = to_lps * Eigen::Vector3d(d[0], d[1], d[2]) * unit_mm;
    } else {
      const double s = spacings && std::size_t(a) < spacings->size() ? (*spacings)[std::size_t(a)] : 1.0;
      g.affine.col(int(i)) = Eigen::Vector3d::Unit(int(i)) * s * unit_mm;
    }
  }
  if (axes.spatial.size() == 2) g.affine.col(2) = g.affine.col(0).normalized().cross(g.affine.col(1).normalized());
  if (const auto so = h.fields.get({"space origin"})) {
    const auto o = nrrd_vector(*so);
    if (!o || o->size() != 3)
      throw Error(fmt::format("{}: NRRD space origin '{}' is not a 3-vector like (0,0,0)", quoted(h.path), *so));
    g.origin_mm = to_lps * Eigen::Vector3d((*o)[0], (*o)[1], (*o)[2]) * unit_mm;
  }
  return g;
}

/// The file holding the voxel bytes and the byte they start at (after 'line skip', before
/// 'byte skip'): the header file itself after its blank line, or its 'data file'.
std::pair<fs::path, std::uintmax_t> locate_data(const NrrdHeader& h) {
  const fs::path& path = h.path;
  fs::path data_path = path;
  std::uintmax_t offset = 0;
  if (const auto df = h.fields.get({"data file", "datafile"})) {
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
    if (h.data_start == std::string::npos)
      throw Error(quoted(path) + ": NRRD header does not end with a blank line and names no data file (a "
                                 "detached header needs 'data file: NAME')");
    offset = h.data_start;
  }
  if (const auto ls = h.fields.get({"line skip", "lineskip"}); ls && std::atoll(ls->c_str()) > 0) {
    const std::uintmax_t fsize = file_size_or_zero(data_path);
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
  return {data_path, offset};
}

/// `n` values written as text.
std::vector<float> read_ascii_values(const fs::path& data_path, std::uintmax_t offset, std::size_t n) {
  std::ifstream in(data_path, std::ios::binary);
  in.seekg(std::streamoff(offset));
  std::vector<float> hu(n);
  for (std::size_t i = 0; i < n; ++i) {
    double x;
    if (!(in >> x))
      throw Error(fmt::format("{}: ASCII NRRD data ends after {} of {} values (truncated file?)", quoted(data_path),
                              i, n));
    hu[i] = float(x);
  }
  return hu;
}

/// The voxels of a `dims` grid of `type` (`layers` values per voxel, the layer fastest), in any
/// of the encodings.
std::vector<float> read_voxels(const NrrdHeader& h, ScalarType type, const Eigen::Vector3i& dims,
                               long long layers = 1) {
  std::string encoding = lower(h.fields.get({"encoding"}).value_or("raw"));
  if (encoding == "gz") encoding = "gzip";
  if (encoding == "txt" || encoding == "text") encoding = "ascii";
  if (encoding != "raw" && encoding != "gzip" && encoding != "ascii")
    throw Error(fmt::format("{}: NRRD encoding '{}' is not supported (raw, gzip or ascii); re-save it with one "
                            "of those (e.g. 'unu save -e gzip')",
                            quoted(h.path), encoding));
  const std::size_t bytes = std::size_t(scalar_bytes(type));
  const std::size_t n = checked_voxel_count(Eigen::Vector3i(dims.x(), dims.y(), int(dims.z() * layers)), h.path);
  const bool big = lower(h.fields.get({"endian"}).value_or("little")) == "big";
  const bool swap = bytes > 1 && big != (std::endian::native == std::endian::big);
  auto [data_path, offset] = locate_data(h);
  const std::uintmax_t fsize = file_size_or_zero(data_path);
  long long byte_skip = 0;
  if (const auto bs = h.fields.get({"byte skip", "byteskip"})) byte_skip = std::atoll(bs->c_str());
  if (encoding == "ascii") return read_ascii_values(data_path, offset, n);

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
  return raw_to_float(raw.data(), n, type, swap);
}

}  // namespace

Volume read_nrrd(const fs::path& path) {
  const NrrdHeader h = parse_nrrd_header(path);
  const auto type = nrrd_type(h.need("type"));
  if (!type)
    throw Error(fmt::format("{}: NRRD type '{}' is not a scalar type voxelastic reads", quoted(path), h.need("type")));
  const NrrdAxes axes = read_axes(h);
  const NrrdGrid grid = read_grid(h, axes);
  Volume v;
  v.hu = read_voxels(h, *type, grid.dims);
  v.geometry = geometry_from_affine(grid.dims, grid.affine, grid.origin_mm);
  return v;
}

NrrdLayers read_nrrd_layers(const fs::path& path) {
  const NrrdHeader h = parse_nrrd_header(path);
  const auto type = nrrd_type(h.need("type"));
  if (!type)
    throw Error(fmt::format("{}: NRRD type '{}' is not a scalar type voxelastic reads", quoted(path), h.need("type")));
  const NrrdAxes axes = read_axes(h, true);
  if (axes.layers > kMaxNrrdLayers)
    throw Error(fmt::format("{}: NRRD first axis of {} values is not a segmentation's layers (at most {})",
                            quoted(path), axes.layers, kMaxNrrdLayers));
  const NrrdGrid grid = read_grid(h, axes);
  const std::vector<float> values = read_voxels(h, *type, grid.dims, axes.layers);
  NrrdLayers out;
  out.geometry = geometry_from_affine(grid.dims, grid.affine, grid.origin_mm);
  out.key_values = h.key_values;
  // the layer is the fastest axis of the file: one volume per layer
  const std::size_t n = std::size_t(out.geometry.voxel_count()), layers = std::size_t(axes.layers);
  out.layers.assign(layers, std::vector<float>(n));
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t l = 0; l < layers; ++l) out.layers[l][i] = values[i * layers + l];
  return out;
}

void write_nrrd_labels(const GridGeometry& g, const std::vector<std::uint8_t>& labels,
                       const std::vector<std::pair<std::string, std::string>>& key_values, const fs::path& tmp) {
  const std::vector<unsigned char> packed = deflate_bytes(labels.data(), labels.size(), true);
  const Eigen::Matrix3d A = g.direction * g.spacing_mm.asDiagonal();
  auto vec = [](const Eigen::Vector3d& x) { return fmt::format("({})", format_numbers({x[0], x[1], x[2]}, ",")); };
  std::string header = "NRRD0004\n# written by voxelastic; labels, positions in LPS mm\n";
  header += "type: unsigned char\ndimension: 3\nspace: left-posterior-superior\n";
  header += fmt::format("sizes: {} {} {}\n", g.dims.x(), g.dims.y(), g.dims.z());
  header += "space directions: " + vec(A.col(0)) + " " + vec(A.col(1)) + " " + vec(A.col(2)) + "\n";
  header += "kinds: domain domain domain\nencoding: gzip\n";
  header += "space units: \"mm\" \"mm\" \"mm\"\n";
  header += "space origin: " + vec(g.origin_mm) + "\n";
  for (const auto& [key, value] : key_values) {
    std::string escaped;
    for (char c : value)
      escaped += c == '\n' ? std::string("\\n") : c == '\\' ? std::string("\\\\") : std::string(1, c);
    header += key + ":=" + escaped + "\n";
  }
  header += "\n";
  write_header_and_data(tmp, header, packed);
}

void write_nrrd(const Volume& v, const std::filesystem::path& tmp) {
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
  write_header_and_data(tmp, header, packed);
}

}  // namespace vx::volume_formats
