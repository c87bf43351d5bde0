// The simulation loop against analytic solutions: Hertz indentation, plate compression, a tap
// (impulse = momentum), a rebound from a wall, a two-probe grasp under gravity; skipping changes
// no result; a live probe (handed across threads by the probe app: apps/probe/sim_exchange.h; the
// device force and the local contact models: tests/core/haptics/device_side_test.cpp).
#include "sim/simulation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "base/error.h"
#include "model/gradational_builder.h"
#include "support/sim_helpers.h"

using namespace vx;
using namespace vx::testing;

namespace {

Eigen::Vector3d centre_of_mass(const Simulation& sim) {
  const auto& m = sim.physics().node_mass_kg;
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double total = 0;
  for (int i = 0; i < sim.state().num_nodes(); ++i) {
    c += m[std::size_t(i)] * sim.state().positions.col(i);
    total += m[std::size_t(i)];
  }
  return c / total;
}

Eigen::Vector3d momentum_n_s(const Simulation& sim) {
  const auto& m = sim.physics().node_mass;  // N s^2/mm
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  for (int i = 0; i < sim.state().num_nodes(); ++i) p += m[std::size_t(i)] * sim.state().velocities.col(i);
  return p;  // N s
}

}  // namespace

/// Hertz's force for a rigid sphere of radius R pressed to depth d (mm) into a layer of
/// thickness h bonded to a rigid base: F = 4/3 E* sqrt(R) d^1.5 * c(chi), chi = sqrt(R d) / h,
/// with the bonded-layer correction c of Dimitriadis et al. (Biophys. J. 82, 2002, eq. 12 with
/// alpha0, beta0 for Poisson ratio nu); c -> 1 for a half-space (h -> infinity). N, mm, kPa.
double hertz_bonded_layer_n(double e_kpa, double nu, double r, double d, double h) {
  const double pi = 3.14159265358979323846;
  const double a0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu * nu) / (1 - nu);
  const double b0 = (0.6387 - 1.0277 * nu + 1.5164 * nu * nu) / (1 - nu);
  const double x = std::sqrt(r * d) / h;
  const double c = 1 - 2 * a0 / pi * x + 4 * a0 * a0 / (pi * pi) * x * x -
                   8 / (pi * pi * pi) * (a0 * a0 * a0 + 4 * pi * pi * b0 / 15) * x * x * x +
                   16 * a0 / (pi * pi * pi * pi) * (a0 * a0 * a0 + 3 * pi * pi * b0 / 5) * x * x * x * x;
  const double e_star = e_kpa * kKpaToNPerMm2 / (1 - nu * nu);
  return 4.0 / 3.0 * e_star * std::sqrt(r) * std::pow(d, 1.5) * c;
}

/// Presses a ball of radius R 2 mm into the top of a 40 x 40 x 20 mm block (1 mm voxels, base
/// fixed, E = 10 kPa, Poisson 0) at 10 mm/s and returns (depth, mean force) per bin of 32 steps
/// (the raw force jitters from step to step, paper fig. 10).
std::vector<std::pair<double, double>> indent_block(Layout r, double restitution, int threads = 1) {
  auto phys = physics_of(block_model(40, 40, 20, r), 10.0);
  SimulationSettings s;
  s.integrator = symplectic(*phys);
  s.integrator.threads = threads;
  s.fixed_nodes = nodes_on_face(*phys->model, BoxFace::z_min);
  s.contact.restitution = restitution;
  const double R = 8.0, top = 20.0, gap = 0.2, depth = 2.0, speed = 10.0;
  const double T = (gap + depth) / speed;
  s.probes = {path_probe("ball", ProbeShape::sphere, R, {{0.0, {20, 20, top + R + gap}}, {T, {20, 20, top + R - depth}}})};
  Simulation sim(phys, s);
  std::vector<std::pair<double, double>> out;
  double sum = 0, sum_d = 0;
  Eigen::Vector2d lateral = Eigen::Vector2d::Zero();
  int n = 0;
  while (sim.time_s() < T - 0.5 * sim.dt_s()) {
    EXPECT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
    if (sim.failed()) break;
    sum += sim.probe(0).raw_force_n.z();
    sum_d += top - (sim.probe(0).pose.position_mm.z() - R);
    lateral += sim.probe(0).raw_force_n.head<2>();
    if (++n < 32) continue;
    out.emplace_back(sum_d / n, sum / n);
    EXPECT_LT(lateral.norm(), 2e-3 * std::abs(sum) + 1e-12) << "the press is symmetric: no net sideways force";
    lateral.setZero();
    sum = sum_d = 0;
    n = 0;
  }
  EXPECT_GT(sim.counters().contact.narrow_tests_skipped, 10 * sim.counters().contact.narrow_tests);
  return out;
}

