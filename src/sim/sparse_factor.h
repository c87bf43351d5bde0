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
/// solution to rounding. The solves run on the factor's arrays directly: one pass over L per
/// triangle serves K right-hand sides interleaved (each entry of L is read once for all of
/// them), and a unit vector's forward pass starts at its own row. CHOLMOD's factor stays
/// supernodal (L L^T in dense column blocks that share their row pattern): the solve streams 8
/// bytes per entry instead of the 12 of a simplicial factor with its row index, which is what a
/// solve of this size is bound by (memory). Eigen's is copied into one unit-lower L and diagonal
/// D. A supernodal pass large enough runs tree-parallel (set_threads(): the disjoint subtrees
/// below the top separators on the threads, the separators on one), every row's updates in the
/// serial order: bit-identical on any number of threads.

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <cstdint>
#include <functional>
#include <iosfwd>
#include <memory>
#include <span>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "base/simd.h"

namespace vx {

class SparseFactor;

/// An array that either owns its values or views them in memory that `keep` keeps alive (a
/// factor read from a mapped file: sparse_factor.h, read()). Read-only once filled, so a copy
/// shares the values instead of copying them (owned values are held by a shared vector): a copy
/// of a factor for a background write (SparseFactor::file_copy) costs no memory.
template <typename T>
class SharedArray {
 public:
  SharedArray() = default;
  SharedArray(const SharedArray&) = default;
  SharedArray& operator=(const SharedArray&) = default;
  SharedArray(SharedArray&& o) noexcept
      : keep_(std::move(o.keep_)), data_(std::exchange(o.data_, nullptr)), size_(std::exchange(o.size_, 0)) {}
  SharedArray& operator=(SharedArray&& o) noexcept {
    keep_ = std::move(o.keep_);
    data_ = std::exchange(o.data_, nullptr);
    size_ = std::exchange(o.size_, 0);
    return *this;
  }
  /// Owns `v` (its buffer moves, no copy).
  void own(std::vector<T> v) {
    auto held = std::make_shared<const std::vector<T>>(std::move(v));
    data_ = held->data();
    size_ = held->size();
    keep_ = std::move(held);
  }
  /// Views n values at `data`, kept alive by `keep`.
  void view(const T* data, std::size_t n, std::shared_ptr<const void> keep) {
    keep_ = std::move(keep);
    data_ = data;
    size_ = n;
  }
  void clear() {
    keep_.reset();
    data_ = nullptr;
    size_ = 0;
  }
  [[nodiscard]] const T* data() const { return data_; }
  [[nodiscard]] std::size_t size() const { return size_; }
  [[nodiscard]] bool empty() const { return size_ == 0; }
  [[nodiscard]] const T& operator[](std::size_t i) const { return data_[i]; }

