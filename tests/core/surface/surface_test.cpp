// The surface that follows the deformation (docs/model.md section 10): the staircase, the paper's surface
// with its concave steps hidden, and the embedding of any mesh in the model's nodes.
#include "surface/surface.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <string>

#include "base/error.h"
#include "model/gradational_builder.h"
#include "model/voxel_shapes.h"
#include "support/builder_checks.h"

using namespace vx;
using vx::testing::make_grid;

namespace {

/// A grid holding the listed voxels, with a margin of empty voxels around them.
VoxelGrid grid_of(const std::vector<Eigen::Vector3i>& voxels, int n = 5) {
  return make_grid({n, n, n}, [&](int i, int j, int k) {
    for (const auto& v : voxels)
      if (v == Eigen::Vector3i(i, j, k)) return true;
    return false;
  });
}

/// A random blob: a noisy sphere, for stress tests (diagonal contacts, grooves, pits).
VoxelGrid noisy_blob(int n, double r, double noise, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-noise, noise);
  const double c = 0.5 * (n - 1);
  std::vector<double> jitter(std::size_t(n) * n * n);
  for (auto& j : jitter) j = u(rng);
  return make_grid({n, n, n}, [&](int i, int j, int k) {
    const double d = std::sqrt((i - c) * (i - c) + (j - c) * (j - c) + (k - c) * (k - c));
    return d + jitter[std::size_t(i + n * (j + n * k))] <= r;
  });
}

/// Volume of the fills the report counts, in voxels: prism 1/2, cube minus corner 5/6, cube 1.
double fill_voxels(const VoxelSurfaceReport& r) {
  return 0.5 * double(r.filled_steps) + 5.0 / 6.0 * double(r.filled_corners) + double(r.filled_voxels);
}

/// Largest |a - b| over all entries.
double max_diff(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  return a.cols() == 0 ? 0.0 : (a - b).cwiseAbs().maxCoeff();
}

/// Positions of the model's nodes under x -> A x + t.
Eigen::Matrix3Xd affine_nodes(const Model& m, const Eigen::Matrix3d& A, const Eigen::Vector3d& t) {
  return (A * m.rest_positions).colwise() + t;
}

/// Every triangle's area, mm^2.
double min_triangle_area(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xi& tris) {
  double lo = INFINITY;
  for (int t = 0; t < tris.cols(); ++t)
    lo =
        std::min(lo, 0.5 * (x.col(tris(1, t)) - x.col(tris(0, t))).cross(x.col(tris(2, t)) - x.col(tris(0, t))).norm());
  return lo;
}

void expect_closed(const EmbeddedSurface& s) {
  const MeshTopology topo = mesh_topology(s.triangles, s.num_vertices());
  EXPECT_EQ(topo.open_edges, 0);
  EXPECT_EQ(topo.misoriented_edges, 0);
  EXPECT_EQ(topo.degenerate_triangles, 0);
  EXPECT_EQ(s.validate(), "");
}

}  // namespace

TEST(Surface, MethodNames) {
  for (auto m : {SurfaceMethod::staircase, SurfaceMethod::paper, SurfaceMethod::iso})
    EXPECT_EQ(parse_surface_method(to_string(m)), m);
  EXPECT_THROW((void)parse_surface_method("marching"), Error);
}

TEST(Surface, SingleVoxelStaircaseIsACube) {
  const VoxelGrid g = grid_of({{2, 2, 2}});
  const Model m = build_model(g, BuildSettings{Layout::voxel, -1, {}});
  const EmbeddedSurface s = make_voxel_surface(m, g, false);
  EXPECT_EQ(s.num_vertices(), 8);
  EXPECT_EQ(s.num_triangles(), 12);
  expect_closed(s);
  EXPECT_EQ(mesh_topology(s.triangles, s.num_vertices()).euler_characteristic, 2);
  EXPECT_NEAR(enclosed_volume_mm3(s.rest_vertices, s.triangles), 1.0, 1e-12);
  // a single convex voxel has nothing to hide
  const EmbeddedSurface p = make_voxel_surface(m, g, true);
  EXPECT_EQ(p.num_triangles(), 12);
}

