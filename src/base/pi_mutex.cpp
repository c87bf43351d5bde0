#include "base/pi_mutex.h"

#include <system_error>

namespace vx {

PiMutex::PiMutex() noexcept {
  pthread_mutexattr_t attr;
  pthread_mutexattr_init(&attr);
  inherits_ = pthread_mutexattr_setprotocol(&attr, PTHREAD_PRIO_INHERIT) == 0;
  if (pthread_mutex_init(&mutex_, &attr) != 0) {
    // the protocol accepted by the attribute but not by the kernel: an ordinary mutex
    inherits_ = false;
    pthread_mutex_init(&mutex_, nullptr);
  }
  pthread_mutexattr_destroy(&attr);
}

PiMutex::~PiMutex() { pthread_mutex_destroy(&mutex_); }

void PiMutex::lock() {
  if (const int e = pthread_mutex_lock(&mutex_); e != 0)
    throw std::system_error(e, std::generic_category(), "PiMutex::lock");
}

bool PiMutex::try_lock() noexcept { return pthread_mutex_trylock(&mutex_) == 0; }

void PiMutex::unlock() noexcept { pthread_mutex_unlock(&mutex_); }

}  // namespace vx
