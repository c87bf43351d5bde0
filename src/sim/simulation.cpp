#include "sim/simulation.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "base/error.h"

namespace vx {

std::vector<std::int32_t> collidable_nodes(const Model& model, const std::vector<std::uint8_t>& fixed) {
  std::vector<std::int32_t> nodes;
  for (int i = 0; i < model.num_nodes(); ++i)
    if (!(std::size_t(i) < fixed.size() && fixed[std::size_t(i)]))
      nodes.push_back(i);
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
  if (settings_.device)
    if (const std::string bad = settings_.device->validate(); !bad.empty()) err << "device: " << bad;
  if (settings_.local_contact)
    if (const std::string bad = settings_.local_contact->validate(); !bad.empty()) err << "local contact: " << bad;
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
  // the implicit integrator takes the probes and walls into its solve (the post-step projection
  // would lose most of the reaction force at its long steps); the explicit schemes keep the
  // post-step projection, unchanged
  if (integrator_->solves_contact() && (collide_ || !settings_.skip_unneeded)) {
    implicit_contact_ = std::make_unique<ImplicitContact>(*this);
    integrator_->set_contact_provider(implicit_contact_.get());
  }

  // device forces: only with a device (or when told to do all the work)
  shape_ = has_device() || !settings_.skip_unneeded;
  if (shape_) {
    const DeviceForceSettings dev = has_device() ? *settings_.device : DeviceForceSettings{};
    shapers_.resize(np);
    for (auto& s : shapers_) s.init(dev, dt_s());
  }

  // local contact models for a haptic device
  if (settings_.local_contact) {
    const LocalContactSettings& lc = *settings_.local_contact;
    local_average_s_ = lc.average_s >= 0 ? lc.average_s : (integrator_->solves_contact() ? 0.0 : 0.002);
    local_anchor_.resize(np);
    for (auto& a : local_anchor_) {
      a.node_force.assign(std::size_t(nn), Eigen::Vector3d::Zero());
      a.listed.assign(std::size_t(nn), 0);
    }
    for (std::size_t i = 0; i < np; ++i) local_out_.push_back(std::make_unique<TripleBuffer<LocalContactModel>>());
    if (!use_integrator_compliance()) patch_.init(physics_, state_.node_fixed, lc.horizon_s);
  }

  outputs_.resize(np);
  published_.resize(np);
  live_.resize(np);
  live_dirty_.assign(np, false);
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
  for (auto& s : shapers_) s.reset();
  for (std::size_t i = 0; i < local_anchor_.size(); ++i) {
    LocalAnchor& a = local_anchor_[i];
    for (const std::int32_t n : a.nodes) {
      a.node_force[std::size_t(n)].setZero();
      a.listed[std::size_t(n)] = 0;
    }
    a.nodes.clear();
    a.started = false;
    LocalContactModel& m = local_out_[i]->write_buffer();
    m.valid = false;
    m.resize(0);
    local_out_[i]->publish();
  }
  contact_.invalidate();
  wall_force_.setZero();
  surface_step_ = -1;
  std::lock_guard<std::mutex> lock(mutex_);
  published_ = outputs_;
  frame_ready_ = false;
}

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

  // live input from other threads
  if (live_pending_.exchange(false, std::memory_order_acq_rel)) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (std::size_t i = 0; i < drivers_.size(); ++i)
      if (live_dirty_[i]) {
        drivers_[i].set_live(live_[i]);
        live_dirty_[i] = false;
      }
  }

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
    counters_.factor_s += report.factor_s;
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
                       wall_force_, &contacts_, settings_.local_contact ? &contact_records_ : nullptr);
    }
    ++counters_.contact_passes;
    counters_.contact = contact_.counters();
  } else {
    ++counters_.contact_passes_skipped;
  }

  if (physics_->is_2d()) hold_plane();

  if (settings_.local_contact) accumulate_local_contact();

  // probe outputs and the device force
  for (std::size_t i = 0; i < drivers_.size(); ++i) {
    ProbeOutput& o = outputs_[i];
    o.pose = poses_[i];
    o.raw_force_n = raw_[i];
    o.contacts = contacts_[i];
    o.time_s = state_.time_s;
    if (shape_) {
      const Eigen::Vector3d& shaped = shapers_[i].push(raw_[i], state_.time_s);
      if (has_device()) {
        o.shaped_force_n = shaped;
        o.pulse = shapers_[i].pulse();
      }
      ++counters_.device_shaping_steps;
    } else {
      ++counters_.device_shaping_skipped;
    }
  }

  // the surface: deformed now only when told to do all the work; else on demand
  if (settings_.surface && !settings_.skip_unneeded) (void)surface_vertices();

  ++counters_.steps;
  counters_.surface_updates_skipped = counters_.steps - counters_.surface_updates;
  publish();
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

