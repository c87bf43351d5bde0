#include "scene/run_outputs.h"

#include <fmt/format.h>
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "base/version.h"
#include "render/plot.h"
#include "sim/contact.h"
#include "sim/probe.h"

namespace vx {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

json vec(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

const char* source_name(ObjectSource s) {
  switch (s) {
    case ObjectSource::phantom: return "phantom";
    case ObjectSource::volume: return "volume";
    case ObjectSource::model: return "model";
    case ObjectSource::box: return "box";
  }
  return "?";
}

}  // namespace

RunOutputs::RunOutputs(Simulation& sim, const DeviceSide& device, const PreparedScene& prepared,
                       const SceneOutputs& outputs, const fs::path& dir, std::int64_t steps)
    : device_(device), dir_(dir), outputs_(outputs), steps_(steps) {
  // what to record: only what was asked for
  if (outputs_.forces_csv || outputs_.plot) recorder_.emplace(sim, &device_, outputs_.forces_interval_s);
  series_ = outputs_.pvd_model || outputs_.pvd_surface;
  if (outputs_.pvd_model) {
    model_series_.emplace(dir_, "model", "vtu");
    model_writer_ = std::make_unique<ModelFrameWriter>(*prepared.model);
  }
  if (outputs_.pvd_surface) {
    surface_series_.emplace(dir_, "surface", "vtp");
    surface_writer_ = std::make_unique<SurfaceFrameWriter>(*prepared.surface);
  }
  if (series_ && sim.num_probes() > 0) probe_series_.emplace(dir_, "probes", "vtp");
  frame_every_ = std::max<std::int64_t>(1, std::llround(outputs_.pvd_interval_s / sim.dt_s()));
  if (series_) write_frame(sim);
}

RunOutputs::~RunOutputs() = default;

void RunOutputs::write_frame(Simulation& sim) {
  if (model_series_) {
    model_writer_->write(sim.state().positions, sim.state().velocities, model_series_->next_frame_path());
    model_series_->add(sim.time_s());
  }
  if (surface_series_) {
    surface_writer_->write(sim.surface_vertices(), surface_series_->next_frame_path());
    surface_series_->add(sim.time_s());
  }
  if (probe_series_) {
    write_probe_frame(sim, &device_, probe_series_->next_frame_path());
    probe_series_->add(sim.time_s());
  }
  ++frames_;
  last_frame_s_ = sim.time_s();
}

void RunOutputs::last_frame(Simulation& sim) {
  if (series_ && sim.time_s() > last_frame_s_) write_frame(sim);
}

void RunOutputs::after_step(Simulation& sim, std::int64_t k) {
  if (recorder_) recorder_->record(sim);
  if (series_ && (k % frame_every_ == 0 || k == steps_)) write_frame(sim);
}

void RunOutputs::finish(const Simulation& sim) {
  if (recorder_) recorder_->finish(sim);
  if (outputs_.forces_csv) {
    recorder_->write_csv(dir_ / "forces.csv");
    written_.push_back("forces.csv");
  } else {
    not_requested_.push_back("forces.csv");
  }
  if (outputs_.plot) {
    plot_forces(*recorder_, dir_ / "forces.png", references_);
    written_.push_back("forces.png");
  } else {
    not_requested_.push_back("forces.png");
  }
  for (auto* s : {&model_series_, &surface_series_, &probe_series_})
    if (*s) {
      (*s)->finish();
      written_.push_back((*s)->collection_path().filename().string());
    }
  if (!outputs_.pvd_model) not_requested_.push_back("model.pvd");
  if (!outputs_.pvd_surface) not_requested_.push_back("surface.pvd");
}

std::vector<ForceReference> scene_force_references(const Scene& s) {
  if (s.object.source != ObjectSource::box || s.object.build.dimensions != 3 || !s.material.hounsfield.empty() ||
      !s.material.inclusions.empty() || s.probes.size() != 1 || s.gravity_m_s2.norm() > 0)
    return {};
  const ProbeSettings& p = s.probes[0];
  if (p.geometry.shape != ProbeShape::sphere || p.drive != ProbeDrive::path || p.path.size() < 2) return {};
  // the one coordinate the path changes
  const Eigen::Vector3d p0 = p.path.front().position_mm;
  int axis = -1;
  for (const PathKey& k : p.path)
    for (int a = 0; a < 3; ++a)
      if (std::abs(k.position_mm[a] - p0[a]) > 1e-9) {
        if (axis >= 0 && axis != a) return {};
        axis = a;
      }
  if (axis < 0) return {};
  const Eigen::Vector3d& lo = s.object.box_min_mm;
  const Eigen::Vector3d& hi = s.object.box_max_mm;
  const double r = p.geometry.radius_mm;
  const bool from_max = p0[axis] - r >= hi[axis], from_min = p0[axis] + r <= lo[axis];
  if (!from_max && !from_min) return {};
  // the face opposite the pressed one is fixed, nothing else
  const auto opposite = BoxFace(2 * axis + (from_max ? 0 : 1));
  if (s.fixed.size() != 1 || !s.fixed[0].is_face || s.fixed[0].face != opposite) return {};
  for (int a = 0; a < 3; ++a)
    if (a != axis && (p0[a] - lo[a] < r || hi[a] - p0[a] < r)) return {};
  const Material& m = s.material.base;
  ForceReference ref;
  ref.e_kpa = m.youngs_modulus_kpa;
  ref.nu = m.poisson_ratio;
  ref.radius_mm = r;
  ref.layer_mm = hi[axis] - lo[axis];
  ref.title =
      fmt::format("finite-layer Hertz (E {:g} kPa, Poisson {:g}, layer {:g} mm)", ref.e_kpa, ref.nu, ref.layer_mm);
  return {ref};
}

json run_summary_json(const Scene& scene, const fs::path& scene_file, const PreparedScene& prepared,
                      const Simulation& sim, const RunOutputs& outputs, double wall_s) {
  const ForceRecorder* recorder = outputs.forces();
  const SceneOutputs& out = scene.outputs;
  const double dt = sim.dt_s();
  const std::int64_t frames = outputs.frames();
  const bool pvd = outputs.series();
  const SimulationCounters& c = sim.counters();
  const DeviceSide& device = outputs.device();
  const DeviceSideCounters& dc = device.counters();
  const Model& m = *prepared.model;
  const bool stable = !sim.failed() && sim.state().positions.allFinite();
  json j;
  j["scene"] = fs::absolute(scene_file).string();
  j["description"] = scene.description;
  j["voxelastic_version"] = vx::kVersion;
  j["steps"] = c.steps;
  j["sim_time_s"] = sim.time_s();
  j["wall_s"] = wall_s;
  j["realtime_factor"] = wall_s > 0 ? sim.time_s() / wall_s : 0.0;
  j["elements"] = m.num_elements();
  j["nodes"] = m.num_nodes();
  j["vertex_entries"] = m.num_vertex_entries();
  j["surface_nodes"] = m.num_surface_nodes();
  j["fixed_nodes"] = prepared.fixed_nodes;
  j["integrator"] = to_string(scene.integrator);
  j["dt_s"] = dt;
  j["dt_stable_estimate_s"] =
      std::isfinite(prepared.dt_stable_estimate_s) ? json(prepared.dt_stable_estimate_s) : json(nullptr);
  j["threads"] = prepared.settings.integrator.threads;
  {
    const IntegratorSettings& in = prepared.settings.integrator;
    json conf = {{"integrator", to_string(in.kind)}, {"dt_s", in.time_step_s}, {"default", !scene.integrator_given}};
    if (in.kind == IntegratorKind::implicit) {
      conf["iterations"] = in.max_iterations;
      conf["residual_tolerance_n"] = in.residual_tolerance_n;
      conf["region_radius_mm"] = in.region_radius_mm;
      conf["sweep_precision"] = in.single_precision_sweeps ? "single" : "double";
    }
    const PhysicsModel& p = *prepared.physics;
    conf["mass_scaling"] = {{"factor", p.mass_scaling.factor},
                            {"time_step_s", p.mass_scaling.time_step_s},
                            {"scaled_nodes", p.scaled_nodes},
                            {"added_mass_kg", p.added_mass_kg}};
    j["configuration"] = conf;
  }
  if (const auto& e = prepared.region_stiffening) {
    // the regional solves' estimated over-stiffening on this support (docs/model.md section 7)
    j["region_stiffening"] = {{"probe", prepared.region_stiffening_probe},
                              {"estimated_force_ratio", e->force_ratio},
                              {"estimated_force_error_rel", e->error_rel()},
                              {"warned", e->error_rel() > kRegionStiffeningWarnRel},
                              {"compliance_full_mm_n", e->compliance_full_mm_n},
                              {"compliance_region_mm_n", e->compliance_region_mm_n},
                              {"region_nodes", e->region_nodes},
                              {"far_nodes", e->far_nodes},
                              {"estimate_s", e->seconds}};
  }
  j["stable"] = stable;
  j["status"] = to_string(sim.state().status);
  j["message"] = sim.state().message;
  j["max_force_n"] = recorder ? recorder->max_force_n() : 0.0;
  j["max_step_force_n"] = recorder ? recorder->max_step_force_n() : 0.0;
  j["forces_interval_s"] = out.forces_interval_s;
  j["object"] = {{"source", source_name(scene.object.source)},
                 {"resolution", to_string(m.layout)},
                 {"bounds_mm", {{"min", vec(prepared.bounds_min_mm)}, {"max", vec(prepared.bounds_max_mm)}}},
                 {"mass_kg", prepared.physics->total_mass_kg()},
                 {"spacing_mm", vec(m.grid.spacing_mm)}};
  j["material"] = {{"youngs_modulus_kpa", scene.material.base.youngs_modulus_kpa},
                   {"poisson_ratio", scene.material.base.poisson_ratio},
                   {"density_kg_m3", scene.material.base.density_kg_m3},
                   {"damping", scene.material.base.damping_ratio},
                   {"element", to_string(scene.material.element)},
                   {"element_modulus_kpa", {{"min", prepared.min_modulus_kpa}, {"max", prepared.max_modulus_kpa}}},
                   {"heterogeneous_elements", prepared.heterogeneous_elements}};
  json probes = json::array();
  for (int i = 0; i < sim.num_probes(); ++i) {
    const ProbeSettings& p = prepared.settings.probes[std::size_t(i)];
    const ProbeOutput& po = sim.probe(i);
    probes.push_back({{"name", p.name},
                      {"shape", to_string(p.geometry.shape)},
                      {"drive", to_string(p.drive)},
                      {"max_force_n", recorder ? recorder->max_force_n(i) : 0.0},
                      {"final_position_mm", vec(po.pose.position_mm)},
                      {"final_force_n", vec(po.raw_force_n)}});
  }
  j["probes"] = probes;
  j["walls"] = scene.workspace.enabled
                   ? json{{"min_mm", vec(scene.workspace.min_mm)},
                          {"max_mm", vec(scene.workspace.max_mm)},
                          {"max_force_n", recorder ? recorder->max_wall_force_n() : 0.0},
                          {"impulse_n_s", recorder ? vec(recorder->wall_impulse_n_s()) : json(nullptr)}}
                   : json(nullptr);
  j["device"] = device.has_device() ? json{{"update_interval_s", device.settings().device->update_interval_s},
                                           {"average_steps", device.settings().device->average_steps},
                                           {"mean_preserving", device.settings().device->mean_preserving}}
                                    : json(nullptr);
  j["work"] = {{"contact_passes", c.contact_passes},
               {"narrow_phase_tests", c.contact.narrow_tests},
               {"broad_phase_tests", c.contact.broad_tests},
               {"broad_phase_rebuilds", c.contact.rebuilds},
               {"node_contacts", c.contact.contacts},
               {"wall_contacts", c.contact.wall_contacts},
               {"device_shaping_steps", dc.device_shaping_steps},
               {"surface_updates", c.surface_updates},
               {"output_frames", frames},
               {"force_rows", recorder ? json(recorder->rows().size()) : json(0)}};
  j["skipped"] = {{"contact_passes", c.contact_passes_skipped},
                  {"narrow_phase_tests", c.contact.narrow_tests_skipped},
                  {"device_shaping_steps", dc.device_shaping_skipped},
                  {"surface_updates", c.surface_updates_skipped},
                  {"steps_without_output_frame", c.steps - std::max<std::int64_t>(0, frames - (pvd ? 1 : 0))},
                  {"sleeping_element_updates", c.sleeping_element_updates},
                  {"sleeping_node_solves", c.sleeping_node_solves},
                  {"steps_at_rest", c.steps_at_rest},
                  {"outputs_not_requested", outputs.not_requested()}};
  j["rest"] = {{"sleeps", c.sleeps},
               {"last_sleep_s", c.last_sleep_s},
               {"last_sleep_since_release_s", c.last_sleep_since_release_s},
               {"last_sleep_offset_mm", c.last_sleep_offset_mm},
               {"last_release_offset_mm", c.last_release_offset_mm},
               {"last_sleep_cause", to_string(c.last_sleep_cause)}};
  j["warnings"] = prepared.warnings;
  std::vector<std::string> written = outputs.written();
  written.push_back("summary.json");
  j["outputs"] = written;
  return j;
}

}  // namespace vx
