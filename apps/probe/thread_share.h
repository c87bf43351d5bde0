#pragma once
/// @file thread_share.h
/// How many threads the physics steps on when it shares the cores with a display: all it was
/// given (`most`) while it needs them to keep real time, one while it runs well ahead of it, so
/// that its idle OpenMP worker does not spin at the barriers inside each step on the core the
/// display (and a software renderer) would use. The results do not change: the core's parallel
/// loops give the same bits on any thread count (base/parallel.h).
///
/// Going to one thread: the load is the wall time of the steps per simulated second (1: the steps
/// take all of real time; a time the system held the physics up counts against going to one
/// thread, never for it). On `most` threads the physics goes to one when the load times `most` has stayed below
/// kDrop over kHold_s of wall time: on one thread the same steps take at most `most` times as
/// long (no parallel speed-up is larger than the thread count), so the load there stays below
/// kDrop and it keeps real time.
///
/// Going back: on one thread it goes back to `most` as soon as it lags real time by more than
/// kRiseLag_s (a press begins, the solver refactors), so the tissue falls behind by that much at
/// most. A burst of a few slow steps that it catches up with (the tick's budget is twice real
/// time) is not a lag, and does not cost the display a kHold_s of spinning worker.
/// docs/probe.md, "Sharing the cores with the display".

#include <cstdint>

namespace vx::probe {

class ThreadShare {
 public:
  /// One thread when `most` times the load on `most` threads is below this.
  static constexpr double kDrop = 0.9;
  /// The wall time of low load before the physics goes to one thread, s.
  static constexpr double kHold_s = 2.0;
  /// The simulated time a window needs before it decides, s: a window that spans a pause (no
  /// steps, no calls) holds only the few steps around it, and waits for more.
  static constexpr double kMinWindowSim_s = 0.5 * kHold_s;
  /// The lag behind real time on one thread that brings the others back, s.
  static constexpr double kRiseLag_s = 0.05;

  /// `most`: the threads the physics was given (>= 1; 1: nothing to share).
  explicit ThreadShare(int most);

  /// After a tick whose steps took `busy_s` of wall time and advanced the simulation by `sim_s`,
  /// leaving it `lag_s` behind real time (ticks without steps need no call), at `now_s` (wall
  /// time, any fixed origin): the threads for the next steps.
  int after_steps(double now_s, double busy_s, double sim_s, double lag_s);

  [[nodiscard]] int threads() const { return threads_; }
  /// Changes of the thread count so far (either way).
  [[nodiscard]] std::int64_t changes() const { return changes_; }

 private:
  void set(int threads, double now_s);
  int most_;
  int threads_;
  std::int64_t changes_{0};
  bool window_open_{false};
  double window_start_s_{0.0};
  double window_busy_s_{0.0};
  double window_sim_s_{0.0};
};

}  // namespace vx::probe
