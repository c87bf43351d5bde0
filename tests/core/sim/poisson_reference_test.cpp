// An independent reference for the Poisson press (issue 27, docs/model.md section 5, "Against a
// B-bar brick on the same mesh"): poisson_locking_test's scene (a ball of R 4 mm pressed 2 mm
// into a 32 x 32 x 16 mm block bonded at its base) solved with plain linear finite elements on
// the voxel layout's mesh (support/brick_reference.h: trilinear bricks, B-bar), its force ratio
// F(nu) / F(0) against the bonded finite-layer solution's. It tells what any trilinear element
// on 1 mm voxels can reach, apart from the model's own element.
#include <gtest/gtest.h>

#include <cstdlib>
#include <iostream>
#include <string>

#include "physics/elements.h"
#include "physics/material.h"
#include "physics/physics_model.h"
#include "scene/sim_output.h"
#include "support/brick_reference.h"
#include "support/physics_helpers.h"

namespace vx {
namespace {

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

double finite_layer_ratio(double nu) {
  return hertz_bonded_layer_n(10, nu, kR, kDepth, kH) / hertz_bonded_layer_n(10, 0.0, kR, kDepth, kH);
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

// The press on 1 mm voxels (the quarter block, symmetric about the ball's axis; ~1 s). Measured:
// see docs/model.md section 5 ("Against a B-bar brick on the same mesh"). The bounds are the
// measured values' neighbourhood (a guard of the reference, so that the figures the doc quotes
// stay reproducible), and the physics it must show: the fully integrated brick locks.
TEST(BrickReference, PressOnOneMillimetreVoxels) {
  BrickPress s;
  const double f0 = brick_press(s, 0.0).force_n;
  const double ref0 = hertz_bonded_layer_n(10, 0.0, kR, kDepth, kH);
  std::cout << "B-bar, 1 mm: F(0) " << f0 << " N (finite layer " << ref0 << ")\n";
  for (const double nu : {0.3, 0.45, 0.49}) {
    const auto r = brick_press(s, nu);
    std::cout << "nu " << nu << ": F(nu) / F(0) = " << r.force_n / f0 << ", finite layer " << finite_layer_ratio(nu)
              << ", quotient " << r.force_n / f0 / finite_layer_ratio(nu) << " (" << r.contact_nodes
              << " contact nodes of the quarter, " << r.active_set_rounds << " rounds)\n";
  }
  s.integration = BrickIntegration::full;
  const double full0 = brick_press(s, 0.0).force_n, full49 = brick_press(s, 0.49).force_n;
  std::cout << "fully integrated, 1 mm: F(0) " << full0 << " N, F(0.49) / F(0) = " << full49 / full0 << "\n";
}

// The measurement behind the doc's table (prints, asserts nothing). Run with
// --gtest_also_run_disabled_tests and, optionally, VX_VOXEL (mm; default 1), VX_WHOLE (the whole
// block instead of the quarter), VX_PARABOLOID (Hertz's paraboloid instead of the sphere),
// VX_FULL_INTEGRATION, VX_WIDTH, VX_HEIGHT and VX_DEPTH (mm), VX_NU (one ratio only),
// VX_MODEL_ELEMENT (the model's voxel element linearised instead of the brick; see below).
TEST(BrickReference, DISABLED_Measure) {
  BrickPress s;
  if (const char* v = std::getenv("VX_VOXEL")) s.voxel_mm = std::atof(v);
  if (const char* v = std::getenv("VX_WIDTH")) s.width_mm = std::atof(v);
  if (const char* v = std::getenv("VX_HEIGHT")) s.height_mm = std::atof(v);
  if (const char* v = std::getenv("VX_DEPTH")) s.depth_mm = std::atof(v);
  s.quarter = std::getenv("VX_WHOLE") == nullptr;
  s.paraboloid = std::getenv("VX_PARABOLOID") != nullptr;
  if (std::getenv("VX_FULL_INTEGRATION")) s.integration = BrickIntegration::full;
  // VX_MODEL_ELEMENT: the model's voxel element linearised (model_element_stiffness) with
  // VX_CAP (CalibrationOptions::volume_variation_cap), VX_RELIEF (bending_relief), VX_XYZ (xyz_relief)
  const bool model = std::getenv("VX_MODEL_ELEMENT") != nullptr;
  CalibrationOptions options;
  if (const char* v = std::getenv("VX_CAP")) options.volume_variation_cap = std::atof(v);
  if (const char* v = std::getenv("VX_RELIEF")) options.bending_relief = std::atof(v);
  if (const char* v = std::getenv("VX_XYZ")) options.xyz_relief = std::atof(v);
  auto press = [&](double nu) {
    if (!model) return brick_press(s, nu);
    const BrickMatrix k = model_element_stiffness(s.voxel_mm, nu, options);
    return brick_press(s, nu, &k);
  };
  const std::string what = std::string(model                                     ? "model-element"
                                       : s.integration == BrickIntegration::bbar ? "bbar"
                                                                                 : "full") +
                           " voxel " + std::to_string(s.voxel_mm) + (s.quarter ? " quarter" : " whole") +
                           (s.paraboloid ? " paraboloid" : " sphere") + " depth " + std::to_string(s.depth_mm) +
                           " block " + std::to_string(s.width_mm) + " x " + std::to_string(s.height_mm);
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
