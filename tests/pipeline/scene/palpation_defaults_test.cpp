// The palpation defaults (scene/palpation_defaults.h), built by prepare_scene as the probe app
// builds them for a volume or a model: the support holds the organ's lower part (not a 13-node
// patch), and the tool starts just above tissue it touches when pressed straight down, also
// where a hole (the torus) or a fissure (two blocks on a bridge) lies under the centre.
#include "scene/palpation_defaults.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "base/error.h"
#include "convert/phantom.h"
#include "io/model_io.h"
#include "model/gradational_builder.h"
#include "scene/scene.h"
#include "sim/simulation.h"

using namespace vx;

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
};

Built build(const VoxelGrid& grid) { return {std::make_shared<const Model>(build_model(grid))}; }

// the palpation defaults around `b`'s model (written to a model file, as the app opens one),
// built by prepare_scene
PreparedScene default_scene(const Built& b, const Eigen::Vector3d& up, double held_fraction = 0.25) {
  const std::filesystem::path path =
      std::filesystem::temp_directory_path() /
      ("vx_palpation_defaults_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) + ".vtu");
  save_model(*b.model, path);
  SceneObject object;
  object.source = ObjectSource::model;
  object.path = path;
  Material material;
  material.youngs_modulus_kpa = 10.0;
  material.damping_ratio = 0.2;
  PalpationDefaults defaults;
  defaults.up = up;
  defaults.held_fraction = held_fraction;
  PreparedScene built = prepare_scene(default_palpation_scene(object, material, defaults));
  std::filesystem::remove(path);
  return built;
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
int contacts_when_pressed(const PreparedScene& scene, const Eigen::Vector3d& up, double seconds) {
  Simulation sim(scene.physics, scene.settings);
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
  const PreparedScene scene = default_scene(b, up);
  const Model& m = *scene.model;
  ASSERT_EQ(m.num_nodes(), b.model->num_nodes());
  const double bottom = m.rest_positions.row(2).minCoeff(), top = m.rest_positions.row(2).maxCoeff();
  const double limit = bottom + 0.25 * (top - bottom);
  int expected = 0;
  for (int n = 0; n < m.num_nodes(); ++n) expected += m.rest_positions(2, n) <= limit + 1e-6;
  const auto& held = scene.settings.fixed_nodes;
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
  for (const auto& n : scene.log) noted = noted || n.find("nodes held (the lowest 25 %") != std::string::npos;
  EXPECT_TRUE(noted);
  // the fraction is an option
  EXPECT_GT(default_scene(b, up, 1.0 / 3.0).settings.fixed_nodes.size(), held.size());
  // the rest of the defaults: walls with the table at the tissue's bottom, the fast
  // configuration (20 ms implicit steps, one iteration) and the paper's device over two steps
  EXPECT_TRUE(scene.settings.workspace.enabled);
  EXPECT_NEAR(scene.settings.workspace.min_mm.z(), bottom, 1e-12);
  EXPECT_EQ(scene.settings.integrator.kind, IntegratorKind::implicit);
  EXPECT_NEAR(scene.settings.integrator.time_step_s, 0.02, 1e-15);
  EXPECT_EQ(scene.settings.integrator.max_iterations, 1);
  EXPECT_EQ(scene.settings.integrator.region_radius_mm, 0.0);
  ASSERT_TRUE(scene.device_side.device.has_value());
  EXPECT_NEAR(scene.device_side.device->update_interval_s, 0.04, 1e-15);
  EXPECT_EQ(scene.settings.probes.at(0).drive, ProbeDrive::live);
  EXPECT_EQ(scene.settings.probes.at(0).geometry.shape, ProbeShape::capsule);
  EXPECT_NEAR((scene.up - up).norm(), 0.0, 1e-15);
  EXPECT_FALSE(scene.pending_region_check);
}

TEST(DefaultScene, ToolStartsAboveTheTorusRingNotItsHole) {
  const VoxelGrid grid = phantom_grid("torus", 48);
  const Built b = build(grid);
  const Eigen::Vector3d up(0, 0, 1);
  const PreparedScene scene = default_scene(b, up);
  const ProbeSettings& tool = scene.settings.probes.at(0);
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
  const PreparedScene scene = default_scene(b, up);
  const ProbeSettings& tool = scene.settings.probes.at(0);
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
  const double down_fissure = travel_to_contact_mm(*b.model, Eigen::Vector3d(fissure_x, start.y(), start.z()), up, r);
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

TEST(DefaultScene, AMaterialOutOfRangeIsAClearError) {
  Material material;
  material.youngs_modulus_kpa = -1.0;
  try {
    (void)default_palpation_scene(SceneObject{}, material);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("material: "), std::string::npos) << e.what();
  }
}
