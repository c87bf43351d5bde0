#include "force_guard.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace vx::probe {

std::string ForceGuardSettings::validate() const {
  std::ostringstream err;
  if (!(max_force_N > 0) || !std::isfinite(max_force_N)) err << "the maximum force must be > 0 N; ";
  if (!(ramp_up_s >= 0) || !std::isfinite(ramp_up_s)) err << "the ramp-up time must be >= 0 s; ";
  if (!(fade_s >= 0) || !(fade_s <= 0.05)) err << "the fade after a fault must be 0 to 0.05 s; ";
  return err.str();
}

DeviceForceGuard::DeviceForceGuard(ForceGuardSettings settings) : settings_(settings) {}

void DeviceForceGuard::restart() {
  stay_off_ = false;
  phase_ = Phase::rising;
  gain_ = 0.0;
  last_N_.setZero();
}

void DeviceForceGuard::disconnect() {
  interrupt();
  stay_off_ = true;
}

void DeviceForceGuard::interrupt() {
  ++interrupts_;
  if (phase_ == Phase::fading || phase_ == Phase::off) return;
  // the force now fades from what the hand feels now (the ramp's gain included)
  held_N_ = last_N_;
  phase_ = Phase::fading;
  gain_ = 1.0;
}

Eigen::Vector3d DeviceForceGuard::apply(const Eigen::Vector3d& wanted_N, double dt_s) {
  const double dt = std::max(0.0, std::isfinite(dt_s) ? dt_s : 0.0);
  Eigen::Vector3d f = wanted_N;
  if (!f.allFinite()) {
    ++non_finite_;
    interrupt();
    f.setZero();
  }
  // the rated maximum: the direction kept, the magnitude cut
  const double n = f.norm();
  if (n > settings_.max_force_N) {
    f *= settings_.max_force_N / n;
    ++clamped_;
  }
  switch (phase_) {
    case Phase::fading:
      gain_ = settings_.fade_s > 0 ? std::max(0.0, gain_ - dt / settings_.fade_s) : 0.0;
      if (gain_ > 0.0) {
        last_N_ = gain_ * held_N_;
        return last_N_;
      }
      // faded out: from zero again (or nothing until the device is back)
      phase_ = stay_off_ ? Phase::off : Phase::rising;
      gain_ = 0.0;
      last_N_.setZero();
      return last_N_;
    case Phase::rising:
      gain_ = settings_.ramp_up_s > 0 ? std::min(1.0, gain_ + dt / settings_.ramp_up_s) : 1.0;
      if (gain_ >= 1.0) phase_ = Phase::on;
      last_N_ = gain_ * f;
      return last_N_;
    case Phase::off: last_N_.setZero(); return last_N_;
    case Phase::on: break;
  }
  last_N_ = f;
  return last_N_;
}

}  // namespace vx::probe
