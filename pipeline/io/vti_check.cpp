// What vtkXMLImageDataReader (VTK 9.1) will read, checked before it reads it: it trusts the
// file's header, and a reversed extent (SIGSEGV in ReadSubExtent), a block header of the wrong
// width (header_type UInt32 on 64-bit blocks: a block size of 0, SIGFPE in ReadCompressedData)
// or byte order (sizes byte-swapped into terabytes: std::bad_alloc) crash it or exhaust memory.
// Here every extent is checked and every data array's block header is decoded and checked
// against the bytes the array needs and the bytes the file holds.
#include "io/vti_check.h"

#include <fmt/format.h>
#include <vtkXMLDataElement.h>
#include <vtkXMLDataParser.h>
#include <vtkXMLImageDataReader.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "base/error.h"
#include "io/volume_formats.h"
#include "util/text.h"

namespace vx::volume_formats {
namespace {
namespace fs = std::filesystem;

[[noreturn]] void damaged(const fs::path& path, const std::string& what) {
  throw Error(fmt::format("cannot read {} as a VTK image (.vti): {} (the file is damaged or was written by a "
                          "broken exporter; export it again)",
                          quoted(path), what));
}

/// Six integers of an extent attribute ("i0 i1 j0 j1 k0 k1"), each pair in order.
std::array<long long, 6> read_extent(vtkXMLDataElement* e, const char* name, const fs::path& path) {
  const char* text = e->GetAttribute(name);
  if (!text) damaged(path, fmt::format("<{}> has no {} attribute", e->GetName(), name));
  std::istringstream in(text);
  std::array<long long, 6> x{};
  for (auto& v : x)
    if (!(in >> v)) damaged(path, fmt::format("{}=\"{}\" is not six integers", name, text));
  std::string rest;
  if (in >> rest) damaged(path, fmt::format("{}=\"{}\" is not six integers", name, text));
  for (int a = 0; a < 3; ++a) {
    if (x[2 * a + 1] < x[2 * a])
      damaged(path, fmt::format("{}=\"{}\" is reversed along axis {} ({} > {}): an extent runs from its first to its "
                                "last index",
                                name, text, "xyz"[a], x[2 * a], x[2 * a + 1]));
    if (std::llabs(x[2 * a]) > (1LL << 30) || std::llabs(x[2 * a + 1]) > (1LL << 30))
      damaged(path, fmt::format("{}=\"{}\" holds indices beyond 2^30", name, text));
  }
  return x;
}

/// Bytes per value of a VTK XML type name, 0 when unknown.
int type_bytes(const std::string& t) {
  if (t == "Int8" || t == "UInt8" || t == "Char" || t == "UnsignedChar") return 1;
  if (t == "Int16" || t == "UInt16" || t == "Short" || t == "UnsignedShort") return 2;
  if (t == "Int32" || t == "UInt32" || t == "Float32" || t == "Int" || t == "UnsignedInt" || t == "Float") return 4;
  if (t == "Int64" || t == "UInt64" || t == "Float64" || t == "Double" || t == "IdType" || t == "Long" ||
      t == "UnsignedLong" || t == "LongLong" || t == "UnsignedLongLong")
    return 8;
  return 0;
}

/// Reads the bytes of one array's data as they are stored: raw at a file position, or
/// base64 text (skipping white space) from a file position.
class DataSource {
 public:
  DataSource(const fs::path& path, std::uintmax_t position, bool base64, std::uintmax_t file_size)
      : path_(path), position_(position), base64_(base64), file_size_(file_size) {}

