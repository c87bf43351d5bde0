#include "bench/bench.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <thread>

#include "base/error.h"
#include "base/parallel.h"
#include "render/plot.h"
#include "scene/scene.h"
#include "scene/sim_output.h"
#include "sim/simulation.h"
#include "util/atomic_file.h"

namespace vx {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// A number for JSON: null when not finite.
json num(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

/// A number for CSV: empty when not finite.
std::string csv_num(double v) { return std::isfinite(v) ? fmt::format("{:.6g}", v) : std::string(); }

/// A CSV field, quoted when it holds a comma, a quote or a line break.
std::string csv_text(const std::string& s) {
  if (s.find_first_of(",\"\n\r") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) out += c == '"' ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

/// "0.5x" for explicit schemes, "" for implicit.
std::string fraction_text(double f) { return std::isfinite(f) ? fmt::format("{:g}x", f) : std::string(); }

/// The colour of a resolution in every plot.
const char* resolution_color(Layout r) {
  switch (r) {
    case Layout::gradational: return "#1f77b4";
    case Layout::uniform: return "#2ca02c";
    case Layout::voxel: return "#d62728";
  }
  return "black";
}

/// A shade of a resolution's colour for size number `i` of `count` (light: small, dark: large).
std::string resolution_shade(Layout r, std::size_t i, std::size_t count) {
  // light and dark ends per resolution (ColorBrewer blues, greens, reds)
  static const int light[3][3] = {{0x9e, 0xca, 0xe1}, {0xa1, 0xd9, 0x9b}, {0xfc, 0x92, 0x72}};
  static const int dark[3][3] = {{0x08, 0x30, 0x6b}, {0x00, 0x44, 0x1b}, {0x67, 0x00, 0x0d}};
  const int k = int(r);
  const double w = count > 1 ? double(i) / double(count - 1) : 0.6;
  int c[3];
  for (int a = 0; a < 3; ++a) c[a] = int(std::lround(light[k][a] + w * (dark[k][a] - light[k][a])));
  return fmt::format("#{:02x}{:02x}{:02x}", c[0], c[1], c[2]);
}

/// The point type of an integrator in every plot.
int integrator_point(IntegratorKind k) {
  switch (k) {
    case IntegratorKind::explicit_euler: return 9;     // triangle
    case IntegratorKind::symplectic_euler: return 13;  // diamond
    case IntegratorKind::implicit: return 5;           // square
  }
  return 7;
}

const std::vector<IntegratorKind> kIntegrators{IntegratorKind::explicit_euler, IntegratorKind::symplectic_euler,
                                               IntegratorKind::implicit};

/// An integrator's name for plots (gnuplot's enhanced text reads '_' as a subscript).
const char* integrator_title(IntegratorKind k) {
  switch (k) {
    case IntegratorKind::explicit_euler: return "explicit Euler";
    case IntegratorKind::symplectic_euler: return "symplectic Euler";
    case IntegratorKind::implicit: return "implicit";
  }
  return "?";
}

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
  ForceRecorder recorder(sim, set.scene.force_interval_s);
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

std::string seconds_text(double s) { return s < 100 ? fmt::format("{:.1f} s", s) : fmt::format("{:.0f} s", s); }

}  // namespace

// --- scene and metrics -----------------------------------------------------------------------

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
                   {"damping", s.material.damping_ratio}};
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

double peak_force_n(const ForceCurve& curve) {
  double peak = 0.0;
  for (double f : curve.force_n) peak = std::max(peak, f);
  return peak;
}

CurveError force_curve_error(const ForceCurve& curve, const ForceCurve& ref) {
  if (curve.time_s.empty() || ref.time_s.empty()) throw Error("force curve error: an empty curve");
  if (curve.time_s.size() != curve.force_n.size() || ref.time_s.size() != ref.force_n.size())
    throw Error("force curve error: times and forces differ in length");
  const double ref_peak = peak_force_n(ref);
  if (!(ref_peak > 0)) throw Error("force curve error: the reference has no positive force");
  // linear interpolation of `curve` at time t, held beyond its ends (its times increase)
  std::size_t j = 0;
  auto at = [&](double t) {
    const auto& x = curve.time_s;
    const auto& y = curve.force_n;
    if (t <= x.front()) return y.front();
    if (t >= x.back()) return y.back();
    while (j + 1 < x.size() && x[j + 1] < t) ++j;
    const double w = x[j + 1] > x[j] ? (t - x[j]) / (x[j + 1] - x[j]) : 1.0;
    return y[j] + w * (y[j + 1] - y[j]);
  };
  double sum2 = 0.0, max_abs = 0.0;
  for (std::size_t i = 0; i < ref.time_s.size(); ++i) {
    const double d = at(ref.time_s[i]) - ref.force_n[i];
    sum2 += d * d;
    max_abs = std::max(max_abs, std::abs(d));
  }
  CurveError e;
  e.rms_rel = std::sqrt(sum2 / double(ref.time_s.size())) / ref_peak;
  e.max_abs_rel = max_abs / ref_peak;
  e.peak_rel = (peak_force_n(curve) - ref_peak) / ref_peak;
  return e;
}

const char* to_string(BenchStatus s) {
  switch (s) {
    case BenchStatus::ok: return "ok";
    case BenchStatus::unstable: return "unstable";
    case BenchStatus::skipped: return "skipped";
  }
  return "?";
}

bool BenchRow::usable() const {
  return status == BenchStatus::ok && std::isfinite(wall_per_sim_s) && std::isfinite(error.rms_rel);
}

std::string BenchRow::label() const {
  if (integrator == IntegratorKind::implicit)
    return fmt::format("n={} {} implicit dt={:g} ms", size, to_string(layout), time_step_s * 1e3);
  return fmt::format("n={} {} {} dt={} ({:.2e} s)", size, to_string(layout), to_string(integrator),
                     fraction_text(dt_fraction), time_step_s);
}

std::vector<std::size_t> mark_pareto_front(std::vector<BenchRow>& rows) {
  std::vector<std::size_t> front;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    rows[i].pareto = false;
    if (!rows[i].usable()) continue;
    const double wi = rows[i].wall_per_sim_s, ei = rows[i].error.rms_rel;
    bool dominated = false;
    for (std::size_t j = 0; j < rows.size() && !dominated; ++j) {
      if (j == i || !rows[j].usable()) continue;
      const double wj = rows[j].wall_per_sim_s, ej = rows[j].error.rms_rel;
      dominated = wj <= wi && ej <= ei && (wj < wi || ej < ei);
    }
    if (!dominated) {
      rows[i].pareto = true;
      front.push_back(i);
    }
  }
  std::sort(front.begin(), front.end(), [&](std::size_t a, std::size_t b) {
    return rows[a].wall_per_sim_s < rows[b].wall_per_sim_s ||
           (rows[a].wall_per_sim_s == rows[b].wall_per_sim_s && rows[a].error.rms_rel < rows[b].error.rms_rel);
  });
  return front;
}

