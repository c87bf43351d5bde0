#pragma once
/// @file physics_loop.h
/// The physics thread's loop (one tick per --physics-rate period): advances the simulation to
/// the wall clock in whole steps with a step budget per tick; when it cannot keep up it drops
/// the lag and goes on in slow motion, never bursting. Local shaping: one update per tick (the
/// tool moved to the device's proxy over its steps, then a local contact model published).
/// Publishes what it did in `AppShared::physics` (app_shared.h).

#include "app_shared.h"

namespace vx::probe {

class PhysicsLoop {
 public:
  explicit PhysicsLoop(AppShared& shared) : s_(shared) {}
  /// One tick (the FixedRateThread body).
  void tick();
  /// Test hooks (--test-step-delay, --test-startup-delay): extra wall time per physics step, and
  /// on the first step (as a factorisation would take), s.
  void set_step_delay(double per_step_s, double first_step_s) {
    step_delay_s_ = per_step_s;
    first_step_delay_s_ = first_step_s;
  }

 private:
  /// Resets the simulation when the GUI asked.
  void apply_reset();
  /// The steps of one tick toward `sim_target_s_` (`elapsed`: wall time since the last tick);
  /// returns the steps taken.
  int advance(SteadyClock::time_point now, double elapsed);
  /// local shaping: one physics update; returns the steps taken. The update ends after about
  /// one physics period of wall time even when it has not taken all `steps` (a slow physics
  /// publishes at its rate and falls behind in simulated time, not in updates).
  int local_update(int steps, SteadyClock::time_point start);
  /// One step (and the test hook's delay).
  void step_once();
  /// Publishes the steps and simulated time of this tick, the start-up, a failure; true when
  /// this tick ended the start-up.
  bool publish(int steps, double sim_before_s);

  AppShared& s_;
  SteadyClock::time_point last_{};
  bool started_{false};
  double sim_target_s_{0.0};
  double lag_dropped_s_{0.0};
  bool have_targets_{false};
  double step_cost_s_{0.0};  ///< wall time of one step (mean)
  double step_delay_s_{0.0};
  double first_step_delay_s_{0.0};
  bool first_step_done_{false};
};

}  // namespace vx::probe
