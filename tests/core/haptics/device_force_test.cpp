// The device force (paper 4.3): mean of the last raw forces at a slow update interval, played as
// positive half sines that are zero at every update instant.
#include "haptics/device_force.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "base/error.h"

using namespace vx;

TEST(DeviceForce, ZeroAtEveryUpdateAndHalfSineBetween) {
  DeviceForceSettings s;
  s.update_interval_s = 0.01;
  const double dt = 1e-3;  // 10 steps per update
  DeviceForceShaper shaper;
  shaper.init(s, dt);
  ASSERT_EQ(shaper.steps_per_update(), 10);
  ASSERT_EQ(shaper.window_steps(), 10);
  const Eigen::Vector3d raw(0, 0, 2.0);
  for (int n = 1; n <= 100; ++n) {
    const Eigen::Vector3d f = shaper.push(raw, n * dt);
    if (n % 10 == 0) {
      EXPECT_EQ(f, Eigen::Vector3d::Zero()) << "step " << n;  // exactly zero at the update
    } else if (n > 10) {
      // constant raw force 2 N: peak pi/2 * 2 N, a positive half sine
      const double expected = std::numbers::pi / 2 * 2.0 * std::sin(std::numbers::pi * (n % 10) / 10.0);
      EXPECT_NEAR(f.z(), expected, 1e-12) << "step " << n;
      EXPECT_GT(f.z(), 0.0);
    } else {
      EXPECT_EQ(f, Eigen::Vector3d::Zero());  // nothing before the first update
    }
  }
  EXPECT_EQ(shaper.updates(), 10);
  // the pulse a device thread evaluates at its own clock agrees with the sampled force
  const HalfSinePulse& p = shaper.pulse();
  EXPECT_NEAR(p.start_s, 0.1, 1e-12);
  EXPECT_NEAR(p.duration_s, 0.01, 1e-15);
  EXPECT_NEAR(p.at(0.1025).z(), std::numbers::pi * std::sin(std::numbers::pi * 0.25), 1e-9);
  EXPECT_EQ(p.at(0.1), Eigen::Vector3d::Zero());
  EXPECT_EQ(p.at(0.111), Eigen::Vector3d::Zero());
  EXPECT_TRUE(p.mean_n.isApprox(raw));
}

TEST(DeviceForce, MeanFollowsTheRawMeanOfAJitteringForce) {
  // raw force like the paper's fig. 10: a slow ramp with large step-to-step jitter
  DeviceForceSettings s;
  s.update_interval_s = 0.02;
  const double dt = 1e-4;  // 200 steps per device update
  DeviceForceShaper shaper;
  shaper.init(s, dt);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> jitter(-1.0, 1.0);
  const int steps = 20000;  // 2 s, 100 updates
  double raw_sum = 0, shaped_sum = 0, max_jump_raw = 0, max_jump_shaped = 0, prev_raw = 0, prev_shaped = 0;
  const int skip = 400;  // the shaped force lags one interval: compare after the first updates
  for (int n = 1; n <= steps; ++n) {
    const double t = n * dt;
    const double mean = 0.5 + 0.25 * t;  // N
    const double raw = mean * (1.0 + 0.9 * jitter(rng)) + ((n % 2) ? 0.3 : -0.3);
    const double shaped = shaper.push(Eigen::Vector3d(raw, 0, 0), t).x();
    if (n > skip) {
      raw_sum += raw;
      shaped_sum += shaped;
      max_jump_raw = std::max(max_jump_raw, std::abs(raw - prev_raw));
      max_jump_shaped = std::max(max_jump_shaped, std::abs(shaped - prev_shaped));
    }
    prev_raw = raw;
    prev_shaped = shaped;
  }
  const double raw_mean = raw_sum / (steps - skip);
  const double shaped_mean = shaped_sum / (steps - skip);
  // the shaped force lags the raw one by one interval: on a ramp of 0.25 N/s that is
  // 0.005 N of 0.75 N; the averaging of +-90% jitter over 200 steps adds ~0.2%
  EXPECT_NEAR(shaped_mean / raw_mean, 1.0, 0.015) << raw_mean << " vs " << shaped_mean;
  // and the shaped force is smooth: its step-to-step change is far below the raw jitter
  EXPECT_LT(max_jump_shaped, 0.05 * max_jump_raw);
}

TEST(DeviceForce, WindowOfTheLastFewSteps) {
  DeviceForceSettings s;
  s.update_interval_s = 0.01;
  s.average_steps = 3;
  DeviceForceShaper shaper;
  shaper.init(s, 1e-3);
  for (int n = 1; n <= 10; ++n) shaper.push(Eigen::Vector3d(n, 0, 0), n * 1e-3);
  // the update at step 10 averages steps 8, 9, 10
  EXPECT_NEAR(shaper.pulse().mean_n.x(), 9.0, 1e-12);
  s.mean_preserving = false;
  shaper.init(s, 1e-3);
  for (int n = 1; n <= 15; ++n) shaper.push(Eigen::Vector3d(0, 1, 0), n * 1e-3);
  EXPECT_NEAR(shaper.shaped().y(), 1.0, 1e-12);  // peak = mean at mid-interval
}

TEST(DeviceForce, RejectsIntervalsShorterThanTwoSteps) {
  DeviceForceSettings s;
  s.update_interval_s = 1e-4;
  DeviceForceShaper shaper;
  EXPECT_THROW(shaper.init(s, 1e-4), Error);
  s.update_interval_s = -1;
  EXPECT_NE(s.validate().find("interval"), std::string::npos);
}
