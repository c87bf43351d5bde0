// Palpation maps on small phantoms (seconds): the grid and its points, the lesion found where it
// is, a uniform block without contrast, the same map on 1 and 2 threads, and the files.
#include "scene/palpation_map.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "base/error.h"
#include "convert/phantom.h"
#include "io/volume_io.h"
#include "support/png_stats.h"

namespace fs = std::filesystem;
using namespace vx;

namespace {

class PalpationMapTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_palpation_map_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  /// A phantom written to a volume file and prepared as palpate-map prepares it.
  PreparedScene prepare(const PhantomSettings& s, const std::string& file = "phantom.vti") {
    write_volume(make_phantom(s), dir_ / file);
    return prepare_scene(palpation_scene(dir_ / file, PalpationSceneOptions{}));
  }

  fs::path dir_;
};

/// block-lesion 32: the block is 24 x 18 x 12 mm (half 12, 9, 6) centred at the origin.
PhantomSettings lesion_phantom(const Eigen::Vector3d& centre, double radius) {
  PhantomSettings s;
  s.name = "block-lesion";
  s.size = 32;
  s.lesion_center_mm = centre;
  s.lesion_radius_mm = radius;
  return s;
}

PalpationMapSettings quick(double spacing = 2.0) {
  PalpationMapSettings m;
  m.spacing_mm = spacing;
  m.threads = 2;
  return m;
}

TEST_F(PalpationMapTest, PointsLieOnTheTopWhereTheWholeBallIsOverTissue) {
  PhantomSettings s;
  s.name = "block";
  s.size = 32;
  const PreparedScene p = prepare(s);
  PalpationMapSettings m = quick(2.0);
  m.hold_s = m.average_s = 0.02;  // the points are what this test looks at
  m.depth_mm = 0.5;
  const PalpationMap map = palpation_map(p, m);
  // the block's top spans [-12, 12] x [-9, 9] at z = 6: points at least 4 mm in from every edge
  ASSERT_FALSE(map.points.empty());
  int expected = 0;
  for (int j = 0; j < map.grid_v; ++j)
    for (int i = 0; i < map.grid_u; ++i) {
      const double u = map.u0_mm + 2.0 * i, v = map.v0_mm + 2.0 * j;
      expected += std::abs(u) <= 8.0 + 1e-9 && std::abs(v) <= 5.0 + 1e-9;
    }
  EXPECT_EQ(int(map.points.size()), expected);
  // the grid is centred on the top: 13 x 10 points 2 mm apart over 24 x 18 mm
  EXPECT_EQ(map.grid_u, 13);
  EXPECT_EQ(map.grid_v, 10);
  EXPECT_NEAR(map.u0_mm, -12.0, 1e-9);
  EXPECT_NEAR(map.v0_mm, -9.0, 1e-9);
  for (const PalpationPoint& q : map.points) {
    EXPECT_NEAR(q.surface_mm.z(), 6.0, 1e-9);
    EXPECT_LE(std::abs(q.surface_mm.x()), 8.0 + 1e-9);
    EXPECT_LE(std::abs(q.surface_mm.y()), 5.0 + 1e-9);
    EXPECT_TRUE(q.failure.empty()) << q.failure;
    EXPECT_GT(q.force_n, 0.0);
  }
  EXPECT_EQ(map.normal_axis, 2);
  EXPECT_EQ(map.outward, 1.0);
}

TEST_F(PalpationMapTest, FindsTheLesionUnderTheSurface) {
  // a 4 mm lesion (10x stiffer) centred 1 mm under the middle's height, off-centre in x and y:
  // its top 1 mm under the 6 mm top
  const Eigen::Vector3d truth(3.0, -2.0, 1.0);
  const PreparedScene p = prepare(lesion_phantom(truth, 4.0));
  const PalpationMap map = palpation_map(p, quick(2.0));
  const PalpationSummary s = summarize_palpation_map(map);
  EXPECT_EQ(s.failed, 0);
  const double error = (s.lesion_estimate_mm.head<2>() - truth.head<2>()).norm();
  std::printf(
      "lesion estimate (%.2f, %.2f, %.2f) mm, in-plane error %.2f mm; contrast %.3f; background %.4g, peak "
      "%.4g N/mm; %d of %d points above threshold; %.2f s on %d threads\n",
      s.lesion_estimate_mm.x(), s.lesion_estimate_mm.y(), s.lesion_estimate_mm.z(), error, s.contrast,
      s.background_n_mm, s.peak_n_mm, s.points_above, s.points, map.wall_s, map.threads);
  EXPECT_LT(error, 2.0);
  EXPECT_NEAR(s.lesion_estimate_mm.z(), 6.0, 1e-9);  // on the top
  EXPECT_GT(s.contrast, 1.5);
  EXPECT_GT(s.extent_u_mm, 0.0);
  // the stiffest point is within one spacing (and the diagonal) of the lesion's axis
  const auto stiffest = std::max_element(map.points.begin(), map.points.end(), [](const auto& a, const auto& b) {
    return a.stiffness_n_mm < b.stiffness_n_mm;
  });
  EXPECT_LT((stiffest->surface_mm.head<2>() - truth.head<2>()).norm(), 2.0 * std::sqrt(2.0) + 1e-9);
}

