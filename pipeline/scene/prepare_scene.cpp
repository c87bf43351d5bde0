// Building a loaded scene (scene.h): the object and its model, the material per element, the
// integrator and its time step, the fixed nodes, walls, device and probes, and the surface; with
// the checks only the built model can make.
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <optional>

#include "base/error.h"
#include "io/model_io.h"
#include "physics/calibration.h"
#include "scene/fast_configuration.h"
#include "scene/palpation_defaults.h"
#include "scene/scene.h"
#include "sim/region_stiffening.h"
#include "sim/sparse_factor.h"
#include "sim/time_step.h"
#include "util/thread_priority.h"

namespace vx {
namespace {

/// Where a scene's errors point: "FILE: JSON-PATH: what".
struct SceneErrors {
  std::string file;  ///< the scene file, or "scene" when parsed from text
  [[noreturn]] void fail(const std::string& path, const std::string& what) const {
    throw Error(file + ": " + path + ": " + what);
  }
};

/// The object: a phantom or a volume (thresholded and cleaned up), a model file or a box, and
/// its model built, with its bounds. Returns the volume when there is one (for the HU table).
std::optional<Volume> build_object(const Scene& scene, PreparedScene& out) {
  const SceneObject& obj = scene.object;
  std::optional<Volume> volume;
  Model model;
  switch (obj.source) {
    case ObjectSource::phantom: {
      PhantomShape shape;
      volume = make_phantom(obj.phantom, &shape);
      out.log.push_back(fmt::format("phantom {} ({}^3 voxels of {:g} mm)", obj.phantom.name, obj.phantom.size,
                                    obj.phantom.spacing_mm));
      break;
    }
    case ObjectSource::volume:
      volume = read_volume(obj.path, obj.read);
      out.log.push_back(fmt::format("volume {} ({}x{}x{} voxels)", obj.path.string(), volume->geometry.dims.x(),
                                    volume->geometry.dims.y(), volume->geometry.dims.z()));
      break;
    case ObjectSource::model:
      model = load_model(obj.path);
      out.grid = grid_from_model(model);
      out.log.push_back(fmt::format("model {} ({} elements)", obj.path.string(), model.num_elements()));
      break;
    case ObjectSource::box: {
      GridGeometry g;
      const Eigen::Vector3d size = obj.box_max_mm - obj.box_min_mm;
      for (int c = 0; c < 3; ++c) g.dims[c] = int(std::lround(size[c] / obj.box_voxel_mm));
      g.spacing_mm = Eigen::Vector3d::Constant(obj.box_voxel_mm);
      g.origin_mm = obj.box_min_mm + Eigen::Vector3d::Constant(0.5 * obj.box_voxel_mm);
      out.grid = VoxelGrid(g);
      std::fill(out.grid.data().begin(), out.grid.data().end(), std::uint8_t(1));
      out.log.push_back(
          fmt::format("box {}x{}x{} voxels of {:g} mm", g.dims.x(), g.dims.y(), g.dims.z(), obj.box_voxel_mm));
      break;
    }
  }
  if (volume) {
    PrepareReport report;
    out.grid = prepare_grid(*volume, obj.prepare, &report);
    out.log.push_back(report.summary());
  }
  if (obj.source != ObjectSource::model) {
    // a one-slice object (a one-slice volume, the disk, rectangle and disk-lesion phantoms) makes
    // the 2D model (docs/model.md section 12)
    BuildSettings build = obj.build;
    if (out.grid.dims().z() == 1) build.dimensions = 2;
    BuildReport report;
    model = build_model(out.grid, build, &report);
  }
  out.model = std::make_shared<const Model>(std::move(model));
  const Model& m = *out.model;
  out.bounds_min_mm = m.rest_positions.rowwise().minCoeff();
  out.bounds_max_mm = m.rest_positions.rowwise().maxCoeff();
  out.log.push_back(
      fmt::format("{} model: {} elements, {} nodes, {} vertex entries; bounds [{:.4g}, {:.4g}, {:.4g}] .. "
                  "[{:.4g}, {:.4g}, {:.4g}] mm",
                  to_string(m.layout), m.num_elements(), m.num_nodes(), m.num_vertex_entries(), out.bounds_min_mm.x(),
                  out.bounds_min_mm.y(), out.bounds_min_mm.z(), out.bounds_max_mm.x(), out.bounds_max_mm.y(),
                  out.bounds_max_mm.z()));
  return volume;
}

/// The material per element when heterogeneous (HU table, inclusions), and the physics.
void calibrate_material(const Scene& scene, const Volume* volume, const PrepareSceneOptions& options,
                        PreparedScene& out) {
  const MaterialField field = material_field(*out.model, scene.material, volume);
  CalibrationOptions calibration;
  calibration.element = scene.material.element;
  calibration.mass_scaling = scene.material.mass_scaling;
  out.physics = make_physics_model(out.model, scene.material.base, field, calibration, options.calibration_cache.get());
  if (scene.material.mass_scaling.active())
    out.log.push_back(
        fmt::format("mass scaling: factor {:g}, floor for a {:.3g} ms step: {} nodes heavier, +{:.3g} % mass",
                    scene.material.mass_scaling.factor, 1e3 * scene.material.mass_scaling.time_step_s,
                    out.physics->scaled_nodes, 100.0 * out.physics->added_mass_kg / out.physics->total_mass_kg()));
  out.min_modulus_kpa = out.max_modulus_kpa = scene.material.base.youngs_modulus_kpa;
  if (!field.youngs_modulus_kpa.empty()) {
    const auto [lo, hi] = std::minmax_element(field.youngs_modulus_kpa.begin(), field.youngs_modulus_kpa.end());
    out.min_modulus_kpa = *lo;
    out.max_modulus_kpa = *hi;
    for (double e : field.youngs_modulus_kpa)
      if (std::abs(e - scene.material.base.youngs_modulus_kpa) > 1e-12 * scene.material.base.youngs_modulus_kpa)
        ++out.heterogeneous_elements;
    out.log.push_back(fmt::format(
        "material: modulus {:.4g} to {:.4g} kPa per element ({} elements differ from {:g} kPa)", out.min_modulus_kpa,
        out.max_modulus_kpa, out.heterogeneous_elements, scene.material.base.youngs_modulus_kpa));
    for (std::size_t i = 0; i < scene.material.inclusions.size(); ++i) {
      const Inclusion& inc = scene.material.inclusions[i];
      if ((inc.center_mm.array() + inc.radius_mm < out.bounds_min_mm.array()).any() ||
          (inc.center_mm.array() - inc.radius_mm > out.bounds_max_mm.array()).any())
        out.warnings.push_back(
            fmt::format("material.inclusions[{}] lies outside the object's bounds: it changes nothing", i));
    }
  }
}

/// The integrator: its time step (the scene's, or automatic) checked against the model's
/// stable step, threads and gravity.
void choose_integrator(const Scene& scene, const PrepareSceneOptions& options, const SceneErrors& errors,
                       PreparedScene& out) {
  SimulationSettings& s = out.settings;
  s.integrator.kind = scene.integrator;
  const TimeStepEstimate est = estimate_time_steps(*out.physics);
  out.dt_stable_estimate_s = est.limit(scene.integrator);
  double automatic_dt_s = automatic_time_step(est, scene.integrator);
  // no integrator key and a large model: the fast configuration's 30 ms steps with regional solves
  const FastConfiguration fast = default_fast_configuration();
  const bool large =
      scene.integrator == IntegratorKind::implicit && !scene.integrator_given && fast.large(out.model->num_nodes());
  if (large) automatic_dt_s = fast.time_step_for(out.model->num_nodes());
  if (scene.integrator == IntegratorKind::implicit) {
    // the fast configuration's step, shortened where a probe would move more than a quarter of
    // its radius per step or a device update would span fewer than two steps
    for (const ProbeSettings& p : scene.probes) {
      const double speed = p.max_scripted_speed_mm_s();
      if (p.geometry.shape != ProbeShape::plane && speed > 0)
        automatic_dt_s = std::min(automatic_dt_s, 0.25 * p.geometry.radius_mm / speed);
    }
    if (scene.device) automatic_dt_s = std::min(automatic_dt_s, 0.5 * scene.device->update_interval_s);
    s.integrator.max_iterations = scene.iterations > 0     ? scene.iterations
                                  : scene.integrator_given ? IntegratorSettings{}.max_iterations
                                                           : fast.iterations;
    s.integrator.residual_tolerance_n = scene.residual_tolerance_n;
    if (scene.iterations == 0 && !scene.integrator_given) {  // the fast configuration's return to rest
      s.integrator.free_iterations = fast.free_iterations_for(out.model->num_nodes());
      s.integrator.free_tolerance_mm = fast.free_tolerance_mm;
    }
    s.integrator.factor_cache = options.factor_cache;
    s.integrator.region_radius_mm = large ? fast.region_radius_for(out.model->num_nodes()) : scene.region_radius_mm;
    s.integrator.region_far_field_degree = scene.region_far_field_degree;
    // only a supernodal (CHOLMOD) factor sweeps in single precision: what runs is what is said
    const bool supernodal = SparseFactor::best_backend() == SparseFactor::Backend::cholmod;
    s.integrator.single_precision_sweeps =
        supernodal && scene.single_precision_sweeps.value_or(fast.large(out.model->num_nodes()) &&
                                                             fast.large_model_single_precision_sweeps);
    if (!supernodal && scene.single_precision_sweeps.value_or(false))
      out.warnings.push_back(fmt::format(
          "integrator.sweep_precision \"single\" needs the supernodal factor of CHOLMOD, and this run factors with "
          "{}: its sweeps stay in double (scripts/install-deps.sh installs SuiteSparse; VOXELASTIC_FACTOR chooses)",
          SparseFactor::to_string(SparseFactor::best_backend())));
    if (large)
      out.log.push_back(fmt::format(
          "the fast configuration of a large model ({} nodes, {} or more): implicit, {:g} ms steps, "
          "regional solves within {:g} mm of a tool, the factor swept in {} precision (docs/bench.md)",
          out.model->num_nodes(), fast.large_model_nodes, 1e3 * std::min(automatic_dt_s, fast.large_model_time_step_s),
          fast.large_model_region_radius_mm, s.integrator.single_precision_sweeps ? "single" : "double"));
  }
  out.automatic_dt_s = automatic_dt_s;
  if (scene.dt_s > 0) {
    s.integrator.time_step_s = scene.dt_s;
  } else if (automatic_dt_s > 0) {
    s.integrator.time_step_s = automatic_dt_s;
  } else {
    errors.fail("$.integrator",
                "explicit_euler without damping is unstable at any time step (docs/model.md section 7); set "
                "material.damping > 0 "
                "or use symplectic_euler or implicit");
  }
  if (scene.integrator != IntegratorKind::implicit) {
    if (out.dt_stable_estimate_s == 0.0)
      out.warnings.push_back(
          "explicit_euler without damping gains energy every step at any dt_s: the run will blow up");
    else if (s.integrator.time_step_s > 1.25 * out.dt_stable_estimate_s)
      // the estimate is close to the real limit (a block blew up at 1.3x within 40 steps)
      errors.fail(
          "$.integrator.dt_s",
          fmt::format(
              "{:.3g} s is {:.2g} times the estimated stable step {:.3g} s of {} for this model and material: the "
              "run would blow up within a few steps; use \"auto\" (half the estimate) or at most {:.3g} s, or the "
              "implicit integrator",
              s.integrator.time_step_s, s.integrator.time_step_s / out.dt_stable_estimate_s, out.dt_stable_estimate_s,
              to_string(scene.integrator), out.dt_stable_estimate_s));
    else if (s.integrator.time_step_s > out.dt_stable_estimate_s)
      out.warnings.push_back(
          fmt::format("integrator.dt_s {:.3g} s exceeds the estimated stable step {:.3g} s of {}: the run "
                      "may blow up (the summary's \"stable\" will say)",
                      s.integrator.time_step_s, out.dt_stable_estimate_s, to_string(scene.integrator)));
  }
  if (std::string w = incompressible_iterations_warning(s.integrator, out.physics->material.poisson_ratio); !w.empty())
    out.warnings.push_back(std::move(w));
  if (scene.integrator == IntegratorKind::implicit && scene.contact.friction > 0)
    out.warnings.push_back(
        fmt::format("contact.friction {:g} is ignored by the implicit integrator (its contact is "
                    "frictionless and inelastic, solved inside the step); use symplectic_euler to "
                    "grasp and lift",
                    scene.contact.friction));
  // a run must be able to finish: a step of 1e-9 s over a second is 1e9 steps
  if (const double steps = scene.duration_s / s.integrator.time_step_s; !(steps <= kMaxSceneSteps))
    errors.fail(
        scene.dt_s > 0 ? "$.integrator.dt_s" : "$.duration_s",
        fmt::format("{:g} s in steps of {:.3g} s is {:.3g} steps, more than one run takes ({:.0e}, already many "
                    "hours for a small model); use a longer dt_s (\"auto\" picks {:.3g} s for this model) or a "
                    "shorter duration_s",
                    scene.duration_s, s.integrator.time_step_s, steps, kMaxSceneSteps, automatic_dt_s));
  s.integrator.threads = options.threads_override >= 0 ? options.threads_override : scene.threads;
  s.gravity_mm_s2 = scene.gravity_m_s2 * 1000.0;
}

/// The nodes the fixed regions hold; returns a flag per node (1: fixed).
std::vector<std::uint8_t> fix_nodes(const Scene& scene, const SceneErrors& errors, PreparedScene& out) {
  const Model& m = *out.model;
  SimulationSettings& s = out.settings;
  std::vector<std::uint8_t> fixed(std::size_t(m.num_nodes()), 0);
  for (std::size_t r = 0; r < scene.fixed.size(); ++r) {
    const FixedRegion& f = scene.fixed[r];
    if (f.is_face && m.is_2d()) {
      // the faces across the slice would hold every node of a 2D model
      const int axis = int(f.face) / 2;
      const Eigen::Vector3d n = m.grid.direction.col(0).cross(m.grid.direction.col(1)).normalized();
      if (std::abs(n(axis)) > 0.5)
        errors.fail(fmt::format("$.fixed[{}]", r),
                    fmt::format("\"{}\" lies across the slice of a 2D model and would hold all of it; hold an edge of "
                                "the slice instead (a face along the slice: {})",
                                f.label,
                                axis == 0   ? "y_min, y_max, z_min, z_max"
                                : axis == 1 ? "x_min, x_max, z_min, z_max"
                                            : "x_min, x_max, y_min, y_max"));
    }
    const std::vector<int> nodes =
        f.is_face ? nodes_on_face(m, f.face, std::max(f.within_mm, 1e-6 * m.grid.spacing_mm.minCoeff()))
                  : nodes_in_box(m, f.box_min_mm, f.box_max_mm);
    if (nodes.empty())
      errors.fail(
          fmt::format("$.fixed[{}]", r),
          fmt::format(
              "\"{}\" holds no node of the object (bounds [{:.4g}, {:.4g}, {:.4g}] .. [{:.4g}, {:.4g}, {:.4g}] mm)",
              f.label, out.bounds_min_mm.x(), out.bounds_min_mm.y(), out.bounds_min_mm.z(), out.bounds_max_mm.x(),
              out.bounds_max_mm.y(), out.bounds_max_mm.z()));
    if (f.is_face && nodes.size() < 3)
      out.warnings.push_back(
          fmt::format("fixed[{}] \"{}\" holds only {} node(s) (a rounded object touches its bounding box in "
                      "a point); use {{\"face\": \"{}\", \"within_mm\": 2}}",
                      r, f.label, nodes.size(), f.label));
    for (int i : nodes) fixed[std::size_t(i)] = 1;
  }
  for (int i = 0; i < m.num_nodes(); ++i)
    if (fixed[std::size_t(i)]) s.fixed_nodes.push_back(i);
  out.fixed_nodes = int(s.fixed_nodes.size());
  return fixed;
}

/// Walls, contact, the device and the probes, checked against the model and the time step (a
/// probe that would tunnel through the surface, one that starts inside it).
void place_walls_and_probes(const Scene& scene, const std::vector<std::uint8_t>& fixed, const SceneErrors& errors,
                            PreparedScene& out) {
  const Model& m = *out.model;
  SimulationSettings& s = out.settings;
  s.workspace = scene.workspace;
  if (s.workspace.enabled && ((out.bounds_min_mm.array() < s.workspace.min_mm.array()).any() ||
                              (out.bounds_max_mm.array() > s.workspace.max_mm.array()).any()))
    out.warnings.push_back("the object does not fit in workspace_mm: the walls push it in at the first step");
  s.contact = scene.contact;
  out.device_side.device = scene.device;
  s.probes = scene.probes;
  if (m.is_2d()) {
    // a 2D model meets each probe in the slice plane (docs/model.md section 12.2)
    const Eigen::Vector3d n = m.grid.direction.col(0).cross(m.grid.direction.col(1)).normalized();
    for (std::size_t i = 0; i < s.probes.size(); ++i)
      if (const std::string bad = slice_probe_problem(s.probes[i].geometry, n); !bad.empty())
        errors.fail(fmt::format("$.probes[{}]", i),
                    fmt::format("\"{}\": the object is a 2D model (one slice); {}; a sphere is a circle in the plane "
                                "of any slice",
                                s.probes[i].name, bad));
  }
  const double spacing = m.grid.spacing_mm.minCoeff();
  const double dt = s.integrator.time_step_s;
  const std::optional<DeviceForceSettings>& device = out.device_side.device;
  if (device && device->shaping == ForceShaping::paper && device->update_interval_s < 1.5 * dt)
    errors.fail("$.device.update_interval_s",
                fmt::format("{:.3g} s spans less than 2 physics steps of {:.3g} s; a half sine needs "
                            "room: raise it (e.g. 0.02 s) or lower integrator.dt_s",
                            device->update_interval_s, dt));
  const std::vector<std::int32_t> surface_nodes = collidable_nodes(m, fixed);
  for (std::size_t i = 0; i < s.probes.size(); ++i) {
    const ProbeSettings& p = s.probes[i];
    const std::string at = fmt::format("$.probes[{}]", i);
    const double speed = p.max_scripted_speed_mm_s();
    if (p.geometry.shape != ProbeShape::plane) {
      // nodes are pushed to the nearest surface point: a probe moving more than about half its
      // radius per step would push them out of its far side (tunnelling)
      if (speed * dt > 0.5 * p.geometry.radius_mm)
        errors.fail(
            at,
            fmt::format("the probe moves up to {:.4g} mm/s, {:.3g} mm per step of {:.3g} s: more than half its radius "
                        "({:g} mm), so it would pass through the surface; slow it down or lower integrator.dt_s",
                        speed, speed * dt, dt, p.geometry.radius_mm));
      if (p.geometry.radius_mm < spacing)
        out.warnings.push_back(
            fmt::format("probes[{}] \"{}\": radius {:g} mm is below the node spacing {:g} mm; it can pass "
                        "between surface nodes",
                        i, p.name, p.geometry.radius_mm, spacing));
    } else if (speed * dt > spacing) {
      out.warnings.push_back(fmt::format("probes[{}] \"{}\": the plate moves {:.3g} mm per step, more than a voxel", i,
                                         p.name, speed * dt));
    }
    const Eigen::Vector3d start = p.initial_position();
    int inside = 0;
    for (const std::int32_t n : surface_nodes)
      if (probe_signed_distance(p.geometry, start, m.rest_positions.col(n)) < 0) ++inside;
    if (inside > 0)
      out.warnings.push_back(
          fmt::format("probes[{}] \"{}\" starts with {} surface nodes inside it: they are pushed out at "
                      "the first step",
                      i, p.name, inside));
  }
}

/// Implicit with regional solves: estimates per probe how much the region over-stiffens its press
/// on this support (region_stiffening.h) and warns, with the configuration that would be right,
/// when the worst is above kRegionStiffeningWarnRel. Reads only its arguments (runs on a thread
/// of its own with RegionCheckTiming::background).
RegionCheck check_region_support(const PhysicsModel& physics, const std::vector<std::uint8_t>& fixed,
                                 const SimulationSettings& s, RegionStiffeningCache* cache,
                                 const std::atomic<bool>* cancel) {
  RegionCheck out;
  for (const ProbeSettings& p : s.probes) {
    if (p.geometry.shape == ProbeShape::plane) continue;
    RegionStiffeningSettings rs;
    rs.tool_mm = p.initial_position();
    rs.tool_radius_mm = p.geometry.radius_mm;
    rs.region_radius_mm = s.integrator.region_radius_mm;
    rs.time_step_s = s.integrator.time_step_s;
    rs.cancel = cancel;
    rs.cache = cache;
    const RegionStiffeningEstimate e = estimate_region_stiffening(physics, fixed, rs);
    if (!e.valid) {
      out.log.push_back(
          fmt::format("regional solves: no estimate of their error under probe \"{}\" ({})", p.name, e.reason));
      continue;
    }
    if (!out.estimate || e.force_ratio > out.estimate->force_ratio) {
      out.estimate = e;
      out.probe = p.name;
    }
  }
  if (!out.estimate) return out;
  const RegionStiffeningEstimate& e = *out.estimate;
  out.log.push_back(
      fmt::format("regional solves within {:g} mm: under probe \"{}\" the press is estimated {:.1f} % too hard "
                  "(compliance {:.4g} mm/N of the whole model against {:.4g} with the far field held; "
                  "{} of {} free nodes awake; {} + {} CG iterations, {:.2f} s{})",
                  s.integrator.region_radius_mm, out.probe, 100.0 * e.error_rel(), e.compliance_full_mm_n,
                  e.compliance_region_mm_n, e.region_nodes, e.region_nodes + e.far_nodes, e.iterations_full,
                  e.iterations_region, e.seconds, e.loaded ? ", loaded from the cache" : ""));
  if (e.error_rel() > kRegionStiffeningWarnRel)
    out.warnings.push_back(fmt::format(
        "the regional solve (region_radius_mm {:g}) holds the far field still; on this support it presses about "
        "{:.2g}x too "
        "hard under probe \"{}\" (estimated: {:.0f} % force error: the object is held weakly and gives as a whole); "
        "for "
        "accuracy use \"integrator\": {} (no region; slower), or hold the object over a larger part (docs/model.md "
        "section 7)",
        s.integrator.region_radius_mm, e.force_ratio, out.probe, 100.0 * e.error_rel(),
        accurate_integrator_json(physics.material.poisson_ratio)));
  return out;
}

/// Moves a finished check into `out`.
void apply_region_check(const RegionCheck& c, PreparedScene& out) {
  out.region_stiffening = c.estimate;
  out.region_stiffening_probe = c.probe;
  out.log.insert(out.log.end(), c.log.begin(), c.log.end());
  out.warnings.insert(out.warnings.end(), c.warnings.begin(), c.warnings.end());
}

/// Runs `stage` and records its wall time under `name`.
template <class F>
void timed(PreparedScene& out, const char* name, F&& stage) {
  const auto t0 = std::chrono::steady_clock::now();
  stage();
  out.stage_seconds.emplace_back(name, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
}

}  // namespace

PreparedScene prepare_scene(const Scene& scene, const PrepareSceneOptions& options) {
  PreparedScene out;
  const SceneErrors errors{scene.file.empty() ? std::string("scene") : scene.file.string()};
  std::optional<Volume> volume;
  timed(out, "object", [&] { volume = build_object(scene, out); });
  timed(out, "material", [&] { calibrate_material(scene, volume ? &*volume : nullptr, options, out); });
  std::vector<std::uint8_t> fixed;
  timed(out, "support and probes", [&] {
    if (scene.palpation) {
      // an object without a scene of its own: the probe app's defaults around it
      fixed = place_palpation_defaults(*scene.palpation, options, out);
      return;
    }
    choose_integrator(scene, options, errors, out);
    fixed = fix_nodes(scene, errors, out);
    place_walls_and_probes(scene, fixed, errors, out);
  });
  const IntegratorSettings& integ = out.settings.integrator;
  if (integ.kind == IntegratorKind::implicit && integ.region_radius_mm > 0 &&
      options.region_check != RegionCheckTiming::none) {
    if (options.region_check == RegionCheckTiming::background) {
      // the estimate reads only what it is given (the physics is immutable and shared)
      out.pending_region_check = std::make_shared<BackgroundRegionCheck>(
          [physics = out.physics, fixed, settings = out.settings, cache = options.region_check_cache,
           nice = options.region_check_nice](const std::atomic<bool>& cancel) {
            (void)set_this_thread_name("vx-region-check");
            if (nice != 0) (void)set_this_thread_nice(nice);  // a real-time run goes first
            return check_region_support(*physics, fixed, settings, cache.get(), &cancel);
          });
    } else {
      timed(out, "region check", [&] {
        apply_region_check(
            check_region_support(*out.physics, fixed, out.settings, options.region_check_cache.get(), nullptr), out);
      });
    }
  }

  // the surface, only when someone will show or write it
  const Model& m = *out.model;
  if (options.surface) {
    timed(out, "surface", [&] {
      const bool paper = scene.outputs.surface_method != SurfaceMethod::staircase;
      VoxelSurfaceReport rep;
      out.surface = std::make_shared<const EmbeddedSurface>(m.is_2d() ? make_slice_surface(m)
                                                                      : make_voxel_surface(m, out.grid, paper, &rep));
    });
    out.log.push_back(fmt::format("surface ({}): {} vertices, {} triangles", to_string(out.surface->method),
                                  out.surface->num_vertices(), out.surface->num_triangles()));
  }
  out.settings.surface = out.surface;
  out.settings.skip_unneeded = options.skip_unneeded;
  return out;
}

BackgroundRegionCheck::BackgroundRegionCheck(std::function<RegionCheck(const std::atomic<bool>& cancel)> work)
    : result_(std::async(std::launch::async, [this, work = std::move(work)] { return work(cancel_); })) {}

BackgroundRegionCheck::~BackgroundRegionCheck() {
  cancel_.store(true);
  if (result_.valid()) result_.wait();
}

bool BackgroundRegionCheck::ready() const {
  return result_.valid() && result_.wait_for(std::chrono::seconds(0)) == std::future_status::ready;
}

RegionCheck BackgroundRegionCheck::get() {
  if (!result_.valid()) throw Error("the background region check was already taken");
  return result_.get();
}

std::optional<RegionCheck> take_region_check(PreparedScene& prepared, bool wait) {
  if (!prepared.pending_region_check || (!wait && !prepared.pending_region_check->ready())) return std::nullopt;
  RegionCheck c = prepared.pending_region_check->get();
  prepared.pending_region_check.reset();
  apply_region_check(c, prepared);
  return c;
}

}  // namespace vx
