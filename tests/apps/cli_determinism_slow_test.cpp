// `voxelastic simulate` gives the same bits on one and two threads (issue 28) in the default
// configuration of a large model: the folded organ (at 75 voxels of 2.85 mm: the 214 phantom's
// shape in mm, 34,578 nodes, over the 20,000 that switch on implicit 30 ms steps with regional
// solves on CHOLMOD's supernodal factor), pressed and slid far enough that the region follows
// the probe. forces.csv and every model .vtu of the run (the nodes' float64 displacements,
// zlib-compressed) must be equal byte for byte. Slow (two runs of about 10-30 s): ctest label
// `slow`.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "support/run_binary.h"

namespace fs = std::filesystem;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "voxelastic" / "voxelastic";

// The shape and support of samples/organ/folded-press.json on a coarser grid; no integrator key
// (the default configuration). Rate control at 25 mm/s with an 8 % dead zone: down at about
// 6 mm/s for 0.8 s (the ball meets the gyrus after about 0.15 s), then along +x at about
// 14 mm/s for 0.7 s, 9.7 mm over the gyrus towards a sulcus: past a quarter of the 30 mm
// region, so the region moves.
constexpr const char* kScene = R"({
  "object": {"phantom": "folded", "size": 75, "spacing_mm": 2.8533333333333335, "resolution": "gradational"},
  "material": {"youngs_modulus_kpa": 10, "damping": 0.2, "density_kg_m3": 1000, "poisson_ratio": 0},
  "fixed": [{"box_mm": {"min": [-10.5, -10.5, -77], "max": [10.5, 10.5, -72]}}],
  "probes": [{
    "name": "ball", "shape": "sphere", "radius_mm": 4,
    "joystick": {
      "start_mm": [19, -2, 77.6], "mode": "rate", "speed_mm_s": 25, "dead_zone": 0.08,
      "directions": [[1, 0, 0], [0, 0, -1]],
      "input": [
        {"t_s": 0.0, "axes": [0, 0.3]}, {"t_s": 0.8, "axes": [0, 0.3]}, {"t_s": 0.81, "axes": [0, 0]},
        {"t_s": 0.9, "axes": [0, 0]}, {"t_s": 0.91, "axes": [0.6, 0]}, {"t_s": 1.6, "axes": [0.6, 0]},
        {"t_s": 1.61, "axes": [0, 0]}
      ]
    }
  }],
  "duration_s": 1.8,
  "outputs": {"forces_csv": true, "forces_interval_s": 0.03, "plot": false,
              "pvd": {"model": true, "surface": false, "interval_s": 0.6}}
})";

// The run's files, relative to its folder, sorted.
std::vector<fs::path> files_under(const fs::path& dir) {
  std::vector<fs::path> out;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file()) out.push_back(fs::relative(e.path(), dir));
  std::sort(out.begin(), out.end());
  return out;
}

TEST(CliDeterminismSlow, FoldedOrganIsBitIdenticalOnOneAndTwoThreads) {
  const fs::path dir = fs::temp_directory_path() / ("vx_cli_determinism_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream(dir / "scene.json") << kScene;
  nlohmann::json summary[2];
  for (int t = 1; t <= 2; ++t) {
    // both runs factor (no factor cache, should one be configured: neither loads the other's)
    const auto r = vx::testing::run_binary(
        kBinary, "simulate scene.json -o out" + std::to_string(t) + " --threads " + std::to_string(t), dir, dir,
        "env VOXELASTIC_FACTOR_CACHE=off");
    ASSERT_EQ(r.code, 0) << r.err;
    std::ifstream in(dir / ("out" + std::to_string(t)) / "summary.json");
    summary[t - 1] = nlohmann::json::parse(in);
    std::printf("threads %d: %s s wall, start-up %s s\n", t, summary[t - 1].at("wall_s").dump().c_str(),
                summary[t - 1].at("startup_s").dump().c_str());
  }
  // the runs are what the test is about: 1 and 2 threads, the large model's default configuration
  for (int k = 0; k < 2; ++k) {
    const auto& s = summary[k];
    EXPECT_EQ(s.at("threads").get<int>(), k + 1);
    EXPECT_EQ(s.at("status").get<std::string>(), "ok");
    EXPECT_GE(s.at("nodes").get<int>(), 20000);
    EXPECT_TRUE(s.at("configuration").at("default").get<bool>());
    EXPECT_EQ(s.at("configuration").at("integrator").get<std::string>(), "implicit");
    EXPECT_DOUBLE_EQ(s.at("configuration").at("region_radius_mm").get<double>(), 60.0);
    EXPECT_GT(s.at("skipped").at("sleeping_node_solves").get<std::int64_t>(), 0);  // the region was used
    EXPECT_GT(s.at("max_force_n").get<double>(), 0.01);                            // the ball pressed
  }
  // the probe slid more than a quarter of the region's radius (the region followed it)
  std::ifstream csv(dir / "out1" / "forces.csv");
  std::string line;
  std::getline(csv, line);
  double x_first = 0, x_last = 0;
  for (bool first = true; std::getline(csv, line); first = false) {
    std::stringstream ss(line);
    std::string cell;
    for (int c = 0; c < 3; ++c) std::getline(ss, cell, ',');
    (first ? x_first : x_last) = std::stod(cell);
  }
  EXPECT_GT(x_last - x_first, 7.5);
  // the same bits: the forces, and the nodes' displacements in every frame of the series
  const auto files1 = files_under(dir / "out1"), files2 = files_under(dir / "out2");
  EXPECT_EQ(files1, files2);
  int compared = 0, models = 0;
  for (const auto& f : files1) {
    if (f == "summary.json") continue;  // times and the thread count differ
    const std::string a = vx::testing::slurp(dir / "out1" / f), b = vx::testing::slurp(dir / "out2" / f);
    EXPECT_FALSE(a.empty()) << f;
    EXPECT_TRUE(a == b) << f << " differs between 1 and 2 threads";
    ++compared;
    if (f.extension() == ".vtu") ++models;
  }
  EXPECT_GE(models, 3);  // t = 0, 0.6, 1.2, 1.8 s
  EXPECT_GE(compared, 5);
  if (!HasFailure()) fs::remove_all(dir);
}

}  // namespace
