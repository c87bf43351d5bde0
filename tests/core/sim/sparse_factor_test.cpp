// The sparse factor (sim/sparse_factor.h): the backends agree, and a factor written and read
// back (the factor cache's form) solves bit for bit as the one computed, while a damaged file
// or a truncated one is refused; the content hash depends on every byte.
#include <gtest/gtest.h>

#include <Eigen/Sparse>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <iostream>
#include <memory>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "base/content_hash.h"
#include "base/parallel.h"
#include "model/gradational_builder.h"
#include "physics/calibration.h"
#include "physics/physics_model.h"
#include "sim/sparse_factor.h"
#include "support/physics_helpers.h"
#include "support/sparse_helpers.h"

namespace vx {
namespace {

using testing::aligned_copy;
using testing::bytes_of;
using testing::elastic_matrix_plus;
using testing::hand_block;

/// The elastic matrix of a small block plus a mass term: symmetric positive definite.
SparseFactor::Matrix block_matrix(int nx = 6, int ny = 5, int nz = 4) {
  Material mat;
  mat.youngs_modulus_kpa = 10.0;
  mat.density_kg_m3 = 1000.0;
  const auto p = make_physics_model(hand_block(nx, ny, nz, 1.0), mat);
  return elastic_matrix_plus(*p, [](int) { return 1e-3; });
}

std::vector<SparseFactor::Backend> backends() {
  std::vector<SparseFactor::Backend> out;
  for (auto b : {SparseFactor::Backend::eigen_amd, SparseFactor::Backend::eigen_metis, SparseFactor::Backend::cholmod})
    if (SparseFactor::available(b)) out.push_back(b);
  return out;
}

/// What the solver asks of a factor: a full solve, a unit column, forward vectors and their
/// response, a regional solve.
struct Answers {
  Eigen::MatrixX3d x, partial;
  std::vector<double> column;
  double dot{0.0};
  Eigen::MatrixX3d response;
};

Answers ask(SparseFactor& f, int n) {
  Answers a;
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(n, 3);
  a.x.resize(n, 3);
  f.solve3(b, a.x);
  a.column.assign(std::size_t(n), 0.0);
  f.solve_unit(n / 3, a.column.data());
  SparseFactor::UnitForward zi, zj;
  f.forward_unit(2, zi);
  f.forward_unit(n - 3, zj);
  a.dot = SparseFactor::dot(zi, zj);
  a.response = Eigen::MatrixX3d::Zero(n, 3);
  f.add_response3({&zi, &zj}, {0.1, -0.2, 0.3, 1.0, 0.5, -0.25}, a.response, false);
  a.partial = a.x;
  if (f.supports_partial()) {
    f.set_partial_rows({1, 5, n / 2});
    Eigen::MatrixX3d b2 = b;
    b2.row(n / 2) += Eigen::RowVector3d(1, 2, 3);
    f.solve3_partial(b2, a.partial);
  }
  return a;
}

void expect_same_bits(const Answers& a, const Answers& b, const std::string& what) {
  EXPECT_EQ(std::memcmp(a.x.data(), b.x.data(), sizeof(double) * std::size_t(a.x.size())), 0) << what;
  EXPECT_EQ(a.column, b.column) << what;
  EXPECT_EQ(a.dot, b.dot) << what;
  EXPECT_EQ(std::memcmp(a.response.data(), b.response.data(), sizeof(double) * std::size_t(a.response.size())), 0)
      << what;
  EXPECT_EQ(std::memcmp(a.partial.data(), b.partial.data(), sizeof(double) * std::size_t(a.partial.size())), 0) << what;
}

TEST(SparseFactor, BackendsAgreeOnTheSameMatrix) {
  const SparseFactor::Matrix a = block_matrix();
  const int nn = int(a.rows());
  Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(nn, 3), x(nn, 3), ref(nn, 3);
  bool first = true;
  for (auto backend : backends()) {
    SparseFactor f;
    ASSERT_TRUE(f.compute(a, backend)) << SparseFactor::to_string(backend);
    EXPECT_EQ(f.backend(), backend);
    f.solve3(b, x);
    const double res = (a * x - b).norm() / b.norm();
    std::cout << SparseFactor::to_string(backend) << ": " << f.nonzeros() << " nonzeros, relative residual " << res
              << "\n";
    EXPECT_LT(res, 1e-10);
    std::vector<double> col(static_cast<std::size_t>(nn), 0.0);
    f.solve_unit(7, col.data());
    const Eigen::VectorXd ax = a * Eigen::Map<Eigen::VectorXd>(col.data(), nn);
    EXPECT_NEAR(ax(7), 1.0, 1e-9);
    EXPECT_NEAR(ax.norm(), 1.0, 1e-9);
    if (first) ref = x, first = false;
    EXPECT_LT((x - ref).norm(), 1e-9 * ref.norm());
    // forward vectors (the contact set's compliance): z_i . z_j = (A^-1)_ij, and the response
    // to forces at a few rows is A^-1 of them
    SparseFactor::UnitForward zi, zj, zk;
    std::vector<double> colj(static_cast<std::size_t>(nn), 0.0);
    for (const auto& [i, j] : {std::pair{7, 7}, std::pair{7, 40}, std::pair{3, nn - 1}, std::pair{nn / 2, 11}}) {
      f.forward_unit(i, zi);
      f.forward_unit(j, zj);
      f.solve_unit(j, colj.data());
      EXPECT_NEAR(SparseFactor::dot(zi, zj), colj[std::size_t(i)], 1e-10 * std::abs(colj[std::size_t(j)]))
          << SparseFactor::to_string(backend) << " " << i << " " << j;
      EXPECT_LT(zi.value.size(), std::size_t(nn));  // the path, not a whole column
    }
    f.forward_unit(3, zi);
    f.forward_unit(nn - 1, zj);
    f.forward_unit(nn - 5, zk);
    const std::vector<const SparseFactor::UnitForward*> zs = {&zi, &zj, &zk};
    const std::vector<double> forces = {0.1, -0.2, 0.3, 1.0, 0.5, -0.25, -0.7, 0.0, 0.4};
    Eigen::MatrixX3d resp = Eigen::MatrixX3d::Zero(nn, 3), rhs = Eigen::MatrixX3d::Zero(nn, 3), direct(nn, 3);
    rhs.row(3) += Eigen::RowVector3d(0.1, -0.2, 0.3);
    rhs.row(nn - 1) += Eigen::RowVector3d(1.0, 0.5, -0.25);
    rhs.row(nn - 5) += Eigen::RowVector3d(-0.7, 0.0, 0.4);
    f.add_response3(zs, forces, resp, false);
    f.solve3(rhs, direct);
    EXPECT_LT((resp - direct).norm(), 1e-10 * direct.norm()) << SparseFactor::to_string(backend);
  }
  // not positive definite: refused by every backend
  SparseFactor::Matrix bad = a;
  bad.coeffRef(3, 3) = -1.0;
  for (auto backend : {SparseFactor::Backend::eigen_amd, SparseFactor::Backend::cholmod}) {
    if (!SparseFactor::available(backend)) continue;
    SparseFactor f;
    EXPECT_FALSE(f.compute(bad, backend)) << SparseFactor::to_string(backend);
  }
  // the agreement above needs two different backends: a build with Eigen's AMD alone has
  // compared one with itself, so says so rather than pass
  if (backends().size() < 2)
    GTEST_SKIP() << "one sparse backend in this build (no METIS, no CHOLMOD): nothing compared";
}

// solve_units (the probe app's contact patches): the columns of several rows solved together are
// solve_unit's, value for value, whatever their order, their count against the lanes, a row given
// twice, and on every backend (the supernodal one solves them one at a time)
TEST(SparseFactor, UnitColumnsSolvedTogetherAreTheOnesSolvedAlone) {
  const SparseFactor::Matrix a = block_matrix();
  const int nn = int(a.rows());
  // two full passes of kUnitLanes and one of one; out of order (the first lane of a pass not its
  // earliest row in the factor's order), a row given twice
  std::vector<int> rows;
  for (int k = 0; k < 2 * SparseFactor::kUnitLanes; ++k) rows.push_back(((nn - 1 - 37 * k) % nn + nn) % nn);
  rows.push_back(rows[3]);
  ASSERT_EQ(rows.size(), std::size_t(2 * SparseFactor::kUnitLanes + 1));
  // the passes on one thread and on two (each its own lanes' buffer), the same bits
  for (const std::size_t stride : {std::size_t(nn), std::size_t(nn) + 5}) {
    for (auto backend : backends())
      for (const int threads : {1, 2}) {
        SparseFactor f;
        ASSERT_TRUE(f.compute(a, backend)) << SparseFactor::to_string(backend);
        std::vector<double> together(stride * rows.size(), -1.0), alone(static_cast<std::size_t>(nn));
        {
          ScopedThreads scope;
          scope.set(threads);
          f.solve_units(rows.data(), int(rows.size()), together.data(), stride);
        }
        for (std::size_t r = 0; r < rows.size(); ++r) {
          f.solve_unit(rows[r], alone.data());
          const double* got = together.data() + r * stride;
          for (int k = 0; k < nn; ++k)
            ASSERT_EQ(got[k], alone[std::size_t(k)])
                << SparseFactor::to_string(backend) << " on " << threads << " thread(s): row " << rows[r] << " (lane "
                << r << "), entry " << k;
          // A x = e_row: a column of the inverse, not only the same as solve_unit's
          const Eigen::VectorXd ax = a * Eigen::Map<const Eigen::VectorXd>(got, nn);
          EXPECT_NEAR(ax(rows[r]), 1.0, 1e-9);
          EXPECT_NEAR(ax.norm(), 1.0, 1e-9);
          // the gap between columns (a stride longer than a column) is left as it was
          for (std::size_t k = std::size_t(nn); k < stride && r + 1 < rows.size(); ++k) EXPECT_EQ(got[k], -1.0);
        }
      }
  }
}

TEST(SparseFactor, AFactorReadBackSolvesBitForBitAsTheOneComputed) {
  const SparseFactor::Matrix a = block_matrix();
  const int n = int(a.rows());
  for (auto backend : backends()) {
    const std::string name = SparseFactor::to_string(backend);
    SparseFactor computed;
    ASSERT_TRUE(computed.compute(a, backend)) << name;
    const std::string bytes = bytes_of(computed);
    EXPECT_GE(bytes.size(), std::size_t(computed.nonzeros()) * sizeof(double)) << name;
    EXPECT_LE(double(bytes.size()), 1.05 * double(computed.stored_bytes()) + 1024) << name;
    std::srand(7);
    const Answers want = ask(computed, n);
    // viewing the bytes in place (a mapped file) and copying them give the same factor
    for (bool view : {true, false}) {
      const std::shared_ptr<const void> mem = aligned_copy(bytes);
      SparseFactor read;
      std::string why;
      ASSERT_TRUE(read.read(static_cast<const unsigned char*>(mem.get()), bytes.size(), view ? mem : nullptr, &why))
          << name << ": " << why;
      EXPECT_EQ(read.size(), n);
      EXPECT_EQ(read.backend(), backend);
      EXPECT_EQ(read.nonzeros(), computed.nonzeros());
      EXPECT_EQ(read.supports_partial(), computed.supports_partial());
      std::srand(7);
      expect_same_bits(want, ask(read, n), name + (view ? " (viewed)" : " (copied)"));
      // and it writes the same bytes again
      EXPECT_EQ(bytes_of(read), bytes) << name;
    }
  }
}

TEST(SparseFactor, ADamagedOrForeignFileIsRefusedAndLeavesTheFactorEmpty) {
  const SparseFactor::Matrix a = block_matrix(4, 4, 3);
  SparseFactor computed;
  ASSERT_TRUE(computed.compute(a));
  const std::string good = bytes_of(computed);
  const auto refused = [](const std::string& bytes, const std::string& expect_in_why) {
    const std::shared_ptr<const void> mem = aligned_copy(bytes);
    SparseFactor f;
    std::string why;
    const bool ok = f.read(static_cast<const unsigned char*>(mem.get()), bytes.size(), mem, &why);
    EXPECT_FALSE(ok) << expect_in_why;
    EXPECT_NE(why.find(expect_in_why), std::string::npos) << "why: " << why;
    EXPECT_EQ(f.size(), 0);
    EXPECT_EQ(f.nonzeros(), 0);
  };
  std::string flipped = good;
  flipped[good.size() / 2] ^= 0x10;  // a bit in the values
  refused(flipped, "checksum");
  refused(good.substr(0, good.size() - 9), "truncated");
  refused(good.substr(0, 20), "truncated");
  refused(good + "x", "after the end");
  std::string magic = good;
  magic[0] = 'Q';
  refused(magic, "not a voxelastic factor");
  std::string version = good;
  version[8] = 99;  // the format version after the 8-byte magic
  refused(version, "format version");
  refused(std::string(), "truncated");
}

/// The largest difference between two answers, relative to the first's largest entry.
double relative_difference(const Answers& a, const Answers& b) {
  const auto rel = [](const auto& x, const auto& y) {
    const Eigen::Map<const Eigen::VectorXd> xm(x.data(), Eigen::Index(x.size())), ym(y.data(), Eigen::Index(y.size()));
    return (xm - ym).cwiseAbs().maxCoeff() / xm.cwiseAbs().maxCoeff();
  };
  return std::max({rel(a.x, b.x), rel(a.column, b.column), std::abs(a.dot - b.dot) / std::abs(a.dot),
                   rel(a.response, b.response), rel(a.partial, b.partial)});
}

TEST(SparseFactor, TheGatheredSweepsSolveAsTheColumnSweepsOnEveryInstructionSet) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "no supernodal factor in this build";
  // a block large enough for nested dissection's separators to be supernodes of many columns
  const SparseFactor::Matrix a = block_matrix(14, 13, 12);
  const int n = int(a.rows());
  SparseFactor f;
  ASSERT_TRUE(f.compute(a, SparseFactor::Backend::cholmod));
  ASSERT_GE(f.widest_supernode(), 40);  // the gathered kernel runs (4 columns or more)
  f.set_sweep_kernel(SparseFactor::SweepKernel::column);
  std::srand(11);
  const Answers want = ask(f, n);
  // the column sweeps solve A x = b (the reference the gathered ones are held to)
  std::srand(11);
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(n, 3);
  EXPECT_LT((a.selfadjointView<Eigen::Lower>() * want.x - b).norm() / b.norm(), 1e-10);
  int levels = 0;
  for (const SimdLevel simd : {SimdLevel::generic, SimdLevel::avx2, SimdLevel::avx512}) {
    if (!simd_supported(simd)) continue;
    ++levels;
    f.set_sweep_kernel(SparseFactor::SweepKernel::gathered, simd);
    EXPECT_EQ(f.sweep_simd(), simd);
    std::srand(11);
    const Answers got = ask(f, n);
    const double diff = relative_difference(want, got);
    std::cout << "gathered " << to_string(simd) << ": largest difference from the column sweeps " << diff
              << " (relative)\n";
    EXPECT_LT(diff, 1e-12) << to_string(simd);
    EXPECT_GT(diff, 0.0) << to_string(simd) << ": the same bits, so the gathered kernel did not run";
    // and the same bits from run to run
    std::srand(11);
    expect_same_bits(got, ask(f, n), std::string("gathered ") + to_string(simd) + ", again");
  }
  EXPECT_GE(levels, 1);
}

/// Every supernodal pass the solver runs, on `f`: a full solve (forward and backward over the
/// whole factor), the far field's forward fields (18 lanes), a regional step (forward half on
/// the changed rows' ancestors, candidates' rows, one backward half with contact forces), the
/// forces' response over everything and over the closure, a unit column on the closure.
struct PassResults {
  Eigen::MatrixX3d x, partial, response, response_partial;
  std::vector<double> fields, column;
  Eigen::Vector3d row;
  int changed{0};  ///< the rows the forward half found changed
};

PassResults run_passes(SparseFactor& f, const std::vector<int>& region, const std::vector<int>& candidates) {
  const int n = f.size();
  PassResults r;
  std::srand(11);
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(n, 3);
  r.x.resize(n, 3);
  f.solve3(b, r.x);
  f.forward_fields(Eigen::MatrixXd::Random(n, 9), r.fields);
  f.set_partial_rows(region);
  Eigen::MatrixX3d b2 = b;
  for (const int i : region) b2.row(i) += Eigen::RowVector3d(0.5, -1.0, 0.25);
  r.changed = f.forward3_partial(b2);
  std::vector<SparseFactor::UnitForward> z(candidates.size());
  std::vector<const SparseFactor::UnitForward*> zp;
  std::vector<double> forces;
  r.row.setZero();
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    f.forward_unit(candidates[k], z[k]);
    zp.push_back(&z[k]);
    r.row += f.solution_row(z[k]);
    forces.insert(forces.end(), {0.1 * double(k + 1), -0.2, 0.3});
  }
  r.partial = r.x;
  f.backward3_partial(zp, forces, r.partial);
  r.response = Eigen::MatrixX3d::Zero(n, 3);
  f.add_response3(zp, forces, r.response, false);
  r.response_partial = Eigen::MatrixX3d::Zero(n, 3);
  f.add_response3(zp, forces, r.response_partial, true);
  r.column.assign(std::size_t(n), 0.0);
  f.solve_unit_partial(candidates.front(), r.column.data());
  return r;
}

