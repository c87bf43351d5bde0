#pragma once
/// @file app_shared.h
/// What the app's three loops share (physics_loop.h, device_loop.h, gui_loop.h), written down in
/// one place: who writes each field, who reads it, and how it crosses threads.
///
///   physics -> device, GUI: `PhysicsReport` (atomics; the clock under a mutex held for a copy);
///                           the local contact models (DeviceSide::publish_local_contact /
///                           take_local_contact: one triple buffer per probe, haptics/device_side.h);
///                           paper shaping: the half sine to play (DeviceSide::output_snapshot);
///                           each probe's output after every step and the deformed surface
///                           (`exchange`: SimulationExchange::probe, request_frame / take_frame,
///                           never waited for; sim_exchange.h)
///   device  -> physics:     `tool_targets` (local shaping: the proxy positions, a triple buffer);
///                           paper shaping: the live stick commands (SimulationExchange::set_live)
///   device  -> GUI:         `DeviceReport` under its mutex (held only to copy, never while
///                           rendering or stepping)
///   GUI     -> device:      the view basis (a mutex held for a copy); the keyboard (KeyboardStick)
///   GUI     -> all:         `AppControls` (pause, reset, screenshot, quit: atomics)
///
/// Every mutex that the device thread takes inherits priority (base/pi_mutex.h): the device runs
/// at SCHED_FIFO, and a plain mutex held by the physics or the GUI would make it wait until the
/// scheduler gave the holder a core again (priority inversion; tens of ms on a busy machine).

#include <fmt/core.h>

#include <Eigen/Core>

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "app_options.h"
#include "base/pi_mutex.h"
#include "probe_view.h"
#include "rate_thread.h"
#include "real_time_meter.h"
#include "sim_exchange.h"

namespace vx::probe {
class BackgroundDisplaySurface;  // probe_scene.h
}  // namespace vx::probe

namespace vx {
class BackgroundRegionCheck;  // scene/scene.h
}  // namespace vx

namespace vx {
class DeviceSide;
}

namespace vx::probe {

[[nodiscard]] inline double seconds(SteadyClock::duration d) { return std::chrono::duration<double>(d).count(); }

/// Where the physics is: simulated time at a wall instant.
struct SimClock {
  double sim_s{0.0};
  SteadyClock::time_point wall{};
  bool paused{false};
};

/// The keys and stop conditions every loop obeys.
struct AppControls {
  std::atomic<bool> paused{false};
  std::atomic<bool> reset_requested{false};  ///< GUI -> physics
  std::atomic<int> reset_generation{0};      ///< physics -> device: resets done
  std::atomic<bool> screenshot_requested{false};
  std::atomic<bool> quit{false};
  /// GUI -> physics: the display draws a frame while the tissue runs behind real time. With the
  /// cores shared (--share-cores), the physics steps on one thread until it ends, so that the
  /// renderer has a core to itself for the frame's own time; drawn beside the physics' team it
  /// took one of its cores for a second or more of wall time at its lower priority, and the
  /// team waited at its barriers meanwhile (docs/probe.md, "Where the physics thread's time
  /// goes, and the display's turn").
  std::atomic<bool> display_turn{false};

  /// Work in the background the session no longer wants once it quits (the solver being built:
  /// IntegratorSettings::stop_background); turned true by request_quit().
  std::shared_ptr<std::atomic<bool>> stop_background;  ///< (null: none)

  /// The first reason given wins.
  void request_quit(const std::string& why) {
    std::lock_guard lock(mutex_);
    if (stop_background) stop_background->store(true);
    if (!quit.exchange(true)) reason_ = why;
  }
  [[nodiscard]] std::string quit_reason() const {
    std::lock_guard lock(mutex_);
    return reason_;
  }