int best_real_time_row(const std::vector<BenchRow>& rows, bool& real_time, double limit) {
  int best = -1, fastest = -1;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const BenchRow& r = rows[i];
    if (!r.usable()) continue;
    if (fastest < 0 || r.wall_per_sim_s < rows[std::size_t(fastest)].wall_per_sim_s) fastest = int(i);
    if (r.wall_per_sim_s > limit) continue;
    if (best < 0) {
      best = int(i);
      continue;
    }
    const BenchRow& b = rows[std::size_t(best)];
    if (r.error.rms_rel < b.error.rms_rel || (r.error.rms_rel == b.error.rms_rel && r.wall_per_sim_s < b.wall_per_sim_s))
      best = int(i);
  }
  real_time = best >= 0;
  return best >= 0 ? best : fastest;
}

double log_log_slope(const std::vector<double>& x, const std::vector<double>& y) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int k = 0;
  for (std::size_t i = 0; i < x.size() && i < y.size(); ++i) {
    if (!(x[i] > 0) || !(y[i] > 0) || !std::isfinite(x[i]) || !std::isfinite(y[i])) continue;
    const double lx = std::log(x[i]), ly = std::log(y[i]);
    sx += lx;
    sy += ly;
    sxx += lx * lx;
    sxy += lx * ly;
    ++k;
  }
  if (k < 2) return kNaN;
  const double d = k * sxx - sx * sx;
  return std::abs(d) > 1e-300 ? (k * sxy - sx * sy) / d : kNaN;
}

// --- settings -----------------------------------------------------------------------------

BenchSettings BenchSettings::quick_settings() {
  BenchSettings s;
  s.quick = true;
  s.step_sizes = {32, 64};
  s.step_uniform_max_size = 64;
  s.step_voxel_max_size = 64;
  s.step_implicit_max_size = 64;
  s.step_implicit_uniform_max_size = 32;
  s.step_implicit_voxel_max_size = 16;  // none: its factorisation takes 10 s at 32
  s.step_min_time_s = 0.2;
  s.sizes = {16, 24};
  s.explicit_fractions = {0.5, 1.0, 1.5};
  s.implicit_steps_s = {1e-3, 2e-3, 5e-3};
  s.reference_size = 32;
  s.max_run_s = 15.0;
  return s;
}

void BenchSettings::validate() const {
  if (threads < 1) throw Error(fmt::format("bench: threads must be >= 1 (got {})", threads));
  if (!run_step && !run_palpation) throw Error("bench: nothing to run (both parts are off)");
  if (run_step) {
    if (step_sizes.empty()) throw Error("bench: no step benchmark sizes");
    for (int n : step_sizes)
      if (n < 8 || n > 512) throw Error(fmt::format("bench: step benchmark size {} must be in 8..512", n));
    if (!(step_min_time_s >= 0)) throw Error("bench: step_min_time_s must be >= 0");
  }
  if (run_palpation) {
    if (sizes.empty()) throw Error("bench: no palpation sizes");
    for (int n : sizes)
      if (n < 8 || n > 256 || n % 2 != 0)
        throw Error(fmt::format("bench: palpation size {} must be even and in 8..256 (voxels across the block)", n));
    if (reference_size < 8 || reference_size > 256 || reference_size % 2 != 0)
      throw Error(fmt::format("bench: reference size {} must be even and in 8..256", reference_size));
    if (resolutions.empty()) throw Error("bench: no resolutions");
    for (double f : explicit_fractions)
      if (!(f > 0 && f <= 10)) throw Error(fmt::format("bench: time step fraction {} must be in (0, 10]", f));
    for (double dt : implicit_steps_s)
      if (!(dt > 0 && dt <= 0.05)) throw Error(fmt::format("bench: implicit time step {} s must be in (0, 0.05]", dt));
    if (!(reference_fraction > 0 && reference_fraction <= 1))
      throw Error("bench: the reference's time step fraction must be in (0, 1]");
    if (!(max_run_s > 0)) throw Error("bench: max_run_s must be > 0");
    if (implicit_iterations < 1) throw Error("bench: implicit_iterations must be >= 1");
    const PalpationSceneSettings& s = scene;
    if (!(s.depth_mm > 0 && s.depth_mm < s.height_mm && s.probe_radius_mm > 0 && s.press_s > 0 &&
          s.duration_s > s.press_s && s.force_interval_s > 0))
      throw Error("bench: the palpation scene's depth, radius and times are inconsistent");
  }
}

// --- the bench ----------------------------------------------------------------------------

