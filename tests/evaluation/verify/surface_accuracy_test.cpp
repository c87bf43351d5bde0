// Accuracy of the three surfaces against the analytic phantoms (docs/model.md section 10): distance from the
// true shape (mm and voxels), enclosed-volume error and normal error, measured and pinned.
#include "verify/surface_accuracy.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <numbers>

#include "base/error.h"
#include "convert/iso_surface.h"
#include "convert/phantom.h"
#include "model/gradational_builder.h"
#include "support/surface_accuracy_table.h"
#include "support/uv_sphere.h"
#include "surface/surface.h"

using namespace vx;
using vx::testing::AccuracyRow;
using vx::testing::accuracy_table;

TEST(SurfaceAccuracy, ExactSphereMeshMeasuresZeroAtVertices) {
  // a UV sphere with vertices on the true sphere: vertex distances are 0, centres lie inside
  // by the chord sagitta, the volume is a little low, the normals (radial) nearly exact
  PhantomShape shape;
  shape.name = "sphere";
  shape.center_mm = {1, 2, 3};
  shape.half_extent_mm = Eigen::Vector3d::Constant(10.0);
  const int rings = 60, segments = 120;
  Eigen::Matrix3Xd v;
  Eigen::Matrix3Xi tris;
  vx::testing::uv_sphere(rings, segments, shape.center_mm, [](double, double) { return 10.0; }, v, tris);
  Eigen::Matrix3Xd normals = (v.colwise() - shape.center_mm).colwise().normalized();
  const SurfaceAccuracy a = measure_surface_accuracy(v, tris, shape, 0.5, &normals);
  EXPECT_EQ(a.samples, v.cols() + tris.cols());
  EXPECT_LT(a.max_distance_mm, 0.05);
  EXPECT_LT(a.mean_signed_distance_mm, 0.0);
  EXPECT_NEAR(a.mean_distance_voxels, a.mean_distance_mm / 0.5, 1e-12);
  EXPECT_LT(a.volume_error_percent, 0.0);
  EXPECT_GT(a.volume_error_percent, -0.5);
  EXPECT_LT(a.max_normal_error_deg, 1e-3);
  EXPECT_THROW((void)measure_surface_accuracy(v, tris, shape, 0.0), Error);
}

TEST(SurfaceAccuracy, TableAtSize48) {
  // pinned figures (size 48, 1 mm voxels); see surface_accuracy_table.h for the layout
  const auto rows = accuracy_table(48);
  for (const AccuracyRow& r : rows) {
    SCOPED_TRACE(r.phantom + " " + to_string(r.method));
    const SurfaceAccuracy& a = r.accuracy;
    switch (r.method) {
      case SurfaceMethod::staircase:
        // unbiased but rough: mean ~0.25 voxel, corners ~0.85 voxel off, normals ~19 deg
        EXPECT_LT(a.mean_distance_voxels, 0.30);
        EXPECT_LT(a.max_distance_voxels, 0.90);
        EXPECT_LT(std::abs(a.volume_error_percent), 3.0);
        break;
      case SurfaceMethod::paper:
        // the fills sit outside the staircase: smoother normals, an outward bias of ~0.25-0.3
        // voxel and more volume
        EXPECT_LT(a.mean_distance_voxels, 0.40);
        EXPECT_GT(a.mean_signed_distance_mm, 0.15);
        EXPECT_LT(a.max_distance_voxels, 0.90);
        EXPECT_GT(a.volume_error_percent, 0.0);
        EXPECT_LT(a.volume_error_percent, 12.0);
        break;
      case SurfaceMethod::iso:
        EXPECT_LT(a.mean_distance_voxels, 0.2);
        EXPECT_LT(a.max_distance_voxels, 0.6);
        EXPECT_LT(std::abs(a.volume_error_percent), 3.0);
        break;
      case SurfaceMethod::slice:  // a 2D model's outline: not in a volume table
        ADD_FAILURE() << "a slice surface in the volume accuracy table";
        break;
    }
  }
  // per phantom: the paper surface's normals beat the staircase's, the iso-surface beats both
  for (std::size_t i = 0; i + 2 < rows.size(); i += 3) {
    const SurfaceAccuracy &st = rows[i].accuracy, &pa = rows[i + 1].accuracy, &iso = rows[i + 2].accuracy;
    SCOPED_TRACE(rows[i].phantom);
    EXPECT_LT(pa.mean_normal_error_deg, 0.75 * st.mean_normal_error_deg);
    EXPECT_LT(iso.mean_normal_error_deg, 0.5 * pa.mean_normal_error_deg);
    EXPECT_LT(iso.mean_distance_mm, 0.6 * st.mean_distance_mm);
    EXPECT_LT(iso.mean_distance_mm, 0.6 * pa.mean_distance_mm);
  }
}