 private:
  std::shared_ptr<const void> keep_;
  const T* data_{nullptr};
  std::size_t size_{0};
};

/// What a factor is the factor of: the content of the matrix it factors and who factored it.
/// Two matrices with the same key have the same factor (a 64-bit hash of every entry, bit for
/// bit: a step, a material or a support that changes one entry changes the key; the implicit
/// solver's is projective_matrix_key, projective_solver.h).
struct FactorKey {
  std::uint64_t hash{0};  ///< ContentHash of the matrix's entries (base/content_hash.h)
  std::int64_t rows{0};
  std::int64_t nonzeros{0};  ///< a size of the matrix (for the file name; the hash holds the content)
  std::uint8_t backend{0};   ///< SparseFactor::Backend
  /// The factor's values in single precision (SparseFactor::use_single_precision_sweeps): the
  /// same matrix's factor in double is another file.
  bool single{false};
  /// A file-name-safe name: "cholmod-326564n-7012345nz-0123456789abcdef".
  [[nodiscard]] std::string name() const;
  [[nodiscard]] bool operator==(const FactorKey&) const = default;
};

/// A store of factors by key: the factor cache beside the model (pipeline/io/factor_cache.h
/// keeps it in a folder). The implicit solver (projective_solver.h) asks it before assembling
/// and factoring and hands it the new factor after. Both calls may fail quietly: a factor not
/// found or not stored is computed.
class FactorCache {
 public:
  virtual ~FactorCache() = default;
  /// Fills `factor` with the stored factor of `key` (SparseFactor::read); false when there is
  /// none or it cannot be read (then `factor` is empty).
  virtual bool load(const FactorKey& key, SparseFactor& factor) = 0;
  /// Offers the factor of `key` just computed (SparseFactor::write; factor_seconds() says what
  /// it cost).
  virtual void store(const FactorKey& key, const SparseFactor& factor) = 0;
  /// The fill-reducing order kept for the matrix pattern `pattern` (SparseFactor::pattern_key):
  /// METIS's order of another matrix of the same model and support (another material, step or
  /// damping), which the factor of this one may take instead of ordering again. False when there
  /// is none (`order` then empty); a cache may keep none.
  virtual bool load_order(const FactorKey& pattern, std::vector<int>& order) {
    (void)pattern;
    order.clear();
    return false;
  }
  /// Offers the order `factor` was just factored in (SparseFactor::order(); order_seconds() says
  /// what finding it cost).
  virtual void store_order(const FactorKey& pattern, const SparseFactor& factor) {
    (void)pattern;
    (void)factor;
  }
  /// No store from now on; returns once a store begun has ended. For a process that ends
  /// without waiting for a factorisation still under way (a session that quits).
  virtual void close() {}
};

class SparseFactor {
 public:
  using Matrix = Eigen::SparseMatrix<double>;

  /// Who factors (see the file comment).
  enum class Backend : std::uint8_t { automatic, cholmod, eigen_metis, eigen_amd };
  /// "cholmod", "eigen_metis", "eigen_amd" ("automatic": the build's best).
  [[nodiscard]] static const char* to_string(Backend b);
  /// The backend `automatic` stands for in this build: the environment variable
  /// VOXELASTIC_FACTOR (cholmod, eigen_metis, eigen_amd) when it names one the build has, else
  /// the best the build has.
  [[nodiscard]] static Backend best_backend();
  /// True when this build has `b`.
  [[nodiscard]] static bool available(Backend b);
  /// The BLAS under CHOLMOD's supernodes in this process (the libblas.so.3 that Debian's
  /// alternatives chose): "OpenBLAS ..." with its build line, "BLIS ...", "MKL ...", else "the
  /// reference BLAS"; "none" without CHOLMOD. The reference one factors about 3.7 times slower
  /// (docs/bench.md, "The start-up on the folded organ"): scripts/install-deps.sh installs
  /// OpenBLAS (single-threaded; a threaded OpenBLAS is put on one thread before each
  /// factorisation).
  [[nodiscard]] static std::string blas_library();
  /// Whether blas_library() is the reference BLAS (a factorisation that took long deserves a hint).
  [[nodiscard]] static bool reference_blas();

  /// Factors `a` (n x n, symmetric; the lower triangle is read) with `backend` (automatic: the
  /// build's best; one the build lacks falls back to it). Returns false when it is not positive
  /// definite (a part of the model held by nothing, a NaN). `order` (CHOLMOD only; empty: METIS's)
  /// is the fill-reducing order to factor in, order[k] the row that comes k-th: an order() kept
  /// from a matrix of the same pattern (the order cache: METIS's time saved, the same factor).
  /// `stop` (may be empty): asked between the stages (CHOLMOD: before the order, between it and
  /// the numeric factorisation, and after it); true throws Cancelled (base/error.h) and leaves
  /// this factor empty. The stages themselves (METIS, the numeric factorisation) run to their end.
  [[nodiscard]] bool compute(const Matrix& a, Backend backend = Backend::automatic, std::span<const int> order = {},
                             const std::function<bool()>& stop = {});
  /// Writes the factor in a binary form (native byte order; a header, the arrays each at a
  /// 64-byte boundary, a checksum): what read() reads back on this machine, with its values in
  /// the precision the sweeps read (use_single_precision_sweeps()). Throws vx::Error when the
  /// stream fails.
  void write(std::ostream& out) const;
  /// What write() writes and nothing else (no solve state), sharing the factor's values and row
  /// indices rather than copying them: a copy to write on another thread while this one solves
  /// (the factor cache's background write, pipeline/io/factor_cache.h).
  [[nodiscard]] SparseFactor file_copy() const;
  /// Reads what write() wrote from the `size` bytes at `data` (8-byte aligned: a mapped file).
  /// With `keep`, the factor's two large arrays (values and row indices) view `data`, which
  /// `keep` keeps alive for as long as the factor uses them (no copy: a mapped file is read in
  /// the time its pages take to come in); without, everything is copied. Checks the header,
  /// every array's size and structure (a permutation, supernodes that tile the columns, rows in
  /// range, positive diagonals) and the checksum; on any failure the factor is left empty, `why`
  /// says what was wrong, and it returns false.
  bool read(const unsigned char* data, std::size_t size, std::shared_ptr<const void> keep, std::string* why = nullptr);
  /// True when the factor was read (read()), not computed.
  [[nodiscard]] bool from_cache() const { return from_cache_; }
  /// True when the factor was computed in an order compute() was given (the order cache's), not
  /// one it found.
  [[nodiscard]] bool order_given() const { return order_given_; }
  /// Bytes write() writes (about: the arrays).
  [[nodiscard]] std::uint64_t stored_bytes() const;

