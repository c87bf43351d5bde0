// voxelastic simulate SCENE.json --out DIR: runs a scene headless, as fast as it can, and writes
// forces.csv, summary.json, forces.png and (when asked) .pvd series for ParaView.
#include <fmt/core.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "base/error.h"
#include "base/version.h"
#include "commands.h"
#include "render/plot.h"
#include "scene/scene.h"
#include "scene/sim_output.h"
#include "sim/simulation.h"
#include "util/atomic_file.h"
#include "util/progress.h"

namespace vx::cli {
namespace {
namespace fs = std::filesystem;
using json = nlohmann::json;

struct SimulateOptions {
  std::string scene;
  std::string out;
  int threads{-1};
  bool quiet{false};
};

json vec(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

const char* source_name(ObjectSource s) {
  switch (s) {
    case ObjectSource::phantom: return "phantom";
    case ObjectSource::volume: return "volume";
    case ObjectSource::model: return "model";
    case ObjectSource::box: return "box";
  }
  return "?";
}

void run_simulate(const SimulateOptions& o) {
  // the scene and the outputs first: a mistake there should cost nothing
  const Scene scene = load_scene(o.scene);
  const fs::path dir(o.out);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    throw Error(fmt::format("--out '{}': cannot create the folder ({})", o.out, ec ? ec.message() : "not a folder"));
  check_output_path(dir / "summary.json");
  const SceneOutputs& out = scene.outputs;
  if (out.plot) check_gnuplot();

  // build the object and its physics
  PrepareSceneOptions popt;
  popt.surface = out.pvd_surface;
  popt.threads_override = o.threads;
  const PreparedScene prepared = prepare_scene(scene, popt);
  if (!o.quiet) {
    for (const auto& line : prepared.log) fmt::print("{}\n", line);
    for (const auto& w : prepared.warnings) fmt::print(stderr, "voxelastic: warning: {}\n", w);
  }
  Simulation sim(prepared.physics, prepared.settings);
  const double dt = sim.dt_s();
  const std::int64_t steps = std::max<std::int64_t>(1, std::int64_t(std::ceil(scene.duration_s / dt - 1e-9)));
  if (!o.quiet)
    fmt::print("simulating {:g} s: {} steps of {:.4g} s ({}), {} probe(s){}{}\n", scene.duration_s, steps, dt,
               to_string(scene.integrator), sim.num_probes(), scene.workspace.enabled ? ", walls" : "",
               sim.has_device() ? ", device" : "");

  // what to record: only what was asked for
  std::optional<ForceRecorder> recorder;
  if (out.forces_csv || out.plot) recorder.emplace(sim, out.forces_interval_s);
  const bool pvd = out.pvd_model || out.pvd_surface;
  std::optional<PvdSeries> model_series, surface_series, probe_series;
  std::unique_ptr<ModelFrameWriter> model_writer;
  std::unique_ptr<SurfaceFrameWriter> surface_writer;
  if (out.pvd_model) {
    model_series.emplace(dir, "model", "vtu");
    model_writer = std::make_unique<ModelFrameWriter>(*prepared.model);
  }
  if (out.pvd_surface) {
    surface_series.emplace(dir, "surface", "vtp");
    surface_writer = std::make_unique<SurfaceFrameWriter>(*prepared.surface);
  }
  if (pvd && sim.num_probes() > 0) probe_series.emplace(dir, "probes", "vtp");
  std::int64_t frames = 0;
  const std::int64_t frame_every = std::max<std::int64_t>(1, std::llround(out.pvd_interval_s / dt));
  auto write_frame = [&] {
    if (model_series) {
      model_writer->write(sim.state().positions, sim.state().velocities, model_series->next_frame_path());
      model_series->add(sim.time_s());
    }
    if (surface_series) {
      surface_writer->write(sim.surface_vertices(), surface_series->next_frame_path());
      surface_series->add(sim.time_s());
    }
    if (probe_series) {
      write_probe_frame(sim, probe_series->next_frame_path());
      probe_series->add(sim.time_s());
    }
    ++frames;
  };
  if (pvd) write_frame();

  // run
  Progress progress("simulate", !o.quiet);
  const auto t0 = std::chrono::steady_clock::now();
  for (std::int64_t k = 1; k <= steps; ++k) {
    if (sim.step() != StepStatus::ok) break;
    if (recorder) recorder->record(sim);
    if (pvd && (k % frame_every == 0 || k == steps)) write_frame();
    if ((k & 63) == 0) progress.update(double(k) / double(steps));
  }
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  progress.done();
  if (recorder) recorder->finish(sim);

  // outputs
  std::vector<std::string> written, not_requested;
  if (out.forces_csv) {
    recorder->write_csv(dir / "forces.csv");
    written.push_back("forces.csv");
  } else {
    not_requested.push_back("forces.csv");
  }
  if (out.plot) {
    plot_forces(*recorder, dir / "forces.png");
    written.push_back("forces.png");
  } else {
    not_requested.push_back("forces.png");
  }
  for (auto* s : {&model_series, &surface_series, &probe_series})
    if (*s) {
      (*s)->finish();
      written.push_back((*s)->collection_path().filename().string());
    }
  if (!out.pvd_model) not_requested.push_back("model.pvd");
  if (!out.pvd_surface) not_requested.push_back("surface.pvd");

  const SimulationCounters& c = sim.counters();
  const Model& m = *prepared.model;
  const bool stable = !sim.failed() && sim.state().positions.allFinite();
  json j;
  j["scene"] = fs::absolute(o.scene).string();
  j["description"] = scene.description;
  j["voxelastic_version"] = vx::kVersion;
  j["steps"] = c.steps;
  j["sim_time_s"] = sim.time_s();
  j["wall_s"] = wall_s;
  j["realtime_factor"] = wall_s > 0 ? sim.time_s() / wall_s : 0.0;
  j["elements"] = m.num_elements();
  j["nodes"] = m.num_nodes();
  j["vertex_entries"] = m.num_vertex_entries();
  j["surface_nodes"] = m.num_surface_nodes();
  j["fixed_nodes"] = prepared.fixed_nodes;
  j["integrator"] = to_string(scene.integrator);
  j["dt_s"] = dt;
  j["dt_stable_estimate_s"] = std::isfinite(prepared.dt_stable_estimate_s) ? json(prepared.dt_stable_estimate_s) : json(nullptr);
  j["threads"] = prepared.settings.integrator.threads;
  j["stable"] = stable;
  j["status"] = to_string(sim.state().status);
  j["message"] = sim.state().message;
  j["max_force_n"] = recorder ? recorder->max_force_n() : 0.0;
  j["max_step_force_n"] = recorder ? recorder->max_step_force_n() : 0.0;
  j["forces_interval_s"] = out.forces_interval_s;
  j["object"] = {{"source", source_name(scene.object.source)},
                 {"resolution", to_string(m.layout)},
                 {"bounds_mm", {{"min", vec(prepared.bounds_min_mm)}, {"max", vec(prepared.bounds_max_mm)}}},
                 {"mass_kg", prepared.physics->total_mass_kg()},
                 {"spacing_mm", vec(m.grid.spacing_mm)}};
  j["material"] = {{"youngs_modulus_kpa", scene.material.base.youngs_modulus_kpa},
                   {"poisson_ratio", scene.material.base.poisson_ratio},
                   {"density_kg_m3", scene.material.base.density_kg_m3},
                   {"damping", scene.material.base.damping_ratio},
                   {"element_modulus_kpa", {{"min", prepared.min_modulus_kpa}, {"max", prepared.max_modulus_kpa}}},
                   {"heterogeneous_elements", prepared.heterogeneous_elements}};
  json probes = json::array();
  for (int i = 0; i < sim.num_probes(); ++i) {
    const ProbeSettings& p = prepared.settings.probes[std::size_t(i)];
    const ProbeOutput& po = sim.probe(i);
    probes.push_back({{"name", p.name},
                      {"shape", to_string(p.geometry.shape)},
                      {"drive", to_string(p.drive)},
                      {"max_force_n", recorder ? recorder->max_force_n(i) : 0.0},
                      {"final_position_mm", vec(po.pose.position_mm)},
                      {"final_force_n", vec(po.raw_force_n)}});
  }
  j["probes"] = probes;
  j["walls"] = scene.workspace.enabled
                   ? json{{"min_mm", vec(scene.workspace.min_mm)},
                          {"max_mm", vec(scene.workspace.max_mm)},
                          {"max_force_n", recorder ? recorder->max_wall_force_n() : 0.0},
                          {"impulse_n_s", recorder ? vec(recorder->wall_impulse_n_s()) : json(nullptr)}}
                   : json(nullptr);
  j["device"] = sim.has_device()
                    ? json{{"update_interval_s", prepared.settings.device->update_interval_s},
                           {"average_steps", prepared.settings.device->average_steps},
                           {"mean_preserving", prepared.settings.device->mean_preserving}}
                    : json(nullptr);
  j["work"] = {{"contact_passes", c.contact_passes},
               {"narrow_phase_tests", c.contact.narrow_tests},
               {"broad_phase_tests", c.contact.broad_tests},
               {"broad_phase_rebuilds", c.contact.rebuilds},
               {"node_contacts", c.contact.contacts},
               {"wall_contacts", c.contact.wall_contacts},
               {"device_shaping_steps", c.device_shaping_steps},
               {"surface_updates", c.surface_updates},
               {"output_frames", frames},
               {"force_rows", recorder ? json(recorder->rows().size()) : json(0)}};
  j["skipped"] = {{"contact_passes", c.contact_passes_skipped},
                  {"narrow_phase_tests", c.contact.narrow_tests_skipped},
                  {"device_shaping_steps", c.device_shaping_skipped},
                  {"surface_updates", c.surface_updates_skipped},
                  {"steps_without_output_frame", c.steps - std::max<std::int64_t>(0, frames - (pvd ? 1 : 0))},
                  {"outputs_not_requested", not_requested}};
  j["warnings"] = prepared.warnings;
  written.push_back("summary.json");
  j["outputs"] = written;
  write_text_atomically(dir / "summary.json", j.dump(2) + "\n");

  if (!o.quiet)
    fmt::print("{} steps, {:.4g} s simulated in {:.3g} s (x{:.3g} real time); max force {:.4g} N; skipped: {} narrow-phase "
               "tests, {} device shapings, {} surface updates -> {}\n",
               c.steps, sim.time_s(), wall_s, wall_s > 0 ? sim.time_s() / wall_s : 0.0,
               recorder ? recorder->max_force_n() : 0.0, c.contact.narrow_tests_skipped, c.device_shaping_skipped,
               c.surface_updates_skipped, dir.string());
  if (!stable)
    throw Error(fmt::format("the simulation stopped at t = {:.6g} s: {}; the outputs up to then are in {}", sim.time_s(),
                            sim.state().message, dir.string()));
}

}  // namespace

void add_simulate_command(CLI::App& app) {
  auto opts = std::make_shared<SimulateOptions>();
  CLI::App* sub = app.add_subcommand(
      "simulate",
      "Run a scene (JSON, see docs/scenes.md) headless as fast as possible: writes DIR/forces.csv, DIR/summary.json, "
      "DIR/forces.png and, when the scene asks, .pvd series for ParaView.");
  sub->add_option("SCENE", opts->scene, "scene file (.json)")->required()->check(CLI::ExistingFile);
  sub->add_option("-o,--out", opts->out, "output folder (created if missing)")->required();
  sub->add_option("--threads", opts->threads, "threads for the physics (0: all cores; default: the scene's)");
  sub->add_flag("-q,--quiet", opts->quiet, "no progress or summary on the console");
  sub->callback([opts] { run_simulate(*opts); });
}

}  // namespace vx::cli
