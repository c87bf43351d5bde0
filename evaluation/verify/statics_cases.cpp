// The verify cases on mechanics against theory: plate compression (stress = E strain), Hertz
// indentation (finite-layer Hertz), a cantilever under its own weight (Timoshenko), the
// three layouts on one indentation against the voxel-level model, the folded phantom
// hanging from its stem (the support carries its weight), and the same at tissue-like Poisson
// ratios (the press against the finite-strain reference of finite_brick_reference.h).
#include <fmt/format.h>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "base/error.h"
#include "convert/phantom.h"
#include "convert/threshold.h"
#include "model/gradational_builder.h"
#include "physics/calibration.h"
#include "physics/elements.h"
#include "scene/sim_output.h"
#include "sim/contact.h"
#include "sim/simulation.h"
#include "sim/state.h"
#include "sim/static_solver.h"
#include "verify/case_helpers.h"
#include "verify/cases.h"
#include "verify/finite_brick_reference.h"
#include "verify/static_newton.h"

namespace vx::cases {

// --- mechanics: plate compression --------------------------------------------------------------

namespace {

/// Clamps the bottom, moves the clamped top down by strain * H, solves statically; returns the
/// stress (kPa) and sets the lateral strain at mid-height.
double compression_stress_kpa(const std::shared_ptr<const PhysicsModel>& p, double strain, double* lateral) {
  const Model& m = *p->model;
  SimState s = make_state(p);
  const auto bottom = nodes_on_face(m, BoxFace::z_min), top = nodes_on_face(m, BoxFace::z_max);
  s.fix_nodes(bottom);
  s.fix_nodes(top);
  const double height = rest_max(m, 2) - rest_min(m, 2);
  for (int i : top) s.positions(2, i) -= strain * height;
  solve_static(s, static_settings());
  if (s.failed()) throw Error("static compression failed: " + s.message);
  const double area = (rest_max(m, 0) - rest_min(m, 0)) * (rest_max(m, 1) - rest_min(m, 1));
  const double reaction = elastic_force_on(s, top, kThreads).z();
  if (lateral) {
    const auto left = nodes_on_face(m, BoxFace::x_min), right = nodes_on_face(m, BoxFace::x_max);
    const double zmid = rest_min(m, 2) + 0.5 * height;
    double l = 0, r = 0;
    int nl = 0, nr = 0;
    for (int i : left)
      if (std::abs(m.rest_positions(2, i) - zmid) < 1e-9) l += s.positions(0, i), ++nl;
    for (int i : right)
      if (std::abs(m.rest_positions(2, i) - zmid) < 1e-9) r += s.positions(0, i), ++nr;
    *lateral = (nl && nr) ? (r / nr - l / nl) / (rest_max(m, 0) - rest_min(m, 0)) - 1.0 : std::nan("");
  }
  return reaction / area / kKpaToNPerMm2;
}

}  // namespace

void run_compression(VerifyContext& ctx, Layout r, double tolerance) {
  const int n = ctx.full() ? 20 : 16;
  const double e_kpa = 10.0;
  const auto p = make_physics_model(block_model(r, {n, n, n}, 1.0), tissue(e_kpa));
  std::vector<double> strain = {0.01, 0.02, 0.03, 0.05}, stress, line;
  double lateral = 0;
  for (double eps : strain) stress.push_back(compression_stress_kpa(p, eps, eps == 0.05 ? &lateral : nullptr));
  const double e_fit = slope_through_origin(strain, stress);
  double nonlinearity = 0;
  for (std::size_t i = 0; i < strain.size(); ++i) {
    nonlinearity = std::max(nonlinearity, std::abs(stress[i] / (e_fit * strain[i]) - 1.0));
    line.push_back(e_kpa * strain[i]);
  }
  ctx.log(fmt::format("{} cube {}^3 ({} elements): stress {:.4g} kPa at 5 % strain, E measured {:.4g} kPa",
                      layout_name(r), n, p->num_elements(), stress.back(), e_fit));
  ctx.check("modulus_ratio", e_fit / e_kpa, 1.0, tolerance, "",
            "E measured (slope of stress against strain) / E set; Poisson 0 makes stress = E strain exact");
  ctx.check("linearity", nonlinearity, 0.0, 0.01, "",
            "largest deviation of stress / (E_fit strain) from 1 up to 5 % strain (the element is linear in stretch)",
            CheckRule::at_most);
  ctx.check("lateral_strain", lateral, 0.0, 1e-3, "", "mid-height widening at 5 % strain: none at Poisson 0");
  ctx.plot("stress-strain", "Plate compression: stress against strain, Poisson 0",
           {{fmt::format("Compression of a {}^3 mm cube, {} layout, E = {} kPa", n, layout_name(r), e_kpa),
             "strain",
             "stress, kPa",
             {{"measured", strain, stress, true}, {"E * strain", strain, line}}}});
}

// --- mechanics: Hertz indentation --------------------------------------------------------------

namespace {

/// One Hertz indentation (block `dims_mm`, voxel `voxel_mm`): the force and the references.
struct HertzRun {
  int elements{0};
  double final_depth_mm{0}, final_force_n{0}, final_reference_n{0};
  double modulus_ratio{0};  ///< E recovered / E set
  double exponent{0};       ///< log-log slope of the half-space-equivalent force
  std::vector<double> d15, f, ref, half;
};

HertzRun hertz_run(Layout r, const Eigen::Vector3d& dims_mm, double voxel_mm, double radius, double depth,
                   double e_kpa) {
  const Eigen::Vector3i dims = (dims_mm / voxel_mm).array().round().cast<int>();
  const double h = dims_mm.z();
  const auto p = make_physics_model(block_model(r, dims, voxel_mm), tissue(e_kpa));
  const Indentation ind = indent(p, radius, depth, 0.5 * dims_mm.x(), 0.5 * dims_mm.y());
  if (!ind.failure.empty()) throw Error("the indentation stopped: " + ind.failure);
  HertzRun out;
  out.elements = p->num_elements();
  std::vector<double> ld, lf, fit_ref, fit_f;
  for (std::size_t k = 0; k < ind.depth_mm.size(); ++k) {
    const double d = ind.depth_mm[k];
    if (d <= 0) continue;
    const double layer = hertz_bonded_layer_n(e_kpa, 0.0, radius, d, h);
    const double space = hertz_bonded_layer_n(e_kpa, 0.0, radius, d, 1e12);
    out.d15.push_back(std::pow(d, 1.5));
    out.f.push_back(ind.force_n[k]);
    out.ref.push_back(layer);
    out.half.push_back(space);
    // fit from a third of the depth on: below it the contact holds only a handful of nodes
    if (d >= depth / 3.0 && ind.force_n[k] > 0) {
      ld.push_back(std::log(d));
      lf.push_back(std::log(ind.force_n[k] * space / layer));  // half-space equivalent: grows like d^1.5
      fit_ref.push_back(layer);
      fit_f.push_back(ind.force_n[k]);
    }
  }
  out.modulus_ratio = slope_through_origin(fit_ref, fit_f);
  out.exponent = fitted_slope(ld, lf);
  out.final_depth_mm = ind.depth_mm.empty() ? 0.0 : ind.depth_mm.back();
  out.final_force_n = out.f.empty() ? 0.0 : out.f.back();
  out.final_reference_n = out.ref.empty() ? 0.0 : out.ref.back();
  return out;
}

}  // namespace

void run_hertz(VerifyContext& ctx, Layout r, const std::vector<double>& voxels_mm, double modulus_tolerance,
               double exponent_tolerance, bool against_voxel_layout) {
  // quick: 32 x 32 x 16 mm, R 6, 1.5 mm deep; full: the 40 x 40 x 20 mm, R 8, 2 mm of the slow test
  const bool full = ctx.full();
  const Eigen::Vector3d dims = full ? Eigen::Vector3d(40, 40, 20) : Eigen::Vector3d(32, 32, 16);
  const double radius = full ? 8.0 : 6.0, depth = full ? 2.0 : 1.5, e_kpa = 10.0;
  std::vector<HertzRun> runs;
  std::vector<PlotSeries> series;
  for (double h : voxels_mm) {
    runs.push_back(hertz_run(r, dims, h, radius, depth, e_kpa));
    const HertzRun& run = runs.back();
    ctx.log(
        fmt::format("{} layout, voxel {} mm, {} elements: force {:.4g} N at {:.2f} mm against {:.4g} N "
                    "(finite-layer Hertz); E recovered {:.4g} kPa, exponent {:.3f}",
                    layout_name(r), h, run.elements, run.final_force_n, run.final_depth_mm, run.final_reference_n,
                    run.modulus_ratio * e_kpa, run.exponent));
    series.push_back({fmt::format("simulated, voxel {} mm", h), run.d15, run.f, true});
  }
  const HertzRun& fine = runs.back();
  ctx.check(
      "modulus_ratio", fine.modulus_ratio, 1.0, modulus_tolerance, "",
      fmt::format("E recovered by fitting the force to finite-layer Hertz / E set (voxel {} mm)", voxels_mm.back()));
  // the coarser models at 0.5 mm voxels or finer (the voxel layout's 1 mm elements at the surface) too
  for (std::size_t k = 0; k + 1 < runs.size(); ++k)
    if (voxels_mm[k] <= 0.5 + 1e-12)
      ctx.check(fmt::format("modulus_ratio_{}mm", voxels_mm[k]), runs[k].modulus_ratio, 1.0, modulus_tolerance, "",
                fmt::format("E recovered / E set at voxel {} mm", voxels_mm[k]));
  if (against_voxel_layout) {
    // the voxel layout at 1 mm (1 mm elements everywhere) on the same scene: the modulus must
    // come closer to it with every halving of the voxel, and end within 3 % of it
    const HertzRun voxel = hertz_run(Layout::voxel, dims, 1.0, radius, depth, e_kpa);
    ctx.log(
        fmt::format("voxel layout, voxel 1 mm, {} elements: E recovered {:.4g} kPa (the reference of the "
                    "convergence)",
                    voxel.elements, voxel.modulus_ratio * e_kpa));
    for (std::size_t k = 1; k < runs.size(); ++k)
      ctx.check(fmt::format("gap_to_voxel_{}mm", voxels_mm[k]), std::abs(runs[k].modulus_ratio - voxel.modulus_ratio),
                std::abs(runs[k - 1].modulus_ratio - voxel.modulus_ratio), 0.0, "",
                fmt::format("|E recovered at {} mm - E recovered by the voxel layout (1 mm)| / E: at most the gap at "
                            "{} mm (converging towards the voxel layout)",
                            voxels_mm[k], voxels_mm[k - 1]),
                CheckRule::at_most);
    ctx.check("gap_to_voxel_finest", std::abs(fine.modulus_ratio - voxel.modulus_ratio), 0.0, 0.03, "",
              fmt::format("|E recovered at {} mm - E recovered by the voxel layout (1 mm)| / E", voxels_mm.back()),
              CheckRule::at_most);
  }
  ctx.check("exponent", fine.exponent, 1.5, exponent_tolerance, "",
            "slope of log(half-space-equivalent force) against log(depth): Hertz's 1.5");
  if (runs.size() >= 2) {
    const double coarse_err = std::abs(runs[runs.size() - 2].modulus_ratio - 1.0);
    const double fine_err = std::abs(fine.modulus_ratio - 1.0);
    ctx.check("error_falls", fine_err - coarse_err, 0.0, 0.0, "",
              fmt::format("|E error| at voxel {} mm - |E error| at {} mm: halving the voxel must not make it worse",
                          voxels_mm.back(), voxels_mm[voxels_mm.size() - 2]),
              CheckRule::at_most);
  }
  series.push_back({"Hertz, finite layer (reference)", fine.d15, fine.ref});
  series.push_back({"Hertz, half-space", fine.d15, fine.half});
  ctx.plot("force-depth", "Hertz indentation: force against depth^1.5 (a straight line for Hertz)",
           {{fmt::format("Ball R = {} mm into a {}x{}x{} mm block, {} layout, E = {} kPa", radius, dims.x(), dims.y(),
                         dims.z(), layout_name(r), e_kpa),
             "depth^{1.5}, mm^{1.5}", "force, N", series}});
}

// --- mechanics: cantilever bending; convergence in resolution ----------------------------------

namespace {

/// Tip deflection of a beam (length L along x, square section t, voxel h), clamped at x = 0,
/// under its own weight; mm (downwards positive).
double cantilever_tip_mm(Layout r, double length, double t, double h, double e_kpa, int* elements) {
  const Eigen::Vector3i dims(int(std::lround(length / h)), int(std::lround(t / h)), int(std::lround(t / h)));
  const auto p = make_physics_model(block_model(r, dims, h), tissue(e_kpa));
  if (elements) *elements = p->num_elements();
  SimState s = make_state(p);
  s.fix_nodes(nodes_on_face(*p->model, BoxFace::x_min));
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  solve_static(s, static_settings());
  if (s.failed()) throw Error("static bending failed: " + s.message);
  return -mean_displacement(s, nodes_on_face(*p->model, BoxFace::x_max), 2);
}

/// Timoshenko cantilever under uniform load q = rho g A: q L^4 / (8 E I) + q L^2 / (2 kappa G A),
/// square section t, Poisson 0 (G = E / 2), kappa = 5/6; mm.
double cantilever_theory_mm(double length, double t, double e_kpa, double density) {
  const double q = density * kKgM3ToKgPerMm3 * kStandardGravityMmS2 * 1e-3 * t * t;  // N/mm
  const double e = e_kpa * kKpaToNPerMm2, i = t * t * t * t / 12.0, a = t * t;
  return q * std::pow(length, 4) / (8 * e * i) + q * length * length / (2 * (5.0 / 6.0) * (e / 2) * a);
}

}  // namespace

void run_cantilever(VerifyContext& ctx, Layout r, const std::vector<double>& voxels_mm, double tolerance) {
  const double length = 32.0, t = 4.0, e_kpa = 3000.0;
  const double theory = cantilever_theory_mm(length, t, e_kpa, 1000.0);
  std::vector<double> hs, errors, lh, le;
  for (double h : voxels_mm) {
    int elements = 0;
    const double tip = cantilever_tip_mm(r, length, t, h, e_kpa, &elements);
    const double err = tip / theory - 1.0;
    ctx.log(
        fmt::format("{} layout, voxel {} mm ({} elements, {:.0f} across): tip {:.4g} mm, beam theory {:.4g} mm "
                    "({:+.1f} %)",
                    layout_name(r), h, elements, t / h, tip, theory, 100 * err));
    hs.push_back(h);
    errors.push_back(err);
    lh.push_back(std::log10(h));
    le.push_back(std::log10(std::abs(err)));
  }
  ctx.check("tip_ratio_finest", 1.0 + errors.back(), 1.0, tolerance, "",
            fmt::format("tip deflection / Timoshenko beam theory at the finest voxel ({} mm)", hs.back()));
  // convergence: each halving takes the error to at most 0.8 of what it was, unless it is
  // already within 2 % (the beam solution's own accuracy for this 8:1 beam clamped over its
  // whole end face: models with exact bending elements read -0.8 % at every voxel size)
  for (std::size_t k = 1; k < errors.size(); ++k)
    ctx.check(fmt::format("error_{}mm", hs[k]), std::abs(errors[k]), std::max(0.8 * std::abs(errors[k - 1]), 0.02), 0.0,
              "",
              fmt::format("|tip / beam theory - 1| at {} mm: at most 0.8 x the error at {} mm, or within the 2 % floor "
                          "(convergence in resolution)",
                          hs[k], hs[k - 1]),
              CheckRule::at_most);
  ctx.plot("convergence", "Cantilever under its own weight: tip deflection error against voxel size, log-log",
           {{fmt::format("Beam {} x {} x {} mm clamped at one end, {} layout, E = {} kPa", length, t, t, layout_name(r),
                         e_kpa),
             "log10 voxel size, mm",
             "log10 |tip / beam theory - 1|",
             {{"error", lh, le, true}}}});
}

// --- mechanics at tissue-like Poisson ratios (issue 27; docs/model.md section 5, "Locking") -----

namespace {

/// The paper element's ratios F(nu) / F(0) (press, cantilever) against the references' ratios.
constexpr double kPaperRatioTolerance = 0.05;

Material tissue_nu(double e_kpa, double nu) {
  Material m = tissue(e_kpa);
  m.poisson_ratio = nu;
  return m;
}

/// A ball of R 4 mm pressed 2 mm into the centre of a 32 x 32 x 16 mm block (voxel `h`) bonded at
/// its base, quasi-static: the implicit integrator at 10 ms steps, the press over 0.2 s from 0.2 mm
/// above, held to 0.4 s; the mean force over the last 0.1 s, N (as poisson_locking_slow_test).
double quasi_static_press_n(Layout r, double h, double nu, ElementKind element = ElementKind::hourglass) {
  const int n = int(std::lround(32.0 / h)), nz = int(std::lround(16.0 / h));
  CalibrationOptions options;
  options.element = element;
  const auto p = make_physics_model(block_model(r, {n, n, nz}, h), tissue_nu(10.0, nu), {}, options);
  const Model& m = *p->model;
  SimulationSettings s;
  s.integrator = integrator(IntegratorKind::implicit, 0.01);
  s.integrator.max_iterations = 60;
  s.integrator.residual_tolerance_n = 1e-7;
  s.fixed_nodes = nodes_on_face(m, BoxFace::z_min);
  ProbeSettings ball;
  ball.name = "ball";
  ball.geometry.shape = ProbeShape::sphere;
  ball.geometry.radius_mm = 4.0;
  ball.drive = ProbeDrive::path;
  const double cx = 0.5 * (rest_min(m, 0) + rest_max(m, 0)), cy = 0.5 * (rest_min(m, 1) + rest_max(m, 1));
  const double top = rest_max(m, 2);
  ball.path = {{0.0, {cx, cy, top + 4.2}}, {0.2, {cx, cy, top + 2.0}}, {0.4, {cx, cy, top + 2.0}}};
  s.probes = {ball};
  Simulation sim(p, s);
  double sum = 0;
  int k = 0;
  while (sim.time_s() < 0.4 - 1e-9) {
    if (sim.step() != StepStatus::ok) throw Error("the quasi-static press stopped: " + sim.state().message);
    if (sim.time_s() > 0.3 + 1e-9) sum += sim.probe(0).raw_force_n.z(), ++k;
  }
  return sum / k;
}

}  // namespace

void run_poisson_hertz(VerifyContext& ctx) {
  // The model's press against the finite-strain reference on the same mesh (voxel layout: the
  // reference's bricks are its voxels; docs/model.md section 5, "A finite-strain reference"): the
  // finite-layer solution (small strain, vertical contact on the flat surface) does not hold for
  // a 4 mm ball 2 mm deep on 1-2 mm voxels (the reference itself reads 0.77-0.84 of its ratio at
  // 0.45), so it is shown and bounds locking only (at most 10 % above it)
  const double r = 4.0, d = 2.0, layer = 16.0;
  const std::vector<double> nus = {0.0, 0.3, 0.45, 0.49};
  auto finite_layer_ratio = [&](double nu) {
    return hertz_bonded_layer_n(10.0, nu, r, d, layer) / hertz_bonded_layer_n(10.0, 0.0, r, d, layer);
  };
  struct Mesh {
    double voxel_mm;
    std::vector<double> nus;
  };
  // 2 mm: every ratio (the reference about 5 s each); 1 mm: 0 and 0.45 (the reference 1-5 min each)
  const std::vector<Mesh> meshes = {{2.0, nus}, {1.0, {0.0, 0.45}}};
  std::map<double, double> model_ratio45, reference_ratio45;                  // by voxel size
  std::map<std::pair<double, double>, double> reference_ratio, reference_f0;  // by voxel size and nu
  std::vector<double> plot_nu, plot_model, plot_reference, plot_layer;
  for (const Mesh& mesh : meshes) {
    reference::FinitePress fp;
    fp.voxel_mm = mesh.voxel_mm;
    fp.steps = 2;  // the force at the final depth does not depend on the path (elastic, frictionless)
    fp.material = reference::FiniteMaterial::corotational;  // the model's law (its shape term, its volume term)
    double f0 = 0, r0 = 0;
    for (double nu : mesh.nus) {
      const double f = quasi_static_press_n(Layout::voxel, mesh.voxel_mm, nu);
      const auto ref = reference::finite_brick_press(fp, nu);
      const double rf = ref.force_n.back();
      ctx.log(
          fmt::format("voxel layout, {} mm voxels, Poisson {}: the model {:.4g} N, the finite-strain reference "
                      "{:.4g} N ({} unknowns, {:.0f} s)",
                      mesh.voxel_mm, nu, f, rf, ref.dofs, ref.total_s));
      reference_ratio[{mesh.voxel_mm, nu}] = r0 > 0 ? rf / r0 : 1.0;
      if (nu == 0.0) {
        f0 = f, r0 = rf;
        reference_f0[{mesh.voxel_mm, nu}] = rf;
        ctx.check(fmt::format("force_{}mm_nu0", mesh.voxel_mm), f / rf, 1.0, 0.03, "",
                  fmt::format(
                      "the model's F(0) / the finite-strain reference's on the same {} mm voxels (measured "
                      "0.983 on 2 mm, 0.997 on 1 mm; the reference's law is the model's at Poisson 0, its contact the "
                      "sphere's normal pushes: what is left is the model's element against the B-bar brick)",
                      mesh.voxel_mm));
        continue;
      }
      const double model = f / f0, refr = rf / r0, layer_ratio = finite_layer_ratio(nu);
      ctx.log(
          fmt::format("  F({}) / F(0): the model {:.4f}, the reference {:.4f} ({:+.1f} %), the finite layer {:.4f} "
                      "(model / finite layer {:.3f}, reference / finite layer {:.3f})",
                      nu, model, refr, 100 * (model / refr - 1), layer_ratio, model / layer_ratio, refr / layer_ratio));
      ctx.check(fmt::format("ratio_{}mm_nu{}", mesh.voxel_mm, nu), model / refr, 1.0, 0.025, "",
                fmt::format("F({}) / F(0) of the model over the finite-strain reference's on the same {} mm voxels "
                            "(the issue's 5 %, halved: measured +1.5, +1.0, +1.1 % at 0.3, 0.45, 0.49 on 2 mm, -0.1 % "
                            "at 0.45 on 1 mm)",
                            nu, mesh.voxel_mm));
      ctx.check(fmt::format("no_locking_{}mm_nu{}", mesh.voxel_mm, nu), model / layer_ratio, 1.0, 0.10, "",
                fmt::format("F({}) / F(0) over the finite layer's {:.3f}: at most 10 % above it (no volumetric "
                            "locking; the former volume term on the vertex fit read 2.1 times it at 0.45)",
                            nu, layer_ratio),
                CheckRule::at_most);
      if (nu == 0.45) model_ratio45[mesh.voxel_mm] = model, reference_ratio45[mesh.voxel_mm] = refr;
      if (mesh.voxel_mm == 2.0) {
        plot_nu.push_back(nu), plot_model.push_back(model), plot_reference.push_back(refr);
        plot_layer.push_back(layer_ratio);
      }
    }
  }
  // convergence as the voxel halves: the model's ratio moves as the reference's does (towards the
  // finite layer's: 0.783 -> 0.837 of it, the reference 0.775 -> 0.838)
  const double model_step = model_ratio45[1.0] / model_ratio45[2.0],
               reference_step = reference_ratio45[1.0] / reference_ratio45[2.0];
  ctx.log(fmt::format("2 -> 1 mm at 0.45: the model's ratio x {:.4f}, the reference's x {:.4f}", model_step,
                      reference_step));
  ctx.check("halving_nu0.45", model_step / reference_step, 1.0, 0.02, "",
            "the change of F(0.45) / F(0) from 2 to 1 mm voxels, the model's over the reference's (convergence: the "
            "model follows the reference as the voxels halve: measured 1.070 against 1.082; 0.5 mm not run: the "
            "reference's factor alone took 7 min there, the press tens of minutes per ratio)");
  ctx.check("rises_nu0.45", model_ratio45[1.0], model_ratio45[2.0], 0.0, "",
            "F(0.45) / F(0) on 1 mm voxels at least that on 2 mm (the ratio rises towards the finite layer's as the "
            "voxels halve, as the reference's does)",
            CheckRule::at_least);
  // the gradational layout on 1 mm voxels (its interior elements up to 8 voxels wide) against the
  // reference's 1 mm ratio: its large elements keep one volume constraint each (docs/model.md
  // section 5: 4 % below the voxel layout)
  {
    const double g0 = quasi_static_press_n(Layout::gradational, 1.0, 0.0),
                 g45 = quasi_static_press_n(Layout::gradational, 1.0, 0.45);
    ctx.log(
        fmt::format("gradational layout, 1 mm voxels: F(0) {:.4g} N, F(0.45) / F(0) {:.4f} ({:.3f} of the "
                    "reference's on the same voxels)",
                    g0, g45 / g0, g45 / g0 / reference_ratio45[1.0]));
    ctx.check("ratio_gradational_1mm_nu0.45", g45 / g0 / reference_ratio45[1.0], 1.0, 0.05, "",
              "F(0.45) / F(0) of the gradational layout over the finite-strain reference's on the same 1 mm voxels "
              "(the issue's 5 %; its large interior elements keep one volume constraint each: measured 0.959)");
  }
  // the paper's element (every non-affine mode held by the penalty k; at Poisson 0 8-15 % stiff in
  // bending, docs/model.md section 5): its own F(nu) / F(0) against the reference's ratio, so its
  // stiffness at Poisson 0 cancels and what is left is what the volume term does to it
  for (const Mesh& mesh : meshes) {
    const double f0 = quasi_static_press_n(Layout::voxel, mesh.voxel_mm, 0.0, ElementKind::paper);
    ctx.log(fmt::format("paper element, voxel layout, {} mm voxels: F(0) {:.4g} N ({:.3f} of the reference's)",
                        mesh.voxel_mm, f0, f0 / reference_f0[{mesh.voxel_mm, 0.0}]));
    for (double nu : mesh.nus) {
      if (nu == 0.0) continue;
      const double ratio = quasi_static_press_n(Layout::voxel, mesh.voxel_mm, nu, ElementKind::paper) / f0,
                   refr = reference_ratio[{mesh.voxel_mm, nu}];
      ctx.log(fmt::format("  paper element F({}) / F(0) {:.4f}, the reference {:.4f} ({:+.1f} %)", nu, ratio, refr,
                          100 * (ratio / refr - 1)));
      ctx.check(fmt::format("paper_ratio_{}mm_nu{}", mesh.voxel_mm, nu), ratio / refr, 1.0, kPaperRatioTolerance, "",
                fmt::format("F({}) / F(0) of the paper's element over the finite-strain reference's on the same {} mm "
                            "voxels (its own stiffness at Poisson 0 cancels; the issue's 5 %)",
                            nu, mesh.voxel_mm));
    }
  }
  // the paper's element on the gradational layout: its large interior elements hold their extra face
  // vertices with the full penalty k, so it is stiff at Poisson 0 (F(0) about 1.15 of the reference's)
  // and that stiffness does not scale with the volume term: its ratio F(0.45) / F(0) reads below the
  // reference's (measured 0.932) while F(0.45) itself is closer to the reference than F(0) is. Locking
  // would show as the opposite, the excess over the reference growing with nu; so it is judged
  // one-sided on the ratio, and F(0.45) is held to at least the reference's (not softer than 5 %).
  {
    const double g0 = quasi_static_press_n(Layout::gradational, 1.0, 0.0, ElementKind::paper),
                 g45 = quasi_static_press_n(Layout::gradational, 1.0, 0.45, ElementKind::paper);
    const double reference0 = reference_f0[{1.0, 0.0}], reference45 = reference0 * reference_ratio45[1.0];
    const double excess0 = g0 / reference0, excess45 = g45 / reference45;
    ctx.log(
        fmt::format("paper element, gradational layout, 1 mm voxels: F(0) {:.4g} N ({:.3f} of the reference's), "
                    "F(0.45) {:.4g} N ({:.3f} of the reference's), F(0.45) / F(0) {:.4f} ({:.3f} of the reference's)",
                    g0, excess0, g45, excess45, g45 / g0, g45 / g0 / reference_ratio45[1.0]));
    ctx.check("paper_no_locking_gradational_1mm_nu0.45", excess45 / excess0, 1.0, kPaperRatioTolerance, "",
              "F(0.45) over the finite-strain reference's, divided by the same at Poisson 0, paper's element on the "
              "gradational layout, 1 mm voxels: at most 5 % above 1 (locking would make the element's excess over "
              "the reference grow with nu; its stiffness at 0 is the paper's element's own, docs/model.md section 5; "
              "measured 0.932: 1.106 at 0, 1.031 at 0.45)",
              CheckRule::at_most);
    ctx.check("paper_gradational_1mm_nu0.45_not_soft", excess45, 1.0, kPaperRatioTolerance, "",
              "F(0.45) of the paper's element on the gradational layout over the finite-strain reference's on the "
              "same 1 mm voxels: not more than 5 % below it (the volume term is carried in full; measured 1.031)",
              CheckRule::at_least);
  }
  ctx.plot("ratio", "Ball pressed into a bonded block: F(nu) / F(0) against Poisson's ratio, 2 mm voxels",
           {{"R 4 mm, 2 mm into 32 x 32 x 16 mm, voxel layout 2 mm, quasi-static",
             "Poisson ratio",
             "F(nu) / F(0)",
             {{"model", plot_nu, plot_model, true},
              {"finite-strain reference, same mesh", plot_nu, plot_reference},
              {"finite layer (Dimitriadis 2002, small strain)", plot_nu, plot_layer}}}});
}

namespace {

/// The 8 x 8 x 32 mm bar (1 mm voxels, E = 10 kPa) between frictionless ends: both end faces held
/// along z only, the top moved down by `strain` x the height; rigid motion taken out by the bottom
/// face's centre node (held in x and y) and the node at the middle of its x_max edge (held in y).
/// Uniaxial stress is the exact answer: a uniform strain, which the model reproduces exactly (the
/// patch test), lateral strain nu x the axial one, stress E x strain. Solved by Newton's method on
/// the model's own forces (static_newton.h: the static solver holds whole nodes only).
/// The bulge case's tolerance on both figures: 0.5 %, the 5 % tightened ten times (measured
/// 1.0004, 1.0007, 1.0007 at 0.3, 0.45, 0.49 on both layouts and elements: the finite strain of 0.1 %).
constexpr double kBulgeTolerance = 0.005;

struct SlidingBar {
  double widening{0};  ///< mean width change of the bar (x and y faces) / (nu x strain)
  double modulus{0};   ///< nominal stress / strain / E
  double residual_n{0};
};

SlidingBar sliding_bar(Layout r, ElementKind element, double nu, double strain) {
  const double e_kpa = 10.0;
  CalibrationOptions options;
  options.element = element;
  const auto p = make_physics_model(block_model(r, {8, 8, 32}, 1.0), tissue_nu(e_kpa, nu), {}, options);
  const Model& m = *p->model;
  const int nn = m.num_nodes();
  HeldCoordinates held(std::size_t(3 * nn), 0);
  Eigen::Matrix3Xd start = m.rest_positions;
  const double height = rest_max(m, 2) - rest_min(m, 2);
  const auto bottom = nodes_on_face(m, BoxFace::z_min), top = nodes_on_face(m, BoxFace::z_max);
  for (int i : bottom) held[std::size_t(3 * i + 2)] = 1;
  for (int i : top) held[std::size_t(3 * i + 2)] = 1, start(2, i) -= strain * height;
  const double cx = 0.5 * (rest_min(m, 0) + rest_max(m, 0)), cy = 0.5 * (rest_min(m, 1) + rest_max(m, 1));
  auto nearest_on_bottom = [&](double x, double y) {
    int best = -1;
    double d = std::numeric_limits<double>::infinity();
    for (int i : bottom)
      if (const double di = std::hypot(m.rest_positions(0, i) - x, m.rest_positions(1, i) - y); di < d)
        d = di, best = i;
    if (best < 0 || d > 1e-9) throw Error("the bar's bottom face has no node where the lateral pins go");
    return best;
  };
  const int centre = nearest_on_bottom(cx, cy), edge = nearest_on_bottom(rest_max(m, 0), cy);
  held[std::size_t(3 * centre)] = held[std::size_t(3 * centre + 1)] = held[std::size_t(3 * edge + 1)] = 1;
  SlidingBar out;
  SimState s = make_state(p);
  s.positions = newton_static_positions(*p, start, held, Eigen::Vector3d::Zero(), &out.residual_n);
  const double area = (rest_max(m, 0) - rest_min(m, 0)) * (rest_max(m, 1) - rest_min(m, 1));
  out.modulus = elastic_force_on(s, top, kThreads).z() / area / kKpaToNPerMm2 / strain / e_kpa;
  double widening = 0;
  for (int axis : {0, 1}) {
    const auto lo = nodes_on_face(m, axis == 0 ? BoxFace::x_min : BoxFace::y_min),
               hi = nodes_on_face(m, axis == 0 ? BoxFace::x_max : BoxFace::y_max);
    const double width = rest_max(m, axis) - rest_min(m, axis);
    widening += 0.5 * (mean_displacement(s, hi, axis) - mean_displacement(s, lo, axis)) / width;
  }
  out.widening = widening / (nu * strain);
  return out;
}

}  // namespace

void run_poisson_bulge(VerifyContext& ctx) {
  // The bar between frictionless ends (sliding_bar), compressed 0.1 % (small strain: the volume
  // term keeps det F, not tr eps, and near 0.5 its finite-strain share grows): uniaxial stress
  // exactly, so widening / (nu strain) and stress / strain / E are 1 for a correct model on every
  // layout and element. The former clamped ends, which cannot contract, added 2-6 % to both.
  std::vector<Layout> layouts = {Layout::gradational};
  if (ctx.full()) layouts.push_back(Layout::voxel);
  for (Layout r : layouts)
    for (ElementKind element : {ElementKind::hourglass, ElementKind::paper})
      for (double nu : {0.3, 0.45, 0.49}) {
        const SlidingBar b = sliding_bar(r, element, nu, 0.001);
        ctx.log(
            fmt::format("{} layout, {} element, Poisson {}: widening / (nu strain) {:.5f}, modulus / E {:.5f} "
                        "(largest force left {:.1g} N)",
                        layout_name(r), to_string(element), nu, b.widening, b.modulus, b.residual_n));
        const std::string name = fmt::format("{}_{}_nu{}", layout_name(r), to_string(element), nu);
        ctx.check("bulge_" + name, b.widening, 1.0, kBulgeTolerance, "",
                  "widening / (nu x axial strain) of the bar between frictionless ends, 0.1 % strain "
                  "(uniaxial stress: exact for a correct model)");
        ctx.check("modulus_" + name, b.modulus, 1.0, kBulgeTolerance, "",
                  "nominal stress / strain / E of the bar between frictionless ends, 0.1 % strain (uniaxial stress: "
                  "exact for a correct model)");
      }
}

void run_poisson_cantilever(VerifyContext& ctx) {
  // The 32 x 4 x 4 mm cantilever under its own weight on the voxel layout at 2, 1 and 0.5 mm voxels
  // (2, 4 and 8 elements through the thickness), Poisson 0.3, 0.45, 0.49, its static equilibrium
  // found by Newton's method on the model's own forces (newton_static_positions). Measured: -3.3,
  // -1.9, -1.4 % at 0.3; -7.9, -4.6, -3.3 % at 0.45; -9.7, -5.6, -4.0 % at 0.49 (13 s of CPU in all)
  const double length = 32.0, t = 4.0, e_kpa = 3000.0;
  // the tip's deflection over Timoshenko's (G = E / (2 (1 + nu)), kappa = 10 (1 + nu) / (12 + 11 nu):
  // square section) on layout r at voxel h, logged with the largest force left
  auto tip_ratio = [&](Layout r, double h, double nu, ElementKind element = ElementKind::hourglass) {
    const Eigen::Vector3i dims(int(std::lround(length / h)), int(std::lround(t / h)), int(std::lround(t / h)));
    CalibrationOptions options;
    options.element = element;
    const auto p = make_physics_model(block_model(r, dims, h), tissue_nu(e_kpa, nu), {}, options);
    double residual = 0;
    const Eigen::Matrix3Xd x = newton_static_positions(
        *p, p->model->rest_positions, held_nodes(p->model->num_nodes(), nodes_on_face(*p->model, BoxFace::x_min)),
        {0, 0, -kStandardGravityMmS2}, &residual);
    const auto tip_nodes = nodes_on_face(*p->model, BoxFace::x_max);
    double tip = 0;
    for (int i : tip_nodes) tip -= (x(2, i) - p->model->rest_positions(2, i)) / double(tip_nodes.size());
    const double q = 1000.0 * kKgM3ToKgPerMm3 * kStandardGravityMmS2 * 1e-3 * t * t;
    const double e = e_kpa * kKpaToNPerMm2, g = e / (2 * (1 + nu)), kappa = 10 * (1 + nu) / (12 + 11 * nu);
    const double ratio = tip / (q * std::pow(length, 4) / (8 * e * t * t * t * t / 12.0) +
                                q * length * length / (2 * kappa * g * t * t));
    ctx.log(
        fmt::format("{} layout, {} element, {} mm voxels, Poisson {}: tip / Timoshenko {:.4f} ({:+.1f} %), largest "
                    "force left {:.2g} N",
                    to_string(r), to_string(element), h, nu, ratio, 100 * (ratio - 1), residual));
    return ratio;
  };
  std::map<double, std::vector<double>> errors;  // by nu, at each voxel size
  const std::vector<double> hs = {2.0, 1.0, 0.5};
  std::vector<double> lh;
  std::map<double, std::vector<double>> le;
  for (double h : hs) {
    lh.push_back(std::log10(h));
    for (double nu : {0.3, 0.45, 0.49}) {
      const double ratio = tip_ratio(Layout::voxel, h, nu);
      errors[nu].push_back(ratio - 1);
      le[nu].push_back(std::log10(std::max(std::abs(ratio - 1), 1e-6)));
      if (h == hs.back())
        ctx.check(fmt::format("tip_ratio_nu{}", nu), ratio, 1.0, 0.05, "",
                  fmt::format("tip deflection / Timoshenko beam theory at {} mm voxels (8 elements through the "
                              "thickness; at Poisson 0 the same model reads -0.8 %: the beam solution's own accuracy "
                              "for an 8:1 beam clamped over its whole end face, whose clamp also holds the section's "
                              "Poisson contraction)",
                              h));
    }
  }
  for (const auto& [nu, e] : errors)
    for (std::size_t k = 1; k < e.size(); ++k)
      ctx.check(fmt::format("halving_{}mm_nu{}", hs[k], nu), std::abs(e[k]), std::max(0.8 * std::abs(e[k - 1]), 0.02),
                0.0, "",
                fmt::format("|tip / beam theory - 1| at {} mm: at most 0.8 x the error at {} mm, or within the 2 % "
                            "floor (the beam solution's own accuracy here); convergence as the voxels halve",
                            hs[k], hs[k - 1]),
                CheckRule::at_most);
  // the gradational layout (its interior elements grow inside the 4 mm section): within 5 % at
  // 0.5 and 0.25 mm (measured -1.5, -3.7, -4.4 % and -2.0, -3.8, -4.5 % at 0.3, 0.45, 0.49; at
  // 1 mm +2.3, -1.2, -2.3 %). Its error does not shrink from 0.5 to 0.25 mm: the large interior
  // elements keep one volume constraint each, as in the Hertz case (13 s of CPU)
  for (double h : {0.5, 0.25})
    for (double nu : {0.3, 0.45, 0.49}) {
      const double ratio = tip_ratio(Layout::gradational, h, nu);
      ctx.check(fmt::format("tip_ratio_gradational_{}mm_nu{}", h, nu), ratio, 1.0, 0.05, "",
                fmt::format("tip deflection / Timoshenko beam theory, gradational layout at {} mm voxels (the issue's "
                            "5 %)",
                            h));
    }
  // the paper's element (at Poisson 0 -33.2 / -3.7 % at 2 / 0.5 mm voxels: its bending stiffness):
  // its tip at nu over its own at 0, both over beam theory, so that stiffness cancels
  for (double h : {1.0, 0.5}) {
    const double at0 = tip_ratio(Layout::voxel, h, 0.0, ElementKind::paper);
    for (double nu : {0.3, 0.45, 0.49}) {
      const double ratio = tip_ratio(Layout::voxel, h, nu, ElementKind::paper) / at0;
      ctx.log(
          fmt::format("  paper element, {} mm voxels: (tip / Timoshenko) at {} over that at 0: {:.4f}", h, nu, ratio));
      if (h == 0.5)
        ctx.check(fmt::format("paper_tip_ratio_nu{}", nu), ratio, 1.0, kPaperRatioTolerance, "",
                  fmt::format("the paper element's tip / Timoshenko at Poisson {} over its own at 0, 0.5 mm voxels "
                              "(its bending stiffness at 0 cancels; the issue's 5 %)",
                              nu));
    }
  }
  ctx.plot("convergence", "Cantilever at tissue-like Poisson ratios: tip deflection error against voxel size, log-log",
           {{fmt::format("Beam {} x {} x {} mm clamped at one end, voxel layout, E = {} kPa", length, t, t, e_kpa),
             "log10 voxel size, mm",
             "log10 |tip / beam theory - 1|",
             {{"Poisson 0.3", lh, le[0.3], true},
              {"Poisson 0.45", lh, le[0.45], true},
              {"Poisson 0.49", lh, le[0.49], true}}}});
}

// --- the three layouts on the same scene -------------------------------------------------------

void run_layouts(VerifyContext& ctx) {
  // the same indentation (ball R 5, 1.5 mm into a 24 x 24 x 12 mm block) on the three layouts.
  // The uniform and gradational layouts' smallest elements are 2 voxels wide, so they are run at
  // 1 mm voxels (the same data as the voxel layout) and at 0.5 mm voxels (the same surface
  // elements as the voxel layout, the fair comparison of the models)
  struct Run {
    Layout r;
    double voxel_mm;
    std::shared_ptr<const PhysicsModel> phys;
    Indentation ind;
  };
  std::vector<Run> runs;
  for (const auto& [r, h] : std::vector<std::pair<Layout, double>>{{Layout::voxel, 1.0},
                                                                   {Layout::uniform, 1.0},
                                                                   {Layout::gradational, 1.0},
                                                                   {Layout::uniform, 0.5},
                                                                   {Layout::gradational, 0.5}}) {
    const Eigen::Vector3i dims = (Eigen::Vector3d(24, 24, 12) / h).array().round().cast<int>();
    Run run{r, h, make_physics_model(block_model(r, dims, h), tissue(10.0)), {}};
    run.ind = indent(run.phys, 5.0, 1.5, 12, 12);
    if (!run.ind.failure.empty())
      throw Error(fmt::format("{} indentation at {} mm voxels stopped: {}", layout_name(r), h, run.ind.failure));
    runs.push_back(std::move(run));
  }
  // vertical displacement of the top nodes on the 1 mm lattice (a 0.5 mm model has a node at
  // every one of them, at even lattice indices)
  const auto top_uz = [](const Run& run) {
    std::map<std::tuple<int, int>, double> uz;
    const Model& m = *run.phys->model;
    const double top = rest_max(m, 2);
    const int step = int(std::lround(1.0 / run.voxel_mm));
    for (int i = 0; i < m.num_nodes(); ++i)
      if (std::abs(m.rest_positions(2, i) - top) < 1e-9 && m.node_lattice(0, i) % step == 0 &&
          m.node_lattice(1, i) % step == 0)
        uz[{m.node_lattice(0, i) / step, m.node_lattice(1, i) / step}] =
            run.ind.final_positions(2, i) - m.rest_positions(2, i);
    return uz;
  };
  // forces compared at one depth, the shallowest final depth of the runs: the last 32-step
  // bin's mean depth depends on the time step (1.45 mm at 1 mm voxels, 1.48 mm at 0.5 mm), and
  // 2 % more depth is 3 % more force
  double depth = std::numeric_limits<double>::infinity();
  for (const Run& run : runs) depth = std::min(depth, run.ind.depth_mm.back());
  const auto force_at = [depth](const Indentation& ind) {
    const auto& d = ind.depth_mm;
    for (std::size_t k = 1; k < d.size(); ++k)
      if (d[k] >= depth && d[k] > d[k - 1])
        return ind.force_n[k - 1] + (ind.force_n[k] - ind.force_n[k - 1]) * (depth - d[k - 1]) / (d[k] - d[k - 1]);
    return ind.force_n.back();
  };
  const Run& voxel = runs[0];
  const auto ref = top_uz(voxel);
  double ref_max = 0;
  for (const auto& [k, v] : ref) ref_max = std::max(ref_max, std::abs(v));
  const double f_ref = force_at(voxel.ind);
  std::vector<PlotSeries> series;
  for (const Run& run : runs) {
    const double f = force_at(run.ind);
    const std::string name = fmt::format("{}, {} mm voxels", layout_name(run.r), run.voxel_mm);
    series.push_back({name, run.ind.depth_mm, run.ind.force_n});
    if (&run == &voxel) continue;
    const auto uz = top_uz(run);
    double sq = 0;
    int n = 0;
    for (const auto& [k, v] : ref)
      if (const auto it = uz.find(k); it != uz.end()) sq += (it->second - v) * (it->second - v), ++n;
    const double rms = n ? std::sqrt(sq / n) / ref_max : std::nan("");
    ctx.log(
        fmt::format("{}: {} elements, force {:.4g} N at {:.3f} mm against {:.4g} N (voxel layout, 1 mm): ratio "
                    "{:.3f}; top displacement RMS difference {:.3g} of the largest ({} nodes)",
                    name, run.phys->num_elements(), f, depth, f_ref, f / f_ref, rms, n));
    if (run.voxel_mm != 0.5) continue;
    // the same surface elements, the same material: the force may differ by the contact's
    // discretisation and the coarser interior (gradational), whose elements bend like
    // elasticity (the hourglass element): 5 %
    ctx.check(layout_name(run.r) + ".force_ratio", f / f_ref, 1.0, 0.05, "",
              "force at the final depth, 0.5 mm voxels (the voxel layout's element size) / the voxel-level model's "
              "(at the shallowest final depth of the runs)");
    ctx.check(layout_name(run.r) + ".displacement_difference", rms, 0.0, 0.05, "",
              "RMS difference of the top surface's vertical displacement from the voxel-level model's / its largest",
              CheckRule::at_most);
  }
  // the cost of the paper's reduction alone: gradational against uniform on the same voxels
  for (int k : {0, 1}) {
    const Run& u = runs[std::size_t(1 + 2 * k)];
    const Run& g = runs[std::size_t(2 + 2 * k)];
    ctx.check(fmt::format("gradational_over_uniform_{}mm", u.voxel_mm), force_at(g.ind) / force_at(u.ind), 1.0, 0.03,
              "",
              fmt::format("force of the gradational / the uniform layout on the same {} mm voxels (same surface "
                          "elements, coarser interior)",
                          u.voxel_mm));
  }
  ctx.plot("force-depth", "The same indentation on the three layouts: force against depth",
           {{"Ball R = 5 mm into a 24 x 24 x 12 mm block, E = 10 kPa", "depth, mm", "force, N", series}});
}

// --- the folded (brain-like) phantom: its counts, and hanging from its stem ---------------------

void run_folded(VerifyContext& ctx) {
  // the counts of the model scenes and the scale bench use: 214 voxels of 1 mm
  {
    PhantomShape shape;
    const VoxelGrid grid = phantom_grid("folded", 214, &shape);
    const Model m = build_model(grid);
    const double surface = double(m.num_surface_nodes()) / double(m.num_nodes());
    ctx.log(
        fmt::format("folded phantom 214^3 at 1 mm: {} tissue voxels, {} elements, {} nodes, {} on the surface "
                    "({:.1f} %)",
                    grid.count(), m.num_elements(), m.num_nodes(), m.num_surface_nodes(), 100 * surface));
    ctx.check("elements", double(m.num_elements()), 40000, 0, "", "elements of the gradational model (at least 40,000)",
              CheckRule::at_least);
    ctx.check("nodes", double(m.num_nodes()), 200000, 0, "", "nodes (at least 200,000)", CheckRule::at_least);
    ctx.check("surface_fraction", surface, 0.75, 0, "", "share of the nodes on the surface (at least 3/4: folded)",
              CheckRule::at_least);
    ctx.check("volume", m.total_volume_mm3() / double(grid.count()), 1.0, 1e-12, "",
              "the elements' volume / the tissue voxels' (the gradational model covers every voxel once)");
  }
  // hanging from its stem at half the size (107 voxels of 1 mm: 5 mm stem radius): the bottom
  // 3 mm of the stem held, gravity down, solved to static equilibrium. The support must carry
  // the whole weight, density x volume x g, and push straight up
  PhantomShape shape;
  const VoxelGrid grid = phantom_grid("folded", 107, &shape);
  const auto model = std::make_shared<const Model>(build_model(grid));
  const double e_kpa = 1000.0;  // stiff, so the hemispheres hang near their rest shape
  const auto p = make_physics_model(model, tissue(e_kpa));
  std::vector<int> stem;
  for (int i = 0; i < model->num_nodes(); ++i) {
    const Eigen::Vector3d x = model->rest_positions.col(i);
    if (x.z() <= shape.stem_center_mm.z() + 3.0 &&
        std::hypot(x.x() - shape.stem_center_mm.x(), x.y() - shape.stem_center_mm.y()) <= shape.stem_radius_mm + 0.5)
      stem.push_back(i);
  }
  SimState s = make_state(p);
  s.fix_nodes(stem);
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  // (the elastic forces of every element add up to zero for any rotation fit, so the support's
  // force differs from the weight only by the free nodes' imbalance, which falls long before the
  // positions stop moving: a loose stop suffices)
  StaticSolveSettings st = static_settings();
  st.tolerance_mm = 1e-4;
  st.max_iterations = 300;
  const StepReport rep = solve_static(s, st);
  if (s.failed()) throw Error("folded: the static solve failed: " + s.message);
  // the support's force on the held nodes balances their elastic force and their own weight
  double held_kg = 0;
  for (int i : stem) held_kg += p->node_mass_kg[std::size_t(i)];
  const Eigen::Vector3d g_n = s.gravity_mm_s2 * 1e-3;  // N per kg
  const Eigen::Vector3d support = -(elastic_force_on(s, stem, kThreads) + held_kg * g_n);
  const double weight = 1000.0 * kKgM3ToKgPerMm3 * model->total_volume_mm3() * kStandardGravityMmS2 * 1e-3;
  double sag = 0;
  for (int i = 0; i < model->num_nodes(); ++i) sag = std::max(sag, model->rest_positions(2, i) - s.positions(2, i));
  ctx.log(
      fmt::format("folded phantom 107^3 at 1 mm, E = {} kPa: {} nodes, {} held at the stem; weight {:.5g} N; "
                  "support ({:.5g}, {:.5g}, {:.5g}) N ({:+.2e} of the weight); largest sag {:.3g} mm; {} iterations",
                  e_kpa, model->num_nodes(), stem.size(), weight, support.x(), support.y(), support.z(),
                  support.z() / weight - 1.0, sag, rep.iterations));
  ctx.check("support_over_weight", support.z() / weight, 1.0, 1e-3, "",
            "upward force of the stem's support / (density x volume x g) at static equilibrium");
  ctx.check("support_sideways", std::hypot(support.x(), support.y()) / weight, 0.0, 1e-3, "",
            "sideways force of the support / weight (gravity is vertical)", CheckRule::at_most);
  ctx.check("mass", p->total_mass_kg() / (1000.0 * kKgM3ToKgPerMm3 * model->total_volume_mm3()), 1.0, 1e-9, "",
            "lumped mass / (density x volume)");
}

}  // namespace vx::cases
