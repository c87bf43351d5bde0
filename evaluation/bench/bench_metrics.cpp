// Scoring the runs of `voxelastic bench` (bench.h): a force curve against the reference, the
// Pareto front of error against run time, the best configuration for real time, and log-log
// slopes of cost against size.
#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "base/error.h"
#include "bench/bench.h"
#include "bench/bench_parts.h"

namespace vx {

using bench_parts::kNaN;

double peak_force_n(const ForceCurve& curve) {
  double peak = 0.0;
  for (double f : curve.force_n) peak = std::max(peak, f);
  return peak;
}

CurveError force_curve_error(const ForceCurve& curve, const ForceCurve& ref) {
  if (curve.time_s.empty() || ref.time_s.empty()) throw Error("force curve error: an empty curve");
  if (curve.time_s.size() != curve.force_n.size() || ref.time_s.size() != ref.force_n.size())
    throw Error("force curve error: times and forces differ in length");
  const double ref_peak = peak_force_n(ref);
  if (!(ref_peak > 0)) throw Error("force curve error: the reference has no positive force");
  // linear interpolation of `curve` at time t, held beyond its ends (its times increase)
  std::size_t j = 0;
  auto at = [&](double t) {
    const auto& x = curve.time_s;
    const auto& y = curve.force_n;
    if (t <= x.front()) return y.front();
    if (t >= x.back()) return y.back();
    while (j + 1 < x.size() && x[j + 1] < t) ++j;
    const double w = x[j + 1] > x[j] ? (t - x[j]) / (x[j + 1] - x[j]) : 1.0;
    return y[j] + w * (y[j + 1] - y[j]);
  };
  double sum2 = 0.0, max_abs = 0.0;
  for (std::size_t i = 0; i < ref.time_s.size(); ++i) {
    const double d = at(ref.time_s[i]) - ref.force_n[i];
    sum2 += d * d;
    max_abs = std::max(max_abs, std::abs(d));
  }
  CurveError e;
  e.rms_rel = std::sqrt(sum2 / double(ref.time_s.size())) / ref_peak;
  e.max_abs_rel = max_abs / ref_peak;
  e.peak_rel = (peak_force_n(curve) - ref_peak) / ref_peak;
  return e;
}

std::vector<std::size_t> mark_pareto_front(std::vector<BenchRow>& rows) {
  std::vector<std::size_t> front;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    rows[i].pareto = false;
    if (!rows[i].usable()) continue;
    const double wi = rows[i].wall_per_sim_s, ei = rows[i].error.rms_rel;
    bool dominated = false;
    for (std::size_t j = 0; j < rows.size() && !dominated; ++j) {
      if (j == i || !rows[j].usable()) continue;
      const double wj = rows[j].wall_per_sim_s, ej = rows[j].error.rms_rel;
      dominated = wj <= wi && ej <= ei && (wj < wi || ej < ei);
    }
    if (!dominated) {
      rows[i].pareto = true;
      front.push_back(i);
    }
  }
  std::sort(front.begin(), front.end(), [&](std::size_t a, std::size_t b) {
    return rows[a].wall_per_sim_s < rows[b].wall_per_sim_s ||
           (rows[a].wall_per_sim_s == rows[b].wall_per_sim_s && rows[a].error.rms_rel < rows[b].error.rms_rel);
  });
  return front;
}

int best_real_time_row(const std::vector<BenchRow>& rows, bool& real_time, double limit) {
  int best = -1, fastest = -1;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const BenchRow& r = rows[i];
    if (!r.usable()) continue;
    if (fastest < 0 || r.wall_per_sim_s < rows[std::size_t(fastest)].wall_per_sim_s) fastest = int(i);
    if (r.wall_per_sim_s > limit) continue;
    if (best < 0) {
      best = int(i);
      continue;
    }
    const BenchRow& b = rows[std::size_t(best)];
    if (r.error.rms_rel < b.error.rms_rel || (r.error.rms_rel == b.error.rms_rel && r.wall_per_sim_s < b.wall_per_sim_s))
      best = int(i);
  }
  real_time = best >= 0;
  return best >= 0 ? best : fastest;
}

double log_log_slope(const std::vector<double>& x, const std::vector<double>& y) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int k = 0;
  for (std::size_t i = 0; i < x.size() && i < y.size(); ++i) {
    if (!(x[i] > 0) || !(y[i] > 0) || !std::isfinite(x[i]) || !std::isfinite(y[i])) continue;
    const double lx = std::log(x[i]), ly = std::log(y[i]);
    sx += lx;
    sy += ly;
    sxx += lx * lx;
    sxy += lx * ly;
    ++k;
  }
  if (k < 2) return kNaN;
  const double d = k * sxx - sx * sx;
  return std::abs(d) > 1e-300 ? (k * sxy - sx * sy) / d : kNaN;
}

int bench_parts::best_of(const std::vector<BenchRow>& rows, Layout layout, bool real_time_only) {
  int best = -1;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const BenchRow& r = rows[i];
    if (r.layout != layout || !r.usable() || (real_time_only && r.wall_per_sim_s > 1.0)) continue;
    if (best < 0 || r.error.rms_rel < rows[std::size_t(best)].error.rms_rel) best = int(i);
  }
  return best;
}

}  // namespace vx
