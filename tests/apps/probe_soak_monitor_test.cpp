// The soak's per-second judgement of the device (apps/probe/soak.h): the worst second's forces
// and the hypervisor's steal in that second, read where each window starts and ends.
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
}

TEST(SoakMonitor, TheMachinesStealIsAClockThatDoesNotRunBackwards) {
  const double a = cpu_steal_s();
  const double b = cpu_steal_s();
  EXPECT_GE(a, 0.0);
  EXPECT_GE(b, a);
}

}  // namespace
}  // namespace vx::probe
