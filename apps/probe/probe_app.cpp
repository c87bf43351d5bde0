#include "probe_app.h"

#include <fmt/core.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "base/error.h"
#include "display.h"
#include "force_output.h"
#include "joystick_script.h"
#include "probe_view.h"
#include "rate_thread.h"
#include "sdl_input.h"
#include "sim/local_contact.h"
#include "sim/simulation.h"

namespace vx::probe {

DeviceChoice parse_device_choice(const std::string& s) {
  if (s == "auto") return DeviceChoice::automatic;
  if (s == "haptic") return DeviceChoice::haptic;
  if (s == "rumble") return DeviceChoice::rumble;
  if (s == "none") return DeviceChoice::none;
  throw Error("unknown force output '" + s + "': use auto, haptic, rumble or none");
}

namespace {

std::atomic<bool> g_interrupted{false};
extern "C" void on_interrupt(int) { g_interrupted.store(true); }

double seconds(SteadyClock::duration d) { return std::chrono::duration<double>(d).count(); }

/// Where the physics is: simulated time at a wall instant.
struct SimClock {
  double sim_s{0.0};
  SteadyClock::time_point wall{};
  bool paused{false};
};

/// The forces the HUD shows.
struct HudForces {
  std::array<double, 2> force_N{};
  std::array<int, 2> contacts{};
  std::array<int, 2> model_nodes{};
};

/// Per probe: the largest forces seen, for the summary.
struct ForceStats {
  double max_device_N{0.0};
  double max_raw_N{0.0};
  double sum_device_N{0.0};
  double max_step_N{0.0};       ///< largest tick-to-tick change of the device force
  Eigen::Vector3d last_N{Eigen::Vector3d::Zero()};
  std::int64_t samples{0};
};

class App {
 public:
  App(const AppOptions& options, ProbeScene scene) : options_(options), scene_(std::move(scene)) {}
  int run();

 private:
  void say(const std::string& line) const {
    if (!options_.quiet) fmt::print("{}\n", line);
  }
  void open_input();
  void open_outputs();
  void physics_tick();
  /// local shaping: one physics update (the tool moved to the device's proxy over its steps,
  /// then a local contact model published); returns the steps taken. The update ends after
  /// about one physics period of wall time even when it has not taken all `steps` (a slow
  /// physics publishes at its rate and falls behind in simulated time, not in updates).
  int local_physics_update(int steps, SteadyClock::time_point start);
  void device_tick();
  /// local shaping: the device (hand) position from the stick, the force from the local
  /// contact model, the proxy to the physics; fills `f`.
  void local_device_probe(int p, const Eigen::Vector3d& cmd, const Eigen::Vector3d& drag, const Eigen::Matrix3d& basis,
                          double dt, bool paused, double now_s, SteadyClock::time_point wall, ProbeForce& f);
  [[nodiscard]] SimClock clock() const {
    std::lock_guard lock(clock_mutex_);
    return clock_;
  }
  void set_clock(const SimClock& c) {
    std::lock_guard lock(clock_mutex_);
    clock_ = c;
  }
  [[nodiscard]] Eigen::Matrix3d basis() const {
    std::lock_guard lock(basis_mutex_);
    return basis_;
  }
  void request_quit(const std::string& why) {
    std::lock_guard lock(quit_mutex_);
    if (!quit_.exchange(true)) quit_reason_ = why;
  }
  void on_action(ViewAction a);
  [[nodiscard]] HudInfo hud(double physics_rate, double rtf, double device_rate, double updates_rate);
  void summary(double wall_s);

  // the stages of run()
  /// The HUD's input and force-output lines.
  struct IoLines {
    std::string input, output;
  };
  /// The simulation, the stick mapping (command line over scene over defaults), the commanders.
  void start_simulation();
  /// Prints what drives the probes and where the force goes; returns the HUD's lines.
  [[nodiscard]] IoLines describe_io();
  /// The window (null when headless).
  [[nodiscard]] std::unique_ptr<ProbeView> open_view(const IoLines& lines);
  /// What the GUI loop keeps from one pass to the next.
  struct GuiLoop {
    GuiLoop(int probes, double fps)
        : probe_pos(std::size_t(probes), Eigen::Vector3d::Zero()),
          probe_contacts(std::size_t(probes), 0),
          frame_period(std::chrono::duration_cast<SteadyClock::duration>(
              std::chrono::duration<double>(1.0 / std::max(1.0, fps)))) {}
    RateMeter physics_rate{0.5}, device_rate{0.5}, update_rate{0.5};
    /// real-time factor: simulated over running wall time, per half second (pauses, resets excluded)
    double rtf{1.0};
    bool rtf_valid{false};
    std::int64_t rtf_sim0{0}, rtf_wall0{0};
    SimulationFrame frame;
    std::vector<Eigen::Vector3d> probe_pos;
    std::vector<int> probe_contacts;
    bool window_closed{false};
    bool warned_behind{false};
    SteadyClock::duration frame_period;
    SteadyClock::time_point next_frame{SteadyClock::now()};
    SteadyClock::time_point next_report{SteadyClock::now() + std::chrono::seconds(2)};
  };
  /// The GUI thread until a quit: rates, then a frame (or a console line when headless).
  /// Returns the error that ended it ("" for none).
  [[nodiscard]] std::string run_gui_loop(ProbeView* view, GuiLoop& loop, const FixedRateThread& physics,
                                         const FixedRateThread& device);
  /// Physics and device rates, the real-time factor, input messages, the slow-motion warning;
  /// returns the time they were measured at.
  SteadyClock::time_point measure_rates(GuiLoop& loop, const FixedRateThread& device);
  /// One frame of the window; false once the window closed.
  bool show_frame(ProbeView& view, GuiLoop& loop);
  /// Headless: a progress line every 2 s (`now`: this pass's time).
  void report_headless(GuiLoop& loop, SteadyClock::time_point now);
  /// After the threads stopped: the force outputs closed, the screenshot, the summary; returns
  /// the exit code.
  [[nodiscard]] int finish(ProbeView* view, const GuiLoop& loop, FixedRateThread& physics, FixedRateThread& device,
                           std::string error);

