#include "util/thread_priority.h"

#if defined(__linux__)
#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif

namespace vx {

bool set_this_thread_nice(int nice) {
#if defined(__linux__)
  // setpriority on a thread id: Linux keeps the nice value per thread
  return setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), nice) == 0;
#else
  (void)nice;
  return false;
#endif
}

bool set_this_thread_name(const std::string& name) {
#if defined(__linux__)
  return pthread_setname_np(pthread_self(), name.substr(0, 15).c_str()) == 0;
#else
  (void)name;
  return false;
#endif
}

std::string this_thread_name() {
#if defined(__linux__)
  char name[16] = {};
  if (pthread_getname_np(pthread_self(), name, sizeof name) == 0) return name;
#endif
  return {};
}

}  // namespace vx
