// `voxelastic verify` and `verify-merge` through the built binary: usage errors (exit 2), bad
// folders and merges (exit 1, a message, no crash), and the whole quick suite run as two shards
// and merged (the CI run of the suite: label slow).
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <string>

#include "support/run_binary.h"
#include "verify/verify.h"

namespace fs = std::filesystem;
using json = nlohmann::json;
using vx::testing::RunResult;
using vx::testing::slurp;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "voxelastic" / "voxelastic";

class CliVerify : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_cli_verify_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "work");
  }
  void TearDown() override { fs::remove_all(dir_); }
  RunResult run(const std::string& args) const { return vx::testing::run_binary(kBinary, args, dir_ / "work", dir_); }
  fs::path dir_;
};

}  // namespace

TEST_F(CliVerify, UsageErrorsExitTwoWithAMessage) {
  struct Case {
    std::string args, says;
  };
  for (const Case& c :
       {Case{"verify --shard 3/2 --out o", "I must be below N"}, Case{"verify --shard 0/0 --out o", "N must be"},
        Case{"verify --shard x --out o", "I/N"}, Case{"verify --suite medium --out o", "medium"},
        Case{"verify --jobs 0 --out o", "jobs"}, Case{"verify --case no-such-case --out o", "no-such-case"},
        Case{"verify --case compression-gradational --out o", "not a case of the quick suite"},
        Case{"verify --case model-counts --shard 1/2 --out o", "holds no case"}, Case{"verify-merge --out o", "DIR"}}) {
    const RunResult r = run(c.args);
    EXPECT_EQ(r.code, 2) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.says), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "work" / "o")) << c.args << ": nothing written";
  }
}

TEST_F(CliVerify, BadFoldersAndBadMergesExitOneWithAMessage) {
  // an output folder that cannot be created (a file is in the way)
  std::ofstream(dir_ / "work" / "file") << "x";
  RunResult r = run("verify --case model-counts --out file/sub");
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("cannot create the folder"), std::string::npos) << r.err;

  // one real partial report to merge wrongly
  r = run("verify --case model-counts --out part --jobs 1");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("[1/1] model-counts: passed"), std::string::npos) << r.err;
  const json report = json::parse(slurp(dir_ / "work" / "part" / "report.json"));
  EXPECT_EQ(report.at("suite"), "quick");
  EXPECT_GT(report.at("checks").size(), 10u);
  for (const auto& e : fs::directory_iterator(dir_ / "work" / "part"))
    EXPECT_EQ(e.path().filename().string().rfind(".verify-staging", 0), std::string::npos) << "no stage left behind";

  r = run("verify-merge part --out merged");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("missing"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("geometry"), std::string::npos) << r.err;
  r = run("verify-merge part part --out merged");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("is in both"), std::string::npos) << r.err;
  fs::create_directories(dir_ / "work" / "empty");
  r = run("verify-merge part empty --out merged");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("has no report.json"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "work" / "merged" / "report.json"));
}

TEST_F(CliVerify, SimdEnvironmentVariableIsCheckedAndObeyed) {
  const auto run_env = [&](const std::string& env, const std::string& args) {
    return vx::testing::run_binary(kBinary, args, dir_ / "work", dir_, env);
  };
  RunResult r = run_env("VOXELASTIC_SIMD=avx3", "verify --case model-counts --out bad");
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("VOXELASTIC_SIMD=avx3 is not an instruction set"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("auto, generic, avx2 or avx512"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "work" / "bad"));
  // the scalar-width copy (here: the packed kernel) runs everywhere and passes
  r = run_env("VOXELASTIC_SIMD=generic", "verify --case compression-voxel --out generic --jobs 1");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("passed"), std::string::npos) << r.err;
}

// The quick suite, as two shards of a job array, then merged: every case once, every check
// passing, the plots the report links to present. About 1-2 minutes on 2 cores.
TEST_F(CliVerify, QuickSuiteInTwoShardsMergesAndPasses) {
  for (int i = 0; i < 2; ++i) {
    const RunResult r =
        run("verify --suite quick --jobs 2 --shard " + std::to_string(i) + "/2 --out shard" + std::to_string(i));
    EXPECT_EQ(r.code, 0) << r.err;
  }
  const RunResult r = run("verify-merge shard0 shard1 --out all");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("checks passed"), std::string::npos) << r.out;
  const fs::path all = dir_ / "work" / "all";
  const json report = json::parse(slurp(all / "report.json"));
  ASSERT_EQ(report.size(), 2u);
  EXPECT_EQ(report.at("suite"), "quick");
  std::set<std::string> cases;
  for (const json& c : report.at("checks")) {
    EXPECT_TRUE(c.at("passed").get<bool>()) << c.dump();
    cases.insert(c.at("case").get<std::string>());
  }
  std::set<std::string> expected;
  for (const vx::VerifyCase* c : vx::verify_suite("quick")) expected.insert(c->name);
  EXPECT_EQ(cases, expected);
  // report.md links only to plots that are there
  const std::string md = slurp(all / "report.md");
  EXPECT_NE(md.find("**PASSED**"), std::string::npos);
  std::size_t links = 0;
  for (std::size_t p = md.find("](plots/"); p != std::string::npos; p = md.find("](plots/", p + 1)) {
    const std::string file = md.substr(p + 2, md.find(')', p) - p - 2);
    EXPECT_TRUE(fs::exists(all / file)) << file;
    ++links;
  }
  EXPECT_GE(links, 10u);
}
