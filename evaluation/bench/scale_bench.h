#pragma once
/// @file scale_bench.h
/// `voxelastic bench --scale` (docs/bench.md, "Palpation at organ size"): how close each
/// configuration of the simulation comes to real time on models of growing size, and what force
/// error it costs. Every model (sphere phantoms 32 to 256 voxels across at 1 mm, the organ
/// phantom, an ellipsoid of 140 x 180 x 150 mm, and the folded, brain-like phantom of the same
/// size) is palpated the same way: a ball pressed 5 mm into the top in 1 s, then slid 10 mm
/// sideways in 1 s (E 10 kPa, damping ratio 0.2; held by its support: the bottom 3 mm, or the
/// folded phantom's stem or lower third). Per model and configuration: elements, nodes, the
/// step, the wall time per step, steps per simulated second, the real-time factor (simulated /
/// wall time) on 1 and 2 threads,
/// and the RMS force error against the model's reference configuration (symplectic Euler at its
/// automatic step, physical masses) as a fraction of the reference's peak force.
///
/// Runs are timed on the whole press-and-slide unless they would take longer than
/// max_wall_s: then only the first max_wall_s of wall time is run, the factor comes from it
/// (said in the row's note) and the error is left out. One-thread runs are timed over the same
/// window as the two-thread runs or less; their forces equal the two-thread ones (tested), so
/// the error column is the two-thread run's.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "physics/physics_model.h"
#include "scene/scene.h"
#include "sim/integrator_kind.h"

namespace vx {

/// One way of running the simulation.
struct ScaleConfig {
  std::string name;
  IntegratorKind kind{IntegratorKind::symplectic_euler};
  double time_step_s{0.0};             ///< 0: automatic (time_step.h) for the (scaled) model
  MassScaling mass;                    ///< mass scaling (none: physical masses)
  int max_iterations{10};              ///< implicit
  double residual_tolerance_n{0};      ///< implicit
  int free_iterations{0};              ///< implicit: IntegratorSettings::free_iterations (the fast configuration's: 8)
  double free_tolerance_mm{0};         ///< implicit: IntegratorSettings::free_tolerance_mm
  double region_radius_mm{0};          ///< implicit: regional solves within this distance of the ball (0: everywhere)
  bool reference{false};               ///< the model's reference (the error of the others is against it)
  bool region_solve_far_field{false};  ///< diagnostic: IntegratorSettings::region_solve_far_field
  bool region_refresh_on_move{true};   ///< diagnostic: IntegratorSettings::region_refresh_on_move
  bool region_visit_still_far_field{false};  ///< diagnostic: IntegratorSettings::region_visit_still_far_field
  int region_far_field_degree{0};            ///< IntegratorSettings::region_far_field_degree (0: held)
  bool single_precision_sweeps{false};       ///< IntegratorSettings::single_precision_sweeps
};

/// One model: a phantom at 1 mm voxels, gradational layout.
struct ScaleModelSpec {
  std::string name;     ///< e.g. "sphere 128"
  std::string phantom;  ///< phantom name (phantom.h)
  int size{64};         ///< grid voxels per axis
  /// "best": the lattice origin with the fewest vertex entries (docs/model.md 3.5, the default);
  /// "crop": the crop's 1-voxel margin (the name then says "crop origin")
  std::string lattice_origin{"best"};
  /// What holds the model: "bottom 3 mm" (the nodes within 3 mm of its lowest point, the
  /// default), "stem" (the bottom 3 mm of the folded phantom's stem, a patch 20 mm across at
  /// size 214: PhantomShape::stem_center_mm) or "lower third" (every node in the lowest third
  /// of its height)
  std::string support{"bottom 3 mm"};
  /// The ball presses along the vertical through the centre of the model's bounding box moved
  /// by this much (x, y mm): the folded phantom's is on a gyrus of a hemisphere, off the fissure
  Eigen::Vector2d press_offset_mm{0, 0};
  /// The phantom's voxel size, mm (size x spacing is its grid's edge, so a model at 2 mm with
  /// half the size is the same shape on a coarser grid: fewer nodes for the physics)
  double spacing_mm{1.0};
  /// Not empty: the name of a model run before this one in the same suite (the same shape at its
  /// own resolution) whose reference judges this one, and whose path this one's ball follows (the
  /// same tool positions in mm); its own reference configuration is a row like the others (the
  /// error of the grid alone). So a coarser model's error is what it costs against the finer
  /// model a user has.
  std::string judged_against{};
};

struct ScaleBenchSettings {
  std::vector<ScaleModelSpec> models;
  std::vector<ScaleConfig> configs;
  std::vector<int> threads{1, 2};
  double youngs_modulus_kpa{10.0};
  double damping_ratio{0.2};
  double poisson_ratio{0.0};  ///< the material's (docs/model.md section 5: the volume term)
  double probe_radius_mm{4.0};
  double depth_mm{5.0};
  double slide_mm{10.0};
  double press_s{1.0};
  double slide_s{1.0};
  double max_wall_s{120.0};  ///< per run (the reference runs to the end regardless)
  double reference_max_wall_s{1800.0};
  double force_interval_s{0.01};
  std::string element;  ///< "paper" or "hourglass" (docs/model.md section 5); empty: the default
  /// Not empty: every complete run on the most threads writes its force curve there as it ends
  /// (`<model>__<configuration>.csv`: t_s, force_n, the ball's +z force, mean per interval), so
  /// a curve outlives a suite that is stopped and another binary's run can be judged against it.
  std::filesystem::path curves_dir;
  std::function<void(const std::string&)> log;  ///< progress (may be empty)

