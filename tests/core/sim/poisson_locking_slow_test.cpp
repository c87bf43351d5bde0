// Volumetric locking at tissue-like Poisson ratios (issue 27, docs/model.md section 5, "Locking"):
// a ball pressed into a bonded block, the same scene at Poisson 0 and nu, the force ratio
// F(nu) / F(0) against the bonded finite-layer solution's (Dimitriadis et al. 2002, whose own
// error at Poisson 0 the ratio cancels); a clamped bar compressed, its mid-height bulge against
// nu * axial strain; no force under rigid motion at nu = 0.49. Quasi-static: the implicit
// integrator at 10 ms steps (the block's lowest period is ~20 ms, implicit Euler damps it away)
// and static solves, seconds per case instead of the explicit run's minutes (about 80 s in all:
// label "slow").
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <numbers>

#include "model/gradational_builder.h"
#include "physics/calibration.h"
#include "physics/elements.h"
#include "physics/material.h"
#include "sim/simulation.h"
#include "sim/static_solver.h"
#include "sim/time_step.h"
#include "support/brick_reference.h"
#include "support/physics_helpers.h"
#include "verify/finite_brick_reference.h"

namespace vx {
namespace {

constexpr double kPi = std::numbers::pi;

/// The calibration of the presses and bars below (the default; PoissonLocking.DISABLED_Measure sets it).
CalibrationOptions g_options;

/// A W x W x H mm block of voxels of edge h mm filling its grid, corner at the origin.
std::shared_ptr<const Model> block(Layout r, double w, double height, double h) {
  const int n = int(std::lround(w / h)), nz = int(std::lround(height / h));
  const VoxelGrid grid = testing::box_grid({n, n, nz}, {0, 0, 0}, {n, n, nz}, h);
  BuildSettings bs;
  bs.layout = r;
  return std::make_shared<const Model>(build_model(grid, bs));
}

Material tissue(double nu) {
  Material m;
  m.youngs_modulus_kpa = 10.0;
  m.density_kg_m3 = 1000.0;
  m.damping_ratio = 0.1;
  m.poisson_ratio = nu;
  return m;
}

/// Dimitriadis et al. (Biophys. J. 82, 2002, eq. 12), a rigid sphere of radius r pressed d into
/// a layer of thickness h bonded to a rigid base, N (as evaluation/verify/statics_cases.cpp).
double bonded_layer_n(double e_kpa, double nu, double r, double d, double h) {
  const double a0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu * nu) / (1 - nu);
  const double b0 = (0.6387 - 1.0277 * nu + 1.5164 * nu * nu) / (1 - nu);
  const double x = std::sqrt(r * d) / h;
  const double c = 1 - 2 * a0 / kPi * x + 4 * a0 * a0 / (kPi * kPi) * x * x -
                   8 / (kPi * kPi * kPi) * (a0 * a0 * a0 + 4 * kPi * kPi * b0 / 15) * x * x * x +
                   16 * a0 / (kPi * kPi * kPi * kPi) * (a0 * a0 * a0 + 3 * kPi * kPi * b0 / 5) * x * x * x * x;
  return 4.0 / 3.0 * e_kpa * kKpaToNPerMm2 / (1 - nu * nu) * std::sqrt(r) * std::pow(d, 1.5) * c;
}

// The press: a ball of R = 4 mm pressed 2 mm into the centre of a 32 x 32 x 16 mm block bonded
// at its base (E = 10 kPa), over 0.2 s from 0.2 mm above, held until 0.4 s; the force is the
// mean over the last 0.1 s of the hold.
constexpr double kW = 32.0, kH = 16.0, kR = 4.0, kDepth = 2.0;
double g_depth_mm = kDepth;  ///< the press's depth (PoissonLocking.DISABLED_Measure sets it)
int g_iterations = 60;       ///< implicit iterations per step (DISABLED_Measure sets it)

double press_force_n(const std::shared_ptr<const Model>& m, double nu, int iterations = g_iterations) {
  const auto p = make_physics_model(m, tissue(nu), {}, g_options);
  SimulationSettings s;
  s.integrator.kind = IntegratorKind::implicit;
  s.integrator.time_step_s = 0.01;
  s.integrator.threads = 1;
  s.integrator.max_iterations = iterations;
  s.integrator.residual_tolerance_n = 1e-7;
  s.fixed_nodes = nodes_on_face(*m, BoxFace::z_min);
  ProbeSettings ball;
  ball.name = "ball";
  ball.geometry.shape = ProbeShape::sphere;
  ball.geometry.radius_mm = kR;
  ball.drive = ProbeDrive::path;
  const Eigen::Vector3d lo = m->rest_positions.rowwise().minCoeff(), hi = m->rest_positions.rowwise().maxCoeff();
  const double cx = 0.5 * (lo.x() + hi.x()), cy = 0.5 * (lo.y() + hi.y());
  const Eigen::Vector3d up(cx, cy, hi.z() + kR + 0.2), down(cx, cy, hi.z() + kR - g_depth_mm);
  ball.path = {{0.0, up}, {0.2, down}, {0.4, down}};
  s.probes = {ball};
  Simulation sim(p, s);
  double sum = 0;
  int n = 0;
  while (sim.time_s() < 0.4 - 1e-9) {
    EXPECT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
    if (sim.failed()) break;
    if (sim.time_s() > 0.3 + 1e-9) sum += sim.probe(0).raw_force_n.z(), ++n;
  }
  return n > 0 ? sum / n : 0.0;
}

struct Bulge {
  double lateral_ratio;  ///< mid-height width change / (-nu * axial strain)
  double modulus_ratio;  ///< (reaction / area / strain) / E
};

/// A W x W x 4W bar clamped at both ends, the top pressed down by 1 %, solved statically.
Bulge bulge(Layout r, double nu, double w, double h) {
  const auto m = block(r, w, 4 * w, h);
  const auto p = make_physics_model(m, tissue(nu), {}, g_options);
  SimState s = make_state(p);
  const auto bottom = nodes_on_face(*m, BoxFace::z_min), top = nodes_on_face(*m, BoxFace::z_max);
  s.fix_nodes(bottom);
  s.fix_nodes(top);
  const Eigen::Vector3d lo = m->rest_positions.rowwise().minCoeff();
  const double strain = 0.01, height = 4 * w;
  for (int i : top) s.positions(2, i) -= strain * height;
  StaticSolveSettings ss;
  ss.max_iterations = 3000;
  ss.tolerance_mm = 1e-10;
  ss.threads = 1;
  solve_static(s, ss);
  EXPECT_FALSE(s.failed()) << s.message;
  const double reaction = elastic_force_on(s, top).z();
  double left = 0, right = 0;
  int nl = 0, nr = 0;
  for (int i = 0; i < m->num_nodes(); ++i) {
    if (std::abs(m->rest_positions(2, i) - lo.z() - 0.5 * height) > 1e-9) continue;
    if (std::abs(m->rest_positions(0, i) - lo.x()) < 1e-9) left += s.positions(0, i), ++nl;
    if (std::abs(m->rest_positions(0, i) - lo.x() - w) < 1e-9) right += s.positions(0, i), ++nr;
  }
  const double lateral = (right / nr - left / nl) / w - 1.0;
  const double modulus = reaction / (w * w) / strain / kKpaToNPerMm2;
  return {nu > 0 ? lateral / (nu * strain) : lateral, modulus / 10.0};
}

/// Node forces of the elastic pass (no damping) at positions x.
Eigen::Matrix3Xd node_forces(const PhysicsModel& p, const Eigen::Matrix3Xd& x) {
  std::vector<Eigen::Quaterniond> rot(std::size_t(p.num_elements()), Eigen::Quaterniond::Identity());
  Eigen::Matrix3Xd entry, nf;
  ElementPassScratch scratch;
  ElementPassOptions o;
  o.damping = false;
  o.rotation = RotationFitSettings{30, 1e-14};
  compute_element_forces(p, x, nullptr, rot, entry, nullptr, o, 1, scratch);
  gather_node_forces(p, entry, nf, 1);
  return nf;
}

}  // namespace

