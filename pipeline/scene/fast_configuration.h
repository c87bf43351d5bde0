#pragma once
/// @file fast_configuration.h
/// The fast configuration for real-time palpation (docs/bench.md, "Palpation at organ size"), as
/// data: what a scene without an `integrator` key runs (prepare_scene) and what the probe app's
/// default scene runs (scene/palpation_defaults.h). Start from default_fast_configuration() and
/// change what you need, as Box2D's b2DefaultBodyDef.
///
/// The implicit integrator (backward Euler by projective dynamics, contact inside its solve) at
/// a 20 ms step with one local/global iteration per step, each step starting from the last
/// (x_n + dt v_n, the last rotations and contact set). A slow press is quasi-static: the
/// tissue's waves (h/c = 0.3 ms at 1 mm and 10 kPa) play no part in the force a hand feels at a
/// few mm/s, so the step is set by the tool's motion and the device's update rate, not by the
/// element's period. Measured on the press-and-slide of docs/bench.md: 3 % RMS force error
/// against symplectic Euler at its stable step on the 64 sphere.
///
/// Units: s, mm.

#include <string>

#include "haptics/device_force.h"
#include "sim/integrator_kind.h"
#include "sim/integrators.h"

namespace vx {

struct FastConfiguration {
  IntegratorKind kind{IntegratorKind::implicit};
  double time_step_s{0.0};  ///< the step of a model below large_model_nodes, s
  int iterations{0};        ///< local/global iterations per step
  /// A step that leaves no tool touching iterates up to this many times while a node moved more
  /// than free_tolerance_mm in the last iteration (IntegratorSettings::free_iterations): the
  /// tissue let go comes back to rest. Measured on the CI soak's organ at Poisson 0.45 (docs/model.md
  /// section 5, "The return to rest"): 3.4 % of the press from rest 4 s after the release with
  /// one iteration, 0.14 % with these; the steps in contact cost the same. Below large_model_nodes
  /// only: on a large model each extra iteration is a regional or full solve over the whole factor
  /// (a let-go tissue there is brought to rest by the regional solves' idle refresh, docs/model.md 7).
  int free_iterations{0};
  double free_tolerance_mm{0.0};
  /// Large models (large_model_nodes nodes or more): 30 ms steps with regional solves within
  /// 60 mm of a tool. Measured side by side against converged references in one `bench --scale`
  /// run (docs/bench.md, "The 5 % table"), RMS force error at 60 / 30 mm: the 128 sphere 3.46 /
  /// 3.98 %, the 256 sphere 4.76 / 5.69 %, the organ 5.19 / 5.53 %, the folded organ over its lower
  /// third 4.11 / 8.53 % (the sleeping elements' held rotations), at 1.07 to 1.5x the time per step.
  int large_model_nodes{0};
  double large_model_time_step_s{0.0};
  double large_model_region_radius_mm{0.0};
  /// A large model's factor sweeps in single precision (IntegratorSettings::single_precision_sweeps):
  /// the folded organ's regional step about a sixth faster for about 1e-5 of the force (docs/bench.md,
  /// "Single-precision sweeps"). A smaller model's factor is swept from the caches, so it stays in
  /// double there.
  bool large_model_single_precision_sweeps{true};
  /// The device's force updates span this many steps (a half sine spans at least two).
  double device_update_steps{0.0};

  [[nodiscard]] bool large(int nodes) const { return nodes >= large_model_nodes; }
  /// The step of a model with `nodes` nodes: the large model's for a large model.
  [[nodiscard]] double time_step_for(int nodes) const { return large(nodes) ? large_model_time_step_s : time_step_s; }
  /// Regional solves within this radius of a tool (mm) for a large model; 0 (none) otherwise.
  [[nodiscard]] double region_radius_for(int nodes) const { return large(nodes) ? large_model_region_radius_mm : 0.0; }
  /// The iterations a step that leaves no tool touching may take (free_iterations): 0 for a large
  /// model, whose extra iterations would be regional or full solves (its tissue let go is brought
  /// to rest by the regional solves' idle refresh).
  [[nodiscard]] int free_iterations_for(int nodes) const { return large(nodes) ? 0 : free_iterations; }
  /// The device's force update interval that goes with the step, s.
  [[nodiscard]] double device_update_interval_for(int nodes) const {
    return device_update_steps * time_step_for(nodes);
  }
  /// The integrator for a model of `nodes` nodes (kind, step, iterations, region; one thread).
  [[nodiscard]] IntegratorSettings integrator_for(int nodes) const;
  /// The device with the paper's half sines for a model of `nodes` nodes.
  [[nodiscard]] DeviceForceSettings device_for(int nodes) const;
};

/// From this Poisson ratio a run whose implicit steps take a few fixed local/global iterations
/// gets incompressible_iterations_warning().
inline constexpr double kSlowVolumePoissonRatio = 0.4;
/// The most fixed iterations per step that incompressible_iterations_warning() speaks for (5
/// iterations were measured outside 5 %; more were not measured).
inline constexpr int kSlowVolumeMaxIterations = 5;

/// What a run at Poisson ratio `poisson_ratio` with `integrator` is told when its force is off a
/// converged run for want of iterations: implicit steps of at most kSlowVolumeMaxIterations fixed
/// local/global iterations (no residual tolerance) on a nearly incompressible tissue
/// (kSlowVolumePoissonRatio or more), whose volume term those iterations converge slowly: the
/// force measured against converged references (docs/bench.md, "The 5 % table at Poisson 0.45") and the
/// configuration that is right. Empty when that does not apply.
[[nodiscard]] std::string incompressible_iterations_warning(const IntegratorSettings& integrator, double poisson_ratio);
/// The same in one line for a screen (the probe app's status line; the warning goes to its
/// console); empty when it does not apply.
[[nodiscard]] std::string incompressible_iterations_status(const IntegratorSettings& integrator, double poisson_ratio);
/// The integrator a warning recommends for forces within 5 % of a converged run, as scene JSON
/// (`"integrator": ...`): implicit 10 ms steps without a region, 5 iterations; from
/// kSlowVolumePoissonRatio on, iterated to a 1e-5 N residual (at most 30 iterations), which
/// incompressible_iterations_warning() does not warn about.
[[nodiscard]] std::string accurate_integrator_json(double poisson_ratio);

/// The fast configuration's values: implicit, 20 ms steps (kImplicitAutomaticTimeStepS,
/// sim/time_step.h), one iteration (up to 8 while no tool touches, until no node moves 1e-6 mm);
/// from 20,000 nodes 30 ms steps with regional solves within 60 mm of a tool; the device updated
/// every two steps.
[[nodiscard]] FastConfiguration default_fast_configuration();

}  // namespace vx
