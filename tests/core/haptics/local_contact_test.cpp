// The local contact model (haptics/local_contact.h): the LCP solver on hand-made cases, the model a
// simulation publishes (its force at the anchor is the physics' force; small tool moves follow the
// full implicit solution), the patch compliance against the whole model's, and the passivity of
// the rendered force in a closed loop with the physics at 60 Hz and the device at 1 kHz and 250 Hz.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <random>

#include "haptics/device_side.h"
#include "haptics/local_compliance.h"
#include "haptics/local_contact.h"
#include "model/gradational_builder.h"
#include "physics/calibration.h"
#include "sim/simulation.h"
#include "support/allocation_counter.h"

using namespace vx;

namespace {

// ------------------------------------------------------------------ hand-made models

/// m nodes under a tool pressing down (-z): normals -z tilted a little, compliance W.
LocalContactModel hand_model(const Eigen::MatrixXd& w, const Eigen::VectorXd& lambda0, const Eigen::VectorXd& gap0,
                             std::mt19937& rng) {
  const int m = int(w.rows());
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  LocalContactModel model;
  model.resize(m);
  model.valid = true;
  model.tool.shape = ProbeShape::plane;  // the normals stay as they are: the linear problem
  model.anchor_mm = Eigen::Vector3d(1, 2, 3);
  for (int i = 0; i < m; ++i) {
    model.node[std::size_t(i)] = i;
    model.normal.col(i) = Eigen::Vector3d(u(rng), u(rng), -1.0).normalized();
    model.point_mm.col(i) = model.anchor_mm + 5.0 * model.normal.col(i);
  }
  model.compliance = w;
  model.force_n = lambda0;
  model.gap_mm = gap0;
  model.anchor_force_n = -(model.normal * lambda0);
  return model;
}

/// A random symmetric positive definite compliance (mm/N) with strong coupling between nodes,
/// like an elastic half-space's.
Eigen::MatrixXd random_compliance(int m, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Eigen::MatrixXd pos(3, m);
  for (int i = 0; i < m; ++i) pos.col(i) = Eigen::Vector3d(4 * u(rng), 4 * u(rng), 0);
  Eigen::MatrixXd w(m, m);
  for (int i = 0; i < m; ++i)
    for (int j = 0; j < m; ++j) w(i, j) = 2.0 / (1.0 + (pos.col(i) - pos.col(j)).norm());  // ~ 1/r decay
  w.diagonal().array() += 0.5;
  return w;
}

}  // namespace

TEST(LocalContactSolver, OneNodeIsASpringOfItsCompliance) {
  LocalContactModel m;
  m.resize(1);
  m.valid = true;
  m.tool.shape = ProbeShape::plane;
  m.tool.axis = Eigen::Vector3d(0, 0, -1);
  m.node = {0};
  m.anchor_mm = Eigen::Vector3d::Zero();
  m.point_mm.col(0) = Eigen::Vector3d(0, 0, -5);
  m.normal.col(0) = Eigen::Vector3d(0, 0, -1);  // tool above the node, pushing it down
  m.force_n << 0.2;
  m.gap_mm << 0.0;
  m.compliance << 4.0;  // mm/N: 0.25 N/mm
  ASSERT_EQ(m.validate(), "");
  LocalContactSolver s;
  ASSERT_TRUE(s.set(m, 0.0));
  // at the anchor: the anchor force
  EXPECT_NEAR(s.solve(Eigen::Vector3d::Zero()).force_n.z(), 0.2, 1e-15);
  // 0.4 mm deeper: 0.1 N more; sideways moves change nothing (one flat contact)
  EXPECT_NEAR(s.solve(Eigen::Vector3d(0.7, -0.2, -0.4)).force_n.z(), 0.3, 1e-14);
  EXPECT_NEAR(s.result().stiffness_n_mm(2, 2), 0.25, 1e-15);
  // lifted 0.8 mm: the node follows until its force is gone, then lets go
  const auto& up = s.solve(Eigen::Vector3d(0, 0, 0.8));
  EXPECT_EQ(up.active, 0);
  EXPECT_EQ(up.force_n.norm(), 0.0);
  EXPECT_EQ(up.stiffness_n_mm.norm(), 0.0);
  // a coupling spring of 1 N/mm in series: 0.4 mm deeper gives 0.1 * (0.25 / 0.25 + ...) :
  // k = 1 / (4 + 1) = 0.2 N/mm, and the proxy stops short of the device by force / k_c
  ASSERT_TRUE(s.set(m, 1.0));
  const auto& c = s.solve(Eigen::Vector3d(0, 0, -0.4));
  EXPECT_NEAR(c.force_n.z(), 0.2 + 0.4 / 5.0 - 0.2 * 1.0 / 5.0, 1e-14);  // from the anchor's coupled state
  EXPECT_NEAR(c.stiffness_n_mm(2, 2), 0.2, 1e-15);
  EXPECT_NEAR(c.proxy_mm.z(), -0.4 + c.force_n.z() / 1.0, 1e-14);
}