std::string LocalContactSettings::validate() const {
  std::ostringstream err;
  if (!std::isfinite(margin_mm)) err << "margin must be finite; ";
  if (max_nodes < 1 || max_nodes > LocalContactSolver::kMaxNodes)
    err << "max_nodes " << max_nodes << " must be in 1.." << LocalContactSolver::kMaxNodes << "; ";
  if (!std::isfinite(average_s) || average_s > 1.0) err << "average_s must be <= 1 s; ";
  if (!(horizon_s > 0) || !std::isfinite(horizon_s)) err << "horizon_s must be > 0; ";
  if (!(update_period_s > 0) || !std::isfinite(update_period_s)) err << "update_period_s must be > 0; ";
  if (!(compliance_scale > 0) || !std::isfinite(compliance_scale)) err << "compliance_scale must be > 0; ";
  if (!std::isfinite(patch_radius_mm)) err << "patch radius must be finite; ";
  return err.str();
}

bool Simulation::use_integrator_compliance() const {
  // not with a volume term (Poisson > 0): the factor's projective volume matrix is far stiffer than
  // the converged step (docs/model.md 9.1); the patch compliance follows nu
  return settings_.local_contact && settings_.local_contact->integrator_compliance && integrator_->solves_contact() &&
         !physics_->has_volume_term() && dt_s() >= 0.5 * settings_.local_contact->update_period_s;
}

double Simulation::local_compliance_scale() const { return settings_.local_contact->compliance_scale; }

void Simulation::accumulate_local_contact() {
  const double dt = dt_s();
  const double alpha = local_average_s_ > 0 ? 1.0 - std::exp(-dt / local_average_s_) : 1.0;
  const int np = num_probes();
  const std::vector<ContactConstraint>& contacts = implicit_contact_ ? integrator_->contacts() : contact_records_;
  for (int q = 0; q < np; ++q) {
    LocalAnchor& a = local_anchor_[std::size_t(q)];
    const Eigen::Vector3d& pose = poses_[std::size_t(q)].position_mm;
    a.pose = a.started ? Eigen::Vector3d(a.pose + alpha * (pose - a.pose)) : pose;
    a.started = true;
    for (const std::int32_t n : a.nodes) a.node_force[std::size_t(n)] *= 1.0 - alpha;
  }
  for (const ContactConstraint& c : contacts) {
    if (c.owner < 0 || c.owner >= np || !(c.force_n > 0.0)) continue;
    LocalAnchor& a = local_anchor_[std::size_t(c.owner)];
    a.node_force[std::size_t(c.node)] += (alpha * c.force_n) * c.normal;
    if (!a.listed[std::size_t(c.node)]) {
      a.listed[std::size_t(c.node)] = 1;
      a.nodes.push_back(c.node);
    }
  }
  // forget the nodes whose mean force has died away
  for (LocalAnchor& a : local_anchor_) {
    std::size_t k = 0;
    for (const std::int32_t n : a.nodes) {
      if (a.node_force[std::size_t(n)].squaredNorm() > 1e-24) {
        a.nodes[k++] = n;
      } else {
        a.node_force[std::size_t(n)].setZero();
        a.listed[std::size_t(n)] = 0;
      }
    }
    a.nodes.resize(k);
  }
}