  const AppOptions& options_;
  ProbeScene scene_;
  std::unique_ptr<Simulation> sim_;
  std::shared_ptr<const JoystickScript> script_;
  std::unique_ptr<SdlInput> input_;
  ForceOutputs outputs_;
  std::vector<std::string> output_notes_;
  KeyboardStick keyboard_;
  ControlSettings control_;
  ControlSettings keyboard_control_;
  std::vector<ProbeCommander> commanders_;
  int probes_{0};

  SteadyClock::time_point start_{};
  double physics_period_s_{0.001};
  double device_period_s_{0.001};
  bool local_{false};  ///< local shaping (else the paper's half sines)

  // physics thread
  SteadyClock::time_point physics_last_{};
  bool physics_started_{false};
  double sim_target_s_{0.0};
  std::atomic<std::int64_t> steps_total_{0};
  std::atomic<std::int64_t> sim_time_us_{0};
  std::atomic<std::int64_t> sim_advanced_us_{0};  // simulated time advanced (resets and pauses excluded)
  std::atomic<std::int64_t> active_wall_us_{0};   // wall time while running (not paused, not failed)
  double lag_dropped_s_{0.0};                     // physics thread only
  std::atomic<std::int64_t> lag_drops_{0};
  std::atomic<bool> physics_failed_{false};
  std::string physics_failure_;                   // written once before physics_failed_ is set
  std::atomic<std::int64_t> physics_updates_{0};  // local: local contact models published
  std::atomic<std::int64_t> device_time_us_{0};   // local: the device's clock
  // local shaping: the tool positions (proxies) the device thread hands to the physics
  TripleBuffer<std::array<Eigen::Vector3d, kMaxSticks>> tool_targets_;
  bool have_targets_{false};                      // physics thread
  double step_cost_s_{0.0};                       // physics thread: wall time of one step (mean)

  // shared
  mutable std::mutex clock_mutex_;
  SimClock clock_;
  mutable std::mutex basis_mutex_;
  Eigen::Matrix3d basis_{Eigen::Matrix3d::Identity()};
  std::atomic<bool> paused_{false};
  std::atomic<bool> reset_requested_{false};
  std::atomic<int> reset_generation_{0};
  std::atomic<bool> screenshot_requested_{false};
  std::atomic<bool> quit_{false};
  std::mutex quit_mutex_;
  std::string quit_reason_;

  // device thread -> GUI
  std::mutex device_mutex_;
  HudForces hud_forces_;
  std::vector<PlotSample> plot_pending_;
  std::vector<std::string> messages_;
  std::array<ForceStats, 2> stats_{};
  int device_reset_seen_{0};
  std::int64_t device_ticks_{0};

