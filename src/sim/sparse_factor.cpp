#include "sim/sparse_factor.h"

#include <Eigen/SparseCholesky>
#include <algorithm>
#include <chrono>
#include <cmath>

#ifdef VOXELASTIC_HAVE_METIS
#include <iostream>  // Eigen's MetisSupport uses std::cerr without including it

#include <Eigen/MetisSupport>
#endif
#ifdef VOXELASTIC_HAVE_CHOLMOD
#include <cholmod.h>
#endif

namespace vx {

const char* SparseFactor::to_string(Backend b) {
  switch (b) {
    case Backend::automatic: return "automatic";
    case Backend::cholmod: return "cholmod";
    case Backend::eigen_metis: return "eigen_metis";
    case Backend::eigen_amd: return "eigen_amd";
  }
  return "?";
}

bool SparseFactor::available(Backend b) {
  switch (b) {
    case Backend::automatic:
    case Backend::eigen_amd: return true;
    case Backend::cholmod:
#ifdef VOXELASTIC_HAVE_CHOLMOD
      return true;
#else
      return false;
#endif
    case Backend::eigen_metis:
#ifdef VOXELASTIC_HAVE_METIS
      return true;
#else
      return false;
#endif
  }
  return false;
}

SparseFactor::Backend SparseFactor::best_backend() {
  if (available(Backend::cholmod)) return Backend::cholmod;
  if (available(Backend::eigen_metis)) return Backend::eigen_metis;
  return Backend::eigen_amd;
}

bool SparseFactor::compute(const Matrix& a, Backend backend) {
  const auto t0 = std::chrono::steady_clock::now();
  if (backend == Backend::automatic || !available(backend)) backend = best_backend();
  size_ = 0;
  bool ok = false;
  switch (backend) {
    case Backend::cholmod: ok = compute_cholmod(a); break;
    case Backend::eigen_metis: ok = compute_eigen(a, true); break;
    default: ok = compute_eigen(a, false); break;
  }
  factor_s_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!ok) {
    size_ = 0;
    outer_.assign(1, 0);
    inner_.clear();
    values_.clear();
    return false;
  }
  backend_ = backend;
  size_ = int(a.rows());
  work3_.assign(3 * std::size_t(size_), 0.0);
  work1_.assign(std::size_t(size_), 0.0);
  return true;
}

namespace {

/// Copies Eigen's LDL^T (strictly lower L, D, permutation) into the plain arrays.
template <typename Ldlt>
bool copy_eigen(const Ldlt& ldlt, int n, std::vector<int>& perm, std::vector<std::int64_t>& outer,
                std::vector<int>& inner, std::vector<double>& values, std::vector<double>& inv_d) {
  if (ldlt.info() != Eigen::Success) return false;
  const auto& l = ldlt.matrixL().nestedExpression();
  const auto& d = ldlt.vectorD();
  const auto& p = ldlt.permutationP().indices();
  perm.resize(std::size_t(n));
  for (int i = 0; i < n; ++i) perm[std::size_t(i)] = p(i);
  outer.assign(std::size_t(n) + 1, 0);
  const auto* lo = l.outerIndexPtr();
  const auto* nnz = l.innerNonZeroPtr();
  for (int j = 0; j < n; ++j) outer[std::size_t(j) + 1] = outer[std::size_t(j)] + (nnz ? nnz[j] : lo[j + 1] - lo[j]);
  inner.resize(std::size_t(outer[std::size_t(n)]));
  values.resize(std::size_t(outer[std::size_t(n)]));
  for (int j = 0; j < n; ++j) {
    const std::int64_t len = outer[std::size_t(j) + 1] - outer[std::size_t(j)];
    std::copy_n(l.innerIndexPtr() + lo[j], len, inner.begin() + outer[std::size_t(j)]);
    std::copy_n(l.valuePtr() + lo[j], len, values.begin() + outer[std::size_t(j)]);
  }
  inv_d.resize(std::size_t(n));
  for (int j = 0; j < n; ++j) {
    if (!(d(j) > 0) || !std::isfinite(d(j))) return false;
    inv_d[std::size_t(j)] = 1.0 / d(j);
  }
  return true;
}

}  // namespace

bool SparseFactor::compute_eigen(const Matrix& a, bool metis) {
  const int n = int(a.rows());
#ifdef VOXELASTIC_HAVE_METIS
  if (metis) {
    Eigen::SimplicialLDLT<Matrix, Eigen::Lower, Eigen::MetisOrdering<int>> ldlt(a);
    return copy_eigen(ldlt, n, perm_, outer_, inner_, values_, inv_d_);
  }
#else
  (void)metis;
#endif
  Eigen::SimplicialLDLT<Matrix> ldlt(a);
  return copy_eigen(ldlt, n, perm_, outer_, inner_, values_, inv_d_);
}

