// Contact inside the implicit solve (integrators.h, contact.h, simulation.h): the reaction force
// at long implicit steps against a symplectic reference and an analytic one, the multipliers,
// penetration, release, determinism, and no allocation in steady state.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <new>

#include "base/error.h"
#include "model/gradational_builder.h"
#include "sim/contact.h"
#include "sim/integrators.h"
#include "sim/simulation.h"

#include "physics/calibration.h"
#include "support/allocation_counter.h"

using namespace vx;

namespace {

/// An all-tissue block of nx x ny x nz voxels of 1 mm spanning [0, n] mm on each axis.
std::shared_ptr<const Model> block_model(int nx, int ny, int nz, Layout r) {
  GridGeometry g;
  g.dims = {nx, ny, nz};
  g.origin_mm = {0.5, 0.5, 0.5};
  VoxelGrid grid(g);
  for (auto& v : grid.data()) v = 1;
  BuildSettings b;
  b.layout = r;
  return std::make_shared<const Model>(build_model(grid, b));
}

std::shared_ptr<const PhysicsModel> physics_of(std::shared_ptr<const Model> m, double e_kpa, double damping) {
  Material mat;
  mat.youngs_modulus_kpa = e_kpa;
  mat.density_kg_m3 = 1000;
  mat.damping_ratio = damping;
  mat.poisson_ratio = 0.0;
  return make_physics_model(std::move(m), mat);
}

ProbeSettings path_probe(ProbeShape shape, double radius, std::vector<PathKey> path) {
  ProbeSettings p;
  p.name = "tip";
  p.geometry.shape = shape;
  p.geometry.radius_mm = radius;
  p.drive = ProbeDrive::path;
  p.path = std::move(path);
  return p;
}

// The press: a ball of R = 4 mm pressed 2 mm into the top centre of a 16 x 16 x 8 mm block
// (1 mm voxels, gradational, base fixed, E = 5 kPa, Poisson 0, damping ratio 0.1) from 0.2 mm
// above over 0.1 s, held until 0.2 s, lifted back to the start by 0.25 s and left until 0.3 s.
constexpr double kR = 4.0, kTop = 8.0, kGap = 0.2, kDepth = 2.0;
constexpr double kPress = 0.1, kHold = 0.2, kLift = 0.25, kEnd = 0.3;

std::shared_ptr<const PhysicsModel> press_block() {
  static const auto phys = physics_of(block_model(16, 16, 8, Layout::gradational), 5.0, 0.1);
  return phys;
}

SimulationSettings press_scene(const PhysicsModel& p, IntegratorKind kind, double dt, int threads = 1) {
  SimulationSettings s;
  s.integrator.kind = kind;
  s.integrator.time_step_s = dt > 0 ? dt : 0.5 * stable_time_step(p, kind);
  s.integrator.threads = threads;
  s.integrator.max_iterations = 10;  // as voxelastic bench
  s.fixed_nodes = nodes_on_face(*p.model, BoxFace::z_min);
  const Eigen::Vector3d up(8, 8, kTop + kR + kGap), down(8, 8, kTop + kR - kDepth);
  s.probes = {path_probe(ProbeShape::sphere, kR, {{0.0, up}, {kPress, down}, {kHold, down}, {kLift, up}})};
  return s;
}

/// Deepest penetration of a collidable node into probe 0, mm (<= 0: none).
double deepest_penetration(const Simulation& sim) {
  double worst = -1e9;
  for (const std::int32_t i : collidable_nodes(*sim.physics().model, sim.state().node_fixed))
    worst = std::max(worst, -probe_signed_distance(sim.settings().probes[0].geometry, sim.probe(0).pose.position_mm,
                                                   sim.state().positions.col(i)));
  return worst;
}

struct PressResult {
  double press_mid_n{0};   ///< mean force over the second half of the press (t in [0.05, 0.1] s), N
  double hold_n{0};        ///< mean force over the end of the hold (t in [0.15, 0.2] s), N
  double max_lateral_n{0}; ///< largest |sideways force| / hold force
  double max_penetration_mm{0};
  double min_force_n{0};   ///< smallest z force over the run (a pull would be negative)
  double after_release_n{-1};  ///< largest |force| once the ball is off (t > 0.25 s)
  int contacts_held{0};
  std::vector<double> t, f;  ///< the force curve (z, N) at the end of each step
};

/// Mean of the curve's samples within +-half_s of t (a centred average: smooths the symplectic
/// force's step-to-step jitter without a lag).
double smoothed(const PressResult& r, double t, double half_s) {
  double sum = 0;
  int n = 0;
  for (std::size_t k = 0; k < r.t.size(); ++k)
    if (std::abs(r.t[k] - t) <= half_s) sum += r.f[k], ++n;
  return n > 0 ? sum / n : std::numeric_limits<double>::quiet_NaN();
}

PressResult run_press(IntegratorKind kind, double dt, int threads = 1) {
  const auto phys = press_block();
  Simulation sim(phys, press_scene(*phys, kind, dt, threads));
  PressResult r;
  double sum_press = 0, sum_hold = 0;
  int n_press = 0, n_hold = 0;
  r.after_release_n = 0;
  while (sim.time_s() < kEnd - 0.5 * sim.dt_s()) {
    EXPECT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
    if (sim.failed()) break;
    const double t = sim.time_s();
    const Eigen::Vector3d f = sim.probe(0).raw_force_n;
    r.min_force_n = std::min(r.min_force_n, f.z());
    r.t.push_back(t);
    r.f.push_back(f.z());
    if (t > 0.05 + 1e-9 && t <= kPress + 1e-9) sum_press += f.z(), ++n_press;
    if (t > 0.15 + 1e-9 && t <= kHold + 1e-9) {
      sum_hold += f.z(), ++n_hold;
      r.max_lateral_n = std::max(r.max_lateral_n, f.head<2>().norm());
      r.contacts_held = sim.probe(0).contacts;
    }
    if (t > kLift + 1e-9) r.after_release_n = std::max(r.after_release_n, f.norm());
    if (kind == IntegratorKind::implicit) r.max_penetration_mm = std::max(r.max_penetration_mm, deepest_penetration(sim));
  }
  r.press_mid_n = sum_press / std::max(1, n_press);
  r.hold_n = sum_hold / std::max(1, n_hold);
  r.max_lateral_n /= std::max(1e-12, std::abs(r.hold_n));
  return r;
}

const PressResult& symplectic_reference() {
  static const PressResult r = run_press(IntegratorKind::symplectic_euler, 0.0);
  return r;
}

}  // namespace

