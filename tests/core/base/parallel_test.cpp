// The core's parallel loop (base/parallel.h): chunk boundaries that do not depend on the thread
// count (the same sums on 1 and 2 threads, bit for bit), no fork for less than two full chunks,
// and release_openmp_workers, which ends a
// thread's idle OpenMP workers (they are counted against the cores by GNU OpenMP, and slow every
// other team's waits: the microbenchmark team/*).
#include "base/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <thread>
#include <vector>

using namespace vx;

namespace {

/// Threads of this process now (Linux: /proc/self/task), -1 where that cannot be read.
int thread_count() {
  std::error_code ec;
  int n = 0;
  for (std::filesystem::directory_iterator it("/proc/self/task", ec), end; !ec && it != end; it.increment(ec)) ++n;
  return ec ? -1 : n;
}

/// The thread count once it has fallen to `n` (a released worker leaves on its own time), or
/// after 5 s whatever it is then.
int thread_count_once_at_most(int n) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  int count = thread_count();
  while (count > n && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
    count = thread_count();
  }
  return count;
}

/// Per-chunk partial sums of 1/(i+1), reduced in chunk order.
double chunked_sum(int threads) {
  const std::int64_t n = 100003, grain = 1000;
  std::vector<double> partial(std::size_t(chunk_count(n, grain)), 0.0);
  parallel_for_chunks(n, grain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
    double s = 0.0;
    for (std::int64_t i = b; i < e; ++i) s += 1.0 / double(i + 1);
    partial[std::size_t(c)] = s;
  });
  double total = 0.0;
  for (double p : partial) total += p;
  return total;
}

}  // namespace

TEST(Parallel, ChunksDoNotDependOnTheThreadCount) {
  EXPECT_EQ(chunk_count(0, 10), 0);
  EXPECT_EQ(chunk_count(10, 10), 1);
  EXPECT_EQ(chunk_count(11, 10), 2);
  const double one = chunked_sum(1), two = chunked_sum(2);
  EXPECT_EQ(one, two);  // bit for bit
  // the harmonic number H_n = ln n + gamma + 1/(2n) - ..., within 1e-9
  EXPECT_NEAR(one, std::log(100003.0) + 0.5772156649015329 + 0.5 / 100003.0, 1e-9);
}

// It forks at most one thread per full chunk: less than two full chunks run on the calling
// thread, in chunk order; two full chunks fork two threads (each chunk waits for the other to
// start, so one thread alone could not finish).
TEST(Parallel, LessThanTwoFullChunksRunOnTheCallingThread) {
  const auto threads_used = [](std::int64_t n, std::int64_t grain) {
    std::vector<std::thread::id> who(std::size_t(chunk_count(n, grain)));
    std::vector<std::int64_t> order;
    parallel_for_chunks(n, grain, 2, [&](std::int64_t c, std::int64_t, std::int64_t) {
      who[std::size_t(c)] = std::this_thread::get_id();
#pragma omp critical
      order.push_back(c);
    });
    return std::make_pair(who, order);
  };
  // 1,138 items in chunks of 1,024: one full chunk and 114 items
  const auto [who, order] = threads_used(1138, 1024);
  ASSERT_EQ(who.size(), 2u);
  EXPECT_EQ(who[0], std::this_thread::get_id());
  EXPECT_EQ(who[1], std::this_thread::get_id());
  EXPECT_EQ(order, (std::vector<std::int64_t>{0, 1}));
  // 2,048: two full chunks on two threads, which meet inside the chunks
  std::atomic<int> arrived{0};
  std::vector<std::thread::id> two(2);
  parallel_for_chunks(2048, 1024, 2, [&](std::int64_t c, std::int64_t, std::int64_t) {
    two[std::size_t(c)] = std::this_thread::get_id();
    arrived.fetch_add(1);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    while (arrived.load() < 2 && std::chrono::steady_clock::now() < deadline) std::this_thread::yield();
  });
  EXPECT_EQ(arrived.load(), 2);
  EXPECT_NE(two[0], two[1]);
}

TEST(Parallel, ReleasingAThreadsWorkersEndsThem) {
#ifndef _LIBGOMP_OMP_LOCK_DEFINED
  GTEST_SKIP() << "not GNU OpenMP: another runtime's pause may keep its workers asleep";
#endif
  if (thread_count() < 0) GTEST_SKIP() << "no /proc/self/task";
  int before = 0, with_team = 0, after = 0;
  bool released = false;
  std::thread t([&] {
    before = thread_count();
    (void)chunked_sum(2);  // a team of 2: one idle worker after it
    with_team = thread_count();
    released = release_openmp_workers();
    after = thread_count_once_at_most(before);
  });
  t.join();
  EXPECT_EQ(with_team, before + 1);
  EXPECT_TRUE(released);
  EXPECT_EQ(after, before);
}

TEST(Parallel, AThreadThatLeavesTheWorkToOthersFormsNoTeamAgain) {
#ifndef _LIBGOMP_OMP_LOCK_DEFINED
  GTEST_SKIP() << "not GNU OpenMP: another runtime's pause may keep its workers asleep";
#endif
  if (thread_count() < 0) GTEST_SKIP() << "no /proc/self/task";
  int before = 0, after = 0, max_threads = 0, other_max_threads = 0;
  double one = 0.0, serial = 0.0;
  std::thread t([&] {
    before = thread_count();
    one = chunked_sum(2);  // a team of 2: one idle worker after it
    (void)leave_parallel_work_to_others();
    max_threads = omp_get_max_threads();
    (void)thread_count_once_at_most(before);
    serial = chunked_sum(0);  // the default thread count: this thread alone, no worker
    after = thread_count();
  });
  t.join();
  std::thread other([&] { other_max_threads = omp_get_max_threads(); });
  other.join();
  EXPECT_EQ(max_threads, 1);
  EXPECT_EQ(after, before);
  EXPECT_EQ(serial, one);  // the same sum, bit for bit
  // another thread keeps the default (the cores, or OMP_NUM_THREADS)
  EXPECT_EQ(other_max_threads, omp_get_max_threads());
}
