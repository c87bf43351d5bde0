// voxelastic phantom NAME -o OUT: a synthetic CT volume with a known analytic shape.
#include <fmt/format.h>

#include <Eigen/Core>
#include <cmath>
#include <filesystem>
#include <memory>
#include <string>

#include "base/error.h"
#include "commands.h"
#include "convert/phantom.h"
#include "io/volume_io.h"
#include "usage.h"
#include "util/atomic_file.h"

namespace vx::cli {
namespace {
namespace fs = std::filesystem;

struct PhantomOptions {
  PhantomSettings settings;
  std::string output;
  std::string lesion_center;  ///< --lesion-center-mm "X,Y,Z" ("" : the default)
};

/// Parses "X,Y,Z" (mm); throws CLI::ValidationError (a usage error, exit 2) otherwise.
Eigen::Vector3d parse_point_mm(const std::string& option, const std::string& text) {
  Eigen::Vector3d p;
  std::size_t start = 0;
  for (int i = 0; i < 3; ++i) {
    const std::size_t comma = text.find(',', start);
    if ((i < 2) != (comma != std::string::npos))
      throw CLI::ValidationError(option, fmt::format("'{}' is not three numbers X,Y,Z in mm (e.g. 5,0,2.4)", text));
    const std::string part = text.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    try {
      std::size_t used = 0;
      p[i] = std::stod(part, &used);
      if (used != part.size() || !std::isfinite(p[i])) throw std::invalid_argument(part);
    } catch (const std::exception&) {
      throw CLI::ValidationError(option, fmt::format("'{}' is not three numbers X,Y,Z in mm (e.g. 5,0,2.4)", text));
    }
    start = comma + 1;
  }
  return p;
}

/// -o: a format a phantom can be written in (a command-line mistake otherwise, exit 2).
std::string check_phantom_output(const std::string& output) {
  const std::string format = volume_format(output);
  const std::string ext = fs::path(output).extension().string();
  if (format.empty() || ext == ".mhd" || ext == ".nhdr" || ext == ".dcm")
    return fmt::format("'{}': cannot write a phantom as '{}'; use .vti, .mha, .nii.gz, .nii, .nrrd, or a folder path "
                       "ending in '/' for a DICOM series",
                       output, ext);
  return "";
}

void run_phantom(PhantomOptions o) {
  // the lesion options are checked against the block before anything else: a usage error (exit 2)
  if (!o.lesion_center.empty()) o.settings.lesion_center_mm = parse_point_mm("--lesion-center-mm", o.lesion_center);
  if (const std::string e = lesion_settings_error(o.settings); !e.empty())
    throw CLI::ValidationError("--lesion-center-mm/--lesion-radius-mm", e);
  // the output first (its format was checked while parsing): a mistake there should cost nothing
  if (volume_format(o.output) != "dicom") check_output_path(o.output);

  PhantomShape shape;
  const Volume volume = make_phantom(o.settings, &shape);
  write_volume(volume, o.output);

  const GridGeometry& g = volume.geometry;
  if (shape.is_2d()) {
    fmt::print("phantom {} (one slice, a 2D model): {}x{} pixels of {:g} mm, {:g} mm thick, {} tissue pixels = {:.4g} "
               "mm^2 (analytic {:.4g} mm^2){} -> {}\n",
               shape.name, g.dims.x(), g.dims.y(), g.spacing_mm.x(), g.spacing_mm.z(), shape.tissue_voxels,
               double(shape.tissue_voxels) * g.spacing_mm.x() * g.spacing_mm.y(), shape.area_mm2(),
               shape.lesion_radius_mm > 0 ? fmt::format(", lesion r {:.3g} mm at ({:.4g}, {:.4g}) mm, {:g} HU ({} pixels)",
                                                        shape.lesion_radius_mm, shape.lesion_center_mm.x(),
                                                        shape.lesion_center_mm.y(), o.settings.lesion_hu,
                                                        shape.lesion_voxels)
                                          : std::string(),
               o.output);
    return;
  }
  const double voxel_cm3 = double(shape.tissue_voxels) * g.voxel_volume_mm3() / 1000.0;
  if (!shape.has_closed_form()) {  // folded: no analytic volume to compare with
    fmt::print("phantom {}: {}x{}x{} voxels of {:g} mm, {} tissue voxels = {:.4g} cm^3, stem r {:.3g} mm at "
               "({:.4g}, {:.4g}, {:.4g}) mm (its bottom){} -> {}\n",
               shape.name, g.dims.x(), g.dims.y(), g.dims.z(), g.spacing_mm.x(), shape.tissue_voxels, voxel_cm3,
               shape.stem_radius_mm, shape.stem_center_mm.x(), shape.stem_center_mm.y(), shape.stem_center_mm.z(),
               o.settings.noise_hu > 0 ? fmt::format(", noise {:g} HU (seed {})", o.settings.noise_hu, o.settings.seed)
                                       : std::string(),
               o.output);
    return;
  }
  const double analytic_cm3 = shape.volume_mm3() / 1000.0;
  std::string lesion;
  if (shape.lesion_radius_mm > 0)
    lesion = fmt::format(", lesion r {:.3g} mm at ({:.4g}, {:.4g}, {:.4g}) mm, {:g} HU ({} voxels)",
                         shape.lesion_radius_mm, shape.lesion_center_mm.x(), shape.lesion_center_mm.y(),
                         shape.lesion_center_mm.z(), o.settings.lesion_hu, shape.lesion_voxels);
  fmt::print("phantom {}: {}x{}x{} voxels of {:g} mm, {} tissue voxels = {:.4g} cm^3 (analytic {:.4g} cm^3, {:+.2f}%){}{} "
             "-> {}\n",
             shape.name, g.dims.x(), g.dims.y(), g.dims.z(), g.spacing_mm.x(), shape.tissue_voxels, voxel_cm3,
             analytic_cm3, 100.0 * (voxel_cm3 - analytic_cm3) / analytic_cm3, lesion,
             o.settings.noise_hu > 0 ? fmt::format(", noise {:g} HU (seed {})", o.settings.noise_hu, o.settings.seed)
                                     : std::string(),
             o.output);
}

}  // namespace

void add_phantom_command(CLI::App& app) {
  auto opts = std::make_shared<PhantomOptions>();
  std::string names;
  for (const auto& n : phantom_names()) names += (names.empty() ? "" : ", ") + n;
  CLI::App* sub = app.add_subcommand(
      "phantom",
      "Write a synthetic CT volume of a known shape (tissue in air, HU, LPS mm, centred at the origin): the ground "
      "truth for tests and demos. disk, rectangle and disk-lesion are one slice: convert makes them 2D models.");
  sub->add_option("NAME", opts->settings.name, "shape: " + names)->required()->check(phantom_name_check());
  sub->add_option("-o,--output", opts->output,
                  "volume to write: .vti, .mha, .nii.gz, .nii, .nrrd, or a folder path ending in '/' (DICOM series)")
      ->required()
      ->check(CLI::Validator([](std::string& path) { return check_phantom_output(path); }, "OUT"));
  sub->add_option("--size", opts->settings.size, "voxels along each axis, 4 to 1024")->capture_default_str();
  sub->add_option("--spacing", opts->settings.spacing_mm, "voxel size, mm")->capture_default_str();
  sub->add_option("--noise", opts->settings.noise_hu, "standard deviation of Gaussian noise, HU")
      ->capture_default_str();
  sub->add_option("--seed", opts->settings.seed, "noise seed")->capture_default_str();
  sub->add_option("--tissue-hu", opts->settings.tissue_hu, "value inside the shape, HU")->capture_default_str();
  sub->add_option("--lesion-hu", opts->settings.lesion_hu, "block-lesion, disk-lesion: value inside the lesion, HU")
      ->capture_default_str();
  sub->add_option("--lesion-center-mm", opts->lesion_center,
                  "block-lesion, disk-lesion: the lesion's centre X,Y,Z in mm (the block is centred at the origin; "
                  "disk-lesion: Z = 0); the lesion must lie wholly inside the block");
  sub->add_option("--lesion-radius-mm", opts->settings.lesion_radius_mm,
                  "block-lesion, disk-lesion: the lesion's radius, mm (default: about 0.15 of the grid's edge)")
      ->check(CLI::PositiveNumber);
  sub->add_option("--thickness", opts->settings.thickness_mm,
                  "disk, rectangle, disk-lesion (one slice, a 2D model): the slice thickness, mm (0: the spacing)")
      ->capture_default_str();
  sub->callback([opts] { run_phantom(*opts); });
}

}  // namespace vx::cli
