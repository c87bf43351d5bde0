#pragma once
/// @file device_loop.h
/// The device thread's loop (one tick per --device-rate period, 1 kHz for haptics): reads the
/// joysticks (or plays the script into the virtual joysticks), computes the device force and
/// writes it to the force outputs. Two shapings (docs/probe.md, "Force shaping"):
/// - paper: the script runs in simulated time; the stick commands go to the simulation's live
///   probes; the force is the paper's half sine at the device's clock;
/// - local: this loop owns the tool: it moves the device (hand) position with the stick in wall
///   time, evaluates the local contact model the physics last published (haptics/local_contact.h)
///   at every tick, and hands the tool (proxy) position to the physics (`AppShared::tool_targets`).
/// What the GUI shows goes to `AppShared::device` (app_shared.h).
/// Every force passes a `DeviceForceGuard` (force_guard.h) on its way out: clamped to the
/// device's rated maximum (--max-force), ramped up over 100 ms after the start, a reset or a
/// reconnect, faded out over 40 ms when the physics fails (`PhysicsReport::fault_generation`)
/// or is reset. A stick unplugged and plugged back re-binds its force output.

#include <memory>
#include <string>
#include <vector>

#include "app_shared.h"
#include "force_guard.h"
#include "force_output.h"
#include "haptics/local_contact.h"
#include "joystick_script.h"
#include "sdl_input.h"
#include "sim/probe.h"
#include "stick_control.h"

namespace vx::probe {

/// What the device loop reads and drives; the app owns them.
struct DeviceParts {
  SdlInput* input{nullptr};
  KeyboardStick* keyboard{nullptr};
  ForceOutputs* outputs{nullptr};
  std::shared_ptr<const JoystickScript> script;
  ControlSettings control;           ///< the sticks' mapping
  ControlSettings keyboard_control;  ///< the keyboard's (no dead zone)
};

class DeviceLoop {
 public:
  DeviceLoop(AppShared& shared, DeviceParts parts);
  /// A stick commander per probe (first), starting at the probe's position and kept in `allowed`.
  void add_commander(const Eigen::Vector3d& start_mm, const Box& allowed);
  /// local shaping: a hand and a force renderer per probe; returns the hand's start position.
  Eigen::Vector3d add_local_probe(const ProbeSettings& probe, const HapticCouplingSettings& coupling);
  [[nodiscard]] const LocalForceRenderer& renderer(int p) const { return renderers_[std::size_t(p)]; }
  [[nodiscard]] std::size_t local_probes() const { return renderers_.size(); }

  /// One tick (the FixedRateThread body); the first tick asks for a real-time priority.
  void tick(std::int64_t n);

  [[nodiscard]] std::int64_t ticks() const { return ticks_; }
  [[nodiscard]] double clock_s() const { return clock_s_; }
  [[nodiscard]] double mean_tick_cost_s() const { return ticks_ > 0 ? cost_sum_s_ / double(ticks_) : 0.0; }
  [[nodiscard]] double max_tick_cost_s() const { return cost_max_s_; }
  [[nodiscard]] const std::string& priority() const { return priority_; }
  [[nodiscard]] const DeviceForceGuard& guard(int p) const { return guards_[std::size_t(p)]; }

 private:
  /// One probe's figures of this tick.
  struct ProbeTick {
    Eigen::Vector3d cmd{Eigen::Vector3d::Zero()};
    Eigen::Vector3d drag{Eigen::Vector3d::Zero()};
    double update_mean_N{0.0};  ///< the HUD's force
    double plot_mean_N{0.0};    ///< the plot's mean line
  };
  /// When the local contact models of one probe arrived.
  struct ModelArrival {
    SteadyClock::time_point wall{};
    double period_s{0.0};  ///< between the last two models (mean), s
    bool seen{false};
    int nodes{0};
    Eigen::Vector3d anchor_N{Eigen::Vector3d::Zero()};
  };

  // the stages of one tick
  void run_tick();
  /// Commanders (and local hands, renderers, the clock) back to the start after a reset; the
  /// force faded out after a reset or a physics fault.
  void follow_reset();
  /// Sticks unplugged or plugged back: their force output re-bound, the force ramped up; the
  /// test hooks' unplug and replug at the device's time `now_s`.
  void follow_connections(double now_s);
  /// paper: simulated time now, from the physics' last report; local: the device's own clock.
  [[nodiscard]] double advance_clock(const SimClock& c, SteadyClock::time_point now, double dt);
  /// The stick of probe p plus, for the active probe, the keyboard and mouse.
  [[nodiscard]] ProbeTick stick_of(int p);
  /// local shaping: the hand from the stick, the force from the local contact model, the proxy
  /// to the physics; fills `f`.
  void local_probe(int p, ProbeTick& t, double dt, bool paused, double now_s, SteadyClock::time_point wall,
                   ProbeForce& f);
  /// paper shaping: the live command to the physics, the half sine at the device's clock.
  void paper_probe(int p, ProbeTick& t, const ProbeOutput& snap, bool paused, bool sim_paused, double now_s,
                   ProbeForce& f);
  /// The HUD's forces, the statistics, a plot point every 4 ms, the input messages.
  void report(const DeviceTick& tick, const std::array<ProbeTick, kMaxSticks>& t, std::vector<std::string> msgs);
  /// Stop conditions: the script's end in the script's time, --duration in the tissue's simulated
  /// time.
  void check_stop(double script_s);
  /// A soak's end, after its script: true once the tissue sleeps, its idle window has passed in
  /// simulated time, or kSoakSettleWall_s of wall time (true at once outside a soak).
  [[nodiscard]] bool soak_settled();

  AppShared& s_;
  DeviceParts parts_;
  std::vector<ProbeCommander> commanders_;
  Eigen::Matrix3d basis_{Eigen::Matrix3d::Identity()};  ///< this tick's view basis
  int reset_seen_{0};
  int fault_seen_{0};
  std::array<DeviceForceGuard, kMaxSticks> guards_;
  std::array<int, kMaxSticks> connection_seen_{};
  bool unplugged_{false}, replugged_{false};  ///< the test hooks done
  double script_start_s_{-1.0};               ///< soak: the device time its script started at (the physics' start)
  /// soak: after the script, the wait for the tissue to rest (soak_settled): the simulated time
  /// it waits at most, s, when the wait began (wall and simulated, s; < 0: not yet) and how it ended
  static constexpr double kSoakSettleSim_s = 10.0;  ///< without regional solves (nothing sleeps)
  static constexpr double kSoakSettleWall_s = 120.0;
  double settle_window_s_{kSoakSettleSim_s};
  double settle_wall_s_{-1.0}, settle_sim_s_{0.0};
  double release_sim_s_{-1.0};  ///< the simulated time at the soak script's release (its tools up), s
  std::string settle_;
  std::int64_t ticks_{0};
  SteadyClock::time_point last_{};
  bool started_{false};
  double clock_s_{0.0};             ///< local: wall time while running (pauses excluded), s
  std::vector<ProbeDriver> hands_;  ///< local: the device (hand) position of each probe
  std::vector<LocalForceRenderer> renderers_;
  std::vector<ModelArrival> arrivals_;
  std::string priority_{"default priority"};  ///< what the thread got (at its first tick)
  double cost_sum_s_{0.0};                    ///< the tick's own cost (its CPU time, not the wait)
  double cost_max_s_{0.0};
};

}  // namespace vx::probe