// A stale model: the ball (r 4 mm) driven 6 mm down from its anchor, its centre passing through a
// node it touched there. The node's closest-point normal flips as the centre passes it; the turn
// of the normals fades out for nodes deeper than a quarter of the radius, so the force stays
// continuous (measured on the organ at 3 physics updates per second: a 28 % step before).
TEST(LocalContactSolver, AStaleModelStaysContinuousWhenTheToolPassesANode) {
  LocalContactModel m;
  m.resize(1);
  m.valid = true;
  m.tool.shape = ProbeShape::sphere;
  m.tool.radius_mm = 4.0;
  m.node = {0};
  m.anchor_mm = Eigen::Vector3d(0, 0, 4);
  m.point_mm.col(0) = Eigen::Vector3d(0, 0, 0);  // under the ball, on its surface
  m.normal.col(0) = Eigen::Vector3d(0, 0, -1);
  m.force_n << 0.1;
  m.gap_mm << 0.0;
  m.compliance << 10.0;
  ASSERT_EQ(m.validate(), "");
  LocalContactSolver s;
  ASSERT_TRUE(s.set(m, 1.0));
  EXPECT_NEAR(s.solve(m.anchor_mm).force_n.z(), 0.1 * 10.0 / 11.0, 1e-12);  // the coupled anchor state
  double max_step = 0.0;
  Eigen::Vector3d last = s.result().force_n;
  for (int k = 1; k <= 6000; ++k) {
    const Eigen::Vector3d f = s.solve(m.anchor_mm - Eigen::Vector3d(0, 0, 0.001 * k)).force_n;
    max_step = std::max(max_step, (f - last).norm());
    last = f;
  }
  // the force changes by 1 mm / (W + 1/k_c) = 0.09 N per mm: a step of 0.001 mm is 1e-4 N (with
  // the full turn the force flipped from +0.45 to -0.45 N as the centre passed the node)
  EXPECT_LT(max_step, 1e-3);
  EXPECT_NEAR(last.z(), 3.0 / 11.0, 1e-9);  // at 6 mm: (9 - 6) mm / 11 mm/N, still pushing the tool up
}

TEST(LocalContactSolver, SolvesTheComplementarityProblemExactly) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    const int m = 5 + 7 * trial;
    const Eigen::MatrixXd w = random_compliance(m, rng);
    // a consistent anchor: the first half in contact (gap 0, force > 0), the rest apart
    Eigen::VectorXd lambda0 = Eigen::VectorXd::Zero(m), gap0 = Eigen::VectorXd::Zero(m);
    for (int i = 0; i < m; ++i) (i < m / 2 ? lambda0[i] : gap0[i]) = 0.05 * (1.5 + u(rng));
    const LocalContactModel model = hand_model(w, lambda0, gap0, rng);
    ASSERT_EQ(model.validate(), "");
    LocalContactSolver s;
    ASSERT_TRUE(s.set(model, trial % 2 ? 0.5 : 0.0));
    const double c = trial % 2 ? 0.5 : 0.0;
    for (int k = 0; k < 30; ++k) {
      const Eigen::Vector3d dev = model.anchor_mm + 0.3 * Eigen::Vector3d(u(rng), u(rng), u(rng));
      const auto& r = s.solve(dev);
      ASSERT_TRUE(r.converged);
      // lambda >= 0, g >= 0, lambda g = 0 with g = g0 - W lambda0 - N^T d + (W + c N^T N) lambda
      const Eigen::Map<const Eigen::VectorXd> lambda(s.multipliers(), m);
      const Eigen::VectorXd g = gap0 - w * lambda0 - model.normal.transpose() * (dev - model.anchor_mm) +
                                (w + c * model.normal.transpose() * model.normal) * lambda;
      EXPECT_GE(lambda.minCoeff(), 0.0);
      EXPECT_GE(g.minCoeff(), -1e-9);
      EXPECT_LT(lambda.cwiseProduct(g).cwiseAbs().maxCoeff(), 1e-12);
      EXPECT_LT((r.force_n + model.normal * lambda).norm(), 1e-12);
    }
    // at the anchor without coupling: the anchor force, and the anchor's multipliers
    if (c == 0) {
      EXPECT_LT((s.solve(model.anchor_mm).force_n - model.anchor_force_n).norm(), 1e-12 * model.anchor_force_n.norm());
    }
  }
}

TEST(LocalContactSolver, ItsStiffnessIsTheFiniteDifferenceOfItsForce) {
  std::mt19937 rng(3);
  const int m = 40;
  Eigen::VectorXd lambda0 = Eigen::VectorXd::Zero(m), gap0 = Eigen::VectorXd::Zero(m);
  for (int i = 0; i < m; ++i) (i % 3 ? lambda0[i] : gap0[i]) = 0.02 + 0.001 * i;
  const LocalContactModel model = hand_model(random_compliance(m, rng), lambda0, gap0, rng);
  LocalContactSolver s;
  ASSERT_TRUE(s.set(model, 0.2));
  const Eigen::Vector3d x0 = model.anchor_mm + Eigen::Vector3d(0.01, -0.02, -0.05);
  const Eigen::Matrix3d k = s.solve(x0).stiffness_n_mm;
  const double h = 1e-7;  // within one active set: the force is affine there
  for (int c = 0; c < 3; ++c) {
    const Eigen::Vector3d fp = s.solve(x0 + h * Eigen::Vector3d::Unit(c)).force_n;
    const Eigen::Vector3d fm = s.solve(x0 - h * Eigen::Vector3d::Unit(c)).force_n;
    EXPECT_LT(((fp - fm) / (2 * h) + k.col(c)).norm(), 1e-6 * k.norm()) << "axis " << c;
  }
  EXPECT_LT((k - k.transpose()).norm(), 1e-12 * k.norm());
  EXPECT_GE(Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(k).eigenvalues().minCoeff(), -1e-12);
}

TEST(LocalContactSolver, AllocatesNothingAtTheDeviceRate) {
  std::mt19937 rng(11);
  const int m = 120;
  Eigen::VectorXd lambda0 = Eigen::VectorXd::Zero(m), gap0 = Eigen::VectorXd::Zero(m);
  for (int i = 0; i < m; ++i) (i < 60 ? lambda0[i] : gap0[i]) = 0.01;
  const LocalContactModel model = hand_model(random_compliance(m, rng), lambda0, gap0, rng);
  LocalForceRenderer r;
  HapticCouplingSettings hs;
  r.init(hs);
  r.update_model(model, 0.0, 0.016);
  (void)r.tick(model.anchor_mm, 0.0);
  const long before = vx::testing::allocations();
  double t = 0.0;
  for (int k = 0; k < 2000; ++k) {
    t += 1e-3;
    if (k % 16 == 0) r.update_model(model, t, 0.016);
    (void)r.tick(model.anchor_mm + Eigen::Vector3d(0.2 * std::sin(0.01 * k), 0.0, -0.2 * std::sin(0.003 * k)), t);
  }
  EXPECT_EQ(vx::testing::allocations() - before, 0);
}

