// The real-time factor the probe app reports (apps/probe/real_time_meter.h): simulated over wall
// time of one named interval, with exact numbers.
#include <gtest/gtest.h>

#include "real_time_meter.h"

using vx::probe::rate_between;
using vx::probe::RateSample;
using vx::probe::RateWindow;
using vx::probe::RealTimeMeter;

TEST(RealTimeMeter, FactorIsSimulatedOverWallTimeOfTheSameInterval) {
  const RateWindow w = rate_between({10.0, 2.0, 100}, {12.0, 2.5, 125});
  EXPECT_DOUBLE_EQ(w.wall_s, 2.0);
  EXPECT_DOUBLE_EQ(w.sim_s, 0.5);
  EXPECT_EQ(w.steps, 25);
  EXPECT_DOUBLE_EQ(w.factor(), 0.25);
  EXPECT_DOUBLE_EQ(w.steps_per_s(), 12.5);
  // steps x dt over the same wall time is the factor: 12.5 steps/s x 20 ms = 0.25
  EXPECT_DOUBLE_EQ(w.steps_per_s() * 0.02, w.factor());
  EXPECT_EQ(rate_between({1.0, 0, 0}, {1.0, 0, 0}).factor(), 0.0);  // an empty interval is 0, not inf
}

TEST(RealTimeMeter, WindowEndsAtTheNewestSampleAndReachesBackAtLeastTheWindow) {
  RealTimeMeter m;
  EXPECT_EQ(m.over_last(1.0).wall_s, 0.0);  // nothing yet
  // 0.25 s apart; the physics makes 10 ms of simulated time per 0.25 s (0.04x), then stalls
  for (int i = 0; i <= 8; ++i) m.add({0.25 * i, 0.01 * i, i});
  RateWindow w = m.over_last(1.0);
  EXPECT_TRUE(w.full);
  EXPECT_DOUBLE_EQ(w.wall_s, 1.0);  // 1.0 .. 2.0
  EXPECT_NEAR(w.sim_s, 0.04, 1e-15);
  EXPECT_NEAR(w.factor(), 0.04, 1e-14);
  EXPECT_EQ(w.steps, 4);
  // a step that is still running counts as wall time without simulated time
  m.add({2.5, 0.08, 8});
  w = m.over_last(1.0);
  EXPECT_DOUBLE_EQ(w.wall_s, 1.0);  // 1.5 .. 2.5
  EXPECT_NEAR(w.sim_s, 0.02, 1e-15);
  EXPECT_NEAR(w.factor(), 0.02, 1e-14);
  m.add({3.6, 0.08, 8});
  w = m.over_last(1.0);
  EXPECT_DOUBLE_EQ(w.wall_s, 1.1);  // 2.5 .. 3.6: the newest sample at least 1 s older
  EXPECT_EQ(w.factor(), 0.0);
  // the whole history when it is shorter than the window (not full)
  w = m.over_last(100.0);
  EXPECT_FALSE(w.full);
  EXPECT_DOUBLE_EQ(w.wall_s, 3.6);
  EXPECT_NEAR(w.factor(), 0.08 / 3.6, 1e-15);
}

TEST(RealTimeMeter, RestartForgetsAPauseAndTheRingKeepsTheNewest) {
  RealTimeMeter m(4);
  m.add({0.0, 0.0, 0});
  m.add({1.0, 1.0, 10});
  m.restart();  // paused from 1 s to 5 s
  EXPECT_EQ(m.size(), 0u);
  m.add({5.0, 1.0, 10});
  m.add({6.0, 1.5, 15});
  EXPECT_DOUBLE_EQ(m.over_last(1.0).factor(), 0.5);  // the pause is not counted
  for (int i = 7; i <= 12; ++i) m.add({double(i), 1.5 + 0.5 * (i - 6), 10 + 5 * (i - 5)});
  EXPECT_EQ(m.size(), 4u);
  const RateWindow w = m.over_last(100.0);
  EXPECT_DOUBLE_EQ(w.wall_s, 3.0);  // 9 .. 12: the four newest
  EXPECT_DOUBLE_EQ(w.factor(), 0.5);
  m.add({11.0, 9.0, 99});  // wall time going back is ignored
  EXPECT_DOUBLE_EQ(m.over_last(1.0).factor(), 0.5);
}

TEST(RealTimeMeter, StartUpIsWordedAsStartUpAndRatesNameTheirWindow) {
  EXPECT_EQ(vx::probe::StartupReport::preparing(3.24, std::nullopt), "preparing the solver (3.2 s)");
  EXPECT_EQ(vx::probe::StartupReport::preparing(3.24, 0.4), "preparing the solver: 40 %");
  RateWindow w{2.0, 0.5, 26, true};
  EXPECT_EQ(vx::probe::describe_physics_rate(w, 1.0, false), "13 steps/s (0.25x real time, last 1 s)");
  w.full = false;
  EXPECT_EQ(vx::probe::describe_physics_rate(w, 1.0, true), "13 steps/s (tissue 0.25x real time, last 2.0 s)");
  // no interval yet (one sample, the display's first pass after the start-up): no 0x of nothing
  const RateWindow empty{0.0, 0.0, 0, false};
  EXPECT_EQ(vx::probe::describe_physics_rate(empty, 1.0, true), "steps/s: measuring (tissue real time: measuring)");
  EXPECT_EQ(vx::probe::describe_physics_rate(empty, 1.0, false), "steps/s: measuring (real time: measuring)");
}
