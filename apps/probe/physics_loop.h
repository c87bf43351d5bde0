#pragma once
/// @file physics_loop.h
/// The physics thread's loop (one tick per --physics-rate period): advances the simulation to
/// the wall clock in whole steps with a step budget per tick; when it cannot keep up it drops
/// the lag and goes on in slow motion, never bursting. Local shaping: one update per tick (the
/// tool moved to the device's proxy over its steps, then a local contact model published).
/// Publishes what it did in `AppShared::physics` (app_shared.h).
///
/// Faults: a step that gives NaN/Inf or runs away (the state's own check) or throws does not end
/// the session: the tissue goes back to its last good state (`TissueSnapshot`, copied at the end
/// of a tick whose steps all passed the check, at least `kSnapshotEvery_s` of wall time apart and
/// at least `kSnapshotCostShare` times the last copy's time, so copying stays under 2 % of the
/// physics' time on an organ whose copy takes tens of ms;
/// three faults in a row from the same snapshot: back to rest), the console and the HUD say so,
/// and `fault_generation` tells the device to fade its force out (force_guard.h).

#include <vector>

#include "app_shared.h"
#include "sim/simulation.h"
#include "thread_share.h"

namespace vx::probe {

class PhysicsLoop {
 public:
  explicit PhysicsLoop(AppShared& shared) : s_(shared), share_(shared.share_cores ? shared.physics_threads : 1) {}
  /// One tick (the FixedRateThread body).
  void tick();
  /// Test hooks (--test-step-delay, --test-startup-delay): extra wall time per physics step, and
  /// on the first step (as a factorisation would take), s.
  void set_step_delay(double per_step_s, double first_step_s) {
    step_delay_s_ = per_step_s;
    first_step_delay_s_ = first_step_s;
  }
  /// After the thread stopped (the caller's thread): the soak's last figure (the tissue at the end).
  void finish();
  /// Test hook (--test-fault): faults injected at the start of the given steps.
  void set_faults(std::vector<InjectedFault> faults) { faults_ = std::move(faults); }
  /// The wall time between two snapshots of the last good state at least, s.
  static constexpr double kSnapshotEvery_s = 0.25;
  /// ... and at least this many times the last copy's own time.
  static constexpr double kSnapshotCostShare = 50.0;

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
  /// One step: the live commands handed over before it, its outputs published after it
  /// (sim_exchange.h); the injected fault, the test hook's delay.
  void step_once();
  /// The state after a fault back to the last good one; `what` for the console and the HUD.
  void recover(const std::string& what, bool drop_solver);
  /// Keeps the state now as the last good one when the last is old enough.
  void keep_good_state(SteadyClock::time_point now);
  /// Publishes the steps and simulated time of this tick, the start-up, a failure; true when
  /// this tick ended the start-up.
  bool publish(int steps, double sim_before_s);
  /// Sharing the cores: the threads for the next steps after this tick's `steps`, which took
  /// `busy_s` of wall time and advanced `sim_s` (thread_share.h). Steps on one thread in the
  /// display's turn (`display_turn`, AppControls::display_turn) are counted, not measured.
  void share_cores(int steps, double busy_s, double sim_s, bool display_turn);
  /// This thread's OpenMP threads for the next steps (set only when they change).
  void set_threads(int threads);
  /// Adds `until - from` to one of the physics thread's time counters (PhysicsReport::in_steps_us
  /// and the others) once the start-up has ended.
  void add_time(std::atomic<std::int64_t>& to, SteadyClock::time_point from, SteadyClock::time_point until);

  AppShared& s_;
  ThreadShare share_;   ///< the physics' threads while it shares the cores (most 1: it does not)
  int omp_threads_{0};  ///< this thread's OpenMP setting (0: not set yet)
  SteadyClock::time_point last_{};
  bool started_{false};
  double sim_target_s_{0.0};
  double lag_dropped_s_{0.0};
  /// the last tick's target (real time at its start) less where its steps left the simulation
  /// (before a drop; their own wall time not in it), s
  double lag_s_{0.0};
  bool have_targets_{false};
  double step_cost_s_{0.0};  ///< wall time of one step (mean)
  double step_delay_s_{0.0};
  double first_step_delay_s_{0.0};
  bool first_step_done_{false};
  std::vector<InjectedFault> faults_;
  TissueSnapshot good_;  ///< the last good state
  TissueSnapshot rest_;  ///< the rest state (after repeated faults)
  SteadyClock::time_point good_wall_{};
  double snapshot_every_s_{kSnapshotEvery_s};  ///< kSnapshotEvery_s, or longer where a copy is slow
  int faults_since_good_{0};
  Eigen::Matrix3Xd soak_ref_;  ///< soak: the tissue at rest before the first press
  /// soak: the largest node displacement from the reference now, mm (0 without one)
  [[nodiscard]] double soak_displacement_mm() const;
  void soak_watch();
};

}  // namespace vx::probe