// The finite-layer solution's ratio at this depth: F(0.45) / F(0) = 1.312, F(0.49) / F(0) = 1.398
// (F(0.3) / F(0) = 1.113). Measured, gradational layout, 1 mm voxels (1088 elements):
//   the former volume term (on the vertex fit): 2.79 and 7.82 (locked);
//   the volume term on the consistent F:        1.007 and 1.030;
//   + the bending relief calibrated at nu:      1.054 and 1.087.
// So the locking is gone but the ratio stays about 20 % short of the finite-layer solution's:
// one volume constraint per (large) element leaves the dilatation inside it free (docs/model.md
// section 5, "Locking"). The tolerances below are a REGRESSION GUARD around what the model
// gives today, plus the bounds that must hold: the volume term stiffens (ratio > 1) and does not
// lock (ratio below the reference + 10 %). Second round (docs/model.md section 5, "Why soft"): the
// shortfall is not the relief's (1 + nu) calibration (no relief at all still reads 11 % short, the
// voxel layout 16 %) but the dilatation's variation inside an element, which costs no lambda; the
// 5 % bound is not reached, so the bounds stay as they are. Fourth round (poisson_reference_test):
// linearised and pressed with a vertical contact the voxel element reads 0.972 of the reference
// ratio and the gradational model 0.911; the contact's normal pushes move the ratio, not the element.
// Fifth round (ModelPressMatchesTheFiniteStrainReference below): a finite-strain reference with
// the same contact reads as the model's press does; the finite layer's ratio holds at small strain only.
TEST(PoissonLocking, IndentationForceRatioNoLongerLocks) {
  const double ref45 = bonded_layer_n(10, 0.45, kR, kDepth, kH) / bonded_layer_n(10, 0.0, kR, kDepth, kH);
  const double ref49 = bonded_layer_n(10, 0.49, kR, kDepth, kH) / bonded_layer_n(10, 0.0, kR, kDepth, kH);
  const auto m = block(Layout::gradational, kW, kH, 1.0);
  const double f0 = press_force_n(m, 0.0), f45 = press_force_n(m, 0.45), f49 = press_force_n(m, 0.49);
  std::cout << "gradational (" << m->num_elements() << " elements): F(0) " << f0 << " N (finite layer "
            << bonded_layer_n(10, 0.0, kR, kDepth, kH) << "), F(0.45) / F(0) = " << f45 / f0 << " (reference " << ref45
            << "), F(0.49) / F(0) = " << f49 / f0 << " (reference " << ref49 << ")\n";
  EXPECT_NEAR(f0 / bonded_layer_n(10, 0.0, kR, kDepth, kH), 1.0, 0.10);
  EXPECT_GT(f45 / f0, 1.0);
  EXPECT_LT(f45 / f0, 1.1 * ref45);
  EXPECT_GT(f49 / f0, f45 / f0);
  EXPECT_LT(f49 / f0, 1.1 * ref49);
  EXPECT_NEAR(f45 / f0, 1.054, 0.02) << "regression guard (not the reference " << ref45 << ")";
}

