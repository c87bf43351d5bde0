// voxelastic convert INPUT -o MODEL.vtu: volume -> voxel grid -> gradational model -> files.
#include <fmt/core.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include "base/error.h"
#include "base/version.h"
#include "commands.h"
#include "convert/iso_surface.h"
#include "convert/prepare.h"
#include "convert/stats.h"
#include "convert/threshold.h"
#include "io/model_io.h"
#include "io/segmentation_io.h"
#include "io/surface_io.h"
#include "io/volume_io.h"
#include "model/gradational_builder.h"
#include "physics/material.h"
#include "render/render.h"
#include "scene/scene.h"
#include "usage.h"
#include "util/atomic_file.h"
#include "util/exit_codes.h"
#include "util/log.h"
#include "util/progress.h"
#include "util/text.h"

namespace vx::cli {
namespace {
namespace fs = std::filesystem;

struct ConvertOptions {
  std::string input;
  std::string output;
  std::string threshold;
  std::string label;  ///< --label: a label number (a labelmap) or a segment's name (.seg.nrrd); "" or "-1": none
  std::string mask;   ///< --mask: the voxels that became the model, as a Slicer segmentation (.seg.nrrd)
  double youngs_modulus_kpa{Material{}.youngs_modulus_kpa};  ///< the model file's youngs_modulus_kpa (no table)
  std::string hounsfield_table;  ///< "HU:KPA,HU:KPA,...": the modulus from each voxel's HU instead
  std::string layout{"gradational"};
  int max_level{-1};
  std::string stats;
  std::string png;
  std::string surface;
  std::string surface_method{"iso"};
  bool largest_component{false};
  bool fill_holes{false};
  bool no_crop{false};
  std::string lattice_origin{"best"};
  double voxel_mm{0.0};
  std::string series;
  std::string modality{"ct"};
  bool quiet{false};
};

/// Outputs are first written beside their targets under temporary names and renamed onto the
/// targets only when every output is written: a failure leaves no new file and keeps old ones.
class StagedOutputs {
 public:
  StagedOutputs() = default;
  StagedOutputs(const StagedOutputs&) = delete;
  StagedOutputs& operator=(const StagedOutputs&) = delete;
  ~StagedOutputs() {
    std::error_code ec;
    for (const auto& [tmp, target] : staged_) fs::remove(tmp, ec);
  }
  /// A temporary path beside `target` with the same extension; remembered for commit().
  fs::path stage(const fs::path& target) {
    const fs::path tmp = target.parent_path() / ("." + target.stem().string() + ".part" + std::to_string(::getpid()) +
                                                 target.extension().string());
    staged_.emplace_back(tmp, target);
    return tmp;
  }
  /// Renames every staged file onto its target (each flushed to disk first, the folders after).
  void commit() {
    for (const auto& [tmp, target] : staged_) sync_file(tmp);
    for (std::size_t i = 0; i < staged_.size(); ++i) {
      std::error_code ec;
      fs::rename(staged_[i].first, staged_[i].second, ec);
      if (ec) {
        // undo the ones already in place, so the run leaves nothing half done
        for (std::size_t k = 0; k < i; ++k) fs::remove(staged_[k].second, ec);
        throw Error("could not move '" + staged_[i].first.string() + "' to '" + staged_[i].second.string() +
                    "': " + ec.message());
      }
    }
    for (const auto& [tmp, target] : staged_) sync_folder(target.parent_path());
    staged_.clear();
  }

