#pragma once
/// @file scene.h
/// Scene files (JSON): what object to simulate, its material, how it is held, which probes
/// press, tap or grasp it, for how long, and what to write. The reference is docs/scenes.md;
/// the examples are samples/scenes/*.json.
///
/// Loading is strict: an unknown key, a value of the wrong type, a wrong unit or an impossible
/// value is a vx::Error naming the file and the key's JSON path (`$.probes[1].radius_mm`),
/// saying what is wrong and how to fix it. Loading a scene reads no volume; prepare_scene()
/// builds the object, its material and the core's SimulationSettings.
///
/// Units: mm, s, N, kPa, kg/m^3, HU; gravity m/s^2 (as people write it); LPS coordinates.

#include <Eigen/Core>
#include <atomic>
#include <filesystem>
#include <functional>
#include <future>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <vector>

#include "convert/phantom.h"
#include "convert/prepare.h"
#include "haptics/device_force.h"
#include "haptics/device_side.h"
#include "io/volume.h"
#include "io/volume_io.h"
#include "model/gradational_builder.h"
#include "physics/calibration_key.h"
#include "physics/physics_model.h"
#include "sim/contact.h"
#include "sim/integrators.h"
#include "sim/probe.h"
#include "sim/region_stiffening.h"
#include "sim/simulation.h"
#include "sim/state.h"
#include "surface/surface.h"

