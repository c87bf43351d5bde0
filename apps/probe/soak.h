#pragma once
/// @file soak.h
/// A long scripted session (--soak-s S --seed N): a random joystick script of presses, holds,
/// slides and lifts (and, with two sticks, grasps: both tools pressed towards each other), then
/// a release and a rest; and what the run is judged by (SoakMonitor): non-finite values, resident
/// memory after the warm-up and at the end, device forces per second over each 1 s window, the
/// tissue back at rest after the release. docs/robustness.md, "Soak".

#include <cstdint>
#include <functional>
#include <random>
#include <string>

namespace vx::probe {

/// How the sticks move the tools (rate control) and how far the tissue is.
struct SoakMotion {
  double speed_mm_s{25.0};  ///< at full tilt
  double dead_zone{0.08};
  double gap_mm{3.0};  ///< from the tool down to the tissue at the start
};

/// The script's text (joystick_script.h format) for `duration_s` seconds of the device's clock:
/// 3 s at rest, random episodes, every tool lifted back to its start and 2 s more, then at rest
/// for soak_rest_s(). An episode: down through the gap and 1 to 5 mm into the tissue at
/// 2 to 6 mm/s, a hold, a slide of up to 8 mm (two sticks, 3 in 10 episodes: a grasp, both
/// towards each other) and back, a hold, up by as much as it went down, a pause.
[[nodiscard]] std::string make_soak_script(double duration_s, std::uint32_t seed, int sticks, const SoakMotion& motion);
/// The rest at the end of a soak's script, after the release (the tools lifted for 2 s), s of
/// the device's clock (wall time): 8 s, or 10 % of a longer soak. The session then goes on until
/// the tissue sleeps or its idle window has passed in simulated time since the release
/// (DeviceLoop::soak_settled: a tissue slower than real time gets its rest), and the tissue is
/// judged at the end.
[[nodiscard]] inline double soak_rest_s(double duration_s) { return duration_s < 80.0 ? 8.0 : 0.1 * duration_s; }

/// Resident memory of this process now, bytes (0 where /proc is not there).
[[nodiscard]] std::int64_t resident_bytes();

/// CPU time the hypervisor has taken from this machine's CPUs since boot ("steal", the eighth
/// figure of /proc/stat's `cpu` line), summed over the CPUs, s; 0 on bare metal or without /proc.
/// In a virtual machine a device tick can be late with no thread of ours in its way: the whole
/// guest does not run (docs/probe.md, "The device thread's late seconds").
[[nodiscard]] double cpu_steal_s();

/// The GUI thread's part of the judgement: memory and the device's rate per whole second.
class SoakMonitor {
 public:
  /// `warm_up_s`: memory is compared from this long after the physics' first step on.
  /// `steal_s`: reads the machine's steal so far, s (cpu_steal_s; a test passes its own).
  /// `device_hz`: the device's tick rate, the forces a second should have.
  explicit SoakMonitor(double warm_up_s, std::function<double()> steal_s = cpu_steal_s, double device_hz = 1000.0)
      : warm_up_s_(warm_up_s), steal_s_(std::move(steal_s)), device_hz_(device_hz) {}
  /// Called often (every GUI pass): wall time since the open, the device's ticks so far, the
  /// wall time the physics started at (< 0: not yet). The windows count from the physics' start.
  /// `cache_bytes`: the contact solver's bounded cache now (kept beside the resident memory).
  /// `quiet_from_s`: when the start-up's background work (the region check) ended, wall s (< 0:
  /// not yet); memory's warm-up counts from it when it is later than the physics' start.
  void sample(double wall_s, std::int64_t device_ticks, double started_at_s, std::int64_t cache_bytes = 0,
              double quiet_from_s = 0.0);
  [[nodiscard]] double min_forces_per_s() const { return min_rate_; }
  [[nodiscard]] int windows() const { return windows_; }
  /// The hypervisor's steal in the window of the fewest forces, and in the window that had the
  /// most, s of CPU time (summed over the CPUs).
  [[nodiscard]] double steal_in_worst_window_s() const { return worst_steal_s_; }
  [[nodiscard]] double max_window_steal_s() const { return max_steal_s_; }
  /// The most forces per second that any window lacked beyond what the hypervisor's steal in it
  /// can explain: device_hz - rate - device_hz * steal / window, at least 0. While the machine is
  /// stopped no thread of the guest runs, so a stop takes at most device_hz * its length forces;
  /// the steal is summed over the CPUs, so this counts the whole stop even where only the
  /// device's CPU stood still: it never credits the host with less than it took. It counts a
  /// stop of both CPUs of two twice, so in such a second it can excuse up to half of a shortfall
  /// that was ours. On bare metal the steal reads 0 and this is device_hz - min_forces_per_s().
  [[nodiscard]] double max_unexplained_shortfall_per_s() const { return max_unexplained_; }
  [[nodiscard]] std::int64_t warm_bytes() const { return warm_bytes_; }
  [[nodiscard]] std::int64_t end_bytes() const { return end_bytes_; }
  [[nodiscard]] double warm_at_s() const { return warm_at_s_; }
  [[nodiscard]] std::int64_t warm_cache_bytes() const { return warm_cache_; }
  [[nodiscard]] std::int64_t end_cache_bytes() const { return end_cache_; }

 private:
  double warm_up_s_;
  std::function<double()> steal_s_;
  double window_start_s_{-1.0};
  std::int64_t window_ticks_{0};
  double window_steal_s_{0.0};
  double device_hz_;
  double worst_steal_s_{0.0}, max_steal_s_{0.0}, max_unexplained_{0.0};
  double min_rate_{0.0};
  int windows_{0};
  std::int64_t warm_bytes_{0}, end_bytes_{0};
  std::int64_t warm_cache_{0}, end_cache_{0};
  double warm_at_s_{-1.0};
  double last_rss_s_{-1.0};
};

}  // namespace vx::probe
