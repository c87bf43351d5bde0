#include "bench/scale_bench.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>

#include "base/error.h"
#include "convert/phantom.h"
#include "physics/calibration.h"
#include "render/plot.h"
#include "scene/fast_configuration.h"
#include "scene/scene.h"
#include "sim/simulation.h"
#include "sim/time_step.h"
#include "util/atomic_file.h"

namespace vx {
namespace fs = std::filesystem;
using json = nlohmann::json;

ScaleBenchSettings ScaleBenchSettings::standard() {
  ScaleBenchSettings s;
  s.models = {{"sphere 32", "sphere", 32},
              {"sphere 64", "sphere", 64},
              {"sphere 128", "sphere", 128},
              {"sphere 256", "sphere", 256},
              {"organ", "organ", 214}};
  // the brain-like phantom, held at its stem (it hangs from a patch 20 mm across) and over its
  // lower third; pressed on a gyrus off the fissure
  ScaleModelSpec folded{"folded (stem)", "folded", 214};
  folded.support = "stem";
  folded.press_offset_mm = {19.0, -2.0};
  s.models.push_back(folded);
  folded.name = "folded (lower third)";
  folded.support = "lower third";
  s.models.push_back(folded);
  ScaleConfig ref;
  ref.name = "symplectic, auto step (reference)";
  ref.reference = true;
  ScaleConfig floor;
  floor.name = "symplectic, mass floor 0.1 ms";
  floor.mass.time_step_s = 1e-4;
  ScaleConfig floor_scale;
  floor_scale.name = "symplectic, mass floor 0.25 ms";
  floor_scale.mass.time_step_s = 2.5e-4;
  // implicit runs: one step size and iteration count, optionally with regional solves
  const auto implicit = [](double step_ms, int iterations, double region_mm, const char* note) {
    ScaleConfig c;
    c.name = fmt::format("implicit {:g} ms, {} iteration{}", step_ms, iterations, iterations == 1 ? "" : "s");
    if (region_mm > 0) c.name += fmt::format(", region {:g} mm", region_mm);
    if (*note) c.name += fmt::format(" ({})", note);
    c.kind = IntegratorKind::implicit;
    c.time_step_s = step_ms * 1e-3;
    c.max_iterations = iterations;
    c.region_radius_mm = region_mm;
    return c;
  };
  const ScaleConfig implicit10 = implicit(10, 2, 0, "");
  ScaleConfig implicit20 = implicit(20, 1, 0, "the fast configuration below 20,000 nodes");
  const ScaleConfig implicit30 = implicit(30, 1, 0, "");
  const ScaleConfig region15 = implicit(20, 1, 15, "");
  const ScaleConfig region30 = implicit(20, 1, 30, "");
  const ScaleConfig region30_30 = implicit(30, 1, 30, "");
  const ScaleConfig region45_30 = implicit(30, 1, 45, "");
  ScaleConfig region60_30 = implicit(30, 1, 60, "the fast configuration of larger models");
  // the fast configuration's iterations while no tool touches (fast_configuration.h)
  const FastConfiguration fast = default_fast_configuration();
  implicit20.free_iterations = fast.free_iterations;  // small models only (fast_configuration.h)
  implicit20.free_tolerance_mm = fast.free_tolerance_mm;
  region60_30.single_precision_sweeps = fast.large_model_single_precision_sweeps;  // as a large model's
  s.configs = {ref,      floor,    floor_scale, implicit10,  implicit20, implicit30,
               region15, region30, region30_30, region45_30, region60_30};
  return s;
}

std::vector<ScaleConfig> ScaleBenchSettings::diagnostic_configs() {
  std::vector<ScaleConfig> out;
  ScaleConfig one;  // the fast configuration below 20,000 nodes without its iterations after a release
  one.name = "implicit 20 ms, 1 iteration, one after a release too";
  one.kind = IntegratorKind::implicit;
  one.time_step_s = 0.02;
  one.max_iterations = 1;
  out.push_back(one);
  ScaleConfig c;
  c.kind = IntegratorKind::implicit;
  c.time_step_s = 0.03;
  c.max_iterations = 1;
  c.region_radius_mm = 30;
  c.name = "implicit 30 ms, 1 iteration, region 30 mm, far field held";  // the default
  c.region_far_field_degree = 0;
  out.push_back(c);
  c.name = "implicit 30 ms, 1 iteration, region 30 mm, far field held, no refresh on move";
  c.region_refresh_on_move = false;
  out.push_back(c);
  c.name = "implicit 30 ms, 1 iteration, region 30 mm, far field solved";
  c.region_refresh_on_move = true;
  c.region_solve_far_field = true;
  out.push_back(c);
  c.name = "implicit 30 ms, 1 iteration, region 30 mm, far field solved, no refresh on move";
  c.region_refresh_on_move = false;
  out.push_back(c);
  c.name = "implicit 30 ms, 1 iteration, region 30 mm, far field carried";  // \"region_far_field\": \"carried\"
  c.region_refresh_on_move = true;
  c.region_solve_far_field = false;
  c.region_far_field_degree = 1;
  out.push_back(c);
  c.name = "implicit 30 ms, 1 iteration, region 30 mm, far field carried, no refresh on move";
  c.region_refresh_on_move = false;
  out.push_back(c);
  // more local/global iterations in the fast configuration of larger models (a nearly
  // incompressible tissue's volume term converges slowly), and whether the reference is
  // converged in its step (a step 3.3x longer, iterated the same way)
  for (const int iterations : {2, 3, 5}) {
    ScaleConfig it;
    it.kind = IntegratorKind::implicit;
    it.time_step_s = 0.03;
    it.max_iterations = iterations;
    it.region_radius_mm = 60;
    it.name = fmt::format("implicit 30 ms, {} iterations, region 60 mm", iterations);
    out.push_back(it);
  }
  // the fast configuration of larger models with every node visited in every step while the far
  // field is held still: the same bits, the cost of those passes (docs/bench.md)
  ScaleConfig visit;
  visit.kind = IntegratorKind::implicit;
  visit.time_step_s = 0.03;
  visit.max_iterations = 1;
  visit.region_radius_mm = 60;
  visit.region_visit_still_far_field = true;
  visit.single_precision_sweeps = true;
  visit.name = "implicit 30 ms, 1 iteration, region 60 mm, every node visited (the still far field's passes)";
  out.push_back(visit);
  // the fast configuration of larger models with its factor swept in double: what the single
  // precision sweeps gain and cost (docs/bench.md, "Single-precision sweeps")
  ScaleConfig twice = visit;
  twice.region_visit_still_far_field = false;
  twice.single_precision_sweeps = false;
  twice.name = "implicit 30 ms, 1 iteration, region 60 mm, double-precision sweeps";
  out.push_back(twice);
  ScaleConfig coarse;
  coarse.kind = IntegratorKind::implicit;
  coarse.time_step_s = 0.01;
  coarse.max_iterations = 30;
  coarse.residual_tolerance_n = 1e-5;
  coarse.name = "implicit 10 ms, iterated to 1e-5 N (is the reference converged in its step?)";
  out.push_back(coarse);
  return out;
}

void ScaleBenchSettings::use_implicit_reference() {
  for (ScaleConfig& c : configs)
    if (c.reference) {
      c.name = "implicit 3 ms, iterated to 1e-5 N (reference)";
      c.kind = IntegratorKind::implicit;
      c.time_step_s = 0.003;
      c.mass = MassScaling{};
      c.max_iterations = 30;
      c.residual_tolerance_n = 1e-5;
      c.region_radius_mm = 0.0;
    }
}

void ScaleBenchSettings::validate() const {
  if (models.empty()) throw Error("bench --scale: no models");
  if (configs.empty()) throw Error("bench --scale: no configurations");
  if (!element.empty() && element != "paper" && element != "hourglass")
    throw Error("bench --scale: unknown element '" + element + "' (paper or hourglass)");
  for (const auto& m : models) {
    if (m.lattice_origin != "best" && m.lattice_origin != "crop")
      throw Error("bench --scale: unknown lattice origin '" + m.lattice_origin + "' (best or crop)");
    if (m.support != "bottom 3 mm" && m.support != "stem" && m.support != "lower third")
      throw Error("bench --scale: " + m.name + ": unknown support '" + m.support +
                  "' (bottom 3 mm, stem or lower third)");
    if (!(m.spacing_mm > 0 && std::isfinite(m.spacing_mm)))
      throw Error("bench --scale: " + m.name + ": the voxel size must be a positive number of mm");
    const auto index_of = [&](const std::string& name) {
      return std::find_if(models.begin(), models.end(), [&](const ScaleModelSpec& o) { return o.name == name; }) -
             models.begin();
    };
    if (!m.judged_against.empty() && index_of(m.judged_against) >= index_of(m.name))
      throw Error("bench --scale: " + m.name + " is judged against '" + m.judged_against +
                  "', which must be in the same run before it (list it first)");
  }
  for (int t : threads)
    if (t < 1) throw Error("bench --scale: threads must be >= 1");
  if (!(max_wall_s > 0)) throw Error("bench --scale: max_wall_s must be > 0");
  if (!(poisson_ratio >= 0.0 && poisson_ratio < 0.5)) throw Error("bench --scale: poisson_ratio must be in [0, 0.5)");
}

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

PreparedScene prepare_scale_model(const ScaleModelSpec& m, const ScaleBenchSettings& s) {
  json j;
  j["object"] = {{"phantom", m.phantom},
                 {"size", m.size},
                 {"spacing_mm", m.spacing_mm},
                 {"resolution", "gradational"},
                 {"lattice_origin", m.lattice_origin}};
  j["material"] = {{"youngs_modulus_kpa", s.youngs_modulus_kpa},
                   {"damping", s.damping_ratio},
                   {"density_kg_m3", 1000.0},
                   {"poisson_ratio", s.poisson_ratio}};
  if (!s.element.empty()) j["material"]["element"] = s.element;
  // the support, from the phantom's analytic shape (the model keeps its LPS coordinates)
  PhantomSettings ps;
  ps.name = m.phantom;
  ps.size = m.size;
  ps.spacing_mm = m.spacing_mm;
  const PhantomShape shape = phantom_shape(ps);
  if (m.support == "stem") {
    if (!(shape.stem_radius_mm > 0))
      throw Error("bench --scale: " + m.name + ": support 'stem' needs a phantom with a stem (folded), not " +
                  m.phantom);
    // the stem's bottom 3 mm: a box round its bottom face, half a voxel wider than the stem and
    // half a voxel beyond 3 mm (the lowest nodes may lie up to half a voxel below the face)
    const double half = 0.5 * m.spacing_mm;
    const Eigen::Vector3d c = shape.stem_center_mm, r(shape.stem_radius_mm + half, shape.stem_radius_mm + half, half);
    const Eigen::Vector3d lo = c - r, hi = c + Eigen::Vector3d(r.x(), r.y(), 3.0 + half);
    j["fixed"] = json::array({{{"box_mm", {{"min", {lo.x(), lo.y(), lo.z()}}, {"max", {hi.x(), hi.y(), hi.z()}}}}}});
  } else if (m.support == "lower third") {
    const double bottom =
        shape.stem_radius_mm > 0 ? shape.stem_center_mm.z() : shape.center_mm.z() - shape.half_extent_mm.z();
    const double top = shape.center_mm.z() + shape.half_extent_mm.z();
    j["fixed"] = json::array({{{"face", "z_min"}, {"within_mm", (top - bottom) / 3.0}}});
  } else {
    j["fixed"] = json::array({{{"face", "z_min"}, {"within_mm", 3.0}}});
  }
  j["duration_s"] = s.press_s + s.slide_s;
  j["outputs"] = {{"forces_csv", false}, {"plot", false}};
  const Scene scene = parse_scene(j, fs::current_path(), "scale bench " + m.name);
  PrepareSceneOptions opt;
  opt.threads_override = 1;
  return prepare_scene(scene, opt);
}

std::vector<PathKey> scale_palpation_path(const PreparedScene& p, const ScaleModelSpec& spec,
                                          const ScaleBenchSettings& s) {
  const Model& m = *p.model;
  Eigen::Vector3d c = 0.5 * (p.bounds_min_mm + p.bounds_max_mm);
  c.head<2>() += spec.press_offset_mm;
  double top = p.bounds_min_mm.z();
  for (int i = 0; i < m.num_nodes(); ++i) {
    const Eigen::Vector3d x = m.rest_positions.col(i);
    if (std::hypot(x.x() - c.x(), x.y() - c.y()) <= s.probe_radius_mm) top = std::max(top, x.z());
  }
  const double z0 = top + s.probe_radius_mm + 0.5;
  const double z1 = top + s.probe_radius_mm - s.depth_mm;
  return {{0.0, {c.x(), c.y(), z0}},
          {s.press_s, {c.x(), c.y(), z1}},
          {s.press_s + s.slide_s, {c.x() + s.slide_mm, c.y(), z1}}};
}

namespace {

struct RunOutput {
  ScaleRow row;
  std::vector<double> t, f;  ///< force curve: +z force on the ball, mean per interval
};

RunOutput run_one(const ScaleModelSpec& spec, const PreparedScene& prepared,
                  const std::shared_ptr<const PhysicsModel>& physics, const ScaleConfig& cfg,
                  const std::vector<PathKey>& path, int threads, double max_wall_s, const ScaleBenchSettings& s) {
  RunOutput out;
  ScaleRow& row = out.row;
  row.model = spec.name;
  row.config = cfg.name;
  row.threads = threads;
  const Model& m = *prepared.model;
  row.elements = m.num_elements();
  row.nodes = m.num_nodes();
  row.vertex_entries = m.num_vertex_entries();
  row.added_mass_rel = physics->added_mass_kg / physics->total_mass_kg();

  SimulationSettings ss = prepared.settings;
  ss.integrator.kind = cfg.kind;
  const TimeStepEstimate est = estimate_time_steps(*physics);
  ss.integrator.time_step_s = cfg.time_step_s > 0 ? cfg.time_step_s : automatic_time_step(est, cfg.kind);
  ss.integrator.threads = threads;
  ss.integrator.max_iterations = cfg.max_iterations;
  ss.integrator.residual_tolerance_n = cfg.residual_tolerance_n;
  ss.integrator.free_iterations = cfg.free_iterations;
  ss.integrator.free_tolerance_mm = cfg.free_tolerance_mm;
  ss.integrator.region_radius_mm = cfg.region_radius_mm;
  ss.integrator.region_solve_far_field = cfg.region_solve_far_field;
  ss.integrator.region_refresh_on_move = cfg.region_refresh_on_move;
  ss.integrator.region_visit_still_far_field = cfg.region_visit_still_far_field;
  ss.integrator.region_far_field_degree = cfg.region_far_field_degree;
  ss.integrator.single_precision_sweeps = cfg.single_precision_sweeps;
  ProbeSettings probe;
  probe.name = "ball";
  probe.geometry.shape = ProbeShape::sphere;
  probe.geometry.radius_mm = s.probe_radius_mm;
  probe.path = path;
  ss.probes = {probe};
  row.time_step_s = ss.integrator.time_step_s;

  const double duration = s.press_s + s.slide_s;
  const auto t_setup = std::chrono::steady_clock::now();
  Simulation sim(physics, ss);
  sim.step();  // the implicit factorisation happens here
  row.setup_s = seconds_since(t_setup);
  const auto t0 = std::chrono::steady_clock::now();
  double next_sample = s.force_interval_s, sum = 0;
  int count = 0;
  std::int64_t timed_steps = 0;
  out.t.push_back(0.0);
  out.f.push_back(0.0);
  while (sim.time_s() < duration - 0.5 * sim.dt_s()) {
    if (sim.step() != StepStatus::ok) break;
    ++timed_steps;
    sum += sim.probe(0).raw_force_n.z();
    ++count;
    if (sim.time_s() >= next_sample - 0.5 * sim.dt_s()) {
      out.t.push_back(sim.time_s());
      out.f.push_back(count ? sum / count : 0.0);
      sum = 0;
      count = 0;
      next_sample += s.force_interval_s;
    }
    if ((timed_steps & 7) == 0 && seconds_since(t0) > max_wall_s) break;
  }
  row.wall_s = seconds_since(t0);
  row.steps = sim.steps();
  row.sim_s = sim.time_s();
  row.stable = !sim.failed();
  if (sim.failed()) row.note = sim.state().message;
  row.complete = row.stable && row.sim_s >= duration - 0.5 * sim.dt_s();
  const double timed_sim = row.sim_s - ss.integrator.time_step_s;
  row.step_ms = timed_steps > 0 ? 1e3 * row.wall_s / double(timed_steps) : 0.0;
  row.steps_per_sim_s = 1.0 / ss.integrator.time_step_s;
  row.real_time_factor = row.wall_s > 0 ? timed_sim / row.wall_s : 0.0;
  for (double f : out.f) row.peak_force_n = std::max(row.peak_force_n, f);
  if (!row.complete && row.stable)
    row.note =
        fmt::format("timed over the first {:.3g} s of simulated time ({:.0f} s of wall time)", row.sim_s, row.wall_s);
  return out;
}

/// RMS of (curve - reference) at the reference's samples (curve interpolated) / reference peak.
double rms_error(const std::vector<double>& t, const std::vector<double>& f, const std::vector<double>& rt,
                 const std::vector<double>& rf) {
  double peak = 0;
  for (double v : rf) peak = std::max(peak, v);
  if (!(peak > 0) || t.size() < 2) return -1.0;
  double s = 0;
  for (std::size_t k = 0; k < rt.size(); ++k) {
    const auto it = std::lower_bound(t.begin(), t.end(), rt[k]);
    double v;
    if (it == t.begin()) {
      v = f.front();
    } else if (it == t.end()) {
      v = f.back();
    } else {
      const std::size_t j = std::size_t(it - t.begin());
      const double a = (rt[k] - t[j - 1]) / (t[j] - t[j - 1]);
      v = (1 - a) * f[j - 1] + a * f[j];
    }
    s += (v - rf[k]) * (v - rf[k]);
  }
  return std::sqrt(s / double(rt.size())) / peak;
}

/// A file-name-safe form of `name` (letters, digits, '-', '.'; the rest '_').
std::string file_safe(const std::string& name) {
  std::string o;
  for (const char ch : name) o += (std::isalnum(static_cast<unsigned char>(ch)) || ch == '-' || ch == '.') ? ch : '_';
  return o;
}

void write_curve(const fs::path& dir, const ScaleModelSpec& spec, const ScaleConfig& cfg, const RunOutput& r) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  std::ostringstream o;
  o << "t_s,force_n\n";
  for (std::size_t k = 0; k < r.t.size(); ++k) o << fmt::format("{:.6g},{:.9g}\n", r.t[k], r.f[k]);
  write_text_atomically(dir / (file_safe(spec.name) + "__" + file_safe(cfg.name) + ".csv"), o.str());
}

}  // namespace

