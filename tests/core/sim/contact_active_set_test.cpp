// The contact active set of an implicit step (sim/contact_active_set.h) on a hand-made system: a
// chain of nodes on springs, pushed down into a floor in its middle. The constrained solution
// must meet the floor's conditions exactly (Karush-Kuhn-Tucker: no node below it, multipliers
// >= 0, each multiplier the force balance's residual at its node, none where a node is off the
// floor), leave the other coordinates alone, find the nodes the linearisation point did not
// list, and start the next solve from the last active set.
#include "sim/contact_active_set.h"

#include <gtest/gtest.h>

#include <Eigen/LU>
#include <cmath>
#include <numeric>
#include <vector>

#include "sim/sparse_factor.h"

using namespace vx;

namespace {

constexpr int kNodes = 41;
constexpr double kSpring = 50.0;  ///< N/mm between neighbours
constexpr double kMass = 1.0;     ///< the diagonal term (m/dt^2), N/mm

/// A = k L + m I: a chain on springs (free ends), the same scalar matrix for x, y and z.
SparseFactor::Matrix chain_matrix() {
  std::vector<Eigen::Triplet<double>> t;
  for (int i = 0; i < kNodes; ++i) t.emplace_back(i, i, kMass);
  for (int i = 0; i + 1 < kNodes; ++i) {
    t.emplace_back(i, i, kSpring);
    t.emplace_back(i + 1, i + 1, kSpring);
    t.emplace_back(i, i + 1, -kSpring);
    t.emplace_back(i + 1, i, -kSpring);
  }
  SparseFactor::Matrix a(kNodes, kNodes);
  a.setFromTriplets(t.begin(), t.end());
  return a;
}

/// The floor z >= 0 (owner 0), linearised anywhere as itself; with `near` also the nodes within
/// 0.5 mm above it.
class Floor final : public ContactProvider {
 public:
  void collect(const Eigen::Matrix3Xd& x, bool near, std::vector<ContactConstraint>& out) override {
    ++calls;
    for (int i = 0; i < int(x.cols()); ++i)
      if (x(2, i) < (near ? 0.5 : 0.0)) {
        ContactConstraint c;
        c.node = i;
        c.owner = 0;
        c.point_mm = Eigen::Vector3d(x(0, i), x(1, i), 0.0);
        c.normal = Eigen::Vector3d::UnitZ();
        out.push_back(c);
      }
  }
  int calls{0};
};

struct Chain {
  SparseFactor::Matrix a = chain_matrix();
  SparseFactor factor;
  std::vector<int> free_index, free_nodes;
  Eigen::MatrixX3d b, unconstrained;
  Chain() {
    EXPECT_TRUE(factor.compute(a));
    free_index.resize(kNodes);
    std::iota(free_index.begin(), free_index.end(), 0);
    free_nodes = free_index;
    // a load pressing the middle down (z), and some sideways load (x, y) the floor must not touch
    b.resize(kNodes, 3);
    for (int i = 0; i < kNodes; ++i) {
      const double s = (i - kNodes / 2) / 6.0;
      b(i, 0) = 0.3 * std::sin(0.2 * i);
      b(i, 1) = -0.1 * i;
      b(i, 2) = 2.0 - 40.0 * std::exp(-s * s);
    }
    unconstrained.resize(kNodes, 3);
    factor.solve3(b, unconstrained);
  }
};

/// The KKT conditions of min 1/2 z^T A z - b^T z subject to z >= 0 for `z`, with the
/// multipliers `active` (node, force): returns the worst violation.
double kkt_violation(const Chain& c, const Eigen::VectorXd& z, const std::vector<ContactConstraint>& active) {
  Eigen::VectorXd lambda = Eigen::VectorXd::Zero(kNodes);
  double worst = 0;
  for (const ContactConstraint& k : active) {
    worst = std::max(worst, -k.force_n);  // no pulling
    lambda[k.node] = k.force_n;
    worst = std::max(worst, std::abs(z[k.node]));  // on the floor
  }
  const Eigen::VectorXd residual = c.a * z - c.b.col(2);  // = lambda (force balance)
  worst = std::max(worst, (residual - lambda).cwiseAbs().maxCoeff());
  worst = std::max(worst, -z.minCoeff());  // nobody below the floor
  return worst;
}

}  // namespace

