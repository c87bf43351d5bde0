#include "util/thread_priority.h"

#if defined(__linux__)
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

}  // namespace vx