bool same_bits(const Eigen::MatrixX3d& a, const Eigen::MatrixX3d& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), sizeof(double) * std::size_t(a.size())) == 0;
}

/// The passes of `serial` (on one thread) on 2 and 3 threads: the same bits. Returns the serial
/// results.
PassResults expect_tree_passes_as_serial(SparseFactor& serial, const std::vector<int>& region,
                                         const std::vector<int>& candidates) {
  serial.set_threads(1);
  const PassResults want = run_passes(serial, region, candidates);
  EXPECT_EQ(serial.tree_parallel_passes(), 0);
  for (const int threads : {2, 3}) {
    SparseFactor split = serial;  // the same factor, its passes on `threads` threads
    split.set_threads(threads, 0);
    const PassResults got = run_passes(split, region, candidates);
    const std::string what = std::to_string(threads) + " threads";
    // the passes ran split (the full ones, the regional ones and the 18-lane fields at least)
    EXPECT_GE(split.tree_parallel_passes(), 6) << what;
    EXPECT_TRUE(same_bits(got.x, want.x))
        << what << " max diff " << (got.x - want.x).cwiseAbs().maxCoeff() << " of " << want.x.cwiseAbs().maxCoeff();
    EXPECT_EQ(got.fields, want.fields) << what;
    // the forward half's scan for the changed rows (by chunks of 1,024 rows on the threads)
    EXPECT_EQ(got.changed, want.changed) << what;
    EXPECT_EQ(std::memcmp(got.row.data(), want.row.data(), sizeof(double) * 3), 0) << what;
    EXPECT_TRUE(same_bits(got.partial, want.partial)) << what;
    EXPECT_TRUE(same_bits(got.response, want.response)) << what;
    EXPECT_TRUE(same_bits(got.response_partial, want.response_partial)) << what;
    EXPECT_EQ(got.column, want.column) << what;
  }
  return want;
}