 private:
  mutable PiMutex mutex_;
  std::string reason_;
};

/// What the physics loop publishes (written by the physics thread only).
struct PhysicsReport {
  std::atomic<std::int64_t> steps{0};            ///< steps taken (all)
  std::atomic<std::int64_t> sim_time_us{0};      ///< the simulation's time
  std::atomic<std::int64_t> sim_advanced_us{0};  ///< simulated time advanced (resets excluded)
  std::atomic<std::int64_t> lag_drops{0};        ///< times it could not keep real time
  std::atomic<std::int64_t> updates{0};          ///< local: local contact models published
  /// Start-up: the wall time (since the open) at which the first step completed, and the
  /// simulated time advanced and steps by then; valid once `started` (release/acquire).
  std::atomic<bool> started{false};
  double startup_s{0.0};
  RateSample at_startup{};
  /// The end of the run: the first tick after a quit; valid once `ended` (release/acquire).
  std::atomic<bool> ended{false};
  RateSample at_end{};
  std::atomic<bool> failed{false};
  std::string failure;  ///< written once before `failed` is set
  /// Faults recovered from (a step gave NaN/Inf, ran away or threw: the tissue went back to its
  /// last good state, the session went on). The device fades its force at each new generation.
  std::atomic<std::int64_t> faults{0};
  std::atomic<int> fault_generation{0};
  std::atomic<std::int64_t> fault_wall_us{0};    ///< when the last one was (wall time since the open)
  std::atomic<std::int64_t> snapshots{0};        ///< last good states kept
  std::atomic<std::int64_t> snapshot_max_us{0};  ///< the longest copy of one
  /// Soak (physics thread; read after it stopped): the tissue's largest displacement from its
  /// reference, mm, and the displacement at the end, after the release (< 0: not measured). The
  /// reference is the model's shape without gravity (soak_ref_is_shape); with gravity, the state
  /// at the first snapshot after 1 s simulated with no tool touching (soak_ref_s; < 0: none yet).
  bool soak_ref_is_shape{false};
  double soak_ref_s{-1.0};
  double soak_peak_mm{0.0};
  /// The implicit solver's contact cache (ProjectiveSolver::contact_cache_bytes), bytes: updated
  /// with each last-good-state snapshot in a soak.
  std::atomic<std::int64_t> contact_cache_bytes{0};
  double soak_final_mm{-1.0};
  /// ... and the simulation's counters then (whether, when and how far from its rest shape the
  /// tissue last fell asleep) with the simulated time at the end, s.
  SimulationCounters soak_counters;
  double soak_end_s{0.0};
  /// Whether the tissue's last step found it asleep (at rest, nothing computed; docs/model.md
  /// section 7, "A tissue at rest sleeps"): a soak's end waits for it (DeviceLoop::soak_settled).
  std::atomic<bool> asleep{false};
  /// Sharing the cores (thread_share.h): the threads the physics steps on now, the steps it took
  /// on one thread out of more, how often it changed, and its trials on one thread (all, kept).
  std::atomic<int> threads{1};
  std::atomic<std::int64_t> steps_on_one{0};
  std::atomic<std::int64_t> thread_changes{0};
  std::atomic<std::int64_t> thread_trials{0};
  std::atomic<std::int64_t> thread_trials_kept{0};
  /// Steps taken on one thread during the display's turns (AppControls::display_turn).
  std::atomic<std::int64_t> steps_in_display_turns{0};
  /// Where the physics thread's wall time went after the start-up, us: in the steps
  /// (Simulation::step), the local contact models built after them (local shaping), the copies of
  /// the last good state, and the outputs handed to the other threads after each step (a frame's
  /// positions when the GUI asked); the rest of the interval is waiting for real time and the
  /// tick's own work. The steps' figure is the one `simulate` and `bench` time.
  std::atomic<std::int64_t> in_steps_us{0};
  std::atomic<std::int64_t> in_local_models_us{0};
  std::atomic<std::int64_t> in_snapshots_us{0};
  std::atomic<std::int64_t> in_outputs_us{0};
  /// The implicit solver built in the background while the tissue rests
  /// (IntegratorSettings::factor_in_background): being built now; when it was taken (wall time
  /// since the open, us; < 0: not yet or never built so); the wall time steps waited for it, us.
  std::atomic<bool> solver_pending{false};
  /// The quit found a step waiting for that solver (a tool had reached the tissue): the wait stopped.
  std::atomic<bool> quit_while_waiting{false};
  std::atomic<std::int64_t> solver_ready_us{-1};
  std::atomic<std::int64_t> factor_wait_us{0};

