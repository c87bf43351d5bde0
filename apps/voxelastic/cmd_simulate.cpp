// voxelastic simulate SCENE.json --out DIR: runs a scene headless, as fast as it can, and writes
// forces.csv, summary.json, forces.png and (when asked) .pvd series for ParaView.
#include <fmt/core.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "base/error.h"
#include "commands.h"
#include "render/plot.h"
#include "scene/run_outputs.h"
#include "scene/scene.h"
#include "sim/simulation.h"
#include "util/atomic_file.h"
#include "util/progress.h"

namespace vx::cli {
namespace {
namespace fs = std::filesystem;

struct SimulateOptions {
  std::string scene;
  std::string out;
  int threads{-1};
  bool quiet{false};
};

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

  // run, recording what the scene asks for
  RunOutputs outputs(sim, prepared, out, dir, steps);
  Progress progress("simulate", !o.quiet);
  const auto t0 = std::chrono::steady_clock::now();
  for (std::int64_t k = 1; k <= steps; ++k) {
    if (sim.step() != StepStatus::ok) break;
    outputs.after_step(sim, k);
    if ((k & 63) == 0) progress.update(double(k) / double(steps));
  }
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  progress.done();

  // the outputs, summary.json last
  outputs.finish(sim);
  write_text_atomically(dir / "summary.json",
                        run_summary_json(scene, o.scene, prepared, sim, outputs, wall_s).dump(2) + "\n");

  const SimulationCounters& c = sim.counters();
  const ForceRecorder* recorder = outputs.forces();
  const bool stable = !sim.failed() && sim.state().positions.allFinite();
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
