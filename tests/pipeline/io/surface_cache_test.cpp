// The display surface cache in a folder (io/surface_cache.h): a display surface loaded from it is
// the one built and decimated, bit for bit; another grid, model or target is another key; a
// damaged file is removed and the surface built again; the folder's size limit counts its files.
#include "io/surface_cache.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "convert/decimate_surface.h"
#include "convert/iso_surface.h"
#include "io/cache_file.h"
#include "model/gradational_builder.h"

namespace vx {
namespace {
namespace fs = std::filesystem;

/// A ball of 26 voxels of 1 mm with grooves on top (a folded surface of some thousand triangles).
VoxelGrid grooved_ball() {
  GridGeometry g;
  g.dims = Eigen::Vector3i(30, 30, 30);
  g.origin_mm = Eigen::Vector3d(-14.5, -14.5, -14.5);
  VoxelGrid grid(g);
  for (int k = 0; k < 30; ++k)
    for (int j = 0; j < 30; ++j)
      for (int i = 0; i < 30; ++i) {
        const Eigen::Vector3d p(i - 14.5, j - 14.5, k - 14.5);
        if (p.norm() > 13.0) continue;
        if (p.z() > 6.0 && (i % 5) == 0) continue;  // grooves a voxel wide
        grid.set(i, j, k, 1);
      }
  return grid;
}

void expect_same_surface(const EmbeddedSurface& a, const EmbeddedSurface& b) {
  EXPECT_EQ(a.method, b.method);
  EXPECT_EQ(a.model_nodes, b.model_nodes);
  ASSERT_EQ(a.rest_vertices.cols(), b.rest_vertices.cols());
  ASSERT_EQ(a.triangles.cols(), b.triangles.cols());
  EXPECT_TRUE(a.rest_vertices == b.rest_vertices);
  EXPECT_TRUE(a.triangles == b.triangles);
  EXPECT_EQ(a.embed_offsets, b.embed_offsets);
  EXPECT_EQ(a.embed_nodes, b.embed_nodes);
  EXPECT_EQ(a.embed_weights, b.embed_weights);
  EXPECT_EQ(a.vertex_face_offsets, b.vertex_face_offsets);
  EXPECT_TRUE(a.rest_normals == b.rest_normals);
}

class SurfaceCacheTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_surface_cache_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    grid_ = grooved_ball();
    model_ = build_model(grid_);
    settings_.target_triangles = 1500;
  }
  void TearDown() override { fs::remove_all(dir_); }
  [[nodiscard]] SurfaceCache cache() const {
    SurfaceCacheSettings s;
    s.folder = dir_ / "cache";
    s.min_seconds = 0.0;
    return SurfaceCache(s);
  }
  [[nodiscard]] std::vector<fs::path> files() const {
    std::vector<fs::path> out;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(dir_ / "cache", ec)) out.push_back(e.path());
    return out;
  }
  fs::path dir_;
  VoxelGrid grid_;
  Model model_;
  DecimationSettings settings_;
};

TEST_F(SurfaceCacheTest, TheSecondStartLoadsTheBuiltAndDecimatedSurfaceBitForBit) {
  SurfaceCache c = cache();
  DecimationReport first, second;
  const EmbeddedSurface built = display_surface_of_grid(model_, grid_, SurfaceMethod::iso, settings_, &first, &c);
  EXPECT_FALSE(first.from_cache);
  ASSERT_TRUE(first.decimated) << "the grooved ball has more than " << settings_.target_triangles << " triangles";
  EXPECT_GT(first.triangles_before, 2 * settings_.target_triangles);
  EXPECT_NEAR(built.num_triangles(), settings_.target_triangles, 0.1 * settings_.target_triangles);
  EXPECT_EQ(c.counters().stored, 1);
  ASSERT_EQ(files().size(), 1u);
  EXPECT_EQ(files()[0].extension(), ".vxsurf");
  EXPECT_TRUE(is_cache_file(files()[0]));  // the folder's size limit counts it

  const EmbeddedSurface loaded = display_surface_of_grid(model_, grid_, SurfaceMethod::iso, settings_, &second, &c);
  EXPECT_TRUE(second.from_cache);
  EXPECT_EQ(c.counters().hits, 1);
  EXPECT_EQ(second.triangles_before, first.triangles_before);
  EXPECT_EQ(second.vertices_before, first.vertices_before);
  EXPECT_EQ(second.triangles_after, built.num_triangles());
  expect_same_surface(loaded, built);
  // and what the app computes without a cache is the same surface
  const EmbeddedSurface plain =
      decimate_surface(model_, make_surface(model_, grid_, nullptr, SurfaceMethod::iso), settings_);
  expect_same_surface(plain, built);
}