TEST(SparseFactor, TreeParallelPassesGiveTheSerialPassesBitForBit) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "no supernodal factor in this build";
  // a block of 17 x 17 x 13 nodes: a nested-dissection tree with subtrees worth splitting
  const SparseFactor::Matrix a = block_matrix(16, 16, 12);
  const int n = int(a.rows());
  SparseFactor serial;
  ASSERT_TRUE(serial.compute(a, SparseFactor::Backend::cholmod));
  ASSERT_TRUE(serial.supports_partial());
  // a region of rows spread over the block (its closure branches below the top separators) and
  // contact candidates inside it
  std::vector<int> region;
  for (int i = 0; i < n; i += 7) region.push_back(i);
  const std::vector<int> candidates = {region[3], region[region.size() / 2], region.back()};
  const PassResults want = expect_tree_passes_as_serial(serial, region, candidates);
  // and the serial answers are right: the rows that changed (the region's, every one of them),
  // the full solve's residual, the regional solve's rows
  EXPECT_EQ(want.changed, int(region.size()));
  std::srand(11);
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(n, 3);
  EXPECT_LT((a * want.x - b).norm(), 1e-10 * b.norm());
  Eigen::MatrixX3d b2 = b;
  for (const int i : region) b2.row(i) += Eigen::RowVector3d(0.5, -1.0, 0.25);
  for (std::size_t k = 0; k < candidates.size(); ++k)
    b2.row(candidates[k]) += Eigen::RowVector3d(0.1 * double(k + 1), -0.2, 0.3);
  const Eigen::MatrixX3d full = Eigen::SimplicialLDLT<SparseFactor::Matrix>(a).solve(b2);
  double worst = 0.0;
  for (const int i : region) worst = std::max(worst, (want.partial.row(i) - full.row(i)).norm());
  EXPECT_LT(worst, 1e-9 * full.norm());
  // a pass shorter than the least parallel work stays serial
  SparseFactor small = serial;
  small.set_threads(2, std::int64_t(1) << 40);
  run_passes(small, region, candidates);
  EXPECT_EQ(small.tree_parallel_passes(), 0);
}

