// Contact of surface nodes with probes and walls: response, reaction force, broad phase (the
// probes' geometry and drivers: probe_test.cpp).
#include "sim/contact.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "base/error.h"
#include "sim/probe.h"

using namespace vx;

namespace {

ProbeGeometry make_geometry(ProbeShape shape, double r, double len, Eigen::Vector3d axis) {
  ProbeGeometry g;
  g.shape = shape;
  g.radius_mm = r;
  g.length_mm = len;
  g.axis = axis.normalized();
  return g;
}

}  // namespace

namespace {

/// A flat sheet of free nodes at z = 0 on a 1 mm lattice, with unit-ish masses.
struct Sheet {
  Eigen::Matrix3Xd x, v;
  std::vector<double> m;
  std::vector<std::int32_t> ids;
  explicit Sheet(int n, double mass = 1e-6) {
    x.resize(3, n * n);
    v.setZero(3, n * n);
    m.assign(std::size_t(n * n), mass);
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        x.col(i + n * j) = Eigen::Vector3d(i - (n - 1) / 2.0, j - (n - 1) / 2.0, 0.0);
        ids.push_back(i + n * j);
      }
  }
};

}  // namespace

TEST(ContactSolver, ReflectsRelativeVelocityAndReportsMomentumChange) {
  // one node resting inside a sphere moving down at 100 mm/s: it is put on the sphere and
  // leaves at twice the probe speed (elastic collision with a very heavy body)
  Eigen::Matrix3Xd x(3, 1), v(3, 1);
  x.col(0) = Eigen::Vector3d(0, 0, -0.5);
  v.setZero();
  const std::vector<double> m = {2e-6};  // N s^2/mm (2 g)
  ContactSolver solver;
  solver.init({0}, 1, {}, {}, 1.0);
  const std::vector<ProbeGeometry> g = {make_geometry(ProbeShape::sphere, 1.0, 0, {0, 0, 1})};
  const std::vector<ProbeState> p = {{Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 0, -100)}};
  std::vector<Eigen::Vector3d> force;
  Eigen::Vector3d wall;
  const double dt = 1e-4;
  solver.resolve(x, v, m, g, p, dt, force, wall);
  EXPECT_TRUE(x.col(0).isApprox(Eigen::Vector3d(0, 0, -1)));
  EXPECT_TRUE(v.col(0).isApprox(Eigen::Vector3d(0, 0, -200)));
  // the node gained m * 200 mm/s downward: the tissue pushes the probe up by that per dt
  ASSERT_EQ(force.size(), 1u);
  EXPECT_NEAR(force[0].z(), 2e-6 * 200 / dt, 1e-12);
  EXPECT_NEAR(force[0].head<2>().norm(), 0.0, 1e-15);
  EXPECT_EQ(solver.counters().contacts, 1);
}

TEST(ContactSolver, RestitutionZeroAndFrictionStickOrSlide) {
  // two nodes moving into a plate that faces down (normal -z) at 10 mm/s while sliding along x:
  // restitution 0 removes the normal 10 mm/s (jn = 10); with mu = 0.5 friction can take up to
  // 5 mm/s of tangential velocity. Node 0 slides at 30 mm/s: 1/6 of its tangential velocity and
  // of this step's slip (30 mm/s * 1 ms) is removed. Node 1 slides at only 4 mm/s: it sticks.
  Eigen::Matrix3Xd x(3, 2), v(3, 2);
  x.col(0) = Eigen::Vector3d(0, 0, -0.1);
  x.col(1) = Eigen::Vector3d(5, 0, -0.19);
  v.col(0) = Eigen::Vector3d(30, 0, 10);
  v.col(1) = Eigen::Vector3d(4, 0, 10);
  const std::vector<double> m = {1e-6, 1e-6};
  ContactSettings s;
  s.restitution = 0.0;
  s.friction = 0.5;
  ContactSolver solver;
  solver.init({0, 1}, 1, {}, s, 1.0);
  const std::vector<ProbeGeometry> g = {make_geometry(ProbeShape::plane, 0, 0, {0, 0, -1})};
  const std::vector<ProbeState> p = {{Eigen::Vector3d(0, 0, -0.2), Eigen::Vector3d::Zero()}};
  std::vector<Eigen::Vector3d> force;
  Eigen::Vector3d wall;
  const double dt = 1e-3;
  solver.resolve(x, v, m, g, p, dt, force, wall);
  // normal part removed, both put on the plate
  EXPECT_NEAR(v(2, 0), 0.0, 1e-12);
  EXPECT_NEAR(v(2, 1), 0.0, 1e-12);
  EXPECT_NEAR(x(2, 0), -0.2, 1e-12);
  EXPECT_NEAR(x(2, 1), -0.2, 1e-12);
  // node 0 slides: 1/6 removed
  EXPECT_NEAR(v(0, 0), 25.0, 1e-12);
  EXPECT_NEAR(x(0, 0), -0.005, 1e-12);
  // node 1 sticks: no tangential velocity left, this step's slip undone
  EXPECT_NEAR(v(0, 1), 0.0, 1e-12);
  EXPECT_NEAR(x(0, 1), 5.0 - 0.004, 1e-12);
  // momentum change per step: normal 2 x 10 mm/s, tangential 5 + 4 mm/s
  EXPECT_NEAR(force[0].z(), 1e-6 * 20 / dt, 1e-12);
  EXPECT_NEAR(force[0].x(), 1e-6 * 9 / dt, 1e-12);
}

