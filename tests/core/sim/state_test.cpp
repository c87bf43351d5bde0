// The simulation state: creation, fixed-node regions, energies in N*mm, reset.
#include "sim/state.h"

#include <gtest/gtest.h>

#include "base/error.h"
#include "physics/calibration.h"
#include "support/physics_helpers.h"

namespace vx {
namespace {

using testing::hand_block;

TEST(State, StartsAtRestAndSharesTheModel) {
  const auto p = make_physics_model(hand_block(2, 3, 4, 1.0), Material{});
  SimState a = make_state(p), b = make_state(p);
  EXPECT_EQ(a.physics.get(), b.physics.get());
  EXPECT_EQ(a.positions, p->model->rest_positions);
  EXPECT_EQ(a.velocities.cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ(int(a.rotations.size()), p->num_elements());
  EXPECT_EQ(a.num_fixed(), 0);
  EXPECT_FALSE(a.failed());
  const Energies e = compute_energies(a);
  EXPECT_EQ(e.kinetic, 0.0);
  EXPECT_LT(e.elastic, 1e-25);
  EXPECT_EQ(e.gravitational, 0.0);
}

TEST(State, FixedRegionsByFaceBoxOrList) {
  const Model m = hand_block(2, 3, 4, 1.0);
  EXPECT_EQ(nodes_on_face(m, BoxFace::x_min).size(), 4u * 5u);
  EXPECT_EQ(nodes_on_face(m, BoxFace::z_max).size(), 3u * 4u);
  EXPECT_EQ(nodes_in_box(m, {-0.1, -0.1, -0.1}, {0.1, 10, 10}), nodes_on_face(m, BoxFace::x_min));
  SimState s = make_state(make_physics_model(m, Material{}));
  s.velocities.setOnes();
  const auto v0 = s.fixed_version;
  s.fix_nodes(nodes_on_face(m, BoxFace::z_min));
  EXPECT_EQ(s.num_fixed(), 12);
  EXPECT_GT(s.fixed_version, v0);
  EXPECT_EQ(s.velocities.col(0).norm(), 0.0);  // fixed nodes start at rest
  s.free_nodes({0});
  EXPECT_EQ(s.num_fixed(), 11);
  EXPECT_THROW(s.fix_nodes({-1}), Error);
  EXPECT_THROW(s.fix_nodes({m.num_nodes()}), Error);
  s.free_all_nodes();
  EXPECT_EQ(s.num_fixed(), 0);
}

TEST(State, EnergiesInNewtonMillimetres) {
  Material mat;
  mat.density_kg_m3 = 1000.0;
  const auto p = make_physics_model(hand_block(2, 2, 2, 10.0), mat);  // 20 mm cube: 8 g
  SimState s = make_state(p);
  const double mass_kg = 8e-3;
  ASSERT_NEAR(p->total_mass_kg(), mass_kg, 1e-15);
  // 1 m/s everywhere: 1/2 m v^2 = 4 mJ = 4 N*mm
  s.velocities.row(0).setConstant(1000.0);
  // lifted by 10 mm against g: m g h = 8e-3 * 9.80665 * 0.01 J = 0.78 mJ
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  s.positions.row(2).array() += 10.0;
  const Energies e = compute_energies(s);
  EXPECT_NEAR(e.kinetic, 4.0, 1e-12);
  EXPECT_NEAR(e.gravitational, mass_kg * 9.80665 * 0.01 * 1e3, 1e-12);
  EXPECT_LT(e.elastic, 1e-20);
  s.reset();
  EXPECT_EQ(s.positions, p->model->rest_positions);
  EXPECT_EQ(s.velocities.cwiseAbs().maxCoeff(), 0.0);
}

}  // namespace
}  // namespace vx
