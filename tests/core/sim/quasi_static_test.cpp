// The levers of quasi-static palpation (docs/model.md sections 6 and 7, docs/bench.md "Palpation
// at organ size"): mass scaling changes the dynamics and not the equilibrium, raises the stable
// step as derived, and keeps gravity's weight physical; the implicit integrator's residual stop
// reaches its tolerance; 1 and 2 threads give the same bits with
// the fast configuration.
#include <gtest/gtest.h>
#include <omp.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <future>
#include <iostream>
#include <set>
#include <thread>
#include <utility>

#include "base/error.h"
#include "model/gradational_builder.h"
#include "physics/calibration.h"
#include "sim/integrators.h"
#include "sim/projective_solver.h"
#include "sim/sparse_factor.h"
#include "sim/state.h"
#include "sim/static_solver.h"
#include "sim/time_step.h"
#include "support/physics_helpers.h"
#include "support/sparse_helpers.h"

namespace vx {
namespace {

using testing::hand_block;

Material tissue(double damping) {
  Material m;
  m.youngs_modulus_kpa = 10.0;
  m.density_kg_m3 = 1000.0;
  m.damping_ratio = damping;
  return m;
}

/// A gradational ball of `n` voxels across (1 mm), the cap below z_min + 2 mm fixed.
/// A ball of radius n/2 - 1 voxels centred in an n^3 grid of 1 mm voxels, gradational.
std::shared_ptr<const Model> ball(int n) {
  GridGeometry g;
  g.dims = {n, n, n};
  g.spacing_mm = Eigen::Vector3d::Ones();
  VoxelGrid grid(g);
  const double c = 0.5 * (n - 1), r = 0.5 * n - 1.0;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i)
        grid.set(i, j, k, (i - c) * (i - c) + (j - c) * (j - c) + (k - c) * (k - c) <= r * r ? 1 : 0);
  return std::make_shared<const Model>(build_model(grid));
}

std::vector<int> bottom_cap(const Model& m, double within_mm) {
  const double zmin = m.rest_positions.row(2).minCoeff();
  std::vector<int> out;
  for (int i = 0; i < m.num_nodes(); ++i)
    if (m.rest_positions(2, i) <= zmin + within_mm) out.push_back(i);
  return out;
}

/// Runs symplectic Euler at the automatic step from rest under gravity and a push on the top
/// nodes until `t_end`; returns the positions.
Eigen::Matrix3Xd settle(const std::shared_ptr<const PhysicsModel>& p, double t_end, int threads = 1) {
  SimState s = make_state(p);
  s.fix_nodes(bottom_cap(*p->model, 3.0));
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  const double ztop = p->model->rest_positions.row(2).maxCoeff();
  for (int i = 0; i < s.num_nodes(); ++i)
    if (p->model->rest_positions(2, i) >= ztop - 1.5) s.external_forces(2, i) = -2e-4;  // N per node
  IntegratorSettings set;
  set.kind = IntegratorKind::symplectic_euler;
  set.time_step_s = automatic_time_step(estimate_time_steps(*p), set.kind);
  set.threads = threads;
  auto integ = make_integrator(set);
  integ->advance(s, int(std::ceil(t_end / set.time_step_s)));
  EXPECT_FALSE(s.failed()) << s.message;
  return s.positions;
}

TEST(MassScaling, RaisesTheStableStepAsDerivedAndKeepsTheWeight) {
  const auto model = ball(16);
  const auto plain = make_physics_model(model, tissue(0.2));
  const TimeStepEstimate e0 = estimate_time_steps(*plain);
  // a uniform factor s: every frequency / sqrt(s); the (damped) stable step grows by about sqrt(s)
  CalibrationOptions opt;
  opt.mass_scaling.factor = 16.0;
  const auto scaled = make_physics_model(model, tissue(0.2), {}, opt);
  const TimeStepEstimate e1 = estimate_time_steps(*scaled);
  std::cout << "stable step " << e0.symplectic_euler_s << " s -> x16 mass " << e1.symplectic_euler_s << " s\n";
  EXPECT_NEAR(e1.highest_frequency_hz, e0.highest_frequency_hz / 4.0, 1e-9 * e0.highest_frequency_hz);
  EXPECT_GT(e1.symplectic_euler_s, 3.9 * e0.symplectic_euler_s);
  EXPECT_NEAR(scaled->added_mass_kg, 15.0 * plain->total_mass_kg(), 1e-9 * plain->total_mass_kg());
  EXPECT_EQ(scaled->scaled_nodes, scaled->num_nodes());
  // the floor: only the nodes that need it get mass; the estimate reaches twice the target
  const double target = e0.symplectic_euler_s;
  CalibrationOptions fl;
  fl.mass_scaling.time_step_s = target;
  const auto floored = make_physics_model(model, tissue(0.2), {}, fl);
  const TimeStepEstimate e2 = estimate_time_steps(*floored);
  std::cout << "floor for " << target << " s: stable step " << e2.symplectic_euler_s << " s, " << floored->scaled_nodes
            << " of " << floored->num_nodes() << " nodes heavier, mass +"
            << 100 * floored->added_mass_kg / plain->total_mass_kg() << " %\n";
  EXPECT_GE(e2.symplectic_euler_s, (1.0 - 1e-6) * 2.0 * target);
  EXPECT_GT(floored->scaled_nodes, 0);
  EXPECT_LT(floored->scaled_nodes, floored->num_nodes());
  EXPECT_NEAR(automatic_time_step(e2, IntegratorKind::symplectic_euler), 0.5 * e2.symplectic_euler_s, 1e-15);
  // gravity acts on the physical mass
  for (int i = 0; i < floored->num_nodes(); ++i)
    EXPECT_NEAR(floored->node_mass[std::size_t(i)] * floored->node_gravity_ratio[std::size_t(i)],
                plain->node_mass[std::size_t(i)], 1e-12 * plain->node_mass[std::size_t(i)]);
  // invalid settings are refused
  CalibrationOptions bad;
  bad.mass_scaling.factor = 0.5;
  EXPECT_THROW((void)make_physics_model(model, tissue(0.2), {}, bad), Error);
}

TEST(MassScaling, LeavesTheStaticSolutionUnchanged) {
  // the equilibrium under gravity and a push on the top: the static solve, and symplectic Euler
  // run to rest with and without scaling, all agree (scaling changes how it gets there)
  const auto model = ball(12);
  const auto plain = make_physics_model(model, tissue(0.5));
  CalibrationOptions opt;
  opt.mass_scaling.factor = 4.0;
  opt.mass_scaling.time_step_s =
      2.0 * automatic_time_step(estimate_time_steps(*plain), IntegratorKind::symplectic_euler);
  const auto scaled = make_physics_model(model, tissue(0.5), {}, opt);
  SimState st = make_state(scaled);
  st.fix_nodes(bottom_cap(*model, 3.0));
  st.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  const double ztop = model->rest_positions.row(2).maxCoeff();
  for (int i = 0; i < st.num_nodes(); ++i)
    if (model->rest_positions(2, i) >= ztop - 1.5) st.external_forces(2, i) = -2e-4;
  SimState st_plain = st;
  st_plain.physics = plain;
  solve_static(st);
  solve_static(st_plain);
  const double sag = (st_plain.positions - model->rest_positions).colwise().norm().maxCoeff();
  EXPECT_LT((st.positions - st_plain.positions).cwiseAbs().maxCoeff(), 1e-9 * std::max(1.0, sag));
  const Eigen::Matrix3Xd x_plain = settle(plain, 0.6), x_scaled = settle(scaled, 0.6);
  const double d_plain = (x_plain - st.positions).cwiseAbs().maxCoeff();
  const double d_scaled = (x_scaled - st.positions).cwiseAbs().maxCoeff();
  std::cout << "largest displacement " << sag << " mm; dynamic runs at rest differ from the static solution by "
            << d_plain << " mm (physical masses) and " << d_scaled << " mm (scaled)\n";
  EXPECT_GT(sag, 0.05);
  EXPECT_LT(d_plain, 0.02 * sag);
  EXPECT_LT(d_scaled, 0.02 * sag);
}

TEST(ImplicitResidual, FallsToItsTolerance) {
  const auto model = ball(12);
  const auto p = make_physics_model(model, tissue(0.2));
  for (double tol : {1e-5, 1e-7}) {
    SimState s = make_state(p);
    s.fix_nodes(bottom_cap(*model, 2.0));
    s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
    IntegratorSettings set;
    set.kind = IntegratorKind::implicit;
    set.time_step_s = 0.02;
    set.max_iterations = 500;
    set.residual_tolerance_n = tol;
    auto integ = make_integrator(set);
    const StepReport r = integ->step(s);
    std::cout << "tolerance " << tol << " N: " << r.iterations << " iterations, largest residual " << r.max_residual_n
              << " N (RMS " << r.residual_n << ")\n";
    EXPECT_LE(r.max_residual_n, tol);
    EXPECT_LT(r.iterations, 500);
    EXPECT_GE(r.iterations, 1);
    EXPECT_LE(r.residual_n, r.max_residual_n);
    // the next step starts from the last: warm, fewer iterations
    const StepReport r2 = integ->step(s);
    EXPECT_LE(r2.max_residual_n, tol);
    EXPECT_LE(r2.iterations, r.iterations);
  }
}

TEST(FastConfiguration, OneAndTwoThreadsGiveTheSameBits) {
  const auto model = ball(12);
  CalibrationOptions opt;
  opt.mass_scaling.time_step_s = 1e-4;
  const auto p = make_physics_model(model, tissue(0.2), {}, opt);
  for (IntegratorKind kind : {IntegratorKind::symplectic_euler, IntegratorKind::implicit}) {
    Eigen::Matrix3Xd ref;
    for (int threads : {1, 2}) {
      SimState s = make_state(p);
      s.fix_nodes(bottom_cap(*model, 2.0));
      s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
      IntegratorSettings set;
      set.kind = kind;
      set.threads = threads;
      set.time_step_s = kind == IntegratorKind::implicit ? 0.01 : 1e-4;
      set.max_iterations = 3;
      set.residual_tolerance_n = 1e-9;
      auto integ = make_integrator(set);
      integ->advance(s, 20);
      ASSERT_FALSE(s.failed()) << s.message;
      if (threads == 1)
        ref = s.positions;
      else
        EXPECT_EQ(std::memcmp(ref.data(), s.positions.data(), sizeof(double) * std::size_t(ref.size())), 0)
            << to_string(kind);
    }
  }
}

// The probe app shares the cores (apps/probe/thread_share.h): its core runs with threads 0 and
// the physics thread changes its own OpenMP setting between steps. The steps give the same bits
// as on one thread throughout.
TEST(FastConfiguration, AThreadCountChangedBetweenStepsGivesTheSameBits) {
  const auto model = ball(12);
  CalibrationOptions opt;
  opt.mass_scaling.time_step_s = 1e-4;
  const auto p = make_physics_model(model, tissue(0.2), {}, opt);
  for (IntegratorKind kind : {IntegratorKind::symplectic_euler, IntegratorKind::implicit}) {
    Eigen::Matrix3Xd runs[2];
    for (int changing : {0, 1}) {
      // on a thread of its own: its OpenMP setting is its own (as the app's physics thread's)
      std::thread([&] {
        SimState s = make_state(p);
        s.fix_nodes(bottom_cap(*model, 2.0));
        s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
        IntegratorSettings set;
        set.kind = kind;
        set.threads = changing ? 0 : 1;
        set.time_step_s = kind == IntegratorKind::implicit ? 0.01 : 1e-4;
        set.max_iterations = 3;
        set.residual_tolerance_n = 1e-9;
        auto integ = make_integrator(set);
        for (int k = 0; k < 20; ++k) {
          if (changing) omp_set_num_threads(k % 3 == 0 ? 1 : 2);
          (void)integ->step(s);
        }
        EXPECT_FALSE(s.failed()) << s.message;
        runs[changing] = s.positions;
      }).join();
    }
    ASSERT_EQ(runs[0].size(), runs[1].size());
    EXPECT_EQ(std::memcmp(runs[0].data(), runs[1].data(), sizeof(double) * std::size_t(runs[0].size())), 0)
        << to_string(kind);
  }
}

}  // namespace
}  // namespace vx