// The reference: symplectic Euler at half its stable step with the post-step projection
// (restitution 1, as the scenes default), which bench measured within ~6 % of a fine
// voxel-level reference. The implicit integrator at 1 ms and 5 ms (10 iterations, as bench)
// must give the same force: before the contact was part of its solve it read 16-50 % (1 ms) and
// 87-98 % (5 ms) short on the bench's palpation scene.
// Measured (hold = mean over the end of the hold, press = mean over the second half of the
// press): see the printed lines; tolerances below are set from them with some margin.
TEST(ImplicitContact, PressForceMatchesTheSymplecticReferenceAtLongSteps) {
  const PressResult& ref = symplectic_reference();
  std::printf("symplectic: press %.5f N, hold %.5f N, lateral %.2e, contacts %d\n", ref.press_mid_n, ref.hold_n,
              ref.max_lateral_n, ref.contacts_held);
  ASSERT_GT(ref.hold_n, 1e-3);
  for (double dt : {1e-3, 5e-3}) {
    const PressResult r = run_press(IntegratorKind::implicit, dt);
    std::printf("implicit dt %g ms: press %.5f N (%+.2f %%), hold %.5f N (%+.2f %%), lateral %.2e, penetration %.2e mm, "
                "contacts %d, min force %.3e N, after release %.3e N\n",
                dt * 1e3, r.press_mid_n, 100 * (r.press_mid_n / ref.press_mid_n - 1), r.hold_n,
                100 * (r.hold_n / ref.hold_n - 1), r.max_lateral_n, r.max_penetration_mm, r.contacts_held,
                r.min_force_n, r.after_release_n);
    // along the press and the hold: each step's force against the reference around that time
    double worst = 0;
    for (std::size_t k = 0; k < r.t.size(); ++k)
      if (r.t[k] >= 0.03 && r.t[k] <= kHold + 1e-9)
        worst = std::max(worst, std::abs(r.f[k] - smoothed(ref, r.t[k], 0.5e-3)) / ref.hold_n);
    std::printf("  largest |force - reference| over 0.03-0.2 s: %.2f %% of the held force\n", 100 * worst);
    EXPECT_NEAR(r.hold_n / ref.hold_n, 1.0, 0.03) << "dt " << dt;
    EXPECT_LT(worst, 0.06) << "dt " << dt;  // measured 3.4 % at both steps (nodes entering contact)
    // the gradational mesh is not quite symmetric about the ball: the reference has 1.2e-4 of
    // the force sideways, the implicit runs 1.0e-4
    EXPECT_LT(r.max_lateral_n, 1e-3) << "the press is symmetric: no net sideways force";
    EXPECT_GT(r.contacts_held, 4);
    // no node inside the ball: the constraint is the tangent plane at the node's closest
    // surface point, so a node ends on or just outside the sphere
    EXPECT_LT(r.max_penetration_mm, 1e-6) << "dt " << dt;
    // the probe never pulls the tissue, and lets go of it once lifted
    EXPECT_GE(r.min_force_n, 0.0);
    EXPECT_EQ(r.after_release_n, 0.0);
  }
}

