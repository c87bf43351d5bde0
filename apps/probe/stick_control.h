#pragma once
/// @file stick_control.h
/// From a stick (or the keyboard) to a probe's motion: the paper's rate control (the probe
/// moves with a velocity proportional to the tilt, paper 4.2) and a position-control option
/// (the tilt sets the offset from a home point). As in the paper, tilting the stick moves the
/// probe in the screen plane: commands are in the view frame (x = right on screen, y = up,
/// z = away from the user, into the screen), and the view basis turns them into world
/// (LPS mm) motion. The device force goes back through the same basis, so the force that
/// resists pressing the probe down pushes the stick forward.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>

#include "base/pi_mutex.h"
#include "sdl_input.h"
#include "sim/probe.h"

namespace vx::probe {

/// Settings of the stick-to-probe mapping.
struct ControlSettings {
  /// The mapping a scene's probe has too (sim/probe.h), with the app's defaults:
  /// - mode: rate (velocity proportional to tilt, the paper) or position (tilt sets the offset
  ///   from the home point, moved there at a bounded speed);
  /// - max_speed_mm_s: rate control's speed at full tilt; also the top speed in position mode;
  /// - range_mm: position control's offset at full tilt;
  /// - dead_zone: tilt below this counts as 0 (stick centre noise).
  /// Its `directions` are not used here: the view basis turns the stick into world motion.
  JoystickMapping mapping{JoystickMode::rate, Eigen::Matrix3d::Identity(), 25.0, 30.0, 0.08};
  int z_axis{-1};             ///< axis for the third (depth) motion, e.g. 2 = twist, 3 = throttle; -1: buttons/hat only
  bool invert_z_axis{false};  ///< flip the sign of z_axis
  int z_away_button{0};       ///< button that moves the probe away from the user (into the screen)
  int z_toward_button{1};     ///< button that moves it towards the user
};

/// The command of one stick in the view frame, each component in [-1, 1]:
/// x = right (axis 0), y = up (minus axis 1: stick pushed forward = up), z = away from the user
/// (z_axis plus buttons z_away/z_toward and hat up/down).
[[nodiscard]] Eigen::Vector3d stick_command(const StickState& stick, const ControlSettings& settings);

/// An axis-aligned box, LPS mm.
struct Box {
  Eigen::Vector3d lo{0, 0, 0};
  Eigen::Vector3d hi{0, 0, 0};
  [[nodiscard]] Eigen::Vector3d clamp(const Eigen::Vector3d& p) const { return p.cwiseMax(lo).cwiseMin(hi); }
  [[nodiscard]] Eigen::Vector3d center() const { return 0.5 * (lo + hi); }
  [[nodiscard]] bool valid() const { return (hi.array() >= lo.array()).all(); }
};

/// Turns one probe's stick commands into live commands for the simulation (vx::LiveCommand),
/// on the device thread. Rate control sends a velocity, which the physics integrates in
/// simulated time (the paper); position control sends a target around the home point, which
/// the physics approaches at the probe's speed limit. Mouse drags are added as an offset that
/// is worked off at a bounded speed. The probe is kept inside `allowed`: a velocity that would
/// carry it out is cut at the boundary, a target is clamped to the box.
class ProbeCommander {
 public:
  ProbeCommander() = default;
  /// `home_mm`: the probe's start (the position-control centre); `allowed`: where its reference
  /// point may go.
  ProbeCommander(const Eigen::Vector3d& home_mm, const Box& allowed, const ControlSettings& settings);

  /// Back to the start: no pending drag, depth offset 0.
  void reset();
  /// The command for this tick. `command`: view frame (stick_command); `drag_view_mm`: new
  /// mouse drag in the view frame; `view_basis`: columns right, up, away (world);
  /// `probe_mm`: the probe's current position; `dt_s`: the device tick.
  [[nodiscard]] LiveCommand update(const Eigen::Vector3d& command, const Eigen::Vector3d& drag_view_mm,
                                   const Eigen::Matrix3d& view_basis, const Eigen::Vector3d& probe_mm, double dt_s);

  [[nodiscard]] const Eigen::Vector3d& home_mm() const { return home_; }
  [[nodiscard]] const Box& allowed() const { return allowed_; }
  [[nodiscard]] const ControlSettings& settings() const { return settings_; }

 private:
  Eigen::Vector3d home_{0, 0, 0};
  Box allowed_;
  ControlSettings settings_;
  Eigen::Vector3d pending_drag_{0, 0, 0};  ///< world mm still to move (rate control)
  Eigen::Vector3d drag_offset_{0, 0, 0};   ///< world mm added to the target (position control)
  double depth_mm_{0.0};                   ///< position control with depth buttons: offset along "away"
};

/// The keyboard as a stick, for when no joystick is connected: keys held give full tilt.
/// Filled from the GUI thread (key events), read from the device thread. X11 auto-repeat
/// sends release+press pairs; a release followed by a press within a short grace is ignored.
class KeyboardStick {
 public:
  enum Key : int { left, right, up, down, away, toward, key_count };
  /// Key `k` went down / up now.
  void press(Key k);
  void release(Key k);
  /// Mouse drag: a displacement in the view frame (x right, y up, z away), mm, added to a
  /// pending offset that the physics thread consumes.
  void add_drag(const Eigen::Vector3d& view_offset_mm);
  /// Takes the pending drag offset (and clears it).
  [[nodiscard]] Eigen::Vector3d take_drag();
  /// Which probe the keyboard and mouse drive (0 or 1).
  void set_active_probe(int p);
  [[nodiscard]] int active_probe() const;
  /// The keys as a stick: axis 0 = left/right, axis 1 = up/down (SDL sign: +1 = down),
  /// button 0 = away, button 1 = towards the user.
  [[nodiscard]] StickState state() const;
  /// Forget all keys (focus lost).
  void clear();

 private:
  using Clock = std::chrono::steady_clock;
  mutable PiMutex mutex_;
  std::array<bool, key_count> held_{};
  std::array<Clock::time_point, key_count> released_at_{};
  Eigen::Vector3d drag_{0, 0, 0};
  int active_probe_{0};
};

}  // namespace vx::probe
