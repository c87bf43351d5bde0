// voxelastic simulate SCENE.json --out DIR: runs a scene headless, as fast as it can, and writes
// forces.csv, summary.json, forces.png and (when asked) .pvd series for ParaView.
#include <fmt/core.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdint>
#include <ctime>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "base/error.h"
#include "commands.h"
#include "io/calibration_cache.h"
#include "io/factor_cache.h"
#include "io/region_check_cache.h"
#include "render/plot.h"
#include "scene/run_outputs.h"
#include "scene/scene.h"
#include "sim/simulation.h"
#include "sim/sparse_factor.h"
#include "util/atomic_file.h"
#include "util/exit_codes.h"
#include "util/log.h"
#include "util/progress.h"

namespace vx::cli {
namespace {
namespace fs = std::filesystem;

/// Set by the first Ctrl-C (or SIGTERM); a second one ends the program at once. One stop can
/// arrive twice (`timeout -s INT`, a CI runner or a shell script signals the process and then its
/// process group): a second signal within kDuplicateNs of the first is that same stop, not a
/// second Ctrl-C, and is ignored.
std::atomic<bool> g_stop{false};
std::atomic<std::int64_t> g_first_stop_ns{0};
constexpr std::int64_t kDuplicateNs = 500'000'000;
static_assert(std::atomic<std::int64_t>::is_always_lock_free, "the signal handler needs a lock-free atomic");

extern "C" void on_stop_signal(int sig) {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);  // async-signal-safe
  const std::int64_t now = std::int64_t(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
  const std::int64_t first = g_first_stop_ns.load();
  if (first == 0) {
    g_first_stop_ns.store(now);
    g_stop.store(true);
  } else if (now - first > kDuplicateNs) {
    std::signal(sig, SIG_DFL);  // a second Ctrl-C: end now, as the default action would
    std::raise(sig);
  }
}

/// Catches SIGINT and SIGTERM while alive, restores them after.
class StopSignals {
 public:
  StopSignals() {
    g_stop.store(false);
    g_first_stop_ns.store(0);
    struct sigaction sa {};
    sa.sa_handler = on_stop_signal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = 0;
    sigaction(SIGINT, &sa, &old_int_);
    sigaction(SIGTERM, &sa, &old_term_);
  }
  ~StopSignals() {
    sigaction(SIGINT, &old_int_, nullptr);
    sigaction(SIGTERM, &old_term_, nullptr);
  }
  StopSignals(const StopSignals&) = delete;
  StopSignals& operator=(const StopSignals&) = delete;
  [[nodiscard]] bool stop() const { return g_stop.load(); }

