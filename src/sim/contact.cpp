#include "sim/contact.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <sstream>

#include "base/error.h"
#include "base/parallel.h"

namespace vx {

namespace {

/// Listed nodes per chunk of node_move()'s check (as the node passes' kNodeGrain).
constexpr std::int64_t kMoveGrain = 1024;

}  // namespace

std::string ContactSettings::validate() const {
  std::ostringstream err;
  if (!(restitution >= 0 && restitution <= 1)) err << "restitution " << restitution << " must be in [0, 1]; ";
  if (!(friction >= 0 && std::isfinite(friction))) err << "friction " << friction << " must be >= 0; ";
  if (!std::isfinite(skin_mm)) err << "broad-phase skin must be finite; ";
  return err.str();
}

void ContactSolver::init(std::vector<std::int32_t> nodes, int probes, const Workspace& workspace,
                         const ContactSettings& settings, double spacing_mm) {
  if (const std::string bad = settings.validate(); !bad.empty()) throw Error("contact settings: " + bad);
  std::sort(nodes.begin(), nodes.end());
  nodes_ = std::move(nodes);
  probes_ = probes;
  workspace_ = workspace;
  settings_ = settings;
  skin_mm_ = settings.skin_mm > 0 ? settings.skin_mm : 2.0 * std::max(spacing_mm, 1e-6);
  lists_.assign(std::size_t(probes_ + 1), {});
  for (auto& l : lists_) l.reserve(nodes_.size());
  node_at_rebuild_.resize(3, Eigen::Index(nodes_.size()));
  chunk_move_.assign(std::size_t(chunk_count(std::int64_t(nodes_.size()), kMoveGrain)), 0.0);
  chunk_still_.assign(chunk_move_.size(), 0.0);
  is_watched_.assign(nodes_.size(), 0);
  watched_.clear();
  watched_.reserve(nodes_.size());
  end_watch();
  probe_at_rebuild_.assign(std::size_t(probes_), Eigen::Vector3d::Zero());
  counters_ = {};
  valid_ = false;
  // friction anchors, per node id
  const std::size_t slots = nodes_.empty() ? 0 : std::size_t(nodes_.back()) + 1;
  anchor_.assign(slots, Eigen::Vector3d::Zero());
  anchor_owner_.assign(slots, -1);
  anchor_step_.assign(slots, 0);
  step_ = 0;
}

void ContactSolver::rebuild(const Eigen::Matrix3Xd& x, const std::vector<ProbeGeometry>& geometry,
                            const std::vector<ProbeState>& probes) {
  const std::size_t n = nodes_.size();
  for (auto& l : lists_) l.clear();
  // a ball round each probe rejects the far nodes with a squared distance (probe.h)
  reach_.resize(std::size_t(probes_));
  for (int q = 0; q < probes_; ++q) {
    ProbeReach& r = reach_[std::size_t(q)];
    const double reach =
        probe_bounding_ball(geometry[std::size_t(q)], probes[std::size_t(q)].position_mm, r.centre) + skin_mm_;
    r.reach2 = reach * reach;
  }
  for (std::size_t k = 0; k < n; ++k) {
    const std::int32_t i = nodes_[k];
    const Eigen::Vector3d p = x.col(i);
    node_at_rebuild_.col(Eigen::Index(k)) = p;
    if (!settings_.broad_phase) {
      for (auto& l : lists_) l.push_back(i);
      continue;
    }
    for (int q = 0; q < probes_; ++q)
      if ((p - reach_[std::size_t(q)].centre).squaredNorm() < reach_[std::size_t(q)].reach2 &&
          probe_signed_distance(geometry[std::size_t(q)], probes[std::size_t(q)].position_mm, p) < skin_mm_)
        lists_[std::size_t(q)].push_back(i);
    if (workspace_.enabled) {
      const double inside = std::min((p - workspace_.min_mm).minCoeff(), (workspace_.max_mm - p).minCoeff());
      if (inside < skin_mm_) lists_[std::size_t(probes_)].push_back(i);
    }
  }
  for (int q = 0; q < probes_; ++q) probe_at_rebuild_[std::size_t(q)] = probes[std::size_t(q)].position_mm;
  // every node's move is 0 now; under a promise the others keep these positions
  still_move2_ = 0.0;
  watch_ready_ = watch_period_ != 0;
  if (settings_.broad_phase) {
    counters_.broad_tests += std::int64_t(n) * (probes_ + (workspace_.enabled ? 1 : 0));
    ++counters_.rebuilds;
  }
  valid_ = true;
}

void ContactSolver::invalidate() {
  valid_ = false;
  std::fill(anchor_owner_.begin(), anchor_owner_.end(), -1);
  end_watch();
}

void ContactSolver::end_watch() {
  watch_period_ = 0;
  watch_active_ = false;
  watch_ready_ = false;
}

void ContactSolver::watch_moving(const std::vector<int>* moving, std::uint64_t period) {
  if (period == 0) {
    end_watch();
    return;
  }
  if (period == watch_period_) {
    watch_active_ = moving != nullptr;
    return;
  }
  if (moving == nullptr) {  // a pause of a period never begun
    end_watch();
    return;
  }
  for (const std::int64_t k : watched_) is_watched_[std::size_t(k)] = 0;
  watched_.clear();
  // both ascending: one merge
  std::size_t k = 0;
  for (const int i : *moving) {
    while (k < nodes_.size() && nodes_[k] < i) ++k;
    if (k == nodes_.size()) break;
    if (nodes_[k] == i) {
      watched_.push_back(std::int64_t(k));
      is_watched_[k] = 1;
    }
  }
  watch_period_ = period;
  watch_active_ = true;
  watch_ready_ = false;
}

double ContactSolver::node_move(const Eigen::Matrix3Xd& x) {
  // largest node displacement since the rebuild: every node that may collide (the folded
  // organ's 274,533 surface nodes), twice in an implicit step, so on the step's threads. Under
  // the regional solves' promise only the watched ones (the closure's), the others' largest
  // move kept from the period's first check, which looks at every node.
  const bool watched = watch_period_ != 0 && watch_active_ && watch_ready_;
  const bool split = watch_period_ != 0 && !watched;
  const std::int64_t n = watched ? std::int64_t(watched_.size()) : std::int64_t(nodes_.size());
  parallel_for_chunks(n, kMoveGrain, threads_, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
    double max_d2 = 0.0, still = 0.0;
    for (std::int64_t j = b; j < e; ++j) {
      const std::int64_t k = watched ? watched_[std::size_t(j)] : j;
      const double d2 = (x.col(nodes_[std::size_t(k)]) - node_at_rebuild_.col(k)).squaredNorm();
      max_d2 = std::max(max_d2, d2);
      if (split && !is_watched_[std::size_t(k)]) still = std::max(still, d2);
    }
    chunk_move_[std::size_t(c)] = max_d2;
    chunk_still_[std::size_t(c)] = still;
  });
  const auto chunks = std::size_t(chunk_count(n, kMoveGrain));
  double max_d2 = watched ? still_move2_ : 0.0;
  for (std::size_t c = 0; c < chunks; ++c) max_d2 = std::max(max_d2, chunk_move_[c]);
  if (split) {
    still_move2_ = 0.0;
    for (std::size_t c = 0; c < chunks; ++c) still_move2_ = std::max(still_move2_, chunk_still_[c]);
    watch_ready_ = true;
  }
  if (watched) ++watched_checks_;
  return std::sqrt(max_d2);
}