TEST(Surface, ConcaveStepIsSpannedByOneFlatFace) {
  // an L of three voxels: the empty fourth voxel of the 2x2 square touches tissue on two
  // perpendicular faces and becomes a half-voxel prism
  const VoxelGrid g = grid_of({{1, 1, 2}, {2, 1, 2}, {1, 2, 2}});
  const Model m = build_model(g);
  VoxelSurfaceReport r;
  const EmbeddedSurface s = make_voxel_surface(m, g, true, &r);
  expect_closed(s);
  EXPECT_EQ(r.filled_steps, 1);
  EXPECT_EQ(r.filled_corners + r.filled_voxels + r.dropped_fills, 0);
  EXPECT_NEAR(enclosed_volume_mm3(s.rest_vertices, s.triangles), 3.5, 1e-12);
  // the step's face: a 1 x sqrt(2) rectangle with normal (1,1,0)/sqrt(2)
  int diagonal = 0;
  for (int t = 0; t < s.num_triangles(); ++t) {
    const Eigen::Vector3d a = s.rest_vertices.col(s.triangles(0, t));
    const Eigen::Vector3d n =
        (s.rest_vertices.col(s.triangles(1, t)) - a).cross(s.rest_vertices.col(s.triangles(2, t)) - a);
    if (n.normalized().isApprox(Eigen::Vector3d(1, 1, 0).normalized(), 1e-12)) ++diagonal;
  }
  EXPECT_EQ(diagonal, 2);
}

TEST(Surface, ConcaveCornerIsCutByOneTriangle) {
  // a 3x3x3 block missing one corner voxel: the notch has tissue on three perpendicular faces
  std::vector<Eigen::Vector3i> v;
  for (int k = 1; k <= 3; ++k)
    for (int j = 1; j <= 3; ++j)
      for (int i = 1; i <= 3; ++i)
        if (!(i == 3 && j == 3 && k == 3)) v.emplace_back(i, j, k);
  const VoxelGrid g = grid_of(v, 6);
  const Model m = build_model(g);
  VoxelSurfaceReport r;
  const EmbeddedSurface s = make_voxel_surface(m, g, true, &r);
  expect_closed(s);
  EXPECT_EQ(r.filled_corners, 1);
  EXPECT_EQ(r.filled_steps, 0);
  EXPECT_NEAR(enclosed_volume_mm3(s.rest_vertices, s.triangles), 26.0 + 5.0 / 6.0, 1e-12);
}

TEST(Surface, GrooveIsFilled) {
  // a 1-voxel groove in the top of a 3x3x2 block: the groove voxel has tissue on both sides and
  // below, so it is filled whole
  std::vector<Eigen::Vector3i> v;
  for (int k = 1; k <= 2; ++k)
    for (int j = 1; j <= 3; ++j)
      for (int i = 1; i <= 3; ++i)
        if (!(k == 2 && i == 2)) v.emplace_back(i, j, k);
  const VoxelGrid g = grid_of(v, 6);
  const Model m = build_model(g);
  VoxelSurfaceReport r;
  const EmbeddedSurface s = make_voxel_surface(m, g, true, &r);
  expect_closed(s);
  EXPECT_EQ(r.filled_voxels, 3);
  EXPECT_NEAR(enclosed_volume_mm3(s.rest_vertices, s.triangles), 18.0, 1e-12);
}