  /// The first `n` decoded bytes, nullopt when the file ends before.
  [[nodiscard]] std::optional<std::vector<unsigned char>> bytes(std::size_t n) const {
    std::ifstream in(path_, std::ios::binary);
    if (!in) return std::nullopt;
    in.seekg(std::streamoff(position_));
    std::vector<unsigned char> out;
    out.reserve(n);
    if (!base64_) {
      out.resize(n);
      in.read(reinterpret_cast<char*>(out.data()), std::streamsize(n));
      if (std::size_t(in.gcount()) != n) return std::nullopt;
      return out;
    }
    // base64: groups of 4 characters give 3 bytes; white space between characters is skipped
    std::uint32_t group = 0;
    int have = 0, pad = 0;
    while (out.size() < n) {
      const int c = in.get();
      if (c == EOF) return std::nullopt;
      if (c == ' ' || c == '\n' || c == '\r' || c == '\t') continue;
      int v = 0;
      if (c >= 'A' && c <= 'Z') v = c - 'A';
      else if (c >= 'a' && c <= 'z') v = c - 'a' + 26;
      else if (c >= '0' && c <= '9') v = c - '0' + 52;
      else if (c == '+') v = 62;
      else if (c == '/') v = 63;
      else if (c == '=') v = 0, ++pad;
      else return std::nullopt;
      group = (group << 6) | std::uint32_t(v);
      if (++have == 4) {
        const unsigned char b[3] = {static_cast<unsigned char>(group >> 16), static_cast<unsigned char>(group >> 8),
                                    static_cast<unsigned char>(group)};
        for (int i = 0; i < 3 - pad && out.size() < n; ++i) out.push_back(b[i]);
        group = 0, have = 0, pad = 0;
      }
    }
    return out;
  }
  /// Stored bytes left in the file from the data's start (for base64, the bytes they decode to, at most).
  [[nodiscard]] std::uintmax_t available() const {
    const std::uintmax_t left = file_size_ > position_ ? file_size_ - position_ : 0;
    return base64_ ? left / 4 * 3 + 3 : left;
  }