namespace vx {
namespace {

TEST(RegionalSolve, PartialSolvesAreExactOnTheirRows) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  const auto model = ball(16);
  const auto p = make_physics_model(model, tissue(0.0));
  const Model& m = *model;
  const int nn = m.num_nodes();
  const SparseFactor::Matrix a =
      testing::elastic_matrix_plus(*p, [&](int i) { return 1e-2 * p->node_mass[std::size_t(i)] / 1e-8; });
  SparseFactor f;
  ASSERT_TRUE(f.compute(a, SparseFactor::Backend::cholmod));
  ASSERT_TRUE(f.supports_partial());
  Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(nn, 3), x(nn, 3), ref(nn, 3);
  f.solve3(b, x);
  // the rows near the top: a region
  const double ztop = m.rest_positions.row(2).maxCoeff();
  std::vector<int> rows;
  for (int i = 0; i < nn; ++i)
    if (m.rest_positions(2, i) > ztop - 4.0) rows.push_back(i);
  const std::vector<int>& closure = f.set_partial_rows(rows);
  std::cout << rows.size() << " rows wanted, closure " << closure.size() << " of " << nn << " rows\n";
  EXPECT_GE(closure.size(), rows.size());
  EXPECT_LT(closure.size(), std::size_t(nn));
  for (int round = 0; round < 3; ++round) {
    // b changes on a few rows of the region and one far away
    for (int k = 0; k < 5; ++k) b.row(rows[std::size_t(k * 7 % int(rows.size()))]) += Eigen::RowVector3d::Random();
    b.row(round) += Eigen::RowVector3d::Random();
    Eigen::MatrixX3d xp = x;
    const int changed = f.solve3_partial(b, xp);
    EXPECT_EQ(changed, 6);
    SparseFactor full;
    ASSERT_TRUE(full.compute(a, SparseFactor::Backend::cholmod));
    full.solve3(b, ref);
    double err = 0;
    for (int i : closure) err = std::max(err, (xp.row(i) - ref.row(i)).norm());
    EXPECT_LT(err, 1e-10 * ref.norm()) << "round " << round;
    // a unit column on the closure
    std::vector<double> col(static_cast<std::size_t>(nn), 0.0), colref(static_cast<std::size_t>(nn), 0.0);
    f.solve_unit_partial(rows[0], col.data());
    full.solve_unit(rows[0], colref.data());
    double cerr = 0, cmax = 0;
    for (int i : closure)
      cerr = std::max(cerr, std::abs(col[std::size_t(i)] - colref[std::size_t(i)])),
      cmax = std::max(cmax, std::abs(colref[std::size_t(i)]));
    EXPECT_LT(cerr, 1e-10 * cmax);
    // a force at a region row, applied on the closure only: exact there, nothing elsewhere
    SparseFactor::UnitForward z;
    f.forward_unit(rows[1], z);
    Eigen::MatrixX3d part = Eigen::MatrixX3d::Zero(nn, 3), whole = Eigen::MatrixX3d::Zero(nn, 3);
    f.add_response3({&z}, {0.3, -0.1, 0.2}, part, true);
    full.add_response3({&z}, {0.3, -0.1, 0.2}, whole, false);
    std::vector<std::uint8_t> in(static_cast<std::size_t>(nn), 0);
    for (int i : closure) in[std::size_t(i)] = 1;
    double perr = 0, outside = 0;
    for (int i = 0; i < nn; ++i) {
      if (in[std::size_t(i)])
        perr = std::max(perr, (part.row(i) - whole.row(i)).norm());
      else
        outside = std::max(outside, part.row(i).norm());
    }
    EXPECT_LT(perr, 1e-10 * whole.norm());
    EXPECT_EQ(outside, 0.0);
    // the two halves with the force between them (one backward pass): the solve plus the
    // response on the closure, and a row of the solution from its forward vector alone
    b.row(rows[2]) += Eigen::RowVector3d::Random();
    full.solve3(b, ref);
    ASSERT_TRUE(f.partial_ready());
    EXPECT_EQ(f.forward3_partial(b), 1);
    SparseFactor::UnitForward z2;
    f.forward_unit(rows[2], z2);
    const Eigen::Vector3d row2 = f.solution_row(z2);
    EXPECT_LT((row2.transpose() - ref.row(rows[2])).norm(), 1e-10 * ref.norm());
    Eigen::MatrixX3d halves = xp;
    f.backward3_partial({&z}, {0.3, -0.1, 0.2}, halves);
    double herr = 0, hout = 0;
    for (int i = 0; i < nn; ++i) {
      if (in[std::size_t(i)])
        herr = std::max(herr, (halves.row(i) - ref.row(i) - whole.row(i)).norm());
      else
        hout = std::max(hout, (halves.row(i) - xp.row(i)).norm());
    }
    EXPECT_LT(herr, 1e-10 * ref.norm());
    EXPECT_EQ(hout, 0.0);
    x = halves;
  }
}

}  // namespace
}  // namespace vx

