// The factor cache in a folder (io/factor_cache.h): a factor kept is loaded back and solves bit
// for bit as computed; a damaged file is removed and the factor computed; the folder stays
// under its size limit by dropping the least recently used; quick factors are not kept; the
// option and the environment pick the folder or none; an order kept by the matrix's pattern
// serves another matrix of it with METIS's factor, and a false order file is refused; a factor
// swept in single precision is kept under a key of its own and loaded in single precision.
#include "io/factor_cache.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "base/error.h"

namespace vx {
namespace {
namespace fs = std::filesystem;

/// A 3D grid Laplacian plus a mass term (n^3 rows): symmetric positive definite; `shift`
/// changes its diagonal (another matrix, another key).
SparseFactor::Matrix grid_matrix(int n, double shift = 0.0) {
  std::vector<Eigen::Triplet<double>> t;
  const auto id = [n](int i, int j, int k) { return (k * n + j) * n + i; };
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const int r = id(i, j, k);
        t.emplace_back(r, r, 6.0 + 0.01 + shift);
        if (i + 1 < n) t.emplace_back(r, id(i + 1, j, k), -1.0), t.emplace_back(id(i + 1, j, k), r, -1.0);
        if (j + 1 < n) t.emplace_back(r, id(i, j + 1, k), -1.0), t.emplace_back(id(i, j + 1, k), r, -1.0);
        if (k + 1 < n) t.emplace_back(r, id(i, j, k + 1), -1.0), t.emplace_back(id(i, j, k + 1), r, -1.0);
      }
  SparseFactor::Matrix a(n * n * n, n * n * n);
  a.setFromTriplets(t.begin(), t.end());
  return a;
}

/// A key for a test matrix (the solver's comes from projective_matrix_key).
FactorKey key_of(const SparseFactor::Matrix& a) {
  FactorKey k;
  k.rows = a.rows();
  k.nonzeros = a.nonZeros();
  k.backend = std::uint8_t(SparseFactor::best_backend());
  std::uint64_t h = 1469598103934665603ULL;
  for (Eigen::Index i = 0; i < a.nonZeros(); ++i) {
    std::uint64_t bits;
    std::memcpy(&bits, a.valuePtr() + i, 8);
    h = (h ^ bits) * 1099511628211ULL;
  }
  k.hash = h;
  return k;
}

/// Factors `a`, looking it up in `cache` first and offering it after, as the solver does.
SparseFactor factor_with(FolderFactorCache& cache, const SparseFactor::Matrix& a) {
  SparseFactor f;
  if (cache.load(key_of(a), f)) return f;
  EXPECT_TRUE(f.compute(a));
  cache.store(key_of(a), f);
  return f;
}

/// Flips the bits of `mask` in the byte in the middle of `file`.
void flip_middle_bit(const fs::path& file, char mask) {
  std::fstream io(file, std::ios::in | std::ios::out | std::ios::binary);
  io.seekg(std::streamoff(fs::file_size(file) / 2));
  char c = 0;
  io.read(&c, 1);
  c = char(c ^ mask);
  io.seekp(std::streamoff(fs::file_size(file) / 2));
  io.write(&c, 1);
}

class FactorCacheTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_factor_cache_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  [[nodiscard]] FactorCacheSettings settings() const {
    FactorCacheSettings s;
    s.folder = dir_ / "factors";  // created when the first factor is kept
    s.min_factor_s = 0.0;
    return s;
  }
  static std::vector<fs::path> files(const fs::path& folder) {
    std::vector<fs::path> out;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(folder, ec)) out.push_back(e.path());
    return out;
  }
  fs::path dir_;
};

