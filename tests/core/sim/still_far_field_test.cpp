// The regional solves' still far field: the contact's broad phase and re-check, and the implicit
// step's node passes, look at the region's closure only while the far field is held still
// (ContactProvider::watch_moving, ProjectiveSolver::still_far_field_nodes). Exact: the same
// rebuilds, constraints, forces and positions, bit for bit, as looking at every node. And the same
// regional press with the factor swept in single precision, within the floats' rounding.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <memory>
#include <vector>

#include "model/gradational_builder.h"
#include "model/voxel_shapes.h"
#include "physics/calibration.h"
#include "sim/contact.h"
#include "sim/integrators.h"
#include "sim/probe.h"
#include "sim/projective_solver.h"
#include "sim/simulation.h"
#include "sim/sparse_factor.h"
#include "sim/state.h"

namespace vx {
namespace {

/// A flat sheet of n x n nodes at z = 0 on a 1 mm lattice, centred on the origin.
Eigen::Matrix3Xd sheet(int n) {
  Eigen::Matrix3Xd x(3, n * n);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) x.col(i + n * j) = Eigen::Vector3d(i - (n - 1) / 2.0, j - (n - 1) / 2.0, 0.0);
  return x;
}

TEST(StillFarField, TheBroadPhaseUnderThePromiseRebuildsAndFindsAsEveryNodeDoes) {
  // 40 x 40 nodes (two chunks of the check), a ball of 3 mm above the left half; the left half
  // is watched (it moves), the right half is not. One node of the right half moved 1.2 mm before
  // the period began: the watched checks must carry that move, or they rebuild too late.
  const int n = 40;
  Eigen::Matrix3Xd x = sheet(n);
  std::vector<std::int32_t> ids(std::size_t(n * n));
  for (int i = 0; i < n * n; ++i) ids[std::size_t(i)] = i;
  std::vector<int> watched;
  for (int i = 0; i < n * n; ++i)
    if (x(0, i) < 0.0) watched.push_back(i);
  ProbeGeometry g;
  g.shape = ProbeShape::sphere;
  g.radius_mm = 3.0;
  const std::vector<ProbeGeometry> geometry = {g};
  std::vector<ProbeState> probes = {{Eigen::Vector3d(-8.0, 0.0, 3.2), Eigen::Vector3d::Zero()}};
  ContactSettings cs;
  cs.skin_mm = 2.0;
  ContactSolver every, promised;
  every.init(ids, 1, {}, cs, 1.0);
  promised.init(ids, 1, {}, cs, 1.0);
  std::vector<ContactConstraint> a, b;
  const auto collect_both = [&](const char* when) {
    a.clear();
    b.clear();
    every.collect(x, geometry, probes, true, a);
    promised.collect(x, geometry, probes, true, b);
    EXPECT_EQ(every.counters().rebuilds, promised.counters().rebuilds) << when;
    ASSERT_EQ(a.size(), b.size()) << when;
    for (std::size_t k = 0; k < a.size(); ++k) {
      EXPECT_EQ(a[k].node, b[k].node) << when;
      EXPECT_EQ(a[k].point_mm, b[k].point_mm) << when;
    }
  };
  collect_both("at rest");
  const int far = n * n - 1;  // the right half's corner
  x(2, far) = 1.2;
  promised.watch_moving(&watched, 7);
  collect_both("the period's first check");
  // the watched nodes rise a little and the ball comes down 0.2 mm a time: the far node's
  // 1.2 mm, the ball's 0.4 mm and the margin's 0.5 mm reach the skin of 2 mm at the second move
  // (the watched nodes' own moves alone would not, so a check that forgot the far node's move
  // would rebuild later); then again after the rebuild
  const std::int64_t rebuilds_before = every.counters().rebuilds;
  for (int t = 1; t <= 12; ++t) {
    for (const int i : watched) x(2, i) = 0.02 * t * std::exp(-0.01 * x.col(i).head<2>().squaredNorm());
    probes[0].position_mm.z() -= 0.2;
    collect_both("a watched move");
    if (t == 2) {
      EXPECT_GT(every.counters().rebuilds, rebuilds_before) << "the far node's move did not count";
    }
    if (t == 5) {
      // a pause checks every node and keeps the others' move; the same period resumes it
      promised.watch_moving(nullptr, 7);
      collect_both("paused");
      promised.watch_moving(&watched, 7);
    }
  }
  EXPECT_GE(every.counters().rebuilds, rebuilds_before + 2) << "the moves reached the skin once only";
  EXPECT_GT(promised.watched_checks(), 8);
  EXPECT_FALSE(a.empty()) << "the ball touched nothing: the test shows nothing";
  // a period ended by invalidate() starts again with a check of every node
  promised.invalidate();
  every.invalidate();
  const std::int64_t checks = promised.watched_checks();
  promised.watch_moving(&watched, 7);
  collect_both("after invalidate");
  EXPECT_EQ(promised.watched_checks(), checks);
}

/// A gradational ball of n voxels across (1 mm voxels, radius n/2 - 1), Poisson 0.45.
std::shared_ptr<const PhysicsModel> ball_model(int n) {
  Material m;
  m.youngs_modulus_kpa = 10.0;
  m.density_kg_m3 = 1000.0;
  m.damping_ratio = 0.2;
  m.poisson_ratio = 0.45;
  return make_physics_model(std::make_shared<const Model>(build_model(ball_grid(n, 0.5 * n - 1.0))), m);
}

/// A press on a 32-voxel ball held at its bottom 3 mm: pressed 2.5 mm by a ball of 3 mm and slid
/// 6 mm (the region, 8 mm, moves with it), then lifted; implicit 20 ms steps of one iteration (up
/// to four while the ball is off) on two threads.
SimulationSettings ball_press(const Model& m) {
  const Eigen::Vector3d c = 0.5 * (m.rest_positions.rowwise().minCoeff() + m.rest_positions.rowwise().maxCoeff());
  const double ztop = m.rest_positions.row(2).maxCoeff();
  SimulationSettings ss;
  ss.integrator.kind = IntegratorKind::implicit;
  ss.integrator.time_step_s = 0.02;
  ss.integrator.max_iterations = 1;
  ss.integrator.region_radius_mm = 8.0;
  ss.integrator.threads = 2;
  // while no tool touches, up to 4 iterations while a node moves more than 1 um: the iterations
  // count on the largest move, every node's
  ss.integrator.free_iterations = 4;
  ss.integrator.free_tolerance_mm = 1e-3;
  const double zmin = m.rest_positions.row(2).minCoeff();
  for (int i = 0; i < m.num_nodes(); ++i)
    if (m.rest_positions(2, i) <= zmin + 3.0) ss.fixed_nodes.push_back(i);
  ProbeSettings probe;
  probe.name = "ball";
  probe.geometry.radius_mm = 3.0;
  probe.path = {{0.0, {c.x() - 3.0, c.y(), ztop + 3.5}},
                {0.5, {c.x() - 3.0, c.y(), ztop + 0.5}},
                {1.1, {c.x() + 3.0, c.y(), ztop + 0.5}},
                {1.4, {c.x() + 3.0, c.y(), ztop + 4.0}},
                {1.8, {c.x() + 3.0, c.y(), ztop + 4.0}}};
  ss.probes = {probe};
  return ss;
}

TEST(StillFarField, ARegionalPressIsTheSameBitForBitAsOneThatVisitsEveryNode) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  // ball_press(). The other run saves and restores its tissue before every step: that changes
  // nothing but the state's positions_version, so the regional solves never hold the far field
  // still and every pass visits every node.
  const auto p = ball_model(32);
  const SimulationSettings ss = ball_press(*p->model);
  Simulation held(p, ss), visited(p, ss);
  TissueSnapshot snap;
  int steps = 0;
  double peak = 0.0;
  while (held.time_s() < 1.8 - 1e-9 && !held.failed() && !visited.failed()) {
    visited.save_tissue(snap);
    visited.restore_tissue(snap);
    held.step();
    visited.step();
    ++steps;
    ASSERT_EQ(held.probe(0).raw_force_n, visited.probe(0).raw_force_n) << "step " << steps;
    ASSERT_TRUE(held.state().positions == visited.state().positions) << "step " << steps;
    ASSERT_TRUE(held.state().velocities == visited.state().velocities) << "step " << steps;
    peak = std::max(peak, held.probe(0).raw_force_n.z());
  }
  ASSERT_FALSE(held.failed()) << held.state().message;
  ASSERT_FALSE(visited.failed()) << visited.state().message;
  EXPECT_GT(peak, 0.005) << "the ball pressed nothing: the test shows nothing";
  const ProjectiveSolver& solver = *held.state().integrator_cache.solver;
  EXPECT_GT(solver.steady_solves(), steps / 2) << "the far field was hardly ever held still";
  EXPECT_GT(solver.closure_pass_solves(), steps / 3) << "the right-hand side hardly ever gathered on the closure only";
  EXPECT_EQ(visited.state().integrator_cache.solver->steady_solves(), 0);
  EXPECT_EQ(visited.state().integrator_cache.solver->closure_pass_solves(), 0);
  EXPECT_LT(solver.region_nodes(), std::int64_t(solver.free_nodes().size()));
}

