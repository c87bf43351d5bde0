// The 2D model's surface (make_slice_surface, surface.h): the slice as a flat sheet. Its
// triangles tile exactly the tissue's area, all face the slice normal, none is degenerate, the
// sheet is oriented and open only along the outline, and its vertices follow affine motions of
// the nodes exactly.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>

#include "base/error.h"
#include "model/gradational_builder.h"
#include "surface/surface.h"

namespace vx {
namespace {

Model disk_2d(int n, Layout layout, const Eigen::Matrix3d& direction) {
  GridGeometry g;
  g.dims = {n, n, 1};
  g.spacing_mm = {0.5, 0.5, 2.0};
  g.direction = direction;
  g.origin_mm = {4.0, -2.0, 7.0};
  VoxelGrid grid(g);
  const double c = 0.5 * n, r = 0.5 * n - 0.5;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) grid.set(i, j, 0, (i + 0.5 - c) * (i + 0.5 - c) + (j + 0.5 - c) * (j + 0.5 - c) <= r * r);
  BuildSettings b;
  b.layout = layout;
  b.dimensions = 2;
  return build_model(grid, b);
}

TEST(SliceSurface, TilesTheSliceFacingItsNormalAndFollowsAffineMotion) {
  const Eigen::Matrix3d frame =
      (Eigen::AngleAxisd(0.5, Eigen::Vector3d(1, 2, 3).normalized())).toRotationMatrix();
  const Eigen::Vector3d normal = frame.col(0).cross(frame.col(1));
  for (const Layout layout : {Layout::gradational, Layout::voxel}) {
    const Model m = disk_2d(40, layout, frame);
    const EmbeddedSurface s = make_slice_surface(m);
    EXPECT_EQ(s.method, SurfaceMethod::slice);
    EXPECT_EQ(s.validate(), "");
    double area = 0;
    for (int t = 0; t < s.num_triangles(); ++t) {
      const Eigen::Vector3d a = s.rest_vertices.col(s.triangles(0, t)), b = s.rest_vertices.col(s.triangles(1, t)),
                            c = s.rest_vertices.col(s.triangles(2, t));
      const Eigen::Vector3d cr = (b - a).cross(c - a);
      EXPECT_GT(cr.dot(normal), 1e-9) << "triangle " << t << " faces the normal, not degenerate";
      area += 0.5 * cr.norm();
    }
    EXPECT_NEAR(area, double(m.covered_voxels()) * 0.25, 1e-9 * area) << to_string(layout);
    for (int v = 0; v < s.num_vertices(); ++v) EXPECT_NEAR(s.rest_normals.col(v).dot(normal), 1.0, 1e-12);
    const MeshTopology topo = mesh_topology(s.triangles, s.num_vertices());
    EXPECT_EQ(topo.misoriented_edges, 0);
    EXPECT_EQ(topo.non_manifold_edges, 0);
    EXPECT_EQ(topo.degenerate_triangles, 0);
    // the open edges are the outline: one per boundary node (a closed loop of them)
    int outline = 0;
    for (int i = 0; i < m.num_nodes(); ++i) outline += m.node_surface[std::size_t(i)] ? 1 : 0;
    EXPECT_EQ(topo.open_edges, outline) << to_string(layout);
    // an in-plane affine map of the nodes moves every vertex (apexes too) by the same map
    const auto e = frame.leftCols<2>();
    Eigen::Matrix2d a2;
    a2 << 1.2, 0.3, -0.1, 0.8;
    const Eigen::Matrix3d a = e * a2 * e.transpose() + normal * normal.transpose();
    const Eigen::Vector3d shift(1.0, -2.0, 0.5);
    const Eigen::Matrix3Xd x = (a * m.rest_positions).colwise() + shift;
    Eigen::Matrix3Xd v;
    deform_vertices(s, x, v);
    const Eigen::Matrix3Xd want = (a * s.rest_vertices).colwise() + shift;
    EXPECT_LT((v - want).cwiseAbs().maxCoeff(), 1e-10);
  }
  // a volume model has no slice surface
  GridGeometry g;
  g.dims = {4, 4, 4};
  VoxelGrid cube(g);
  for (auto& c : cube.data()) c = 1;
  EXPECT_THROW((void)make_slice_surface(build_model(cube, BuildSettings{})), Error);
}

}  // namespace
}  // namespace vx