TEST_F(FactorCacheTest, AFactorKeptIsLoadedBackAndSolvesTheSame) {
  const SparseFactor::Matrix a = grid_matrix(12);
  FolderFactorCache cache(settings());
  SparseFactor first = factor_with(cache, a);
  EXPECT_FALSE(first.from_cache());
  const FolderFactorCache::Counters c1 = cache.counters();
  EXPECT_EQ(c1.misses, 1);
  EXPECT_EQ(c1.stored, 1);
  const std::vector<fs::path> kept = files(settings().folder);
  ASSERT_EQ(kept.size(), 1u);  // no temporary file left beside it
  EXPECT_EQ(kept[0], cache.file_of(key_of(a)));
  EXPECT_EQ(kept[0].extension(), ".vxfactor");

  // a second run (another cache object on the same folder, as another process would)
  FolderFactorCache again(settings());
  SparseFactor second = factor_with(again, a);
  EXPECT_TRUE(second.from_cache());
  EXPECT_EQ(again.counters().hits, 1);
  EXPECT_EQ(again.counters().stored, 0);
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(a.rows(), 3);
  Eigen::MatrixX3d x1(a.rows(), 3), x2(a.rows(), 3);
  first.solve3(b, x1);
  second.solve3(b, x2);
  EXPECT_EQ(x1, x2);  // bit for bit
  EXPECT_LT((a * x2 - b).norm(), 1e-10 * b.norm());
}

TEST_F(FactorCacheTest, ASinglePrecisionFactorIsKeptApartAndLoadedInSinglePrecision) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "no supernodal factor in this build";
  const SparseFactor::Matrix a = grid_matrix(12);
  FactorKey single_key = key_of(a);
  single_key.single = true;
  FolderFactorCache cache(settings());
  SparseFactor first;
  ASSERT_TRUE(first.compute(a));
  ASSERT_TRUE(first.use_single_precision_sweeps());  // before it is kept, as the solver does
  cache.store(single_key, first);
  const fs::path file = cache.file_of(single_key);
  EXPECT_NE(file.filename().string().find("-single.vxfactor"), std::string::npos) << file;
  // the same matrix in double is another file: not found
  FolderFactorCache again(settings());
  SparseFactor twice;
  EXPECT_FALSE(again.load(key_of(a), twice));
  ASSERT_TRUE(twice.compute(a));
  again.store(key_of(a), twice);
  EXPECT_LT(fs::file_size(file), fs::file_size(again.file_of(key_of(a))));
  SparseFactor second;
  ASSERT_TRUE(again.load(single_key, second));
  EXPECT_TRUE(second.from_cache());
  EXPECT_TRUE(second.single_precision_sweeps());
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(a.rows(), 3);
  Eigen::MatrixX3d x1(a.rows(), 3), x2(a.rows(), 3), xd(a.rows(), 3);
  first.solve3(b, x1);
  second.solve3(b, x2);
  twice.solve3(b, xd);
  EXPECT_EQ(x1, x2);  // bit for bit
  EXPECT_NE(x1, xd);  // the floats were read
  EXPECT_LT((x1 - xd).norm(), 1e-6 * xd.norm());
}

TEST_F(FactorCacheTest, AFactorWrittenInTheBackgroundOutlivesItsSolverAndIsFoundAtOnce) {
  // the solver's factor may be gone before its background write ends: the copy written shares
  // its arrays and keeps them; a load right after the store waits for the write and finds it
  const SparseFactor::Matrix a = grid_matrix(16);
  FactorCacheSettings s = settings();
  s.background_writes = true;
  s.writer_nice = 0;
  FolderFactorCache cache(s);
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(a.rows(), 3);
  Eigen::MatrixX3d x1(a.rows(), 3), x2(a.rows(), 3);
  {
    SparseFactor f;
    ASSERT_TRUE(f.compute(a));
    f.solve3(b, x1);
    cache.store(key_of(a), f);
  }  // the solver's factor is gone; its arrays are freed unless the copy keeps them
  std::vector<std::vector<double>> scribble;  // reuse what a free returned, with other values
  for (int i = 0; i < 8; ++i) scribble.emplace_back(std::size_t(1) << 18, -1e300);
  SparseFactor g;
  ASSERT_TRUE(cache.load(key_of(a), g));
  EXPECT_TRUE(g.from_cache());
  EXPECT_EQ(cache.counters().stored, 1);
  EXPECT_EQ(cache.counters().hits, 1);
  ASSERT_EQ(files(s.folder).size(), 1u);  // no temporary file left beside it
  g.solve3(b, x2);
  EXPECT_EQ(x1, x2);  // bit for bit
  EXPECT_LT((a * x2 - b).norm(), 1e-10 * b.norm());
}

