// voxelastic palpate-map INPUT --out DIR: a ball pressed at a grid of points over one face of an
// object (a scene, a model or a volume), each press from rest, in parallel; writes map.csv,
// map.vtp, map.png and summary.json (the lesion estimate, its extent and the contrast).
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "base/error.h"
#include "base/version.h"
#include "commands.h"
#include "render/plot.h"
#include "scene/palpation_map.h"
#include "util/atomic_file.h"
#include "util/log.h"
#include "util/progress.h"

namespace vx::cli {
namespace {
namespace fs = std::filesystem;

struct PalpateMapOptions {
  std::string input;
  std::string out;
  std::string face{"+z"};
  std::string hounsfield{"40:5,120:50"};
  PalpationMapSettings map;
  PalpationSceneOptions scene;
  bool png{true};
};

/// "HU:KPA,HU:KPA,..." (sorted by HU, at least two rows), or "none".
std::vector<HuModulus> parse_hounsfield(const std::string& text) {
  std::vector<HuModulus> rows;
  if (text == "none") return rows;
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t comma = std::min(text.find(',', start), text.size());
    const std::string row = text.substr(start, comma - start);
    const std::size_t colon = row.find(':');
    HuModulus r;
    try {
      if (colon == std::string::npos) throw std::invalid_argument(row);
      std::size_t a = 0, b = 0;
      r.hu = std::stod(row.substr(0, colon), &a);
      r.youngs_modulus_kpa = std::stod(row.substr(colon + 1), &b);
      if (a != colon || b != row.size() - colon - 1) throw std::invalid_argument(row);
    } catch (const std::exception&) {
      throw CLI::ValidationError("--hounsfield", fmt::format("'{}' is not HU:KPA (e.g. 40:5,120:50)", row));
    }
    if (!std::isfinite(r.hu) || !(r.youngs_modulus_kpa > 0) || !std::isfinite(r.youngs_modulus_kpa))
      throw CLI::ValidationError("--hounsfield", fmt::format("'{}': the modulus must be a positive number of kPa", row));
    if (!rows.empty() && r.hu <= rows.back().hu)
      throw CLI::ValidationError("--hounsfield", "the rows must be sorted by increasing HU");
    rows.push_back(r);
    start = comma + 1;
  }
  if (rows.size() < 2) throw CLI::ValidationError("--hounsfield", "give at least two rows HU:KPA, or 'none'");
  return rows;
}

/// `x` for a 0.01 mm figure: no "-0.00".
double tidy(double x) { return std::abs(x) < 0.005 ? 0.0 : x; }

void run_palpate_map(PalpateMapOptions o) {
  // the options and the outputs first: a mistake there should cost nothing
  try {
    o.map.face = o.scene.face = parse_face(o.face);
  } catch (const Error& e) {
    throw CLI::ValidationError("--face", e.what());
  }
  if (const std::string e = o.map.validate(); !e.empty()) throw CLI::ValidationError("palpate-map", e);
  o.scene.hounsfield = parse_hounsfield(o.hounsfield);
  const fs::path dir(o.out);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    throw Error(fmt::format("--out '{}': cannot create the folder ({})", o.out, ec ? ec.message() : "not a folder"));
  check_output_path(dir / "summary.json");

  // the object, its material and support
  const Scene scene = palpation_scene(o.input, o.scene);
  const PreparedScene prepared = prepare_scene(scene);
  for (const auto& line : prepared.log) log::info("{}", line);
  for (const auto& w : prepared.warnings) log::warn("{}", w);

  // the presses, on every core
  Progress progress("palpate-map", log::level() <= log::Level::info);
  const PalpationMap map = palpation_map(prepared, o.map, [&](int done, int total) {
    progress.update(double(done) / double(total));
  });
  progress.done();
  const PalpationSummary s = summarize_palpation_map(map);
  nlohmann::json extra;
  extra["input"] = o.input;
  extra["voxelastic"] = kVersion;
  extra["material"] = {{"youngs_modulus_kpa", scene.material.base.youngs_modulus_kpa},
                       {"modulus_range_kpa", {prepared.min_modulus_kpa, prepared.max_modulus_kpa}}};
  write_palpation_map(map, s, dir, extra, o.png);

  fmt::print(
      "palpate-map: {} points of the {} face ({} failed) in {:.3g} s on {} thread(s), {} steps of {:g} ms "
      "each; stiffness {:.4g} N/mm (median) to {:.4g} N/mm; contrast {:.3g}; lesion estimate ({:.2f}, {:.2f}, "
      "{:.2f}) mm, extent {:.3g} x {:.3g} mm -> {}\n",
      s.points, face_name(map.settings.face), s.failed, map.wall_s, map.threads, map.steps_per_press,
      1e3 * map.time_step_s, s.background_n_mm, s.peak_n_mm, s.contrast, tidy(s.lesion_estimate_mm.x()),
      tidy(s.lesion_estimate_mm.y()), tidy(s.lesion_estimate_mm.z()), s.extent_u_mm, s.extent_v_mm, dir.string());
  if (s.failed > 0)
    throw Error(fmt::format("{} of {} presses failed (first: {}); the map of the others is in {}", s.failed, s.points,
                            std::find_if(map.points.begin(), map.points.end(),
                                         [](const PalpationPoint& p) { return !p.failure.empty(); })
                                ->failure,
                            dir.string()));
}

}  // namespace