BenchResult run_bench(const BenchSettings& set) {
  set.validate();
  const Clock::time_point t_all = Clock::now();
  const auto log = [&](const std::string& s) {
    if (set.log) set.log(s);
  };
  BenchResult res;
  res.settings = set;
  res.settings.log = nullptr;

  // ---- part A: one step on sphere phantoms, every resolution
  if (set.run_step) {
    struct Part {
      Layout r;
      int max_size, implicit_max;
    };
    const std::vector<Part> parts{{Layout::gradational, 1 << 30, set.step_implicit_max_size},
                                  {Layout::uniform, set.step_uniform_max_size, set.step_implicit_uniform_max_size},
                                  {Layout::voxel, set.step_voxel_max_size, set.step_implicit_voxel_max_size}};
    int k = 0;
    for (const Part& p : parts) {
      ++k;
      StepBenchmarkSettings ss;
      ss.layout = p.r;
      ss.threads = set.threads;
      ss.min_time_s = set.step_min_time_s;
      ss.implicit_max_size = p.implicit_max;
      ss.sizes.clear();
      for (int n : set.step_sizes)
        if (n <= p.max_size) ss.sizes.push_back(n);
      ss.log = [&](const std::string& line) { log("[step " + std::to_string(k) + "/3 " + to_string(p.r) + "] " + line); };
      log(fmt::format("[step {}/3] {} models, sphere sizes {}", k, to_string(p.r), fmt::join(ss.sizes, ", ")));
      const Clock::time_point t = Clock::now();
      std::vector<StepBenchmarkRow> rows;
      if (!ss.sizes.empty()) rows = run_step_benchmark(ss);
      for (int n : set.step_sizes) {
        if (n <= p.max_size) continue;
        for (IntegratorKind kind : ss.integrators) {
          StepBenchmarkRow row;
          row.size = n;
          row.integrator = kind;
          row.layout = p.r;
          row.threads = set.threads;
          row.skipped = true;
          row.note = fmt::format("{} models skipped above size {} (time and memory)", to_string(p.r), p.max_size);
          rows.push_back(row);
        }
        res.notes.push_back(fmt::format("step benchmark: the {} model of the {}^3 sphere was skipped (above size {}: time "
                                        "and memory)",
                                        to_string(p.r), n, p.max_size));
        log(res.notes.back());
      }
      for (const auto& row : rows)
        if (row.skipped && row.integrator == IntegratorKind::implicit && row.size <= p.max_size)
          res.notes.push_back(fmt::format("step benchmark: implicit on the {} model of the {}^3 sphere skipped (the "
                                          "factorisation above size {})",
                                          to_string(p.r), row.size, p.implicit_max));
      log(fmt::format("[step {}/3] {} done in {}", k, to_string(p.r), seconds_text(seconds_since(t))));
      res.step_rows.insert(res.step_rows.end(), rows.begin(), rows.end());
    }
    auto slope = [&](Layout r) {
      std::vector<double> x, y;
      for (const auto& row : res.step_rows)
        if (row.layout == r && row.integrator == IntegratorKind::explicit_euler && !row.skipped && row.step_s > 0) {
          x.push_back(row.size);
          y.push_back(row.step_s);
        }
      return log_log_slope(x, y);
    };
    res.step_slope_gradational = slope(Layout::gradational);
    res.step_slope_uniform = slope(Layout::uniform);
    res.step_slope_voxel = slope(Layout::voxel);
  }

  // ---- part B: run time against error on the palpation scene
  if (set.run_palpation) {
    // count the runs: time steps depend on each model's estimate, but their number does not
    std::size_t per_model = 0;
    for (IntegratorKind kind : kIntegrators)
      per_model += kind == IntegratorKind::implicit ? set.implicit_steps_s.size() : set.explicit_fractions.size();
    const std::size_t total = 1 + set.sizes.size() * set.resolutions.size() * per_model;
    std::size_t done = 0;
    auto report = [&](const BenchRow& row, double seconds) {
      ++done;
      std::string what;
      if (row.status == BenchStatus::ok)
        what = std::isfinite(row.error.rms_rel)
                   ? fmt::format("{:.3g} s per simulated s, peak {:.4g} N, RMS error {:.2f} %", row.wall_per_sim_s,
                                 row.peak_force_n, 100 * row.error.rms_rel)
                   : fmt::format("{:.3g} s per simulated s, peak {:.4g} N", row.wall_per_sim_s, row.peak_force_n);
      else
        what = fmt::format("{}: {}", to_string(row.status), row.note);
      log(fmt::format("[bench {}/{}] {}: {} ({})", done, total, row.label(), what, seconds_text(seconds)));
    };

    // the reference first: every error is measured against it
    {
      const Clock::time_point t = Clock::now();
      const PreparedScene p = prepare_palpation(set, set.reference_size, Layout::voxel);
      const double build_s = seconds_since(t);
      const TimeStepEstimate est = estimate_time_steps(*p.physics);
      BenchRow& ref = res.reference;
      describe_model(p, set.reference_size, build_s, set.threads, ref);
      ref.integrator = IntegratorKind::symplectic_euler;
      ref.dt_stable_estimate_s = est.limit(ref.integrator);
      ref.dt_fraction = set.reference_fraction;
      ref.time_step_s = set.reference_fraction * ref.dt_stable_estimate_s;
      log(fmt::format("[bench] reference: voxel-level model of {} voxels across ({} elements, {} vertex entries), "
                      "symplectic Euler at {:.2e} s",
                      set.reference_size, ref.elements, ref.vertex_entries, ref.time_step_s));
      BenchSettings unlimited = set;
      unlimited.max_run_s = std::numeric_limits<double>::infinity();  // the reference must run
      run_palpation(p, unlimited, ref.integrator, ref.time_step_s, ref);
      if (ref.status != BenchStatus::ok || !(ref.peak_force_n > 0))
        throw Error(fmt::format("bench: the reference run failed ({}); nothing to compare with",
                                ref.note.empty() ? "no force on the probe" : ref.note));
      ref.error = CurveError{0.0, 0.0, 0.0};
      report(ref, seconds_since(t));
    }

    for (int n : set.sizes)
      for (Layout r : set.resolutions) {
        const Clock::time_point tb = Clock::now();
        const PreparedScene p = prepare_palpation(set, n, r);
        const double build_s = seconds_since(tb);
        const TimeStepEstimate est = estimate_time_steps(*p.physics);
        for (IntegratorKind kind : kIntegrators) {
          const auto steps = time_steps(set, kind, est);
          if (steps.empty()) {
            res.notes.push_back(fmt::format("n={} {}: {} has no stable time step (no damping)", n, to_string(r),
                                            to_string(kind)));
            done += kind == IntegratorKind::implicit ? set.implicit_steps_s.size() : set.explicit_fractions.size();
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
            report(row, seconds_since(t));
            res.rows.push_back(std::move(row));
          }
        }
      }
    res.pareto = mark_pareto_front(res.rows);
    res.best = best_real_time_row(res.rows, res.best_is_real_time);
  }
  res.total_s = seconds_since(t_all);
  return res;
}

