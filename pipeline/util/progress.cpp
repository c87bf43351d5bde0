#include "util/progress.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>

#include "util/log.h"

namespace vx {

Progress::Progress(std::string label, bool enabled)
    : label_(std::move(label)), enabled_(enabled && log::enabled(log::Level::info)), tty_(::isatty(STDERR_FILENO) != 0),
      start_(std::chrono::steady_clock::now()), last_draw_(start_) {}

Progress::~Progress() {
  if (enabled_ && !finished_ && tty_ && last_permille_ >= 0) std::fputc('\n', stderr);
}

void Progress::update(double fraction) {
  if (!enabled_ || finished_) return;
  fraction = std::clamp(fraction, 0.0, 1.0);
  const auto now = std::chrono::steady_clock::now();
  if (tty_) {
    const int permille = int(fraction * 1000);
    if (permille == last_permille_ || (now - last_draw_ < std::chrono::milliseconds(100) && permille < 1000)) return;
    last_permille_ = permille;
    last_draw_ = now;
    const int width = 30, filled = int(std::lround(fraction * width));
    std::fprintf(stderr, "\r%s [%.*s%*s] %5.1f%%", label_.c_str(), filled, "##############################",
                 width - filled, "", fraction * 100.0);
    std::fflush(stderr);
  } else {
    // not a terminal (a log, a pipe): lines only for work that has taken over a second
    if (now - start_ < std::chrono::seconds(1)) return;
    const int decile = int(fraction * 10);
    if (decile <= last_decile_) return;
    last_decile_ = decile;
    std::fprintf(stderr, "%s: %d%%\n", label_.c_str(), decile * 10);
  }
}

void Progress::done() {
  if (!enabled_ || finished_) return;
  finished_ = true;
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  if (tty_) std::fprintf(stderr, "\r%s done in %.2f s%*s\n", label_.c_str(), s, 30, "");
  else if (last_decile_ >= 0 || s >= 1.0)
    std::fprintf(stderr, "%s: done in %.2f s\n", label_.c_str(), s);
}

}  // namespace vx
