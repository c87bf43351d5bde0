#pragma once
/// @file haptic_accuracy.h
/// How well the local contact model (haptics/local_contact.h) carries the force at 1 kHz when the
/// physics updates at a lower rate (`voxelastic bench --haptic`, docs/probe.md "Force shaping").
///
/// The palpation demo's tissue (samples/scenes/palpation-lesion.json: a 36 x 28 x 16 mm block of
/// 10 kPa with an 80 kPa lesion) is pressed and slid across by its capsule tool along a scripted
/// path. The reference is the full-rate simulation: the implicit integrator at its small step
/// (1 ms, 10 local/global iterations), the tool on the path, the force at every 1 ms device tick.
/// Physics at a rate R (1000, 200, 60, 30 Hz):
///   - `chunks`: the same small steps, run in updates of 1/R s: the model of an update reaches
///     the device one update later (the physics thread takes the period to compute it);
///   - `large steps`: one implicit step of 1/R s per update (the physics made cheaper, its
///     own factor giving the compliance), also one update late.
/// The device evaluates, at every 1 ms tick and the tool's position on the path, the local model
/// it last received (no coupling or damping: the force of the model itself, with its fading
/// offset at each new model), and, for comparison, the last physics force held (what a device
/// thread without a model plays) and the paper's half sines (20 ms, from the full-rate physics).
/// Errors are |F - F_ref| (vectors), RMS over the run and peak, as fractions of the reference's
/// peak force.
///
/// Units: mm, s, N.

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace vx {

struct HapticAccuracySettings {
  std::filesystem::path scene;                ///< the palpation scene (samples/scenes/palpation-lesion.json)
  std::vector<double> physics_hz{1000.0, 200.0, 60.0, 30.0};
  double device_hz{1000.0};
  double reference_dt_s{1e-3};                ///< the reference's implicit step
  int iterations{10};                         ///< local/global iterations per implicit step
  double press_mm_s{8.0};                     ///< the tool's speed down into the tissue
  double slide_mm_s{10.0};                    ///< and across it
  double depth_mm{3.0};
  double slide_mm{29.0};                      ///< from x = -15 mm over the lesion (x = +5.4 mm)
  bool large_steps{true};                     ///< also the large-step physics
  double compliance_scale{0.0};               ///< LocalContactSettings::compliance_scale (0: its default)
  std::function<void(const std::string&)> log;
};

/// One way of making the device force at one physics rate.
struct HapticAccuracyRow {
  std::string method;      ///< "local (chunks)", "local (large steps)", "held (chunks)", "paper"
  double physics_hz{0.0};
  double rms{0.0};         ///< RMS |F - F_ref| / peak |F_ref|
  double peak{0.0};        ///< max |F - F_ref| / peak |F_ref|
  double max_step{0.0};    ///< largest tick-to-tick change / peak |F_ref|
};

struct HapticAccuracyCurve {
  std::string title;
  std::vector<double> t_s, force_n;  ///< |F| at every device tick
};

struct HapticAccuracyResult {
  double peak_force_n{0.0};
  double duration_s{0.0};
  int elements{0};
  std::vector<HapticAccuracyRow> rows;
  std::vector<HapticAccuracyCurve> curves;  ///< the reference first
  double wall_s{0.0};
};

/// Runs it. Throws vx::Error for a missing scene.
[[nodiscard]] HapticAccuracyResult run_haptic_accuracy(const HapticAccuracySettings& settings);

/// The table (markdown) and the curves (PNG: force against time; error against physics rate).
[[nodiscard]] std::string haptic_accuracy_table(const HapticAccuracyResult& result);
void plot_haptic_accuracy(const HapticAccuracyResult& result, const std::filesystem::path& png);

}  // namespace vx
