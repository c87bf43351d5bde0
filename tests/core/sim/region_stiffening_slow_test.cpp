// The regional solves' over-stiffening (region_stiffening.h): the estimate against what the
// solver itself does. A 64 x 64 x 128 mm column of 4 mm voxels (524 g) is pressed at the centre of
// its top by a force on the nodes under a 4 mm tool, held either at an 8 x 8 mm patch of its
// base (a stem) or over its lower third; regional solves within 30 mm of the tool at 30 ms steps
// (the fast configuration of large models). Measured: the press's compliance (mean displacement under the
// tool per newton) of the whole model (the static solve, iterated to convergence) against the
// implicit integrator's regional solves at 30 ms steps stepped until they settle.
#include "sim/region_stiffening.h"

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

#include "physics/calibration.h"
#include "sim/integrators.h"
#include "sim/projective_solver.h"
#include "sim/state.h"
#include "support/physics_helpers.h"

namespace vx {
namespace {

using testing::hand_block;

constexpr double kSpacing = 4.0;  // mm
constexpr double kToolRadius = 4.0, kRegionRadius = 30.0, kDt = 0.03;
constexpr int kCells = 16;  // the column is kCells x kCells x 2 kCells voxels
constexpr double kMid = 0.5 * kCells * kSpacing, kHeight = 2 * kCells * kSpacing;
constexpr double kForce = 2e-3;  // N in total, small: the linear range

Material tissue() {
  Material m;
  m.youngs_modulus_kpa = 10.0;
  m.density_kg_m3 = 1000.0;
  m.damping_ratio = 0.2;
  return m;
}

struct Column {
  SimState state;
  Eigen::Vector3d tool{0, 0, 0};
  std::vector<int> load;  ///< nodes under the tool
};

/// The column held at a stem (true) or over its lower third.
Column column(bool stem) {
  auto physics = make_physics_model(hand_block(kCells, kCells, 2 * kCells, kSpacing), tissue());
  Column c{make_state(physics), Eigen::Vector3d::Zero(), {}};
  const Eigen::Matrix3Xd& x = physics->model->rest_positions;
  std::vector<int> held;
  for (int i = 0; i < c.state.num_nodes(); ++i) {
    const Eigen::Vector3d p = x.col(i);
    if (stem ? (p.z() < 1e-9 && std::abs(p.x() - kMid) <= 4 + 1e-9 && std::abs(p.y() - kMid) <= 4 + 1e-9)
             : p.z() <= kHeight / 3 + 1e-9)
      held.push_back(i);
  }
  c.state.fix_nodes(held);
  c.tool = Eigen::Vector3d(kMid, kMid, kHeight + kToolRadius);
  const Eigen::Vector3d top(kMid, kMid, kHeight);
  for (int i = 0; i < c.state.num_nodes(); ++i)
    if ((x.col(i) - top).norm() <= kToolRadius + 1e-9) c.load.push_back(i);
  return c;
}

RegionStiffeningEstimate estimate(const Column& c, bool rotation_curvature = false) {
  RegionStiffeningSettings s;
  s.rotation_curvature = rotation_curvature;
  s.tool_mm = c.tool;
  s.tool_radius_mm = kToolRadius;
  s.region_radius_mm = kRegionRadius;
  s.time_step_s = kDt;
  return estimate_region_stiffening(*c.state.physics, c.state.node_fixed, s);
}

/// Mean downward displacement of the loaded nodes per newton, mm/N.
double compliance(const Column& c, const Eigen::Matrix3Xd& x) {
  double d = 0;
  for (int i : c.load) d += c.state.physics->model->rest_positions(2, i) - x(2, i);
  return d / double(c.load.size()) / kForce;
}

/// The whole model's static press (no mass), iterated until nothing moves.
double static_compliance(Column c) {
  ProjectiveSetup setup;
  setup.inertia = false;
  setup.time_step_s = 1.0;
  ProjectiveSolver solver(c.state.physics, c.state.node_fixed, setup);
  Eigen::Matrix3Xd x = c.state.positions;
  for (std::size_t f = 0; f < solver.free_nodes().size(); ++f) {
    const int i = solver.free_nodes()[f];
    solver.constant_rhs().row(Eigen::Index(f)).setZero();
    for (int l : c.load)
      if (l == i) solver.constant_rhs()(Eigen::Index(f), 2) = -kForce / double(c.load.size());
  }
  ProjectiveIterations its;
  its.max_iterations = 200;
  its.tolerance_mm = 1e-7;
  its.threads = 1;
  StepReport rep;
  solver.solve(c.state, x, its, nullptr, rep);
  EXPECT_LT(rep.max_update_mm, 1e-6);
  return compliance(c, x);
}

/// The implicit integrator's regional solves (the nodes within kRegionRadius of the tool awake):
/// `steps` steps of kDt with the force on, 3 iterations each; returns the compliance at the end.
/// `far_degree`: the far field held (0: what the estimate models) or carried
/// (ProjectiveSolver::set_carry_far_field).
double regional_compliance(Column c, int steps, bool region = true, int far_degree = 0) {
  const PhysicsModel& p = *c.state.physics;
  ProjectiveSetup setup;
  setup.time_step_s = kDt;
  setup.damping = p.damped;
  ProjectiveSolver solver(c.state.physics, c.state.node_fixed, setup);
  std::vector<int> awake;
  for (int i = 0; i < c.state.num_nodes(); ++i)
    if (!c.state.node_fixed[std::size_t(i)] && (c.state.positions.col(i) - c.tool).norm() <= kRegionRadius)
      awake.push_back(i);
  solver.set_carry_far_field(far_degree);
  if (region) solver.set_region(awake);
  for (int i : c.load) c.state.external_forces(2, i) = -kForce / double(c.load.size());
  ProjectiveIterations its;
  its.max_iterations = 3;
  its.threads = 1;
  for (int n = 0; n < steps; ++n) {
    Eigen::Matrix3Xd x = c.state.positions + kDt * c.state.velocities;
    for (std::size_t f = 0; f < solver.free_nodes().size(); ++f) {
      const int i = solver.free_nodes()[f];
      const double m = p.node_mass[std::size_t(i)];
      const Eigen::Vector3d y = x.col(i) + kDt * kDt * c.state.external_forces.col(i) / m;
      solver.constant_rhs().row(Eigen::Index(f)) = (m / (kDt * kDt)) * y.transpose();
    }
    StepReport rep;
    solver.solve(c.state, x, its, nullptr, rep);
    c.state.velocities = (x - c.state.positions) / kDt;
    c.state.positions = x;
  }
  return compliance(c, c.state.positions);
}

TEST(RegionStiffening, TheEstimateMatchesTheRegionalSolvesOnAStemAndOnABase) {
  for (const bool stem : {true, false}) {
    SCOPED_TRACE(stem ? "stem" : "base");
    const Column c = column(stem);
    const RegionStiffeningEstimate e = estimate(c);
    ASSERT_TRUE(e.valid) << e.reason;
    EXPECT_GT(e.far_nodes, 0);
    EXPECT_GT(e.region_nodes, 0);
    EXPECT_GT(e.load_nodes, 4);
    const double full = static_compliance(c), regional = regional_compliance(c, 100);
    const double measured = full / regional;
    std::cout << (stem ? "stem" : "base") << ": estimated ratio " << e.force_ratio << " (c " << e.compliance_full_mm_n
              << " / " << e.compliance_region_mm_n << " mm/N, " << e.iterations_full << " + " << e.iterations_region
              << " CG iterations, " << e.seconds << " s); measured " << measured << " (c " << full << " / " << regional
              << " mm/N)\n";
    // the estimate holds every node outside the radius by m/dt^2; the solver also keeps the
    // region's ancestors in the factor's elimination tree awake (separator planes across the
    // model), so the estimate is high: on the safe side (measured: 1.51 against 1.38 on the stem)
    EXPECT_NEAR(e.force_ratio, measured, 0.25 * measured);
    EXPECT_GE(e.force_ratio, measured);
    if (stem) {
      EXPECT_GT(e.force_ratio, 1.3);
      EXPECT_GT(measured, 1.3);
      // carried (the default), the far field's inertia follows and only its rotations stay held:
      // measured 1.16 against 1.38 held
      const double carried = full / regional_compliance(c, 100, true, 1);
      std::cout << "stem, the far field carried: measured " << carried << "\n";
      EXPECT_LT(carried - 1.0, 0.6 * (measured - 1.0));
    } else {
      EXPECT_LT(e.force_ratio, 1.05);
      EXPECT_LT(measured, 1.05);
    }
    // the tangent (with the rotation curvature) gives the converged static press's compliance
    // itself, and the same ratio
    const RegionStiffeningEstimate t = estimate(c, true);
    ASSERT_TRUE(t.valid) << t.reason;
    EXPECT_NEAR(t.compliance_full_mm_n, full, 0.01 * full);
    EXPECT_NEAR(t.force_ratio, e.force_ratio, 0.02 * e.force_ratio);
  }
}

TEST(RegionStiffening, WithoutARegionTheImplicitStepsSettleToTheStaticPress) {
  // the same stepping without a region gives: the stiffening is the region's, not the step's
  const Column c = column(true);
  const double full = static_compliance(c), stepped = regional_compliance(c, 150, false);
  EXPECT_NEAR(stepped, full, 0.05 * full);
}

TEST(RegionStiffening, NoEstimateWithoutAHold) {
  auto physics = make_physics_model(hand_block(3, 3, 3, kSpacing), tissue());
  RegionStiffeningSettings s;
  s.tool_mm = Eigen::Vector3d(3, 3, 10);
  const RegionStiffeningEstimate e =
      estimate_region_stiffening(*physics, std::vector<std::uint8_t>(std::size_t(physics->num_nodes()), 0), s);
  EXPECT_FALSE(e.valid);
  EXPECT_NE(e.reason.find("floats"), std::string::npos);
}

TEST(RegionStiffening, ARegionOverTheWholeModelChangesNothing) {
  const Column c = column(true);
  RegionStiffeningSettings s;
  s.tool_mm = c.tool;
  s.region_radius_mm = 1000.0;
  const RegionStiffeningEstimate e = estimate_region_stiffening(*c.state.physics, c.state.node_fixed, s);
  ASSERT_TRUE(e.valid);
  EXPECT_EQ(e.far_nodes, 0);
  EXPECT_DOUBLE_EQ(e.force_ratio, 1.0);
}

}  // namespace
}  // namespace vx
