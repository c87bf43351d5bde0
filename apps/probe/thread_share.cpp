#include "thread_share.h"

#include <algorithm>

namespace vx::probe {

ThreadShare::ThreadShare(int most) : most_(std::max(1, most)) {}

void ThreadShare::enter(Mode mode, double now_s) {
  const int before = threads();
  mode_ = mode;
  if (threads() != before) ++changes_;
  window_open_ = true;
  window_start_s_ = now_s;
  window_busy_s_ = 0.0;
  window_sim_s_ = 0.0;
}

bool ThreadShare::window_full(double now_s, double busy_s, double sim_s, double wall_s, double min_s) {
  // the window starts with the first steps measured (the steps before them are the start-up)
  if (!window_open_) enter(mode_, now_s);
  window_busy_s_ += busy_s;
  window_sim_s_ += sim_s;
  return now_s - window_start_s_ >= wall_s && std::max(window_sim_s_, window_busy_s_) >= min_s;
}

int ThreadShare::after_steps(double now_s, double busy_s, double sim_s, double target_lag_s) {
  if (most_ == 1 || sim_s <= 0.0) return threads();
  // behind real time now: the tick's target was real time at its start, before its steps
  const double lag_s = target_lag_s + busy_s;
  switch (mode_) {
    case Mode::kAhead:
      // one thread falls behind: back to all of them
      if (lag_s > kRiseLag_s) enter(Mode::kAll, now_s);
      break;
    case Mode::kAll:
      if (!window_full(now_s, busy_s, sim_s, kHold_s, kMinWindowSim_s)) break;
      all_load_ = window_load();
      // one thread when even `most` times the load keeps real time; else a trial when one is due
      if (all_load_ * double(most_) < kDrop) {
        enter(Mode::kAhead, now_s);
      } else if (now_s >= next_trial_s_) {
        ++trials_;
        enter(Mode::kTrial, now_s);
      } else {
        enter(Mode::kAll, now_s);
      }
      break;
    case Mode::kTrial: {
      if (!window_full(now_s, busy_s, sim_s, kTrialWall_s, kTrialSim_s)) break;
      const double load = window_load();
      if (load <= kSame * all_load_) {
        ++trials_kept_;
        kept_load_ = load;
        retry_s_ = kRetry_s;
        recheck_s_ = now_s + kRecheck_s;
        enter(load < kDrop ? Mode::kAhead : Mode::kKept, now_s);
      } else {
        next_trial_s_ = now_s + retry_s_;
        retry_s_ = std::min(2.0 * retry_s_, kRetryMax_s);
        enter(Mode::kAll, now_s);
      }
      break;
    }
    case Mode::kKept: {
      if (!window_full(now_s, busy_s, sim_s, kTrialWall_s, kTrialSim_s)) break;
      const double load = window_load();
      if (load > kRise * kept_load_ || now_s >= recheck_s_) {
        // the load changed (a press begins) or the machine may have: measure all threads again,
        // and try one after that window
        next_trial_s_ = now_s;
        enter(Mode::kAll, now_s);
      } else {
        enter(load < kDrop ? Mode::kAhead : Mode::kKept, now_s);
      }
      break;
    }
  }
  return threads();
}

}  // namespace vx::probe