// Single-precision sweeps (SparseFactor::use_single_precision_sweeps, docs/bench.md): every
// answer within the floats' rounding of the double sweeps' and not the same bits (the floats are
// read), the same bits on any number of threads and from run to run, the double values released.
TEST(SparseFactor, SinglePrecisionSweepsAnswerWithinTheFloatsRounding) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "no supernodal factor in this build";
  const SparseFactor::Matrix a = block_matrix(14, 13, 12);
  const int n = int(a.rows());
  SparseFactor twice;
  ASSERT_TRUE(twice.compute(a, SparseFactor::Backend::cholmod));
  SparseFactor single = twice;  // shares the double values until it releases its own
  EXPECT_FALSE(single.single_precision_sweeps());
  ASSERT_TRUE(single.use_single_precision_sweeps());
  EXPECT_TRUE(single.single_precision_sweeps());
  EXPECT_FALSE(twice.single_precision_sweeps());
  EXPECT_EQ(single.nonzeros(), twice.nonzeros());
  // the values' bytes halved: what a cache file holds
  EXPECT_LT(double(single.stored_bytes()), 0.6 * double(twice.stored_bytes()));
  EXPECT_GT(double(single.stored_bytes()), 0.4 * double(twice.stored_bytes()));
  std::srand(11);
  const Answers want = ask(twice, n);
  std::srand(11);
  const Answers got = ask(single, n);
  const double diff = relative_difference(want, got);
  std::cout << "single-precision sweeps: largest difference from the double sweeps " << diff << " (relative)\n";
  EXPECT_LT(diff, 2e-6);
  EXPECT_GT(diff, 1e-9) << "the floats were not read";
  std::srand(11);
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(n, 3);
  EXPECT_LT((a.selfadjointView<Eigen::Lower>() * got.x - b).norm() / b.norm(), 1e-6);
  std::srand(11);
  expect_same_bits(got, ask(single, n), "single, again");
  // the floats widened on every instruction set this CPU runs, and by the column kernel
  for (const SimdLevel simd : {SimdLevel::generic, SimdLevel::avx2, SimdLevel::avx512}) {
    if (!simd_supported(simd)) continue;
    single.set_sweep_kernel(SparseFactor::SweepKernel::gathered, simd);
    std::srand(11);
    EXPECT_LT(relative_difference(want, ask(single, n)), 2e-6) << to_string(simd);
  }
  single.set_sweep_kernel(SparseFactor::SweepKernel::column);
  std::srand(11);
  EXPECT_LT(relative_difference(want, ask(single, n)), 2e-6) << "column kernel";
  single.set_sweep_kernel(SparseFactor::SweepKernel::gathered);
  // once single, it stays single; the double factor it was copied from is untouched
  EXPECT_TRUE(single.use_single_precision_sweeps());
  std::srand(11);
  expect_same_bits(want, ask(twice, n), "the double factor after its copy went single");
  // a factor of Eigen's (simplicial) stays in double
  if (SparseFactor::available(SparseFactor::Backend::eigen_amd)) {
    SparseFactor simplicial;
    ASSERT_TRUE(simplicial.compute(a, SparseFactor::Backend::eigen_amd));
    EXPECT_FALSE(simplicial.use_single_precision_sweeps());
    EXPECT_FALSE(simplicial.single_precision_sweeps());
  }
}

