#pragma once
/// @file time_step.h
/// Time-step limits of a physics model and the automatic step of each integrator
/// (docs/model.md section 7): the one place where a step is chosen by integrator.

#include <limits>

#include "physics/physics_model.h"
#include "sim/integrator_kind.h"

namespace vx {

/// Time-step limits of a physics model, from its stiffest element (Gershgorin bounds of the
/// linearised system: per node, omega^2 <= sum_e (|K_e| row sum + 2 w_i (1 - w_i/W_e) k_v,e) / m_i and
/// the damping rate gamma <= sum_e 2 w_i (1 - w_i/W_e) c_e / m_i, with w_i the vertex weight
/// and W_e the element's weight sum; conservative, not tight).
struct TimeStepEstimate {
  double highest_frequency_hz{0.0};  ///< bound on the highest vibration frequency
  double element_period_s{0.0};      ///< shortest element period 2 pi sqrt(m_unit / k_e)
  /// symplectic Euler: dt <= (sqrt(4 omega^2 + gamma^2) - gamma) / omega^2 at the worst node
  /// (2 / omega without damping)
  double symplectic_euler_s{0.0};
  /// explicit Euler (the paper): dt <= 0.9 min_i (damping / stiffness Gershgorin sums at node i)
  /// and dt <= 0.9 * 2 / gamma_max; the sums' ratio is c / k for the paper's cube element and
  /// ~c / k_e in general (less where the consistent gradient stiffens an element); measured
  /// limits are 1.1x (gradational cube) to 3.1x (gradational ball) the estimate; 0 without
  /// damping (unstable at any dt)
  double explicit_euler_s{0.0};
  /// implicit: unconditionally stable (infinity); accuracy falls off above ~element_period_s / 10
  double implicit_s{std::numeric_limits<double>::infinity()};

  /// The stable step of `kind` (infinity for implicit, 0 for undamped explicit Euler).
  [[nodiscard]] double limit(IntegratorKind kind) const;
};
[[nodiscard]] TimeStepEstimate estimate_time_steps(const PhysicsModel& physics);
/// The estimate for one integrator: estimate_time_steps(physics).limit(kind).
[[nodiscard]] double stable_time_step(const PhysicsModel& physics, IntegratorKind kind);


/// The fast configuration for real-time palpation (docs/bench.md, "Palpation at organ size"):
/// the implicit integrator (backward Euler by projective dynamics, contact inside its solve) at
/// a 20 ms step with one local/global iteration per step, each step starting from the last
/// (x_n + dt v_n, the last rotations and contact set). A slow press is quasi-static: the
/// tissue's waves (h/c = 0.3 ms at 1 mm and 10 kPa) play no part in the force a hand feels at a
/// few mm/s, so the step is set by the tool's motion and the device's update rate, not by the
/// element's period. Measured on the press-and-slide of docs/bench.md: 3 % RMS force error
/// against symplectic Euler at its stable step on the 64 sphere.
struct FastConfiguration {
  static constexpr IntegratorKind kind = IntegratorKind::implicit;
  static constexpr double time_step_s = 0.02;
  static constexpr int iterations = 1;
  /// Large models (large_model_nodes nodes or more): 30 ms steps with regional solves within
  /// 30 mm of a tool. Measured (docs/bench.md): the 128 sphere (60,580 nodes) 1.05x real time on
  /// one thread, 1.22x on two, at 3.8 % RMS force error, against 0.27-0.32x at 1.8 % for 20 ms
  /// steps without a region.
  static constexpr int large_model_nodes = 20000;
  static constexpr double large_model_time_step_s = 0.03;
  static constexpr double large_model_region_radius_mm = 30.0;
  [[nodiscard]] static constexpr bool large(int nodes) { return nodes >= large_model_nodes; }
  /// The step of a model with `nodes` nodes: 30 ms for a large model, 20 ms otherwise.
  [[nodiscard]] static constexpr double time_step_for(int nodes) {
    return large(nodes) ? large_model_time_step_s : time_step_s;
  }
  /// Regional solves within this radius of a tool (mm) for a large model; 0 (none) otherwise.
  [[nodiscard]] static constexpr double region_radius_for(int nodes) {
    return large(nodes) ? large_model_region_radius_mm : 0.0;
  }
  /// The device's force update interval that goes with the step: two steps (a half sine spans
  /// at least two).
  [[nodiscard]] static constexpr double device_update_interval_for(int nodes) { return 2.0 * time_step_for(nodes); }
};

/// The automatic step ("dt_s": "auto") of `kind`: half the stable estimate for the explicit
/// integrators (the estimate is close to the real limit: a block blew up at 1.3x within 40
/// steps), the fast configuration's 20 ms for the implicit one (stable at any step; a slow press
/// is quasi-static; a scene caps it where a probe would move more than half its radius per
/// step). 0 when there is none (explicit Euler without damping is unstable at any step).
[[nodiscard]] double automatic_time_step(const TimeStepEstimate& estimate, IntegratorKind kind);

}  // namespace vx