bool SparseFactor::compute_cholmod(const Matrix& a_in) {
#ifdef VOXELASTIC_HAVE_CHOLMOD
  Matrix a = a_in;
  a.makeCompressed();
  const int n = int(a.rows());
  cholmod_common cm;
  cholmod_start(&cm);
  cm.print = 0;
  cm.error_handler = nullptr;
  cm.supernodal = CHOLMOD_SUPERNODAL;
  cm.nmethods = 1;
  cm.method[0].ordering = CHOLMOD_METIS;
  cm.postorder = 1;
  cm.quick_return_if_not_posdef = 1;
  cholmod_sparse view{};
  view.nrow = std::size_t(n);
  view.ncol = std::size_t(n);
  view.nzmax = std::size_t(a.nonZeros());
  view.p = a.outerIndexPtr();
  view.i = a.innerIndexPtr();
  view.x = a.valuePtr();
  view.stype = -1;  // the lower triangle is read, the upper ignored
  view.itype = CHOLMOD_INT;
  view.xtype = CHOLMOD_REAL;
  view.dtype = CHOLMOD_DOUBLE;
  view.sorted = 1;
  view.packed = 1;
  cholmod_factor* l = cholmod_analyze(&view, &cm);
  bool ok = l != nullptr;
  if (ok) ok = cholmod_factorize(&view, l, &cm) && cm.status == CHOLMOD_OK && l->minor == l->n;
  // simplicial LL^T, packed, columns sorted with the diagonal first
  if (ok) ok = cholmod_change_factor(CHOLMOD_REAL, 1, 0, 1, 1, l, &cm);
  if (ok) {
    const int* lp = static_cast<const int*>(l->p);
    const int* li = static_cast<const int*>(l->i);
    const int* lnz = static_cast<const int*>(l->nz);
    const double* lx = static_cast<const double*>(l->x);
    const int* pp = static_cast<const int*>(l->Perm);  // position k holds original row pp[k]
    perm_.resize(std::size_t(n));
    for (int k = 0; k < n; ++k) perm_[std::size_t(pp[k])] = k;
    outer_.assign(std::size_t(n) + 1, 0);
    for (int j = 0; j < n; ++j) outer_[std::size_t(j) + 1] = outer_[std::size_t(j)] + (lnz[j] - 1);
    inner_.resize(std::size_t(outer_[std::size_t(n)]));
    values_.resize(std::size_t(outer_[std::size_t(n)]));
    inv_d_.resize(std::size_t(n));
    for (int j = 0; j < n && ok; ++j) {
      const int b = lp[j];
      if (li[b] != j || !(lx[b] > 0) || !std::isfinite(lx[b])) {
        ok = false;
        break;
      }
      const double ljj = lx[b];
      inv_d_[std::size_t(j)] = 1.0 / (ljj * ljj);
      std::int64_t o = outer_[std::size_t(j)];
      for (int p = b + 1; p < b + lnz[j]; ++p, ++o) {
        inner_[std::size_t(o)] = li[p];
        values_[std::size_t(o)] = lx[p] / ljj;  // L = Lu D^1/2: Lu_ij = L_ij / L_jj, D_j = L_jj^2
      }
    }
  }
  if (l) cholmod_free_factor(&l, &cm);
  cholmod_finish(&cm);
  return ok;
#else
  (void)a_in;
  return false;
#endif
}

void SparseFactor::solve3(const Eigen::MatrixX3d& b, Eigen::MatrixX3d& x) {
  const int n = size_;
  double* w = work3_.data();
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) w[3 * perm_[std::size_t(i)] + c] = b(i, c);
  solve_in_place<3>(w, 0);
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) x(i, c) = w[3 * perm_[std::size_t(i)] + c];
}

void SparseFactor::solve_unit(int i, double* out) {
  const int n = size_;
  double* w = work1_.data();
  std::fill(work1_.begin(), work1_.end(), 0.0);
  w[perm_[std::size_t(i)]] = 1.0;
  solve_in_place<1>(w, perm_[std::size_t(i)]);
  for (int k = 0; k < n; ++k) out[k] = w[perm_[std::size_t(k)]];
}

template <int K>
void SparseFactor::solve_in_place(double* w, int first) const {
  const int n = size_;
  const std::int64_t* outer = outer_.data();
  const int* inner = inner_.data();
  const double* val = values_.data();
  // forward: L z = w (L strictly lower, unit diagonal)
  for (int j = first; j < n; ++j) {
    double wj[K];
    bool zero = true;
    for (int c = 0; c < K; ++c) {
      wj[c] = w[K * j + c];
      zero = zero && wj[c] == 0.0;
    }
    if (zero) continue;  // nothing to carry (sparse right-hand sides)
    for (std::int64_t p = outer[j]; p < outer[j + 1]; ++p) {
      double* wi = w + K * std::int64_t(inner[p]);
      for (int c = 0; c < K; ++c) wi[c] -= val[p] * wj[c];
    }
  }
  // diagonal
  for (int j = 0; j < n; ++j) {
    const double inv = inv_d_[std::size_t(j)];
    for (int c = 0; c < K; ++c) w[K * j + c] *= inv;
  }
  // backward: L^T x = z
  for (int j = n - 1; j >= 0; --j) {
    double wj[K];
    for (int c = 0; c < K; ++c) wj[c] = w[K * j + c];
    for (std::int64_t p = outer[j]; p < outer[j + 1]; ++p) {
      const double* wi = w + K * std::int64_t(inner[p]);
      for (int c = 0; c < K; ++c) wj[c] -= val[p] * wi[c];
    }
    for (int c = 0; c < K; ++c) w[K * j + c] = wj[c];
  }
}

template void SparseFactor::solve_in_place<1>(double*, int) const;
template void SparseFactor::solve_in_place<3>(double*, int) const;

}  // namespace vx