// --- outputs ------------------------------------------------------------------------------

std::string step_csv(const std::vector<StepBenchmarkRow>& rows) {
  std::ostringstream out;
  out << "resolution,size,integrator,threads,elements,nodes,vertex_entries,build_s,setup_s,time_step_s,steps,step_ms,"
         "ns_per_element,ns_per_entry,real_time_factor,iterations,factor_nonzeros,skipped,note\n";
  for (const auto& r : rows) {
    out << to_string(r.layout) << ',' << r.size << ',' << to_string(r.integrator) << ',' << r.threads << ','
        << r.elements << ',' << r.nodes << ',' << r.vertex_entries << ',';
    if (r.skipped) {
      out << ",,,,,,,,,," << "1," << csv_text(r.note) << '\n';
      continue;
    }
    out << csv_num(r.build_s) << ',' << csv_num(r.setup_s) << ',' << csv_num(r.time_step_s) << ',' << r.steps << ','
        << csv_num(r.step_s * 1e3) << ',' << csv_num(r.ns_per_element) << ',' << csv_num(r.ns_per_entry) << ','
        << csv_num(r.real_time_factor) << ',' << r.iterations << ',' << r.factor_nonzeros << ",0," << csv_text(r.note)
        << '\n';
  }
  return out.str();
}

const std::vector<std::string>& bench_csv_columns() {
  static const std::vector<std::string> cols{
      "size",           "voxel_mm",     "resolution",  "integrator",    "dt_s",           "dt_fraction",
      "dt_stable_estimate_s", "threads", "elements",   "nodes",         "vertex_entries", "build_s",
      "setup_s",        "steps",        "sim_time_s",  "wall_s",        "wall_per_sim_s", "peak_force_n",
      "rms_error_rel",  "max_error_rel", "peak_error_rel", "status",    "pareto",         "real_time",
      "note"};
  return cols;
}

std::string bench_csv(const std::vector<BenchRow>& rows) {
  std::ostringstream out;
  const auto& cols = bench_csv_columns();
  for (std::size_t i = 0; i < cols.size(); ++i) out << (i ? "," : "") << cols[i];
  out << '\n';
  for (const auto& r : rows) {
    const bool rt = r.usable() && r.wall_per_sim_s <= 1.0;
    out << r.size << ',' << csv_num(r.voxel_mm) << ',' << to_string(r.layout) << ',' << to_string(r.integrator) << ','
        << csv_num(r.time_step_s) << ',' << csv_num(r.dt_fraction) << ',' << csv_num(r.dt_stable_estimate_s) << ','
        << r.threads << ',' << r.elements << ',' << r.nodes << ',' << r.vertex_entries << ',' << csv_num(r.build_s) << ','
        << csv_num(r.setup_s) << ',' << r.steps << ',' << csv_num(r.sim_time_s) << ',' << csv_num(r.wall_s) << ','
        << csv_num(r.wall_per_sim_s) << ',' << csv_num(r.peak_force_n) << ',' << csv_num(r.error.rms_rel) << ','
        << csv_num(r.error.max_abs_rel) << ',' << csv_num(r.error.peak_rel) << ',' << to_string(r.status) << ','
        << (r.pareto ? 1 : 0) << ',' << (rt ? 1 : 0) << ',' << csv_text(r.note) << '\n';
  }
  return out.str();
}

namespace {

json row_json(const BenchRow& r) {
  return {{"size", r.size},
          {"voxel_mm", r.voxel_mm},
          {"resolution", to_string(r.layout)},
          {"integrator", to_string(r.integrator)},
          {"dt_s", r.time_step_s},
          {"dt_fraction", num(r.dt_fraction)},
          {"dt_stable_estimate_s", num(r.dt_stable_estimate_s)},
          {"threads", r.threads},
          {"elements", r.elements},
          {"nodes", r.nodes},
          {"vertex_entries", r.vertex_entries},
          {"build_s", r.build_s},
          {"setup_s", r.setup_s},
          {"steps", r.steps},
          {"sim_time_s", r.sim_time_s},
          {"wall_s", r.wall_s},
          {"wall_per_sim_s", num(r.wall_per_sim_s)},
          {"peak_force_n", num(r.peak_force_n)},
          {"rms_error_rel", num(r.error.rms_rel)},
          {"max_error_rel", num(r.error.max_abs_rel)},
          {"peak_error_rel", num(r.error.peak_rel)},
          {"status", to_string(r.status)},
          {"pareto", r.pareto},
          {"real_time", r.usable() && r.wall_per_sim_s <= 1.0},
          {"note", r.note},
          {"label", r.label()}};
}

json step_row_json(const StepBenchmarkRow& r) {
  json j = {{"resolution", to_string(r.layout)},
            {"size", r.size},
            {"integrator", to_string(r.integrator)},
            {"threads", r.threads},
            {"elements", r.elements},
            {"nodes", r.nodes},
            {"vertex_entries", r.vertex_entries},
            {"skipped", r.skipped},
            {"note", r.note}};
  if (!r.skipped) {
    j["build_s"] = r.build_s;
    j["setup_s"] = r.setup_s;
    j["time_step_s"] = r.time_step_s;
    j["steps"] = r.steps;
    j["step_ms"] = r.step_s * 1e3;
    j["ns_per_element"] = r.ns_per_element;
    j["ns_per_entry"] = r.ns_per_entry;
    j["real_time_factor"] = r.real_time_factor;
    j["iterations"] = r.iterations;
    j["factor_nonzeros"] = r.factor_nonzeros;
  }
  return j;
}

/// The scene that re-runs a row with `voxelastic simulate`.
json row_scene(const BenchSettings& s, const BenchRow& r) {
  return palpation_scene_json(s.scene, r.size, r.layout, r.integrator, r.time_step_s, r.threads);
}

/// The lowest-error usable row of a resolution (-1: none); `real_time_only` keeps those <= 1 s/s.
int best_of(const std::vector<BenchRow>& rows, Layout res, bool real_time_only) {
  int best = -1;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const BenchRow& r = rows[i];
    if (r.layout != res || !r.usable() || (real_time_only && r.wall_per_sim_s > 1.0)) continue;
    if (best < 0 || r.error.rms_rel < rows[std::size_t(best)].error.rms_rel) best = int(i);
  }
  return best;
}

