// The verify cases on robustness: extreme inputs (a teleported probe, a very stiff object, a
// crushed and an inverted one) recover or are flagged, never NaN; and a stiff lesion in soft
// tissue is felt by palpation.
#include <fmt/format.h>

#include <Eigen/Dense>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>
#include <nlohmann/json.hpp>

#include "base/error.h"
#include "physics/calibration.h"
#include "scene/palpation_map.h"
#include "scene/scene.h"
#include "sim/contact.h"
#include "sim/simulation.h"
#include "sim/state.h"
#include "sim/time_step.h"
#include "verify/case_helpers.h"
#include "verify/cases.h"

namespace vx::cases {

// --- stability: extreme inputs -----------------------------------------------------------------

namespace {

/// Root-mean-square distance between the state's shape and its rest shape after the best rigid
/// alignment (Kabsch), mm.
double shape_error_mm(const SimState& s) {
  const Eigen::Matrix3Xd& x0 = s.physics->model->rest_positions;
  const Eigen::Vector3d c0 = x0.rowwise().mean(), c = s.positions.rowwise().mean();
  const Eigen::Matrix3Xd a = x0.colwise() - c0, b = s.positions.colwise() - c;
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(b * a.transpose(), Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
  const Eigen::Matrix3d r = svd.matrixV() * d * svd.matrixU().transpose();  // rotates current onto rest
  return std::sqrt(((r * b) - a).colwise().squaredNorm().mean());
}

/// Elements whose fitted deformation A = sum_i w_i r_i R0_i^T has det <= 0 (inverted or flat).
std::int64_t inverted_elements(const SimState& s) {
  const PhysicsModel& p = *s.physics;
  const Model& m = *p.model;
  std::int64_t n = 0;
  for (int e = 0; e < m.num_elements(); ++e) {
    const int b = m.element_offsets[e], end = m.element_offsets[e + 1];
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    double w = 0;
    for (int j = b; j < end; ++j) c += p.entry_weight[j] * s.positions.col(m.element_vertices[j]), w += p.entry_weight[j];
    c /= w;
    Eigen::Matrix3d a = Eigen::Matrix3d::Zero();
    for (int j = b; j < end; ++j)
      a += (s.positions.col(m.element_vertices[j]) - c) * p.entry_rest_weighted.col(j).transpose();
    if (a.determinant() <= 0) ++n;
  }
  return n;
}

}  // namespace

void run_extreme(VerifyContext& ctx) {
  // (1) a probe teleported deep into the tissue, held, then pulled out: recovers or is flagged
  {
    const auto p = make_physics_model(block_model(Layout::gradational, {16, 16, 16}, 1.0), tissue(10.0, 0.3));
    SimulationSettings s;
    s.integrator = integrator(IntegratorKind::symplectic_euler, 0.5 * stable_time_step(*p, IntegratorKind::symplectic_euler));
    s.fixed_nodes = nodes_on_face(*p->model, BoxFace::z_min);
    ProbeSettings probe;
    probe.name = "ball";
    probe.geometry.radius_mm = 4.0;
    const Eigen::Vector3d above(8, 8, 21), deep(8, 8, 13);
    probe.path = {{0.0, above}, {0.01, above}, {0.0101, deep}, {0.05, deep}, {0.0501, above}};
    s.probes = {probe};
    bool finite = true, flagged = false, rejected = false;
    double final_disp = 0.0;  // largest displacement from rest over the last 0.1 s
    std::string message;
    try {
      Simulation sim(p, s);
      while (sim.time_s() < 2.0) {
        if (sim.step() != StepStatus::ok) {
          flagged = !sim.state().message.empty();
          message = sim.state().message;
          break;
        }
        if (!sim.state().positions.allFinite()) finite = false;
        if (sim.time_s() >= 1.9)
          final_disp = std::max(final_disp, (sim.state().positions - p->model->rest_positions).colwise().norm().maxCoeff());
      }
      finite = finite && sim.state().positions.allFinite();
      if (!finite) final_disp = std::nan("");
    } catch (const Error& e) {
      rejected = true;  // refused up front with a message: flagged before any step
      message = e.what();
    }
    ctx.log(fmt::format("teleported probe: {}{}", rejected ? "refused: " : flagged ? "flagged: " : "ran through",
                        rejected || flagged ? message : fmt::format(", largest displacement from rest over 1.9-2.0 s {:.3g} mm", final_disp)));
    ctx.check("teleport.finite", finite ? 1.0 : 0.0, 1.0, 0.0, "", "1 when no position ever became NaN or infinite");
    // recovered: within a tenth of a voxel of rest 1.9-2.0 s after the probe left (damping 0.3).
    // Every free node collides, so the teleported ball throws the nodes inside it out (up to
    // 31 mm) and the block rings in its slow modes, which element damping (relative to each
    // element's own frequency) decays with a time constant of about 0.5 s: 0.9 mm at 0.4 s,
    // 0.09 mm at 1.5 s, 0.035 mm at 2 s (measured)
    const bool recovered = std::isfinite(final_disp) && final_disp < 0.1;
    ctx.check("teleport.recovered_or_flagged", (recovered || flagged || rejected) ? 1.0 : 0.0, 1.0, 0.0, "",
              "1 when the tissue returned to rest (< 0.1 mm over 1.9-2.0 s) after the probe left, or the run was flagged "
              "with a message");
  }
  // (2) very high stiffness: 1 GPa runs stably at its estimated step, and a soft-tissue step is flagged
  {
    const auto p = make_physics_model(block_model(Layout::gradational, {8, 8, 8}, 1.0), tissue(1e6, 0.1));
    const double est = stable_time_step(*p, IntegratorKind::symplectic_euler);
    ctx.check("stiff.stable_at_estimate", runs_stably(p, IntegratorKind::symplectic_euler, 0.5 * est, 2000) ? 1.0 : 0.0,
              1.0, 0.0, "", "1 when E = 1 GPa runs 2000 steps at half its estimated stable step with bounded energy");
    SimState s = make_state(p);
    s.velocities.setConstant(1.0);
    s.velocities.col(0) *= -1.0;
    auto integ = make_integrator(integrator(IntegratorKind::symplectic_euler, 1e-4));
    integ->advance(s, 2000);
    ctx.log(fmt::format("E = 1 GPa at dt = 1e-4 s ({:.0f}x its stable step): status {}, '{}'", 1e-4 / est,
                        to_string(s.status), s.message));
    ctx.check("stiff.flagged_at_soft_step", s.failed() && !s.message.empty() ? 1.0 : 0.0, 1.0, 0.0, "",
              "1 when a step far above the limit is flagged (status and message) instead of running on");
    ctx.check("stiff.finite_after_flag", s.positions.allFinite() && s.velocities.allFinite() ? 1.0 : 0.0, 1.0, 0.0, "",
              "1 when the flagged state holds no NaN (the failing step is not applied)");
  }
  // (3) a crushed object (flattened to 2 % of its height) and (4) an inverted one (mirrored):
  // free, no gravity, damped; each element's rotation fit is proper, so the shape comes back
  const auto model = block_model(Layout::gradational, {12, 12, 12}, 1.0);
  const auto p = make_physics_model(model, tissue(10.0, 0.5));
  const double diag = (model->rest_positions.rowwise().maxCoeff() - model->rest_positions.rowwise().minCoeff()).norm();
  std::vector<PlotSeries> series;
  for (const char* what : {"crushed", "inverted"}) {
    SimState s = make_state(p);
    const double z0 = rest_min(*model, 2), z1 = rest_max(*model, 2);
    for (int i = 0; i < s.num_nodes(); ++i)
      s.positions(2, i) = std::string(what) == "crushed" ? z0 + 0.02 * (s.positions(2, i) - z0) : z0 + z1 - s.positions(2, i);
    const std::int64_t inverted0 = inverted_elements(s);
    auto integ = make_integrator(integrator(IntegratorKind::symplectic_euler, 0.5 * stable_time_step(*p, IntegratorKind::symplectic_euler)));
    std::vector<double> t, err;
    bool finite = true;
    while (s.time_s < 0.3 && !s.failed()) {
      integ->advance(s, 20);
      finite = finite && s.positions.allFinite();
      t.push_back(s.time_s);
      err.push_back(shape_error_mm(s) / diag);
    }
    const double final_err = err.empty() ? std::nan("") : err.back();
    ctx.log(fmt::format("{}: {} of {} elements inverted or flat at the start, {} after 0.3 s; shape error / diagonal "
                        "{:.3g}{}",
                        what, inverted0, model->num_elements(), inverted_elements(s), final_err,
                        s.failed() ? ", flagged: " + s.message : ""));
    const std::string name = what;
    ctx.check(name + ".finite", finite ? 1.0 : 0.0, 1.0, 0.0, "", "1 when no position became NaN or infinite");
    ctx.check(name + ".shape_error", s.failed() ? std::nan("") : final_err, 0.0, 0.01, "",
              "RMS distance from the rest shape after rigid alignment / diagonal after 0.3 s (recovered: < 1 %)",
              CheckRule::at_most);
    ctx.check(name + ".inverted_elements_left", double(inverted_elements(s)), 0.0, 0.0, "elements",
              "elements still inverted or flat after 0.3 s");
    series.push_back({name, t, err});
  }
  ctx.plot("recovery", "Recovery of a crushed and an inverted cube: shape error against time",
           {{"Gradational 12^3 mm cube, E = 10 kPa, damping 0.5, free", "time, s", "shape error / diagonal", series}});
}

// --- heterogeneous tissue: a stiff lesion --------------------------------------------------------

void run_lesion(VerifyContext& ctx) {
  // a 40 x 24 x 16 mm block (5 kPa) with a 50 kPa sphere (radius 4 mm, its top 2 mm under the
  // surface) under x = 12; the ball presses 2 mm over it and over x = 28 (as far from the other end)
  const auto model = block_model(Layout::gradational, {40, 24, 16}, 1.0);
  SceneMaterial sm;
  sm.base = tissue(5.0, 0.2);
  sm.inclusions.push_back({Eigen::Vector3d(12, 12, 10), 4.0, 50.0, 0.0});
  const MaterialField field = material_field(*model, sm, nullptr);
  const auto p = make_physics_model(model, sm.base, field);
  const Indentation over = indent(p, 4.0, 2.0, 12, 12), away = indent(p, 4.0, 2.0, 28, 12);
  if (!over.failure.empty() || !away.failure.empty()) throw Error("an indentation stopped: " + over.failure + away.failure);
  const double f_over = over.force_n.back(), f_away = away.force_n.back();
  ctx.log(fmt::format("force at 2 mm: {:.4g} N over the lesion, {:.4g} N away from it (x{:.2f})", f_over, f_away,
                      f_over / f_away));
  // the contact (radius sqrt(R d) = 2.8 mm) strains tissue down to about 3 contact radii, which
  // the 10x stiffer lesion largely fills: the force must rise clearly; 1.3 is a safe floor
  ctx.check("force_ratio", f_over / f_away, 1.3, 0.0, "",
            "force over the lesion / force away from it at 2 mm depth", CheckRule::at_least);
  ctx.plot("force-depth", "Palpation: force against depth over the stiff lesion and away from it",
           {{"Ball R = 4 mm into a 5 kPa block with a 50 kPa lesion (gradational)", "depth, mm", "force, N",
             {{"over the lesion", over.depth_mm, over.force_n}, {"away from it", away.depth_mm, away.force_n}}}});
}

// --- palpation maps: where is the lesion, and how does it fade with depth ------------------------

void run_palpation_map(VerifyContext& ctx) {
  // block-lesion 40 (1 mm voxels): a 32 x 24 x 16 mm block (top at z = 8 mm), tissue 5 kPa, a
  // 4 mm lesion of 50 kPa at (4, -2) whose top lies 1, 2.5 and 4 mm under the top; held at its
  // base, mapped from +z by a 4 mm ball pressed 2 mm every 2 mm, in the fast configuration
  const Eigen::Vector2d truth(4.0, -2.0);
  const double radius = 4.0;
  const std::vector<double> depths{1.0, 2.5, 4.0};
  std::vector<double> contrast, error;
  PlotSeries profile_series[3];
  for (std::size_t k = 0; k < depths.size(); ++k) {
    const double zc = 8.0 - radius - depths[k];
    const nlohmann::json j = {
        {"object", {{"phantom", "block-lesion"}, {"size", 40}, {"lesion_center_mm", {truth.x(), truth.y(), zc}},
                    {"lesion_radius_mm", radius}}},
        {"material", {{"youngs_modulus_kpa", 5}, {"damping", 0.2},
                      {"hounsfield_table", {{{"hu", 40}, {"youngs_modulus_kpa", 5}}, {{"hu", 120}, {"youngs_modulus_kpa", 50}}}}}},
        {"fixed", {"z_min"}},
        {"duration_s", 1.0},
        {"threads", kThreads}};
    const PreparedScene prepared = prepare_scene(parse_scene(j, ".", "palpation-map case"));
    PalpationMapSettings m;
    m.spacing_mm = 2.0;
    m.threads = kThreads;  // cases run in parallel
    const PalpationMap map = palpation_map(prepared, m);
    const PalpationSummary s = summarize_palpation_map(map);
    if (s.failed > 0) throw Error(fmt::format("{} presses failed", s.failed));
    contrast.push_back(s.contrast);
    error.push_back((s.lesion_estimate_mm.head<2>() - truth).norm());
    ctx.log(
        fmt::format("lesion top {:g} mm deep: {} presses in {:.1f} s; stiffness {:.4g} N/mm (median) to {:.4g}; "
                    "contrast {:.3f}; estimate ({:.2f}, {:.2f}) mm, {:.2f} mm from the lesion's axis; {} points above "
                    "the threshold",
                    depths[k], s.points, map.wall_s, s.background_n_mm, s.peak_n_mm, s.contrast,
                    s.lesion_estimate_mm.x(), s.lesion_estimate_mm.y(), error.back(), s.points_above));
    // the profile along x through the lesion's row
    profile_series[k].title = fmt::format("lesion top {:g} mm deep", depths[k]);
    profile_series[k].with_points = true;
    for (const PalpationPoint& p : map.points)
      if (std::abs(p.v_mm - truth.y()) < 0.5 * m.spacing_mm + 1e-9) {
        profile_series[k].x.push_back(p.u_mm);
        profile_series[k].y.push_back(p.stiffness_n_mm);
      }
    const std::string d = fmt::format("depth_{:g}mm", depths[k]);
    // the grid is 2 mm: the estimate lands within one spacing of the lesion's axis
    ctx.check(d + ".estimate_error", error.back(), 0.0, 2.0, "mm",
              "in-plane distance from the stiffness-weighted centroid of the points above the threshold to the lesion's "
              "axis",
              CheckRule::at_most);
  }
  ctx.check("contrast_shallow", contrast[0], 1.5, 0.0, "",
            "peak / surrounding stiffness with the lesion's top 1 mm deep (the 10x stiffer lesion fills the strained "
            "region under the 2.8 mm contact)",
            CheckRule::at_least);
  ctx.check("contrast_falls_with_depth", contrast[0] > contrast[1] && contrast[1] > contrast[2] && contrast[2] > 1.0 ? 1.0 : 0.0,
            1.0, 0.0, "", "1 when the contrast falls strictly from 1 to 2.5 to 4 mm deep and stays above 1");
  ctx.plot("profile", "Palpation map: stiffness along x through the lesion, three lesion depths",
           {{"4 mm ball pressed 2 mm into a 5 kPa block over a 50 kPa lesion (r 4 mm) at x = 4 mm", "x, mm",
             "stiffness, N/mm", {profile_series[0], profile_series[1], profile_series[2]}}});
}

}  // namespace vx::cases
