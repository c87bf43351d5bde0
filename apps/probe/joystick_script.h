#pragma once
/// @file joystick_script.h
/// A script of joystick axis values over time, played into SDL virtual joysticks
/// (`--virtual-joystick SCRIPT`) so that palpation runs are reproducible and run in CI.
///
/// Text format, one keyframe per line, `#` starts a comment:
///
///     sticks 1                      # optional: number of virtual joysticks (1 or 2)
///     # t_s  stick  a0    a1    a2   [a3]  [bBITS]
///     0.0    0      0.0   0.0   0.0
///     1.5    0      0.5   0.0  -1.0  0.0   b0100
///
/// - `t_s`: time in seconds of simulated time, non-decreasing per stick, at most
///   kMaxScriptTime_s;
/// - `stick`: 0 or 1 (which virtual joystick, i.e. which probe);
/// - `a0..a3`: axis values in [-1, 1] (missing axes are 0); a0 = x (right), a1 = y (SDL
///   convention: +1 = pulled back towards the user), a2 = twist, a3 = throttle;
/// - `bBITS`: optional button states, button 0 first (`b01` = button 1 held).
/// Axis values are interpolated linearly between a stick's keyframes; buttons hold the value
/// of the last keyframe at or before t. Before the first keyframe the first values hold,
/// after the last the last values hold.

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace vx::probe {

/// Axes per virtual joystick (x, y, twist, throttle).
inline constexpr int kScriptAxes = 4;
/// Buttons per virtual joystick.
inline constexpr int kScriptButtons = 8;
/// The latest keyframe time a script may have, s (as scenes: a longer run would never end).
inline constexpr double kMaxScriptTime_s = 1e5;
/// Most joysticks (probes) the app drives.
inline constexpr int kMaxSticks = 2;

/// One keyframe of one stick.
struct ScriptKey {
  double t_s{0.0};                          ///< simulated time, s
  std::array<double, kScriptAxes> axes{};   ///< axis values in [-1, 1]
  std::uint32_t buttons{0};                 ///< bit b = button b held
};

/// The value of one stick at one time.
struct ScriptSample {
  std::array<double, kScriptAxes> axes{};
  std::uint32_t buttons{0};
};

/// A parsed joystick script.
class JoystickScript {
 public:
  /// Parses `text`; throws vx::Error naming `source` and the line for any bad line.
  [[nodiscard]] static JoystickScript parse(std::string_view text, const std::string& source = "script");
  /// Reads and parses a file; throws vx::Error when it cannot be read or parsed.
  [[nodiscard]] static JoystickScript load(const std::filesystem::path& path);

  /// Number of virtual joysticks the script drives (1 or 2).
  [[nodiscard]] int sticks() const { return sticks_; }
  /// Time of the last keyframe over all sticks, s.
  [[nodiscard]] double duration_s() const;
  /// Keyframes of one stick, in time order.
  [[nodiscard]] const std::vector<ScriptKey>& keys(int stick) const { return keys_[std::size_t(stick)]; }
  /// The stick's axes and buttons at time t_s (see the file comment for the rules).
  [[nodiscard]] ScriptSample sample(int stick, double t_s) const;

 private:
  int sticks_{1};
  std::array<std::vector<ScriptKey>, kMaxSticks> keys_;
};

}  // namespace vx::probe
