// The probes (sim/probe.h): the signed distance of each shape (its gradient is the normal, its
// surface point at distance zero), the settings' validation, and the drivers (path, joystick
// rate and position control, live targets).
#include "sim/probe.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <limits>
#include <random>

#include "base/error.h"

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

/// Finite-difference check that the distance's gradient is the normal and the surface point
/// lies at distance zero.
void expect_consistent(const ProbeGeometry& g, const Eigen::Vector3d& c, const Eigen::Vector3d& x) {
  Eigen::Vector3d p, n;
  const double d = probe_signed_distance(g, c, x, &p, &n);
  EXPECT_NEAR(n.norm(), 1.0, 1e-12);
  EXPECT_NEAR(probe_signed_distance(g, c, p), 0.0, 1e-9) << x.transpose();
  EXPECT_NEAR((x - p).norm(), std::abs(d), 1e-9);
  if (std::abs(d) > 1e-6) {
    EXPECT_GT((x - p).dot(n) * d, 0.0);  // x lies on the normal's side iff outside
  }
}

}  // namespace

TEST(ProbeGeometry, SphereDistance) {
  const auto g = make_geometry(ProbeShape::sphere, 4.0, 0.0, {0, 0, 1});
  Eigen::Vector3d p, n;
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {1, 2, 3}, {1, 2, 10}, &p, &n), 3.0);
  EXPECT_TRUE(p.isApprox(Eigen::Vector3d(1, 2, 7)));
  EXPECT_TRUE(n.isApprox(Eigen::Vector3d(0, 0, 1)));
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {1, 2, 3}, {1, 2, 2}, &p, &n), -3.0);
  EXPECT_TRUE(n.isApprox(Eigen::Vector3d(0, 0, -1)));
}

TEST(ProbeGeometry, CapsuleDistanceAlongRodAndTip) {
  // tip centre at the origin, rod along +z for 10 mm, radius 2
  const auto g = make_geometry(ProbeShape::capsule, 2.0, 10.0, {0, 0, 1});
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {0, 0, 0}, {0, 0, -5}), 3.0);  // below the tip
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {0, 0, 0}, {5, 0, 4}), 3.0);   // beside the rod
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {0, 0, 0}, {0, 0, 14}), 2.0);  // past the far cap
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {0, 0, 0}, {1, 0, 6}), -1.0);  // inside the rod
}

TEST(ProbeGeometry, CylinderDistanceSideCapAndRim) {
  // centred at the origin, axis x, radius 3, length 8 (caps at x = +-4)
  const auto g = make_geometry(ProbeShape::cylinder, 3.0, 8.0, {1, 0, 0});
  Eigen::Vector3d p, n;
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {0, 0, 0}, {0, 5, 0}), 2.0);
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {0, 0, 0}, {6, 1, 0}), 2.0);
  EXPECT_NEAR(probe_signed_distance(g, {0, 0, 0}, {7, 7, 0}), 5.0, 1e-12);  // rim (3,4) away
  // inside, nearer the cap than the side: leaves through the cap
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {0, 0, 0}, {3.5, 0.5, 0}, &p, &n), -0.5);
  EXPECT_TRUE(n.isApprox(Eigen::Vector3d(1, 0, 0)));
  EXPECT_TRUE(p.isApprox(Eigen::Vector3d(4, 0.5, 0)));
  // inside, nearer the side
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {0, 0, 0}, {0, 0, -2.5}, &p, &n), -0.5);
  EXPECT_TRUE(n.isApprox(Eigen::Vector3d(0, 0, -1)));
}

TEST(ProbeGeometry, PlaneDistance) {
  const auto g = make_geometry(ProbeShape::plane, 0.0, 0.0, {0, 0, -1});  // plate above, facing down
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {0, 0, 10}, {3, 4, 7}), 3.0);
  EXPECT_DOUBLE_EQ(probe_signed_distance(g, {0, 0, 10}, {3, 4, 11}), -1.0);
}

TEST(ProbeGeometry, SurfacePointsAndNormalsConsistent) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-8.0, 8.0);
  const Eigen::Vector3d c(1, -2, 0.5);
  const ProbeGeometry shapes[] = {
      make_geometry(ProbeShape::sphere, 3, 0, {0, 0, 1}), make_geometry(ProbeShape::capsule, 2, 6, {1, 1, 0}),
      make_geometry(ProbeShape::cylinder, 2.5, 5, {0, 1, 2}), make_geometry(ProbeShape::plane, 0, 0, {1, -1, 1})};
  for (const auto& g : shapes)
    for (int k = 0; k < 300; ++k) expect_consistent(g, c, c + Eigen::Vector3d(u(rng), u(rng), u(rng)));
}