  /// Rows of the factored matrix.
  [[nodiscard]] int size() const { return size_; }
  /// Nonzeros of L (the cost of one solve; supernodal: the stored entries of its blocks).
  [[nodiscard]] std::int64_t nonzeros() const {
    return supernodal_ && !value_start_.empty() ? value_start_.back() : std::int64_t(values_.size());
  }
  /// The backend that computed the factor.
  [[nodiscard]] Backend backend() const { return backend_; }
  /// How the supernodal sweeps run (every solve below; docs/bench.md, "The gathered sweeps"):
  ///   - column: column by column, each entry of L scattered to its row through the row index;
  ///   - gathered (the default): a supernode 4 or more columns wide has its rows gathered into
  ///     contiguous arrays once, runs its columns on them with vector instructions, and scatters
  ///     them back. The same solution to rounding (the backward sweep's dot products add 2, 4 or
  ///     8 partial sums, the lanes of the instruction set's vectors); the same bits from run to
  ///     run on one instruction set.
  enum class SweepKernel : std::uint8_t { column, gathered };
  [[nodiscard]] static const char* to_string(SweepKernel k);
  /// The kernel a new factor sweeps with: gathered, or the one the environment variable
  /// VOXELASTIC_SWEEP names (column, gathered). Throws vx::Error for another value.
  [[nodiscard]] static SweepKernel default_sweep_kernel();
  /// From now on (until the next compute() or read()) the supernodal sweeps read L's values in
  /// single precision, the sums and the right-hand sides staying in double (docs/bench.md,
  /// "Single-precision sweeps"): a regional step streams the factor's closure from memory twice,
  /// and floats halve that. It costs the solution about 1e-7 of its size (L's entries rounded to
  /// 24 bits); the same bits from run to run and on any number of threads, as in double. The
  /// double values are released (with a mapped factor file: its pages, the row indices copied
  /// first), so the factor's memory falls by a third rather than grows; write() then writes the
  /// single values (a factor cache keeps them under a key of their own: FactorKey::single). A
  /// factor read from such a file sweeps in single precision already. Returns whether the sweeps
  /// are in single precision: false for a simplicial factor (Eigen's backends), whose passes stay
  /// in double.
  bool use_single_precision_sweeps();
  [[nodiscard]] bool single_precision_sweeps() const { return !values_single_.empty(); }
  /// Sets the sweeps' kernel and instruction set (automatic or one this CPU lacks: the widest it
  /// runs, best_simd_level()).
  void set_sweep_kernel(SweepKernel kernel, SimdLevel simd = SimdLevel::automatic);
  [[nodiscard]] SweepKernel sweep_kernel() const { return sweep_kernel_; }
  [[nodiscard]] SimdLevel sweep_simd() const { return sweep_simd_; }
  /// The supernodal passes' threads (1: serial; 0: OpenMP's default) and the least work, in
  /// entries of L, that a pass splits into subtrees for them (a shorter one, a path of a few
  /// supernodes, stays on the calling thread). A pass split runs the disjoint subtrees below the
  /// top separators on the threads and the separators on the calling thread, every row's
  /// updates in the serial order: the results are bit for bit the same whatever either is
  /// (docs/bench.md, "The sweeps on two cores"). From inside a parallel region a pass is serial.
  void set_threads(int threads, std::int64_t min_parallel_entries = kTreeMinParallelEntries) {
    threads_ = threads;
    min_parallel_entries_ = min_parallel_entries;
  }
  [[nodiscard]] int threads() const { return threads_; }
  /// The least work of a tree-parallel pass by default: about 0.1 ms of sweeping.
  static constexpr std::int64_t kTreeMinParallelEntries = 100000;
  /// Passes that ran tree-parallel since compute() or read() (a diagnostic for tests).
  [[nodiscard]] std::int64_t tree_parallel_passes() const { return tree_passes_; }
  /// The widest supernode's columns (0: a simplicial factor): the gathered kernel runs on
  /// supernodes of 4 columns or more.
  [[nodiscard]] int widest_supernode() const;
  /// Wall time of the last compute() or read(), s.
  [[nodiscard]] double factor_seconds() const { return factor_s_; }
  /// Of that, the fill-reducing order and the symbolic analysis (CHOLMOD's analyze: METIS's
  /// order, or a given order's check and postorder), s; 0 for the other backends and a read.
  [[nodiscard]] double order_seconds() const { return order_s_; }
  /// The order the factor is in: order()[k] is the row factored k-th (what compute() takes back
  /// for a matrix of the same pattern: the same order, the same factor's structure).
  [[nodiscard]] std::vector<int> order() const;
  /// The key of a's pattern (its size and the rows of its lower triangle's entries, not their
  /// values): the key an order is kept by (FactorCache::load_order). backend: CHOLMOD's.
  [[nodiscard]] static FactorKey pattern_key(const Matrix& a);

