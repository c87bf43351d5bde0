#pragma once
/// @file display.h
/// VTK 9.1 on Debian renders through X11 only and segfaults without a display, so the app
/// checks for one before it creates any window.

#include <string>

namespace vx::probe {

/// Empty when an X display can be opened; otherwise what is missing and how to fix it.
[[nodiscard]] std::string display_problem();

/// Sets LP_NUM_THREADS, the threads a software OpenGL renderer (Mesa's llvmpipe: Xvfb, a machine
/// without a GPU) rasterises on, to the cores the physics' `physics_threads` leave, at least one,
/// for the renderer loaded after it; unless it is set already (the user's choice is kept). By
/// default llvmpipe takes one per core, and on the physics' cores its threads stall the physics'
/// OpenMP team at every barrier (docs/probe.md, "The right-hand side over the closure only, then
/// the software renderer off the physics' cores"). Returns the value in force (0: not a number).
int limit_software_render_threads(int cores, int physics_threads);

}  // namespace vx::probe