TEST(LocalForceRenderer, CouplingFromColgatesConditionAndNoJumpAtANewModel) {
  HapticCouplingSettings hs;
  hs.device_rate_hz = 1000;
  EXPECT_EQ(hs.validate(), "");
  // b = 1.5 N s/m, beta = 1: k_c T/2 + beta k_c T = b  ->  k_c = 1.0 N/mm at 1 kHz, 0.25 at 250 Hz
  EXPECT_NEAR(hs.stiffness_n_mm(), 1.0, 1e-12);
  hs.device_rate_hz = 250;
  EXPECT_NEAR(hs.stiffness_n_mm(), 0.25, 1e-12);
  hs.damping_margin = -0.3;
  EXPECT_NE(hs.validate(), "");

  // a model, then a different one: the force does not jump, and fades to the new one
  LocalContactModel a;
  a.resize(1);
  a.valid = true;
  a.tool.shape = ProbeShape::plane;
  a.tool.axis = Eigen::Vector3d(0, 0, -1);
  a.node = {0};
  a.normal.col(0) = Eigen::Vector3d(0, 0, -1);
  a.point_mm.col(0) = Eigen::Vector3d(0, 0, -1);
  a.force_n << 0.3;
  a.gap_mm << 0.0;
  a.compliance << 2.0;
  LocalContactModel b = a;
  b.force_n << 0.4;  // the physics found 0.1 N more at the same place
  LocalForceRenderer r;
  hs = {};
  hs.blend_s = 0.01;
  r.init(hs);
  r.update_model(a, 0.0);
  const double f0 = r.tick(Eigen::Vector3d::Zero(), 0.0).force_n.z();
  r.update_model(b, 0.001);
  const double f1 = r.tick(Eigen::Vector3d::Zero(), 0.001).force_n.z();
  EXPECT_NEAR(f1, f0, 1e-12);
  const double f_half = r.tick(Eigen::Vector3d::Zero(), 0.006).force_n.z();
  const double f_end = r.tick(Eigen::Vector3d::Zero(), 0.012).force_n.z();
  EXPECT_NEAR(f_half - f0, 0.5 * (f_end - f0), 1e-12);
  LocalContactSolver ref;
  ref.set(b, 1.0 / r.coupling_stiffness_n_mm());
  EXPECT_NEAR(f_end, ref.solve(Eigen::Vector3d::Zero()).force_n.z(), 1e-12);
}

// ------------------------------------------------------------------ with the simulation

namespace {

/// An all-tissue block of 16 x 16 x 8 mm (1 mm voxels, gradational), base held; E = 5 kPa (or tissue_kpa),
/// damping 0.1, Poisson 0 (or poisson); with `lesion_kpa` > 0 the elements whose centres lie within 3.6 mm of
/// (8, 8, 4) mm (a lesion under the top centre, reaching up to its surface layer) have that modulus.
std::shared_ptr<const PhysicsModel> block(double lesion_kpa = 0.0, double tissue_kpa = 5.0, double poisson = 0.0) {
  GridGeometry g;
  g.dims = {16, 16, 8};
  g.origin_mm = {0.5, 0.5, 0.5};
  VoxelGrid grid(g);
  for (auto& v : grid.data()) v = 1;
  BuildSettings b;
  b.layout = Layout::gradational;
  auto model = std::make_shared<const Model>(build_model(grid, b));
  Material mat;
  mat.youngs_modulus_kpa = tissue_kpa;
  mat.density_kg_m3 = 1000;
  mat.damping_ratio = 0.1;
  mat.poisson_ratio = poisson;
  MaterialField field;
  if (lesion_kpa > 0) {
    field.youngs_modulus_kpa.assign(std::size_t(model->num_elements()), tissue_kpa);
    for (int e = 0; e < model->num_elements(); ++e) {
      Eigen::Vector3d c = Eigen::Vector3d::Zero();
      const int o = model->element_offsets[e], n = model->element_offsets[e + 1] - o;
      for (int j = o; j < o + n; ++j) c += model->rest_positions.col(model->element_vertices[j]);
      if ((c / n - Eigen::Vector3d(8, 8, 4.0)).norm() < 3.6) field.youngs_modulus_kpa[std::size_t(e)] = lesion_kpa;
    }
  }
  return make_physics_model(model, mat, field);
}

constexpr double kR = 4.0, kTop = 8.0;

/// A simulation's settings and its local contact models'.
struct RigSettings : SimulationSettings {
  std::optional<LocalContactSettings> local_contact;
};

/// A simulation with its device side building the local contact models.
struct Rig : Simulation {
  Rig(std::shared_ptr<const PhysicsModel> p, const RigSettings& s)
      : Simulation(std::move(p), s), side(*this, DeviceSideSettings{std::nullopt, s.local_contact}) {}
  void build_local_contact(int i, LocalContactModel& m) { side.build_local_contact(i, m); }
  [[nodiscard]] const PatchCompliance& patch_compliance() const { return side.patch_compliance(); }
  DeviceSide side;
};

RigSettings scene(const PhysicsModel& p, IntegratorKind kind, double dt) {
  RigSettings s;
  s.integrator.kind = kind;
  s.integrator.time_step_s = dt;
  s.integrator.threads = 1;
  s.fixed_nodes = nodes_on_face(*p.model, BoxFace::z_min);
  ProbeSettings probe;
  probe.name = "tool";
  probe.geometry.shape = ProbeShape::sphere;
  probe.geometry.radius_mm = kR;
  probe.drive = ProbeDrive::live;
  probe.start_mm = {8, 8, kTop + kR + 0.3};
  probe.max_speed_mm_s = 500;
  s.probes = {probe};
  s.local_contact = LocalContactSettings{};
  return s;
}

/// Steps with the tool moved linearly from where it is to `to` over `duration_s`.
void move_tool(Simulation& sim, const Eigen::Vector3d& to, double duration_s) {
  const Eigen::Vector3d from = sim.probe(0).pose.position_mm;
  const int n = std::max(1, int(std::lround(duration_s / sim.dt_s())));
  for (int k = 1; k <= n; ++k) {
    sim.set_live(0, {LiveCommand::Kind::position, from + (to - from) * (double(k) / n)});
    ASSERT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
  }
}

Eigen::Vector3d tool_at(double depth, double x = 8.0) { return {x, 8.0, kTop + kR - depth}; }

}  // namespace