  [[nodiscard]] std::string last_fault() const {
    std::lock_guard lock(fault_mutex_);
    return last_fault_;
  }
  void set_last_fault(const std::string& what) {
    std::lock_guard lock(fault_mutex_);
    last_fault_ = what;
  }

  [[nodiscard]] SimClock clock() const {
    std::lock_guard lock(clock_mutex_);
    return clock_;
  }
  void set_clock(const SimClock& c) {
    std::lock_guard lock(clock_mutex_);
    clock_ = c;
  }
  /// Now, as a rate sample (wall time since `start`).
  [[nodiscard]] RateSample sample(SteadyClock::time_point start, SteadyClock::time_point now) const {
    return {seconds(now - start), double(sim_advanced_us.load()) * 1e-6, steps.load()};
  }

 private:
  mutable PiMutex clock_mutex_;
  SimClock clock_;
  mutable PiMutex fault_mutex_;
  std::string last_fault_;
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
  double max_step_N{0.0};  ///< largest tick-to-tick change of the device force
  Eigen::Vector3d last_N{Eigen::Vector3d::Zero()};
  std::int64_t samples{0};
};

/// What the device loop hands the GUI (under `mutex`, held only to copy or swap).
struct DeviceReport {
  PiMutex mutex;
  HudForces hud;
  std::vector<PlotSample> plot_pending;
  std::vector<std::string> messages;
  std::array<ForceStats, 2> stats{};
  std::atomic<std::int64_t> device_time_us{0};  ///< local: the device's clock
};

/// Everything the loops share; the app owns it and outlives the threads.
struct AppShared {
  AppShared(const AppOptions& o, Simulation& s, DeviceSide& d) : options(o), sim(s), device_side(d), exchange(s) {}
  const AppOptions& options;
  Simulation& sim;              ///< the physics thread's alone; the others go through `exchange`
  DeviceSide& device_side;      ///< the simulation's device force and local contact models
  SimulationExchange exchange;  ///< live commands in, probe outputs and frames out
  int probes{0};
  bool local{false};  ///< local shaping (else the paper's half sines)
  double physics_period_s{0.001};
  double device_period_s{0.001};
  /// The threads the physics was given (--threads, 0 resolved to the cores), and whether it
  /// steps on one of them while it runs well ahead of real time or one is as fast (--share-cores;
  /// thread_share.h)
  int physics_threads{1};
  bool share_cores{false};
  SteadyClock::time_point start{};  ///< the open: the threads started
  /// The regional solves' error on this support, still being estimated (null: none or reported)
  std::shared_ptr<BackgroundRegionCheck> region_check;
  /// A standing accuracy warning for the status line (ProbeScene::accuracy_status); empty: none
  std::string accuracy_status;
  /// The display surface the window opened with (the physics' frames carry the one they deform)
  std::shared_ptr<const EmbeddedSurface> display_surface;
  /// Its decimation, still running while display_surface is a preview (null: none, or taken
  /// by the GUI loop, which hands the result to the physics: SimulationExchange::offer_surface)
  std::shared_ptr<BackgroundDisplaySurface> surface_refinement;

  AppControls controls;
  PhysicsReport physics;
  DeviceReport device;
  /// local shaping: the tool positions (proxies) the device hands to the physics
  TripleBuffer<std::array<Eigen::Vector3d, kMaxSticks>> tool_targets;

  [[nodiscard]] Eigen::Matrix3d basis() const {
    std::lock_guard lock(basis_mutex_);
    return basis_;
  }
  void set_basis(const Eigen::Matrix3d& b) {
    std::lock_guard lock(basis_mutex_);
    basis_ = b;
  }
  void say(const std::string& line) const {
    if (!options.quiet) fmt::print("{}\n", line);
  }

 private:
  mutable PiMutex basis_mutex_;
  Eigen::Matrix3d basis_{Eigen::Matrix3d::Identity()};
};

}  // namespace vx::probe