std::string pct(double v) { return std::isfinite(v) ? fmt::format("{:.2f} %", 100 * v) : std::string("-"); }
std::string pct_signed(double v) { return std::isfinite(v) ? fmt::format("{:+.1f} %", 100 * v) : std::string("-"); }
std::string sps(double v) { return std::isfinite(v) ? fmt::format("{:.3g}", v) : std::string("-"); }

}  // namespace

json bench_json(const BenchResult& res) {
  const BenchSettings& s = res.settings;
  json j;
  j["quick"] = s.quick;
  j["threads"] = s.threads;
  j["hardware_threads"] = std::thread::hardware_concurrency();
  j["total_s"] = res.total_s;
  j["notes"] = res.notes;
  if (s.run_step) {
    json steps = json::array();
    for (const auto& r : res.step_rows) steps.push_back(step_row_json(r));
    j["step_benchmark"] = {{"phantom", "sphere of radius n/2 - 1 voxels in an n^3 grid of 1 mm voxels, lowest cap fixed, "
                                       "gravity"},
                           {"sizes", s.step_sizes},
                           {"rows", steps},
                           {"explicit_step_slope", {{"gradational", num(res.step_slope_gradational)},
                                                    {"uniform", num(res.step_slope_uniform)},
                                                    {"voxel", num(res.step_slope_voxel)}}}};
  }
  if (s.run_palpation) {
    const PalpationSceneSettings& sc = s.scene;
    j["scene"] = {{"block_mm", {sc.block_mm, sc.block_mm, sc.height_mm}},
                  {"probe_radius_mm", sc.probe_radius_mm},
                  {"gap_mm", sc.gap_mm},
                  {"depth_mm", sc.depth_mm},
                  {"press_s", sc.press_s},
                  {"duration_s", sc.duration_s},
                  {"youngs_modulus_kpa", sc.material.youngs_modulus_kpa},
                  {"density_kg_m3", sc.material.density_kg_m3},
                  {"damping", sc.material.damping_ratio},
                  {"force_interval_s", sc.force_interval_s},
                  {"force", "z component of the tissue's force on the probe (N, +z up), rows averaged over the steps "
                            "between them"},
                  {"error", "rms_error_rel: RMS of (force - reference) at the reference's sample times / reference peak; "
                            "peak_error_rel: (peak - reference peak) / reference peak"}};
    j["sizes"] = s.sizes;
    j["explicit_fractions"] = s.explicit_fractions;
    j["implicit_steps_s"] = s.implicit_steps_s;
    j["implicit_iterations"] = s.implicit_iterations;
    j["max_run_s"] = s.max_run_s;
    json ref = row_json(res.reference);
    ref["scene"] = row_scene(s, res.reference);
    ref["curve"] = {{"time_s", res.reference.curve.time_s}, {"force_n", res.reference.curve.force_n}};
    j["reference"] = ref;
    json rows = json::array();
    for (const auto& r : res.rows) rows.push_back(row_json(r));
    j["rows"] = rows;
    json front = json::array();
    for (std::size_t i : res.pareto) front.push_back(i);
    j["pareto_front"] = front;  // indices into rows, by wall time
    if (res.best >= 0) {
      json best = row_json(res.rows[std::size_t(res.best)]);
      best["index"] = res.best;
      best["real_time"] = res.best_is_real_time;
      best["scene"] = row_scene(s, res.rows[std::size_t(res.best)]);
      j["best"] = best;
    } else {
      j["best"] = nullptr;
    }
    json per = json::object();
    for (Layout r : s.resolutions) {
      const int b = best_of(res.rows, r, false), brt = best_of(res.rows, r, true);
      per[to_string(r)] = {{"lowest_error", b >= 0 ? row_json(res.rows[std::size_t(b)]) : json(nullptr)},
                           {"lowest_error_real_time", brt >= 0 ? row_json(res.rows[std::size_t(brt)]) : json(nullptr)}};
    }
    j["per_resolution"] = per;
    j["conclusion"] = best_statement(res);
  }
  return j;
}

std::string best_statement(const BenchResult& res) {
  if (!res.settings.run_palpation) return "";
  const BenchRow& ref = res.reference;
  if (res.best < 0) return "No run of the palpation scene was stable and measured: no configuration to recommend.";
  const BenchRow& b = res.rows[std::size_t(res.best)];
  const std::string what = fmt::format(
      "{}: {:.3g} s per simulated s (x{:.3g} real time), RMS force error {} of the reference peak ({:.4g} N), peak force "
      "{:.4g} N ({})",
      b.label(), b.wall_per_sim_s, 1.0 / b.wall_per_sim_s, pct(b.error.rms_rel), ref.peak_force_n, b.peak_force_n,
      pct_signed(b.error.peak_rel));
  if (res.best_is_real_time)
    return "Best for real time (lowest error at <= 1 s of wall time per simulated second, " +
           std::to_string(b.threads) + " thread(s)): " + what + ".";
  return "No configuration ran in real time (<= 1 s of wall time per simulated second on " + std::to_string(b.threads) +
         " thread(s)); the nearest (fastest stable) is " + what + ".";
}

