// The force guard between the app's force and the hand (apps/probe/force_guard.h): the rated
// maximum, the ramp up after a start, the fade after a fault, at a 1 kHz device tick.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "force_guard.h"

namespace vx::probe {
namespace {

constexpr double kTick_s = 0.001;

/// The forces a guard plays for `wanted` over `ticks` ticks of 1 ms.
std::vector<Eigen::Vector3d> play(DeviceForceGuard& g, const Eigen::Vector3d& wanted, int ticks) {
  std::vector<Eigen::Vector3d> out;
  for (int k = 0; k < ticks; ++k) out.push_back(g.apply(wanted, kTick_s));
  return out;
}

double largest_step(const std::vector<Eigen::Vector3d>& f, const Eigen::Vector3d& before) {
  double m = (f.front() - before).norm();
  for (std::size_t i = 1; i < f.size(); ++i) m = std::max(m, (f[i] - f[i - 1]).norm());
  return m;
}

/// The first tick (1-based) from which the force's magnitude stays within tol of `level`.
int settled_at(const std::vector<Eigen::Vector3d>& f, double level, double tol = 1e-9) {
  int k = int(f.size());
  while (k > 0 && std::abs(f[std::size_t(k - 1)].norm() - level) <= tol) --k;
  return k + 1;
}

TEST(DeviceForceGuard, RampsUpOverTheFirst100msFromZero) {
  DeviceForceGuard g;
  const Eigen::Vector3d wanted(0.0, 0.0, 1.2);
  const auto f = play(g, wanted, 200);
  // linear: k ms after the start, k/100 of the force; full at 100 ms and no earlier
  EXPECT_NEAR(f[0].z(), 1.2 * 0.01, 1e-12);
  EXPECT_NEAR(f[49].z(), 1.2 * 0.50, 1e-12);
  EXPECT_LT(f[98].z(), 1.2);
  EXPECT_EQ(settled_at(f, 1.2), 100);
  EXPECT_NEAR(largest_step(f, Eigen::Vector3d::Zero()), 0.012, 1e-12);
  EXPECT_EQ(g.phase(), DeviceForceGuard::Phase::on);
}

TEST(DeviceForceGuard, ClampsToTheRatedMaximumKeepingTheDirection) {
  ForceGuardSettings s;
  s.max_force_N = 2.0;
  s.ramp_up_s = 0.0;
  DeviceForceGuard g(s);
  const Eigen::Vector3d wanted(3.0, 0.0, 4.0);  // 5 N
  const Eigen::Vector3d f = g.apply(wanted, kTick_s);
  EXPECT_NEAR(f.norm(), 2.0, 1e-12);
  EXPECT_NEAR(f.x() / f.z(), 0.75, 1e-12);
  EXPECT_EQ(g.clamped_ticks(), 1);
  // under the maximum: untouched
  EXPECT_EQ(g.apply(Eigen::Vector3d(0.5, 0, 0), kTick_s), Eigen::Vector3d(0.5, 0, 0));
  EXPECT_EQ(g.clamped_ticks(), 1);
}

TEST(DeviceForceGuard, AFaultFadesTheHeldForceToZeroWithin40msThenRampsUpAgain) {
  DeviceForceGuard g;
  const Eigen::Vector3d wanted(0.3, -0.4, 1.2);  // 1.3 N
  auto f = play(g, wanted, 150);
  ASSERT_EQ(g.phase(), DeviceForceGuard::Phase::on);
  g.interrupt();
  // what the physics says after the fault is not played: the held force fades
  const auto fade = play(g, Eigen::Vector3d(0.0, 0.0, 1.9), 40);
  EXPECT_TRUE(fade.back().isZero(0.0));
  EXPECT_GT(fade[38].norm(), 0.0);  // not cut at once
  for (const auto& x : fade) EXPECT_NEAR(x.normalized().dot(wanted.normalized()), x.isZero(0.0) ? 0.0 : 1.0, 1e-12);
  EXPECT_NEAR(largest_step(fade, f.back()), 1.3 / 40.0, 1e-12);
  // then from zero over 100 ms to the new force
  const Eigen::Vector3d after(0.0, 0.0, 0.8);
  const auto rise = play(g, after, 150);
  EXPECT_EQ(settled_at(rise, 0.8), 100);
  EXPECT_NEAR(largest_step(rise, fade.back()), 0.008, 1e-12);
  EXPECT_EQ(g.interrupts(), 1);
}

TEST(DeviceForceGuard, AFaultWhileRisingFadesFromWhatTheHandFeels) {
  DeviceForceGuard g;
  const auto f = play(g, Eigen::Vector3d(0.0, 0.0, 1.0), 50);  // half way: 0.5 N
  g.interrupt();
  g.interrupt();  // a second fault during the fade does not restart it
  const auto fade = play(g, Eigen::Vector3d(0.0, 0.0, 1.0), 40);
  EXPECT_NEAR(fade[0].z(), 0.5 * 39.0 / 40.0, 1e-12);
  EXPECT_TRUE(fade.back().isZero(0.0));
  EXPECT_NEAR(largest_step(fade, f.back()), 0.5 / 40.0, 1e-12);
}

TEST(DeviceForceGuard, ANonFiniteForceIsNeverPlayedAndFadesLikeAFault) {
  DeviceForceGuard g;
  const auto f = play(g, Eigen::Vector3d(0.0, 1.0, 0.0), 120);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::vector<Eigen::Vector3d> out;
  for (int k = 0; k < 60; ++k) out.push_back(g.apply(Eigen::Vector3d(nan, 0.0, 0.0), kTick_s));
  for (const auto& x : out) EXPECT_TRUE(x.allFinite());
  EXPECT_NEAR(largest_step(out, f.back()), 1.0 / 40.0, 1e-12);
  EXPECT_TRUE(out[39].isZero(0.0));
  EXPECT_EQ(g.non_finite(), 60);
  EXPECT_EQ(g.interrupts(), 60);
}

TEST(DeviceForceGuard, ARestartRampsUpFromZero) {
  DeviceForceGuard g;
  (void)play(g, Eigen::Vector3d(1.0, 0.0, 0.0), 150);
  g.restart();  // a reconnected device
  const auto f = play(g, Eigen::Vector3d(1.0, 0.0, 0.0), 150);
  EXPECT_NEAR(f[0].x(), 0.01, 1e-12);
  EXPECT_EQ(settled_at(f, 1.0), 100);
}

TEST(DeviceForceGuard, AnUnpluggedDeviceFadesOutAndStaysAtZeroUntilPluggedBack) {
  DeviceForceGuard g;
  (void)play(g, Eigen::Vector3d(0.0, 0.0, 0.8), 150);
  g.disconnect();
  const auto off = play(g, Eigen::Vector3d(0.0, 0.0, 0.8), 300);
  EXPECT_NEAR(largest_step(off, Eigen::Vector3d(0.0, 0.0, 0.8)), 0.02, 1e-12);
  for (std::size_t k = 39; k < off.size(); ++k) EXPECT_TRUE(off[k].isZero(0.0)) << k;
  EXPECT_EQ(g.phase(), DeviceForceGuard::Phase::off);
  g.restart();
  const auto back = play(g, Eigen::Vector3d(0.0, 0.0, 0.8), 150);
  EXPECT_EQ(settled_at(back, 0.8), 100);
  EXPECT_NEAR(largest_step(back, off.back()), 0.008, 1e-12);
}

TEST(DeviceForceGuard, SettingsAreChecked) {
  EXPECT_EQ(ForceGuardSettings{}.validate(), "");
  ForceGuardSettings s;
  s.fade_s = 0.08;
  EXPECT_NE(s.validate().find("0.05"), std::string::npos);
  s = {};
  s.max_force_N = 0.0;
  EXPECT_NE(s.validate().find("maximum"), std::string::npos);
}

}  // namespace
}  // namespace vx::probe