namespace vx {

/// The longest simulated time a scene may ask for (duration, keyframe times), s: a day and a bit.
inline constexpr double kMaxSceneTime_s = 1e5;
/// The most steps one run may take: more cannot finish in any sensible time (1e8 steps of the
/// smallest model take about 20 minutes); prepare_scene() refuses a scene that needs more.
inline constexpr double kMaxSceneSteps = 1e8;

/// Where the object comes from.
enum class ObjectSource : std::uint8_t { phantom, volume, model, box };

/// The `object` of a scene.
struct SceneObject {
  ObjectSource source{ObjectSource::phantom};
  std::filesystem::path path;           ///< volume or model file (resolved against the scene's folder)
  PhantomSettings phantom;              ///< phantom
  PrepareOptions prepare;               ///< phantom, volume: threshold and clean-up
  ReadOptions read;                     ///< volume
  Eigen::Vector3d box_min_mm{0, 0, 0};  ///< box: a solid block of tissue
  Eigen::Vector3d box_max_mm{0, 0, 0};
  double box_voxel_mm{1.0};  ///< box: voxel size
  BuildSettings build;       ///< resolution, max level (not for a model file)
};

/// One row of a Hounsfield-to-modulus table.
struct HuModulus {
  double hu{0.0};
  double youngs_modulus_kpa{0.0};
};

/// A spherical inclusion with its own material (a stiff lesion to find by palpation).
struct Inclusion {
  Eigen::Vector3d center_mm{0, 0, 0};
  double radius_mm{0.0};
  double youngs_modulus_kpa{0.0};
  double density_kg_m3{0.0};  ///< 0: the surrounding density
};

/// The `material` of a scene.
struct SceneMaterial {
  Material base;                                      ///< homogeneous part
  ElementKind element{CalibrationOptions{}.element};  ///< "element": hourglass (default) or paper
  MassScaling mass_scaling;                           ///< `mass_scaling`: none by default (docs/model.md section 6)
  std::vector<HuModulus> hounsfield;                  ///< optional: modulus per voxel from its HU (piecewise linear)
  std::vector<Inclusion> inclusions;                  ///< optional: spheres with their own modulus
};

/// One entry of `fixed`: a face of the object's bounding box (nodes within `within_mm` of
/// it), or a box.
struct FixedRegion {
  bool is_face{true};
  BoxFace face{BoxFace::z_min};
  double within_mm{0.0};
  Eigen::Vector3d box_min_mm{0, 0, 0}, box_max_mm{0, 0, 0};
  std::string label;  ///< what the scene said, for messages
};

/// What to write.
struct SceneOutputs {
  bool forces_csv{true};           ///< DIR/forces.csv
  double forces_interval_s{1e-3};  ///< rows every this long (raw force averaged over the steps between rows)
  bool plot{true};                 ///< DIR/forces.png: force against time and against indentation depth
  bool pvd_model{false};           ///< DIR/model.pvd: deformed model series (point array displacement_mm)
  bool pvd_surface{false};         ///< DIR/surface.pvd: deformed surface series
  double pvd_interval_s{0.02};     ///< a frame every this long
  SurfaceMethod surface_method{SurfaceMethod::paper};
};

/// Defaults placed around an object that comes without a scene of its own (the probe app given a
/// volume or a model): prepare_scene holds its lower part, puts walls around it and one capsule
/// tool just above tissue the tool touches when pressed down, and runs the fast configuration
/// (scene/palpation_defaults.h). No JSON key: default_palpation_scene() sets it.
struct PalpationDefaults {
  Eigen::Vector3d up{0.0, -1.0, 0.0};  ///< up (LPS direction; in the slice plane of a 2D model); default anterior
  /// The support holds every node in this lowest fraction of the tissue's height along `up`.
  double held_fraction{0.25};
  /// The tool starts above a point with tissue at least this deep beneath it, mm.
  double press_depth_mm{5.0};
};

/// A whole scene, loaded and checked, nothing built yet.
struct Scene {
  std::filesystem::path file;  ///< the scene file ("" when parsed from text)
  std::string description;
  SceneObject object;
  SceneMaterial material;
  std::vector<FixedRegion> fixed;
  Eigen::Vector3d gravity_m_s2{0, 0, 0};
  Workspace workspace;
  /// without an `integrator` key: the fast configuration (FastConfiguration, scene/fast_configuration.h:
  /// implicit, automatic step, one iteration), or symplectic Euler when the contact has friction
  IntegratorKind integrator{IntegratorKind::implicit};
  bool integrator_given{false};      ///< the scene has an `integrator` key
  double dt_s{0.0};                  ///< 0: automatic (automatic_time_step() of sim/time_step.h)
  int iterations{0};                 ///< implicit: local/global iterations per step (0: 10, or 1 by default)
  double residual_tolerance_n{0.0};  ///< implicit: stop once the largest force imbalance is below (N)
  double region_radius_mm{0.0};      ///< implicit: regional solves within this distance of a probe (0: off)
  /// implicit with regional solves: 0 the far field held ("held", the default), 1 carried by an
  /// affine field ("carried": IntegratorSettings::region_far_field_degree)
  int region_far_field_degree{0};
  /// implicit: the factor's sweeps in single precision ("sweep_precision": "single") or double
  /// ("double"); unset ("auto", the default): single on a model of the fast configuration's large
  /// size (IntegratorSettings::single_precision_sweeps)
  std::optional<bool> single_precision_sweeps;
  ContactSettings contact;
  std::optional<DeviceForceSettings> device;
  std::vector<ProbeSettings> probes;
  double duration_s{0.0};
  SceneOutputs outputs;
  int threads{0};
  /// Set: the support, walls, probe, integrator and device come from these defaults once the
  /// object is built (fixed, workspace, probes, integrator keys and device are not read).
  std::optional<PalpationDefaults> palpation;
};

/// Reads and checks a scene file. Throws vx::Error (file, JSON path, what, how to fix).
[[nodiscard]] Scene load_scene(const std::filesystem::path& path);
/// Parses scene JSON text; relative paths resolve against `base_dir`; `name` labels messages.
[[nodiscard]] Scene parse_scene(const std::string& text, const std::filesystem::path& base_dir,
                                const std::string& name = "scene");
/// The same from parsed JSON.
[[nodiscard]] Scene parse_scene(const nlohmann::json& j, const std::filesystem::path& base_dir,
                                const std::string& name = "scene");

/// When prepare_scene estimates the regional solves' error on the scene's support
/// (region_stiffening.h: seconds on a large model).
enum class RegionCheckTiming {
  before_run,  ///< in prepare_scene: the result is in PreparedScene when it returns
  background,  ///< on a thread of its own at low priority while the run starts (take_region_check)
  none,        ///< not at all
};

/// What to build besides the physics.
struct PrepareSceneOptions {
  bool surface{false};       ///< build the embedded surface (display, .pvd surface output)
  int threads_override{-1};  ///< >= 0: replaces the scene's `threads`
  bool skip_unneeded{true};  ///< false: the Simulation does every optional piece of work
  RegionCheckTiming region_check{RegionCheckTiming::before_run};
  /// background: the check's thread's nice value (10: it yields to a real-time run; 0: a batch
  /// run, which waits for it at its end anyway)
  int region_check_nice{10};
  /// implicit: the factor cache (io/factor_cache.h; make_factor_cache); null: none
  std::shared_ptr<FactorCache> factor_cache;
  /// the calibration cache (io/calibration_cache.h; make_calibration_cache); null: none
  std::shared_ptr<CalibrationCache> calibration_cache;
  /// the region check's estimates (io/region_check_cache.h; make_region_check_cache); null: none
  std::shared_ptr<RegionStiffeningCache> region_check_cache;
};

/// The regional solves' error on a scene's support: the estimate of the probe where it is worst,
/// and what to log and to warn about it.
struct RegionCheck {
  std::optional<RegionStiffeningEstimate> estimate;
  std::string probe;                  ///< the probe of `estimate`
  std::vector<std::string> log;       ///< one line per probe without an estimate, one for the worst
  std::vector<std::string> warnings;  ///< the warning above kRegionStiffeningWarnRel
};

/// A RegionCheck running on a thread of its own. Destroying it cancels the estimate and joins
/// the thread (at the estimate's next iteration).
class BackgroundRegionCheck {
 public:
  explicit BackgroundRegionCheck(std::function<RegionCheck(const std::atomic<bool>& cancel)> work);
  ~BackgroundRegionCheck();
  BackgroundRegionCheck(const BackgroundRegionCheck&) = delete;
  BackgroundRegionCheck& operator=(const BackgroundRegionCheck&) = delete;
  [[nodiscard]] bool ready() const;
  /// Waits for the result (once; later calls throw). Rethrows what the estimate threw.
  [[nodiscard]] RegionCheck get();

