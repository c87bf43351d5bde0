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

/// The implicit integrator's automatic step, s: the fast configuration's (pipeline/scene/
/// fast_configuration.h, docs/bench.md "Palpation at organ size"). A slow press is
/// quasi-static: the tool's motion and the device's update rate set the step, not the element's
/// period.
inline constexpr double kImplicitAutomaticTimeStepS = 0.02;

/// The automatic step ("dt_s": "auto") of `kind`: half the stable estimate for the explicit
/// integrators (the estimate is close to the real limit: a block blew up at 1.3x within 40
/// steps), the fast configuration's 20 ms for the implicit one (stable at any step; a slow press
/// is quasi-static; a scene caps it where a probe would move more than half its radius per
/// step). 0 when there is none (explicit Euler without damping is unstable at any step).
[[nodiscard]] double automatic_time_step(const TimeStepEstimate& estimate, IntegratorKind kind);

}  // namespace vx
