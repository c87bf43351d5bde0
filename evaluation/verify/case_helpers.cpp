#include "verify/case_helpers.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "convert/threshold.h"
#include "model/gradational_builder.h"
#include "sim/contact.h"
#include "sim/simulation.h"
#include "sim/time_step.h"

namespace vx::cases {

std::shared_ptr<const Model> block_model(Layout r, const Eigen::Vector3i& dims, double h) {
  GridGeometry g;
  g.dims = dims;
  g.spacing_mm = Eigen::Vector3d::Constant(h);
  g.origin_mm = Eigen::Vector3d::Constant(0.5 * h);
  VoxelGrid grid(g);
  std::fill(grid.data().begin(), grid.data().end(), std::uint8_t(1));
  BuildSettings b;
  b.layout = r;
  return std::make_shared<const Model>(build_model(grid, b));
}

Material tissue(double e_kpa, double damping) {
  Material m;
  m.youngs_modulus_kpa = e_kpa;
  m.density_kg_m3 = 1000.0;
  m.damping_ratio = damping;
  m.poisson_ratio = 0.0;
  return m;
}

StaticSolveSettings static_settings() {
  StaticSolveSettings s;
  s.max_iterations = 3000;
  s.tolerance_mm = 1e-9;
  s.threads = kThreads;
  return s;
}

IntegratorSettings integrator(IntegratorKind kind, double dt_s) {
  IntegratorSettings s;
  s.kind = kind;
  s.time_step_s = dt_s;
  s.threads = kThreads;
  return s;
}

double reference_step_s(const PhysicsModel& p, IntegratorKind kind) {
  return stable_time_step(p, kind == IntegratorKind::implicit ? IntegratorKind::symplectic_euler : kind);
}

double rest_min(const Model& m, int axis) { return m.rest_positions.row(axis).minCoeff(); }
double rest_max(const Model& m, int axis) { return m.rest_positions.row(axis).maxCoeff(); }

double mean_displacement(const SimState& s, const std::vector<int>& nodes, int axis) {
  double sum = 0;
  for (int i : nodes) sum += s.positions(axis, i) - s.physics->model->rest_positions(axis, i);
  return nodes.empty() ? 0.0 : sum / double(nodes.size());
}

double slope_through_origin(const std::vector<double>& x, const std::vector<double>& y) {
  double sxy = 0, sxx = 0;
  for (std::size_t i = 0; i < x.size(); ++i) sxy += x[i] * y[i], sxx += x[i] * x[i];
  return sxx > 0 ? sxy / sxx : std::nan("");
}

double fitted_slope(const std::vector<double>& x, const std::vector<double>& y) {
  const double n = double(x.size());
  if (x.size() < 2) return std::nan("");
  double mx = 0, my = 0;
  for (std::size_t i = 0; i < x.size(); ++i) mx += x[i], my += y[i];
  mx /= n, my /= n;
  double sxy = 0, sxx = 0;
  for (std::size_t i = 0; i < x.size(); ++i) sxy += (x[i] - mx) * (y[i] - my), sxx += (x[i] - mx) * (x[i] - mx);
  return sxx > 0 ? sxy / sxx : std::nan("");
}

double energy(const SimState& s) {
  const Energies e = compute_energies(s, kThreads);
  return e.kinetic + e.elastic + e.gravitational;
}

std::string layout_name(Layout r) { return to_string(r); }

Indentation indent(const std::shared_ptr<const PhysicsModel>& p, double radius_mm, double depth_mm, double x_mm,
                   double y_mm, double speed_mm_s) {
  const Model& m = *p->model;
  SimulationSettings s;
  s.integrator = integrator(IntegratorKind::symplectic_euler, 0.5 * stable_time_step(*p, IntegratorKind::symplectic_euler));
  s.fixed_nodes = nodes_on_face(m, BoxFace::z_min);
  const double top = rest_max(m, 2), gap = 0.2, t_end = (gap + depth_mm) / speed_mm_s;
  ProbeSettings probe;
  probe.name = "ball";
  probe.geometry.radius_mm = radius_mm;
  probe.path = {{0.0, {x_mm, y_mm, top + radius_mm + gap}}, {t_end, {x_mm, y_mm, top + radius_mm - depth_mm}}};
  s.probes = {probe};
  Simulation sim(p, s);
  Indentation out;
  double sum_f = 0, sum_d = 0;
  int n = 0;
  while (sim.time_s() < t_end - 0.5 * sim.dt_s()) {
    if (sim.step() != StepStatus::ok) {
      out.failure = sim.state().message;
      break;
    }
    sum_f += sim.probe(0).raw_force_n.z();
    sum_d += top - (sim.probe(0).pose.position_mm.z() - radius_mm);
    if (++n < 32) continue;
    out.depth_mm.push_back(sum_d / n);
    out.force_n.push_back(sum_f / n);
    sum_f = sum_d = 0;
    n = 0;
  }
  out.final_positions = sim.state().positions;
  return out;
}

bool runs_stably(const std::shared_ptr<const PhysicsModel>& p, IntegratorKind kind, double dt, int steps) {
  SimState s = make_state(p);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < s.num_nodes(); ++i) s.velocities.col(i) = Eigen::Vector3d(u(rng), u(rng), u(rng));
  const double e0 = energy(s);
  auto integ = make_integrator(integrator(kind, dt));
  integ->advance(s, steps);
  // unstable: the runaway guard stopped it, or the amplitude grew 100-fold. A stable run near its
  // limit keeps a bounded but strongly oscillating discrete energy (the invariant of symplectic
  // Euler degenerates as omega dt -> 2), so the threshold must be far above the initial energy;
  // beyond the limit the growth is exponential and crosses it within a few hundred steps.
  return !s.failed() && s.positions.allFinite() && energy(s) < 1e4 * e0;
}

VoxelGrid phantom_grid(const std::string& name, int size, PhantomShape* shape) {
  PhantomSettings ps;
  ps.name = name;
  ps.size = size;
  const Volume v = make_phantom(ps, shape);
  HuRange r;
  r.lo = 0.5 * (ps.tissue_hu + ps.air_hu);
  return threshold(v, r);
}

}  // namespace vx::cases