TEST(Surface, StaircaseAndPaperOfSphereAreClosedWithExactVolumes) {
  const VoxelGrid g = ball_grid(24, 9.3);
  const Model m = build_model(g);
  const double voxels = double(g.count());
  const EmbeddedSurface st = make_voxel_surface(m, g, false);
  expect_closed(st);
  EXPECT_EQ(mesh_topology(st.triangles, st.num_vertices()).euler_characteristic, 2);
  EXPECT_NEAR(enclosed_volume_mm3(st.rest_vertices, st.triangles), voxels, 1e-9);
  VoxelSurfaceReport r;
  const EmbeddedSurface pa = make_voxel_surface(m, g, true, &r);
  expect_closed(pa);
  EXPECT_GT(r.filled_steps, 0);
  // the surface bounds exactly the tissue plus the fills
  EXPECT_NEAR(enclosed_volume_mm3(pa.rest_vertices, pa.triangles), voxels + fill_voxels(r), 1e-9);
  EXPECT_GT(min_triangle_area(pa.rest_vertices, pa.triangles), 0.49);
  // every vertex is a surface node, embedded with weight 1 at its rest position
  for (int v = 0; v < pa.num_vertices(); ++v) {
    ASSERT_EQ(pa.embed_offsets[std::size_t(v) + 1] - pa.embed_offsets[std::size_t(v)], 1);
    const int n = pa.embed_nodes[std::size_t(pa.embed_offsets[std::size_t(v)])];
    EXPECT_EQ(m.node_surface[std::size_t(n)], 1);
    EXPECT_EQ(pa.rest_vertices.col(v), m.rest_positions.col(n));
  }
  // normals point out of the sphere
  const Eigen::Vector3d c = m.grid.index_to_lps(Eigen::Vector3d::Constant(0.5 * 23));
  for (int v = 0; v < pa.num_vertices(); ++v) EXPECT_GT(pa.rest_normals.col(v).dot(pa.rest_vertices.col(v) - c), 0.0);
}

TEST(Surface, PaperSurfaceTradesAnOutwardBiasForSmootherNormals) {
  // against the true sphere (voxel centres inside it are tissue): the staircase is unbiased
  // but its normals are axis-aligned; the paper's fills hide the concave notches, so its
  // normals are much closer to the sphere's, its deepest points are gone, and it lies outside
  // the staircase (a bias of about a quarter voxel, so a larger mean distance)
  const int n = 40;
  const double r = 15.2, c = 0.5 * (n - 1);
  const VoxelGrid g = ball_grid(n, r);
  const Model m = build_model(g);
  struct Figures {
    double mean = 0, bias = 0, deepest = 0, normal_deg = 0;
  };
  const auto measure = [&](const EmbeddedSurface& s) {
    Figures f;
    const auto signed_distance = [&](const Eigen::Vector3d& p) { return (p.array() - c).matrix().norm() - r; };
    const auto sample = [&](const Eigen::Vector3d& p) {
      const double d = signed_distance(p);
      f.mean += std::abs(d);
      f.bias += d;
      f.deepest = std::min(f.deepest, d);
    };
    for (int v = 0; v < s.num_vertices(); ++v) {
      sample(s.rest_vertices.col(v));
      const Eigen::Vector3d radial = (s.rest_vertices.col(v).array() - c).matrix().normalized();
      f.normal_deg += std::acos(std::clamp(radial.dot(s.rest_normals.col(v)), -1.0, 1.0)) * 180 / std::numbers::pi;
    }
    for (int t = 0; t < s.num_triangles(); ++t)
      sample((s.rest_vertices.col(s.triangles(0, t)) + s.rest_vertices.col(s.triangles(1, t)) +
              s.rest_vertices.col(s.triangles(2, t))) /
             3.0);
    const double samples = double(s.num_vertices() + s.num_triangles());
    f.mean /= samples;
    f.bias /= samples;
    f.normal_deg /= s.num_vertices();
    return f;
  };
  const Figures st = measure(make_voxel_surface(m, g, false)), pa = measure(make_voxel_surface(m, g, true));
  std::printf("sphere r=%.1f voxels   mean |d|  bias    deepest  normal error\n", r);
  std::printf("  staircase          %.3f   %+.3f   %+.3f   %.1f deg\n", st.mean, st.bias, st.deepest, st.normal_deg);
  std::printf("  paper              %.3f   %+.3f   %+.3f   %.1f deg\n", pa.mean, pa.bias, pa.deepest, pa.normal_deg);
  EXPECT_LT(pa.normal_deg, 0.7 * st.normal_deg);
  EXPECT_GT(pa.deepest, st.deepest + 0.1);
  EXPECT_NEAR(st.bias, 0.0, 0.1);
  EXPECT_GT(pa.bias, 0.15);
  EXPECT_LT(pa.mean, 0.35);
}

