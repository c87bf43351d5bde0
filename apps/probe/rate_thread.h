#pragma once
/// @file rate_thread.h
/// The timing scaffolding of the app: a thread that calls its body at a fixed rate (physics,
/// device), a rate meter for the HUD, and a lock-free triple buffer that hands the newest
/// result of one thread to another without either ever waiting for the other.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

namespace vx::probe {

using SteadyClock = std::chrono::steady_clock;

/// Calls `body(tick)` every 1/rate_hz seconds on its own thread, against absolute deadlines
/// (no drift). When a tick is late by a whole period or more, the missed ticks are skipped
/// (counted, never replayed in a burst). An exception in the body stops the thread and is
/// kept as error().
class FixedRateThread {
 public:
  using Body = std::function<void(std::int64_t tick)>;
  FixedRateThread(std::string name, double rate_hz, Body body);
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

/// Single producer, single consumer, newest value wins: the producer fills write_buffer() and
/// publish()es; the consumer calls fetch() and reads read_buffer(). Neither blocks.
template <class T>
class TripleBuffer {
 public:
  /// The producer's buffer (only the producer touches it until publish()).
  T& write_buffer() { return buffers_[back_]; }
  /// Makes the write buffer the newest value.
  void publish() {
    const int old = state_.exchange(back_ | kFresh, std::memory_order_acq_rel);
    back_ = old & kIndex;
  }
  /// Takes the newest published value if there is one; returns true when it is new.
  bool fetch() {
    if (!(state_.load(std::memory_order_relaxed) & kFresh)) return false;
    const int old = state_.exchange(front_, std::memory_order_acq_rel);
    front_ = old & kIndex;
    return true;
  }
  /// The consumer's buffer (the newest value fetched).
  const T& read_buffer() const { return buffers_[front_]; }
  T& read_buffer() { return buffers_[front_]; }
  /// Sets all three buffers (before the threads start).
  void fill(const T& value) {
    for (auto& b : buffers_) b = value;
  }

 private:
  static constexpr int kIndex = 3;
  static constexpr int kFresh = 4;
  T buffers_[3]{};
  int back_{0};
  int front_{1};
  std::atomic<int> state_{2};
};

}  // namespace vx::probe
