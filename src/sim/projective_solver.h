#pragma once
/// @file projective_solver.h
/// The projective-dynamics solver (Bouaziz et al. 2014; docs/model.md section 7): the implicit
/// integrator's step and the static solve. Precompute once (the constructor: number the free
/// nodes, assemble and factor the constant system matrix), then solve many times (solve():
/// local/global iterations), as libigl's arap_precomputation / arap_solve.
///
/// Each solve minimises over the free nodes
///   1/(2 dt^2) |x - y|_M^2 + sum_e E_e(x) + sum_e D_e(x) - x . f,
/// the element energy E_e = mu V |F - Q|^2 + k/2 sum_i w_i |r_i - F R0_i|^2 (elements.h) with
/// F the consistent gradient, plus the volume term (Poisson ratio > 0) and the damping term
/// D_e = c_e/(2 dt) min_R sum_i w_i |r_i - R r_i^n|^2 (the vertex motion during the step relative
/// to the element's best rigid motion: the backward-Euler form of the explicit damping force).
/// Every term is projective, so the iteration alternates
///   local:  per element the rotation fits (Q, the volume term's T, the damping's R) and the
///           per-entry targets t_i = 2 mu V Q g_i + w_i (k_v T R0_i + (c/dt) R r_i^n);
///   global: A x = b + sum_e (targets gathered per node), with the constant matrix
///           A = M/dt^2 + sum_e (K_e + (k_v,e + c_e/dt) (diag(w) - w w^T / W)_e)
///           (K_e: the element's elastic matrix, elements.h), prefactored (sparse_factor.h),
///           the fixed nodes eliminated (their coupling A_fc x_c moved to the right-hand side).
/// Without inertia (the static solve) the mass term is absent and every connected part of the
/// model must hold a fixed node. Contact (contact_active_set.h): the probes and walls are
/// unilateral node constraints of the same minimisation, solved exactly in every global step.
///
/// Allocation: the constructor allocates everything a solve needs, except the contact set's
/// cache of columns, which grows when a node first touches.
/// Units: positions mm, forces N, masses N*s^2/mm, dt s.

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <memory>
#include <utility>
#include <vector>

#include "physics/elements.h"
#include "physics/material.h"
#include "sim/contact_active_set.h"
#include "sim/contact_constraint.h"
#include "sim/sparse_factor.h"

namespace vx {

struct SimState;
struct StepReport;

/// What the precomputation depends on (a change needs a new solver).
struct ProjectiveSetup {
  double time_step_s{1.0e-3};  ///< dt, s (the static solve uses 1)
  bool inertia{true};          ///< false: the static solve (no mass term)
  bool damping{false};         ///< the damping term c_e/dt (implicit steps of a damped material)
  /// The factor swept in single precision (SparseFactor::use_single_precision_sweeps; a factor
  /// cache keeps it apart, FactorKey::single): IntegratorSettings::single_precision_sweeps.
  bool single_precision_sweeps{false};

