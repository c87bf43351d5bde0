// The verify cases' static Newton solve (verify/static_newton.h): with whole nodes held it finds
// the core static solver's equilibrium; with the end faces held along z only (the bulge case's
// frictionless ends) it finds the uniform uniaxial strain, lateral strain -nu x axial, exactly as
// far as the model's finite strain allows, and keeps every held coordinate where it was put.
#include "verify/static_newton.h"

#include <gtest/gtest.h>

#include <cmath>

#include "base/error.h"
#include "physics/calibration.h"
#include "sim/state.h"
#include "sim/static_solver.h"
#include "verify/case_helpers.h"

using namespace vx;
using namespace vx::cases;

namespace {

std::shared_ptr<const PhysicsModel> bar(Layout r, double nu) {
  Material m = tissue(10.0);
  m.poisson_ratio = nu;
  return make_physics_model(block_model(r, {4, 4, 8}, 1.0), m);
}

}  // namespace

TEST(StaticNewton, WholeNodesHeldGiveTheStaticSolversEquilibrium) {
  const auto p = bar(Layout::voxel, 0.0);
  const Model& m = *p->model;
  const auto held = nodes_on_face(m, BoxFace::x_min);
  const Eigen::Vector3d g(0, 0, -9810.0);
  double residual = 1;
  const Eigen::Matrix3Xd x =
      newton_static_positions(*p, m.rest_positions, held_nodes(m.num_nodes(), held), g, &residual);
  SimState s = make_state(p);
  s.gravity_mm_s2 = g;
  s.fix_nodes(held);
  StaticSolveSettings settings;
  settings.max_iterations = 20000;
  settings.tolerance_mm = 1e-11;
  solve_static(s, settings);
  ASSERT_FALSE(s.failed()) << s.message;
  const double sag = (x - m.rest_positions).colwise().norm().maxCoeff();
  EXPECT_GT(sag, 1e-3) << "the bar sagged, mm";
  EXPECT_LT((x - s.positions).colwise().norm().maxCoeff(), 1e-6 * sag / 1e-3) << "the two equilibria, mm";
  EXPECT_LT(residual, 1e-9) << "largest free force left, N";
}

TEST(StaticNewton, EndsHeldAlongTheAxisOnlyGiveUniaxialStress) {
  for (Layout r : {Layout::voxel, Layout::gradational})
    for (double nu : {0.3, 0.49}) {
      const auto p = bar(r, nu);
      const Model& m = *p->model;
      const int nn = m.num_nodes();
      const double strain = 1e-4, height = 8.0;
      HeldCoordinates held(std::size_t(3 * nn), 0);
      Eigen::Matrix3Xd start = m.rest_positions;
      for (int i : nodes_on_face(m, BoxFace::z_min)) held[std::size_t(3 * i + 2)] = 1;
      for (int i : nodes_on_face(m, BoxFace::z_max)) held[std::size_t(3 * i + 2)] = 1, start(2, i) -= strain * height;
      // rigid motion: the bottom face's centre in x and y, the middle of its x_max edge in y
      int centre = -1, edge = -1;
      for (int i = 0; i < nn; ++i) {
        const Eigen::Vector3d q = m.rest_positions.col(i);
        if ((q - Eigen::Vector3d(2, 2, 0)).norm() < 1e-9) centre = i;
        if ((q - Eigen::Vector3d(4, 2, 0)).norm() < 1e-9) edge = i;
      }
      ASSERT_GE(centre, 0);
      ASSERT_GE(edge, 0);
      held[std::size_t(3 * centre)] = held[std::size_t(3 * centre + 1)] = held[std::size_t(3 * edge + 1)] = 1;
      const Eigen::Matrix3Xd x = newton_static_positions(*p, start, held, Eigen::Vector3d::Zero());
      // every held coordinate where it was put; every node where the uniform strain puts it
      for (int i = 0; i < nn; ++i)
        for (int a = 0; a < 3; ++a)
          if (held[std::size_t(3 * i + a)]) {
            EXPECT_EQ(x(a, i), start(a, i));
          }
      double worst = 0;
      for (int i = 0; i < nn; ++i) {
        const Eigen::Vector3d q = m.rest_positions.col(i);
        const Eigen::Vector3d u(nu * strain * (q.x() - 2), nu * strain * (q.y() - 2), -strain * q.z());
        worst = std::max(worst, (x.col(i) - q - u).norm());
      }
      // the finite strain's share: of order strain^2 / (1 - 2 nu) of the 4e-4 mm moved (the volume
      // term keeps det F, not tr eps)
      EXPECT_LT(worst, 0.01 * nu * strain * 2)
          << to_string(r) << " layout, nu " << nu << ": the farthest node from the uniform strain, mm";
    }
}

TEST(StaticNewton, RefusesHeldCoordinatesOfTheWrongSize) {
  const auto p = bar(Layout::voxel, 0.0);
  EXPECT_THROW(
      (void)newton_static_positions(*p, p->model->rest_positions, HeldCoordinates(3, 1), Eigen::Vector3d::Zero()),
      Error);
}