#include "physics/calibration.h"
#include "sim/simulation.h"

namespace vx {
namespace {

TEST(RegionalSolve, ForwardFieldsCarryARightHandSideAndGiveItsProducts) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  // b += c g added through the forward field of g gives the solution of b + c g on the closure,
  // and the backward half gives g^T x (x with a contact force) without a pass outside it
  const auto model = ball(16);
  const auto p = make_physics_model(model, tissue(0.0));
  const Model& m = *model;
  const int nn = m.num_nodes();
  const SparseFactor::Matrix a =
      testing::elastic_matrix_plus(*p, [&](int i) { return 1e-2 * p->node_mass[std::size_t(i)] / 1e-8; });
  SparseFactor f, full;
  ASSERT_TRUE(f.compute(a, SparseFactor::Backend::cholmod));
  ASSERT_TRUE(full.compute(a, SparseFactor::Backend::cholmod));
  Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(nn, 3), x(nn, 3), ref(nn, 3);
  f.solve3(b, x);
  const double ztop = m.rest_positions.row(2).maxCoeff();
  std::vector<int> rows;
  for (int i = 0; i < nn; ++i)
    if (m.rest_positions(2, i) > ztop - 4.0) rows.push_back(i);
  const std::vector<int>& closure = f.set_partial_rows(rows);
  // two fields (6 columns), nonzero off the closure only
  std::vector<std::uint8_t> in(static_cast<std::size_t>(nn), 0);
  for (int i : closure) in[std::size_t(i)] = 1;
  Eigen::MatrixXd g = Eigen::MatrixXd::Random(nn, 6);
  for (int i = 0; i < nn; ++i)
    if (in[std::size_t(i)]) g.row(i).setZero();
  std::vector<double> w;
  f.forward_fields(g, w);
  f.set_product_fields(&w, 2);
  const double coef[2] = {0.7, -1.3};
  b.row(rows[0]) += Eigen::RowVector3d::Random();  // a change the forward half sees
  const Eigen::MatrixX3d b_total = b + coef[0] * g.leftCols(3) + coef[1] * g.rightCols(3);
  ASSERT_TRUE(f.partial_ready());
  f.forward3_partial(b);
  f.add_forward_fields(w, 2, coef);
  SparseFactor::UnitForward z;
  f.forward_unit(rows[1], z);
  f.backward3_partial({&z}, {0.3, -0.1, 0.2}, x);
  Eigen::MatrixX3d force = Eigen::MatrixX3d::Zero(nn, 3);
  force.row(rows[1]) << 0.3, -0.1, 0.2;
  full.solve3(b_total + force, ref);
  double err = 0;
  for (int i : closure) err = std::max(err, (x.row(i) - ref.row(i)).norm());
  EXPECT_LT(err, 1e-10 * ref.norm());
  for (int k = 0; k < 2; ++k) {
    const double want = (g.middleCols(3 * k, 3).array() * ref.array()).sum();
    EXPECT_NEAR(f.field_products()[std::size_t(k)], want, 1e-9 * std::abs(want) + 1e-12) << "field " << k;
  }
}

/// A ball pressed 3 mm into the top of a 24-voxel ball by the fast configuration; the force on
/// it at the end, with regional solves of `radius_mm` (0: none).
double pressed_force(const std::shared_ptr<const PhysicsModel>& p, double radius_mm, std::int64_t* region_nodes) {
  SimulationSettings ss;
  // the fast configuration's (pipeline/scene/fast_configuration.h): implicit, 20 ms, one iteration
  ss.integrator.kind = IntegratorKind::implicit;
  ss.integrator.time_step_s = kImplicitAutomaticTimeStepS;
  ss.integrator.max_iterations = 1;
  ss.integrator.region_radius_mm = radius_mm;
  ss.integrator.threads = 1;
  ss.fixed_nodes = bottom_cap(*p->model, 3.0);
  const double ztop = p->model->rest_positions.row(2).maxCoeff();
  const Eigen::Vector3d c =
      0.5 * (p->model->rest_positions.rowwise().minCoeff() + p->model->rest_positions.rowwise().maxCoeff());
  ProbeSettings probe;
  probe.name = "ball";
  probe.geometry.shape = ProbeShape::sphere;
  probe.geometry.radius_mm = 4.0;
  probe.path = {
      {0.0, {c.x(), c.y(), ztop + 4.5}}, {0.5, {c.x(), c.y(), ztop + 1.0}}, {0.7, {c.x() + 1.0, c.y(), ztop + 1.0}}};
  ss.probes = {probe};
  Simulation sim(p, ss);
  while (sim.time_s() < 0.7 - 1e-9 && !sim.failed()) sim.step();
  EXPECT_FALSE(sim.failed()) << sim.state().message;
  if (region_nodes)
    *region_nodes = sim.state().integrator_cache.solver ? sim.state().integrator_cache.solver->region_nodes() : 0;
  return sim.probe(0).raw_force_n.z();
}

/// The regional tests' press: implicit 20 ms steps of one iteration, an 8 mm region, one
/// thread, the bottom 3 mm held, a ball tool of radius 3 mm named "ball" (its path left to the test).
SimulationSettings regional_ball_press(const Model& m) {
  SimulationSettings ss;
  ss.integrator.kind = IntegratorKind::implicit;
  ss.integrator.time_step_s = 0.02;
  ss.integrator.max_iterations = 1;
  ss.integrator.region_radius_mm = 8.0;
  ss.integrator.threads = 1;
  ss.fixed_nodes = bottom_cap(m, 3.0);
  ProbeSettings probe;
  probe.name = "ball";
  probe.geometry.radius_mm = 3.0;
  ss.probes = {probe};
  return ss;
}

TEST(RegionalSolve, TheForceOfAPressMatchesTheFullSolve) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  const auto p = make_physics_model(ball(24), tissue(0.2));
  std::int64_t all = 0, some = 0;
  const double full = pressed_force(p, 0.0, nullptr);
  const double everywhere = pressed_force(p, 100.0, &all);
  const double region = pressed_force(p, 12.0, &some);
  std::cout << "force " << full << " N (full solves), " << everywhere << " N (region over everything, " << all
            << " nodes), " << region << " N (region of 12 mm: " << some << " of " << p->num_nodes() << " nodes)\n";
  EXPECT_GT(full, 0.01);
  EXPECT_NEAR(everywhere, full, 1e-8 * full);
  EXPECT_NEAR(region, full, 0.05 * full);
  EXPECT_LT(some, all);
}

}  // namespace
}  // namespace vx