// Clamped ends add a little to the bulge and the modulus (the ends cannot contract; measured
// 1.02-1.06 here, both layouts, nu 0.3-0.49). The former volume term read 1.12 (0.45) and 1.30
// (0.49) on the gradational layout, 1.08 and 1.19 on the voxel layout.
TEST(PoissonLocking, ClampedBarBulgesByPoissonsRatio) {
  for (Layout r : {Layout::gradational, Layout::voxel}) {
    for (double nu : {0.3, 0.45, 0.49}) {
      const Bulge b = bulge(r, nu, 8.0, 1.0);
      std::cout << to_string(r) << " nu " << nu << ": lateral strain / (nu * axial) = " << b.lateral_ratio
                << ", modulus / E = " << b.modulus_ratio << "\n";
      EXPECT_NEAR(b.lateral_ratio, 1.0, 0.07) << to_string(r) << " nu " << nu;
      EXPECT_NEAR(b.modulus_ratio, 1.0, 0.07) << to_string(r) << " nu " << nu;
    }
  }
}

// Issue 27, fifth round (docs/model.md section 5, "A finite-strain reference"): the model's own
// press (the voxel layout, its contact pushing each node along the sphere's normal, finite
// strain) against an independent finite-strain reference on the same mesh (2 mm voxels: 2 per
// ball radius, so that it runs in seconds): B-bar bricks with the corotational law
// (verify/finite_brick_reference.h), the ball's frictionless contact on its deformed normals,
// solved by Newton. Measured: the reference F(0) 0.0843 N, F(0.45) / F(0) 1.016, i.e. 0.774 of
// the finite layer's ratio; the model 0.0828 N and 1.027 (0.783); the linear reference with its
// vertical contact on the same mesh 0.951. So the model's press agrees with the reference to
// 2 % in F(0) and 1 % in the ratio: its ratio below the finite layer's is what finite strain and
// the sphere's normal contact give on this mesh (a / R = 0.71 at 2 mm depth), not a defect. On
// 1 mm voxels (FiniteBrickReference.DISABLED_Measure, 4 to 10 min per ratio) the reference
// reads 0.838 and the model 0.837.
TEST(PoissonLocking, ModelPressMatchesTheFiniteStrainReference) {
  const double voxel_mm = 2.0,
               ref_ratio = bonded_layer_n(10, 0.45, kR, kDepth, kH) / bonded_layer_n(10, 0.0, kR, kDepth, kH);
  reference::FinitePress fp;
  fp.voxel_mm = voxel_mm;
  fp.steps = 4;
  fp.material = reference::FiniteMaterial::corotational;
  const double r0 = reference::finite_brick_press(fp, 0.0).force_n.back(),
               r45 = reference::finite_brick_press(fp, 0.45).force_n.back();
  testing::BrickPress lp;
  lp.voxel_mm = voxel_mm;
  const double linear = testing::brick_press(lp, 0.45).force_n / testing::brick_press(lp, 0.0).force_n / ref_ratio;
  const auto m = block(Layout::voxel, kW, kH, voxel_mm);
  const double f0 = press_force_n(m, 0.0), f45 = press_force_n(m, 0.45);
  std::cout << "2 mm voxels, depth 2 mm: finite-strain reference F(0) " << r0 << " N, F(0.45) / F(0) " << r45 / r0
            << " (" << r45 / r0 / ref_ratio << " of the finite layer's); the model " << f0 << " N, " << f45 / f0 << " ("
            << f45 / f0 / ref_ratio << "); the linear reference (vertical contact) " << linear << "\n";
  EXPECT_NEAR(r45 / r0 / ref_ratio, 0.774, 0.01);  // the finite-strain reference
  EXPECT_NEAR(linear, 0.951, 0.01);                // linear: the drop is finite strain's
  EXPECT_NEAR(f0 / r0, 1.0, 0.03);
  EXPECT_NEAR((f45 / f0) / (r45 / r0), 1.0, 0.025);
}