std::string bench_markdown(const BenchResult& res) {
  const BenchSettings& s = res.settings;
  std::ostringstream md;
  md << "# voxelastic bench" << (s.quick ? " --quick" : "") << "\n\n";
  md << fmt::format("{} physics thread(s) on a machine with {} hardware threads; the whole bench took {}.\n\n", s.threads,
                    std::thread::hardware_concurrency(), seconds_text(res.total_s));
  if (s.run_palpation) {
    const BenchRow& ref = res.reference;
    const PalpationSceneSettings& sc = s.scene;
    md << "## Run time against error\n\n" << best_statement(res) << "\n\n";
    md << fmt::format(
        "Scene: a {:g} mm ball pressed {:g} mm into the top of a {:g} x {:g} x {:g} mm block ({:g} kPa, {:g} kg/m^3, "
        "damping ratio {:g}) fixed at its base until t = {:g} s, then lifted back to its start by {:g} s; n voxels across "
        "the block. "
        "Reference: the voxel-level model of n = {} ({} elements) with symplectic Euler at {:.2e} s ({:g}x its stable "
        "estimate): peak force {:.4g} N, {} per simulated s. Error: RMS of the probe force's difference from the "
        "reference over the curve, as a fraction of the reference peak.\n\n",
        sc.probe_radius_mm, sc.depth_mm, sc.block_mm, sc.block_mm, sc.height_mm, sc.material.youngs_modulus_kpa,
        sc.material.density_kg_m3, sc.material.damping_ratio, sc.press_s, sc.duration_s, ref.size, ref.elements,
        ref.time_step_s, ref.dt_fraction, ref.peak_force_n, seconds_text(ref.wall_per_sim_s));
    md << "![error against run time](bench_error.png)\n\n![cost against model size](bench_cost.png)\n\n"
          "![force curves](bench_curves.png)\n\n";
    md << "Per resolution (lowest error overall / lowest error in real time):\n\n"
          "| resolution | lowest error | s per s | error | real time: lowest error | s per s | error |\n"
          "|---|---|---|---|---|---|---|\n";
    for (Layout r : s.resolutions) {
      const int b = best_of(res.rows, r, false), brt = best_of(res.rows, r, true);
      auto cells = [&](int i) {
        if (i < 0) return std::string("none | - | -");
        const BenchRow& x = res.rows[std::size_t(i)];
        return fmt::format("{} | {} | {}", x.label(), sps(x.wall_per_sim_s), pct(x.error.rms_rel));
      };
      md << "| " << to_string(r) << " | " << cells(b) << " | " << cells(brt) << " |\n";
    }
    md << "\nPareto front (no other run is both faster and more accurate):\n\n";
    for (std::size_t i : res.pareto) {
      const BenchRow& r = res.rows[i];
      md << fmt::format("- {}: {} s per s, RMS error {}, peak {}\n", r.label(), sps(r.wall_per_sim_s), pct(r.error.rms_rel),
                        pct_signed(r.error.peak_rel));
    }
    md << "\nAll runs (s per s: wall time per simulated second; * on the Pareto front):\n\n"
          "| n | resolution | integrator | dt | elements | s per s | peak N | RMS error | peak error | status |\n"
          "|---|---|---|---|---|---|---|---|---|---|\n";
    for (const auto& r : res.rows) {
      const std::string dt = r.integrator == IntegratorKind::implicit
                                 ? fmt::format("{:g} ms", r.time_step_s * 1e3)
                                 : fmt::format("{} = {:.2e} s", fraction_text(r.dt_fraction), r.time_step_s);
      md << fmt::format("| {} | {} | {} | {} | {} | {}{} | {} | {} | {} | {}{} |\n", r.size, to_string(r.layout),
                        to_string(r.integrator), dt, r.elements, sps(r.wall_per_sim_s), r.pareto ? " *" : "",
                        std::isfinite(r.peak_force_n) ? fmt::format("{:.4g}", r.peak_force_n) : "-", pct(r.error.rms_rel),
                        pct_signed(r.error.peak_rel), to_string(r.status), r.note.empty() ? "" : ": " + r.note);
    }
    md << "\n";
  }
  if (s.run_step) {
    md << "## Cost of one step\n\n![cost per step against model size](step.png)\n\n";
    md << fmt::format(
        "Explicit Euler step time against the sphere size n, log-log slope: gradational {:.2f}, uniform {:.2f}, voxel-level "
        "{:.2f} (the work of a step: ~26 n^2 vertex entries for the gradational model, 8 n^3 for the voxel-level one).\n\n",
        res.step_slope_gradational, res.step_slope_uniform, res.step_slope_voxel);
    md << "| resolution | n | integrator | elements | vertex entries | ms per step | ns per entry | real time x | note |\n"
          "|---|---|---|---|---|---|---|---|---|\n";
    for (const auto& r : res.step_rows) {
      if (r.skipped) {
        md << fmt::format("| {} | {} | {} | {} | {} | - | - | - | {} |\n", to_string(r.layout), r.size,
                          to_string(r.integrator), r.elements ? std::to_string(r.elements) : "-",
                          r.vertex_entries ? std::to_string(r.vertex_entries) : "-", r.note);
        continue;
      }
      md << fmt::format("| {} | {} | {} | {} | {} | {:.3f} | {:.2f} | {:.3g} | {} |\n", to_string(r.layout), r.size,
                        to_string(r.integrator), r.elements, r.vertex_entries, r.step_s * 1e3, r.ns_per_entry,
                        r.real_time_factor, r.note);
    }
    md << "\n";
  }
  if (!res.notes.empty()) {
    md << "## Notes\n\n";
    for (const auto& n : res.notes) md << "- " << n << "\n";
    md << "\n";
  }
  return md.str();
}

