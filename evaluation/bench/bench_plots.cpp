// The pictures of `voxelastic bench` (render/plot.h): part A's step time and
// work against the sphere size, part B's error against run time, run time against size, and the
// force curves of the best runs against the reference. Every layout keeps one colour, every
// integrator one point type.
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <string>

#include "bench/bench_parts.h"
#include "render/plot.h"

namespace vx::bench_parts {
namespace fs = std::filesystem;
namespace {

/// The colour of a resolution in every plot.
const char* resolution_color(Layout r) {
  switch (r) {
    case Layout::gradational: return "#1f77b4";
    case Layout::uniform: return "#2ca02c";
    case Layout::voxel: return "#d62728";
  }
  return "black";
}

/// A shade of a resolution's colour for size number `i` of `count` (light: small, dark: large).
std::string resolution_shade(Layout r, std::size_t i, std::size_t count) {
  // light and dark ends per resolution (ColorBrewer blues, greens, reds)
  static const int light[3][3] = {{0x9e, 0xca, 0xe1}, {0xa1, 0xd9, 0x9b}, {0xfc, 0x92, 0x72}};
  static const int dark[3][3] = {{0x08, 0x30, 0x6b}, {0x00, 0x44, 0x1b}, {0x67, 0x00, 0x0d}};
  const int k = int(r);
  const double w = count > 1 ? double(i) / double(count - 1) : 0.6;
  int c[3];
  for (int a = 0; a < 3; ++a) c[a] = int(std::lround(light[k][a] + w * (dark[k][a] - light[k][a])));
  return fmt::format("#{:02x}{:02x}{:02x}", c[0], c[1], c[2]);
}

/// The point type of an integrator in every plot.
int integrator_point(IntegratorKind k) {
  switch (k) {
    case IntegratorKind::explicit_euler: return 9;     // triangle
    case IntegratorKind::symplectic_euler: return 13;  // diamond
    case IntegratorKind::implicit: return 5;           // square
  }
  return 7;
}

/// An integrator's name for plots, in plain words.
const char* integrator_title(IntegratorKind k) {
  switch (k) {
    case IntegratorKind::explicit_euler: return "explicit Euler";
    case IntegratorKind::symplectic_euler: return "symplectic Euler";
    case IntegratorKind::implicit: return "implicit";
  }
  return "?";
}

/// A reference slope c n^p through (x0, y0) over [x0, x1].
PlotSeries slope_line(const std::string& title, double p, double x0, double y0, double x1) {
  PlotSeries s;
  s.title = title;
  s.dash_type = 2;
  s.color = "gray40";
  s.line_width = 1.2;
  for (int i = 0; i <= 16; ++i) {
    const double x = x0 * std::pow(x1 / x0, i / 16.0);
    s.x.push_back(x);
    s.y.push_back(y0 * std::pow(x / x0, p));
  }
  return s;
}

}  // namespace

void plot_step(const BenchResult& res, const fs::path& png) {
  PlotPanel time, work;
  time.title = fmt::format("One step against model size (sphere phantoms, {} thread(s))", res.settings.threads);
  time.xlabel = "sphere size n (voxels across)";
  time.ylabel = "wall time per step (ms)";
  time.log_x = time.log_y = true;
  work.title = "Work of one step: vertex entries (summed over elements)";
  work.xlabel = "sphere size n (voxels across)";
  work.ylabel = "vertex entries";
  work.log_x = work.log_y = true;
  time.key = work.key = "bottom right";
  double nmin = 1e30, nmax = 0;
  for (const auto& r : res.step_rows) {
    nmin = std::min(nmin, double(r.size));
    nmax = std::max(nmax, double(r.size));
  }
  double anchor2 = 0, anchor3 = 0, entries2 = 0, entries3 = 0;
  for (Layout r : {Layout::gradational, Layout::uniform, Layout::voxel})
    for (IntegratorKind k : {IntegratorKind::explicit_euler, IntegratorKind::implicit}) {
      PlotSeries s;
      s.title = fmt::format("{}, {}", to_string(r), integrator_title(k));
      s.with_points = true;
      s.color = resolution_color(r);
      s.point_type = integrator_point(k);
      s.dash_type = k == IntegratorKind::implicit ? 2 : 0;
      PlotSeries w;
      w.title = to_string(r);
      w.with_points = true;
      w.color = resolution_color(r);
      for (const auto& row : res.step_rows) {
        if (row.layout != r || row.integrator != k || row.skipped || row.dimensions != 3) continue;
        s.x.push_back(row.size);
        s.y.push_back(row.step_s * 1e3);
        w.x.push_back(row.size);
        w.y.push_back(double(row.vertex_entries));
        if (k == IntegratorKind::explicit_euler && row.size == nmin) {
          if (r == Layout::gradational) anchor2 = row.step_s * 1e3, entries2 = double(row.vertex_entries);
          if (r == Layout::voxel) anchor3 = row.step_s * 1e3, entries3 = double(row.vertex_entries);
        }
      }
      if (!s.x.empty()) time.series.push_back(s);
      if (k == IntegratorKind::explicit_euler && !w.x.empty()) work.series.push_back(w);
    }
  time.xrange = work.xrange = fmt::format("[{}:{}]", nmin / 1.25, nmax * 1.25);
  if (nmax > nmin) {
    if (anchor2 > 0) time.series.push_back(slope_line("n^{2}", 2, nmin, anchor2 * 0.7, nmax));
    if (anchor3 > 0) time.series.push_back(slope_line("n^{3}", 3, nmin, anchor3 * 1.4, nmax));
    if (entries2 > 0) work.series.push_back(slope_line("n^{2}", 2, nmin, entries2 * 0.7, nmax));
    if (entries3 > 0) work.series.push_back(slope_line("n^{3}", 3, nmin, entries3 * 1.4, nmax));
  }
  plot_png({time, work}, png, 900, 460);
}

void plot_error(const BenchResult& res, const fs::path& png) {
  PlotPanel p;
  p.title = fmt::format("Run time against error: palpation scene, reference voxel-level n = {} ({} thread(s))",
                        res.reference.size, res.settings.threads);
  p.xlabel = "wall time per simulated second (s/s, log; left of 1 = faster than real time)";
  p.ylabel = "RMS force error (% of the reference peak, log)";
  p.log_x = p.log_y = true;
  p.key = "outside right top";
  double ymin = 1e30, ymax = 0;
  const std::vector<int>& sizes = res.settings.sizes;
  for (Layout r : res.settings.resolutions)
    for (std::size_t si = 0; si < sizes.size(); ++si)
      for (IntegratorKind k : kIntegrators) {
        PlotSeries s;
        s.title = fmt::format("{} n={}, {}", to_string(r), sizes[si], integrator_title(k));
        s.points = true;
        s.color = resolution_shade(r, si, sizes.size());
        s.point_type = integrator_point(k);
        for (const auto& row : res.rows)
          if (row.layout == r && row.size == sizes[si] && row.integrator == k && row.usable()) {
            s.x.push_back(row.wall_per_sim_s);
            s.y.push_back(100 * row.error.rms_rel);
            if (row.error.rms_rel > 0) ymin = std::min(ymin, 100 * row.error.rms_rel);
            ymax = std::max(ymax, 100 * row.error.rms_rel);
          }
        if (!s.x.empty()) p.series.push_back(s);
      }
  double wmin = 1.0, wmax = 1.0;
  for (const auto& row : res.rows)
    if (row.usable()) {
      wmin = std::min(wmin, row.wall_per_sim_s);
      wmax = std::max(wmax, row.wall_per_sim_s);
    }
  p.xrange = fmt::format("[{}:{}]", wmin / 1.5, wmax * 1.5);
  PlotSeries front;
  front.title = "Pareto front";
  front.color = "black";
  front.line_width = 1.2;
  for (std::size_t i : res.pareto) {
    front.x.push_back(res.rows[i].wall_per_sim_s);
    front.y.push_back(100 * res.rows[i].error.rms_rel);
  }
  if (!front.x.empty()) p.series.push_back(front);
  if (ymax > 0) {
    PlotSeries rt;
    rt.title = "real time (1 s per s)";
    rt.color = "orange";
    rt.dash_type = 2;
    rt.line_width = 2;
    rt.x = {1.0, 1.0};
    rt.y = {ymin * 0.7, ymax * 1.4};
    p.series.push_back(rt);
  }
  if (res.best >= 0) {
    PlotSeries b;
    b.title = "best for real time";
    b.points = true;
    b.point_type = 6;  // open circle, around the best point
    b.color = "black";
    b.x = {res.rows[std::size_t(res.best)].wall_per_sim_s};
    b.y = {100 * res.rows[std::size_t(res.best)].error.rms_rel};
    p.series.push_back(b);
  }
  plot_png({p}, png, 1150, 700);
}

void plot_cost(const BenchResult& res, const fs::path& png) {
  PlotPanel p;
  p.title = fmt::format("Palpation: wall time per simulated second against model size ({} thread(s))",
                        res.settings.threads);
  p.xlabel = "n (voxels across the block, log)";
  p.ylabel = "wall time per simulated second (s/s, log)";
  p.log_x = p.log_y = true;
  p.key = "outside right top";
  double nmin = 1e30, nmax = 0, lo = 1e30, hi = 0;
  for (Layout r : res.settings.resolutions) {
    // symplectic Euler at its stable estimate, and implicit at its smallest step
    const double implicit_dt = res.settings.implicit_steps_s.empty()
                                   ? 0.0
                                   : *std::min_element(res.settings.implicit_steps_s.begin(), res.settings.implicit_steps_s.end());
    PlotSeries se, im;
    se.title = fmt::format("{}, symplectic Euler 1x", to_string(r));
    im.title = fmt::format("{}, implicit {:g} ms", to_string(r), implicit_dt * 1e3);
    se.with_points = im.with_points = true;
    se.color = im.color = resolution_color(r);
    se.point_type = integrator_point(IntegratorKind::symplectic_euler);
    im.point_type = integrator_point(IntegratorKind::implicit);
    im.dash_type = 2;
    for (const auto& row : res.rows) {
      if (row.layout != r || !std::isfinite(row.wall_per_sim_s) || row.status != BenchStatus::ok) continue;
      PlotSeries* s = nullptr;
      if (row.integrator == IntegratorKind::symplectic_euler && std::abs(row.dt_fraction - 1.0) < 1e-9) s = &se;
      if (row.integrator == IntegratorKind::implicit && std::abs(row.time_step_s - implicit_dt) < 1e-12) s = &im;
      if (!s) continue;
      s->x.push_back(row.size);
      s->y.push_back(row.wall_per_sim_s);
      nmin = std::min(nmin, double(row.size));
      nmax = std::max(nmax, double(row.size));
      lo = std::min(lo, row.wall_per_sim_s);
      hi = std::max(hi, row.wall_per_sim_s);
    }
    if (!se.x.empty()) p.series.push_back(se);
    if (!im.x.empty()) p.series.push_back(im);
  }
  if (nmax > 0) {
    p.xrange = fmt::format("[{}:{}]", nmin / 1.25, nmax * 1.25);
    PlotSeries rt;
    rt.title = "real time (1 s per s)";
    rt.color = "orange";
    rt.dash_type = 2;
    rt.line_width = 2;
    rt.x = {nmin / 1.25, nmax * 1.25};
    rt.y = {1.0, 1.0};
    p.series.push_back(rt);
  }
  if (nmax > nmin) {
    // a step costs ~n^2 (gradational) or ~n^3 (voxel-level) and the stable step shrinks like 1/n
    p.series.push_back(slope_line("n^{3} (step cost n^{2}, time step 1/n)", 3, nmin, lo, nmax));
    p.series.push_back(slope_line("n^{4} (step cost n^{3}, time step 1/n)", 4, nmin, lo * 3, nmax));
  }
  plot_png({p}, png, 1100, 560);
}

void plot_curves(const BenchResult& res, const fs::path& png) {
  PlotPanel p;
  p.title = "Probe force against time";
  p.xlabel = "time (s)";
  p.ylabel = "force on the probe, +z (N)";
  p.key = "top right";
  p.xrange = fmt::format("[0:{}]", 1.7 * res.settings.scene.duration_s);
  PlotSeries ref;
  ref.title = fmt::format("reference: voxel n={}, symplectic Euler {:.1e} s", res.reference.size,
                          res.reference.time_step_s);
  ref.color = "black";
  ref.line_width = 3;
  ref.x = res.reference.curve.time_s;
  ref.y = res.reference.curve.force_n;
  p.series.push_back(ref);
  std::set<int> shown;
  auto add = [&](int i, const std::string& prefix, int dash) {
    if (i < 0 || shown.count(i)) return;
    shown.insert(i);
    const BenchRow& r = res.rows[std::size_t(i)];
    PlotSeries s;
    const std::string dt = r.integrator == IntegratorKind::implicit ? fmt::format("{:g} ms", r.time_step_s * 1e3)
                                                                    : fraction_text(r.dt_fraction);
    s.title = fmt::format("{}n={} {} {} {}: {}", prefix, r.size, to_string(r.layout), integrator_title(r.integrator),
                          dt, pct(r.error.rms_rel));
    s.color = resolution_color(r.layout);
    s.dash_type = dash;
    s.x = r.curve.time_s;
    s.y = r.curve.force_n;
    p.series.push_back(s);
  };
  add(res.best, "best for real time: ", 0);
  for (Layout r : res.settings.resolutions) add(best_of(res.rows, r, false), "most accurate: ", 2);
  plot_png({p}, png, 1000, 520);
}

}  // namespace vx::bench_parts
