#include "bench/haptic_accuracy.h"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "base/error.h"
#include "haptics/device_force.h"
#include "haptics/device_side.h"
#include "haptics/local_contact.h"
#include "render/plot.h"
#include "scene/scene.h"
#include "sim/simulation.h"

namespace vx {

namespace {

/// The demo's tissue and tool, the scripted path, the settings every run starts from.
struct Setup {
  PreparedScene prep;
  std::vector<PathKey> path;
  double duration_s{0.0};
};

Setup make_setup(const HapticAccuracySettings& hs) {
  Setup s;
  s.prep = prepare_scene(load_scene(hs.scene));
  if (s.prep.settings.probes.empty()) throw Error("haptic accuracy: the scene has no probe");
  const ProbeSettings& probe = s.prep.settings.probes[0];
  const Eigen::Vector3d start = probe.initial_position();
  const double r = probe.geometry.radius_mm;
  const double top = s.prep.bounds_max_mm.z();
  const Eigen::Vector3d above(start.x(), start.y(), top + r + 0.5), down(start.x(), start.y(), top + r - hs.depth_mm);
  const Eigen::Vector3d across = down + Eigen::Vector3d(hs.slide_mm, 0, 0);
  const Eigen::Vector3d lifted(across.x(), across.y(), above.z());
  double t = 0.0;
  s.path.push_back({t, above});
  t += 0.1;
  s.path.push_back({t, above});
  t += (above - down).norm() / hs.press_mm_s;
  s.path.push_back({t, down});
  t += 0.3;
  s.path.push_back({t, down});
  t += hs.slide_mm / hs.slide_mm_s;
  s.path.push_back({t, across});
  t += 0.2;
  s.path.push_back({t, across});
  t += (above - down).norm() / hs.press_mm_s;
  s.path.push_back({t, lifted});
  t += 0.1;
  s.path.push_back({t, lifted});
  s.duration_s = t;
  return s;
}

SimulationSettings make_settings(const Setup& s, const HapticAccuracySettings& hs, double dt) {
  SimulationSettings set = s.prep.settings;
  set.integrator.kind = IntegratorKind::implicit;
  set.integrator.time_step_s = dt;
  set.integrator.max_iterations = hs.iterations;
  set.integrator.threads = 1;
  set.probes.resize(1);
  set.probes[0].drive = ProbeDrive::path;
  set.probes[0].path = s.path;
  return set;
}

/// The device side: local contact models every `period` (no device force).
DeviceSideSettings local_models(const HapticAccuracySettings& hs, double period) {
  DeviceSideSettings set;
  set.local_contact = LocalContactSettings{};
  set.local_contact->update_period_s = period;
  if (hs.compliance_scale > 0) set.local_contact->compliance_scale = hs.compliance_scale;
  return set;
}

/// The renderer as the accuracy sees it: the model's own force (no coupling, no damping, no
/// guard), with its fading offset at each new model.
LocalForceRenderer model_renderer(double device_hz) {
  HapticCouplingSettings c;
  c.device_rate_hz = device_hz;
  c.coupling_stiffness_n_mm = 1e12;
  c.damping_margin = 0.0;
  c.energy_guard = false;
  LocalForceRenderer r;
  r.init(c);
  return r;
}

struct Errors {
  double sum2{0}, peak{0}, max_step{0};
  int n{0};
  Eigen::Vector3d last{Eigen::Vector3d::Zero()};
  void add(const Eigen::Vector3d& f, const Eigen::Vector3d& ref) {
    const double e = (f - ref).norm();
    sum2 += e * e;
    peak = std::max(peak, e);
    if (n > 0) max_step = std::max(max_step, (f - last).norm());
    last = f;
    ++n;
  }
  HapticAccuracyRow row(const std::string& method, double hz, double fmax) const {
    return {method, hz, std::sqrt(sum2 / std::max(1, n)) / fmax, peak / fmax, max_step / fmax};
  }
};

}  // namespace

HapticAccuracyResult run_haptic_accuracy(const HapticAccuracySettings& hs) {
  const auto wall0 = std::chrono::steady_clock::now();
  const auto say = [&](const std::string& m) {
    if (hs.log) hs.log(m);
  };
  if (std::abs(hs.device_hz * hs.reference_dt_s - 1.0) > 1e-9)
    throw Error("haptic accuracy: the reference step must be one device tick");
  const Setup setup = make_setup(hs);
  const double dt = hs.reference_dt_s;
  const int ticks = int(std::lround(setup.duration_s / dt));
  HapticAccuracyResult res;
  res.duration_s = setup.duration_s;
  res.elements = setup.prep.physics->num_elements();
  const auto path_at = [&](double t) { return path_position(setup.path, t); };

  // the reference: the force after every 1 ms step, and the paper's half sines of it
  std::vector<Eigen::Vector3d> ref(std::size_t(ticks) + 1, Eigen::Vector3d::Zero());
  std::vector<Eigen::Vector3d> paper(std::size_t(ticks) + 1, Eigen::Vector3d::Zero());
  {
    Simulation sim(setup.prep.physics, make_settings(setup, hs, dt));
    DeviceForceShaper shaper;
    shaper.init(DeviceForceSettings{}, dt);
    for (int k = 1; k <= ticks; ++k) {
      if (sim.step() != StepStatus::ok) throw Error("haptic accuracy: the reference failed: " + sim.state().message);
      ref[std::size_t(k)] = sim.probe(0).raw_force_n;
      paper[std::size_t(k)] = shaper.push(ref[std::size_t(k)], sim.time_s());
    }
  }
  for (const auto& f : ref) res.peak_force_n = std::max(res.peak_force_n, f.norm());
  const double fmax = std::max(res.peak_force_n, 1e-12);
  say(fmt::format("reference: implicit {:.0f} ms steps, {} elements, {:.2f} s, peak {:.4f} N", dt * 1e3, res.elements,
                  setup.duration_s, res.peak_force_n));
  HapticAccuracyCurve ref_curve{"reference: full-rate physics (implicit, 1 ms)", {}, {}};
  HapticAccuracyCurve paper_curve{"paper: half sines of 20 ms", {}, {}};
  Errors paper_err;
  for (int k = 1; k <= ticks; ++k) {
    ref_curve.t_s.push_back(k * dt);
    ref_curve.force_n.push_back(ref[std::size_t(k)].norm());
    paper_curve.t_s.push_back(k * dt);
    paper_curve.force_n.push_back(paper[std::size_t(k)].norm());
    paper_err.add(paper[std::size_t(k)], ref[std::size_t(k)]);
  }
  res.curves.push_back(ref_curve);

  for (const double hz : hs.physics_hz) {
    const int n = std::max(1, int(std::lround(1.0 / (hz * dt))));
    const double period = n * dt;
    // chunks: the reference's own steps, a model every n of them, delivered n ticks later
    {
      Simulation sim(setup.prep.physics, make_settings(setup, hs, dt));
      DeviceSide side(sim, local_models(hs, period));
      LocalForceRenderer r = model_renderer(hs.device_hz);
      LocalContactModel pending, delivered;
      bool have = false;
      Eigen::Vector3d held = Eigen::Vector3d::Zero();
      Errors local, hold;
      HapticAccuracyCurve lc{fmt::format("local model, physics {:.0f} Hz", hz), {}, {}};
      HapticAccuracyCurve hc{fmt::format("held, physics {:.0f} Hz", hz), {}, {}};
      for (int k = 1; k <= ticks; ++k) {
        if (sim.step() != StepStatus::ok) throw Error("haptic accuracy: a run failed: " + sim.state().message);
        const double t = k * dt;
        if (k % n == 0) {
          if (have) {
            std::swap(delivered, pending);
            r.update_model(delivered, t, period);
            held = delivered.anchor_force_n;
          }
          side.build_local_contact(0, pending);
          have = true;
        }
        const Eigen::Vector3d f = r.tick(path_at(t), t).force_n;
        local.add(f, ref[std::size_t(k)]);

        hold.add(held, ref[std::size_t(k)]);
        lc.t_s.push_back(t);
        lc.force_n.push_back(f.norm());
        hc.t_s.push_back(t);
        hc.force_n.push_back(held.norm());
      }
      res.rows.push_back(local.row("local model (chunks)", hz, fmax));
      res.rows.push_back(hold.row("physics force held (chunks)", hz, fmax));
      if (hz == 60.0 || hz == 30.0) res.curves.push_back(lc);
      if (hz == 30.0) res.curves.push_back(hc);
      say(fmt::format("physics {:4.0f} Hz, chunks of {} steps: local model RMS {:.2f} %, peak {:.2f} %; held RMS {:.2f} %",
                      hz, n, 100 * res.rows[res.rows.size() - 2].rms, 100 * res.rows[res.rows.size() - 2].peak,
                      100 * res.rows.back().rms));
    }
    // large steps: one implicit step of the period per update, the model one update later
    if (hs.large_steps && n > 1) {
      Simulation sim(setup.prep.physics, make_settings(setup, hs, period));
      DeviceSide side(sim, local_models(hs, period));
      LocalForceRenderer r = model_renderer(hs.device_hz);
      LocalContactModel pending, delivered;
      bool have = false;
      Errors local;
      for (int k = 1; k <= ticks; ++k) {
        const double t = k * dt;
        if (k % n == 0) {
          if (have) {
            std::swap(delivered, pending);
            r.update_model(delivered, t, period);
          }
          if (sim.step() != StepStatus::ok) throw Error("haptic accuracy: a run failed: " + sim.state().message);
          side.build_local_contact(0, pending);
          have = true;
        }
        local.add(r.tick(path_at(t), t).force_n, ref[std::size_t(k)]);
      }
      res.rows.push_back(local.row("local model (large steps)", hz, fmax));
      say(fmt::format("physics {:4.0f} Hz, implicit steps of {:.1f} ms: local model RMS {:.2f} %, peak {:.2f} %", hz,
                      period * 1e3, 100 * res.rows.back().rms, 100 * res.rows.back().peak));
    }
  }
  res.rows.push_back(paper_err.row("paper: half sines (full-rate physics)", 1.0 / dt, fmax));
  res.curves.push_back(paper_curve);
  res.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  return res;
}

std::string haptic_accuracy_table(const HapticAccuracyResult& r) {
  std::string s = fmt::format(
      "Device force at 1 kHz against the full-rate physics ({} elements, {:.1f} s press-and-slide, peak {:.3f} N); "
      "errors as % of the peak force\n\n| method | physics (Hz) | RMS error | peak error | largest tick step |\n"
      "|---|---|---|---|---|\n",
      r.elements, r.duration_s, r.peak_force_n);
  for (const auto& row : r.rows)
    s += fmt::format("| {} | {:.0f} | {:.2f} % | {:.2f} % | {:.2f} % |\n", row.method, row.physics_hz, 100 * row.rms,
                     100 * row.peak, 100 * row.max_step);
  return s;
}

void plot_haptic_accuracy(const HapticAccuracyResult& r, const std::filesystem::path& png) {
  PlotPanel curves;
  curves.title = "device force at 1 kHz: the local model against the full-rate physics";
  curves.xlabel = "time (s)";
  curves.ylabel = "|F| (N)";
  PlotPanel zoom = curves;
  zoom.title = "zoom: sliding over the lesion";
  const std::vector<std::string> colours{"black", "#1f77b4", "#d62728", "#999999", "#2ca02c"};
  double t_peak = 0.0, f_peak = -1.0;
  for (std::size_t i = 0; i < r.curves.front().t_s.size(); ++i)
    if (r.curves.front().force_n[i] > f_peak) f_peak = r.curves.front().force_n[i], t_peak = r.curves.front().t_s[i];
  for (std::size_t c = 0; c < r.curves.size(); ++c) {
    PlotSeries s;
    s.title = r.curves[c].title;
    s.x = r.curves[c].t_s;
    s.y = r.curves[c].force_n;
    s.color = colours[c % colours.size()];
    s.line_width = c == 0 ? 3.0 : 1.5;
    const bool paper = c + 1 == r.curves.size();  // the half sines: in the zoom only (they swing 0 to 1.6x)
    if (paper) s.line_width = 1.0;
    if (!paper) curves.series.push_back(s);
    PlotSeries z;
    z.title = s.title;
    z.color = s.color;
    z.line_width = s.line_width;
    for (std::size_t i = 0; i < s.x.size(); ++i)
      if (std::abs(s.x[i] - t_peak) <= 0.3) z.x.push_back(s.x[i]), z.y.push_back(s.y[i]);
    zoom.series.push_back(z);
  }
  curves.key = "top left";
  zoom.key = "bottom right";
  PlotPanel err;
  err.title = "RMS error against the physics rate";
  err.xlabel = "physics updates per second";
  err.ylabel = "RMS error (% of peak force)";
  err.log_x = true;
  err.key = "top right";
  for (const char* method : {"local model (chunks)", "local model (large steps)", "physics force held (chunks)"}) {
    PlotSeries s;
    s.title = method;
    s.with_points = true;
    for (const auto& row : r.rows)
      if (row.method == method) s.x.push_back(row.physics_hz), s.y.push_back(100 * row.rms);
    if (!s.x.empty()) err.series.push_back(s);
  }
  plot_png({curves, zoom, err}, png, 1000, 380);
}

}  // namespace vx