TEST(SparseFactor, SinglePrecisionTreeParallelPassesGiveTheSerialPassesBitForBit) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "no supernodal factor in this build";
  const SparseFactor::Matrix a = block_matrix(16, 16, 12);
  const int n = int(a.rows());
  SparseFactor serial;
  ASSERT_TRUE(serial.compute(a, SparseFactor::Backend::cholmod));
  ASSERT_TRUE(serial.use_single_precision_sweeps());
  std::vector<int> region;
  for (int i = 0; i < n; i += 7) region.push_back(i);
  const std::vector<int> candidates = {region[3], region[region.size() / 2], region.back()};
  expect_tree_passes_as_serial(serial, region, candidates);
}

TEST(SparseFactor, ASinglePrecisionFactorReadBackSolvesBitForBitAndAMappedOneIsReleased) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "no supernodal factor in this build";
  const SparseFactor::Matrix a = block_matrix(10, 9, 8);
  const int n = int(a.rows());
  SparseFactor computed;
  ASSERT_TRUE(computed.compute(a, SparseFactor::Backend::cholmod));
  const std::string doubles = bytes_of(computed);
  ASSERT_TRUE(computed.use_single_precision_sweeps());
  const std::string floats = bytes_of(computed);
  EXPECT_LT(floats.size(), doubles.size());
  std::srand(5);
  const Answers want = ask(computed, n);
  for (bool view : {true, false}) {
    const std::shared_ptr<const void> mem = aligned_copy(floats);
    SparseFactor read;
    std::string why;
    ASSERT_TRUE(read.read(static_cast<const unsigned char*>(mem.get()), floats.size(), view ? mem : nullptr, &why))
        << why;
    EXPECT_TRUE(read.single_precision_sweeps());
    EXPECT_EQ(read.nonzeros(), computed.nonzeros());
    std::srand(5);
    expect_same_bits(want, ask(read, n), view ? "single, viewed" : "single, copied");
    EXPECT_EQ(bytes_of(read), floats);
  }
  // a mapped file of doubles made single: the same floats, and the mapping no longer held
  std::shared_ptr<const void> mem = aligned_copy(doubles);
  const std::weak_ptr<const void> mapped = mem;
  SparseFactor converted;
  ASSERT_TRUE(converted.read(static_cast<const unsigned char*>(mem.get()), doubles.size(), mem));
  mem.reset();
  EXPECT_FALSE(mapped.expired());  // viewed by the double factor
  ASSERT_TRUE(converted.use_single_precision_sweeps());
  EXPECT_TRUE(mapped.expired()) << "the double values and row indices still hold the mapped file";
  std::srand(5);
  expect_same_bits(want, ask(converted, n), "a mapped double factor made single");
}

