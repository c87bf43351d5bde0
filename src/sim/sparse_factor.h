#pragma once
/// @file sparse_factor.h
/// A sparse symmetric positive definite matrix factored once and solved many times
/// (docs/model.md section 7): the global step of the projective-dynamics solver
/// (projective_solver.h) solves it for the three coordinates at once, and its contact active set
/// (contact_active_set.h) for single unit columns.
///
/// The factor is Eigen's SimplicialLDLT, P A P^T = L D L^T with a fill-reducing permutation P
/// (AMD ordering). The solves run on the factor's arrays directly: one pass over L per triangle
/// serves K right-hand sides interleaved (each entry of L is read once for all of them), and a
/// unit vector's solve starts its forward pass at its own row. Serial and in a fixed order:
/// deterministic.

#include <Eigen/Core>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <cstdint>
#include <vector>

namespace vx {

class SparseFactor {
 public:
  using Matrix = Eigen::SparseMatrix<double>;

  /// Factors `a` (n x n, symmetric; the lower triangle is read). Returns false when it is not
  /// positive definite (a part of the model held by nothing, a NaN).
  [[nodiscard]] bool compute(const Matrix& a);

  /// Rows of the factored matrix.
  [[nodiscard]] int size() const { return size_; }
  /// Nonzeros of L (the cost of one solve).
  [[nodiscard]] std::int64_t nonzeros() const { return nonzeros_; }

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

  Eigen::SimplicialLDLT<Matrix> ldlt_;
  int size_{0};
  std::int64_t nonzeros_{0};
  std::vector<double> work3_;  ///< n x 3, row-major, permuted order
  std::vector<double> work1_;  ///< n, permuted order
};

}  // namespace vx
