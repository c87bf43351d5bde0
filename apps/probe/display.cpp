#include "display.h"

#include <X11/Xlib.h>

#include <cstdlib>

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
  XCloseDisplay(d);
  return {};
}

}  // namespace vx::probe