  /// The default suite: spheres 32, 64, 128, 256, the organ phantom, and the folded phantom
  /// held at its stem ("folded (stem)") and over its lower third ("folded (lower third)"); the
  /// configurations of docs/bench.md.
  [[nodiscard]] static ScaleBenchSettings standard();
  /// Configurations outside the suite, run only when `--scale-configs` names them: the fast
  /// configuration of larger models with one source of its regional error switched off
  /// (docs/bench.md, "Where the regional error comes from").
  [[nodiscard]] static std::vector<ScaleConfig> diagnostic_configs();
  /// Replaces the reference (symplectic Euler at its stable step, an hour on the organ) by the
  /// implicit integrator at 3 ms steps iterated to convergence (largest force imbalance below
  /// 1e-5 N, at most 30 iterations): the other converged reference, minutes there.
  void use_implicit_reference();
  /// Throws vx::Error for an empty or invalid suite.
  void validate() const;
};

struct ScaleRow {
  std::string model, config;
  int threads{1};
  std::int64_t elements{0}, nodes{0}, vertex_entries{0};
  double time_step_s{0.0};
  std::int64_t steps{0};
  double sim_s{0.0}, wall_s{0.0}, setup_s{0.0};
  double step_ms{0.0};  ///< wall time per step (after the first)
  double steps_per_sim_s{0.0};
  double real_time_factor{0.0};  ///< simulated / wall time (>= 1: real time)
  double rms_error_rel{-1.0};    ///< against the reference, fraction of its peak (-1: not measured)
  double peak_force_n{0.0};
  double added_mass_rel{0.0};  ///< mass scaling: added / physical mass
  bool complete{false};        ///< ran the whole press-and-slide
  bool stable{true};
  std::string note;
};

struct ScaleBenchResult {
  std::vector<ScaleRow> rows;
  double total_s{0.0};
};

[[nodiscard]] ScaleBenchResult run_scale_bench(const ScaleBenchSettings& settings);

/// The model's prepared scene (no probe yet): the phantom at its voxel size, gradational, its support
/// held (ScaleModelSpec::support). Throws vx::Error for an unknown support, or "stem" on a
/// phantom without one.
[[nodiscard]] PreparedScene prepare_scale_model(const ScaleModelSpec& model, const ScaleBenchSettings& settings);

/// The ball's path: 0.5 mm above the top along the press vertical (the highest node within the
/// ball's radius of it), pressed depth_mm in press_s, slid slide_mm along +x in slide_s.
[[nodiscard]] std::vector<PathKey> scale_palpation_path(const PreparedScene& prepared, const ScaleModelSpec& model,
                                                        const ScaleBenchSettings& settings);

/// Writes scale.csv, scale.md and scale.png (real-time factor against elements, one line per
/// configuration and thread count, with the real-time line) into `dir`; returns the names.
std::vector<std::string> write_scale_report(const ScaleBenchResult& result, const std::filesystem::path& dir);

/// The table of scale.md.
[[nodiscard]] std::string format_scale_table(const ScaleBenchResult& result);

}  // namespace vx
