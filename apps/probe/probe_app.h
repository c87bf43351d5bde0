#pragma once
/// @file probe_app.h
/// The palpation app: three rates, never waiting on each other.
///
/// - physics thread (fixed tick, default 1 kHz): advances the simulation to the wall clock in
///   whole steps with a step budget per tick; when it cannot keep up it drops the lag (paper
///   shaping: the app runs in slow motion, reported on the HUD and at the end), never bursting;
/// - device thread (fixed tick, default 1 kHz): reads the joysticks (or plays the script into
///   the virtual joysticks), computes the device force and writes it to the force outputs.
///   Two shapings (docs/probe.md, "Force shaping"):
///   - paper: the script runs in simulated time; the stick commands go to the simulation's live
///     probes; the force is the paper's half sine at the device's clock;
///   - local: the device thread owns the tool: it moves the device (hand) position with the
///     stick in wall time, evaluates the local contact model the physics last published
///     (sim/local_contact.h: virtual coupling, damping, re-anchoring, energy guard) at every
///     tick, and hands the tool (proxy) position to the physics, which moves the simulated tool
///     there over its next update and publishes a new model. The physics may run at 30-60 Hz
///     (--physics-rate) or slower than real time: the tool and the force stay real time;
/// - GUI thread (display rate): window events, the deformed surface (frames requested from the
///   physics and taken when ready, never waited for), HUD, force plot, screenshots.

#include <filesystem>
#include <optional>
#include <string>

#include "probe_scene.h"
#include "sim/device_force.h"
#include "util/exit_codes.h"
#include "stick_control.h"

namespace vx::probe {

/// Exit codes besides 0, from the table both programs share (util/exit_codes.h; usage errors
/// are 2, internal errors 3).
inline constexpr int kExitError = vx::exit_code::error;            ///< bad input, or a failure while running
inline constexpr int kExitNoDisplay = vx::exit_code::no_display;  ///< no X display (run under xvfb-run or use --headless)

/// Which device backend to use.
enum class DeviceChoice : std::uint8_t { automatic, haptic, rumble, none };
[[nodiscard]] DeviceChoice parse_device_choice(const std::string& s);

/// Everything the command line sets.
struct AppOptions {
  std::filesystem::path input;                  ///< scene, volume or model
  DefaultSceneOptions scene;                    ///< for volumes and models
  std::filesystem::path joystick_script;        ///< empty: physical joysticks / keyboard
  bool exit_after_script{false};                ///< quit when the script has ended
  bool use_joysticks{true};                     ///< false: keyboard and mouse only
  std::int64_t frames{0};                       ///< > 0: quit after this many frames
  double duration_s{0.0};                       ///< > 0: quit at this simulated time
  std::filesystem::path screenshot;             ///< written from the last frame
  std::filesystem::path force_log;              ///< CSV from the recording backend
  DeviceChoice device{DeviceChoice::automatic};
  double max_force_N{2.0};                      ///< device full scale
  double device_update_hz{100.0};               ///< haptic/rumble commands per second at most
  /// The device force: the scene's device block decides unless set (else paper).
  std::optional<ForceShaping> force_shaping;
  ControlSettings control;
  /// Which fields of `control.mapping` the command line set; the others come from the scene's
  /// live probe (its mode, speed_mm_s, range_mm, dead_zone) or the defaults.
  bool mode_set{false}, speed_set{false}, range_set{false}, deadzone_set{false};
  /// The displayed surface for scene files: iso (smoothed) or paper.
  SurfaceMethod surface_method{SurfaceMethod::iso};
  double physics_hz{1000.0};                    ///< physics thread tick
  double device_hz{1000.0};                     ///< device thread tick
  double fps{60.0};                             ///< display frame limit
  int threads{1};                               ///< physics threads (0: all cores)
  int width{1280};
  int height{800};
  bool headless{false};                         ///< no window (needs --duration or --exit-after-script)
  bool show_levels{false};                      ///< start with the element levels view
  bool quiet{false};
  /// Test hooks (hidden options): extra wall time per physics step, and on the first step only
  /// (a slow start-up), s. The figures the app reports must show them.
  double test_step_delay_s{0.0};
  double test_startup_delay_s{0.0};
};

/// Runs the app; returns the exit code. Throws vx::Error for bad input found before the run.
[[nodiscard]] int run_probe_app(const AppOptions& options);

}  // namespace vx::probe
