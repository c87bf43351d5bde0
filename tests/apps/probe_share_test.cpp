// `voxelastic-probe` sharing the cores (apps/probe/thread_share.h), through the built binary, on a
// small block (18 elements) whose implicit steps of 30 ms take well under 1 % of real time on a
// quiet machine: far below the 45 % under which two threads go to one, so a machine busy with
// other tests (three busy loops beside it on two cores: the same figures) does not change it.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <string>

#include "support/run_binary.h"

namespace fs = std::filesystem;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "probe" / "voxelastic-probe";

class ProbeShare : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_probe_share_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    std::ofstream(dir_ / "block.json") << R"({
      "object": {"box_mm": {"min": [0, 0, 0], "max": [24, 24, 16]}, "voxel_mm": 4},
      "material": {"youngs_modulus_kpa": 10, "damping": 0.2},
      "integrator": {"type": "implicit", "dt_s": 0.03, "iterations": 1},
      "fixed": [{"box_mm": {"min": [-1, -1, -0.1], "max": [25, 25, 0.1]}}],
      "probes": [{"name": "ball", "shape": "sphere", "radius_mm": 3, "path": [{"t_s": 0, "position_mm": [12, 12, 30]}]}],
      "duration_s": 1
    })";
  }
  void TearDown() override { fs::remove_all(dir_); }
  vx::testing::RunResult run(const std::string& args) const {
    return vx::testing::run_binary(kBinary, "block.json --headless --threads 2 " + args, dir_, dir_);
  }
  /// run(), again (at most 3 runs in all) while the session says its physics fell behind real time
  /// (the final line's "could not keep real time": a lag of 50 ms or more was dropped). These
  /// steps take 1.5 ms of each 30 ms even under AddressSanitizer, so such a lag is the thread not
  /// scheduled at all, which the rule answers as it should (behind real time: every thread again)
  /// and which is not what is measured here. Seen once in CI's ASan run beside another session
  /// of the app (0.71x over one second): 30 of 167 steps on one thread and 3 changes.
  vx::testing::RunResult run_in_real_time(const std::string& args) const {
    vx::testing::RunResult r;
    for (int attempt = 0; attempt < 3; ++attempt) {
      r = run(args);
      if (r.code != 0 || r.out.find("could not keep real time") == std::string::npos) break;
    }
    return r;
  }
  fs::path dir_;
};

// It goes to one of its two threads after a hold of 2 s of low load. Slowed on purpose to more
// than 45 % of real time per step (a sleep, which no thread count shortens) it tries one thread
// after that hold and keeps it: as fast. With --no-share-cores every step is on both. When a
// trial finds two threads faster: ThreadShare's tests (probe_thread_share_test.cpp).
TEST_F(ProbeShare, ThePhysicsSharesTheCoresWhileItRunsWellAheadOrOneThreadIsAsFast) {
  if (vx::testing::kUnderTsan) GTEST_SKIP() << "under TSan the app's figures are not real time";
  const std::regex line(
      R"(physics threads: 2, the cores shared: (\d+) of (\d+) steps on one thread \(ahead of real time )"
      R"(without the others, or as fast: (\d+) of (\d+) trials kept\), (\d+) changes)");
  std::smatch m;
  vx::testing::RunResult r = run_in_real_time("--duration 5");
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  ASSERT_TRUE(std::regex_search(r.out, m, line)) << r.out;
  // down at the end of the first window of 2 s of wall time: the last 3 of 5 s, 99 of 167 steps
  // (98 read in quiet and in busy runs)
  EXPECT_NEAR(std::stod(m[1]), 0.6 * std::stod(m[2]), 0.05 * std::stod(m[2])) << r.out;
  EXPECT_EQ(m[3], "0") << r.out;  // no trial: the load alone sent it to one thread
  EXPECT_EQ(m[4], "0") << r.out;
  EXPECT_EQ(m[5], "1") << r.out;
  // 20 ms of sleep per 30 ms step: 67 % of real time or more, over 45 % in all. The trial takes
  // one thread at the end of the first window (2 s) and keeps it: the last 1 of 3 s, 33 of 100
  // steps (31 read)
  r = run_in_real_time("--duration 3 --test-step-delay 0.02");
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  ASSERT_TRUE(std::regex_search(r.out, m, line)) << r.out;
  EXPECT_NEAR(std::stod(m[1]), 0.33 * std::stod(m[2]), 0.06 * std::stod(m[2])) << r.out;
  EXPECT_EQ(m[3], "1") << r.out;
  EXPECT_EQ(m[4], "1") << r.out;
  EXPECT_EQ(m[5], "1") << r.out;
  r = run("--duration 1 --no-share-cores");
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("physics threads: 2, every step on all of them (--no-share-cores)"), std::string::npos) << r.out;
}

}  // namespace
