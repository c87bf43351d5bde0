// The soak's per-second judgement of the device (apps/probe/soak.h): the worst second's forces
// and the hypervisor's steal in that second, read where each window starts and ends; the forces
// lacking in a second beyond what that steal can take.
#include <gtest/gtest.h>

#include "soak.h"

namespace vx::probe {
namespace {

TEST(SoakMonitor, TheWorstSecondCarriesItsOwnSteal) {
  double steal = 100.0;  // the machine's steal so far, s
  SoakMonitor m(1.0, [&] { return steal; });
  // the physics starts at 0.5 s; the windows count from then on
  m.sample(0.0, 0, -1.0);
  m.sample(0.5, 0, 0.5);  // opens the first window: 0 ticks, steal 100 s
  // second 1: 1000 forces, 5 ms stolen
  steal += 0.005;
  m.sample(1.5, 1000, 0.5);
  // second 2: 870 forces, 40 ms stolen (the worst second)
  steal += 0.040;
  m.sample(2.5, 1870, 0.5);
  // second 3: 990 forces, 60 ms stolen (more steal, fewer lost forces: the largest steal)
  steal += 0.060;
  m.sample(3.5, 2860, 0.5);
  // half a second: no window closes
  steal += 1.0;
  m.sample(3.9, 3000, 0.5);
  EXPECT_EQ(m.windows(), 3);
  EXPECT_NEAR(m.min_forces_per_s(), 870.0, 1e-9);
  EXPECT_NEAR(m.steal_in_worst_window_s(), 0.040, 1e-9);
  EXPECT_NEAR(m.max_window_steal_s(), 0.060, 1e-9);
  // second 2 lacked 130 forces, 40 of which the 40 ms of steal can take
  EXPECT_NEAR(m.max_unexplained_shortfall_per_s(), 90.0, 1e-9);
}

TEST(SoakMonitor, AShortfallTheStealCannotTakeIsOurs) {
  double steal = 0.0;
  SoakMonitor m(
      1.0, [&] { return steal; }, 1000.0);
  m.sample(0.0, 0, 0.0);
  // second 1: the host stopped the machine for 320 ms of CPU; 700 forces (300 lost, all of
  // them in the steal's reach)
  steal += 0.320;
  m.sample(1.0, 700, 0.0);
  EXPECT_NEAR(m.max_unexplained_shortfall_per_s(), 0.0, 1e-9);
  // second 2: no steal, 850 forces: 150 lost with the machine running (a stall of ours)
  m.sample(2.0, 1550, 0.0);
  EXPECT_NEAR(m.max_unexplained_shortfall_per_s(), 150.0, 1e-9);
  // second 3: 900 forces with 30 ms of steal; the worst second stays the one of 700 forces
  steal += 0.030;
  m.sample(3.0, 2450, 0.0);
  EXPECT_NEAR(m.max_unexplained_shortfall_per_s(), 150.0, 1e-9);
  EXPECT_NEAR(m.min_forces_per_s(), 700.0, 1e-9);
  // a window of 1.25 s (a late GUI pass): per second, 100 forces short with 50 ms of steal in
  // the window (40 forces per second) -> 60
  steal += 0.050;
  m.sample(4.25, 2450 + 1125, 0.0);
  EXPECT_NEAR(m.max_unexplained_shortfall_per_s(), 150.0, 1e-9);
  SoakMonitor slow(
      1.0, [&] { return steal; }, 500.0);  // a 500 Hz device: 1 force per 2 ms
  slow.sample(0.0, 0, 0.0);
  steal += 0.100;  // 50 ticks of steal
  slow.sample(1.0, 400, 0.0);
  EXPECT_NEAR(slow.max_unexplained_shortfall_per_s(), 50.0, 1e-9);
}

TEST(SoakMonitor, StealBeforeThePhysicsStartsIsNotCounted) {
  double steal = 0.0;
  SoakMonitor m(1.0, [&] { return steal; });
  m.sample(0.0, 0, -1.0);
  steal += 5.0;  // a long start-up on a stolen machine
  m.sample(3.0, 3000, -1.0);
  m.sample(3.2, 3200, 3.1);  // the physics started at 3.1 s: the window opens here
  steal += 0.010;
  m.sample(4.2, 4150, 3.1);
  EXPECT_EQ(m.windows(), 1);
  EXPECT_NEAR(m.min_forces_per_s(), 950.0, 1e-9);
  EXPECT_NEAR(m.steal_in_worst_window_s(), 0.010, 1e-9);
  EXPECT_NEAR(m.max_window_steal_s(), 0.010, 1e-9);
  EXPECT_NEAR(m.max_unexplained_shortfall_per_s(), 40.0, 1e-9);
}

TEST(SoakMonitor, TheMachinesStealIsAClockThatDoesNotRunBackwards) {
  const double a = cpu_steal_s();
  const double b = cpu_steal_s();
  EXPECT_GE(a, 0.0);
  EXPECT_GE(b, a);
}

}  // namespace
}  // namespace vx::probe
