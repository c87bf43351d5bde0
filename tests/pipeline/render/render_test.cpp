#include "render/render.h"

#include <gtest/gtest.h>
#include <unistd.h>
#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPNGReader.h>

#include <array>
#include <cstdlib>
#include <filesystem>
#include <set>

#include "base/error.h"
#include "model/gradational_builder.h"
#include "model/voxel_shapes.h"
#include "support/builder_checks.h"
#include "support/model_test_models.h"

using namespace vx;
namespace fs = std::filesystem;

namespace {

class Render : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_render_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    // VX_KEEP_PNG=folder keeps the pictures for a look
    if (const char* keep = std::getenv("VX_KEEP_PNG"))
      for (const auto& f : fs::directory_iterator(dir_)) fs::copy_file(f.path(), fs::path(keep) / f.path().filename(), fs::copy_options::overwrite_existing);
    fs::remove_all(dir_);
  }
  fs::path dir_;
};

struct Picture {
  int width{0}, height{0}, components{0};
  std::vector<std::array<int, 3>> rgb;  ///< row 0 at the bottom (VTK order)
  [[nodiscard]] const std::array<int, 3>& at(int x, int y) const { return rgb[std::size_t(y * width + x)]; }
};

Picture read_png(const fs::path& p) {
  vtkNew<vtkPNGReader> reader;
  reader->SetFileName(p.c_str());
  reader->Update();
  vtkImageData* img = reader->GetOutput();
  Picture pic;
  int dims[3];
  img->GetDimensions(dims);
  pic.width = dims[0];
  pic.height = dims[1];
  pic.components = img->GetNumberOfScalarComponents();
  for (int y = 0; y < pic.height; ++y)
    for (int x = 0; x < pic.width; ++x) {
      std::array<int, 3> c{};
      for (int k = 0; k < 3; ++k) c[std::size_t(k)] = int(img->GetScalarComponentAsDouble(x, y, 0, k));
      pic.rgb.push_back(c);
    }
  return pic;
}

// the renderer's level colours (ColorBrewer Set2)
constexpr int kLevel[3][3] = {{102, 194, 165}, {252, 141, 98}, {141, 160, 203}};

/// Pixels of the scene part of the picture (left 74%, below the title band) that are lit
/// versions of level L's colour: saturated, and nearest to that colour's direction in RGB.
std::array<int, 3> level_pixels(const Picture& pic) {
  std::array<int, 3> count{};
  for (int y = 0; y < int(pic.height * 0.85); ++y)
    for (int x = int(pic.width * 0.15); x < int(pic.width * 0.72); ++x) {  // skip the axes corner
      const auto& c = pic.at(x, y);
      const int lo = std::min({c[0], c[1], c[2]}), hi = std::max({c[0], c[1], c[2]});
      if (hi - lo < 40) continue;  // grey: background, edges, text
      int best = -1;
      double best_cos = 0.995;
      for (int l = 0; l < 3; ++l) {
        const Eigen::Vector3d a(c[0], c[1], c[2]), b(kLevel[l][0], kLevel[l][1], kLevel[l][2]);
        const double cs = a.dot(b) / (a.norm() * b.norm());
        if (cs > best_cos) best_cos = cs, best = l;
      }
      if (best >= 0) ++count[std::size_t(best)];
    }
  return count;
}

Model sphere_model() {
  return build_model(vx::ball_grid(28, 12.6));
}

}  // namespace