TEST(Surface, NoisyShapesGiveClosedOrientedSurfaces) {
  // noisy blobs have diagonal contacts, grooves, pits and crossing fills: the surface must
  // still bound exactly tissue plus fills, closed and consistently oriented
  for (unsigned seed = 1; seed <= 6; ++seed) {
    const VoxelGrid g = noisy_blob(20, 7.0, 1.6, seed);
    const Model m = build_model(g);
    for (bool hide : {false, true}) {
      VoxelSurfaceReport r;
      const EmbeddedSurface s = make_voxel_surface(m, g, hide, &r);
      SCOPED_TRACE("seed " + std::to_string(seed) + (hide ? " paper" : " staircase"));
      expect_closed(s);
      EXPECT_NEAR(enclosed_volume_mm3(s.rest_vertices, s.triangles), double(g.count()) + fill_voxels(r), 1e-9);
      if (hide)
        std::printf("seed %u: steps %lld corners %lld whole %lld dropped %lld\n", seed, (long long)r.filled_steps,
                    (long long)r.filled_corners, (long long)r.filled_voxels, (long long)r.dropped_fills);
    }
  }
}

TEST(Surface, TissueOnTheGridBorderIsClosed) {
  // tissue touching the grid border: the border counts as outside
  const VoxelGrid g = make_grid({6, 5, 4}, [](int i, int j, int k) { return i + j + k < 7; });
  const Model m = build_model(g);
  VoxelSurfaceReport r;
  const EmbeddedSurface s = make_voxel_surface(m, g, true, &r);
  expect_closed(s);
  EXPECT_NEAR(enclosed_volume_mm3(s.rest_vertices, s.triangles), double(g.count()) + fill_voxels(r), 1e-9);
}

TEST(Surface, MirroredAndAnisotropicGeometryKeepsTheSurfaceOutward) {
  VoxelGrid g = ball_grid(16, 6.1);
  GridGeometry geo = g.geometry();
  geo.spacing_mm = {0.7, 1.1, 2.5};
  geo.origin_mm = {-120.0, 35.0, 410.0};
  geo.direction = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix() *
                  Eigen::Vector3d(1, -1, 1).asDiagonal();  // a mirror
  VoxelGrid h(geo);
  h.data() = g.data();
  const Model m = build_model(h);
  VoxelSurfaceReport r;
  const EmbeddedSurface s = make_voxel_surface(m, h, true, &r);
  expect_closed(s);
  EXPECT_NEAR(enclosed_volume_mm3(s.rest_vertices, s.triangles),
              (double(h.count()) + fill_voxels(r)) * geo.voxel_volume_mm3(), 1e-6);
}

TEST(Surface, GridMustMatchTheModel) {
  const VoxelGrid g = ball_grid(12, 4.0);
  const Model m = build_model(g);
  EXPECT_THROW((void)make_voxel_surface(m, ball_grid(12, 3.0), true), Error);
  EXPECT_THROW((void)make_voxel_surface(m, ball_grid(14, 4.0), true), Error);
}

TEST(Surface, PaperSurfaceFollowsTheNodesExactly) {
  const VoxelGrid g = ball_grid(20, 7.4);
  const Model m = build_model(g);
  const EmbeddedSurface s = make_voxel_surface(m, g, true);
  std::mt19937 rng(3);
  std::normal_distribution<double> nd(0.0, 0.3);
  Eigen::Matrix3Xd x = m.rest_positions;
  for (Eigen::Index i = 0; i < x.size(); ++i) x.data()[i] += nd(rng);
  Eigen::Matrix3Xd v, n;
  deform(s, x, v, n);
  for (int i = 0; i < s.num_vertices(); ++i)
    EXPECT_EQ(v.col(i), x.col(s.embed_nodes[std::size_t(s.embed_offsets[std::size_t(i)])]));
}

// ---------------------------------------------------------------------------------------------
// embedding of arbitrary meshes