  /// x = A^-1 b for the three columns of b (n x 3) at once. Allocation-free after compute().
  void solve3(const Eigen::MatrixX3d& b, Eigen::MatrixX3d& x);
  /// out = A^-1 e_i (n values). Allocation-free after compute().
  void solve_unit(int i, double* out);
  /// out + a * stride = A^-1 e_rows[a] for a < count: solve_unit's columns, the same values, on a
  /// simplicial factor kUnitLanes at a time (one pass over the factor for each kUnitLanes
  /// columns, where the passes are memory-bound: the probe app's contact patches, issue 25), the
  /// passes on the caller's OpenMP threads. Allocation-free after its first call on as many threads.
  void solve_units(const int* rows, int count, double* out, std::size_t stride);
  static constexpr int kUnitLanes = 8;

  // --- forward vectors: the contact set's compliance without whole columns -------------------
  // With A^-1 = P^T L^-T D^-1 L^-1 P (D = I for the supernodal L L^T), the scaled forward vector
  //   z_i = D^-1/2 L^-1 P e_i
  // is nonzero only on the path from e_i's column to the root of the elimination tree (a few
  // thousand of the factor's positions, against n for a column of A^-1), it does not depend on a
  // region, and
  //   (A^-1)_ij = z_i . z_j,     A^-1 sum_k e_k f_k^T = P^T L^-T D^-1/2 sum_k z_k f_k^T,
  // so the contact set (contact_active_set.h) builds its Schur complement from dot products and
  // applies the contact forces with one backward pass for all of them (docs/model.md section 8).