  [[nodiscard]] bool operator==(const ProjectiveSetup&) const = default;
};

/// How far a solve iterates.
struct ProjectiveIterations {
  int max_iterations{10};    ///< local/global iterations
  double tolerance_mm{0.0};  ///< > 0: stop once no node moved more than this in an iteration
  /// > 0: stop once the largest force imbalance on a free node is below this (N): the residual
  /// of the step's minimisation at the current iterate, rhs(x_k) - rhs(x_{k-1}) (A x_k =
  /// rhs(x_{k-1}) after the global solve). Checked before each global solve after the first, so
  /// a step costs at least two local steps and one solve.
  double residual_tolerance_n{0.0};
  /// > max_iterations: a solve whose last iteration left no tool in contact (no active
  /// constraint of a tool: ContactProvider::tool_owners; walls do not count) goes on iterating,
  /// up to this many iterations in all, while a node moved more than `free_tolerance_mm` in the
  /// last one. A tissue let go then relaxes at about the converged step's rate, and the steps in
  /// contact cost what max_iterations makes them cost (docs/model.md section 5, "The return to
  /// rest"). Checked after the global step: a step that stops costs no extra local step.
  int free_max_iterations{0};
  double free_tolerance_mm{0.0};
  RotationFitSettings rotation;
  int threads{0};  ///< 0: OpenMP default
  /// The caller's word on the constant right-hand side's inputs besides the positions: its
  /// gravity, and whether any node has an external force. With no external force at this solve
  /// and the last, and the same gravity, a steady regional solve that follows two over the same
  /// closure passes over the closure's rows only (docs/model.md section 7, "Passes over the
  /// closure only"). Not given (`inputs_given` false): every row, every solve.
  bool inputs_given{false};
  Eigen::Vector3d gravity_mm_s2{Eigen::Vector3d::Zero()};
  bool external_forces{true};
};

/// The free and fixed numbering of a model's nodes.
struct NodeNumbering {
  std::vector<int> free_index;   ///< nodes -> free index, -1 for a fixed node
  std::vector<int> fixed_index;  ///< nodes -> fixed index, -1 for a free node
  std::vector<int> free_nodes;   ///< free index -> node
  std::vector<int> fixed_nodes;  ///< fixed index -> node
};
/// Numbers the nodes in order, free and fixed apart (node_fixed[i] = 1: kinematic).
[[nodiscard]] NodeNumbering number_nodes(const std::vector<std::uint8_t>& node_fixed);

/// The global matrix of `setup` over the free nodes (scalar: the same for x, y and z), as the
/// solver factors it: A = [M/dt^2] + sum_e (K_e + kappa_e (diag(w) - w w^T / W)) with
/// kappa_e = projective_centring_weight(), its lower triangle only (A is symmetric; read it as
/// a_free.selfadjointView<Eigen::Lower>()). `a_free_fixed` (may be null): the free x fixed
/// coupling. The element entries on `threads` (0: OpenMP's default), the same bits on any number.
/// Allocates.
void assemble_projective_matrix(const PhysicsModel& physics, const NodeNumbering& numbering,
                                const ProjectiveSetup& setup, Eigen::SparseMatrix<double>& a_free,
                                Eigen::SparseMatrix<double>* a_free_fixed, int threads = 1);
/// The factor cache's key of that matrix (sim/sparse_factor.h): a hash of every entry the
/// assembly would sum (from the same generator, in the same order, so no input of the matrix
/// can be missed), the mass diagonal, the sizes and the backend; bit-identical on any number
/// of `threads`. About a tenth of the assembly's time (no triplets are stored or sorted).
/// `a_free_fixed` (may be null): the free x fixed coupling, built on the way.
[[nodiscard]] FactorKey projective_matrix_key(const PhysicsModel& physics, const NodeNumbering& numbering,
                                              const ProjectiveSetup& setup, int threads,
                                              Eigen::SparseMatrix<double>* a_free_fixed);
/// kappa_e of element `e`: k_v,e (the volume term) + c_e / dt (the damping term, with setup.damping), N/mm.
[[nodiscard]] double projective_centring_weight(const PhysicsModel& physics, int e, const ProjectiveSetup& setup);
/// The projective matrix's entries of element `e`, K_e + kappa_e (diag(w) - w w^T / W): calls
/// emit(a, b, value) for every pair of its vertices (a, b: places in the element's vertex list),
/// row by row. The one source of these entries: the implicit integrator's assembly and factor key
/// read it, and so do the local contact model's patches (local_compliance.h: `volume` false, the
/// elastic part scaled by `elastic_scale`). `ke`: work space.
template <typename Emit>
void for_each_projective_entry(const PhysicsModel& physics, int e, const ProjectiveSetup& setup, Eigen::MatrixXd& ke,
                               Emit&& emit, bool volume = true, double elastic_scale = 1.0) {
  const Model& m = *physics.model;
  const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
  const double kap = projective_centring_weight(physics, e, setup);
  const double* w = physics.entry_weight.data() + b;
  double wsum = 0;
  for (int i = 0; i < n; ++i) wsum += w[i];
  element_elastic_matrix(physics, e, ke, true, volume);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      emit(i, j, elastic_scale * ke(i, j) + kap * ((i == j ? w[i] : 0.0) - w[i] * w[j] / wsum));
}

class ProjectiveSolver {
 public:
  /// Precomputation: numbers the free nodes (node_fixed[i] = 1: kinematic), assembles the
  /// system matrix of `physics` for `setup` and factors it (allocates). Throws vx::Error when
  /// the matrix cannot be factored, or (static) when a part of the model holds no fixed node.
  /// `factor_cache` (may be null; used during the constructor only): the factor is loaded from
  /// it when it holds the matrix's, and offered to it when computed (SparseFactor::compute).
  /// `threads`: for the factor key (0: OpenMP's default). `stop` (may be empty): asked between
  /// the stages (the key, the cache's load, the assembly, the order, the numeric factorisation,
  /// before the cache's store); true throws Cancelled (base/error.h) and nothing is stored. A
  /// stage asked to stop runs to its end first (METIS and CHOLMOD cannot be cut short).
  ProjectiveSolver(std::shared_ptr<const PhysicsModel> physics, const std::vector<std::uint8_t>& node_fixed,
                   const ProjectiveSetup& setup, FactorCache* factor_cache = nullptr, int threads = 0,
                   const std::function<bool()>& stop = {});
  ProjectiveSolver(const ProjectiveSolver&) = delete;
  ProjectiveSolver& operator=(const ProjectiveSolver&) = delete;

