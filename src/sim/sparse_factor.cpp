#include "sim/sparse_factor.h"
// The factorisation: the backends (CHOLMOD, Eigen's LDL^T with METIS or AMD), the supernodes'
// index. The solves are in sparse_factor_solve.cpp, the supernodal sweeps in
// sparse_factor_sweeps.cpp, the byte form in sparse_factor_file.cpp.

#include <dlfcn.h>

#include <Eigen/SparseCholesky>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <mutex>
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

namespace {

/// The name of the BLAS loaded in this process, from a function only it has ("" for none of
/// those).
std::string loaded_blas() {
  using Text = const char* (*)();
  if (void* f = dlsym(RTLD_DEFAULT, "openblas_get_config")) {
    const char* config = reinterpret_cast<Text>(f)();
    return config ? std::string(config) : std::string("OpenBLAS");
  }
  if (void* f = dlsym(RTLD_DEFAULT, "bli_info_get_version_str")) {
    const char* version = reinterpret_cast<Text>(f)();
    return std::string("BLIS ") + (version ? version : "");
  }
  if (dlsym(RTLD_DEFAULT, "MKL_Get_Version_String")) return "MKL";
  return "";
}

/// Puts an OpenBLAS with threads (Debian's libopenblas0-pthread or -openmp, which the
/// alternatives prefer to the single-threaded one install-deps.sh installs) on the calling thread:
/// its threads would compete with the physics' OpenMP team and the region check for the cores
/// (measured 1.9x slower on a loaded machine, nothing gained on a quiet one: docs/bench.md).
void single_threaded_blas() {
  using SetThreads = void (*)(int);
  if (void* f = dlsym(RTLD_DEFAULT, "openblas_set_num_threads")) reinterpret_cast<SetThreads>(f)(1);
}

/// One CHOLMOD factorisation at a time in the process: Debian's single-threaded OpenBLAS (the one
/// install-deps.sh installs) is built without locking, and two threads in its kernels at once
/// corrupt each other's buffers (a factor 24 off in SparseFactor.TwoThreadsFactoringAtOnceGet
/// TheSerialFactor; the palpation map, which factors on each of its threads, read another lesion
/// from run to run). A factorisation is a start-up's, so waiting for another costs little.
std::mutex& factorisation_lock() {
  static std::mutex lock;
  return lock;
}

}  // namespace

std::string SparseFactor::blas_library() {
  if (!available(Backend::cholmod)) return "none";
  const std::string name = loaded_blas();
  return name.empty() ? "the reference BLAS" : name;
}

bool SparseFactor::reference_blas() { return available(Backend::cholmod) && loaded_blas().empty(); }

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

SparseFactor::SweepKernel SparseFactor::default_sweep_kernel() {
  // VOXELASTIC_SWEEP pins the sweeps' kernel (column, gathered), e.g. to compare them in a run
  static const SweepKernel kernel = [] {
    const char* env = std::getenv("VOXELASTIC_SWEEP");
    if (env == nullptr || *env == '\0') return SweepKernel::gathered;
    for (const SweepKernel k : {SweepKernel::column, SweepKernel::gathered})
      if (std::string(env) == to_string(k)) return k;
    throw Error(std::string("VOXELASTIC_SWEEP=") + env +
                " is not a sweep kernel; unset it or choose column or gathered");
  }();
  return kernel;
}

void SparseFactor::reset() {
  size_ = 0;
  supernodal_ = false;
  order_s_ = 0.0;
  have_forward_ = false;
  from_cache_ = false;
  order_given_ = false;
  closure_rows_.clear();
  closure_supers_.clear();
  closure_columns_ = 0;
  perm_.clear();
  outer_.assign(1, 0);
  inner_.clear();
  values_.clear();
  values_single_.clear();
  inv_d_.clear();
  super_.clear();
  rows_.clear();
  row_start_.clear();
  value_start_.clear();
  column_super_.clear();
  super_parent_.clear();
  tree_ok_ = false;
  tree_passes_ = 0;
  most_rows_ = 0;
}

