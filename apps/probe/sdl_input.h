#pragma once
/// @file sdl_input.h
/// Joystick input through SDL2, without SDL video (VTK owns the window): up to two physical
/// joysticks, or up to two SDL virtual joysticks fed by a JoystickScript.
///
/// Threading: construct on one thread; afterwards every call except the const accessors of
/// the construction-time facts (count, name, ...) must come from one thread (the device thread).

#include <SDL.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "joystick_script.h"

namespace vx::probe {

/// Most axes read per stick.
inline constexpr int kStickAxes = 6;

/// The state of one stick; axes normalised to [-1, 1] (SDL convention: y = +1 pulled back).
struct StickState {
  bool present{false};                     ///< false when no stick / disconnected
  std::array<double, kStickAxes> axes{};   ///< axis values, [-1, 1]
  int num_axes{0};
  std::uint32_t buttons{0};                ///< bit b = button b held
  std::uint8_t hat{0};                     ///< SDL_HAT_* bits of hat 0
};

/// What the virtual joystick's Rumble callback received (the test sink for force output).
struct VirtualRumble {
  std::atomic<int> calls{0};
  std::atomic<std::uint16_t> low{0};
  std::atomic<std::uint16_t> high{0};
};

/// What to open.
struct InputSettings {
  bool joysticks{true};                       ///< false: do not open physical joysticks
  std::shared_ptr<const JoystickScript> script;  ///< given: attach virtual joysticks fed by it
  int max_sticks{kMaxSticks};                 ///< 1 or 2
};

/// SDL's joystick and haptic subsystems and the open joysticks.
class SdlInput {
 public:
  /// Initialises SDL (joystick, haptic) and opens the sticks: with a script, one virtual
  /// joystick per scripted stick (physical joysticks are then ignored); otherwise the first
  /// `max_sticks` physical joysticks (none is fine: the app falls back to the keyboard).
  /// Without SDL joystick support there are no sticks (a message says why); without haptic
  /// support the sticks open without force feedback. Throws vx::Error when a script was given
  /// and SDL joysticks are unavailable, or a virtual joystick cannot be attached.
  explicit SdlInput(const InputSettings& settings);
  ~SdlInput();
  SdlInput(const SdlInput&) = delete;
  SdlInput& operator=(const SdlInput&) = delete;

  /// Number of open sticks (0..2).
  [[nodiscard]] int count() const { return int(sticks_.size()); }
  [[nodiscard]] const std::string& name(int i) const { return sticks_[std::size_t(i)].name; }
  [[nodiscard]] bool is_virtual(int i) const { return sticks_[std::size_t(i)].is_virtual; }
  /// The SDL joystick (for haptics and rumble); nullptr after a disconnect.
  [[nodiscard]] SDL_Joystick* joystick(int i) const { return sticks_[std::size_t(i)].js; }
  /// What the Rumble callback of virtual stick i received (nullptr for a physical stick).
  [[nodiscard]] const VirtualRumble* virtual_rumble(int i) const;
  /// One line per stick for the console.
  [[nodiscard]] std::string describe() const;

  /// Sets the virtual sticks' axes and buttons to the script's values at t_s (no-op without script).
  void play_script(double t_s);
  /// Pumps SDL (applies the virtual values, notices disconnects) and reads every stick.
  void poll();
  /// State of stick i as of the last poll().
  [[nodiscard]] const StickState& state(int i) const { return sticks_[std::size_t(i)].state; }
  /// Messages about disconnects and reconnects since the last call (for the console and HUD).
  [[nodiscard]] std::vector<std::string> take_messages();
  /// Times stick i was unplugged or plugged back (the device loop re-binds its force output and
  /// ramps its force up again when this changes). A stick plugged back takes its old place: the
  /// first place left empty by a stick of its kind (physical or virtual), in SDL's order.
  [[nodiscard]] int connection_changes(int i) const { return sticks_[std::size_t(i)].changes; }
  /// Test hooks: virtual stick i detached from SDL (as if unplugged: SDL_JOYDEVICEREMOVED) and
  /// attached again (SDL_JOYDEVICEADDED); the next poll() notices, as for a physical stick.
  void unplug_virtual(int i);
  void replug_virtual(int i);

 private:
  struct Stick {
    SDL_Joystick* js{nullptr};
    SDL_JoystickID id{-1};
    int device_index{-1};
    bool is_virtual{false};
    std::string name;
    StickState state;
    std::unique_ptr<VirtualRumble> rumble;
    int changes{0};
  };
  /// Attaches a virtual joystick for `stick` (its name and rumble sink); returns the device
  /// index or throws vx::Error.
  static int attach_virtual(Stick& stick);
  /// Opens the devices SDL announced (SDL_JOYDEVICEADDED) into empty places.
  void take_added(const std::vector<int>& device_indices);
  std::vector<Stick> sticks_;
  std::vector<int> virtual_device_indices_;
  std::shared_ptr<const JoystickScript> script_;
  std::vector<std::string> messages_;
  Uint32 subsystems_{0};  ///< SDL subsystems initialised (joystick, haptic)
};

}  // namespace vx::probe
