#include "haptics/device_side.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "base/error.h"
#include "base/parallel.h"

namespace vx {

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

DeviceSide::DeviceSide(Simulation& sim, DeviceSideSettings settings) : sim_(sim), settings_(std::move(settings)) {
  std::ostringstream err;
  if (settings_.device)
    if (const std::string bad = settings_.device->validate(); !bad.empty()) err << "device: " << bad;
  if (settings_.local_contact)
    if (const std::string bad = settings_.local_contact->validate(); !bad.empty()) err << "local contact: " << bad;
  if (const std::string bad = err.str(); !bad.empty()) throw Error("simulation: " + bad);
  const std::size_t np = std::size_t(sim_.num_probes());
  const int nn = sim_.state().num_nodes();

  // device forces: only with a device (or when told to do all the work)
  shape_ = has_device() || !sim_.settings().skip_unneeded;
  if (shape_) {
    const DeviceForceSettings dev = has_device() ? *settings_.device : DeviceForceSettings{};
    shapers_.resize(np);
    for (auto& s : shapers_) s.init(dev, sim_.dt_s());
  }

  // local contact models for a haptic device
  if (settings_.local_contact) {
    const LocalContactSettings& lc = *settings_.local_contact;
    local_average_s_ = lc.average_s >= 0 ? lc.average_s : (sim_.solves_contact() ? 0.0 : 0.002);
    local_anchor_.resize(np);
    for (auto& a : local_anchor_) {
      a.node_force.assign(std::size_t(nn), Eigen::Vector3d::Zero());
      a.listed.assign(std::size_t(nn), 0);
    }
    for (std::size_t i = 0; i < np; ++i) local_out_.push_back(std::make_unique<TripleBuffer<LocalContactModel>>());
    if (!use_integrator_compliance()) patch_.init(sim_.shared_physics(), sim_.state().node_fixed, lc.horizon_s);
  }

  outputs_.resize(np);
  published_.resize(np);
  after_reset();
  // the explicit integrators' contacts are recorded for the local contact models only
  sim_.set_step_listener(this, settings_.local_contact.has_value());
}

DeviceSide::~DeviceSide() { sim_.set_step_listener(nullptr, false); }

void DeviceSide::after_reset() {
  for (auto& s : shapers_) s.reset();
  for (auto& o : outputs_) o = {};
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
  std::lock_guard lock(mutex_);
  published_ = outputs_;
}

void DeviceSide::after_step() {
  if (settings_.local_contact) accumulate_local_contact();

  // the device force
  for (int i = 0; i < num_probes(); ++i) {
    DeviceOutput& o = outputs_[std::size_t(i)];
    if (shape_) {
      const Eigen::Vector3d& shaped = shapers_[std::size_t(i)].push(sim_.probe(i).raw_force_n, sim_.time_s());
      if (has_device()) {
        o.shaped_force_n = shaped;
        o.pulse = shapers_[std::size_t(i)].pulse();
      }
      ++counters_.device_shaping_steps;
    } else {
      ++counters_.device_shaping_skipped;
    }
  }
  if (has_device()) {
    std::lock_guard lock(mutex_);
    for (std::size_t i = 0; i < outputs_.size(); ++i) published_[i] = outputs_[i];
  }
}

DeviceOutput DeviceSide::output_snapshot(int i) const {
  std::lock_guard lock(mutex_);
  return published_.at(std::size_t(i));
}

static_assert(PatchCompliance::kCacheColumns >= LocalContactSolver::kMaxNodes,
              "the patch compliance's cache holds the columns of one local model");

bool DeviceSide::use_integrator_compliance() const {
  // not with a volume term (Poisson > 0): the factor's projective volume matrix is far stiffer than
  // the converged step (docs/model.md 9.1); the patch compliance follows nu
  return settings_.local_contact && settings_.local_contact->integrator_compliance && sim_.solves_contact() &&
         !sim_.physics().has_volume_term() && sim_.dt_s() >= 0.5 * settings_.local_contact->update_period_s;
}

double DeviceSide::local_compliance_scale() const { return settings_.local_contact->compliance_scale; }

void DeviceSide::accumulate_local_contact() {
  const double dt = sim_.dt_s();
  const double alpha = local_average_s_ > 0 ? 1.0 - std::exp(-dt / local_average_s_) : 1.0;
  const int np = num_probes();
  const std::vector<ContactConstraint>& contacts = sim_.step_contacts();
  for (int q = 0; q < np; ++q) {
    LocalAnchor& a = local_anchor_[std::size_t(q)];
    const Eigen::Vector3d& pose = sim_.probe(q).pose.position_mm;
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

void DeviceSide::build_local_contact(int q, LocalContactModel& m) {
  if (!settings_.local_contact) throw Error("simulation: no local contact settings");
  if (q < 0 || q >= num_probes()) throw Error("simulation: no probe " + std::to_string(q));
  const LocalContactSettings& lc = *settings_.local_contact;
  const LocalAnchor& a = local_anchor_[std::size_t(q)];
  const ProbeGeometry& g = sim_.probe_geometry(q);
  const Eigen::Vector3d anchor = a.started ? a.pose : sim_.probe(q).pose.position_mm;
  const double margin = lc.margin_mm > 0 ? lc.margin_mm : sim_.contact_solver().skin_mm();
  const Eigen::Matrix3Xd& x = sim_.state().positions;
  // the candidates: the nodes the tool pushes (mean force > 0), then the nodes near it
  local_candidates_.clear();
  for (const std::int32_t n : a.nodes) {
    const Eigen::Vector3d& f = a.node_force[std::size_t(n)];
    const double len = f.norm();
    local_candidates_.push_back({n, len, 0.0, f / len});
  }
  // every node that may collide (the folded organ's 274,533 surface nodes), on the physics'
  // thread after each update while its other threads wait: the far ones out by a squared distance
  // to a ball round the tool, in chunks on the physics' threads, each chunk's finds appended in
  // chunk order (the same candidates, in the same order, on any thread count)
  Eigen::Vector3d centre;
  const double reach = probe_bounding_ball(g, anchor, centre) + margin, reach2 = reach * reach;
  const std::vector<std::int32_t>& surface = sim_.contact_solver().nodes();
  const std::int64_t chunks = chunk_count(std::int64_t(surface.size()), kLocalScanGrain);
  if (local_found_.size() < std::size_t(chunks)) local_found_.resize(std::size_t(chunks));
  parallel_for_chunks(std::int64_t(surface.size()), kLocalScanGrain, 0,
                      [&](std::int64_t c, std::int64_t b, std::int64_t e) {
                        std::vector<LocalCandidate>& found = local_found_[std::size_t(c)];
                        found.clear();
                        Eigen::Vector3d point, normal;
                        for (std::int64_t k = b; k < e; ++k) {
                          const std::int32_t n = surface[std::size_t(k)];
                          if ((x.col(n) - centre).squaredNorm() >= reach2 || a.listed[std::size_t(n)]) continue;
                          const double d = probe_signed_distance(g, anchor, x.col(n), &point, &normal);
                          if (d < margin) found.push_back({n, 0.0, std::max(0.0, d), normal});
                        }
                      });
  for (std::int64_t c = 0; c < chunks; ++c)
    local_candidates_.insert(local_candidates_.end(), local_found_[std::size_t(c)].begin(),
                             local_found_[std::size_t(c)].end());
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
    if (use_integrator_compliance() && sim_.contact_compliance(m.node, local_g_)) {
      m.source = ComplianceSource::integrator;
    } else {
      if (!patch_.ready()) patch_.init(sim_.shared_physics(), sim_.state().node_fixed, lc.horizon_s);
      // (PatchCompliance widens it for a contact wider than this: a rod along the tissue, a plate)
      const double radius = lc.patch_radius_mm > 0 ? lc.patch_radius_mm
                                                   : std::max(g.shape == ProbeShape::plane ? 0.0 : 6.0 * g.radius_mm,
                                                              12.0 * surface_node_spacing_mm(*sim_.physics().model));
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
  m.step = sim_.steps();
  m.time_s = sim_.time_s();
  m.anchor_mm = anchor;
  m.anchor_force_n = force;
  m.tool = g;
}

void DeviceSide::publish_local_contact() {
  if (!settings_.local_contact) return;
  ++local_updates_;
  for (int q = 0; q < num_probes(); ++q) {
    LocalContactModel& m = local_out_[std::size_t(q)]->write_buffer();
    build_local_contact(q, m);
    m.update = local_updates_;
    local_out_[std::size_t(q)]->publish();
  }
}

const LocalContactModel* DeviceSide::take_local_contact(int i) {
  if (!settings_.local_contact || i < 0 || i >= int(local_out_.size())) return nullptr;
  TripleBuffer<LocalContactModel>& b = *local_out_[std::size_t(i)];
  return b.fetch() ? &b.read_buffer() : nullptr;
}

}  // namespace vx
