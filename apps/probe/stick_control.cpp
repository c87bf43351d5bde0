#include "stick_control.h"

#include <algorithm>
#include <cmath>

#include "base/error.h"

namespace vx::probe {

namespace {

// removes the dead zone and rescales the rest to [0, 1] so motion starts smoothly
double shape_axis(double v, double deadzone) {
  const double a = std::abs(v);
  if (a <= deadzone) return 0.0;
  return std::copysign(std::min(1.0, (a - deadzone) / std::max(1e-9, 1.0 - deadzone)), v);
}

constexpr auto kRepeatGrace = std::chrono::milliseconds(60);

}  // namespace

Eigen::Vector3d stick_command(const StickState& stick, const ControlSettings& settings) {
  if (!stick.present) return Eigen::Vector3d::Zero();
  const double dz = std::clamp(settings.mapping.dead_zone, 0.0, 0.9);
  Eigen::Vector3d c;
  c.x() = shape_axis(stick.num_axes > 0 ? stick.axes[0] : 0.0, dz);
  c.y() = -shape_axis(stick.num_axes > 1 ? stick.axes[1] : 0.0, dz);  // SDL: +1 = pulled back = down
  double z = 0.0;
  if (settings.z_axis >= 0 && settings.z_axis < stick.num_axes) {
    z = shape_axis(stick.axes[std::size_t(settings.z_axis)], dz);
    if (settings.invert_z_axis) z = -z;
  }
  // buttons and the hat add to the axis (either can be used)
  const auto held = [&](int b) { return b >= 0 && b < 32 && ((stick.buttons >> b) & 1u); };
  if (held(settings.z_away_button) || (stick.hat & SDL_HAT_UP)) z += 1.0;
  if (held(settings.z_toward_button) || (stick.hat & SDL_HAT_DOWN)) z -= 1.0;
  c.z() = std::clamp(z, -1.0, 1.0);
  return c;
}

ProbeCommander::ProbeCommander(const Eigen::Vector3d& home_mm, const Box& allowed, const ControlSettings& settings)
    : home_(allowed.clamp(home_mm)), allowed_(allowed), settings_(settings) {}

void ProbeCommander::reset() {
  pending_drag_.setZero();
  drag_offset_.setZero();
  depth_mm_ = 0.0;
}

LiveCommand ProbeCommander::update(const Eigen::Vector3d& command, const Eigen::Vector3d& drag_view_mm,
                                   const Eigen::Matrix3d& view_basis, const Eigen::Vector3d& probe_mm, double dt_s) {
  const Eigen::Vector3d c = command.cwiseMax(-1.0).cwiseMin(1.0);
  const Eigen::Vector3d drag = view_basis * drag_view_mm;
  LiveCommand out;
  if (settings_.mapping.mode == JoystickMode::rate) {
    // the paper: velocity proportional to the tilt
    Eigen::Vector3d v = view_basis * (c * settings_.mapping.max_speed_mm_s);
    // a drag is worked off within about 50 ms, at most twice the full-tilt speed
    pending_drag_ += drag;
    if (dt_s > 0 && pending_drag_.norm() > 1e-9) {
      Eigen::Vector3d vd = pending_drag_ / 0.05;
      const double cap = 2.0 * settings_.mapping.max_speed_mm_s;
      if (vd.norm() > cap) vd *= cap / vd.norm();
      if ((vd * dt_s).norm() >= pending_drag_.norm()) vd = pending_drag_ / dt_s;
      pending_drag_ -= vd * dt_s;
      v += vd;
    }
    // never out of the allowed box: cut the components that would leave it
    const double h = std::max(dt_s, 1e-9);
    for (int i = 0; i < 3; ++i) {
      if (v[i] < 0 && probe_mm[i] + v[i] * h < allowed_.lo[i]) v[i] = std::min(0.0, (allowed_.lo[i] - probe_mm[i]) / h);
      if (v[i] > 0 && probe_mm[i] + v[i] * h > allowed_.hi[i]) v[i] = std::max(0.0, (allowed_.hi[i] - probe_mm[i]) / h);
    }
    out.kind = LiveCommand::Kind::velocity;
    out.value = v;
  } else {
    // position control: the tilt picks a target around home in the screen plane; depth is
    // absolute with a depth axis and a rate when driven by buttons
    if (settings_.z_axis >= 0)
      depth_mm_ = c.z() * settings_.mapping.range_mm;
    else
      depth_mm_ = std::clamp(depth_mm_ + c.z() * settings_.mapping.max_speed_mm_s * dt_s, -settings_.mapping.range_mm,
                             settings_.mapping.range_mm);
    drag_offset_ += drag;
    const Eigen::Vector3d offset_view(c.x() * settings_.mapping.range_mm, c.y() * settings_.mapping.range_mm,
                                      depth_mm_);
    out.kind = LiveCommand::Kind::position;
    out.value = allowed_.clamp(home_ + drag_offset_ + view_basis * offset_view);
  }
  return out;
}

void KeyboardStick::press(Key k) {
  std::lock_guard lock(mutex_);
  held_[std::size_t(k)] = true;
  released_at_[std::size_t(k)] = {};
}

void KeyboardStick::release(Key k) {
  std::lock_guard lock(mutex_);
  released_at_[std::size_t(k)] = Clock::now();
}

void KeyboardStick::add_drag(const Eigen::Vector3d& view_offset_mm) {
  std::lock_guard lock(mutex_);
  drag_ += view_offset_mm;
}

Eigen::Vector3d KeyboardStick::take_drag() {
  std::lock_guard lock(mutex_);
  const Eigen::Vector3d d = drag_;
  drag_.setZero();
  return d;
}

void KeyboardStick::set_active_probe(int p) {
  std::lock_guard lock(mutex_);
  active_probe_ = std::clamp(p, 0, kMaxSticks - 1);
}

int KeyboardStick::active_probe() const {
  std::lock_guard lock(mutex_);
  return active_probe_;
}

StickState KeyboardStick::state() const {
  std::lock_guard lock(mutex_);
  const auto now = Clock::now();
  std::array<bool, key_count> on{};
  for (int k = 0; k < key_count; ++k) {
    const auto rel = released_at_[std::size_t(k)];
    // a release counts once the auto-repeat grace has passed without a new press
    on[std::size_t(k)] = held_[std::size_t(k)] && (rel == Clock::time_point{} || now - rel < kRepeatGrace);
  }
  StickState s;
  s.present = true;
  s.num_axes = 2;
  s.axes[0] = double(on[right]) - double(on[left]);
  s.axes[1] = double(on[down]) - double(on[up]);
  s.buttons = (on[away] ? 1u : 0u) | (on[toward] ? 2u : 0u);
  return s;
}

void KeyboardStick::clear() {
  std::lock_guard lock(mutex_);
  held_.fill(false);
  released_at_.fill({});
  drag_.setZero();
}

}  // namespace vx::probe
