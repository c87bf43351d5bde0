#include "sim/sparse_factor.h"
// The factor's supernodal sweeps (sparse_factor.h): the column and gathered kernels (one copy of
// the gathered ones per instruction set), the passes over a list of supernodes, and the
// tree-parallel passes (plan_tree: the subtrees below the top separators on the threads). The
// solves that call them: sparse_factor_solve.cpp.

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#include "base/parallel.h"
#include "base/simd.h"

// The lane vectors of the gathered sweeps never cross a function boundary (always_inline), so the
// ABI note GCC gives for vector arguments without AVX does not apply.
#pragma GCC diagnostic ignored "-Wpsabi"

namespace vx {

namespace {

/// One supernode of L as the sweeps read it: columns k1 .. k1 + nscol - 1, rows r[0 .. nsrow)
/// (its own columns first), values x column by column (nsrow each).
template <typename T>
struct Supernode {
  int k1, nscol, nsrow;
  const int* r;
  const T* x;
};

/// The supernodal arrays a pass reads (T: the values' type).
template <typename T>
struct SupernodalArrays {
  const int* super;
  const std::int64_t* row_start;
  const std::int64_t* value_start;
  const int* rows;
  const T* values;
  SupernodalArrays(const std::vector<int>& s, const std::vector<std::int64_t>& rs, const std::vector<std::int64_t>& vs,
                   const SharedArray<int>& r, const T* v)
      : super(s.data()), row_start(rs.data()), value_start(vs.data()), rows(r.data()), values(v) {}
  [[nodiscard]] Supernode<T> at(int q) const {
    const int k1 = super[q], nscol = super[q + 1] - k1;
    const std::int64_t r0 = row_start[q];
    return {k1, nscol, int(row_start[q + 1] - r0), rows + r0, values + value_start[q]};
  }
};

/// The supernodes of a pass: `list` (ascending, `count` of them), or without a list the range
/// first .. first + count - 1.
struct SuperList {
  const int* list;
  int count;
  int first;
  [[nodiscard]] int at(int i) const { return list != nullptr ? list[i] : first + i; }
};

#define VX_SWEEP_INLINE [[gnu::always_inline]] inline

/// The forward sweep L z = w over one supernode (K right-hand sides interleaved in w), each
/// column streamed once; a column whose value is zero for every right-hand side is skipped.
/// The column kernel: every entry scatters to w through its row index. Updates the rows
/// r[.. row_end) (row_end >= nscol); kLeftOut: only what that left out, the updates of the rows
/// r[row_end ..] from the columns' final values, column by column as it would have made them.
template <int K, bool kLeftOut = false, typename T>
VX_SWEEP_INLINE void forward_columns(double* w, const Supernode<T>& s, int row_end) {
  for (int jj = 0; jj < s.nscol; ++jj) {
    const T* col = s.x + std::int64_t(jj) * s.nsrow;
    double* wj = w + K * std::int64_t(s.k1 + jj);
    bool zero = true;
    for (int c = 0; c < K; ++c) {
      if constexpr (!kLeftOut) wj[c] /= col[jj];
      zero = zero && wj[c] == 0.0;
    }
    if (zero) continue;
    double v[K];
    for (int c = 0; c < K; ++c) v[c] = wj[c];
    const int from = kLeftOut ? row_end : jj + 1, to = kLeftOut ? s.nsrow : row_end;
    for (int ii = from; ii < to; ++ii) {
      double* wi = w + K * std::int64_t(s.r[ii]);
      const double l = col[ii];
      for (int c = 0; c < K; ++c) wi[c] -= l * v[c];
    }
  }
}

/// The backward sweep L^T x = z over one supernode, its columns last to first (column kernel).
template <int K, typename T>
VX_SWEEP_INLINE void backward_columns(double* w, const Supernode<T>& s) {
  for (int jj = s.nscol - 1; jj >= 0; --jj) {
    const T* col = s.x + std::int64_t(jj) * s.nsrow;
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

// The gathered kernels (K = 1 or 3): the supernode's rows of w are gathered once into one
// contiguous array per right-hand side, the columns run on those arrays (unit stride: the
// compiler vectorises over the rows), and the rows are scattered back once. The column kernel
// goes through the row index at every entry of every column; a supernode of nscol columns and
// nsrow rows reads the index nsrow times here instead of about nscol x nsrow / 2. The top
// separators of a nested-dissection factor, most of a regional pass, are hundreds of columns wide.

/// Gathers w's rows r[0 .. n) into t (K arrays of `ld`).
template <int K>
VX_SWEEP_INLINE void gather_rows(const double* w, const int* r, int n, double* t, int ld) {
  for (int ii = 0; ii < n; ++ii) {
    const double* wi = w + K * std::int64_t(r[ii]);
    for (int c = 0; c < K; ++c) t[c * ld + ii] = wi[c];
  }
}

template <int K>
VX_SWEEP_INLINE void scatter_rows(double* w, const int* r, int n, const double* t, int ld) {
  for (int ii = 0; ii < n; ++ii) {
    double* wi = w + K * std::int64_t(r[ii]);
    for (int c = 0; c < K; ++c) wi[c] = t[c * ld + ii];
  }
}

/// Columns per pass over the rows in the gathered kernels: each row of t is loaded and stored
/// once for kBlock columns (the column kernel loads and stores it once per column).
constexpr int kBlock = 4;

/// kLanes doubles in one vector (GCC's and clang's vector extensions; the instruction set each
/// copy of the passes is compiled for makes it one register or several).
template <int kLanes>
struct Lanes;
template <>
struct Lanes<2> {
  using type = double __attribute__((vector_size(16)));
};
template <>
struct Lanes<4> {
  using type = double __attribute__((vector_size(32)));
};
template <>
struct Lanes<8> {
  using type = double __attribute__((vector_size(64)));
};
template <int kLanes>
using vec = typename Lanes<kLanes>::type;

template <int kLanes>
VX_SWEEP_INLINE vec<kLanes> load(const double* p) {
  vec<kLanes> v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
template <int kLanes>
VX_SWEEP_INLINE void store(double* p, const vec<kLanes>& v) {
  std::memcpy(p, &v, sizeof v);
}
template <int kLanes>
VX_SWEEP_INLINE vec<kLanes> splat(double x) {
  vec<kLanes> v;
  for (int k = 0; k < kLanes; ++k) v[k] = x;
  return v;
}

/// kLanes floats of L widened to doubles (the single-precision copy of the values:
/// SparseFactor::set_sweep_precision).
template <int kLanes>
struct FloatLanes;
template <>
struct FloatLanes<2> {
  using type = float __attribute__((vector_size(8)));
};
template <>
struct FloatLanes<4> {
  using type = float __attribute__((vector_size(16)));
};
template <>
struct FloatLanes<8> {
  using type = float __attribute__((vector_size(32)));
};
template <int kLanes>
VX_SWEEP_INLINE vec<kLanes> load(const float* p) {
  typename FloatLanes<kLanes>::type f;
  std::memcpy(&f, p, sizeof f);
  return __builtin_convertvector(f, vec<kLanes>);
}

/// t_c -= l_j v_jc over rows [begin, end) for the m <= kBlock columns l_j (j in order, one
/// subtraction after the other: the column kernel's arithmetic, the same bits).
template <int K, int kLanes, typename T>
VX_SWEEP_INLINE void update_rows(double* t, int ld, const T* const* l, const double (*v)[K], int m, int begin,
                                 int end) {
  using V = vec<kLanes>;
  int ii = begin;
  if (m == kBlock) {
    V vv[kBlock][K];
    for (int j = 0; j < kBlock; ++j)
      for (int c = 0; c < K; ++c) vv[j][c] = splat<kLanes>(v[j][c]);
    for (; ii + kLanes <= end; ii += kLanes) {
      const V l0 = load<kLanes>(l[0] + ii), l1 = load<kLanes>(l[1] + ii), l2 = load<kLanes>(l[2] + ii),
              l3 = load<kLanes>(l[3] + ii);
      for (int c = 0; c < K; ++c) {
        double* tc = t + c * ld + ii;
        V u = load<kLanes>(tc);
        u -= l0 * vv[0][c];
        u -= l1 * vv[1][c];
        u -= l2 * vv[2][c];
        u -= l3 * vv[3][c];
        store<kLanes>(tc, u);
      }
    }
  }
  for (; ii < end; ++ii)
    for (int c = 0; c < K; ++c) {
      double u = t[c * ld + ii];
      for (int j = 0; j < m; ++j) u -= l[j][ii] * v[j][c];
      t[c * ld + ii] = u;
    }
}

/// out[j][c] = sum over rows [begin, end) of l_j t_c for the m <= kBlock columns l_j (kLanes
/// partial sums each, added in a fixed order: the same bits from run to run).
template <int K, int kLanes, typename T>
VX_SWEEP_INLINE void dot_rows(const double* t, int ld, const T* const* l, int m, int begin, int end, double (*out)[K]) {
  using V = vec<kLanes>;
  V s[kBlock][K];
  for (int j = 0; j < kBlock; ++j)
    for (int c = 0; c < K; ++c) s[j][c] = splat<kLanes>(0.0);
  int ii = begin;
  if (m == kBlock)
    for (; ii + kLanes <= end; ii += kLanes) {
      const V l0 = load<kLanes>(l[0] + ii), l1 = load<kLanes>(l[1] + ii), l2 = load<kLanes>(l[2] + ii),
              l3 = load<kLanes>(l[3] + ii);
      for (int c = 0; c < K; ++c) {
        const V x = load<kLanes>(t + c * ld + ii);
        s[0][c] += l0 * x;
        s[1][c] += l1 * x;
        s[2][c] += l2 * x;
        s[3][c] += l3 * x;
      }
    }
  for (int j = 0; j < m; ++j)
    for (int c = 0; c < K; ++c) {
      double sum = 0.0;
      for (int k = 0; k < kLanes; ++k) sum += s[j][c][k];
      for (int i = ii; i < end; ++i) sum += l[j][i] * t[c * ld + i];
      out[j][c] = sum;
    }
}

/// The gathered forward sweep over one supernode: the rows r[.. row_end) (row_end >= nscol; the
/// rest: forward_external_gathered()).
template <int K, int kLanes, typename T>
VX_SWEEP_INLINE void forward_gathered(double* w, const Supernode<T>& s, double* t, int row_end) {
  const int n = row_end, ld = s.nsrow;
  gather_rows<K>(w, s.r, n, t, ld);
  for (int j0 = 0; j0 < s.nscol; j0 += kBlock) {
    const int m = std::min(kBlock, s.nscol - j0), j1 = j0 + m;
    // the block's own triangle, column by column
    const T* l[kBlock];
    double v[kBlock][K];
    bool zero = true;
    for (int j = 0; j < m; ++j) {
      const int jj = j0 + j;
      l[j] = s.x + std::int64_t(jj) * ld;
      for (int c = 0; c < K; ++c) {
        v[j][c] = t[c * ld + jj] /= l[j][jj];
        zero = zero && v[j][c] == 0.0;
      }
      for (int ii = jj + 1; ii < j1; ++ii)
        for (int c = 0; c < K; ++c) t[c * ld + ii] -= l[j][ii] * v[j][c];
    }
    // the rows below it, all m columns in one pass
    if (!zero) update_rows<K, kLanes>(t, ld, l, v, m, j1, n);
  }
  scatter_rows<K>(w, s.r, n, t, ld);
}

/// What forward_gathered(w, s, t, ext) left out: the rows r[ext ..] updated by the supernode's
/// columns (their values final), block by block as it would have updated them.
template <int K, int kLanes, typename T>
VX_SWEEP_INLINE void forward_external_gathered(double* w, const Supernode<T>& s, double* t, int ext) {
  const int n = s.nsrow, ld = n;
  if (ext >= n) return;
  gather_rows<K>(w, s.r + ext, n - ext, t + ext, ld);
  for (int j0 = 0; j0 < s.nscol; j0 += kBlock) {
    const int m = std::min(kBlock, s.nscol - j0);
    const T* l[kBlock];
    double v[kBlock][K];
    bool zero = true;
    for (int j = 0; j < m; ++j) {
      l[j] = s.x + std::int64_t(j0 + j) * n;
      for (int c = 0; c < K; ++c) {
        v[j][c] = w[K * std::int64_t(s.k1 + j0 + j) + c];
        zero = zero && v[j][c] == 0.0;
      }
    }
    if (!zero) update_rows<K, kLanes>(t, ld, l, v, m, ext, n);
  }
  scatter_rows<K>(w, s.r + ext, n - ext, t + ext, ld);
}

template <int K, int kLanes, typename T>
VX_SWEEP_INLINE void backward_gathered(double* w, const Supernode<T>& s, double* t) {
  const int n = s.nsrow, ld = n;
  gather_rows<K>(w, s.r, n, t, ld);
  // blocks last to first; the last block holds the columns left over (nscol % kBlock)
  for (int j1 = s.nscol; j1 > 0;) {
    const int m = j1 % kBlock != 0 ? j1 % kBlock : kBlock, j0 = j1 - m;
    const T* l[kBlock];
    for (int j = 0; j < m; ++j) l[j] = s.x + std::int64_t(j0 + j) * n;
    // the rows below the block (final already), all m columns in one pass
    double d[kBlock][K];
    dot_rows<K, kLanes>(t, ld, l, m, j1, n, d);
    // the block's own triangle, its columns last to first
    for (int j = m - 1; j >= 0; --j) {
      const int jj = j0 + j;
      for (int c = 0; c < K; ++c) {
        double acc = t[c * ld + jj] - d[j][c];
        for (int ii = jj + 1; ii < j1; ++ii) acc -= l[j][ii] * t[c * ld + ii];
        t[c * ld + jj] = acc / l[j][jj];
      }
    }
    j1 = j0;
  }
  scatter_rows<K>(w, s.r, s.nscol, t, ld);  // only its own columns changed
}

/// Supernodes narrower than this run the column kernel (gathering costs more than it saves).
constexpr int kGatherMinColumns = 4;

/// The per-thread scratch of the gathered kernels (K x the widest supernode's rows).
double* gather_scratch(std::size_t values) {
  thread_local std::vector<double> scratch;
  if (scratch.size() < values) scratch.resize(values);
  return scratch.data();
}

/// No row left out of a forward pass.
constexpr int kAllRows = std::numeric_limits<int>::max();

/// The first of s's rows at or past `end_column` (its rows ascend: SparseFactor::tree_ok_).
template <typename T>
VX_SWEEP_INLINE int first_row_from(const Supernode<T>& s, int end_column) {
  if (end_column == kAllRows) return s.nsrow;
  return int(std::lower_bound(s.r + s.nscol, s.r + s.nsrow, end_column) - s.r);
}

/// True when a supernode's own rows of w are all zero (its forward sweep changes nothing).
template <int K, typename T>
VX_SWEEP_INLINE bool own_rows_zero(const double* w, const Supernode<T>& s) {
  bool zero = true;
  for (int j = 0; j < K * s.nscol && zero; ++j) zero = w[K * std::int64_t(s.k1) + j] == 0.0;
  return zero;
}

/// The forward pass over `supers`, the updates of rows at or past `end_column` left out (those of
/// a slice of a tree-parallel pass); kLeftOut: only those updates, supernode by supernode in order.
template <int K, bool kGathered, int kLanes = 2, bool kLeftOut = false, typename T>
VX_SWEEP_INLINE void forward_pass(double* w, const SupernodalArrays<T>& a, const SuperList& supers, int end_column) {
  for (int i = 0; i < supers.count; ++i) {
    const Supernode<T> s = a.at(supers.at(i));
    const int row_end = first_row_from(s, end_column);
    if (kLeftOut && row_end >= s.nsrow) continue;
    if constexpr (kGathered) {
      if (s.nscol >= kGatherMinColumns) {
        if (own_rows_zero<K>(w, s)) continue;
        double* t = gather_scratch(std::size_t(K) * std::size_t(s.nsrow));
        if constexpr (kLeftOut)
          forward_external_gathered<K, kLanes>(w, s, t, row_end);
        else
          forward_gathered<K, kLanes>(w, s, t, row_end);
        continue;
      }
    }
    forward_columns<K, kLeftOut>(w, s, row_end);
  }
}

template <int K, bool kGathered, int kLanes = 2, typename T>
VX_SWEEP_INLINE void backward_pass(double* w, const SupernodalArrays<T>& a, const SuperList& supers) {
  for (int i = supers.count - 1; i >= 0; --i) {
    const Supernode<T> s = a.at(supers.at(i));
    if constexpr (kGathered) {
      if (s.nscol >= kGatherMinColumns) {
        backward_gathered<K, kLanes>(w, s, gather_scratch(std::size_t(K) * std::size_t(s.nsrow)));
        continue;
      }
    }
    backward_columns<K>(w, s);
  }
}

// one copy of the gathered passes per instruction set (the same source; the compiler vectorises
// the rows for each)
#define VX_SWEEP_PASSES(name, lanes, attributes)                                                               \
  template <int K, typename T>                                                                                 \
  attributes void forward_##name(double* w, const SupernodalArrays<T>& a, const SuperList& supers, int end) {  \
    forward_pass<K, true, lanes>(w, a, supers, end);                                                           \
  }                                                                                                            \
  template <int K, typename T>                                                                                 \
  attributes void external_##name(double* w, const SupernodalArrays<T>& a, const SuperList& supers, int end) { \
    forward_pass<K, true, lanes, true>(w, a, supers, end);                                                     \
  }                                                                                                            \
  template <int K, typename T>                                                                                 \
  attributes void backward_##name(double* w, const SupernodalArrays<T>& a, const SuperList& supers, int) {     \
    backward_pass<K, true, lanes>(w, a, supers);                                                               \
  }

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
VX_SWEEP_PASSES(avx512, 8, __attribute__((target("arch=x86-64-v4"))))
VX_SWEEP_PASSES(avx2, 4, __attribute__((target("arch=x86-64-v3"))))
#elif defined(__x86_64__) && defined(__clang__)
VX_SWEEP_PASSES(avx512, 8, __attribute__((target("avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,bmi2"))))
VX_SWEEP_PASSES(avx2, 4, __attribute__((target("avx2,fma,bmi2"))))
#endif
VX_SWEEP_PASSES(generic, 2, )

/// The three kinds of pass: forward (L z = w), the updates a forward pass left out, backward
/// (L^T x = z).
enum class Pass { forward, external, backward };

/// One pass with `kernel` on `simd` (end_column: forward and external, kAllRows for none left out).
template <int K, Pass kPass, typename T>
void run_pass(double* w, const SupernodalArrays<T>& a, const SuperList& supers, int end_column,
              SparseFactor::SweepKernel kernel, SimdLevel simd) {
  if constexpr (K == 1 || K == 3) {
    if (kernel == SparseFactor::SweepKernel::gathered) {
#define VX_SWEEP_CALL(name)                                                   \
  switch (kPass) {                                                            \
    case Pass::forward: return forward_##name<K>(w, a, supers, end_column);   \
    case Pass::external: return external_##name<K>(w, a, supers, end_column); \
    case Pass::backward: return backward_##name<K>(w, a, supers, end_column); \
  }
      switch (simd) {
#if defined(__x86_64__) && defined(__GNUC__)
        case SimdLevel::avx512: VX_SWEEP_CALL(avx512) break;
        case SimdLevel::avx2: VX_SWEEP_CALL(avx2) break;
#endif
        default: VX_SWEEP_CALL(generic) break;
      }
#undef VX_SWEEP_CALL
      return;
    }
  }
  if constexpr (kPass == Pass::forward)
    forward_pass<K, false>(w, a, supers, end_column);
  else if constexpr (kPass == Pass::external)
    forward_pass<K, false, 2, true>(w, a, supers, end_column);
  else
    backward_pass<K, false>(w, a, supers);
}

}  // namespace

void SparseFactor::set_sweep_kernel(SweepKernel kernel, SimdLevel simd) {
  if (simd == SimdLevel::automatic || !simd_supported(simd)) simd = best_simd_level();
  sweep_kernel_ = kernel;
  sweep_simd_ = simd;
}

int SparseFactor::widest_supernode() const {
  int most = 0;
  for (std::size_t q = 0; q + 1 < super_.size(); ++q) most = std::max(most, super_[q + 1] - super_[q]);
  return most;
}

const char* SparseFactor::to_string(SweepKernel k) { return k == SweepKernel::column ? "column" : "gathered"; }

template <typename Pass>
void SparseFactor::with_sweep_arrays(const Pass& pass) const {
  if (single_precision_sweeps())
    pass(SupernodalArrays<float>(super_, row_start_, value_start_, rows_, values_single_.data()));
  else
    pass(SupernodalArrays<double>(super_, row_start_, value_start_, rows_, values_.data()));
}

template <int K>
void SparseFactor::solve_supernodal(double* w, int first) const {
  const int ns = int(super_.size()) - 1;
  // forward: L z = w, supernode by supernode (columns in order), from the one holding `first`
  const int q0 = first > 0 ? column_super_[std::size_t(first)] : 0;
  const auto passes = [&](const auto& a) {
    run_pass<K, Pass::forward>(w, a, {nullptr, ns - q0, q0}, kAllRows, sweep_kernel_, sweep_simd_);
    // backward: L^T x = z
    run_pass<K, Pass::backward>(w, a, {nullptr, ns, 0}, kAllRows, sweep_kernel_, sweep_simd_);
  };
  with_sweep_arrays(passes);
}

/// Cuts `supers` (ascending, closed under the parent) for a tree-parallel pass (sparse_factor.h):
/// tasks_ (by position) and task_order_ (largest first). Splits the largest subtree (its root
/// goes to the serial rest) while that shortens the estimated pass (the rest plus the larger of
/// the largest subtree and an even share of the subtrees); false (serial) when the pass is
/// shorter than min_parallel_entries_ or the split gains less than a sixth. Which split it
/// picks changes the time, never the result.
bool SparseFactor::plan_tree(const std::vector<int>& supers) const {
  tasks_.clear();
  const int threads = resolve_threads(threads_);
  const int m = int(supers.size());
  if (threads <= 1 || !tree_ok_ || m < 2 || omp_in_parallel()) return false;
  std::int64_t total = 0;
  for (int p = 0; p < m; ++p) {
    const int q = supers[std::size_t(p)];
    tree_pos_[std::size_t(q)] = p;
    tree_work_[std::size_t(q)] = super_work_[std::size_t(q)];
    tree_child_[std::size_t(q)] = -1;
    total += super_work_[std::size_t(q)];
  }
  if (total < min_parallel_entries_) return false;
  const auto in_list = [&](int q) {
    const int p = tree_pos_[std::size_t(q)];
    return p >= 0 && p < m && supers[std::size_t(p)] == q;
  };
  roots_.clear();
  for (int p = 0; p < m; ++p) {
    const int q = supers[std::size_t(p)], up = super_parent_[std::size_t(q)];
    if (up >= 0 && in_list(up)) {
      tree_work_[std::size_t(up)] += tree_work_[std::size_t(q)];
      tree_sibling_[std::size_t(q)] = tree_child_[std::size_t(up)];
      tree_child_[std::size_t(up)] = q;
    } else {
      roots_.push_back(q);
    }
  }
  const auto lighter = [&](int a, int b) { return tree_work_[std::size_t(a)] < tree_work_[std::size_t(b)]; };
  // splits the heaviest subtree of frontier_ (a heap) once; false when it is one supernode
  const auto split = [&](std::int64_t& rest) {
    const int t = frontier_.front();
    if (tree_child_[std::size_t(t)] < 0) return false;
    std::pop_heap(frontier_.begin(), frontier_.end(), lighter);
    frontier_.pop_back();
    rest += super_work_[std::size_t(t)];
    for (int c = tree_child_[std::size_t(t)]; c >= 0; c = tree_sibling_[std::size_t(c)]) {
      frontier_.push_back(c);
      std::push_heap(frontier_.begin(), frontier_.end(), lighter);
    }
    return true;
  };
  const auto estimate = [&](std::int64_t rest) {
    return rest + std::max(tree_work_[std::size_t(frontier_.front())], (total - rest + threads - 1) / threads);
  };
  constexpr int kMostSplits = 64;
  frontier_.assign(roots_.begin(), roots_.end());
  std::make_heap(frontier_.begin(), frontier_.end(), lighter);
  std::int64_t rest = 0, best = estimate(0);
  int best_splits = 0;
  for (int k = 1; k <= kMostSplits && split(rest); ++k) {
    const std::int64_t e = estimate(rest);
    if (e < best) best = e, best_splits = k;
  }
  if (best * 6 > total * 5) return false;
  frontier_.assign(roots_.begin(), roots_.end());
  std::make_heap(frontier_.begin(), frontier_.end(), lighter);
  rest = 0;
  for (int k = 0; k < best_splits; ++k) split(rest);
  for (const int t : frontier_) {
    const int b = int(std::lower_bound(supers.begin(), supers.end(), first_desc_[std::size_t(t)]) - supers.begin());
    tasks_.push_back({b, tree_pos_[std::size_t(t)] + 1, tree_work_[std::size_t(t)]});
  }
  std::sort(tasks_.begin(), tasks_.end(), [](const TreeTask& a, const TreeTask& b) { return a.begin < b.begin; });
  task_order_.resize(tasks_.size());
  for (std::size_t k = 0; k < tasks_.size(); ++k) task_order_[k] = int(k);
  std::sort(task_order_.begin(), task_order_.end(), [&](int a, int b) {  // not stable_sort: it allocates
    const std::int64_t wa = tasks_[std::size_t(a)].work, wb = tasks_[std::size_t(b)].work;
    return wa != wb ? wa > wb : a < b;
  });
  ++tree_passes_;
  return true;
}

void SparseFactor::ready_scratch(int k, bool team) const {
  const std::size_t values = std::size_t(k) * std::size_t(most_rows_);
  (void)gather_scratch(values);
  if (!team) return;
  const int t = resolve_threads(threads_);
  const std::thread::id me = std::this_thread::get_id();
  if (t <= 1 || (scratch_team_ >= t && scratch_master_ == me && scratch_values_ >= values)) return;
#pragma omp parallel num_threads(t)
  {
    (void)gather_scratch(values);  // on every thread of the team (a loop's chunks might all go to one)
  }
  scratch_team_ = t;
  scratch_master_ = me;
  scratch_values_ = values;
}

template <int K>
void SparseFactor::forward_supers(double* w, const std::vector<int>& supers) const {
  const auto pass = [&](const auto& a) {
    const auto slice = [&](int begin, int end) { return SuperList{supers.data() + begin, end - begin, 0}; };
    const bool tree = plan_tree(supers);
    ready_scratch(K, tree);
    if (!tree) {
      run_pass<K, Pass::forward>(w, a, slice(0, int(supers.size())), kAllRows, sweep_kernel_, sweep_simd_);
      return;
    }
    // the subtrees on the threads: a subtree's rows take updates from its own supernodes only;
    // those of the rows above it wait (but the first slice's: nothing comes before them)
    const auto end_column = [&](const TreeTask& t) {
      return t.begin == 0 ? kAllRows : super_[std::size_t(supers[std::size_t(t.end - 1)]) + 1];
    };
    parallel_for_chunks(std::int64_t(tasks_.size()), 1, threads_, [&](std::int64_t c, std::int64_t, std::int64_t) {
      const TreeTask& t = tasks_[std::size_t(task_order_[std::size_t(c)])];
      run_pass<K, Pass::forward>(w, a, slice(t.begin, t.end), end_column(t), sweep_kernel_, sweep_simd_);
    });
    // the rest and the updates put off, in the serial order (each row's updates as serially)
    std::size_t k = 0;
    for (int p = 0; p < int(supers.size());) {
      if (k < tasks_.size() && p == tasks_[k].begin) {
        const TreeTask& t = tasks_[k++];
        if (t.begin > 0)
          run_pass<K, Pass::external>(w, a, slice(t.begin, t.end), end_column(t), sweep_kernel_, sweep_simd_);
        p = t.end;
      } else {
        const int next = k < tasks_.size() ? tasks_[k].begin : int(supers.size());
        run_pass<K, Pass::forward>(w, a, slice(p, next), kAllRows, sweep_kernel_, sweep_simd_);
        p = next;
      }
    }
  };
  with_sweep_arrays(pass);
}

template <int K>
void SparseFactor::backward_supers(double* w, const std::vector<int>& supers) const {
  const auto pass = [&](const auto& a) {
    const auto slice = [&](int begin, int end) { return SuperList{supers.data() + begin, end - begin, 0}; };
    const bool tree = plan_tree(supers);
    ready_scratch(K, tree);
    if (!tree) {
      run_pass<K, Pass::backward>(w, a, slice(0, int(supers.size())), kAllRows, sweep_kernel_, sweep_simd_);
      return;
    }
    // the rest first (a column reads only its ancestors'), then the subtrees on the threads
    std::size_t k = tasks_.size();
    for (int p = int(supers.size()); p > 0;) {
      if (k > 0 && p == tasks_[k - 1].end) {
        p = tasks_[--k].begin;
        continue;
      }
      const int begin = k > 0 ? tasks_[k - 1].end : 0;
      run_pass<K, Pass::backward>(w, a, slice(begin, p), kAllRows, sweep_kernel_, sweep_simd_);
      p = begin;
    }
    parallel_for_chunks(std::int64_t(tasks_.size()), 1, threads_, [&](std::int64_t c, std::int64_t, std::int64_t) {
      const TreeTask& t = tasks_[std::size_t(task_order_[std::size_t(c)])];
      run_pass<K, Pass::backward>(w, a, slice(t.begin, t.end), kAllRows, sweep_kernel_, sweep_simd_);
    });
  };
  with_sweep_arrays(pass);
}

template void SparseFactor::solve_supernodal<1>(double*, int) const;
template void SparseFactor::solve_supernodal<3>(double*, int) const;
template void SparseFactor::forward_supers<1>(double*, const std::vector<int>&) const;
template void SparseFactor::forward_supers<3>(double*, const std::vector<int>&) const;
template void SparseFactor::forward_supers<SparseFactor::kFieldLanes>(double*, const std::vector<int>&) const;
template void SparseFactor::backward_supers<1>(double*, const std::vector<int>&) const;
template void SparseFactor::backward_supers<3>(double*, const std::vector<int>&) const;

}  // namespace vx