TEST_F(SurfaceCacheTest, AnotherGridMethodTargetOrModelIsAnotherKey) {
  SurfaceCache c = cache();
  (void)display_surface_of_grid(model_, grid_, SurfaceMethod::iso, settings_, nullptr, &c);
  ASSERT_EQ(c.counters().misses, 1);

  VoxelGrid other = grid_;  // one voxel more
  other.set(15, 15, 1, 1);
  (void)display_surface_of_grid(build_model(other), other, SurfaceMethod::iso, settings_, nullptr, &c);
  EXPECT_EQ(c.counters().misses, 2);
  (void)display_surface_of_grid(model_, grid_, SurfaceMethod::paper, settings_, nullptr, &c);
  EXPECT_EQ(c.counters().misses, 3);
  DecimationSettings fewer = settings_;
  fewer.target_triangles = 1000;
  (void)display_surface_of_grid(model_, grid_, SurfaceMethod::iso, fewer, nullptr, &c);
  EXPECT_EQ(c.counters().misses, 4);
  BuildSettings voxel_level;
  voxel_level.max_level = 0;  // the same grid, another model
  (void)display_surface_of_grid(build_model(grid_, voxel_level), grid_, SurfaceMethod::iso, settings_, nullptr, &c);
  EXPECT_EQ(c.counters().misses, 5);
  EXPECT_EQ(c.counters().hits, 0);
  EXPECT_EQ(files().size(), 5u);
}

TEST_F(SurfaceCacheTest, ADamagedFileIsRemovedAndTheSurfaceBuiltAgain) {
  SurfaceCache c = cache();
  const EmbeddedSurface built = display_surface_of_grid(model_, grid_, SurfaceMethod::iso, settings_, nullptr, &c);
  ASSERT_EQ(files().size(), 1u);
  const fs::path file = files()[0];
  {
    std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(std::streamoff(fs::file_size(file) / 2));
    const char flip = '\x5a';
    f.write(&flip, 1);
  }
  DecimationReport report;
  const EmbeddedSurface again = display_surface_of_grid(model_, grid_, SurfaceMethod::iso, settings_, &report, &c);
  EXPECT_FALSE(report.from_cache);
  EXPECT_EQ(c.counters().damaged, 1);
  expect_same_surface(again, built);
  EXPECT_EQ(c.counters().stored, 2);  // kept again, whole
  DecimationReport third;
  (void)display_surface_of_grid(model_, grid_, SurfaceMethod::iso, settings_, &third, &c);
  EXPECT_TRUE(third.from_cache);

  // a file cut short is refused by its reader
  std::ifstream in(file, std::ios::binary);
  std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ContentHash h = surface_key_hash(model_, settings_.target_triangles, settings_.feature_angle_deg);
  std::string why;
  EXPECT_FALSE(read_surface_cache_file(bytes.data(), bytes.size() / 2, SurfaceKey{h.value(), 1, 1}, &why));
  EXPECT_FALSE(why.empty());
}

TEST_F(SurfaceCacheTest, ADecimationOfAGivenSurfaceIsKeptByThatSurface) {
  SurfaceCache c = cache();
  const EmbeddedSurface full = make_surface(model_, grid_, nullptr, SurfaceMethod::iso);
  DecimationReport first, second;
  const EmbeddedSurface a = decimate_surface(model_, full, settings_, &first, &c);
  const EmbeddedSurface b = decimate_surface(model_, full, settings_, &second, &c);
  EXPECT_FALSE(first.from_cache);
  EXPECT_TRUE(second.from_cache);
  expect_same_surface(a, b);
  EmbeddedSurface moved = full;  // another surface of the same model: another key
  moved.rest_vertices.row(0).array() += 0.01;
  DecimationReport third;
  (void)decimate_surface(model_, moved, settings_, &third, &c);
  EXPECT_FALSE(third.from_cache);
}

}  // namespace
}  // namespace vx
