#include "soak.h"

#include <fmt/core.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <limits>

namespace vx::probe {

namespace {

/// One keyframe line: the axes of `stick` held from t (a repeated time makes a step).
std::string key(double t, int stick, double a0, double a1, double a2) {
  return fmt::format("{:.3f} {} {:.3f} {:.3f} {:.3f}\n", t, stick, a0, a1, a2);
}

}  // namespace

std::string make_soak_script(double duration_s, std::uint32_t seed, int sticks, const SoakMotion& motion) {
  std::mt19937 rng(seed);
  const auto uniform = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  sticks = std::clamp(sticks, 1, 2);
  // the tilt for a speed (rate control: speed * (a - dead zone) / (1 - dead zone))
  const double dz = std::clamp(motion.dead_zone, 0.0, 0.9);
  const auto tilt = [&](double v_mm_s) {
    return std::min(1.0, dz + (1.0 - dz) * std::abs(v_mm_s) / motion.speed_mm_s) * (v_mm_s < 0 ? -1.0 : 1.0);
  };
  std::string out = fmt::format("# soak: {:.0f} s, seed {}, {} stick(s) (voxelastic-probe --soak-s)\nsticks {}\n",
                                duration_s, seed, sticks, sticks);
  for (int s = 0; s < sticks; ++s) out += key(0.0, s, 0, 0, 0);
  // a move of one stick from t: axis values for `span` seconds, then zero
  const auto move = [&](int s, double t, double span, double ax, double ay) {
    out += key(t, s, ax, ay, 0) + key(t + span, s, ax, ay, 0) + key(t + span, s, 0, 0, 0);
  };
  double t = 3.0;
  const double end_episodes = duration_s - soak_rest_s(duration_s) - 2.0;
  while (true) {
    const bool grasp = sticks == 2 && uniform(0, 1) < 0.3;
    const double v = uniform(2.0, 6.0), depth = motion.gap_mm + uniform(1.0, 5.0), hold = uniform(0.2, 1.5);
    const double down_s = depth / v, vs = uniform(2.0, 6.0), slide = uniform(-8.0, 8.0);
    const double slide_s = std::abs(slide) / vs;
    const double span = 2.0 * down_s + 2.0 * slide_s + 2.0 * hold + 0.1;
    if (t + span > end_episodes) break;
    for (int s = 0; s < sticks; ++s) {
      // the screen's y: +1 (pulled back) moves the tool down
      double u = t;
      move(s, u, down_s, 0, tilt(v));
      u += down_s + hold;
      // out and back: a slide, or with two sticks a grasp (towards each other)
      const double vx = (grasp ? (s == 0 ? 1.0 : -1.0) : (slide < 0 ? -1.0 : 1.0)) * vs;
      move(s, u, slide_s, tilt(vx), 0);
      u += slide_s + 0.05;
      move(s, u, slide_s, tilt(-vx), 0);
      u += slide_s + hold;
      move(s, u, down_s, 0, -tilt(v));
    }
    t += span + uniform(0.3, 1.5);
  }
  // the release: every tool up 2 s more at 5 mm/s, then nothing until the end
  const double lift = std::max(t, end_episodes);
  for (int s = 0; s < sticks; ++s) {
    move(s, lift, 2.0, 0, -tilt(5.0));
    out += key(duration_s, s, 0, 0, 0);
  }
  return out;
}

std::int64_t resident_bytes() {
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0;
  long long pages = 0, resident = 0;
  const int n = std::fscanf(f, "%lld %lld", &pages, &resident);
  std::fclose(f);
  return n == 2 ? std::int64_t(resident) * std::int64_t(sysconf(_SC_PAGESIZE)) : 0;
}

double cpu_steal_s() {
  std::FILE* f = std::fopen("/proc/stat", "r");
  if (!f) return 0.0;
  // cpu  user nice system idle iowait irq softirq steal ...
  unsigned long long v[8] = {};
  const int n = std::fscanf(f, "cpu %llu %llu %llu %llu %llu %llu %llu %llu", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5],
                            &v[6], &v[7]);
  std::fclose(f);
  const long hz = sysconf(_SC_CLK_TCK);
  return n == 8 && hz > 0 ? double(v[7]) / double(hz) : 0.0;
}

void SoakMonitor::sample(double wall_s, std::int64_t device_ticks, double started_at_s, std::int64_t cache_bytes,
                         double quiet_from_s) {
  // the device's rate over each whole second (from the first second on)
  // (and the hypervisor's steal in each: read only where a window starts or ends)
  const auto open_window = [&] {
    window_start_s_ = wall_s;
    window_ticks_ = device_ticks;
    // (not read at every GUI pass of a start-up, only once the physics runs)
    window_steal_s_ = steal_s_ && started_at_s >= 0 ? steal_s_() : 0.0;
  };
  if (window_start_s_ < 0 || started_at_s < 0 || window_start_s_ < started_at_s) {
    // before the physics' first step (a start-up of seconds on an organ) the device plays
    // nothing: the windows count from then on
    open_window();
  } else if (wall_s - window_start_s_ >= 1.0) {
    const double window_s = wall_s - window_start_s_;
    const double rate = double(device_ticks - window_ticks_) / window_s;
    const double steal_before = window_steal_s_;
    open_window();
    const double steal = std::max(0.0, window_steal_s_ - steal_before);
    // the forces missing beyond those the machine's stop could have taken (1 per tick of steal)
    max_unexplained_ = std::max(max_unexplained_, device_hz_ - rate - device_hz_ * steal / window_s);
    if (windows_ == 0 || rate < min_rate_) {
      min_rate_ = rate;
      worst_steal_s_ = steal;
    }
    max_steal_s_ = std::max(max_steal_s_, steal);
    ++windows_;
  }
  // memory: once after the warm-up, then at the end (sampled at most 10 times a second)
  // (the warm-up counts from the physics' start, or from the end of the start-up's background
  // work if that is later: the region check holds a copy of the model until it ends, and a solver
  // built in the background is allocated when it is taken)
  if (started_at_s < 0 || quiet_from_s < 0 || (last_rss_s_ >= 0 && wall_s - last_rss_s_ < 0.1)) return;
  last_rss_s_ = wall_s;
  const std::int64_t rss = resident_bytes();
  if (warm_at_s_ < 0 && wall_s >= std::max(started_at_s, quiet_from_s) + warm_up_s_) {
    warm_bytes_ = rss;
    warm_cache_ = cache_bytes;
    warm_at_s_ = wall_s;
  }
  if (warm_at_s_ >= 0) {
    end_bytes_ = rss;
    end_cache_ = cache_bytes;
  }
}

}  // namespace vx::probe
