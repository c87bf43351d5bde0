// The projective-dynamics solver called directly (precompute, then solve; projective_solver.h),
// its agreement with the implicit integrator and the static solve that wrap it, the residual
// falling with the iterations, the contact active set against the weight it carries, and the
// state-owned cache: a copy of a state refactors, one integrator steps two states alike; the
// factor cache: a factor found by its key steps bit for bit as the one computed, and the key
// follows every input of the matrix; the first solve finds its buffers mapped (no page faults
// left to the tool's first touch).
#include "sim/projective_solver.h"

#include <gtest/gtest.h>
#include <sys/resource.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <cmath>
#include <cstring>
#include <iostream>
#include <memory>

#include "base/error.h"
#include "physics/calibration.h"
#include "sim/integrators.h"
#include "sim/state.h"
#include "sim/static_solver.h"
#include "support/physics_helpers.h"
#include "support/sparse_helpers.h"

namespace vx {
namespace {

using testing::hand_block;

Material soft(double damping = 0.0) {
  Material m;
  m.youngs_modulus_kpa = 5.0;
  m.density_kg_m3 = 1000.0;
  m.damping_ratio = damping;
  return m;
}

/// A 4 x 4 x 3 block of 2 mm cubes, its base fixed, its other nodes displaced by a smooth field.
SimState perturbed_block(double damping, double amplitude_mm = 0.3) {
  auto physics = make_physics_model(hand_block(4, 4, 3, 2.0), soft(damping));
  SimState s = make_state(physics);
  s.fix_nodes(nodes_on_face(*physics->model, BoxFace::z_min));
  for (int i = 0; i < s.num_nodes(); ++i) {
    if (s.node_fixed[std::size_t(i)]) continue;
    const Eigen::Vector3d r = s.positions.col(i);
    s.positions.col(i) +=
        amplitude_mm * Eigen::Vector3d(std::sin(0.4 * r.z()), 0.5 * std::cos(0.3 * r.x()), 0.2 * r.z() / 6);
  }
  return s;
}

/// Fills the solver's constant right-hand side of an implicit step (the integrator's rule) and
/// returns the start iterate x_n + dt v_n.
Eigen::Matrix3Xd implicit_start(ProjectiveSolver& solver, const SimState& s, double dt) {
  const PhysicsModel& p = *s.physics;
  Eigen::Matrix3Xd x = s.positions + dt * s.velocities;
  const std::vector<int>& free = solver.free_nodes();
  for (std::size_t f = 0; f < free.size(); ++f) {
    const int i = free[f];
    const double m = p.node_mass[std::size_t(i)];
    const Eigen::Vector3d y = x.col(i) + dt * dt * (s.gravity_mm_s2 + s.external_forces.col(i) / m);
    solver.constant_rhs().row(Eigen::Index(f)) = (m / (dt * dt)) * y.transpose();
  }
  return x;
}

TEST(ProjectiveSolver, DirectSolveIsTheImplicitIntegratorsStep) {
  for (double damping : {0.0, 0.2}) {
    SCOPED_TRACE(damping);
    const double dt = 2e-3;
    SimState direct = perturbed_block(damping);
    SimState stepped = direct;
    ProjectiveSetup setup;
    setup.time_step_s = dt;
    setup.damping = damping > 0;
    ProjectiveSolver solver(direct.physics, direct.node_fixed, setup);
    EXPECT_EQ(solver.num_free(), direct.num_nodes() - direct.num_fixed());
    EXPECT_GT(solver.factor_nonzeros(), solver.num_free());
    Eigen::Matrix3Xd x = implicit_start(solver, direct, dt);
    ProjectiveIterations its;
    its.max_iterations = 10;
    StepReport rep;
    solver.solve(direct, x, its, nullptr, rep);
    EXPECT_EQ(rep.iterations, 10);

    IntegratorSettings set;
    set.kind = IntegratorKind::implicit;
    set.time_step_s = dt;
    set.max_iterations = 10;
    auto integ = make_integrator(set);
    const StepReport r = integ->step(stepped);
    EXPECT_TRUE(r.refactored);
    EXPECT_EQ(r.factor_nonzeros, solver.factor_nonzeros());
    EXPECT_EQ((x - stepped.positions).cwiseAbs().maxCoeff(), 0.0) << "bit for bit";
  }
}

/// Page faults of the calling thread so far (first touches of memory: each maps a 4 KiB page).
long minor_faults() {
  rusage u{};
  getrusage(RUSAGE_THREAD, &u);
  return u.ru_minflt;
}

// A solver built in the background while the tissue rests (the probe app) must not leave the
// first touch of its solve buffers to its first solve, the tool's first touch: on the folded organ
// that was about 75 MB, 0.17 s of a 0.52 s step (docs/bench.md, "The first touch"). Here: a block
// of 30 x 30 x 20 mm, one thread, large allocations fresh from the kernel (glibc's mmap threshold
// fixed at its starting 128 KiB, as the probe app has it, for the rest of this process): the
// first solve maps fewer pages than half of those of the buffers it writes (the element targets
// and start shapes, the right-hand side and the solution).
TEST(ProjectiveSolver, TheFirstSolveFindsItsBuffersMapped) {
#if defined(VOXELASTIC_SANITIZED)
  GTEST_SKIP() << "a sanitizer's allocator maps memory its own way (glibc's threshold does not apply)";
#endif
#if defined(__GLIBC__)
  ASSERT_EQ(mallopt(M_MMAP_THRESHOLD, 128 * 1024), 1);
#endif
  auto physics = make_physics_model(hand_block(30, 30, 20, 1.0), soft(0.2));
  SimState s = make_state(physics);
  s.fix_nodes(nodes_on_face(*physics->model, BoxFace::z_min));
  ProjectiveSetup setup;
  setup.time_step_s = 0.03;
  setup.damping = true;
  ProjectiveSolver solver(s.physics, s.node_fixed, setup, nullptr, 1);
  const long entries = long(physics->num_vertex_entries()), free = long(solver.num_free());
  // bytes: targets and start shapes 3 x entries each, the right-hand side and the solution n x 3
  const long buffer_pages = (2 * 3 * entries + 2 * 3 * free) * long(sizeof(double)) / 4096;
  ASSERT_GT(buffer_pages, 1500);
  Eigen::Matrix3Xd x = implicit_start(solver, s, setup.time_step_s);
  ProjectiveIterations its;
  its.max_iterations = 1;
  its.threads = 1;
  StepReport rep;
  const long before = minor_faults();
  solver.solve(s, x, its, nullptr, rep);
  const long faults = minor_faults() - before;
  EXPECT_LT(faults, buffer_pages / 2) << "the first solve mapped " << faults << " pages; its buffers hold "
                                      << buffer_pages;
}

TEST(ProjectiveSolver, ResidualFallsWithTheIterationsAndStaticMatchesSolveStatic) {
  SimState s = perturbed_block(0.0);
  s.gravity_mm_s2 = Eigen::Vector3d(0, 0, -kStandardGravityMmS2);
  ProjectiveSetup setup;
  setup.time_step_s = 1.0;
  setup.inertia = false;
  ProjectiveSolver solver(s.physics, s.node_fixed, setup);
  const auto residual_after = [&](int iterations, Eigen::Matrix3Xd* out) {
    SimState t = s;
    const std::vector<int>& free = solver.free_nodes();
    for (std::size_t f = 0; f < free.size(); ++f)
      solver.constant_rhs().row(Eigen::Index(f)) =
          (t.physics->node_mass[std::size_t(free[f])] * t.gravity_mm_s2).transpose();
    Eigen::Matrix3Xd x = t.positions;
    ProjectiveIterations its;
    its.max_iterations = iterations;
    its.rotation = {20, 1e-12};
    StepReport rep;
    solver.solve(t, x, its, nullptr, rep);
    if (out) *out = x;
    return rep.residual_n;
  };
  const double r2 = residual_after(2, nullptr), r20 = residual_after(20, nullptr);
  Eigen::Matrix3Xd x200;
  const double r200 = residual_after(200, &x200);
  std::cout << "RMS residual per free node: " << r2 << " N (2 iterations), " << r20 << " (20), " << r200 << " (200)\n";
  EXPECT_GT(r2, 0.0);
  EXPECT_LT(r20, 0.1 * r2);
  EXPECT_LT(r200, 1e-6 * r2);
  // the static solve is the same solver: the same equilibrium
  SimState t = s;
  StaticSolveSettings st;
  st.max_iterations = 200;
  st.tolerance_mm = 0;
  solve_static(t, st);
  EXPECT_LT((t.positions - x200).cwiseAbs().maxCoeff(), 1e-12);
}

/// A floor at z = 0 under every node (normal +z).
class Floor final : public ContactProvider {
 public:
  void collect(const Eigen::Matrix3Xd& x, bool near, std::vector<ContactConstraint>& out) override {
    for (int i = 0; i < x.cols(); ++i)
      if (x(2, i) < (near ? 0.5 : 0.0)) {
        ContactConstraint c;
        c.node = i;
        c.owner = 0;
        c.point_mm = Eigen::Vector3d(x(0, i), x(1, i), 0.0);
        c.normal = Eigen::Vector3d::UnitZ();
        out.push_back(c);
      }
  }
};

TEST(ProjectiveSolver, ContactMultipliersCarryTheWeightAtRest) {
  // a free block resting on a floor: at equilibrium the multipliers sum to its weight
  auto physics = make_physics_model(hand_block(3, 3, 2, 2.0), soft(0.5));
  SimState s = make_state(physics);
  s.gravity_mm_s2 = Eigen::Vector3d(0, 0, -kStandardGravityMmS2);
  const double dt = 5e-3;
  ProjectiveSetup setup;
  setup.time_step_s = dt;
  setup.damping = true;
  ProjectiveSolver solver(s.physics, s.node_fixed, setup);
  Floor floor;
  ProjectiveIterations its;
  its.max_iterations = 30;
  double carried = 0;
  for (int step = 0; step < 200; ++step) {
    Eigen::Matrix3Xd x = implicit_start(solver, s, dt);
    StepReport rep;
    solver.solve(s, x, its, &floor, rep);
    s.velocities = (x - s.positions) / dt;
    s.positions = x;
    carried = 0;
    for (const ContactConstraint& c : solver.active_contacts()) {
      EXPECT_GE(c.force_n, 0.0);
      carried += c.force_n;
    }
  }
  const double weight = physics->total_mass_kg() * kStandardGravityMmS2 * 1e-3;  // N
  std::cout << "floor carries " << carried << " N of a " << weight << " N weight\n";
  EXPECT_NEAR(carried, weight, 1e-6 * weight);
  EXPECT_GT(s.positions.row(2).minCoeff(), -1e-9) << "no node below the floor";
}

TEST(ProjectiveSolver, TheCacheBelongsToTheState) {
  // a copy of a state has no factor (it refactors) and steps exactly like the original; one
  // integrator stepping two states in turn gives each what its own integrator would
  IntegratorSettings set;
  set.kind = IntegratorKind::implicit;
  set.time_step_s = 2e-3;
  SimState a = perturbed_block(0.1);
  auto shared = make_integrator(set);
  EXPECT_TRUE(shared->step(a).refactored);
  EXPECT_FALSE(shared->step(a).refactored);
  SimState b = a;
  SimState b_alone = a;
  b.fix_nodes({0});  // b holds one more node: its own factor
  b_alone.fix_nodes({0});
  auto own = make_integrator(set);
  EXPECT_TRUE(shared->step(b).refactored);
  EXPECT_TRUE(own->step(b_alone).refactored);
  SimState a_alone = a;
  auto own_a = make_integrator(set);
  for (int k = 0; k < 5; ++k) {
    EXPECT_FALSE(shared->step(a).refactored);
    EXPECT_FALSE(shared->step(b).refactored);
    own->step(b_alone);
    own_a->step(a_alone);
  }
  EXPECT_EQ((a.positions - a_alone.positions).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ((b.positions - b_alone.positions).cwiseAbs().maxCoeff(), 0.0);
  // a changed time step or fixed set refactors
  IntegratorSettings longer = set;
  longer.time_step_s = 4e-3;
  EXPECT_TRUE(make_integrator(longer)->step(a).refactored);
  a.fix_nodes({1});
  EXPECT_TRUE(shared->step(a).refactored);
}

TEST(ProjectiveSolver, StaticSolverRefusesAPartHeldByNothing) {
  auto physics = make_physics_model(hand_block(2, 2, 2, 1.0), soft());
  std::vector<std::uint8_t> none(std::size_t(physics->num_nodes()), 0);
  ProjectiveSetup setup;
  setup.inertia = false;
  EXPECT_THROW(ProjectiveSolver(physics, none, setup), Error);
  setup.inertia = true;  // with inertia a free body is fine
  EXPECT_NO_THROW(ProjectiveSolver(physics, none, setup));
}

TEST(FactorCache, AFactorFoundByItsKeyStepsBitForBitAsTheOneComputed) {
  const auto cache = std::make_shared<testing::MemoryFactorCache>();
  IntegratorSettings set;
  set.kind = IntegratorKind::implicit;
  set.time_step_s = 0.01;
  set.max_iterations = 3;
  set.factor_cache = cache;
  Eigen::Matrix3Xd first;
  for (int run = 0; run < 2; ++run) {
    SimState s = perturbed_block(0.2);
    s.gravity_mm_s2 = {0, 0, -9810.0};
    auto integ = make_integrator(set);
    const StepReport r = integ->step(s);
    ASSERT_EQ(r.status, StepStatus::ok);
    EXPECT_TRUE(r.refactored);
    EXPECT_EQ(r.factor_from_cache, run == 1) << run;
    integ->step(s);  // the fixed nodes' coupling (kept beside the factor) in a second step too
    if (run == 0)
      first = s.positions;
    else
      EXPECT_EQ(std::memcmp(first.data(), s.positions.data(), sizeof(double) * std::size_t(first.size())), 0);
  }
  EXPECT_EQ(cache->files.size(), 1u);
  EXPECT_EQ(cache->loads, 2);
}

// The assembly is the lower triangle of a symmetric matrix whose rows (over the free and the
// held nodes) sum to zero without the mass term: each element's K_e and centring term move a
// translated element by nothing.
TEST(ProjectiveAssembly, IsTheLowerTriangleOfTheSymmetricMatrixThatMovesATranslationByNothing) {
  const SimState s = perturbed_block(0.2);
  const NodeNumbering numbering = number_nodes(s.node_fixed);
  ProjectiveSetup setup;
  setup.time_step_s = 0.01;
  setup.inertia = false;
  setup.damping = false;
  Eigen::SparseMatrix<double> a, coupling;
  assemble_projective_matrix(*s.physics, numbering, setup, a, &coupling);
  const Eigen::SparseMatrix<double> upper = a.triangularView<Eigen::StrictlyUpper>();
  EXPECT_EQ(upper.nonZeros(), 0);
  const Eigen::SparseMatrix<double> strict_lower = a.triangularView<Eigen::StrictlyLower>();
  EXPECT_GT(strict_lower.nonZeros(), 0);
  const Eigen::VectorXd ones_free = Eigen::VectorXd::Ones(a.rows()),
                        ones_fixed = Eigen::VectorXd::Ones(coupling.cols());
  const Eigen::VectorXd rows = a.selfadjointView<Eigen::Lower>() * ones_free + coupling * ones_fixed;
  EXPECT_LT(rows.cwiseAbs().maxCoeff(), 1e-9 * a.diagonal().cwiseAbs().maxCoeff());
  // and the matrix read as given (the lower triangle alone) is not: the reading matters
  const Eigen::VectorXd lower_only = a * ones_free + coupling * ones_fixed;
  EXPECT_GT(lower_only.cwiseAbs().maxCoeff(), 0.1 * a.diagonal().cwiseAbs().maxCoeff());
}

// The assembly on several threads (the elements in chunks of 512, each written to its own stretch
// of the triplets): the same matrix to the bit as on one thread, and still the symmetric matrix
// that moves a translation by nothing, on a block of 1,152 elements (three chunks).
TEST(ProjectiveAssembly, OnSeveralThreadsIsTheSameMatrixToTheBit) {
  auto physics = make_physics_model(hand_block(12, 12, 8, 1.0), soft(0.2));
  SimState s = make_state(physics);
  s.fix_nodes(nodes_on_face(*physics->model, BoxFace::z_min));
  ASSERT_GT(physics->num_elements(), 1024);
  const NodeNumbering numbering = number_nodes(s.node_fixed);
  ProjectiveSetup setup;
  setup.time_step_s = 0.01;
  setup.damping = true;
  Eigen::SparseMatrix<double> a1, c1;
  assemble_projective_matrix(*physics, numbering, setup, a1, &c1, 1);
  const auto same = [](const Eigen::SparseMatrix<double>& x, const Eigen::SparseMatrix<double>& y) {
    return x.rows() == y.rows() && x.cols() == y.cols() && x.nonZeros() == y.nonZeros() &&
           std::memcmp(x.valuePtr(), y.valuePtr(), sizeof(double) * std::size_t(x.nonZeros())) == 0 &&
           std::memcmp(x.innerIndexPtr(), y.innerIndexPtr(), sizeof(int) * std::size_t(x.nonZeros())) == 0 &&
           std::memcmp(x.outerIndexPtr(), y.outerIndexPtr(), sizeof(int) * std::size_t(x.cols() + 1)) == 0;
  };
  for (const int threads : {2, 3}) {
    Eigen::SparseMatrix<double> a, c;
    assemble_projective_matrix(*physics, numbering, setup, a, &c, threads);
    a.makeCompressed();
    c.makeCompressed();
    a1.makeCompressed();
    c1.makeCompressed();
    EXPECT_TRUE(same(a, a1)) << threads;
    EXPECT_TRUE(same(c, c1)) << threads;
  }
  // without the mass term, the rows sum to zero: every entry is where it belongs
  setup.inertia = false;
  setup.damping = false;
  Eigen::SparseMatrix<double> k, coupling;
  assemble_projective_matrix(*physics, numbering, setup, k, &coupling, 2);
  EXPECT_EQ(Eigen::SparseMatrix<double>(k.triangularView<Eigen::StrictlyUpper>()).nonZeros(), 0);
  const Eigen::VectorXd rows = k.selfadjointView<Eigen::Lower>() * Eigen::VectorXd::Ones(k.rows()) +
                               coupling * Eigen::VectorXd::Ones(coupling.cols());
  EXPECT_LT(rows.cwiseAbs().maxCoeff(), 1e-9 * k.diagonal().cwiseAbs().maxCoeff());
}

TEST(FactorCache, TheKeyFollowsEveryInputOfTheMatrixAndNotTheThreads) {
  const SimState s = perturbed_block(0.2);
  const NodeNumbering numbering = number_nodes(s.node_fixed);
  ProjectiveSetup setup;
  setup.time_step_s = 0.01;
  setup.damping = true;
  Eigen::SparseMatrix<double> coupling1, coupling2, assembled_free, assembled_coupling;
  const FactorKey k = projective_matrix_key(*s.physics, numbering, setup, 1, &coupling1);
  // threads: the same key, the same coupling (bit for bit), and the coupling is the assembly's
  EXPECT_EQ(projective_matrix_key(*s.physics, numbering, setup, 2, &coupling2), k);
  assemble_projective_matrix(*s.physics, numbering, setup, assembled_free, &assembled_coupling);
  ASSERT_EQ(coupling1.nonZeros(), assembled_coupling.nonZeros());
  EXPECT_GT(coupling1.nonZeros(), 0);
  EXPECT_EQ(Eigen::MatrixXd(coupling1 - assembled_coupling).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ(Eigen::MatrixXd(coupling1 - coupling2).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ(k.rows, int(numbering.free_nodes.size()));
  // every input: the step, the damping term, the mass term, the support, the material
  ProjectiveSetup other = setup;
  other.time_step_s = 0.02;
  EXPECT_NE(projective_matrix_key(*s.physics, numbering, other, 1, nullptr).hash, k.hash);
  other = setup;
  other.damping = false;
  EXPECT_NE(projective_matrix_key(*s.physics, numbering, other, 1, nullptr).hash, k.hash);
  other = setup;
  other.inertia = false;
  EXPECT_NE(projective_matrix_key(*s.physics, numbering, other, 1, nullptr).hash, k.hash);
  std::vector<std::uint8_t> fixed = s.node_fixed;
  for (std::size_t i = 0; i < fixed.size(); ++i)
    if (!fixed[i]) {
      fixed[i] = 1;  // one more node held
      break;
    }
  EXPECT_NE(projective_matrix_key(*s.physics, number_nodes(fixed), setup, 1, nullptr).hash, k.hash);
  Material stiffer = soft(0.2);
  stiffer.youngs_modulus_kpa *= 1.0 + 1e-12;
  const auto p2 = make_physics_model(hand_block(4, 4, 3, 2.0), stiffer);
  EXPECT_NE(projective_matrix_key(*p2, numbering, setup, 1, nullptr).hash, k.hash);
  Material heavier = soft(0.2);
  heavier.density_kg_m3 *= 1.001;
  const auto p3 = make_physics_model(hand_block(4, 4, 3, 2.0), heavier);
  EXPECT_NE(projective_matrix_key(*p3, numbering, setup, 1, nullptr).hash, k.hash);
  // and the same inputs rebuilt: the same key
  const auto p4 = make_physics_model(hand_block(4, 4, 3, 2.0), soft(0.2));
  EXPECT_EQ(projective_matrix_key(*p4, numbering, setup, 1, nullptr), k);
}

}  // namespace
}  // namespace vx
