#pragma once
/// @file static_solver.h
/// Static equilibrium (docs/model.md section 7): the projective-dynamics solver
/// (projective_solver.h) without inertia, for calibration checks and verification.

#include "physics/elements.h"
#include "sim/state.h"
#include "sim/step_report.h"

namespace vx {

/// Settings of the static solver.
struct StaticSolveSettings {
  int max_iterations{500};
  double tolerance_mm{1e-9};  ///< stop once no node moves more than this in an iteration
  int threads{0};
  RotationFitSettings rotation{20, 1e-12};
};

/// Moves the free nodes of `state` to static equilibrium under gravity and external forces,
/// with fixed nodes held where they are (local/global iterations without inertia). Velocities
/// are set to zero. Throws vx::Error when a part of the model is held by no fixed node.
StepReport solve_static(SimState& state, const StaticSolveSettings& settings = {});

}  // namespace vx
