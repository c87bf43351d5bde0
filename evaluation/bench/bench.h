#pragma once
/// @file bench.h
/// `voxelastic bench`: run time against error (issue 8) and the cost of one step (issue 4).
///
/// Part A, step cost: evaluation/bench/step_benchmark.h on sphere phantoms of growing size for every
/// resolution (gradational, uniform, voxel-level) and integrator, with the log-log slope of the
/// cost per step against the grid size n (the paper: gradational ~ n^2, voxel-level ~ n^3).
///
/// Part B, run time against error: one palpation scene (a ball pressed a few mm into the top of
/// a block fixed at its base, then lifted) discretised at several grid sizes n (voxels across
/// the block; the block's size in mm stays the same, so a larger n is a finer model), in each
/// resolution, with each integrator at several time steps. Every run records the probe's force
/// curve and its wall time per simulated second; its error is measured against a fine
/// reference (the voxel-level model of the largest size with a small step). The Pareto front of
/// error against run time and the best configuration for real time (lowest error at <= 1 wall
/// second per simulated second) come out of it.
///
/// Units: mm, s, N, kPa, kg/m^3; errors are fractions of the reference's peak force.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <limits>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <vector>

#include "bench/step_benchmark.h"
#include "model/model.h"
#include "physics/physics_model.h"
#include "sim/integrators.h"

namespace vx {

/// The palpation scene of part B: a block of `block_mm` x `block_mm` x `height_mm` (LPS x, y, z,
/// lowest corner at the origin) fixed at its base (z_min), a ball of `probe_radius_mm` starting
/// `gap_mm` above the top centre, pressed `depth_mm` into the tissue until `press_s`, then lifted
/// back to its start at `duration_s`. No gravity (the force is the tissue's response alone).
struct PalpationSceneSettings {
  double block_mm{32.0};
  double height_mm{16.0};
  double probe_radius_mm{5.0};
  double gap_mm{0.5};
  double depth_mm{3.0};
  double press_s{0.15};
  double duration_s{0.3};
  Material material{5.0, 1000.0, 0.1, 0.0};  ///< soft tissue, E = 5 kPa, damping ratio 0.1
  ElementKind element{CalibrationOptions{}.element};  ///< the element of every model (physics_model.h)
  double force_interval_s{2e-3};            ///< force curve sampling (rows average the steps between them)
};

/// The scene (the JSON of docs/scenes.md, runnable with `voxelastic simulate`) for a grid of `n`
/// voxels across the block (voxel = block_mm / n), in `resolution`, with `integrator` at
/// `time_step_s` (0: "auto"), on `threads` threads. Throws vx::Error when n is odd or below 4.
[[nodiscard]] nlohmann::json palpation_scene_json(const PalpationSceneSettings& scene, int n, Layout layout,
                                                  IntegratorKind integrator, double time_step_s, int threads);

/// A force curve: the force of the tissue on the probe along the pressing axis (+z, up), N.
struct ForceCurve {
  std::vector<double> time_s;
  std::vector<double> force_n;
};

/// How far a force curve is from the reference.
struct CurveError {
  double rms_rel{0.0};       ///< RMS of (force - reference) over the reference's samples / reference peak
  double max_abs_rel{0.0};   ///< largest |force - reference| / reference peak
  double peak_rel{0.0};      ///< (peak force - reference peak) / reference peak (signed)
};

/// Compares `curve` (linearly interpolated, held beyond its ends) with `reference` at the
/// reference's sample times. Throws vx::Error when either curve is empty, their lengths differ
/// from their times, or the reference's peak force is not positive.
[[nodiscard]] CurveError force_curve_error(const ForceCurve& curve, const ForceCurve& reference);

/// Largest force of a curve, N (0 when empty).
[[nodiscard]] double peak_force_n(const ForceCurve& curve);

/// How a run ended.
enum class BenchStatus : std::uint8_t { ok, unstable, skipped };
[[nodiscard]] const char* to_string(BenchStatus s);

/// One run of the palpation scene (one row of bench.csv).
struct BenchRow {
  int size{0};                       ///< n, voxels across the block
  double voxel_mm{0.0};
  Layout layout{Layout::gradational};
  IntegratorKind integrator{IntegratorKind::symplectic_euler};
  double time_step_s{0.0};
  double dt_fraction{std::numeric_limits<double>::quiet_NaN()};  ///< explicit schemes: dt / stable estimate
  double dt_stable_estimate_s{0.0};  ///< the integrator's estimate (infinity for implicit)
  int threads{1};
  int elements{0};
  int nodes{0};
  std::int64_t vertex_entries{0};
  double build_s{0.0};               ///< model and calibration, s (shared by a size's runs)
  double setup_s{0.0};               ///< first step (the implicit factorisation), s
  std::int64_t steps{0};             ///< steps taken
  double sim_time_s{0.0};            ///< simulated time reached, s
  double wall_s{0.0};                ///< wall time of the steps after the first, s
  double wall_per_sim_s{std::numeric_limits<double>::quiet_NaN()};  ///< wall s per simulated s (<= 1: real time)
  double peak_force_n{std::numeric_limits<double>::quiet_NaN()};
  CurveError error{std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::quiet_NaN(),
                   std::numeric_limits<double>::quiet_NaN()};
  BenchStatus status{BenchStatus::ok};
  std::string note;                  ///< why unstable or skipped
  bool pareto{false};                ///< on the Pareto front of error against wall time
  ForceCurve curve;                  ///< the force curve (not in the CSV)

