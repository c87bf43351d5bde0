// The probe app's default scene for a volume or a model: the support holds the organ's lower part
// (not a 13-node patch), and the tool starts just above tissue it touches when pressed straight
// down, also where a hole (the torus) or a fissure (two blocks on a bridge) lies under the centre.
#include "probe_scene.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "convert/phantom.h"
#include "model/gradational_builder.h"
#include "scene/scene.h"
#include "sim/simulation.h"

using namespace vx;
using namespace vx::probe;

namespace {

VoxelGrid phantom_grid(const std::string& name, int size) {
  PhantomSettings s;
  s.name = name;
  s.size = size;
  const Volume v = make_phantom(s);
  VoxelGrid g(v.geometry);
  for (std::size_t i = 0; i < v.hu.size(); ++i) g.data()[i] = v.hu[i] > -480.0 ? 1 : 0;
  return g;
}

// two 30 mm tall blocks either side of an 8 mm wide fissure, joined by a 6 mm bridge at the
// bottom (a brain's hemispheres over the corpus callosum, seen along the fissure)
VoxelGrid fissure_grid() {
  GridGeometry g;
  g.dims = Eigen::Vector3i(44, 24, 34);
  g.spacing_mm = Eigen::Vector3d::Constant(1.0);
  VoxelGrid grid(g);
  for (int k = 2; k < 32; ++k)
    for (int j = 2; j < 22; ++j)
      for (int i = 2; i < 42; ++i)
        if (k < 8 || std::abs(i - 21.5) > 4.0) grid.set(i, j, k, 1);
  return grid;
}

struct Built {
  std::shared_ptr<const Model> model;
  std::shared_ptr<const EmbeddedSurface> surface;
};

Built build(const VoxelGrid& grid) {
  Built b;
  b.model = std::make_shared<const Model>(build_model(grid));
  b.surface = std::make_shared<const EmbeddedSurface>(make_voxel_surface(*b.model, grid, true));
  return b;
}

// how far a sphere of radius r at `start` travels straight down (against `up`) before it
// touches a model node; infinity when it never does
double travel_to_contact_mm(const Model& model, const Eigen::Vector3d& start, const Eigen::Vector3d& up, double r) {
  double travel = INFINITY;
  for (int n = 0; n < model.num_nodes(); ++n) {
    const Eigen::Vector3d d = model.rest_positions.col(n) - start;
    const double along = d.dot(up);
    const double lateral = (d - along * up).norm();
    if (lateral >= r || along > 0) continue;
    travel = std::min(travel, -along - std::sqrt(r * r - lateral * lateral));
  }
  return travel;
}

// the tool pressed straight down at 10 mm/s in the simulation the scene sets up: the most
// nodes it touched in `seconds`
int contacts_when_pressed(const ProbeScene& scene, const Eigen::Vector3d& up, double seconds) {
  Simulation sim(scene.physics, scene.simulation);
  LiveCommand down;
  down.kind = LiveCommand::Kind::velocity;
  down.value = -10.0 * up;
  sim.set_live(0, down);
  int most = 0;
  while (sim.time_s() < seconds && !sim.failed()) {
    sim.step();
    most = std::max(most, sim.probe(0).contacts);
  }
  return most;
}

}  // namespace

TEST(DefaultScene, HoldsTheLowestQuarterOfTheHeight) {
  const Built b = build(phantom_grid("sphere", 32));
  const Eigen::Vector3d up(0, 0, 1);
  const ProbeScene scene = make_default_scene(b.model, b.surface, DefaultSceneOptions{}, up, "sphere");
  const Model& m = *b.model;
  const double bottom = m.rest_positions.row(2).minCoeff(), top = m.rest_positions.row(2).maxCoeff();
  const double limit = bottom + 0.25 * (top - bottom);
  int expected = 0;
  for (int n = 0; n < m.num_nodes(); ++n) expected += m.rest_positions(2, n) <= limit + 1e-6;
  const auto& held = scene.simulation.fixed_nodes;
  ASSERT_EQ(int(held.size()), expected);
  double highest = -INFINITY;
  for (int n : held) highest = std::max(highest, m.rest_positions(2, n));
  EXPECT_LE(highest, limit + 1e-6);
  EXPECT_GE(highest, limit - 2.0);  // the band reaches up to a quarter of the height (2 mm elements)
  // a cap, not the 13-node patch at the bottom face the app held before
  EXPECT_GT(held.size(), 100u);
  EXPECT_LT(double(held.size()), 0.5 * m.num_nodes());
  // the note says what is held
  bool noted = false;
  for (const auto& n : scene.notes) noted = noted || n.find("nodes held (the lowest 25 %") != std::string::npos;
  EXPECT_TRUE(noted);
  // the fraction is an option
  DefaultSceneOptions third;
  third.held_fraction = 1.0 / 3.0;
  EXPECT_GT(make_default_scene(b.model, b.surface, third, up, "sphere").simulation.fixed_nodes.size(), held.size());
}

