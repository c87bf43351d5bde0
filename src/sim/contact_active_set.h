#pragma once
/// @file contact_active_set.h
/// The contact constraints of one global step of the projective-dynamics solver
/// (projective_solver.h), solved exactly on its factor (docs/model.md section 8).
///
/// Why inside the solve: after an integrator's step, a post-step projection (contact.h) only sees
/// the momentum change m (v' - v) / dt of the nodes it moves, which at long implicit steps is a
/// small part of the elastic reaction (roughly (m/dt^2) / (K + m/dt^2) of it): the nodes relaxed
/// to the free equilibrium inside the step. So the probes and walls take part in the
/// minimisation itself: every global step solves
///   A x = b + sum_i lambda_i n_i e_i^T,  n_i . x_i >= n_i . p_i,  lambda_i >= 0,
///   lambda_i (n_i . x_i - n_i . p_i) = 0,
/// with each constraint linearised at the current iterate (the closest surface point p_i and
/// the outward normal n_i; re-linearised every local/global iteration, so a curved probe is
/// followed). A acts on each coordinate alike, so with G = A_s^-1 (the scalar matrix),
///   x = x_u + sum_j lambda_j n_j G e_j,    x_u = A^-1 b (the unconstrained solve),
/// and the constraints on the working set W give the Schur complement system
///   S lambda = d,  S_ij = (n_i . n_j) G_ij,  d_i = n_i . (p_i - x_u,i),
/// exact on the existing factorisation. G is never formed: each node that is a candidate gets
/// its forward vector z_j = D^-1/2 L^-1 P e_j once (SparseFactor::forward_unit: nonzero only on
/// its path to the root of the elimination tree), G_ij = z_i . z_j is computed when first needed
/// and kept in a small matrix between the cached nodes, and the forces of the working set are
/// applied with one backward pass for all of them (SparseFactor::add_response3). Forward vectors
/// do not depend on a regional solve's region, so they stay cached until the matrix is
/// refactored (within kColumnBudgetBytes and kMaxSlots; the least recently used are reused
/// beyond). Before, each contact node cost a whole column G e_j (a backward pass over the whole
/// factor or region, n doubles of memory) and every region move dropped them all.
/// An active-set iteration keeps lambda >= 0: it drops the constraints that pull and adds the
/// candidates the solution violates, starting from the last solve's active set (a warm start
/// that usually converges in 1-2 rounds). The multipliers are the contact forces (N, A x = b is
/// a force balance). Serial and in a fixed order, but for the re-check's copy of every node
/// (split by node): the same result for any thread count.

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "sim/contact_constraint.h"
#include "sim/sparse_factor.h"

namespace vx {

/// Work counters of the contact solves (added up over a step).
struct ContactSolveCounters {
  int rounds{0};            ///< active-set rounds
  std::int64_t columns{0};  ///< new forward vectors z_i solved (SparseFactor::forward_unit)
};

class ContactActiveSet {
 public:
  static constexpr int kMaxRounds = 100;           ///< active-set rounds per global solve
  static constexpr int kMaxPasses = 4;             ///< re-checks for nodes pushed into a probe
  static constexpr double kGapToleranceMm = 1e-9;  ///< a violation smaller than this is none
  static constexpr double kColumnBudgetBytes = 256.0 * 1024 * 1024;
  static constexpr int kMaxSlots = 2048;  ///< cached nodes (the G matrix between them: 32 MB)

  /// Binds the set to a new factor and its free-node numbering (free_index: nodes -> free index
  /// or -1; free_nodes: free index -> node): the cached columns belong to the old factor.
  /// Allocates. The warm start is kept (it is keyed by node, not by factor).
  void bind(const std::vector<int>& free_index, const std::vector<int>& free_nodes);
  /// Reserves the cache's storage for the bound factor once, and touches it, so that it is
  /// resident from now on and never grows (a long session's memory stays flat; without it the
  /// cache fills as tools visit new nodes: 36 -> 89 MB in a 10-minute soak on the folded organ).
  /// The slots: kMaxSlots, or the free nodes if fewer, or as many forward vectors of the factor's
  /// longest (SparseFactor::longest_unit_forward) as fit kColumnBudgetBytes; G between them and
  /// every slot's vectors at that longest size. Beyond them the least recently used slot is
  /// reused as before (only a single solve with more candidates than slots grows it). Allocates.
  void reserve(const SparseFactor& factor);
  /// Apply the contact forces on the factor's regional rows only (SparseFactor::add_response3
  /// partial: exact on the region, the rest untouched) instead of on every node.
  void set_partial(bool partial) { partial_ = partial; }
  /// Threads of the re-check's copy of the constrained iterate (every node; 0: OpenMP's default).
  /// The same result on any number.
  void set_threads(int threads) { threads_ = threads; }
  /// The regional solves' promise (ContactProvider::watch_moving) for the solves that follow:
  /// the re-check's copy of the constrained iterate copies the nodes of `moving` only once it has
  /// copied every node in the period (the others' solution rows and positions stay as they were,
  /// so the copy is the same). Null or period 0: every node, every time. `moving` is kept by
  /// pointer and must outlive the promise.
  void watch_moving(const std::vector<int>* moving, std::uint64_t period) {
    moving_ = period != 0 ? moving : nullptr;
    moving_period_ = moving_ != nullptr ? period : 0;
  }
  /// Forgets the warm start (the state was reset, replaced, or the provider changed).
  void forget_warm_start() { active_.clear(); }