TEST_F(Render, WithoutDisplayFailsClearly) {
  if (display_available()) GTEST_SKIP() << "an X display is available (this checks the error without one)";
  const Model m = sphere_model();
  try {
    render_model_png(m, dir_ / "m.png");
    FAIL() << "rendered without a display";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("xvfb-run"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(fs::is_empty(dir_));
}

TEST_F(Render, BadArgumentsFailBeforeRendering) {
  const Model m = sphere_model();
  EXPECT_THROW(render_model_png(m, dir_ / "m.jpg"), Error);
  EXPECT_THROW(render_model_png(m, dir_ / "missing" / "m.png"), Error);
  RenderSettings tiny;
  tiny.width = 10;
  EXPECT_THROW(render_model_png(m, dir_ / "m.png", tiny), Error);
  EXPECT_THROW(render_model_png(Model{}, dir_ / "m.png"), Error);
  EXPECT_TRUE(fs::is_empty(dir_));
}

TEST_F(Render, SphereCutawayShowsInnerLevels) {
  if (!display_available()) GTEST_SKIP() << "no X display (run under xvfb-run)";
  const Model m = sphere_model();
  ASSERT_GE(m.num_levels(), 3);
  RenderSettings s;
  s.title = "sphere phantom, radius 12.6 mm";
  const fs::path cut = dir_ / "sphere_cutaway.png";
  render_model_png(m, cut, s);
  s.cutaway = false;
  const fs::path whole = dir_ / "sphere_whole.png";
  render_model_png(m, whole, s);
  // nothing left over besides the two pictures
  std::set<std::string> names;
  for (const auto& f : fs::directory_iterator(dir_)) names.insert(f.path().filename().string());
  EXPECT_EQ(names, (std::set<std::string>{"sphere_cutaway.png", "sphere_whole.png"}));

  const Picture a = read_png(cut), b = read_png(whole);
  EXPECT_EQ(a.width, 1200);
  EXPECT_EQ(a.height, 900);
  EXPECT_GE(a.components, 3);
  // not blank: many colours
  std::set<int> colours;
  for (const auto& c : a.rgb) colours.insert(c[0] << 16 | c[1] << 8 | c[2]);
  EXPECT_GT(colours.size(), 50u);
  // the legend swatches carry the exact level colours
  for (int l = 0; l < 3; ++l) {
    int exact = 0;
    for (const auto& c : a.rgb) exact += c[0] == kLevel[l][0] && c[1] == kLevel[l][1] && c[2] == kLevel[l][2];
    EXPECT_GT(exact, 100) << "legend swatch of level " << l;
  }
  // the model: the whole sphere shows only its level-0 shell; the cutaway opens the inner levels
  const auto in_cut = level_pixels(a), in_whole = level_pixels(b);
  const int scene_px = int(a.width * 0.57 * a.height * 0.85);
  EXPECT_GT(in_whole[0], scene_px / 10) << "level-0 shell";
  EXPECT_LT(in_whole[1] + in_whole[2], in_whole[0] / 100) << "inner levels hidden without the cutaway";
  EXPECT_GT(in_cut[1], scene_px / 200) << "level 1 seen in the cutaway";
  EXPECT_GT(in_cut[2], scene_px / 400) << "level 2 seen in the cutaway";
}

TEST_F(Render, SliceModelIsDrawnFaceOnWithEveryLevel) {
  // a 2D (slice) model: the slice face on, every level's elements in its colour, their areas in
  // proportion (the polygons are drawn as VTK fans from their first point, which the builder
  // puts where every part of an L-shaped element is seen from)
  if (!display_available()) GTEST_SKIP() << "no X display (run under xvfb-run)";
  GridGeometry g;
  g.dims = {48, 48, 1};
  g.spacing_mm = {0.5, 0.5, 2.0};
  VoxelGrid grid(g);
  for (int j = 0; j < 48; ++j)
    for (int i = 0; i < 48; ++i) grid.set(i, j, 0, (i - 23.5) * (i - 23.5) + (j - 23.5) * (j - 23.5) < 20.0 * 20.0);
  BuildSettings b;
  b.dimensions = 2;
  const Model m = build_model(grid, b);
  ASSERT_GE(m.num_levels(), 3);
  RenderSettings s;
  const fs::path p = dir_ / "slice.png";
  render_model_png(m, p, s);
  const Picture pic = read_png(p);
  const auto px = level_pixels(pic);
  // drawn area per level against the model's: each level's share of the picture's tissue pixels
  // within a few % of its share of the tissue area
  std::vector<double> area(std::size_t(m.num_levels()), 0.0);
  double total = 0;
  for (int e = 0; e < m.num_elements(); ++e) {
    const int l = m.element_level[std::size_t(e)];
    area[std::size_t(l)] += m.element_volume_mm3[std::size_t(e)];
    if (l < 3) total += m.element_volume_mm3[std::size_t(e)];  // level_pixels tells levels 0 to 2 apart
  }
  double drawn = 0;
  for (int l = 0; l < 3; ++l) drawn += px[std::size_t(l)];
  ASSERT_GT(drawn, 0);
  for (int l = 0; l < 3; ++l)
    EXPECT_NEAR(px[std::size_t(l)] / drawn, area[std::size_t(l)] / total, 0.06) << "level " << l;  // edges darken small elements more
}

TEST_F(Render, SmallHandModel) {
  if (!display_available()) GTEST_SKIP() << "no X display (run under xvfb-run)";
  const Model m = vx::testing::make_hand_model({{{0, 0, 0}, 1, 1, 0}, {{1, 0, 0}, 1, 1, 0}}, vx::testing::oblique_grid({2, 1, 1}),
                                               Layout::voxel);
  RenderSettings s;
  s.width = 640;
  s.height = 480;
  const fs::path p = dir_ / "two_voxels.png";
  render_model_png(m, p, s);
  const Picture pic = read_png(p);
  EXPECT_EQ(pic.width, 640);
  EXPECT_EQ(pic.height, 480);
  EXPECT_GT(level_pixels(pic)[0], 640 * 480 / 50);
}