// Two threads that factor at once get the serial factor, bit for bit: the palpation map factors
// on each of its threads, and Debian's single-threaded OpenBLAS (built without locking) is not
// safe to call from two threads at once (the map read another lesion from run to run).
TEST(SparseFactor, TwoThreadsFactoringAtOnceGetTheSerialFactor) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "no supernodal factor in this build";
  const SparseFactor::Matrix a = block_matrix(20, 20, 16);  // supernodes large enough for BLAS's blocked kernels
  const int n = int(a.rows());
  std::srand(5);
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(n, 3);
  SparseFactor serial;
  ASSERT_TRUE(serial.compute(a, SparseFactor::Backend::cholmod));
  Eigen::MatrixX3d want(n, 3);
  serial.solve3(b, want);
  constexpr int kRounds = 6;
  std::vector<Eigen::MatrixX3d> got(2 * kRounds);
  std::vector<int> ok(2 * kRounds, 0);
  std::vector<std::thread> workers;
  for (int t = 0; t < 2; ++t)
    workers.emplace_back([&, t] {
      for (int r = 0; r < kRounds; ++r) {
        SparseFactor f;
        const std::size_t k = std::size_t(t * kRounds + r);
        ok[k] = f.compute(a, SparseFactor::Backend::cholmod) ? 1 : 0;
        got[k].resize(n, 3);
        if (ok[k]) f.solve3(b, got[k]);
      }
    });
  for (std::thread& w : workers) w.join();
  for (std::size_t k = 0; k < got.size(); ++k) {
    ASSERT_EQ(ok[k], 1) << k;
    EXPECT_EQ(std::memcmp(got[k].data(), want.data(), sizeof(double) * std::size_t(want.size())), 0)
        << "factor " << k << ": max diff " << (got[k] - want).cwiseAbs().maxCoeff() << " ("
        << SparseFactor::blas_library() << ")";
  }
}