namespace {

/// A test mesh near the tissue boundary: the paper surface's vertices moved along their
/// normals by `offset` voxels (out for > 0), plus points inside and outside.
Eigen::Matrix3Xd probe_points(const Model& m, const EmbeddedSurface& s, double offset, int extra, unsigned seed) {
  const double h = m.grid.spacing_mm.minCoeff();
  Eigen::Matrix3Xd p(3, s.num_vertices() + extra);
  for (int v = 0; v < s.num_vertices(); ++v) p.col(v) = s.rest_vertices.col(v) + offset * h * s.rest_normals.col(v);
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> pick(0, s.num_vertices() - 1);
  std::uniform_real_distribution<double> u(-1.5, 1.0);
  for (int i = 0; i < extra; ++i) {
    const int v = pick(rng);
    p.col(s.num_vertices() + i) = s.rest_vertices.col(v) + u(rng) * h * s.rest_normals.col(v);
  }
  return p;
}

}  // namespace

TEST(SurfaceEmbedding, RestAffineAndRigidMotionAreExact) {
  for (Layout res : {Layout::gradational, Layout::uniform, Layout::voxel}) {
    SCOPED_TRACE(to_string(res));
    VoxelGrid g = ball_grid(22, 8.6);
    GridGeometry geo = g.geometry();
    geo.spacing_mm = {0.8, 0.9, 1.3};
    geo.origin_mm = {-80.0, 20.0, 300.0};
    VoxelGrid h(geo);
    h.data() = g.data();
    const Model m = build_model(h, BuildSettings{res, -1, {}});
    const EmbeddedSurface paper = make_voxel_surface(m, h, true);
    const Eigen::Matrix3Xd p = probe_points(m, paper, 0.45, 500, 7);
    const Eigen::Matrix3Xi no_triangles(3, 0);
    const EmbeddedSurface s = embed_surface(m, p, no_triangles, SurfaceMethod::iso);
    EXPECT_EQ(s.validate(), "");
    Eigen::Matrix3Xd v;
    deform_vertices(s, m.rest_positions, v);
    EXPECT_LT(max_diff(v, p), 1e-9);
    // rigid motion
    const Eigen::Matrix3d R = Eigen::AngleAxisd(0.9, Eigen::Vector3d(-1, 2, 0.5).normalized()).toRotationMatrix();
    const Eigen::Vector3d t(13.0, -4.0, 250.0);
    deform_vertices(s, affine_nodes(m, R, t), v);
    EXPECT_LT(max_diff(v, (R * p).colwise() + t), 1e-9);
    // uniform stretch about a point
    const Eigen::Vector3d c = p.rowwise().mean();
    deform_vertices(s, affine_nodes(m, 1.3 * Eigen::Matrix3d::Identity(), -0.3 * c), v);
    EXPECT_LT(max_diff(v, (1.3 * p).colwise() - 0.3 * c), 1e-9);
    // any affine map
    Eigen::Matrix3d A;
    A << 1.1, 0.2, -0.1, 0.05, 0.9, 0.3, -0.2, 0.1, 1.2;
    deform_vertices(s, affine_nodes(m, A, t), v);
    EXPECT_LT(max_diff(v, (A * p).colwise() + t), 1e-9);
  }
}

TEST(SurfaceEmbedding, IsContinuousAcrossCellsAndElements) {
  // under a random (non-affine) motion of the nodes, points close together stay close: walk
  // along lines through the boundary region in tiny steps and bound the jump per step
  const VoxelGrid g = ball_grid(26, 10.2);
  const Model m = build_model(g);
  std::mt19937 rng(11);
  std::normal_distribution<double> nd(0.0, 0.25);
  Eigen::Matrix3Xd x = m.rest_positions;
  for (Eigen::Index i = 0; i < x.size(); ++i) x.data()[i] += nd(rng);
  const Eigen::Vector3d c = m.grid.index_to_lps(Eigen::Vector3d::Constant(12.5));
  const int steps = 4000;
  const double step_mm = 1e-3;
  Eigen::Matrix3Xd p(3, steps);
  const Eigen::Vector3d dir = Eigen::Vector3d(0.31, 0.17, 0.93).normalized();
  // a chord near the surface (radius about 9.8 to 10.6 voxels), crossing many cells
  const Eigen::Vector3d side = dir.cross(Eigen::Vector3d(1, 0, 0)).normalized();
  for (int i = 0; i < steps; ++i) p.col(i) = c + 10.0 * side + (i - steps / 2) * step_mm * dir;
  const EmbeddedSurface s = embed_surface(m, p, Eigen::Matrix3Xi(3, 0), SurfaceMethod::iso);
  Eigen::Matrix3Xd v;
  deform_vertices(s, x, v);
  double worst = 0;
  for (int i = 1; i < steps; ++i) worst = std::max(worst, (v.col(i) - v.col(i - 1)).norm());
  // a Lipschitz bound: the motion gradient here is O(1), a jump would be O(0.25 mm)
  EXPECT_LT(worst, 20 * step_mm);
}

