#pragma once
/// @file rate_thread.h
/// The timing scaffolding of the app: a thread that calls its body at a fixed rate (physics,
/// device), a rate meter for the HUD, and (base/triple_buffer.h) the lock-free triple buffer that
/// hands the newest result of one thread to another without either ever waiting for the other.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

#include "base/triple_buffer.h"

namespace vx::probe {

using SteadyClock = std::chrono::steady_clock;

/// Calls `body(tick)` every 1/rate_hz seconds on its own thread, against absolute deadlines
/// (no drift). When a tick is late by a whole period or more, the missed ticks are skipped
/// (counted, never replayed in a burst). An exception in the body stops the thread and is
/// kept as error(). `on_start` runs on the thread before its first tick (the app names its
/// threads there: util/thread_priority.h).
class FixedRateThread {
 public:
  using Body = std::function<void(std::int64_t tick)>;
  FixedRateThread(std::string name, double rate_hz, Body body, std::function<void()> on_start = {});
  ~FixedRateThread();
  FixedRateThread(const FixedRateThread&) = delete;
  FixedRateThread& operator=(const FixedRateThread&) = delete;

  void start();
  /// Asks the thread to stop and joins it (safe to call twice).
  void stop();

  [[nodiscard]] const std::string& name() const { return name_; }
  [[nodiscard]] double rate_hz() const { return rate_hz_; }
  /// Ticks run so far.
  [[nodiscard]] std::int64_t ticks() const { return ticks_.load(std::memory_order_relaxed); }
  /// Ticks skipped because the thread ran late.
  [[nodiscard]] std::int64_t missed() const { return missed_.load(std::memory_order_relaxed); }
  /// True once the body threw; error() says what.
  [[nodiscard]] bool failed() const { return failed_.load(); }
  [[nodiscard]] std::string error() const;

 private:
  void run();
  std::string name_;
  double rate_hz_;
  Body body_;
  std::function<void()> on_start_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<std::int64_t> ticks_{0};
  std::atomic<std::int64_t> missed_{0};
  std::atomic<bool> failed_{false};
  mutable std::mutex error_mutex_;
  std::string error_;
};

/// Turns a growing counter into a rate for the HUD: sample(count) from one reader thread; the
/// rate is updated over windows of at least `window_s`.
class RateMeter {
 public:
  explicit RateMeter(double window_s = 0.5) : window_s_(window_s) {}
  /// Feeds the counter's current value; returns the latest rate, per second.
  double sample(std::int64_t count, SteadyClock::time_point now = SteadyClock::now());
  [[nodiscard]] double rate() const { return rate_; }
  /// True once a full window has been measured.
  [[nodiscard]] bool valid() const { return valid_; }

 private:
  double window_s_;
  bool started_{false};
  bool valid_{false};
  std::int64_t count0_{0};
  SteadyClock::time_point t0_{};
  double rate_{0.0};
};

/// The lock-free hand-over (base/triple_buffer.h), shared with the core.
using vx::TripleBuffer;

}  // namespace vx::probe