  /// z_i in segments of consecutive factored positions (ascending).
  struct UnitForward {
    std::vector<int> first;            ///< segment -> first factored position
    std::vector<int> count;            ///< segment -> positions
    std::vector<std::int64_t> offset;  ///< segment -> start in value
    std::vector<double> value;
    [[nodiscard]] std::size_t bytes() const {
      return value.size() * sizeof(double) + first.size() * (2 * sizeof(int) + sizeof(std::int64_t));
    }
  };
  /// z = z_i for row i (original numbering). Allocates z's storage when it grows.
  void forward_unit(int i, UnitForward& z);
  /// The storage of the largest z_i of this factor, {values, segments}: its longest path to a root
  /// of the elimination tree (a bound for every forward_unit(); ContactActiveSet::reserve).
  [[nodiscard]] std::pair<std::int64_t, std::int64_t> longest_unit_forward() const;
  /// z_a . z_b = (A^-1)_ij.
  [[nodiscard]] static double dot(const UnitForward& a, const UnitForward& b);
  /// x += A^-1 sum_k e_(row k) f_k^T for the forces f_k (3 per k, in `forces3`) at the rows whose
  /// forward vectors are z[k]: on every row, or with `partial` on the closure rows of
  /// set_partial_rows() only (the others untouched; as solve3_partial). Allocation-free after
  /// compute().
  void add_response3(const std::vector<const UnitForward*>& z, const std::vector<double>& forces3, Eigen::MatrixX3d& x,
                     bool partial);

  // --- regional (partial) solves: only where the tool is --------------------------------------
  // With a supernodal factor the solution on a set of rows S is exact without solving for the
  // others: the backward substitution of a column needs only its ancestors in the elimination
  // tree, and a forward substitution whose right-hand side changed on a few rows changes only
  // their ancestors. So the factor keeps the forward solution z = L^-1 P b of the last right-hand
  // side; a partial solve finds the rows where b changed (exactly), updates z on their
  // ancestors, and substitutes backward on S and its ancestors (the closure) only. The rows
  // outside the closure keep the values of the last solve that reached them (they sleep).

  /// True when partial solves are available (a supernodal factor).
  [[nodiscard]] bool supports_partial() const { return supernodal_; }
  /// Sets S (rows in the original numbering); returns the closure's rows (original numbering,
  /// sorted), which partial solves write. Allocates.
  const std::vector<int>& set_partial_rows(const std::vector<int>& rows);
  /// The closure's rows of the last set_partial_rows().
  [[nodiscard]] const std::vector<int>& partial_rows() const { return closure_rows_; }
  /// Columns of the closure (the cost of a partial backward pass, against size()).
  [[nodiscard]] std::int64_t partial_columns() const { return closure_columns_; }
  /// x = A^-1 b on the closure rows (others untouched). Needs a full solve3() since compute().
  /// Returns the number of rows where b changed. `rows`: as forward3_partial's.
  int solve3_partial(const Eigen::MatrixX3d& b, Eigen::MatrixX3d& x, const std::vector<int>* rows = nullptr);
  // solve3_partial in two halves, so that the contact set can add its forces between them and
  // substitute backward once (docs/model.md section 8, "One backward pass"):
  /// True when the two halves below can run (a supernodal factor, a full solve3() since
  /// compute(), a closure set).
  [[nodiscard]] bool partial_ready() const { return supernodal_ && have_forward_ && !closure_supers_.empty(); }
  /// The forward half: z = L^-1 P b kept current on the ancestors of the rows where b changed.
  /// Needs partial_ready(). Returns the number of rows where b changed. Every row is compared
  /// with the last b, or with `rows` only these: the caller's word that b is the last b, bit for
  /// bit, on every other row (a steady regional solve's closure: docs/model.md section 7,
  /// "Passes over the closure only"); b's other rows are then not read.
  int forward3_partial(const Eigen::MatrixX3d& b, const std::vector<int>* rows = nullptr);
  /// Row i of A^-1 b for the right-hand side of the last forward half: z_i . z (no backward pass).
  [[nodiscard]] Eigen::Vector3d solution_row(const UnitForward& zi) const;
  /// The backward half: x = A^-1 (b + sum_k e_(row k) f_k^T) on the closure rows (others
  /// untouched), b the last forward half's, f_k as add_response3's (z and forces3 may be empty).
  void backward3_partial(const std::vector<const UnitForward*>& z, const std::vector<double>& forces3,
                         Eigen::MatrixX3d& x);
  /// out = A^-1 e_i on the closure rows, 0 elsewhere (n values).
  void solve_unit_partial(int i, double* out);

