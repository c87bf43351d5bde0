#include "verify/surface_accuracy.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "base/error.h"

namespace vx {

std::string SurfaceAccuracy::summary() const {
  std::string s = fmt::format("mean {:.3f} mm ({:.3f} vox), max {:.3f} mm ({:.3f} vox), bias {:+.3f} mm, volume {:+.2f} %",
                              mean_distance_mm, mean_distance_voxels, max_distance_mm, max_distance_voxels,
                              mean_signed_distance_mm, volume_error_percent);
  if (mean_normal_error_deg >= 0) s += fmt::format(", normals {:.1f} deg (max {:.1f})", mean_normal_error_deg, max_normal_error_deg);
  return s;
}

SurfaceAccuracy measure_surface_accuracy(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles,
                                         const PhantomShape& shape, double voxel_mm, const Eigen::Matrix3Xd* normals) {
  if (!(voxel_mm > 0)) throw Error("surface accuracy: the voxel size must be positive");
  SurfaceAccuracy a;
  const int nv = int(vertices.cols()), nt = int(triangles.cols());
  a.vertices = nv;
  a.triangles = nt;
  a.samples = nv + nt;
  if (a.samples == 0) throw Error("surface accuracy: the mesh is empty");
  double sum = 0, sum2 = 0, sum_signed = 0, worst = 0;
  const auto sample = [&](const Eigen::Vector3d& p) {
    const double d = shape.signed_distance_mm(p);
    sum += std::abs(d);
    sum2 += d * d;
    sum_signed += d;
    worst = std::max(worst, std::abs(d));
  };
  // distance at vertices and triangle centres
  for (int v = 0; v < nv; ++v) sample(vertices.col(v));
  for (int t = 0; t < nt; ++t)
    sample((vertices.col(triangles(0, t)) + vertices.col(triangles(1, t)) + vertices.col(triangles(2, t))) / 3.0);
  const double n = double(a.samples);
  a.mean_distance_mm = sum / n;
  a.rms_distance_mm = std::sqrt(sum2 / n);
  a.mean_signed_distance_mm = sum_signed / n;
  a.max_distance_mm = worst;
  a.mean_distance_voxels = a.mean_distance_mm / voxel_mm;
  a.max_distance_voxels = a.max_distance_mm / voxel_mm;
  // volume by the divergence theorem
  a.volume_mm3 = enclosed_volume_mm3(vertices, triangles);
  a.true_volume_mm3 = shape.volume_mm3();
  a.volume_error_percent = 100.0 * (a.volume_mm3 - a.true_volume_mm3) / a.true_volume_mm3;
  // normals against the gradient of the signed distance (central differences)
  if (normals && normals->cols() == nv && nv > 0) {
    const double h = 1e-4 * voxel_mm;
    double sum_angle = 0, worst_angle = 0;
    for (int v = 0; v < nv; ++v) {
      Eigen::Vector3d g;
      for (int i = 0; i < 3; ++i) {
        const Eigen::Vector3d e = h * Eigen::Vector3d::Unit(i);
        g[i] = shape.signed_distance_mm(vertices.col(v) + e) - shape.signed_distance_mm(vertices.col(v) - e);
      }
      const double c = std::clamp(g.normalized().dot(normals->col(v)), -1.0, 1.0);
      const double angle = std::acos(c) * 180.0 / 3.14159265358979323846;
      sum_angle += angle;
      worst_angle = std::max(worst_angle, angle);
    }
    a.mean_normal_error_deg = sum_angle / nv;
    a.max_normal_error_deg = worst_angle;
  }
  return a;
}

SurfaceAccuracy measure_surface_accuracy(const EmbeddedSurface& surface, const PhantomShape& shape, double voxel_mm) {
  return measure_surface_accuracy(surface.rest_vertices, surface.triangles, shape, voxel_mm,
                                  surface.rest_normals.cols() == surface.num_vertices() ? &surface.rest_normals : nullptr);
}

}  // namespace vx