TEST(DefaultScene, ToolStartsAboveTheTorusRingNotItsHole) {
  const VoxelGrid grid = phantom_grid("torus", 48);
  const Built b = build(grid);
  const Eigen::Vector3d up(0, 0, 1);
  const ProbeScene scene = make_default_scene(b.model, b.surface, DefaultSceneOptions{}, up, "torus");
  const ProbeSettings& tool = scene.simulation.probes.at(0);
  const double r = tool.geometry.radius_mm;
  const Eigen::Vector3d start = tool.start_mm;
  // over the ring (major radius 0.28 x 48 = 13.4 mm, minor 5.8 mm), not over the hole
  const double from_axis = start.head<2>().norm();
  EXPECT_NEAR(from_axis, 13.4, 5.8 - r) << start.transpose();
  // pressed straight down it touches the ring at once (the clearance, 2 mm), and the centre
  // start the app used before touches nothing
  const double travel = travel_to_contact_mm(*b.model, start, up, r);
  EXPECT_LT(travel, 2.0 + 1.0) << start.transpose();
  EXPECT_GT(travel, 0.0);
  const Eigen::Vector3d centre_start(0, 0, start.z());
  EXPECT_EQ(travel_to_contact_mm(*b.model, centre_start, up, r), INFINITY);
  // the physics agrees: pressed down for 0.5 s (5 mm) the tool touches the tissue
  EXPECT_GT(contacts_when_pressed(scene, up, 0.5), 0);

  const ToolStart s = default_tool_start(*b.model, grid, up, r, 5.0, 2.0);
  EXPECT_TRUE(s.found);
  EXPECT_GE(s.tissue_below_mm, 5.0);
  EXPECT_NEAR(s.surface_mm.z(), 5.8, 1.0);  // the top of the tube
}

TEST(DefaultScene, ToolStartsOnAHemisphereNotAboveTheFissure) {
  const VoxelGrid grid = fissure_grid();
  const Built b = build(grid);
  const Eigen::Vector3d up(0, 0, 1);
  const ProbeScene scene = make_default_scene(b.model, b.surface, DefaultSceneOptions{}, up, "fissure");
  const ProbeSettings& tool = scene.simulation.probes.at(0);
  const double r = tool.geometry.radius_mm;
  ASSERT_LT(2.0 * r, 8.0);  // the fissure is wider than the tool
  const Eigen::Vector3d start = tool.start_mm;
  const Eigen::Vector3d lo = b.model->rest_positions.rowwise().minCoeff();
  const Eigen::Vector3d hi = b.model->rest_positions.rowwise().maxCoeff();
  const double fissure_x = 0.5 * (lo.x() + hi.x());
  // beside the fissure, on a block's top, its contact patch clear of the edge
  EXPECT_GT(std::abs(start.x() - fissure_x), 4.0 + 0.5 * r) << start.transpose();
  const double travel = travel_to_contact_mm(*b.model, start, up, r);
  EXPECT_GT(travel, 0.0);
  EXPECT_LT(travel, 8.0 + 1.0);  // at most the clearance (0.05 x 30 mm, at least 2 mm, at most 8 mm)
  // straight down the fissure from the same height the tool would travel to the bridge
  const double down_fissure =
      travel_to_contact_mm(*b.model, Eigen::Vector3d(fissure_x, start.y(), start.z()), up, r);
  EXPECT_GT(down_fissure, travel + 20.0);
  EXPECT_GT(contacts_when_pressed(scene, up, 1.0), 0);
}

TEST(DefaultScene, ThinTissueStillGetsAToolOverIt) {
  // a 3 mm slab: no column holds the 5 mm press depth, so the thickest does
  GridGeometry g;
  g.dims = Eigen::Vector3i(20, 20, 7);
  VoxelGrid grid(g);
  for (int k = 2; k < 5; ++k)
    for (int j = 2; j < 18; ++j)
      for (int i = 2; i < 18; ++i) grid.set(i, j, k, 1);
  const Model model = build_model(grid);
  const ToolStart s = default_tool_start(model, grid, Eigen::Vector3d(0, 0, 1), 1.5, 5.0, 2.0);
  ASSERT_TRUE(s.found);
  EXPECT_NEAR(s.tissue_below_mm, 3.0, 1e-9);
  EXPECT_NEAR(s.start_mm.z() - s.surface_mm.z(), 1.5 + 2.0, 1e-9);
}

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
      {R"({"min": [-3, -3, -9], "max": [3, 3, -4]})", Eigen::Vector3d(0, 0, 1)},   // held below
      {R"({"min": [4, -3, -3], "max": [9, 3, 3]})", Eigen::Vector3d(-1, 0, 0)},    // held on its +x side
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