namespace vx {
namespace {

TEST(RegionalSolve, ASleepingNodeWakesWhenPressed) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  // a 32-voxel ball; a ball tool presses the top at x = -8 mm, then moves over to x = +8 mm and
  // presses there; with an 8 mm region, a surface node near x = +8 sleeps (does not move at all)
  // during the first press and moves when the tool comes to it
  const auto p = make_physics_model(ball(32), tissue(0.2));
  const Model& m = *p->model;
  const Eigen::Vector3d c = 0.5 * (m.rest_positions.rowwise().minCoeff() + m.rest_positions.rowwise().maxCoeff());
  const double ztop = m.rest_positions.row(2).maxCoeff();
  // candidates near x = +8 on the top; the one watched is the nearest that the first press's
  // region leaves asleep (outside the region's closure in the factor)
  std::vector<std::pair<double, int>> near_plus;
  for (int i = 0; i < m.num_nodes(); ++i) {
    const Eigen::Vector3d x = m.rest_positions.col(i);
    if (x.z() > ztop - 4.0) near_plus.emplace_back(std::hypot(x.x() - (c.x() + 8.0), x.y() - c.y()), i);
  }
  std::sort(near_plus.begin(), near_plus.end());
  int watched = -1;
  const double z_at = m.rest_positions(2, near_plus.front().second);
  SimulationSettings ss = regional_ball_press(m);
  // held: a node outside the region's closure does not move at all (carried, it would move with
  // the far field's rigid motion: TheCarriedFarFieldPressesAsTheFullSolveOnAStem)
  ss.integrator.region_far_field_degree = 0;
  ProbeSettings& probe = ss.probes.front();
  probe.path = {{0.0, {c.x() - 8.0, c.y(), ztop + 3.0}},
                {0.4, {c.x() - 8.0, c.y(), ztop + 1.5}},
                {0.6, {c.x() - 8.0, c.y(), ztop + 5.0}},
                {1.2, {c.x() + 8.0, c.y(), z_at + 5.0}},
                {1.6, {c.x() + 8.0, c.y(), z_at + 1.5}}};
  Simulation sim(p, ss);
  // the first press: after the first step (a full solve), the nodes off the region's closure sleep
  sim.step();
  sim.step();
  {
    const ProjectiveSolver& solver = *sim.state().integrator_cache.solver;
    std::vector<std::uint8_t> solved(std::size_t(m.num_nodes()), 0);
    for (int f : solver.factor().partial_rows()) solved[std::size_t(solver.free_nodes()[std::size_t(f)])] = 1;
    for (const auto& [d, i] : near_plus)
      if (!solved[std::size_t(i)] && d < 2.0) {
        watched = i;
        break;
      }
  }
  ASSERT_GE(watched, 0) << "no sleeping node near x = +8";
  const Eigen::Vector3d x0 = sim.state().positions.col(watched);
  bool stayed = true;
  while (sim.time_s() < 0.4 - 1e-9 && !sim.failed()) {
    sim.step();
    stayed = stayed && sim.state().positions.col(watched) == x0;
  }
  EXPECT_TRUE(stayed) << "the node far from the first press moved";
  EXPECT_GT(sim.counters().sleeping_element_updates, 0);
  EXPECT_GT(sim.counters().sleeping_node_solves, 0);
  while (sim.time_s() < 1.6 - 1e-9 && !sim.failed()) sim.step();
  ASSERT_FALSE(sim.failed()) << sim.state().message;
  const double moved = (sim.state().positions.col(watched) - x0).norm();
  std::cout << "watched node " << watched << " moved " << moved << " mm once pressed; force "
            << sim.probe(0).raw_force_n.z() << " N; sleeping element updates "
            << sim.counters().sleeping_element_updates << "\n";
  EXPECT_GT(moved, 0.5);
  EXPECT_GT(sim.probe(0).raw_force_n.z(), 0.0);
}

TEST(RegionalSolve, TheFarFieldReturnsToRestAfterTheRelease) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  // a 32-voxel ball pressed 2.5 mm by a ball tool with an 8 mm region, lifted away, left alone
  // for 1.5 s: with the idle refresh (every 4th step full: 0.5 %; every 8th: 2 %; every 2nd:
  // 0.04 %) the whole ball returns to rest; without it the nodes that
  // slept through the press stay where the last full solve left them
  const auto p = make_physics_model(ball(32), tissue(0.2));
  const Model& m = *p->model;
  const Eigen::Vector3d c = 0.5 * (m.rest_positions.rowwise().minCoeff() + m.rest_positions.rowwise().maxCoeff());
  const double ztop = m.rest_positions.row(2).maxCoeff();
  const auto offset_after = [&](int refresh_steps, double* peak) {
    SimulationSettings ss = regional_ball_press(m);
    ss.integrator.region_idle_refresh_steps = refresh_steps;
    ProbeSettings& probe = ss.probes.front();
    probe.path = {{0.0, {c.x(), c.y(), ztop + 3.5}},
                  {0.4, {c.x(), c.y(), ztop + 0.5}},
                  {0.6, {c.x(), c.y(), ztop + 0.5}},
                  {0.8, {c.x(), c.y(), ztop + 12.0}}};
    Simulation sim(p, ss);
    *peak = 0.0;
    while (sim.time_s() < 2.3 - 1e-9 && !sim.failed()) {
      sim.step();
      *peak = std::max(*peak, (sim.state().positions - m.rest_positions).colwise().norm().maxCoeff());
    }
    EXPECT_FALSE(sim.failed()) << sim.state().message;
    return (sim.state().positions - m.rest_positions).colwise().norm().maxCoeff();
  };
  double peak_on = 0, peak_off = 0;
  const double on = offset_after(IntegratorSettings{}.region_idle_refresh_steps, &peak_on),
               off = offset_after(0, &peak_off);
  std::cout << "largest offset from rest 1.5 s after the release: " << on << " mm with the idle refresh, " << off
            << " mm without (largest displacement " << peak_on << " / " << peak_off << " mm)\n";
  EXPECT_GT(peak_on, 1.5);
  EXPECT_LT(on, 0.01 * peak_on);
  EXPECT_GT(off, 5.0 * on);
  EXPECT_GT(off, 0.05 * peak_off);
}

