#pragma once
/// @file display.h
/// VTK 9.1 on Debian renders through X11 only and segfaults without a display, so the app
/// checks for one before it creates any window.

#include <string>

namespace vx::probe {

/// Empty when an X display can be opened; otherwise what is missing and how to fix it.
[[nodiscard]] std::string display_problem();

}  // namespace vx::probe
