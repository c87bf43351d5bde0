// The verify cases on dynamics: the natural frequency of a fixed-free bar, convergence in the
// time step, the largest stable step against stiffness, and the energy of long runs.
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "base/error.h"
#include "physics/calibration.h"
#include "sim/contact.h"
#include "sim/state.h"
#include "sim/static_solver.h"
#include "sim/time_step.h"
#include "verify/case_helpers.h"
#include "verify/cases.h"

namespace vx::cases {

// --- mechanics: natural frequency of a fixed-free bar ------------------------------------------

namespace {

/// Releases a bar (fixed at z = 0, section t, length L, voxel h) from its static stretch under an
/// axial load and measures the frequency of the top's motion from its zero crossings; Hz.
/// Undamped, symplectic Euler at `dt_fraction` of the stable step. Fills the time series.
double bar_frequency_hz(const std::shared_ptr<const PhysicsModel>& p, double periods_expected, double f_expected,
                        std::vector<double>* ts, std::vector<double>* zs,
                        IntegratorKind kind = IntegratorKind::symplectic_euler, double dt_s = 0) {
  const Model& m = *p->model;
  SimState s = make_state(p);
  s.fix_nodes(nodes_on_face(m, BoxFace::z_min));
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  solve_static(s, static_settings());
  s.gravity_mm_s2.setZero();
  s.velocities.setZero();
  const auto top = nodes_on_face(m, BoxFace::z_max);
  if (dt_s <= 0) dt_s = 0.5 * stable_time_step(*p, kind);
  auto integ = make_integrator(integrator(kind, dt_s));
  const int steps = int(std::ceil(periods_expected / f_expected / dt_s));
  std::vector<double> crossings;
  double prev = mean_displacement(s, top, 2);
  for (int k = 1; k <= steps; ++k) {
    integ->step(s);
    if (s.failed()) throw Error("the free vibration stopped: " + s.message);
    const double z = mean_displacement(s, top, 2);
    if (ts) ts->push_back(s.time_s), zs->push_back(z);
    if ((prev < 0) != (z < 0)) crossings.push_back(s.time_s - dt_s * z / (z - prev));
    prev = z;
  }
  if (crossings.size() < 3) return std::nan("");
  return 0.5 * double(crossings.size() - 1) / (crossings.back() - crossings.front());
}

}  // namespace

void run_frequency(VerifyContext& ctx, Layout r, int section_voxels, double h) {
  const double length = 32.0, e_kpa = 10.0, rho = 1000.0;
  const auto p = make_physics_model(block_model(r, {section_voxels, section_voxels, int(std::lround(length / h))}, h),
                                    tissue(e_kpa, 0.0));
  const double c = std::sqrt(e_kpa * kKpaToNPerMm2 / (rho * kKgM3ToKgPerMm3 * kKgToNs2PerMm));  // mm/s
  const double f_theory = c / (4 * length);
  std::vector<double> t, z;
  const double f = bar_frequency_hz(p, 4.0, f_theory, &t, &z);
  ctx.log(fmt::format("{} layout, {} elements, {:.0f} voxels along: f = {:.4g} Hz, sqrt(E/rho)/(4L) = {:.4g} Hz",
                      layout_name(r), p->num_elements(), length / h, f, f_theory));
  // lumped masses lower the frequency by (pi h / 4 L)^2 / 6 < 0.1 %; the release excites the
  // third mode by ~3 %, which shifts single zero crossings by < 1 %: 2 %
  ctx.check("frequency_ratio", f / f_theory, 1.0, 0.02, "",
            "first axial frequency of a fixed-free bar / sqrt(E / rho) / (4 L)");
  ctx.plot("vibration", "Free axial vibration of a fixed-free bar: the top's displacement against time",
           {{fmt::format("Bar {} x {} x {} mm, {} layout, E = {} kPa, undamped", section_voxels * h, section_voxels * h,
                         length, layout_name(r), e_kpa),
             "time, s",
             "top displacement, mm",
             {{"simulated", t, z}}}});
}

// --- convergence in time step ------------------------------------------------------------------

void run_convergence_dt(VerifyContext& ctx) {
  // a damped fixed-free bar released from its stretch; its top's trajectory against a reference
  // with a step 64 times smaller, for each integrator (all three are first order)
  const double length = 16.0;
  std::vector<PlotSeries> series;
  for (IntegratorKind kind :
       {IntegratorKind::symplectic_euler, IntegratorKind::explicit_euler, IntegratorKind::implicit}) {
    const auto p = make_physics_model(block_model(Layout::voxel, {4, 4, int(length)}, 1.0), tissue(10.0, 0.05));
    const double f = std::sqrt(10.0 * kKpaToNPerMm2 / (1000.0 * kKgM3ToKgPerMm3 * kKgToNs2PerMm)) / (4 * length);
    // the coarsest step: half the stable one (explicit), the stable symplectic one for implicit
    const double dt0 = (kind == IntegratorKind::implicit ? 2.0 : 0.5) * reference_step_s(*p, kind);
    const double t_end = 1.5 / f;
    const auto trajectory = [&](double dt, double sample_dt) {
      std::vector<double> t, z;
      (void)bar_frequency_hz(p, t_end * f, f, &t, &z, kind, dt);
      // samples at multiples of sample_dt (the coarsest step), by linear interpolation
      std::vector<double> out;
      for (double ts = sample_dt; ts <= t_end - sample_dt; ts += sample_dt) {
        const auto it = std::lower_bound(t.begin(), t.end(), ts - 1e-12);
        if (it == t.end()) break;
        const std::size_t j = std::size_t(it - t.begin());
        if (j == 0) {
          out.push_back(z[0]);
          continue;
        }
        const double w = (ts - t[j - 1]) / (t[j] - t[j - 1]);
        out.push_back((1 - w) * z[j - 1] + w * z[j]);
      }
      return out;
    };
    const std::vector<double> reference = trajectory(dt0 / 64, dt0);
    double amplitude = 0;
    for (double v : reference) amplitude = std::max(amplitude, std::abs(v));
    std::vector<double> dts, errs, ldt, lerr;
    for (int k = 0; k < 4; ++k) {
      const double dt = dt0 / double(1 << k);
      const std::vector<double> z = trajectory(dt, dt0);
      double err = 0;
      for (std::size_t i = 0; i < std::min(z.size(), reference.size()); ++i)
        err = std::max(err, std::abs(z[i] - reference[i]));
      dts.push_back(dt);
      errs.push_back(err / amplitude);
      ldt.push_back(std::log10(dt));
      lerr.push_back(std::log10(err / amplitude));
    }
    const std::string name = to_string(kind);
    ctx.log(fmt::format("{}: steps {:.3g} .. {:.3g} s, max trajectory error / amplitude {:.3g}, {:.3g}, {:.3g}, {:.3g}",
                        name, dts.front(), dts.back(), errs[0], errs[1], errs[2], errs[3]));
    // first order: halving the step halves the error, so the observed order log2(e(dt)/e(dt/2))
    // -> 1; the error against a reference at dt/64 is itself 1/64 off, and the coarsest steps are
    // not yet asymptotic: 0.3
    ctx.check(name + ".order", std::log2(errs[2] / errs[3]), 1.0, 0.3, "",
              "observed order of accuracy from the two finest steps (first-order scheme)");
    ctx.check(name + ".error_falls", errs[3] / errs[0], 0.0, 0.25, "",
              "error at dt/8 / error at dt: must fall (about 1/8 for a first-order scheme)", CheckRule::at_most);
    series.push_back({name, ldt, lerr, true});
  }
  ctx.plot("error-dt", "Convergence in time step: trajectory error against the step, log-log",
           {{"Damped fixed-free bar (voxel layout, 4 x 4 x 16 mm): max error of the top's motion / amplitude",
             "log10 time step, s", "log10 error / amplitude", series}});
}

// --- stability: largest stable time step against stiffness --------------------------------------

namespace {

/// The largest stable step by bisection between 0.1 and 10 times the estimate (log scale).
double measured_stable_dt(const std::shared_ptr<const PhysicsModel>& p, IntegratorKind kind, double estimate) {
  double lo = std::log(0.1 * estimate), hi = std::log(10.0 * estimate);
  if (!runs_stably(p, kind, std::exp(lo), 3000)) return std::exp(lo);
  if (runs_stably(p, kind, std::exp(hi), 3000)) return std::exp(hi);
  for (int k = 0; k < 14; ++k) {
    const double mid = 0.5 * (lo + hi);
    (runs_stably(p, kind, std::exp(mid), 3000) ? lo : hi) = mid;
  }
  return std::exp(lo);
}

}  // namespace

/// The stable-step search for `kind` (symplectic: undamped; explicit Euler: damping 0.1);
/// with `implicit`, also the implicit integrator far above the explicit limits.
void run_stability_dt(VerifyContext& ctx, IntegratorKind kind, bool implicit) {
  const auto model = block_model(Layout::gradational, {8, 8, 8}, 1.0);
  std::vector<PlotSeries> series;
  const std::vector<double> moduli = {1.0, 10.0, 100.0, 1000.0};
  {
    // symplectic undamped (its limit 2 / omega), explicit Euler damped (it needs damping)
    const double damping = kind == IntegratorKind::explicit_euler ? 0.1 : 0.0;
    std::vector<double> le, lm, lest;
    double worst_low = 1e9, worst_high = 0;
    for (double e : moduli) {
      const auto p = make_physics_model(model, tissue(e, damping));
      const double est = stable_time_step(*p, kind);
      const double dt = measured_stable_dt(p, kind, est);
      worst_low = std::min(worst_low, dt / est);
      worst_high = std::max(worst_high, dt / est);
      ctx.log(fmt::format("{} (damping {}), E = {} kPa: largest stable step {:.4g} s, estimate {:.4g} s (x{:.2f})",
                          to_string(kind), damping, e, dt, est, dt / est));
      le.push_back(std::log10(e));
      lm.push_back(std::log10(dt));
      lest.push_back(std::log10(est));
    }
    const std::string name = to_string(kind);
    ctx.check(name + ".estimate_is_safe", worst_low, 1.0, 0.0, "",
              "smallest (largest stable step / estimate) over the moduli: the estimate must never exceed the limit",
              CheckRule::at_least);
    // Gershgorin bounds overestimate the highest frequency by at most the node's neighbour
    // count effect, about 2x on a lattice; the explicit bound is per element: 3x
    ctx.check(name + ".estimate_is_tight", worst_high, 0.0, kind == IntegratorKind::explicit_euler ? 3.0 : 2.5, "",
              "largest (largest stable step / estimate): a usable estimate is not overly conservative",
              CheckRule::at_most);
    ctx.check(name + ".scaling_exponent", fitted_slope(le, lm), -0.5, 0.03, "",
              "slope of log(stable step) against log(E): the step scales like 1 / sqrt(E)");
    series.push_back({name + " measured", le, lm, true});
    series.push_back({name + " estimate", le, lest});
  }
  // implicit: stable far above the explicit limits (E = 1000 kPa, undamped, 100 x the symplectic estimate)
  if (implicit) {
    const auto p = make_physics_model(model, tissue(1000.0, 0.0));
    const double dt = 100.0 * stable_time_step(*p, IntegratorKind::symplectic_euler);
    SimState s = make_state(p);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (int i = 0; i < s.num_nodes(); ++i) s.velocities.col(i) = Eigen::Vector3d(u(rng), u(rng), u(rng));
    const double e0 = energy(s);
    auto integ = make_integrator(integrator(IntegratorKind::implicit, dt));
    integ->advance(s, 500);
    const double ratio = s.failed() ? std::nan("") : energy(s) / e0;
    ctx.check(
        "implicit.energy_ratio_at_100x", ratio, 1.0, 0.0, "",
        "energy after 500 implicit steps at 100x the symplectic limit / initial: backward Euler never gains energy",
        CheckRule::at_most);
  }
  // full suite, symplectic Euler: the step as the Poisson ratio nears 0.5 (issue 27; docs/model.md
  // section 5, "The stable step"): the volume term stiffens the volumetric modes, the step falls
  // like the inverse P-wave speed, sqrt((1 + nu)(1 - 2 nu) / (1 - nu)) of the step at Poisson 0
  if (ctx.full() && kind == IntegratorKind::symplectic_euler) {
    double dt0 = 0;
    for (double nu : {0.0, 0.3, 0.45, 0.49}) {
      Material m = tissue(10.0, 0.0);
      m.poisson_ratio = nu;
      const auto p = make_physics_model(model, m);
      const double est = stable_time_step(*p, kind), dt = measured_stable_dt(p, kind, est);
      if (nu == 0.0) dt0 = dt;
      const double wave = std::sqrt((1 + nu) * (1 - 2 * nu) / (1 - nu));
      ctx.log(
          fmt::format("symplectic Euler, E = 10 kPa, Poisson {}: largest stable step {:.4g} s (x{:.3f} the step at "
                      "0; P-wave scaling x{:.3f}), estimate {:.4g} s (x{:.2f})",
                      nu, dt, dt / dt0, wave, est, dt / est));
      if (nu == 0.0) continue;
      ctx.check(fmt::format("poisson{}.estimate_is_safe", nu), dt / est, 1.0, 0.0, "",
                fmt::format("largest stable step / estimate at Poisson {}: the estimate (with the volume term's "
                            "k_v g g^T) stays safe (measured 1.61, 1.80, 1.86 at 0.3, 0.45, 0.49; 1.26 at 0)",
                            nu),
                CheckRule::at_least);
      ctx.check(fmt::format("poisson{}.step_ratio", nu), dt / dt0 / wave, 1.0, 0.15, "",
                fmt::format("largest stable step at Poisson {} / at 0, over the P-wave scaling {:.3f} (the volume "
                            "term stiffens the element's volumetric mode by 3 nu / (1 - 2 nu); the highest mode mixes "
                            "shape and volume, so not exactly: measured 1.09, 1.06, 1.04 at 0.3, 0.45, 0.49)",
                            nu, wave));
    }
  }
  ctx.plot("stable-dt", "Largest stable time step against Young's modulus, measured (points) and estimated (lines)",
           {{fmt::format("Stable time step of a gradational 8^3 mm cube, {} (damping {})", to_string(kind),
                         kind == IntegratorKind::explicit_euler ? 0.1 : 0.0),
             "log10 E, kPa", "log10 time step, s", series}});
}

// --- stability: long runs, energy ---------------------------------------------------------------

void run_energy(VerifyContext& ctx, const std::vector<EnergyRun>& runs) {
  const auto model = block_model(Layout::gradational, {8, 8, 32}, 1.0);
  const double duration = 0.4;  // 10 periods of the bar's axial mode
  std::vector<PlotSeries> series;
  for (const EnergyRun& run : runs) {
    const auto p = make_physics_model(model, tissue(10.0, run.damping));
    SimState s = make_state(p);
    s.fix_nodes(nodes_on_face(*model, BoxFace::z_min));
    s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
    solve_static(s, static_settings());
    s.gravity_mm_s2.setZero();
    const double dt = run.dt_factor * reference_step_s(*p, run.kind);
    auto integ = make_integrator(integrator(run.kind, dt));
    const double e0 = energy(s);
    const int steps = int(std::ceil(duration / dt));
    const int every = std::max(1, steps / 400);
    std::vector<double> t = {0.0}, e = {1.0};
    double emax = 1.0, emin = 1.0;
    for (int k = 1; k <= steps; ++k) {
      integ->step(s);
      if (s.failed()) break;
      if (k % every == 0 || k == steps) {
        const double ratio = energy(s) / e0;
        t.push_back(s.time_s);
        e.push_back(ratio);
        emax = std::max(emax, ratio);
        emin = std::min(emin, ratio);
      }
    }
    const bool ok = !s.failed() && s.positions.allFinite();
    ctx.log(fmt::format("{}: {} steps of {:.3g} s, energy / initial in [{:.4f}, {:.4f}], final {:.4f}{}", run.label,
                        steps, dt, emin, emax, e.back(), ok ? "" : ", stopped: " + s.message));
    const std::string name = run.label;
    if (run.kind == IntegratorKind::symplectic_euler && run.damping == 0) {
      // symplectic Euler keeps a shadow energy: the true energy oscillates by O(omega dt) about
      // it without drifting; at half the stable step the highest modes carry little energy: 5 %
      ctx.check(name + ".max_deviation", ok ? std::max(emax - 1, 1 - emin) : std::nan(""), 0.0, 0.05, "",
                "largest |energy / initial - 1| over 10 periods, undamped", CheckRule::at_most);
    } else {
      ctx.check(name + ".max_ratio", ok ? emax : std::nan(""), 1.0, run.kind == IntegratorKind::implicit ? 1e-3 : 0.02,
                "",
                "largest energy / initial: damping or backward Euler never add energy (2 % for the oscillation of "
                "an explicit scheme's discrete energy)",
                CheckRule::at_most);
      if (run.damping > 0)
        ctx.check(name + ".final_ratio", ok ? e.back() : std::nan(""), 0.0, 0.9, "",
                  "energy left after 10 periods at damping 0.1: it must fall; only weakly, because element damping is "
                  "relative to each element's own frequency, so the slow axial mode sees zeta * omega_mode / "
                  "omega_element",
                  CheckRule::at_most);
    }
    series.push_back({name, t, e});
  }
  ctx.plot("energy", "Energy against time (relative to the initial energy) for long runs",
           {{"Released fixed-free bar, gradational 8 x 8 x 32 mm, E = 10 kPa", "time, s", "energy / initial", series}});
}

}  // namespace vx::cases
