// The calling thread's name and nice value (util/thread_priority.h), read back from the system.
#include "util/thread_priority.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cerrno>
#include <string>
#include <thread>

#if defined(__linux__)
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif

namespace vx {
namespace {

TEST(ThreadName, NamesOnlyTheCallingThreadCutToFifteenCharacters) {
#if defined(__linux__)
  const std::string caller = this_thread_name();
  std::string named, cut;
  std::thread([&] {
    EXPECT_TRUE(set_this_thread_name("vx-physics"));
    named = this_thread_name();
    EXPECT_TRUE(set_this_thread_name("a-name-longer-than-fifteen"));
    cut = this_thread_name();
  }).join();
  EXPECT_EQ(named, "vx-physics");
  EXPECT_EQ(cut, "a-name-longer-t");
  EXPECT_EQ(this_thread_name(), caller);
#else
  GTEST_SKIP() << "threads are named on Linux only";
#endif
}

TEST(ThreadNice, LowersOnlyTheCallingThread) {
#if defined(__linux__)
  const auto nice_of_this_thread = [] {
    errno = 0;
    return getpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)));
  };
  const int caller = nice_of_this_thread();
  int inside = -100;
  std::thread([&] {
    EXPECT_TRUE(set_this_thread_nice(std::min(19, caller + 3)));
    inside = nice_of_this_thread();
  }).join();
  EXPECT_EQ(inside, std::min(19, caller + 3));
  EXPECT_EQ(nice_of_this_thread(), caller);
#else
  GTEST_SKIP() << "per-thread nice values are Linux only";
#endif
}

}  // namespace
}  // namespace vx