// With the implicit integrator the model is the linearisation SOFA uses: the contact nodes of the
// last step, their multipliers and A^-1 between them. At the anchor it gives the step's force
// exactly. For small tool moves it follows the full implicit solution of the same step (the same
// state stepped with the tool moved): exactly with one local/global iteration per step (the step
// is then linear in the tool: rotations fitted before the solve); with 10 iterations the
// rotation fits converge to the nonlinear solution, whose tangent is softer than the
// projective-dynamics matrix (which leaves out the rotations' derivatives, as a corotational
// stiffness does): 1.22x the full solution's stiffness along the press (a compliance_scale of
// 1.2 takes it out: 1.00-1.02x).
TEST(LocalContactModel, ImplicitModelIsTheStepAtTheAnchorAndFollowsSmallMoves) {
  const auto phys = block();
  for (const int iterations : {1, 10}) {
    RigSettings s = scene(*phys, IntegratorKind::implicit, 2e-3);
    s.integrator.max_iterations = iterations;
    s.local_contact->update_period_s = 2e-3;  // one step per update: the integrator's factor
    Rig a(phys, s);
    move_tool(a, tool_at(1.5), 0.15);
    move_tool(a, tool_at(1.5), 0.05);  // settle
    LocalContactModel model;
    a.build_local_contact(0, model);
    ASSERT_TRUE(model.valid);
    EXPECT_EQ(model.source, ComplianceSource::integrator);
    EXPECT_EQ(model.validate(), "");
    const Eigen::Vector3d f0 = a.probe(0).raw_force_n;
    ASSERT_GT(f0.z(), 0.01);
    EXPECT_LT((model.anchor_force_n - f0).norm(), 1e-12 * f0.norm());
    EXPECT_LT((model.anchor_mm - tool_at(1.5)).norm(), 1e-12);
    LocalContactSolver solver;
    ASSERT_TRUE(solver.set(model, 0.0));
    EXPECT_LT((solver.solve(model.anchor_mm).force_n - f0).norm(), 1e-12 * f0.norm());
    const Eigen::Matrix3d k = solver.result().stiffness_n_mm;
    std::printf("%d iteration(s): anchor %.5f N from %d nodes (%d candidates), stiffness z %.4f N/mm, x %.4f N/mm\n",
                iterations, f0.z(), solver.result().active, model.size(), k(2, 2), k(0, 0));

    // the same step again from the same state, with the tool moved by d: the full solution
    for (const Eigen::Vector3d& d : {Eigen::Vector3d(0, 0, -0.05), Eigen::Vector3d(0, 0, 0.05),
                                     Eigen::Vector3d(0.1, 0, 0), Eigen::Vector3d(0.05, -0.05, -0.05)}) {
      Rig b(phys, s), c(phys, s);
      for (Simulation* sim : {&b, &c}) {
        move_tool(*sim, tool_at(1.5), 0.15);
        move_tool(*sim, tool_at(1.5), 0.05 - s.integrator.time_step_s);
      }
      LocalContactModel before;
      c.build_local_contact(0, before);
      move_tool(b, tool_at(1.5) + d, s.integrator.time_step_s);
      move_tool(c, tool_at(1.5), s.integrator.time_step_s);
      const Eigen::Vector3d full = b.probe(0).raw_force_n - c.probe(0).raw_force_n;
      // the model of the state both stepped from, for the step's tool move (d for b, none for c)
      LocalContactSolver sb;
      ASSERT_TRUE(sb.set(before, 0.0));
      const Eigen::Vector3d moved = sb.solve(before.anchor_mm + d).force_n;
      const Eigen::Vector3d local = moved - sb.solve(before.anchor_mm).force_n;
      std::printf("  d (%+.2f %+.2f %+.2f) mm: full %+.6f %+.6f %+.6f N, local %+.6f %+.6f %+.6f N\n", d.x(), d.y(),
                  d.z(), full.x(), full.y(), full.z(), local.x(), local.y(), local.z());
      if (iterations == 1) {
        // (measured: 0.7-1.1 % along the press; the sideways 0.1 mm move reads 0.00035 N against
        // 0.00043 N, 0.2 % of the anchor force)
        EXPECT_LT((local - full).norm(), 0.03 * full.norm() + 0.003 * f0.norm()) << "d " << d.transpose();
      } else if (d.z() != 0) {
        // (measured 1.19-1.22)
        EXPECT_GT(local.z() / full.z(), 1.1) << "d " << d.transpose();
        EXPECT_LT(local.z() / full.z(), 1.3) << "d " << d.transpose();
      }
    }
  }
}

