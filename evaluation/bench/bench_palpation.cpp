// Part B of `voxelastic bench`: run time against error. One palpation scene (a ball pressed into
// a block and lifted) at several grid sizes, in each layout, with each integrator at several
// time steps; every run's force curve is scored against a fine reference run (bench_metrics.cpp).
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>
#include <utility>

#include "base/error.h"
#include "bench/bench_parts.h"
#include "haptics/device_side.h"
#include "scene/scene.h"
#include "scene/sim_output.h"
#include "sim/simulation.h"
#include "sim/time_step.h"

namespace vx {
namespace fs = std::filesystem;
using json = nlohmann::json;

json palpation_scene_json(const PalpationSceneSettings& s, int n, Layout layout, IntegratorKind integrator,
                          double time_step_s, int threads) {
  if (n < 4 || n % 2 != 0) throw Error(fmt::format("bench: palpation size {} must be even and >= 4", n));
  const double voxel = s.block_mm / n;
  const double c = 0.5 * s.block_mm;
  const double z0 = s.height_mm + s.probe_radius_mm + s.gap_mm;
  const double z1 = s.height_mm + s.probe_radius_mm - s.depth_mm;
  json j;
  j["description"] = fmt::format(
      "voxelastic bench palpation: a {:g} mm ball pressed {:g} mm into a {:g} x {:g} x {:g} mm block of {:g} kPa fixed at "
      "its base until {:g} s, lifted back by {:g} s; {} voxels across ({:.4g} mm), {} layout",
      s.probe_radius_mm, s.depth_mm, s.block_mm, s.block_mm, s.height_mm, s.material.youngs_modulus_kpa, s.press_s,
      s.duration_s, n, voxel, to_string(layout));
  j["object"] = {{"box_mm", {{"min", {0.0, 0.0, 0.0}}, {"max", {s.block_mm, s.block_mm, s.height_mm}}}},
                 {"voxel_mm", voxel},
                 {"resolution", to_string(layout)}};
  j["material"] = {{"youngs_modulus_kpa", s.material.youngs_modulus_kpa},
                   {"poisson_ratio", s.material.poisson_ratio},
                   {"density_kg_m3", s.material.density_kg_m3},
                   {"damping", s.material.damping_ratio},
                   {"element", to_string(s.element)}};
  j["fixed"] = {"z_min"};
  j["integrator"] = {{"type", to_string(integrator)}, {"dt_s", time_step_s > 0 ? json(time_step_s) : json("auto")}};
  j["probes"] = json::array({{{"name", "tip"},
                              {"shape", "sphere"},
                              {"radius_mm", s.probe_radius_mm},
                              {"path",
                               {{{"t_s", 0.0}, {"position_mm", {c, c, z0}}},
                                {{"t_s", s.press_s}, {"position_mm", {c, c, z1}}},
                                {{"t_s", s.duration_s}, {"position_mm", {c, c, z0}}}}}}});
  j["duration_s"] = s.duration_s;
  j["threads"] = threads;
  j["outputs"] = {{"forces_csv", true}, {"forces_interval_s", s.force_interval_s}, {"plot", true}};
  return j;
}

namespace bench_parts {
namespace {

/// The time steps a bench runs for one integrator on one model.
std::vector<std::pair<double, double>> time_steps(const BenchSettings& set, IntegratorKind kind,
                                                  const TimeStepEstimate& est) {
  std::vector<std::pair<double, double>> out;  // (dt, fraction)
  if (kind == IntegratorKind::implicit) {
    for (double dt : set.implicit_steps_s) out.emplace_back(dt, kNaN);
    return out;
  }
  const double limit = est.limit(kind);
  if (limit > 0)
    for (double f : set.explicit_fractions) out.emplace_back(f * limit, f);
  return out;
}

/// Runs the prepared palpation scene with `kind` at `dt` and fills the run part of `row`.
void run_palpation(const PreparedScene& prepared, const BenchSettings& set, IntegratorKind kind, double dt,
                   BenchRow& row) {
  SimulationSettings ss = prepared.settings;
  ss.integrator.kind = kind;
  ss.integrator.time_step_s = dt;
  ss.integrator.threads = set.threads;
  ss.integrator.max_iterations = set.implicit_iterations;
  Simulation sim(prepared.physics, ss);
  const DeviceSide device(sim, prepared.device_side);
  ForceRecorder recorder(sim, &device, set.scene.force_interval_s);
  const std::int64_t steps = std::max<std::int64_t>(1, std::int64_t(std::ceil(set.scene.duration_s / dt - 1e-9)));

  Clock::time_point t = Clock::now();
  StepStatus status = sim.step();  // the implicit factorisation happens here
  row.setup_s = seconds_since(t);
  if (status == StepStatus::ok) recorder.record(sim);
  t = Clock::now();
  bool predicted = false;
  for (std::int64_t k = 2; k <= steps && status == StepStatus::ok; ++k) {
    status = sim.step();
    if (status != StepStatus::ok) break;
    recorder.record(sim);
    if (!predicted && (k >= 40 || (k >= 3 && seconds_since(t) > 1.0))) {
      // the time budget: a run predicted to take too long is stopped, not waited for
      predicted = true;
      const double expect_s = row.setup_s + seconds_since(t) / double(k - 1) * double(steps - 1);
      if (expect_s > set.max_run_s) {
        row.status = BenchStatus::skipped;
        row.note = fmt::format("predicted {:.0f} s for {} steps, over the {:g} s budget per run", expect_s, steps,
                               set.max_run_s);
        row.steps = k;
        return;
      }
    }
  }
  row.wall_s = seconds_since(t);
  recorder.finish(sim);
  row.steps = sim.steps();
  row.sim_time_s = sim.time_s();
  if (status != StepStatus::ok || sim.failed() || !sim.state().positions.allFinite()) {
    row.status = BenchStatus::unstable;
    row.note = sim.state().message.empty() ? std::string("non-finite state") : sim.state().message;
  }
  row.wall_per_sim_s = row.steps > 1 ? row.wall_s / (row.sim_time_s - dt) : row.setup_s / std::max(dt, row.sim_time_s);
  for (const ForceRow& r : recorder.rows()) {
    if (r.probe != 0) continue;
    row.curve.time_s.push_back(r.time_s);
    row.curve.force_n.push_back(r.raw_n.z());
  }
  for (double f : row.curve.force_n)
    if (!std::isfinite(f)) {
      row.status = BenchStatus::unstable;
      if (row.note.empty()) row.note = "non-finite probe force";
      break;
    }
  row.peak_force_n = row.status == BenchStatus::unstable ? kNaN : peak_force_n(row.curve);
}

/// The scene of one size and resolution, prepared (model built and calibrated).
PreparedScene prepare_palpation(const BenchSettings& set, int n, Layout r) {
  const json j = palpation_scene_json(set.scene, n, r, IntegratorKind::symplectic_euler, 0.0, set.threads);
  const Scene scene = parse_scene(j, fs::current_path(), fmt::format("palpation scene n={} {}", n, to_string(r)));
  return prepare_scene(scene);
}

/// Fills the model part of a row.
void describe_model(const PreparedScene& p, int n, double build_s, int threads, BenchRow& row) {
  row.size = n;
  row.voxel_mm = p.model->grid.spacing_mm.x();
  row.layout = p.model->layout;
  row.threads = threads;
  row.elements = p.model->num_elements();
  row.nodes = p.model->num_nodes();
  row.vertex_entries = p.model->num_vertex_entries();
  row.build_s = build_s;
}

/// Part B's progress: "[bench 3/40] label: figures (time)" after each run.
class RunProgress {
 public:
  RunProgress(const BenchSettings& set, const Log& log) : log_(log) {
    // count the runs: time steps depend on each model's estimate, but their number does not
    std::size_t per_model = 0;
    for (IntegratorKind kind : kIntegrators) per_model += runs_per_model(set, kind);
    total_ = 1 + set.sizes.size() * set.resolutions.size() * per_model;
  }
  /// The runs of `kind` on one model.
  static std::size_t runs_per_model(const BenchSettings& set, IntegratorKind kind) {
    return kind == IntegratorKind::implicit ? set.implicit_steps_s.size() : set.explicit_fractions.size();
  }
  /// Counts runs that were not made (no stable step).
  void skip(std::size_t runs) { done_ += runs; }
  /// Counts a run and logs its outcome.
  void report(const BenchRow& row, double seconds) {
    ++done_;
    std::string what;
    if (row.status == BenchStatus::ok)
      what = std::isfinite(row.error.rms_rel)
                 ? fmt::format("{:.3g} s per simulated s, peak {:.4g} N, RMS error {:.2f} %", row.wall_per_sim_s,
                               row.peak_force_n, 100 * row.error.rms_rel)
                 : fmt::format("{:.3g} s per simulated s, peak {:.4g} N", row.wall_per_sim_s, row.peak_force_n);
    else
      what = fmt::format("{}: {}", to_string(row.status), row.note);
    log_(fmt::format("[bench {}/{}] {}: {} ({})", done_, total_, row.label(), what, seconds_text(seconds)));
  }