// The closure-only passes (ProjectiveIterations::inputs_given, docs/model.md section 7, "Passes
// over the closure only"), at the solver: a 24-voxel ball held at its bottom 3 mm, sagging under
// gravity with its top 8 mm solved, gives the every-row passes' positions bit for bit, across a
// force on one node of the far field (step 15) and a turn of gravity (from step 25). The far rows
// of the right-hand side change then, and the closure's answer with them (through the forward
// solution's shared ancestors): passes that missed it would not be bit for bit.
TEST(ClosurePasses, GiveTheEveryRowPassesBitForBitAcrossAFarForceAndAGravityTurn) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  const auto p = ball_model(24);
  const Model& m = *p->model;
  const double dt = 0.02, zmin = m.rest_positions.row(2).minCoeff(), ztop = m.rest_positions.row(2).maxCoeff();
  SimState start = make_state(p);
  std::vector<int> held;
  for (int i = 0; i < m.num_nodes(); ++i)
    if (m.rest_positions(2, i) <= zmin + 3.0) held.push_back(i);
  start.fix_nodes(held);
  ProjectiveSetup setup;
  setup.time_step_s = dt;
  setup.inertia = true;
  setup.damping = p->damped;
  ProjectiveSolver on(p, start.node_fixed, setup), off(p, start.node_fixed, setup);
  off.set_region_diagnostics(false, true, true);  // never holds the far field still: every row, every solve
  for (ProjectiveSolver* solver : {&on, &off})
    solver->set_carry_far_field(0);  // held still, as the integrator's default
  std::vector<int> top;
  int far = -1;
  for (int i = 0; i < m.num_nodes(); ++i) {
    if (start.node_fixed[std::size_t(i)]) continue;
    if (m.rest_positions(2, i) >= ztop - 8.0)
      top.push_back(i);
    else if (m.rest_positions(2, i) <= zmin + 5.0 && (far < 0 || m.rest_positions(0, i) < m.rest_positions(0, far)))
      far = i;  // the lowest free layer's leftmost node
  }
  on.set_region(top);
  off.set_region(top);
  ASSERT_GE(far, 0);
  SimState a = start, b = start;
  const auto step = [&](ProjectiveSolver& solver, SimState& s, const Eigen::Vector3d& g) {
    Eigen::Matrix3Xd x = s.positions + dt * s.velocities;
    bool pushed = false;
    for (std::size_t f = 0; f < solver.free_nodes().size(); ++f) {
      const int i = solver.free_nodes()[f];
      const double mass = p->node_mass[std::size_t(i)];
      pushed = pushed || !s.external_forces.col(i).isZero(0.0);
      const Eigen::Vector3d y =
          x.col(i) + dt * dt * (p->node_gravity_ratio[std::size_t(i)] * g + s.external_forces.col(i) / mass);
      solver.constant_rhs().row(Eigen::Index(f)) = (mass / (dt * dt)) * y.transpose();
    }
    ProjectiveIterations its;
    its.max_iterations = 2;
    its.threads = 2;
    its.inputs_given = true;
    its.gravity_mm_s2 = g;
    its.external_forces = pushed;
    StepReport rep;
    solver.solve(s, x, its, nullptr, rep);
    s.velocities = (x - s.positions) / dt;
    s.positions = x;
  };
  std::int64_t before_force = 0, before_turn = 0;
  for (int n = 0; n < 40; ++n) {
    const Eigen::Vector3d g = n < 25 ? Eigen::Vector3d(0, 0, -9810) : Eigen::Vector3d(4000, 0, -9810);
    for (SimState* s : {&a, &b})
      s->external_forces.col(far) = n == 15 ? Eigen::Vector3d(0.0, 0.0, -0.05) : Eigen::Vector3d::Zero();
    if (n == 15) before_force = on.closure_pass_solves();
    if (n == 25) before_turn = on.closure_pass_solves();
    step(on, a, g);
    step(off, b, g);
    ASSERT_TRUE(a.positions == b.positions) << "step " << n;
  }
  // the closure's passes ran from the third regional solve on, but not at the force nor the
  // solve after it (the force gone: its row changed again), nor at the turn: solves 3-14, 17-24
  // and 26-39
  EXPECT_EQ(before_force, 12);
  EXPECT_EQ(before_turn - before_force, 8);
  EXPECT_EQ(on.closure_pass_solves() - before_turn, 14);
  EXPECT_EQ(off.closure_pass_solves(), 0);
  EXPECT_GT((a.positions - start.positions).colwise().norm().maxCoeff(), 0.05)
      << "nothing sagged: the test shows nothing";
  EXPECT_LT(on.region_nodes(), std::int64_t(on.free_nodes().size()));
}