 private:
  std::vector<std::pair<fs::path, fs::path>> staged_;
};

/// Throws unless `path` ends in `ext` and its folder exists and is writable.
void check_output(const std::string& path, const char* ext, const char* option, const char* what) {
  const std::string name = fs::path(path).filename().string();
  if (name.size() <= std::strlen(ext) || !name.ends_with(ext))
    throw Error(fmt::format("{} '{}': the {} must be a {} file (for example {}{})", option, path, what, ext,
                            fs::path(path).stem().string().empty() ? "out" : fs::path(path).stem().string(), ext));
  check_output_path(path);
}

/// "40 to 300" or ">= -200".
std::string hu_window(const HuRange& r) {
  return std::isfinite(r.hi) ? fmt::format("{:g} to {:g}", r.lo, r.hi) : fmt::format(">= {:g}", r.lo);
}

/// Checks every option before any work, so a mistake costs nothing.
void validate(const ConvertOptions& o) {
  std::error_code ec;
  if (!fs::exists(o.input, ec))
    throw Error("input '" + o.input + "' does not exist: give a volume file (.nrrd, .nii.gz, .mha, .vti) or a DICOM folder");
  // the format itself is checked by read_volume, first thing (DICOM files may lack an extension)
  check_output(o.output, ".vtu", "-o", "model");
  if (!o.stats.empty()) check_output(o.stats, ".json", "--stats", "statistics file");
  if (!o.png.empty()) check_output(o.png, ".png", "--png", "picture");
  if (!o.surface.empty()) check_output(o.surface, ".vtp", "--surface", "surface");
  if (!o.mask.empty()) check_output(o.mask, ".seg.nrrd", "--mask", "mask (a 3D Slicer segmentation)");
  if (o.max_level < -1) throw Error(fmt::format("--max-level {}: the level must be 0 or more", o.max_level));
  if (o.max_level >= 0 && o.layout != "gradational")
    throw Error("--max-level applies to --resolution gradational only (the " + o.layout +
                " layout has a single level); leave it out");
  if (!(o.voxel_mm >= 0.0) || !std::isfinite(o.voxel_mm))
    throw Error(fmt::format("--voxel {}: the voxel size must be a positive number of mm", o.voxel_mm));
  if (!o.png.empty() && !display_available())
    throw NoDisplay("--png needs an X display for rendering and there is none (DISPLAY unset or not reachable): run "
                "under xvfb-run, e.g. `xvfb-run -a -s \"-screen 0 1280x1024x24\" voxelastic convert ...`, or leave out --png");
}

/// --label N: the volume must be a labelmap (integer values) that holds N; otherwise says which
/// labels it has.
void check_label(const Volume& volume, int label, const std::string& input) {
  // (a segmentation's segment was chosen by choose_segment instead)
  std::set<float> values;
  std::int64_t count = 0;
  for (const float v : volume.hu) {
    if (v != std::round(v))
      throw CLI::ValidationError("--label", fmt::format("'{}' holds the value {:g}, so it is not a labelmap "
                                                        "(labels are whole numbers) and --label {} does not apply; "
                                                        "give --threshold instead",
                                                        input, double(v), label));
    count += v == float(label);
    if (values.size() <= 20) values.insert(v);
  }
  if (count > 0) return;
  std::string list;
  int shown = 0;
  for (const float v : values)
    if (shown++ < 20) list += fmt::format("{}{:g}", list.empty() ? "" : ", ", double(v));
  throw CLI::ValidationError("--label", fmt::format("no voxel of the labelmap has label {}; its labels are "
                                                    "{}{}",
                                                    label, list, values.size() > 20 ? ", ..." : ""));
}

/// --label as given: a number (>= 0), a segment's name, or nothing ("" or -1).
struct LabelArgument {
  bool given{false};
  std::optional<int> number;  ///< when the text is a whole number
  std::string text;
};

LabelArgument parse_label(const std::string& label) {
  LabelArgument a;
  a.text = trim(label);
  if (a.text.empty() || a.text == "-1") return a;
  a.given = true;
  char* end = nullptr;
  const long v = std::strtol(a.text.c_str(), &end, 10);
  if (end == a.text.c_str() + a.text.size() && v >= 0 && v <= std::numeric_limits<int>::max()) a.number = int(v);
  return a;
}

/// "liver (label 1), lesion (label 1, layer 1)"
std::string segment_list(const Segmentation& seg) {
  std::string out;
  for (const Segment& s : seg.segments) {
    out += fmt::format("{}'{}' (label {}", out.empty() ? "" : ", ", s.name, s.label_value);
    if (seg.layers.size() > 1) out += fmt::format(", layer {}", s.layer);
    out += ")";
  }
  return out;
}

/// The segment --label names (by name, or by label value when only one segment has it); the only
/// segment when --label is not given. Otherwise a command-line mistake (exit 2) listing the
/// segments, with the nearest name for a typo.
const Segment& choose_segment(const Segmentation& seg, const LabelArgument& label, const std::string& input) {
  const std::string list = segment_list(seg);
  if (!label.given) {
    if (seg.segments.size() == 1) return seg.segments.front();
    throw CLI::ValidationError("--label", fmt::format("'{}' is a segmentation of {} segments: choose one with --label "
                                                      "NAME; its segments are {}",
                                                      input, seg.segments.size(), list));
  }
  // by name: exactly, then ignoring case when that is unambiguous
  for (const Segment& s : seg.segments)
    if (s.name == label.text) return s;
  const Segment* by_case = nullptr;
  int matches = 0;
  for (const Segment& s : seg.segments)
    if (lower(s.name) == lower(label.text)) by_case = &s, ++matches;
  if (matches == 1) return *by_case;
  if (label.number) {
    const Segment* found = nullptr;
    int n = 0;
    for (const Segment& s : seg.segments)
      if (s.label_value == *label.number) found = &s, ++n;
    if (n == 1) return *found;
    if (n > 1)
      throw CLI::ValidationError("--label", fmt::format("label {} is in {} layers of '{}': give the segment's name; "
                                                        "its segments are {}",
                                                        *label.number, n, input, list));
    throw CLI::ValidationError(
        "--label", fmt::format("no segment of '{}' has label {}; its segments are {}", input, *label.number, list));
  }
  const std::string near = nearest_word(label.text, seg.names());
  throw CLI::ValidationError(
      "--label", fmt::format("'{}' has no segment named '{}'{}; its segments are {}", input, label.text,
                             near.empty() ? std::string() : fmt::format(" (did you mean '{}'?)", near), list));
}

/// --hounsfield-table "HU:KPA,HU:KPA,...": at least two rows, HU increasing, moduli positive
/// (the scene key hounsfield_table's rules); a mistake is a command-line mistake.
std::vector<HuModulus> parse_hounsfield_table(const std::string& text) {
  std::vector<HuModulus> rows;
  std::stringstream in(text);
  for (std::string item; std::getline(in, item, ',');) {
    const auto colon = item.find(':');
    char* end_hu = nullptr;
    char* end_e = nullptr;
    const std::string hu = trim(item.substr(0, colon)),
                      e = colon == std::string::npos ? "" : trim(item.substr(colon + 1));
    HuModulus row{std::strtod(hu.c_str(), &end_hu), std::strtod(e.c_str(), &end_e)};
    if (hu.empty() || e.empty() || *end_hu || *end_e || !std::isfinite(row.hu) || !(row.youngs_modulus_kpa > 0) ||
        !std::isfinite(row.youngs_modulus_kpa))
      throw CLI::ValidationError("--hounsfield-table", fmt::format("'{}' is not a row HU:KPA with a modulus above 0 "
                                                                   "(for example -100:3,100:30)",
                                                                   trim(item)));
    if (!rows.empty() && !(row.hu > rows.back().hu))
      throw CLI::ValidationError("--hounsfield-table", fmt::format("rows must be sorted by increasing HU ({:g} after "
                                                                   "{:g})",
                                                                   row.hu, rows.back().hu));
    rows.push_back(row);
  }
  if (rows.size() < 2)
    throw CLI::ValidationError("--hounsfield-table", "give at least two rows HU:KPA (for example -100:3,100:30)");
  return rows;
}

void run_convert(const ConvertOptions& o) {
  // everything the user typed, checked first
  validate(o);
  // a labelmap: one label is the tissue (the HU window N:N); a segmentation: one segment (its
  // voxels 1, the others 0); resampling would blend labels
  const LabelArgument label_arg = parse_label(o.label);
  const bool segmentation = is_segmentation_path(o.input);
  const bool labels = label_arg.given || segmentation;
  if (labels && !o.threshold.empty() && lower(trim(o.threshold)) != "tissue")
    throw CLI::ValidationError("--label", segmentation ? "a segmentation's segment is the tissue: leave out --threshold"
                                                       : "give --label N (a labelmap) or --threshold (HU), not both");
  if (labels && o.voxel_mm > 0)
    throw CLI::ValidationError("--label", "a labelmap cannot be resampled (--voxel would blend its labels)");
  if (label_arg.given && !label_arg.number && !segmentation)
    throw CLI::ValidationError("--label", fmt::format("'{}' is a name: names are the segments of a 3D Slicer "
                                                      "segmentation (.seg.nrrd); '{}' is a labelmap, give the "
                                                      "label's number",
                                                      label_arg.text, o.input));
  if (labels && !o.hounsfield_table.empty())
    throw CLI::ValidationError("--hounsfield-table", "a labelmap holds labels, not HU: leave out --hounsfield-table");
  if (!(o.youngs_modulus_kpa > 0) || !std::isfinite(o.youngs_modulus_kpa))
    throw CLI::ValidationError("--youngs-modulus-kpa",
                               fmt::format("{} kPa: the modulus must be above 0", o.youngs_modulus_kpa));
  SceneMaterial material;
  material.base.youngs_modulus_kpa = o.youngs_modulus_kpa;
  if (!o.hounsfield_table.empty()) material.hounsfield = parse_hounsfield_table(o.hounsfield_table);
  PrepareOptions prep;
  if (!o.threshold.empty()) prep.range = parse_threshold(o.threshold);
  prep.largest_component = o.largest_component;
  prep.fill_holes = o.fill_holes;
  prep.crop = !o.no_crop;
  prep.voxel_mm = o.voxel_mm;
  BuildSettings build;
  build.layout = parse_layout(o.layout);
  build.max_level = o.max_level;
  prep.lattice_period = o.lattice_origin == "best" && prep.crop ? 4 : 0;  // docs/model.md section 3.5
  prep.lattice_build = build;
  ReadOptions read;
  read.series_uid = o.series;
  read.any_modality = o.modality == "any";
  const bool talk = !o.quiet;
  if (o.quiet) log::set_level(std::max(log::level(), log::Level::warn));  // the readers' notes and progress too

  // read the volume; a segmentation gives its segment's voxels (1) and the rest (0)
  Progress reading("reading " + fs::path(o.input).filename().string(), talk);
  Volume volume;
  int label = -1;            // the label value that is the tissue; -1: HU
  std::string segment_name;  // a segmentation's segment
  if (segmentation) {
    const Segmentation seg = read_segmentation(o.input);
    const Segment& chosen = choose_segment(seg, label_arg, o.input);
    volume = seg.mask(chosen);
    label = chosen.label_value;
    segment_name = chosen.name;
    prep.range = HuRange{1.0, 1.0};
  } else {
    volume = read_volume(o.input, read);
    if (label_arg.number) {
      label = *label_arg.number;
      prep.range = HuRange{double(label), double(label)};
    }
  }
  reading.done();
  if (!segmentation && label >= 0) check_label(volume, label, o.input);

  // threshold, clean up, crop, resample
  PrepareReport prepared;
  Progress preparing("preparing the voxel grid", talk);
  const VoxelGrid grid = prepare_grid(volume, prep, &prepared);
  preparing.done();

  // build the model: a one-slice volume makes the 2D (slice) model (docs/model.md section 12)
  if (grid.dims().z() == 1) {
    build.dimensions = 2;
    if (talk)
      log::info("one slice ({} x {} pixels of {:g} x {:g} mm, {:g} mm thick): building the 2D model (plane stress)",
                grid.dims().x(), grid.dims().y(), grid.geometry().spacing_mm.x(), grid.geometry().spacing_mm.y(),
                grid.geometry().spacing_mm.z());
  }
  BuildReport built;
  Progress building("building the " + o.layout + " model", talk);
  build.progress = [&building](double f) { building.update(f); };
  const Model model = build_model(grid, build, &built);
  building.done();
  const ModelStats stats = model_stats(model);

  // the smoothed surface, embedded in the model so a simulation can deform it
  EmbeddedSurface surface;
  if (!o.surface.empty()) {
    Progress surfacing(model.is_2d() ? std::string("making the slice surface (2D model)")
                                     : "extracting the " + o.surface_method + " surface",
                       talk);
    // contour the HU values where they sit on the model's voxels (no resampling) and the window
    // is open above; otherwise the binary grid, which is exactly what the model holds
    const bool use_hu = o.voxel_mm == 0.0 && !std::isfinite(prep.range.hi);
    IsoSurfaceSettings iso;
    if (use_hu) iso.iso_hu = prep.range.lo;
    surface = make_surface(model, grid, use_hu ? &volume : nullptr, parse_surface_method(o.surface_method), iso);
    surfacing.done();
  }

  // per element, for ParaView: the modulus a simulation would give it (constant, or from the
  // HU table averaged over its voxels) and, for a CT volume, its mean HU (a lesion shows)
  ElementArrays element_arrays;
  {
    const MaterialField field = material_field(model, material, &volume);
    element_arrays.emplace_back("youngs_modulus_kpa",
                                field.youngs_modulus_kpa.empty()
                                    ? std::vector<double>(std::size_t(model.num_elements()), o.youngs_modulus_kpa)
                                    : field.youngs_modulus_kpa);
    if (label < 0) element_arrays.emplace_back("mean_hu", element_mean_values(model, volume));
  }

  // write every output under a temporary name, then move them all in place
  StagedOutputs outputs;
  {
    Progress saving("writing " + fs::path(o.output).filename().string(), talk);
    save_model(model, outputs.stage(o.output), element_arrays);
    saving.done();
  }
  if (!o.surface.empty()) save_surface(surface, outputs.stage(o.surface));
  if (!o.mask.empty()) {
    // the grid's tissue voxels put back into the (resampled) input's grid, uncropped: the
    // voxels that became the model, where Slicer shows the input
    const GridGeometry& gg = grid.geometry();
    GridGeometry full = gg;
    full.dims = prepared.resampled_dims;
    full.origin_mm = gg.index_to_lps(-prepared.crop_lo.cast<double>());
    std::vector<std::uint8_t> mask(std::size_t(full.voxel_count()), 0);
    for (int k = 0; k < gg.dims.z(); ++k)
      for (int j = 0; j < gg.dims.y(); ++j)
        for (int i = 0; i < gg.dims.x(); ++i) {
          if (!grid.at(i, j, k)) continue;
          const Eigen::Vector3i p = prepared.crop_lo + Eigen::Vector3i(i, j, k);
          if ((p.array() < 0).any() || (p.array() >= full.dims.array()).any())
            throw std::logic_error("a tissue voxel outside the input's grid");  // tissue comes from the input
          mask[std::size_t(p.x() + std::int64_t(full.dims.x()) * (p.y() + std::int64_t(full.dims.y()) * p.z()))] = 1;
        }
    Segment s;
    s.name = segment_name.empty() ? "voxelastic model" : segment_name;
    s.id = "voxelastic_model";
    s.color = Eigen::Vector3d(0.945098, 0.839216, 0.568627);  // Slicer's "tissue" colour
    write_segmentation(full, mask, s, outputs.stage(o.mask));
  }
  if (!o.stats.empty()) {
    nlohmann::json j;
    to_json(j, stats);
    j["input"] = o.input;
    j["build_s"] = built.build_s;
    j["max_level"] = o.max_level >= 0 ? nlohmann::json(o.max_level) : nlohmann::json(nullptr);  // null: no limit
    const double hi = prep.range.hi;
    j["label"] = label >= 0 ? nlohmann::json(label) : nlohmann::json(nullptr);  // null: HU, not a labelmap
    j["segment"] = segment_name.empty() ? nlohmann::json(nullptr) : nlohmann::json(segment_name);
    j["threshold_hu"] = {prep.range.lo, std::isfinite(hi) ? nlohmann::json(hi) : nlohmann::json(nullptr)};
    nlohmann::json pj;
    prepared.to_json(pj);
    j["prepare"] = pj;
    const auto optional = [](const std::string& v) { return v.empty() ? nlohmann::json(nullptr) : nlohmann::json(v); };
    j["outputs"] = {{"model", o.output},
                    {"stats", o.stats},
                    {"png", optional(o.png)},
                    {"surface", optional(o.surface)},
                    {"mask", optional(o.mask)}};
    if (!o.surface.empty())
      j["surface"] = {{"method", to_string(surface.method)}, {"vertices", surface.num_vertices()}, {"triangles", surface.num_triangles()}};
    j["voxelastic_version"] = vx::kVersion;
    write_text_atomically(outputs.stage(o.stats), j.dump(2) + "\n");
  }
  if (!o.png.empty()) {
    Progress drawing("drawing " + fs::path(o.png).filename().string(), talk);
    RenderSettings r;
    r.title = !segment_name.empty() ? fmt::format("{}: segment {}", fs::path(o.input).filename().string(), segment_name)
              : label >= 0
                  ? fmt::format("{}: label {}", fs::path(o.input).filename().string(), label)
                  : fmt::format("{}: tissue HU {}", fs::path(o.input).filename().string(), hu_window(prep.range));
    render_model_png(model, outputs.stage(o.png), r);
    drawing.done();
  }
  outputs.commit();

  if (!talk) return;
  fmt::print("source:         {}\n", o.input);
  if (!segment_name.empty())
    fmt::print("segment:        {} (label {})\n", segment_name, label);
  else if (label >= 0)
    fmt::print("label:          {}\n", label);
  else
    fmt::print("threshold:      HU {}\n", hu_window(prep.range));
  // each figure once: the tissue count is the model's (stats), the build time the progress line's
  fmt::print("{}\n", prepared.summary(false));
  fmt::print("{}\n", summary(stats));
  fmt::print("wrote:          {}", o.output);
  if (!o.stats.empty()) fmt::print(", {}", o.stats);
  if (!o.png.empty()) fmt::print(", {}", o.png);
  if (!o.mask.empty()) fmt::print(", {}", o.mask);
  if (!o.surface.empty())
    fmt::print(", {} ({} surface: {} vertices, {} triangles)", o.surface, to_string(surface.method), surface.num_vertices(),
               surface.num_triangles());
  fmt::print("\n");
}

/// The Slicer Execution Model description of `convert` (what `convert --xml` prints): 3D Slicer
/// reads it to build the module's panel, then runs `voxelastic convert` with the values.
/// Slicer's parser (ModuleDescriptionParser) takes a <longflag> of letters, digits and '_' only,
/// so the flags are written with '_' for '-' (`--fill_holes`), which the command line takes too
/// (usage.h, hyphenated_long_options). tests/apps/cli_slicer_xml_test.cpp checks the parser's
/// rules and that it names every option of convert.
std::string slicer_xml() {
  return std::string(R"(<?xml version="1.0" encoding="utf-8"?>
<executable>
  <category>Simulation.voxelastic</category>
  <title>voxelastic convert</title>
  <description><![CDATA[Converts a CT volume into a gradational-resolution elastic model (.vtu, LPS mm) for soft-tissue simulation: threshold the HU, clean up, build the elements (level 0 at the surface, larger inside), save.]]></description>
  <version>)") +
         vx::kVersion + R"(</version>
  <documentation-url></documentation-url>
  <license>BSD-3-Clause</license>
  <contributor>The voxelastic authors</contributor>
  <parameters>
    <label>Input and outputs</label>
    <description><![CDATA[The CT volume and the files to write.]]></description>
    <image>
      <name>input</name>
      <label>CT volume</label>
      <description><![CDATA[The volume in Hounsfield units (.nrrd, .nii.gz, .mha, .vti, or a DICOM folder).]]></description>
      <channel>input</channel>
      <index>0</index>
    </image>
    <geometry fileExtensions=".vtu">
      <name>output</name>
      <label>Elastic model</label>
      <description><![CDATA[The model to write (.vtu, LPS mm).]]></description>
      <flag>o</flag>
      <longflag>output</longflag>
      <channel>output</channel>
    </geometry>
    <geometry fileExtensions=".vtp">
      <name>surface</name>
      <label>Surface</label>
      <description><![CDATA[Also write the smoothed surface, embedded in the model (.vtp, LPS mm).]]></description>
      <longflag>surface</longflag>
      <channel>output</channel>
    </geometry>
    <file fileExtensions=".json">
      <name>stats</name>
      <label>Statistics</label>
      <description><![CDATA[Write the model statistics as JSON (.json).]]></description>
      <longflag>stats</longflag>
      <channel>output</channel>
    </file>
    <image type="label" fileExtensions=".seg.nrrd">
      <name>mask</name>
      <label>Model voxels</label>
      <description><![CDATA[Also write the voxels that became the model, on the input's grid (.seg.nrrd: a segmentation of one segment; Slicer's module panel loads it as a labelmap).]]></description>
      <longflag>mask</longflag>
      <channel>output</channel>
    </image>
    <file fileExtensions=".png">
      <name>png</name>
      <label>Picture</label>
      <description><![CDATA[Draw the model to a picture (.png; needs an X display).]]></description>
      <longflag>png</longflag>
      <channel>output</channel>
    </file>
  </parameters>
  <parameters>
    <label>Tissue</label>
    <description><![CDATA[Which voxels are tissue.]]></description>
    <string>
      <name>threshold</name>
      <label>HU window</label>
      <description><![CDATA[LO (HU >= LO), LO:HI, or a preset: soft-tissue, bone, fat, lung, tissue (HU >= -200, the default).]]></description>
      <longflag>threshold</longflag>
      <default>tissue</default>
    </string>
    <string>
      <name>label</name>
      <label>Label or segment (labelmap input)</label>
      <description><![CDATA[The input is a labelmap: the voxels of this label number are the tissue, instead of the HU window; or a segmentation (.seg.nrrd): the segment of this name or label number. Empty: not a labelmap (a segmentation of one segment needs none).]]></description>
      <longflag>label</longflag>
      <default></default>
    </string>
    <double>
      <name>youngs_modulus_kpa</name>
      <label>Young's modulus (kPa)</label>
      <description><![CDATA[Written per element to the model (cell data youngs_modulus_kpa) when no Hounsfield table is given, kPa.]]></description>
      <longflag>youngs_modulus_kpa</longflag>
      <default>5</default>
      <constraints>
        <minimum>0.001</minimum>
        <maximum>1000000</maximum>
        <step>0.1</step>
      </constraints>
    </double>
    <string>
      <name>hounsfield_table</name>
      <label>Hounsfield table</label>
      <description><![CDATA[HU:KPA,HU:KPA,...: each voxel's modulus from its HU (linear between rows), averaged over each element. Empty: the modulus above.]]></description>
      <longflag>hounsfield_table</longflag>
      <default></default>
    </string>
    <boolean>
      <name>largest_component</name>
      <label>Largest component only</label>
      <description><![CDATA[Keep only the largest connected piece of tissue.]]></description>
      <longflag>largest_component</longflag>
      <default>false</default>
    </boolean>
    <boolean>
      <name>fill_holes</name>
      <label>Fill holes</label>
      <description><![CDATA[Fill cavities inside the tissue.]]></description>
      <longflag>fill_holes</longflag>
      <default>false</default>
    </boolean>
    <boolean>
      <name>no_crop</name>
      <label>Do not crop</label>
      <description><![CDATA[Keep the whole volume instead of cropping to the tissue.]]></description>
      <longflag>no_crop</longflag>
      <default>false</default>
    </boolean>
    <double>
      <name>voxel</name>
      <label>Resample to voxel size (mm)</label>
      <description><![CDATA[Resample to isotropic voxels of this size first, mm (0: keep the volume's voxels).]]></description>
      <longflag>voxel</longflag>
      <default>0</default>
      <constraints>
        <minimum>0</minimum>
        <maximum>20</maximum>
        <step>0.1</step>
      </constraints>
    </double>
  </parameters>
  <parameters>
    <label>Elements</label>
    <description><![CDATA[How the tissue becomes elements.]]></description>
    <string-enumeration>
      <name>resolution</name>
      <label>Element layout</label>
      <description><![CDATA[gradational (the paper's shells), uniform (all 2x2x2-voxel elements), voxel (one element per voxel).]]></description>
      <longflag>resolution</longflag>
      <default>gradational</default>
      <element>gradational</element>
      <element>uniform</element>
      <element>voxel</element>
    </string-enumeration>
    <integer>
      <name>max_level</name>
      <label>Largest element level</label>
      <description><![CDATA[Largest element level (cells of 2^L voxels); -1: no limit.]]></description>
      <longflag>max_level</longflag>
      <default>-1</default>
      <constraints>
        <minimum>-1</minimum>
        <maximum>30</maximum>
        <step>1</step>
      </constraints>
    </integer>
    <string-enumeration>
      <name>surface_method</name>
      <label>Surface method</label>
      <description><![CDATA[iso: smoothed iso-surface (default); paper: the voxel surface with concave steps bridged; staircase: raw voxel faces.]]></description>
      <longflag>surface_method</longflag>
      <default>iso</default>
      <element>iso</element>
      <element>paper</element>
      <element>staircase</element>
    </string-enumeration>
    <string-enumeration>
      <name>lattice_origin</name>
      <label>Lattice origin</label>
      <description><![CDATA[best: the origin with the fewest vertex entries (default); crop: the crop's 1-voxel margin.]]></description>
      <longflag>lattice_origin</longflag>
      <default>best</default>
      <element>best</element>
      <element>crop</element>
    </string-enumeration>
    <string>
      <name>series</name>
      <label>DICOM series UID</label>
      <description><![CDATA[DICOM: the SeriesInstanceUID to read (empty: the largest CT series).]]></description>
      <longflag>series</longflag>
      <default></default>
    </string>
    <string-enumeration>
      <name>modality</name>
      <label>DICOM modality</label>
      <description><![CDATA[ct: CT images only; any: also MR etc. (values are then not HU).]]></description>
      <longflag>modality</longflag>
      <default>ct</default>
      <element>ct</element>
      <element>any</element>
    </string-enumeration>
  </parameters>
</executable>
)";
}

}  // namespace

void add_convert_command(CLI::App& app) {
  auto opts = std::make_shared<ConvertOptions>();
  CLI::App* sub = app.add_subcommand(
      "convert",
      "Convert a CT volume into a gradational-resolution elastic model (.vtu, LPS mm): threshold, clean up, "
      "build the elements (level 0 at the surface, larger inside), save, report.");
  sub->add_option("INPUT", opts->input, "volume: .nrrd/.nhdr, .nii/.nii.gz, .mha/.mhd, .vti, or a DICOM folder / .dcm file")
      ->required();
  sub->add_option("-o,--output", opts->output, "model file to write (.vtu: open in ParaView or 3D Slicer)")
      ->required()
      ->check(extension_check(".vtu", "model"));
  sub->add_option("--threshold", opts->threshold,
                  "tissue HU window: LO (HU >= LO), LO:HI, or a preset name; default: HU >= -200")
      ->check(threshold_check());
  sub->add_option("--label", opts->label,
                  "N|NAME: the input is a labelmap and the voxels of label N are the tissue, instead of an HU "
                  "window; or a 3D Slicer segmentation (.seg.nrrd) and the segment NAME (or of label N) is (a "
                  "segmentation of one segment needs no --label); -1: not a labelmap (default)")
      ->check(CLI::Validator(
          [](std::string& text) {
            const std::string t = trim(text);
            if (t.empty()) return std::string("--label needs a label number or a segment's name");
            if (t == "-1" || t[0] != '-') return std::string();
            return "'" + text + "' is not a label (a number from 0, or a segment's name)";
          },
          "N|NAME"));
  sub->add_option("--mask", opts->mask,
                  "write the voxels that became the model as a 3D Slicer segmentation (.seg.nrrd, one segment, "
                  "on the input's grid (resampled with --voxel) in the same place, LPS)")
      ->check(extension_check(".seg.nrrd", "mask (a 3D Slicer segmentation)"));
  sub->add_option("--youngs-modulus-kpa", opts->youngs_modulus_kpa,
                  fmt::format("Young's modulus written per element to the model file (cell data youngs_modulus_kpa), "
                              "kPa; default {:g}, the scenes' default",
                              Material{}.youngs_modulus_kpa));
  sub->add_option("--hounsfield-table", opts->hounsfield_table,
                  "HU:KPA,HU:KPA,...: the modulus of each voxel from its HU instead (linear between rows, constant "
                  "beyond the ends, as a scene's hounsfield_table), averaged over each element");
  sub->add_option("--resolution", opts->layout,
                  "element layout: gradational (the paper's shells), uniform (all 2x2x2-voxel elements), "
                  "voxel (one element per voxel, the fine reference)")
      ->check(CLI::IsMember({"gradational", "uniform", "voxel"}));
  sub->add_option("--max-level", opts->max_level, "largest element level (cells of 2^L voxels); default (-1): no limit")
      ->check(CLI::Range(-1, 30));
  sub->add_option("--stats", opts->stats, "write the model statistics as JSON (.json)")
      ->check(extension_check(".json", "statistics file"));
  sub->add_option("--png", opts->png, "draw the model to a picture (.png; needs an X display, e.g. xvfb-run)")
      ->check(extension_check(".png", "picture"));
  sub->add_option("--surface", opts->surface,
                  "also write the smoothed surface, embedded in the model so it follows the deformation (.vtp, LPS mm)")
      ->check(extension_check(".vtp", "surface"));
  sub->add_option("--surface-method", opts->surface_method,
                  "iso: smoothed iso-surface embedded in the elements (accurate, default); paper: the voxel surface "
                  "with concave steps bridged, vertices on the model nodes (the paper's); staircase: raw voxel faces")
      ->check(CLI::IsMember({"iso", "paper", "staircase"}));
  sub->add_flag("--largest-component", opts->largest_component, "keep only the largest connected piece of tissue");
  sub->add_flag("--fill-holes", opts->fill_holes, "fill cavities inside the tissue");
  sub->add_flag("--no-crop", opts->no_crop, "keep the whole volume instead of cropping to the tissue");
  sub->add_option("--lattice-origin", opts->lattice_origin,
                  "best: start the cropped grid 0-3 air voxels further out, per axis, where the model has the fewest "
                  "vertex entries (default; docs/model.md 3.5); crop: keep the crop's 1-voxel margin")
      ->check(CLI::IsMember({"best", "crop"}));
  sub->add_option("--voxel", opts->voxel_mm, "resample to isotropic voxels of this size first, mm (0: no resampling)")
      ->check(CLI::Validator(
          [](std::string& text) {
            double v = 0;
            return CLI::detail::lexical_cast(text, v) && v >= 0 && std::isfinite(v)
                       ? std::string()
                       : "the voxel size must be a positive number of mm (0: no resampling), got '" + text + "'";
          },
          "MM>=0"));
  sub->add_option("--series", opts->series, "DICOM: SeriesInstanceUID to read (default: the largest CT series)");
  sub->add_option("--modality", opts->modality, "DICOM: ct (CT images only) or any (also MR etc., with a warning)")
      ->check(CLI::IsMember({"ct", "any"}));
  // 3D Slicer asks a CLI module for its description with --xml (before INPUT and -o are checked)
  sub->add_flag_callback(
      "--xml",
      [] {
        fmt::print("{}", slicer_xml());
        throw CLI::Success();
      },
      "print the Slicer Execution Model description of convert (a 3D Slicer CLI module) and exit");
  sub->callback([opts] {
    opts->quiet = quiet();  // -q: nothing but warnings and errors (on stderr)
    run_convert(*opts);
  });
}

}  // namespace vx::cli