 private:
  const Log& log_;
  std::size_t total_{0};
  std::size_t done_{0};
};

/// The reference run (voxel-level at the reference size, symplectic Euler at a fraction of its
/// stable step, no time budget) into res.reference; throws vx::Error when it fails.
void run_reference(const BenchSettings& set, BenchResult& res, const Log& log, RunProgress& progress) {
  const Clock::time_point t = Clock::now();
  BenchSettings with_element = set;
  if (set.reference_element) with_element.scene.element = *set.reference_element;
  const PreparedScene p = prepare_palpation(with_element, set.reference_size, Layout::voxel);
  const double build_s = seconds_since(t);
  const TimeStepEstimate est = estimate_time_steps(*p.physics);
  BenchRow& ref = res.reference;
  describe_model(p, set.reference_size, build_s, set.threads, ref);
  ref.integrator = IntegratorKind::symplectic_euler;
  ref.dt_stable_estimate_s = est.limit(ref.integrator);
  ref.dt_fraction = set.reference_fraction;
  ref.time_step_s = set.reference_fraction * ref.dt_stable_estimate_s;
  log(fmt::format("[bench] reference: voxel-level model of {} voxels across ({} elements, {} vertex entries, {} "
                  "element), symplectic Euler at {:.2e} s",
                  set.reference_size, ref.elements, ref.vertex_entries, to_string(with_element.scene.element),
                  ref.time_step_s));
  BenchSettings unlimited = set;
  unlimited.max_run_s = std::numeric_limits<double>::infinity();  // the reference must run
  run_palpation(p, unlimited, ref.integrator, ref.time_step_s, ref);
  if (ref.status != BenchStatus::ok || !(ref.peak_force_n > 0))
    throw Error(fmt::format("bench: the reference run failed ({}); nothing to compare with",
                            ref.note.empty() ? "no force on the probe" : ref.note));
  ref.error = CurveError{0.0, 0.0, 0.0};
  progress.report(ref, seconds_since(t));
}

/// Every integrator at each of its time steps on the model of size `n` in `layout`, scored
/// against the reference, into res.rows.
void run_model(const BenchSettings& set, int n, Layout layout, BenchResult& res, RunProgress& progress) {
  const Clock::time_point tb = Clock::now();
  const PreparedScene p = prepare_palpation(set, n, layout);
  const double build_s = seconds_since(tb);
  const TimeStepEstimate est = estimate_time_steps(*p.physics);
  for (IntegratorKind kind : kIntegrators) {
    const auto steps = time_steps(set, kind, est);
    if (steps.empty()) {
      res.notes.push_back(fmt::format("n={} {}: {} has no stable time step (no damping)", n, to_string(layout),
                                      to_string(kind)));
      progress.skip(RunProgress::runs_per_model(set, kind));
    }
    for (const auto& [dt, fraction] : steps) {
      const Clock::time_point t = Clock::now();
      BenchRow row;
      describe_model(p, n, build_s, set.threads, row);
      row.integrator = kind;
      row.time_step_s = dt;
      row.dt_fraction = fraction;
      row.dt_stable_estimate_s = est.limit(kind);
      run_palpation(p, set, kind, dt, row);
      if (row.status == BenchStatus::ok) row.error = force_curve_error(row.curve, res.reference.curve);
      if (row.status == BenchStatus::skipped) res.notes.push_back(row.label() + ": " + row.note);
      progress.report(row, seconds_since(t));
      res.rows.push_back(std::move(row));
    }
  }
}

}  // namespace

void run_palpation_part(const BenchSettings& set, BenchResult& res, const Log& log) {
  RunProgress progress(set, log);
  // the reference first: every error is measured against it
  run_reference(set, res, log, progress);
  for (int n : set.sizes)
    for (Layout layout : set.resolutions) run_model(set, n, layout, res, progress);
  res.pareto = mark_pareto_front(res.rows);
  res.best = best_real_time_row(res.rows, res.best_is_real_time);
}

}  // namespace bench_parts
}  // namespace vx