// The ball the broad phase and the local contact model reject far nodes with: no point is
// nearer the probe than the ball's surface (a scan that skips the nodes beyond the ball plus a
// margin misses none within the margin), and the ball touches the probe (it is no larger than
// it must be: the point of the probe farthest from the centre is on the ball).
TEST(ProbeGeometry, TheBoundingBallHoldsTheProbeAndTouchesIt) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-12.0, 12.0);
  const Eigen::Vector3d c(1, -2, 0.5);
  const ProbeGeometry shapes[] = {make_geometry(ProbeShape::sphere, 3, 0, {0, 0, 1}),
                                  make_geometry(ProbeShape::capsule, 2, 6, {1, 1, 0}),
                                  make_geometry(ProbeShape::cylinder, 2.5, 5, {0, 1, 2})};
  for (const auto& g : shapes) {
    Eigen::Vector3d centre;
    const double radius = probe_bounding_ball(g, c, centre);
    double nearest_gap = std::numeric_limits<double>::infinity();  // distance minus the ball's bound
    for (int k = 0; k < 20000; ++k) {
      const Eigen::Vector3d x = c + Eigen::Vector3d(u(rng), u(rng), u(rng));
      const double bound = (x - centre).norm() - radius;
      const double d = probe_signed_distance(g, c, x);
      EXPECT_GE(d, bound - 1e-12) << to_string(g.shape) << " at " << x.transpose();
      nearest_gap = std::min(nearest_gap, d - bound);
    }
    // the farthest point of the probe from the centre: the capsule's far tip, the cylinder's rim
    Eigen::Vector3d far = c + 3.0 * Eigen::Vector3d::UnitX();  // the sphere: any surface point
    if (g.shape == ProbeShape::capsule) far = c + (g.length_mm + g.radius_mm) * g.axis;
    if (g.shape == ProbeShape::cylinder)
      far = c + 0.5 * g.length_mm * g.axis + g.radius_mm * g.axis.cross(Eigen::Vector3d::UnitX()).normalized();
    EXPECT_NEAR(probe_signed_distance(g, c, far), 0.0, 1e-12) << to_string(g.shape);
    EXPECT_NEAR((far - centre).norm(), radius, 1e-12) << to_string(g.shape);
    if (g.shape == ProbeShape::sphere) {
      EXPECT_NEAR(nearest_gap, 0.0, 1e-12);  // exact for a ball
    }
  }
  Eigen::Vector3d centre;
  EXPECT_TRUE(std::isinf(probe_bounding_ball(make_geometry(ProbeShape::plane, 0, 0, {0, 0, 1}), c, centre)));
}

TEST(ProbeGeometry, ValidationNamesTheProblem) {
  auto g = make_geometry(ProbeShape::cylinder, 2, 0, {0, 0, 1});
  EXPECT_NE(g.validate().find("length"), std::string::npos);
  g.length_mm = 3;
  g.axis = {0, 0, 2};
  EXPECT_NE(g.validate().find("unit"), std::string::npos);
  EXPECT_THROW((void)parse_probe_shape("cube"), Error);
  EXPECT_EQ(parse_probe_shape("capsule"), ProbeShape::capsule);
}

TEST(ProbeDriver, PathIsLinearBetweenKeysAndVelocityIsDisplacementOverDt) {
  ProbeSettings s;
  s.drive = ProbeDrive::path;
  s.path = {{0.0, {0, 0, 10}}, {1.0, {0, 0, 0}}, {2.0, {10, 0, 0}}};
  ASSERT_EQ(s.validate(), "");
  EXPECT_DOUBLE_EQ(s.max_scripted_speed_mm_s(), 10.0);
  ProbeDriver d(s);
  EXPECT_TRUE(d.state().position_mm.isApprox(Eigen::Vector3d(0, 0, 10)));
  const double dt = 0.01;
  for (int k = 1; k <= 50; ++k) d.advance(k * dt, dt);
  EXPECT_TRUE(d.state().position_mm.isApprox(Eigen::Vector3d(0, 0, 5)));
  EXPECT_TRUE(d.state().velocity_mm_s.isApprox(Eigen::Vector3d(0, 0, -10)));
  for (int k = 51; k <= 300; ++k) d.advance(k * dt, dt);
  EXPECT_TRUE(d.state().position_mm.isApprox(Eigen::Vector3d(10, 0, 0)));  // held after the last key
  EXPECT_NEAR(d.state().velocity_mm_s.norm(), 0.0, 1e-12);
}

