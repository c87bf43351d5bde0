#pragma once
/// @file step_report.h
/// What one step did: filled by the integrators (integrators.h), the projective-dynamics solver
/// (projective_solver.h) and the static solve (static_solver.h). Counters and the step's status;
/// forces in N, lengths in mm.

#include <cstdint>

#include "sim/state.h"

namespace vx {

/// What one step did.
struct StepReport {
  StepStatus status{StepStatus::ok};
  int iterations{0};               ///< explicit: 1 force evaluation; implicit: global solves done
  double residual_n{0.0};          ///< implicit: RMS force imbalance per free node (N) at the last checked iterate
  double max_residual_n{0.0};      ///< implicit: the largest force imbalance on a free node (N), same iterate
  double max_update_mm{0.0};       ///< implicit: largest node move of the last iteration, mm
  std::int64_t inverted_elements{0};     ///< elements found inverted or flat in the step
  std::int64_t unconverged_rotations{0}; ///< rotation fits that hit max_iterations
  bool refactored{false};          ///< implicit: the system matrix was (re)factored in this step
  bool factor_from_cache{false};   ///< implicit, refactored: the factor was loaded from the factor cache
  double factor_s{0.0};            ///< implicit, refactored: wall time of the factorisation (or of the load), s
  std::int64_t factor_nonzeros{0}; ///< implicit: nonzeros of the Cholesky factor L (cost of a solve)
  int contacts{0};                 ///< implicit with a contact provider: active constraints at the end
  int contact_rounds{0};           ///< implicit with a contact provider: active-set rounds in the step
  std::int64_t contact_columns{0}; ///< implicit: new columns A^-1 e_i solved in this step (each allocates once)
  std::int64_t region_elements{0}; ///< implicit with a region: elements computed (0: all)
  std::int64_t region_nodes{0};    ///< implicit with a region: free nodes solved for (0: all)
  bool asleep{false};              ///< implicit with a region: the tissue was at rest, nothing computed
};

}  // namespace vx