TEST(SparseFactor, NamesTheBlasUnderItsSupernodes) {
  const std::string name = SparseFactor::blas_library();
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) {
    EXPECT_EQ(name, "none");
    EXPECT_FALSE(SparseFactor::reference_blas());
    return;
  }
  // OpenBLAS (scripts/install-deps.sh), BLIS, MKL, or else the reference one, and the hint's
  // test agrees with the name
  EXPECT_TRUE(name.rfind("OpenBLAS", 0) == 0 || name.rfind("BLIS", 0) == 0 || name == "MKL" ||
              name == "the reference BLAS")
      << name;
  EXPECT_EQ(SparseFactor::reference_blas(), name == "the reference BLAS") << name;
  std::cout << "BLAS: " << name << "\n";
}

TEST(ContentHash, IsXXH64) {
  // the reference values (Debian's xxhash, `xxhsum -H64`), for inputs below one stripe, of one,
  // and of many fed in uneven pieces
  const auto of = [](const std::string& text) {
    ContentHash h;
    h.add(text.data(), text.size());
    return h.value();
  };
  EXPECT_EQ(of(""), 0xef46db3751d8e999ULL);
  EXPECT_EQ(of("abc"), 0x44bc2cf5ad770999ULL);
  EXPECT_EQ(of("Nobody inspects the spammish repetition"), 0xfbcea83c8a378bf1ULL);
  std::vector<unsigned char> data(1000);
  for (std::size_t i = 0; i < data.size(); ++i) data[i] = static_cast<unsigned char>(i * 37 % 256);
  ContentHash parts;
  for (std::size_t at = 0, piece = 1; at < data.size(); at += piece, piece = piece * 3 % 41 + 1)
    parts.add(data.data() + at, std::min(piece, data.size() - at));
  EXPECT_EQ(parts.value(), 0xbfba0b19df72611cULL);
}