TEST(ProbeDriver, JoystickRateControlVelocityProportionalToTilt) {
  ProbeSettings s;
  s.drive = ProbeDrive::joystick;
  s.start_mm = {1, 2, 3};
  s.mapping.max_speed_mm_s = 40;
  s.mapping.directions.col(1) = Eigen::Vector3d(0, 0, -1);  // stick forward pushes down
  s.mapping.directions.col(2).setZero();
  s.joystick = {{0.0, {0.5, 0, 0}}, {1.0, {0.5, 0, 0}}, {1.001, {0, 1, 0}}, {2.0, {0, 1, 0}}};
  ASSERT_EQ(s.validate(), "");
  ProbeDriver d(s);
  const double dt = 1e-3;
  for (int k = 1; k <= 1000; ++k) d.advance(k * dt, dt);
  // half tilt for 1 s at 40 mm/s full speed: 20 mm along x
  EXPECT_NEAR(d.state().position_mm.x(), 21.0, 1e-9);
  EXPECT_NEAR(d.state().velocity_mm_s.x(), 20.0, 1e-9);
  for (int k = 1001; k <= 2000; ++k) d.advance(k * dt, dt);
  // a one-step ramp to full forward tilt, then 40 mm/s down (the trapezoid is exact here)
  EXPECT_NEAR(d.state().position_mm.z(), 3.0 - 0.5 * 40 * 0.001 - 40.0 * (2.0 - 1.001), 1e-9);
  EXPECT_NEAR(d.state().velocity_mm_s.z(), -40.0, 1e-9);
}

TEST(ProbeDriver, JoystickPositionControlAndDeadZone) {
  JoystickMapping m;
  m.mode = JoystickMode::position;
  m.range_mm = 10;
  m.dead_zone = 0.2;
  EXPECT_TRUE(m.map({0.1, -1.0, 0.6}).isApprox(Eigen::Vector3d(0, -10, 5)));
  ProbeSettings s;
  s.drive = ProbeDrive::joystick;
  s.mapping = m;
  s.start_mm = {0, 0, 0};
  s.joystick = {{0.0, {0, 0, 0}}, {1.0, {1, 0, 0}}};
  ProbeDriver d(s);
  for (int k = 1; k <= 100; ++k) d.advance(k * 0.01, 0.01);
  EXPECT_TRUE(d.state().position_mm.isApprox(Eigen::Vector3d(10, 0, 0)));
  EXPECT_EQ(parse_joystick_mode("rate"), JoystickMode::rate);
  EXPECT_EQ(parse_joystick_mode(to_string(JoystickMode::position)), JoystickMode::position);
  EXPECT_THROW((void)parse_joystick_mode("joy"), Error);
}

TEST(ProbeDriver, LiveTargetsAreSpeedLimited) {
  ProbeSettings s;
  s.drive = ProbeDrive::live;
  s.start_mm = {0, 0, 0};
  s.max_speed_mm_s = 100;
  ProbeDriver d(s);
  d.set_live({LiveCommand::Kind::position, {10, 0, 0}});
  d.advance(0.01, 0.01);  // at most 1 mm per 10 ms
  EXPECT_TRUE(d.state().position_mm.isApprox(Eigen::Vector3d(1, 0, 0)));
  EXPECT_TRUE(d.state().velocity_mm_s.isApprox(Eigen::Vector3d(100, 0, 0)));
  d.set_live({LiveCommand::Kind::velocity, {0, -20, 0}});
  d.advance(0.02, 0.01);
  EXPECT_TRUE(d.state().position_mm.isApprox(Eigen::Vector3d(1, -0.2, 0)));
  d.set_live({LiveCommand::Kind::hold, {}});
  d.advance(0.03, 0.01);
  EXPECT_TRUE(d.state().position_mm.isApprox(Eigen::Vector3d(1, -0.2, 0)));
  EXPECT_NEAR(d.state().velocity_mm_s.norm(), 0.0, 1e-12);
}

TEST(ProbeDriver, ValidationNamesTheProblem) {
  ProbeSettings s;
  s.drive = ProbeDrive::path;
  s.path = {{0.0, {0, 0, 0}}, {0.0, {1, 0, 0}}};
  EXPECT_NE(s.validate().find("times must increase"), std::string::npos);
  s.drive = ProbeDrive::joystick;
  s.joystick = {{0.0, {2, 0, 0}}};
  EXPECT_NE(s.validate().find("[-1, 1]"), std::string::npos);
}
