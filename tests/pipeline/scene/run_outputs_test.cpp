// What a headless run of a scene records and writes (`voxelastic simulate`): only the outputs
// the scene asks for, a frame every pvd interval and at the last step, and summary.json.
#include "scene/run_outputs.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "scene/scene.h"

using namespace vx;
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

/// A box indented by a ball; a model series every 10 ms, no plot.
Scene indent_scene() {
  return parse_scene(json::parse(R"({
    "description": "run outputs test",
    "object": {"box_mm": {"min": [0, 0, 0], "max": [12, 12, 6]}, "voxel_mm": 1.0},
    "material": {"youngs_modulus_kpa": 10, "poisson_ratio": 0, "density_kg_m3": 1000, "damping": 0.1},
    "fixed": ["z_min"],
    "integrator": {"type": "symplectic_euler", "dt_s": 1e-4},
    "probes": [{"name": "ball", "shape": "sphere", "radius_mm": 3,
                "path": [{"t_s": 0, "position_mm": [6, 6, 9.2]}, {"t_s": 0.025, "position_mm": [6, 6, 8.2]}]}],
    "duration_s": 0.025,
    "outputs": {"forces_interval_s": 0.005, "plot": false, "pvd": {"model": true, "surface": false, "interval_s": 0.01}}
  })"),
                     ".", "test.json");
}

}  // namespace

TEST(RunOutputs, WritesWhatTheSceneAsksForAndSummarisesTheRun) {
  const Scene scene = indent_scene();
  const PreparedScene prepared = prepare_scene(scene);
  Simulation sim(prepared.physics, prepared.settings);
  const DeviceSide device(sim, prepared.device_side);
  const fs::path dir = fs::temp_directory_path() / ("vx_run_outputs_test_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::int64_t steps = std::int64_t(std::ceil(scene.duration_s / sim.dt_s() - 1e-9));
  ASSERT_EQ(steps, 250);
  RunOutputs outputs(sim, device, prepared, scene.outputs, dir, steps);
  EXPECT_EQ(outputs.frames(), 1);  // the start
  for (std::int64_t k = 1; k <= steps; ++k) {
    ASSERT_EQ(sim.step(), StepStatus::ok);
    outputs.after_step(sim, k);
  }
  outputs.finish(sim);

  // a frame at the start, every 100 steps and at the last: 0, 100, 200, 250
  EXPECT_EQ(outputs.frames(), 4);
  EXPECT_TRUE(outputs.series());
  EXPECT_EQ(outputs.written(), (std::vector<std::string>{"forces.csv", "model.pvd", "probes.pvd"}));
  EXPECT_EQ(outputs.not_requested(), (std::vector<std::string>{"forces.png", "surface.pvd"}));
  for (const char* f : {"forces.csv", "model.pvd", "probes.pvd", "model/model_000003.vtu"})
    EXPECT_TRUE(fs::exists(dir / f)) << f;
  EXPECT_FALSE(fs::exists(dir / "forces.png"));
  ASSERT_NE(outputs.forces(), nullptr);
  EXPECT_EQ(outputs.forces()->rows().size(), 6u);  // t = 0 and every 5 ms

  const json j = run_summary_json(scene, "test.json", prepared, sim, outputs, 0.5);
  EXPECT_EQ(j["description"], "run outputs test");
  EXPECT_EQ(j["steps"], 250);
  EXPECT_EQ(j["stable"], true);
  EXPECT_DOUBLE_EQ(j["realtime_factor"].get<double>(), sim.time_s() / 0.5);
  EXPECT_EQ(j["object"]["source"], "box");
  EXPECT_EQ(j["probes"][0]["name"], "ball");
  EXPECT_DOUBLE_EQ(j["max_force_n"].get<double>(), outputs.forces()->max_force_n());
  EXPECT_GT(j["max_force_n"].get<double>(), 0.0);
  EXPECT_EQ(j["work"]["output_frames"], 4);
  EXPECT_EQ(j["skipped"]["steps_without_output_frame"], 250 - 3);
  EXPECT_EQ(j["skipped"]["outputs_not_requested"], json({"forces.png", "surface.pvd"}));
  EXPECT_EQ(j["outputs"], json({"forces.csv", "model.pvd", "probes.pvd", "summary.json"}));
  EXPECT_TRUE(j["walls"].is_null());
  EXPECT_TRUE(j["device"].is_null());
  EXPECT_FALSE(j.contains("region_stiffening"));  // no regional solves, no estimate
  fs::remove_all(dir);
}

TEST(RunOutputs, TheSummaryGivesTheRegionalSolvesEstimatedError) {
  // a 64 x 64 x 128 mm column held at an 8 x 8 mm stem, regional solves within 30 mm of the ball
  // (docs/model.md section 7; scene_test.cpp checks the warning)
  const Scene scene = parse_scene(json::parse(R"({
    "object": {"box_mm": {"min": [0, 0, 0], "max": [64, 64, 128]}, "voxel_mm": 4.0},
    "material": {"youngs_modulus_kpa": 10, "poisson_ratio": 0, "density_kg_m3": 1000, "damping": 0.2},
    "fixed": [{"box_mm": {"min": [27.9, 27.9, -0.1], "max": [36.1, 36.1, 0.1]}}],
    "integrator": {"type": "implicit", "dt_s": 0.03, "iterations": 1, "region_radius_mm": 30},
    "probes": [{"name": "ball", "shape": "sphere", "radius_mm": 4,
                "path": [{"t_s": 0, "position_mm": [32, 32, 132]}, {"t_s": 0.03, "position_mm": [32, 32, 131.9]}]}],
    "duration_s": 0.03,
    "outputs": {"forces_csv": false, "plot": false}
  })"),
                                  ".", "test.json");
  const PreparedScene prepared = prepare_scene(scene);
  ASSERT_TRUE(prepared.region_stiffening.has_value());
  Simulation sim(prepared.physics, prepared.settings);
  const DeviceSide device(sim, prepared.device_side);
  const fs::path dir = fs::temp_directory_path() / ("vx_run_outputs_region_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  RunOutputs outputs(sim, device, prepared, scene.outputs, dir, 1);
  ASSERT_EQ(sim.step(), StepStatus::ok);
  outputs.after_step(sim, 1);
  outputs.finish(sim);
  const json j = run_summary_json(scene, "test.json", prepared, sim, outputs, 0.5);
  const json& r = j["region_stiffening"];
  EXPECT_EQ(r["probe"], "ball");
  EXPECT_DOUBLE_EQ(r["estimated_force_ratio"].get<double>(), prepared.region_stiffening->force_ratio);
  EXPECT_DOUBLE_EQ(r["estimated_force_error_rel"].get<double>(), prepared.region_stiffening->force_ratio - 1.0);
  EXPECT_GT(r["estimated_force_error_rel"].get<double>(), kRegionStiffeningWarnRel);
  EXPECT_EQ(r["warned"], true);
  EXPECT_GT(r["far_nodes"].get<int>(), 0);
  fs::remove_all(dir);
}
