#pragma once
/// @file step_benchmark.h
/// Time per step of each integrator on sphere phantoms of growing size (the library side of
/// `voxelastic bench` and of the Google Benchmark target voxelastic_bench_step).
///
/// Scenario: a ball of radius n/2 - 1 voxels in an n^3 grid, its lowest cap of nodes fixed,
/// under gravity, after a few warm-up steps (so the elements deform and the rotation fits
/// work every step). Reports wall time per step, per element and per vertex entry (the work
/// measure of docs/model.md section 3), the threads used, and the real-time factor dt / step time.

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "model/model.h"
#include "model/voxel_grid.h"
#include "physics/physics_model.h"
#include "sim/integrators.h"

namespace vx {

struct StepBenchmarkRow;

/// A ball phantom: ball_grid(n, n/2 - 1, voxel_mm) (model/voxel_shapes.h); throws for n < 4.
[[nodiscard]] VoxelGrid make_sphere_grid(int n, double voxel_mm = 1.0);
/// Its 2D analogue: a disk of radius n/2 - 1 pixels in an n x n x 1 grid (pixels and slice
/// thickness voxel_mm); throws for n < 4.
[[nodiscard]] VoxelGrid make_disk_grid(int n, double voxel_mm = 1.0);

/// "gradational", "uniform", "voxel", with "-2d" for a 2D row.
[[nodiscard]] std::string step_row_resolution(const StepBenchmarkRow& row);

/// The integrators a step benchmark times by default: explicit Euler, symplectic Euler, implicit.
/// (Out of line: GCC 12 warns, falsely, that an initializer list of this enum inlined into every
/// default-constructed settings may be read uninitialized.)
[[nodiscard]] std::vector<IntegratorKind> step_benchmark_integrators();

/// What to benchmark.
struct StepBenchmarkSettings {
  std::vector<int> sizes{32, 64, 128, 256};  ///< grid edges n (voxels)
  std::vector<IntegratorKind> integrators{step_benchmark_integrators()};
  Layout layout{Layout::gradational};
  /// 3: sphere phantoms; 2: the 2D model of a disk n pixels across (one slice of voxel_mm
  /// thickness, docs/model.md section 12), its lowest cap held, gravity in its plane (-y)
  int dimensions{3};
  Material material{5.0, 1000.0, 0.1, 0.0};           ///< soft tissue, E = 5 kPa
  ElementKind element{CalibrationOptions{}.element};  ///< the element (physics_model.h)
  double voxel_mm{1.0};
  int threads{0};          ///< 0: OpenMP default
  double min_time_s{0.5};  ///< time each case at least this long
  int min_steps{5};
  int warmup_steps{10};
  /// explicit integrators run at this fraction of their stable time step estimate
  double explicit_dt_fraction{0.5};
  double implicit_time_step_s{1e-3};  ///< the real-time target step
  int implicit_iterations{10};
  int implicit_max_size{128};                   ///< larger grids skip the implicit integrator (factorisation cost)
  std::function<void(const std::string&)> log;  ///< progress lines (may be empty)
};

/// One measured case.
struct StepBenchmarkRow {
  int size{0};
  IntegratorKind integrator{IntegratorKind::symplectic_euler};
  Layout layout{Layout::gradational};
  int dimensions{3};  ///< 2: the 2D disk (StepBenchmarkSettings::dimensions)
  int threads{0};
  int elements{0};
  int nodes{0};
  std::int64_t vertex_entries{0};
  double build_s{0};      ///< build_model + calibration, s
  double setup_s{0};      ///< first step (the implicit factorisation), s
  double time_step_s{0};  ///< simulated dt, s
  int steps{0};           ///< timed steps
  double step_s{0};       ///< wall time per step, s
  double ns_per_element{0};
  double ns_per_entry{0};
  double real_time_factor{0};       ///< dt / step time (>= 1: faster than real time)
  int iterations{0};                ///< implicit: iterations per step
  std::int64_t factor_nonzeros{0};  ///< implicit: nonzeros of the Cholesky factor
  bool skipped{false};
  std::string note;  ///< why skipped, or a failure message
};

/// Runs the cases (sizes x integrators). Throws vx::Error for invalid settings.
[[nodiscard]] std::vector<StepBenchmarkRow> run_step_benchmark(const StepBenchmarkSettings& settings);

/// A fixed-width text table of the rows.
[[nodiscard]] std::string format_step_benchmark(const std::vector<StepBenchmarkRow>& rows);

}  // namespace vx
