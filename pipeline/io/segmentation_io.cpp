// 3D Slicer segmentations (.seg.nrrd): the NRRD itself is read and written by nrrd_io.cpp
// (its layer axis and key/value pairs included); here the Segment<k>_ fields become segments.
#include "io/segmentation_io.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <optional>
#include <utility>

#include "base/error.h"
#include "io/volume_formats.h"
#include "util/atomic_file.h"
#include "util/text.h"

namespace vx {
namespace {
namespace fs = std::filesystem;

/// The whole of `text` as an integer; nullopt when it is not one.
std::optional<long long> to_integer(const std::string& text) {
  const std::string t = trim(text);
  if (t.empty()) return std::nullopt;
  char* end = nullptr;
  const long long v = std::strtoll(t.c_str(), &end, 10);
  if (end != t.c_str() + t.size()) return std::nullopt;
  return v;
}

/// Segment `k`'s fields from the key/value pairs; nullopt when the file has no segment `k`.
std::optional<Segment> read_segment(const std::map<std::string, std::string>& kv, int k, std::size_t layers,
                                    const fs::path& path) {
  const std::string prefix = fmt::format("Segment{}_", k);
  const auto field = [&](const char* name) -> std::optional<std::string> {
    const auto it = kv.find(prefix + name);
    return it == kv.end() ? std::nullopt : std::optional<std::string>(it->second);
  };
  if (!field("ID") && !field("Name")) return std::nullopt;
  Segment s;
  s.id = field("ID").value_or(field("Name").value_or(""));
  s.name = field("Name").value_or(s.id);
  // Slicer 4.10 and older wrote neither: a 3D file's segment k is label k+1, a 4D file's is layer k
  const bool layered = layers > 1;
  s.label_value = layered ? 1 : k + 1;
  s.layer = layered ? k : 0;
  if (const auto v = field("LabelValue")) {
    const auto n = to_integer(*v);
    if (!n || *n < 1 || *n > 65535)
      throw Error(
          fmt::format("{}: {}LabelValue '{}' is not a label (a whole number from 1)", quoted(path), prefix, *v));
    s.label_value = int(*n);
  }
  if (const auto v = field("Layer")) {
    const auto n = to_integer(*v);
    if (!n || *n < 0) throw Error(fmt::format("{}: {}Layer '{}' is not a layer number", quoted(path), prefix, *v));
    s.layer = int(*n);
  }
  if (std::size_t(s.layer) >= layers)
    throw Error(fmt::format("{}: segment '{}' is in layer {}, but the file holds {} layer{} (damaged header?)",
                            quoted(path), s.name, s.layer, layers, layers == 1 ? "" : "s"));
  if (const auto v = field("Color")) {
    const auto rgb = volume_formats::to_doubles(*v);
    if (rgb && rgb->size() == 3) s.color = Eigen::Vector3d((*rgb)[0], (*rgb)[1], (*rgb)[2]);
  }
  return s;
}

/// "i0 i1 j0 j1 k0 k1": the bounding box of the non-zero voxels, inclusive ("0 -1 0 -1 0 -1": none).
std::string extent_text(const Eigen::Vector3i& dims, const std::vector<std::uint8_t>& mask) {
  Eigen::Vector3i lo = dims, hi = Eigen::Vector3i::Constant(-1);
  std::size_t i = 0;
  for (int z = 0; z < dims.z(); ++z)
    for (int y = 0; y < dims.y(); ++y)
      for (int x = 0; x < dims.x(); ++x, ++i)
        if (mask[i]) {
          lo = lo.cwiseMin(Eigen::Vector3i(x, y, z));
          hi = hi.cwiseMax(Eigen::Vector3i(x, y, z));
        }
  if (hi.x() < 0) return "0 -1 0 -1 0 -1";
  return fmt::format("{} {} {} {} {} {}", lo.x(), hi.x(), lo.y(), hi.y(), lo.z(), hi.z());
}

}  // namespace

std::vector<std::string> Segmentation::names() const {
  std::vector<std::string> out;
  for (const Segment& s : segments) out.push_back(s.name);
  return out;
}

Volume Segmentation::mask(const Segment& segment) const {
  Volume v;
  v.geometry = geometry;
  const auto& values = layers.at(std::size_t(segment.layer));
  const float label = float(segment.label_value);
  v.hu.resize(values.size());
  std::transform(values.begin(), values.end(), v.hu.begin(), [label](float x) { return x == label ? 1.0f : 0.0f; });
  return v;
}

std::int64_t Segmentation::count(const Segment& segment) const {
  const auto& values = layers.at(std::size_t(segment.layer));
  return std::count(values.begin(), values.end(), float(segment.label_value));
}

bool is_segmentation_path(const fs::path& path) { return lower(path.filename().string()).ends_with(".seg.nrrd"); }

Segmentation read_segmentation(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec))
    throw Error("cannot read " + quoted(path) + ": no such file (check the path and the current folder)");
  volume_formats::NrrdLayers file = volume_formats::read_nrrd_layers(path);
  Segmentation out;
  // the checks every volume gets, on the first layer (the others share its geometry)
  Volume first{file.geometry, std::move(file.layers.front())};
  volume_formats::finish_volume(first, path);
  out.geometry = first.geometry;
  file.layers.front() = std::move(first.hu);
  out.layers = std::move(file.layers);
  for (int k = 0;; ++k) {
    auto s = read_segment(file.key_values, k, out.layers.size(), path);
    if (!s) break;
    out.segments.push_back(std::move(*s));
  }
  if (out.segments.empty())
    throw Error(
        fmt::format("{} names no segments (no Segment0_ID or Segment0_Name field): it is a labelmap, not a "
                    "3D Slicer segmentation; give the label's number (--label N)",
                    quoted(path)));
  return out;
}

