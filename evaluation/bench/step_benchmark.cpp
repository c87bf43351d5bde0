#include "bench/step_benchmark.h"

#include <chrono>
#include <cstdio>
#include <memory>
#include <sstream>

#include "base/error.h"
#include "base/parallel.h"
#include "model/gradational_builder.h"
#include "model/voxel_shapes.h"
#include "physics/calibration.h"
#include "sim/state.h"

namespace vx {

VoxelGrid make_sphere_grid(int n, double voxel_mm) {
  if (n < 4) throw Error("sphere grid: size " + std::to_string(n) + " must be >= 4");
  return ball_grid(n, 0.5 * n - 1.0, voxel_mm);
}

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

}  // namespace

VoxelGrid make_disk_grid(int n, double voxel_mm) {
  if (n < 4) throw Error("disk grid: size " + std::to_string(n) + " must be >= 4");
  GridGeometry g;
  g.dims = {n, n, 1};
  g.spacing_mm = Eigen::Vector3d::Constant(voxel_mm);
  VoxelGrid grid(g);
  const double c = 0.5 * n, r = 0.5 * n - 1.0;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      grid.set(i, j, 0, (i + 0.5 - c) * (i + 0.5 - c) + (j + 0.5 - c) * (j + 0.5 - c) <= r * r);
  return grid;
}

std::string step_row_resolution(const StepBenchmarkRow& row) {
  return std::string(to_string(row.layout)) + (row.dimensions == 2 ? "-2d" : "");
}

std::vector<IntegratorKind> step_benchmark_integrators() {
  return {IntegratorKind::explicit_euler, IntegratorKind::symplectic_euler, IntegratorKind::implicit};
}