// A plate pressed 0.5 mm onto a uniform 12 x 12 x 8 mm block at Poisson 0: uniaxial strain,
// F = E A d / H (the uniform layout's calibration is exact for small uniform strain). One long
// implicit step of 50 ms per 0.05 s of press, held; the force comes from the multipliers alone.
// Also: the multipliers are >= 0 and balance the base's reaction.
TEST(ImplicitContact, PlateHeldByTheConstraintGivesEAStrain) {
  const auto phys = physics_of(block_model(12, 12, 8, Layout::uniform), 10.0, 0.3);
  SimulationSettings s;
  s.integrator.kind = IntegratorKind::implicit;
  s.integrator.time_step_s = 0.05;
  s.integrator.threads = 1;
  s.integrator.max_iterations = 200;
  s.fixed_nodes = nodes_on_face(*phys->model, BoxFace::z_min);
  const double H = 8.0, d = 0.5;
  ProbeSettings plate = path_probe(ProbeShape::plane, 0.0, {{0.0, {6, 6, H + 0.1}}, {0.1, {6, 6, H - d}}, {1.0, {6, 6, H - d}}});
  plate.geometry.axis = {0, 0, -1};
  s.probes = {plate};
  Simulation sim(phys, s);
  while (sim.time_s() < 1.0 - 1e-9) ASSERT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
  const double expected = 10.0 * kKpaToNPerMm2 * 12.0 * 12.0 * d / H;  // 0.09 N
  const Eigen::Vector3d f = sim.probe(0).raw_force_n;
  std::printf("plate (implicit, 50 ms): %.6f N against E A strain %.6f N (%+.3f %%), %d contacts\n", f.z(), expected,
              100 * (f.z() / expected - 1), sim.probe(0).contacts);
  EXPECT_NEAR(f.z() / expected, 1.0, 0.03);
  EXPECT_NEAR(f.head<2>().norm(), 0.0, 1e-6 * expected);
  EXPECT_EQ(sim.probe(0).contacts, 13 * 13);  // every node of the top face
  const Eigen::Vector3d base = elastic_force_on(sim.state(), s.fixed_nodes);
  EXPECT_NEAR(-base.z() / f.z(), 1.0, 0.01) << base.transpose();
  // the top face is flat on the plate
  for (const int i : nodes_on_face(*phys->model, BoxFace::z_max))
    EXPECT_NEAR(sim.state().positions(2, i), H - d, 1e-9) << "node " << i;
}

namespace {

/// A plate at height z with normal -z, for the integrator alone (no simulation).
class PlateProvider final : public ContactProvider {
 public:
  PlateProvider(std::vector<std::int32_t> nodes, double z) : z_(z), nodes_(std::move(nodes)) {}
  void collect(const Eigen::Matrix3Xd& x, bool near, std::vector<ContactConstraint>& out) override {
    ++calls;
    for (const std::int32_t i : nodes_) {
      const double dist = z_ - x(2, i);
      if (!(dist < (near ? 0.25 : 0.0))) continue;
      ContactConstraint c;
      c.node = i;
      c.owner = 0;
      c.point_mm = {x(0, i), x(1, i), z_};
      c.normal = {0, 0, -1};
      out.push_back(c);
    }
  }
  double z_;
  int calls{0};

 private:
  std::vector<std::int32_t> nodes_;
};

}  // namespace