  // --- forward fields: a far field carried in the forward solution (projective_solver.h) ------
  // A right-hand side that changes on the rows outside the closure by a combination of a few
  // fixed fields, b += sum_k c_k g_k, changes the forward solution by sum_k c_k w_k with
  // w_k = L^-1 P g_k, and the products g_k^T A^-1 b = w_k . z (A^-1 = P^T L^-T L^-1 P): so with
  // the w_k computed once, a regional solve carries such a change and reads the products without
  // a pass over the rows outside the closure. Supernodal factors only (D = I).
  /// w (permuted, row-major n x 3m: row j holds w_0 (3 values), .., w_{m-1}) = L^-1 P g for the m
  /// fields g (n x 3m, original numbering, field k in columns 3k..3k+2). One forward pass over the
  /// whole factor for all of them. Needs a supernodal factor. Allocates.
  void forward_fields(const Eigen::MatrixXd& g, std::vector<double>& w) const;
  /// The forward solution of the last forward half += sum_k coef[k] w_k (w from forward_fields():
  /// the right-hand side changed by sum_k coef[k] g_k on rows whose b the next forward half does
  /// not see change). Needs partial_ready().
  void add_forward_fields(const std::vector<double>& w, int m, const double* coef);
  /// From now on every backward half (backward3_partial) also computes g_k^T x for the m fields
  /// of `w` (as forward_fields(); kept by pointer, so it must outlive their use), x the solution it
  /// substitutes (contact forces included): field_products(). m = 0: none.
  void set_product_fields(const std::vector<double>* w, int m) {
    product_fields_ = m > 0 ? w : nullptr;
    product_count_ = m;
    field_products_.assign(std::size_t(m), 0.0);
  }
  /// g_k^T x of the last backward half (set_product_fields()).
  [[nodiscard]] const std::vector<double>& field_products() const { return field_products_; }

 private:
  /// Solves L D L^T w = w in place on the factor (permuted order; K right-hand sides
  /// interleaved, row-major n x K). Entries before `first` must be zero in every lane: the
  /// forward pass starts there.
  template <int K>
  void solve_in_place(double* w, int first) const;
  template <int K>
  void solve_supernodal(double* w, int first) const;
  /// pass(the supernodal arrays the sweeps read): L's values in single precision when it has them
  /// (use_single_precision_sweeps()), else in double (sparse_factor_sweeps.cpp).
  template <typename Pass>
  void with_sweep_arrays(const Pass& pass) const;

  void reset();
  void finish();
  bool index_supernodes();
  bool compute_eigen(const Matrix& a, bool metis);
  /// `stop(where)`: true once a stop was asked (compute(): the CHOLMOD memory is given back first).
  bool compute_cholmod(const Matrix& a, std::span<const int> order, const std::function<bool(const char*)>& stop);