TEST_F(FactorCacheTest, AClosedCacheFinishesTheWriteBegunAndBeginsNoOther) {
  // close() (a process about to end without waiting for a factorisation still under way): the
  // write begun in the background is whole on disk when it returns, and a factor offered after it
  // is not written at all (so no file is ever left half written), while loads still work
  const SparseFactor::Matrix a = grid_matrix(16), b = grid_matrix(12);
  FactorCacheSettings s = settings();
  s.background_writes = true;
  s.writer_nice = 0;
  FolderFactorCache cache(s);
  SparseFactor fa, fb;
  ASSERT_TRUE(fa.compute(a));
  ASSERT_TRUE(fb.compute(b));
  cache.store(key_of(a), fa);  // written beside
  cache.close();
  const std::vector<fs::path> after_close = files(s.folder);
  ASSERT_EQ(after_close.size(), 1u) << "the write begun is finished, with no temporary beside it";
  EXPECT_EQ(after_close[0], cache.file_of(key_of(a)));
  cache.store(key_of(b), fb);
  cache.store_order(SparseFactor::pattern_key(b), fb);
  EXPECT_EQ(files(s.folder), after_close) << "nothing is written once closed";
  EXPECT_EQ(cache.counters().stored, 1);
  FolderFactorCache again(s);
  SparseFactor g;
  EXPECT_TRUE(again.load(key_of(a), g));
  EXPECT_FALSE(again.load(key_of(b), g));
}

TEST_F(FactorCacheTest, ADamagedFileIsRemovedAndTheFactorComputed) {
  const SparseFactor::Matrix a = grid_matrix(10);
  FolderFactorCache cache(settings());
  SparseFactor f = factor_with(cache, a);
  const fs::path file = cache.file_of(key_of(a));
  ASSERT_TRUE(fs::exists(file));
  flip_middle_bit(file, 0x04);  // in the middle of the values
  FolderFactorCache again(settings());
  SparseFactor g = factor_with(again, a);
  EXPECT_FALSE(g.from_cache());
  EXPECT_EQ(again.counters().damaged, 1);
  EXPECT_EQ(again.counters().stored, 1);  // computed and kept anew
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(a.rows(), 3);
  Eigen::MatrixX3d x(a.rows(), 3);
  g.solve3(b, x);
  EXPECT_LT((a * x - b).norm(), 1e-10 * b.norm());
  // an empty file of the same name: the same
  fs::resize_file(file, 0);
  SparseFactor h = factor_with(again, a);
  EXPECT_FALSE(h.from_cache());
  EXPECT_EQ(again.counters().damaged, 2);
}

