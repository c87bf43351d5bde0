// The lock-free triple buffer (base/triple_buffer.h): the newest value wins, a consumer never
// sees an older value after a newer one, and neither side waits.
#include "base/triple_buffer.h"

#include <gtest/gtest.h>

#include <atomic>
#include <thread>

using namespace vx;

TEST(TripleBuffer, NewestValueWinsAndNobodyWaits) {
  TripleBuffer<int> b;
  b.fill(0);
  EXPECT_FALSE(b.fetch());
  b.write_buffer() = 1;
  b.publish();
  b.write_buffer() = 2;
  b.publish();
  EXPECT_TRUE(b.fetch());
  EXPECT_EQ(b.read_buffer(), 2);
  EXPECT_FALSE(b.fetch());
  EXPECT_EQ(b.read_buffer(), 2);
  // a producer and a consumer hammering it: values only grow
  std::atomic<bool> done{false};
  std::thread producer([&] {
    for (int i = 3; i < 200000; ++i) {
      b.write_buffer() = i;
      b.publish();
    }
    done = true;
  });
  int last = 2;
  bool ordered = true;
  while (!done) {
    if (b.fetch()) {
      ordered = ordered && b.read_buffer() > last;
      last = b.read_buffer();
    }
  }
  producer.join();
  b.fetch();
  EXPECT_TRUE(ordered);
  EXPECT_EQ(b.read_buffer(), 199999);
}