TEST(ContactSolver, StickingNodeReturnsToItsAnchorAfterABounce) {
  // a node touches a plate, bounces off for a step (sliding 0.02 mm), touches again: sticking
  // undoes the whole slip since the first touch, not only the last step's
  Eigen::Matrix3Xd x(3, 1), v(3, 1);
  x.col(0) = Eigen::Vector3d(0, 0, 0.01);  // plate normal +z at z = 0.02: 0.01 inside
  v.col(0) = Eigen::Vector3d(0, 0, -5);
  const std::vector<double> m = {1e-6};
  ContactSettings s;
  s.friction = 1.0;  // restitution 1: the node bounces
  ContactSolver solver;
  solver.init({0}, 1, {}, s, 1.0);
  const std::vector<ProbeGeometry> g = {make_geometry(ProbeShape::plane, 0, 0, {0, 0, 1})};
  const std::vector<ProbeState> p = {{Eigen::Vector3d(0, 0, 0.02), Eigen::Vector3d::Zero()}};
  std::vector<Eigen::Vector3d> force;
  Eigen::Vector3d wall;
  const double dt = 1e-3;
  solver.resolve(x, v, m, g, p, dt, force, wall);
  EXPECT_NEAR(x(2, 0), 0.02, 1e-12);
  EXPECT_NEAR(v(2, 0), 5.0, 1e-12);
  // off the plate for a step, drifting 0.02 mm along x
  x.col(0) = Eigen::Vector3d(0.01, 0, 0.025);
  v.col(0) = Eigen::Vector3d(10, 0, 0);
  solver.resolve(x, v, m, g, p, dt, force, wall);
  EXPECT_NEAR(x(0, 0), 0.01, 1e-15);  // not in contact: untouched
  // back in, having slid 0.02 mm since the first touch: stuck (10 mm/s <= 1.0 * 2 * 5 mm/s)
  x.col(0) = Eigen::Vector3d(0.02, 0, 0.015);
  v.col(0) = Eigen::Vector3d(10, 0, -5);
  solver.resolve(x, v, m, g, p, dt, force, wall);
  EXPECT_NEAR(x(0, 0), 0.0, 1e-12);
  EXPECT_NEAR(v(0, 0), 0.0, 1e-12);
  EXPECT_NEAR(force[0].x(), 1e-6 * 10 / dt, 1e-12);
}