  [[nodiscard]] const ProjectiveSetup& setup() const { return setup_; }
  [[nodiscard]] const PhysicsModel& physics() const { return *physics_; }
  /// Free nodes in the solver's numbering (free index -> node).
  [[nodiscard]] const std::vector<int>& free_nodes() const { return numbering_.free_nodes; }
  [[nodiscard]] int num_free() const { return int(numbering_.free_nodes.size()); }
  /// Nonzeros of the Cholesky factor L (the cost of one global solve).
  [[nodiscard]] std::int64_t factor_nonzeros() const { return factor_.nonzeros(); }

  /// The constant part of the right-hand side (free nodes x 3, N, in free order): inertia
  /// M y / dt^2 and the external forces. Fill it before each solve().
  [[nodiscard]] Eigen::MatrixX3d& constant_rhs() { return rhs_const_; }

  /// Solve: local/global iterations from `x` (3 x nodes, mm; in: the start iterate with the
  /// fixed nodes at their targets; out: the solution). Uses the state's warm-start rotations
  /// (updated) and, with damping, its positions as the start of the step x_n; sets
  /// state.element_stats. `contact`: the probes and walls (null: none). Fills the iteration,
  /// residual and contact fields of `report`.
  void solve(SimState& state, Eigen::Matrix3Xd& x, const ProjectiveIterations& iterations, ContactProvider* contact,
             StepReport& report);

  // --- regional solves (sparse_factor.h: only where the tool is) -----------------------------
  /// Restricts the following solves to the elements that touch `awake_nodes` (their rotation
  /// fits and targets) and to the free nodes of those elements and their ancestors in the
  /// factor's elimination tree (the global solve, exact there); the other nodes sleep at their
  /// positions, the other elements keep their targets. The first solve after the factorisation
  /// and the first after each set_region() are full: every node and element brought up to date. Without a supernodal
  /// factor it does nothing (full solves). Allocates. The contact set's cached forward vectors stay (they do not depend
  /// on a region).
  void set_region(const std::vector<int>& awake_nodes);
  /// Back to full solves.
  void clear_region();
  /// Diagnostics (IntegratorSettings::region_solve_far_field, region_refresh_on_move): with
  /// `solve_far_field` the regional solves fit rotations in the region only but solve every
  /// node; without `refresh_on_move` set_region() does not make the next solve a full one.
  void set_region_diagnostics(bool solve_far_field, bool refresh_on_move, bool visit_still_far_field = false) {
    solve_far_field_ = solve_far_field;
    refresh_on_move_ = refresh_on_move;
    visit_still_ = visit_still_far_field;
  }
  /// Regional solves carry the far field (IntegratorSettings::region_carry_far_field; docs/model.md
  /// section 7, "The far field carried"): the nodes outside the region's closure move by a
  /// polynomial displacement field of degree `degree` (1: affine, 2: quadratic) over their anchor
  /// positions, the mass-weighted projection of their exact solution in every step, instead of
  /// being held where the last full solve left them. 0: held.
  void set_carry_far_field(int degree) {
    if (degree != far_degree_) far_.ready = false;
    far_degree_ = degree;
  }
  /// The far field's displacement since its anchor (the last full solve) at its centre of mass,
  /// mm; zero when it is not carried.
  [[nodiscard]] Eigen::Vector3d far_field_motion() const {
    return far_.ready ? Eigen::Vector3d(far_.q.head<3>()) : Eigen::Vector3d::Zero();
  }

  /// The next solve is full (every node and element brought up to date), the region kept for
  /// the solves after it: the far field relaxes once the tool has let go (the implicit
  /// integrator's IntegratorSettings::region_idle_refresh_steps).
  void refresh_all_next() { targets_valid_ = false; }
  [[nodiscard]] bool has_region() const { return region_; }
  /// The last solve() computed every element and node (no region, or its full refresh).
  [[nodiscard]] bool last_solve_full() const { return last_full_; }
  /// Elements and free nodes the regional solves compute (0 without a region).
  [[nodiscard]] std::int64_t region_elements() const { return region_ ? std::int64_t(region_elements_.size()) : 0; }
  [[nodiscard]] std::int64_t region_nodes() const { return region_ ? std::int64_t(factor_.partial_rows().size()) : 0; }

