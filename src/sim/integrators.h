#pragma once
/// @file integrators.h
/// Time integration (docs/model.md section 7, paper 2.1) behind one interface.
///
/// - explicit_euler: the paper's eq. 1-2 exactly: v' = v + dt F(x, v)/m, x' = x + dt v
///   (the position moves with the OLD velocity). Without damping it gains energy every step
///   for any dt (unconditionally unstable); with damping it is stable only for
///   dt <= ~c_e / k_e = 2 zeta / omega_e (time_step.h).
/// - symplectic_euler: v' = v + dt F(x, v)/m, x' = x + dt v' (semi-implicit). Undamped, its
///   energy stays bounded for dt < 2 / omega_max.
/// - implicit: backward Euler by projective dynamics (projective_solver.h): each step minimises
///     1/(2 dt^2) |x - y|_M^2 + sum_e E_e(x) + sum_e D_e(x),   y = x_n + dt v_n + dt^2 M^-1 f_ext,
///   by local rotation fits and global solves with a prefactored constant matrix; stable for
///   any dt. Contact (set_contact_provider()): the probes and walls are unilateral node
///   constraints of the same minimisation, solved exactly in every global step
///   (contact_active_set.h), so the reaction force is the constraint multiplier, right at any
///   dt. The contact is perfectly inelastic (v = (x' - x_n)/dt; restitution does not apply)
///   and frictionless. Its factorisation lives in the state (SimState::integrator_cache).
///
/// The stable steps are in time_step.h, the static solve in static_solver.h.
/// Units: dt in s, positions mm, velocities mm/s, forces N, masses N*s^2/mm (material.h).

#include <Eigen/Core>
#include <atomic>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "physics/elements.h"
#include "physics/physics_model.h"
#include "sim/contact_constraint.h"
#include "sim/integrator_kind.h"
#include "sim/state.h"
#include "sim/step_report.h"
#include "sim/time_step.h"