ScaleBenchResult run_scale_bench(const ScaleBenchSettings& s) {
  s.validate();
  const auto t_all = std::chrono::steady_clock::now();
  ScaleBenchResult res;
  const auto say = [&](const std::string& line) {
    if (s.log) s.log(line);
  };
  const int most_threads = *std::max_element(s.threads.begin(), s.threads.end());
  struct Judge {
    std::vector<double> t, f;  ///< the reference's curve (empty: none ran to the end)
    std::vector<PathKey> path;
  };
  std::map<std::string, Judge> judges;  // by model name, for the models judged against another
  for (const ScaleModelSpec& spec : s.models) {
    const auto t_build = std::chrono::steady_clock::now();
    const PreparedScene prepared = prepare_scale_model(spec, s);
    say(fmt::format("[scale] {}: {} elements, {} nodes, {} vertex entries (built in {:.1f} s)", spec.name,
                    prepared.model->num_elements(), prepared.model->num_nodes(), prepared.model->num_vertex_entries(),
                    seconds_since(t_build)));
    const bool judged = !spec.judged_against.empty();
    Judge& own = judges[spec.name];
    own.path = judged ? judges.at(spec.judged_against).path : scale_palpation_path(prepared, spec, s);
    if (judged) {
      own.t = judges.at(spec.judged_against).t;
      own.f = judges.at(spec.judged_against).f;
      say(fmt::format("[scale] {}: judged against {}'s reference{}, its ball on the same path", spec.name,
                      spec.judged_against, own.t.empty() ? " (none ran to the end: no error column)" : ""));
    }
    // the reference first (its curve judges the others), then the others; on a model judged
    // against another's, the reference configuration is a row like the others (what the grid
    // alone costs)
    std::vector<const ScaleConfig*> order;
    for (const auto& c : s.configs)
      if (c.reference) order.push_back(&c);
    for (const auto& c : s.configs)
      if (!c.reference) order.push_back(&c);
    for (const ScaleConfig* cfg : order) {
      std::shared_ptr<const PhysicsModel> physics = prepared.physics;
      if (cfg->mass.active()) {
        CalibrationOptions opt;
        opt.mass_scaling = cfg->mass;
        physics = make_physics_model(prepared.model, prepared.physics->material, {}, opt);
      }
      // the most threads first: the whole run (the force curve); then fewer threads timed over
      // at most the same wall time
      std::vector<int> threads = s.threads;
      std::sort(threads.begin(), threads.end(), std::greater<>());
      double window = cfg->reference ? s.reference_max_wall_s : s.max_wall_s;
      double error = -1.0;
      for (int th : threads) {
        RunOutput r = run_one(spec, prepared, physics, *cfg, own.path, th, window, s);
        if (th == most_threads) {
          if (!s.curves_dir.empty() && r.row.complete) write_curve(s.curves_dir, spec, *cfg, r);
          if (cfg->reference && !judged && r.row.complete) {
            own.t = r.t;
            own.f = r.f;
          }
          if (r.row.complete && !own.t.empty()) error = rms_error(r.t, r.f, own.t, own.f);
          window = std::min(window, std::max(10.0, r.row.wall_s));
        }
        r.row.rms_error_rel = error;
        if (judged && error >= 0) r.row.note = "error against " + spec.judged_against + "'s reference";
        say(fmt::format("[scale] {} | {} | {} thread(s): dt {:.3g} s, {:.3g} ms per step, real-time factor {:.3g}{}{}",
                        spec.name, cfg->name, th, r.row.time_step_s, r.row.step_ms, r.row.real_time_factor,
                        error >= 0 ? fmt::format(", force error {:.2f} %", 100 * error) : std::string(),
                        r.row.note.empty() ? std::string() : " (" + r.row.note + ")"));
        res.rows.push_back(std::move(r.row));
      }
    }
  }
  res.total_s = seconds_since(t_all);
  return res;
}