void write_segmentation(const GridGeometry& geometry, const std::vector<std::uint8_t>& mask, const Segment& segment,
                        const fs::path& path) {
  if (std::int64_t(mask.size()) != geometry.voxel_count())
    throw Error(fmt::format("cannot write {}: {} mask values for {} voxels", quoted(path), mask.size(),
                            geometry.voxel_count()));
  if (segment.label_value < 1 || segment.label_value > 255)
    throw Error(fmt::format("cannot write {}: label value {} (an unsigned-char segmentation holds 1 to 255)",
                            quoted(path), segment.label_value));
  std::vector<std::uint8_t> labels(mask.size());
  std::transform(mask.begin(), mask.end(), labels.begin(),
                 [&](std::uint8_t m) { return m ? std::uint8_t(segment.label_value) : std::uint8_t(0); });
  const Eigen::Vector3d& c = segment.color;
  const std::vector<std::pair<std::string, std::string>> fields = {
      {"Segment0_Color", fmt::format("{:g} {:g} {:g}", c.x(), c.y(), c.z())},
      {"Segment0_ColorAutoGenerated", "0"},
      {"Segment0_Extent", extent_text(geometry.dims, mask)},
      {"Segment0_ID", segment.id.empty() ? segment.name : segment.id},
      {"Segment0_LabelValue", std::to_string(segment.label_value)},
      {"Segment0_Layer", "0"},
      {"Segment0_Name", segment.name},
      {"Segment0_NameAutoGenerated", "0"},
      {"Segment0_Tags", "Segmentation.Status:completed|"},
      {"Segmentation_ContainedRepresentationNames", "Binary labelmap|"},
      {"Segmentation_MasterRepresentation", "Binary labelmap"},
      {"Segmentation_ReferenceImageExtentOffset", "0 0 0"}};
  write_atomically(path,
                   [&](const fs::path& tmp) { volume_formats::write_nrrd_labels(geometry, labels, fields, tmp); });
}

}  // namespace vx
