#include "haptics/device_force.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <sstream>

#include "base/error.h"

namespace vx {

const char* to_string(ForceShaping s) { return s == ForceShaping::local ? "local" : "paper"; }

ForceShaping parse_force_shaping(const std::string& s) {
  if (s == "paper") return ForceShaping::paper;
  if (s == "local") return ForceShaping::local;
  throw Error("unknown force shaping \"" + s +
              "\": use local (the local contact model at 1 kHz) or paper (half sines)");
}

std::string DeviceForceSettings::validate() const {
  std::ostringstream err;
  if (!(device_damping_n_s_mm > 0 && std::isfinite(device_damping_n_s_mm)))
    err << "device damping " << device_damping_n_s_mm << " N s/mm must be > 0; ";
  if (!(update_interval_s > 0 && std::isfinite(update_interval_s)))
    err << "device update interval " << update_interval_s << " s must be > 0 (e.g. 0.02 s for 50 Hz); ";
  if (average_steps < 0) err << "average_steps " << average_steps << " must be >= 0 (0 = the whole interval); ";
  return err.str();
}

Eigen::Vector3d HalfSinePulse::at(double t_s) const {
  const double u = duration_s > 0 ? (t_s - start_s) / duration_s : -1.0;
  if (!(u >= 0.0 && u < 1.0)) return Eigen::Vector3d::Zero();
  return peak_n * std::sin(std::numbers::pi * u);
}

void DeviceForceShaper::init(const DeviceForceSettings& settings, double dt_s) {
  if (const std::string bad = settings.validate(); !bad.empty()) throw Error("device force: " + bad);
  if (!(dt_s > 0)) throw Error("device force: the physics step must be > 0");
  const double steps = settings.update_interval_s / dt_s;
  if (!(steps >= 1.5))
    throw Error("device force: the update interval " + std::to_string(settings.update_interval_s) +
                " s must span at least 2 physics steps of " + std::to_string(dt_s) +
                " s (a half sine needs room); raise device.update_interval_s or lower integrator.dt_s");
  settings_ = settings;
  dt_ = dt_s;
  steps_per_update_ = int(std::lround(steps));
  window_ = settings.average_steps > 0 ? settings.average_steps : steps_per_update_;
  scale_ = settings.mean_preserving ? std::numbers::pi / 2.0 : 1.0;
  ring_.assign(std::size_t(window_), Eigen::Vector3d::Zero());
  reset();
}

void DeviceForceShaper::reset() {
  std::fill(ring_.begin(), ring_.end(), Eigen::Vector3d::Zero());
  ring_next_ = 0;
  ring_filled_ = 0;
  step_ = 0;
  update_step_ = 0;
  updates_ = 0;
  pulse_ = {};
  pulse_.duration_s = steps_per_update_ * dt_;
  shaped_.setZero();
}

const Eigen::Vector3d& DeviceForceShaper::push(const Eigen::Vector3d& raw, double t_s) {
  // remember the raw force
  ring_[std::size_t(ring_next_)] = raw;
  ring_next_ = (ring_next_ + 1) % window_;
  ring_filled_ = std::min(ring_filled_ + 1, window_);
  ++step_;
  // device update: the mean of the last few raw forces starts a new half sine
  if (step_ % steps_per_update_ == 0) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (int k = 0; k < ring_filled_; ++k) sum += ring_[std::size_t(k)];
    pulse_.mean_n = sum / double(ring_filled_);
    pulse_.peak_n = scale_ * pulse_.mean_n;
    pulse_.start_s = t_s;
    pulse_.duration_s = steps_per_update_ * dt_;
    update_step_ = step_;
    ++updates_;
  }
  // the half sine, from the whole step count (exactly zero at the update instants)
  const double phase = double(step_ - update_step_) / double(steps_per_update_);
  shaped_ = pulse_.peak_n * std::sin(std::numbers::pi * phase);
  return shaped_;
}

}  // namespace vx
