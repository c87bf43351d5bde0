#pragma once
/// @file triple_buffer.h
/// A lock-free hand-over from one thread to another: the newest value wins and neither side
/// ever waits (the simulation's local contact models for the device thread, sim/simulation.h;
/// the probe app's results between its threads).

#include <atomic>

namespace vx {

/// Single producer, single consumer, newest value wins: the producer fills write_buffer() and
/// publish()es; the consumer calls fetch() and reads read_buffer(). Neither blocks. The three
/// buffers are reused, so a T that keeps its capacity (vectors, Eigen arrays of a steady size)
/// is handed over without allocating.
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

}  // namespace vx
