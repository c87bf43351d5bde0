// Calibration against elasticity on one block, for the voxel, uniform and gradational layouts
// built by build_model: the static compression (stress = E * strain for Poisson ratio 0), the
// sag under its own weight (rho g H^2 / (2 E)), and the lateral bulge of the volume term
// (lateral strain = -nu * axial strain). Slow (static solves of ~10^4 nodes): label "slow".
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

#include "model/gradational_builder.h"
#include "physics/calibration.h"
#include "sim/integrators.h"
#include "sim/static_solver.h"
#include "support/physics_helpers.h"

namespace vx {
namespace {

constexpr Layout kLayouts[] = {Layout::voxel, Layout::uniform, Layout::gradational};

/// A W x W x H block of voxels of edge h mm filling its grid.
Model block(Layout r, int w, int height, double h = 1.0) {
  const VoxelGrid grid = testing::box_grid({w, w, height}, {0, 0, 0}, {w, w, height}, h);
  BuildSettings bs;
  bs.layout = r;
  return build_model(grid, bs);
}

struct Compression {
  double modulus_kpa;     ///< (reaction / area) / strain
  double lateral_strain;  ///< mid-height width change / width
  int iterations;
};

/// Clamps the bottom face, moves the clamped top face down by strain * H, solves statically.
Compression compress(const Model& m, const Material& mat, double strain) {
  auto p = make_physics_model(m, mat);
  SimState s = make_state(p);
  const auto bottom = nodes_on_face(m, BoxFace::z_min), top = nodes_on_face(m, BoxFace::z_max);
  s.fix_nodes(bottom);
  s.fix_nodes(top);
  const double zmin = m.rest_positions.row(2).minCoeff(), zmax = m.rest_positions.row(2).maxCoeff();
  const double height = zmax - zmin;
  for (int i : top) s.positions(2, i) -= strain * height;
  StaticSolveSettings ss;
  ss.max_iterations = 2000;
  ss.tolerance_mm = 1e-10;
  const StepReport r = solve_static(s, ss);
  EXPECT_FALSE(s.failed()) << s.message;
  const double xmin = m.rest_positions.row(0).minCoeff(), xmax = m.rest_positions.row(0).maxCoeff();
  const double ymin = m.rest_positions.row(1).minCoeff(), ymax = m.rest_positions.row(1).maxCoeff();
  const double area = (xmax - xmin) * (ymax - ymin);
  const double reaction = elastic_force_on(s, top).z();  // N, pushing the press back up
  // mid-height width along x: mean x of the nodes on the x faces at z = H/2
  double left = 0, right = 0;
  int nl = 0, nr = 0;
  for (int i = 0; i < m.num_nodes(); ++i) {
    if (std::abs(m.rest_positions(2, i) - (zmin + 0.5 * height)) > 1e-9) continue;
    if (std::abs(m.rest_positions(0, i) - xmin) < 1e-9) left += s.positions(0, i), ++nl;
    if (std::abs(m.rest_positions(0, i) - xmax) < 1e-9) right += s.positions(0, i), ++nr;
  }
  const double width = right / nr - left / nl;
  return {reaction / area / strain / kKpaToNPerMm2, width / (xmax - xmin) - 1.0, r.iterations};
}

TEST(Calibration, StaticCompressionGivesTheSameModulusInEveryLayoutAndMatchesE) {
  Material mat;
  mat.youngs_modulus_kpa = 10.0;
  double moduli[3];
  int n = 0;
  for (Layout r : kLayouts) {
    const Model m = block(r, 16, 32);
    const Compression c = compress(m, mat, 0.01);
    moduli[n++] = c.modulus_kpa;
    std::cout << to_string(r) << ": " << m.num_elements() << " elements, " << m.num_vertex_entries()
              << " vertex entries: E_measured / E = " << c.modulus_kpa / mat.youngs_modulus_kpa << " (lateral strain "
              << c.lateral_strain << ", " << c.iterations << " iterations)\n";
    // stress = E * strain (Poisson 0): every layout passes the patch test on a box (the
    // consistent gradient, element_gradient.h), so the static state is exactly uniform
    EXPECT_NEAR(c.modulus_kpa / mat.youngs_modulus_kpa, 1.0, 1e-6) << to_string(r);
    EXPECT_NEAR(c.lateral_strain, 0.0, 1e-3) << "no bulge at Poisson ratio 0";
  }
  // the same compression in every layout
  EXPECT_NEAR(moduli[1] / moduli[0], 1.0, 1e-6);
  EXPECT_NEAR(moduli[2] / moduli[0], 1.0, 1e-6);
}

TEST(Calibration, GradationalCubesOfEverySizeCompressLikeE) {
  // A cube has the most levels for its size. With the paper's least-squares fit the
  // gradational cube read 6.7 % (16^3), 9.0 % (24^3) and 10.7 % (32^3) soft, because the
  // corners of large elements push harder than the small elements they meet; the consistent
  // gradient removes this exactly.
  Material mat;
  mat.youngs_modulus_kpa = 10.0;
  for (int n : {16, 24, 32}) {
    const Model m = block(Layout::gradational, n, n);
    ASSERT_GE(m.num_levels(), n == 16 ? 3 : 4);
    const Compression c = compress(m, mat, 0.01);
    std::cout << n << "^3 gradational: " << m.num_elements() << " elements in " << m.num_levels()
              << " levels, E_measured / E = " << c.modulus_kpa / mat.youngs_modulus_kpa << "\n";
    EXPECT_NEAR(c.modulus_kpa / mat.youngs_modulus_kpa, 1.0, 1e-6) << n;
  }
}

TEST(Calibration, SagUnderOwnWeightMatchesTheBarSolution) {
  // a bar clamped at the bottom under gravity, Poisson 0: top displacement rho g H^2 / (2 E)
  Material mat;
  mat.youngs_modulus_kpa = 5.0;
  mat.density_kg_m3 = 1000.0;
  const double height = 32.0;
  const double expected = mat.density_kg_m3 * 1e-9 * kStandardGravityMmS2 * 1e-3 * height * height /
                          (2.0 * mat.youngs_modulus_kpa * kKpaToNPerMm2);
  double sags[3];
  int n = 0;
  for (Layout r : kLayouts) {
    const Model m = block(r, 16, int(height));
    auto p = make_physics_model(m, mat);
    SimState s = make_state(p);
    s.fix_nodes(nodes_on_face(m, BoxFace::z_min));
    s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
    StaticSolveSettings ss;
    ss.max_iterations = 2000;
    ss.tolerance_mm = 1e-10;
    solve_static(s, ss);
    double sag = 0;
    const auto top = nodes_on_face(m, BoxFace::z_max);
    for (int i : top) sag += (m.rest_positions(2, i) - s.positions(2, i)) / double(top.size());
    sags[n++] = sag;
    std::cout << to_string(r) << ": sag " << sag << " mm, bar solution " << expected << " mm, ratio " << sag / expected
              << "\n";
    // within 3 % (measured: voxel 1.000, uniform 1.003, gradational 1.002)
    EXPECT_NEAR(sag / expected, 1.0, 0.03) << to_string(r);
  }
  EXPECT_NEAR(sags[1] / sags[0], 1.0, 0.03);
  EXPECT_NEAR(sags[2] / sags[0], 1.0, 0.03);
}

TEST(Calibration, VolumeTermBulgesACompressedBlockByPoissonsRatio) {
  // a bar 4x as tall as wide, clamped ends: away from the ends the state is near uniaxial
  // stress, so the mid-height width grows by nu * axial strain and stress = E * strain
  for (Layout r : {Layout::voxel, Layout::gradational}) {
    for (double nu : {0.3, 0.45}) {
      Material mat;
      mat.youngs_modulus_kpa = 10.0;
      mat.poisson_ratio = nu;
      const Model m = block(r, 8, 32);
      const Compression c = compress(m, mat, 0.01);
      std::cout << to_string(r) << " nu " << nu
                << ": lateral strain / (nu * axial) = " << c.lateral_strain / (nu * 0.01)
                << ", E_measured / E = " << c.modulus_kpa / mat.youngs_modulus_kpa << " (" << c.iterations
                << " iterations)\n";
      EXPECT_NEAR(c.lateral_strain / (nu * 0.01), 1.0, 0.15) << to_string(r) << " nu " << nu;
      // clamped ends stiffen the bar a little (the volume term on the consistent F; before, on
      // the vertex fit, it also held the non-affine modes and read lateral 1.02-1.13, modulus
      // 1.02-1.21; docs/model.md section 5, "Locking")
      EXPECT_NEAR(c.modulus_kpa / mat.youngs_modulus_kpa, 1.0, 0.25) << to_string(r) << " nu " << nu;
    }
  }
}

}  // namespace
}  // namespace vx
