#pragma once
/// @file integrators.h
/// Time integration (MODEL.md section 2, paper 2.1) behind one interface, stability limits
/// and a static solver.
///
/// - explicit_euler: the paper's eq. 1-2 exactly: v' = v + dt F(x, v)/m, x' = x + dt v
///   (the position moves with the OLD velocity). Without damping it gains energy every step
///   for any dt (unconditionally unstable); with damping it is stable only for
///   dt <= ~c_e / k_e = 2 zeta / omega_e (see estimate_time_steps()).
/// - symplectic_euler: v' = v + dt F(x, v)/m, x' = x + dt v' (semi-implicit). Undamped, its
///   energy stays bounded for dt < 2 / omega_max.
/// - implicit: backward Euler by projective dynamics (Bouaziz et al. 2014). The element energy
///   k/2 sum_i w_i |x_i - c - Q R0_i|^2 is a projective term, so each step minimises
///     1/(2 dt^2) |x - y|_M^2 + sum_e E_e(x) + sum_e D_e(x),   y = x_n + dt v_n + dt^2 M^-1 f_ext,
///   by alternating local rotation fits and a global solve with the constant matrix
///     M / dt^2 + sum_e (k_e + k_v,e + c_e/dt) (diag(w) - w w^T / W)_e
///   (the weighted centring operator of element e, material.h),
///   prefactored once by a sparse Cholesky (Eigen SimplicialLDLT, AMD ordering) with fixed
///   nodes eliminated. Damping D_e = c_e/(2 dt) min_R sum_i |r_i - R r_i^n|^2 (the vertex
///   motion during the step relative to the element's best rigid motion) is the backward
///   Euler form of the explicit damping force and also a projective term. Stable for any dt.
///   Contact (set_contact_provider()): the probes and walls are unilateral node constraints
///   n_i . x_i >= n_i . p_i of the same minimisation, solved exactly in every global step (an
///   active-set iteration on the Schur complement of the prefactored matrix), so the reaction
///   force is the constraint multiplier, right at any dt. The contact is perfectly inelastic
///   (v = (x' - x_n)/dt; restitution does not apply) and frictionless.
///
/// Units: dt in s, positions mm, velocities mm/s, forces N, masses N*s^2/mm (material.h).

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "physics/elements.h"
#include "physics/material.h"
#include "sim/state.h"

namespace vx {

/// The available integrators.
enum class IntegratorKind : std::uint8_t { explicit_euler, symplectic_euler, implicit };
[[nodiscard]] const char* to_string(IntegratorKind k);
/// Parses "explicit_euler", "symplectic_euler" or "implicit"; throws vx::Error otherwise.
[[nodiscard]] IntegratorKind parse_integrator(const std::string& s);

/// Limits beyond which a step is refused (not applied) and the state flagged.
struct StabilityLimits {
  double max_speed_mm_s{1.0e5};     ///< any node faster than this (100 m/s): runaway
  double max_displacement_mm{0.0};  ///< any node farther from rest; <= 0: 10 x the rest bounding-box diagonal
  bool stop_on_runaway{true};       ///< false: flag a runaway but apply the step and go on
};

/// One unilateral contact constraint of an implicit step: node `node` must stay on the free side
/// of the plane through `point_mm` with unit normal `normal`,  normal . x_node >= normal . point_mm
/// (the probe's or wall's surface linearised at the node: its closest surface point and outward
/// normal, see probe_signed_distance() in contact.h).
struct ContactConstraint {
  std::int32_t node{0};
  std::int32_t owner{0};  ///< who pushes (the provider's numbering: a probe, a wall face)
  Eigen::Vector3d point_mm{Eigen::Vector3d::Zero()};
  Eigen::Vector3d normal{Eigen::Vector3d::UnitZ()};
  /// integrator output: the multiplier, the force of the surface on the node along `normal`
  /// (N, >= 0; the force of the node on the probe is -force_n * normal)
  double force_n{0.0};
};

/// Supplies the contact constraints of an implicit step (the simulation's probes and walls;
/// contact.h finds them). The implicit integrator calls it with its iterates during the step.
class ContactProvider {
 public:
  virtual ~ContactProvider() = default;
  /// Appends a constraint (linearised at x) for every collidable node that `x` (3 x nodes, mm)
  /// puts inside a probe or beyond a wall, and with `near` also for the nodes within the
  /// provider's margin outside them (candidates that may touch within the step). Each
  /// (owner, node) pair at most once. Must not allocate in steady state.
  virtual void collect(const Eigen::Matrix3Xd& x, bool near, std::vector<ContactConstraint>& out) = 0;
};

/// Settings of an integrator, with defaults that suit soft tissue at voxel size ~1 mm.
struct IntegratorSettings {
  IntegratorKind kind{IntegratorKind::symplectic_euler};
  double time_step_s{1.0e-4};
  int threads{0};              ///< 0: OpenMP default (OMP_NUM_THREADS or all cores)
  bool track_energy{false};    ///< fill SimState::energies every step (small extra cost)
  RotationFitSettings rotation;
  // implicit only
  int max_iterations{10};      ///< local/global iterations per step
  double tolerance_mm{0.0};    ///< > 0: stop early once no node moved more than this in an iteration
  StabilityLimits limits;
};

/// What one step did.
struct StepReport {
  StepStatus status{StepStatus::ok};
  int iterations{0};               ///< explicit: 1 force evaluation; implicit: global solves done
  double residual_n{0.0};          ///< implicit: RMS force imbalance per free node (N) at the last checked iterate
  double max_update_mm{0.0};       ///< implicit: largest node move of the last iteration, mm
  std::int64_t inverted_elements{0};     ///< elements found inverted or flat in the step
  std::int64_t unconverged_rotations{0}; ///< rotation fits that hit max_iterations
  bool refactored{false};          ///< implicit: the system matrix was (re)factored in this step
  std::int64_t factor_nonzeros{0}; ///< implicit: nonzeros of the Cholesky factor L (cost of a solve)
  int contacts{0};                 ///< implicit with a contact provider: active constraints at the end
  int contact_rounds{0};           ///< implicit with a contact provider: active-set rounds in the step
  std::int64_t contact_columns{0}; ///< implicit: new columns A^-1 e_i solved in this step (each allocates once)
};

/// One time-integration scheme. An integrator may keep per-state caches (the implicit one
/// keeps its factorisation, rebuilt when the state, its fixed nodes or the time step change),
/// so use one integrator per state.
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

 protected:
  IntegratorSettings settings_;
};

/// Creates the integrator `settings.kind`. Throws vx::Error for invalid settings.
[[nodiscard]] std::unique_ptr<Integrator> make_integrator(const IntegratorSettings& settings);

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
};
[[nodiscard]] TimeStepEstimate estimate_time_steps(const PhysicsModel& physics);
/// The estimate for one integrator.
[[nodiscard]] double stable_time_step(const PhysicsModel& physics, IntegratorKind kind);

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