 private:
  fs::path path_;
  std::uintmax_t position_;
  bool base64_;
  std::uintmax_t file_size_;
};

/// Where the parser found an element's inline data (vtkXMLDataElement keeps it protected; a
/// member pointer taken in a derived class reads it without pretending the element is one).
struct InlinePosition : vtkXMLDataElement {
  static vtkTypeInt64 of(vtkXMLDataElement* e) {
    vtkTypeInt64 (vtkXMLDataElement::*get)() = &InlinePosition::GetInlineDataPosition;
    return (e->*get)();
  }
};

/// The layout every array of the file shares (VTKFile attributes).
struct Layout {
  int header_bytes{4};  ///< header_type UInt32 (the default) or UInt64
  bool swap{false};     ///< byte_order differs from this machine's
  bool compressed{false};
};

/// Unsigned integer `i` of `width` bytes from `b`, byte order as the file says.
std::uint64_t word(const std::vector<unsigned char>& b, std::size_t i, const Layout& l) {
  unsigned char w[8] = {};
  std::memcpy(w, b.data() + i * std::size_t(l.header_bytes), std::size_t(l.header_bytes));
  if (l.swap) std::reverse(w, w + l.header_bytes);
  std::uint64_t v = 0;
  if (l.header_bytes == 4) {
    std::uint32_t v32 = 0;
    std::memcpy(&v32, w, 4);
    v = v32;
  } else {
    std::memcpy(&v, w, 8);
  }
  return v;
}

/// Checks the block header of one array that needs `needed` bytes.
void check_blocks(const DataSource& src, const Layout& l, double needed, const std::string& name,
                  const fs::path& path) {
  const std::size_t hb = std::size_t(l.header_bytes);
  const char* width_hint = l.header_bytes == 4 ? " (is header_type=\"UInt32\" right? 64-bit block headers need "
                                                 "header_type=\"UInt64\")"
                                               : "";
  if (!l.compressed) {
    const auto head = src.bytes(hb);
    if (!head) damaged(path, fmt::format("the data of array '{}' is cut short", name));
    const double size = double(word(*head, 0, l));
    if (size < needed)
      damaged(path, fmt::format("array '{}' holds {:.0f} bytes but its extent needs {:.0f}{}", name, size, needed,
                                width_hint));
    if (size + double(hb) > double(src.available()))
      damaged(path, fmt::format("array '{}' declares {:.0f} bytes but the file holds only {} after it (cut short, or "
                                "a wrong byte_order/header_type)",
                                name, size, src.available()));
    return;
  }
  const auto head = src.bytes(3 * hb);
  if (!head) damaged(path, fmt::format("the compressed data of array '{}' is cut short", name));
  const std::uint64_t blocks = word(*head, 0, l), block = word(*head, 1, l), last = word(*head, 2, l);
  if (double(blocks) * double(hb) > double(src.available()))
    damaged(path, fmt::format("array '{}' declares {} compressed blocks, more than the file can hold (a wrong "
                              "byte_order or header_type?)",
                              name, blocks));
  if (blocks == 0) {
    if (needed > 0) damaged(path, fmt::format("array '{}' has no compressed blocks but needs {:.0f} bytes", name, needed));
    return;
  }
  if (block == 0)
    damaged(path, fmt::format("array '{}' declares compressed blocks of 0 bytes{}", name, width_hint));
  if (last > block)
    damaged(path, fmt::format("array '{}': its last block ({} bytes) is larger than a block ({} bytes){}", name, last,
                              block, width_hint));
  const double total = double(blocks - 1) * double(block) + double(last == 0 ? block : last);
  if (total < needed)
    damaged(path, fmt::format("array '{}' holds {:.0f} bytes but its extent needs {:.0f}{}", name, total, needed,
                              width_hint));
  if (total > needed + double(block))
    damaged(path, fmt::format("array '{}' declares {:.0f} bytes, far more than the {:.0f} its extent needs{}", name,
                              total, needed, width_hint));
  const auto sizes = src.bytes(std::size_t(3 + blocks) * hb);
  if (!sizes) damaged(path, fmt::format("the block sizes of array '{}' are cut short", name));
  double packed = 0;
  for (std::uint64_t b = 0; b < blocks; ++b) {
    const double s = double(word(*sizes, std::size_t(3 + b), l));
    // a deflated block is at most ~1/1032 of its data: a smaller one cannot hold it
    const double raw = b + 1 == blocks && last ? double(last) : double(block);
    if (s * 1100.0 + 4096.0 < raw)
      damaged(path, fmt::format("array '{}': block {} of {:.0f} compressed bytes cannot hold {:.0f} bytes", name, b,
                                s, raw));
    packed += s;
  }
  if (packed + double(3 + blocks) * double(hb) > double(src.available()))
    damaged(path, fmt::format("array '{}' declares {:.0f} compressed bytes but the file holds only {} after it (cut "
                              "short?)",
                              name, packed, src.available()));
}

}  // namespace

void check_vti_before_reading(vtkXMLImageDataReader& reader, const fs::path& path) {
  vtkXMLDataParser* parser = reader.GetXMLParser();
  vtkXMLDataElement* root = parser ? parser->GetRootElement() : nullptr;
  if (!root) damaged(path, "its XML could not be parsed");
  Layout l;
  const std::string header_type = root->GetAttribute("header_type") ? root->GetAttribute("header_type") : "UInt32";
  if (header_type == "UInt64") l.header_bytes = 8;
  else if (header_type != "UInt32") damaged(path, "header_type=\"" + header_type + "\" is neither UInt32 nor UInt64");
  const std::string order = root->GetAttribute("byte_order") ? root->GetAttribute("byte_order") : "";
  if (order != "LittleEndian" && order != "BigEndian")
    damaged(path, "byte_order=\"" + order + "\" is neither LittleEndian nor BigEndian");
  l.swap = (order == "BigEndian") != (std::endian::native == std::endian::big);
  const char* compressor = root->GetAttribute("compressor");
  l.compressed = compressor && *compressor;
  if (l.compressed && std::string(compressor) != "vtkZLibDataCompressor" &&
      std::string(compressor) != "vtkLZ4DataCompressor" && std::string(compressor) != "vtkLZMADataCompressor")
    damaged(path, fmt::format("unknown compressor \"{}\"", compressor));

  vtkXMLDataElement* image = root->FindNestedElementWithName("ImageData");
  if (!image) damaged(path, "it has no <ImageData> element");
  const auto whole = read_extent(image, "WholeExtent", path);
  const Eigen::Vector3i whole_dims(int(whole[1] - whole[0] + 1), int(whole[3] - whole[2] + 1), int(whole[5] - whole[4] + 1));
  (void)checked_voxel_count(whole_dims, path);

  // appended data: where it starts and how it is stored
  vtkXMLDataElement* appended = root->FindNestedElementWithName("AppendedData");
  const bool appended_base64 =
      appended && appended->GetAttribute("encoding") && std::string(appended->GetAttribute("encoding")) == "base64";
  const std::uintmax_t file_size = file_size_or_zero(path);

  // one data array of `tuples` tuples: its declared size and block header against the file
  const auto check_array = [&](vtkXMLDataElement* array, double tuples) {
    // VTK reads both element names: a DataArray, and an Array (vtkAbstractArray) of the same layout
    if (const std::string tag = array->GetName(); tag != "DataArray" && tag != "Array") return;
    const std::string name = array->GetAttribute("Name") ? array->GetAttribute("Name") : "(unnamed)";
    const std::string type = array->GetAttribute("type") ? array->GetAttribute("type") : "";
    const int bytes = type_bytes(type);
    if (bytes == 0 && type != "String" && type != "Bit")
      damaged(path, fmt::format("array '{}' has unknown type \"{}\"", name, type));
    if (bytes == 0) return;  // strings and bits: not voxel values, VTK checks them itself
    int components = 1;
    if (const char* c = array->GetAttribute("NumberOfComponents")) {
      char* end = nullptr;
      const long v = std::strtol(c, &end, 10);
      if (end == c || *end || v < 1 || v > 64)
        damaged(path, fmt::format("array '{}' has NumberOfComponents=\"{}\"", name, c));
      components = int(v);
    }
    const double needed = tuples * components * bytes;
    const std::string format = array->GetAttribute("format") ? array->GetAttribute("format") : "";
    if (format == "ascii") {
      // parsed number by number, but into an array VTK allocates first: at least one
      // character and a separator per value must be in the file
      if (tuples * components * 2 > double(file_size) + 2)
        damaged(path, fmt::format("array '{}' needs {:.0f} values but the file is {} bytes long", name,
                                  tuples * components, file_size));
      return;
    }
    if (format == "appended") {
      if (!appended) damaged(path, fmt::format("array '{}' is appended but the file has no <AppendedData>", name));
      const char* off = array->GetAttribute("offset");
      char* end = nullptr;
      const long long offset = off ? std::strtoll(off, &end, 10) : -1;
      if (!off || end == off || *end || offset < 0)
        damaged(path, fmt::format("array '{}' has no valid offset (\"{}\")", name, off ? off : ""));
      const vtkTypeInt64 start = parser->GetAppendedDataPosition();
      if (start <= 0 || std::uintmax_t(start) > file_size)
        damaged(path, "the appended data section has no start marker '_'");
      // offsets count stored bytes (base64 characters when encoded)
      const std::uintmax_t at = std::uintmax_t(start) + std::uintmax_t(offset);
      if (at >= file_size)
        damaged(path, fmt::format("array '{}' starts at offset {}, beyond the end of the file", name, offset));
      check_blocks(DataSource(path, at, appended_base64, file_size), l, needed, name, path);
    } else if (format == "binary") {
      const vtkTypeInt64 at = InlinePosition::of(array);
      if (at <= 0 || std::uintmax_t(at) >= file_size) damaged(path, fmt::format("array '{}' has no inline data", name));
      check_blocks(DataSource(path, std::uintmax_t(at), true, file_size), l, needed, name, path);
    } else {
      damaged(path, fmt::format("array '{}' has format=\"{}\" (ascii, binary or appended)", name, format));
    }
  };

  // arrays of the image's field data (VTK reads them too): NumberOfTuples says their size
  for (int f = 0; f < image->GetNumberOfNestedElements(); ++f) {
    vtkXMLDataElement* set = image->GetNestedElement(f);
    if (std::string(set->GetName()) != "FieldData") continue;
    for (int d = 0; d < set->GetNumberOfNestedElements(); ++d) {
      vtkXMLDataElement* array = set->GetNestedElement(d);
      const char* n = array->GetAttribute("NumberOfTuples");
      if (!n) continue;  // VTK reads no tuples without it
      char* end = nullptr;
      const double tuples = std::strtod(n, &end);
      if (end == n || *end || !(tuples >= 0) || tuples > 1e12)
        damaged(path, fmt::format("a field data array has NumberOfTuples=\"{}\"", n));
      check_array(array, tuples);
    }
  }

  for (int p = 0; p < image->GetNumberOfNestedElements(); ++p) {
    vtkXMLDataElement* piece = image->GetNestedElement(p);
    if (std::string(piece->GetName()) != "Piece") continue;
    const auto ext = read_extent(piece, "Extent", path);
    for (int a = 0; a < 3; ++a)
      if (ext[2 * a] < whole[2 * a] || ext[2 * a + 1] > whole[2 * a + 1])
        damaged(path, fmt::format("piece {} (Extent=\"{}\") reaches outside WholeExtent", p, piece->GetAttribute("Extent")));
    double points = 1, cells = 1;
    for (int a = 0; a < 3; ++a) {
      const double n = double(ext[2 * a + 1] - ext[2 * a] + 1);
      points *= n;
      cells *= std::max(1.0, n - 1);
    }
    for (int s = 0; s < piece->GetNumberOfNestedElements(); ++s) {
      vtkXMLDataElement* set = piece->GetNestedElement(s);
      const std::string set_name = set->GetName();
      if (set_name != "PointData" && set_name != "CellData") continue;
      const double tuples = set_name == "PointData" ? points : cells;
      for (int d = 0; d < set->GetNumberOfNestedElements(); ++d) check_array(set->GetNestedElement(d), tuples);
    }
  }
}

}  // namespace vx::volume_formats
