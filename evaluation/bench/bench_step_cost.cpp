// Part A of `voxelastic bench`: the cost of one step (step_benchmark.h) on sphere phantoms for
// every layout and integrator, models above the settings' sizes skipped (as rows and notes), and
// the log-log slope of the explicit step's time against the sphere size n.
#include <algorithm>
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <string>
#include <vector>

#include "bench/bench_parts.h"
#include "bench/step_benchmark.h"

namespace vx::bench_parts {

void run_step_cost(const BenchSettings& set, BenchResult& res, const Log& log) {
  struct Part {
    Layout r;
    int max_size, implicit_max;
  };
  const std::vector<Part> parts{{Layout::gradational, 1 << 30, set.step_implicit_max_size},
                                {Layout::uniform, set.step_uniform_max_size, set.step_implicit_uniform_max_size},
                                {Layout::voxel, set.step_voxel_max_size, set.step_implicit_voxel_max_size}};
  int k = 0;
  for (const Part& p : parts) {
    ++k;
    StepBenchmarkSettings ss;
    ss.layout = p.r;
    ss.element = set.scene.element;
    ss.threads = set.threads;
    ss.min_time_s = set.step_min_time_s;
    ss.implicit_max_size = p.implicit_max;
    ss.sizes.clear();
    for (int n : set.step_sizes)
      if (n <= p.max_size) ss.sizes.push_back(n);
    ss.log = [&](const std::string& line) { log("[step " + std::to_string(k) + "/3 " + to_string(p.r) + "] " + line); };
    log(fmt::format("[step {}/3] {} models, sphere sizes {}", k, to_string(p.r), fmt::join(ss.sizes, ", ")));
    const Clock::time_point t = Clock::now();
    std::vector<StepBenchmarkRow> rows;
    if (!ss.sizes.empty()) rows = run_step_benchmark(ss);
    for (int n : set.step_sizes) {
      if (n <= p.max_size) continue;
      for (IntegratorKind kind : ss.integrators) {
        StepBenchmarkRow row;
        row.size = n;
        row.integrator = kind;
        row.layout = p.r;
        row.threads = set.threads;
        row.skipped = true;
        row.note = fmt::format("{} models skipped above size {} (time and memory)", to_string(p.r), p.max_size);
        rows.push_back(row);
      }
      res.notes.push_back(fmt::format("step benchmark: the {} model of the {}^3 sphere was skipped (above size {}: time "
                                      "and memory)",
                                      to_string(p.r), n, p.max_size));
      log(res.notes.back());
    }
    for (const auto& row : rows)
      if (row.skipped && row.integrator == IntegratorKind::implicit && row.size <= p.max_size)
        res.notes.push_back(fmt::format("step benchmark: implicit on the {} model of the {}^3 sphere skipped (the "
                                        "factorisation above size {})",
                                        to_string(p.r), row.size, p.implicit_max));
    log(fmt::format("[step {}/3] {} done in {}", k, to_string(p.r), seconds_text(seconds_since(t))));
    res.step_rows.insert(res.step_rows.end(), rows.begin(), rows.end());
  }
  // the 2D row: the gradational 2D model of a disk as many pixels across as the largest sphere
  // (docs/model.md section 12), every integrator
  if (!set.step_sizes.empty()) {
    StepBenchmarkSettings ss;
    ss.layout = Layout::gradational;
    ss.dimensions = 2;
    ss.element = set.scene.element;
    ss.threads = set.threads;
    ss.min_time_s = set.step_min_time_s;
    ss.sizes = {*std::max_element(set.step_sizes.begin(), set.step_sizes.end())};
    ss.implicit_max_size = 1 << 30;  // a slice's factorisation is small
    ss.log = [&](const std::string& line) { log("[step 2D] " + line); };
    log(fmt::format("[step 2D] the gradational 2D model of a disk {} pixels across", ss.sizes.front()));
    const std::vector<StepBenchmarkRow> rows = run_step_benchmark(ss);
    res.step_rows.insert(res.step_rows.end(), rows.begin(), rows.end());
  }
  auto slope = [&](Layout r) {
    std::vector<double> x, y;
    for (const auto& row : res.step_rows)
      if (row.layout == r && row.dimensions == 3 && row.integrator == IntegratorKind::explicit_euler && !row.skipped &&
          row.step_s > 0) {
        x.push_back(row.size);
        y.push_back(row.step_s);
      }
    return log_log_slope(x, y);
  };
  res.step_slope_gradational = slope(Layout::gradational);
  res.step_slope_uniform = slope(Layout::uniform);
  res.step_slope_voxel = slope(Layout::voxel);
}

}  // namespace vx::bench_parts
