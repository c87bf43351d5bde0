// The display surface: a folded iso-surface decimated to a target, embedded in the model like the
// full one (affine motion exact), close to the full surface at rest, closed and outward.
#include "convert/decimate_surface.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <array>
#include <chrono>
#include <cmath>
#include <map>

#include "base/error.h"
#include "convert/iso_surface.h"
#include "model/gradational_builder.h"
#include "surface/surface.h"

using namespace vx;

namespace {

// a folded slab at 1 mm voxels: an 18 mm base with 10 mm gyri on top, separated by sulci two
// voxels wide that wander across the slab, and rounded in plan (a brain's cortex in miniature)
VoxelGrid folded_grid() {
  GridGeometry g;
  g.dims = Eigen::Vector3i(72, 64, 34);
  g.spacing_mm = Eigen::Vector3d::Constant(1.0);
  g.origin_mm = Eigen::Vector3d(-36.0, -32.0, -17.0);
  VoxelGrid grid(g);
  for (int k = 2; k < 32; ++k)
    for (int j = 2; j < 62; ++j)
      for (int i = 2; i < 70; ++i) {
        const double x = i - 36.0, y = j - 32.0;
        if (x * x / (33.0 * 33.0) + y * y / (29.0 * 29.0) > 1.0) continue;
        if (k < 20) {
          grid.set(i, j, k, 1);
          continue;
        }
        const int shift = int(std::lround(3.0 * std::sin(j / 6.0)));
        const int phase = ((i + shift) % 9 + 9) % 9;
        if (phase >= 2) grid.set(i, j, k, 1);  // sulci at phases 0 and 1
      }
  return grid;
}

struct Folded {
  VoxelGrid grid;
  Model model;
  EmbeddedSurface full;
};

const Folded& folded() {
  static const Folded f = [] {
    Folded x{folded_grid(), {}, {}};
    x.model = build_model(x.grid);
    x.full = make_surface(x.model, x.grid, nullptr, SurfaceMethod::iso);
    return x;
  }();
  return f;
}

}  // namespace

TEST(DecimateSurface, ReachesTheTargetAndStaysClosedAndOutward) {
  const Folded& f = folded();
  const int target = f.full.num_triangles() * 2 / 7;  // 350 k -> 100 k, the brain's ratio
  ASSERT_GT(f.full.num_triangles(), 30000) << "a folded surface of some size";
  DecimationSettings settings;
  settings.target_triangles = target;
  DecimationReport report;
  const auto t0 = std::chrono::steady_clock::now();
  const EmbeddedSurface d = decimate_surface(f.model, f.full, settings, &report);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_TRUE(report.decimated);
  EXPECT_EQ(report.triangles_before, f.full.num_triangles());
  EXPECT_EQ(report.triangles_after, d.num_triangles());
  EXPECT_NEAR(d.num_triangles(), target, 0.1 * target);
  EXPECT_EQ(d.method, SurfaceMethod::iso);
  EXPECT_EQ(report.method, "vtkDecimatePro, topology preserved");
  EXPECT_EQ(report.embedding, "the full surface's");
  EXPECT_EQ(d.validate(), "");
  // the topology-preserving decimation keeps this closed surface closed, manifold and oriented
  const MeshTopology full_topo = mesh_topology(f.full.triangles, f.full.num_vertices());
  const MeshTopology topo = mesh_topology(d.triangles, d.num_vertices());
  EXPECT_TRUE(topo.closed_and_oriented()) << topo.open_edges << " open, " << topo.misoriented_edges << " misoriented";
  EXPECT_EQ(topo.non_manifold_edges, 0);
  EXPECT_EQ(topo.euler_characteristic, full_topo.euler_characteristic);
  // outward, and the volume preserved
  const double v_full = enclosed_volume_mm3(f.full.rest_vertices, f.full.triangles);
  const double v = enclosed_volume_mm3(d.rest_vertices, d.triangles);
  EXPECT_GT(v, 0.0);
  EXPECT_NEAR(v, v_full, 0.005 * v_full);  // measured -0.25 %
  std::printf(
      "[ figures  ] %d -> %d triangles (target %d) in %.3f s (decimate %.3f s, embed %.3f s), volume %.1f -> %.1f "
      "mm3\n",
      f.full.num_triangles(), d.num_triangles(), target, seconds, report.decimate_s, report.embed_s, v_full, v);
}