// The explicit integrators have no factor: the compliance is the implicit matrix at a horizon T on
// a patch around the contact. Over the whole model it is the implicit integrator's factor at dt =
// T to the last digits; the automatic patch (held beyond 6 tool radii) is a little stiffer.
TEST(LocalContactModel, PatchComplianceIsTheImplicitFactorOverTheWholeModel) {
  const auto phys = block();
  RigSettings si = scene(*phys, IntegratorKind::implicit, 0.02);
  Rig imp(phys, si);
  move_tool(imp, tool_at(1.5), 0.2);
  LocalContactModel ref;
  imp.build_local_contact(0, ref);
  ASSERT_EQ(ref.source, ComplianceSource::integrator);
  ASSERT_GT(ref.size(), 10);

  RigSettings sp = si;
  sp.local_contact->integrator_compliance = false;
  sp.local_contact->horizon_s = 0.02;
  for (const double radius : {1000.0, 0.0, 12.0}) {
    sp.local_contact->patch_radius_mm = radius;
    Rig pat(phys, sp);
    move_tool(pat, tool_at(1.5), 0.2);
    LocalContactModel m;
    pat.build_local_contact(0, m);
    ASSERT_EQ(m.source, ComplianceSource::patch);
    ASSERT_EQ(m.node, ref.node);
    LocalContactSolver a, b;
    ASSERT_TRUE(a.set(ref, 0.0));
    ASSERT_TRUE(b.set(m, 0.0));
    const double ka = a.solve(ref.anchor_mm).stiffness_n_mm(2, 2), kb = b.solve(m.anchor_mm).stiffness_n_mm(2, 2);
    std::printf("patch radius %s: %d of %d nodes, contact stiffness %.5f N/mm against %.5f (whole model, %+.1f %%)\n",
                radius > 0 ? std::to_string(radius).c_str() : "auto", pat.patch_compliance().patch_nodes(),
                phys->num_nodes(), kb, ka, 100 * (kb / ka - 1));
    if (radius >= 1000) {
      EXPECT_LT((m.compliance - ref.compliance).norm(), 1e-9 * ref.compliance.norm());
    } else {
      EXPECT_GE(kb, ka * (1 - 1e-9));  // held farther out: stiffer, never softer
      EXPECT_LT(kb, ka * 1.25);
    }
  }
}

// The patch compliance follows the Poisson ratio (docs/model.md 9.1): the local model's stiffness
// along a 0.1 mm press against the full model's quasi-static response (converged implicit steps
// of 10 ms, the tool pressed 1.5 mm and held, then 0.1 mm deeper and held), at Poisson 0 and
// 0.45. At 0 the projective matrix is stiffer than the converged tangent (the rotations'
// derivatives left out: measured 1.41x here, the integrator's factor); at 0.45 the volume term's
// projective matrix penalised every gradient component with 3 lambda V: the local model read 8.0x
// the full stiffness. With the volume term left out and the rest scaled by 1 / (1 - nu)
// (local_compliance.h), the patch: 1.51x (1.07x its ratio at 0).
TEST(LocalContactModel, PatchComplianceFollowsThePoissonRatio) {
  double ratio[2] = {0, 0};
  for (int c = 0; c < 2; ++c) {
    const double nu = c == 0 ? 0.0 : 0.45;
    const auto phys = block(0.0, 5.0, nu);
    RigSettings s = scene(*phys, IntegratorKind::implicit, 0.01);
    s.integrator.max_iterations = 200;
    s.integrator.residual_tolerance_n = 1e-9;
    Rig sim(phys, s);  // (integrator_compliance left on: at Poisson > 0 the patch all the same)
    move_tool(sim, tool_at(1.5), 0.2);
    move_tool(sim, tool_at(1.5), 0.2);  // settle
    LocalContactModel model;
    sim.build_local_contact(0, model);
    ASSERT_EQ(model.source, nu > 0 ? ComplianceSource::patch : ComplianceSource::integrator);
    const double f0 = sim.probe(0).raw_force_n.z();
    move_tool(sim, tool_at(1.6), 0.05);
    move_tool(sim, tool_at(1.6), 0.25);  // settle
    const double full = sim.probe(0).raw_force_n.z() - f0;
    LocalContactSolver solver;
    ASSERT_TRUE(solver.set(model, 0.0));
    const double local = solver.solve(model.anchor_mm + Eigen::Vector3d(0, 0, -0.1)).force_n.z() -
                         solver.solve(model.anchor_mm).force_n.z();
    ratio[c] = local / full;
    std::printf("Poisson %.2f: force %.5f N, 0.1 mm deeper: full %+.6f N, local model %+.6f N (%.3fx)\n", nu, f0, full,
                local, ratio[c]);
    ASSERT_GT(full, 0.0);
  }
  EXPECT_GT(ratio[1], 0.9);  // never softer than the tissue (docs/model.md 9.1: a stiffer model stays passive)
  EXPECT_LT(ratio[1], 1.7);
  EXPECT_NEAR(ratio[1] / ratio[0], 1.0, 0.2);
}

// A contact wider than the patch its tool's radius asks for (a rod lying along the tissue, a
// plate) gets a patch wide enough for it: at Poisson 0.45 the local model takes the patch, and a
// patch radius smaller than the contact (here 1 mm against a ball pressed 1.5 mm) used to make
// PatchCompliance refuse the contact and the physics step throw. Its compliance is the one of a
// patch with the contact in its inner three quarters: the radius asked for, doubled until it is.
TEST(LocalContactModel, AContactWiderThanItsPatchGetsAWiderPatch) {
  const auto phys = block(0.0, 5.0, 0.45);
  RigSettings s = scene(*phys, IntegratorKind::implicit, 0.01);
  s.local_contact->patch_radius_mm = 1.0;
  Rig sim(phys, s);
  move_tool(sim, tool_at(1.5), 0.2);
  LocalContactModel model;
  ASSERT_NO_THROW(sim.build_local_contact(0, model));
  ASSERT_EQ(model.source, ComplianceSource::patch);
  ASSERT_GT(model.size(), 10);
  const Eigen::Matrix3Xd& rest = phys->model->rest_positions;
  Eigen::Vector3d mid = Eigen::Vector3d::Zero();
  for (const std::int32_t i : model.node) mid += rest.col(i) / double(model.size());
  double extent = 0;
  for (const std::int32_t i : model.node) extent = std::max(extent, (rest.col(i) - mid).norm());
  EXPECT_GT(extent, 1.0) << "the contact is wider than the patch asked for";
  // the same contact's compliance from a patch asked for at that width
  double radius = 1.0;
  while (extent > 0.75 * radius) radius *= 2.0;
  RigSettings wide = s;
  wide.local_contact->patch_radius_mm = radius;
  Rig sim_wide(phys, wide);
  move_tool(sim_wide, tool_at(1.5), 0.2);
  LocalContactModel reference;
  sim_wide.build_local_contact(0, reference);
  ASSERT_EQ(reference.node, model.node);
  EXPECT_LT((model.compliance - reference.compliance).norm(), 1e-12 * reference.compliance.norm());
  EXPECT_GT(model.compliance.diagonal().minCoeff(), 0.0);
}