TEST(RegionalSolve, AStemHeldTissueFallsAsleepAtItsRestShape) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  // the 32-voxel ball held at a small patch at its bottom (a stem: it sways about it, as the
  // folded organ does), the fast configuration (30 ms, one iteration, a region), pressed about
  // 3 mm off its axis and let go. By speed alone (no node faster than 0.05 mm/s in a full solve;
  // region_rest_fraction 0, as before) it fell asleep 2.6 s after the release 0.74 % of its
  // largest displacement from rest and stayed there; now it falls asleep within the idle refresh
  // window (here at its end, 0.3 % from rest: the regional steps between the full ones make the
  // far field creep back slowly) and is put at its rest shape.
  const auto p = make_physics_model(ball(32), tissue(0.2));
  const Model& m = *p->model;
  const Eigen::Vector3d c = 0.5 * (m.rest_positions.rowwise().minCoeff() + m.rest_positions.rowwise().maxCoeff());
  const double ztop = m.rest_positions.row(2).maxCoeff();
  struct Run {
    double peak_mm{0}, at_sleep_mm{-1}, after_mm{-1}, since_release_s{0};
    std::int64_t sleeps{0}, at_rest{0};
    SleepCause cause{SleepCause::none};
  };
  const auto run = [&](double rest_fraction) {
    SimulationSettings ss = regional_ball_press(m);
    ss.integrator.time_step_s = 0.03;
    ss.integrator.region_rest_fraction = rest_fraction;
    ss.fixed_nodes = bottom_cap(m, 1.0);
    ProbeSettings& probe = ss.probes.front();
    probe.path = {{0.0, {c.x() + 6.0, c.y(), ztop + 4.0}},
                  {0.6, {c.x() + 6.0, c.y(), ztop - 1.5}},
                  {0.9, {c.x() + 6.0, c.y(), ztop - 1.5}},
                  {1.2, {c.x() + 6.0, c.y(), ztop + 12.0}}};
    Simulation sim(p, ss);
    Run r;
    const std::int64_t first = [&] {
      for (int k = 0; k < 3; ++k) sim.step();
      return sim.counters().sleeps;  // asleep from the start (at rest, the tool above)
    }();
    while (sim.time_s() < 12.0 - 1e-9 && !sim.failed() && sim.counters().sleeps == first) {
      sim.step();
      r.peak_mm = std::max(r.peak_mm, (sim.state().positions - m.rest_positions).colwise().norm().maxCoeff());
    }
    EXPECT_FALSE(sim.failed()) << sim.state().message;
    EXPECT_EQ(first, 1) << "asleep at the start";
    const SimulationCounters& k = sim.counters();
    r.sleeps = k.sleeps - first;
    r.at_sleep_mm = k.last_sleep_offset_mm;
    r.since_release_s = k.last_sleep_since_release_s;
    r.cause = k.last_sleep_cause;
    const std::int64_t rest_before = k.steps_at_rest;
    for (int s = 0; s < 10; ++s) sim.step();
    r.at_rest = sim.counters().steps_at_rest - rest_before;
    r.after_mm = (sim.state().positions - m.rest_positions).colwise().norm().maxCoeff();
    return r;
  };
  const Run now = run(IntegratorSettings{}.region_rest_fraction), speed = run(0.0);
  std::cout << "asleep " << now.since_release_s << " s after the release (" << to_string(now.cause) << "), "
            << now.at_sleep_mm << " mm from rest then, " << now.after_mm << " mm after, of a largest " << now.peak_mm
            << " mm; by speed alone " << speed.since_release_s << " s after, " << speed.at_sleep_mm << " mm ("
            << 100.0 * speed.at_sleep_mm / speed.peak_mm << " %)\n";
  EXPECT_GT(now.peak_mm, 1.5);
  ASSERT_EQ(now.sleeps, 1) << "asleep again after the release";
  EXPECT_TRUE(now.cause == SleepCause::near_rest || now.cause == SleepCause::window_end) << to_string(now.cause);
  EXPECT_GE(now.at_sleep_mm, 0.0);
  EXPECT_LT(now.at_sleep_mm, 0.01 * now.peak_mm) << "the issue's bound: within 1 % of rest once released";
  EXPECT_EQ(now.after_mm, 0.0) << "put at its rest shape, and kept there asleep";
  EXPECT_EQ(now.at_rest, 10);
  EXPECT_LE(now.since_release_s, IntegratorSettings{}.region_idle_refresh_window_s + 0.03);
  // the criterion before: slow, but left short of its rest (beyond the 0.5 % it is put at rest from)
  ASSERT_EQ(speed.sleeps, 1);
  EXPECT_EQ(speed.cause, SleepCause::slow);
  EXPECT_GT(speed.at_sleep_mm, 0.005 * speed.peak_mm);
  EXPECT_EQ(speed.after_mm, speed.at_sleep_mm);
}

