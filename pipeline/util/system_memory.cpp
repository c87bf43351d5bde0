#include "util/system_memory.h"

#include <unistd.h>

namespace vx {

std::uint64_t physical_memory_bytes() {
  const long pages = sysconf(_SC_PHYS_PAGES), page_bytes = sysconf(_SC_PAGESIZE);
  if (pages <= 0 || page_bytes <= 0) return 0;
  return std::uint64_t(pages) * std::uint64_t(page_bytes);
}

}  // namespace vx
