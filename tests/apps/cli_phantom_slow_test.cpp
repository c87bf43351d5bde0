// `voxelastic phantom folded` at its default size through `voxelastic convert`: the counts the
// folded organ exists for (issue 25): at least 40,000 elements and 200,000 nodes, three
// quarters of the nodes on the surface, 300,000 surface triangles. Slow (a 214^3 phantom and
// its model and iso-surface): ctest label `slow`.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "support/run_binary.h"

namespace fs = std::filesystem;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "voxelastic" / "voxelastic";

TEST(CliPhantomSlow, FoldedAtItsDefaultSizeMeetsTheCounts) {
  const fs::path dir = fs::temp_directory_path() / ("vx_cli_phantom_slow_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const auto run = [&](const std::string& args) { return vx::testing::run_binary(kBinary, args, dir, dir); };
  auto r = run("phantom folded -o f.nii.gz --size 214");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto t0 = std::chrono::steady_clock::now();
  r = run("convert f.nii.gz -o m.vtu --stats m.json --surface m.vtp --largest-component");
  ASSERT_EQ(r.code, 0) << r.err;
  const double convert_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::ifstream in(dir / "m.json");
  const nlohmann::json stats = nlohmann::json::parse(in);
  const auto elements = stats.at("elements").get<std::int64_t>(), nodes = stats.at("nodes").get<std::int64_t>();
  const auto surface = stats.at("surface_nodes").get<std::int64_t>();
  const auto triangles = stats.at("surface").at("triangles").get<std::int64_t>();
  std::printf("folded 214: %lld elements, %lld nodes, %lld on the surface (%.1f %%), %lld triangles; convert %.1f s\n",
              (long long)elements, (long long)nodes, (long long)surface, 100.0 * double(surface) / double(nodes),
              (long long)triangles, convert_s);
  EXPECT_GE(elements, 40000);
  EXPECT_GE(nodes, 200000);
  EXPECT_GE(double(surface) / double(nodes), 0.75);
  EXPECT_GE(triangles, 300000);
  // one piece: the largest component is all of it
  EXPECT_EQ(stats.at("prepare").at("components").get<int>(), 1) << stats.at("prepare").dump();
  EXPECT_EQ(stats.at("prepare").at("removed_voxels").get<std::int64_t>(), 0);
  fs::remove_all(dir);
}

}  // namespace
