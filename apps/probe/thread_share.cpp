#include "thread_share.h"

#include <algorithm>

namespace vx::probe {

ThreadShare::ThreadShare(int most) : most_(std::max(1, most)), threads_(most_) {}

void ThreadShare::set(int threads, double now_s) {
  if (threads != threads_) ++changes_;
  threads_ = threads;
  window_open_ = true;
  window_start_s_ = now_s;
  window_busy_s_ = 0.0;
  window_sim_s_ = 0.0;
}

int ThreadShare::after_steps(double now_s, double busy_s, double sim_s, double lag_s) {
  if (most_ == 1 || sim_s <= 0.0) return threads_;
  if (threads_ == 1) {
    // one thread falls behind: back to all of them
    if (lag_s > kRiseLag_s) set(most_, now_s);
    return threads_;
  }
  // the window starts with the first steps measured (the steps before them are the start-up)
  if (!window_open_) set(threads_, now_s);
  window_busy_s_ += busy_s;
  window_sim_s_ += sim_s;
  if (now_s - window_start_s_ < kHold_s || window_sim_s_ < kMinWindowSim_s) return threads_;
  // the window is over: one thread when even `most` times its load keeps real time
  set(window_busy_s_ * double(most_) < kDrop * window_sim_s_ ? 1 : most_, now_s);
  return threads_;
}

}  // namespace vx::probe
