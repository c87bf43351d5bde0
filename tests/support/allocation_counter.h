#pragma once
/// @file allocation_counter.h
/// Counts heap allocations through the global operator new (std::vector, std::string, ...),
/// for tests that check a step does not allocate. Include it in exactly one source file of a
/// test executable: it replaces the global operator new and delete.

#include <atomic>
#include <cstdlib>
#include <new>

namespace vx::testing {
inline std::atomic<long> g_allocations{0};
/// Heap allocations so far.
inline long allocations() { return g_allocations.load(); }
}  // namespace vx::testing

// noinline: when the replacement bodies are inlined into a caller, GCC 12 pairs the malloc and
// free it then sees with the new/delete expressions and warns (-Wmismatched-new-delete)
[[gnu::noinline]] void* operator new(std::size_t n) {
  ++vx::testing::g_allocations;
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
[[gnu::noinline]] void operator delete(void* p) noexcept { std::free(p); }
[[gnu::noinline]] void operator delete(void* p, std::size_t) noexcept { std::free(p); }
// the nothrow forms too (std::stable_sort's buffer): else a sanitizer's own nothrow new would be
// paired with the free above
[[gnu::noinline]] void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
  ++vx::testing::g_allocations;
  return std::malloc(n ? n : 1);
}
[[gnu::noinline]] void operator delete(void* p, const std::nothrow_t&) noexcept { std::free(p); }
