// PiMutex (base/pi_mutex.h): the priority inversion that a real-time thread meets on a plain
// mutex, staged on one core, and bounded by priority inheritance.
//
// On one core: a low thread (SCHED_OTHER) takes the lock and then needs 20 ms of its own CPU time
// to let go; a middle thread (SCHED_FIFO 2) spins for 300 ms; a high thread (SCHED_FIFO 3) wants
// the lock. On a plain mutex the high thread waits for the middle one's 300 ms (the low one
// cannot run); with inheritance the low thread runs at the high one's priority and the wait is
// its own 20 ms. Needs the permission to raise a thread's priority (root or CAP_SYS_NICE) and two
// cores; it says so and skips without them.

#include "base/pi_mutex.h"

#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>
#include <time.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <functional>
#include <mutex>
#include <thread>

namespace {

using Clock = std::chrono::steady_clock;

double thread_cpu_s() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}

/// A thread pinned to `cpu`, at SCHED_FIFO `priority` (0: SCHED_OTHER) from its first instruction.
class Pinned {
 public:
  template <class F>
  Pinned(int cpu, int priority, F body) : body_(std::move(body)) {
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    pthread_attr_setaffinity_np(&attr, sizeof set, &set);
    if (priority > 0) {
      pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
      pthread_attr_setschedpolicy(&attr, SCHED_FIFO);
      sched_param p{};
      p.sched_priority = priority;
      pthread_attr_setschedparam(&attr, &p);
    }
    started_ = pthread_create(&thread_, &attr, &Pinned::run, this) == 0;
    pthread_attr_destroy(&attr);
  }
  ~Pinned() {
    if (started_) pthread_join(thread_, nullptr);
  }
  Pinned(const Pinned&) = delete;
  Pinned& operator=(const Pinned&) = delete;
  [[nodiscard]] bool started() const { return started_; }

 private:
  static void* run(void* self) {
    static_cast<Pinned*>(self)->body_();
    return nullptr;
  }
  std::function<void()> body_;
  pthread_t thread_{};
  bool started_{false};
};

bool real_time_permitted() {
  return Pinned(0, 1, [] {}).started();
}

/// The stage on core `core`: how long, s, the high thread waited for the lock (< 0: a thread
/// could not be started).
template <class Mutex>
double stage_inversion(Mutex& m, int core) {
  std::atomic<bool> locked{false};
  std::atomic<bool> middle_on{false};
  double wait_s = -1.0;
  const Pinned low(core, 0, [&] {
    std::lock_guard lock(m);
    locked = true;
    const double t0 = thread_cpu_s();
    while (thread_cpu_s() - t0 < 0.020) {
    }
  });
  if (!low.started()) return -1.0;
  while (!locked) std::this_thread::yield();
  const Pinned middle(core, 2, [&] {
    middle_on = true;
    const auto until = Clock::now() + std::chrono::milliseconds(300);
    while (Clock::now() < until) {
    }
  });
  if (!middle.started()) return -1.0;
  while (!middle_on) std::this_thread::yield();
  {
    const Pinned high(core, 3, [&] {
      const auto t0 = Clock::now();
      std::lock_guard lock(m);
      wait_s = std::chrono::duration<double>(Clock::now() - t0).count();
    });
    if (!high.started()) return -1.0;
  }
  return wait_s;
}

/// The stage on core 1, with this thread on core 0 meanwhile (so that it can start the others
/// while the middle one spins) and back on its own cores after.
template <class Mutex>
double inversion_wait_s(Mutex& m) {
  cpu_set_t before;
  pthread_getaffinity_np(pthread_self(), sizeof before, &before);
  cpu_set_t off;
  CPU_ZERO(&off);
  CPU_SET(0, &off);
  pthread_setaffinity_np(pthread_self(), sizeof off, &off);
  const double wait_s = stage_inversion(m, 1);
  pthread_setaffinity_np(pthread_self(), sizeof before, &before);
  return wait_s;
}

bool can_stage() {
  if (std::thread::hardware_concurrency() < 2) return false;
  return real_time_permitted();
}

TEST(PiMutex, InheritsPriorityOnLinux) {
  const vx::PiMutex m;
  EXPECT_TRUE(m.inherits_priority()) << "glibc supports PTHREAD_PRIO_INHERIT";
}

TEST(PiMutex, LocksTryLocksAndUnlocks) {
  vx::PiMutex m;
  m.lock();
  std::atomic<bool> other{true};
  std::thread([&] { other = m.try_lock(); }).join();
  EXPECT_FALSE(other) << "held by this thread";
  m.unlock();
  std::thread([&] {
    other = m.try_lock();
    if (other) m.unlock();
  }).join();
  EXPECT_TRUE(other) << "free again";
}

TEST(PiMutex, APlainMutexMakesTheRealTimeThreadWaitForTheMiddleOne) {
  // the stage itself: without inheritance the inversion shows, so the next test can fail
  if (!can_stage()) GTEST_SKIP() << "needs two cores and the permission for SCHED_FIFO (root or CAP_SYS_NICE)";
  std::mutex m;
  const double wait = inversion_wait_s(m);
  ASSERT_GE(wait, 0.0);
  std::printf("a plain mutex: the real-time thread waited %.1f ms\n", wait * 1e3);
  EXPECT_GT(wait, 0.200) << "the middle thread's 300 ms spin came between";
}

TEST(PiMutex, TheHolderRunsAtTheWaitersPriorityUntilItLetsGo) {
  if (!can_stage()) GTEST_SKIP() << "needs two cores and the permission for SCHED_FIFO (root or CAP_SYS_NICE)";
  vx::PiMutex m;
  const double wait = inversion_wait_s(m);
  ASSERT_GE(wait, 0.0);
  std::printf("PiMutex: the real-time thread waited %.1f ms\n", wait * 1e3);
  // the holder's 20 ms of CPU time (less what it had done before the high thread came), not 300
  EXPECT_LT(wait, 0.080) << "s waited for the lock";
}

}  // namespace
