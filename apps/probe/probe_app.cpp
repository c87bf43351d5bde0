#include "probe_app.h"

#include <fmt/core.h>
#include <omp.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <future>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "app_shared.h"
#include "base/error.h"
#include "base/parallel.h"
#include "device_loop.h"
#include "display.h"
#include "force_output.h"
#include "gui_loop.h"
#include "haptics/device_side.h"
#include "haptics/local_contact.h"
#include "io/calibration_cache.h"
#include "io/factor_cache.h"
#include "io/region_check_cache.h"
#include "io/surface_cache.h"
#include "joystick_script.h"
#include "physics_loop.h"
#include "probe_view.h"
#include "rate_thread.h"
#include "sdl_input.h"
#include "sim/contact.h"
#include "sim/simulation.h"
#include "soak.h"
#include "util/thread_priority.h"

namespace vx::probe {

namespace {

std::atomic<bool> g_interrupted{false};
extern "C" void on_interrupt(int) { g_interrupted.store(true); }

/// What a session that ended leaves running: the solver being built in the background, asked
/// to stop (IntegratorCache::abandon_pending), and the factor cache it may offer its factor to.
struct LeftRunning {
  std::future<IntegratorCache::SolverPtr> solver;
  double solver_age_s{0.0};  ///< how long it had been building at the end, s
  std::shared_ptr<FactorCache> factor_cache;
};

/// The app: opens the scene, the input and the outputs, starts the physics and device threads
/// (physics_loop.h, device_loop.h), runs the GUI loop (gui_loop.h) on this thread, and reports.
/// What the loops share is `AppShared` (app_shared.h).
class App {
 public:
  App(const AppOptions& options, ProbeScene scene) : options_(options), scene_(std::move(scene)) {}
  int run();
  /// After run(): what is still building in the background, handed over so that the App's end
  /// does not wait for it.
  [[nodiscard]] LeftRunning leave_running() {
    LeftRunning left;
    if (!sim_ || !sim_->solver_pending()) return left;
    left.solver_age_s = sim_->solver_pending_s();
    left.solver = sim_->abandon_pending_solver();
    left.factor_cache = scene_.simulation.integrator.factor_cache;
    return left;
  }

 private:
  void say(const std::string& line) const {
    if (!options_.quiet) fmt::print("{}\n", line);
  }
  /// The HUD's input and force-output lines.
  struct IoLines {
    std::string input, output;
  };
  // the stages of run()
  /// The simulation with the options that override the scene; the stick mapping (command line
  /// over scene over defaults).
  void start_simulation();
  void open_input();
  void open_outputs();
  /// The device loop with its commanders (and, local shaping, its hands and renderers).
  void make_device_loop();
  /// Prints what drives the probes and where the force goes; returns the HUD's lines.
  [[nodiscard]] IoLines describe_io();
  /// The window (null when headless).
  [[nodiscard]] std::unique_ptr<ProbeView> open_view(const IoLines& lines);
  /// The three loops until a quit (the window opened once the threads run); returns the error
  /// that ended them ("" for none).
  [[nodiscard]] std::string run_loops(const IoLines& lines);
  /// After the threads stopped: the force outputs closed, the screenshot, the summary; returns
  /// the exit code.
  [[nodiscard]] int finish(ProbeView* view, std::string error);
  /// The final lines: start-up, the real-time factor over the run after the start-up, forces.
  void summary(double wall_s);
  /// --soak-s: the soak's figures in one line (docs/robustness.md, "Soak").
  void soak_summary();