  int size_{0};
  Backend backend_{Backend::automatic};
  double factor_s_{0.0};
  double order_s_{0.0};
  bool from_cache_{false};
  bool order_given_{false};
  // P A P^T = L D L^T: L strictly lower (unit diagonal implied), column-compressed
  std::vector<int> perm_;             ///< original row -> factored position
  std::vector<std::int64_t> outer_;   ///< n + 1 column starts
  std::vector<int> inner_;            ///< row of each entry
  SharedArray<double> values_;        ///< L entries
  SharedArray<float> values_single_;  ///< supernodal: L's entries in single precision (use_single_precision_sweeps)
  std::vector<double> inv_d_;         ///< 1 / D
  std::vector<double> inv_sqrt_d_;    ///< D^-1/2 (forward vectors of the simplicial factor)
  std::vector<int> parent_;           ///< simplicial: column -> parent in the elimination tree (-1: a root)
  std::vector<int> path_;             ///< forward_unit's path (supernodes or columns)
  // supernodal L L^T (CHOLMOD): supernode s has columns super_[s] .. super_[s+1]-1, rows
  // rows_[row_start_[s] ..] (its own columns first), values values_[value_start_[s] ..]
  // column-major (leading dimension: its row count), diagonal included
  bool supernodal_{false};
  std::vector<int> super_;
  SharedArray<int> rows_;
  std::vector<std::int64_t> row_start_, value_start_;
  std::vector<int> column_super_;  ///< column -> its supernode
  std::vector<int> super_parent_;  ///< supernode -> parent in the elimination tree (-1: a root)
  // regional solves
  bool have_forward_{false};
  std::vector<double> last_b_;       ///< n x 3 column-major, original order (as b): the last right-hand side solved
  std::vector<double> forward_;      ///< n x 3 permuted: z = L^-1 P last_b
  std::vector<int> closure_supers_;  ///< ascending
  std::vector<int> closure_rows_;
  std::int64_t closure_columns_{0};
  std::vector<std::uint32_t> mark_;  ///< supernodes: generation stamp
  std::uint32_t generation_{0};
  std::vector<int> changed_supers_;
  /// forward3_partial's scan: per chunk of rows, the supernode of each row that changed
  std::vector<std::vector<int>> chunk_changed_;
  std::vector<int> all_supers_;
  /// Right-hand sides per pass of forward_fields() (each entry of L read once for all of them).
  static constexpr int kFieldLanes = 18;
  template <int K>
  void forward_supers(double* w, const std::vector<int>& supers) const;
  template <int K>
  void backward_supers(double* w, const std::vector<int>& supers) const;
  // tree-parallel passes (sparse_factor_sweeps.cpp, plan_tree()): a pass over a list of
  // supernodes closed under the parent (ascending) is cut into slices that are whole subtrees of
  // the list (contiguous: the factor is postordered), run on the threads, and the rest (the
  // separators above them), run on the calling thread: a forward pass runs the slices first (the
  // updates of rows above a slice put off, but for the first slice's), then the rest and the
  // put-off updates in the serial order; a backward pass the rest first, then the slices.
  struct TreeTask {
    int begin, end;     ///< positions in the list
    std::int64_t work;  ///< entries of L
  };
  bool tree_ok_{false};                   ///< postordered, rows ascending in every supernode
  std::vector<int> first_desc_;           ///< supernode -> the first supernode of its subtree
  std::vector<std::int64_t> super_work_;  ///< supernode -> entries of L it holds
  int threads_{1};
  std::int64_t min_parallel_entries_{kTreeMinParallelEntries};
  mutable std::int64_t tree_passes_{0};
  /// The gathered kernels' per-thread scratch (K x a supernode's rows) is grown before a pass,
  /// not when a thread first meets a wide supernode: which thread takes which subtree changes
  /// from pass to pass, and a step must not allocate (Integrators.StepsDoNotAllocate under load).
  /// The most rows of a supernode; the last team grown (its size and the thread that formed it)
  /// and the values its threads' scratch holds (thread_local: it outlives a factor, so a new
  /// factor regrows only when it needs more).
  std::int64_t most_rows_{0};
  mutable int scratch_team_{0};
  mutable std::thread::id scratch_master_;
  mutable std::size_t scratch_values_{0};
  /// Grows the calling thread's scratch to K x most_rows_ values, and with `team` every thread of
  /// the team of threads_ this thread forms (once per team and size).
  void ready_scratch(int k, bool team) const;
  // plan_tree's work space (sized by supernodes); a factor is used from one thread at a time
  mutable std::vector<TreeTask> tasks_;
  mutable std::vector<std::int64_t> tree_work_;
  mutable std::vector<int> tree_child_, tree_sibling_, tree_pos_;
  mutable std::vector<int> frontier_, task_order_, roots_;
  void index_tree();
  bool plan_tree(const std::vector<int>& supers) const;
  void ancestors(std::vector<int>& supers);
  static void scatter_forward_forces(const std::vector<const UnitForward*>& z, const std::vector<double>& forces3,
                                     double* w);
  const std::vector<double>* product_fields_{nullptr};  ///< set_product_fields()
  int product_count_{0};
  std::vector<double> field_products_;
  std::vector<std::uint8_t> in_closure_;  ///< factored positions: 1 in the closure
  SweepKernel sweep_kernel_{default_sweep_kernel()};
  SimdLevel sweep_simd_{best_simd_level()};
  std::vector<double> work3_;       ///< n x 3, row-major, permuted order
  std::vector<double> work1_;       ///< n, permuted order
  std::vector<double> work_units_;  ///< per thread kUnitLanes x n, permuted order, interleaved (solve_units)
};

}  // namespace vx
