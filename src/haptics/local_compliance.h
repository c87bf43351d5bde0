#pragma once
/// @file local_compliance.h
/// The tissue compliance between contact nodes for the local contact model (local_contact.h)
/// when the integrator has no factor of its own (the explicit integrators), or when asked for.
///
/// The matrix is the implicit integrator's (projective_solver.h) at a time horizon T:
///     A_T = M / T^2 + sum_e (K_e + (k_v,e + c_e / T) (diag(w) - w w^T / W)_e),
/// the same scalar matrix for x, y and z, constant (built on the rest shape), so
/// C_ij = (A_T^-1)_ij I. T is the time the local model has to carry the force (about one
/// physics period): the tissue's inertia and damping over T stiffen it a little, and keep A_T
/// positive definite when nothing is held. Inverting A_T on the whole model is what the implicit
/// integrator's factor does; here only a patch is factored: the free nodes within `radius_mm`
/// (rest positions) of the contact, the nodes beyond it held. Holding the patch's border makes
/// the tissue a little stiffer than the whole model (docs/probe.md measures by how much); a
/// radius beyond the model gives the whole model. The factor and its columns are kept while the
/// contact stays within a quarter of the radius of the patch's centre.
///
/// Memory (issue 27, issue 25): nothing is kept over the whole model; each patch assembles its
/// block of A_T from the elements that touch it (a few milliseconds beside its factorisation).
/// The solved columns live in one buffer of kCacheColumns columns of 1.5x
/// the largest patch seen (at most the model's free nodes), reused by every patch (a patch that
/// needs more columns than are free starts the cache over), and the patch's assembly reuses its
/// triplets and matrix; so the cache's bytes stop growing once the largest patch has been seen,
/// and a session that moves the tool over the organ for minutes does not leave the heap larger
/// with each new patch.
///
/// The Poisson ratio (docs/model.md 9.1): A_T is one scalar matrix for x, y and z, so it cannot
/// hold the volume term as the model does (its projective matrix k_v g g^T penalises every
/// component of the gradient with k_v = 3 lambda V, not only the trace: 8.0x the converged
/// model's contact stiffness at nu = 0.45 on local_contact_test's block, against 1.41x at 0).
/// A_T leaves it out and scales the rest (which scales with mu) by 1 / (1 - nu): an elastic
/// half-space's surface compliance between two points is (1 - nu^2) / (pi E r) =
/// (1 - nu) / (2 pi mu r), so a scalar (Laplacian-like) model with stiffness mu / (1 - nu) has
/// the half-space's compliance at every nu (1.51x the converged model at 0.45).
///
/// Units: mm, s, N; compliance mm/N.

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <cstdint>
#include <memory>
#include <vector>

#include "physics/physics_model.h"
#include "sim/sparse_factor.h"

namespace vx {

/// The factor on the elastic part of A_T (the volume term left out) for Poisson ratio nu:
/// 1 / (1 - nu) (1 at nu = 0).
[[nodiscard]] double poisson_compliance_stiffening(double nu);

class PatchCompliance {
 public:
  /// Solved columns kept per patch: at least the candidates one local model holds
  /// (LocalContactSolver::kMaxNodes, checked where both are used: device_side.cpp).
  static constexpr int kCacheColumns = 256;

  /// Keeps the model and the nodes held (`node_fixed`, never in a patch); assembles nothing (each
  /// patch assembles its block of A_T from the elements that touch it).
  void init(std::shared_ptr<const PhysicsModel> physics, const std::vector<std::uint8_t>& node_fixed, double horizon_s);
  [[nodiscard]] bool ready() const { return bool(physics_); }

  /// g (m x m) = the scalar compliance between `nodes` (free nodes), mm/N, from the patch of
  /// radius `radius_mm` around their mean rest position, doubled until the nodes lie within 3/4
  /// of it (a contact wider than the radius asked for). Allocates when it refactors or caches a
  /// new column. Returns false when a node is held, there are more than kCacheColumns nodes,
  /// the radius is not > 0, or the patch cannot be factored.
  bool compute(const std::vector<std::int32_t>& nodes, double radius_mm, Eigen::MatrixXd& g);

  [[nodiscard]] int patch_nodes() const { return int(patch_nodes_.size()); }
  [[nodiscard]] std::int64_t refactors() const { return refactors_; }
  [[nodiscard]] std::int64_t columns_solved() const { return columns_solved_; }
  /// Columns in the cache now (<= kCacheColumns), and the times it was started over in a patch.
  [[nodiscard]] int cached_columns() const { return int(slot_column_.size()); }
  [[nodiscard]] std::int64_t cache_restarts() const { return cache_restarts_; }
  /// Bytes the cache's buffers hold (columns, slots, the patch's numbering and assembly; not the
  /// factor, which SparseFactor::stored_bytes() measures): kCacheColumns x 8 bytes per node of
  /// the largest patch seen, plus its assembly.
  [[nodiscard]] std::size_t cache_bytes() const;
  /// The patch's factor (its size and bytes).
  [[nodiscard]] const SparseFactor& factor() const { return factor_; }
  [[nodiscard]] double horizon_s() const { return horizon_; }

 private:
  bool build_patch(const Eigen::Vector3d& centre, double radius_mm);

  std::shared_ptr<const PhysicsModel> physics_;
  std::vector<std::uint8_t> fixed_;
  std::size_t free_nodes_{0};  ///< nodes not held: the largest patch possible
  double horizon_{0.02};
  // the patch
  bool has_patch_{false};
  Eigen::Vector3d centre_{Eigen::Vector3d::Zero()};
  double radius_{0.0};
  std::vector<int> patch_index_;  ///< nodes -> patch index or -1
  std::vector<int> patch_nodes_;  ///< patch index -> node
  SparseFactor factor_;
  std::vector<int> column_slot_;  ///< patch index -> column slot or -1
  std::vector<int> slot_column_;  ///< column slot -> patch index (to start the cache over)
  /// kCacheColumns columns of patch_nodes() values each (column-major), sized for 1.5x the
  /// largest patch seen (at most free_nodes_) and never shrunk: patches reuse it
  std::vector<double> columns_;
  std::int64_t cache_restarts_{0};
  // the patch's assembly, reused
  std::vector<Eigen::Triplet<double>> trip_;
  Eigen::MatrixXd ke_;  ///< one element's elastic matrix
  SparseFactor::Matrix patch_matrix_;
  std::int64_t refactors_{0};
  std::int64_t columns_solved_{0};
};

}  // namespace vx