TEST_F(FactorCacheTest, AnOrderKeptServesAnotherMatrixOfThePatternWithTheSameFactor) {
  if (SparseFactor::best_backend() != SparseFactor::Backend::cholmod) GTEST_SKIP() << "orders are CHOLMOD's";
  const SparseFactor::Matrix a = grid_matrix(12), b = grid_matrix(12, 0.5);  // the pattern, other values
  EXPECT_NE(key_of(a).hash, key_of(b).hash);
  const FactorKey pattern = SparseFactor::pattern_key(a);
  EXPECT_EQ(SparseFactor::pattern_key(b), pattern);
  EXPECT_NE(SparseFactor::pattern_key(grid_matrix(11)), pattern);
  {  // one more entry in a column: another pattern
    SparseFactor::Matrix c = a;
    c.coeffRef(5, 0) = 0.0;
    EXPECT_NE(SparseFactor::pattern_key(c), pattern);
  }
  SparseFactor first;
  ASSERT_TRUE(first.compute(a));
  EXPECT_GT(first.order_seconds(), 0.0);
  FolderFactorCache cache(settings());
  cache.store_order(pattern, first);
  EXPECT_EQ(cache.order_counters().stored, 1);
  EXPECT_EQ(cache.order_file_of(pattern).extension(), ".vxorder");

  FolderFactorCache again(settings());
  std::vector<int> order;
  ASSERT_TRUE(again.load_order(pattern, order));
  EXPECT_EQ(again.order_counters().hits, 1);
  EXPECT_EQ(order, first.order());
  // b factored in the kept order and b factored with METIS: the same order, the same bits
  SparseFactor kept, metis;
  ASSERT_TRUE(kept.compute(b, SparseFactor::Backend::automatic, order));
  ASSERT_TRUE(metis.compute(b));
  EXPECT_EQ(kept.order(), metis.order());
  EXPECT_EQ(kept.nonzeros(), metis.nonzeros());
  const Eigen::MatrixX3d rhs = Eigen::MatrixX3d::Random(b.rows(), 3);
  Eigen::MatrixX3d x1(b.rows(), 3), x2(b.rows(), 3);
  kept.solve3(rhs, x1);
  metis.solve3(rhs, x2);
  EXPECT_EQ(x1, x2);
  EXPECT_LT((b * x1 - rhs).norm(), 1e-10 * rhs.norm());
  // another pattern finds nothing
  EXPECT_FALSE(again.load_order(SparseFactor::pattern_key(grid_matrix(11)), order));
  EXPECT_TRUE(order.empty());
  // an order of the wrong length is refused by the factor, not used
  SparseFactor wrong;
  EXPECT_THROW((void)wrong.compute(b, SparseFactor::Backend::cholmod, std::vector<int>(5, 0)), Error);
}

TEST_F(FactorCacheTest, AnOrderFileThatIsNotThePatternsPermutationIsRefused) {
  const FactorKey pattern{.hash = 0x1234, .rows = 4, .nonzeros = 7, .backend = 0};
  const auto read = [&](const std::vector<int>& written, const FactorKey& key, std::string& why) {
    std::ostringstream out;
    write_order_file(out, key, written);
    const std::string bytes = out.str();
    std::vector<int> order;
    const bool ok =
        read_order_file(reinterpret_cast<const unsigned char*>(bytes.data()), bytes.size(), pattern, order, &why);
    EXPECT_EQ(ok, !order.empty());
    return ok;
  };
  std::string why;
  EXPECT_TRUE(read({2, 0, 3, 1}, pattern, why)) << why;
  EXPECT_FALSE(read({2, 0, 2, 1}, pattern, why));  // a row twice
  EXPECT_NE(why.find("not a permutation"), std::string::npos) << why;
  EXPECT_FALSE(read({2, 0, 4, 1}, pattern, why));  // a row out of range
  EXPECT_NE(why.find("not a permutation"), std::string::npos) << why;
  EXPECT_FALSE(read({2, 0, 1}, pattern, why));  // too short
  EXPECT_FALSE(why.empty());
  FactorKey other = pattern;
  other.hash = 0x1235;
  EXPECT_FALSE(read({2, 0, 3, 1}, other, why));
  EXPECT_NE(why.find("another matrix pattern"), std::string::npos) << why;

  // a stored file with a bit flipped: removed, counted damaged, nothing loaded
  if (SparseFactor::best_backend() != SparseFactor::Backend::cholmod) return;
  const SparseFactor::Matrix a = grid_matrix(10);
  SparseFactor f;
  ASSERT_TRUE(f.compute(a));
  FolderFactorCache cache(settings());
  const FactorKey key = SparseFactor::pattern_key(a);
  cache.store_order(key, f);
  const fs::path file = cache.order_file_of(key);
  ASSERT_TRUE(fs::exists(file));
  flip_middle_bit(file, 0x10);  // in the middle of the order
  std::vector<int> order;
  EXPECT_FALSE(cache.load_order(key, order));
  EXPECT_TRUE(order.empty());
  EXPECT_EQ(cache.order_counters().damaged, 1);
  EXPECT_FALSE(fs::exists(file));
}

