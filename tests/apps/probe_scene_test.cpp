// The probe app's scenes: a scene file as it is (up pointing away from its support), and a model
// file opened with the palpation defaults through the same prepare_scene
// (tests/pipeline/scene/palpation_defaults_test.cpp tests the defaults themselves).
#include "probe_scene.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "convert/phantom.h"
#include "io/model_io.h"
#include "model/gradational_builder.h"
#include "scene/scene.h"

using namespace vx;
using namespace vx::probe;

// A scene held by a box selector (an organ on its stem, no gravity, no face) looks at it with
// up pointing away from its support, so that the stick's "down" presses into it.
TEST(SceneFile, UpPointsAwayFromABoxSupport) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "vx_probe_scene_up";
  std::filesystem::create_directories(dir);
  struct Case {
    std::string box;
    Eigen::Vector3d up;
  };
  // a 16-voxel sphere of 1 mm: its nodes span about -6.4 .. 6.4 mm
  const std::vector<Case> cases = {
      {R"({"min": [-3, -3, -9], "max": [3, 3, -4]})", Eigen::Vector3d(0, 0, 1)},  // held below
      {R"({"min": [4, -3, -3], "max": [9, 3, 3]})", Eigen::Vector3d(-1, 0, 0)},   // held on its +x side
  };
  for (const auto& c : cases) {
    const std::filesystem::path path = dir / "scene.json";
    {
      std::ofstream out(path);
      out << R"({"object": {"phantom": "sphere", "size": 16, "spacing_mm": 1.0},
        "material": {"youngs_modulus_kpa": 10},
        "fixed": [{"box_mm": )"
          << c.box << R"(}],
        "probes": [{"name": "ball", "shape": "sphere", "radius_mm": 2,
                    "live": {"start_mm": [0, 0, 9]}}],
        "duration_s": 1})";
    }
    DefaultSceneOptions options;
    const ProbeScene scene = load_probe_scene(path, options);
    EXPECT_FALSE(scene.simulation.fixed_nodes.empty()) << c.box;
    EXPECT_NEAR((scene.world_up - c.up).norm(), 0.0, 1e-12) << c.box << ": up " << scene.world_up.transpose();
  }
  std::filesystem::remove_all(dir);
}

// A model file opens with the palpation defaults: the capsule tool live above the tissue, the
// lower quarter held, up anterior (LPS -y), the fast configuration, and notes that say so.
TEST(ModelFile, OpensWithThePalpationDefaults) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "vx_probe_scene_model";
  std::filesystem::create_directories(dir);
  PhantomSettings s;
  s.name = "sphere";
  s.size = 16;
  const Volume v = make_phantom(s);
  VoxelGrid grid(v.geometry);
  for (std::size_t i = 0; i < v.hu.size(); ++i) grid.data()[i] = v.hu[i] > -480.0 ? 1 : 0;
  const Model model = build_model(grid);
  save_model(model, dir / "sphere.vtu");
  DefaultSceneOptions options;
  options.surface_method = SurfaceMethod::paper;
  const ProbeScene scene = load_probe_scene(dir / "sphere.vtu", options);
  DefaultSceneOptions paper = options;  // --poisson-ratio 0: the paper's model, no volume term
  paper.poisson_ratio = 0.0;
  const ProbeScene paper_scene = load_probe_scene(dir / "sphere.vtu", paper);
  std::filesystem::remove_all(dir);
  EXPECT_EQ(paper_scene.physics->material.poisson_ratio, 0.0);
  EXPECT_FALSE(paper_scene.physics->has_volume_term());
  EXPECT_EQ(scene.name, "sphere.vtu");
  EXPECT_NEAR((scene.world_up - Eigen::Vector3d(0, -1, 0)).norm(), 0.0, 1e-15);
  ASSERT_EQ(scene.simulation.probes.size(), 1u);
  EXPECT_EQ(scene.simulation.probes[0].drive, ProbeDrive::live);
  EXPECT_EQ(scene.simulation.probes[0].geometry.shape, ProbeShape::capsule);
  // held: the nodes in the lowest quarter along up (-y: the largest y)
  const double top = -model.rest_positions.row(1).minCoeff(), bottom = -model.rest_positions.row(1).maxCoeff();
  int expected = 0;
  for (int n = 0; n < model.num_nodes(); ++n)
    expected += -model.rest_positions(1, n) <= bottom + 0.25 * (top - bottom) + 1e-6;
  EXPECT_EQ(int(scene.simulation.fixed_nodes.size()), expected);
  EXPECT_EQ(scene.simulation.integrator.kind, IntegratorKind::implicit);
  EXPECT_NEAR(scene.simulation.integrator.time_step_s, 0.02, 1e-15);
  // tissue-like Poisson 0.45 by default, with the volume term (DefaultSceneOptions::poisson_ratio
  // says why)
  EXPECT_EQ(scene.physics->material.poisson_ratio, 0.45);
  EXPECT_TRUE(scene.physics->has_volume_term());
  ASSERT_TRUE(scene.device_side.device.has_value());
  EXPECT_FALSE(scene.region_check);
  ASSERT_TRUE(scene.surface);
  EXPECT_EQ(scene.surface->method, SurfaceMethod::paper);
  EXPECT_EQ(scene.simulation.surface, scene.surface);
  bool noted = false;
  for (const auto& n : scene.notes)
    noted = noted || n.find("default palpation scene: E = 10 kPa, Poisson ratio 0.45,") != std::string::npos;
  EXPECT_TRUE(noted);
  // the tool may go where the walls allow, its start included
  ASSERT_EQ(scene.probe_allowed.size(), 1u);
  EXPECT_TRUE((scene.probe_allowed[0].lo.array() <= scene.simulation.probes[0].start_mm.array()).all());
  EXPECT_TRUE((scene.probe_allowed[0].hi.array() >= scene.simulation.probes[0].start_mm.array()).all());
}