/// Least-squares slope of log y against log x over the points with x >= x_min.
double loglog_slope(const std::vector<std::pair<double, double>>& p, double x_min) {
  std::vector<double> lx, ly;
  for (const auto& [x, y] : p)
    if (x >= x_min && y > 0) lx.push_back(std::log(x)), ly.push_back(std::log(y));
  double mx = 0, my = 0;
  for (std::size_t k = 0; k < lx.size(); ++k) mx += lx[k], my += ly[k];
  mx /= double(lx.size());
  my /= double(lx.size());
  double sxx = 0, sxy = 0;
  for (std::size_t k = 0; k < lx.size(); ++k) sxx += (lx[k] - mx) * (lx[k] - mx), sxy += (lx[k] - mx) * (ly[k] - my);
  return sxy / sxx;
}

// Hertz in the default (gradational) layout with the paper's elastic collision (restitution 1).
//
// The reference is Hertz corrected for the block's finite thickness (bonded layer): with
// a = sqrt(R d) up to 4 mm under a 20 mm layer (chi = 0.2) the correction is +9 % at 0.5 mm and
// +19 % at 2 mm. tests/core/simulation_slow_test.cpp shows that the same press on the voxel
// layout (8-vertex elements, exactly calibrated) matches this reference within 8 % at every
// depth (+6 to +8 %: a 1 mm node lattice under a contact only 2-4 mm wide): the contact, the
// collision response and the force measurement are right.
// The gradational layout comes out stiffer: measured +14 % at 0.5 mm to +23 % at 2 mm, i.e.
// 7-14 % above the voxel layout. Its uniform compression is exact (consistent gradient, see
// PlateCompressionGivesEAStrain); what remains is resolution: under a contact 2-4 mm wide its
// surface elements are 2 mm cubes whose surface nodes move with one deformation gradient, so
// the surface cannot dimple as finely as the 1 mm voxel layout. (With the paper's least-squares
// fit it read -3 % to -19 %: its 9 % uniform softness masked this.) Tolerance: force within
// [-5 %, +28 %] of the reference for 0.5 <= d <= 2 mm, and the force must grow like d^1.5:
// log-log slope of F/c(chi) in 1.5 +- 0.1 (measured 1.44; 1.47 for the voxel layout).
TEST(Simulation, HertzIndentationOfABlock) {
  const auto curve = indent_block(Layout::gradational, 1.0);
  std::vector<std::pair<double, double>> reduced;  // F / c(chi): the half-space equivalent
  double lo = 10, hi = 0;
  for (const auto& [d, f] : curve) {
    if (d < 0.5) continue;
    const double ref = hertz_bonded_layer_n(10.0, 0.0, 8.0, d, 20.0);
    lo = std::min(lo, f / ref);
    hi = std::max(hi, f / ref);
    EXPECT_GT(f / ref, 0.95) << "depth " << d << " mm: " << f << " N against " << ref << " N";
    EXPECT_LT(f / ref, 1.28) << "depth " << d << " mm: " << f << " N against " << ref << " N";
    reduced.emplace_back(d, f * hertz_bonded_layer_n(10.0, 0.0, 8.0, d, 1e12) / ref);
  }
  ASSERT_GT(reduced.size(), 20u);
  const double exponent = loglog_slope(reduced, 0.5);
  std::printf("Hertz (gradational): force / finite-layer Hertz %.3f .. %.3f, exponent %.3f (raw F: %.3f)\n", lo, hi,
              exponent, loglog_slope(curve, 0.5));
  EXPECT_NEAR(exponent, 1.5, 0.1);
}

