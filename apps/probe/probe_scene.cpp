#include "probe_scene.h"

#include <fmt/core.h>

#include <chrono>
#include <optional>

#include "base/error.h"
#include "base/parallel.h"
#include "convert/decimate_surface.h"
#include "convert/iso_surface.h"
#include "convert/threshold.h"
#include "io/surface_io.h"
#include "io/volume_io.h"
#include "scene/fast_configuration.h"
#include "scene/palpation_defaults.h"
#include "scene/scene.h"
#include "util/text.h"
#include "util/thread_priority.h"

namespace vx::probe {

namespace {

std::string lower_extension(const std::filesystem::path& p) {
  const std::string name = lower(p.filename().string());
  if (name.size() > 7 && name.ends_with(".nii.gz")) return ".nii.gz";
  const auto dot = name.rfind('.');
  return dot == std::string::npos ? std::string() : name.substr(dot);
}

// the axis from the held nodes' centroid towards the model's (the side away from the support)
Eigen::Vector3d away_from_support(const Model& model, const std::vector<int>& fixed_nodes) {
  Eigen::Vector3d held = Eigen::Vector3d::Zero();
  for (const int n : fixed_nodes) held += model.rest_positions.col(n);
  held /= double(fixed_nodes.size());
  const Eigen::Vector3d all = model.rest_positions.rowwise().mean();
  const Eigen::Vector3d d = all - held;
  Eigen::Index axis = 0;
  if (d.cwiseAbs().maxCoeff(&axis) < 1e-9) return Eigen::Vector3d(0, -1, 0);
  Eigen::Vector3d up = Eigen::Vector3d::Zero();
  up[axis] = d[axis] > 0 ? 1.0 : -1.0;
  return up;
}

// "up" for the view: against gravity; else away from the face the tissue is held by (a
// specimen fixed at z_min sits on a table below it); else along the first probe's tool axis
// (tip -> handle); else away from any other
// support (a box or sphere selector: an organ on its stem); else anterior (LPS -y: a patient lying on the table)
Eigen::Vector3d scene_up(const Scene& file, const Model& model, const SimulationSettings& s) {
  if (s.gravity_mm_s2.norm() > 0) return -s.gravity_mm_s2.normalized();
  for (const auto& f : file.fixed) {
    if (!f.is_face) continue;
    switch (f.face) {
      case BoxFace::x_min: return Eigen::Vector3d(1, 0, 0);
      case BoxFace::x_max: return Eigen::Vector3d(-1, 0, 0);
      case BoxFace::y_min: return Eigen::Vector3d(0, 1, 0);
      case BoxFace::y_max: return Eigen::Vector3d(0, -1, 0);
      case BoxFace::z_min: return Eigen::Vector3d(0, 0, 1);
      case BoxFace::z_max: return Eigen::Vector3d(0, 0, -1);
    }
  }
  for (const auto& p : s.probes)
    if (p.geometry.shape == ProbeShape::capsule || p.geometry.shape == ProbeShape::cylinder ||
        p.geometry.shape == ProbeShape::plane)
      return p.geometry.axis.normalized();
  // held by a box or sphere selector (an organ on its stem): up points from the held nodes to
  // the rest, along the nearest axis (a stem below the organ gives +z, as the body would)
  if (!s.fixed_nodes.empty()) return away_from_support(model, s.fixed_nodes);
  return Eigen::Vector3d(0, -1, 0);
}

// The scene the input asks for: a scene file as it is; a volume or a model with the palpation
// defaults (scene/palpation_defaults.h). Throws vx::Error for any other input.
Scene scene_of_input(const std::filesystem::path& input, const DefaultSceneOptions& options) {
  namespace fs = std::filesystem;
  if (!fs::exists(input)) throw Error("input '" + input.string() + "' does not exist");
  const std::string ext = lower_extension(input);
  if (ext == ".json") return load_scene(input);
  SceneObject object;
  object.path = input;
  if (ext == ".vtu") {
    // a model written by `voxelastic convert`
    object.source = ObjectSource::model;
  } else if (fs::is_directory(input) || !volume_format(input).empty()) {
    // a CT-like volume: threshold, largest component, fill holes, build the gradational model
    object.source = ObjectSource::volume;
    object.prepare.range = parse_threshold(options.threshold);
    object.prepare.largest_component = true;
    object.prepare.fill_holes = true;
    object.prepare.voxel_mm = options.voxel_mm;
    object.prepare.lattice_period = 4;  // the fewest vertex entries (docs/model.md section 3.5)
  } else {
    throw Error("input '" + input.string() +
                "': not a scene (.json), a volume (.vti .mha .mhd .nii .nii.gz .nrrd .nhdr, DICOM folder) "
                "or a model (.vtu)");
  }
  Material material;
  material.youngs_modulus_kpa = options.youngs_modulus_kpa;
  material.poisson_ratio = options.poisson_ratio;
  material.damping_ratio = options.damping_ratio;
  PalpationDefaults defaults;
  defaults.held_fraction = options.held_fraction;
  defaults.press_depth_mm = options.press_depth_mm;
  return default_palpation_scene(object, material, defaults);
}

}  // namespace

BackgroundDisplaySurface::BackgroundDisplaySurface(std::function<EmbeddedSurface(DecimationReport*)> finish,
                                                   std::shared_ptr<std::atomic<bool>> cancel)
    : finish_(std::move(finish)), cancel_(std::move(cancel)) {}

void BackgroundDisplaySurface::start() {
  if (started()) return;
  result_ = std::async(std::launch::async, [this, finish = std::move(finish_)] {
    (void)set_this_thread_name("vx-surface");
    // below the physics and the device, and never an OpenMP team of its own (an idle team on
    // another thread makes the physics' waits sleep: base/parallel.h)
    (void)set_this_thread_nice(10);
    (void)leave_parallel_work_to_others();
    return std::make_shared<const EmbeddedSurface>(finish(&report_));
  });
}

BackgroundDisplaySurface::~BackgroundDisplaySurface() {
  cancel_->store(true);
  if (result_.valid()) result_.wait();
}

bool BackgroundDisplaySurface::ready() const {
  return result_.valid() && result_.wait_for(std::chrono::seconds(0)) == std::future_status::ready;
}

std::shared_ptr<const EmbeddedSurface> BackgroundDisplaySurface::get(DecimationReport* report) {
  if (!result_.valid()) throw Error("the background display surface was not started or already taken");
  taken_ = true;
  std::shared_ptr<const EmbeddedSurface> s = result_.get();
  if (report) *report = report_;
  return s;
}

void use_display_surface(ProbeScene& scene, const DefaultSceneOptions& options) {
  if (!scene.surface || !scene.model) return;
  DecimationSettings settings;
  settings.target_triangles = options.display_triangles;
  DecimationReport report;
  EmbeddedSurface shown =
      decimate_surface(*scene.model, *scene.surface, settings, &report, options.surface_cache.get());
  if (!report.decimated) return;
  // the physics deforms the surface it publishes: the decimated one only
  scene.surface = std::make_shared<const EmbeddedSurface>(std::move(shown));
  scene.simulation.surface = scene.surface;
  scene.notes.push_back(report.summary());
}

std::string physics_configuration(const IntegratorSettings& in, const PhysicsModel& p) {
  std::string s = in.kind == IntegratorKind::implicit           ? "implicit"
                  : in.kind == IntegratorKind::symplectic_euler ? "symplectic Euler"
                                                                : "explicit Euler";
  s += in.time_step_s >= 1e-3 ? fmt::format(" {:.3g} ms", 1e3 * in.time_step_s)
                              : fmt::format(" {:.3g} us", 1e6 * in.time_step_s);
  if (in.kind == IntegratorKind::implicit) {
    s += fmt::format(", {} iteration{}", in.max_iterations, in.max_iterations == 1 ? "" : "s");
    if (in.residual_tolerance_n > 0) s += fmt::format(" (to {:.2g} N)", in.residual_tolerance_n);
    if (in.region_radius_mm > 0) s += fmt::format(", region {:g} mm", in.region_radius_mm);
  }
  if (p.mass_scaling.factor != 1.0) s += fmt::format(", mass x{:g}", p.mass_scaling.factor);
  if (p.mass_scaling.time_step_s > 0) s += fmt::format(", mass floor for {:.3g} ms", 1e3 * p.mass_scaling.time_step_s);
  return s;
}

void make_probes_live(ProbeScene& scene) {
  SimulationSettings& sim = scene.simulation;
  const Eigen::Vector3d lo = scene.model->rest_positions.rowwise().minCoeff();
  const Eigen::Vector3d hi = scene.model->rest_positions.rowwise().maxCoeff();
  const Eigen::Vector3d extent = hi - lo;
  scene.probe_allowed.clear();
  bool first_live = true;
  for (auto& p : sim.probes) {
    const Eigen::Vector3d start = p.initial_position();
    if (p.drive == ProbeDrive::live && first_live) {
      // the scene's stick mapping of its first live probe sets the app's defaults
      first_live = false;
      scene.control_from_scene = true;
      scene.control.mapping = p.mapping;
    }
    if (p.drive != ProbeDrive::live) {
      p.drive = ProbeDrive::live;
      p.start_mm = start;
      p.path.clear();
      p.joystick.clear();
    }
    if (!(p.max_speed_mm_s > 0)) p.max_speed_mm_s = 150.0;
    Box allowed;
    const double r = p.geometry.shape == ProbeShape::plane ? 0.0 : p.geometry.radius_mm;
    if (sim.workspace.enabled) {
      allowed.lo = sim.workspace.min_mm + Eigen::Vector3d::Constant(r);
      allowed.hi = sim.workspace.max_mm - Eigen::Vector3d::Constant(r);
      allowed.lo = allowed.lo.cwiseMin(start);
      allowed.hi = allowed.hi.cwiseMax(start);
    } else {
      allowed.lo = (lo - 0.5 * extent).cwiseMin(start);
      allowed.hi = (hi + 0.5 * extent).cwiseMax(start);
    }
    scene.probe_allowed.push_back(allowed);
  }
}

ProbeScene load_probe_scene(const std::filesystem::path& input, const DefaultSceneOptions& options) {
  const Scene file = scene_of_input(input, options);
  const bool defaults = file.palpation.has_value();
  PrepareSceneOptions prep;
  // a scene's own (paper) surface; none when nothing is shown
  prep.surface = options.display && !defaults && options.surface_method != SurfaceMethod::iso;
  // a scene file: seconds on a large organ, not before the run; the defaults: none
  prep.region_check = defaults ? RegionCheckTiming::none : RegionCheckTiming::background;
  prep.calibration_cache = options.calibration_cache;
  prep.region_check_cache = options.region_check_cache;
  PreparedScene built = prepare_scene(file, prep);
  ProbeScene scene;
  scene.name = defaults ? input.filename().string() : input.stem().string();
  scene.model = built.model;
  scene.physics = built.physics;
  scene.simulation = built.settings;
  scene.device_side = built.device_side;
  scene.region_check = built.pending_region_check;
  if (scene.simulation.probes.empty())
    throw Error(input.string() + ": $.probes: the scene has no probe to palpate with");
  std::optional<DecimationReport> built_display;  // the built surface: decimated on the way
  if (!options.display) {
    // headless: nothing is shown, so no surface is built, decimated or deformed
  } else if (defaults && !options.surface.empty()) {
    // a model's surface written with it by `voxelastic convert`
    scene.surface = std::make_shared<const EmbeddedSurface>(load_surface(options.surface, scene.model.get()));
  } else if (defaults || options.surface_method == SurfaceMethod::iso) {
    // the voxels' surface (a smoothed iso-surface, or the paper's), embedded in the elements and
    // decimated for display; a second start of the same organ loads it (io/surface_cache.h)
    DecimationSettings settings;
    settings.target_triangles = options.display_triangles;
    const SurfaceMethod method = defaults ? options.surface_method : SurfaceMethod::iso;
    built_display.emplace();
    if (options.surface_in_background) {
      // a first start: a preview now, the decimation (10 s on the folded organ) on a thread of
      // its own while the session runs (the GUI loop swaps it in)
      auto cancel = std::make_shared<std::atomic<bool>>(false);
      settings.cancel = cancel.get();
      StagedDisplaySurface staged =
          stage_display_surface_of_grid(built.model, built.grid, method, settings, options.surface_cache);
      *built_display = staged.report;
      scene.surface = std::make_shared<const EmbeddedSurface>(std::move(staged.shown));
      if (staged.finish)
        scene.surface_refinement = std::make_shared<BackgroundDisplaySurface>(std::move(staged.finish), cancel);
    } else {
      scene.surface = std::make_shared<const EmbeddedSurface>(display_surface_of_grid(
          *built.model, built.grid, method, settings, &*built_display, options.surface_cache.get()));
    }
  } else {
    scene.surface = built.surface;
  }
  scene.simulation.surface = scene.surface;
  scene.world_up = defaults ? built.up : scene_up(file, *scene.model, scene.simulation);
  if (!file.description.empty()) scene.notes.push_back(file.description);
  for (const auto& l : built.log) scene.notes.push_back(l);
  if (built_display && built_display->from_cache)
    scene.notes.push_back(
        fmt::format("surface: {} ({} triangles)", to_string(scene.surface->method), built_display->triangles_before));
  else if (built_display && built_display->preview_blocks > 0)
    scene.notes.push_back(fmt::format("surface: {} (about {} triangles, built and decimated in the background)",
                                      to_string(scene.surface->method), built_display->triangles_before));
  else if (built_display)
    scene.notes.push_back(fmt::format("surface: {} ({} triangles, built in {:.2f} s)", to_string(scene.surface->method),
                                      built_display->triangles_before, built_display->build_s));
  else if (scene.surface)
    scene.notes.push_back(fmt::format("surface: {}{} ({} triangles)", to_string(scene.surface->method),
                                      defaults && !options.surface.empty() ? " from " + options.surface.string() : "",
                                      scene.surface->num_triangles()));
  else
    scene.notes.push_back("surface: none (headless: nothing is shown)");
  scene.notes.push_back(fmt::format("physics: {}{}", physics_configuration(scene.simulation.integrator, *scene.physics),
                                    !scene.device_side.device ? std::string(", no device shaping (raw force)")
                                    : scene.device_side.device->shaping == ForceShaping::local
                                        ? std::string(", device force from the local contact model")
                                        : fmt::format(", device updates every {:g} ms (half sines)",
                                                      1e3 * scene.device_side.device->update_interval_s)));
  for (const auto& w : built.warnings) scene.notes.push_back("warning: " + w);
  scene.accuracy_status =
      incompressible_iterations_status(scene.simulation.integrator, scene.physics->material.poisson_ratio);
  make_probes_live(scene);
  if (built_display) {
    if (built_display->decimated || built_display->from_cache || built_display->preview)
      scene.notes.push_back(built_display->summary());
  } else {
    use_display_surface(scene, options);
  }
  return scene;
}

}  // namespace vx::probe
