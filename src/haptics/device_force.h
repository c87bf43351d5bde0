#pragma once
/// @file device_force.h
/// The force a haptic device plays (docs/model.md section 9, paper 4.3, fig. 10).
///
/// The raw force on a probe (the momentum change of the nodes it hit, per step) jitters from
/// step to step, and a device can only change its force slowly. So the device force is updated
/// at a longer interval T than the physics step dt: at each update instant the mean of the last
/// few raw forces is taken, and until the next update the device plays one positive half of a
/// sine wave of that mean:
///
///     shaped(t) = s * F_k * sin(pi (t - t_k) / T),   t_k <= t < t_k + T,
///
/// which is zero at every update instant, so switching causes no jolt. With `mean_preserving`
/// (the default) s = pi/2, so the half sine's mean over its interval is F_k and the shaped
/// force's mean follows the raw mean; otherwise s = 1 (the peak is F_k).
/// T is rounded to a whole number of physics steps, so update instants fall on steps.
///
/// Units: N, s.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

namespace vx {

/// How the probe app makes the device force (docs/probe.md, "Force shaping").
enum class ForceShaping : std::uint8_t {
  paper,  ///< the half sines below, evaluated at the device's clock (the paper's 4.3)
  local,  ///< the local contact model at every device tick (local_contact.h)
};
[[nodiscard]] const char* to_string(ForceShaping s);
/// Parses "paper" or "local"; throws vx::Error otherwise.
[[nodiscard]] ForceShaping parse_force_shaping(const std::string& s);

/// How a device force is made from the raw force.
struct DeviceForceSettings {
  double update_interval_s{0.02};  ///< T: time between device updates (the paper's slow update), s
  int average_steps{0};            ///< raw forces averaged per update; 0 = every step since the last update
  bool mean_preserving{true};      ///< half-sine peak pi/2 x the mean (mean kept); false: peak = mean
  /// The probe app's shaping. The simulation itself always computes the half sines for a
  /// device; `local` also needs the simulation's local contact models (the app asks for them).
  ForceShaping shaping{ForceShaping::paper};
  /// local: the physical damping of the device that sizes the virtual coupling (Colgate's
  /// condition, HapticCouplingSettings in local_contact.h), N s/mm.
  double device_damping_n_s_mm{1.5e-3};

  /// Empty when valid, else what is wrong.
  [[nodiscard]] std::string validate() const;
};

/// One update of the device: a half sine of amplitude `peak_n` starting at `start_s` and
/// lasting `duration_s`. A device thread running faster than the physics can evaluate it at
/// its own clock.
struct HalfSinePulse {
  Eigen::Vector3d peak_n{Eigen::Vector3d::Zero()};  ///< peak force (s * F_k), N
  Eigen::Vector3d mean_n{Eigen::Vector3d::Zero()};  ///< F_k: the averaged raw force, N
  double start_s{0.0};                              ///< update instant t_k, s
  double duration_s{0.0};                           ///< T, s

  /// The shaped force at time t (zero outside [start, start + duration)).
  [[nodiscard]] Eigen::Vector3d at(double t_s) const;
};

/// Turns a stream of raw forces (one per physics step) into the shaped device force.
/// No allocation after init().
class DeviceForceShaper {
 public:
  /// Throws vx::Error for invalid settings or dt.
  void init(const DeviceForceSettings& settings, double dt_s);
  /// Forgets all forces (time restarts at 0).
  void reset();

  /// Feeds the raw force of the step that ended at time `t_s` = steps * dt and returns the
  /// shaped force at that time. Every `steps_per_update()` steps an update happens first.
  const Eigen::Vector3d& push(const Eigen::Vector3d& raw_n, double t_s);

  [[nodiscard]] const Eigen::Vector3d& shaped() const { return shaped_; }  ///< latest shaped force, N
  [[nodiscard]] const HalfSinePulse& pulse() const { return pulse_; }      ///< the pulse being played
  [[nodiscard]] int steps_per_update() const { return steps_per_update_; }
  [[nodiscard]] int window_steps() const { return window_; }
  [[nodiscard]] std::int64_t updates() const { return updates_; }  ///< device updates so far
  [[nodiscard]] double scale() const { return scale_; }            ///< s: peak / mean

 private:
  DeviceForceSettings settings_;
  double dt_{0.0};
  int steps_per_update_{1};
  int window_{1};
  double scale_{1.0};
  std::vector<Eigen::Vector3d> ring_;  ///< the last `window_` raw forces
  int ring_next_{0};
  int ring_filled_{0};
  std::int64_t step_{0};         ///< steps pushed
  std::int64_t update_step_{0};  ///< step of the current pulse's start
  std::int64_t updates_{0};
  HalfSinePulse pulse_;
  Eigen::Vector3d shaped_{Eigen::Vector3d::Zero()};
};

}  // namespace vx