 private:
  struct sigaction old_int_ {
  }, old_term_{};
};

/// "3 h 20 min", "12 min", "40 s".
std::string duration_text(double s) {
  if (s >= 3600) return fmt::format("{:.0f} h {:.0f} min", std::floor(s / 3600), std::fmod(s, 3600) / 60);
  if (s >= 60) return fmt::format("{:.0f} min", s / 60);
  if (s >= 10) return fmt::format("{:.0f} s", s);
  return fmt::format("{:.2g} s", s);
}

/// A step this many times below the stable step (or the one "auto" picks) is far below it.
constexpr double kFarBelowStableStep = 100.0;

/// Wall time of one step of `prepared`'s run, s: a scratch simulation's steps after its first
/// (which sets up an implicit solver), up to 50 of them or half a second.
double measure_step_s(const PreparedScene& prepared) {
  Simulation trial(prepared.physics, prepared.settings);
  if (trial.step() != StepStatus::ok) return 0.0;
  const auto t0 = std::chrono::steady_clock::now();
  int n = 0;
  double elapsed = 0.0;
  while (n < 50 && elapsed < 0.5) {
    if (trial.step() != StepStatus::ok) break;
    ++n;
    elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
  return n > 0 ? elapsed / n : 0.0;
}

/// Before the run: a step far below the stable one (1e-9 s: millions of steps for what "auto"
/// does in thousands) is said, with the run time it means, measured on trial steps.
void warn_if_step_far_below_stable(const Scene& scene, const PreparedScene& prepared, double dt, std::int64_t steps) {
  const double stable = prepared.dt_stable_estimate_s;
  const bool explicit_stable = stable > 0 && std::isfinite(stable);
  const double reference = explicit_stable ? stable : prepared.automatic_dt_s;
  if (!(reference > 0) || dt * kFarBelowStableStep > reference || steps < 1000) return;
  const double step_s = measure_step_s(prepared);
  std::string better;
  if (prepared.automatic_dt_s > dt) {
    const double auto_steps = std::ceil(scene.duration_s / prepared.automatic_dt_s);
    better = fmt::format("; \"dt_s\": \"auto\" ({:.3g} s) takes {:.0f} steps, about {}", prepared.automatic_dt_s,
                         auto_steps, duration_text(auto_steps * step_s));
  }
  log::warn(
      "integrator.dt_s {:.3g} s is {:.3g} times below the {} {:.3g} s: {} steps, about {} at {:.3g} ms per step "
      "(measured on trial steps){}",
      dt, reference / dt, explicit_stable ? "estimated stable step" : "step \"auto\" picks", reference, steps,
      duration_text(double(steps) * step_s), 1e3 * step_s, better);
}

struct SimulateOptions {
  std::string scene;
  std::string out;
  int threads{-1};
  std::string factor_cache;  ///< "" the default folder, "off", or a folder
  bool quiet{false};
  double test_rest_fraction{-1.0};  ///< hidden: IntegratorSettings::region_rest_fraction (< 0: the default)
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

  // build the object and its physics
  PrepareSceneOptions popt;
  popt.surface = out.pvd_surface;
  popt.threads_override = o.threads;
  popt.region_check = RegionCheckTiming::background;  // seconds on a large model: the run starts meanwhile
  popt.region_check_nice = 0;                         // a batch run: its end waits for the check
  popt.factor_cache = make_factor_cache(o.factor_cache);
  popt.calibration_cache = make_calibration_cache(o.factor_cache);  // the same folder
  popt.region_check_cache = make_region_check_cache(o.factor_cache);
  if (o.quiet) log::set_level(std::max(log::level(), log::Level::warn));
  const auto open = std::chrono::steady_clock::now();
  PreparedScene prepared = prepare_scene(scene, popt);
  const auto prepared_at = std::chrono::steady_clock::now();
  if (!o.quiet)
    for (const auto& line : prepared.log) fmt::print("{}\n", line);
  for (const auto& w : prepared.warnings) log::warn("{}", w);  // -q or not: warnings go to stderr
  // the background check's lines once it is done (during the run or after it)
  const auto report_region_check = [&](bool wait) {
    if (const std::optional<RegionCheck> c = take_region_check(prepared, wait)) {
      if (!o.quiet)
        for (const auto& line : c->log) log::info("{}", line);
      for (const auto& w : c->warnings) log::warn("{}", w);
    }
  };
  if (o.test_rest_fraction >= 0) prepared.settings.integrator.region_rest_fraction = o.test_rest_fraction;
  Simulation sim(prepared.physics, prepared.settings);
  const DeviceSide device(sim, prepared.device_side);
  const double dt = sim.dt_s();
  const std::int64_t steps = std::max<std::int64_t>(1, std::int64_t(std::ceil(scene.duration_s / dt - 1e-9)));
  warn_if_step_far_below_stable(scene, prepared, dt, steps);  // -q or not: a warning
  if (!o.quiet)
    fmt::print("simulating {:g} s: {} steps of {:.4g} s ({}), {} probe(s){}{}\n", scene.duration_s, steps, dt,
               to_string(scene.integrator), sim.num_probes(), scene.workspace.enabled ? ", walls" : "",
               device.has_device() ? ", device" : "");

  // run, recording what the scene asks for; Ctrl-C stops after the current step and the
  // outputs up to then are written as for a finished run
  RunOutputs outputs(sim, device, prepared, out, dir, steps);
  outputs.set_force_references(scene_force_references(scene));
  Progress progress("simulate", !o.quiet);
  const StopSignals signals;
  bool interrupted = false, estimated = false;
  const auto t0 = std::chrono::steady_clock::now();
  auto first_step_done = t0;
  for (std::int64_t k = 1; k <= steps; ++k) {
    if (signals.stop()) {
      interrupted = true;
      break;
    }
    if (sim.step() != StepStatus::ok) break;
    if (k == 1) first_step_done = std::chrono::steady_clock::now();
    outputs.after_step(sim, k);
    report_region_check(false);
    if ((k & 63) == 0) {
      progress.update(double(k) / double(steps));
      // after two seconds, say how long the whole run will take when that is long
      const double so_far = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (!estimated && so_far > 2.0) {
        estimated = true;
        const double total = so_far / double(k) * double(steps);
        if (total > 120.0)
          log::info("simulate: about {} for {} steps; Ctrl-C stops early and keeps what is done", duration_text(total),
                    steps);
      }
    }
  }
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  progress.done();
  if (interrupted)
    prepared.pending_region_check.reset();  // cancelled: the outputs do not wait for it
  else
    report_region_check(true);
  // the start-up: the scene's stages, the simulation's set-up, and the first step (which factors
  // an implicit solver); open to the end of the first step
  const auto secs = [](auto a, auto b) { return std::chrono::duration<double>(b - a).count(); };
  std::vector<std::pair<std::string, double>> startup = prepared.stage_seconds;
  startup.emplace_back("simulation set-up", secs(prepared_at, t0));
  startup.emplace_back("first step", secs(t0, first_step_done));
  const SimulationCounters& c = sim.counters();
  const double startup_s = secs(open, first_step_done);
  const auto* calibrations = dynamic_cast<const FolderCalibrationCache*>(popt.calibration_cache.get());
  const bool calibration_loaded = calibrations && calibrations->counters().hits > 0;

  // the outputs, summary.json last
  if (interrupted) outputs.last_frame(sim);
  outputs.finish(sim);
  nlohmann::json summary = run_summary_json(scene, o.scene, prepared, sim, outputs, wall_s);
  summary["duration_s"] = scene.duration_s;
  summary["interrupted"] = interrupted;
  summary["startup_s"] = startup_s;
  summary["factorisations"] = c.factorisations;
  summary["factors_from_cache"] = c.factors_from_cache;
  summary["orders_from_cache"] = c.orders_from_cache;
  summary["factor_s"] = c.factor_s;
  summary["blas"] = SparseFactor::blas_library();
  summary["calibration_from_cache"] = calibration_loaded;
  summary["region_check_from_cache"] = prepared.region_stiffening && prepared.region_stiffening->loaded;
  nlohmann::json& stages = summary["startup_stages_s"];
  for (const auto& [name, s] : startup) stages[name] = s;
  if (interrupted) summary["status"] = "interrupted";
  write_text_atomically(dir / "summary.json", summary.dump(2) + "\n");
  if (interrupted)
    throw Interrupted(
        fmt::format("interrupted at t = {:.6g} s of {:g} s ({} of {} steps); the outputs up to then are "
                    "in {} (summary.json says \"interrupted\": true)",
                    sim.time_s(), scene.duration_s, sim.counters().steps, steps, dir.string()));

  if (!o.quiet) {
    std::string parts;
    for (const auto& [name, s] : startup) parts += fmt::format("{}{} {:.2f} s", parts.empty() ? "" : ", ", name, s);
    std::string factor;
    if (c.factorisations > 0)
      factor = c.factors_from_cache == c.factorisations
                   ? fmt::format("; the factor loaded from the cache in {:.2f} s", c.factor_s)
                   : fmt::format("; factoring took {:.2f} s{}{}", c.factor_s,
                                 c.orders_from_cache > 0 ? " (METIS's order loaded from the cache)" : "",
                                 c.factor_s > 5.0 && SparseFactor::reference_blas()
                                     ? " on the reference BLAS (OpenBLAS factors about 3.7x faster: "
                                       "apt-get install libopenblas0-serial, or scripts/install-deps.sh)"
                                     : "");
    fmt::print("start-up {:.2f} s, open to the end of the first step ({}{}{}{})\n", startup_s, parts,
               calibration_loaded ? "; the calibration loaded from the cache" : "", factor,
               !prepared.region_stiffening          ? ""
               : prepared.region_stiffening->loaded ? "; the region check loaded from the cache"
                                                    : "; the region check ran beside the run");
  }
  const ForceRecorder* recorder = outputs.forces();
  const bool stable = !sim.failed() && sim.state().positions.allFinite();
  if (!o.quiet)
    fmt::print("{} steps, {:.4g} s simulated in {:.3g} s (x{:.3g} real time); max force {:.4g} N -> {}\n", c.steps,
               sim.time_s(), wall_s, wall_s > 0 ? sim.time_s() / wall_s : 0.0, recorder ? recorder->max_force_n() : 0.0,
               dir.string());
  // a tissue at rest sleeps (regional solves): when it last fell asleep, and how far from its rest
  if (!o.quiet && c.sleeps > 0)
    fmt::print(
        "the tissue fell asleep {} time(s), the last at t = {:.3f} s, {:.3f} s after a tool let go ({:.4f} mm "
        "from its rest shape then), {}\n",
        c.sleeps, c.last_sleep_s, c.last_sleep_since_release_s, c.last_release_offset_mm,
        c.last_sleep_offset_mm < 0 ? std::string("its rest shape not known (gravity or a load): slow enough")
        : c.last_sleep_cause == SleepCause::slow
            ? fmt::format("{:.4f} mm from its rest shape and left there (slow)", c.last_sleep_offset_mm)
            : fmt::format("{:.4f} mm from its rest shape and put there ({})", c.last_sleep_offset_mm,
                          to_string(c.last_sleep_cause)));
  if (!o.quiet && sim.state().gravity_mm_s2.isZero(0.0))
    fmt::print("the tissue at the end: {:.4f} mm from its rest shape (the largest node displacement)\n",
               (sim.state().positions - sim.physics().model->rest_positions).colwise().norm().maxCoeff());
  // the work the run left out, for who tunes it (-v; summary.json's "skipped" always)
  log::debug("skipped: {} narrow-phase tests, {} device shapings, {} surface updates, {} steps at rest",
             c.contact.narrow_tests_skipped, device.counters().device_shaping_skipped, c.surface_updates_skipped,
             c.steps_at_rest);
  if (!stable)
    throw Error(fmt::format("the simulation stopped at t = {:.6g} s: {}; the outputs up to then are in {}",
                            sim.time_s(), sim.state().message, dir.string()));
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
  sub->add_option("--factor-cache", opts->factor_cache,
                  "where the implicit solver keeps its factors by the matrix's content, and the material's calibration "
                  "by the model's, so the next start of the same model loads instead of factoring and calibrating: a "
                  "folder, or off (default: $VOXELASTIC_FACTOR_CACHE, else ~/.cache/voxelastic/factors)");
  sub->add_option("--test-rest-fraction", opts->test_rest_fraction,
                  "a tissue at rest: the fraction of its release displacement it falls asleep within (0: by speed "
                  "alone, as before)")
      ->group("");
  sub->callback([opts] {
    opts->quiet = quiet();  // -q: no progress or summary on the console (warnings still go to stderr)
    run_simulate(*opts);
  });
}

}  // namespace vx::cli