TEST(ContactSolver, WallsKeepNodesInTheBox) {
  Eigen::Matrix3Xd x(3, 2), v(3, 2);
  x.col(0) = Eigen::Vector3d(5, 0, -11);
  v.col(0) = Eigen::Vector3d(1, 0, -50);
  x.col(1) = Eigen::Vector3d(0, 0, 0);  // far from every wall
  v.col(1) = Eigen::Vector3d(0, 0, -50);
  const std::vector<double> m = {1e-6, 1e-6};
  Workspace w;
  w.enabled = true;
  w.min_mm = Eigen::Vector3d(-10, -10, -10);
  w.max_mm = Eigen::Vector3d(10, 10, 10);
  ContactSolver solver;
  solver.init({0, 1}, 0, w, {}, 1.0);
  std::vector<Eigen::Vector3d> force;
  Eigen::Vector3d wall;
  solver.resolve(x, v, m, {}, {}, 1e-3, force, wall);
  EXPECT_DOUBLE_EQ(x(2, 0), -10.0);
  EXPECT_DOUBLE_EQ(v(2, 0), 50.0);
  EXPECT_DOUBLE_EQ(v(0, 0), 1.0);
  EXPECT_NEAR(wall.z(), -1e-6 * 100 / 1e-3, 1e-12);  // the node pushes the floor down
  EXPECT_EQ(solver.counters().wall_contacts, 1);
  // the far node was culled (skin 2 mm)
  EXPECT_EQ(solver.counters().narrow_tests, 1);
  EXPECT_EQ(solver.counters().narrow_tests_skipped, 1);
}

TEST(ContactSolver, BroadPhaseGivesIdenticalResultsAndSkipsFarNodes) {
  // a capsule and a sphere sweep across a jittering sheet; the culled run must match the
  // brute-force run bit for bit while testing far fewer nodes
  const int n = 40;
  Sheet a(n), b(n);
  const std::vector<ProbeGeometry> g = {make_geometry(ProbeShape::capsule, 2.0, 8.0, {0.3, 0, 1}),
                                        make_geometry(ProbeShape::sphere, 3.0, 0, {0, 0, 1})};
  ContactSettings culled, brute;
  brute.broad_phase = false;
  Workspace w;
  w.enabled = true;
  w.min_mm = Eigen::Vector3d(-19, -19, -5);
  w.max_mm = Eigen::Vector3d(19, 19, 5);
  ContactSolver sa, sb;
  sa.init(a.ids, 2, w, culled, 1.0);
  sb.init(b.ids, 2, w, brute, 1.0);
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 20.0);
  const double dt = 1e-3;
  std::vector<Eigen::Vector3d> fa, fb;
  Eigen::Vector3d wa, wb;
  double total_force = 0;
  for (int step = 0; step < 400; ++step) {
    const double t = step * dt;
    std::vector<ProbeState> p = {{Eigen::Vector3d(-15 + 75 * t, 0, 1.0), Eigen::Vector3d(75, 0, 0)},
                                 {Eigen::Vector3d(5, -15 + 70 * t, 2.2), Eigen::Vector3d(0, 70, 0)}};
    // free flight with random velocities, same for both
    for (int i = 0; i < n * n; ++i) {
      const Eigen::Vector3d dv(noise(rng), noise(rng), noise(rng));
      a.v.col(i) += dv;
      b.v.col(i) += dv;
      a.x.col(i) += dt * a.v.col(i);
      b.x.col(i) += dt * b.v.col(i);
    }
    sa.resolve(a.x, a.v, a.m, g, p, dt, fa, wa);
    sb.resolve(b.x, b.v, b.m, g, p, dt, fb, wb);
    ASSERT_EQ(fa, fb) << "step " << step;
    ASSERT_EQ(wa, wb) << "step " << step;
    total_force += fa[0].norm() + fa[1].norm();
  }
  EXPECT_EQ(a.x, b.x);
  EXPECT_EQ(a.v, b.v);
  EXPECT_EQ(sa.counters().contacts, sb.counters().contacts);
  EXPECT_GT(sa.counters().contacts, 100);
  EXPECT_GT(total_force, 0.0);
  // brute force tests every node against 2 probes and the walls every step
  EXPECT_EQ(sb.counters().narrow_tests, 400LL * n * n * 3);
  EXPECT_EQ(sb.counters().narrow_tests_skipped, 0);
  EXPECT_LT(sa.counters().narrow_tests, sb.counters().narrow_tests / 5);
  EXPECT_EQ(sa.counters().narrow_tests + sa.counters().narrow_tests_skipped, sb.counters().narrow_tests);
  EXPECT_GT(sa.counters().rebuilds, 1);
}

TEST(ContactSolver, SettingsValidated) {
  ContactSettings s;
  s.restitution = 1.5;
  ContactSolver solver;
  EXPECT_THROW(solver.init({}, 0, {}, s, 1.0), Error);
}