// The patch compliance's memory is bounded (issue 27: the CI soak's resident memory grew +1.9 %
// at Poisson 0.45, where the local models use the patch): 300 contacts of 1 to 256 nodes at random
// places of a 0.45 block, a new patch for most. The cache never holds more than kCacheColumns
// columns, its bytes are kCacheColumns x 8 per node of 1.5x the largest patch seen plus the patch's
// assembly, and every compliance equals a fresh patch's (the columns reused and the cache started
// over correctly).
TEST(LocalContactModel, PatchComplianceCacheIsBoundedAndReusedAcrossPatches) {
  const auto phys = block(0.0, 5.0, 0.45);
  const int nn = phys->num_nodes();
  std::vector<std::uint8_t> fixed(std::size_t(nn), 0);
  const Eigen::Matrix3Xd& rest = phys->model->rest_positions;
  for (int i = 0; i < nn; ++i) fixed[std::size_t(i)] = rest(2, i) < 0.5 ? 1 : 0;
  PatchCompliance pc;
  pc.init(phys, fixed, 0.1);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> where(2.0, 14.0);
  Eigen::MatrixXd g, fresh_g;
  int largest_patch = 0, checked = 0;
  std::size_t bytes_at_largest = 0;
  std::int64_t assembly_limit = 0;
  for (int move = 0; move < 300; ++move) {
    // the m free nodes nearest a random point on or in the block (m up to a local model's 256)
    // drawn one at a time: the order of a call's arguments is unspecified (GCC draws them right to
    // left, clang left to right, and the two builds would test different contacts)
    const double cz = 8.0 * where(rng) / 14.0, cy = where(rng), cx = where(rng);
    const Eigen::Vector3d c(cx, cy, cz);
    const int m = move % 10 == 9 ? 256 : std::uniform_int_distribution<int>(1, 60)(rng);
    std::vector<std::pair<double, std::int32_t>> near;
    for (int i = 0; i < nn; ++i)
      if (!fixed[std::size_t(i)]) near.push_back({(rest.col(i) - c).norm(), i});
    std::partial_sort(near.begin(), near.begin() + m, near.end());
    std::vector<std::int32_t> nodes;
    for (int i = 0; i < m; ++i) nodes.push_back(near[std::size_t(i)].second);
    // the patch's radius, at least the contact's own extent from its centre plus a millimetre (a
    // contact wider than its patch is refused by design: compute returns false)
    Eigen::Vector3d mid = Eigen::Vector3d::Zero();
    for (const int i : nodes) mid += rest.col(i) / m;
    double extent = 0.0;
    for (const int i : nodes) extent = std::max(extent, (rest.col(i) - mid).norm());
    const double radius = std::max(m > 60 ? 12.0 : move % 3 == 0 ? 6.0 : 9.0, std::ceil(extent) + 1.0);
    const std::int64_t refactors = pc.refactors();
    ASSERT_TRUE(pc.compute(nodes, radius, g));
    ASSERT_LE(pc.cached_columns(), PatchCompliance::kCacheColumns);
    if (pc.patch_nodes() > largest_patch) {
      largest_patch = pc.patch_nodes();
      bytes_at_largest = pc.cache_bytes();
    }
    // columns, slots, and the patch's assembly: at most 64 neighbours per node (a node of a large
    // element couples to more than the 27 of a voxel lattice), 16-byte triplets
    // and 12-byte entries of the matrix (both its triangles)
    // (the columns for 1.5x the largest patch: the buffer's room to spare)
    assembly_limit =
        std::int64_t(largest_patch) * (PatchCompliance::kCacheColumns * 8 * 3 / 2 + 2 * 4 + 64 * (16 + 12) + 4);
    EXPECT_LE(std::int64_t(pc.cache_bytes()), assembly_limit) << "move " << move;
    if (move % 3 == 0 && pc.refactors() > refactors) {  // a new patch: the same as a fresh one's
      PatchCompliance fresh;
      fresh.init(phys, fixed, 0.1);
      ASSERT_TRUE(fresh.compute(nodes, radius, fresh_g));
      EXPECT_LT((g - fresh_g).norm(), 1e-12 * fresh_g.norm()) << "move " << move;
      ++checked;
    }
  }
  {  // two contacts of 200 nodes in one patch: the second's columns do not fit beside the first's
    std::vector<std::pair<double, std::int32_t>> near;
    for (int i = 0; i < nn; ++i)
      if (!fixed[std::size_t(i)]) near.push_back({(rest.col(i) - Eigen::Vector3d(8, 8, 8)).norm(), i});
    std::sort(near.begin(), near.end());
    std::vector<std::int32_t> inner, ring;
    for (int i = 0; i < 400; ++i) (i < 200 ? inner : ring).push_back(near[std::size_t(i)].second);
    ASSERT_TRUE(pc.compute(inner, 12.0, g));
    const std::int64_t refactors = pc.refactors(), restarts = pc.cache_restarts();
    ASSERT_TRUE(pc.compute(ring, 12.0, g));
    EXPECT_EQ(pc.refactors(), refactors) << "the patch kept";
    EXPECT_EQ(pc.cache_restarts(), restarts + 1);
    EXPECT_EQ(pc.cached_columns(), 200);
    PatchCompliance fresh;  // the same patch: the inner contact's centre
    fresh.init(phys, fixed, 0.1);
    ASSERT_TRUE(fresh.compute(inner, 12.0, fresh_g));
    ASSERT_TRUE(fresh.compute(ring, 12.0, fresh_g));
    EXPECT_LT((g - fresh_g).norm(), 1e-12 * fresh_g.norm());
  }
  std::printf(
      "largest patch %d nodes, cache %.2f MB (limit %.2f MB), %lld refactors, %lld columns solved, "
      "%lld restarts, %d compliances checked against a fresh patch\n",
      largest_patch, 1e-6 * double(pc.cache_bytes()), 1e-6 * double(assembly_limit), (long long)pc.refactors(),
      (long long)pc.columns_solved(), (long long)pc.cache_restarts(), checked);
  EXPECT_GT(pc.refactors(), 100);
  EXPECT_GT(checked, 10);
  // the buffers stop growing once the largest patch was seen
  EXPECT_LE(pc.cache_bytes(), std::max(bytes_at_largest, std::size_t(assembly_limit)));
}