TEST(RegionalSolve, ATissueAtRestSleepsUntilAToolComesBack) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  // the press and release above, the tool away until 3.6 s, then the same press again: at the
  // start and once the ball has come to rest again (about 1.7 s after the release at 0.05 mm/s)
  // it sleeps (its steps compute nothing and nothing moves), and the second press wakes it and
  // feels what it feels with the sleep turned off, within the regional solves' own spread (the
  // far field's history differs: 1.4 % measured)
  const auto p = make_physics_model(ball(32), tissue(0.2));
  const Model& m = *p->model;
  const Eigen::Vector3d c = 0.5 * (m.rest_positions.rowwise().minCoeff() + m.rest_positions.rowwise().maxCoeff());
  const double ztop = m.rest_positions.row(2).maxCoeff();
  struct Run {
    std::int64_t at_rest_before_press{0}, at_rest_while_pressing{0}, at_rest_first_steps{0};
    double offset_mm{0}, peak_mm{0}, second_force_n{0};
    bool still_while_asleep{true};
  };
  const auto run = [&](double rest_speed_mm_s) {
    SimulationSettings ss = regional_ball_press(m);
    ss.integrator.region_rest_speed_mm_s = rest_speed_mm_s;
    ProbeSettings& probe = ss.probes.front();
    probe.path = {{0.0, {c.x(), c.y(), ztop + 6.0}},  {0.4, {c.x(), c.y(), ztop + 0.5}},
                  {0.6, {c.x(), c.y(), ztop + 0.5}},  {0.8, {c.x(), c.y(), ztop + 12.0}},
                  {3.6, {c.x(), c.y(), ztop + 12.0}}, {4.1, {c.x(), c.y(), ztop + 0.5}}};
    Simulation sim(p, ss);
    Run r;
    for (int k = 0; k < 5; ++k) sim.step();
    r.at_rest_first_steps = sim.counters().steps_at_rest;  // at rest from the start, the tool above
    while (sim.time_s() < 3.5 - 1e-9 && !sim.failed()) {
      const Eigen::Matrix3Xd before = sim.state().positions;
      const std::int64_t slept = sim.counters().steps_at_rest;
      sim.step();
      if (sim.counters().steps_at_rest > slept)
        r.still_while_asleep = r.still_while_asleep && sim.state().positions == before;
      r.peak_mm = std::max(r.peak_mm, (sim.state().positions - m.rest_positions).colwise().norm().maxCoeff());
    }
    r.offset_mm = (sim.state().positions - m.rest_positions).colwise().norm().maxCoeff();
    r.at_rest_before_press = sim.counters().steps_at_rest;
    // the tool comes down from 12 mm above: asleep until it is within reach, awake for the press
    while (sim.time_s() < 4.0 - 1e-9 && !sim.failed()) sim.step();
    const std::int64_t reached = sim.counters().steps_at_rest;
    while (sim.time_s() < 4.1 - 1e-9 && !sim.failed()) sim.step();
    EXPECT_FALSE(sim.failed()) << sim.state().message;
    r.at_rest_while_pressing = sim.counters().steps_at_rest - reached;
    r.second_force_n = sim.probe(0).raw_force_n.z();
    return r;
  };
  const Run on = run(IntegratorSettings{}.region_rest_speed_mm_s), off = run(0.0);
  std::cout << "steps at rest: " << on.at_rest_first_steps << " of the first 5, " << on.at_rest_before_press
            << " by 3.5 s; offset from rest at 3.5 s " << on.offset_mm << " mm (" << off.offset_mm
            << " mm without the sleep) of a largest " << on.peak_mm << " mm; the second press " << on.second_force_n
            << " N against " << off.second_force_n << " N without the sleep\n";
  EXPECT_GE(on.at_rest_first_steps, 3);
  EXPECT_GT(on.at_rest_before_press, 25);  // asleep for at least 0.5 of the 2.7 s after the release
  EXPECT_TRUE(on.still_while_asleep);
  EXPECT_EQ(on.at_rest_while_pressing, 0);
  EXPECT_EQ(off.at_rest_before_press, 0);
  EXPECT_GT(on.peak_mm, 1.5);
  EXPECT_LT(on.offset_mm, 0.01 * on.peak_mm);
  EXPECT_GT(on.second_force_n, 0.01);
  EXPECT_NEAR(on.second_force_n, off.second_force_n, 0.03 * off.second_force_n);
}

// The probe app steps on one thread while the tissue rests ahead of real time (threads 0: the
// physics thread's own OpenMP setting, 1 then), and the tool's first touch wakes it in a step of
// about 0.3 s on the folded organ. That step runs on wake_threads (2 here), the steps before and
// after it on the caller's setting, which is as it was after the step; the same bits as with the
// wake on the caller's one thread.
TEST(RegionalSolve, TheStepThatWakesATissueRunsOnItsWakeThreads) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  const auto p = make_physics_model(ball(24), tissue(0.2));
  const Model& m = *p->model;
  const Eigen::Vector3d c = 0.5 * (m.rest_positions.rowwise().minCoeff() + m.rest_positions.rowwise().maxCoeff());
  const double ztop = m.rest_positions.row(2).maxCoeff();
  struct Run {
    SimulationCounters counters;
    Eigen::Matrix3Xd positions;
    int setting_after{0};
    std::vector<int> threads_seen;  ///< omp_get_max_threads() after each step
  };
  const auto run = [&](int wake_threads) {
    Run r;
    // on a thread of its own: its OpenMP setting is its own (as the app's physics thread's)
    std::thread([&] {
      omp_set_num_threads(1);
      SimulationSettings ss = regional_ball_press(m);
      ss.integrator.threads = 0;
      ss.integrator.wake_threads = wake_threads;
      ss.probes.front().path = {{0.0, {c.x(), c.y(), ztop + 6.0}}, {0.5, {c.x(), c.y(), ztop - 1.5}}};
      Simulation sim(p, ss);
      while (sim.time_s() < 0.6 - 1e-9 && !sim.failed()) {
        sim.step();
        r.threads_seen.push_back(omp_get_max_threads());
      }
      EXPECT_FALSE(sim.failed()) << sim.state().message;
      r.counters = sim.counters();
      r.positions = sim.state().positions;
      r.setting_after = omp_get_max_threads();
    }).join();
    return r;
  };
  const Run woke2 = run(2), woke1 = run(0);
  EXPECT_GT(woke2.counters.steps_at_rest, 3);  // asleep while the tool came down
  EXPECT_EQ(woke2.counters.wakes, 1);
  EXPECT_EQ(woke2.counters.last_wake_threads, 2);
  EXPECT_EQ(woke1.counters.wakes, 1);
  EXPECT_EQ(woke1.counters.last_wake_threads, 1);
  // the caller's setting is its own again after the step that woke, and was never left changed
  EXPECT_EQ(woke2.setting_after, 1);
  for (const int t : woke2.threads_seen) EXPECT_EQ(t, 1);
  ASSERT_EQ(woke1.positions.size(), woke2.positions.size());
  EXPECT_EQ(
      std::memcmp(woke1.positions.data(), woke2.positions.data(), sizeof(double) * std::size_t(woke1.positions.size())),
      0);
}