TEST(SurfaceEmbedding, FarPointsAreRejected) {
  const VoxelGrid g = ball_grid(30, 4.0);
  const Model m = build_model(g);
  Eigen::Matrix3Xd p(3, 1);
  p.col(0) = m.grid.index_to_lps(Eigen::Vector3d(1, 1, 1));  // about 13 voxels from the ball
  EXPECT_THROW((void)embed_surface(m, p, Eigen::Matrix3Xi(3, 0), SurfaceMethod::iso), Error);
  // one far point after thousands of good ones (its lattice points weighed in a later chunk,
  // on another thread): the same refusal, not a crash or a partial embedding
  const EmbeddedSurface paper = make_voxel_surface(m, g, true);
  Eigen::Matrix3Xd many = probe_points(m, paper, 0.3, 9000, 4);
  many.col(many.cols() - 1) = p.col(0);
  try {
    (void)embed_surface(m, many, Eigen::Matrix3Xi(3, 0), SurfaceMethod::iso);
    ADD_FAILURE() << "a point 13 voxels from the tissue was embedded";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("more than 8 voxels from any tissue"), std::string::npos) << e.what();
  }
}

TEST(SurfaceEmbedding, EachRowIsThePointsOwnEmbeddingOnAnyThreadCount) {
  // embed_surface weighs the lattice points all the vertices use once, in parallel chunks, then
  // each vertex from them: a vertex's row must be what embedding that vertex alone gives, bit
  // for bit, and the whole the same on one thread and on two (chunks of 4,096 points and
  // vertices: this mesh has several of each)
  const VoxelGrid g = ball_grid(40, 16.0);
  const Model m = build_model(g);
  const EmbeddedSurface paper = make_voxel_surface(m, g, true);
  const Eigen::Matrix3Xd p = probe_points(m, paper, 0.4, 12000, 9);
  ASSERT_GT(p.cols(), 3 * 4096);
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  const EmbeddedSurface one = embed_surface(m, p, Eigen::Matrix3Xi(3, 0), SurfaceMethod::iso);
  omp_set_num_threads(std::max(threads, 2));
  const EmbeddedSurface two = embed_surface(m, p, Eigen::Matrix3Xi(3, 0), SurfaceMethod::iso);
  omp_set_num_threads(threads);
  EXPECT_EQ(one.embed_offsets, two.embed_offsets);
  EXPECT_EQ(one.embed_nodes, two.embed_nodes);
  EXPECT_EQ(one.embed_weights, two.embed_weights);
  for (int v = 0; v < p.cols(); v += 97) {
    SCOPED_TRACE(v);
    const EmbeddedSurface alone = embed_surface(m, p.col(v), Eigen::Matrix3Xi(3, 0), SurfaceMethod::iso);
    const auto b = std::size_t(two.embed_offsets[std::size_t(v)]),
               e = std::size_t(two.embed_offsets[std::size_t(v) + 1]);
    ASSERT_EQ(alone.embed_offsets.back(), std::int32_t(e - b));
    for (std::size_t k = 0; k < e - b; ++k) {
      EXPECT_EQ(alone.embed_nodes[k], two.embed_nodes[b + k]);
      EXPECT_EQ(alone.embed_weights[k], two.embed_weights[b + k]);
    }
  }
}