// A plate pressed onto a block fixed at its base: uniaxial strain, F = E A (d / H) for Poisson 0
// (no lateral expansion, so the fixed base adds no constraint). 20 x 20 x 20 mm, E = 10 kPa,
// plate pressed 1 mm (5 % strain) and held. Tolerance 3 % for the uniform layout (the element
// calibration of material.h is exact for small uniform strain of full elements; the rest is
// the 5 % finite strain and the contact jitter, averaged over 0.1 s). The gradational layout
// is held to 15 %: its larger interior elements come out softer in the physics core's
// calibration (measured -8.6 % to -10.2 % here as that core evolved, and the same in a static
// solve without any contact, so it is not the contact's doing).
double plate_compression_ratio(Layout r) {
  auto phys = physics_of(block_model(20, 20, 20, r), 10.0, 0.3);
  SimulationSettings s;
  s.integrator = symplectic(*phys);
  s.fixed_nodes = nodes_on_face(*phys->model, BoxFace::z_min);
  const double H = 20.0, d = 1.0;
  ProbeSettings plate = path_probe("plate", ProbeShape::plane, 0.0, {{0.0, {10, 10, H + 0.1}}, {0.11, {10, 10, H - d}}, {0.3, {10, 10, H - d}}});
  plate.geometry.axis = {0, 0, -1};  // out of the plate, towards the tissue below
  s.probes = {plate};
  Simulation sim(phys, s);
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  int n = 0;
  while (sim.time_s() < 0.3 - 0.5 * sim.dt_s()) {
    EXPECT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
    if (sim.failed()) return 0.0;
    if (sim.time_s() > 0.2) {
      sum += sim.probe(0).raw_force_n;
      ++n;
    }
  }
  const double expected = 10.0 * kKpaToNPerMm2 * 20.0 * 20.0 * d / H;  // 0.2 N
  const Eigen::Vector3d f = sum / n;
  std::printf("compression (%s): %.5f N against E A strain %.5f N (%+.2f %%)\n", to_string(r), f.z(), expected,
              100 * (f.z() / expected - 1));
  EXPECT_NEAR(f.head<2>().norm(), 0.0, 1e-3 * expected);
  // the reaction at the fixed base carries the same load
  const Eigen::Vector3d base = elastic_force_on(sim.state(), s.fixed_nodes);
  EXPECT_NEAR(-base.z() / f.z(), 1.0, 0.01) << base.transpose();
  return f.z() / expected;
}

TEST(Simulation, PlateCompressionGivesEAStrain) {
  EXPECT_NEAR(plate_compression_ratio(Layout::uniform), 1.0, 0.03);
  EXPECT_NEAR(plate_compression_ratio(Layout::gradational), 1.0, 0.15);
}

