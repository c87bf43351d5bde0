// Sharing the cores with the display (apps/probe/thread_share.h): when the physics goes to one
// thread and back, and when it tries one, driven by made-up step costs on a made-up clock.
#include "thread_share.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <functional>

namespace vx::probe {
namespace {

constexpr double kDt = 0.03;  // s: the fast configuration's step

// Steps of kDt against a wall clock: a step starts when it is due (its simulated time in real
// time) or, when the physics lags, at once, and costs cost(t, threads) s of wall time; the lag is
// how far the wall clock is past the next step's due time (as PhysicsLoop::advance catches up).
// Each step is a tick, handed over as PhysicsLoop hands its ticks: the target's lag (the wall
// clock at the step's start less the next step's due time), the step's wall time apart.
// Runs `seconds` of wall time on.
struct Clocked {
  ThreadShare share;
  double wall{0.0};
  double due{0.0};
  double lag{0.0};
  double max_lag_on_one{0.0};  ///< ahead of real time on one thread (a trial may lag more)
  int steps_on_one{0};
  int steps_on_trial{0};

  explicit Clocked(int most) : share(most) {}
  void go(double seconds, const std::function<double(double, int)>& cost) {
    const double end = wall + seconds;
    while (wall < end) {
      const int threads = share.threads();
      const ThreadShare::Mode mode = share.mode();
      wall = std::max(wall, due);
      const double c = cost(wall, threads);
      wall += c;
      due += kDt;
      lag = std::max(0.0, wall - due);
      if (threads == 1) ++steps_on_one;
      if (mode == ThreadShare::Mode::kAhead) max_lag_on_one = std::max(max_lag_on_one, lag);
      if (mode == ThreadShare::Mode::kTrial) ++steps_on_trial;
      (void)share.after_steps(wall, c, kDt, (wall - c) - due);
    }
  }
};

TEST(ThreadShare, OneThreadGivenHasNothingToShare) {
  Clocked r(1);
  r.go(30.0, [](double, int) { return 0.001; });
  EXPECT_EQ(r.share.threads(), 1);
  EXPECT_EQ(r.share.changes(), 0);
}

TEST(ThreadShare, GoesToOneThreadAfterTheHoldOfLowLoad) {
  ThreadShare s(2);
  // load 0.3: twice that keeps real time
  double t = 0.0;
  s.after_steps(t, 0.009, kDt, 0.0);  // the window opens here
  while (t + kDt < ThreadShare::kHold_s - 1e-9) {
    t += kDt;
    EXPECT_EQ(s.after_steps(t, 0.009, kDt, 0.0), 2) << t;
  }
  t = ThreadShare::kHold_s;
  EXPECT_EQ(s.after_steps(t, 0.009, kDt, 0.0), 1);
  EXPECT_EQ(s.changes(), 1);
}

TEST(ThreadShare, StaysOnAllWhenOneThreadWouldNotKeepRealTime) {
  // load 0.46 on two threads: one thread could need 0.92 of real time, over kDrop. A trial at
  // 2 s finds it (0.92 against 0.46); the next waits 10 s, the one after 20 s, then 40 s: three
  // trials of 0.5 s in a minute, each back on two threads
  Clocked high(2);
  high.go(60.0, [](double, int threads) { return (threads == 2 ? 0.46 : 0.92) * kDt; });
  EXPECT_EQ(high.share.trials(), 3);
  EXPECT_EQ(high.share.trials_kept(), 0);
  EXPECT_EQ(high.share.changes(), 6);
  EXPECT_EQ(high.steps_on_one, high.steps_on_trial);
  EXPECT_LE(high.steps_on_trial, 3 * 19);  // 0.5 s at 0.92 x 30 ms a step, three times
  EXPECT_EQ(high.share.threads(), 2);
  // 0.44: one thread at twice that keeps it, without a trial
  Clocked low(2);
  low.go(60.0, [](double, int threads) { return (threads == 2 ? 0.44 : 0.88) * kDt; });
  EXPECT_EQ(low.share.changes(), 1);
  EXPECT_EQ(low.share.trials(), 0);
  EXPECT_EQ(low.share.threads(), 1);
  EXPECT_GT(low.steps_on_one, 1800);  // all but the first 2 s of 60 s at 33 steps/s
  EXPECT_EQ(low.max_lag_on_one, 0.0);
}

TEST(ThreadShare, ThreeThreadsGoToOneOnlyWhenThreeTimesTheLoadKeepsRealTime) {
  Clocked r(3);
  r.go(30.0, [](double, int threads) { return (threads == 3 ? 0.32 : 0.96) * kDt; });
  EXPECT_EQ(r.share.trials_kept(), 0);
  EXPECT_EQ(r.steps_on_one, r.steps_on_trial);  // one thread only to try it
  EXPECT_EQ(r.share.threads(), 3);
  Clocked s(3);
  s.go(30.0, [](double, int threads) { return (threads == 3 ? 0.29 : 0.87) * kDt; });
  EXPECT_EQ(s.share.threads(), 1);
}

TEST(ThreadShare, APressBringsTheThreadsBackWithinTheLag) {
  // at rest (asleep: steps cost nothing), then from 10 s a press whose steps take 1.5 dt on one
  // thread and 0.8 dt on two
  Clocked r(2);
  const auto cost = [](double t, int threads) {
    if (t < 10.0) return 0.001;
    return (threads == 2 ? 0.8 : 1.5) * kDt;
  };
  r.go(10.0, cost);
  EXPECT_EQ(r.share.threads(), 1);
  r.go(20.0, cost);
  EXPECT_EQ(r.share.threads(), 2);
  // down once, up once; under the press one thread only in two trials (at 2 s and 12.5 s into it)
  EXPECT_EQ(r.share.trials(), 2);
  EXPECT_EQ(r.share.trials_kept(), 0);
  EXPECT_EQ(r.share.changes(), 2 + 2 * 2);
  // it came back as soon as the lag passed kRiseLag_s: one step later at most
  EXPECT_GT(r.max_lag_on_one, ThreadShare::kRiseLag_s);
  EXPECT_LE(r.max_lag_on_one, ThreadShare::kRiseLag_s + 0.5 * kDt + 1e-12);
}

// Ahead on one thread at rest (a tissue asleep: 1 ms a step), a tick whose one step took 0.3 s
// (the folded organ's first touch on one thread) and left the simulation where the tick aimed
// (its target's lag 0: the step's own wall time is not in it): every thread for the next steps,
// at once. The steps that come after it (the region's set-up, 0.25 s on one thread) no longer
// wait for the next tick to find the lag. A step of 45 ms is not a lag (a burst: the test below).
TEST(ThreadShare, OneSlowStepIsALagAtOnce) {
  ThreadShare s(2);
  double t = 0.0;
  for (int k = 0; k < 100; ++k, t += kDt) (void)s.after_steps(t, 0.001, kDt, -0.5 * kDt);  // 3 s at rest
  ASSERT_EQ(s.mode(), ThreadShare::Mode::kAhead);
  EXPECT_EQ(s.after_steps(t, 0.045, kDt, 0.0), 1);  // 45 ms: within kRiseLag_s
  EXPECT_EQ(s.after_steps(t + 0.3, 0.3, kDt, 0.0), 2);
  EXPECT_EQ(s.mode(), ThreadShare::Mode::kAll);
}

TEST(ThreadShare, ABurstItCatchesUpWithKeepsOneThread) {
  // one thread at load 0.4 with a burst of three steps at 1.5 dt every 150 steps: 45 ms behind
  // at most, caught up in the steps after
  Clocked r(2);
  int step = 0;
  r.go(60.0, [&](double t, int threads) {
    const bool burst = t > 3.0 && ++step % 150 < 3;
    return (burst ? 1.5 : threads == 2 ? 0.2 : 0.4) * kDt;
  });
  EXPECT_EQ(r.share.changes(), 1);
  EXPECT_EQ(r.share.threads(), 1);
  EXPECT_GT(r.max_lag_on_one, 0.04);
}

TEST(ThreadShare, AWindowThatSpansAPauseWaitsForMoreSteps) {
  // 0.3 s of light steps, a pause of 5 s (no steps, no calls), then a press at load 0.8 on two
  // threads: deciding at the first step after the pause, on the light steps, would drop to one
  // thread (and come back at the lag); the window waits for kMinWindowSim_s of steps instead
  Clocked r(2);
  bool pressing = false;
  const auto cost = [&](double, int threads) { return (pressing ? 0.8 : 0.1) * (threads == 2 ? 1.0 : 2.0) * kDt; };
  r.go(0.3, cost);
  r.wall += 5.0;
  r.due = r.wall;
  pressing = true;
  r.go(10.0, cost);
  EXPECT_EQ(r.steps_on_one, r.steps_on_trial);  // never ahead on one thread
  EXPECT_EQ(r.share.trials(), 1);               // a trial after the first full window, not kept
  EXPECT_EQ(r.share.trials_kept(), 0);
  EXPECT_EQ(r.share.threads(), 2);
}

// Two threads that are no faster than one (a busy machine; a display on the other core): steps
// at 0.95 of real time on two and 1.0 on one. A trial keeps one thread after the first window;
// after kRecheck_s it measures two again and keeps one again.
TEST(ThreadShare, OneThreadAsFastAsAllIsKept) {
  Clocked r(2);
  r.go(60.0, [](double, int threads) { return (threads == 2 ? 0.95 : 1.0) * kDt; });
  EXPECT_EQ(r.share.trials(), 2);
  EXPECT_EQ(r.share.trials_kept(), 2);
  EXPECT_EQ(r.share.changes(), 3);  // down, up for the recheck, down
  EXPECT_EQ(r.share.mode(), ThreadShare::Mode::kKept);
  // on two threads only for the two windows of 2 s: 4 of 60 s
  const int steps = int(60.0 / kDt);
  EXPECT_NEAR(r.steps_on_one, steps - int(4.0 / (0.95 * kDt)), 10);
}

// Kept on one thread, a press that two threads carry better (0.8 against 1.5 of real time)
// brings them back within one kept window; the trial after the next window does not keep one.
TEST(ThreadShare, APressBringsTheThreadsBackFromAKeptTrial) {
  Clocked r(2);
  const auto cost = [](double t, int threads) {
    if (t < 10.0) return (threads == 2 ? 0.95 : 1.0) * kDt;
    return (threads == 2 ? 0.8 : 1.5) * kDt;
  };
  r.go(10.0, cost);
  ASSERT_EQ(r.share.mode(), ThreadShare::Mode::kKept);
  double back_s = -1.0;
  while (r.wall < 30.0) {
    r.go(0.001, cost);
    if (back_s < 0.0 && r.share.threads() == 2) back_s = r.wall;
  }
  // within the first kept window wholly in the press (the one it began in may average below
  // kRise): two windows of 0.5 s of wall time and the step that ends the second
  EXPECT_GT(back_s, 10.0);
  EXPECT_LE(back_s, 10.0 + 2 * ThreadShare::kTrialWall_s + 1.5 * kDt);
  EXPECT_EQ(r.share.trials_kept(), 1);
  EXPECT_EQ(r.share.trials(), 3);  // at 2 s (kept), after the press's first window, 10 s later
  EXPECT_EQ(r.share.threads(), 2);
}

// A busy machine that quietens: kept on one thread while two are no faster; at the recheck two
// threads are twice as fast, and it stays on them.
TEST(ThreadShare, TheRecheckFindsAQuietMachine) {
  Clocked r(2);
  r.go(60.0, [](double t, int threads) {
    if (t < 20.0) return (threads == 2 ? 0.95 : 1.0) * kDt;
    return (threads == 2 ? 0.5 : 1.0) * kDt;
  });
  EXPECT_EQ(r.share.trials_kept(), 1);
  EXPECT_EQ(r.share.trials(), 3);  // kept at 2 s; failed after the recheck (34.5 s) and 10 s later
  EXPECT_EQ(r.share.threads(), 2);
  EXPECT_EQ(r.share.mode(), ThreadShare::Mode::kAll);
}

// Far behind real time: a tiny model whose two threads wait at every barrier for a worker that a
// busy machine has not scheduled (0.4 s a 30 ms step on two, 60 ms on one). Its window holds
// 0.4 s of simulated time in 2 s of wall time, all of it in steps, and decides at its end: the
// trial keeps one thread. (Waiting for 1 s of simulated time, it would decide after 13 s.)
TEST(ThreadShare, APhysicsFarBehindDecidesAtItsWindowsEnd) {
  Clocked r(2);
  r.go(5.0, [](double, int threads) { return threads == 2 ? 0.4 : 0.06; });
  EXPECT_EQ(r.share.trials(), 1);
  EXPECT_EQ(r.share.trials_kept(), 1);
  EXPECT_EQ(r.share.threads(), 1);
  EXPECT_EQ(r.share.mode(), ThreadShare::Mode::kKept);  // 2x real time on one: not ahead
}

TEST(ThreadShare, StepsWithoutSimulatedTimeChangeNothing) {
  ThreadShare s(2);
  for (int k = 0; k < 1000; ++k) EXPECT_EQ(s.after_steps(0.01 * k, 0.0, 0.0, 0.0), 2);
  EXPECT_EQ(s.changes(), 0);
}

}  // namespace
}  // namespace vx::probe