  /// Stable and measured: a candidate for the Pareto front and the best configuration.
  [[nodiscard]] bool usable() const;
  /// "n=24 gradational symplectic_euler dt=0.5x (1.2e-04 s)".
  [[nodiscard]] std::string label() const;
};

/// Marks `pareto` on the usable rows no other usable row beats (wall_per_sim_s and rms error
/// both <= with one <); clears it on the rest. Returns the front's row indices by wall time.
std::vector<std::size_t> mark_pareto_front(std::vector<BenchRow>& rows);

/// The best configuration for real time: the usable row of lowest RMS error among those with
/// wall_per_sim_s <= `real_time_limit` (ties: the faster); when none is that fast, the usable
/// row with the lowest wall_per_sim_s. -1 when no row is usable. `real_time` says which case.
[[nodiscard]] int best_real_time_row(const std::vector<BenchRow>& rows, bool& real_time, double real_time_limit = 1.0);

/// Least-squares slope of log(y) against log(x) over the points with x, y > 0 (NaN when fewer
/// than two): the exponent p of y ~ x^p.
[[nodiscard]] double log_log_slope(const std::vector<double>& x, const std::vector<double>& y);

/// What `voxelastic bench` runs.
struct BenchSettings {
  bool quick{false};
  int threads{1};                                   ///< physics threads (>= 1)
  // part A
  bool run_step{true};
  std::vector<int> step_sizes{32, 64, 128, 256};    ///< sphere grid sizes
  int step_uniform_max_size{256};                   ///< larger uniform models are skipped
  int step_voxel_max_size{128};                     ///< larger voxel-level models are skipped (memory, time)
  int step_implicit_max_size{128};                  ///< gradational implicit up to this size
  int step_implicit_uniform_max_size{64};
  int step_implicit_voxel_max_size{32};
  double step_min_time_s{0.3};
  // part B
  bool run_palpation{true};
  PalpationSceneSettings scene;
  std::vector<int> sizes{16, 24, 32};               ///< palpation grid sizes n (even)
  std::vector<Layout> resolutions{Layout::gradational, Layout::uniform, Layout::voxel};
  std::vector<double> explicit_fractions{0.25, 0.5, 1.0, 1.5};  ///< of each explicit scheme's stable estimate
  std::vector<double> implicit_steps_s{0.5e-3, 1e-3, 2e-3, 5e-3};
  int implicit_iterations{10};
  int reference_size{48};                           ///< the reference: voxel-level at this size...
  double reference_fraction{0.25};                  ///< ...symplectic Euler at this fraction of its estimate
  /// ...with this element (unset: scene.element, the runs' element)
  std::optional<ElementKind> reference_element;
  double max_run_s{90.0};                           ///< runs predicted longer than this are skipped (noted)
  std::function<void(const std::string&)> log;      ///< progress lines (may be empty)

  /// The --quick settings: step sizes 32, 64; palpation sizes 16, 24, reference 32; fewer steps.
  static BenchSettings quick_settings();
  /// Throws vx::Error for invalid settings (sizes, threads, steps).
  void validate() const;
};

/// Everything a bench produced.
struct BenchResult {
  BenchSettings settings;
  std::vector<StepBenchmarkRow> step_rows;          ///< part A, every resolution
  std::vector<BenchRow> rows;                        ///< part B
  BenchRow reference;                                ///< part B's reference run
  std::vector<std::size_t> pareto;                   ///< part B's front, by wall time
  int best{-1};                                      ///< part B's best for real time (-1: none)
  bool best_is_real_time{false};
  /// Part A: log-log slope of the explicit step time against n, per resolution (NaN: too few sizes).
  double step_slope_gradational{0}, step_slope_uniform{0}, step_slope_voxel{0};
  double total_s{0.0};                               ///< wall time of the whole bench
  std::vector<std::string> notes;                    ///< what was skipped and why
};

/// Runs part A and part B. Throws vx::Error for invalid settings or a scene that cannot be
/// built; unstable runs are rows, not errors.
[[nodiscard]] BenchResult run_bench(const BenchSettings& settings);

/// Part A's rows as step.csv text (header + one row per case).
[[nodiscard]] std::string step_csv(const std::vector<StepBenchmarkRow>& rows);
/// Part B's rows as bench.csv text (header + one row per run).
[[nodiscard]] std::string bench_csv(const std::vector<BenchRow>& rows);
/// The column names of bench.csv, in order.
[[nodiscard]] const std::vector<std::string>& bench_csv_columns();
/// bench.json: settings, the reference (with its curve), every row, the front, the best.
[[nodiscard]] nlohmann::json bench_json(const BenchResult& result);
/// bench.md: the summary a person reads (the best configuration, a table per resolution).
[[nodiscard]] std::string bench_markdown(const BenchResult& result);
/// The one-paragraph conclusion (stdout and bench.md): which configuration is best for real time.
[[nodiscard]] std::string best_statement(const BenchResult& result);

/// Writes step.csv, step.png, bench.csv, bench.json, bench.md, bench_error.png, bench_cost.png,
/// bench_curves.png (those of the parts that ran) into `dir`, all or nothing: every file is
/// first written into a staging folder inside `dir`, then moved into place. Throws vx::Error.
/// Returns the names written.
std::vector<std::string> write_bench_report(const BenchResult& result, const std::filesystem::path& dir);

}  // namespace vx