// A tap: a ball strikes a free block (no gravity, no fixture) and retreats. The block flies
// off away from the ball, its momentum equal to the impulse the raw force recorded
// (momentum conservation: the force on the probe is minus the momentum given to the nodes).
TEST(Simulation, TapSendsTheBlockAwayWithTheRecordedImpulse) {
  auto phys = physics_of(block_model(12, 12, 12), 10.0);
  SimulationSettings s;
  s.integrator = symplectic(*phys);
  // from the -x side at 200 mm/s, 1 mm into the block, back out
  s.probes = {path_probe("tap", ProbeShape::sphere, 3.0,
                         {{0.0, {-3.5, 6, 6}}, {0.0075, {-2.0, 6, 6}}, {0.015, {-3.5, 6, 6}}, {0.03, {-8.5, 6, 6}}})};
  Simulation sim(phys, s);
  Eigen::Vector3d impulse = Eigen::Vector3d::Zero();
  const Eigen::Vector3d c0 = centre_of_mass(sim);
  while (sim.time_s() < 0.1) {
    ASSERT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
    impulse += sim.probe(0).raw_force_n * sim.dt_s();
  }
  const Eigen::Vector3d p = momentum_n_s(sim);
  // the tissue pushed the ball back (-x); the block got the opposite momentum (+x)
  EXPECT_LT(impulse.x(), 0.0);
  EXPECT_GT(p.x(), 0.0);
  EXPECT_NEAR(p.x(), -impulse.x(), 1e-9 * std::abs(impulse.x()) + 1e-15);
  EXPECT_NEAR(p.y(), -impulse.y(), 1e-6 * std::abs(impulse.x()));
  EXPECT_EQ(sim.probe(0).contacts, 0);  // the ball has left
  const Eigen::Vector3d c1 = centre_of_mass(sim);
  EXPECT_GT(c1.x() - c0.x(), 0.1);      // the block moves away (mm)
  EXPECT_LT(std::abs(c1.y() - c0.y()), 0.02 * (c1.x() - c0.x()));  // along the tap
}

// A rebound: a block dropped under gravity onto the floor of the workspace bounces back up.
TEST(Simulation, DroppedBlockReboundsFromTheFloor) {
  auto phys = physics_of(block_model(10, 10, 10), 10.0, 0.05);
  SimulationSettings s;
  s.integrator = symplectic(*phys);
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  s.workspace.enabled = true;
  s.workspace.min_mm = {-20, -20, -5};  // floor 5 mm below the block
  s.workspace.max_mm = {30, 30, 40};
  Simulation sim(phys, s);
  const double v_impact = -std::sqrt(2 * kStandardGravityMmS2 * 5.0);  // ~ -313 mm/s
  double vmin = 0, vmax_after = 0, wall_impulse = 0;
  bool hit = false;
  while (sim.time_s() < 0.09) {
    ASSERT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
    const double vz = momentum_n_s(sim).z() / (phys->total_mass_kg() * kKgToNs2PerMm);
    vmin = std::min(vmin, vz);
    if (sim.wall_force_n().norm() > 0) hit = true;
    wall_impulse += sim.wall_force_n().z() * sim.dt_s();
    if (hit) vmax_after = std::max(vmax_after, vz);
  }
  EXPECT_TRUE(hit);
  EXPECT_NEAR(vmin / v_impact, 1.0, 0.05);  // free fall before the impact
  // the block comes back up at a good part of its impact speed
  EXPECT_GT(vmax_after, 0.5 * std::abs(v_impact));
  EXPECT_LT(wall_impulse, 0.0);  // the block pushed the floor down
}

// Two probes grasp a block resting on the floor, lift it 10 mm and hold it under gravity:
// friction at the contacts carries the weight (wall force drops to zero, the probes carry the
// weight between them, the block rises with the probes). Coulomb's law decides: squeezed with
// F_n ~ 0.059 N per side, the block (weight 0.040 N) is held when 2 mu F_n > W (mu = 0.5:
// 0.059 N) and slips out when not (mu = 0.3: 0.035 N), with the paper's elastic collision
// (restitution 1).
struct GraspResult {
  double lift_mm, carried_n, floor_n, weight_n, squeeze_n;
};