namespace vx {

class FactorCache;  // sim/sparse_factor.h

/// Limits beyond which a step is refused (not applied) and the state flagged.
struct StabilityLimits {
  double max_speed_mm_s{1.0e5};     ///< any node faster than this (100 m/s): runaway
  double max_displacement_mm{0.0};  ///< any node farther from rest; <= 0: 10 x the rest bounding-box diagonal
  bool stop_on_runaway{true};       ///< false: flag a runaway but apply the step and go on
};

/// Settings of an integrator, with defaults that suit soft tissue at voxel size ~1 mm.
struct IntegratorSettings {
  IntegratorKind kind{IntegratorKind::symplectic_euler};
  double time_step_s{1.0e-4};
  int threads{0};            ///< 0: OpenMP default (OMP_NUM_THREADS or all cores)
  bool track_energy{false};  ///< fill SimState::energies every step (small extra cost)
  RotationFitSettings rotation;
  // implicit only
  int max_iterations{10};    ///< local/global iterations per step
  double tolerance_mm{0.0};  ///< > 0: stop early once no node moved more than this in an iteration
  /// > 0: stop early once the largest force imbalance on a free node is below this, N
  /// (ProjectiveIterations::residual_tolerance_n)
  double residual_tolerance_n{0.0};
  /// > max_iterations: a step that leaves no tool touching the tissue goes on iterating, up to
  /// this many iterations, while a node moved more than free_tolerance_mm in the last one
  /// (ProjectiveIterations::free_max_iterations): the fast configuration's tissue let go comes
  /// back to rest at Poisson 0.45 (docs/model.md section 5, "The return to rest"). 0: off.
  int free_iterations{0};
  double free_tolerance_mm{0.0};
  /// > 0 (implicit, with a contact provider that names its tools): regional solves, the
  /// rotation fits and the global solve only within this distance of a tool, mm
  /// (ProjectiveSolver::set_region; the rest sleeps). The region follows a tool once it has
  /// moved a quarter of the radius. 0: every node every step.
  double region_radius_mm{0.0};
  /// implicit with a region: while the tissue may be moving and no tool touches (after a
  /// release, or from the start), every this many steps is a full solve, so the far field that
  /// slept through the press relaxes back to rest (without it, it stays where the last full solve
  /// left it: 1.5 to 1.8 % of the largest displacement on the folded organ; a ball of 32 voxels
  /// 1.5 s after the release: 12 % without, 2 % every 8th step, 0.5 % every 4th). A full step
  /// costs about 2.5 regional ones on an organ. 0: never.
  int region_idle_refresh_steps{4};
  /// ... for at most this long after the last contact, s. A tissue with no tool, no gravity, no
  /// external force and its fixed nodes at their rest positions has its rest shape as its one
  /// equilibrium: if it is not at rest by then (region_rest_fraction), it is put there and
  /// sleeps (the static solution; so such a tissue always sleeps within this time). With gravity
  /// or a load, a tissue not at rest by then (region_rest_speed_mm_s) is left to the regional
  /// solves without sleeping.
  double region_idle_refresh_window_s{10.0};
  /// implicit with a region: the nodes outside the region's closure move by a polynomial
  /// displacement field of this degree over their positions (1: affine, 2: quadratic), the
  /// mass-weighted projection of their exact solution in every step, instead of sleeping where
  /// the last full solve left them, so their inertia follows the press (docs/model.md section 7,
  /// "The far field carried"). 0: held, the default: carried costs 1.2 to 1.4x per step on the
  /// organ phantom and 1.66x on the folded organ for 0.1 to 1 % of force error (docs/bench.md).
  int region_far_field_degree{0};
  /// Diagnostics of the regional error (docs/bench.md, "Where the regional error comes from"):
  /// true: the regional steps fit rotations in the region only but solve the whole model, so the
  /// far field moves (its inertia is right) and only its rotations sleep. Costs a full solve.
  bool region_solve_far_field{false};
  /// false: a region move keeps the far field as it is (no full solve at the move; the elements
  /// that join the region are fitted from the next step on).
  bool region_refresh_on_move{true};
  /// true: every step's node passes and contact checks visit every node even while the regional
  /// solves hold the far field still (ProjectiveSolver::still_far_field_nodes; the same bits,
  /// slower: the bench's side by side, docs/bench.md).
  bool region_visit_still_far_field{false};
  /// implicit: the factor's supernodal sweeps read L's values in single precision, the sums in
  /// double (ProjectiveSolver::use_single_precision_sweeps): a regional step on the folded organ
  /// about a sixth faster for about 1e-5 of the force (docs/bench.md, "Single-precision sweeps"),
  /// and the factor a third smaller in memory. The fast configuration of a large model sets it.
  bool single_precision_sweeps{false};
  /// implicit with a region: once no tool touches and a full solve finds the tissue at rest, it
  /// sleeps as a whole: its steps only advance the time (no rotation fit, no solve, velocities
  /// 0) until a tool comes within the contact margin of a node, the state is replaced, or the
  /// gravity, the external forces or the fixed nodes change. A tissue left alone costs nothing
  /// (docs/model.md section 7, "A tissue at rest sleeps"). At rest means no node faster than this,
  /// mm/s, and, when its rest shape is known (no gravity, no external force, the fixed nodes at
  /// their rest positions), every node within region_rest_fraction of it too: then it is put
  /// exactly at its rest shape as it falls asleep. 0: never.
  double region_rest_speed_mm_s{0.05};
  /// ... the largest node displacement from the rest shape at which a tissue with a known rest
  /// shape may fall asleep (and is put at rest), as a fraction of its largest node displacement
  /// when the last tool let go (or 1 um, whichever is larger). A speed alone stopped the folded
  /// organ's return at 0.8 % of the press (a stem-held organ creeps back at under 0.05 mm/s, and
  /// the regional steps between full ones zero the far field's velocity).
  /// 0: by speed alone, never put at rest (as before).
  double region_rest_fraction{0.005};
  /// implicit: the contact solve's cache (forward vectors and G between the nodes tools touch,
  /// contact_active_set.h) reserved and resident from each factorisation on, instead of filling
  /// as tools visit new nodes (up to tens of MB on an organ): for a long session whose memory must
  /// stay flat (the probe app). Costs its whole bound at once (ContactActiveSet::reserve).
  bool reserve_contact_cache{false};
  /// implicit with a region (and region_rest_speed_mm_s > 0): a solver needed while the tissue is
  /// exactly at its rest shape and at rest (no gravity, no external force, the fixed nodes at
  /// rest, no node within the contact margin of a tool or a wall) is built on a thread of its own;
  /// meanwhile the tissue sleeps (its steps advance the time, as the solver would: its rest shape
  /// is its one equilibrium). A step whose tissue is not at rest any more (a tool within reach, a
  /// load) waits for it (StepReport::factor_wait_s). The steps are the same bits whenever the
  /// solver is ready: the tissue starts asleep either way. For a session that starts while a large
  /// model factors (the probe app; docs/model.md section 7, "A solver built while the tissue rests").
  bool factor_in_background{false};
  /// implicit with a region, `threads` 0 (each calling thread's own OpenMP setting): the step
  /// that wakes a sleeping tissue (a tool's first touch after a rest: a full solve and the
  /// region's set-up, about 0.3 s on the folded organ on one thread) runs on this many threads,
  /// whatever the caller's setting is then. For the probe app, which steps on one thread while
  /// the tissue rests ahead of real time and learns of a slow step only after it
  /// (apps/probe/thread_share.h). 0: the caller's setting. The same bits on any count.
  int wake_threads{0};
  /// Tests: extra wall time on building a solver in the background (stands for a large model's
  /// factorisation: it cannot be stopped), s.
  double factor_in_background_delay_s{0.0};
  /// The caller's word that a solver being built in the background is not wanted any more (a
  /// session that quits; null: never): once true, the build stops at its next stage (Cancelled,
  /// ProjectiveSolver's constructor) and keeps nothing, and a step waiting for it throws Cancelled
  /// within 20 ms instead of waiting on. Its own stop (IntegratorCache::pending_stop) is apart.
  std::shared_ptr<const std::atomic<bool>> stop_background;
  /// Called first on the thread that builds a solver in the background (null: nothing): the
  /// caller names it, so that `top -H`, `perf` and `gdb` tell it from the thread it was started
  /// from (the probe app: "vx-factor", where it was "vx-physics" like the physics).
  std::function<void()> background_thread_start;
  /// implicit: where factors are looked up before and kept after a factorisation (by the
  /// content of the matrix: sparse_factor.h); null: every solver factors. Shared, not owned by
  /// one integrator: pipeline/io/factor_cache.h keeps one in a folder.
  std::shared_ptr<FactorCache> factor_cache;
  StabilityLimits limits;
};

/// One time-integration scheme. What it keeps per state between steps lives in the state
/// (the implicit integrator's factorisation, rebuilt when the state's fixed nodes, the time step
/// or the damping change), so one integrator may step several states.
class Integrator {
 public:
  explicit Integrator(const IntegratorSettings& settings) : settings_(settings) {}
  virtual ~Integrator() = default;
  Integrator(const Integrator&) = delete;
  Integrator& operator=(const Integrator&) = delete;

