#pragma once
/// @file huge_pages.h
/// A hint for large arrays about to be filled: back them with huge pages (2 MB) where the system
/// can. Fresh memory costs per page on its first touch, and on a virtual machine that hands its
/// free memory back to the host that cost dominates a large model's start-up: 256 MB took 1.8
/// to 2.4 s to touch in 4 kB pages on the machine of docs/bench.md, 0.5 to 1.3 s when advised
/// first (its start-up section). Only a hint: the contents and every result stay the same.

#include <cstddef>

namespace vx {

/// Advises the kernel to back the whole 2 MB pages inside [data, data + bytes) with huge pages
/// (Linux: madvise MADV_HUGEPAGE; elsewhere, or for less than 4 MB, nothing). Call it before the
/// memory is first written (after a vector's reserve, an Eigen matrix's resize).
void prefer_huge_pages(const void* data, std::size_t bytes);

}  // namespace vx