GraspResult grasp_and_lift(double friction) {
  const int n = 16;
  auto phys = physics_of(block_model(n, n, n), 10.0);
  SimulationSettings s;
  s.integrator = symplectic(*phys);
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  s.contact.friction = friction;
  s.workspace.enabled = true;
  s.workspace.min_mm = {-40, -40, 0};
  s.workspace.max_mm = {60, 60, 80};
  const double R = 4, c = n / 2.0, squeeze = 1.5;
  auto jaw = [&](const char* name, double side) {
    const double x0 = c + side * (c + R + 0.5), x1 = c + side * (c + R - squeeze);
    return path_probe(name, ProbeShape::sphere, R,
                      {{0, {x0, c, c}}, {0.2, {x1, c, c}}, {0.3, {x1, c, c}}, {0.8, {x1, c, c + 10}}});
  };
  s.probes = {jaw("left", -1), jaw("right", +1)};
  Simulation sim(phys, s);
  GraspResult r{};
  r.weight_n = phys->total_mass_kg() * kStandardGravityMmS2 * 1e-3;  // N
  const double z0 = centre_of_mass(sim).z();
  Eigen::Vector3d held = Eigen::Vector3d::Zero(), wall = Eigen::Vector3d::Zero();
  int m = 0;
  while (sim.time_s() < 1.1) {
    EXPECT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
    if (sim.failed()) break;
    if (sim.time_s() > 0.9) {
      held += sim.probe(0).raw_force_n + sim.probe(1).raw_force_n;
      wall += sim.wall_force_n();
      r.squeeze_n += -sim.probe(0).raw_force_n.x();
      ++m;
    }
  }
  r.lift_mm = centre_of_mass(sim).z() - z0;
  r.carried_n = -held.z() / m;
  r.floor_n = -wall.z() / m;
  r.squeeze_n /= m;
  std::printf("grasp (mu %.1f): lifted %.2f mm of 10; probes carry %.4f N of the weight %.4f N; floor %.5f N; "
              "squeeze %.4f N\n",
              friction, r.lift_mm, r.carried_n, r.weight_n, r.floor_n, r.squeeze_n);
  return r;
}

TEST(Simulation, TwoProbesGraspAndLiftABlock) {
  const GraspResult held = grasp_and_lift(0.5);
  EXPECT_GT(held.lift_mm, 8.5);                          // the block sags a little between the jaws
  EXPECT_NEAR(held.floor_n, 0.0, 1e-12);                 // off the floor
  EXPECT_NEAR(held.carried_n / held.weight_n, 1.0, 0.10); // the tissue hangs on the probes (measured -1 %)
  EXPECT_GT(2 * 0.5 * held.squeeze_n, held.weight_n);    // inside the friction cone
  // too little friction: 2 mu squeeze below the weight (mu 0.3 holds since the consistent
  // gradient made the gradational block stiffer: 2 * 0.3 * 0.070 N > 0.040 N)
  const GraspResult slips = grasp_and_lift(0.15);
  EXPECT_LT(2 * 0.15 * slips.squeeze_n, slips.weight_n);
  EXPECT_LT(slips.lift_mm, 1.0);                         // left behind on the floor
  EXPECT_GT(slips.floor_n, 0.5 * slips.weight_n);
}

namespace {

/// A scene that exercises every optional piece of work: probes near and far, walls (the device
/// side's share: tests/core/haptics/device_side_test.cpp).
SimulationSettings busy_scene(const PhysicsModel& phys, bool skip) {
  SimulationSettings s;
  s.integrator = symplectic(phys);
  s.integrator.threads = 1;
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  s.workspace.enabled = true;
  s.workspace.min_mm = {-5, -5, 0};
  s.workspace.max_mm = {17, 17, 30};
  s.contact.friction = 0.3;
  ProbeSettings cap = path_probe("rod", ProbeShape::capsule, 2.0, {{0.0, {6, 6, 14}}, {0.05, {6, 6, 10.5}}});
  cap.geometry.length_mm = 20;
  s.probes = {cap, path_probe("far", ProbeShape::sphere, 2.0, {{0.0, {40, 40, 40}}})};
  s.skip_unneeded = skip;
  return s;
}

}  // namespace