TEST(ContentHash, DependsOnTheBytesNotOnHowTheyAreFed) {
  std::vector<unsigned char> data(1000);
  for (std::size_t i = 0; i < data.size(); ++i) data[i] = static_cast<unsigned char>(i * 37 + 11);
  ContentHash whole;
  whole.add(data.data(), data.size());
  for (std::size_t piece : {1u, 3u, 7u, 8u, 13u, 999u}) {
    ContentHash parts;
    for (std::size_t at = 0; at < data.size(); at += piece)
      parts.add(data.data() + at, std::min(piece, data.size() - at));
    EXPECT_EQ(parts.value(), whole.value()) << piece;
  }
  // a changed bit, a byte more, another seed: another value
  std::vector<unsigned char> other = data;
  other[500] ^= 1;
  ContentHash h2;
  h2.add(other.data(), other.size());
  EXPECT_NE(h2.value(), whole.value());
  ContentHash h3;
  h3.add(data.data(), data.size() - 1);
  EXPECT_NE(h3.value(), whole.value());
  ContentHash h4(1);
  h4.add(data.data(), data.size());
  EXPECT_NE(h4.value(), whole.value());
  // zeros of different lengths differ (the length is hashed)
  const std::vector<unsigned char> z8(8, 0), z16(16, 0);
  ContentHash a8, a16;
  a8.add(z8.data(), 8);
  a16.add(z16.data(), 16);
  EXPECT_NE(a8.value(), a16.value());
}

}  // namespace
}  // namespace vx
