#pragma once
/// @file step_report.h
/// What one step did: filled by the integrators (integrators.h), the projective-dynamics solver
/// (projective_solver.h) and the static solve (static_solver.h). Counters and the step's status;
/// forces in N, lengths in mm.

#include <cstdint>

#include "sim/state.h"

namespace vx {

/// Why a tissue fell asleep (implicit with a region; docs/model.md section 7, "A tissue at rest
/// sleeps").
enum class SleepCause : std::uint8_t {
  none,        ///< it did not fall asleep in this step
  near_rest,   ///< no tool or load: within IntegratorSettings::region_rest_fraction of its rest shape, put there
  window_end,  ///< no tool or load: still short of that at the end of the idle refresh window, put at rest
  slow,        ///< by speed alone (gravity or a load: the rest shape unknown; or region_rest_fraction 0): no
               ///< node faster than region_rest_speed_mm_s, the tissue left where it is
};

[[nodiscard]] inline const char* to_string(SleepCause c) {
  switch (c) {
    case SleepCause::none: return "none";
    case SleepCause::near_rest: return "near_rest";
    case SleepCause::window_end: return "window_end";
    case SleepCause::slow: return "slow";
  }
  return "none";
}

/// What one step did.
struct StepReport {
  StepStatus status{StepStatus::ok};
  int iterations{0};                  ///< explicit: 1 force evaluation; implicit: global solves done
  double residual_n{0.0};             ///< implicit: RMS force imbalance per free node (N) at the last checked iterate
  double max_residual_n{0.0};         ///< implicit: the largest force imbalance on a free node (N), same iterate
  double max_update_mm{0.0};          ///< implicit: largest node move of the last iteration, mm
  std::int64_t inverted_elements{0};  ///< elements found inverted or flat in the step
  std::int64_t unconverged_rotations{0};  ///< rotation fits that hit max_iterations
  bool refactored{false};                 ///< implicit: the system matrix was (re)factored in this step
  bool factor_from_cache{false};          ///< implicit, refactored: the factor was loaded from the factor cache
  bool order_from_cache{false};           ///< implicit, refactored: factored in an order from the factor cache
  double factor_s{0.0};                   ///< implicit, refactored: wall time of the factorisation (or of the load), s
  /// implicit, refactored: the solver was built on a thread of its own while the tissue rested
  /// (IntegratorSettings::factor_in_background); factor_s is then its whole wall time there
  bool factored_in_background{false};
  double factor_wait_s{0.0};        ///< implicit: wall time this step waited for a solver built in the background, s
  bool factor_pending{false};       ///< implicit: a solver is being built in the background (the step was at rest)
  std::int64_t factor_nonzeros{0};  ///< implicit: nonzeros of the Cholesky factor L (cost of a solve)
  int contacts{0};                  ///< implicit with a contact provider: active constraints at the end
  int contact_rounds{0};            ///< implicit with a contact provider: active-set rounds in the step
  std::int64_t contact_columns{0};  ///< implicit: new columns A^-1 e_i solved in this step (each allocates once)
  std::int64_t region_elements{0};  ///< implicit with a region: elements computed (0: all)
  std::int64_t region_nodes{0};     ///< implicit with a region: free nodes solved for (0: all)
  bool asleep{false};               ///< implicit with a region: the tissue was at rest, nothing computed
  bool woke{false};                 ///< implicit with a region: the tissue slept before this step and not in it
  /// implicit: the threads the step's parallel loops were given (threads 0: the calling
  /// thread's OpenMP setting then; IntegratorSettings::wake_threads for a step that wakes)
  int threads{0};
  SleepCause fell_asleep{SleepCause::none};  ///< implicit with a region: the tissue fell asleep after this step
  double sleep_offset_mm{-1.0};              ///< ... its largest node displacement from its rest shape then, mm (before
                                             ///< it was put there); < 0: not known (gravity or a load)
  double since_release_s{0.0};    ///< ... simulated time since a tool last touched it (or since the start), s
  double release_offset_mm{0.0};  ///< ... its largest node displacement from its rest shape then, mm (0: unknown)
};

}  // namespace vx
