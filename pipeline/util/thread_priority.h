#pragma once
/// @file thread_priority.h
/// The calling thread's scheduling priority (Linux: per thread, inherited by the threads it
/// creates afterwards). Used so the work a user is not waiting for (a display, a background
/// estimate) yields the CPU to the physics and the device, and the device's tick goes first.

#include <string>

namespace vx {

/// Sets the calling thread's nice value (-20 highest .. 19 lowest; below 0 needs privileges).
/// Returns false when the system refused (or on a system without per-thread priorities).
bool set_this_thread_nice(int nice);

/// Names the calling thread as `top -H`, `perf` and debuggers show it (Linux keeps 15
/// characters; a longer name is cut). Returns false where threads cannot be named.
bool set_this_thread_name(const std::string& name);

/// The calling thread's name ("" where threads have none).
std::string this_thread_name();

}  // namespace vx
