#include "sim/sparse_factor.h"

#include <Eigen/SparseCholesky>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <numeric>
#include <ostream>
#include <string>

#include "base/content_hash.h"
#include "base/error.h"

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
  // VOXELASTIC_FACTOR pins the backend (cholmod, eigen_metis, eigen_amd), e.g. to compare them
  if (const char* env = std::getenv("VOXELASTIC_FACTOR")) {
    for (Backend b : {Backend::cholmod, Backend::eigen_metis, Backend::eigen_amd})
      if (std::string(env) == to_string(b) && available(b)) return b;
  }
  if (available(Backend::cholmod)) return Backend::cholmod;
  if (available(Backend::eigen_metis)) return Backend::eigen_metis;
  return Backend::eigen_amd;
}

void SparseFactor::reset() {
  size_ = 0;
  supernodal_ = false;
  have_forward_ = false;
  from_cache_ = false;
  closure_rows_.clear();
  closure_supers_.clear();
  closure_columns_ = 0;
  perm_.clear();
  outer_.assign(1, 0);
  inner_.clear();
  values_.clear();
  inv_d_.clear();
  super_.clear();
  rows_.clear();
  row_start_.clear();
  value_start_.clear();
  column_super_.clear();
  super_parent_.clear();
}

bool SparseFactor::compute(const Matrix& a, Backend backend) {
  const auto t0 = std::chrono::steady_clock::now();
  reset();
  if (backend == Backend::automatic || !available(backend)) backend = best_backend();
  bool ok = false;
  switch (backend) {
    case Backend::cholmod: ok = compute_cholmod(a); break;
    case Backend::eigen_metis: ok = compute_eigen(a, true); break;
    default: ok = compute_eigen(a, false); break;
  }
  factor_s_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!ok) {
    reset();
    return false;
  }
  backend_ = backend;
  size_ = int(a.rows());
  finish();
  return true;
}

/// What every factor needs besides its arrays: the work space, and the elimination tree of a
/// simplicial one (a supernodal one has super_parent_).
void SparseFactor::finish() {
  work3_.assign(3 * std::size_t(size_), 0.0);
  work1_.assign(std::size_t(size_), 0.0);
  if (supernodal_) {
    all_supers_.resize(super_.size() - 1);
    for (std::size_t q = 0; q < all_supers_.size(); ++q) all_supers_[q] = int(q);
    path_.reserve(super_.size());
    mark_.assign(super_.size() - 1, 0);
    generation_ = 0;
  } else {
    // the elimination tree of L: a column's parent is its first row below the diagonal
    parent_.assign(std::size_t(size_), -1);
    inv_sqrt_d_.resize(std::size_t(size_));
    for (int j = 0; j < size_; ++j) {
      int first = size_;
      for (std::int64_t p = outer_[std::size_t(j)]; p < outer_[std::size_t(j) + 1]; ++p) first = std::min(first, inner_[std::size_t(p)]);
      parent_[std::size_t(j)] = first < size_ ? first : -1;
      inv_sqrt_d_[std::size_t(j)] = std::sqrt(inv_d_[std::size_t(j)]);
    }
    path_.reserve(std::size_t(size_));
  }
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
    std::vector<double> values;
    const bool ok = copy_eigen(ldlt, n, perm_, outer_, inner_, values, inv_d_);
    values_.own(std::move(values));
    return ok;
  }
#else
  (void)metis;
