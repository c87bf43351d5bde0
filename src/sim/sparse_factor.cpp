#include "sim/sparse_factor.h"

#include <algorithm>

namespace vx {

bool SparseFactor::compute(const Matrix& a) {
  ldlt_.compute(a);
  if (ldlt_.info() != Eigen::Success) {
    size_ = 0;
    nonzeros_ = 0;
    return false;
  }
  size_ = int(a.rows());
  nonzeros_ = ldlt_.matrixL().nestedExpression().nonZeros();
  work3_.assign(3 * std::size_t(size_), 0.0);
  work1_.assign(std::size_t(size_), 0.0);
  return true;
}

void SparseFactor::solve3(const Eigen::MatrixX3d& b, Eigen::MatrixX3d& x) {
  const int n = size_;
  const auto& perm = ldlt_.permutationP().indices();
  double* w = work3_.data();
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) w[3 * perm(i) + c] = b(i, c);
  solve_in_place<3>(w, 0);
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) x(i, c) = w[3 * perm(i) + c];
}

void SparseFactor::solve_unit(int i, double* out) {
  const int n = size_;
  const auto& perm = ldlt_.permutationP().indices();
  double* w = work1_.data();
  std::fill(work1_.begin(), work1_.end(), 0.0);
  w[perm(i)] = 1.0;
  solve_in_place<1>(w, perm(i));
  for (int k = 0; k < n; ++k) out[k] = w[perm(k)];
}

template <int K>
void SparseFactor::solve_in_place(double* w, int first) const {
  const int n = size_;
  const auto& l = ldlt_.matrixL().nestedExpression();
  const auto& d = ldlt_.vectorD();
  const auto* outer = l.outerIndexPtr();
  const auto* nnz = l.innerNonZeroPtr();
  const auto* inner = l.innerIndexPtr();
  const double* val = l.valuePtr();
  // forward: L z = w (L is Eigen's strictly lower unit factor)
  for (int j = first; j < n; ++j) {
    double wj[K];
    bool zero = true;
    for (int c = 0; c < K; ++c) {
      wj[c] = w[K * j + c];
      zero = zero && wj[c] == 0.0;
    }
    if (zero) continue;  // nothing to carry (sparse right-hand sides)
    const auto end = nnz ? outer[j] + nnz[j] : outer[j + 1];
    for (auto p = outer[j]; p < end; ++p) {
      double* wi = w + K * std::int64_t(inner[p]);
      for (int c = 0; c < K; ++c) wi[c] -= val[p] * wj[c];
    }
  }
  // diagonal
  for (int j = 0; j < n; ++j) {
    const double inv = 1.0 / d(j);
    for (int c = 0; c < K; ++c) w[K * j + c] *= inv;
  }
  // backward: L^T x = z
  for (int j = n - 1; j >= 0; --j) {
    double wj[K];
    for (int c = 0; c < K; ++c) wj[c] = w[K * j + c];
    const auto end = nnz ? outer[j] + nnz[j] : outer[j + 1];
    for (auto p = outer[j]; p < end; ++p) {
      const double* wi = w + K * std::int64_t(inner[p]);
      for (int c = 0; c < K; ++c) wj[c] -= val[p] * wi[c];
    }
    for (int c = 0; c < K; ++c) w[K * j + c] = wj[c];
  }
}

template void SparseFactor::solve_in_place<1>(double*, int) const;
template void SparseFactor::solve_in_place<3>(double*, int) const;

}  // namespace vx