TEST(DecimateSurface, DecimatedVerticesMoveExactlyAffinely) {
  const Folded& f = folded();
  DecimationSettings settings;
  settings.target_triangles = f.full.num_triangles() / 4;
  const EmbeddedSurface d = decimate_surface(f.model, f.full, settings);
  // an affine motion of the nodes: stretch, shear, rotation and a shift
  Eigen::Matrix3d a = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  a *= Eigen::Vector3d(1.2, 0.9, 1.05).asDiagonal();
  a(0, 2) += 0.15;
  const Eigen::Vector3d shift(4.0, -7.0, 2.5);
  const Eigen::Matrix3Xd nodes = (a * f.model.rest_positions).colwise() + shift;
  SurfaceFrame frame;
  deform(d, nodes, frame);
  const Eigen::Matrix3Xd expected = (a * d.rest_vertices).colwise() + shift;
  EXPECT_LT((frame.vertices - expected).cwiseAbs().maxCoeff(), 1e-9);
  // under any motion each decimated vertex is where the full surface's vertex at the same rest
  // point is (it keeps that vertex's embedding row)
  Eigen::Matrix3Xd wavy = f.model.rest_positions;
  for (Eigen::Index n = 0; n < wavy.cols(); ++n)
    wavy(2, n) += 2.0 * std::sin(0.3 * wavy(0, n)) * std::cos(0.2 * wavy(1, n));
  SurfaceFrame full_frame;
  deform(f.full, wavy, full_frame);
  deform(d, wavy, frame);
  std::map<std::array<double, 3>, int> full_at;
  for (int w = 0; w < f.full.num_vertices(); ++w)
    full_at[{f.full.rest_vertices(0, w), f.full.rest_vertices(1, w), f.full.rest_vertices(2, w)}] = w;
  int matched = 0;
  for (int v = 0; v < d.num_vertices(); ++v) {
    const auto it = full_at.find({d.rest_vertices(0, v), d.rest_vertices(1, v), d.rest_vertices(2, v)});
    if (it == full_at.end()) continue;
    EXPECT_LT((frame.vertices.col(v) - full_frame.vertices.col(it->second)).norm(), 1e-12);
    ++matched;
  }
  EXPECT_EQ(matched, d.num_vertices());
  // at rest it is where the decimation put it
  deform(d, f.model.rest_positions, frame);
  EXPECT_LT((frame.vertices - d.rest_vertices).cwiseAbs().maxCoeff(), 1e-9);
  // and its normals follow the rotation at a rigid motion (outward stays outward)
  const Eigen::Matrix3d rot = Eigen::AngleAxisd(0.7, Eigen::Vector3d(0, 1, 0)).toRotationMatrix();
  deform(d, (rot * f.model.rest_positions).colwise() + shift, frame);
  EXPECT_LT((frame.normals - rot * d.rest_normals).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(DecimateSurface, StaysWithinHalfAMillimetreOfTheFullSurfaceAtOneMillimetreVoxels) {
  const Folded& f = folded();
  DecimationSettings settings;
  settings.target_triangles = f.full.num_triangles() * 2 / 7;
  const EmbeddedSurface d = decimate_surface(f.model, f.full, settings);
  const MeshDistance dist = mesh_distance_mm(d.rest_vertices, d.triangles, f.full.rest_vertices, f.full.triangles);
  std::printf(
      "[ figures  ] distance decimated <-> full: max %.3f mm (decimated to full %.3f, full to decimated %.3f), "
      "mean %.4f mm\n",
      dist.max_mm, dist.max_a_to_b_mm, dist.max_b_to_a_mm, dist.mean_mm);
  // measured max 0.415 mm (at sulci opening to the side), mean 0.027 mm; the kept vertices lie
  // on the full surface
  EXPECT_LT(dist.max_mm, 0.5);
  EXPECT_LT(dist.mean_mm, 0.05);
  EXPECT_LT(dist.max_a_to_b_mm, 1e-6);
  EXPECT_GT(dist.max_mm, 0.1);  // it did change the surface
}

// The preview the probe app shows while it decimates (preview_surface): near the target, on the
// full surface (its vertices are full-surface vertices that move as those do), outward, its
// volume and its distance to the full surface within a bin.
TEST(DecimateSurface, APreviewIsNearTheTargetOnTheFullSurfaceAndOutward) {
  const Folded& f = folded();
  DecimationSettings settings;
  settings.target_triangles = f.full.num_triangles() * 2 / 7;
  DecimationReport report;
  const EmbeddedSurface p = preview_surface(f.model, f.full, settings, &report);
  EXPECT_TRUE(report.preview);
  EXPECT_FALSE(report.decimated);
  EXPECT_EQ(report.triangles_after, p.num_triangles());
  EXPECT_EQ(report.embedding, "the full surface's");
  EXPECT_EQ(p.validate(), "");
  EXPECT_GT(p.num_triangles(), settings.target_triangles / 2);
  EXPECT_LT(p.num_triangles(), 1.2 * settings.target_triangles);
  // under any motion each vertex is where the full surface's vertex at its rest point is
  Eigen::Matrix3Xd wavy = f.model.rest_positions;
  for (Eigen::Index n = 0; n < wavy.cols(); ++n)
    wavy(2, n) += 2.0 * std::sin(0.3 * wavy(0, n)) * std::cos(0.2 * wavy(1, n));
  SurfaceFrame full_frame, frame;
  deform(f.full, wavy, full_frame);
  deform(p, wavy, frame);
  std::map<std::array<double, 3>, int> full_at;
  for (int w = 0; w < f.full.num_vertices(); ++w)
    full_at[{f.full.rest_vertices(0, w), f.full.rest_vertices(1, w), f.full.rest_vertices(2, w)}] = w;
  for (int v = 0; v < p.num_vertices(); ++v) {
    const auto it = full_at.find({p.rest_vertices(0, v), p.rest_vertices(1, v), p.rest_vertices(2, v)});
    ASSERT_NE(it, full_at.end()) << v;
    EXPECT_LT((frame.vertices.col(v) - full_frame.vertices.col(it->second)).norm(), 1e-12);
  }
  // outward, the volume kept and the shape within about a bin (the bins' size in the report)
  const double v_full = enclosed_volume_mm3(f.full.rest_vertices, f.full.triangles);
  const double v = enclosed_volume_mm3(p.rest_vertices, p.triangles);
  const MeshDistance dist = mesh_distance_mm(p.rest_vertices, p.triangles, f.full.rest_vertices, f.full.triangles);
  std::printf(
      "[ figures  ] preview %d -> %d triangles (target %d; %s) in %.3f s, volume %.1f -> %.1f mm3, distance "
      "max %.3f mm, mean %.4f mm\n",
      f.full.num_triangles(), p.num_triangles(), settings.target_triangles, report.method.c_str(),
      report.decimate_s + report.embed_s, v_full, v, dist.max_mm, dist.mean_mm);
  EXPECT_GT(v, 0.0);
  EXPECT_NEAR(v, v_full, 0.03 * v_full);
  EXPECT_LT(dist.max_a_to_b_mm, 1e-6);  // its vertices are on the full surface
  EXPECT_LT(dist.mean_mm, 0.25);
  // a surface small enough is kept as it is; a target of a few triangles still gives some
  DecimationSettings big;
  big.target_triangles = f.full.num_triangles();
  EXPECT_EQ(preview_surface(f.model, f.full, big).num_triangles(), f.full.num_triangles());
  DecimationSettings few;
  few.target_triangles = 3;
  const EmbeddedSurface tiny = preview_surface(f.model, f.full, few);
  EXPECT_GT(tiny.num_triangles(), 0);
  EXPECT_LT(tiny.num_triangles(), 100);
  EXPECT_EQ(tiny.validate(), "");
}

TEST(DecimateSurface, SmallSurfacesAndTargetZeroAreKept) {
  const Folded& f = folded();
  DecimationReport report;
  DecimationSettings none;
  none.target_triangles = 0;
  const EmbeddedSurface same = decimate_surface(f.model, f.full, none, &report);
  EXPECT_FALSE(report.decimated);
  EXPECT_EQ(same.num_triangles(), f.full.num_triangles());
  EXPECT_EQ(same.embed_nodes, f.full.embed_nodes);
  DecimationSettings big;
  big.target_triangles = f.full.num_triangles();
  (void)decimate_surface(f.model, f.full, big, &report);
  EXPECT_FALSE(report.decimated);
  // a surface of another model is refused
  EmbeddedSurface other = f.full;
  other.model_nodes += 1;
  EXPECT_THROW((void)decimate_surface(f.model, other, DecimationSettings{}, nullptr), Error);
}

TEST(MeshDistance, OfAShiftedMeshIsTheShift) {
  const Folded& f = folded();
  // the full surface moved 0.2 mm along z: every vertex is at most 0.2 mm from the other mesh
  const Eigen::Matrix3Xd moved = f.full.rest_vertices.colwise() + Eigen::Vector3d(0, 0, 0.2);
  const MeshDistance d = mesh_distance_mm(moved, f.full.triangles, f.full.rest_vertices, f.full.triangles);
  EXPECT_LE(d.max_mm, 0.2 + 1e-9);
  EXPECT_GT(d.max_mm, 0.19);  // the flat tops are 0.2 mm apart
  EXPECT_GT(d.mean_mm, 0.0);
  EXPECT_EQ(mesh_distance_mm(f.full.rest_vertices, f.full.triangles, f.full.rest_vertices, f.full.triangles).max_mm,
            0.0);
}