  // device thread, local shaping
  double device_clock_s_{0.0};                    ///< wall time while running (pauses excluded), s
  SteadyClock::time_point device_last_{};
  bool device_started_{false};
  std::vector<ProbeDriver> hands_;                ///< the device (hand) position of each probe
  std::vector<LocalForceRenderer> renderers_;
  struct ModelArrival {
    SteadyClock::time_point wall{};
    double period_s{0.0};                         ///< between the last two models (mean), s
    bool seen{false};
    int nodes{0};
    Eigen::Vector3d anchor_N{Eigen::Vector3d::Zero()};
  };
  std::vector<ModelArrival> arrivals_;
  std::string device_priority_{"default priority"};  ///< what the device thread got (written by it at its first tick)
  // the device tick's own cost (its CPU time, not the wait)
  double tick_cost_sum_s_{0.0};
  double tick_cost_max_s_{0.0};
};

// ---------------------------------------------------------------- set-up

void App::open_input() {
  InputSettings in;
  in.max_sticks = std::min(kMaxSticks, std::max(1, probes_));
  in.joysticks = options_.use_joysticks;
  if (!options_.joystick_script.empty()) {
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

/// The calling thread at SCHED_FIFO 1, else nice -10; says which (or that neither was permitted).
static std::string raise_device_thread_priority() {
  sched_param sp{};
  sp.sched_priority = 1;
  if (pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0) return "real-time priority (SCHED_FIFO 1)";
  if (setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), -10) == 0) return "priority nice -10";
  return "default priority (raising it was not permitted)";
}

// ---------------------------------------------------------------- physics thread

void App::physics_tick() {
  const auto now = SteadyClock::now();
  // local shaping: the device thread is the one with a deadline; the physics' updates yield to
  // it when the CPU is short (Linux: per thread; the display yields more)
  if (local_ && !physics_started_) (void)setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 2);
  const double elapsed = physics_started_ ? seconds(now - physics_last_) : 0.0;
  physics_started_ = true;
  physics_last_ = now;
  const double dt_wall = std::min(elapsed, 0.1);  // a long stall is not replayed
  if (reset_requested_.exchange(false)) {
    sim_->reset();
    sim_target_s_ = 0.0;
    reset_generation_.fetch_add(1);
  }
  const bool paused = paused_.load();
  if (!paused && !sim_->failed()) {
    const double t0 = sim_->time_s();
    sim_target_s_ += dt_wall;
    // at most twice real time per tick: catch up a little, never burst
    const int budget = std::max(1, int(std::ceil(2.0 * physics_period_s_ / sim_->dt_s())));
    if (local_) {
      // the steps the wall clock asks for, as many as fit in one physics period (a slow physics
      // publishes at its rate and falls behind in simulated time)
      int want = std::clamp(int(std::floor((sim_target_s_ - t0) / sim_->dt_s() + 0.5)), 0, budget);
      if (step_cost_s_ > 0)
        want = std::min(want, std::max(1, int(0.9 * physics_period_s_ / step_cost_s_)));
      steps_total_.fetch_add(local_physics_update(want, now), std::memory_order_relaxed);
    } else {
      steps_total_.fetch_add(sim_->advance_to(sim_target_s_, budget), std::memory_order_relaxed);
    }
    const double lag = sim_target_s_ - sim_->time_s();
    if (lag > std::max(0.05, 3.0 * physics_period_s_)) {
      // cannot keep real time: drop the lag and go on in slow motion
      lag_dropped_s_ += lag;
      lag_drops_.fetch_add(1);
      sim_target_s_ = sim_->time_s();
    }
    // the real-time factor counts all the wall time that passed (a tick that stepped for a
    // second counts a second, not the 0.1 s the target advanced by): the HUD tells the truth
    active_wall_us_.fetch_add(std::llround(elapsed * 1e6), std::memory_order_relaxed);
    sim_advanced_us_.fetch_add(std::llround((sim_->time_s() - t0) * 1e6), std::memory_order_relaxed);
    if (sim_->failed() && !physics_failed_.load()) {
      physics_failure_ = fmt::format("physics stopped at t = {:.3f} s: {} ({}); press r to reset", sim_->time_s(),
                                     to_string(sim_->state().status), sim_->state().message);
      physics_failed_.store(true);
    }
  }
  sim_time_us_.store(std::int64_t(std::llround(sim_->time_s() * 1e6)), std::memory_order_relaxed);
  set_clock(SimClock{sim_->time_s(), now, paused || sim_->failed()});
}

int App::local_physics_update(int steps, SteadyClock::time_point start) {
  if (steps <= 0) return 0;
  // the tool from where the physics has it to where the device last put it, over the update
  if (tool_targets_.fetch()) have_targets_ = true;
  const std::array<Eigen::Vector3d, kMaxSticks>& to = tool_targets_.read_buffer();
  const int np = std::min(probes_, kMaxSticks);
  std::array<Eigen::Vector3d, kMaxSticks> from{};
  for (int p = 0; p < np; ++p) from[std::size_t(p)] = sim_->probe(p).pose.position_mm;
  int done = 0;
  const auto deadline = start + std::chrono::duration_cast<SteadyClock::duration>(
                                    std::chrono::duration<double>(0.9 * physics_period_s_));
  for (int k = 1; k <= steps && !sim_->failed() && !quit_.load(std::memory_order_relaxed); ++k) {
    if (have_targets_)
      for (int p = 0; p < np; ++p)
        sim_->set_live(p, {LiveCommand::Kind::position,
                           from[std::size_t(p)] + (to[std::size_t(p)] - from[std::size_t(p)]) * (double(k) / steps)});
    sim_->step();
    ++done;
    // out of time (the steps took longer than they used to): the tool goes on from where it is
    // at the next update
    if (k < steps && SteadyClock::now() >= deadline) break;
  }
  if (done > 0) {
    const double per_step = seconds(SteadyClock::now() - start) / done;
    step_cost_s_ = step_cost_s_ > 0 ? 0.7 * step_cost_s_ + 0.3 * per_step : per_step;
  }
  if (!sim_->failed()) {
    sim_->publish_local_contact();
    physics_updates_.fetch_add(1, std::memory_order_relaxed);
  }
  return done;
}

// ---------------------------------------------------------------- device thread

void App::local_device_probe(int p, const Eigen::Vector3d& cmd, const Eigen::Vector3d& drag, const Eigen::Matrix3d& b,
                             double dt, bool paused, double now_s, SteadyClock::time_point wall, ProbeForce& f) {
  const auto i = std::size_t(p);
  ProbeDriver& hand = hands_[i];
  // the hand: the stick moves the device position in wall time (the probe's speed limit)
  if (!paused && dt > 0) {
    hand.set_live(commanders_[i].update(cmd, drag, b, hand.state().position_mm, dt));
    hand.advance(now_s, dt);
  }
  const Eigen::Vector3d x = hand.state().position_mm;
  LocalForceRenderer& r = renderers_[i];
  ModelArrival& a = arrivals_[i];
  if (const LocalContactModel* m = sim_->take_local_contact(p)) {
    if (a.seen) {
      const double gap = seconds(wall - a.wall);
      a.period_s = a.period_s > 0 ? 0.8 * a.period_s + 0.2 * gap : gap;
    }
    a.wall = wall;
    a.seen = true;
    a.nodes = m->size();
    a.anchor_N = m->valid ? m->anchor_force_n : Eigen::Vector3d::Zero();
    r.update_model(*m, now_s, a.period_s);
  }
  const LocalForceRenderer::Output& o = r.tick(x, now_s);
  tool_targets_.write_buffer()[i] = o.proxy_mm;
  if (!paused) {
    f.device_N = o.force_n;
    f.model_N = o.contact_n;
    f.guard_N = o.guard_n.norm();
  }
  f.tip_mm = o.proxy_mm;
  f.hand_mm = x;
  f.anchor_N = a.anchor_N;
  f.update_age_ms = a.seen ? 1e3 * seconds(wall - a.wall) : 0.0;
  f.stiffness_N_mm = 0.0;
  if (o.stiffness_n_mm.norm() > 0) {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(o.stiffness_n_mm, Eigen::EigenvaluesOnly);
    f.stiffness_N_mm = es.eigenvalues().maxCoeff();
  }
}

void App::device_tick() {
  const auto now = SteadyClock::now();
  const SimClock c = clock();
  const double dt_dev = device_started_ ? std::min(seconds(now - device_last_), 0.05) : 0.0;  // a stall is not replayed
  device_last_ = now;
  device_started_ = true;
  const int gen = reset_generation_.load();
  if (gen != device_reset_seen_) {
    device_reset_seen_ = gen;
    for (auto& pc : commanders_) pc.reset();
    if (local_) {
      for (auto& h : hands_) h.reset();
      for (auto& r : renderers_) r.reset();
      for (auto& a : arrivals_) a = ModelArrival{};
      device_clock_s_ = 0.0;
    }
  }
  // paper: the simulated time now, from the physics' last report; never ahead of the physics by
  // more than one of its ticks (the half-sine pulse is evaluated within the step being computed).
  // local: the device's own clock, wall time while running: the tool never goes in slow motion
  if (local_ && !c.paused) device_clock_s_ += dt_dev;
  double sim_now = local_ ? device_clock_s_
                          : c.sim_s + (c.paused ? 0.0 : std::min(seconds(now - c.wall), physics_period_s_));
  if (local_) device_time_us_.store(std::llround(device_clock_s_ * 1e6), std::memory_order_relaxed);
  // sticks: the script runs at the device's clock (paper: simulated time, so slow motion keeps
  // the palpation the same)
  input_->play_script(sim_now);
  input_->poll();
  std::vector<std::string> msgs = input_->take_messages();

  const Eigen::Matrix3d b = basis();
  const bool paused = paused_.load();
  DeviceTick tick;
  tick.wall_s = seconds(now - start_);
  tick.sim_s = sim_now;
  tick.local = local_;
  tick.probes = std::min(probes_, kMaxSticks);
  std::array<double, kMaxSticks> plot_mean{};
  const int active = keyboard_.active_probe();
  std::array<double, kMaxSticks> update_mean{};
  for (int p = 0; p < tick.probes; ++p) {
    const ProbeOutput snap = sim_->probe_snapshot(p);
    // the stick of this probe plus, for the active probe, the keyboard and mouse
    Eigen::Vector3d cmd = Eigen::Vector3d::Zero();
    if (p < input_->count()) cmd = stick_command(input_->state(p), control_);
    Eigen::Vector3d drag = Eigen::Vector3d::Zero();
    if (p == active) {
      cmd = (cmd + stick_command(keyboard_.state(), keyboard_control_)).cwiseMax(-1.0).cwiseMin(1.0);
      drag = keyboard_.take_drag();
    }
    ProbeForce& f = tick.probe[std::size_t(p)];
    f.physics_s = snap.time_s;
    f.contacts = snap.contacts;
    if (local_) {
      // the local contact model at this tick, for the device's position now
      local_device_probe(p, cmd, drag, b, dt_dev, paused || c.paused, sim_now, now, f);
      if (!paused && !c.paused) f.raw_N = snap.raw_force_n;
      update_mean[std::size_t(p)] = f.device_N.norm();
      plot_mean[std::size_t(p)] = f.anchor_N.norm();
    } else {
      if (!paused)
        sim_->set_live(p, commanders_[std::size_t(p)].update(cmd, drag, b, snap.pose.position_mm, device_period_s_));
      // the device force: the paper's half sine, at the device's own clock
      if (!paused && !c.paused) {
        f.device_N = sim_->has_device() ? snap.pulse.at(std::max(sim_now, snap.time_s)) : snap.raw_force_n;
        f.raw_N = snap.raw_force_n;
        update_mean[std::size_t(p)] = sim_->has_device() ? snap.pulse.mean_n.norm() : snap.raw_force_n.norm();
      }
      plot_mean[std::size_t(p)] = update_mean[std::size_t(p)];
      f.tip_mm = snap.pose.position_mm;
      f.hand_mm = snap.pose.position_mm;
      f.anchor_N = sim_->has_device() ? snap.pulse.mean_n : snap.raw_force_n;
      f.update_age_ms = sim_->has_device() ? 1e3 * std::max(0.0, sim_now - snap.pulse.start_s) : 0.0;
    }
    f.stick_N = b.transpose() * f.device_N;
  }
  if (local_) tool_targets_.publish();
  outputs_.write(tick);
  ++device_ticks_;

  // what the GUI shows: forces now, a plot point every 4 ms of simulated time
  std::lock_guard lock(device_mutex_);
  for (int p = 0; p < tick.probes; ++p) {
    const ProbeForce& f = tick.probe[std::size_t(p)];
    // the HUD shows the force of the current device update (the half sine's mean), which
    // reads steadily; the played half sine itself passes through zero 50 times a second
    hud_forces_.force_N[std::size_t(p)] = update_mean[std::size_t(p)];
    hud_forces_.contacts[std::size_t(p)] = f.contacts;
    if (local_) hud_forces_.model_nodes[std::size_t(p)] = arrivals_[std::size_t(p)].nodes;
    ForceStats& s = stats_[std::size_t(p)];
    s.max_device_N = std::max(s.max_device_N, f.device_N.norm());
    s.max_raw_N = std::max(s.max_raw_N, f.raw_N.norm());
    s.sum_device_N += f.device_N.norm();
    if (s.samples > 0) s.max_step_N = std::max(s.max_step_N, (f.device_N - s.last_N).norm());
    s.last_N = f.device_N;
    ++s.samples;
  }
  if (plot_pending_.empty() || sim_now >= plot_pending_.back().t_s + 0.004 || sim_now < plot_pending_.back().t_s) {
    PlotSample ps;
    ps.t_s = sim_now;
    for (int p = 0; p < tick.probes; ++p) {
      ps.device_N[std::size_t(p)] = float(tick.probe[std::size_t(p)].device_N.norm());
      ps.mean_N[std::size_t(p)] = float(plot_mean[std::size_t(p)]);
      ps.raw_N[std::size_t(p)] = float(tick.probe[std::size_t(p)].raw_N.norm());
    }
    if (plot_pending_.size() > 20000) plot_pending_.clear();  // nobody is reading (headless)
    plot_pending_.push_back(ps);
  }
  for (auto& m : msgs) messages_.push_back(std::move(m));

  // stop conditions in simulated time
  if (options_.exit_after_script && script_ && sim_now > script_->duration_s() + 0.25)
    request_quit(fmt::format("the joystick script ended ({:.2f} s)", script_->duration_s()));
  if (options_.duration_s > 0 && sim_now >= options_.duration_s)
    request_quit(fmt::format("simulated {:.2f} s (--duration)", options_.duration_s));
}

// ---------------------------------------------------------------- GUI thread

void App::on_action(ViewAction a) {
  switch (a) {
    case ViewAction::quit: request_quit("quit key"); break;
    case ViewAction::pause: paused_.store(!paused_.load()); break;
    case ViewAction::reset_scene: reset_requested_.store(true); break;
    case ViewAction::screenshot: screenshot_requested_.store(true); break;
    case ViewAction::next_probe: keyboard_.set_active_probe((keyboard_.active_probe() + 1) % std::max(1, probes_)); break;
  }
}

HudInfo App::hud(double physics_rate, double rtf, double device_rate, double updates_rate) {
  HudInfo h;
  h.sim_s = double((local_ ? device_time_us_ : sim_time_us_).load()) * 1e-6;
  h.physics_steps_per_s = physics_rate;
  h.physics_updates_per_s = updates_rate;
  h.real_time_factor = rtf;
  h.paused = paused_.load();
  h.behind_real_time = !h.paused && !physics_failed_.load() && rtf < 0.95;
  h.device_hz = device_rate;
  h.device_target_hz = options_.device_hz;
  h.probes = std::min(probes_, 2);
  h.active_probe = keyboard_.active_probe();
  std::lock_guard lock(device_mutex_);
  h.force_N = hud_forces_.force_N;
  h.contacts = hud_forces_.contacts;
  h.model_nodes = hud_forces_.model_nodes;
  if (physics_failed_.load()) h.status = physics_failure_;
  return h;
}

void App::summary(double wall_s) {
  const double sim_s = double(sim_advanced_us_.load()) * 1e-6;
  const double active_s = double(active_wall_us_.load()) * 1e-6;
  const std::int64_t steps = steps_total_.load();
  say(fmt::format("voxelastic-probe: {:.2f} s wall, {:.2f} s simulated ({:.2f}x real time{}); physics {} steps "
                  "({:.0f} steps/s, dt {:.3g} ms)",
                  wall_s, sim_s, active_s > 0 ? sim_s / active_s : 0.0,
                  lag_drops_.load() > 0 ? (local_ ? ", the tissue could not keep real time" : ", could not keep real time")
                                        : "",
                  steps, active_s > 0 ? double(steps) / active_s : 0.0, 1e3 * sim_->dt_s()));
  if (local_)
    say(fmt::format("local force shaping: {} physics updates ({:.1f} per second), device clock {:.2f} s", physics_updates_.load(),
                    wall_s > 0 ? double(physics_updates_.load()) / wall_s : 0.0, device_clock_s_));
  std::lock_guard lock(device_mutex_);
  for (int p = 0; p < std::min(probes_, 2); ++p) {
    const ForceStats& s = stats_[std::size_t(p)];
    say(fmt::format("probe {}: device force max {:.3f} N, mean {:.3f} N, largest tick-to-tick change {:.4f} N; raw "
                    "reaction max {:.3f} N{}",
                    p, s.max_device_N, s.samples ? s.sum_device_N / double(s.samples) : 0.0, s.max_step_N, s.max_raw_N,
                    local_ && std::size_t(p) < renderers_.size()
                        ? fmt::format("; energy guard {} ticks", renderers_[std::size_t(p)].guard_ticks())
                        : std::string()));
  }
}

// ---------------------------------------------------------------- the run, stage by stage

void App::start_simulation() {
  // the simulation, with the options that override the scene
  scene_.simulation.integrator.threads = options_.threads;
  std::optional<DeviceForceSettings>& dev = scene_.simulation.device;
  local_ = options_.force_shaping.value_or(dev ? dev->shaping : ForceShaping::paper) == ForceShaping::local;
  if (local_ && !dev) dev = DeviceForceSettings{};
  if (dev) dev->shaping = local_ ? ForceShaping::local : ForceShaping::paper;
  if (local_) {
    LocalContactSettings lc;
    lc.update_period_s = 1.0 / options_.physics_hz;
    scene_.simulation.local_contact = lc;
  }
  sim_ = std::make_unique<Simulation>(scene_.physics, scene_.simulation);
  probes_ = sim_->num_probes();
  if (probes_ == 0) throw Error("the scene has no probe to palpate with");
  if (probes_ > kMaxSticks)
    say(fmt::format("note: the scene has {} probes; the app drives the first {}", probes_, kMaxSticks));
  // the stick mapping: the command line over the scene over the defaults
  control_ = options_.control;
  if (scene_.control_from_scene) {
    const JoystickMapping& scene_mapping = scene_.control.mapping;
    if (!options_.mode_set) control_.mapping.mode = scene_mapping.mode;
    if (!options_.speed_set) control_.mapping.max_speed_mm_s = scene_mapping.max_speed_mm_s;
    if (!options_.range_set) control_.mapping.range_mm = scene_mapping.range_mm;
    if (!options_.deadzone_set) control_.mapping.dead_zone = scene_mapping.dead_zone;
  }
  for (int p = 0; p < std::min(probes_, kMaxSticks); ++p) {
    const Box allowed = p < int(scene_.probe_allowed.size()) ? scene_.probe_allowed[std::size_t(p)] : Box{};
    commanders_.emplace_back(sim_->probe(p).pose.position_mm, allowed, control_);
  }
  keyboard_control_ = ControlSettings{};
  keyboard_control_.mapping = control_.mapping;
  keyboard_control_.mapping.dead_zone = 0.0;
  // local shaping: the device thread owns the tools' (hands') positions and the force rendering
  if (local_) {
    HapticCouplingSettings hs;
    hs.device_rate_hz = options_.device_hz;
    if (dev) hs.device_damping_n_s_mm = dev->device_damping_n_s_mm;
    if (const std::string bad = hs.validate(); !bad.empty()) throw Error("local force shaping: " + bad);
    std::array<Eigen::Vector3d, kMaxSticks> start{};
    for (int p = 0; p < std::min(probes_, kMaxSticks); ++p) {
      hands_.emplace_back(scene_.simulation.probes[std::size_t(p)]);
      renderers_.emplace_back();
      renderers_.back().init(hs);
      arrivals_.emplace_back();
      start[std::size_t(p)] = hands_.back().state().position_mm;
    }
    tool_targets_.fill(start);
    say(fmt::format("force: local contact model at every device tick ({:.0f}/s): virtual coupling {:.2f} N/mm (Colgate, "
                    "device damping {:.2g} N s/m), damping {:.1f} T K, energy guard; physics updates at up to {:.0f}/s",
                    options_.device_hz, renderers_.front().coupling_stiffness_n_mm(), 1e3 * hs.device_damping_n_s_mm,
                    hs.damping_margin, options_.physics_hz));
  }
}

App::IoLines App::describe_io() {
  const std::string control = control_.mapping.mode == JoystickMode::rate ? "rate control" : "position control";
  IoLines lines;
  if (script_)
    lines.input = fmt::format("{}: {} virtual joystick{} ({})", control, input_->count(), input_->count() > 1 ? "s" : "",
                              options_.joystick_script.filename().string());
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
  setup.levels = std::make_shared<const LevelCells>(make_level_cells(*scene_.model));
  for (int p = 0; p < probes_; ++p) {
    setup.probes.push_back(scene_.simulation.probes[std::size_t(p)].geometry);
    setup.probe_names.push_back(scene_.simulation.probes[std::size_t(p)].name);
    setup.probe_start_mm.push_back(sim_->probe(p).pose.position_mm);
  }
  setup.walls = scene_.simulation.workspace.enabled;
  setup.workspace = Box{scene_.simulation.workspace.min_mm, scene_.simulation.workspace.max_mm};
  setup.world_up = scene_.world_up;
  setup.flat = scene_.model->is_2d();
  if (setup.flat) setup.slice_normal = scene_.model->grid.direction.col(0).cross(scene_.model->grid.direction.col(1)).normalized();
  setup.width = options_.width;
  setup.height = options_.height;
  setup.input_line = lines.input;
  setup.output_line = lines.output;
  setup.local_shaping = local_;
  setup.physics_line = physics_configuration(scene_.simulation.integrator, *scene_.physics);
  auto view = std::make_unique<ProbeView>(setup, &keyboard_, [this](ViewAction a) { on_action(a); });
  if (options_.show_levels) view->toggle_levels();
  return view;
}

SteadyClock::time_point App::measure_rates(GuiLoop& loop, const FixedRateThread& device) {
  const auto now = SteadyClock::now();
  loop.physics_rate.sample(steps_total_.load(), now);
  loop.device_rate.sample(device.ticks(), now);
  loop.update_rate.sample(physics_updates_.load(), now);
  if (const std::int64_t w = active_wall_us_.load(), sm = sim_advanced_us_.load(); w - loop.rtf_wall0 >= 500000) {
    loop.rtf = double(sm - loop.rtf_sim0) / double(w - loop.rtf_wall0);
    loop.rtf_valid = true;
    loop.rtf_sim0 = sm;
    loop.rtf_wall0 = w;
  }
  {
    std::lock_guard lock(device_mutex_);
    for (const auto& m : messages_) say("input: " + m);
    messages_.clear();
  }
  if (loop.rtf_valid && loop.rtf < 0.9 && lag_drops_.load() > 0 && !paused_.load() && !physics_failed_.load() &&
      !loop.warned_behind) {
    if (local_)
      say(fmt::format("note: the tissue cannot keep real time ({:.2f}x); the tool and its force stay real time (the "
                      "local contact model carries the force between the physics' updates)",
                      loop.rtf));
    else
      say(fmt::format("warning: physics cannot keep real time ({:.2f}x): the simulation runs in slow motion "
                      "(a smaller model, fewer --threads competitors, a larger time step or --force-shaping local help)",
                      loop.rtf));
    loop.warned_behind = true;
  }
  return now;
}

bool App::show_frame(ProbeView& view, GuiLoop& loop) {
  if (!view.process_events()) {
    loop.window_closed = true;
    request_quit("window closed");
    return false;
  }
  {
    std::lock_guard lock(basis_mutex_);
    basis_ = view.view_basis();
  }
  // the newest frame, if the physics made one since; never waited for
  sim_->request_frame();
  if (sim_->take_frame(loop.frame)) {
    for (int p = 0; p < probes_ && p < int(loop.frame.probes.size()); ++p) {
      loop.probe_pos[std::size_t(p)] = loop.frame.probes[std::size_t(p)].pose.position_mm;
      loop.probe_contacts[std::size_t(p)] = loop.frame.probes[std::size_t(p)].contacts;
    }
    view.update_geometry(loop.frame.surface_vertices, loop.frame.surface_normals, loop.frame.positions, loop.probe_pos,
                         loop.probe_contacts);
  }
  std::vector<PlotSample> samples;
  {
    std::lock_guard lock(device_mutex_);
    samples.swap(plot_pending_);
  }
  view.add_plot_samples(samples);
  view.set_hud(hud(loop.physics_rate.rate(), loop.rtf_valid ? loop.rtf : 1.0, loop.device_rate.rate(),
                   loop.update_rate.rate()));
  view.render();
  if (screenshot_requested_.exchange(false)) {
    const std::string name = fmt::format("voxelastic-probe-{:06d}.png", view.frames());
    view.save_screenshot(name);
    say("screenshot: " + name);
  }
  if (options_.frames > 0 && view.frames() >= options_.frames)
    request_quit(fmt::format("{} frames (--frames)", options_.frames));
  loop.next_frame += loop.frame_period;
  const auto after = SteadyClock::now();
  if (loop.next_frame < after) loop.next_frame = after;
  std::this_thread::sleep_until(loop.next_frame);
  return true;
}

void App::report_headless(GuiLoop& loop, SteadyClock::time_point now) {
  {
    std::lock_guard lock(device_mutex_);
    plot_pending_.clear();
  }
  if (now >= loop.next_report) {
    if (local_)
      say(fmt::format("t = {:.2f} s, physics {:.0f} updates/s, {:.0f} steps/s (tissue {:.2f}x real time), device {:.0f} "
                      "forces/s",
                      double(device_time_us_.load()) * 1e-6, loop.update_rate.rate(), loop.physics_rate.rate(), loop.rtf,
                      loop.device_rate.rate()));
    else
      say(fmt::format("t = {:.2f} s simulated, physics {:.0f} steps/s ({:.2f}x real time), device {:.0f} updates/s",
                      double(sim_time_us_.load()) * 1e-6, loop.physics_rate.rate(), loop.rtf, loop.device_rate.rate()));
    loop.next_report = now + std::chrono::seconds(2);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
}

std::string App::run_gui_loop(ProbeView* view, GuiLoop& loop, const FixedRateThread& physics,
                              const FixedRateThread& device) {
  const bool automated =
      options_.headless || options_.frames > 0 || options_.duration_s > 0 || options_.exit_after_script;
  try {
    while (!quit_.load()) {
      if (g_interrupted.load()) request_quit("interrupted");
      if (physics.failed() || device.failed()) return physics.failed() ? physics.error() : device.error();
      // a scripted or timed run cannot go on without physics (an interactive user can reset)
      if (automated && physics_failed_.load()) break;
      const SteadyClock::time_point now = measure_rates(loop, device);
      if (view) {
        if (!show_frame(*view, loop)) break;
      } else {
        report_headless(loop, now);
      }
    }
  } catch (const std::exception& e) {
    return e.what();
  }
  return {};
}

int App::finish(ProbeView* view, const GuiLoop& loop, FixedRateThread& physics, FixedRateThread& device,
                std::string error) {
  const double wall_s = seconds(SteadyClock::now() - start_);
  if (error.empty() && device.failed()) error = device.error();
  if (error.empty() && physics.failed()) error = physics.error();
  try {
    outputs_.stop();
  } catch (const std::exception& e) {
    if (error.empty()) error = e.what();
  }
  if (view && !loop.window_closed && error.empty() && !options_.screenshot.empty()) {
    try {
      view->save_screenshot(options_.screenshot);
      say("screenshot: " + options_.screenshot.string());
    } catch (const std::exception& e) {
      error = e.what();
    }
  }
  {
    std::lock_guard lock(quit_mutex_);
    if (!quit_reason_.empty()) say("stopped: " + quit_reason_);
  }
  summary(wall_s);
  if (view) say(fmt::format("display: {} frames, {:.1f} frames/s", view->frames(), view->frames_per_s()));
  say(fmt::format("device: {} ticks ({:.0f} updates/s, {} late ticks skipped; a tick takes {:.0f} us on average, {:.0f} "
                  "us at most; {})",
                  device_ticks_, wall_s > 0 ? double(device_ticks_) / wall_s : 0.0, device.missed(),
                  device_ticks_ > 0 ? 1e6 * tick_cost_sum_s_ / double(device_ticks_) : 0.0, 1e6 * tick_cost_max_s_,
                  device_priority_));
  for (const auto& o : outputs_.all()) say(fmt::format("  {}: {} device commands", o->describe(), o->device_updates()));
  if (!options_.force_log.empty() && error.empty()) say("force log: " + options_.force_log.string());
  if (!error.empty()) {
    fmt::print(stderr, "voxelastic-probe: error: {}\n", error);
    return kExitError;
  }
  if (physics_failed_.load()) {
    fmt::print(stderr, "voxelastic-probe: error: {}\n", physics_failure_);
    return kExitError;
  }
  return 0;
}

int App::run() {
  start_simulation();
  open_input();
  open_outputs();
  const IoLines lines = describe_io();

  // the start view: stick axes follow the camera
  {
    std::lock_guard lock(basis_mutex_);
    basis_ = start_view_basis(scene_.world_up);
  }
  // the window (after everything that can fail on bad input)
  const std::unique_ptr<ProbeView> view = open_view(lines);

  // the threads
  physics_period_s_ = 1.0 / options_.physics_hz;
  device_period_s_ = 1.0 / options_.device_hz;
  start_ = SteadyClock::now();
  set_clock(SimClock{0.0, start_, false});
  FixedRateThread physics("physics", options_.physics_hz, [this](std::int64_t) { physics_tick(); });
  FixedRateThread device("device", options_.device_hz, [this](std::int64_t tick) {
    // the device thread has the one hard deadline (a tick every millisecond): it asks for the
    // lowest real-time priority (SCHED_FIFO 1; it sleeps between ticks, a tick takes tens of
    // microseconds), else nice -10, else keeps the default (no privilege). On a loaded machine a
    // thread at the default priority wakes up late often enough to skip 5-15 % of the ticks
    // (docs/probe.md, "Force shaping").
    if (tick == 0) device_priority_ = raise_device_thread_priority();
    const auto t0 = SteadyClock::now();
    device_tick();
    const double cost = seconds(SteadyClock::now() - t0);
    tick_cost_sum_s_ += cost;
    tick_cost_max_s_ = std::max(tick_cost_max_s_, cost);
  });
  const auto old_int = std::signal(SIGINT, on_interrupt);
  const auto old_term = std::signal(SIGTERM, on_interrupt);
  physics.start();
  device.start();
  // the display yields to the physics and the device when the CPU is short (Linux: per thread)
  if (view) (void)setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 5);

  GuiLoop loop(probes_, options_.fps);
  std::string error = run_gui_loop(view.get(), loop, physics, device);

  // stop: device first (no more writes), then physics, then zero the force and close files
  device.stop();
  physics.stop();
  std::signal(SIGINT, old_int);
  std::signal(SIGTERM, old_term);
  return finish(view.get(), loop, physics, device, std::move(error));
}

}  // namespace

int run_probe_app(const AppOptions& options) {
  // the checks that need no loading come first
  if (options.headless && options.duration_s <= 0 && !options.exit_after_script)
    throw Error("--headless needs a stop condition: --duration SECONDS or --exit-after-script");
  if (options.exit_after_script && options.joystick_script.empty())
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
  ProbeScene scene = load_probe_scene(options.input, scene_options);
  if (!options.quiet)
    for (const auto& n : scene.notes) fmt::print("{}\n", n);
  App app(options, std::move(scene));
  return app.run();
}

}  // namespace vx::probe
