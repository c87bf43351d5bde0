// The shape-keeping element: rotation fit, zero force at rest and under rigid motion, momentum
// balance, force = -gradient of the energy (finite differences), damping, determinism.
#include "physics/elements.h"

#include <gtest/gtest.h>

#include <cstring>
#include <iostream>
#include <limits>
#include <random>

#include "base/parallel.h"
#include "model/gradational_builder.h"
#include "model/voxel_shapes.h"
#include "physics/calibration.h"
#include "physics/element_batches.h"
#include "sim/state.h"
#include "support/physics_helpers.h"

namespace vx {
namespace {

using testing::hand_block;
using testing::hand_cube;
using testing::hand_element;
using testing::node_forces;

double trace_fit(const Eigen::Matrix3d& q, const Eigen::Matrix3d& a) { return (q.transpose() * a).trace(); }

// ------------------------------------------------------------------------------------------
// rotation fit

TEST(RotationFit, ReachesTheSvdOptimumFromAnyStartIncludingInvertedAndFlat) {
  std::mt19937 rng(7);
  RotationFitSettings fit{100, 1e-13};
  int cases = 0;
  for (int t = 0; t < 2000; ++t) {
    Eigen::Matrix3d a = testing::random_matrix(rng);
    const int kind = t % 5;
    if (kind == 1) a.col(2) *= -1.0;                             // often inverted
    if (kind == 2) a.row(2).setZero();                           // flat (rank 2)
    if (kind == 3) a = a.col(0) * a.col(1).transpose();          // collinear (rank 1)
    if (kind == 4) a = testing::random_rotation(rng) * Eigen::Vector3d(1.0, 1.0, -0.2).asDiagonal();  // inverted
    Eigen::Quaterniond q = t % 2 ? Eigen::Quaterniond::Identity() : Eigen::Quaterniond(testing::random_rotation(rng));
    bool conv = false;
    fit_rotation(a, q, fit, &conv);
    const Eigen::Matrix3d r = q.toRotationMatrix();
    EXPECT_NEAR(r.determinant(), 1.0, 1e-12);
    EXPECT_NEAR((r.transpose() * r - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
    const double best = trace_fit(optimal_rotation_svd(a), a);
    EXPECT_GE(trace_fit(r, a), best - 1e-9 * (1.0 + a.norm())) << "case " << t << " kind " << kind << "\n" << a;
    EXPECT_TRUE(conv) << "case " << t;
    ++cases;
  }
  EXPECT_EQ(cases, 2000);
}

TEST(RotationFit, WarmStartNeedsFewIterations) {
  std::mt19937 rng(3);
  int worst = 0;
  for (int t = 0; t < 500; ++t) {
    const Eigen::Matrix3d r = testing::random_rotation(rng);
    // a rotation with a moderate stretch, warm start 0.05 rad off
    Eigen::Matrix3d s = Eigen::Matrix3d::Identity() + 0.2 * testing::random_matrix(rng);
    s = 0.5 * (s + s.transpose()).eval();
    const Eigen::Matrix3d a = r * s;
    const Eigen::Matrix3d target = optimal_rotation_svd(a);
    Eigen::Quaterniond q(Eigen::AngleAxisd(0.05, Eigen::Vector3d(1, 2, 3).normalized()) * target);
    bool conv = false;
    const int it = fit_rotation(a, q, RotationFitSettings{20, 1e-10}, &conv);
    EXPECT_TRUE(conv);
    EXPECT_LT((q.toRotationMatrix() - target).norm(), 1e-8);
    worst = std::max(worst, it);
  }
  EXPECT_LE(worst, 4) << "Newton from a close warm start converges quadratically";
}

TEST(RotationFit, CollapsedElementKeepsItsWarmStart) {
  Eigen::Quaterniond q(Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitY()));
  const Eigen::Quaterniond before = q;
  bool conv = false;
  EXPECT_EQ(fit_rotation(Eigen::Matrix3d::Zero(), q, {}, &conv), 0);
  EXPECT_TRUE(conv);
  EXPECT_EQ(q.coeffs(), before.coeffs());
  // NaN input: reported as not converged, q untouched
  Eigen::Matrix3d bad = Eigen::Matrix3d::Identity();
  bad(1, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(fit_rotation(bad, q, {}, &conv), 0);
  EXPECT_FALSE(conv);
  EXPECT_EQ(q.coeffs(), before.coeffs());
}

TEST(RotationFit, ClosestWithDeterminantIsOnTheConstraintAndClosest) {
  std::mt19937 rng(11);
  for (int t = 0; t < 300; ++t) {
    Eigen::Matrix3d b = Eigen::Matrix3d::Identity() + 0.5 * testing::random_matrix(rng);
    if (t % 4 == 0) b.col(0) *= -1.0;  // inverted input
    const double det = 0.5 + (t % 7) * 0.3;
    Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
    const Eigen::Matrix3d g = closest_with_determinant(b, det, q, RotationFitSettings{50, 1e-13});
    EXPECT_NEAR(g.determinant(), det, 1e-9 * det);
    // no random point on the constraint (a perturbation of g rescaled to det) is closer
    for (int k = 0; k < 20; ++k) {
      Eigen::Matrix3d h = g + 0.01 * testing::random_matrix(rng);
      if (h.determinant() <= 0) continue;
      h *= std::cbrt(det / h.determinant());
      EXPECT_GE((h - b).norm(), (g - b).norm() - 1e-9);
    }
  }
}

// ------------------------------------------------------------------------------------------
// forces and energy

struct Fixture {
  std::shared_ptr<const PhysicsModel> physics;
  SimState state;
};

Fixture make(const Model& m, Material mat = {}, ElementKind element = CalibrationOptions{}.element) {
  CalibrationOptions opt;
  opt.element = element;
  Fixture f{make_physics_model(m, mat, {}, opt), {}};
  f.state = make_state(f.physics);
  return f;
}

/// An irregular 11-vertex element (any vertex set must work).
Eigen::Matrix3Xd irregular_points() {
  Eigen::Matrix3Xd p(3, 11);
  p << 0, 2, 0, 0, 2, 2, 0, 2.2, 1, 1.1, 0.3,  //
      0, 0, 2, 0, 2, 0, 2, 2.1, 1, 0.2, 1.9,   //
      0, 0, 0, 2, 0, 2, 2, 1.8, 2.1, 1.0, 0.7;
  return p;
}

TEST(Elements, ZeroForceAndEnergyAtRest) {
  for (const Model& m : {hand_cube(2.0), hand_block(3, 2, 2, 1.5), hand_element(irregular_points())}) {
    auto f = make(m);
    double energy = -1;
    const Eigen::Matrix3Xd nf = node_forces(f.state, true, &energy);
    EXPECT_LT(nf.cwiseAbs().maxCoeff(), 1e-15);
    EXPECT_LT(energy, 1e-20);
  }
}

TEST(Elements, ZeroForceAndEnergyUnderAnyRigidMotion) {
  std::mt19937 rng(5);
  for (const Model& m : {hand_cube(2.0), hand_block(3, 2, 2, 1.5), hand_element(irregular_points())}) {
    auto f = make(m);
    const double kscale = f.physics->element_stiffness[0] * 3.0;  // force scale, N (k * size)
    for (int t = 0; t < 20; ++t) {
      const Eigen::Matrix3d r = testing::random_rotation(rng);
      const Eigen::Vector3d shift = 100.0 * Eigen::Vector3d::Random();
      const Eigen::Vector3d v0 = 50.0 * Eigen::Vector3d::Random(), w = 20.0 * Eigen::Vector3d::Random();
      for (int i = 0; i < m.num_nodes(); ++i) {
        f.state.positions.col(i) = r * m.rest_positions.col(i) + shift;
        f.state.velocities.col(i) = v0 + w.cross(f.state.positions.col(i));  // rigid velocity
      }
      double energy = -1;
      const Eigen::Matrix3Xd nf = node_forces(f.state, true, &energy);
      EXPECT_LT(nf.cwiseAbs().maxCoeff(), 1e-11 * kscale) << "rigid motion must not create force";
      EXPECT_LT(energy, 1e-20);
    }
  }
}

TEST(Elements, ForcesSumToZeroAndTheirMomentsBalance) {
  std::mt19937 rng(9);
  Material mat;
  mat.damping_ratio = 0.3;
  for (const Model& m : {hand_cube(2.0), hand_block(3, 3, 2, 1.0), hand_element(irregular_points())}) {
    auto f = make(m, mat);
    const PhysicsModel& p = *f.physics;
    for (int t = 0; t < 10; ++t) {
      // a large random deformation (some elements inverted) with random velocities
      f.state.positions = m.rest_positions + 0.6 * Eigen::Matrix3Xd::Random(3, m.num_nodes());
      f.state.velocities = 30.0 * Eigen::Matrix3Xd::Random(3, m.num_nodes());
      Eigen::Matrix3Xd ef(3, p.num_vertex_entries());
      ElementPassScratch scratch;
      ElementPassOptions opt;
      opt.damping = true;
      opt.rotation = {200, 1e-14};
      compute_element_forces(p, f.state.positions, &f.state.velocities, f.state.rotations, ef, nullptr, opt, 1, scratch);
      for (int e = 0; e < m.num_elements(); ++e) {
        const int b = m.element_offsets[e], n = m.num_vertices(e);
        Eigen::Vector3d c = Eigen::Vector3d::Zero(), sum = Eigen::Vector3d::Zero(), moment = Eigen::Vector3d::Zero();
        for (int j = b; j < b + n; ++j) c += f.state.positions.col(m.element_vertices[j]) / n;
        double scale = 0;
        for (int j = b; j < b + n; ++j) {
          const Eigen::Vector3d fj = ef.col(p.entry_slot[std::size_t(j)]);
          sum += fj;
          moment += (f.state.positions.col(m.element_vertices[j]) - c).cross(fj);
          scale = std::max(scale, fj.norm());
        }
        EXPECT_LT(sum.norm(), 1e-12 * scale * n) << "element " << e;
        EXPECT_LT(moment.norm(), 1e-11 * scale * n) << "element " << e;
      }
    }
  }
}

/// Central finite differences of the total elastic energy against the forces.
void expect_gradient(const Model& m, const Material& mat, std::uint32_t seed, double amplitude) {
  auto f = make(m, mat);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-amplitude, amplitude);
  for (int i = 0; i < m.num_nodes(); ++i)
    for (int d = 0; d < 3; ++d) f.state.positions(d, i) = m.rest_positions(d, i) + u(rng);
  double e0 = 0;
  const Eigen::Matrix3Xd force = node_forces(f.state, false, &e0);
  ASSERT_GT(e0, 0);
  const double hstep = 1e-6;
  double worst = 0;
  const double scale = force.cwiseAbs().maxCoeff();
  for (int i = 0; i < m.num_nodes(); ++i)
    for (int d = 0; d < 3; ++d) {
      SimState s = f.state;
      s.positions(d, i) += hstep;
      double ep = 0, em = 0;
      node_forces(s, false, &ep);
      s.positions(d, i) -= 2 * hstep;
      node_forces(s, false, &em);
      const double grad = (ep - em) / (2 * hstep);
      worst = std::max(worst, std::abs(force(d, i) + grad));
    }
  EXPECT_LT(worst, 1e-6 * scale) << "force = -dE/dx within 1e-6 of the largest force component";
}

TEST(Elements, ForceIsMinusTheEnergyGradient) {
  // (the default element, hourglass; element_modes_test checks both elements on gradational models)
  expect_gradient(hand_cube(2.0), {}, 1, 0.5);
  expect_gradient(hand_block(2, 2, 2, 1.0), {}, 2, 0.3);
  expect_gradient(hand_element(irregular_points()), {}, 3, 0.5);
  // large deformation including inversion
  expect_gradient(hand_cube(1.0), {}, 4, 0.9);
}

TEST(Elements, VolumeTermForceIsMinusItsEnergyGradient) {
  Material mat;
  mat.poisson_ratio = 0.45;
  expect_gradient(hand_cube(2.0), mat, 5, 0.4);
  expect_gradient(hand_block(2, 2, 1, 1.0), mat, 6, 0.2);
  expect_gradient(hand_element(irregular_points()), mat, 7, 0.3);
}

TEST(Elements, DampingOnlyRemovesDeformationEnergy) {
  Material mat;
  mat.damping_ratio = 0.5;
  std::mt19937 rng(13);
  auto f = make(hand_element(irregular_points()), mat);
  const PhysicsModel& p = *f.physics;
  const int n = p.num_nodes();
  f.state.positions += 0.2 * Eigen::Matrix3Xd::Random(3, n);
  for (int t = 0; t < 20; ++t) {
    f.state.velocities = 10.0 * Eigen::Matrix3Xd::Random(3, n);
    const Eigen::Matrix3Xd elastic = node_forces(f.state, false);
    const Eigen::Matrix3Xd total = node_forces(f.state, true);
    const Eigen::Matrix3Xd damp = total - elastic;
    // power of the damping force: -c |v - v_rigid|^2 <= 0
    double power = 0;
    for (int i = 0; i < n; ++i) power += damp.col(i).dot(f.state.velocities.col(i));
    EXPECT_LT(power, 0.0);
    // the rigid part of the velocity is not damped: adding a rigid velocity changes nothing
    SimState s = f.state;
    const Eigen::Vector3d v0(3, -1, 2), w(0.5, 2, -1);
    for (int i = 0; i < n; ++i) s.velocities.col(i) += v0 + w.cross(s.positions.col(i));
    const Eigen::Matrix3Xd damp2 = node_forces(s, true) - elastic;
    EXPECT_LT((damp2 - damp).cwiseAbs().maxCoeff(), 1e-9 * damp.cwiseAbs().maxCoeff());
  }
}

TEST(Elements, InvertedAndCrushedElementsArePushedBack) {
  auto f = make(hand_cube(2.0));
  const Model& m = *f.physics->model;
  // mirror the cube through its mid-plane z = 1: inverted
  for (int i = 0; i < m.num_nodes(); ++i) f.state.positions(2, i) = 2.0 - m.rest_positions(2, i);
  double energy = 0;
  Eigen::Matrix3Xd force = node_forces(f.state, false, &energy);
  EXPECT_GT(energy, 0);
  // a small move along the force lowers the energy
  SimState s = f.state;
  s.positions += 1e-4 * force / force.cwiseAbs().maxCoeff();
  double lower = 0;
  node_forces(s, false, &lower);
  EXPECT_LT(lower, energy);
  // crushed flat (all z = 1): the force has a z-component that restores the height
  for (int i = 0; i < m.num_nodes(); ++i) f.state.positions(2, i) = 1.0;
  force = node_forces(f.state, false, &energy);
  for (int i = 0; i < m.num_nodes(); ++i)
    EXPECT_GT(force(2, i) * (m.rest_positions(2, i) - 1.0), 0.0) << "node " << i << " pushed back out";
  // collapsed to a point: pushed back towards the rest shape
  for (int i = 0; i < m.num_nodes(); ++i) f.state.positions.col(i) = Eigen::Vector3d(1, 1, 1);
  force = node_forces(f.state, false, &energy);
  for (int i = 0; i < m.num_nodes(); ++i)
    EXPECT_GT(force.col(i).dot(m.rest_positions.col(i) - Eigen::Vector3d(1, 1, 1)), 0.0);
}

TEST(Elements, BitIdenticalForOneAndManyThreads) {
  Material mat;
  mat.damping_ratio = 0.2;
  mat.poisson_ratio = 0.3;
  auto f = make(hand_block(24, 20, 16, 1.0), mat);
  const PhysicsModel& p = *f.physics;
  f.state.positions += 0.3 * Eigen::Matrix3Xd::Random(3, p.num_nodes());
  f.state.velocities = Eigen::Matrix3Xd::Random(3, p.num_nodes());
  Eigen::Matrix3Xd ref, nf;
  double ref_energy = 0;
  for (int threads : {1, 2, 3, 4}) {
    std::vector<Eigen::Quaterniond> rot = f.state.rotations;
    Eigen::Matrix3Xd ef(3, p.num_vertex_entries());
    std::vector<double> en;
    ElementPassScratch scratch;
    ElementPassOptions opt;
    opt.energy = true;
    const auto st = compute_element_forces(p, f.state.positions, &f.state.velocities, rot, ef, &en, opt, threads, scratch);
    gather_node_forces(p, ef, nf, threads);
    if (threads == 1) {
      ref = nf;
      ref_energy = st.elastic_energy;
    } else {
      EXPECT_EQ(std::memcmp(ref.data(), nf.data(), sizeof(double) * std::size_t(nf.size())), 0) << threads << " threads";
      EXPECT_EQ(st.elastic_energy, ref_energy) << threads << " threads";
    }
  }
}

/// The force of every vertex entry (3 x entries, entry order) by a plain per-element Eigen loop,
/// straight from the formulas of elements.h; rotations from fit_rotation with the warm starts
/// `rot` (updated), as the kernels do.
Eigen::Matrix3Xd plain_entry_forces(const PhysicsModel& p, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v,
                                    std::vector<Eigen::Quaterniond>& rot, const RotationFitSettings& fit) {
  const Model& m = *p.model;
  Eigen::Matrix3Xd out(3, p.num_vertex_entries());
  for (int e = 0; e < m.num_elements(); ++e) {
    const int b = m.element_offsets[e], n = m.num_vertices(e);
    const auto xe = [&](int j) -> Eigen::Vector3d { return x.col(m.element_vertices[j]); };
    const auto ve = [&](int j) -> Eigen::Vector3d { return v.col(m.element_vertices[j]); };
    double sw = 0;
    Eigen::Vector3d c = Eigen::Vector3d::Zero(), vc = Eigen::Vector3d::Zero();
    for (int j = b; j < b + n; ++j) {
      sw += p.entry_weight[j];
      c += p.entry_weight[j] * xe(j);
      vc += p.entry_weight[j] * ve(j);
    }
    c /= sw;
    vc /= sw;
    Eigen::Matrix3d a = Eigen::Matrix3d::Zero(), fg = Eigen::Matrix3d::Zero(), inertia = Eigen::Matrix3d::Zero();
    Eigen::Vector3d ang = Eigen::Vector3d::Zero();
    for (int j = b; j < b + n; ++j) {
      const Eigen::Vector3d r = xe(j) - c;
      const double w = p.entry_weight[j];
      a += r * p.entry_rest_weighted.col(j).transpose();
      fg += r * p.entry_gradient.col(j).transpose();
      inertia += w * (r.squaredNorm() * Eigen::Matrix3d::Identity() - r * r.transpose());
      ang += w * r.cross(ve(j) - vc);
    }
    // the kernels' regularisation: 1e-10 tr(sum w r r^T) on the diagonal
    inertia.diagonal().array() += 0.5e-10 * inertia.trace();
    const Eigen::Vector3d omega = inertia.inverse() * ang;
    fit_rotation(fg, rot[std::size_t(e)], fit);
    const Eigen::Matrix3d q = rot[std::size_t(e)].toRotationMatrix();
    const double k = p.element_stiffness[e];
    Eigen::Matrix3d gm = p.element_affine_stiffness[e] * (q - fg) + k * (a - fg * p.element_spread[e]);
    if (p.has_volume_term()) {  // the volume term on the consistent F: k_v (T - F), det T = 1
      Eigen::Quaterniond qv = rot[std::size_t(e)];
      gm += p.element_volume_stiffness[e] * (closest_with_determinant(fg, 1.0, qv, fit) - fg);
    }
    // the hourglass element's bending modes: amplitudes qm = sum_j (x_j - c) h_j^T
    Eigen::Matrix<double, 3, kBendingModes> qm = Eigen::Matrix<double, 3, kBendingModes>::Zero();
    if (p.has_bending_modes())
      for (int j = b; j < b + n; ++j) qm += (xe(j) - c) * p.entry_modes.col(j).transpose();
    for (int j = b; j < b + n; ++j) {
      const Eigen::Vector3d r = xe(j) - c, r0 = p.entry_rest.col(j);
      const double w = p.entry_weight[j];
      out.col(j) = k * w * (fg * r0 - r) + gm * p.entry_gradient.col(j) +
                   p.element_damping[e] * w * (vc + omega.cross(r) - ve(j));
      if (p.has_bending_modes()) out.col(j) += qm * p.entry_modes.col(j);
    }
  }
  return out;
}

class PackedKernel : public ::testing::TestWithParam<ElementKind> {};

TEST_P(PackedKernel, MatchesThePlainFormulasAndTheReferenceKernel) {
  // a gradational ball (elements with extra face vertices, non-uniform weights), with damping
  // and the volume term, deformed and moving; the paper's element and the hourglass one
  Material mat;
  mat.damping_ratio = 0.3;
  mat.poisson_ratio = 0.35;
  BuildSettings bs;
  bs.layout = Layout::gradational;
  auto f = make(build_model(ball_grid(14, 6.0), bs), mat, GetParam());
  ASSERT_EQ(f.physics->has_bending_modes(), GetParam() == ElementKind::hourglass);
  const PhysicsModel& p = *f.physics;
  const Model& m = *p.model;
  ASSERT_GT(m.num_levels(), 1);
  ASSERT_EQ(std::int64_t(p.entry_packed.size()), p.num_vertex_entries());
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const RotationFitSettings fit{100, 1e-14};
  for (const double amplitude : {0.05, 0.3}) {
    for (int i = 0; i < m.num_nodes(); ++i)
      for (int d = 0; d < 3; ++d) {
        f.state.positions(d, i) = m.rest_positions(d, i) + amplitude * u(rng);
        f.state.velocities(d, i) = 20.0 * u(rng);
      }
    const auto run = [&](ElementKernel kernel, Eigen::Matrix3Xd& ef, std::vector<double>& en,
                         std::vector<Eigen::Quaterniond>& rot) {
      ElementPassScratch scratch;
      ElementPassOptions opt;
      opt.energy = true;
      opt.rotation = fit;
      opt.kernel = kernel;
      rot = f.state.rotations;
      return compute_element_forces(p, f.state.positions, &f.state.velocities, rot, ef, &en, opt, 2, scratch);
    };
    Eigen::Matrix3Xd ef_packed, ef_ref;
    std::vector<double> en_packed, en_ref;
    std::vector<Eigen::Quaterniond> rot_packed, rot_ref, rot_plain = f.state.rotations;
    const auto st_packed = run(ElementKernel::packed, ef_packed, en_packed, rot_packed);
    const auto st_ref = run(ElementKernel::reference, ef_ref, en_ref, rot_ref);
    const Eigen::Matrix3Xd plain = plain_entry_forces(p, f.state.positions, f.state.velocities, rot_plain, fit);
    double scale = 0, worst_plain = 0, worst_ref = 0;
    for (std::int64_t j = 0; j < p.num_vertex_entries(); ++j) {
      const Eigen::Vector3d fp = ef_packed.col(p.entry_slot[std::size_t(j)]);
      scale = std::max(scale, plain.col(j).cwiseAbs().maxCoeff());
      worst_plain = std::max(worst_plain, (fp - plain.col(j)).cwiseAbs().maxCoeff());
      worst_ref = std::max(worst_ref, (fp - ef_ref.col(p.entry_slot[std::size_t(j)])).cwiseAbs().maxCoeff());
    }
    ASSERT_GT(scale, 0);
    std::cout << "amplitude " << amplitude << ": largest force " << scale << " N, packed - plain "
              << worst_plain / scale << ", packed - reference " << worst_ref / scale << " (relative)\n";
    EXPECT_LT(worst_plain, 1e-12 * scale) << "amplitude " << amplitude << ": packed kernel against the plain formulas";
    EXPECT_LT(worst_ref, 1e-12 * scale) << "amplitude " << amplitude << ": packed against reference kernel";
    // energies, rotations and counters alike
    double en_scale = 0, en_worst = 0;
    for (int e = 0; e < m.num_elements(); ++e) {
      en_scale = std::max(en_scale, std::abs(en_ref[std::size_t(e)]));
      en_worst = std::max(en_worst, std::abs(en_packed[std::size_t(e)] - en_ref[std::size_t(e)]));
      EXPECT_LT((rot_packed[std::size_t(e)].coeffs() - rot_ref[std::size_t(e)].coeffs()).norm(), 1e-12);
      EXPECT_LT((rot_packed[std::size_t(e)].coeffs() - rot_plain[std::size_t(e)].coeffs()).norm(), 1e-12);
    }
    EXPECT_LT(en_worst, 1e-12 * en_scale);
    EXPECT_NEAR(st_packed.elastic_energy, st_ref.elastic_energy, 1e-12 * std::abs(st_ref.elastic_energy));
    EXPECT_EQ(st_packed.rotation_iterations, st_ref.rotation_iterations);
    EXPECT_EQ(st_packed.inverted, st_ref.inverted);
    EXPECT_EQ(st_packed.unconverged, st_ref.unconverged);
    EXPECT_EQ(st_packed.non_finite, 0);
  }
}

INSTANTIATE_TEST_SUITE_P(Elements, PackedKernel, ::testing::Values(ElementKind::paper, ElementKind::hourglass),
                         [](const auto& info) { return std::string(to_string(info.param)); });

// ------------------------------------------------------------------------------------------
// the batched kernel (element_batches.h)

/// A damped gradational ball (elements with extra face vertices, non-uniform weights), Poisson 0
/// (the batched kernel's case), its nodes moved by up to `amplitude` mm and moving.
Fixture batched_ball(double amplitude, unsigned seed, ElementKind element = CalibrationOptions{}.element) {
  Material mat;
  mat.damping_ratio = 0.3;
  BuildSettings bs;
  bs.layout = Layout::gradational;
  auto f = make(build_model(ball_grid(14, 6.0), bs), mat, element);
  const Model& m = *f.physics->model;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < m.num_nodes(); ++i)
    for (int d = 0; d < 3; ++d) {
      f.state.positions(d, i) = m.rest_positions(d, i) + amplitude * u(rng);
      f.state.velocities(d, i) = 20.0 * u(rng);
    }
  return f;
}

struct PassResult {
  Eigen::Matrix3Xd entry_forces;
  std::vector<Eigen::Quaterniond> rotations;
  ElementPassStats stats;
};

PassResult element_pass(const PhysicsModel& p, const SimState& s, ElementKernel kernel, int threads,
                        const RotationFitSettings& fit = {}, SimdLevel simd = SimdLevel::automatic) {
  PassResult r;
  r.rotations = s.rotations;
  ElementPassScratch scratch;
  ElementPassOptions opt;
  opt.kernel = kernel;
  opt.rotation = fit;
  opt.simd = simd;
  r.stats = compute_element_forces(p, s.positions, &s.velocities, r.rotations, r.entry_forces, nullptr, opt, threads,
                                   scratch);
  return r;
}

/// Largest entry-force difference relative to the largest force; rotations must agree to 1e-12.
double relative_difference(const PassResult& a, const PassResult& b) {
  const double scale = b.entry_forces.cwiseAbs().maxCoeff();
  EXPECT_GT(scale, 0.0);
  for (std::size_t e = 0; e < a.rotations.size(); ++e)
    EXPECT_LT((a.rotations[e].coeffs() - b.rotations[e].coeffs()).norm(), 1e-12) << "element " << e;
  return (a.entry_forces - b.entry_forces).cwiseAbs().maxCoeff() / scale;
}

TEST(ElementBatches, CoverEveryVertexEntryOnceWithLittlePadding) {
  const auto f = batched_ball(0.0, 1);
  const PhysicsModel& p = *f.physics;
  const Model& m = *p.model;
  const ElementBatches& eb = p.element_batches;
  ASSERT_EQ(std::int64_t(eb.window_offsets.size()), chunk_count(p.num_elements(), kElementGrain) + 1);
  EXPECT_TRUE(eb.unbatched.empty());
  std::vector<int> seen(std::size_t(m.num_elements()), 0);
  std::int64_t rows = 0;
  for (std::size_t w = 0; w + 1 < eb.window_offsets.size(); ++w)
    for (std::int32_t b = eb.window_offsets[w]; b < eb.window_offsets[w + 1]; ++b) {
      const ElementBatch& bt = eb.batches[std::size_t(b)];
      EXPECT_EQ(bt.first_row, rows);
      rows += bt.rows;
      for (int l = 0; l < kBatchLanes; ++l) {
        const int e = bt.element[l];
        if (e < 0) {
          EXPECT_EQ(bt.count[l], 0);
          continue;
        }
        ++seen[std::size_t(e)];
        EXPECT_EQ(std::int64_t(e) / kElementGrain, std::int64_t(w)) << "element " << e << " left its window";
        EXPECT_EQ(bt.count[l], m.num_vertices(e));
        EXPECT_EQ(bt.stiffness[l], p.element_stiffness[std::size_t(e)]);
        for (int r = 0; r < bt.rows; ++r) {
          const BatchRow& row = eb.rows[std::size_t(bt.first_row + r)];
          if (r >= bt.count[l]) {  // padding: nothing to add, nothing written
            EXPECT_EQ(row.weight[l], 0.0);
            EXPECT_EQ(row.gradient[0][l], 0.0);
            EXPECT_EQ(row.slot[l], -1);
            continue;
          }
          const PackedEntry& pe = p.entry_packed[std::size_t(m.element_offsets[std::size_t(e)] + r)];
          EXPECT_EQ(row.vertex[l], pe.vertex);
          EXPECT_EQ(row.slot[l], pe.slot);
          EXPECT_EQ(row.weight[l], pe.weight);
          for (int d = 0; d < 3; ++d) {
            EXPECT_EQ(row.rest_weighted[d][l], pe.rest_weighted[d]);
            EXPECT_EQ(row.gradient[d][l], pe.gradient[d]);
          }
        }
      }
    }
  EXPECT_EQ(rows, std::int64_t(eb.rows.size()));
  for (std::size_t e = 0; e < seen.size(); ++e) EXPECT_EQ(seen[e], 1) << "element " << e;
  // the lanes of a batch have nearly equal counts: little padding
  const double padded = double(rows * kBatchLanes) / double(p.num_vertex_entries());
  std::cout << "batch rows x lanes / vertex entries: " << padded << "\n";
  EXPECT_LT(padded, 1.05);
}

class BatchedKernel : public ::testing::TestWithParam<ElementKind> {};

TEST_P(BatchedKernel, MatchesThePackedKernelWithEveryInstructionSet) {
  std::cout << "this CPU: " << to_string(best_simd_level()) << ", element " << to_string(GetParam()) << "\n";
  // 2 mm: some elements inverted
  for (const double amplitude : {0.05, 0.3, 2.0}) {
    const auto f = batched_ball(amplitude, 21, GetParam());
    const PhysicsModel& p = *f.physics;
    ASSERT_EQ(p.element_batches.mode_rows.size(), p.has_bending_modes() ? p.element_batches.rows.size() : 0u);
    // from the rest warm start (many lanes need the scalar fit, fitted tightly here), then again
    // from the fitted rotations with the default tolerance (every lane passes the vectorised
    // test), then a little later (most lanes end with the vectorised Newton step)
    const RotationFitSettings tight{100, 1e-13};
    const PassResult packed = element_pass(p, f.state, ElementKernel::packed, 2, tight);
    SimState next = f.state;
    next.rotations = packed.rotations;
    const PassResult packed2 = element_pass(p, next, ElementKernel::packed, 2);
    EXPECT_EQ(packed2.stats.rotation_iterations, 0);
    // a step on (every element turns a little): the fit ends after one short Newton step
    SimState moved = next;
    moved.positions += 1e-4 * moved.velocities;
    const PassResult packed3 = element_pass(p, moved, ElementKernel::packed, 2);
    EXPECT_GE(packed3.stats.rotation_iterations, p.num_elements() / 2);
    for (const SimdLevel simd : {SimdLevel::generic, SimdLevel::avx2, SimdLevel::avx512}) {
      if (!simd_supported(simd)) {
        std::cout << to_string(simd) << ": not on this CPU, not checked\n";
        continue;
      }
      SCOPED_TRACE(to_string(simd));
      const PassResult batched = element_pass(p, f.state, ElementKernel::batched, 2, tight, simd);
      const double first = relative_difference(batched, packed);
      EXPECT_EQ(batched.stats.rotation_iterations, packed.stats.rotation_iterations);
      EXPECT_GT(batched.stats.rotation_iterations, p.num_elements());
      EXPECT_EQ(batched.stats.inverted, packed.stats.inverted);
      EXPECT_EQ(batched.stats.unconverged, packed.stats.unconverged);
      EXPECT_EQ(batched.stats.non_finite, 0);
      const PassResult batched2 = element_pass(p, next, ElementKernel::batched, 2, {}, simd);
      const double second = relative_difference(batched2, packed2);
      EXPECT_EQ(batched2.stats.rotation_iterations, 0);
      EXPECT_EQ(batched2.stats.inverted, packed2.stats.inverted);
      const PassResult batched3 = element_pass(p, moved, ElementKernel::batched, 2, {}, simd);
      const double third = relative_difference(batched3, packed3);
      EXPECT_EQ(batched3.stats.rotation_iterations, packed3.stats.rotation_iterations);
      EXPECT_EQ(batched3.stats.unconverged, packed3.stats.unconverged);
      std::cout << to_string(simd) << ", amplitude " << amplitude << ": batched - packed " << first << ", " << second
                << ", " << third << " (relative); fit iterations " << batched.stats.rotation_iterations << ", "
                << batched3.stats.rotation_iterations << " over "
                << p.num_elements() << " elements, inverted " << batched.stats.inverted << "\n";
      EXPECT_LT(first, 1e-12);
      EXPECT_LT(second, 1e-12);
      EXPECT_LT(third, 1e-12);
      if (amplitude > 1.0) {
        EXPECT_GT(batched.stats.inverted, 0);
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Elements, BatchedKernel, ::testing::Values(ElementKind::paper, ElementKind::hourglass),
                         [](const auto& info) { return std::string(to_string(info.param)); });

TEST(ElementBatches, BitIdenticalForOneAndManyThreads) {
  const auto f = batched_ball(0.3, 5);
  const PhysicsModel& p = *f.physics;
  const PassResult one = element_pass(p, f.state, ElementKernel::batched, 1);
  for (int threads : {2, 3, 4}) {
    const PassResult many = element_pass(p, f.state, ElementKernel::batched, threads);
    EXPECT_EQ(std::memcmp(one.entry_forces.data(), many.entry_forces.data(),
                          sizeof(double) * std::size_t(one.entry_forces.size())),
              0)
        << threads << " threads";
    EXPECT_EQ(many.stats.rotation_iterations, one.stats.rotation_iterations);
  }
}

TEST(ElementBatches, ElementsLeftOutOfTheBatchesRunOnThePackedKernel) {
  const auto f = batched_ball(0.3, 9);
  // a copy of the model whose batches take elements of at most 12 entries
  PhysicsModel small = *f.physics;
  build_element_batches(small, kElementGrain, small.element_batches, 12);
  ASSERT_FALSE(small.element_batches.unbatched.empty());
  ASSERT_LT(std::int64_t(small.element_batches.unbatched.size()), small.num_elements());
  const PassResult packed = element_pass(*f.physics, f.state, ElementKernel::packed, 2);
  for (int threads : {1, 2}) {
    const PassResult mixed = element_pass(small, f.state, ElementKernel::batched, threads);
    EXPECT_LT(relative_difference(mixed, packed), 1e-12) << threads << " threads";
    EXPECT_EQ(mixed.stats.rotation_iterations, packed.stats.rotation_iterations);
  }
}

TEST(ElementBatches, ANonFiniteNodeSilencesOnlyItsElements) {
  auto f = batched_ball(0.05, 13);
  const PhysicsModel& p = *f.physics;
  const Model& m = *p.model;
  const PassResult clean = element_pass(p, f.state, ElementKernel::batched, 2);
  const int bad = m.num_nodes() / 2;
  f.state.positions(1, bad) = std::numeric_limits<double>::quiet_NaN();
  const PassResult hit = element_pass(p, f.state, ElementKernel::batched, 2);
  std::int64_t touching = 0;
  for (int e = 0; e < m.num_elements(); ++e) {
    bool has = false;
    for (int j = m.element_offsets[e]; j < m.element_offsets[e + 1]; ++j) has |= m.element_vertices[j] == bad;
    touching += has ? 1 : 0;
    for (int j = m.element_offsets[e]; j < m.element_offsets[e + 1]; ++j) {
      const int slot = p.entry_slot[std::size_t(j)];
      if (has)
        EXPECT_EQ(hit.entry_forces.col(slot), Eigen::Vector3d::Zero()) << "element " << e;
      else
        EXPECT_EQ(hit.entry_forces.col(slot), clean.entry_forces.col(slot)) << "element " << e;
    }
  }
  EXPECT_GT(touching, 0);
  EXPECT_EQ(hit.stats.non_finite, touching);
  EXPECT_TRUE(hit.entry_forces.allFinite());
}

}  // namespace
}  // namespace vx
