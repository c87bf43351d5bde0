// The probe app's VTK window: level cells of a model, and (under a display) rendering,
// the view basis the sticks follow, screenshots.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>

#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPNGReader.h>

#include "base/error.h"
#include "model/gradational_builder.h"
#include "probe_view.h"
#include "support/uv_sphere.h"
#include "surface/surface.h"

using namespace vx::probe;
namespace fs = std::filesystem;

namespace {

// a 12 x 8 x 6 block of 2 mm voxels
vx::VoxelGrid block_grid() {
  vx::GridGeometry g;
  g.dims = Eigen::Vector3i(14, 10, 8);
  g.spacing_mm = Eigen::Vector3d::Constant(2.0);
  vx::VoxelGrid grid(g);
  for (int k = 1; k < 7; ++k)
    for (int j = 1; j < 9; ++j)
      for (int i = 1; i < 13; ++i) grid.set(i, j, k, 1);
  return grid;
}

// a folded ball of about 358,000 triangles (a brain's surface is 350,000): a latitude-longitude
// sphere of radius 50 mm with two scales of bumps 2.5 and 1.5 mm high, outward
void folded_ball(Eigen::Matrix3Xd& vertices, Eigen::Matrix3Xi& triangles) {
  const int nt = 600, np = 300;  // longitudes, latitude bands
  const auto radius = [](double phi, double theta) {
    return 50.0 *
           (1.0 + 0.05 * std::sin(12 * theta) * std::sin(10 * phi) + 0.03 * std::sin(30 * theta) * std::sin(24 * phi));
  };
  vx::testing::uv_sphere(np, nt, Eigen::Vector3d::Zero(), radius, vertices, triangles);
  if (vx::enclosed_volume_mm3(vertices, triangles) < 0) triangles.row(1).swap(triangles.row(2));
}

// the mean luminance (Rec. 601, 0..255) of the tissue's pixels in a screenshot: reddish pixels
// (red above blue: the background, walls, tools and HUD are grey-blue or white) in the 3D view,
// away from its HUD (top) and legend (bottom); `pixels` counts them
double tissue_luminance(const fs::path& png, int* pixels) {
  vtkNew<vtkPNGReader> reader;
  reader->SetFileName(png.string().c_str());
  reader->Update();
  vtkImageData* image = reader->GetOutput();
  int dims[3];
  image->GetDimensions(dims);
  const int comps = image->GetNumberOfScalarComponents();
  double sum = 0.0;
  int n = 0;
  for (int y = 60; y < dims[1] - 200; ++y)  // row 0 is the bottom
    for (int x = 0; x < int(0.66 * dims[0]); ++x) {
      const auto* p = static_cast<const unsigned char*>(image->GetScalarPointer(x, y, 0));
      const int r = p[0], g = p[1], b = comps >= 3 ? p[2] : p[0];
      if (r < b + 6) continue;
      sum += 0.299 * r + 0.587 * g + 0.114 * b;
      ++n;
    }
  if (pixels) *pixels = n;
  return n ? sum / n : 0.0;
}

ViewSetup bare_setup(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles) {
  ViewSetup setup;
  setup.title = "lit";
  setup.surface_vertices = vertices;
  setup.surface_triangles = triangles;
  setup.world_up = Eigen::Vector3d(0, 0, 1);
  setup.width = 960;
  setup.height = 720;
  return setup;
}

}  // namespace

