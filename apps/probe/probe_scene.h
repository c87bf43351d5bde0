#pragma once
/// @file probe_scene.h
/// What the probe app runs: a physics model, its deforming surface and the simulation
/// settings, from a scene file (pipeline/scene/scene.h), or from a volume or a model file with
/// default palpation settings (a capsule probe above the tissue, the tissue's bottom held
/// on a table, walls around it). Every probe becomes a `live` probe driven by the app.

#include <Eigen/Core>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "model/model.h"
#include "physics/physics_model.h"
#include "sim/simulation.h"
#include "stick_control.h"
#include "surface/surface.h"

namespace vx::probe {

/// Settings for inputs that are not scene files (volumes and models).
struct DefaultSceneOptions {
  std::string threshold{"soft-tissue"};  ///< HU window or preset (volumes)
  double voxel_mm{0.0};                  ///< resample volumes to this voxel size first; 0 = keep
  double youngs_modulus_kpa{10.0};       ///< tissue stiffness
  double damping_ratio{0.2};
  std::filesystem::path surface;         ///< models: the .vtp surface written with the model (optional)
  /// The displayed, deforming surface: `iso` (smoothed iso-surface embedded in the elements)
  /// or `paper` (the voxel surface with its concave steps hidden, paper 3.3).
  SurfaceMethod surface_method{SurfaceMethod::iso};
};

/// A scene ready to simulate and show.
struct ProbeScene {
  std::string name;
  std::shared_ptr<const Model> model;
  std::shared_ptr<const PhysicsModel> physics;
  std::shared_ptr<const EmbeddedSurface> surface;
  SimulationSettings simulation;           ///< probes are live; surface set
  Eigen::Vector3d world_up{0.0, -1.0, 0.0};///< up on screen (LPS); default anterior
  std::vector<Box> probe_allowed;          ///< per probe: where its reference point may go
  std::vector<std::string> notes;          ///< what was loaded and decided, for the console
  ControlSettings control;                 ///< stick mapping defaults (a scene's live probe sets its mapping)
  bool control_from_scene{false};
};

/// Loads a scene (`.json`), a volume (`.vti .mha .mhd .nii .nii.gz .nrrd .nhdr`, a DICOM
/// folder or file) or a model (`.vtu`). Throws vx::Error with a clear message.
[[nodiscard]] ProbeScene load_probe_scene(const std::filesystem::path& input, const DefaultSceneOptions& options);

/// Default palpation settings around a built model: bottom nodes fixed (against `up`), walls,
/// one capsule probe above the top centre, symplectic Euler at half its stable step, a
/// device with the paper's shaping. Exposed for tests.
[[nodiscard]] ProbeScene make_default_scene(std::shared_ptr<const Model> model,
                                            std::shared_ptr<const EmbeddedSurface> surface,
                                            const DefaultSceneOptions& options, const Eigen::Vector3d& up,
                                            const std::string& name);

/// Turns every probe into a live probe (keeping its shape and start) and fills
/// `probe_allowed` (the walls shrunk by the probe radius, else the tissue box with margins).
/// The first probe that was already live gives `control.mapping` (its JoystickMapping: mode,
/// speed, range, dead zone).
void make_probes_live(ProbeScene& scene);

/// The physics configuration in a few words (HUD and console), e.g. "implicit 20 ms, 1
/// iteration" or "symplectic Euler 0.18 ms, mass floor for 0.25 ms".
[[nodiscard]] std::string physics_configuration(const IntegratorSettings& integrator, const PhysicsModel& physics);

}  // namespace vx::probe