TEST_F(PalpationMapTest, UniformBlockHasNoContrast) {
  PhantomSettings s;
  s.name = "block";
  s.size = 32;
  const PalpationMap map = palpation_map(prepare(s), quick(2.0));
  const PalpationSummary sum = summarize_palpation_map(map);
  std::printf("uniform block: contrast %.3f, stiffness %.4g to %.4g N/mm\n", sum.contrast, sum.background_n_mm,
              sum.peak_n_mm);
  EXPECT_EQ(sum.failed, 0);
  EXPECT_GT(sum.contrast, 1.0 - 1e-12);  // peak over a median: never below 1
  EXPECT_LT(sum.contrast, 1.15);
  // symmetric block, symmetric grid: the estimate (wherever the edges leave the stiffest
  // points) stays at the centre
  EXPECT_LT(sum.lesion_estimate_mm.head<2>().norm(), 0.5);
}

TEST_F(PalpationMapTest, TheSameMapOnOneAndTwoThreads) {
  const PreparedScene p = prepare(lesion_phantom(Eigen::Vector3d(3.0, -2.0, 1.0), 4.0));
  PalpationMapSettings m = quick(4.0);
  m.threads = 1;
  const PalpationMap one = palpation_map(p, m);
  m.threads = 2;
  const PalpationMap two = palpation_map(p, m);
  ASSERT_EQ(one.points.size(), two.points.size());
  EXPECT_EQ(two.threads, 2);
  // each press starts from rest, so neither the order nor the thread matters: equal to round-off
  // (the two runs differed by up to 2.4e-16 N at times, not always)
  for (std::size_t k = 0; k < one.points.size(); ++k)
    EXPECT_NEAR(one.points[k].force_n, two.points[k].force_n, 1e-12 * std::abs(one.points[k].force_n)) << k;
}

TEST_F(PalpationMapTest, OtherFacesAndBadSettings) {
  PhantomSettings s;
  s.name = "block";
  s.size = 32;
  write_volume(make_phantom(s), dir_ / "b.vti");
  PalpationSceneOptions so;
  so.face = BoxFace::x_min;  // held at x_max, pressed from -x along +x
  PalpationMapSettings m = quick(3.0);
  m.face = BoxFace::x_min;
  m.hold_s = m.average_s = 0.02;
  const PalpationMap map = palpation_map(prepare_scene(palpation_scene(dir_ / "b.vti", so)), m);
  ASSERT_FALSE(map.points.empty());
  EXPECT_EQ(map.normal_axis, 0);
  EXPECT_EQ(map.outward, -1.0);
  for (const PalpationPoint& q : map.points) {
    EXPECT_NEAR(q.surface_mm.x(), -12.0, 1e-9);
    EXPECT_GT(q.force_n, 0.0);
  }
  EXPECT_EQ(parse_face("+z"), BoxFace::z_max);
  EXPECT_EQ(parse_face("-y"), BoxFace::y_min);
  EXPECT_EQ(parse_face("x_max"), BoxFace::x_max);
  EXPECT_THROW((void)parse_face("up"), Error);
  PalpationMapSettings bad;
  bad.depth_mm = 5.0;  // deeper than the ball's radius
  EXPECT_NE(bad.validate(), "");
  bad = {};
  bad.spacing_mm = 0;
  EXPECT_NE(bad.validate(), "");
  EXPECT_EQ(PalpationMapSettings{}.validate(), "");
  EXPECT_THROW((void)palpation_scene(dir_ / "missing.vti", so), Error);
}

TEST_F(PalpationMapTest, WritesItsFiles) {
  const PreparedScene p = prepare(lesion_phantom(Eigen::Vector3d(3.0, -2.0, 1.0), 4.0));
  PalpationMapSettings m = quick(4.0);
  const PalpationMap map = palpation_map(p, m);
  const PalpationSummary s = summarize_palpation_map(map);
  write_palpation_map(map, s, dir_, {{"input", "test"}}, true);
  std::ifstream csv(dir_ / "map.csv");
  std::string line;
  std::getline(csv, line);
  EXPECT_EQ(line, "x_mm,y_mm,z_mm,force_n,stiffness_n_mm");
  int rows = 0;
  while (std::getline(csv, line)) ++rows;
  EXPECT_EQ(rows, int(map.points.size()));
  std::ifstream in(dir_ / "summary.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j.at("input"), "test");
  EXPECT_EQ(j.at("map").at("points"), int(map.points.size()));
  EXPECT_NEAR(j.at("contrast").get<double>(), s.contrast, 1e-12);
  EXPECT_NEAR(j.at("lesion_estimate_mm")[0].get<double>(), s.lesion_estimate_mm.x(), 1e-12);
  EXPECT_GT(fs::file_size(dir_ / "map.vtp"), 200u);
  const auto png = vx::testing::png_stats(dir_ / "map.png");
  EXPECT_EQ(png.width, 1000);
  EXPECT_GT(png.drawn, 20000);  // the object, the map, its colour bar, the text
  EXPECT_GT(png.colours, 50);
  for (const auto& f : fs::directory_iterator(dir_))  // no temporary files left
    EXPECT_EQ(f.path().filename().string().find(".tmp"), std::string::npos) << f.path();
}

}  // namespace