// Rigid motion costs nothing and a uniform strain is an equilibrium of the gradational model
// (the patch test) with the volume term at nu = 0.49.
TEST(PoissonLocking, RigidMotionIsFreeAndTheVolumeTermPassesThePatchTest) {
  const auto m = block(Layout::gradational, 16.0, 16.0, 1.0);
  for (const double cap : {0.0, 9.0}) {  // the default; the volume points (docs/model.md section 5)
    CalibrationOptions o;
    o.volume_variation_cap = cap;
    const auto p = make_physics_model(m, tissue(0.49), {}, o);
    ASSERT_TRUE(p->has_volume_term());
    ASSERT_EQ(p->has_volume_points(), cap > 0);
    const Eigen::Matrix3d rot = Eigen::AngleAxisd(2.1, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
    const Eigen::Matrix3Xd moved = (rot * m->rest_positions).colwise() + Eigen::Vector3d(3, -7, 11);
    EXPECT_LT(node_forces(*p, moved).cwiseAbs().maxCoeff(), 1e-12);
    // a uniform strain with volume change (2 % compression, shear): the interior nodes feel nothing
    Eigen::Matrix3d f;
    f << 0.98, 0.03, 0.0, 0.01, 1.01, -0.02, 0.0, 0.02, 1.015;
    const Eigen::Matrix3Xd strained = rot * f * m->rest_positions;
    const Eigen::Matrix3Xd nf = node_forces(*p, strained);
    double interior = 0, boundary = 0;
    for (int i = 0; i < m->num_nodes(); ++i)
      (m->node_surface[std::size_t(i)] ? boundary : interior) =
          std::max(m->node_surface[std::size_t(i)] ? boundary : interior, nf.col(i).norm());
    std::cout << "cap " << cap << ": uniform strain: largest interior force " << interior << " N, boundary " << boundary
              << " N\n";
    EXPECT_GT(boundary, 1e-4);
    EXPECT_LT(interior, 1e-9 * boundary);
  }
}

// The stable step shrinks like the inverse P-wave speed, sqrt((1 + nu)(1 - 2 nu) / (1 - nu))
// relative to Poisson 0 (0.51 at 0.45, 0.24 at 0.49): the volume term stiffens the volumetric mode.
// Measured: 0.77, 0.41, 0.19 at 0.3, 0.45, 0.49.
TEST(PoissonLocking, StableStepFollowsThePWaveSpeed) {
  const auto m = block(Layout::gradational, 16.0, 16.0, 1.0);
  const double dt0 = estimate_time_steps(*make_physics_model(m, tissue(0.0))).symplectic_euler_s;
  for (double nu : {0.3, 0.45, 0.49}) {
    const double dt = estimate_time_steps(*make_physics_model(m, tissue(nu), {}, g_options)).symplectic_euler_s;
    const double wave = std::sqrt((1 + nu) * (1 - 2 * nu) / (1 - nu));
    std::cout << "nu " << nu << ": stable step " << dt << " s, / step at 0 = " << dt / dt0 << " (P-wave scaling "
              << wave << ")\n";
    EXPECT_LT(dt, dt0);
    EXPECT_NEAR(dt / dt0 / wave, 1.0, 0.35) << nu;
  }
}

// The measurement behind docs/model.md section 5's volume-point table (not run by default: it
// prints, it asserts nothing). Run with --gtest_also_run_disabled_tests and, optionally,
// VX_VMF (CalibrationOptions::volume_mean_fraction), VX_VPP (volume_point_position), VX_CAP
// (volume_variation_cap), VX_LAYOUT (gradational | voxel), VX_NU (0.45 or 0.49 only),
// VX_BULGE (also the clamped bar), VX_DEPTH (mm, default 2), VX_ITERATIONS (per step, default 60),
// VX_VOXEL (mm, default 1).
TEST(PoissonLocking, DISABLED_Measure) {
  if (const char* v = std::getenv("VX_DEPTH")) g_depth_mm = std::atof(v);
  if (const char* v = std::getenv("VX_ITERATIONS")) g_iterations = std::atoi(v);
  if (const char* v = std::getenv("VX_VMF")) g_options.volume_mean_fraction = std::atof(v);
  if (const char* v = std::getenv("VX_VPP")) g_options.volume_point_position = std::atof(v);
  if (const char* v = std::getenv("VX_CAP")) g_options.volume_variation_cap = std::atof(v);
  const Layout lay = std::getenv("VX_LAYOUT") ? parse_layout(std::getenv("VX_LAYOUT")) : Layout::gradational;
  const double voxel_mm = std::getenv("VX_VOXEL") ? std::atof(std::getenv("VX_VOXEL")) : 1.0;
  const auto m = block(lay, kW, kH, voxel_mm);
  {
    const auto p = make_physics_model(m, tissue(0.45), {}, g_options);
    double ks = 0, kv = 0;
    for (double k : p->volume_point_stiffness) ks += k;
    for (double k : p->element_volume_stiffness) kv += k;
    std::cout << "MEASURE elements " << m->num_elements() << " points " << p->volume_point_stiffness.size() << " terms "
              << p->volume_term_entry.size() << " k points " << ks << " k mean " << kv << std::endl;
  }
  const double f0 = press_force_n(m, 0.0);
  for (double nu : {0.45, 0.49}) {
    if (std::getenv("VX_NU") && std::atof(std::getenv("VX_NU")) != nu) continue;
    const double ref = bonded_layer_n(10, nu, kR, g_depth_mm, kH) / bonded_layer_n(10, 0.0, kR, g_depth_mm, kH);
    const auto t0 = std::chrono::steady_clock::now();
    const double f = press_force_n(m, nu);
    std::cout << "MEASURE press s " << std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()
              << " stable step "
              << estimate_time_steps(*make_physics_model(m, tissue(nu), {}, g_options)).symplectic_euler_s << std::endl;
    std::cout << "MEASURE " << to_string(lay) << " vmf " << g_options.volume_mean_fraction << " vpp "
              << g_options.volume_point_position << " cap " << g_options.volume_variation_cap << " depth " << g_depth_mm
              << " iterations " << g_iterations << " nu " << nu << ": F0 " << f0 << " ratio " << f / f0 << " / ref "
              << ref << " = " << f / f0 / ref << std::endl;
  }
  if (std::getenv("VX_BULGE"))
    for (double nu : {0.45, 0.49}) {
      const Bulge b = bulge(lay, nu, 8.0, 1.0);
      std::cout << "MEASURE bulge " << nu << ": " << b.lateral_ratio << " modulus " << b.modulus_ratio << std::endl;
    }
}

}  // namespace vx
