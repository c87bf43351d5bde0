#include "sim/sparse_factor.h"
// The solves with the factor (sparse_factor.h): the whole solves, the regional (partial) solves
// on an elimination-tree closure, the unit columns' forward halves, the far field's forward
// fields; the simplicial sweeps here, the supernodal ones in sparse_factor_sweeps.cpp.

#include <Eigen/Core>
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <vector>

#include "base/parallel.h"

namespace vx {

namespace {

/// Rows per chunk of forward3_partial's scan for the rows where b changed.
constexpr std::int64_t kScanGrain = 1024;

}  // namespace

void SparseFactor::solve3(const Eigen::MatrixX3d& b, Eigen::MatrixX3d& x) {
  const int n = size_;
  double* w = work3_.data();
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) w[3 * perm_[std::size_t(i)] + c] = b(i, c);
  if (supernodal_) {
    // keep b and the forward solution for regional solves
    last_b_.assign(b.data(), b.data() + 3 * std::size_t(n));
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
  std::fill(work3_.begin(), work3_.end(), 0.0);  // the regional halves expect it zero
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

void SparseFactor::solve_units(const int* rows, int count, double* out, std::size_t stride) {
  constexpr int K = kUnitLanes;
  const int n = size_;
  if (count <= 0) return;
  // the supernodal factor (the whole model's: a few columns, sweeps of its own), one at a time
  if (supernodal_) {
    for (int a = 0; a < count; ++a) solve_unit(rows[a], out + std::size_t(a) * stride);
    return;
  }
  // the passes (kUnitLanes columns each) on the caller's threads, each thread with its own lanes'
  // buffer: a pass writes only its own columns, so the values do not depend on the thread count
  const std::int64_t passes = chunk_count(count, K);
  const int threads = int(std::min<std::int64_t>(resolve_threads(0), passes));
  const std::size_t lanes_size = std::size_t(K) * std::size_t(n);
  if (work_units_.size() < std::size_t(threads) * lanes_size) work_units_.resize(std::size_t(threads) * lanes_size);
  parallel_for_chunks(count, K, threads, [&](std::int64_t, std::int64_t a0, std::int64_t a1) {
    const int lanes = int(a1 - a0);
    // a lone column: solve_unit's own pass (at most one chunk is short: the last)
    if (lanes == 1) {
      solve_unit(rows[a0], out + std::size_t(a0) * stride);
      return;
    }
    double* w = work_units_.data() + std::size_t(omp_get_thread_num()) * lanes_size;
    std::fill(w, w + lanes_size, 0.0);
    // the forward pass from the first of the lanes' columns: a lane whose own column comes later
    // carries zeros until it (x - val * 0 is x), so every lane ends as solve_unit's column
    int first = n;
    for (int c = 0; c < lanes; ++c) {
      const int j = perm_[std::size_t(rows[a0 + c])];
      w[std::size_t(K) * std::size_t(j) + std::size_t(c)] = 1.0;
      first = std::min(first, j);
    }
    solve_in_place<K>(w, first);
    for (int c = 0; c < lanes; ++c) {
      double* o = out + std::size_t(a0 + c) * stride;
      for (int k = 0; k < n; ++k) o[k] = w[std::size_t(K) * std::size_t(perm_[std::size_t(k)]) + std::size_t(c)];
    }
  });
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
  in_closure_.assign(std::size_t(size_), 0);
  for (const int q : closure_supers_)
    for (int j = super_[std::size_t(q)]; j < super_[std::size_t(q) + 1]; ++j) {
      closure_rows_.push_back(inverse[std::size_t(j)]);
      in_closure_[std::size_t(j)] = 1;
    }
  closure_columns_ = std::int64_t(closure_rows_.size());
  std::sort(closure_rows_.begin(), closure_rows_.end());
  return closure_rows_;
}

int SparseFactor::solve3_partial(const Eigen::MatrixX3d& b, Eigen::MatrixX3d& x, const std::vector<int>* rows) {
  if (!partial_ready()) {
    solve3(b, x);
    return size_;
  }
  const int changed = forward3_partial(b, rows);
  backward3_partial({}, {}, x);
  return changed;
}

int SparseFactor::forward3_partial(const Eigen::MatrixX3d& b, const std::vector<int>* rows) {
  const int n = size_;
  double* w = work3_.data();  // zero outside what a pass touches (restored below)
  // the rows where b changed, exactly, and their supernodes (b and last_b_ in the same layout:
  // three linear streams each)
  // (every row, about 1 ms serial on the folded organ's 326,564: on the threads by chunks of rows,
  // whose lists are joined in order; ancestors() sorts them, so the order does not matter)
  const double* bc[3] = {b.data(), b.data() + n, b.data() + 2 * std::int64_t(n)};
  double* lc[3] = {last_b_.data(), last_b_.data() + n, last_b_.data() + 2 * std::int64_t(n)};
  const std::int64_t scanned = rows ? std::int64_t(rows->size()) : n;
  const std::int64_t chunks = chunk_count(scanned, kScanGrain);
  if (std::int64_t(chunk_changed_.size()) < chunks) chunk_changed_.resize(std::size_t(chunks));
  parallel_for_chunks(scanned, kScanGrain, threads_, [&](std::int64_t chunk, std::int64_t lo, std::int64_t hi) {
    std::vector<int>& supers = chunk_changed_[std::size_t(chunk)];
    supers.clear();
    for (std::int64_t r = lo; r < hi; ++r) {
      const std::int64_t i = rows ? (*rows)[std::size_t(r)] : r;
      const double d0 = bc[0][i] - lc[0][i], d1 = bc[1][i] - lc[1][i], d2 = bc[2][i] - lc[2][i];
      if (d0 == 0.0 && d1 == 0.0 && d2 == 0.0) continue;
      const int k = perm_[std::size_t(i)];
      w[3 * k] = d0;
      w[3 * k + 1] = d1;
      w[3 * k + 2] = d2;
      for (int c = 0; c < 3; ++c) lc[c][i] = bc[c][i];
      supers.push_back(column_super_[std::size_t(k)]);
    }
  });
  changed_supers_.clear();
  int changed = 0;
  for (std::int64_t chunk = 0; chunk < chunks; ++chunk) {
    const std::vector<int>& supers = chunk_changed_[std::size_t(chunk)];
    changed_supers_.insert(changed_supers_.end(), supers.begin(), supers.end());
    changed += int(supers.size());
  }
  // forward on the changed rows' ancestors: z += L^-1 P (b - last b)
  if (!changed_supers_.empty()) {
    ancestors(changed_supers_);
    forward_supers<3>(w, changed_supers_);
    // the pass wrote the rows of these supernodes only (a supernode's rows are its ancestors'
    // columns): add them to z and zero them again
    for (const int q : changed_supers_)
      for (int j = super_[std::size_t(q)]; j < super_[std::size_t(q) + 1]; ++j)
        for (int c = 0; c < 3; ++c) {
          forward_[3 * std::size_t(j) + std::size_t(c)] += w[3 * j + c];
          w[3 * j + c] = 0.0;
        }
  }
  return changed;
}

Eigen::Vector3d SparseFactor::solution_row(const UnitForward& zi) const {
  Eigen::Vector3d acc = Eigen::Vector3d::Zero();
  for (std::size_t g = 0; g < zi.first.size(); ++g) {
    const double* v = zi.value.data() + zi.offset[g];
    const double* f = forward_.data() + 3 * std::int64_t(zi.first[g]);
    for (int t = 0; t < zi.count[g]; ++t)
      for (int c = 0; c < 3; ++c) acc[c] += v[t] * f[3 * t + c];
  }
  return acc;
}

void SparseFactor::backward3_partial(const std::vector<const UnitForward*>& z, const std::vector<double>& forces3,
                                     Eigen::MatrixX3d& x) {
  double* w = work3_.data();
  for (const int q : closure_supers_)
    for (int j = super_[std::size_t(q)]; j < super_[std::size_t(q) + 1]; ++j)
      for (int c = 0; c < 3; ++c) w[3 * j + c] = forward_[3 * std::size_t(j) + std::size_t(c)];
  scatter_forward_forces(z, forces3, w);
  // (w is nonzero on the closure's columns and the forces' rows only: zeroed there below)
  if (product_fields_) {
    // g_k^T x = w_k . (the forward solution with the forces): the closure's positions from w,
    // the others from the forward solution (the forces' forward vectors lie on the closure)
    const int m = product_count_, stride = 3 * m;
    const double* wf = product_fields_->data();
    std::fill(field_products_.begin(), field_products_.end(), 0.0);
    double* out = field_products_.data();
    for (int j = 0; j < size_; ++j) {
      const double* zj = in_closure_[std::size_t(j)] ? w + 3 * std::int64_t(j) : forward_.data() + 3 * std::int64_t(j);
      const double* row = wf + std::int64_t(j) * stride;
      for (int k = 0; k < m; ++k) out[k] += row[3 * k] * zj[0] + row[3 * k + 1] * zj[1] + row[3 * k + 2] * zj[2];
    }
  }
  backward_supers<3>(w, closure_supers_);
  for (const int i : closure_rows_)
    for (int c = 0; c < 3; ++c) x(i, c) = w[3 * perm_[std::size_t(i)] + c];
  // zero again where written, not the whole of n x 3 (a pass over memory as long as the scan)
  for (const int q : closure_supers_)
    std::fill(w + 3 * std::int64_t(super_[std::size_t(q)]), w + 3 * std::int64_t(super_[std::size_t(q) + 1]), 0.0);
  for (const UnitForward* zk : z)
    for (std::size_t g = 0; g < zk->first.size(); ++g)
      std::fill(w + 3 * std::int64_t(zk->first[g]), w + 3 * (std::int64_t(zk->first[g]) + zk->count[g]), 0.0);
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

std::pair<std::int64_t, std::int64_t> SparseFactor::longest_unit_forward() const {
  // per supernode (or column): values and segments on its path to the root, parents first (in
  // an elimination tree a parent comes after its children; walked otherwise)
  const bool sup = supernodal_;
  const std::vector<int>& parent = sup ? super_parent_ : parent_;
  const int n = int(parent.size());
  const auto width = [&](int q) { return sup ? std::int64_t(super_[std::size_t(q) + 1] - super_[std::size_t(q)]) : 1; };
  std::vector<std::int64_t> values(std::size_t(n), 0), segments(std::size_t(n), 0);
  std::int64_t most_values = 0, most_segments = 0;
  for (int q = n - 1; q >= 0; --q) {
    std::int64_t v = 0, g = 0;
    const int up = parent[std::size_t(q)];
    if (up > q) {
      v = values[std::size_t(up)], g = segments[std::size_t(up)];
    } else {
      for (int a = up; a >= 0; a = parent[std::size_t(a)]) v += width(a), ++g;
    }
    values[std::size_t(q)] = v + width(q);
    segments[std::size_t(q)] = g + 1;
    most_values = std::max(most_values, values[std::size_t(q)]);
    most_segments = std::max(most_segments, segments[std::size_t(q)]);
  }
  return {most_values, most_segments};
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

/// w += sum_k z_k f_k^T (K = 3 interleaved, factored positions).
void SparseFactor::scatter_forward_forces(const std::vector<const UnitForward*>& z, const std::vector<double>& forces3,
                                          double* w) {
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
}

void SparseFactor::add_response3(const std::vector<const UnitForward*>& z, const std::vector<double>& forces3,
                                 Eigen::MatrixX3d& x, bool partial) {
  if (z.empty()) return;
  const int n = size_;
  double* w = work3_.data();
  scatter_forward_forces(z, forces3, w);
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

void SparseFactor::forward_fields(const Eigen::MatrixXd& g, std::vector<double>& w) const {
  const int n = size_, cols = int(g.cols());
  w.assign(std::size_t(n) * std::size_t(cols), 0.0);
  if (!supernodal_ || cols == 0) return;
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < cols; ++c) w[std::size_t(perm_[std::size_t(i)]) * std::size_t(cols) + std::size_t(c)] = g(i, c);
  std::vector<int> all(super_.size() - 1);
  for (std::size_t q = 0; q < all.size(); ++q) all[q] = int(q);
  // kFieldLanes columns per pass, the last padded
  constexpr int kPass = kFieldLanes;
  std::vector<double> part(std::size_t(kPass) * std::size_t(n));
  for (int c0 = 0; c0 < cols; c0 += kPass) {
    const int nc = std::min(kPass, cols - c0);
    std::fill(part.begin(), part.end(), 0.0);
    for (int j = 0; j < n; ++j)
      for (int c = 0; c < nc; ++c)
        part[std::size_t(kPass) * std::size_t(j) + std::size_t(c)] =
            w[std::size_t(j) * std::size_t(cols) + std::size_t(c0 + c)];
    forward_supers<kPass>(part.data(), all);
    for (int j = 0; j < n; ++j)
      for (int c = 0; c < nc; ++c)
        w[std::size_t(j) * std::size_t(cols) + std::size_t(c0 + c)] =
            part[std::size_t(kPass) * std::size_t(j) + std::size_t(c)];
  }
}

void SparseFactor::add_forward_fields(const std::vector<double>& w, int m, const double* coef) {
  const int stride = 3 * m;
  for (int j = 0; j < size_; ++j) {
    const double* row = w.data() + std::int64_t(j) * stride;
    double* z = forward_.data() + 3 * std::int64_t(j);
    for (int k = 0; k < m; ++k)
      for (int c = 0; c < 3; ++c) z[c] += coef[k] * row[3 * k + c];
  }
}

template void SparseFactor::solve_in_place<1>(double*, int) const;
template void SparseFactor::solve_in_place<3>(double*, int) const;
template void SparseFactor::solve_in_place<SparseFactor::kUnitLanes>(double*, int) const;

}  // namespace vx