// With symplectic Euler the node impulses jitter from step to step: the anchor is their
// exponential mean (2 ms), and the model's force at the anchor is the mean of the raw force.
TEST(LocalContactModel, ExplicitAnchorIsTheMeanForceAtTheMeanToolPosition) {
  const auto phys = block();
  RigSettings s =
      scene(*phys, IntegratorKind::symplectic_euler, 0.5 * stable_time_step(*phys, IntegratorKind::symplectic_euler));
  s.contact.restitution = 1.0;
  Rig sim(phys, s);
  const double tau = 0.002, dt = sim.dt_s();
  const double alpha = 1.0 - std::exp(-dt / tau);
  Eigen::Vector3d mean_force = Eigen::Vector3d::Zero(), mean_pose = sim.probe(0).pose.position_mm;
  bool started = false;
  const Eigen::Vector3d from = sim.probe(0).pose.position_mm, to = tool_at(1.5);
  const int n = int(std::lround(0.2 / dt));
  for (int k = 1; k <= n; ++k) {
    sim.set_live(0, {LiveCommand::Kind::position, from + (to - from) * std::min(1.0, 1.5 * k / n)});
    ASSERT_EQ(sim.step(), StepStatus::ok);
    const Eigen::Vector3d f = sim.probe(0).raw_force_n, p = sim.probe(0).pose.position_mm;
    mean_force = started ? Eigen::Vector3d(mean_force + alpha * (f - mean_force)) : Eigen::Vector3d(alpha * f);
    mean_pose = started ? Eigen::Vector3d(mean_pose + alpha * (p - mean_pose)) : p;
    started = true;
  }
  LocalContactModel m;
  sim.build_local_contact(0, m);
  ASSERT_EQ(m.source, ComplianceSource::patch);
  EXPECT_EQ(m.validate(), "");
  EXPECT_LT((m.anchor_mm - mean_pose).norm(), 1e-9);
  EXPECT_LT((m.anchor_force_n - mean_force).norm(), 1e-9 * mean_force.norm());
  LocalContactSolver solver;
  ASSERT_TRUE(solver.set(m, 0.0));
  EXPECT_LT((solver.solve(m.anchor_mm).force_n - mean_force).norm(), 1e-9 * mean_force.norm());
  std::printf("explicit: mean force %.5f N (last raw %.5f N), %d nodes pushing, stiffness z %.4f N/mm\n",
              mean_force.z(), sim.probe(0).raw_force_n.z(), solver.result().active,
              solver.result().stiffness_n_mm(2, 2));
}

// ------------------------------------------------------------------ passivity

namespace {

struct LoopResult {
  double min_energy_mj{0};    ///< the least energy the hand had put in, over the run (>= 0: passive)
  double final_energy_mj{0};  ///< at the end (what the device dissipated)
  double peak_force_n{0};
  double max_jump_n{0};    ///< largest tick-to-tick change of the force
  double hold_force_n{0};  ///< at the end of the hold
  int ticks{0};
  std::int64_t guard_ticks{0};  ///< ticks the energy guard cut the force
  double guard_mj{0};           ///< energy it withheld
};

/// A closed loop: the hand moves the device along a scripted path (press into the tissue over a
/// stiff lesion, hold, lift); the device thread renders the local model's force at `device_hz`;
/// the physics (implicit, one step per update) runs at `physics_hz`, one update late, with the
/// tool at the proxy the device last sent. The energy the hand puts in is the work of the held
/// force along the device's path: E = -sum_k F_k . (x_{k+1} - x_k).
LoopResult closed_loop(double device_hz, double physics_hz, double lesion_kpa, double depth_mm, double speed_mm_s,
                       bool guard = true, double coupling_n_mm = 0.0, double margin = 1.0, double scale = 1.0) {
  const auto phys = block(lesion_kpa, 20.0);
  const double tp = 1.0 / physics_hz, td = 1.0 / device_hz;
  RigSettings s = scene(*phys, IntegratorKind::implicit, tp);
  s.local_contact->update_period_s = tp;
  s.local_contact->compliance_scale = scale;
  Rig sim(phys, s);
  HapticCouplingSettings hs;
  hs.device_rate_hz = device_hz;
  hs.energy_guard = guard;
  hs.coupling_stiffness_n_mm = coupling_n_mm;
  hs.damping_margin = margin;
  LocalForceRenderer r;
  r.init(hs);
  // the hand rests 0.1 s (the physics publishes its first models), presses, holds, lifts
  const Eigen::Vector3d start = sim.probe(0).pose.position_mm, bottom = tool_at(depth_mm);
  const double t0 = 0.1, t_press = t0 + (start - bottom).norm() / speed_mm_s, t_hold = t_press + 0.3,
               t_lift = t_hold + (t_press - t0);
  const auto hand = [&](double t) -> Eigen::Vector3d {
    if (t < t0) return start;
    if (t < t_press) return start + (bottom - start) * ((t - t0) / (t_press - t0));
    // held, with a hand's tremor: 0.05 mm at 8 Hz against the stiff contact
    if (t < t_hold) return bottom + Eigen::Vector3d(0, 0, 0.05 * std::sin(2 * M_PI * 8 * (t - t_press)));
    if (t < t_lift) return bottom + (start - bottom) * ((t - t_hold) / (t_lift - t_hold));
    return start;
  };
  LoopResult res;
  LocalContactModel pending, delivered;
  bool have_pending = false;
  double next_update = tp;
  Eigen::Vector3d proxy = start, last_force = Eigen::Vector3d::Zero();
  double energy = 0;
  const int n = int(std::ceil((t_lift + 0.1) / td));
  for (int k = 0; k < n; ++k) {
    const double t = k * td;
    while (t >= next_update - 1e-12) {
      if (have_pending) {
        std::swap(delivered, pending);
        r.update_model(delivered, t, tp);
      }
      move_tool(sim, proxy, tp);
      sim.build_local_contact(0, pending);
      have_pending = true;
      next_update += tp;
    }
    const Eigen::Vector3d x = hand(t);
    const LocalForceRenderer::Output& o = r.tick(x, t);
    proxy = o.proxy_mm;
    energy -= o.force_n.dot(hand(t + td) - x);
    res.min_energy_mj = std::min(res.min_energy_mj, energy);
    res.peak_force_n = std::max(res.peak_force_n, o.force_n.norm());
    if (k > 0) res.max_jump_n = std::max(res.max_jump_n, (o.force_n - last_force).norm());
    if (t < t_hold) res.hold_force_n = o.force_n.z();
    last_force = o.force_n;
    ++res.ticks;
  }
  res.final_energy_mj = energy;
  res.guard_ticks = r.guard_ticks();
  res.guard_mj = r.guard_energy_mj();
  return res;
}

}  // namespace

