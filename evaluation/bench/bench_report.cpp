// The outputs of `voxelastic bench` (bench.h): step.csv, bench.csv, bench.json, bench.md and the
// scenes that re-run the reference and the best row, written all or nothing; the pictures are
// bench_plots.cpp.
#include <fmt/format.h>
#include <unistd.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "base/error.h"
#include "bench/bench.h"
#include "bench/bench_parts.h"
#include "util/atomic_file.h"

namespace vx {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace bench_parts {

std::string seconds_text(double s) { return s < 100 ? fmt::format("{:.1f} s", s) : fmt::format("{:.0f} s", s); }
std::string fraction_text(double f) { return std::isfinite(f) ? fmt::format("{:g}x", f) : std::string(); }
std::string pct(double v) { return std::isfinite(v) ? fmt::format("{:.2f} %", 100 * v) : std::string("-"); }
std::string pct_signed(double v) { return std::isfinite(v) ? fmt::format("{:+.1f} %", 100 * v) : std::string("-"); }

}  // namespace bench_parts

namespace {

using bench_parts::best_of;
using bench_parts::fraction_text;
using bench_parts::pct;
using bench_parts::pct_signed;
using bench_parts::seconds_text;

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
  json j = {{"resolution", step_row_resolution(r)},
            {"dimensions", r.dimensions},
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
json row_scene(const BenchSettings& s, const BenchRow& r, bool reference = false) {
  PalpationSceneSettings scene = s.scene;
  if (reference && s.reference_element) scene.element = *s.reference_element;
  return palpation_scene_json(scene, r.size, r.layout, r.integrator, r.time_step_s, r.threads);
}

std::string sps(double v) { return std::isfinite(v) ? fmt::format("{:.3g}", v) : std::string("-"); }

}  // namespace

// --- CSV ----------------------------------------------------------------------------------

std::string step_csv(const std::vector<StepBenchmarkRow>& rows) {
  std::ostringstream out;
  out << "resolution,size,integrator,threads,elements,nodes,vertex_entries,build_s,setup_s,time_step_s,steps,step_ms,"
         "ns_per_element,ns_per_entry,real_time_factor,iterations,factor_nonzeros,skipped,note\n";
  for (const auto& r : rows) {
    out << step_row_resolution(r) << ',' << r.size << ',' << to_string(r.integrator) << ',' << r.threads << ','
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

// --- JSON and Markdown --------------------------------------------------------------------

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
                  {"element", to_string(sc.element)},
                  {"reference_element", to_string(s.reference_element.value_or(sc.element))},
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
    ref["scene"] = row_scene(s, res.reference, true);
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
    md << "`gradational-2d` is the 2D model (one slice, plane stress; docs/model.md section 12) of a disk n pixels "
          "across, the same element and integrators: the paper's 2D case.\n\n";
    md << "| resolution | n | integrator | elements | vertex entries | ms per step | ns per entry | real time x | note |\n"
          "|---|---|---|---|---|---|---|---|---|\n";
    for (const auto& r : res.step_rows) {
      if (r.skipped) {
        md << fmt::format("| {} | {} | {} | {} | {} | - | - | - | {} |\n", step_row_resolution(r), r.size,
                          to_string(r.integrator), r.elements ? std::to_string(r.elements) : "-",
                          r.vertex_entries ? std::to_string(r.vertex_entries) : "-", r.note);
        continue;
      }
      md << fmt::format("| {} | {} | {} | {} | {} | {:.3f} | {:.2f} | {:.3g} | {} |\n", step_row_resolution(r), r.size,
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

// --- the output folder --------------------------------------------------------------------

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
      bench_parts::plot_step(res, staging / "step.png");
      names.push_back("step.png");
    }
    if (res.settings.run_palpation) {
      write_text_atomically(staging / "bench.csv", bench_csv(res.rows));
      names.push_back("bench.csv");
      bench_parts::plot_error(res, staging / "bench_error.png");
      names.push_back("bench_error.png");
      bench_parts::plot_cost(res, staging / "bench_cost.png");
      names.push_back("bench_cost.png");
      bench_parts::plot_curves(res, staging / "bench_curves.png");
      names.push_back("bench_curves.png");
      write_text_atomically(staging / "reference_scene.json", row_scene(res.settings, res.reference, true).dump(2) + "\n");
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
