// `voxelastic palpate-map` through the built binary: a small lesion phantom mapped end to end
// (its files, the summary line, the lesion found), and clean failures.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "support/png_stats.h"
#include "support/run_binary.h"

namespace fs = std::filesystem;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "voxelastic" / "voxelastic";

class CliPalpateMap : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_cli_palpate_map_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  vx::testing::RunResult run(const std::string& args) const { return vx::testing::run_binary(kBinary, args, dir_, dir_); }
  fs::path dir_;
};

TEST_F(CliPalpateMap, MapsALesionPhantom) {
  // block-lesion 32: a 24 x 18 x 12 mm block; the lesion (r 4 mm) at (-3, 2), its top 1 mm under the top
  ASSERT_EQ(run("phantom block-lesion --size 32 --lesion-center-mm -3,2,1 --lesion-radius-mm 4 -o l.vti").code, 0);
  const auto r = run("palpate-map l.vti --out map --spacing-mm 3 --threads 2");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("points of the +z face (0 failed)"), std::string::npos) << r.out;
  for (const char* f : {"map.csv", "map.vtp", "summary.json"}) EXPECT_TRUE(fs::exists(dir_ / "map" / f)) << f;
  const auto png = vx::testing::png_stats(dir_ / "map" / "map.png");
  EXPECT_EQ(png.width, 1000);
  EXPECT_GT(png.drawn, 20000);
  std::ifstream in(dir_ / "map" / "summary.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j.at("input"), "l.vti");
  EXPECT_EQ(j.at("map").at("face"), "+z");
  const double ex = j.at("lesion_estimate_mm")[0].get<double>(), ey = j.at("lesion_estimate_mm")[1].get<double>();
  EXPECT_LT(std::hypot(ex + 3.0, ey - 2.0), 2.0) << j.dump();
  EXPECT_GT(j.at("contrast").get<double>(), 1.5);
}

TEST_F(CliPalpateMap, MapsAModelAndAScene) {
  // a model (.vtu: one modulus, --modulus-kpa) and a scene (its own material and lesion)
  ASSERT_EQ(run("phantom block --size 24 -o b.vti").code, 0);
  ASSERT_EQ(run("convert b.vti -o b.vtu").code, 0);
  auto r = run("palpate-map b.vtu --out m1 --spacing-mm 4 --modulus-kpa 10 --no-png");
  ASSERT_EQ(r.code, 0) << r.err;
  std::ifstream in1(dir_ / "m1" / "summary.json");
  const nlohmann::json j1 = nlohmann::json::parse(in1);
  EXPECT_EQ(j1.at("material").at("youngs_modulus_kpa"), 10.0);
  EXPECT_LT(j1.at("contrast").get<double>(), 1.15);  // uniform
  r = run("palpate-map " + (fs::path(VX_SAMPLES_DIR) / "scenes" / "palpate_lesion.json").string() +
          " --out m2 --spacing-mm 4 --no-png");
  ASSERT_EQ(r.code, 0) << r.err;
  std::ifstream in2(dir_ / "m2" / "summary.json");
  const nlohmann::json j2 = nlohmann::json::parse(in2);
  // block-lesion 48: the lesion's axis at x = 0.3 x 19 = 5.7 mm, y = 0
  EXPECT_LT(std::hypot(j2.at("lesion_estimate_mm")[0].get<double>() - 5.7, j2.at("lesion_estimate_mm")[1].get<double>()),
            2.0)
      << j2.dump();
  EXPECT_GT(j2.at("contrast").get<double>(), 2.0);
}

TEST_F(CliPalpateMap, BadInputFailsCleanly) {
  ASSERT_EQ(run("phantom block --size 24 -o b.vti").code, 0);
  // usage errors: exit 2, nothing written
  for (const std::string bad : {"--face up", "--depth-mm 5", "--spacing-mm 0", "--hounsfield 40", "--hounsfield 120:5,40:2",
                                "--modulus-kpa -1"}) {
    SCOPED_TRACE(bad);
    const auto r = run("palpate-map b.vti --out m " + bad);
    EXPECT_EQ(r.code, 2) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "m" / "summary.json"));
  }
  // bad input: exit 1 with a message
  auto r = run("palpate-map missing.vti --out m");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("does not exist"), std::string::npos) << r.err;
  std::ofstream(dir_ / "x.txt") << "hello";
  r = run("palpate-map x.txt --out m");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("not a scene"), std::string::npos) << r.err;
  // a ball wider than the block's top: no point to press
  r = run("palpate-map b.vti --out m --probe-radius-mm 12 --depth-mm 1 --no-png");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("no point of the +z face"), std::string::npos) << r.err;
}

}  // namespace