TEST(LevelCells, EveryElementIsClosedPolygonsOfItsOwnPoints) {
  const vx::VoxelGrid grid = block_grid();
  const vx::Model model = vx::build_model(grid);
  const LevelCells c = make_level_cells(model);
  ASSERT_EQ(int(c.element_offsets.size()), model.num_elements() + 1);
  ASSERT_EQ(int(c.element_polys.size()), model.num_elements() + 1);
  EXPECT_EQ(std::int64_t(c.point_node.size()), model.num_vertex_entries());
  EXPECT_EQ(c.levels, model.num_levels());
  EXPECT_EQ(int(c.level_size_mm.size()), c.levels);
  EXPECT_DOUBLE_EQ(c.level_size_mm[0], 4.0);  // level 0: 2 voxels of 2 mm
  EXPECT_EQ(c.level_voxels[0], 2);
  EXPECT_EQ(c.poly_level.size() + 1, c.poly_offsets.size());
  for (int e = 0; e < model.num_elements(); ++e) {
    // a closed cube-like element has at least 6 faces; its polygons use its own points only
    EXPECT_GE(c.element_polys[std::size_t(e) + 1] - c.element_polys[std::size_t(e)], 6);
    for (int f = c.element_polys[std::size_t(e)]; f < c.element_polys[std::size_t(e) + 1]; ++f) {
      EXPECT_EQ(c.poly_level[std::size_t(f)], model.element_level[std::size_t(e)]);
      for (int k = c.poly_offsets[std::size_t(f)]; k < c.poly_offsets[std::size_t(f) + 1]; ++k) {
        EXPECT_GE(c.poly_points[std::size_t(k)], c.element_offsets[std::size_t(e)]);
        EXPECT_LT(c.poly_points[std::size_t(k)], c.element_offsets[std::size_t(e) + 1]);
      }
    }
  }
}

TEST(LevelCells, LevelSizesAreTheModelsElementSizes) {
  // the voxel layout's elements are one voxel wide (not the 2 of a gradational level 0), and an
  // anisotropic grid's element edge is the model's (the geometric mean of the spacings)
  vx::GridGeometry g = block_grid().geometry();
  g.spacing_mm = {1.0, 2.0, 4.0};
  vx::VoxelGrid grid(g);
  grid.data() = block_grid().data();
  for (vx::Layout layout : {vx::Layout::voxel, vx::Layout::uniform, vx::Layout::gradational}) {
    vx::BuildSettings b;
    b.layout = layout;
    const vx::Model model = vx::build_model(grid, b);
    const LevelCells c = make_level_cells(model);
    ASSERT_EQ(int(c.level_voxels.size()), c.levels);
    for (int e = 0; e < model.num_elements(); ++e) {
      const auto l = std::size_t(model.element_level[std::size_t(e)]);
      EXPECT_DOUBLE_EQ(c.level_size_mm[l], model.element_size_mm[std::size_t(e)]) << to_string(layout);
      EXPECT_EQ(c.level_voxels[l], model.element_edge_voxels(e)) << to_string(layout);
    }
    EXPECT_EQ(c.level_voxels[0], layout == vx::Layout::voxel ? 1 : 2) << to_string(layout);
    EXPECT_DOUBLE_EQ(c.level_size_mm[0], c.level_voxels[0] * 2.0) << to_string(layout);  // cbrt(1 * 2 * 4) = 2
  }
}

TEST(StartViewBasis, RightUpAwayAreOrthonormal) {
  for (const Eigen::Vector3d& up : {Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(1, 1, 0)}) {
    const Eigen::Matrix3d b = start_view_basis(up);
    EXPECT_TRUE((b.transpose() * b).isApprox(Eigen::Matrix3d::Identity(), 1e-12));
    EXPECT_TRUE(b.col(1).isApprox(up.normalized()));
  }
  // z up: the viewer stands anterior (-y) and looks along +y; right is +x
  const Eigen::Matrix3d b = start_view_basis(Eigen::Vector3d(0, 0, 1));
  EXPECT_TRUE(b.col(0).isApprox(Eigen::Vector3d(1, 0, 0)));
  EXPECT_TRUE(b.col(2).isApprox(Eigen::Vector3d(0, 1, 0)));
}