TEST(RegionalSolve, ASolverBuiltInTheBackgroundWhileTheTissueRestsPressesTheSame) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  // factor_in_background: the first step starts the factorisation on a thread of its own and
  // the tissue, exactly at rest with the tool above, sleeps (its steps advance the time and
  // nothing moves). The tool comes within reach 0.16 s in (8 steps that take microseconds; the
  // 40-voxel ball factors in a tenth of a second or more): that step waits for the solver. A run
  // that waits for it before its second step (taken while the tissue rests) presses the same
  // bits, so when the factor is ready does not change the result, and so does one reset to rest
  // after its first step (it rests on); a run that factors in its first step (the default)
  // presses within the rounding of one solve of the rest shape.
  const auto p = make_physics_model(ball(40), tissue(0.2));
  const Model& m = *p->model;
  const Eigen::Vector3d c = 0.5 * (m.rest_positions.rowwise().minCoeff() + m.rest_positions.rowwise().maxCoeff());
  const double ztop = m.rest_positions.row(2).maxCoeff();
  struct Run {
    std::vector<double> forces;
    bool pending_after_first{false}, at_rest_after_first{false}, pending_at_end{true};
    std::int64_t in_background{0}, factorisations{0}, sleeps{0}, steps_pending{0};
    double wait_s{0.0};
  };
  const auto run = [&](bool background, bool ready_before_second_step, bool reset_after_first = false) {
    SimulationSettings ss = regional_ball_press(m);
    ss.integrator.factor_in_background = background;
    ss.probes.front().path = {
        {0.0, {c.x(), c.y(), ztop + 6.0}}, {0.5, {c.x(), c.y(), ztop - 1.5}}, {0.8, {c.x(), c.y(), ztop - 1.5}}};
    Simulation sim(p, ss);
    Run r;
    sim.step();
    r.pending_after_first = sim.solver_pending();
    r.at_rest_after_first = sim.state().positions == m.rest_positions;
    if (reset_after_first) {
      sim.reset();  // (the app's reset key): back at rest, it rests on
      sim.step();
    }
    if (ready_before_second_step && sim.solver_pending()) sim.state().integrator_cache.pending.wait();
    while (sim.time_s() < 0.8 - 1e-9 && !sim.failed()) {
      sim.step();
      r.forces.push_back(sim.probe(0).raw_force_n.z());
      r.steps_pending += sim.solver_pending() ? 1 : 0;
    }
    EXPECT_FALSE(sim.failed()) << sim.state().message;
    const SimulationCounters& k = sim.counters();
    r.pending_at_end = sim.solver_pending();
    r.in_background = k.factors_in_background;
    r.factorisations = k.factorisations;
    r.sleeps = k.sleeps;
    r.wait_s = k.factor_wait_s;
    return r;
  };
  const Run waited = run(true, false), ready = run(true, true), first = run(false, false),
            reset = run(true, false, true);
  const double peak = *std::max_element(first.forces.begin(), first.forces.end());
  double off = 0.0;
  for (std::size_t k = 0; k < first.forces.size() && k < waited.forces.size(); ++k)
    off = std::max(off, std::abs(waited.forces[k] - first.forces[k]));
  std::cout << "the press waited " << waited.wait_s << " s for the solver built in the background; peak " << peak
            << " N; against factoring in the first step: largest difference " << off << " N\n";
  EXPECT_GT(peak, 0.01);
  for (const Run* r : {&waited, &ready, &reset}) {
    EXPECT_TRUE(r->pending_after_first);
    EXPECT_TRUE(r->at_rest_after_first);
    EXPECT_FALSE(r->pending_at_end);
    EXPECT_EQ(r->in_background, 1);
    EXPECT_EQ(r->factorisations, 1);
    EXPECT_EQ(r->sleeps, 1) << "asleep from the start, as the default finds it after its first step";
  }
  EXPECT_GT(waited.wait_s, 0.0) << "the tool came within reach before the solver was ready";
  EXPECT_GE(waited.steps_pending, 5) << "the tissue stepped at rest while its solver was built (7 before the tool)";
  EXPECT_EQ(ready.wait_s, 0.0);
  EXPECT_EQ(waited.forces, ready.forces) << "when the solver is ready does not change a bit";
  EXPECT_GE(reset.steps_pending, 5) << "reset to rest while the solver is built: the tissue rests on";
  EXPECT_EQ(reset.forces, waited.forces);
  EXPECT_FALSE(first.pending_after_first);
  EXPECT_EQ(first.in_background, 0);
  EXPECT_EQ(first.sleeps, 1);
  ASSERT_EQ(first.forces.size(), waited.forces.size());
  EXPECT_LT(off, 1e-9 * peak);
}

TEST(RegionalSolve, ASolverBuildAskedToStopStopsAtItsNextStageAndKeepsNothing) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  // the solver's set-up asks its stop between every two stages: the key, the cache's look-up, the
  // assembly, CHOLMOD's order and numeric factorisation, the cache's store. A stop that turns true
  // at the k-th question throws Cancelled there, names the stage, and the factor cache keeps
  // nothing; asked one question more than there are, the solver is built and kept
  const auto p = make_physics_model(ball(16), tissue(0.2));
  const std::vector<std::uint8_t> fixed(std::size_t(p->num_nodes()), 0);
  ProjectiveSetup setup;
  setup.time_step_s = 0.03;
  std::vector<std::string> stages;
  int built_at = -1;
  for (int k = 0; k < 20 && built_at < 0; ++k) {
    testing::MemoryFactorCache cache;
    int asked = 0;
    try {
      ProjectiveSolver solver(p, fixed, setup, &cache, 1, [&] { return asked++ >= k; });
      built_at = k;
      EXPECT_EQ(cache.files.size(), 1u) << "the factor built is kept";
      EXPECT_GT(solver.factor_nonzeros(), 0);
    } catch (const Cancelled& e) {
      stages.emplace_back(e.what());
      EXPECT_EQ(asked, k + 1) << "it stopped at the first true answer: " << e.what();
      EXPECT_TRUE(cache.files.empty()) << "a build stopped keeps nothing: " << e.what();
      EXPECT_NE(stages.back().find("was stopped "), std::string::npos) << e.what();
    }
  }
  for (const std::string& st : stages) std::cout << "  " << st << "\n";
  EXPECT_EQ(built_at, int(stages.size()));
  // the implicit solver's three (begun, after the key, before the assembly), the factorisation's
  // five (begun, before the order, after it, after the numeric factorisation, at its end) and the
  // store's one, each a stage of its own
  EXPECT_EQ(stages.size(), 9u);
  EXPECT_EQ(std::set<std::string>(stages.begin(), stages.end()).size(), stages.size());
  EXPECT_NE(stages.at(4).find("before the order"), std::string::npos) << stages.at(4);
  EXPECT_NE(stages.back().find("before the factor cache kept its factor"), std::string::npos) << stages.back();
}

