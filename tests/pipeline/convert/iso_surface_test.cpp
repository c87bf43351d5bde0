// The iso-surface (flying edges + windowed sinc) embedded in the model, its deformation, and
// the surface files (.vtp with the embedding).
#include "convert/iso_surface.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "base/error.h"
#include "convert/decimate_surface.h"
#include "convert/phantom.h"
#include "io/surface_io.h"
#include "model/gradational_builder.h"
#include "surface/surface.h"
#include "verify/surface_accuracy.h"

using namespace vx;
namespace fs = std::filesystem;

namespace {

/// The phantom's tissue as a binary grid (HU above the midpoint of air and tissue).
VoxelGrid tissue_of(const Volume& v, double threshold_hu = -480.0) {
  VoxelGrid g(v.geometry);
  for (std::size_t i = 0; i < v.hu.size(); ++i) g.data()[i] = v.hu[i] > threshold_hu ? 1 : 0;
  return g;
}

struct Phantom {
  Volume volume;
  PhantomShape shape;
  VoxelGrid grid;
  Model model;
};

Phantom phantom(const std::string& name, int size, double spacing_mm = 1.0) {
  Phantom p;
  PhantomSettings s;
  s.name = name;
  s.size = size;
  s.spacing_mm = spacing_mm;
  p.volume = make_phantom(s, &p.shape);
  p.grid = tissue_of(p.volume);
  p.model = build_model(p.grid);
  return p;
}

fs::path temp_path(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / "voxelastic_iso_surface_test";
  fs::create_directories(dir);
  return dir / name;
}

double max_diff(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) { return (a - b).cwiseAbs().maxCoeff(); }

}  // namespace

TEST(IsoSurface, SphereIsClosedOutwardAndClose) {
  const Phantom p = phantom("sphere", 32);
  const TriangleMesh mesh = extract_iso_surface(p.grid);
  const MeshTopology topo = mesh_topology(mesh.triangles, int(mesh.vertices_mm.cols()));
  EXPECT_TRUE(topo.closed_and_oriented());
  EXPECT_EQ(topo.non_manifold_edges, 0);
  EXPECT_EQ(topo.euler_characteristic, 2);
  const SurfaceAccuracy a = measure_surface_accuracy(mesh.vertices_mm, mesh.triangles, p.shape, 1.0);
  EXPECT_LT(a.mean_distance_voxels, 0.2) << a.summary();
  EXPECT_NEAR(a.volume_error_percent, 0.0, 3.0) << a.summary();
}

TEST(IsoSurface, ACoarseSurfaceIsTheShapeOnBlocksWithAboutTheSquareFewerTriangles) {
  // extract_coarse_iso_surface: the tissue averaged on blocks of f^3 voxels, contoured at half
  const Phantom p = phantom("sphere", 48);
  const TriangleMesh full = extract_iso_surface(p.grid);
  for (int f : {1, 2, 3}) {
    SCOPED_TRACE(f);
    const TriangleMesh coarse = extract_coarse_iso_surface(p.grid, f);
    const MeshTopology topo = mesh_topology(coarse.triangles, int(coarse.vertices_mm.cols()));
    EXPECT_TRUE(topo.closed_and_oriented());
    EXPECT_EQ(topo.euler_characteristic, 2);
    const double ratio = double(coarse.triangles.cols()) / double(full.triangles.cols());
    EXPECT_GT(ratio, 0.7 / (f * f));
    EXPECT_LT(ratio, 1.3 / (f * f));
    const SurfaceAccuracy a = measure_surface_accuracy(coarse.vertices_mm, coarse.triangles, p.shape, 1.0);
    std::cout << "blocks of " << f << ": " << coarse.triangles.cols() << " triangles (" << ratio << " of the full), "
              << a.summary() << "\n";
    // (measured: mean 0.03, 0.07, 0.22 voxel; volume -0.3, -1.1, -4.0 %: the smoothing rounds
    // the coarser steps off)
    EXPECT_LT(a.mean_distance_voxels, 0.1 + 0.15 * f) << a.summary();
    EXPECT_NEAR(a.volume_error_percent, 0.0, 1.5 * f) << a.summary();
  }
  // on a grid of anisotropic voxels turned in space and moved: where the full surface is
  GridGeometry geo = p.grid.geometry();
  geo.spacing_mm = {0.7, 0.9, 1.2};
  geo.origin_mm = {-120.0, 35.0, 410.0};
  geo.direction = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  VoxelGrid turned(geo);
  turned.data() = p.grid.data();
  const TriangleMesh turned_full = extract_iso_surface(turned);
  const TriangleMesh turned_coarse = extract_coarse_iso_surface(turned, 2);
  const MeshDistance d = mesh_distance_mm(turned_coarse.vertices_mm, turned_coarse.triangles, turned_full.vertices_mm,
                                          turned_full.triangles);
  EXPECT_LT(d.mean_mm, 0.3) << "mean " << d.mean_mm << " mm";
  EXPECT_LT(d.max_mm, 1.2) << "largest " << d.max_mm << " mm";
  EXPECT_GT(enclosed_volume_mm3(turned_coarse.vertices_mm, turned_coarse.triangles), 0.0) << "outward";
  // refused: no block size, no tissue
  EXPECT_THROW((void)extract_coarse_iso_surface(p.grid, 0), Error);
  EXPECT_THROW((void)extract_coarse_iso_surface(VoxelGrid(p.grid.geometry()), 2), Error);
}

