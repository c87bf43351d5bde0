#pragma once
/// @file force_guard.h
/// What stands between the force the app computes and the hand: the device force clamped to the
/// device's rated maximum, ramped up from zero over `ramp_up_s` after the start, a reset or a
/// reconnect, and faded to zero over `fade_s` (held in direction, never a jump) when the physics
/// fails or is reset, then ramped up again. A non-finite force is a fault too. No SDL: a tick in,
/// a force out (tests/apps/probe_force_guard_test.cpp). Forces in N, times in s.

#include <Eigen/Core>

#include <cstdint>
#include <string>

namespace vx::probe {

/// The guard's limits.
struct ForceGuardSettings {
  double max_force_N{2.0};  ///< the device's rated maximum (--max-force): no force beyond it
  double ramp_up_s{0.1};    ///< zero to full over this after a start, a reset or a reconnect
  double fade_s{0.04};      ///< the last force to zero over this after a fault (<= 50 ms)
  /// Empty when usable, else what is wrong.
  [[nodiscard]] std::string validate() const;
};

/// One device's guard (one per probe); the device thread calls it at every tick.
class DeviceForceGuard {
 public:
  enum class Phase : std::uint8_t { rising, on, fading, off };

  explicit DeviceForceGuard(ForceGuardSettings settings = {});

  /// The force to send this tick for `wanted_N` (the shaped force), `dt_s` after the last tick
  /// (0 on the first). Clamped to max_force_N, scaled by the ramp; while fading, the force held
  /// at the fault, scaled down to zero.
  [[nodiscard]] Eigen::Vector3d apply(const Eigen::Vector3d& wanted_N, double dt_s);
  /// From zero again, ramping up (a start, a reconnect): the force drops to zero at once, so use
  /// it only when the device played nothing (a reconnected device) or from the fade.
  void restart();
  /// The physics failed or was reset: the last force played fades to zero over fade_s, then
  /// the ramp up starts again. A fault during the fade keeps the fade going.
  void interrupt();
  /// The device was unplugged: the force fades as after a fault and stays at zero until
  /// restart() (it was plugged back).
  void disconnect();

  [[nodiscard]] Phase phase() const { return phase_; }
  /// The ramp's factor now, 0..1 (fading: the fraction of the held force still played).
  [[nodiscard]] double gain() const { return gain_; }
  /// Ticks whose wanted force was above max_force_N (clamped).
  [[nodiscard]] std::int64_t clamped_ticks() const { return clamped_; }
  /// Non-finite forces refused (each started a fade).
  [[nodiscard]] std::int64_t non_finite() const { return non_finite_; }
  /// Fades started (faults, resets, non-finite forces).
  [[nodiscard]] std::int64_t interrupts() const { return interrupts_; }
  [[nodiscard]] const ForceGuardSettings& settings() const { return settings_; }

 private:
  ForceGuardSettings settings_;
  Phase phase_{Phase::rising};
  double gain_{0.0};
  bool stay_off_{false};                             ///< disconnected: off after the fade
  Eigen::Vector3d last_N_{Eigen::Vector3d::Zero()};  ///< the force played at the last tick
  Eigen::Vector3d held_N_{Eigen::Vector3d::Zero()};  ///< fading: the force played at the fault
  std::int64_t clamped_{0};
  std::int64_t non_finite_{0};
  std::int64_t interrupts_{0};
};

}  // namespace vx::probe
