#pragma once
/// @file sparse_factor.h
/// A sparse symmetric positive definite matrix factored once and solved many times
/// (docs/model.md section 7): the global step of the projective-dynamics solver
/// (projective_solver.h) solves it for the three coordinates at once, and its contact active set
/// (contact_active_set.h) for single unit columns.
///
/// P A P^T = L D L^T with a fill-reducing permutation P. Who computes it (SparseFactor::Backend):
///   - cholmod: CHOLMOD's supernodal Cholesky (SuiteSparse, BLAS blocks) with a METIS nested
///     dissection ordering, converted to simplicial form; the fastest to factor (a 39k-node grid:
///     3.9 s against 38 s for Eigen with AMD) and the sparsest factor (12.5 M nonzeros against
///     23.5 M);
///   - eigen_metis: Eigen's SimplicialLDLT with Eigen's METIS ordering (MetisOrdering);
///   - eigen_amd: Eigen's SimplicialLDLT with AMD (the build without SuiteSparse and METIS).
/// The build uses CHOLMOD when SuiteSparse is found (VOXELASTIC_HAVE_CHOLMOD), else Eigen with
/// METIS when METIS is found (VOXELASTIC_HAVE_METIS), else Eigen with AMD: all give the same
/// solution to rounding. The factor is then copied into one unit-lower L and diagonal D, and the
/// solves run on those arrays directly: one pass over L per triangle serves K right-hand sides
/// interleaved (each entry of L is read once for all of them), and a unit vector's forward pass
/// starts at its own row. Serial and in a fixed order: deterministic.

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <cstdint>
#include <vector>

namespace vx {

class SparseFactor {
 public:
  using Matrix = Eigen::SparseMatrix<double>;

  /// Who factors (see the file comment).
  enum class Backend : std::uint8_t { automatic, cholmod, eigen_metis, eigen_amd };
  /// "cholmod", "eigen_metis", "eigen_amd" ("automatic": the build's best).
  [[nodiscard]] static const char* to_string(Backend b);
  /// The backend `automatic` stands for in this build.
  [[nodiscard]] static Backend best_backend();
  /// True when this build has `b`.
  [[nodiscard]] static bool available(Backend b);

  /// Factors `a` (n x n, symmetric; the lower triangle is read) with `backend` (automatic: the
  /// build's best; one the build lacks falls back to it). Returns false when it is not positive
  /// definite (a part of the model held by nothing, a NaN).
  [[nodiscard]] bool compute(const Matrix& a, Backend backend = Backend::automatic);

  /// Rows of the factored matrix.
  [[nodiscard]] int size() const { return size_; }
  /// Nonzeros of L (the cost of one solve).
  [[nodiscard]] std::int64_t nonzeros() const { return std::int64_t(values_.size()); }
  /// The backend that computed the factor.
  [[nodiscard]] Backend backend() const { return backend_; }
  /// Wall time of the last compute(), s.
  [[nodiscard]] double factor_seconds() const { return factor_s_; }

  /// x = A^-1 b for the three columns of b (n x 3) at once. Allocation-free after compute().
  void solve3(const Eigen::MatrixX3d& b, Eigen::MatrixX3d& x);
  /// out = A^-1 e_i (n values). Allocation-free after compute().
  void solve_unit(int i, double* out);

 private:
  /// Solves L D L^T w = w in place on the factor (permuted order; K right-hand sides
  /// interleaved, row-major n x K). Entries before `first` must be zero in every lane: the
  /// forward pass starts there.
  template <int K>
  void solve_in_place(double* w, int first) const;

  bool compute_eigen(const Matrix& a, bool metis);
  bool compute_cholmod(const Matrix& a);

  int size_{0};
  Backend backend_{Backend::automatic};
  double factor_s_{0.0};
  // P A P^T = L D L^T: L strictly lower (unit diagonal implied), column-compressed
  std::vector<int> perm_;            ///< original row -> factored position
  std::vector<std::int64_t> outer_;  ///< n + 1 column starts
  std::vector<int> inner_;           ///< row of each entry
  std::vector<double> values_;       ///< L entries
  std::vector<double> inv_d_;        ///< 1 / D
  std::vector<double> work3_;        ///< n x 3, row-major, permuted order
  std::vector<double> work1_;        ///< n, permuted order
};

}  // namespace vx
