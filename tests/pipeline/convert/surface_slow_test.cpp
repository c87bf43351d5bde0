// Slow surface checks (ctest label "slow"): the accuracy table at size 96, and the cost of
// deforming the surfaces of a 128^3 sphere per frame (compare with a physics step).
#include <gtest/gtest.h>
#include <omp.h>

#include <chrono>
#include <ctime>
#include <cmath>

#include "convert/iso_surface.h"
#include "convert/phantom.h"
#include "model/gradational_builder.h"
#include "support/surface_accuracy_table.h"
#include "surface/surface.h"

using namespace vx;
using vx::testing::AccuracyRow;
using vx::testing::accuracy_table;

TEST(SurfaceSlow, AccuracyTableAtSize96) {
  const auto rows = accuracy_table(96);
  for (const AccuracyRow& r : rows) {
    SCOPED_TRACE(r.phantom + " " + to_string(r.method));
    const SurfaceAccuracy& a = r.accuracy;
    switch (r.method) {
      case SurfaceMethod::staircase:
        EXPECT_LT(a.mean_distance_voxels, 0.30);
        EXPECT_LT(a.max_distance_voxels, 0.90);
        EXPECT_LT(std::abs(a.volume_error_percent), 1.5);
        break;
      case SurfaceMethod::paper:
        EXPECT_LT(a.mean_distance_voxels, 0.35);
        EXPECT_GT(a.mean_signed_distance_mm, 0.15);
        EXPECT_GT(a.volume_error_percent, 0.0);
        EXPECT_LT(a.volume_error_percent, 6.0);
        break;
      case SurfaceMethod::iso:
        EXPECT_LT(a.mean_distance_voxels, 0.1);
        EXPECT_LT(a.max_distance_voxels, 0.5);
        EXPECT_LT(std::abs(a.volume_error_percent), 1.0);
        break;
      case SurfaceMethod::slice:  // a 2D model's outline: not in a volume table
        ADD_FAILURE() << "a slice surface in the volume accuracy table";
        break;
    }
  }
  for (std::size_t i = 0; i + 2 < rows.size(); i += 3) {
    SCOPED_TRACE(rows[i].phantom);
    EXPECT_LT(rows[i + 1].accuracy.mean_normal_error_deg, 0.75 * rows[i].accuracy.mean_normal_error_deg);
    EXPECT_LT(rows[i + 2].accuracy.mean_distance_mm, 0.5 * rows[i].accuracy.mean_distance_mm);
  }
}

namespace {

/// CPU time of the calling thread, s (the machine may be shared: wall time overstates the cost).
double thread_cpu_s() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}

}  // namespace

TEST(SurfaceSlow, DeformCostFor128Sphere) {
  PhantomSettings ps;
  ps.name = "sphere";
  ps.size = 128;
  const Volume volume = make_phantom(ps);
  const VoxelGrid grid = vx::testing::phantom_tissue(volume);
  const Model model = build_model(grid);
  std::printf("128^3 sphere: %d nodes, %d elements\n", model.num_nodes(), model.num_elements());
  Eigen::Matrix3Xd x = model.rest_positions;
  const int threads = omp_get_max_threads();
  for (SurfaceMethod m : {SurfaceMethod::paper, SurfaceMethod::iso}) {
    const auto t0 = std::chrono::steady_clock::now();
    const EmbeddedSurface s = make_surface(model, grid, nullptr, m);
    const double build_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("%-5s surface: %d vertices, %d triangles, %.2f weights/vertex, built in %.2f s\n", to_string(m),
                s.num_vertices(), s.num_triangles(), double(s.num_embed_entries()) / s.num_vertices(), build_s);
    SurfaceFrame frame;
    deform(s, x, frame);  // sizes the outputs once
    for (int t : {1, threads}) {
      omp_set_num_threads(t);
      const int frames = 100;
      double wall_positions = 0, wall_total = 0, cpu_positions = 0, cpu_total = 0;
      for (int f = 0; f < frames; ++f) {
        // a wobbling deformation, different every frame
        x.row(2) = model.rest_positions.row(2) * (1.0 + 0.01 * std::sin(0.3 * f));
        const auto a = std::chrono::steady_clock::now();
        const double ca = thread_cpu_s();
        deform_vertices(s, x, frame.vertices);
        const auto b = std::chrono::steady_clock::now();
        const double cb = thread_cpu_s();
        compute_vertex_normals(s, frame.vertices, frame.normals, &frame.face_normals);
        const auto c = std::chrono::steady_clock::now();
        const double cc = thread_cpu_s();
        wall_positions += std::chrono::duration<double>(b - a).count();
        wall_total += std::chrono::duration<double>(c - a).count();
        cpu_positions += cb - ca;
        cpu_total += cc - ca;
      }
      std::printf("  %d thread(s): wall %.3f ms/frame (positions %.3f + normals %.3f)", t, 1e3 * wall_total / frames,
                  1e3 * wall_positions / frames, 1e3 * (wall_total - wall_positions) / frames);
      if (t == 1)
        std::printf(", CPU %.3f ms/frame (positions %.3f + normals %.3f)", 1e3 * cpu_total / frames,
                    1e3 * cpu_positions / frames, 1e3 * (cpu_total - cpu_positions) / frames);
      std::printf("\n");
      // generous (shared machines): one thread's CPU time per frame stays far under a display frame
      if (t == 1) {
        EXPECT_LT(1e3 * cpu_total / frames, 10.0);
      }
    }
    omp_set_num_threads(threads);
  }
}