TEST(SurfaceDeform, SameResultForAnyThreadCountAndNoReallocation) {
  const VoxelGrid g = ball_grid(40, 16.0);
  const Model m = build_model(g);
  const EmbeddedSurface paper = make_voxel_surface(m, g, true);
  const EmbeddedSurface s = embed_surface(m, probe_points(m, paper, 0.3, 0, 1), paper.triangles, SurfaceMethod::iso);
  std::mt19937 rng(5);
  std::normal_distribution<double> nd(0.0, 0.2);
  Eigen::Matrix3Xd x = m.rest_positions;
  for (Eigen::Index i = 0; i < x.size(); ++i) x.data()[i] += nd(rng);
  Eigen::Matrix3Xd v1, n1, v2, n2;
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  deform(s, x, v1, n1);
  omp_set_num_threads(std::max(threads, 2));
  deform(s, x, v2, n2);
  omp_set_num_threads(threads);
  EXPECT_EQ(v1, v2);
  EXPECT_EQ(n1, n2);
  const double* pv = v2.data();
  const double* pn = n2.data();
  deform(s, m.rest_positions, v2, n2);
  EXPECT_EQ(pv, v2.data());
  EXPECT_EQ(pn, n2.data());
  // the frame (with triangle-normal scratch) gives the same numbers, and reuses its buffers
  SurfaceFrame frame;
  deform(s, x, frame);
  EXPECT_EQ(frame.vertices, v1);
  EXPECT_EQ(frame.normals, n1);
  EXPECT_EQ(frame.face_normals.cols(), s.num_triangles());
  const double* pf = frame.face_normals.data();
  deform(s, m.rest_positions, frame);
  EXPECT_EQ(pf, frame.face_normals.data());
  EXPECT_LT(max_diff(frame.normals, s.rest_normals), 1e-12);
}

TEST(SurfaceDeform, IndentationInvertsNoTriangle) {
  // press a smooth bump (3 voxels deep, 4 voxels wide) into the top of a sphere: every
  // triangle of the paper surface and of an embedded offset surface keeps its orientation
  const int n = 36;
  const VoxelGrid g = ball_grid(n, 14.0);
  const Model m = build_model(g);
  const double c = 0.5 * (n - 1);
  const Eigen::Vector3d top = m.grid.index_to_lps(Eigen::Vector3d(c, c, c + 14.0));
  const Eigen::Vector3d down(0, 0, -1);
  Eigen::Matrix3Xd x = m.rest_positions;
  for (int i = 0; i < m.num_nodes(); ++i) {
    const double d2 = (m.rest_positions.col(i) - top).squaredNorm();
    x.col(i) += 3.0 * std::exp(-d2 / (2 * 4.0 * 4.0)) * down;
  }
  const EmbeddedSurface paper = make_voxel_surface(m, g, true);
  const EmbeddedSurface offset =
      embed_surface(m, probe_points(m, paper, 0.4, 0, 1), paper.triangles, SurfaceMethod::iso);
  for (const EmbeddedSurface* s : {&paper, &offset}) {
    Eigen::Matrix3Xd v, nv;
    deform(*s, x, v, nv);
    int inverted = 0;
    double worst = 1;
    for (int t = 0; t < s->num_triangles(); ++t) {
      const auto normal = [&](const Eigen::Matrix3Xd& p) {
        const Eigen::Vector3d a = p.col(s->triangles(0, t));
        return Eigen::Vector3d((p.col(s->triangles(1, t)) - a).cross(p.col(s->triangles(2, t)) - a).normalized());
      };
      const double dot = normal(v).dot(normal(s->rest_vertices));
      worst = std::min(worst, dot);
      inverted += dot <= 0;
    }
    EXPECT_EQ(inverted, 0);
    std::printf("%s: lowest cos(rest normal, indented normal) %.3f\n", to_string(s->method), worst);
    // the bump moved the top by about 3 voxels
    double lowest_top = 1e9;
    for (int i = 0; i < s->num_vertices(); ++i)
      if ((s->rest_vertices.col(i) - top).head<2>().norm() < 1.0) lowest_top = std::min(lowest_top, v(2, i));
    EXPECT_LT(lowest_top, top.z() - 2.0);
  }
}