  /// The factor (its backend, size, nonzeros and time).
  [[nodiscard]] const SparseFactor& factor() const { return factor_; }

  /// The contact constraints active after the last solve, with their forces (N).
  [[nodiscard]] const std::vector<ContactConstraint>& active_contacts() const { return contact_set_.active(); }
  /// The contact solve's cache (ContactActiveSet::cache_bytes), bytes.
  [[nodiscard]] std::size_t contact_cache_bytes() const { return contact_set_.cache_bytes(); }
  /// Reserves (and touches) the contact solve's cache for this factor now, so that it never grows
  /// later (ContactActiveSet::reserve: a long session's memory flat). Allocates.
  void reserve_contact_cache() { contact_set_.reserve(factor_); }
  /// Forgets the contact warm start (the next solve does not follow the last one), and with it
  /// the regional solves' promise to the contact (solve()).
  void forget_contacts() {
    contact_set_.forget_warm_start();
    partial_run_ = 0;
    last_steady_ = false;
  }
  /// Solves that kept the contact's promise (ContactProvider::watch_moving: the rows outside
  /// the closure stayed where they were); a diagnostic for tests.
  [[nodiscard]] std::int64_t steady_solves() const { return steady_solves_; }
  /// Solves whose right-hand side was gathered, compared and solved over the closure's rows only
  /// (ProjectiveIterations::inputs_given); a diagnostic for tests.
  [[nodiscard]] std::int64_t closure_pass_solves() const { return closure_pass_solves_; }
  /// The nodes an implicit step's node passes (the iterate's start x_n + dt v_n, the velocities and
  /// their checks) must visit, or null for every node. Not null once the regional solves have held
  /// the far field still long enough, from one continued state: before the step's solve, the last
  /// solve was regional over the present closure (every free node outside it then has velocity 0
  /// and its position in both of the state's position buffers, its own and its scratch's, swapped
  /// every step); after it (`after_solve`), it and the two before were (then its velocity is 0 in
  /// both velocity buffers too). A pass that skips such a node writes what is there already.
  /// Then: the closure's nodes and the fixed ones, ascending.
  [[nodiscard]] const std::vector<int>* still_far_field_nodes(const SimState& s, bool after_solve) const;
  /// g (m x m) = (A^-1)_ij between `nodes`, mm/N: the compliance of one step between them (the
  /// local contact model's, local_contact.h). False when a node is fixed.
  bool contact_compliance(const std::vector<std::int32_t>& nodes, Eigen::MatrixXd& g);

 private:
  void check_held() const;
  void assemble_and_factor(FactorCache* cache, int threads, const std::function<bool()>& stop);
  void record_start_shape(const Eigen::Matrix3Xd& x, int threads);
  ElementPassStats local_step(SimState& state, const Eigen::Matrix3Xd& x, const RotationFitSettings& fit, int threads);
  /// Calls fn(chunk, first, last) over the elements a solve computes: all, or the region's
  /// (then first..last index region_elements_, and element(k) maps).
  [[nodiscard]] std::int64_t active_elements() const {
    return region_ ? std::int64_t(region_elements_.size()) : std::int64_t(physics_->num_elements());
  }
  [[nodiscard]] std::int64_t active_element(std::int64_t k) const {
    return region_ ? std::int64_t(region_elements_[std::size_t(k)]) : k;
  }
  void gather_rhs(int threads, const std::vector<int>* rows);
  double scatter(Eigen::Matrix3Xd& x, int threads, bool closure_only = false);
  /// RMS and largest per-node norm of a - b (free nodes), N.
  std::pair<double, double> difference_norms(const Eigen::MatrixX3d& a, const Eigen::MatrixX3d& b, int threads,
                                             const std::vector<int>* rows);

  std::shared_ptr<const PhysicsModel> physics_;
  ProjectiveSetup setup_;

  // numbering: free and fixed nodes
  NodeNumbering numbering_;

  // the global matrix
  std::vector<double> centring_weight_;       ///< elements: k_v,e (+ c_e/dt) of diag(w) - w w^T / W, N/mm
  Eigen::SparseMatrix<double> a_free_fixed_;  ///< A_fc: free x fixed coupling
  SparseFactor factor_;                       ///< A_ff = L D L^T

