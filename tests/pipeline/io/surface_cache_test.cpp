// The display surface cache in a folder (io/surface_cache.h): a display surface loaded from it is
// the one built and decimated, bit for bit; another grid, model or target is another key; a
// damaged file is removed and the surface built again; the folder's size limit counts its files.
#include "io/surface_cache.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <map>
#include <memory>
#include <string>
#include <thread>
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

// The probe app's first start (stage_display_surface_of_grid): a preview at once, every vertex
// one of the full surface's; the decimation left to `finish` is display_surface_of_grid's
// surface bit for bit and is kept under its key, so the next start loads it, final, with nothing
// left to do. A decimation cancelled before it ends throws and keeps nothing.
// A sheet one voxel thick, 64 x 64 voxels, at k = 1 of a grid 66 x 66 x `nz`.
VoxelGrid voxel_sheet(int nz) {
  GridGeometry g;
  g.dims = Eigen::Vector3i(66, 66, nz);
  VoxelGrid sheet(g);
  for (int j = 1; j < 65; ++j)
    for (int i = 1; i < 65; ++i) sheet.set(i, j, 1, 1);
  return sheet;
}

TEST_F(SurfaceCacheTest, AStagedSurfaceShowsAPreviewThenKeepsTheSurfaceTheLoadingWouldHaveMade) {
  const EmbeddedSurface whole = display_surface_of_grid(model_, grid_, SurfaceMethod::iso, settings_, nullptr, nullptr);
  const EmbeddedSurface full = make_surface(model_, grid_, nullptr, SurfaceMethod::iso);
  auto model = std::make_shared<const Model>(model_);
  auto c = std::make_shared<SurfaceCache>([&] {
    SurfaceCacheSettings s;
    s.folder = dir_ / "cache";
    s.min_seconds = 0.0;
    return s;
  }());

  // cancelled: thrown, nothing kept
  std::atomic<bool> stop{true};
  DecimationSettings cancelled = settings_;
  cancelled.cancel = &stop;
  StagedDisplaySurface first = stage_display_surface_of_grid(model, grid_, SurfaceMethod::iso, cancelled, c);
  ASSERT_TRUE(first.finish);
  EXPECT_THROW((void)first.finish(nullptr), DecimationCancelled);
  EXPECT_TRUE(files().empty());

  // the surface is 5 times the target: a preview from the voxels on blocks of 2 (the full
  // surface not built), near the full surface, with about a quarter of its triangles
  ASSERT_GT(full.num_triangles(), 4 * settings_.target_triangles);
  StagedDisplaySurface staged = stage_display_surface_of_grid(model, grid_, SurfaceMethod::iso, settings_, c);
  ASSERT_TRUE(staged.finish) << "a first start leaves the decimation to do";
  EXPECT_TRUE(staged.report.preview);
  EXPECT_FALSE(staged.report.from_cache);
  EXPECT_EQ(staged.report.preview_blocks, 2);
  // the estimate, two triangles per tissue voxel face (7,504 against 7,500 here)
  EXPECT_NEAR(staged.report.triangles_before, full.num_triangles(), 0.02 * full.num_triangles());
  EXPECT_EQ(staged.report.triangles_after, staged.shown.num_triangles());
  EXPECT_GT(staged.report.build_s + staged.report.decimate_s + staged.report.embed_s, 0.0);
  {
    const EmbeddedSurface& coarse = staged.shown;
    EXPECT_EQ(coarse.validate(), "");
    EXPECT_EQ(coarse.model_nodes, model_.num_nodes());
    EXPECT_GT(coarse.num_triangles(), 0.15 * full.num_triangles());
    EXPECT_LT(coarse.num_triangles(), 0.4 * full.num_triangles());
    // outward, the volume kept (the block average's half level)
    const double volume = enclosed_volume_mm3(full.rest_vertices, full.triangles);
    EXPECT_NEAR(enclosed_volume_mm3(coarse.rest_vertices, coarse.triangles), volume, 0.05 * volume);
    const MeshDistance d = mesh_distance_mm(coarse.rest_vertices, coarse.triangles, full.rest_vertices, full.triangles);
    std::cout << "coarse preview: " << coarse.num_triangles() << " of " << full.num_triangles()
              << " triangles, mean distance " << d.mean_mm << " mm, largest " << d.max_mm << " mm\n";
    // the cost: grooves a voxel wide close up on blocks of 2 (the largest distance, up to their
    // 7 mm depth; measured 0.46 mm mean, 5.6 mm largest; the folded organ's 3 mm sulci: 0.58 mm
    // and 3.9 mm)
    EXPECT_LT(d.mean_mm, 0.6);
    EXPECT_LT(d.max_mm, 7.5);
  }
  EXPECT_TRUE(files().empty()) << "the preview is not kept";

  // a surface under 4 times the target: the preview clustered from the full surface, each
  // vertex a full-surface vertex with that vertex's embedding row
  {
    DecimationSettings near_target = settings_;
    near_target.target_triangles = full.num_triangles() / 3;
    const StagedDisplaySurface clustered =
        stage_display_surface_of_grid(model, grid_, SurfaceMethod::iso, near_target, nullptr);
    ASSERT_TRUE(clustered.finish);
    EXPECT_TRUE(clustered.report.preview);
    EXPECT_EQ(clustered.report.preview_blocks, 0);
    EXPECT_EQ(clustered.report.triangles_before, full.num_triangles());
    EXPECT_GT(clustered.report.build_s, 0.0);
    const EmbeddedSurface& preview = clustered.shown;
    EXPECT_EQ(preview.validate(), "");
    EXPECT_LT(preview.num_triangles(), full.num_triangles());
    const auto row = [](const EmbeddedSurface& s, int v) {
      const auto b = std::size_t(s.embed_offsets[std::size_t(v)]), e = std::size_t(s.embed_offsets[std::size_t(v) + 1]);
      return std::make_pair(std::vector<std::int32_t>(s.embed_nodes.begin() + b, s.embed_nodes.begin() + e),
                            std::vector<double>(s.embed_weights.begin() + b, s.embed_weights.begin() + e));
    };
    std::map<std::array<double, 3>, int> full_at;
    for (int w = 0; w < full.num_vertices(); ++w)
      full_at[{full.rest_vertices(0, w), full.rest_vertices(1, w), full.rest_vertices(2, w)}] = w;
    for (int v = 0; v < preview.num_vertices(); ++v) {
      const auto it =
          full_at.find({preview.rest_vertices(0, v), preview.rest_vertices(1, v), preview.rest_vertices(2, v)});
      ASSERT_NE(it, full_at.end()) << "preview vertex " << v << " is not a vertex of the full surface";
      EXPECT_EQ(row(preview, v), row(full, it->second));
    }
  }

  // the decimation, on another thread as the app runs it
  DecimationReport report;
  EmbeddedSurface decimated;
  std::thread([&] { decimated = staged.finish(&report); }).join();
  EXPECT_TRUE(report.decimated);
  EXPECT_FALSE(report.preview);
  expect_same_surface(decimated, whole);
  EXPECT_EQ(c->counters().stored, 1);
  ASSERT_EQ(files().size(), 1u);

  // the next start: the final surface from the cache, nothing left to do; the same key as
  // display_surface_of_grid's
  StagedDisplaySurface second = stage_display_surface_of_grid(model, grid_, SurfaceMethod::iso, settings_, c);
  EXPECT_FALSE(second.finish);
  EXPECT_TRUE(second.report.from_cache);
  expect_same_surface(second.shown, whole);
  DecimationReport loaded;
  (void)display_surface_of_grid(model_, grid_, SurfaceMethod::iso, settings_, &loaded, c.get());
  EXPECT_TRUE(loaded.from_cache);
  // a sheet one voxel thick: on blocks of 4 no block is half tissue, so nothing is left at the
  // half level; the preview is clustered from the full surface instead
  DecimationSettings few = settings_;
  few.target_triangles = 1000;
  const auto expect_clustered_from_full = [&](const VoxelGrid& sheet) {
    auto sheet_model = std::make_shared<const Model>(build_model(sheet));
    const StagedDisplaySurface thin =
        stage_display_surface_of_grid(sheet_model, sheet, SurfaceMethod::iso, few, nullptr);
    EXPECT_TRUE(thin.report.preview);
    EXPECT_EQ(thin.report.preview_blocks, 0);
    EXPECT_GT(thin.shown.num_triangles(), few.target_triangles / 2);
    EXPECT_EQ(thin.shown.validate(), "");
  };
  expect_clustered_from_full(voxel_sheet(3));
  // the same sheet carrying a block of 12 x 12 x 12 voxels: on blocks of 4 the block is contoured
  // (so VTK does not fail), the sheet is not, and the blocks give under a quarter of the triangles
  // they should: the threshold, not the exception, sends it to the preview clustered from the
  // full surface
  {
    VoxelGrid sheet = voxel_sheet(16);
    for (int k = 2; k < 14; ++k)
      for (int j = 40; j < 52; ++j)
        for (int i = 40; i < 52; ++i) sheet.set(i, j, k, 1);
    std::int64_t faces = 0;  // the estimate's tissue voxel faces, counted here
    for (int k = 0; k < 16; ++k)
      for (int j = 0; j < 66; ++j)
        for (int i = 0; i < 66; ++i)
          if (sheet.at(i, j, k))
            for (const auto& [di, dj, dk] : {std::array{1, 0, 0}, std::array{-1, 0, 0}, std::array{0, 1, 0},
                                             std::array{0, -1, 0}, std::array{0, 0, 1}, std::array{0, 0, -1}})
              faces += !sheet.at(i + di, j + dj, k + dk);
    const int blocks = int(std::sqrt(2.0 * double(faces) / few.target_triangles));
    ASSERT_EQ(blocks, 4);
    const TriangleMesh on_blocks = extract_coarse_iso_surface(sheet, blocks);
    EXPECT_GT(on_blocks.triangles.cols(), 0) << "the block is contoured: no exception";
    EXPECT_LT(double(on_blocks.triangles.cols()), 0.25 * 2.0 * double(faces) / (blocks * blocks));
    expect_clustered_from_full(sheet);
  }
  // a surface small enough is final at once, without a preview
  DecimationSettings big = settings_;
  big.target_triangles = full.num_triangles();
  StagedDisplaySurface small = stage_display_surface_of_grid(model, grid_, SurfaceMethod::iso, big, nullptr);
  EXPECT_FALSE(small.finish);
  EXPECT_FALSE(small.report.preview);
  EXPECT_EQ(small.shown.num_triangles(), full.num_triangles());
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
