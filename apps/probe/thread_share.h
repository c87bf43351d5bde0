#pragma once
/// @file thread_share.h
/// How many threads the physics steps on when it shares the cores with a display: all it was
/// given (`most`) while they make it faster, one while it runs well ahead of real time or while
/// one is as fast (a busy machine, a display on the other core), so that its idle OpenMP worker
/// does not spin at the barriers inside each step on the core the display (and a software
/// renderer) would use. The results do not change: the core's parallel loops give the same bits
/// on any thread count (base/parallel.h).
///
/// The load is the wall time of the steps per simulated second (1: the steps take all of real
/// time; a time the system held the physics up counts in it). Four modes:
/// - **all** `most` threads, in windows of kHold_s of wall time (and kMinWindowSim_s of steps).
///   When a window's load times `most` is below kDrop, it goes to **ahead**: no parallel speed-up
///   is larger than the thread count, so one thread keeps real time with the same steps. Else,
///   when a trial is due, it goes to **trial**.
/// - **ahead**, one thread: back to all as soon as it lags real time by more than kRiseLag_s (a
///   press begins, the solver refactors). A burst of a few slow steps that it catches up with (the
///   tick's budget is twice real time) is not a lag.
/// - **trial**, one thread for kTrialWall_s (and kTrialSim_s of steps): kept when its load is at
///   most kSame times the load of the window on all threads before it (**kept**; ahead, when it
///   keeps real time with room to spare). Else back to all; the next trial waits kRetry_s,
///   doubled at each failed trial up to kRetryMax_s, so a scene that needs its threads loses a
///   trial's few steps of pace now and then.
/// - **kept**, one thread, in windows as long as a trial's: back to all (a trial due after their
///   first window) when a window's load passes kRise times the kept trial's (a press begins), or
///   after kRecheck_s (the machine may have quietened).
/// docs/probe.md, "Sharing the cores with the display".

#include <cstdint>

namespace vx::probe {

class ThreadShare {
 public:
  /// One thread when `most` times the load on `most` threads is below this.
  static constexpr double kDrop = 0.9;
  /// The wall time of a window on all threads, s.
  static constexpr double kHold_s = 2.0;
  /// What a window on all threads needs before it decides, s: this much simulated time or this
  /// much of the steps' wall time. A window that spans a pause (no steps, no calls) holds only the
  /// few steps around it and waits for more; a physics far behind real time (0.07x) has spent its
  /// window in steps and decides at its end.
  static constexpr double kMinWindowSim_s = 0.5 * kHold_s;
  /// The lag behind real time, ahead on one thread, that brings the others back, s.
  static constexpr double kRiseLag_s = 0.05;
  /// A trial's (and a kept window's) wall time, and the simulated time (or the steps' wall time)
  /// it needs, s.
  static constexpr double kTrialWall_s = 0.5;
  static constexpr double kTrialSim_s = 0.15;
  /// A trial is kept when its load is at most this times the load on all threads.
  static constexpr double kSame = 1.1;
  /// Kept on one thread, a window whose load passes this times the trial's brings the others back.
  static constexpr double kRise = 1.3;
  /// The wait after a failed trial, s, doubled at each failure up to kRetryMax_s.
  static constexpr double kRetry_s = 10.0;
  static constexpr double kRetryMax_s = 80.0;
  /// Kept on one thread, the wall time after which it measures all threads again, s.
  static constexpr double kRecheck_s = 30.0;

  enum class Mode { kAll, kAhead, kTrial, kKept };

  /// `most`: the threads the physics was given (>= 1; 1: nothing to share).
  explicit ThreadShare(int most);

  /// After a tick whose steps took `busy_s` of wall time and advanced the simulation by `sim_s`
  /// (ticks without steps need no call), at `now_s` (wall time, any fixed origin): the threads
  /// for the next steps. `target_lag_s`: real time at the tick's start (the simulated time the
  /// tick aimed for) less where its steps left the simulation (< 0: ahead). The steps' own wall
  /// time is added to it: behind real time now, so that one slow step (a large organ's first
  /// touch, 0.3 s, on one thread) is a lag at once and the steps after it (the region's set-up,
  /// 0.25 s) run on every thread, not one tick later on one.
  int after_steps(double now_s, double busy_s, double sim_s, double target_lag_s);

  [[nodiscard]] int threads() const { return mode_ == Mode::kAll ? most_ : 1; }
  [[nodiscard]] Mode mode() const { return mode_; }
  /// Changes of the thread count so far (either way).
  [[nodiscard]] std::int64_t changes() const { return changes_; }
  /// Trials on one thread so far, and those kept (one thread as fast).
  [[nodiscard]] std::int64_t trials() const { return trials_; }
  [[nodiscard]] std::int64_t trials_kept() const { return trials_kept_; }

 private:
  /// Enters `mode` at `now_s` with a new window.
  void enter(Mode mode, double now_s);
  /// Adds a tick to the window; true when it spans `wall_s` of wall time and holds `min_s` of
  /// simulated time or of the steps' wall time.
  bool window_full(double now_s, double busy_s, double sim_s, double wall_s, double min_s);
  [[nodiscard]] double window_load() const { return window_busy_s_ / window_sim_s_; }

  int most_;
  Mode mode_{Mode::kAll};
  std::int64_t changes_{0};
  std::int64_t trials_{0};
  std::int64_t trials_kept_{0};
  bool window_open_{false};
  double window_start_s_{0.0};
  double window_busy_s_{0.0};
  double window_sim_s_{0.0};
  double all_load_{0.0};      ///< the load of the last window on all threads
  double kept_load_{0.0};     ///< the load of the kept trial
  double next_trial_s_{0.0};  ///< no trial before this wall time
  double retry_s_{kRetry_s};  ///< the wait after the next failed trial
  double recheck_s_{0.0};     ///< kept: all threads again at this wall time
};

}  // namespace vx::probe