  [[nodiscard]] IntegratorKind kind() const { return settings_.kind; }
  [[nodiscard]] const IntegratorSettings& settings() const { return settings_; }

  /// Advances `state` by one time step. A stopped state (status non_finite, or runaway with
  /// limits.stop_on_runaway) is left unchanged and its status returned; a runaway flagged
  /// without stop_on_runaway keeps its status and message but goes on stepping.
  /// Allocation-free (the implicit integrator allocates when it factors, and with a contact
  /// provider when a node first touches: its column A^-1 e_i is solved and cached, and the
  /// contact buffers grow to the largest contact set seen).
  virtual StepReport step(SimState& state) = 0;

  /// Steps `steps` times or until the state stops; returns the last report.
  StepReport advance(SimState& state, int steps);

  /// True when the integrator can take contact constraints into its solve (implicit).
  [[nodiscard]] virtual bool solves_contact() const { return false; }
  /// Implicit: makes the constraints of `provider` part of every following step's solve (null:
  /// none). The provider must outlive the integrator or be unset. Others ignore it.
  virtual void set_contact_provider(ContactProvider* /*provider*/) {}
  /// Implicit: the constraints active at the end of the last step with their forces (N); empty
  /// for the other integrators and without a provider.
  [[nodiscard]] virtual const std::vector<ContactConstraint>& contacts() const;
  /// Implicit: g (m x m) = the compliance of one step between the free `nodes` (the inverse of
  /// its system matrix, mm/N) from the state's factor; false for the other integrators, before
  /// the first step, or when a node is fixed. For the local contact model (local_contact.h).
  virtual bool contact_compliance(SimState& /*state*/, const std::vector<std::int32_t>& /*nodes*/,
                                  Eigen::MatrixXd& /*g*/) {
    return false;
  }

 protected:
  IntegratorSettings settings_;
};

/// Creates the integrator `settings.kind`. Throws vx::Error for invalid settings.
[[nodiscard]] std::unique_ptr<Integrator> make_integrator(const IntegratorSettings& settings);

}  // namespace vx