  const AppOptions& options_;
  /// Turned true by a quit: the solver's build in the background stops (IntegratorSettings::stop_background).
  std::shared_ptr<std::atomic<bool>> stop_background_{std::make_shared<std::atomic<bool>>(false)};
  ProbeScene scene_;
  std::unique_ptr<Simulation> sim_;
  std::unique_ptr<DeviceSide> device_side_;  ///< after sim_: it detaches from it first
  std::unique_ptr<AppShared> shared_;
  std::shared_ptr<const JoystickScript> script_;
  std::unique_ptr<SdlInput> input_;
  ForceOutputs outputs_;
  std::vector<std::string> output_notes_;
  KeyboardStick keyboard_;
  ControlSettings control_;
  std::unique_ptr<DeviceLoop> device_loop_;
  std::unique_ptr<ProbeView> view_;  ///< null when headless
  std::unique_ptr<GuiLoop> gui_loop_;
  /// The display thread's nice value (it and its renderer's threads yield to the physics).
  static constexpr int kGuiNice = 10;
  bool gui_nice_{false};
  int physics_threads_{1};
  int render_threads_{0};  ///< LP_NUM_THREADS for a software renderer (display.h)
  int probes_{0};
  bool local_{false};
  // after the run (finish)
  std::int64_t device_missed_{0};
  RateSample end_{};  ///< the physics at the quit (or when it stopped)
};

// ---------------------------------------------------------------- set-up

void App::open_input() {
  InputSettings in;
  in.max_sticks = std::min(kMaxSticks, std::max(1, probes_));
  in.joysticks = options_.use_joysticks;
  if (options_.soak_s > 0) {
    // the soak's random script: one stick per probe (two: grasps too)
    SoakMotion motion;
    motion.speed_mm_s = control_.mapping.max_speed_mm_s;
    motion.dead_zone = control_.mapping.dead_zone;
    // the gap: from the first tool at its start to the nearest node of the tissue at rest
    const Eigen::Matrix3Xd& rest = scene_.physics->model->rest_positions;
    const ProbeSettings& tool = scene_.simulation.probes.front();
    double gap = std::numeric_limits<double>::infinity();
    for (Eigen::Index i = 0; i < rest.cols(); ++i)
      gap = std::min(gap, probe_signed_distance(tool.geometry, sim_->probe(0).pose.position_mm, rest.col(i)));
    motion.gap_mm = std::clamp(gap, 0.0, 30.0);
    say(fmt::format("soak: {:.0f} s of random presses, slides{} (seed {}), the tool {:.1f} mm above the tissue",
                    options_.soak_s, probes_ > 1 ? ", grasps" : "", options_.soak_seed, motion.gap_mm));
    script_ = std::make_shared<const JoystickScript>(JoystickScript::parse(
        make_soak_script(options_.soak_s, options_.soak_seed, std::min(probes_, kMaxSticks), motion),
        "the soak script"));
    in.script = script_;
  } else if (!options_.joystick_script.empty()) {
    script_ = std::make_shared<const JoystickScript>(JoystickScript::load(options_.joystick_script));
    in.script = script_;
    if (script_->sticks() > probes_)
      say(fmt::format("note: the script drives {} sticks but the scene has {} probe(s); extra sticks are ignored",
                      script_->sticks(), probes_));
  }
  input_ = std::make_unique<SdlInput>(in);
  for (const auto& m : input_->take_messages()) say("input: " + m);
}

void App::open_outputs() {
  DeviceOutputSettings base;
  base.max_force_N = options_.max_force_N;
  base.max_update_hz = options_.device_update_hz;
  if (options_.device != DeviceChoice::none) {
    for (int i = 0; i < input_->count() && i < probes_; ++i) {
      DeviceOutputSettings s = base;
      s.probe = i;
      std::string why_haptic, why_rumble;
      if (options_.device == DeviceChoice::automatic || options_.device == DeviceChoice::haptic) {
        if (auto h = HapticForceOutput::open(input_->joystick(i), input_->name(i), s, why_haptic)) {
          output_notes_.push_back(h->describe());
          outputs_.add(std::move(h));
          continue;
        }
        if (options_.device == DeviceChoice::haptic)
          throw Error(fmt::format("--force-output haptic: joystick '{}' has no usable force feedback: {}",
                                  input_->name(i), why_haptic));
      }
      if (auto r = RumbleForceOutput::open(input_->joystick(i), input_->name(i), s, why_rumble)) {
        if (options_.device == DeviceChoice::automatic)
          say(fmt::format("note: joystick '{}': {}; using rumble instead", input_->name(i), why_haptic));
        output_notes_.push_back(r->describe());
        outputs_.add(std::move(r));
        continue;
      }
      if (options_.device == DeviceChoice::rumble)
        throw Error(fmt::format("--force-output rumble: joystick '{}' cannot rumble", input_->name(i)));
      say(fmt::format("note: joystick '{}' has neither force feedback ({}) nor rumble: no force output on it",
                      input_->name(i), why_haptic));
    }
  }
  if (!options_.force_log.empty()) {
    auto rec = std::make_unique<RecordingForceOutput>(options_.force_log);
    output_notes_.push_back(rec->describe());
    outputs_.add(std::move(rec));
  }
  if (outputs_.empty())
    output_notes_.push_back("no force device: forces on the HUD and plot only (--force-log FILE.csv records them)");
}

void App::start_simulation() {
  // the simulation, with the options that override the scene
  // sharing the cores (thread_share.h): the core's loops follow the physics thread's own OpenMP
  // setting (0), which that thread sets to its share before each step
  const int given = resolve_threads(options_.threads);
  physics_threads_ = given;
  const bool share = options_.share_cores && given > 1;
  scene_.simulation.integrator.threads = share ? 0 : given;
  // the step that wakes a resting tissue (the tool's first touch: 0.3 s on the folded organ) on
  // every thread, though the share had the physics ahead on one while it rested
  scene_.simulation.integrator.wake_threads = share ? given : 0;
  // the second start of the same organ loads its factor instead of computing it (io/factor_cache.h)
  scene_.simulation.integrator.factor_cache = make_factor_cache(options_.factor_cache);
  // a session's memory flat: the contact solve's cache resident from the start, not filling as
  // the tool visits new places (--test-lazy-contact-cache: as before, to measure the difference)
  scene_.simulation.integrator.reserve_contact_cache = !options_.lazy_contact_cache;
  if (options_.test_rest_fraction >= 0) scene_.simulation.integrator.region_rest_fraction = options_.test_rest_fraction;
  // the session starts while the solver is factored beside it, the tissue at rest meanwhile
  scene_.simulation.integrator.factor_in_background = options_.background_factor;
  scene_.simulation.integrator.factor_in_background_delay_s = options_.test_factor_delay_s;
  // a quit stops it (AppControls::request_quit), and no step waits for it past the quit
  scene_.simulation.integrator.stop_background = stop_background_;
  // the solver's build beside the physics, told apart from it (it inherits its nice, 2)
  scene_.simulation.integrator.background_thread_start = [] { (void)set_this_thread_name("vx-factor"); };
  std::optional<DeviceForceSettings>& dev = scene_.device_side.device;
  local_ = options_.force_shaping.value_or(dev ? dev->shaping : ForceShaping::paper) == ForceShaping::local;
  if (local_ && !dev) dev = DeviceForceSettings{};
  if (dev) dev->shaping = local_ ? ForceShaping::local : ForceShaping::paper;
  if (local_) {
    LocalContactSettings lc;
    lc.update_period_s = 1.0 / options_.physics_hz;
    scene_.device_side.local_contact = lc;
  }
  sim_ = std::make_unique<Simulation>(scene_.physics, scene_.simulation);
  device_side_ = std::make_unique<DeviceSide>(*sim_, scene_.device_side);
  probes_ = sim_->num_probes();
  if (probes_ == 0) throw Error("the scene has no probe to palpate with");
  if (probes_ > kMaxSticks)
    say(fmt::format("note: the scene has {} probes; the app drives the first {}", probes_, kMaxSticks));
  shared_ = std::make_unique<AppShared>(options_, *sim_, *device_side_);
  shared_->controls.stop_background = stop_background_;
  shared_->region_check = scene_.region_check;
  shared_->accuracy_status = scene_.accuracy_status;
  shared_->display_surface = scene_.surface;
  shared_->surface_refinement = scene_.surface_refinement;
  shared_->probes = probes_;
  shared_->local = local_;
  shared_->physics_period_s = 1.0 / options_.physics_hz;
  shared_->device_period_s = 1.0 / options_.device_hz;
  shared_->physics_threads = given;
  shared_->share_cores = share;
  shared_->physics.threads.store(given);
  // the stick mapping: the command line over the scene over the defaults
  control_ = options_.control;
  if (scene_.control_from_scene) {
    const JoystickMapping& scene_mapping = scene_.control.mapping;
    if (!options_.mode_set) control_.mapping.mode = scene_mapping.mode;
    if (!options_.speed_set) control_.mapping.max_speed_mm_s = scene_mapping.max_speed_mm_s;
    if (!options_.range_set) control_.mapping.range_mm = scene_mapping.range_mm;
    if (!options_.deadzone_set) control_.mapping.dead_zone = scene_mapping.dead_zone;
  }
}

void App::make_device_loop() {
  DeviceParts parts;
  parts.input = input_.get();
  parts.keyboard = &keyboard_;
  parts.outputs = &outputs_;
  parts.script = script_;
  parts.control = control_;
  parts.keyboard_control.mapping = control_.mapping;
  parts.keyboard_control.mapping.dead_zone = 0.0;
  device_loop_ = std::make_unique<DeviceLoop>(*shared_, std::move(parts));
  for (int p = 0; p < std::min(probes_, kMaxSticks); ++p) {
    const Box allowed = p < int(scene_.probe_allowed.size()) ? scene_.probe_allowed[std::size_t(p)] : Box{};
    device_loop_->add_commander(sim_->probe(p).pose.position_mm, allowed);
  }
  if (!local_) return;
  // local shaping: the device thread owns the tools' (hands') positions and the force rendering
  HapticCouplingSettings hs;
  hs.device_rate_hz = options_.device_hz;
  if (const auto& dev = scene_.device_side.device) hs.device_damping_n_s_mm = dev->device_damping_n_s_mm;
  if (const std::string bad = hs.validate(); !bad.empty()) throw Error("local force shaping: " + bad);
  std::array<Eigen::Vector3d, kMaxSticks> start{};
  for (int p = 0; p < std::min(probes_, kMaxSticks); ++p)
    start[std::size_t(p)] = device_loop_->add_local_probe(scene_.simulation.probes[std::size_t(p)], hs);
  shared_->tool_targets.fill(start);
  say(
      fmt::format("force: local contact model at every device tick ({:.0f}/s): virtual coupling {:.2f} N/mm (Colgate, "
                  "device damping {:.2g} N s/m), damping {:.1f} T K, energy guard; physics updates at up to {:.0f}/s",
                  options_.device_hz, device_loop_->renderer(0).coupling_stiffness_n_mm(),
                  1e3 * hs.device_damping_n_s_mm, hs.damping_margin, options_.physics_hz));
}

App::IoLines App::describe_io() {
  const std::string control = control_.mapping.mode == JoystickMode::rate ? "rate control" : "position control";
  IoLines lines;
  if (script_)
    lines.input = fmt::format("{}: {} virtual joystick{} ({})", control, input_->count(),
                              input_->count() > 1 ? "s" : "", options_.joystick_script.filename().string());
  else if (input_->count() > 0)
    lines.input = fmt::format("{}: {} + keyboard/mouse", control,
                              input_->count() > 1 ? "2 joysticks" : "joystick '" + input_->name(0) + "'");
  else
    lines.input = fmt::format("{}: keyboard and mouse (no joystick)", control);
  lines.output = "force out: ";
  if (outputs_.empty()) lines.output += "none (HUD and plot only)";
  for (std::size_t i = 0; i < outputs_.all().size(); ++i) lines.output += (i ? " + " : "") + outputs_.all()[i]->label();
  say("input: " + (input_->count() > 0 ? input_->describe() : std::string("keyboard and mouse")) + ", " + control);
  for (const auto& n : output_notes_) say("force: " + n);
  for (const auto& m : input_->take_messages()) say("input: " + m);
  return lines;
}

std::unique_ptr<ProbeView> App::open_view(const IoLines& lines) {
  if (options_.headless) return nullptr;
  ViewSetup setup;
  setup.title = scene_.name;
  setup.surface_vertices = scene_.surface->rest_vertices;
  setup.surface_triangles = scene_.surface->triangles;
  // the elements view's cells when it is first shown (`l`, --levels): 1.1 s on the folded organ,
  // which came before the first frame
  setup.make_levels = [model = scene_.model] { return std::make_shared<const LevelCells>(make_level_cells(*model)); };
  for (int p = 0; p < probes_; ++p) {
    setup.probes.push_back(scene_.simulation.probes[std::size_t(p)].geometry);
    setup.probe_names.push_back(scene_.simulation.probes[std::size_t(p)].name);
    setup.probe_start_mm.push_back(sim_->probe(p).pose.position_mm);
  }
  setup.walls = scene_.simulation.workspace.enabled;
  setup.workspace = Box{scene_.simulation.workspace.min_mm, scene_.simulation.workspace.max_mm};
  setup.world_up = scene_.world_up;
  setup.flat = scene_.model->is_2d();
  if (setup.flat)
    setup.slice_normal = scene_.model->grid.direction.col(0).cross(scene_.model->grid.direction.col(1)).normalized();
  setup.width = options_.width;
  setup.height = options_.height;
  setup.input_line = lines.input;
  setup.output_line = lines.output;
  setup.local_shaping = local_;
  setup.physics_line = physics_configuration(scene_.simulation.integrator, *scene_.physics);
  auto view = std::make_unique<ProbeView>(setup, &keyboard_, [this](ViewAction a) {
    if (gui_loop_) gui_loop_->on_action(a);
  });
  if (options_.show_levels) view->toggle_levels();
  return view;
}

// ---------------------------------------------------------------- the run

std::string App::run_loops(const IoLines& lines) {
  PhysicsLoop physics_loop(*shared_);
  physics_loop.set_step_delay(options_.test_step_delay_s, options_.test_startup_delay_s);
  physics_loop.set_faults(options_.test_faults);
  shared_->start = SteadyClock::now();
  shared_->physics.set_clock(SimClock{0.0, shared_->start, false});
  // named for top -H, perf and gdb (the physics' OpenMP workers inherit its name)
  FixedRateThread physics(
      "physics", options_.physics_hz, [&](std::int64_t) { physics_loop.tick(); },
      [] { (void)set_this_thread_name("vx-physics"); });
  FixedRateThread device(
      "device", options_.device_hz, [this](std::int64_t n) { device_loop_->tick(n); },
      [] {
        (void)set_this_thread_name("vx-device");
        // its deadline is 1 ms: the core's loops it calls run on it alone, never on a team of its
        // own (with the physics sharing the cores the core runs with threads 0: each thread's own
        // OpenMP setting)
        omp_set_num_threads(1);
      });
  // the scene was loaded on this thread with OpenMP: its idle workers would make the physics'
  // team sleep at every barrier, and so would a team the display formed (its surface's normals)
  // (base/parallel.h)
  (void)leave_parallel_work_to_others();
  const auto old_int = std::signal(SIGINT, on_interrupt);
  const auto old_term = std::signal(SIGTERM, on_interrupt);
  physics.start();
  device.start();
  // the display yields to the physics and the device when the CPU is short (Linux: per thread,
  // inherited by the threads this one creates: the window is opened after the lowering, so a
  // software renderer's threads (Mesa llvmpipe under Xvfb) run at the display's priority too,
  // not at the physics')
  gui_loop_ = std::make_unique<GuiLoop>(*shared_, nullptr, keyboard_);
  if (!options_.headless) {
    gui_nice_ = set_this_thread_nice(kGuiNice);
    // and a software renderer's threads keep off the physics' cores (display.h)
    render_threads_ = limit_software_render_threads(omp_get_num_procs(), physics_threads_);
    gui_loop_->prime(device);  // (the first frame's rates over the window's opening)
    view_ = open_view(lines);
    gui_loop_->set_view(view_.get());
  }
  std::string error = gui_loop_->run(physics, device, g_interrupted);

  // stop: device first (no more writes), then physics (its last step ends the run's interval)
  device.stop();
  physics.stop();
  physics_loop.finish();
  const PhysicsReport& r = shared_->physics;
  end_ = r.ended.load(std::memory_order_acquire) ? r.at_end : r.sample(shared_->start, SteadyClock::now());
  std::signal(SIGINT, old_int);
  std::signal(SIGTERM, old_term);
  device_missed_ = device.missed();
  if (error.empty() && device.failed()) error = device.error();
  if (error.empty() && physics.failed()) error = physics.error();
  return error;
}

void App::summary(double wall_s) {
  const PhysicsReport& r = shared_->physics;
  const std::int64_t steps = r.steps.load();
  const std::string dt = fmt::format("dt {:.3g} ms", 1e3 * sim_->dt_s());
  if (!r.started.load(std::memory_order_acquire)) {
    say(fmt::format("voxelastic-probe: {:.2f} s wall; start-up not finished (no physics step completed; {})", wall_s,
                    dt));
  } else {
    // the real-time factor over the whole run after the start-up, pauses excluded
    RateWindow w = rate_between(r.at_startup, end_);
    w.wall_s = std::max(0.0, w.wall_s - gui_loop_->paused_s());
    say(fmt::format(
        "voxelastic-probe: {:.2f} s wall; start-up {:.2f} s (loading the scene {:.2f} s, then open to the "
        "first physics step {:.2f} s); after it {:.3f} s simulated in {:.3f} s wall ({:.2f}x real time{}); "
        "physics {} steps ({:.0f} steps/s after the start-up, {})",
        scene_.load_s + wall_s, scene_.load_s + r.startup_s, scene_.load_s, r.startup_s, w.sim_s, w.wall_s, w.factor(),
        r.lag_drops.load() == 0 ? ""
        : local_                ? ", the tissue could not keep real time"
                                : ", could not keep real time",
        steps, w.steps_per_s(), dt));
    // the solver factored beside the session while the tissue rested (--background-factor)
    const std::int64_t ready_us = r.solver_ready_us.load();
    const double waited_s = 1e-6 * double(r.factor_wait_us.load());
    if (ready_us >= 0)
      say(
          fmt::format("solver: factored in the background while the tissue rested, ready {:.2f} s after the open "
                      "({:.2f} s with the loading); steps waited {:.2f} s for it{}",
                      1e-6 * double(ready_us), scene_.load_s + 1e-6 * double(ready_us), waited_s,
                      waited_s > 0 ? " (a tool reached the tissue before it was ready)" : ""));
    else if (r.solver_pending.load())
      say(r.quit_while_waiting.load()
              ? "solver: still being factored in the background at the end (a tool had reached the tissue: the "
                "physics waited for it until the quit)"
              : "solver: still being factored in the background at the end (the tissue rested all the run)");
  }
  if (shared_->share_cores)
    say(fmt::format(
        "physics threads: {}, the cores shared: {} of {} steps on one thread (ahead of real time "
        "without the others, or as fast: {} of {} trials kept), {} changes (--no-share-cores: every step on all {})",
        shared_->physics_threads, r.steps_on_one.load(), steps, r.thread_trials_kept.load(), r.thread_trials.load(),
        r.thread_changes.load(), shared_->physics_threads));
  else
    say(fmt::format("physics threads: {}{}", shared_->physics_threads,
                    shared_->physics_threads > 1 ? ", every step on all of them (--no-share-cores)" : ""));
  if (r.started.load(std::memory_order_acquire)) {
    // the physics thread's wall time after the start-up, pauses included, and where it went
    const double after_s = rate_between(r.at_startup, end_).wall_s;
    const auto s_of = [](const std::atomic<std::int64_t>& us) { return 1e-6 * double(us.load()); };
    const double in_steps = s_of(r.in_steps_us), in_local = s_of(r.in_local_models_us),
                 in_snapshots = s_of(r.in_snapshots_us), in_outputs = s_of(r.in_outputs_us);
    const std::int64_t after_steps = std::max<std::int64_t>(0, steps - r.at_startup.steps);
    const std::int64_t updates = r.updates.load();
    say(fmt::format(
        "physics thread after the start-up ({:.2f} s): in the steps {:.2f} s ({:.1f} ms per step){}, "
        "last good states {:.2f} s, outputs to the other threads {:.2f} s, the rest {:.2f} s (waiting for "
        "real time, pauses)",
        after_s, in_steps, after_steps > 0 ? 1e3 * in_steps / double(after_steps) : 0.0,
        local_ ? fmt::format(", local contact models {:.2f} s ({:.1f} ms each)", in_local,
                             updates > 0 ? 1e3 * in_local / double(updates) : 0.0)
               : std::string(),
        in_snapshots, in_outputs, std::max(0.0, after_s - in_steps - in_local - in_snapshots - in_outputs)));
  }
  if (local_)
    say(fmt::format("local force shaping: {} physics updates ({:.1f} per second), device clock {:.2f} s",
                    r.updates.load(), wall_s > 0 ? double(r.updates.load()) / wall_s : 0.0, device_loop_->clock_s()));
  say(fmt::format(
      "faults: {} physics fault(s) recovered from{}; the last good state kept {} times (at least "
      "{:g} s and {:g} copies' time apart, a copy took {:.1f} ms at most)",
      r.faults.load(), r.faults.load() > 0 ? " (" + r.last_fault() + ")" : std::string(), r.snapshots.load(),
      PhysicsLoop::kSnapshotEvery_s, PhysicsLoop::kSnapshotCostShare, 1e-3 * double(r.snapshot_max_us.load())));
  for (int p = 0; p < std::min(probes_, 2); ++p) {
    const DeviceForceGuard& g = device_loop_->guard(p);
    say(
        fmt::format("probe {} force guard: max {:g} N (--max-force), {} ticks clamped, {} fades (faults and resets), "
                    "{} non-finite forces refused",
                    p, g.settings().max_force_N, g.clamped_ticks(), g.interrupts(), g.non_finite()));
  }
  if (options_.soak_s > 0) soak_summary();
  std::lock_guard lock(shared_->device.mutex);
  for (int p = 0; p < std::min(probes_, 2); ++p) {
    const ForceStats& s = shared_->device.stats[std::size_t(p)];
    say(
        fmt::format("probe {}: device force max {:.3f} N, mean {:.3f} N, largest tick-to-tick change {:.4f} N; raw "
                    "reaction max {:.3f} N{}",
                    p, s.max_device_N, s.samples ? s.sum_device_N / double(s.samples) : 0.0, s.max_step_N, s.max_raw_N,
                    local_ && std::size_t(p) < device_loop_->local_probes()
                        ? fmt::format("; energy guard {} ticks", device_loop_->renderer(p).guard_ticks())
                        : std::string()));
  }
}

void App::soak_summary() {
  const PhysicsReport& r = shared_->physics;
  const SoakMonitor& m = gui_loop_->soak();
  std::int64_t non_finite = 0, guard_ticks = 0;
  for (int p = 0; p < std::min(probes_, kMaxSticks); ++p) {
    non_finite += device_loop_->guard(p).non_finite();
    if (local_ && std::size_t(p) < device_loop_->local_probes()) guard_ticks += device_loop_->renderer(p).guard_ticks();
  }
  const double growth =
      m.warm_bytes() > 0 ? 100.0 * double(m.end_bytes() - m.warm_bytes()) / double(m.warm_bytes()) : 0;
  // the same without the contact solve's cache: what the cache's growth is, beside the whole
  const double warm_rest = double(m.warm_bytes() - m.warm_cache_bytes()),
               end_rest = double(m.end_bytes() - m.end_cache_bytes());
  const double rest_growth = warm_rest > 0 ? 100.0 * (end_rest - warm_rest) / warm_rest : 0;
  say(fmt::format(
      "soak: {:.0f} s, seed {}: non-finite {} (physics faults {}, device forces refused {}); resident "
      "memory {:.1f} MB after the warm-up (at {:.1f} s), {:.1f} MB at the end ({:+.2f} %; the contact solve's "
      "bounded cache {:.1f} -> {:.1f} MB, {}, the rest {:+.2f} %); device forces per "
      "second at least {:.0f} over {} one-second windows (the hypervisor's steal: {:.0f} ms of CPU in that second, at "
      "most {:.0f} ms in one; short beyond the ticks the steal can take: at most {:.0f} forces in a second); "
      "tissue at the end {:.4f} mm from its rest ({}), {:.2f} % "
      "of its largest displacement {:.3f} mm; energy guard {} ticks",
      options_.soak_s, options_.soak_seed, r.faults.load() + non_finite, r.faults.load(), non_finite,
      1e-6 * double(m.warm_bytes()), m.warm_at_s(), 1e-6 * double(m.end_bytes()), growth,
      1e-6 * double(m.warm_cache_bytes()), 1e-6 * double(m.end_cache_bytes()),
      options_.lazy_contact_cache ? "filled as the tools went" : "reserved at the start", rest_growth,
      m.min_forces_per_s(), m.windows(), 1e3 * m.steal_in_worst_window_s(), 1e3 * m.max_window_steal_s(),
      m.max_unexplained_shortfall_per_s(), r.soak_final_mm,
      r.soak_ref_is_shape ? std::string("the model's shape: no gravity")
                          : fmt::format("its state at t = {:.2f} s, sagged under gravity", r.soak_ref_s),
      r.soak_peak_mm > 0 ? 100.0 * r.soak_final_mm / r.soak_peak_mm : 0.0, r.soak_peak_mm,
      local_ ? std::to_string(guard_ticks) : std::string("(paper shaping: none)")));
  // whether the tissue slept at the end, and from how far (docs/model.md 7, "A tissue at rest sleeps")
  const SimulationCounters& c = r.soak_counters;
  if (c.sleeps == 0)
    say(fmt::format("soak: the tissue never fell asleep (simulated {:.2f} s)", r.soak_end_s));
  else
    say(
        fmt::format("soak: the tissue fell asleep {} times, the last at t = {:.2f} s ({:.2f} s before the end at "
                    "{:.2f} s), {:.2f} s after a tool let go of it ({:.4f} mm from its rest shape then), {}; {} steps "
                    "at rest",
                    c.sleeps, c.last_sleep_s, r.soak_end_s - c.last_sleep_s, r.soak_end_s, c.last_sleep_since_release_s,
                    c.last_release_offset_mm,
                    c.last_sleep_offset_mm < 0 ? std::string("its rest shape not known (gravity): slow enough")
                    : c.last_sleep_cause == SleepCause::slow
                        ? fmt::format("{:.4f} mm from its rest shape and left there (slow)", c.last_sleep_offset_mm)
                        : fmt::format("{:.4f} mm from its rest shape and put there ({})", c.last_sleep_offset_mm,
                                      to_string(c.last_sleep_cause)),
                    c.steps_at_rest));
}

int App::finish(ProbeView* view, std::string error) {
  const double wall_s = seconds(SteadyClock::now() - shared_->start);
  try {
    outputs_.stop();
  } catch (const std::exception& e) {
    if (error.empty()) error = e.what();
  }
  if (view && !gui_loop_->window_closed() && error.empty() && !options_.screenshot.empty()) {
    try {
      view->save_screenshot(options_.screenshot);
      say("screenshot: " + options_.screenshot.string());
    } catch (const std::exception& e) {
      error = e.what();
    }
  }
  if (const std::string why = shared_->controls.quit_reason(); !why.empty()) say("stopped: " + why);
  summary(wall_s);
  if (view)
    // over the run since the open, as the device's line; the HUD's rate (its last half second) apart
    say(fmt::format(
        "display: {} frames in {:.1f} s since the open ({:.1f} frames/s; {:.1f} frames/s over its last "
        "half second; the first on screen {:.2f} s after the open) ({})",
        view->frames(), wall_s, wall_s > 0 ? double(view->frames()) / wall_s : 0.0, view->frames_per_s(),
        gui_loop_->first_frame_s(),
        (gui_nice_ ? fmt::format("nice {}, below the physics", kGuiNice) : std::string("default priority")) +
            (view->software_gl() ? fmt::format("; software OpenGL on {} thread(s): LP_NUM_THREADS", render_threads_)
                                 : std::string()) +
            (!gui_loop_->opened_with_preview() ? std::string()
             : gui_loop_->surface_replaced_s() >= 0
                 ? fmt::format("; the preview replaced by the decimated surface {:.1f} s after the open",
                               gui_loop_->surface_replaced_s())
                 : std::string("; the surface still the preview at the end (its decimation stopped)")) +
            (gui_loop_->display_turns() > 0
                 ? fmt::format("; {} behind real time, in the display's turn: {:.2f} s, {} physics steps on one thread",
                               gui_loop_->display_turns(), gui_loop_->display_turns_s(),
                               shared_->physics.steps_in_display_turns.load())
                 : std::string())));
  const DeviceLoop& d = *device_loop_;
  say(fmt::format(
      "device: {} ticks ({:.0f} updates/s, {} late ticks skipped; a tick takes {:.0f} us on average, {:.0f} "
      "us at most; {})",
      d.ticks(), wall_s > 0 ? double(d.ticks()) / wall_s : 0.0, device_missed_, 1e6 * d.mean_tick_cost_s(),
      1e6 * d.max_tick_cost_s(), d.priority()));
  for (const auto& o : outputs_.all()) say(fmt::format("  {}: {} device commands", o->describe(), o->device_updates()));
  if (!options_.force_log.empty() && error.empty()) say("force log: " + options_.force_log.string());
  if (!error.empty()) {
    fmt::print(stderr, "voxelastic-probe: error: {}\n", error);
    return kExitError;
  }
  if (shared_->physics.failed.load()) {
    fmt::print(stderr, "voxelastic-probe: error: {}\n", shared_->physics.failure);
    return kExitError;
  }
  return 0;
}

int App::run() {
  start_simulation();
  open_input();
  open_outputs();
  make_device_loop();
  const IoLines lines = describe_io();
  // the start view: stick axes follow the camera
  shared_->set_basis(start_view_basis(scene_.world_up));
  std::string error = run_loops(lines);
  return finish(view_.get(), std::move(error));
}

/// The end of a session that leaves a solver building (App::leave_running): a build that stops
/// within a moment (it was between stages) ends as any thread; one still in METIS or the numeric
/// factorisation, which cannot be cut short and take seconds on an organ, is not waited for.
/// The factor cache is closed first (a factor it is writing is finished, none is begun), then
/// the process ends with `code`.
int end_left_running(LeftRunning left, int code, bool quiet) {
  if (!left.solver.valid()) return code;
  const auto say = [&](const std::string& line) {
    if (!quiet) fmt::print("{}\n", line);
  };
  if (left.solver.wait_for(std::chrono::milliseconds(250)) == std::future_status::ready) {
    try {
      (void)left.solver.get();
      say("solver: its build in the background ended with the session (not used)");
    } catch (const Cancelled& e) {
      say(fmt::format("solver: the quit stopped its build in the background: {} (nothing of it kept)", e.what()));
    } catch (const std::exception& e) {
      say(fmt::format("solver: its build in the background failed at the end: {}", e.what()));
    }
    return code;
  }
  if (left.factor_cache) left.factor_cache->close();
  say(fmt::format(
      "solver: left unfinished at the quit, {:.1f} s into its build, in a stage that cannot be cut short (the "
      "assembly, METIS's order or CHOLMOD's factorisation); nothing of it is kept: the next start of this organ "
      "factors again",
      left.solver_age_s));
  std::fflush(stdout);
  std::fflush(stderr);
  std::_Exit(code);
}

}  // namespace

int run_probe_app(const AppOptions& options) {
  // the checks that need no loading come first
  if (options.headless && options.duration_s <= 0 && !options.exit_after_script && options.soak_s <= 0)
    throw Error("--headless needs a stop condition: --duration SECONDS or --exit-after-script");
  if (options.exit_after_script && options.joystick_script.empty() && options.soak_s <= 0)
    throw Error("--exit-after-script needs --virtual-joystick SCRIPT");
  if (!options.screenshot.empty() && options.headless) throw Error("--screenshot needs a window (not --headless)");
  if (!options.headless) {
    if (const std::string why = display_problem(); !why.empty()) {
      fmt::print(stderr, "voxelastic-probe: {}\n  (or run without a window: --headless --duration SECONDS)\n", why);
      return kExitNoDisplay;
    }
  }
  if (!options.joystick_script.empty()) (void)JoystickScript::load(options.joystick_script);  // fail early
  if (!options.quiet) fmt::print("voxelastic-probe: loading {} ...\n", options.input.string());
  DefaultSceneOptions scene_options = options.scene;
  scene_options.surface_method = options.surface_method;
  // the second start of the same organ loads its calibration (io/calibration_cache.h, beside the factors)
  scene_options.calibration_cache = make_calibration_cache(options.factor_cache);
  // and its region check's estimate (io/region_check_cache.h)
  scene_options.region_check_cache = make_region_check_cache(options.factor_cache);
  // ... and its decimated display surface (io/surface_cache.h); headless: no surface at all
  scene_options.surface_cache = make_surface_cache(options.factor_cache);
  scene_options.display = !options.headless;
  const auto load_start = SteadyClock::now();
  ProbeScene scene = load_probe_scene(options.input, scene_options);
  scene.load_s = seconds(SteadyClock::now() - load_start);
  if (!options.quiet)
    for (const auto& n : scene.notes) fmt::print("{}\n", n);
  int code = 0;
  LeftRunning left;
  {
    App app(options, std::move(scene));
    code = app.run();
    left = app.leave_running();
  }  // (the threads, the window, the device and the caches' writes ended here)
  return end_left_running(std::move(left), code, options.quiet);
}

}  // namespace vx::probe