TEST(IsoSurface, TorusHasGenusOne) {
  const Phantom p = phantom("torus", 40);
  const TriangleMesh mesh = extract_iso_surface(p.grid);
  const MeshTopology topo = mesh_topology(mesh.triangles, int(mesh.vertices_mm.cols()));
  EXPECT_TRUE(topo.closed_and_oriented());
  EXPECT_EQ(topo.euler_characteristic, 0);
}

TEST(IsoSurface, FollowsAffineMotionExactly) {
  const Phantom p = phantom("ellipsoid", 36, 0.8);
  const EmbeddedSurface s = make_surface(p.model, p.grid, nullptr, SurfaceMethod::iso);
  ASSERT_EQ(s.validate(), "");
  EXPECT_EQ(s.method, SurfaceMethod::iso);
  Eigen::Matrix3Xd v, n;
  deform(s, p.model.rest_positions, v, n);
  EXPECT_LT(max_diff(v, s.rest_vertices), 1e-9);
  EXPECT_LT(max_diff(n, s.rest_normals), 1e-9);
  // rigid motion: positions and normals follow
  const Eigen::Matrix3d R = Eigen::AngleAxisd(2.1, Eigen::Vector3d(0.3, -1, 0.4).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(-40, 7, 120);
  deform(s, (R * p.model.rest_positions).colwise() + t, v, n);
  EXPECT_LT(max_diff(v, (R * s.rest_vertices).colwise() + t), 1e-9);
  EXPECT_LT(max_diff(n, R * s.rest_normals), 1e-9);
  // uniform stretch
  deform(s, 1.25 * p.model.rest_positions, v, n);
  EXPECT_LT(max_diff(v, 1.25 * s.rest_vertices), 1e-9);
  EXPECT_LT(max_diff(n, s.rest_normals), 1e-9);
}

TEST(IsoSurface, IndentationInvertsNoTriangle) {
  // a smooth bump 3 mm deep and 4 mm wide pressed into the top of a sphere (radius 12.8 mm)
  const Phantom p = phantom("sphere", 32);
  const Eigen::Vector3d top = p.shape.center_mm + Eigen::Vector3d(0, 0, p.shape.half_extent_mm.x());
  Eigen::Matrix3Xd x = p.model.rest_positions;
  for (int i = 0; i < p.model.num_nodes(); ++i)
    x(2, i) -= 3.0 * std::exp(-(p.model.rest_positions.col(i) - top).squaredNorm() / (2 * 4.0 * 4.0));
  for (SurfaceMethod m : {SurfaceMethod::iso, SurfaceMethod::paper}) {
    const EmbeddedSurface s = make_surface(p.model, p.grid, nullptr, m);
    Eigen::Matrix3Xd v, n;
    deform(s, x, v, n);
    int inverted = 0;
    double worst = 1;
    for (int f = 0; f < s.num_triangles(); ++f) {
      const auto normal = [&](const Eigen::Matrix3Xd& q) {
        const Eigen::Vector3d a = q.col(s.triangles(0, f));
        return Eigen::Vector3d((q.col(s.triangles(1, f)) - a).cross(q.col(s.triangles(2, f)) - a).normalized());
      };
      const double c = normal(v).dot(normal(s.rest_vertices));
      worst = std::min(worst, c);
      inverted += !(c > 0);
    }
    EXPECT_EQ(inverted, 0) << to_string(m);
    std::printf("%s: %d triangles, lowest cos(rest, indented triangle normal) %.3f\n", to_string(m), s.num_triangles(),
                worst);
    // the top went down by about the bump depth
    double top_z = 1e9;
    for (int i = 0; i < s.num_vertices(); ++i)
      if ((s.rest_vertices.col(i) - top).head<2>().norm() < 1.0) top_z = std::min(top_z, v(2, i));
    EXPECT_LT(top_z, top.z() - 2.0) << to_string(m);
  }
}

TEST(IsoSurface, HuValuesPlaceTheSurfaceBetweenVoxelCentres) {
  // a partial-volume sphere: HU falls linearly from tissue to air over one voxel across the
  // true surface, as a CT scanner's blur would; contouring HU beats the binary boundary
  PhantomShape shape;
  shape.name = "sphere";
  shape.half_extent_mm = Eigen::Vector3d::Constant(9.3);
  Volume v;
  v.geometry.dims = {28, 28, 28};
  v.geometry.origin_mm = Eigen::Vector3d::Constant(-13.5);
  v.hu.resize(std::size_t(v.geometry.voxel_count()));
  for (int k = 0; k < 28; ++k)
    for (int j = 0; j < 28; ++j)
      for (int i = 0; i < 28; ++i) {
        const double d = shape.signed_distance_mm(v.geometry.index_to_lps(Eigen::Vector3d(i, j, k)));
        v.hu[std::size_t(i + 28 * (j + 28 * k))] = float(40.0 - 1040.0 * std::clamp(d + 0.5, 0.0, 1.0));
      }
  const double iso = -480.0;  // midway: the true surface
  const VoxelGrid grid = tissue_of(v, iso);
  IsoSurfaceSettings hu_settings;
  hu_settings.iso_hu = iso;
  const TriangleMesh from_hu = extract_iso_surface(grid, &v, hu_settings);
  const TriangleMesh from_grid = extract_iso_surface(grid);
  EXPECT_TRUE(mesh_topology(from_hu.triangles, int(from_hu.vertices_mm.cols())).closed_and_oriented());
  const SurfaceAccuracy a_hu = measure_surface_accuracy(from_hu.vertices_mm, from_hu.triangles, shape, 1.0);
  const SurfaceAccuracy a_grid = measure_surface_accuracy(from_grid.vertices_mm, from_grid.triangles, shape, 1.0);
  std::printf("partial-volume sphere: HU iso %s\n                       binary  %s\n", a_hu.summary().c_str(),
              a_grid.summary().c_str());
  EXPECT_LT(a_hu.mean_distance_voxels, 0.05);
  EXPECT_LT(a_hu.mean_distance_voxels, a_grid.mean_distance_voxels);
  // a crop of the volume works (whole-voxel offset); a resampled one is refused
  GridGeometry cropped = v.geometry;
  cropped.dims = {24, 24, 24};
  cropped.origin_mm = v.geometry.index_to_lps(Eigen::Vector3d(2, 2, 2));
  VoxelGrid crop(cropped);
  for (int k = 0; k < 24; ++k)
    for (int j = 0; j < 24; ++j)
      for (int i = 0; i < 24; ++i) crop.set(i, j, k, grid.at(i + 2, j + 2, k + 2));
  const TriangleMesh from_crop = extract_iso_surface(crop, &v, hu_settings);
  ASSERT_EQ(from_crop.vertices_mm.cols(), from_hu.vertices_mm.cols());
  EXPECT_LT(max_diff(from_crop.vertices_mm, from_hu.vertices_mm), 1e-4);
  GridGeometry resampled = cropped;
  resampled.spacing_mm *= 1.5;
  EXPECT_THROW((void)extract_iso_surface(VoxelGrid(resampled), &v, hu_settings), Error);
}

TEST(IsoSurface, TissueOnTheGridBorderGivesAClosedSurface) {
  GridGeometry g;
  g.dims = {10, 10, 10};
  VoxelGrid grid(g);
  for (int k = 0; k < 10; ++k)
    for (int j = 0; j < 10; ++j)
      for (int i = 0; i < 10; ++i) grid.set(i, j, k, i + j + k < 12);
  const Model m = build_model(grid);
  const EmbeddedSurface s = make_surface(m, grid, nullptr, SurfaceMethod::iso);
  EXPECT_TRUE(mesh_topology(s.triangles, s.num_vertices()).closed_and_oriented());
  Eigen::Matrix3Xd v;
  deform_vertices(s, m.rest_positions, v);
  EXPECT_LT(max_diff(v, s.rest_vertices), 1e-9);
}

TEST(IsoSurface, RejectsAGridThatIsNotTheModels) {
  const Phantom p = phantom("sphere", 20);
  const Phantom q = phantom("cube", 20);
  EXPECT_THROW((void)make_surface(p.model, q.grid, nullptr, SurfaceMethod::iso), Error);
  EXPECT_THROW((void)extract_iso_surface(VoxelGrid(p.grid.geometry())), Error);  // no tissue
}

// ---------------------------------------------------------------------------------------------
// files

TEST(SurfaceIo, RoundTripKeepsTheEmbedding) {
  const Phantom p = phantom("torus", 28);
  for (SurfaceMethod m : {SurfaceMethod::paper, SurfaceMethod::iso, SurfaceMethod::staircase}) {
    SCOPED_TRACE(to_string(m));
    const EmbeddedSurface s = make_surface(p.model, p.grid, nullptr, m);
    const fs::path path = temp_path(std::string("surface_") + to_string(m) + ".vtp");
    save_surface(s, path);
    const EmbeddedSurface r = load_surface(path, &p.model);
    EXPECT_EQ(r.method, m);
    EXPECT_EQ(r.model_nodes, p.model.num_nodes());
    EXPECT_EQ(r.rest_vertices, s.rest_vertices);
    EXPECT_EQ(r.triangles, s.triangles);
    EXPECT_EQ(r.embed_offsets, s.embed_offsets);
    EXPECT_EQ(r.embed_nodes, s.embed_nodes);
    EXPECT_EQ(r.embed_weights, s.embed_weights);
    EXPECT_LT(max_diff(r.rest_normals, s.rest_normals), 1e-12);
    // a loaded surface deforms like the original
    const Eigen::Matrix3Xd x = 0.9 * p.model.rest_positions;
    Eigen::Matrix3Xd a, b, na, nb;
    deform(s, x, a, na);
    deform(r, x, b, nb);
    EXPECT_EQ(a, b);
    fs::remove(path);
  }
}

TEST(SurfaceIo, RefusesAnotherModelsSurface) {
  const Phantom p = phantom("sphere", 24);
  const fs::path path = temp_path("sphere.vtp");
  save_surface(make_surface(p.model, p.grid, nullptr, SurfaceMethod::iso), path);
  // another model with a different node count
  const Phantom q = phantom("ellipsoid", 24);
  EXPECT_THROW((void)load_surface(path, &q.model), Error);
  // the same node count but other positions
  Model moved = p.model;
  moved.rest_positions.array() += 0.5;
  EXPECT_THROW((void)load_surface(path, &moved), Error);
  EXPECT_NO_THROW((void)load_surface(path, &p.model));
  EXPECT_NO_THROW((void)load_surface(path));
  fs::remove(path);
}

TEST(SurfaceIo, ClearErrorsForBadFiles) {
  const Phantom p = phantom("sphere", 16);
  const EmbeddedSurface s = make_surface(p.model, p.grid, nullptr, SurfaceMethod::paper);
  EXPECT_THROW(save_surface(s, temp_path("surface.vtu")), Error);
  EXPECT_THROW((void)load_surface(temp_path("missing.vtp")), Error);
  const fs::path junk = temp_path("junk.vtp");
  std::ofstream(junk) << "not a vtp file";
  EXPECT_THROW((void)load_surface(junk), Error);
  fs::remove(junk);
  // a failed save leaves nothing behind
  const fs::path in_missing_dir = temp_path("no_such_dir") / "s.vtp";
  EXPECT_THROW(save_surface(s, in_missing_dir), Error);
  EXPECT_FALSE(fs::exists(in_missing_dir));
}