#endif
  Eigen::SimplicialLDLT<Matrix> ldlt(a);
  std::vector<double> values;
  const bool ok = copy_eigen(ldlt, n, perm_, outer_, inner_, values, inv_d_);
  values_.own(std::move(values));
  return ok;
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
  // keep the supernodal L L^T: its blocks as they are
  if (ok) ok = l->is_super && l->is_ll;
  if (ok) {
    const int ns = int(l->nsuper);
    const int* sup = static_cast<const int*>(l->super);
    const int* pi = static_cast<const int*>(l->pi);
    const int* px = static_cast<const int*>(l->px);
    const int* ls = static_cast<const int*>(l->s);
    const double* lx = static_cast<const double*>(l->x);
    const int* pp = static_cast<const int*>(l->Perm);  // position k holds original row pp[k]
    perm_.resize(std::size_t(n));
    for (int k = 0; k < n; ++k) perm_[std::size_t(pp[k])] = k;
    super_.assign(sup, sup + ns + 1);
    row_start_.assign(std::size_t(ns) + 1, 0);
    value_start_.assign(std::size_t(ns) + 1, 0);
    for (int q = 0; q <= ns; ++q) {
      row_start_[std::size_t(q)] = pi[q];
      value_start_[std::size_t(q)] = px[q];
    }
    rows_.own(std::vector<int>(ls, ls + pi[ns]));
    values_.own(std::vector<double>(lx, lx + px[ns]));
    size_ = n;
    ok = index_supernodes();
    supernodal_ = true;
  }
  if (l) cholmod_free_factor(&l, &cm);
  cholmod_finish(&cm);
  return ok;
#else
  (void)a_in;
  return false;
#endif
}

/// column_super_ and super_parent_ from super_, row_start_ and rows_ (size_ set); false when a
/// diagonal entry is not positive and finite.
bool SparseFactor::index_supernodes() {
  const int ns = int(super_.size()) - 1;
  bool ok = true;
  column_super_.resize(std::size_t(size_));
  for (int q = 0; q < ns; ++q) {
    const std::int64_t nsrow = row_start_[std::size_t(q) + 1] - row_start_[std::size_t(q)];
    for (int j = super_[std::size_t(q)]; j < super_[std::size_t(q) + 1]; ++j) {
      column_super_[std::size_t(j)] = q;
      const double d =
          values_[std::size_t(value_start_[std::size_t(q)] + std::int64_t(j - super_[std::size_t(q)]) * (nsrow + 1))];
      if (!(d > 0) || !std::isfinite(d)) ok = false;
    }
  }
  super_parent_.assign(std::size_t(ns), -1);
  for (int q = 0; q < ns; ++q) {
    const int nscol = super_[std::size_t(q) + 1] - super_[std::size_t(q)];
    const std::int64_t nsrow = row_start_[std::size_t(q) + 1] - row_start_[std::size_t(q)];
    if (nsrow > nscol)
      super_parent_[std::size_t(q)] =
          column_super_[std::size_t(rows_[std::size_t(row_start_[std::size_t(q)] + nscol)])];
  }
  return ok;
}

void SparseFactor::solve3(const Eigen::MatrixX3d& b, Eigen::MatrixX3d& x) {
  const int n = size_;
  double* w = work3_.data();
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) w[3 * perm_[std::size_t(i)] + c] = b(i, c);
  if (supernodal_) {
    // keep b and the forward solution for regional solves
    last_b_.assign(w, w + 3 * std::size_t(n));
    all_supers_.resize(super_.size() - 1);
    for (std::size_t q = 0; q < all_supers_.size(); ++q) all_supers_[q] = int(q);
    forward_supers<3>(w, all_supers_);
    forward_.assign(w, w + 3 * std::size_t(n));
    have_forward_ = true;
    backward_supers<3>(w, all_supers_);
  } else {
    solve_in_place<3>(w, 0);
  }
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) x(i, c) = w[3 * perm_[std::size_t(i)] + c];
}