// Single-precision sweeps (IntegratorSettings::single_precision_sweeps, docs/bench.md): the same
// press feels the same force within the floats' rounding, on a factor a third smaller.
TEST(SinglePrecisionSweeps, ARegionalPressFeelsTheDoubleSweepsForceWithinTheirRounding) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  const auto p = ball_model(32);
  const SimulationSettings twice = ball_press(*p->model);
  SimulationSettings once = twice;
  once.integrator.single_precision_sweeps = true;
  Simulation a(p, twice), b(p, once);
  double peak = 0.0, worst = 0.0;
  int differ = 0;
  while (a.time_s() < 1.8 - 1e-9 && !a.failed() && !b.failed()) {
    a.step();
    b.step();
    const double d = (a.probe(0).raw_force_n - b.probe(0).raw_force_n).norm();
    worst = std::max(worst, d);
    differ += d > 0.0 ? 1 : 0;
    peak = std::max(peak, a.probe(0).raw_force_n.z());
  }
  ASSERT_FALSE(a.failed()) << a.state().message;
  ASSERT_FALSE(b.failed()) << b.state().message;
  EXPECT_GT(peak, 0.005) << "the ball pressed nothing: the test shows nothing";
  std::cout << "single-precision sweeps: largest force difference " << worst << " N of a " << peak << " N peak\n";
  EXPECT_LT(worst, 2e-4 * peak);  // 3.4e-5 of it measured (AVX-512); a step's rounding carried by the next
  EXPECT_GT(differ, 0) << "the same forces: the single-precision sweeps did not run";
  const SparseFactor& fa = a.state().integrator_cache.solver->factor();
  const SparseFactor& fb = b.state().integrator_cache.solver->factor();
  EXPECT_FALSE(fa.single_precision_sweeps());
  EXPECT_TRUE(fb.single_precision_sweeps());
  EXPECT_LT(double(fb.stored_bytes()), 0.6 * double(fa.stored_bytes()));
  EXPECT_LT((a.state().positions - b.state().positions).cwiseAbs().maxCoeff(), 5e-4);  // mm; 5.3e-5 measured
}

}  // namespace
}  // namespace vx