TEST(ContactActiveSet, TheConstrainedSolutionMeetsTheFloorExactly) {
  Chain c;
  ASSERT_LT(c.unconstrained.col(2).minCoeff(), -1.0);  // the load pushes the middle well below
  ContactActiveSet set;
  set.bind(c.free_index, c.free_nodes);
  Floor floor;
  ContactSolveCounters counters;
  Eigen::MatrixX3d x = c.unconstrained;
  const Eigen::Matrix3Xd at = c.unconstrained.transpose();  // linearised at the unconstrained solution
  set.solve(floor, at, c.factor, x, counters);
  const std::vector<ContactConstraint>& active = set.active();
  ASSERT_GT(active.size(), 3u);
  ASSERT_LT(active.size(), std::size_t(kNodes));  // the ends stay off the floor
  EXPECT_LT(kkt_violation(c, x.col(2), active), 1e-9);
  // the floor pushes along z only
  EXPECT_LT((x.col(0) - c.unconstrained.col(0)).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((x.col(1) - c.unconstrained.col(1)).cwiseAbs().maxCoeff(), 1e-12);
  // the multipliers carry what the floor holds: the sum of the loads' z minus what the masses take
  double held = 0;
  for (const ContactConstraint& k : active) held += k.force_n;
  EXPECT_NEAR(held, (kMass * x.col(2) - c.b.col(2)).sum(), 1e-9 * std::abs(held));
  EXPECT_GT(counters.rounds, 0);
  EXPECT_GT(counters.columns, 0);
}

TEST(ContactActiveSet, FindsTheNodesTheIterateDidNotListAndWarmStarts) {
  Chain c;
  ContactActiveSet ref_set;
  ref_set.bind(c.free_index, c.free_nodes);
  Floor floor;
  ContactSolveCounters counters;
  Eigen::MatrixX3d ref = c.unconstrained;
  ref_set.solve(floor, Eigen::Matrix3Xd(c.unconstrained.transpose()), c.factor, ref, counters);

  // linearised at an iterate above the floor: no candidate at first; the re-check finds them
  ContactActiveSet set;
  set.bind(c.free_index, c.free_nodes);
  Eigen::Matrix3Xd above = c.unconstrained.transpose();
  above.row(2).setConstant(1.0);
  Eigen::MatrixX3d x = c.unconstrained;
  floor.calls = 0;
  set.solve(floor, above, c.factor, x, counters);
  EXPECT_GE(floor.calls, 2);
  EXPECT_LT(kkt_violation(c, x.col(2), set.active()), 1e-9);
  EXPECT_LT((x - ref).cwiseAbs().maxCoeff(), 1e-9);
  ASSERT_EQ(set.active().size(), ref_set.active().size());

  // the same solve again starts from the last active set: one round finds it unchanged
  ContactSolveCounters again;
  Eigen::MatrixX3d y = c.unconstrained;
  set.solve(floor, Eigen::Matrix3Xd(c.unconstrained.transpose()), c.factor, y, again);
  EXPECT_LE(again.rounds, 1);
  EXPECT_LT((y - ref).cwiseAbs().maxCoeff(), 1e-9);
  // forgetting the warm start costs rounds, not accuracy
  set.forget_warm_start();
  ContactSolveCounters cold;
  Eigen::MatrixX3d w = c.unconstrained;
  set.solve(floor, Eigen::Matrix3Xd(c.unconstrained.transpose()), c.factor, w, cold);
  EXPECT_GT(cold.rounds, again.rounds);
  EXPECT_LT((w - ref).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(ContactActiveSet, TheComplianceIsTheInverseOfTheMatrix) {
  Chain c;
  ContactActiveSet set;
  set.bind(c.free_index, c.free_nodes);
  const std::vector<int> nodes = {3, 20, 21, 40};
  Eigen::MatrixXd g;
  set.compliance(nodes, c.factor, g);
  const Eigen::MatrixXd inverse = Eigen::MatrixXd(c.a).inverse();
  ASSERT_EQ(g.rows(), 4);
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j)
      EXPECT_NEAR(g(i, j), inverse(nodes[std::size_t(i)], nodes[std::size_t(j)]), 1e-12) << i << " " << j;
}

namespace vx {
namespace {

TEST(ContactActiveSet, AReservedCacheAnswersTheSameAndNeverGrows) {
  // reserved when set up (a long session's memory flat): every node's forward vector fits the
  // storage kept for the factor's longest, so using them all allocates nothing more
  Chain c;
  ContactActiveSet set;
  set.bind(c.free_index, c.free_nodes);
  set.reserve(c.factor);
  ASSERT_TRUE(set.reserved());
  const std::size_t reserved = set.cache_bytes();
  const auto [values, segments] = c.factor.longest_unit_forward();
  EXPECT_GE(values, 1);
  EXPECT_LE(values, kNodes);
  EXPECT_GE(segments, 1);
  // G between kNodes slots (fewer free nodes than kMaxSlots) and every slot's vectors
  EXPECT_GE(reserved, std::size_t(kNodes) * kNodes * sizeof(double) + std::size_t(kNodes * values) * sizeof(double));
  std::vector<int> nodes(kNodes);
  std::iota(nodes.begin(), nodes.end(), 0);
  Eigen::MatrixXd g;
  set.compliance(nodes, c.factor, g);
  const Eigen::MatrixXd inverse = Eigen::MatrixXd(c.a).inverse();
  EXPECT_LT((g - inverse).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_EQ(set.cache_bytes(), reserved);
}

}  // namespace
}  // namespace vx
