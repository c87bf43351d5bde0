// An independent reference for the Poisson press (issue 27, docs/model.md section 5, "Against a
// B-bar brick on the same mesh"): poisson_locking_slow_test's scene (a ball of R 4 mm pressed 2 mm
// into a 32 x 32 x 16 mm block bonded at its base) solved with plain linear finite elements on
// the voxel layout's mesh (support/brick_reference.h: trilinear bricks, B-bar), its force ratio
// F(nu) / F(0) against the bonded finite-layer solution's. It tells what any trilinear element
// on 1 mm voxels can reach, apart from the model's own element.
#include <gtest/gtest.h>

#include <cstdlib>
#include <iostream>
#include <string>

#include "model/gradational_builder.h"
#include "physics/calibration.h"
#include "physics/elements.h"
#include "physics/material.h"
#include "physics/physics_model.h"
#include "scene/sim_output.h"
#include "sim/state.h"
#include "support/brick_reference.h"
#include "support/physics_helpers.h"
#include "verify/finite_brick_reference.h"

namespace vx {
namespace {

using reference::finite_brick_energy;
using reference::finite_brick_press;
using reference::FiniteBrickMatrix;
using reference::FiniteBrickVector;
using reference::FinitePress;
using testing::brick_press;
using testing::brick_stiffness;
using testing::BrickIntegration;
using testing::BrickMatrix;
using testing::BrickPress;

constexpr double kR = 4.0, kDepth = 2.0, kH = 16.0;

/// The corner positions of brick_stiffness's cube of edge h, 3 per corner.
Eigen::Matrix<double, 24, 1> displacement_of(double h, const Eigen::Matrix3d& grad, const Eigen::Vector3d& shift) {
  Eigen::Matrix<double, 24, 1> u;
  for (int a = 0; a < 8; ++a) {
    const Eigen::Vector3d x(h / 2 * (2.0 * (a & 1) - 1), h / 2 * (2.0 * ((a >> 1) & 1) - 1),
                            h / 2 * (2.0 * ((a >> 2) & 1) - 1));
    u.segment<3>(3 * a) = grad * x + shift;
  }
  return u;
}

/// The model's own voxel element (an 8-vertex cube of edge h, E = 10 kPa, `options`) linearised
/// at rest: K = -df/dx by central differences of the element pass (no damping), symmetrised.
BrickMatrix model_element_stiffness(double h, double nu, const CalibrationOptions& options) {
  const auto m = std::make_shared<const Model>(testing::hand_cube(h));
  Material mat;
  mat.youngs_modulus_kpa = 10.0;
  mat.poisson_ratio = nu;
  const auto p = make_physics_model(m, mat, {}, options);
  auto forces = [&](const Eigen::Matrix3Xd& x) {
    std::vector<Eigen::Quaterniond> rot(std::size_t(p->num_elements()), Eigen::Quaterniond::Identity());
    Eigen::Matrix3Xd entry, nf;
    ElementPassScratch scratch;
    ElementPassOptions o;
    o.damping = false;
    o.rotation = RotationFitSettings{50, 1e-15};
    compute_element_forces(*p, x, nullptr, rot, entry, nullptr, o, 1, scratch);
    gather_node_forces(*p, entry, nf, 1);
    return nf;
  };
  BrickMatrix k;
  const double step = 1e-5 * h;
  for (int b = 0; b < 24; ++b) {
    Eigen::Matrix3Xd plus = m->rest_positions, minus = m->rest_positions;
    plus(b % 3, b / 3) += step;
    minus(b % 3, b / 3) -= step;
    const Eigen::Matrix3Xd df = (forces(plus) - forces(minus)) / (2 * step);
    for (int a = 0; a < 24; ++a) k(a, b) = -df(a % 3, a / 3);
  }
  return 0.5 * (k + k.transpose());
}

/// The whole model (poisson_locking_slow_test's block at `layout`, 1 mm voxels) linearised at rest by
/// central differences of its element pass, one degree of freedom at a time, and pressed with
/// brick_press's linear contact (vertical; the top nodes under the ball): the model's own
/// stiffness with the reference's contact. Seconds for the gradational layout; the voxel
/// layout's 55 000 degrees of freedom would take minutes (model_element_stiffness does it).
testing::BrickPressResult linearised_model_press(Layout layout, double nu, const CalibrationOptions& options,
                                                 double depth_mm = kDepth) {
  const int n = 32, nz = 16;
  BuildSettings bs;
  bs.layout = layout;
  const auto m =
      std::make_shared<const Model>(build_model(testing::box_grid({n, n, nz}, {0, 0, 0}, {n, n, nz}, 1.0), bs));
  Material mat;
  mat.youngs_modulus_kpa = 10.0;
  mat.poisson_ratio = nu;
  const auto p = make_physics_model(m, mat, {}, options);
  const int nn = m->num_nodes();
  const Eigen::Vector3d lo = m->rest_positions.rowwise().minCoeff(), hi = m->rest_positions.rowwise().maxCoeff();
  std::vector<int> dof(std::size_t(3 * nn), -1);
  int free = 0;
  for (int i = 0; i < nn; ++i)
    if (m->rest_positions(2, i) > lo.z() + 1e-9)
      for (int c = 0; c < 3; ++c) dof[std::size_t(3 * i + c)] = free++;
  std::vector<Eigen::Quaterniond> rot(std::size_t(p->num_elements()), Eigen::Quaterniond::Identity());
  Eigen::Matrix3Xd entry, plus, minus;
  ElementPassScratch scratch;
  ElementPassOptions o;
  o.damping = false;
  o.rotation = RotationFitSettings{50, 1e-15};
  std::vector<Eigen::Triplet<double>> t;
  const double step = 1e-5;
  for (int j = 0; j < nn; ++j)
    for (int c = 0; c < 3; ++c) {
      const int col = dof[std::size_t(3 * j + c)];
      if (col < 0) continue;
      Eigen::Matrix3Xd x = m->rest_positions;
      x(c, j) += step;
      compute_element_forces(*p, x, nullptr, rot, entry, nullptr, o, 1, scratch);
      gather_node_forces(*p, entry, plus, 1);
      x(c, j) -= 2 * step;
      compute_element_forces(*p, x, nullptr, rot, entry, nullptr, o, 1, scratch);
      gather_node_forces(*p, entry, minus, 1);
      for (int i = 0; i < nn; ++i)
        for (int r = 0; r < 3; ++r) {
          const int row = dof[std::size_t(3 * i + r)];
          const double v = -(plus(r, i) - minus(r, i)) / (2 * step);
          if (row >= 0 && v != 0.0 && std::abs(v) > 1e-9)
            t.emplace_back(row, col, 0.5 * v), t.emplace_back(col, row, 0.5 * v);
        }
    }
  SparseFactor::Matrix a(free, free);
  a.setFromTriplets(t.begin(), t.end());
  std::vector<std::array<int, 3>> rows;
  std::vector<Eigen::Vector3d> normal;
  std::vector<double> need;
  const double cx = 0.5 * (lo.x() + hi.x()), cy = 0.5 * (lo.y() + hi.y());
  for (int i = 0; i < nn; ++i) {
    const double x = m->rest_positions(0, i) - cx, y = m->rest_positions(1, i) - cy, rr = x * x + y * y;
    if (m->rest_positions(2, i) < hi.z() - 1e-9 || rr >= kR * kR) continue;
    rows.push_back({dof[std::size_t(3 * i)], dof[std::size_t(3 * i + 1)], dof[std::size_t(3 * i + 2)]});
    normal.emplace_back(0, 0, -1);
    need.push_back(depth_mm - (kR - std::sqrt(kR * kR - rr)));
  }
  return testing::press_with_matrix(a, rows, normal, need, 1.0);
}

double finite_layer_ratio(double nu, double depth_mm = kDepth) {
  return hertz_bonded_layer_n(10, nu, kR, depth_mm, kH) / hertz_bonded_layer_n(10, 0.0, kR, depth_mm, kH);
}

}  // namespace

// The element itself: no force under a (small) rigid motion, linear elasticity's energy
// V (mu eps:eps + lambda/2 tr(eps)^2) under every uniform strain, and a bending mode's energy
// free of lambda in the B-bar brick (its volumetric part sees only the mean dilatation) but
// growing with lambda when fully integrated (volumetric locking).
TEST(BrickReference, ElementIsExactUnderUniformStrainAndBBarDoesNotLock) {
  const double h = 0.7, mu = 3.0, lambda = 40.0;
  for (const BrickIntegration integ : {BrickIntegration::bbar, BrickIntegration::full}) {
    const BrickMatrix k = brick_stiffness(h, mu, lambda, integ);
    EXPECT_LT((k - k.transpose()).cwiseAbs().maxCoeff(), 1e-12 * k.cwiseAbs().maxCoeff());
    Eigen::Matrix3d spin;
    spin << 0, -0.3, 0.2, 0.3, 0, -0.1, -0.2, 0.1, 0;
    EXPECT_LT((k * displacement_of(h, spin, {1, -2, 3})).cwiseAbs().maxCoeff(), 1e-12 * k.cwiseAbs().maxCoeff());
    Eigen::Matrix3d grad;
    grad << 0.01, 0.003, -0.002, 0.001, -0.02, 0.004, 0.0, 0.002, 0.015;
    const Eigen::Matrix3d eps = 0.5 * (grad + grad.transpose());
    const auto u = displacement_of(h, grad, {0.1, 0, 0});
    const double energy = 0.5 * u.dot(k * u);
    const double exact =
        h * h * h * (mu * (eps.array() * eps.array()).sum() + 0.5 * lambda * eps.trace() * eps.trace());
    EXPECT_NEAR(energy / exact, 1.0, 1e-12);
  }
  // the bending mode u_x = s_x s_z (its dilatation x z / (h/2)^2 averages to 0)
  Eigen::Matrix<double, 24, 1> bend = Eigen::Matrix<double, 24, 1>::Zero();
  for (int a = 0; a < 8; ++a) bend(3 * a) = (2.0 * (a & 1) - 1) * (2.0 * ((a >> 2) & 1) - 1);
  auto energy = [&](double lam, BrickIntegration integ) { return bend.dot(brick_stiffness(h, mu, lam, integ) * bend); };
  EXPECT_NEAR(energy(1000 * lambda, BrickIntegration::bbar) / energy(0, BrickIntegration::bbar), 1.0, 1e-9);
  EXPECT_GT(energy(1000 * lambda, BrickIntegration::full) / energy(0, BrickIntegration::full), 100.0);
}

// The press on 1 mm voxels (the quarter block, symmetric about the ball's axis; a few seconds).
// Measured (docs/model.md section 5, "Against a B-bar brick on the same mesh"): the B-bar brick
// reads F(0) = 0.0793 N (0.901 of the finite layer's: the sphere against Hertz's paraboloid,
// 0.968 with the paraboloid) and F(nu) / F(0) at 0.966 and 0.956 of the finite layer's ratio at
// nu = 0.45 and 0.49; the model's own voxel element, linearised, 0.972 at 0.45; the fully
// integrated brick 1.064 at 0.49 (volumetric locking). So 1 mm voxels reach the 5 % with a
// trilinear element, and with the model's. The bounds hold those figures to about 1 %.
TEST(BrickReference, PressOnOneMillimetreVoxels) {
  BrickPress s;
  const double f0 = brick_press(s, 0.0).force_n;
  const double ref0 = hertz_bonded_layer_n(10, 0.0, kR, kDepth, kH);
  std::cout << "B-bar, 1 mm: F(0) " << f0 << " N (finite layer " << ref0 << ")\n";
  EXPECT_NEAR(f0 / ref0, 0.901, 0.01);
  const auto r45 = brick_press(s, 0.45), r49 = brick_press(s, 0.49);
  const double q45 = r45.force_n / f0 / finite_layer_ratio(0.45), q49 = r49.force_n / f0 / finite_layer_ratio(0.49);
  std::cout << "B-bar: F(nu) / F(0) over the finite layer's: " << q45 << " at 0.45, " << q49 << " at 0.49 ("
            << r45.contact_nodes << " contact nodes of the quarter, " << r45.active_set_rounds << " rounds)\n";
  EXPECT_NEAR(q45, 0.966, 0.01);
  EXPECT_NEAR(q49, 0.956, 0.01);
  EXPECT_GT(r45.contact_nodes, 4);  // the active set grew from the nodes under the ball's cap
  const BrickMatrix m0 = model_element_stiffness(1.0, 0.0, {}), m45 = model_element_stiffness(1.0, 0.45, {});
  const double model0 = brick_press(s, 0.0, &m0).force_n, model45 = brick_press(s, 0.45, &m45).force_n;
  std::cout << "the model's element linearised: F(0) " << model0 << " N, F(0.45) / F(0) over the finite layer's "
            << model45 / model0 / finite_layer_ratio(0.45) << "\n";
  EXPECT_NEAR(model0 / f0, 1.0, 0.01);
  EXPECT_NEAR(model45 / model0 / finite_layer_ratio(0.45), 0.972, 0.01);
  s.integration = BrickIntegration::full;
  const double full49 = brick_press(s, 0.49).force_n;  // its F(0) is 1.009 times the B-bar's
  std::cout << "fully integrated, 1 mm: F(0.49) / the B-bar's " << full49 / r49.force_n << "\n";
  EXPECT_GT(full49 / r49.force_n, 1.08);  // it locks
}

// The finite-strain brick (verify/finite_brick_reference.h): linearised at rest it is the B-bar
// brick exactly; its gradient and Hessian are the energy's (central differences at a finite,
// non-uniform deformation, nu = 0.49); it keeps rigid motion free at finite rotation.
TEST(FiniteBrickReference, LinearisedAtRestIsTheBBarBrickAndItsDerivativesAreExact) {
  const double h = 0.7, e = 0.01, nu = 0.49, mu = e / (2 * (1 + nu)), lambda = e * nu / ((1 + nu) * (1 - 2 * nu));
  FiniteBrickVector g;
  FiniteBrickMatrix k;
  EXPECT_EQ(finite_brick_energy(FiniteBrickVector::Zero(), h, mu, lambda, &g, &k), 0.0);
  EXPECT_LT(g.cwiseAbs().maxCoeff(), 1e-18);
  const BrickMatrix bbar = brick_stiffness(h, mu, lambda, BrickIntegration::bbar);
  EXPECT_LT((k - bbar).cwiseAbs().maxCoeff(), 1e-12 * bbar.cwiseAbs().maxCoeff());
  // a finite rotation (0.6 rad) and shift: no energy, no force
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(0.6, Eigen::Vector3d(1, 2, 2).normalized()).toRotationMatrix();
  const FiniteBrickVector rigid = displacement_of(h, turn - Eigen::Matrix3d::Identity(), {0.3, -0.1, 0.2});
  EXPECT_NEAR(finite_brick_energy(rigid, h, mu, lambda, &g), 0.0, 1e-15);
  EXPECT_LT(g.cwiseAbs().maxCoeff(), 1e-15);
  // a finite non-uniform deformation: about 20 % strains, a corner pushed in
  Eigen::Matrix3d grad;
  grad << 0.15, 0.05, -0.1, 0.02, -0.2, 0.08, 0.1, 0.0, -0.25;
  FiniteBrickVector u = displacement_of(h, grad, {0, 0, 0});
  u.segment<3>(21) += Eigen::Vector3d(-0.05, 0.03, -0.08);
  for (const auto energy : {&finite_brick_energy, &reference::corotational_brick_energy}) {
    energy(u, h, mu, lambda, &g, &k);
    const double step = 1e-6;
    double worst_g = 0, worst_k = 0;
    for (int b = 0; b < 24; ++b) {
      FiniteBrickVector up = u, down = u, gp, gm;
      up(b) += step;
      down(b) -= step;
      const double fd =
          (energy(up, h, mu, lambda, &gp, nullptr) - energy(down, h, mu, lambda, &gm, nullptr)) / (2 * step);
      worst_g = std::max(worst_g, std::abs(fd - g(b)));
      worst_k = std::max(worst_k, ((gp - gm) / (2 * step) - k.col(b)).cwiseAbs().maxCoeff());
    }
    EXPECT_LT(worst_g, 1e-7 * g.cwiseAbs().maxCoeff());
    EXPECT_LT(worst_k, 1e-6 * k.cwiseAbs().maxCoeff());
    EXPECT_LT((k - k.transpose()).cwiseAbs().maxCoeff(), 1e-9 * k.cwiseAbs().maxCoeff());
  }
  // the corotational law at rest: linear elasticity's energy under a uniform strain, no force
  // under a finite rotation
  const FiniteBrickVector strain = displacement_of(h, 1e-3 * (grad + grad.transpose()), {0, 0, 0});
  reference::corotational_brick_energy(FiniteBrickVector::Zero(), h, mu, lambda, &g, &k);
  const Eigen::Matrix3d eps = 1e-3 * (grad + grad.transpose());
  EXPECT_NEAR(0.5 * strain.dot(k * strain) /
                  (h * h * h * (mu * (eps.array() * eps.array()).sum() + 0.5 * lambda * eps.trace() * eps.trace())),
              1.0, 1e-9);
  EXPECT_NEAR(reference::corotational_brick_energy(rigid, h, mu, lambda, &g), 0.0, 1e-15);
  EXPECT_LT(g.cwiseAbs().maxCoeff(), 1e-15);
}

// The finite-strain reference pressed (prints, asserts nothing): F(nu) / F(0) over the finite
// layer's ratio at each depth step. Run with --gtest_also_run_disabled_tests and, optionally,
// VX_VOXEL, VX_DEPTH (mm), VX_STEPS, VX_PENALTY (N/mm), VX_NU (one ratio only), VX_COROTATIONAL
// (the corotational law instead of the neo-Hookean), VX_ONLY_NU (one ratio's forces, no F(0)).
TEST(FiniteBrickReference, DISABLED_Measure) {
  FinitePress s;
  if (const char* v = std::getenv("VX_VOXEL")) s.voxel_mm = std::atof(v);
  if (const char* v = std::getenv("VX_DEPTH")) s.depth_mm = std::atof(v);
  if (const char* v = std::getenv("VX_STEPS")) s.steps = std::atoi(v);
  if (const char* v = std::getenv("VX_PENALTY")) s.penalty_n_mm = std::atof(v);
  if (std::getenv("VX_COROTATIONAL")) s.material = reference::FiniteMaterial::corotational;
  if (const char* v = std::getenv("VX_ONLY_NU")) {  // that ratio's forces only (no F(0))
    const auto r = finite_brick_press(s, std::atof(v));
    for (std::size_t k = 0; k < r.depth_mm.size(); ++k)
      std::cout << "MEASURE finite nu " << v << " depth " << r.depth_mm[k] << ": F " << r.force_n[k] << " newton "
                << r.newton_iterations[k] << " s " << r.total_s << std::endl;
    return;
  }
  const auto r0 = finite_brick_press(s, 0.0);
  std::cout << "MEASURE finite voxel " << s.voxel_mm << " dofs " << r0.dofs << " s " << r0.total_s << "\n";
  for (std::size_t k = 0; k < r0.depth_mm.size(); ++k)
    std::cout << "MEASURE finite nu 0 depth " << r0.depth_mm[k] << ": F(0) " << r0.force_n[k] << " / finite layer "
              << r0.force_n[k] / hertz_bonded_layer_n(10, 0.0, kR, r0.depth_mm[k], kH) << " newton "
              << r0.newton_iterations[k] << " contact " << r0.contact_nodes[k] << std::endl;
  for (const double nu : {0.3, 0.45, 0.49}) {
    if (std::getenv("VX_NU") && std::atof(std::getenv("VX_NU")) != nu) continue;
    const auto r = finite_brick_press(s, nu);
    for (std::size_t k = 0; k < r.depth_mm.size(); ++k)
      std::cout << "MEASURE finite nu " << nu << " depth " << r.depth_mm[k] << ": ratio "
                << r.force_n[k] / r0.force_n[k] << " / ref " << finite_layer_ratio(nu, r.depth_mm[k]) << " = "
                << r.force_n[k] / r0.force_n[k] / finite_layer_ratio(nu, r.depth_mm[k]) << " newton "
                << r.newton_iterations[k] << " contact " << r.contact_nodes[k] << " s " << r.total_s << " penetration "
                << r.max_penetration_mm << std::endl;
  }
}

// The measurement behind the doc's table (prints, asserts nothing). Run with
// --gtest_also_run_disabled_tests and, optionally, VX_VOXEL (mm; default 1), VX_WHOLE (the whole
// block instead of the quarter), VX_PARABOLOID (Hertz's paraboloid instead of the sphere),
// VX_FULL_INTEGRATION, VX_WIDTH, VX_HEIGHT and VX_DEPTH (mm), VX_NU (one ratio only),
// VX_MODEL_ELEMENT (the model's voxel element linearised instead of the brick; see below),
// VX_RADIAL (the sphere's normals: BrickPress::radial_normals).
TEST(BrickReference, DISABLED_Measure) {
  BrickPress s;
  if (const char* v = std::getenv("VX_VOXEL")) s.voxel_mm = std::atof(v);
  if (const char* v = std::getenv("VX_WIDTH")) s.width_mm = std::atof(v);
  if (const char* v = std::getenv("VX_HEIGHT")) s.height_mm = std::atof(v);
  if (const char* v = std::getenv("VX_DEPTH")) s.depth_mm = std::atof(v);
  s.quarter = std::getenv("VX_WHOLE") == nullptr;
  s.paraboloid = std::getenv("VX_PARABOLOID") != nullptr;
  s.radial_normals = std::getenv("VX_RADIAL") != nullptr;
  if (std::getenv("VX_FULL_INTEGRATION")) s.integration = BrickIntegration::full;
  // VX_MODEL_ELEMENT: the model's voxel element linearised (model_element_stiffness) with
  // VX_CAP (CalibrationOptions::volume_variation_cap), VX_VMF (volume_mean_fraction), VX_RELIEF (bending_relief),
  // VX_XYZ (xyz_relief)
  const bool model = std::getenv("VX_MODEL_ELEMENT") != nullptr;
  CalibrationOptions options;
  if (const char* v = std::getenv("VX_CAP")) options.volume_variation_cap = std::atof(v);
  if (const char* v = std::getenv("VX_VMF")) options.volume_mean_fraction = std::atof(v);
  if (const char* v = std::getenv("VX_RELIEF")) options.bending_relief = std::atof(v);
  if (const char* v = std::getenv("VX_XYZ")) options.xyz_relief = std::atof(v);
  auto press = [&](double nu) {
    if (!model) return brick_press(s, nu);
    const BrickMatrix k = model_element_stiffness(s.voxel_mm, nu, options);
    return brick_press(s, nu, &k);
  };
  if (std::getenv("VX_WHOLE_MODEL")) {  // the gradational (or VX_LAYOUT) model linearised whole
    const Layout lay = std::getenv("VX_LAYOUT") ? parse_layout(std::getenv("VX_LAYOUT")) : Layout::gradational;
    const auto r0 = linearised_model_press(lay, 0.0, options, s.depth_mm);
    const double ref0 = hertz_bonded_layer_n(10, 0.0, s.radius_mm, s.depth_mm, s.height_mm);
    std::cout << "MEASURE linearised " << to_string(lay) << " vmf " << options.volume_mean_fraction << " cap "
              << options.volume_variation_cap << " depth " << s.depth_mm << ": dofs " << r0.dofs << " F(0) "
              << r0.force_n << " quotient " << r0.force_n / ref0 << std::endl;
    for (const double nu : {0.3, 0.45, 0.49}) {
      const auto r = linearised_model_press(lay, nu, options, s.depth_mm);
      const double ref = hertz_bonded_layer_n(10, nu, s.radius_mm, s.depth_mm, s.height_mm) / ref0;
      std::cout << "MEASURE linearised " << to_string(lay) << " cap " << options.volume_variation_cap << " nu " << nu
                << ": ratio " << r.force_n / r0.force_n << " / ref " << ref << " = " << r.force_n / r0.force_n / ref
                << " contact nodes " << r.contact_nodes << std::endl;
    }
    return;
  }
  const std::string what = std::string(model                                     ? "model-element"
                                       : s.integration == BrickIntegration::bbar ? "bbar"
                                                                                 : "full") +
                           " voxel " + std::to_string(s.voxel_mm) + (s.quarter ? " quarter" : " whole") +
                           (s.paraboloid       ? " paraboloid"
                            : s.radial_normals ? " sphere-normals"
                                               : " sphere") +
                           " depth " + std::to_string(s.depth_mm) + " block " + std::to_string(s.width_mm) + " x " +
                           std::to_string(s.height_mm);
  const auto r0 = press(0.0);
  const double ref0 = hertz_bonded_layer_n(10, 0.0, s.radius_mm, s.depth_mm, s.height_mm);
  std::cout << "MEASURE " << what << ": dofs " << r0.dofs << " factor nonzeros " << r0.factor_nonzeros << " factor s "
            << r0.factor_s << " total s " << r0.total_s << " F(0) " << r0.force_n << " finite layer " << ref0
            << " quotient " << r0.force_n / ref0 << std::endl;
  for (const double nu : {0.3, 0.45, 0.49}) {
    if (std::getenv("VX_NU") && std::atof(std::getenv("VX_NU")) != nu) continue;
    const auto r = press(nu);
    const double ref = hertz_bonded_layer_n(10, nu, s.radius_mm, s.depth_mm, s.height_mm) / ref0;
    std::cout << "MEASURE " << what << " nu " << nu << ": F " << r.force_n << " ratio " << r.force_n / r0.force_n
              << " / ref " << ref << " = " << r.force_n / r0.force_n / ref << " contact nodes " << r.contact_nodes
              << " rounds " << r.active_set_rounds << std::endl;
  }
}

}  // namespace vx