void ContactSolver::keep_lists_valid(const Eigen::Matrix3Xd& x, const std::vector<ProbeGeometry>& geometry,
                                     const std::vector<ProbeState>& probes, int q, double margin, double& moved) {
  const double probe_move =
      q < probes_ ? (probes[std::size_t(q)].position_mm - probe_at_rebuild_[std::size_t(q)]).norm() : 0.0;
  if (valid_ && (!settings_.broad_phase || moved + probe_move + margin < skin_mm_)) return;  // NaN rebuilds
  rebuild(x, geometry, probes);
  moved = 0.0;
}

void ContactSolver::resolve(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, const std::vector<double>& mass,
                            const std::vector<ProbeGeometry>& geometry, const std::vector<ProbeState>& probes,
                            double dt, std::vector<Eigen::Vector3d>& probe_force, Eigen::Vector3d& wall_force,
                            std::vector<int>* probe_contacts, std::vector<ContactConstraint>* records) {
  ++step_;
  end_watch();  // this path moves the nodes it resolves
  probe_force.assign(std::size_t(probes_), Eigen::Vector3d::Zero());
  if (probe_contacts) probe_contacts->assign(std::size_t(probes_), 0);
  wall_force.setZero();
  // the lists hold every node that can be inside its probe (walls) while the largest node
  // displacement since the rebuild (moves this step's projections add to) plus the probe's
  // own displacement stays below the skin; else rebuild from the current positions
  double moved = valid_ && settings_.broad_phase ? node_move(x) : 0.0;

  const double e = settings_.restitution;
  const double mu = settings_.friction;
  // response of node i, already put back on a surface moving at vs (frame origin `origin`)
  // with outward normal n: reflect the approaching normal part of the relative velocity,
  // v_n -> -e v_n, a normal impulse jn per unit mass. Friction (Coulomb, impulse form, with a
  // position-level stick as in position-based dynamics): stopping the node's tangential
  // relative velocity v_t takes |v_t| per unit mass; if that is within mu * jn the node
  // sticks: v_t is removed and its slip over the surface since it last touched it (the anchor,
  // kept for up to kAnchorSteps steps, so nodes that bounce every other step stick too) is
  // undone; else it slides: the fraction mu * jn / |v_t| of both is removed.
  // Returns the velocity change (the impulse per mass given to the node).
  auto respond = [&](int i, const Eigen::Vector3d& n, const Eigen::Vector3d& vs, const Eigen::Vector3d& origin,
                     int owner) -> Eigen::Vector3d {
    const Eigen::Vector3d rel = v.col(i) - vs;
    const double vn = rel.dot(n);
    const double jn = vn < 0 ? -(1.0 + e) * vn : 0.0;
    Eigen::Vector3d dv = jn * n;
    if (mu > 0) {
      const auto k = std::size_t(i);
      const Eigen::Vector3d vt = rel - vn * n;
      Eigen::Vector3d slip;
      if (anchor_owner_[k] == owner && step_ - anchor_step_[k] <= kAnchorSteps) {
        slip = x.col(i) - origin - anchor_[k];
        slip -= slip.dot(n) * n;
      } else {
        slip = dt * vt;
      }
      const double need = vt.norm();
      const double keep = need > 0 ? std::min(1.0, mu * jn / need) : 1.0;
      dv -= keep * vt;
      x.col(i) -= keep * slip;
      anchor_[k] = x.col(i) - origin;
      anchor_owner_[k] = owner;
      anchor_step_[k] = step_;
    }
    v.col(i) += dv;
    return dv;
  };

  // probes, in order
  Eigen::Vector3d surface_point, normal;
  double shift = 0.0;  // largest move of a node by this probe's contacts, mm
  for (int q = 0; q < probes_; ++q) {
    const auto& list = lists_[std::size_t(q)];
    const ProbeGeometry& g = geometry[std::size_t(q)];
    const ProbeState& p = probes[std::size_t(q)];
    keep_lists_valid(x, geometry, probes, q, 0.0, moved);
    Eigen::Vector3d impulse = Eigen::Vector3d::Zero();  // given to the nodes, N*s
    int contacts = 0;
    for (const std::int32_t i : list) {
      const Eigen::Vector3d xi = x.col(i);
      const double depth = -probe_signed_distance(g, p.position_mm, xi, &surface_point, &normal);
      if (!(depth > 0)) continue;
      x.col(i) = surface_point;
      const Eigen::Vector3d dp = mass[std::size_t(i)] * respond(i, normal, p.velocity_mm_s, p.position_mm, q);
      impulse += dp;
      if (records) {
        ContactConstraint c;
        c.node = i;
        c.owner = q;
        c.point_mm = surface_point;
        c.normal = normal;
        c.force_n = dp.dot(normal) / dt;
        records->push_back(c);
      }
      shift = std::max(shift, (x.col(i) - xi).norm());
      ++contacts;
    }
    counters_.narrow_tests += std::int64_t(list.size());
    counters_.narrow_tests_skipped += std::int64_t(nodes_.size() - list.size());
    counters_.contacts += contacts;
    moved += shift;
    shift = 0.0;
    probe_force[std::size_t(q)] = -impulse / dt;
    if (probe_contacts) (*probe_contacts)[std::size_t(q)] = contacts;
  }

  // walls: static, each violated axis in turn
  if (workspace_.enabled) {
    keep_lists_valid(x, geometry, probes, probes_, 0.0, moved);
    const auto& list = lists_[std::size_t(probes_)];
    Eigen::Vector3d impulse = Eigen::Vector3d::Zero();
    for (const std::int32_t i : list) {
      for (int a = 0; a < 3; ++a) {
        for (int side = 0; side < 2; ++side) {
          const double wall = side == 0 ? workspace_.min_mm[a] : workspace_.max_mm[a];
          const double out = side == 0 ? wall - x(a, i) : x(a, i) - wall;  // > 0: outside
          if (!(out > 0)) continue;
          x(a, i) = wall;
          Eigen::Vector3d n = Eigen::Vector3d::Zero();
          n[a] = side == 0 ? 1.0 : -1.0;
          impulse += mass[std::size_t(i)] * respond(i, n, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), probes_);
          ++counters_.wall_contacts;
        }
      }
    }
    counters_.narrow_tests += std::int64_t(list.size());
    counters_.narrow_tests_skipped += std::int64_t(nodes_.size() - list.size());
    wall_force = -impulse / dt;
  }
}

