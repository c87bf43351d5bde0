#include "real_time_meter.h"

#include <fmt/core.h>

#include <algorithm>
#include <cmath>

namespace vx::probe {

RateWindow rate_between(const RateSample& a, const RateSample& b) {
  RateWindow w;
  w.wall_s = std::max(0.0, b.wall_s - a.wall_s);
  w.sim_s = b.sim_s - a.sim_s;
  w.steps = b.steps - a.steps;
  return w;
}

RealTimeMeter::RealTimeMeter(std::size_t capacity) : ring_(std::max<std::size_t>(2, capacity)) {}

void RealTimeMeter::add(const RateSample& s) {
  if (count_ > 0 && s.wall_s < at(0).wall_s) return;
  ring_[next_] = s;
  next_ = (next_ + 1) % ring_.size();
  count_ = std::min(count_ + 1, ring_.size());
}

void RealTimeMeter::restart() {
  next_ = 0;
  count_ = 0;
}

const RateSample& RealTimeMeter::at(std::size_t age) const {
  return ring_[(next_ + ring_.size() - 1 - age) % ring_.size()];
}

RateWindow RealTimeMeter::over_last(double window_s) const {
  if (count_ < 2) return {};
  const RateSample& newest = at(0);
  // the newest sample at least window_s older than the newest one, else the oldest
  std::size_t age = 1;
  while (age + 1 < count_ && newest.wall_s - at(age).wall_s < window_s) ++age;
  RateWindow w = rate_between(at(age), newest);
  w.full = newest.wall_s - at(age).wall_s >= window_s;
  return w;
}

std::string StartupReport::preparing(double elapsed_s, std::optional<double> progress) {
  if (progress) return fmt::format("preparing the solver: {:.0f} %", 100.0 * std::clamp(*progress, 0.0, 1.0));
  return fmt::format("preparing the solver ({:.1f} s)", elapsed_s);
}

std::string describe_physics_rate(const RateWindow& w, double window_s, bool tissue) {
  if (!(w.wall_s > 0)) return fmt::format("steps/s: measuring ({}real time: measuring)", tissue ? "tissue " : "");
  const std::string span = w.full ? fmt::format("last {:g} s", window_s) : fmt::format("last {:.1f} s", w.wall_s);
  return fmt::format("{:.0f} steps/s ({}{:.2f}x real time, {})", w.steps_per_s(), tissue ? "tissue " : "", w.factor(),
                     span);
}

}  // namespace vx::probe