void Simulation::build_local_contact(int q, LocalContactModel& m) {
  if (!settings_.local_contact) throw Error("simulation: no local contact settings");
  if (q < 0 || q >= num_probes()) throw Error("simulation: no probe " + std::to_string(q));
  const LocalContactSettings& lc = *settings_.local_contact;
  const LocalAnchor& a = local_anchor_[std::size_t(q)];
  const ProbeGeometry& g = geometry_[std::size_t(q)];
  const Eigen::Vector3d anchor = a.started ? a.pose : poses_[std::size_t(q)].position_mm;
  const double margin = lc.margin_mm > 0 ? lc.margin_mm : contact_.skin_mm();
  const Eigen::Matrix3Xd& x = state_.positions;
  // the candidates: the nodes the tool pushes (mean force > 0), then the nodes near it
  local_candidates_.clear();
  for (const std::int32_t n : a.nodes) {
    const Eigen::Vector3d& f = a.node_force[std::size_t(n)];
    const double len = f.norm();
    local_candidates_.push_back({n, len, 0.0, f / len});
  }
  Eigen::Vector3d point, normal;
  for (const std::int32_t n : contact_.nodes()) {
    if (a.listed[std::size_t(n)]) continue;
    const double d = probe_signed_distance(g, anchor, x.col(n), &point, &normal);
    if (d < margin) local_candidates_.push_back({n, 0.0, std::max(0.0, d), normal});
  }
  // too many: the largest forces, then the smallest gaps
  if (int(local_candidates_.size()) > lc.max_nodes) {
    std::stable_sort(local_candidates_.begin(), local_candidates_.end(),
                     [](const LocalCandidate& l, const LocalCandidate& r) {
                       return l.force_n != r.force_n ? l.force_n > r.force_n : l.gap_mm < r.gap_mm;
                     });
    local_candidates_.resize(std::size_t(lc.max_nodes));
  }
  const int mc = int(local_candidates_.size());
  m.resize(mc);
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  for (int k = 0; k < mc; ++k) {
    const LocalCandidate& c = local_candidates_[std::size_t(k)];
    m.node[std::size_t(k)] = c.node;
    m.point_mm.col(k) = x.col(c.node);
    m.normal.col(k) = c.normal;
    m.force_n[k] = c.force_n;
    m.gap_mm[k] = c.gap_mm;
    force -= c.force_n * c.normal;
  }
  // the compliance between them
  m.source = ComplianceSource::none;
  if (mc > 0) {
    if (use_integrator_compliance() && integrator_->contact_compliance(state_, m.node, local_g_)) {
      m.source = ComplianceSource::integrator;
    } else {
      if (!patch_.ready()) patch_.init(physics_, state_.node_fixed, lc.horizon_s);
      const double radius = lc.patch_radius_mm > 0
                                ? lc.patch_radius_mm
                                : std::max(g.shape == ProbeShape::plane ? 0.0 : 6.0 * g.radius_mm,
                                           12.0 * surface_node_spacing_mm(*physics_->model));
      if (!patch_.compute(m.node, radius, local_g_))
        throw Error("simulation: the local contact compliance could not be computed (a patch of " +
                    std::to_string(radius) + " mm around the contact)");
      m.source = ComplianceSource::patch;
    }
    const double scale = local_compliance_scale();
    for (int i = 0; i < mc; ++i)
      for (int j = 0; j < mc; ++j) m.compliance(i, j) = scale * m.normal.col(i).dot(m.normal.col(j)) * local_g_(i, j);
  }
  m.valid = true;
  m.step = state_.steps;
  m.time_s = state_.time_s;
  m.anchor_mm = anchor;
  m.anchor_force_n = force;
  m.tool = g;
}

void Simulation::publish_local_contact() {
  if (!settings_.local_contact) return;
  ++local_updates_;
  for (int q = 0; q < num_probes(); ++q) {
    LocalContactModel& m = local_out_[std::size_t(q)]->write_buffer();
    build_local_contact(q, m);
    m.update = local_updates_;
    local_out_[std::size_t(q)]->publish();
  }
}

const LocalContactModel* Simulation::take_local_contact(int i) {
  if (!settings_.local_contact || i < 0 || i >= int(local_out_.size())) return nullptr;
  TripleBuffer<LocalContactModel>& b = *local_out_[std::size_t(i)];
  return b.fetch() ? &b.read_buffer() : nullptr;
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

void Simulation::publish() {
  const bool frame = frame_requested_.exchange(false, std::memory_order_acq_rel);
  if (frame && settings_.surface) (void)surface_vertices();
  std::lock_guard<std::mutex> lock(mutex_);
  for (std::size_t i = 0; i < outputs_.size(); ++i) published_[i] = outputs_[i];
  if (frame) {
    frame_.time_s = state_.time_s;
    frame_.step = state_.steps;
    frame_.positions = state_.positions;
    if (settings_.surface) {
      frame_.surface_vertices = surface_frame_.vertices;
      frame_.surface_normals = surface_frame_.normals;
    }
    frame_.probes = outputs_;
    frame_ready_ = true;
    ++counters_.frames_published;
  } else {
    ++counters_.frames_skipped;
  }
}

void Simulation::set_live(int i, const LiveCommand& command) {
  if (i < 0 || i >= int(settings_.probes.size()))
    throw Error("simulation: no probe " + std::to_string(i) + " (the scene has " +
                std::to_string(settings_.probes.size()) + ")");
  if (settings_.probes[std::size_t(i)].drive != ProbeDrive::live)
    throw Error("simulation: probe " + std::to_string(i) + " (" + settings_.probes[std::size_t(i)].name +
                ") is driven by its " + to_string(settings_.probes[std::size_t(i)].drive) +
                ", not live; give it \"live\": {} in the scene");
  std::lock_guard<std::mutex> lock(mutex_);
  live_[std::size_t(i)] = command;
  live_dirty_[std::size_t(i)] = true;
  live_pending_.store(true, std::memory_order_release);
}

ProbeOutput Simulation::probe_snapshot(int i) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return published_.at(std::size_t(i));
}

bool Simulation::take_frame(SimulationFrame& out) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!frame_ready_) return false;
  std::swap(out, frame_);
  frame_ready_ = false;
  return true;
}

}  // namespace vx
