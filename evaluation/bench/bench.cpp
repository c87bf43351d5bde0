// `voxelastic bench` (bench.h): its settings, a row's status and label, and the run of the two
// parts (bench_parts.h).
#include "bench/bench.h"

#include <fmt/format.h>

#include <cmath>

#include "base/error.h"
#include "bench/bench_parts.h"

namespace vx {

using bench_parts::Clock;
using bench_parts::fraction_text;
using bench_parts::seconds_since;

const char* to_string(BenchStatus s) {
  switch (s) {
    case BenchStatus::ok: return "ok";
    case BenchStatus::unstable: return "unstable";
    case BenchStatus::skipped: return "skipped";
  }
  return "?";
}

bool BenchRow::usable() const {
  return status == BenchStatus::ok && std::isfinite(wall_per_sim_s) && std::isfinite(error.rms_rel);
}

std::string BenchRow::label() const {
  if (integrator == IntegratorKind::implicit)
    return fmt::format("n={} {} implicit dt={:g} ms", size, to_string(layout), time_step_s * 1e3);
  return fmt::format("n={} {} {} dt={} ({:.2e} s)", size, to_string(layout), to_string(integrator),
                     fraction_text(dt_fraction), time_step_s);
}

// --- settings -----------------------------------------------------------------------------

BenchSettings BenchSettings::quick_settings() {
  BenchSettings s;
  s.quick = true;
  s.step_sizes = {32, 64};
  s.step_uniform_max_size = 64;
  s.step_voxel_max_size = 64;
  s.step_implicit_max_size = 64;
  s.step_implicit_uniform_max_size = 32;
  s.step_implicit_voxel_max_size = 16;  // none: its factorisation takes 10 s at 32
  s.step_min_time_s = 0.2;
  s.sizes = {16, 24};
  s.explicit_fractions = {0.5, 1.0, 1.5};
  s.implicit_steps_s = {1e-3, 2e-3, 5e-3};
  s.reference_size = 32;
  s.max_run_s = 15.0;
  return s;
}

void BenchSettings::validate() const {
  if (threads < 1) throw Error(fmt::format("bench: threads must be >= 1 (got {})", threads));
  if (!run_step && !run_palpation) throw Error("bench: nothing to run (both parts are off)");
  if (run_step) {
    if (step_sizes.empty()) throw Error("bench: no step benchmark sizes");
    for (int n : step_sizes)
      if (n < 8 || n > 512) throw Error(fmt::format("bench: step benchmark size {} must be in 8..512", n));
    if (!(step_min_time_s >= 0)) throw Error("bench: step_min_time_s must be >= 0");
  }
  if (run_palpation) {
    if (sizes.empty()) throw Error("bench: no palpation sizes");
    for (int n : sizes)
      if (n < 8 || n > 256 || n % 2 != 0)
        throw Error(fmt::format("bench: palpation size {} must be even and in 8..256 (voxels across the block)", n));
    if (reference_size < 8 || reference_size > 256 || reference_size % 2 != 0)
      throw Error(fmt::format("bench: reference size {} must be even and in 8..256", reference_size));
    if (resolutions.empty()) throw Error("bench: no resolutions");
    for (double f : explicit_fractions)
      if (!(f > 0 && f <= 10)) throw Error(fmt::format("bench: time step fraction {} must be in (0, 10]", f));
    for (double dt : implicit_steps_s)
      if (!(dt > 0 && dt <= 0.05)) throw Error(fmt::format("bench: implicit time step {} s must be in (0, 0.05]", dt));
    if (!(reference_fraction > 0 && reference_fraction <= 1))
      throw Error("bench: the reference's time step fraction must be in (0, 1]");
    if (!(max_run_s > 0)) throw Error("bench: max_run_s must be > 0");
    if (implicit_iterations < 1) throw Error("bench: implicit_iterations must be >= 1");
    const PalpationSceneSettings& s = scene;
    if (!(s.depth_mm > 0 && s.depth_mm < s.height_mm && s.probe_radius_mm > 0 && s.press_s > 0 &&
          s.duration_s > s.press_s && s.force_interval_s > 0))
      throw Error("bench: the palpation scene's depth, radius and times are inconsistent");
  }
}

// --- the bench ----------------------------------------------------------------------------

BenchResult run_bench(const BenchSettings& set) {
  set.validate();
  const Clock::time_point t_all = Clock::now();
  const auto log = [&](const std::string& s) {
    if (set.log) set.log(s);
  };
  BenchResult res;
  res.settings = set;
  res.settings.log = nullptr;
  if (set.run_step) bench_parts::run_step_cost(set, res, log);
  if (set.run_palpation) bench_parts::run_palpation_part(set, res, log);
  res.total_s = seconds_since(t_all);
  return res;
}

}  // namespace vx