void add_palpate_map_command(CLI::App& app) {
  auto opts = std::make_shared<PalpateMapOptions>();
  CLI::App* sub = app.add_subcommand(
      "palpate-map",
      "Press a ball at a grid of points over one face of an object (each press from rest, in parallel) and map the "
      "force at a set depth: writes DIR/map.csv, DIR/map.vtp, DIR/map.png and DIR/summary.json (lesion estimate, "
      "extent, contrast). See docs/palpation.md.");
  sub->add_option("INPUT", opts->input,
                  "a scene (.json: its object, material and fixed regions), a model (.vtu) or a volume (.vti, .nrrd, "
                  ".nii.gz, .mha, DICOM); a model or volume is held at the face opposite the mapped one")
      ->required();
  sub->add_option("-o,--out", opts->out, "output folder (created if missing)")->required();
  sub->add_option("--face", opts->face, "the face to press, by the direction it looks in: +z (default), -z, +x, -x, +y, -y")
      ->capture_default_str();
  sub->add_option("--spacing-mm", opts->map.spacing_mm, "grid spacing in the face's plane, mm")->capture_default_str();
  sub->add_option("--depth-mm", opts->map.depth_mm, "press depth below the first contact, mm")->capture_default_str();
  sub->add_option("--probe-radius-mm", opts->map.probe_radius_mm, "the ball's radius, mm")->capture_default_str();
  sub->add_option("--speed-mm-s", opts->map.speed_mm_s, "press speed, mm/s")->capture_default_str();
  sub->add_option("--hold-s", opts->map.hold_s, "hold at depth before the force is read, s")->capture_default_str();
  sub->add_option("--threads", opts->map.threads, "presses in parallel (0: every core)")->capture_default_str();
  sub->add_option("--modulus-kpa", opts->scene.modulus_kpa, "model or volume: Young's modulus of the tissue, kPa")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  sub->add_option("--hounsfield", opts->hounsfield,
                  "volume: modulus per voxel from its HU, rows HU:KPA sorted by HU (the phantoms' tissue 40 HU and lesion "
                  "120 HU by default), or 'none' for --modulus-kpa everywhere")
      ->capture_default_str();
  sub->add_flag("!--no-png", opts->png, "do not draw map.png");
  sub->callback([opts] { run_palpate_map(*opts); });
}

}  // namespace vx::cli
