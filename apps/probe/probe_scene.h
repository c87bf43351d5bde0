#pragma once
/// @file probe_scene.h
/// What the probe app runs: a physics model, its deforming surface and the simulation
/// settings, from a scene file (pipeline/scene/scene.h), or from a volume or a model file with
/// the palpation defaults (a capsule probe above the tissue, the tissue's lower part held, walls
/// around it: scene/palpation_defaults.h); both built by the same prepare_scene. Every probe
/// becomes a `live` probe driven by the app.

#include <Eigen/Core>
#include <atomic>
#include <filesystem>
#include <functional>
#include <future>
#include <memory>
#include <string>
#include <vector>

#include "convert/decimate_surface.h"
#include "haptics/device_side.h"
#include "io/surface_cache.h"
#include "model/model.h"
#include "model/voxel_grid.h"
#include "physics/calibration_key.h"
#include "physics/physics_model.h"
#include "scene/palpation_defaults.h"
#include "sim/simulation.h"
#include "stick_control.h"
#include "surface/surface.h"

namespace vx {
class BackgroundRegionCheck;  // scene/scene.h
}  // namespace vx

namespace vx::probe {

/// Settings for inputs that are not scene files (volumes and models): what the app's options
/// fill in of the palpation defaults (default_palpation_scene).
struct DefaultSceneOptions {
  std::string threshold{"soft-tissue"};  ///< HU window or preset (volumes)
  double voxel_mm{0.0};                  ///< resample volumes to this voxel size first; 0 = keep
  double youngs_modulus_kpa{10.0};       ///< tissue stiffness
  /// Poisson ratio: 0.45, tissue-like (soft tissue is 0.45-0.49 and keeps its volume; issue 27).
  /// The model reads right there (docs/model.md section 5: its press within 1 % of a finite-strain
  /// reference on the same mesh, the cantilever within 5 % of beam theory), the implicit
  /// configurations cost the same as at 0 (the volume term is in the same constant matrix), the
  /// CI soak at 0.45 leaves the tissue at rest and its memory flat (tests/apps/
  /// probe_soak_slow_test.cpp, docs/scenes.md "Which Poisson ratio"). 0 is the paper's model.
  double poisson_ratio{0.45};
  double damping_ratio{0.2};
  std::filesystem::path surface;  ///< models: the .vtp surface written with the model (optional)
  /// The displayed, deforming surface: `iso` (smoothed iso-surface embedded in the elements)
  /// or `paper` (the voxel surface with its concave steps hidden, paper 3.3).
  SurfaceMethod surface_method{SurfaceMethod::iso};
  /// The default support holds every node in this lowest fraction of the tissue's height (an
  /// organ rests on its lower part in the body; docs/probe.md).
  double held_fraction{0.25};
  /// The default tool starts above a point with tissue at least this deep beneath it, mm.
  double press_depth_mm{5.0};
  /// Any input: the displayed surface is decimated to about this many triangles when it has
  /// more (convert/decimate_surface.h); 0 = show the full surface.
  int display_triangles{100000};
  /// The material's calibration kept by the model's content (io/calibration_cache.h); null: none.
  std::shared_ptr<CalibrationCache> calibration_cache;
  /// The region check's estimate kept by its content (io/region_check_cache.h); null: none.
  std::shared_ptr<RegionStiffeningCache> region_check_cache;
  /// The decimated display surface kept by the content of the model and its full surface
  /// (io/surface_cache.h); null: none.
  std::shared_ptr<SurfaceCache> surface_cache;
  /// false (headless): nothing is shown, so no surface is built, decimated or deformed.
  bool display{true};
  /// A display surface that is neither cached nor small is decimated on a thread of its own
  /// while the session runs, a preview shown meanwhile (convert/decimate_surface.h,
  /// stage_display_surface_of_grid: the folded organ's first start no longer waits 10 s for it);
  /// false: decimated during the loading, as before.
  bool surface_in_background{true};
};

struct ProbeScene;
/// The displayed surface: decimated to `options.display_triangles` when it has more
/// (convert/decimate_surface.h), set as the scene's and the simulation's surface (so the
/// physics deforms only that), with a note saying what was done.
void use_display_surface(ProbeScene& scene, const DefaultSceneOptions& options);

/// The display surface decimated on a thread of its own (StagedDisplaySurface::finish) at nice
/// 10, with OpenMP on that thread alone (so the physics' team keeps the cores and its waits
/// spin), from start() on. The destructor cancels the decimation (it stops within 10,000 edge
/// collapses) and waits for the thread.
class BackgroundDisplaySurface {
 public:
  BackgroundDisplaySurface(std::function<EmbeddedSurface(DecimationReport*)> finish,
                           std::shared_ptr<std::atomic<bool>> cancel);
  ~BackgroundDisplaySurface();
  BackgroundDisplaySurface(const BackgroundDisplaySurface&) = delete;
  BackgroundDisplaySurface& operator=(const BackgroundDisplaySurface&) = delete;
  /// Starts the decimation (once; later calls do nothing). The probe app starts it once the
  /// solver is built, so that the decimation's memory never comes on top of the factorisation's
  /// (the folded organ's peak: 2.4 GB with the two together, docs/probe.md).
  void start();
  [[nodiscard]] bool started() const { return result_.valid() || taken_; }
  /// Started and done.
  [[nodiscard]] bool ready() const;
  /// The decimated surface, with its report in `report` (waits for it; once: later calls
  /// throw). Rethrows what the decimation threw (DecimationCancelled after cancel()).
  [[nodiscard]] std::shared_ptr<const EmbeddedSurface> get(DecimationReport* report);
  /// Stops the decimation under way (get() then throws DecimationCancelled).
  void cancel() { cancel_->store(true); }

