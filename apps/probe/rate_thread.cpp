#include "rate_thread.h"

#include <exception>

namespace vx::probe {

FixedRateThread::FixedRateThread(std::string name, double rate_hz, Body body, std::function<void()> on_start)
    : name_(std::move(name)),
      rate_hz_(rate_hz > 0 ? rate_hz : 1.0),
      body_(std::move(body)),
      on_start_(std::move(on_start)) {}

FixedRateThread::~FixedRateThread() { stop(); }

void FixedRateThread::start() {
  if (thread_.joinable()) return;
  stop_.store(false);
  thread_ = std::thread([this] { run(); });
}

void FixedRateThread::stop() {
  stop_.store(true);
  if (thread_.joinable()) thread_.join();
}

std::string FixedRateThread::error() const {
  std::lock_guard lock(error_mutex_);
  return error_;
}

void FixedRateThread::run() {
  if (on_start_) on_start_();
  const auto period = std::chrono::duration_cast<SteadyClock::duration>(std::chrono::duration<double>(1.0 / rate_hz_));
  auto next = SteadyClock::now();
  std::int64_t tick = 0;
  while (!stop_.load(std::memory_order_relaxed)) {
    try {
      body_(tick);
    } catch (const std::exception& e) {
      std::lock_guard lock(error_mutex_);
      error_ = name_ + " thread: " + e.what();
      failed_.store(true);
      return;
    } catch (...) {
      std::lock_guard lock(error_mutex_);
      error_ = name_ + " thread: unknown error";
      failed_.store(true);
      return;
    }
    ++tick;
    ticks_.store(tick, std::memory_order_relaxed);
    // the next absolute deadline; when a whole period late, skip ahead instead of bursting
    next += period;
    const auto now = SteadyClock::now();
    if (now - next >= period) {
      const auto late = (now - next) / period;
      missed_.fetch_add(std::int64_t(late), std::memory_order_relaxed);
      next += late * period;
    }
    std::this_thread::sleep_until(next);
  }
}

double RateMeter::sample(std::int64_t count, SteadyClock::time_point now) {
  if (!started_) {
    started_ = true;
    count0_ = count;
    t0_ = now;
    return rate_;
  }
  const double dt = std::chrono::duration<double>(now - t0_).count();
  if (dt >= window_s_) {
    rate_ = double(count - count0_) / dt;
    valid_ = true;
    count0_ = count;
    t0_ = now;
  }
  return rate_;
}

}  // namespace vx::probe