TEST_F(FactorCacheTest, TheFolderStaysUnderItsLimitDroppingTheLeastRecentlyUsed) {
  FactorCacheSettings s = settings();
  // one factor of this size is about 0.1 to 0.3 MB; room for two
  SparseFactor probe;
  ASSERT_TRUE(probe.compute(grid_matrix(10)));
  s.max_bytes = std::uint64_t(2.5 * double(probe.stored_bytes()));
  FolderFactorCache cache(s);
  std::vector<FactorKey> keys;
  for (int k = 0; k < 3; ++k) {
    const SparseFactor::Matrix a = grid_matrix(10, 0.1 * k);
    keys.push_back(key_of(a));
    const SparseFactor f = factor_with(cache, a);
    if (k == 1) {
      // use the first again: it becomes the most recently used, the second the oldest
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      const SparseFactor g = factor_with(cache, grid_matrix(10, 0.0));
      EXPECT_TRUE(g.from_cache());
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));  // distinct modification times
  }
  EXPECT_EQ(cache.counters().evicted, 1);
  EXPECT_TRUE(fs::exists(cache.file_of(keys[0])));
  EXPECT_FALSE(fs::exists(cache.file_of(keys[1])));
  EXPECT_TRUE(fs::exists(cache.file_of(keys[2])));
  std::uint64_t total = 0;
  for (const auto& f : files(s.folder)) total += fs::file_size(f);
  EXPECT_LE(total, s.max_bytes);
}

TEST_F(FactorCacheTest, QuickFactorsAreNotKept) {
  FactorCacheSettings s = settings();
  s.min_factor_s = 1e9;
  FolderFactorCache cache(s);
  const SparseFactor f = factor_with(cache, grid_matrix(8));
  EXPECT_EQ(cache.counters().skipped, 1);
  EXPECT_EQ(cache.counters().stored, 0);
  EXPECT_FALSE(fs::exists(s.folder));
}

TEST_F(FactorCacheTest, AFolderThatCannotBeWrittenLeavesTheRunAsWithoutACache) {
  FactorCacheSettings s = settings();
  fs::create_directories(dir_);
  std::ofstream(dir_ / "a_file") << "x";
  s.folder = dir_ / "a_file" / "factors";  // below a file: cannot be created
  FolderFactorCache cache(s);
  const SparseFactor::Matrix a = grid_matrix(8);
  SparseFactor f = factor_with(cache, a);
  EXPECT_EQ(cache.counters().stored, 0);
  const Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(a.rows(), 3);
  Eigen::MatrixX3d x(a.rows(), 3);
  f.solve3(b, x);
  EXPECT_LT((a * x - b).norm(), 1e-10 * b.norm());
}

TEST_F(FactorCacheTest, TheOptionAndTheEnvironmentPickTheFolder) {
  EXPECT_EQ(make_factor_cache("off"), nullptr);
  const auto explicit_folder = std::dynamic_pointer_cast<FolderFactorCache>(make_factor_cache((dir_ / "x").string()));
  ASSERT_NE(explicit_folder, nullptr);
  EXPECT_EQ(explicit_folder->settings().folder, dir_ / "x");
  EXPECT_TRUE(explicit_folder->settings().background_writes);  // the runs' caches write beside the run
  const char* saved = std::getenv("VOXELASTIC_FACTOR_CACHE");
  const std::string keep = saved ? saved : "";
  ::setenv("VOXELASTIC_FACTOR_CACHE", "off", 1);
  EXPECT_EQ(make_factor_cache(""), nullptr);
  ::setenv("VOXELASTIC_FACTOR_CACHE", (dir_ / "env").c_str(), 1);
  const auto from_env = std::dynamic_pointer_cast<FolderFactorCache>(make_factor_cache(""));
  ASSERT_NE(from_env, nullptr);
  EXPECT_EQ(from_env->settings().folder, dir_ / "env");
  ::unsetenv("VOXELASTIC_FACTOR_CACHE");
  ::setenv("XDG_CACHE_HOME", (dir_ / "xdg").c_str(), 1);
  EXPECT_EQ(default_factor_cache_folder(), dir_ / "xdg" / "voxelastic" / "factors");
  ::unsetenv("XDG_CACHE_HOME");
  if (saved) ::setenv("VOXELASTIC_FACTOR_CACHE", keep.c_str(), 1);
}

}  // namespace
}  // namespace vx