std::string format_scale_table(const ScaleBenchResult& r) {
  std::ostringstream o;
  o << "| model | elements / nodes | configuration | threads | dt (ms) | ms per step | steps per sim. s | real-time "
       "factor | force error (RMS, % of peak) | note |\n|---|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& x : r.rows)
    o << fmt::format("| {} | {} / {} | {} | {} | {:.3g} | {:.3g} | {:.0f} | {:.3g} | {} | {} |\n", x.model, x.elements,
                     x.nodes, x.config, x.threads, 1e3 * x.time_step_s, x.step_ms, x.steps_per_sim_s,
                     x.real_time_factor, x.rms_error_rel >= 0 ? fmt::format("{:.2f}", 100 * x.rms_error_rel) : "-",
                     x.stable ? x.note : "unstable: " + x.note);
  return o.str();
}

std::vector<std::string> write_scale_report(const ScaleBenchResult& r, const fs::path& dir) {
  std::vector<std::string> written;
  {
    std::ostringstream csv;
    csv << "model,config,threads,elements,nodes,vertex_entries,time_step_s,steps,sim_s,wall_s,setup_s,step_ms,"
           "steps_per_sim_s,real_time_factor,rms_error_rel,peak_force_n,added_mass_rel,complete,stable,note\n";
    for (const auto& x : r.rows)
      csv << fmt::format(
          "\"{}\",\"{}\",{},{},{},{},{:.6g},{},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{},{:.6g},{:.6g},{},{},\"{}"
          "\"\n",
          x.model, x.config, x.threads, x.elements, x.nodes, x.vertex_entries, x.time_step_s, x.steps, x.sim_s,
          x.wall_s, x.setup_s, x.step_ms, x.steps_per_sim_s, x.real_time_factor,
          x.rms_error_rel >= 0 ? fmt::format("{:.6g}", x.rms_error_rel) : "", x.peak_force_n, x.added_mass_rel,
          x.complete ? 1 : 0, x.stable ? 1 : 0, x.note);
    write_text_atomically(dir / "scale.csv", csv.str());
    written.push_back("scale.csv");
  }
  write_text_atomically(dir / "scale.md", "# voxelastic bench --scale\n\n" + format_scale_table(r));
  written.push_back("scale.md");
  // real-time factor against elements, one line per configuration and thread count
  std::map<std::string, PlotSeries> lines;
  double lo = 1e300, hi = 0;
  for (const auto& x : r.rows) {
    if (!x.stable || x.real_time_factor <= 0) continue;
    const std::string key = fmt::format("{}, {} thread{}", x.config, x.threads, x.threads > 1 ? "s" : "");
    PlotSeries& ps = lines[key];
    ps.title = key;
    ps.with_points = true;
    ps.dash_type = x.threads > 1 ? 0 : 2;
    ps.x.push_back(double(x.elements));
    ps.y.push_back(x.real_time_factor);
    lo = std::min(lo, double(x.elements));
    hi = std::max(hi, double(x.elements));
  }
  PlotPanel panel;
  panel.title = "Palpation (press 5 mm, slide 10 mm): real-time factor against model size";
  panel.xlabel = "elements";
  panel.ylabel = "simulated s per wall s";
  panel.log_x = panel.log_y = true;
  panel.key = "below";
  for (auto& [k, ps] : lines) panel.series.push_back(ps);
  if (hi > 0) {
    PlotSeries rt;
    rt.title = "real time";
    rt.x = {lo, hi};
    rt.y = {1.0, 1.0};
    rt.color = "#e07000";
    rt.line_width = 2.5;
    panel.series.push_back(rt);
  }
  plot_png({panel}, dir / "scale.png", 1000, 640);
  written.push_back("scale.png");
  return written;
}

}  // namespace vx