TEST(Simulation, SkippingChangesNoResult) {
  auto phys = physics_of(block_model(12, 12, 12), 10.0);
  Simulation lean(phys, busy_scene(*phys, true));
  Simulation full(phys, busy_scene(*phys, false));
  for (int k = 0; k < 600; ++k) {
    ASSERT_EQ(lean.step(), StepStatus::ok);
    ASSERT_EQ(full.step(), StepStatus::ok);
    for (int p = 0; p < 2; ++p) {
      ASSERT_EQ(lean.probe(p).raw_force_n, full.probe(p).raw_force_n) << "step " << k;
    }
    ASSERT_EQ(lean.wall_force_n(), full.wall_force_n());
  }
  EXPECT_EQ(lean.state().positions, full.state().positions);
  EXPECT_EQ(lean.state().velocities, full.state().velocities);
  EXPECT_GT(lean.counters().contact.contacts, 100);
  EXPECT_GT(lean.counters().contact.wall_contacts, 0);
  // the lean run skipped most node tests; the full one none
  EXPECT_GT(lean.counters().contact.narrow_tests_skipped, lean.counters().contact.narrow_tests);
  EXPECT_EQ(full.counters().contact.narrow_tests_skipped, 0);
  EXPECT_EQ(lean.counters().contact.narrow_tests + lean.counters().contact.narrow_tests_skipped,
            full.counters().contact.narrow_tests);
}

TEST(Simulation, NoProbesNoWallsNoDeviceSkipsContactAndShaping) {
  auto phys = physics_of(block_model(8, 8, 8), 10.0);
  SimulationSettings s;
  s.integrator = symplectic(*phys);
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  s.fixed_nodes = nodes_on_face(*phys->model, BoxFace::z_min);
  Simulation sim(phys, s);
  for (int k = 0; k < 50; ++k) sim.step();
  EXPECT_EQ(sim.counters().contact_passes, 0);
  EXPECT_EQ(sim.counters().contact_passes_skipped, 50);
  EXPECT_EQ(sim.counters().surface_updates_skipped, 50);
}

TEST(Simulation, SameResultsOnOneAndTwoThreads) {
  auto phys = physics_of(block_model(12, 12, 12), 10.0);
  SimulationSettings a = busy_scene(*phys, true), b = a;
  b.integrator.threads = 2;
  Simulation sa(phys, a), sb(phys, b);
  for (int k = 0; k < 300; ++k) {
    sa.step();
    sb.step();
  }
  EXPECT_EQ(sa.state().positions, sb.state().positions);
  EXPECT_EQ(sa.probe(0).raw_force_n, sb.probe(0).raw_force_n);
}

// A live probe: a position target reached at no more than its speed, the force read after
// each step, a frame copied on demand (the probe app hands these across threads itself:
// apps/probe/sim_exchange.h, tests/apps/probe_sim_exchange_test.cpp).
TEST(Simulation, LiveProbeReachesItsTarget) {
  auto phys = physics_of(block_model(12, 12, 6), 10.0);
  Simulation sim(phys, live_press_settings(*phys));
  EXPECT_THROW(sim.set_live(3, {}), Error);
  EXPECT_THROW(sim.set_live(1, {}), Error);  // driven by its path
  sim.set_live(0, {LiveCommand::Kind::position, {6, 6, 7.0}});
  double seen = 0, fastest = 0;
  Eigen::Vector3d last = sim.probe(0).pose.position_mm;
  for (int k = 0; k < 400; ++k) {
    sim.step();
    seen = std::max(seen, sim.probe(0).raw_force_n.z());
    fastest = std::max(fastest, (sim.probe(0).pose.position_mm - last).norm() / sim.dt_s());
    last = sim.probe(0).pose.position_mm;
  }
  EXPECT_NEAR(sim.probe(0).pose.position_mm.z(), 7.0, 1e-9);  // reached the target
  EXPECT_LE(fastest, 50.0 + 1e-6);                            // at <= 50 mm/s
  EXPECT_GT(seen, 0.0);                                       // pressing into the block
  SimulationFrame frame;
  sim.copy_frame(frame);
  EXPECT_EQ(frame.step, 400);
  EXPECT_EQ(frame.positions, sim.state().positions);
  ASSERT_EQ(frame.probes.size(), 2u);
  EXPECT_EQ(frame.probes[0].raw_force_n, sim.probe(0).raw_force_n);
}