// A stiff tool (the coupling from Colgate's condition: 1 N/mm at 1 kHz, 0.25 N/mm at 250 Hz)
// pressed 2.5 mm into a 20 kPa block over a lesion 100x stiffer (2 MPa, just under the top), held there 0.3 s with a
// 0.05 mm, 8 Hz tremor and lifted, at 10 mm/s and at 40 mm/s; the physics at 60 Hz, one update late. The energy the
// hand has put in never goes below zero: the device never gives back more than it got. Without the energy guard the
// coupling and damping alone keep the slow press passive; the fast one is not (the new anchors lag the tool: printed),
// which the guard catches.
TEST(LocalForceRenderer, PassiveInAClosedLoopAt1kHzAnd250Hz) {
  for (const double device_hz : {1000.0, 250.0})
    for (const double speed : {10.0, 40.0})
      for (const bool guard : {false, true}) {
        const LoopResult r = closed_loop(device_hz, 60.0, 2000.0, 2.5, speed, guard);
        std::printf(
            "device %4.0f Hz, %2.0f mm/s, guard %-3s: peak %.4f N, held %.4f N, largest step %.5f N; energy in: "
            "least %.3e N mm, at the end %.3e N mm; guard %lld ticks, %.2e N mm (%d ticks)\n",
            device_hz, speed, guard ? "on" : "off", r.peak_force_n, r.hold_force_n, r.max_jump_n, r.min_energy_mj,
            r.final_energy_mj, static_cast<long long>(r.guard_ticks), r.guard_mj, r.ticks);
        EXPECT_GT(r.peak_force_n, 0.05);
        EXPECT_GE(r.min_energy_mj, -1e-12) << device_hz << " Hz, " << speed << " mm/s";
        EXPECT_GE(r.final_energy_mj, 0.0);
      }
  // the check can fail: a stiff coupling (50 N/mm) without the damping, no guard
  for (const double device_hz : {1000.0, 250.0}) {
    const LoopResult r = closed_loop(device_hz, 60.0, 2000.0, 2.5, 40.0, false, 50.0, 0.0);
    std::printf("without damping or guard, device %4.0f Hz: least energy in %.3e N mm, at the end %.3e N mm\n",
                device_hz, r.min_energy_mj, r.final_energy_mj);
    const LoopResult g = closed_loop(device_hz, 60.0, 2000.0, 2.5, 40.0, true, 50.0, 0.0);
    std::printf("  the same with the guard: least %.3e N mm, at the end %.3e N mm, guard %lld ticks, %.2e N mm\n",
                g.min_energy_mj, g.final_energy_mj, static_cast<long long>(g.guard_ticks), g.guard_mj);
    EXPECT_GE(g.min_energy_mj, -1e-12);
  }
  // a model softer than the tissue (compliance x 1.2, closer to the converged tangent: more
  // accurate, docs/probe.md) with its anchor one update late returns more than it took
  for (const double device_hz : {1000.0, 250.0}) {
    const LoopResult r = closed_loop(device_hz, 60.0, 2000.0, 2.5, 10.0, false, 0.0, 1.0, 1.2);
    const LoopResult g = closed_loop(device_hz, 60.0, 2000.0, 2.5, 10.0, true, 0.0, 1.0, 1.2);
    std::printf(
        "compliance x 1.2, device %4.0f Hz, 10 mm/s: least energy in %.3e N mm; with the guard %.3e N mm "
        "(%lld ticks, %.2e N mm, largest step %.4f N)\n",
        device_hz, r.min_energy_mj, g.min_energy_mj, static_cast<long long>(g.guard_ticks), g.guard_mj, g.max_jump_n);
    EXPECT_GE(g.min_energy_mj, -1e-12);
    // the guard fades the force over 10 ms instead of cutting it in a tick (measured: 2.2 % and
    // 5.7 % of the peak; a cut to what the energy allows in one tick gave 16 % and 11 %)
    EXPECT_LT(g.max_jump_n, 0.1 * g.peak_force_n) << device_hz << " Hz";
  }
}
