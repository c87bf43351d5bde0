// Material validation and per-element calibration: E = 2k/h for the 8-vertex cube, lumped
// masses, damping ratio, per-element overrides, and the affine-strain energy of every layout
// against continuum elasticity.
#include "physics/physics_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <map>
#include <vector>

#include "base/error.h"
#include "model/gradational_builder.h"
#include "model/voxel_shapes.h"
#include "physics/calibration.h"
#include "physics/elements.h"
#include "sim/state.h"
#include "support/physics_helpers.h"

namespace vx {
namespace {

using testing::hand_block;
using testing::hand_cube;

TEST(Material, CubeOfEdgeHHasEEqualsTwoKOverH) {
  for (double h : {0.5, 1.0, 3.0}) {
    Material mat;
    mat.youngs_modulus_kpa = 12.0;
    mat.density_kg_m3 = 1050.0;
    mat.damping_ratio = 0.2;
    const auto p = make_physics_model(hand_cube(h), mat);
    const double k = p->element_stiffness[0];
    EXPECT_NEAR(2.0 * k / h, 12.0 * kKpaToNPerMm2, 1e-15) << "h = " << h;
    // lumped masses: rho h^3, one eighth per vertex
    const double mass_kg = 1050.0 * 1e-9 * h * h * h;
    EXPECT_NEAR(p->total_mass_kg(), mass_kg, 1e-12 * mass_kg);
    EXPECT_NEAR(p->node_mass_kg[0], mass_kg / 8, 1e-12 * mass_kg);
    EXPECT_NEAR(p->node_mass[0], mass_kg / 8 * 1e-3, 1e-12 * mass_kg);
    // critical damping of the element's own vibration: c = zeta 2 sqrt(k m_v)
    EXPECT_NEAR(p->element_damping[0], 0.2 * 2.0 * std::sqrt(k * mass_kg / 8 * 1e-3), 1e-12);
  }
}

TEST(Material, InvalidMaterialsAreRefusedWithTheValidRange) {
  const Model m = hand_cube();
  const auto expect_error = [&](Material mat, const std::string& needle) {
    try {
      (void)make_physics_model(m, mat);
      ADD_FAILURE() << "expected vx::Error mentioning " << needle;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  Material bad;
  bad.youngs_modulus_kpa = 0;
  expect_error(bad, "Young's modulus");
  bad = {};
  bad.density_kg_m3 = -1;
  expect_error(bad, "density");
  bad = {};
  bad.damping_ratio = -0.1;
  expect_error(bad, "damping ratio");
  bad = {};
  bad.poisson_ratio = 0.5;
  expect_error(bad, "Poisson ratio");
  bad.poisson_ratio = -0.2;
  expect_error(bad, "Poisson ratio");
  MaterialField field;
  field.youngs_modulus_kpa = {1.0, 2.0};
  EXPECT_THROW((void)make_physics_model(m, Material{}, field), Error);
  Model unfinished = m;
  unfinished.rest_offsets.resize(3, 0);
  EXPECT_THROW((void)make_physics_model(unfinished, Material{}), Error);
}

TEST(Material, PerElementOverridesScaleStiffnessAndMass) {
  const Model m = hand_block(3, 1, 1, 1.0);
  MaterialField field;
  field.youngs_modulus_kpa = {5.0, 50.0, 5.0};  // a stiff inclusion in the middle
  field.density_kg_m3 = {1000.0, 2000.0, 1000.0};
  const auto p = make_physics_model(m, Material{}, field);
  EXPECT_NEAR(p->element_stiffness[1] / p->element_stiffness[0], 10.0, 1e-12);
  EXPECT_NEAR(p->element_mass_kg[1] / p->element_mass_kg[0], 2.0, 1e-12);
  EXPECT_NEAR(p->total_mass_kg(), 4000.0 * 1e-9, 1e-18);
}

/// Elastic energy of the model under the affine displacement u = eps x (small), over the
/// continuum energy (mu eps:eps + lambda/2 tr(eps)^2) V of the same volume.
double affine_energy_ratio(const Model& m, const Material& mat, const Eigen::Matrix3d& eps) {
  const auto p = make_physics_model(m, mat);
  SimState s = make_state(p);
  for (int i = 0; i < m.num_nodes(); ++i) s.positions.col(i) = m.rest_positions.col(i) + eps * m.rest_positions.col(i);
  const double discrete = compute_energies(s, 1).elastic;
  const double mu = shear_modulus_n_mm2(mat.youngs_modulus_kpa, mat.poisson_ratio);
  const double lambda = lame_lambda_n_mm2(mat.youngs_modulus_kpa, mat.poisson_ratio);
  const Eigen::Matrix3d e = 0.5 * (eps + eps.transpose());
  const double continuum =
      (mu * (e.array() * e.array()).sum() + 0.5 * lambda * e.trace() * e.trace()) * m.total_volume_mm3();
  return discrete / continuum;
}

TEST(Material, AffineStrainEnergyMatchesElasticityForTheVoxelLayout) {
  const Model m = hand_block(4, 3, 5, 0.8);
  Eigen::Matrix3d uniaxial = Eigen::Matrix3d::Zero();
  uniaxial(2, 2) = 1e-4;
  Eigen::Matrix3d shear = Eigen::Matrix3d::Zero();
  shear(0, 1) = 1e-4;
  Eigen::Matrix3d general;
  general << 1e-4, 2e-5, -3e-5, 0.5e-4, -2e-4, 1e-5, 0, 3e-5, 0.7e-4;
  for (double nu : {0.0, 0.3, 0.45}) {
    Material mat;
    mat.poisson_ratio = nu;
    for (const Eigen::Matrix3d& eps : {uniaxial, shear, general})
      EXPECT_NEAR(affine_energy_ratio(m, mat, eps), 1.0, 1e-3) << "nu = " << nu << "\n" << eps;
  }
}

TEST(Material, EveryLayoutRepresentsTheSameMaterial) {
  // a 16 x 16 x 24 block, away from the grid border
  const VoxelGrid grid = testing::box_grid({20, 20, 28}, {2, 2, 2}, {18, 18, 26}, 0.5);
  Eigen::Matrix3d uniaxial = Eigen::Matrix3d::Zero();
  uniaxial(2, 2) = 1e-4;
  Eigen::Matrix3d shear = Eigen::Matrix3d::Zero();
  shear(0, 2) = 1e-4;
  for (Layout r : {Layout::voxel, Layout::uniform, Layout::gradational}) {
    BuildSettings bs;
    bs.layout = r;
    const Model m = build_model(grid, bs);
    ASSERT_EQ(m.validate(), "");
    EXPECT_NEAR(m.total_volume_mm3(), 16 * 16 * 24 * 0.125, 1e-9);
    for (const Eigen::Matrix3d& eps : {uniaxial, shear}) {
      const double ratio = affine_energy_ratio(m, Material{}, eps);
      // the voxel layout is exact; with the isotropic vertex weights so are the others where
      // every element could be made isotropic (here all); within 2 % in any case
      EXPECT_NEAR(ratio, 1.0, r == Layout::voxel ? 1e-9 : 0.02) << to_string(r) << "\n" << eps;
      std::cout << to_string(r) << " energy ratio " << ratio << "\n";
    }
  }
}

TEST(Material, IsotropicWeightsMakeTheSpreadIsotropic) {
  // an 8-vertex cube keeps equal weights
  const Model cube = hand_cube(2.0);
  Eigen::Matrix3Xd pts = cube.rest_positions;
  double aniso = 1;
  EXPECT_EQ(isotropic_weights(pts, 0.1, 4.0, &aniso), Eigen::VectorXd::Ones(8));
  EXPECT_LT(aniso, 1e-12);
  // a cube with extra vertices at the centres of its top and bottom faces (an interior
  // element between smaller neighbours above and below): equal weights are stiffer along z
  Eigen::Matrix3Xd extra(3, 10);
  extra.leftCols(8) = pts;
  extra.col(8) << 1, 1, 0;
  extra.col(9) << 1, 1, 2;
  const Model m = testing::hand_element(extra);
  CalibrationOptions plain;
  plain.isotropic_weights = false;
  const auto p0 = make_physics_model(m, Material{}, {}, plain);
  const auto p1 = make_physics_model(m, Material{});
  // (face centres add spread along z only: isotropy would need them at weight 0, so they
  // go to the bound and 2 % remain instead of 23 %)
  EXPECT_EQ(p0->anisotropic_elements, 1);
  EXPECT_GT(p0->max_anisotropy, 0.2);
  EXPECT_LT(p1->max_anisotropy, 0.03);
  for (int i = 8; i < 10; ++i) EXPECT_NEAR(p1->entry_weight[std::size_t(i)], 0.1, 1e-9);
  // weights: mean 1, bounded, the weighted centroid at the cube centre, mass follows them
  double wsum = 0;
  for (double w : p1->entry_weight) {
    EXPECT_GE(w, 0.1 - 1e-12);
    EXPECT_LE(w, 4.0 + 1e-12);
    wsum += w;
  }
  EXPECT_NEAR(wsum, 10.0, 1e-9);
  EXPECT_NEAR(p1->total_mass_kg(), 1000.0 * 1e-9, 1e-18);
  // affine uniaxial energies along x and z are now equal
  const auto energy = [&](const std::shared_ptr<const PhysicsModel>& p, int axis) {
    SimState s = make_state(p);
    s.positions.row(axis) *= 1.0 + 1e-4;
    return compute_energies(s, 1).elastic;
  };
  // the affine part of the energy comes from the consistent gradient (element_gradient.h), so
  // uniaxial stretches along x and z cost the same, mu V eps^2 (Poisson 0), whatever the
  // weights; the weights only shape the non-affine part
  const double mu = shear_modulus_n_mm2(Material{}.youngs_modulus_kpa, 0.0), eps = 1e-4;
  for (const auto& p : {p0, p1})
    for (int axis : {0, 2}) EXPECT_NEAR(energy(p, axis) / (mu * 1.0 * eps * eps), 1.0, 1e-3) << "axis " << axis;
}

TEST(Material, CongruentElementsGetTheSameWeightsAndAMovedOneItsOwn) {
  // a gradational ball on voxels of 0.8 x 0.9 x 1.3 mm far from the origin: many elements are
  // the same shape moved by a translation (the same level, the same vertices at the same
  // lattice offsets), and their isotropic weights, solved from each element's own coordinates,
  // can take different bounds by rounding alone (the bounded solve's active set); the
  // calibration solves each shape once, so congruent elements get the same weights
  const VoxelGrid ball = ball_grid(50, 22.3);
  GridGeometry geo = ball.geometry();
  geo.spacing_mm = {0.8, 0.9, 1.3};
  geo.origin_mm = {-83.1, 21.7, 301.9};
  VoxelGrid grid(geo);
  grid.data() = ball.data();
  Model m = build_model(grid);
  const auto shape_key = [&m](int e) {
    std::vector<int> k{m.element_level[std::size_t(e)]};
    for (int j = m.element_offsets[e]; j < m.element_offsets[e + 1]; ++j) {
      const Eigen::Vector3i d = m.node_lattice.col(m.element_vertices[j]) - m.element_anchor.col(e);
      k.insert(k.end(), {d.x(), d.y(), d.z()});
    }
    return k;
  };
  const auto points = [&m](int e) {
    const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
    Eigen::Matrix3Xd pts(3, n);
    for (int i = 0; i < n; ++i) pts.col(i) = m.rest_positions.col(m.element_vertices[b + i]);
    return pts;
  };
  std::map<std::vector<int>, std::vector<int>> shapes;
  for (int e = 0; e < m.num_elements(); ++e) shapes[shape_key(e)].push_back(e);
  ASSERT_LT(shapes.size() * 2, std::size_t(m.num_elements()));
  const CalibrationOptions options;
  const auto p = make_physics_model(m, Material{});
  int own_solves_differ = 0;
  for (const auto& [key, elements] : shapes) {
    const int first = elements.front(), b0 = m.element_offsets[first];
    const Eigen::VectorXd first_own = isotropic_weights(points(first), options.min_weight, options.max_weight);
    for (int e : elements) {
      const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
      for (int i = 0; i < n; ++i) ASSERT_EQ(p->entry_weight[std::size_t(b + i)], p->entry_weight[std::size_t(b0 + i)]);
      // the same spread and stiffness, to rounding (each element's own offsets and volume)
      EXPECT_NEAR(p->element_stiffness[std::size_t(e)], p->element_stiffness[std::size_t(first)],
                  1e-12 * p->element_stiffness[std::size_t(first)]);
      const Eigen::VectorXd own = isotropic_weights(points(e), options.min_weight, options.max_weight);
      if ((own - first_own).cwiseAbs().maxCoeff() > 1e-6) ++own_solves_differ;
    }
  }
  // the witness: here, solving each element alone gives congruent elements other weights
  std::cout << own_solves_differ << " elements whose own solve differs from their shape's\n";
  EXPECT_GT(own_solves_differ, 0);
  // an element moved off its shape (a hand-edited model: one vertex 0.05 mm aside, a vertex
  // that only this element has) is solved from its own coordinates
  int moved = -1, vertex = -1;
  std::vector<int> uses(std::size_t(m.num_nodes()), 0);
  for (int v : m.element_vertices) ++uses[std::size_t(v)];
  for (const auto& [key, elements] : shapes) {
    for (int e : elements)
      for (int j = m.element_offsets[e]; j < m.element_offsets[e + 1] && moved < 0; ++j)
        if (elements.size() > 1 && e != elements.front() && uses[std::size_t(m.element_vertices[j])] == 1)
          moved = e, vertex = m.element_vertices[j];
    if (moved >= 0) break;
  }
  ASSERT_GE(moved, 0) << "no element with a vertex of its own";
  m.rest_positions(0, vertex) += 0.05;
  const auto q = make_physics_model(m, Material{});
  const Eigen::VectorXd own = isotropic_weights(points(moved), options.min_weight, options.max_weight);
  const int b = m.element_offsets[moved];
  for (Eigen::Index i = 0; i < own.size(); ++i) EXPECT_EQ(q->entry_weight[std::size_t(b + i)], own(i));
}

}  // namespace
}  // namespace vx
