#pragma once
/// @file app_options.h
/// What the palpation app's command line sets (AppOptions), read by every loop (app_shared.h),
/// and the app's exit codes.

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "haptics/device_force.h"
#include "probe_scene.h"
#include "stick_control.h"
#include "util/exit_codes.h"

namespace vx::probe {

/// Exit codes besides 0, from the table both programs share (util/exit_codes.h; usage errors
/// are 2, internal errors 3).
inline constexpr int kExitError = vx::exit_code::error;  ///< bad input, or a failure while running
inline constexpr int kExitNoDisplay =
    vx::exit_code::no_display;  ///< no X display (run under xvfb-run or use --headless)

/// Which device backend to use.
enum class DeviceChoice : std::uint8_t { automatic, haptic, rumble, none };
[[nodiscard]] DeviceChoice parse_device_choice(const std::string& s);

/// A fault injected into the physics on purpose (--test-fault KIND@STEP; tests): at the start of
/// step `step` the tissue gets a NaN (non_finite), a node thrown at 1e7 mm/s so the step runs
/// away as a diverging solve does (runaway), or the step throws (exception).
struct InjectedFault {
  enum class Kind : std::uint8_t { non_finite, runaway, exception };
  Kind kind{Kind::non_finite};
  std::int64_t step{0};
};
/// Parses "nan@120", "runaway@300", "throw@40"; throws vx::Error for anything else.
[[nodiscard]] InjectedFault parse_injected_fault(const std::string& s);

/// Everything the command line sets.
struct AppOptions {
  std::filesystem::path input;            ///< scene, volume or model
  DefaultSceneOptions scene;              ///< for volumes and models
  std::filesystem::path joystick_script;  ///< empty: physical joysticks / keyboard
  bool exit_after_script{false};          ///< quit when the script has ended
  bool use_joysticks{true};               ///< false: keyboard and mouse only
  std::int64_t frames{0};                 ///< > 0: quit after this many frames
  double duration_s{0.0};                 ///< > 0: quit at this simulated time
  std::filesystem::path screenshot;       ///< written from the last frame
  std::filesystem::path force_log;        ///< CSV from the recording backend
  DeviceChoice device{DeviceChoice::automatic};
  double max_force_N{2.0};         ///< device full scale
  double device_update_hz{100.0};  ///< haptic/rumble commands per second at most
  /// The device force: the scene's device block decides unless set (else paper).
  std::optional<ForceShaping> force_shaping;
  ControlSettings control;
  /// Which fields of `control.mapping` the command line set; the others come from the scene's
  /// live probe (its mode, speed_mm_s, range_mm, dead_zone) or the defaults.
  bool mode_set{false}, speed_set{false}, range_set{false}, deadzone_set{false};
  /// The displayed surface for scene files: iso (smoothed) or paper.
  SurfaceMethod surface_method{SurfaceMethod::iso};
  double physics_hz{1000.0};  ///< physics thread tick
  double device_hz{1000.0};   ///< device thread tick
  double fps{60.0};           ///< display frame limit
  int threads{0};             ///< physics threads (0, the default: all cores; docs/probe.md)
  bool share_cores{true};     ///< one physics thread while well ahead of real time or as fast (thread_share.h)
  bool background_factor{
      true};                 ///< the solver factored while the tissue rests (IntegratorSettings::factor_in_background)
  std::string factor_cache;  ///< implicit factors kept by content: "" the default folder, "off", or a folder
  int width{1280};
  int height{800};
  bool headless{false};     ///< no window (needs --duration or --exit-after-script)
  bool show_levels{false};  ///< start with the element levels view
  bool quiet{false};
  /// Test hooks (hidden options): extra wall time per physics step, and on the first step only
  /// (a slow start-up), s. The figures the app reports must show them.
  double test_step_delay_s{0.0};
  double test_startup_delay_s{0.0};
  /// Test hook (hidden option): extra wall time per frame drawn in the display's turn (a slow
  /// renderer while the tissue is behind real time; AppControls::display_turn), s.
  double test_frame_delay_s{0.0};
  /// Test hook (hidden option): extra wall time on building a solver in the background (a large
  /// model's factorisation; IntegratorSettings::factor_in_background_delay_s), s.
  double test_factor_delay_s{0.0};
  /// Test hooks: faults injected into the physics (each once), and the virtual stick 0 unplugged
  /// and plugged back at these device times (s; negative: never).
  std::vector<InjectedFault> test_faults;
  /// Soak (> 0): a random script of this many seconds (soak.h), seeded; the run judged at the end.
  double soak_s{0.0};
  std::uint32_t soak_seed{1};
  double test_unplug_s{-1.0};
  double test_replug_s{-1.0};
  /// Test hook: the contact solve's cache fills as the tool goes (IntegratorSettings::
  /// reserve_contact_cache off), to measure what reserving it changes.
  bool lazy_contact_cache{false};
  /// Test hook: IntegratorSettings::region_rest_fraction (< 0: its default; 0: a tissue falls
  /// asleep by speed alone, as before), to measure the rest criterion.
  double test_rest_fraction{-1.0};
};

}  // namespace vx::probe