  /// Turns the unconstrained solution `solution` (free nodes x 3, mm) of one global step into the
  /// constrained one. `x` (3 x nodes) is the iterate before this solve, where the provider
  /// linearises the constraints; `factor` is the global matrix's factor bound by bind(). Serial:
  /// the substitutions it runs are serial (SparseFactor::add_response3 is one backward pass).
  /// With `from_forward` (a regional solve) the factor has run only the forward half of the
  /// unconstrained solve (SparseFactor::forward3_partial) and `solution` holds the last values
  /// outside the closure: the candidates' unconstrained positions come from dot products with
  /// the forward solution and the forces join the one backward pass (backward3_partial).
  void solve(ContactProvider& provider, const Eigen::Matrix3Xd& x, SparseFactor& factor, Eigen::MatrixX3d& solution,
             ContactSolveCounters& counters, bool from_forward = false);

  /// The constraints active after the last solve, sorted by (owner, node), with their
  /// multipliers (N); the next solve starts from them (warm start).
  [[nodiscard]] const std::vector<ContactConstraint>& active() const { return active_; }
  /// Memory held by the cache of forward vectors and G between them, bytes: the storage its
  /// vectors have (their capacity), bounded by about kColumnBudgetBytes and kMaxSlots; it fills
  /// as tools visit new nodes unless reserve()d.
  [[nodiscard]] std::size_t cache_bytes() const;
  /// reserve() was called for the bound factor.
  [[nodiscard]] bool reserved() const { return reserved_; }

  /// g (m x m) = G restricted to the free nodes `free` (free indices): the scalar compliance
  /// between them, mm/N, from the cached columns (solving the missing ones; allocates when the
  /// cache grows). The local contact model's compliance (local_contact.h).
  void compliance(const std::vector<int>& free, SparseFactor& factor, Eigen::MatrixXd& g);

 private:
  [[nodiscard]] int num_free() const { return int(free_nodes_->size()); }
  int column_of(int free, SparseFactor& factor, ContactSolveCounters& counters);
  void grow_slots(int capacity);
  /// G between the nodes of two slots (computed once, then cached).
  double gram(int slot_a, int slot_b);
  [[nodiscard]] Eigen::Vector3d constrained_position(int candidate, SparseFactor& factor,
                                                     ContactSolveCounters& counters);
  int iterate_working_set(SparseFactor& factor, ContactSolveCounters& counters);
  void apply_working_forces(Eigen::MatrixX3d& solution, SparseFactor& factor, bool from_forward);
  /// unconstrained_ on the candidates from `from` on, from the factor's forward solution.
  void unconstrained_from_forward(std::size_t from, SparseFactor& factor, ContactSolveCounters& counters);
  void index_candidates(std::size_t from);

  bool partial_{false};
  int threads_{1};
  const std::vector<int>* free_index_{nullptr};  ///< bound by bind(): nodes -> free index or -1
  const std::vector<int>* free_nodes_{nullptr};  ///< bound by bind(): free index -> node

  // candidates and the working set of one solve
  std::vector<ContactConstraint> candidates_;  ///< near the surfaces, sorted by (owner, node)
  std::vector<ContactConstraint> extra_;       ///< found in a re-check pass
  std::vector<ContactConstraint> active_;      ///< the last solve's active set (warm start)
  std::vector<int> candidate_free_;            ///< candidates: free index of the node
  std::vector<std::uint8_t> in_working_set_;   ///< candidates: 1 in the working set
  std::vector<int> working_;                   ///< the working set's candidates
  std::vector<int> working_column_;            ///< working set: column slot of the node
  std::vector<double> working_force_;          ///< working set: lambda n (3 each), N
  std::vector<double> schur_;                  ///< S, row-major (lower triangle used)
  std::vector<double> schur_rhs_;              ///< d, then lambda
  Eigen::MatrixX3d unconstrained_;             ///< x_u: the global step's solution without contact
  Eigen::Matrix3Xd trial_;                     ///< constrained iterate (all nodes) for the re-check
  const std::vector<int>* moving_{nullptr};    ///< watch_moving()
  std::uint64_t moving_period_{0};
  std::uint64_t trial_period_{0};  ///< the period trial_ was last copied whole in (0: none)

  // cached forward vectors z_f of the bound factor, and G between them
  std::vector<SparseFactor::UnitForward> forward_;  ///< slot -> z of its node
  Eigen::MatrixXd gram_;                            ///< slots x slots, G between their nodes (NaN: not yet)
  std::size_t forward_bytes_{0};
  std::vector<const SparseFactor::UnitForward*> working_forward_;  ///< working set: z (for add_response3)
  std::vector<int> column_slot_;                                   ///< free index -> column slot, -1 none
  std::vector<int> slot_free_;                                     ///< column slot -> free index
  std::vector<std::int64_t> slot_last_used_;                       ///< column slot -> last solve that used it
  int used_slots_{0};
  bool reserved_{false};
  std::int64_t solve_count_{0};
};

}  // namespace vx