namespace {

/// A reference slope c n^p through (x0, y0) over [x0, x1].
PlotSeries slope_line(const std::string& title, double p, double x0, double y0, double x1) {
  PlotSeries s;
  s.title = title;
  s.dash_type = 2;
  s.color = "gray40";
  s.line_width = 1.2;
  for (int i = 0; i <= 16; ++i) {
    const double x = x0 * std::pow(x1 / x0, i / 16.0);
    s.x.push_back(x);
    s.y.push_back(y0 * std::pow(x / x0, p));
  }
  return s;
}

void plot_step(const BenchResult& res, const fs::path& png) {
  PlotPanel time, work;
  time.title = fmt::format("One step against model size (sphere phantoms, {} thread(s))", res.settings.threads);
  time.xlabel = "sphere size n (voxels across)";
  time.ylabel = "wall time per step (ms)";
  time.log_x = time.log_y = true;
  work.title = "Work of one step: vertex entries (summed over elements)";
  work.xlabel = "sphere size n (voxels across)";
  work.ylabel = "vertex entries";
  work.log_x = work.log_y = true;
  time.key = work.key = "bottom right";
  double nmin = 1e30, nmax = 0;
  for (const auto& r : res.step_rows) {
    nmin = std::min(nmin, double(r.size));
    nmax = std::max(nmax, double(r.size));
  }
  double anchor2 = 0, anchor3 = 0, entries2 = 0, entries3 = 0;
  for (Layout r : {Layout::gradational, Layout::uniform, Layout::voxel})
    for (IntegratorKind k : {IntegratorKind::explicit_euler, IntegratorKind::implicit}) {
      PlotSeries s;
      s.title = fmt::format("{}, {}", to_string(r), integrator_title(k));
      s.with_points = true;
      s.color = resolution_color(r);
      s.point_type = integrator_point(k);
      s.dash_type = k == IntegratorKind::implicit ? 2 : 0;
      PlotSeries w;
      w.title = to_string(r);
      w.with_points = true;
      w.color = resolution_color(r);
      for (const auto& row : res.step_rows) {
        if (row.layout != r || row.integrator != k || row.skipped) continue;
        s.x.push_back(row.size);
        s.y.push_back(row.step_s * 1e3);
        w.x.push_back(row.size);
        w.y.push_back(double(row.vertex_entries));
        if (k == IntegratorKind::explicit_euler && row.size == nmin) {
          if (r == Layout::gradational) anchor2 = row.step_s * 1e3, entries2 = double(row.vertex_entries);
          if (r == Layout::voxel) anchor3 = row.step_s * 1e3, entries3 = double(row.vertex_entries);
        }
      }
      if (!s.x.empty()) time.series.push_back(s);
      if (k == IntegratorKind::explicit_euler && !w.x.empty()) work.series.push_back(w);
    }
  time.xrange = work.xrange = fmt::format("[{}:{}]", nmin / 1.25, nmax * 1.25);
  if (nmax > nmin) {
    if (anchor2 > 0) time.series.push_back(slope_line("n^{2}", 2, nmin, anchor2 * 0.7, nmax));
    if (anchor3 > 0) time.series.push_back(slope_line("n^{3}", 3, nmin, anchor3 * 1.4, nmax));
    if (entries2 > 0) work.series.push_back(slope_line("n^{2}", 2, nmin, entries2 * 0.7, nmax));
    if (entries3 > 0) work.series.push_back(slope_line("n^{3}", 3, nmin, entries3 * 1.4, nmax));
  }
  plot_png({time, work}, png, 900, 460);
}

void plot_error(const BenchResult& res, const fs::path& png) {
  PlotPanel p;
  p.title = fmt::format("Run time against error: palpation scene, reference voxel-level n = {} ({} thread(s))",
                        res.reference.size, res.settings.threads);
  p.xlabel = "wall time per simulated second (s/s, log; left of 1 = faster than real time)";
  p.ylabel = "RMS force error (% of the reference peak, log)";
  p.log_x = p.log_y = true;
  p.key = "outside right top";
  double ymin = 1e30, ymax = 0;
  const std::vector<int>& sizes = res.settings.sizes;
  for (Layout r : res.settings.resolutions)
    for (std::size_t si = 0; si < sizes.size(); ++si)
      for (IntegratorKind k : kIntegrators) {
        PlotSeries s;
        s.title = fmt::format("{} n={}, {}", to_string(r), sizes[si], integrator_title(k));
        s.points = true;
        s.color = resolution_shade(r, si, sizes.size());
        s.point_type = integrator_point(k);
        for (const auto& row : res.rows)
          if (row.layout == r && row.size == sizes[si] && row.integrator == k && row.usable()) {
            s.x.push_back(row.wall_per_sim_s);
            s.y.push_back(100 * row.error.rms_rel);
            if (row.error.rms_rel > 0) ymin = std::min(ymin, 100 * row.error.rms_rel);
            ymax = std::max(ymax, 100 * row.error.rms_rel);
          }
        if (!s.x.empty()) p.series.push_back(s);
      }
  double wmin = 1.0, wmax = 1.0;
  for (const auto& row : res.rows)
    if (row.usable()) {
      wmin = std::min(wmin, row.wall_per_sim_s);
      wmax = std::max(wmax, row.wall_per_sim_s);
    }
  p.xrange = fmt::format("[{}:{}]", wmin / 1.5, wmax * 1.5);
  PlotSeries front;
  front.title = "Pareto front";
  front.color = "black";
  front.line_width = 1.2;
  for (std::size_t i : res.pareto) {
    front.x.push_back(res.rows[i].wall_per_sim_s);
    front.y.push_back(100 * res.rows[i].error.rms_rel);
  }
  if (!front.x.empty()) p.series.push_back(front);
  if (ymax > 0) {
    PlotSeries rt;
    rt.title = "real time (1 s per s)";
    rt.color = "orange";
    rt.dash_type = 2;
    rt.line_width = 2;
    rt.x = {1.0, 1.0};
    rt.y = {ymin * 0.7, ymax * 1.4};
    p.series.push_back(rt);
  }
  if (res.best >= 0) {
    PlotSeries b;
    b.title = "best for real time";
    b.points = true;
    b.point_type = 6;  // open circle, around the best point
    b.color = "black";
    b.x = {res.rows[std::size_t(res.best)].wall_per_sim_s};
    b.y = {100 * res.rows[std::size_t(res.best)].error.rms_rel};
    p.series.push_back(b);
  }
  plot_png({p}, png, 1150, 700);
}

void plot_cost(const BenchResult& res, const fs::path& png) {
  PlotPanel p;
  p.title = fmt::format("Palpation: wall time per simulated second against model size ({} thread(s))",
                        res.settings.threads);
  p.xlabel = "n (voxels across the block, log)";
  p.ylabel = "wall time per simulated second (s/s, log)";
  p.log_x = p.log_y = true;
  p.key = "outside right top";
  double nmin = 1e30, nmax = 0, lo = 1e30, hi = 0;
  for (Layout r : res.settings.resolutions) {
    // symplectic Euler at its stable estimate, and implicit at its smallest step
    const double implicit_dt = res.settings.implicit_steps_s.empty()
                                   ? 0.0
                                   : *std::min_element(res.settings.implicit_steps_s.begin(), res.settings.implicit_steps_s.end());
    PlotSeries se, im;
    se.title = fmt::format("{}, symplectic Euler 1x", to_string(r));
    im.title = fmt::format("{}, implicit {:g} ms", to_string(r), implicit_dt * 1e3);
    se.with_points = im.with_points = true;
    se.color = im.color = resolution_color(r);
    se.point_type = integrator_point(IntegratorKind::symplectic_euler);
    im.point_type = integrator_point(IntegratorKind::implicit);
    im.dash_type = 2;
    for (const auto& row : res.rows) {
      if (row.layout != r || !std::isfinite(row.wall_per_sim_s) || row.status != BenchStatus::ok) continue;
      PlotSeries* s = nullptr;
      if (row.integrator == IntegratorKind::symplectic_euler && std::abs(row.dt_fraction - 1.0) < 1e-9) s = &se;
      if (row.integrator == IntegratorKind::implicit && std::abs(row.time_step_s - implicit_dt) < 1e-12) s = &im;
      if (!s) continue;
      s->x.push_back(row.size);
      s->y.push_back(row.wall_per_sim_s);
      nmin = std::min(nmin, double(row.size));
      nmax = std::max(nmax, double(row.size));
      lo = std::min(lo, row.wall_per_sim_s);
      hi = std::max(hi, row.wall_per_sim_s);
    }
    if (!se.x.empty()) p.series.push_back(se);
    if (!im.x.empty()) p.series.push_back(im);
  }
  if (nmax > 0) {
    p.xrange = fmt::format("[{}:{}]", nmin / 1.25, nmax * 1.25);
    PlotSeries rt;
    rt.title = "real time (1 s per s)";
    rt.color = "orange";
    rt.dash_type = 2;
    rt.line_width = 2;
    rt.x = {nmin / 1.25, nmax * 1.25};
    rt.y = {1.0, 1.0};
    p.series.push_back(rt);
  }
  if (nmax > nmin) {
    // a step costs ~n^2 (gradational) or ~n^3 (voxel-level) and the stable step shrinks like 1/n
    p.series.push_back(slope_line("n^{3} (step cost n^{2}, time step 1/n)", 3, nmin, lo, nmax));
    p.series.push_back(slope_line("n^{4} (step cost n^{3}, time step 1/n)", 4, nmin, lo * 3, nmax));
  }
  plot_png({p}, png, 1100, 560);
}

void plot_curves(const BenchResult& res, const fs::path& png) {
  PlotPanel p;
  p.title = "Probe force against time";
  p.xlabel = "time (s)";
  p.ylabel = "force on the probe, +z (N)";
  p.key = "top right";
  p.xrange = fmt::format("[0:{}]", 1.7 * res.settings.scene.duration_s);
  PlotSeries ref;
  ref.title = fmt::format("reference: voxel n={}, symplectic Euler {:.1e} s", res.reference.size,
                          res.reference.time_step_s);
  ref.color = "black";
  ref.line_width = 3;
  ref.x = res.reference.curve.time_s;
  ref.y = res.reference.curve.force_n;
  p.series.push_back(ref);
  std::set<int> shown;
  auto add = [&](int i, const std::string& prefix, int dash) {
    if (i < 0 || shown.count(i)) return;
    shown.insert(i);
    const BenchRow& r = res.rows[std::size_t(i)];
    PlotSeries s;
    const std::string dt = r.integrator == IntegratorKind::implicit ? fmt::format("{:g} ms", r.time_step_s * 1e3)
                                                                    : fraction_text(r.dt_fraction);
    s.title = fmt::format("{}n={} {} {} {}: {}", prefix, r.size, to_string(r.layout), integrator_title(r.integrator),
                          dt, pct(r.error.rms_rel));
    s.color = resolution_color(r.layout);
    s.dash_type = dash;
    s.x = r.curve.time_s;
    s.y = r.curve.force_n;
    p.series.push_back(s);
  };
  add(res.best, "best for real time: ", 0);
  for (Layout r : res.settings.resolutions) add(best_of(res.rows, r, false), "most accurate: ", 2);
  plot_png({p}, png, 1000, 520);
}

}  // namespace