void ContactSolver::collect(const Eigen::Matrix3Xd& x, const std::vector<ProbeGeometry>& geometry,
                            const std::vector<ProbeState>& probes, bool near, std::vector<ContactConstraint>& out) {
  const double margin = near ? near_margin_mm() : 0.0;
  // the lists hold every node within `margin` of its probe (wall) while the largest node
  // displacement since the rebuild plus the probe's displacement plus the margin stays below
  // the skin (the iterates of an implicit step count as displacements)
  double moved = valid_ && settings_.broad_phase ? node_move(x) : 0.0;
  Eigen::Vector3d surface_point, normal;
  for (int q = 0; q < probes_; ++q) {
    const ProbeGeometry& g = geometry[std::size_t(q)];
    const ProbeState& p = probes[std::size_t(q)];
    keep_lists_valid(x, geometry, probes, q, margin, moved);
    const auto& list = lists_[std::size_t(q)];
    for (const std::int32_t i : list) {
      const double dist = probe_signed_distance(g, p.position_mm, x.col(i), &surface_point, &normal);
      if (!(dist < margin)) continue;
      ContactConstraint c;
      c.node = i;
      c.owner = q;
      c.point_mm = surface_point;
      c.normal = normal;
      out.push_back(c);
    }
    counters_.narrow_tests += std::int64_t(list.size());
    counters_.narrow_tests_skipped += std::int64_t(nodes_.size() - list.size());
  }
  if (workspace_.enabled) {
    keep_lists_valid(x, geometry, probes, probes_, margin, moved);
    const auto& list = lists_[std::size_t(probes_)];
    for (const std::int32_t i : list)
      for (int a = 0; a < 3; ++a)
        for (int side = 0; side < 2; ++side) {
          const double wall = side == 0 ? workspace_.min_mm[a] : workspace_.max_mm[a];
          const double in = side == 0 ? x(a, i) - wall : wall - x(a, i);  // < 0: outside
          if (!(in < margin)) continue;
          ContactConstraint c;
          c.node = i;
          c.owner = probes_ + 2 * a + side;
          c.point_mm = x.col(i);
          c.point_mm[a] = wall;
          c.normal.setZero();
          c.normal[a] = side == 0 ? 1.0 : -1.0;
          out.push_back(c);
        }
    counters_.narrow_tests += std::int64_t(list.size());
    counters_.narrow_tests_skipped += std::int64_t(nodes_.size() - list.size());
  }
}

}  // namespace vx