 private:
  std::function<EmbeddedSurface(DecimationReport*)> finish_;
  std::shared_ptr<std::atomic<bool>> cancel_;
  bool taken_{false};
  DecimationReport report_;
  std::future<std::shared_ptr<const EmbeddedSurface>> result_;
};

/// A scene ready to simulate and show.
struct ProbeScene {
  std::string name;
  std::shared_ptr<const Model> model;
  std::shared_ptr<const PhysicsModel> physics;
  std::shared_ptr<const EmbeddedSurface> surface;
  SimulationSettings simulation;             ///< probes are live; surface set
  DeviceSideSettings device_side;            ///< the device (the app adds the local contact models)
  Eigen::Vector3d world_up{0.0, -1.0, 0.0};  ///< up on screen (LPS); default anterior
  std::vector<Box> probe_allowed;            ///< per probe: where its reference point may go
  std::vector<std::string> notes;            ///< what was loaded and decided, for the console
  ControlSettings control;                   ///< stick mapping defaults (a scene's live probe sets its mapping)
  /// The regional solves' error on this support, estimated while the run starts (a scene file
  /// with regional solves; null otherwise); the GUI loop reports it when it is ready.
  std::shared_ptr<BackgroundRegionCheck> region_check;
  /// The display surface still being decimated while `surface` is its preview
  /// (DefaultSceneOptions::surface_in_background); null when `surface` is final.
  std::shared_ptr<BackgroundDisplaySurface> surface_refinement;
  /// A standing accuracy warning for the screen's status line (incompressible_iterations_status;
  /// the full warning is in `notes`); empty when there is none.
  std::string accuracy_status;
  double load_s{0.0};  ///< wall time of loading and preparing it (part of the app's start-up), s
  bool control_from_scene{false};
};

/// Loads a scene (`.json`), a volume (`.vti .mha .mhd .nii .nii.gz .nrrd .nhdr`, a DICOM
/// folder or file) or a model (`.vtu`). Throws vx::Error with a clear message.
[[nodiscard]] ProbeScene load_probe_scene(const std::filesystem::path& input, const DefaultSceneOptions& options);

/// Turns every probe into a live probe (keeping its shape and start) and fills
/// `probe_allowed` (the walls shrunk by the probe radius, else the tissue box with margins).
/// The first probe that was already live gives `control.mapping` (its JoystickMapping: mode,
/// speed, range, dead zone).
void make_probes_live(ProbeScene& scene);

/// The physics configuration in a few words (HUD and console), e.g. "implicit 20 ms, 1
/// iteration" or "symplectic Euler 0.18 ms, mass floor for 0.25 ms".
[[nodiscard]] std::string physics_configuration(const IntegratorSettings& integrator, const PhysicsModel& physics);

}  // namespace vx::probe
