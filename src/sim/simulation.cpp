#include "sim/simulation.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "base/error.h"

namespace vx {

std::vector<std::int32_t> collidable_nodes(const Model& model, const std::vector<std::uint8_t>& fixed) {
  std::vector<std::int32_t> nodes;
  for (int i = 0; i < model.num_nodes(); ++i)
    if (!(std::size_t(i) < fixed.size() && fixed[std::size_t(i)])) nodes.push_back(i);
  return nodes;
}

double surface_node_spacing_mm(const Model& model) { return model.grid.spacing_mm.mean(); }

Simulation::Simulation(std::shared_ptr<const PhysicsModel> physics, SimulationSettings settings)
    : physics_(std::move(physics)), settings_(std::move(settings)) {
  if (!physics_ || !physics_->model) throw Error("simulation: no physics model");
  const Model& model = *physics_->model;
  const int nn = model.num_nodes();

  // check the settings against the model
  std::ostringstream err;
  for (std::size_t i = 0; i < settings_.probes.size(); ++i)
    if (const std::string bad = settings_.probes[i].validate(); !bad.empty())
      err << "probe " << i << " (" << settings_.probes[i].name << "): " << bad;
  for (const int i : settings_.fixed_nodes)
    if (i < 0 || i >= nn) {
      err << "fixed node " << i << " is not a node of the model (0.." << nn - 1 << "); ";
      break;
    }
  if (settings_.workspace.enabled && !(settings_.workspace.min_mm.array() < settings_.workspace.max_mm.array()).all())
    err << "workspace: min must be below max on every axis; ";
  if (!settings_.gravity_mm_s2.allFinite()) err << "gravity is not finite; ";
  if (settings_.surface && settings_.surface->model_nodes != nn)
    err << "surface is embedded in a model of " << settings_.surface->model_nodes << " nodes, this one has " << nn
        << "; ";
  if (physics_->is_2d()) {
    // a slice model meets each probe in the plane: shapes whose cut by the plane is a circle, a
    // rounded rod or a line (docs/model.md section 12.2)
    const Eigen::Vector3d n = physics_->plane_normal();
    for (std::size_t i = 0; i < settings_.probes.size(); ++i)
      if (const std::string bad = slice_probe_problem(settings_.probes[i].geometry, n); !bad.empty())
        err << "probe " << i << " (" << settings_.probes[i].name << "): " << bad
            << "; a sphere is a circle in the plane of any slice; ";
  }
  if (const std::string bad = err.str(); !bad.empty()) throw Error("simulation: " + bad);

  // state, integrator
  state_ = make_state(physics_);
  state_.gravity_mm_s2 = settings_.gravity_mm_s2;
  if (physics_->is_2d()) {
    // plane stress: the slice carries only the in-plane part of gravity
    const Eigen::Vector3d n = physics_->plane_normal();
    state_.gravity_mm_s2 -= n * n.dot(state_.gravity_mm_s2);
  }
  if (!settings_.fixed_nodes.empty()) state_.fix_nodes(settings_.fixed_nodes);
  integrator_ = make_integrator(settings_.integrator);

  // probes and contact
  const std::size_t np = settings_.probes.size();
  for (const auto& p : settings_.probes) {
    drivers_.emplace_back(p);
    geometry_.push_back(p.geometry);
  }
  poses_.resize(np);
  raw_.assign(np, Eigen::Vector3d::Zero());
  contacts_.assign(np, 0);
  collide_ = np > 0 || settings_.workspace.enabled;
  ContactSettings contact = settings_.contact;
  if (!settings_.skip_unneeded) contact.broad_phase = false;  // test every node every step
  contact_.init(collidable_nodes(model, state_.node_fixed), int(np), settings_.workspace, contact,
                surface_node_spacing_mm(model));
  contact_.set_threads(settings_.integrator.threads);
  // the implicit integrator takes the probes and walls into its solve (the post-step projection
  // would lose most of the reaction force at its long steps); the explicit schemes keep the
  // post-step projection, unchanged
  if (integrator_->solves_contact() && (collide_ || !settings_.skip_unneeded)) {
    implicit_contact_ = std::make_unique<ImplicitContact>(*this);
    integrator_->set_contact_provider(implicit_contact_.get());
  }

  outputs_.resize(np);
  reset();
}

Simulation::~Simulation() = default;

void Simulation::reset() {
  state_.reset();
  for (std::size_t i = 0; i < drivers_.size(); ++i) {
    drivers_[i].reset();
    poses_[i] = drivers_[i].state();
    outputs_[i] = {};
    outputs_[i].pose = poses_[i];
  }
  contact_.invalidate();
  wall_force_.setZero();
  surface_step_ = -1;
  if (listener_) listener_->after_reset();
}

void Simulation::set_step_listener(StepListener* listener, bool record_contacts) {
  listener_ = listener;
  record_contacts_ = listener && record_contacts;
}

const std::vector<ContactConstraint>& Simulation::step_contacts() const {
  return implicit_contact_ ? integrator_->contacts() : contact_records_;
}

bool Simulation::contact_compliance(const std::vector<std::int32_t>& nodes, Eigen::MatrixXd& g) {
  return integrator_->contact_compliance(state_, nodes, g);
}

bool Simulation::solves_contact() const { return integrator_->solves_contact(); }

void Simulation::save_tissue(TissueSnapshot& out) const {
  out.positions = state_.positions;
  out.velocities = state_.velocities;
  out.rotations.assign(state_.rotations.begin(), state_.rotations.end());
  out.time_s = state_.time_s;
  out.step = state_.steps;
}

void Simulation::restore_tissue(const TissueSnapshot& snap, bool drop_solver) {
  if (snap.positions.cols() != state_.positions.cols() || snap.velocities.cols() != state_.velocities.cols() ||
      snap.rotations.size() != state_.rotations.size())
    throw Error("simulation: a tissue snapshot of another model");
  state_.positions = snap.positions;
  ++state_.positions_version;
  state_.velocities = snap.velocities;
  std::copy(snap.rotations.begin(), snap.rotations.end(), state_.rotations.begin());
  state_.clear_failure();
  if (drop_solver) state_.integrator_cache = IntegratorCache{};
  contact_.invalidate();
  surface_step_ = -1;
}

int Simulation::probe_index(const std::string& name) const {
  for (std::size_t i = 0; i < settings_.probes.size(); ++i)
    if (settings_.probes[i].name == name) return int(i);
  return -1;
}

StepStatus Simulation::step() {
  if (state_.failed()) return state_.status;
  const double dt = dt_s();

  // probes to the end of the step
  const double t_new = state_.time_s + dt;
  for (std::size_t i = 0; i < drivers_.size(); ++i) {
    drivers_[i].advance(t_new, dt);
    poses_[i] = drivers_[i].state();
  }
  if (physics_->is_2d()) project_probes_to_plane();

  // elastic forces, gravity, integration
  const StepReport report = integrator_->step(state_);
  if (state_.failed()) return state_.status;
  if (report.refactored) {
    ++counters_.factorisations;
    counters_.factors_from_cache += report.factor_from_cache ? 1 : 0;
    counters_.orders_from_cache += report.order_from_cache ? 1 : 0;
    counters_.factor_s += report.factor_s;
    counters_.factors_in_background += report.factored_in_background ? 1 : 0;
  }
  counters_.factor_wait_s += report.factor_wait_s;
  counters_.steps_at_rest += report.asleep ? 1 : 0;
  if (report.woke) {
    ++counters_.wakes;
    counters_.last_wake_threads = report.threads;
  }
  counters_.iterations += report.iterations;
  if (report.fell_asleep != SleepCause::none) {
    ++counters_.sleeps;
    counters_.last_sleep_s = state_.time_s;
    counters_.last_sleep_since_release_s = report.since_release_s;
    counters_.last_sleep_offset_mm = report.sleep_offset_mm;
    counters_.last_release_offset_mm = report.release_offset_mm;
    counters_.last_sleep_cause = report.fell_asleep;
  }
  if (report.region_elements > 0) {
    counters_.sleeping_element_updates += physics_->num_elements() - report.region_elements;
    counters_.sleeping_node_solves += (state_.num_nodes() - state_.num_fixed()) - report.region_nodes;
  }

  // collisions of the nodes near probes and walls
  if (collide_ || !settings_.skip_unneeded) {
    if (implicit_contact_)
      take_implicit_contact_forces();
    else {
      contact_records_.clear();
      contact_.resolve(state_.positions, state_.velocities, physics_->node_mass, geometry_, poses_, dt, raw_,
                       wall_force_, &contacts_, record_contacts_ ? &contact_records_ : nullptr);
    }
    ++counters_.contact_passes;
    counters_.contact = contact_.counters();
  } else {
    ++counters_.contact_passes_skipped;
  }

  if (physics_->is_2d()) hold_plane();

  // probe outputs; then the device side (haptics/device_side.h), when one listens
  for (std::size_t i = 0; i < drivers_.size(); ++i) {
    ProbeOutput& o = outputs_[i];
    o.pose = poses_[i];
    o.raw_force_n = raw_[i];
    o.contacts = contacts_[i];
    o.time_s = state_.time_s;
  }
  if (listener_) listener_->after_step();

  // the surface: deformed now only when told to do all the work; else on demand
  if (settings_.surface && !settings_.skip_unneeded) (void)surface_vertices();

  ++counters_.steps;
  counters_.surface_updates_skipped = counters_.steps - counters_.surface_updates;
  return state_.status;
}

void Simulation::project_probes_to_plane() {
  const Eigen::Vector3d n = physics_->plane_normal(), p0 = physics_->plane_point_mm;
  for (ProbeState& p : poses_) {
    p.position_mm -= n * n.dot(p.position_mm - p0);
    p.velocity_mm_s -= n * n.dot(p.velocity_mm_s);
  }
}

void Simulation::hold_plane() {
  const Eigen::Vector3d n = physics_->plane_normal(), p0 = physics_->plane_point_mm;
  const double d0 = n.dot(p0);
  Eigen::Matrix3Xd& x = state_.positions;
  Eigen::Matrix3Xd& v = state_.velocities;
  for (Eigen::Index i = 0; i < x.cols(); ++i) {
    x.col(i) -= n * (n.dot(x.col(i)) - d0);
    v.col(i) -= n * n.dot(v.col(i));
  }
  for (auto& f : raw_) f -= n * n.dot(f);
}

void Simulation::ImplicitContact::collect(const Eigen::Matrix3Xd& x, bool near, std::vector<ContactConstraint>& out) {
  sim_.contact_.collect(x, sim_.geometry_, sim_.poses_, near, out);
}

void Simulation::ImplicitContact::watch_moving(const std::vector<int>* moving, std::uint64_t period) {
  // (never for a slice model: its nodes are all put back on its plane after every step, so the
  // solver holds no far field still there: ProjectiveSolver::partial_run)
  sim_.contact_.watch_moving(moving, period);
}

void Simulation::ImplicitContact::focus_points(std::vector<Eigen::Vector3d>& out) {
  out.clear();
  for (const ProbeState& p : sim_.poses_) out.push_back(p.position_mm);
}

void Simulation::take_implicit_contact_forces() {
  // each multiplier is the force of a surface on a node along the surface's normal; the node
  // pushes back: -force_n * normal on the probe (the wall), as the momentum formula of the
  // explicit path gives. The constraints come sorted by (owner, node): a fixed summation order.
  const int np = int(raw_.size());
  for (auto& f : raw_) f.setZero();
  std::fill(contacts_.begin(), contacts_.end(), 0);
  wall_force_.setZero();
  std::int64_t probe_contacts = 0, wall_contacts = 0;
  for (const ContactConstraint& c : integrator_->contacts()) {
    const Eigen::Vector3d f = -c.force_n * c.normal;
    if (c.owner < np) {
      raw_[std::size_t(c.owner)] += f;
      ++contacts_[std::size_t(c.owner)];
      ++probe_contacts;
    } else {
      wall_force_ += f;
      ++wall_contacts;
    }
  }
  contact_.count_contacts(probe_contacts, wall_contacts);
}

int Simulation::advance_to(double target_time_s, int max_steps) {
  int done = 0;
  while (done < max_steps && !state_.failed() && state_.time_s < target_time_s - 0.5 * dt_s()) {
    step();
    ++done;
  }
  return done;
}

const Eigen::Matrix3Xd& Simulation::surface_vertices() {
  if (!settings_.surface) throw Error("simulation: this simulation has no surface");
  if (surface_step_ != state_.steps) {
    deform(*settings_.surface, state_.positions, surface_frame_);
    surface_step_ = state_.steps;
    ++counters_.surface_updates;
    counters_.surface_updates_skipped = std::max<std::int64_t>(0, counters_.steps - counters_.surface_updates);
  }
  return surface_frame_.vertices;
}

void Simulation::set_surface(std::shared_ptr<const EmbeddedSurface> surface) {
  if (surface && surface->model_nodes != physics_->model->num_nodes())
    throw Error("simulation: the new surface is embedded in a model of " + std::to_string(surface->model_nodes) +
                " nodes, this one has " + std::to_string(physics_->model->num_nodes()));
  settings_.surface = std::move(surface);
  surface_frame_ = SurfaceFrame{};
  surface_step_ = -1;
}

void Simulation::copy_frame(SimulationFrame& out, bool with_positions) {
  if (settings_.surface) (void)surface_vertices();
  out.time_s = state_.time_s;
  out.step = state_.steps;
  if (with_positions)
    out.positions = state_.positions;
  else
    out.positions.resize(3, 0);
  if (settings_.surface) {
    out.surface_vertices = surface_frame_.vertices;
    out.surface_normals = surface_frame_.normals;
  } else {
    out.surface_vertices.resize(3, 0);
    out.surface_normals.resize(3, 0);
  }
  out.surface = settings_.surface;
  out.probes = outputs_;
}

void Simulation::set_live(int i, const LiveCommand& command) {
  if (i < 0 || i >= int(settings_.probes.size()))
    throw Error("simulation: no probe " + std::to_string(i) + " (the scene has " +
                std::to_string(settings_.probes.size()) + ")");
  if (settings_.probes[std::size_t(i)].drive != ProbeDrive::live)
    throw Error("simulation: probe " + std::to_string(i) + " (" + settings_.probes[std::size_t(i)].name +
                ") is driven by its " + to_string(settings_.probes[std::size_t(i)].drive) +
                ", not live; give it \"live\": {} in the scene");
  drivers_[std::size_t(i)].set_live(command);
}

}  // namespace vx
