#pragma once
/// @file system_memory.h
/// What the machine has: its physical memory, for readers that must refuse a volume before
/// allocating it (Linux overcommits, and touching pages it cannot back kills the process).

#include <cstdint>

namespace vx {

/// The machine's physical memory in bytes; 0 when the system does not say.
[[nodiscard]] std::uint64_t physical_memory_bytes();

}  // namespace vx