  // one solve
  Eigen::Matrix3Xd targets_;        ///< 3 x entries (node-major slots): local-step targets, N
  Eigen::Matrix3Xd start_offsets_;  ///< 3 x entries: r_i^n, vertex offsets at the step's start (damping)
  std::vector<Eigen::Quaterniond> damping_rotations_;  ///< elements: R of the damping term (warm start)
  Eigen::MatrixX3d rhs_const_;                         ///< free x 3: constant part of the right-hand side, N
  Eigen::MatrixX3d rhs_;                               ///< free x 3: this iteration's right-hand side
  Eigen::MatrixX3d rhs_previous_;                      ///< free x 3: the last iteration's (for the residual)
  Eigen::MatrixX3d solution_;                          ///< free x 3: the global step's solution, mm
  Eigen::MatrixX3d fixed_positions_;                   ///< fixed x 3: x_c
  std::vector<ElementPassStats> element_chunk_stats_;
  // regional solves
  bool region_{false};
  bool targets_valid_{false};    ///< every element's targets computed once (by a full solve)
  bool last_full_{false};        ///< the last solve() was a full one
  bool solve_far_field_{false};  ///< set_region_diagnostics()
  bool refresh_on_move_{true};
  bool visit_still_{false};  ///< set_region_diagnostics(): never hold the far field still
  int far_degree_{1};        ///< set_carry_far_field()
  /// The carried far field (the free rows outside the region's closure): positions
  /// a + sum_k q_k U_k with U_k = e_c phi_j((a - centre) / scale) for the monomials phi_j of
  /// degree <= far_degree_ (1 first: the translations are q_0..q_2), q = 0 at the anchor.
  struct FarField {
    bool ready{false};        ///< anchored since the last full solve
    std::vector<int> rows;    ///< free rows outside the closure
    Eigen::MatrixX3d anchor;  ///< rows x 3: a, mm
    Eigen::MatrixXd phi;      ///< rows x monomials: phi_j at the anchor
    Eigen::Vector3d centre{Eigen::Vector3d::Zero()};
    double scale{1.0};                  ///< mm: the monomials' unit length
    int fields{0};                      ///< 3 x monomials
    Eigen::MatrixX3d frozen_rhs;        ///< rows x 3: their right-hand side at q = 0 (M a / dt^2 + loads)
    std::vector<double> forward;        ///< forward fields of g_k = M U_k (SparseFactor::forward_fields)
    Eigen::LDLT<Eigen::MatrixXd> gram;  ///< U^T M U
    Eigen::VectorXd anchor_products;    ///< (M U)^T a
    Eigen::VectorXd q, q_previous;      ///< this step's and the last
    Eigen::VectorXd applied;            ///< the coefficients in the forward solution: (2 q - q_previous) / dt^2
  };
  FarField far_;
  bool anchor_far_field(const SimState& s, const Eigen::Matrix3Xd& x);
  void carry_far_field_in(double dt);
  void carry_far_field_out(Eigen::Matrix3Xd& x);
  std::vector<int> region_elements_;  ///< ascending
  // the regional solves' promise to the contact (solve(): ContactProvider::watch_moving)
  std::vector<int> closure_nodes_;          ///< the closure's rows as node ids, ascending
  std::uint64_t closure_version_{0};        ///< bumped by set_region() and clear_region()
  std::vector<int> pass_nodes_;             ///< closure_nodes_ and the fixed nodes, ascending
  int partial_run_{0};                      ///< regional solves (nothing carried) in a row, the last ones
  std::uint64_t run_closure_version_{0};    ///< ... over this closure
  std::uint64_t run_positions_version_{0};  ///< ... and SimState::positions_version
  /// partial_run_ if it is of this closure and state, else 0
  [[nodiscard]] int partial_run(const SimState& s) const;
  bool last_steady_{false};  ///< the last solve kept the promise
  std::uint64_t watch_period_{0};
  std::int64_t steady_solves_{0};
  // the closure-only passes (solve(), ProjectiveIterations::inputs_given): the last solve's inputs
  bool last_inputs_quiet_{false};  ///< given, and no external force
  Eigen::Vector3d last_gravity_{Eigen::Vector3d::Zero()};
  std::int64_t closure_pass_solves_{0};
  std::vector<double> free_chunk_sums_;  ///< per node chunk: 2 partial sums
  ContactActiveSet contact_set_;
};

}  // namespace vx
