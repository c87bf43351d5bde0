#pragma once
/// @file pi_mutex.h
/// A mutex with priority inheritance, for the locks that a real-time thread shares with ordinary
/// ones (the probe app's 1 kHz device thread at SCHED_FIFO against the physics and the GUI).
///
/// With a plain mutex, a real-time thread that wants a lock held by an ordinary thread waits
/// until the scheduler gives the holder a core again: on a busy machine (other threads of the
/// physics, the display, other programs) that can take tens of milliseconds, the classic priority
/// inversion. With PTHREAD_PRIO_INHERIT the kernel lends the holder the waiter's priority until it
/// lets go, so the wait is only the holder's own time under the lock. Uncontended, it locks and
/// unlocks in user space like std::mutex (an atomic on the owner's thread id).
///
/// Where the protocol is not supported, it is an ordinary mutex (`inherits_priority()` says so).
/// A BasicLockable and Lockable: use it with std::lock_guard and std::unique_lock.

#include <pthread.h>

namespace vx {

class PiMutex {
 public:
  PiMutex() noexcept;
  ~PiMutex();
  PiMutex(const PiMutex&) = delete;
  PiMutex& operator=(const PiMutex&) = delete;

  /// Throws std::system_error if the lock cannot be taken (a deadlock the kernel detects).
  void lock();
  [[nodiscard]] bool try_lock() noexcept;
  void unlock() noexcept;

  /// Whether the holder inherits a waiter's priority (false: the protocol was refused).
  [[nodiscard]] bool inherits_priority() const noexcept { return inherits_; }

 private:
  pthread_mutex_t mutex_;
  bool inherits_{false};
};

}  // namespace vx