std::vector<StepBenchmarkRow> run_step_benchmark(const StepBenchmarkSettings& set) {
  if (set.sizes.empty() || set.integrators.empty()) throw Error("step benchmark: no sizes or integrators");
  if (!(set.min_time_s >= 0) || set.min_steps < 1) throw Error("step benchmark: min_time_s >= 0 and min_steps >= 1");
  const auto log = [&](const std::string& s) {
    if (set.log) set.log(s);
  };
  std::vector<StepBenchmarkRow> rows;
  for (int n : set.sizes) {
    // model and calibration, shared by the integrators
    const Clock::time_point t0 = Clock::now();
    BuildSettings bs;
    bs.layout = set.layout;
    const bool flat = set.dimensions == 2;
    bs.dimensions = flat ? 2 : 3;
    auto model = std::make_shared<const Model>(
        build_model(flat ? make_disk_grid(n, set.voxel_mm) : make_sphere_grid(n, set.voxel_mm), bs));
    CalibrationOptions calibration;
    calibration.element = set.element;
    auto physics = make_physics_model(model, set.material, {}, calibration);
    const double build_s = seconds_since(t0);
    log((flat ? "2D disk " : "sphere ") + std::to_string(n) + ": " + std::to_string(model->num_elements()) +
        " elements, " + std::to_string(model->num_vertex_entries()) + " vertex entries, built in " +
        std::to_string(build_s) + " s");
    // the lowest cap (one voxel high) is held; gravity pulls (a 2D disk: along -y, in its plane)
    const int down = flat ? 1 : 2;
    const double low = model->rest_positions.row(down).minCoeff();
    Eigen::Vector3d cap_top = Eigen::Vector3d::Constant(1e30);
    cap_top(down) = low + set.voxel_mm * 1.01;
    const std::vector<int> cap = nodes_in_box(*model, Eigen::Vector3d::Constant(-1e30), cap_top);
    Eigen::Vector3d gravity = Eigen::Vector3d::Zero();
    gravity(down) = -kStandardGravityMmS2;
    for (IntegratorKind kind : set.integrators) {
      StepBenchmarkRow row;
      row.size = n;
      row.integrator = kind;
      row.layout = set.layout;
      row.dimensions = bs.dimensions;
      row.threads = resolve_threads(set.threads);
      row.elements = model->num_elements();
      row.nodes = model->num_nodes();
      row.vertex_entries = model->num_vertex_entries();
      row.build_s = build_s;
      if (kind == IntegratorKind::implicit && n > set.implicit_max_size) {
        row.skipped = true;
        row.note = "implicit skipped above size " + std::to_string(set.implicit_max_size);
        rows.push_back(row);
        continue;
      }
      SimState state = make_state(physics);
      state.fix_nodes(cap);
      state.gravity_mm_s2 = gravity;
      IntegratorSettings is;
      is.kind = kind;
      is.threads = set.threads;
      is.max_iterations = set.implicit_iterations;
      is.time_step_s = kind == IntegratorKind::implicit ? set.implicit_time_step_s
                                                        : set.explicit_dt_fraction * stable_time_step(*physics, kind);
      row.time_step_s = is.time_step_s;
      if (!(is.time_step_s > 0)) {
        row.skipped = true;
        row.note = std::string(to_string(kind)) + " has no stable time step (no damping)";
        rows.push_back(row);
        continue;
      }
      auto integ = make_integrator(is);
      Clock::time_point t = Clock::now();
      StepReport rep = integ->step(state);  // first step: the implicit factorisation
      row.setup_s = seconds_since(t);
      row.factor_nonzeros = rep.factor_nonzeros;
      integ->advance(state, set.warmup_steps);
      // timed steps
      int steps = 0;
      t = Clock::now();
      double elapsed = 0;
      while ((steps < set.min_steps || elapsed < set.min_time_s) && !state.failed()) {
        rep = integ->step(state);
        ++steps;
        elapsed = seconds_since(t);
      }
      row.steps = steps;
      row.step_s = elapsed / steps;
      row.ns_per_element = row.step_s * 1e9 / row.elements;
      row.ns_per_entry = row.step_s * 1e9 / double(row.vertex_entries);
      row.real_time_factor = row.time_step_s / row.step_s;
      row.iterations = rep.iterations;
      if (state.failed()) row.note = state.message;
      char line[256];
      std::snprintf(
          line, sizeof line, "  %-16s %9.3f ms/step  %6.2f ns/entry  dt %.2e s  real-time x%.3g  setup %.3f s%s",
          to_string(kind), row.step_s * 1e3, row.ns_per_entry, row.time_step_s, row.real_time_factor, row.setup_s,
          row.factor_nonzeros ? ("  nnz(L) " + std::to_string(row.factor_nonzeros)).c_str() : "");
      log(line);
      rows.push_back(row);
    }
  }
  return rows;
}

std::string format_step_benchmark(const std::vector<StepBenchmarkRow>& rows) {
  std::ostringstream out;
  char line[320];
  std::snprintf(line, sizeof line, "%5s %-16s %7s %8s %9s %3s %11s %10s %10s %9s %10s %5s %s\n", "n", "integrator",
                "elems", "nodes", "entries", "thr", "ms/step", "ns/elem", "ns/entry", "dt(ms)", "realtime", "iter",
                "note");
  out << line;
  for (const auto& r : rows) {
    if (r.skipped) {
      std::snprintf(line, sizeof line, "%5d %-16s %7d %8d %9lld %3d %s\n", r.size, to_string(r.integrator), r.elements,
                    r.nodes, static_cast<long long>(r.vertex_entries), r.threads, r.note.c_str());
    } else {
      std::snprintf(line, sizeof line, "%5d %-16s %7d %8d %9lld %3d %11.3f %10.1f %10.2f %9.4f %10.3g %5d %s\n", r.size,
                    to_string(r.integrator), r.elements, r.nodes, static_cast<long long>(r.vertex_entries), r.threads,
                    r.step_s * 1e3, r.ns_per_element, r.ns_per_entry, r.time_step_s * 1e3, r.real_time_factor,
                    r.iterations, r.note.c_str());
    }
    out << line;
  }
  return out.str();
}

}  // namespace vx