// The integrator with a provider of its own: the multipliers are >= 0 and complementary (a
// node with a force lies on the plate, no node is above it), and steady steps do not allocate.
TEST(ImplicitContact, MultipliersArePositiveComplementaryAndStepsDoNotAllocate) {
  const auto phys = physics_of(block_model(10, 10, 6, Layout::gradational), 5.0, 0.1);
  SimState state = make_state(phys);
  state.fix_nodes(nodes_on_face(*phys->model, BoxFace::z_min));
  IntegratorSettings set;
  set.kind = IntegratorKind::implicit;
  set.time_step_s = 5e-3;
  set.threads = 2;
  set.max_iterations = 10;
  auto integ = make_integrator(set);
  ASSERT_TRUE(integ->solves_contact());
  PlateProvider plate(collidable_nodes(*phys->model, state.node_fixed), 6.0 - 0.6);
  integ->set_contact_provider(&plate);
  StepReport rep = integ->advance(state, 10);  // factors, solves the contact nodes' columns
  ASSERT_FALSE(state.failed()) << state.message;
  EXPECT_GT(rep.contacts, 10);
  const long before = vx::testing::allocations();
  for (int k = 0; k < 20; ++k) rep = integ->step(state);
  EXPECT_EQ(vx::testing::allocations() - before, 0);
  EXPECT_EQ(rep.contact_columns, 0);
  EXPECT_GT(plate.calls, 0);
  double total = 0;
  for (const ContactConstraint& c : integ->contacts()) {
    EXPECT_GT(c.force_n, 0.0) << "node " << c.node;
    EXPECT_NEAR(state.positions(2, c.node), plate.z_, 1e-9) << "node " << c.node;
    total += c.force_n;
  }
  EXPECT_GT(total, 0.0);
  for (const std::int32_t i : collidable_nodes(*phys->model, state.node_fixed))
    EXPECT_LT(state.positions(2, i), plate.z_ + 1e-9) << "node " << i;
  // unset: back to the free solve, no contacts reported
  integ->set_contact_provider(nullptr);
  integ->step(state);
  EXPECT_TRUE(integ->contacts().empty());
}

// Threads change nothing (the active set, the Schur solve and the sums run in a fixed order).
TEST(ImplicitContact, SameResultsOnOneAndTwoThreads) {
  const auto phys = press_block();
  Simulation a(phys, press_scene(*phys, IntegratorKind::implicit, 2e-3, 1));
  Simulation b(phys, press_scene(*phys, IntegratorKind::implicit, 2e-3, 2));
  for (int k = 0; k < 60; ++k) {
    a.step();
    b.step();
    ASSERT_EQ(a.probe(0).raw_force_n, b.probe(0).raw_force_n) << "step " << k;
  }
  EXPECT_EQ(a.state().positions, b.state().positions);
  EXPECT_GT(a.probe(0).raw_force_n.z(), 0.0);
  // reset gives the same run again (the warm start is forgotten)
  a.reset();
  Simulation c(phys, press_scene(*phys, IntegratorKind::implicit, 2e-3, 1));
  for (int k = 0; k < 60; ++k) {
    a.step();
    c.step();
  }
  EXPECT_EQ(a.state().positions, c.state().positions);
  EXPECT_EQ(a.probe(0).raw_force_n, c.probe(0).raw_force_n);
}

// Walls: a block dropped onto the workspace floor under gravity comes to rest on it with the
// floor carrying its weight (the implicit path's wall force, from the multipliers).
TEST(ImplicitContact, FloorCarriesTheWeight) {
  const auto phys = physics_of(block_model(6, 6, 4, Layout::uniform), 10.0, 0.3);
  SimulationSettings s;
  s.integrator.kind = IntegratorKind::implicit;
  s.integrator.time_step_s = 5e-3;
  s.integrator.threads = 1;
  s.integrator.max_iterations = 30;
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  s.workspace.enabled = true;
  s.workspace.min_mm = {-10, -10, -1};
  s.workspace.max_mm = {20, 20, 20};
  Simulation sim(phys, s);
  while (sim.time_s() < 1.5 - 1e-9) ASSERT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
  double mass_kg = 0;
  for (double m : phys->node_mass_kg) mass_kg += m;
  const double weight_n = mass_kg * kStandardGravityMmS2 * 1e-3;  // kg * m/s^2
  std::printf("floor: %.6e N against the weight %.6e N\n", -sim.wall_force_n().z(), weight_n);
  EXPECT_NEAR(-sim.wall_force_n().z() / weight_n, 1.0, 0.01);
  EXPECT_NEAR(sim.state().positions.row(2).minCoeff(), -1.0, 1e-9);
  EXPECT_GT(sim.counters().contact.wall_contacts, 0);
}
