#pragma once
/// @file real_time_meter.h
/// The tissue's real-time factor and physics steps per second, both over ONE named interval:
/// simulated seconds advanced / wall seconds elapsed between two samples, as `bench` computes it.
///
/// The GUI thread feeds a sample per pass (the wall clock now; the simulated time the physics has
/// advanced so far, resets excluded; its steps so far) and asks for the figures over the last
/// `window_s` of wall time. A physics step that is still running counts as wall time without
/// simulated time (a 19 s step reads 0x while it runs, not the figure of the tick before). The
/// start-up (open to the physics' first completed step: the factorisation) is not a real-time
/// factor at all: the app feeds samples only after it (`StartupReport` words it).

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace vx::probe {

/// One reading: wall time (s, any fixed origin), simulated time advanced (s) and steps so far.
struct RateSample {
  double wall_s{0.0};
  double sim_s{0.0};
  std::int64_t steps{0};
};

/// The figures between two samples.
struct RateWindow {
  double wall_s{0.0};     ///< wall seconds elapsed
  double sim_s{0.0};      ///< simulated seconds advanced
  std::int64_t steps{0};  ///< physics steps made
  bool full{false};       ///< the samples span the whole window asked for
  /// Simulated over wall seconds (0 for an empty interval).
  [[nodiscard]] double factor() const { return wall_s > 0 ? sim_s / wall_s : 0.0; }
  [[nodiscard]] double steps_per_s() const { return wall_s > 0 ? double(steps) / wall_s : 0.0; }
};

/// The figures from sample `a` to the later sample `b`.
[[nodiscard]] RateWindow rate_between(const RateSample& a, const RateSample& b);

/// The last samples in a ring; the window ends at the newest sample.
class RealTimeMeter {
 public:
  /// Keeps at most `capacity` samples (at 60 passes/s, 4096 span about a minute).
  explicit RealTimeMeter(std::size_t capacity = 4096);
  /// Adds a sample; wall time must not go back (a sample that does is ignored).
  void add(const RateSample& s);
  /// Forgets every sample (a pause: the next window starts after it).
  void restart();
  /// Samples held.
  [[nodiscard]] std::size_t size() const { return count_; }
  /// From the newest sample back to the newest one at least `window_s` older (full), or to the
  /// oldest held when none is that old (not full). Empty (wall 0) with fewer than two samples.
  [[nodiscard]] RateWindow over_last(double window_s) const;

 private:
  [[nodiscard]] const RateSample& at(std::size_t age) const;  ///< 0: newest
  std::vector<RateSample> ring_;
  std::size_t next_{0};
  std::size_t count_{0};
};

/// The start-up: from the open (threads started) to the physics' first completed step.
/// Phrases for the HUD and the console.
struct StartupReport {
  /// "preparing the solver: 40 %" with a progress fraction in [0, 1], else
  /// "preparing the solver (3.2 s)".
  [[nodiscard]] static std::string preparing(double elapsed_s, std::optional<double> progress);
};

/// The line the HUD and the console show for the physics: while starting, the start-up; then
/// the steps per second and the factor over the last `window_s` of wall time, e.g.
/// "physics 34 steps/s (0.52x real time, last 1 s)"; `tissue`: "(tissue 0.52x real time, ...)".
/// Before the window spans any wall time (the display's first pass after the start-up) no rate is
/// given: "steps/s: measuring (tissue real time: measuring)", not a 0x of an empty interval.
[[nodiscard]] std::string describe_physics_rate(const RateWindow& w, double window_s, bool tissue);

}  // namespace vx::probe
