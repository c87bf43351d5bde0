#pragma once
/// @file bench_parts.h
/// Private to evaluation/bench: the parts of `voxelastic bench` (bench.h) and what they share.
/// run_bench() (bench.cpp) runs part A, the cost of one step (bench_step_cost.cpp), and part B,
/// run time against error on the palpation scene (bench_palpation.cpp), whose runs are scored by
/// bench_metrics.cpp; bench_report.cpp writes the CSV, JSON and Markdown, bench_plots.cpp the
/// pictures.

#include <chrono>
#include <filesystem>
#include <functional>
#include <limits>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "bench/bench.h"

namespace vx::bench_parts {

using Clock = std::chrono::steady_clock;
/// Wall seconds since `t`.
[[nodiscard]] inline double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}
inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
/// A progress line (the settings' log, which may be empty).
using Log = std::function<void(const std::string&)>;

/// The integrators part B runs, in its order.
inline const std::vector<IntegratorKind> kIntegrators{IntegratorKind::explicit_euler,
                                                      IntegratorKind::symplectic_euler, IntegratorKind::implicit};

/// "12.3 s" (under 100 s), "123 s".
[[nodiscard]] std::string seconds_text(double s);
/// "0.5x" for explicit schemes (a fraction of the stable step), "" for implicit (NaN).
[[nodiscard]] std::string fraction_text(double f);
/// A fraction as "1.23 %", "-" when not finite.
[[nodiscard]] std::string pct(double v);
/// A signed fraction as "+1.2 %", "-" when not finite.
[[nodiscard]] std::string pct_signed(double v);
/// The lowest-error usable row of a layout (-1: none); `real_time_only` keeps those <= 1 s/s.
[[nodiscard]] int best_of(const std::vector<BenchRow>& rows, Layout layout, bool real_time_only);

/// Part A: the step benchmark on sphere phantoms for every layout, into res.step_rows (skipped
/// sizes as rows and notes) and the explicit step's log-log slopes.
void run_step_cost(const BenchSettings& set, BenchResult& res, const Log& log);
/// Part B: the reference run, then every size x layout x integrator x time step, scored against
/// it; the Pareto front and the best configuration for real time.
void run_palpation_part(const BenchSettings& set, BenchResult& res, const Log& log);

/// The pictures of a result (bench_plots.cpp); each throws vx::Error when a picture cannot be written.
void plot_step(const BenchResult& res, const std::filesystem::path& png);    ///< part A: step time and work against n
void plot_error(const BenchResult& res, const std::filesystem::path& png);   ///< part B: error against run time
void plot_cost(const BenchResult& res, const std::filesystem::path& png);    ///< part B: run time against n
void plot_curves(const BenchResult& res, const std::filesystem::path& png);  ///< part B: force curves

}  // namespace vx::bench_parts
