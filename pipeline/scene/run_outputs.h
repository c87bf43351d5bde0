#pragma once
/// @file run_outputs.h
/// What a headless run of a scene (`voxelastic simulate`) records and writes into its output
/// folder: forces.csv and forces.png (a ForceRecorder), .pvd series of the deformed model,
/// surface and probes (sim_output.h), each only when the scene's `outputs` ask for it, and
/// summary.json, the run's figures. Every file is written atomically.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "haptics/device_side.h"
#include "scene/scene.h"
#include "scene/sim_output.h"
#include "sim/simulation.h"

namespace vx {

/// Records a run: construct it before the first step, call after_step() after every step and
/// finish() after the last.
class RunOutputs {
 public:
  /// What `outputs` asks for, into `dir` (which exists); the .pvd series get their first
  /// frame now. `steps`: the steps the run will take (the last one always gets a frame).
  /// `device`: the run's device side (its device forces; it must outlive the RunOutputs).
  RunOutputs(Simulation& sim, const DeviceSide& device, const PreparedScene& prepared, const SceneOutputs& outputs,
             const std::filesystem::path& dir, std::int64_t steps);
  ~RunOutputs();
  RunOutputs(const RunOutputs&) = delete;
  RunOutputs& operator=(const RunOutputs&) = delete;

  /// After step `k` (1-based): a force sample, and a frame every pvd_interval_s (the simulation
  /// is not const: its surface is brought up to date for a frame).
  void after_step(Simulation& sim, std::int64_t k);
  /// A frame of every series at the simulation's time, unless the last one is there already (a
  /// run stopped early ends its series where it stopped).
  void last_frame(Simulation& sim);
  /// After the last step (or a failed one): the last force row, then forces.csv, forces.png
  /// and the .pvd collections that were asked for. Throws vx::Error when a file cannot be written.
  void finish(const Simulation& sim);

  /// Analytic force-depth curves drawn in forces.png with the presses (scene_force_references()).
  void set_force_references(std::vector<ForceReference> references) { references_ = std::move(references); }

  /// The force recorder (null when neither forces.csv nor the plot was asked for).
  [[nodiscard]] const ForceRecorder* forces() const { return recorder_ ? &*recorder_ : nullptr; }
  /// Frames written per series (0 without .pvd output); true when any series was asked for.
  [[nodiscard]] std::int64_t frames() const { return frames_; }
  [[nodiscard]] bool series() const { return series_; }
  [[nodiscard]] const DeviceSide& device() const { return device_; }
  /// The files finish() wrote, and those the scene did not ask for.
  [[nodiscard]] const std::vector<std::string>& written() const { return written_; }
  [[nodiscard]] const std::vector<std::string>& not_requested() const { return not_requested_; }

 private:
  void write_frame(Simulation& sim);

  const DeviceSide& device_;
  std::filesystem::path dir_;
  SceneOutputs outputs_;
  std::int64_t steps_{0};
  std::int64_t frame_every_{1};
  bool series_{false};
  std::int64_t frames_{0};
  double last_frame_s_{-1.0};
  std::optional<ForceRecorder> recorder_;
  std::optional<PvdSeries> model_series_, surface_series_, probe_series_;
  std::unique_ptr<ModelFrameWriter> model_writer_;
  std::unique_ptr<SurfaceFrameWriter> surface_writer_;
  std::vector<std::string> written_, not_requested_;
  std::vector<ForceReference> references_;
};

/// The analytic force-depth curves a scene has: finite-layer Hertz (hertz_bonded_layer_n) when
/// its one probe is a sphere driven along a straight path perpendicular to a face of a
/// homogeneous 3D box, starting outside it, the opposite face fixed and nothing else; no
/// gravity; the ball's centre at least a radius inside the face's edges. None otherwise.
[[nodiscard]] std::vector<ForceReference> scene_force_references(const Scene& scene);

/// summary.json of a finished run: the scene (`scene_file`), the run (steps, times, stability,
/// status), the object and material, each probe, the walls, the device, the work done and
/// skipped, the warnings and the files written (`outputs`' list plus summary.json itself).
[[nodiscard]] nlohmann::json run_summary_json(const Scene& scene, const std::filesystem::path& scene_file,
                                              const PreparedScene& prepared, const Simulation& sim,
                                              const RunOutputs& outputs, double wall_s);

}  // namespace vx
