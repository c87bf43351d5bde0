#include "display.h"

#include <X11/Xlib.h>

#include <algorithm>
#include <cstdlib>
#include <string>

namespace vx::probe {

std::string display_problem() {
  const char* name = std::getenv("DISPLAY");
  if (!name || !*name)
    return "no display: DISPLAY is not set. The probe app needs an X display (VTK 9.1 renders through X11 only); "
           "run it on a desktop, or headless under a virtual display: xvfb-run -a -s \"-screen 0 1280x1024x24\" "
           "voxelastic-probe ...";
  Display* d = XOpenDisplay(nullptr);
  if (!d)
    return std::string("cannot open the X display '") + name +
           "' (is the X server running and may this user connect?). Headless: xvfb-run -a voxelastic-probe ...";
  // VTK renders through GLX; an X server without it would crash VTK at the first frame
  int opcode = 0, event = 0, error = 0;
  const bool glx = XQueryExtension(d, "GLX", &opcode, &event, &error);
  // kept open for the life of the process when it passes: an X server resets when its last
  // client leaves (Xvfb under xvfb-run does), and VTK aborts when its connection lands in the
  // reset (docs/robustness.md)
  if (!glx) XCloseDisplay(d);
  if (!glx)
    return std::string("the X display '") + name +
           "' has no OpenGL (GLX extension); run under xvfb-run (Xvfb provides GLX) or on a desktop with OpenGL";
  return {};
}

int limit_software_render_threads(int cores, int physics_threads) {
  const int leave = std::max(1, cores - std::max(0, physics_threads));
  (void)setenv("LP_NUM_THREADS", std::to_string(leave).c_str(), 0);
  const char* v = std::getenv("LP_NUM_THREADS");
  return v ? std::atoi(v) : 0;
}

}  // namespace vx::probe