TEST(ProbeView, RendersUpdatesAndWritesScreenshots) {
  if (!std::getenv("DISPLAY")) GTEST_SKIP() << "no DISPLAY (VTK 9.1 needs X11; run under xvfb-run)";
  const vx::VoxelGrid grid = block_grid();
  const vx::Model model = vx::build_model(grid);
  const vx::EmbeddedSurface surface = vx::make_voxel_surface(model, grid, true);

  ViewSetup setup;
  setup.title = "test";
  setup.surface_vertices = surface.rest_vertices;
  setup.surface_triangles = surface.triangles;
  // the elements view's cells made when it is first shown, once
  int levels_made = 0;
  setup.make_levels = [&] {
    ++levels_made;
    return std::make_shared<const LevelCells>(make_level_cells(model));
  };
  vx::ProbeGeometry tool;
  tool.shape = vx::ProbeShape::capsule;
  tool.radius_mm = 3.0;
  tool.length_mm = 20.0;
  tool.axis = Eigen::Vector3d(0, 0, 1);
  setup.probes = {tool};
  setup.probe_names = {"tool"};
  const Eigen::Vector3d top(13.0, 9.0, 18.0);
  setup.probe_start_mm = {top};
  setup.walls = true;
  setup.workspace = Box{Eigen::Vector3d(-5, -5, 2), Eigen::Vector3d(31, 23, 40)};
  setup.world_up = Eigen::Vector3d(0, 0, 1);
  setup.width = 640;
  setup.height = 400;
  KeyboardStick keyboard;
  int actions = 0;
  ProbeView view(setup, &keyboard, [&](ViewAction) { ++actions; });

  // the sticks follow the start camera
  EXPECT_TRUE(view.view_basis().isApprox(start_view_basis(setup.world_up), 1e-9));

  // a few frames with a deformed surface, the level view and the plot
  Eigen::Matrix3Xd verts = surface.rest_vertices, normals;
  vx::compute_vertex_normals(surface, verts, normals);
  EXPECT_FALSE(view.shows_levels());  // the frames need no node positions
  EXPECT_EQ(levels_made, 0) << "the elements view's cells are not made before it is shown";
  view.toggle_levels();
  EXPECT_TRUE(view.shows_levels());  // now they do
  view.toggle_levels();
  EXPECT_FALSE(view.shows_levels());
  view.toggle_levels();
  EXPECT_TRUE(view.shows_levels());
  EXPECT_EQ(levels_made, 1) << "made at the first show only";
  for (int f = 0; f < 5; ++f) {
    verts.row(2).array() -= 0.1;
    ASSERT_TRUE(view.process_events());
    view.update_geometry(verts, normals, model.rest_positions, {top - Eigen::Vector3d(0, 0, f)}, {f});
    PlotSample s;
    s.t_s = 0.01 * f;
    s.device_N[0] = s.mean_N[0] = s.raw_N[0] = 0.1f * float(f);
    view.add_plot_samples({s});
    HudInfo hud;
    hud.probes = 1;
    hud.force_N[0] = 0.1 * f;
    view.set_hud(hud);
    view.render();
  }
  EXPECT_EQ(view.frames(), 5);
  const fs::path dir = fs::temp_directory_path() / ("vx_probe_view_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  view.save_screenshot(dir / "view.png");
  EXPECT_TRUE(fs::exists(dir / "view.png"));
  EXPECT_GT(fs::file_size(dir / "view.png"), 5000u);
  {
    // the guides: the orientation marker's red x axis in the 3D view's bottom right corner, the
    // scale bar's off-white (0.96, 0.96, 0.92) in the 3D view's lower half
    vtkNew<vtkPNGReader> reader;
    reader->SetFileName((dir / "view.png").c_str());
    reader->Update();
    vtkImageData* img = reader->GetOutput();
    int dims[3];
    img->GetDimensions(dims);
    ASSERT_EQ(dims[0], 640);
    long long red = 0, bar = 0;
    const int view_w = int((1.0 - 0.32) * dims[0]);
    for (int y = 0; y < dims[1]; ++y)  // VTK rows: y = 0 at the bottom
      for (int x = 0; x < view_w; ++x) {
        const auto* p = static_cast<const unsigned char*>(img->GetScalarPointer(x, y, 0));
        if (x > view_w - 0.14 * dims[0] && y < 0.24 * dims[1] && p[0] > 180 && p[1] < 60 && p[2] < 60) ++red;
        if (y < dims[1] / 2 && p[0] > 225 && p[1] > 225 && p[2] > 210 && p[2] < p[0] - 3) ++bar;
      }
    EXPECT_GT(red, 15) << "no orientation marker";
    EXPECT_GT(bar, 40) << "no scale bar";
  }
  EXPECT_THROW(view.save_screenshot(dir / "view.jpg"), vx::Error);
  EXPECT_THROW(view.save_screenshot(dir / "missing" / "view.png"), vx::Error);
  view.reset_camera();
  view.clear_plot();
  view.render();
  fs::remove_all(dir);
  EXPECT_EQ(actions, 0);
}

// A large folded organ is drawn lit from its first frame, before the physics sends one (its
// start-up takes seconds): the view starts from the rest normals. It was drawn with zero normals
// until then, lit by the ambient term alone (mean luminance about 20 of 255, as the 350 k-triangle
// brain was). The small sample after a real frame is the reference.
TEST(ProbeView, ALargeFoldedSurfaceIsLitLikeASmallSample) {
  if (!std::getenv("DISPLAY")) GTEST_SKIP() << "no DISPLAY (VTK 9.1 needs X11; run under xvfb-run)";
  const fs::path dir = fs::temp_directory_path() / ("vx_probe_view_lit_" + std::to_string(::getpid()));
  fs::create_directories(dir);

  // the small sample, drawn after a frame with its normals
  const vx::VoxelGrid grid = block_grid();
  const vx::Model model = vx::build_model(grid);
  const vx::EmbeddedSurface small = vx::make_voxel_surface(model, grid, true);
  double small_lum = 0;
  int small_px = 0;
  {
    ProbeView view(bare_setup(small.rest_vertices, small.triangles), nullptr, nullptr);
    ASSERT_TRUE(view.process_events());
    Eigen::Matrix3Xd normals;
    vx::compute_vertex_normals(small, small.rest_vertices, normals);
    view.update_geometry(small.rest_vertices, normals, Eigen::Matrix3Xd(), {}, {});
    view.render();
    view.save_screenshot(dir / "small.png");
    small_lum = tissue_luminance(dir / "small.png", &small_px);
  }

  // the large folded ball, drawn before any frame arrived, then after one
  Eigen::Matrix3Xd vertices;
  Eigen::Matrix3Xi triangles;
  folded_ball(vertices, triangles);
  ASSERT_GT(triangles.cols(), 350000);
  double first_lum = 0, later_lum = 0;
  int first_px = 0, later_px = 0;
  {
    ProbeView view(bare_setup(vertices, triangles), nullptr, nullptr);
    ASSERT_TRUE(view.process_events());
    view.render();
    view.save_screenshot(dir / "large_first.png");
    first_lum = tissue_luminance(dir / "large_first.png", &first_px);
    const Eigen::Matrix3Xd normals = vertex_normals(vertices, triangles);
    view.update_geometry(vertices, normals, Eigen::Matrix3Xd(), {}, {});
    view.render();
    view.save_screenshot(dir / "large_later.png");
    later_lum = tissue_luminance(dir / "large_later.png", &later_px);
  }
  std::printf(
      "[ figures  ] mean tissue luminance: small sample %.1f (%d px), large first frame %.1f (%d px), large "
      "after a frame %.1f (%d px)\n",
      small_lum, small_px, first_lum, first_px, later_lum, later_px);
  ASSERT_GT(small_px, 5000);
  ASSERT_GT(first_px, 20000);
  EXPECT_GT(small_lum, 60.0);
  EXPECT_GT(first_lum, small_lum / 1.5);
  EXPECT_LT(first_lum, small_lum * 1.5);
  EXPECT_NEAR(later_lum, first_lum, 0.02 * first_lum);  // the same normals
  if (!std::getenv("VX_KEEP_SCREENSHOTS")) fs::remove_all(dir);
}