 private:
  std::atomic<bool> cancel_{false};
  std::future<RegionCheck> result_;
};

/// A scene made ready to simulate: the object built, the material calibrated, the settings.
struct PreparedScene {
  std::shared_ptr<const Model> model;
  std::shared_ptr<const PhysicsModel> physics;
  std::shared_ptr<const EmbeddedSurface> surface;  ///< when asked for
  VoxelGrid grid;                                  ///< the grid the model was built from
  SimulationSettings settings;                     ///< ready for Simulation
  DeviceSideSettings device_side;                  ///< ready for DeviceSide (the device, no local contact models)
  Eigen::Vector3d bounds_min_mm{0, 0, 0};          ///< object's rest bounding box, LPS mm
  Eigen::Vector3d bounds_max_mm{0, 0, 0};
  double dt_stable_estimate_s{0.0};  ///< the integrator's estimated stable step
  double automatic_dt_s{0.0};        ///< the step `"dt_s": "auto"` picks (0: none, explicit Euler undamped)
  int fixed_nodes{0};
  int heterogeneous_elements{0};  ///< elements whose modulus differs from the base
  double min_modulus_kpa{0.0}, max_modulus_kpa{0.0};
  std::vector<std::string> warnings;  ///< plausible but risky choices
  std::vector<std::string> log;       ///< what was built, one line each
  /// Scene::palpation: up as the defaults used it (in the slice plane of a 2D model); zero otherwise.
  Eigen::Vector3d up{0, 0, 0};
  /// Implicit with regional solves: how much the region over-stiffens the press of the probe
  /// where it is worst (region_stiffening.h; docs/model.md section 7); empty without a region.
  std::optional<RegionStiffeningEstimate> region_stiffening;
  std::string region_stiffening_probe;  ///< that probe's name
  /// RegionCheckTiming::background: the estimate still running (take_region_check() moves its
  /// result into region_stiffening, log and warnings); null otherwise and once taken.
  std::shared_ptr<BackgroundRegionCheck> pending_region_check;
  /// Wall time of each stage of prepare_scene (name, s), in order: where the start-up goes.
  std::vector<std::pair<std::string, double>> stage_seconds;
};

/// The background region check's result once it is ready (or, with `wait`, once it ends):
/// moved into `prepared` (region_stiffening, its probe; its log lines and warnings appended to
/// prepared.log and prepared.warnings) and returned, so the caller can show what is new.
/// Empty when nothing is pending or (without `wait`) it is still running.
std::optional<RegionCheck> take_region_check(PreparedScene& prepared, bool wait);

/// The estimated force error above which the run warns that its regional solves press too hard.
inline constexpr double kRegionStiffeningWarnRel = 0.05;

/// Builds the object (phantom, volume, model file or box), the per-element material (HU table,
/// inclusions), the fixed nodes and the simulation settings. Checks what only the built model
/// can tell (a fixed region that holds no node, a probe that starts inside the object, a time
/// step or probe speed that would tunnel). Throws vx::Error.
[[nodiscard]] PreparedScene prepare_scene(const Scene& scene, const PrepareSceneOptions& options = {});

/// Per-element Young's modulus and density (MaterialField) from a HU table and inclusions,
/// volume-averaged over each element's voxels (Voigt average). `hu` may be null when there is
/// no table. Returns an empty field when neither applies.
[[nodiscard]] MaterialField material_field(const Model& model, const SceneMaterial& material, const Volume* hu);

/// Per element: the mean of `volume`'s values over the element's voxels (each voxel centre's
/// nearest voxel of `volume`): the mean HU of a CT volume, as material_field averages the modulus.
[[nodiscard]] std::vector<double> element_mean_values(const Model& model, const Volume& volume);

/// The voxel grid covered by a model's elements (for a model loaded from a file).
[[nodiscard]] VoxelGrid grid_from_model(const Model& model);

/// Young's modulus (kPa) for `hu` from a table sorted by HU: linear between rows, constant
/// beyond the ends.
[[nodiscard]] double modulus_from_hu(const std::vector<HuModulus>& table, double hu);

}  // namespace vx