std::vector<int> SparseFactor::order() const {
  std::vector<int> o(perm_.size());
  for (std::size_t row = 0; row < perm_.size(); ++row) o[std::size_t(perm_[row])] = int(row);
  return o;
}

FactorKey SparseFactor::pattern_key(const Matrix& a) {
  ContentHash h;
  const std::int64_t n = a.rows();
  h.add_value(n);
  // column by column, the rows of the lower triangle's entries (the upper is not read)
  std::vector<int> rows;
  for (Eigen::Index j = 0; j < a.outerSize(); ++j) {
    rows.clear();
    for (Matrix::InnerIterator it(a, j); it; ++it)
      if (it.index() >= j) rows.push_back(int(it.index()));
    h.add_value(std::int64_t(rows.size()));
    h.add(rows.data(), rows.size() * sizeof(int));
  }
  FactorKey k;
  k.hash = h.value();
  k.rows = n;
  k.nonzeros = a.nonZeros();
  k.backend = std::uint8_t(Backend::cholmod);
  return k;
}

bool SparseFactor::compute(const Matrix& a, Backend backend, std::span<const int> order,
                           const std::function<bool()>& stop) {
  const auto t0 = std::chrono::steady_clock::now();
  reset();
  if (backend == Backend::automatic || !available(backend)) backend = best_backend();
  const char* stopped = nullptr;  // where a stop was asked (then the factor is empty)
  const auto asked = [&](const char* where) {
    if (!stopped && stop && stop()) stopped = where;
    return stopped != nullptr;
  };
  bool ok = false;
  if (!asked("before it began")) {
    switch (backend) {
      case Backend::cholmod: ok = compute_cholmod(a, order, asked); break;
      case Backend::eigen_metis: ok = compute_eigen(a, true); break;
      default: ok = compute_eigen(a, false); break;
    }
  }
  if (asked("at its end")) {
    reset();
    throw Cancelled("the factorisation of a " + std::to_string(a.rows()) + "-row matrix was stopped " + stopped);
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
    index_tree();
  } else {
    // the elimination tree of L: a column's parent is its first row below the diagonal
    parent_.assign(std::size_t(size_), -1);
    inv_sqrt_d_.resize(std::size_t(size_));
    for (int j = 0; j < size_; ++j) {
      int first = size_;
      for (std::int64_t p = outer_[std::size_t(j)]; p < outer_[std::size_t(j) + 1]; ++p)
        first = std::min(first, inner_[std::size_t(p)]);
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

bool SparseFactor::compute_cholmod(const Matrix& a_in, std::span<const int> order,
                                   const std::function<bool(const char*)>& stop) {
#ifdef VOXELASTIC_HAVE_CHOLMOD
  if (!order.empty() && order.size() != std::size_t(a_in.rows()))
    throw Error("SparseFactor: an order of " + std::to_string(order.size()) + " rows for a matrix of " +
                std::to_string(a_in.rows()));
  Matrix a = a_in;
  a.makeCompressed();
  const int n = int(a.rows());
  const std::lock_guard<std::mutex> one_at_a_time(factorisation_lock());
  cholmod_common cm;
  cholmod_start(&cm);
  single_threaded_blas();
  cm.print = 0;
  cm.error_handler = nullptr;
  cm.supernodal = CHOLMOD_SUPERNODAL;
  cm.nmethods = 1;
  const bool given = !order.empty();
  cm.method[0].ordering = given ? CHOLMOD_GIVEN : CHOLMOD_METIS;
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
  // CHOLMOD checks a given order is a permutation (a null factor if not) and postorders it (an
  // order() is postordered already: it comes back the same)
  // (asked again after the lock, which another factorisation may have held)
  if (stop("before the order")) {
    cholmod_finish(&cm);
    return false;
  }
  const auto t0 = std::chrono::steady_clock::now();
  cholmod_factor* l =
      given ? cholmod_analyze_p(&view, const_cast<int*>(order.data()), nullptr, 0, &cm) : cholmod_analyze(&view, &cm);
  order_s_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  order_given_ = given;
  bool ok = l != nullptr && !stop("after the order, before the numeric factorisation");
  if (ok) ok = cholmod_factorize(&view, l, &cm) && cm.status == CHOLMOD_OK && l->minor == l->n;
  if (ok) ok = !stop("after the numeric factorisation");
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
  (void)order;
  (void)stop;
  return false;
#endif
}

/// What the tree-parallel passes need (sparse_factor.h): every supernode's first descendant and
/// entries, and whether the factor is postordered with its rows ascending (CHOLMOD's is; a
/// factor that is not runs serial).
void SparseFactor::index_tree() {
  const int ns = int(super_.size()) - 1;
  first_desc_.resize(std::size_t(ns));
  super_work_.resize(std::size_t(ns));
  std::vector<int> count(std::size_t(ns), 1);
  tree_ok_ = ns > 1;
  for (int q = 0; q < ns; ++q) first_desc_[std::size_t(q)] = q;
  for (int q = 0; q < ns; ++q) {
    const int up = super_parent_[std::size_t(q)];
    if (up < 0) continue;
    if (up <= q) {
      tree_ok_ = false;
      continue;
    }
    first_desc_[std::size_t(up)] = std::min(first_desc_[std::size_t(up)], first_desc_[std::size_t(q)]);
    count[std::size_t(up)] += count[std::size_t(q)];
  }
  for (int q = 0; q < ns; ++q) {
    // a subtree is the contiguous range [first descendant, q]
    if (count[std::size_t(q)] != q - first_desc_[std::size_t(q)] + 1) tree_ok_ = false;
    const int k1 = super_[std::size_t(q)], nscol = super_[std::size_t(q) + 1] - k1;
    const std::int64_t r0 = row_start_[std::size_t(q)], nsrow = row_start_[std::size_t(q) + 1] - r0;
    const int* r = rows_.data() + r0;
    for (std::int64_t ii = 0; ii < nsrow && tree_ok_; ++ii)
      if (ii < nscol ? r[ii] != k1 + int(ii) : r[ii] <= r[ii - 1]) tree_ok_ = false;
    super_work_[std::size_t(q)] = std::int64_t(nscol) * nsrow - std::int64_t(nscol) * (nscol - 1) / 2;
  }
  tree_work_.assign(std::size_t(ns), 0);
  tree_child_.assign(std::size_t(ns), -1);
  tree_sibling_.assign(std::size_t(ns), -1);
  tree_pos_.assign(std::size_t(ns), -1);
}

bool SparseFactor::use_single_precision_sweeps() {
  if (!supernodal_ || values_.empty()) return single_precision_sweeps();
  std::vector<float> single(values_.size());
  const double* v = values_.data();
  for (std::size_t k = 0; k < single.size(); ++k) single[k] = float(v[k]);
  values_single_.own(std::move(single));
  // the row indices in memory of their own (a copy of a few MB), so that a mapped factor file goes
  // with the double values
  rows_.own(std::vector<int>(rows_.data(), rows_.data() + rows_.size()));
  values_.clear();
  return true;
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
      const std::size_t at =
          std::size_t(value_start_[std::size_t(q)] + std::int64_t(j - super_[std::size_t(q)]) * (nsrow + 1));
      const double d = values_.empty() ? double(values_single_[at]) : values_[at];
      if (!(d > 0) || !std::isfinite(d)) ok = false;
    }
  }
  super_parent_.assign(std::size_t(ns), -1);
  most_rows_ = 0;
  for (int q = 0; q < ns; ++q) {
    const int nscol = super_[std::size_t(q) + 1] - super_[std::size_t(q)];
    const std::int64_t nsrow = row_start_[std::size_t(q) + 1] - row_start_[std::size_t(q)];
    most_rows_ = std::max(most_rows_, nsrow);
    if (nsrow > nscol)
      super_parent_[std::size_t(q)] =
          column_super_[std::size_t(rows_[std::size_t(row_start_[std::size_t(q)] + nscol)])];
  }
  return ok;
}

}  // namespace vx