void SparseFactor::solve_unit(int i, double* out) {
  const int n = size_;
  double* w = work1_.data();
  std::fill(work1_.begin(), work1_.end(), 0.0);
  w[perm_[std::size_t(i)]] = 1.0;
  if (supernodal_)
    solve_supernodal<1>(w, perm_[std::size_t(i)]);
  else
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

namespace {

/// One supernode of L as the sweeps read it: columns k1 .. k1 + nscol - 1, rows r[0 .. nsrow)
/// (its own columns first), values x column by column (nsrow each).
struct Supernode {
  int k1, nscol, nsrow;
  const int* r;
  const double* x;
};

Supernode supernode(const std::vector<int>& super, const std::vector<std::int64_t>& row_start,
                    const std::vector<std::int64_t>& value_start, const int* rows, const double* val, int q) {
  const int k1 = super[std::size_t(q)], nscol = super[std::size_t(q) + 1] - k1;
  const std::int64_t r0 = row_start[std::size_t(q)];
  const int nsrow = int(row_start[std::size_t(q) + 1] - r0);
  return {k1, nscol, nsrow, rows + r0, val + value_start[std::size_t(q)]};
}

/// The forward sweep L z = w over one supernode (K right-hand sides interleaved in w), each
/// column streamed once; a column whose value is zero for every right-hand side is skipped.
template <int K>
void forward_supernode(double* w, const Supernode& s) {
  for (int jj = 0; jj < s.nscol; ++jj) {
    const double* col = s.x + std::int64_t(jj) * s.nsrow;
    double* wj = w + K * std::int64_t(s.k1 + jj);
    bool zero = true;
    for (int c = 0; c < K; ++c) {
      wj[c] /= col[jj];
      zero = zero && wj[c] == 0.0;
    }
    if (zero) continue;
    double v[K];
    for (int c = 0; c < K; ++c) v[c] = wj[c];
    for (int ii = jj + 1; ii < s.nsrow; ++ii) {
      double* wi = w + K * std::int64_t(s.r[ii]);
      const double l = col[ii];
      for (int c = 0; c < K; ++c) wi[c] -= l * v[c];
    }
  }
}

/// The backward sweep L^T x = z over one supernode, its columns last to first.
template <int K>
void backward_supernode(double* w, const Supernode& s) {
  for (int jj = s.nscol - 1; jj >= 0; --jj) {
    const double* col = s.x + std::int64_t(jj) * s.nsrow;
    double acc[K];
    double* wj = w + K * std::int64_t(s.k1 + jj);
    for (int c = 0; c < K; ++c) acc[c] = wj[c];
    for (int ii = jj + 1; ii < s.nsrow; ++ii) {
      const double* wi = w + K * std::int64_t(s.r[ii]);
      const double l = col[ii];
      for (int c = 0; c < K; ++c) acc[c] -= l * wi[c];
    }
    for (int c = 0; c < K; ++c) wj[c] = acc[c] / col[jj];
  }
}

}  // namespace

template <int K>
void SparseFactor::solve_supernodal(double* w, int first) const {
  const int ns = int(super_.size()) - 1;
  // forward: L z = w, supernode by supernode (columns in order), from the one holding `first`
  for (int q = first > 0 ? column_super_[std::size_t(first)] : 0; q < ns; ++q)
    forward_supernode<K>(w, supernode(super_, row_start_, value_start_, rows_.data(), values_.data(), q));
  // backward: L^T x = z
  for (int q = ns - 1; q >= 0; --q)
    backward_supernode<K>(w, supernode(super_, row_start_, value_start_, rows_.data(), values_.data(), q));
}

template <int K>
void SparseFactor::forward_supers(double* w, const std::vector<int>& supers) const {
  for (const int q : supers)
    forward_supernode<K>(w, supernode(super_, row_start_, value_start_, rows_.data(), values_.data(), q));
}

template <int K>
void SparseFactor::backward_supers(double* w, const std::vector<int>& supers) const {
  for (auto it = supers.rbegin(); it != supers.rend(); ++it)
    backward_supernode<K>(w, supernode(super_, row_start_, value_start_, rows_.data(), values_.data(), *it));
}

/// Adds the ancestors of `supers` (marked with a new generation) and sorts: a closed set under
/// the elimination tree's parent, in ascending (forward) order.
void SparseFactor::ancestors(std::vector<int>& supers) {
  if (++generation_ == 0) {
    std::fill(mark_.begin(), mark_.end(), 0u);
    generation_ = 1;
  }
  const std::size_t given = supers.size();
  std::vector<int> seeds(supers.begin(), supers.end());
  supers.clear();
  for (std::size_t k = 0; k < given; ++k)
    for (int q = seeds[k]; q >= 0 && mark_[std::size_t(q)] != generation_; q = super_parent_[std::size_t(q)]) {
      mark_[std::size_t(q)] = generation_;
      supers.push_back(q);
    }
  std::sort(supers.begin(), supers.end());
}

const std::vector<int>& SparseFactor::set_partial_rows(const std::vector<int>& rows) {
  closure_supers_.clear();
  closure_rows_.clear();
  closure_columns_ = 0;
  if (!supernodal_) return closure_rows_;
  for (const int i : rows) closure_supers_.push_back(column_super_[std::size_t(perm_[std::size_t(i)])]);
  ancestors(closure_supers_);
  std::vector<int> inverse(static_cast<std::size_t>(size_));
  for (int i = 0; i < size_; ++i) inverse[std::size_t(perm_[std::size_t(i)])] = i;
  for (const int q : closure_supers_)
    for (int j = super_[std::size_t(q)]; j < super_[std::size_t(q) + 1]; ++j) closure_rows_.push_back(inverse[std::size_t(j)]);
  closure_columns_ = std::int64_t(closure_rows_.size());
  std::sort(closure_rows_.begin(), closure_rows_.end());
  return closure_rows_;
}

int SparseFactor::solve3_partial(const Eigen::MatrixX3d& b, Eigen::MatrixX3d& x) {
  if (!supernodal_ || !have_forward_ || closure_supers_.empty()) {
    solve3(b, x);
    return size_;
  }
  const int n = size_;
  double* w = work3_.data();  // zero outside what a pass touches (restored below)
  // the rows where b changed, exactly, and their supernodes
  changed_supers_.clear();
  int changed = 0;
  for (int i = 0; i < n; ++i) {
    const int k = perm_[std::size_t(i)];
    bool diff = false;
    for (int c = 0; c < 3; ++c) {
      const double d = b(i, c) - last_b_[3 * std::size_t(k) + std::size_t(c)];
      w[3 * k + c] = d;
      diff = diff || d != 0.0;
    }
    if (diff) {
      ++changed;
      for (int c = 0; c < 3; ++c) last_b_[3 * std::size_t(k) + std::size_t(c)] = b(i, c);
      changed_supers_.push_back(column_super_[std::size_t(k)]);
    }
  }
  // forward on the changed rows' ancestors: z += L^-1 P (b - last b)
  if (!changed_supers_.empty()) {
    ancestors(changed_supers_);
    forward_supers<3>(w, changed_supers_);
    for (const int q : changed_supers_)
      for (int j = super_[std::size_t(q)]; j < super_[std::size_t(q) + 1]; ++j)
        for (int c = 0; c < 3; ++c) forward_[3 * std::size_t(j) + std::size_t(c)] += w[3 * j + c];
  }
  std::fill(work3_.begin(), work3_.end(), 0.0);
  // backward on the closure
  for (const int q : closure_supers_)
    for (int j = super_[std::size_t(q)]; j < super_[std::size_t(q) + 1]; ++j)
      for (int c = 0; c < 3; ++c) w[3 * j + c] = forward_[3 * std::size_t(j) + std::size_t(c)];
  backward_supers<3>(w, closure_supers_);
  for (const int i : closure_rows_)
    for (int c = 0; c < 3; ++c) x(i, c) = w[3 * perm_[std::size_t(i)] + c];
  std::fill(work3_.begin(), work3_.end(), 0.0);
  return changed;
}

void SparseFactor::solve_unit_partial(int i, double* out) {
  if (!supernodal_ || closure_supers_.empty()) return solve_unit(i, out);
  const int n = size_;
  double* w = work1_.data();
  std::fill(work1_.begin(), work1_.end(), 0.0);
  const int k = perm_[std::size_t(i)];
  w[k] = 1.0;
  changed_supers_.assign(1, column_super_[std::size_t(k)]);
  ancestors(changed_supers_);
  forward_supers<1>(w, changed_supers_);
  // backward on the closure only (columns of the closure off the ancestors hold 0: right)
  for (const int q : changed_supers_)
    if (!std::binary_search(closure_supers_.begin(), closure_supers_.end(), q))
      for (int j = super_[std::size_t(q)]; j < super_[std::size_t(q) + 1]; ++j) w[j] = 0.0;
  backward_supers<1>(w, closure_supers_);
  std::fill(out, out + n, 0.0);
  for (const int r : closure_rows_) out[r] = w[perm_[std::size_t(r)]];
}

void SparseFactor::forward_unit(int i, UnitForward& z) {
  z.first.clear();
  z.count.clear();
  z.offset.clear();
  z.value.clear();
  double* w = work1_.data();
  const int k = perm_[std::size_t(i)];
  path_.clear();
  if (supernodal_) {
    for (int q = column_super_[std::size_t(k)]; q >= 0; q = super_parent_[std::size_t(q)]) path_.push_back(q);
    std::sort(path_.begin(), path_.end());
    for (const int q : path_)
      for (int j = super_[std::size_t(q)]; j < super_[std::size_t(q) + 1]; ++j) w[j] = 0.0;
    w[k] = 1.0;
    forward_supers<1>(w, path_);  // writes only the path's columns (a supernode's rows are its ancestors')
    for (const int q : path_) {
      const int j0 = super_[std::size_t(q)], nc = super_[std::size_t(q) + 1] - j0;
      z.first.push_back(j0);
      z.count.push_back(nc);
      z.offset.push_back(std::int64_t(z.value.size()));
      z.value.insert(z.value.end(), w + j0, w + j0 + nc);
      std::fill(w + j0, w + j0 + nc, 0.0);
    }
    return;
  }
  // simplicial L D L^T: the path of columns k, parent(k), ... (ascending)
  for (int j = k; j >= 0; j = parent_[std::size_t(j)]) path_.push_back(j);
  for (const int j : path_) w[j] = 0.0;
  w[k] = 1.0;
  const std::int64_t* outer = outer_.data();
  const int* inner = inner_.data();
  const double* val = values_.data();
  for (const int j : path_) {
    const double wj = w[j];
    if (wj == 0.0) continue;
    for (std::int64_t p = outer[j]; p < outer[j + 1]; ++p) w[inner[p]] -= val[p] * wj;  // rows: j's ancestors
  }
  for (const int j : path_) {
    if (z.first.empty() || z.first.back() + z.count.back() != j) {
      z.first.push_back(j);
      z.count.push_back(0);
      z.offset.push_back(std::int64_t(z.value.size()));
    }
    ++z.count.back();
    z.value.push_back(w[j] * inv_sqrt_d_[std::size_t(j)]);
    w[j] = 0.0;
  }
}

double SparseFactor::dot(const UnitForward& a, const UnitForward& b) {
  double acc = 0.0;
  std::size_t i = 0, j = 0;
  while (i < a.first.size() && j < b.first.size()) {
    const int a0 = a.first[i], a1 = a0 + a.count[i];
    const int b0 = b.first[j], b1 = b0 + b.count[j];
    const int lo = std::max(a0, b0), hi = std::min(a1, b1);
    if (lo < hi) {
      const double* x = a.value.data() + a.offset[i] + (lo - a0);
      const double* y = b.value.data() + b.offset[j] + (lo - b0);
      double s = 0.0;
      for (int t = 0; t < hi - lo; ++t) s += x[t] * y[t];
      acc += s;
    }
    if (a1 <= b1) ++i;
    if (b1 <= a1) ++j;
  }
  return acc;
}

void SparseFactor::add_response3(const std::vector<const UnitForward*>& z, const std::vector<double>& forces3,
                                 Eigen::MatrixX3d& x, bool partial) {
  if (z.empty()) return;
  const int n = size_;
  std::fill(work3_.begin(), work3_.end(), 0.0);  // (solve3 leaves its solution there)
  double* w = work3_.data();
  for (std::size_t k = 0; k < z.size(); ++k) {
    const UnitForward& zk = *z[k];
    const double f0 = forces3[3 * k], f1 = forces3[3 * k + 1], f2 = forces3[3 * k + 2];
    for (std::size_t g = 0; g < zk.first.size(); ++g) {
      const double* v = zk.value.data() + zk.offset[g];
      double* wg = w + 3 * std::int64_t(zk.first[g]);
      for (int t = 0; t < zk.count[g]; ++t) {
        wg[3 * t] += v[t] * f0;
        wg[3 * t + 1] += v[t] * f1;
        wg[3 * t + 2] += v[t] * f2;
      }
    }
  }
  if (supernodal_) {
    const bool on_closure = partial && !closure_supers_.empty();
    backward_supers<3>(w, on_closure ? closure_supers_ : all_supers_);
    if (on_closure) {
      for (const int i : closure_rows_)
        for (int c = 0; c < 3; ++c) x(i, c) += w[3 * perm_[std::size_t(i)] + c];
    } else {
      for (int i = 0; i < n; ++i)
        for (int c = 0; c < 3; ++c) x(i, c) += w[3 * perm_[std::size_t(i)] + c];
    }
  } else {
    // D^-1/2, then L^T x = w
    for (int j = 0; j < n; ++j)
      for (int c = 0; c < 3; ++c) w[3 * j + c] *= inv_sqrt_d_[std::size_t(j)];
    const std::int64_t* outer = outer_.data();
    const int* inner = inner_.data();
    const double* val = values_.data();
    for (int j = n - 1; j >= 0; --j) {
      double acc[3] = {w[3 * j], w[3 * j + 1], w[3 * j + 2]};
      for (std::int64_t p = outer[j]; p < outer[j + 1]; ++p) {
        const double* wi = w + 3 * std::int64_t(inner[p]);
        for (int c = 0; c < 3; ++c) acc[c] -= val[p] * wi[c];
      }
      for (int c = 0; c < 3; ++c) w[3 * j + c] = acc[c];
    }
    for (int i = 0; i < n; ++i)
      for (int c = 0; c < 3; ++c) x(i, c) += w[3 * perm_[std::size_t(i)] + c];
  }
  std::fill(work3_.begin(), work3_.end(), 0.0);  // solve3_partial expects it zero
}

template void SparseFactor::solve_supernodal<1>(double*, int) const;
template void SparseFactor::solve_supernodal<3>(double*, int) const;
template void SparseFactor::solve_in_place<1>(double*, int) const;
template void SparseFactor::solve_in_place<3>(double*, int) const;

// --- the factor as bytes: the factor cache ---------------------------------------------------

namespace {

constexpr char kMagic[8] = {'V', 'X', 'F', 'A', 'C', 'T', 'O', 'R'};
constexpr std::uint32_t kFormatVersion = 2;

constexpr std::size_t kAlign = 64;  ///< every array starts at a multiple of this in the file

/// Writes values and feeds them to the checksum.
class HashedWriter {
 public:
  explicit HashedWriter(std::ostream& out) : out_(out) {}
  void bytes(const void* p, std::size_t n) {
    hash_.add(p, n);
    out_.write(static_cast<const char*>(p), std::streamsize(n));
    at_ += n;
  }
  template <typename T>
  void value(const T& v) {
    bytes(&v, sizeof v);
  }
  /// The count, zeros up to the next kAlign boundary, the values.
  template <typename T>
  void array(const T* data, std::size_t n) {
    value(std::uint64_t(n));
    static constexpr unsigned char kZeros[kAlign] = {};
    bytes(kZeros, (kAlign - at_ % kAlign) % kAlign);
    bytes(data, n * sizeof(T));
  }
  template <typename V>
  void array(const V& v) {
    array(v.data(), v.size());
  }
  [[nodiscard]] std::uint64_t checksum() const { return hash_.value(); }

 private:
  std::ostream& out_;
  ContentHash hash_;
  std::size_t at_{0};
};

/// Reads what HashedWriter wrote from memory; the first failure sticks.
class HashedReader {
 public:
  HashedReader(const unsigned char* data, std::size_t size) : data_(data), size_(size) {}
  /// The next n bytes (null on failure).
  const unsigned char* bytes(std::size_t n, const char* what) {
    if (!error_.empty()) return nullptr;
    if (n > size_ - at_) {
      fail(std::string("truncated at ") + what);
      return nullptr;
    }
    const unsigned char* p = data_ + at_;
    hash_.add(p, n);
    at_ += n;
    return p;
  }
  template <typename T>
  bool value(T& v, const char* what) {
    const unsigned char* p = bytes(sizeof v, what);
    if (p) std::memcpy(&v, p, sizeof v);
    return p != nullptr;
  }
  /// An array's values in place (aligned for T) and their count.
  template <typename T>
  std::pair<const T*, std::size_t> array(const char* what) {
    std::uint64_t n = 0;
    if (!value(n, what)) return {nullptr, 0};
    bytes((kAlign - at_ % kAlign) % kAlign, what);
    if (!error_.empty()) return {nullptr, 0};
    if (n > (size_ - at_) / sizeof(T)) {
      fail(std::string("truncated: the size of ") + what + " runs past the end of the file");
      return {nullptr, 0};
    }
    const unsigned char* p = bytes(std::size_t(n) * sizeof(T), what);
    if (!p) return {nullptr, 0};
    if (reinterpret_cast<std::uintptr_t>(p) % alignof(T) != 0) {
      fail("the data is not aligned");
      return {nullptr, 0};
    }
    return {reinterpret_cast<const T*>(p), std::size_t(n)};
  }
  /// Copies an array.
  template <typename T>
  void copy(std::vector<T>& v, const char* what) {
    const auto [p, n] = array<T>(what);
    if (p) v.assign(p, p + n);
  }
  /// Views an array (with `keep`) or copies it.
  template <typename T>
  void share(SharedArray<T>& v, const std::shared_ptr<const void>& keep, const char* what) {
    const auto [p, n] = array<T>(what);
    if (!p) return;
    if (keep)
      v.view(p, n, keep);
    else
      v.own(std::vector<T>(p, p + n));
  }
  void fail(std::string why) {
    if (error_.empty()) error_ = std::move(why);
  }
  [[nodiscard]] std::uint64_t checksum() const { return hash_.value(); }
  [[nodiscard]] const std::string& error() const { return error_; }
  [[nodiscard]] std::size_t remaining() const { return size_ - at_; }

 private:
  const unsigned char* data_;
  std::size_t size_;
  std::size_t at_{0};
  ContentHash hash_;
  std::string error_;
};

/// True when v holds 0 .. v.size()-1 each once.
bool is_permutation(const std::vector<int>& v) {
  std::vector<std::uint8_t> seen(v.size(), 0);
  for (int x : v) {
    if (x < 0 || std::size_t(x) >= v.size() || seen[std::size_t(x)]) return false;
    seen[std::size_t(x)] = 1;
  }
  return true;
}

}  // namespace

std::string FactorKey::name() const {
  char hex[17];
  static constexpr char kDigits[] = "0123456789abcdef";
  for (int i = 0; i < 16; ++i) hex[i] = kDigits[(hash >> (60 - 4 * i)) & 0xF];
  hex[16] = 0;
  return std::string(SparseFactor::to_string(SparseFactor::Backend(backend))) + "-" + std::to_string(rows) + "n-" +
         std::to_string(nonzeros) + "nz-" + hex;
}

std::uint64_t SparseFactor::stored_bytes() const {
  const auto b = [](const auto& v) { return std::uint64_t(v.size() * sizeof(v[0])); };
  return 64 + b(perm_) + b(values_) +
         (supernodal_ ? b(super_) + b(rows_) + b(row_start_) + b(value_start_) : b(outer_) + b(inner_) + b(inv_d_));
}

void SparseFactor::write(std::ostream& out) const {
  HashedWriter w(out);
  w.bytes(kMagic, sizeof kMagic);
  w.value(kFormatVersion);
  w.value(std::uint32_t(sizeof(int)));
  w.value(std::uint8_t(backend_));
  w.value(std::uint8_t(supernodal_ ? 1 : 0));
  w.value(std::int64_t(size_));
  w.array(perm_);
  w.array(values_);
  if (supernodal_) {
    w.array(super_);
    w.array(rows_);
    w.array(row_start_);
    w.array(value_start_);
  } else {
    w.array(outer_);
    w.array(inner_);
    w.array(inv_d_);
  }
  const std::uint64_t sum = w.checksum();
  out.write(reinterpret_cast<const char*>(&sum), sizeof sum);  // not hashed: the hash of what precedes
  if (!out) throw Error("sparse factor: writing the factor failed (disk full?)");
}

bool SparseFactor::read(const unsigned char* data, std::size_t bytes, std::shared_ptr<const void> keep,
                        std::string* why) {
  const auto t0 = std::chrono::steady_clock::now();
  reset();
  HashedReader r(data, bytes);
  std::uint32_t version = 0, int_bytes = 0;
  std::uint8_t backend = 0, supernodal = 0;
  std::int64_t n = 0;
  if (const unsigned char* magic = r.bytes(sizeof kMagic, "the header");
      magic && std::memcmp(magic, kMagic, sizeof kMagic) != 0)
    r.fail("not a voxelastic factor file");
  r.value(version, "the header");
  if (r.error().empty() && version != kFormatVersion)
    r.fail("format version " + std::to_string(version) + ", this build reads " + std::to_string(kFormatVersion));
  r.value(int_bytes, "the header");
  r.value(backend, "the header");
  r.value(supernodal, "the header");
  r.value(n, "the header");
  if (r.error().empty() && (int_bytes != sizeof(int) || backend > std::uint8_t(Backend::eigen_amd) || supernodal > 1 ||
                            n < 0 || n > std::numeric_limits<int>::max()))
    r.fail("a header this build cannot read");
  r.copy(perm_, "the permutation");
  r.share(values_, keep, "the values");
  if (supernodal) {
    r.copy(super_, "the supernodes");
    r.share(rows_, keep, "the row indices");
    r.copy(row_start_, "the row starts");
    r.copy(value_start_, "the value starts");
  } else {
    r.copy(outer_, "the column starts");
    r.copy(inner_, "the row indices");
    r.copy(inv_d_, "the diagonal");
  }
  const std::uint64_t expected = r.checksum();
  std::uint64_t sum = 0;
  if (r.value(sum, "the checksum") && sum != expected) r.fail("the checksum does not match (a damaged file)");
  if (r.error().empty() && r.remaining() != 0)
    r.fail(std::to_string(r.remaining()) + " bytes after the end of the factor");
  // the structure: whatever a solve indexes must be in range
  const int size = int(n);
  if (r.error().empty() && (perm_.size() != std::size_t(size) || !is_permutation(perm_)))
    r.fail("the permutation is not one of the matrix's rows");
  if (r.error().empty() && supernodal) {
    const std::size_t ns = super_.empty() ? 0 : super_.size() - 1;
    bool good = !super_.empty() && super_.front() == 0 && super_.back() == size && row_start_.size() == ns + 1 &&
                value_start_.size() == ns + 1 && row_start_.front() == 0 && value_start_.front() == 0 &&
                row_start_.back() == std::int64_t(rows_.size()) && value_start_.back() == std::int64_t(values_.size());
    for (std::size_t q = 0; good && q < ns; ++q) {
      const std::int64_t nscol = std::int64_t(super_[q + 1]) - super_[q];
      const std::int64_t nsrow = row_start_[q + 1] - row_start_[q];
      good = nscol > 0 && nsrow >= nscol && value_start_[q + 1] - value_start_[q] == nsrow * nscol;
      // a supernode's rows: its own columns, then rows below them, ascending and in range
      for (std::int64_t k = 0; good && k < nsrow; ++k) {
        const int row = rows_[std::size_t(row_start_[q] + k)];
        good = k < nscol ? row == super_[q] + int(k)
                         : row >= super_[q + 1] && row < size && row > rows_[std::size_t(row_start_[q] + k - 1)];
      }
    }
    if (!good) r.fail("the supernodes do not tile the matrix");
  } else if (r.error().empty()) {
    bool good = outer_.size() == std::size_t(size) + 1 && outer_.front() == 0 &&
                outer_.back() == std::int64_t(inner_.size()) && inner_.size() == values_.size() &&
                inv_d_.size() == std::size_t(size);
    for (int j = 0; good && j < size; ++j) {
      good = outer_[std::size_t(j)] <= outer_[std::size_t(j) + 1] && inv_d_[std::size_t(j)] > 0 &&
             std::isfinite(inv_d_[std::size_t(j)]);
      for (std::int64_t p = outer_[std::size_t(j)]; good && p < outer_[std::size_t(j) + 1]; ++p)
        good = inner_[std::size_t(p)] > j && inner_[std::size_t(p)] < size;
    }
    if (!good) r.fail("the columns are not a lower triangle of the matrix");
  }
  size_ = size;
  supernodal_ = supernodal != 0;
  if (r.error().empty() && supernodal_ && !index_supernodes()) r.fail("a diagonal entry is not positive");
  if (!r.error().empty()) {
    if (why) *why = r.error();
    reset();
    return false;
  }
  backend_ = Backend(backend);
  finish();
  from_cache_ = true;
  factor_s_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

}  // namespace vx