TEST(RegionalSolve, ASolverBuildInTheBackgroundIsStoppedByItsCallerAndAbandoned) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  // factor_in_background with a build that takes 2 s more than it does (the delay stands for a
  // large model's order and factorisation, which cannot be cut short) and the caller's stop
  // (IntegratorSettings::stop_background, a session that quits):
  // - a step that must wait for the solver (the tool within reach) throws Cancelled once the
  //   stop is asked, instead of waiting the build out, and the build stays pending;
  // - abandon_pending() hands it over asked to stop: it ends with Cancelled as it leaves its
  //   delay, the simulation has no build pending any more, and nothing is kept;
  // - the caller's hook (IntegratorSettings::background_thread_start) runs on the build's thread
  const auto p = make_physics_model(ball(24), tissue(0.2));
  const Model& m = *p->model;
  const Eigen::Vector3d c = 0.5 * (m.rest_positions.rowwise().minCoeff() + m.rest_positions.rowwise().maxCoeff());
  const double ztop = m.rest_positions.row(2).maxCoeff();
  SimulationSettings ss = regional_ball_press(m);
  ss.integrator.factor_in_background = true;
  ss.integrator.factor_in_background_delay_s = 2.0;
  auto cache = std::make_shared<testing::MemoryFactorCache>();
  ss.integrator.factor_cache = cache;
  auto stop = std::make_shared<std::atomic<bool>>(false);
  ss.integrator.stop_background = stop;
  // the caller's hook runs first on the build's own thread (the probe app names it there)
  std::promise<std::thread::id> started_on;
  ss.integrator.background_thread_start = [&started_on] { started_on.set_value(std::this_thread::get_id()); };
  ss.probes.front().path = {{0.0, {c.x(), c.y(), ztop + 6.0}}, {0.5, {c.x(), c.y(), ztop - 1.5}}};
  Simulation sim(p, ss);
  sim.step();
  ASSERT_TRUE(sim.solver_pending());
  std::future<std::thread::id> hook = started_on.get_future();
  ASSERT_EQ(hook.wait_for(std::chrono::seconds(1)), std::future_status::ready) << "the hook did not run in its delay";
  EXPECT_NE(hook.get(), std::this_thread::get_id());
  stop->store(true);
  const auto t0 = std::chrono::steady_clock::now();
  bool cancelled = false;
  try {
    for (int k = 0; k < 25 && !cancelled; ++k) sim.step();  // the tool reaches the tissue within 0.5 s
  } catch (const Cancelled& e) {
    cancelled = true;
    EXPECT_NE(std::string(e.what()).find("waiting for the solver"), std::string::npos) << e.what();
  }
  const double waited_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_TRUE(cancelled) << "a step within reach waited for the solver";
  EXPECT_LT(waited_s, 1.5) << "the step waited the build out (2 s)";
  EXPECT_TRUE(sim.solver_pending()) << "the build is left to its owner";
  std::future<IntegratorCache::SolverPtr> left = sim.abandon_pending_solver();
  EXPECT_FALSE(sim.solver_pending());
  ASSERT_TRUE(left.valid());
  EXPECT_THROW((void)left.get(), Cancelled);
  EXPECT_TRUE(cache->files.empty());
}

}  // namespace
}  // namespace vx

namespace vx {
namespace {

TEST(RegionalSolve, TheCarriedFarFieldPressesAsTheFullSolveOnAStem) {
  if (!SparseFactor::available(SparseFactor::Backend::cholmod)) GTEST_SKIP() << "needs CHOLMOD (supernodal)";
  // a column of 32 x 32 x 96 mm (4 mm voxels) that hangs from an 8 x 8 mm patch of its base (a
  // stem: it gives as a whole), pressed 3 mm into the centre of its top by a 4 mm ball in 0.6 s
  // and held, at the fast configuration of large models (30 ms, one iteration) with a 20 mm
  // region: the far field held where the last full solve left it takes the load the whole
  // column's sway would take (issue 25); carried as a rigid body (the projection of its exact
  // solution) it gives as in the full solve
  constexpr double kH = 4.0, kSide = 8 * kH, kTall = 24 * kH;
  const auto p = make_physics_model(hand_block(8, 8, 24, kH), tissue(0.2));
  const Model& m = *p->model;
  std::vector<int> stem;
  for (int i = 0; i < m.num_nodes(); ++i) {
    const Eigen::Vector3d x = m.rest_positions.col(i);
    if (x.z() < 1e-9 && std::abs(x.x() - 0.5 * kSide) <= 4 + 1e-9 && std::abs(x.y() - 0.5 * kSide) <= 4 + 1e-9)
      stem.push_back(i);
  }
  const auto force = [&](double region_mm, int degree, double* far_motion_mm) {
    SimulationSettings ss;
    ss.integrator.kind = IntegratorKind::implicit;
    ss.integrator.time_step_s = 0.03;
    ss.integrator.max_iterations = 1;
    ss.integrator.region_radius_mm = region_mm;
    ss.integrator.region_far_field_degree = std::max(degree, 0);
    ss.integrator.region_solve_far_field = degree < 0;  // the diagnostic: the far field solved exactly
    ss.integrator.threads = 1;
    ss.fixed_nodes = stem;
    ProbeSettings probe;
    probe.name = "ball";
    probe.geometry.radius_mm = 4.0;
    const Eigen::Vector3d top(0.5 * kSide, 0.5 * kSide, kTall + 4.0);
    probe.path = {{0.0, top + Eigen::Vector3d(0, 0, 0.3)},
                  {0.6, top - Eigen::Vector3d(0, 0, 3.0)},
                  {0.9, top - Eigen::Vector3d(0, 0, 3.0)}};
    ss.probes = {probe};
    Simulation sim(p, ss);
    while (sim.time_s() < 0.9 - 1e-9 && !sim.failed()) sim.step();
    EXPECT_FALSE(sim.failed()) << sim.state().message;
    if (far_motion_mm) {
      const ProjectiveSolver& solver = *sim.state().integrator_cache.solver;
      *far_motion_mm = solver.far_field_motion().norm();
      EXPECT_GT(solver.region_nodes(), 0);
      EXPECT_LT(solver.region_nodes(), solver.num_free());
    }
    return sim.probe(0).raw_force_n.z();
  };
  double motion = 0, motion1 = 0;
  const double full = force(0.0, 2, nullptr), held = force(20.0, 0, nullptr), affine = force(20.0, 1, &motion1),
               carried = force(20.0, 2, &motion);
  const double solved = force(20.0, -1, nullptr);
  std::cout << "force at 0.9 s: " << full << " N (full solves), " << held << " N (far field held, "
            << 100 * (held / full - 1) << " %), " << affine << " N (carried, affine: " << 100 * (affine / full - 1)
            << " %), " << carried << " N (carried, quadratic: " << 100 * (carried / full - 1)
            << " %; the far field's centre moved " << motion << " mm), " << solved
            << " N (far field solved exactly every step, its rotations asleep: " << 100 * (solved / full - 1)
            << " %)\n";
  EXPECT_GT(full, 1e-3);
  // held, the far field's inertia and its rotations asleep both stiffen the press (8 % here);
  // carried, what remains is the rotations' (the far field solved exactly gives the same)
  EXPECT_GT(held, 1.06 * full);
  EXPECT_NEAR(affine, solved, 1e-3 * full);
  EXPECT_NEAR(carried, solved, 1e-3 * full);
  EXPECT_LT(std::abs(affine - full), 0.6 * std::abs(held - full));
  EXPECT_GT(motion, 0.0);
}

}  // namespace
}  // namespace vx