std::vector<std::string> write_bench_report(const BenchResult& res, const fs::path& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    throw Error(fmt::format("bench: cannot create the output folder '{}' ({})", dir.string(),
                            ec ? ec.message() : "not a folder"));
  check_output_path(dir / "bench.json");
  const fs::path staging = dir / fmt::format(".bench-staging-{}", ::getpid());
  fs::remove_all(staging, ec);
  fs::create_directories(staging, ec);
  if (ec) throw Error(fmt::format("bench: cannot create the staging folder '{}' ({})", staging.string(), ec.message()));
  std::vector<std::string> names;
  try {
    if (res.settings.run_step) {
      write_text_atomically(staging / "step.csv", step_csv(res.step_rows));
      names.push_back("step.csv");
      plot_step(res, staging / "step.png");
      names.push_back("step.png");
    }
    if (res.settings.run_palpation) {
      write_text_atomically(staging / "bench.csv", bench_csv(res.rows));
      names.push_back("bench.csv");
      plot_error(res, staging / "bench_error.png");
      names.push_back("bench_error.png");
      plot_cost(res, staging / "bench_cost.png");
      names.push_back("bench_cost.png");
      plot_curves(res, staging / "bench_curves.png");
      names.push_back("bench_curves.png");
      write_text_atomically(staging / "reference_scene.json", row_scene(res.settings, res.reference).dump(2) + "\n");
      names.push_back("reference_scene.json");
      if (res.best >= 0) {
        write_text_atomically(staging / "best_scene.json",
                              row_scene(res.settings, res.rows[std::size_t(res.best)]).dump(2) + "\n");
        names.push_back("best_scene.json");
      }
    }
    write_text_atomically(staging / "bench.json", bench_json(res).dump(2) + "\n");
    names.push_back("bench.json");
    write_text_atomically(staging / "bench.md", bench_markdown(res));
    names.push_back("bench.md");
    // everything is there: move it into place
    for (const auto& n : names) {
      fs::rename(staging / n, dir / n, ec);
      if (ec) throw Error(fmt::format("bench: cannot move {} into '{}' ({})", n, dir.string(), ec.message()));
    }
  } catch (...) {
    fs::remove_all(staging, ec);
    throw;
  }
  fs::remove_all(staging, ec);
  return names;
}

}  // namespace vx
