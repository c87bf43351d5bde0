#include "haptics/local_contact.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace vx {

const char* to_string(ComplianceSource s) {
  switch (s) {
    case ComplianceSource::none: return "none";
    case ComplianceSource::integrator: return "integrator";
    case ComplianceSource::patch: return "patch";
  }
  return "?";
}

void LocalContactModel::resize(int m) {
  const auto n = std::size_t(std::max(0, m));
  node.resize(n);
  point_mm.resize(3, Eigen::Index(n));
  normal.resize(3, Eigen::Index(n));
  force_n.resize(Eigen::Index(n));
  gap_mm.resize(Eigen::Index(n));
  compliance.resize(Eigen::Index(n), Eigen::Index(n));
}

std::string LocalContactModel::validate() const {
  std::ostringstream err;
  const Eigen::Index m = Eigen::Index(node.size());
  if (point_mm.cols() != m || normal.cols() != m || force_n.size() != m || gap_mm.size() != m ||
      compliance.rows() != m || compliance.cols() != m)
    return "the arrays of the local contact model disagree in size";
  if (!anchor_mm.allFinite() || !anchor_force_n.allFinite()) err << "anchor is not finite; ";
  for (Eigen::Index i = 0; i < m; ++i) {
    if (!(std::abs(normal.col(i).norm() - 1.0) < 1e-6)) err << "normal " << i << " is not a unit vector; ";
    if (!(force_n[i] >= 0.0) || !std::isfinite(force_n[i])) err << "force " << i << " must be >= 0; ";
    if (!(gap_mm[i] >= 0.0) || !std::isfinite(gap_mm[i])) err << "gap " << i << " must be >= 0; ";
    if (!(compliance(i, i) > 0.0) || !std::isfinite(compliance(i, i))) err << "compliance " << i << " must be > 0; ";
    for (Eigen::Index j = 0; j < i; ++j)
      if (!(std::abs(compliance(i, j) - compliance(j, i)) <= 1e-9 * (compliance(i, i) + compliance(j, j)))) {
        err << "compliance is not symmetric at (" << i << ", " << j << "); ";
        break;
      }
    if (err.tellp() > 400) break;
  }
  return err.str();
}

// --------------------------------------------------------------------------- the LCP

LocalContactSolver::LocalContactSolver() {
  const int cap = kMaxNodes;
  normal_.resize(3, cap);
  normal_now_.resize(3, cap);
  point_.resize(3, cap);
  phi0_.resize(cap);
  turn0_.resize(3, cap);
  free_gap_.resize(cap);
  w_.resize(cap, cap);
  lambda_.setZero(cap);
  gap_.resize(cap);
  in_set_.assign(std::size_t(cap), 0);
  set_.reserve(std::size_t(cap));
  factored_set_.reserve(std::size_t(cap));
  chol_.resize(cap, cap);
  rhs_.resize(cap);
  sol_.resize(cap);
  y_.resize(cap, 3);
}

void LocalContactSolver::clear() {
  valid_ = false;
  m_ = 0;
  set_.clear();
  factored_set_.clear();
  result_ = Result{};
}

bool LocalContactSolver::set(const LocalContactModel& model, double coupling_mm_n) {
  const int m = model.size();
  const Eigen::Index em = Eigen::Index(m);
  if (!model.valid || m > kMaxNodes || model.normal.cols() != em || model.force_n.size() != em ||
      model.gap_mm.size() != em || model.compliance.rows() != em || model.compliance.cols() != em ||
      !(coupling_mm_n >= 0.0) || !std::isfinite(coupling_mm_n)) {
    clear();
    return false;
  }
  valid_ = true;
  m_ = m;
  coupling_ = coupling_mm_n;
  anchor_ = model.anchor_mm;
  tool_ = model.tool;
  curved_ = model.tool.shape != ProbeShape::plane && model.point_mm.cols() == em;
  for (int i = 0; i < m; ++i) {
    normal_.col(i) = model.normal.col(i);
    normal_now_.col(i) = model.normal.col(i);
    if (curved_) {
      point_.col(i) = model.point_mm.col(i);
      Eigen::Vector3d n;
      phi0_[i] = probe_signed_distance(tool_, anchor_, point_.col(i), nullptr, &n);
      turn0_.col(i) = n;
    }
  }
  // u = g0 - W lambda0; W' = W + c N^T N
  for (int i = 0; i < m; ++i) {
    double wl = 0.0;
    for (int j = 0; j < m; ++j) wl += model.compliance(i, j) * model.force_n[j];
    free_gap_[i] = model.gap_mm[i] - wl;
    for (int j = 0; j < m; ++j) w_(i, j) = model.compliance(i, j) + coupling_ * normal_.col(i).dot(normal_.col(j));
  }
  // warm start: the anchor's contact set (the solution at the anchor without coupling)
  set_.clear();
  for (int i = 0; i < m; ++i) {
    in_set_[std::size_t(i)] = model.force_n[i] > 0.0 ? 1 : 0;
    if (in_set_[std::size_t(i)]) set_.push_back(i);
  }
  factored_set_.clear();
  factored_set_.push_back(-1);  // nothing factored yet
  result_ = Result{};
  return true;
}

/// Cholesky of W'_SS into chol_ (lower). A pivot below 1e-12 of its diagonal (two nodes whose
/// rows are nearly equal) is raised to it.
bool LocalContactSolver::factor_working_set() {
  const int s = int(set_.size());
  for (int a = 0; a < s; ++a) {
    const int ia = set_[std::size_t(a)];
    for (int b = 0; b <= a; ++b) {
      double v = w_(ia, set_[std::size_t(b)]);
      for (int k = 0; k < b; ++k) v -= chol_(a, k) * chol_(b, k);
      if (b < a) {
        chol_(a, b) = v / chol_(b, b);
      } else {
        const double floor = 1e-12 * std::abs(w_(ia, ia));
        chol_(a, a) = std::sqrt(std::max(v, floor > 0 ? floor : 1e-300));
      }
    }
  }
  factored_set_ = set_;
  // stiffness of this set: K = N_S W'_SS^-1 N_S^T = Y^T Y with Y = L^-1 N_S^T
  for (int a = 0; a < s; ++a) {
    const int ia = set_[std::size_t(a)];
    for (int c = 0; c < 3; ++c) {
      double v = normal_(c, ia);
      for (int k = 0; k < a; ++k) v -= chol_(a, k) * y_(k, c);
      y_(a, c) = v / chol_(a, a);
    }
  }
  Eigen::Matrix3d k = Eigen::Matrix3d::Zero();
  for (int a = 0; a < s; ++a)
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) k(r, c) += y_(a, r) * y_(a, c);
  result_.stiffness_n_mm = 0.5 * (k + k.transpose());
  return true;
}

void LocalContactSolver::solve_working_set(const double* rhs, double* x) const {
  const int s = int(set_.size());
  for (int a = 0; a < s; ++a) {
    double v = rhs[a];
    for (int k = 0; k < a; ++k) v -= chol_(a, k) * x[k];
    x[a] = v / chol_(a, a);
  }
  for (int a = s - 1; a >= 0; --a) {
    double v = x[a];
    for (int k = a + 1; k < s; ++k) v -= chol_(k, a) * x[k];
    x[a] = v / chol_(a, a);
  }
}

const LocalContactSolver::Result& LocalContactSolver::solve(const Eigen::Vector3d& device_mm) {
  Result& r = result_;
  r.force_n.setZero();
  r.proxy_mm = device_mm;
  r.active = 0;
  r.rounds = 0;
  r.converged = true;
  if (!valid_ || m_ == 0) {
    r.stiffness_n_mm.setZero();
    return r;
  }
  const int m = m_;
  const Eigen::Vector3d d = device_mm - anchor_;
  // the gaps with no contact force: b = u - N^T d, or with a curved tool the exact change of each
  // node's distance from it (and the normals there)
  for (int i = 0; i < m; ++i) {
    if (curved_) {
      Eigen::Vector3d n;
      const double phi = probe_signed_distance(tool_, device_mm, point_.col(i), nullptr, &n);
      gap_[i] = free_gap_[i] + phi - phi0_[i];
      // the normals turn with the tool, except for a node deeper than a quarter of the radius
      // (a stale model, the tool far from its anchor): its closest-point normal flips as the
      // tool's centre or axis passes it, so the turn fades out to none at half the radius
      // (measured on the organ, 3 physics updates per second: a 28 % step of the force)
      const double r = std::max(tool_.radius_mm, 1e-9);
      const double w = std::clamp((0.5 * r + phi) / (0.25 * r), 0.0, 1.0);
      normal_now_.col(i) = normal_.col(i) + w * (n - turn0_.col(i));
    } else {
      gap_[i] = free_gap_[i] - normal_.col(i).dot(d);
    }
    lambda_[i] = 0.0;
  }
  constexpr double kTol = 1e-10;  // mm
  for (;;) {
    ++r.rounds;
    if (set_ != factored_set_) factor_working_set();
    const int s = int(set_.size());
    // W'_SS lambda_S = -b_S
    for (int a = 0; a < s; ++a) rhs_[a] = -gap_[set_[std::size_t(a)]];
    solve_working_set(rhs_.data(), sol_.data());
    bool dropped = false;
    for (int a = 0; a < s; ++a)
      if (!(sol_[a] >= 0.0)) {
        in_set_[std::size_t(set_[std::size_t(a)])] = 0;
        dropped = true;
      }
    bool added = false;
    if (!dropped) {
      // the nodes off the set that the solution pushes through the tool join it
      for (int i = 0; i < m; ++i) {
        if (in_set_[std::size_t(i)]) continue;
        double g = gap_[i];
        for (int a = 0; a < s; ++a) g += w_(i, set_[std::size_t(a)]) * sol_[a];
        if (g < -kTol) {
          in_set_[std::size_t(i)] = 1;
          added = true;
        }
      }
    }
    if (!dropped && !added) {
      for (int a = 0; a < s; ++a) lambda_[set_[std::size_t(a)]] = sol_[a];
      break;
    }
    if (r.rounds >= kMaxRounds) {
      // (not converged: keep the multipliers that push)
      for (int a = 0; a < s; ++a) lambda_[set_[std::size_t(a)]] = std::max(0.0, sol_[a]);
      r.converged = false;
      break;
    }
    set_.clear();
    for (int i = 0; i < m; ++i)
      if (in_set_[std::size_t(i)]) set_.push_back(i);
  }
  // the next solve starts from the nodes that push now
  set_.clear();
  for (int i = 0; i < m; ++i) {
    in_set_[std::size_t(i)] = lambda_[i] > 0.0 ? 1 : 0;
    if (lambda_[i] > 0.0) {
      set_.push_back(i);
      r.force_n -= lambda_[i] * normal_now_.col(i);
      ++r.active;
    }
  }
  r.proxy_mm = device_mm + coupling_ * r.force_n;
  if (set_ != factored_set_) factor_working_set();  // the stiffness of the final set
  return r;
}

// --------------------------------------------------------------------------- the renderer

std::string HapticCouplingSettings::validate() const {
  std::ostringstream err;
  if (!(device_rate_hz > 0) || !std::isfinite(device_rate_hz)) err << "device rate must be > 0; ";
  if (!(device_damping_n_s_mm > 0) || !std::isfinite(device_damping_n_s_mm))
    err << "device damping must be > 0 N s/mm; ";
  if (!(damping_margin >= 0.0) || !std::isfinite(damping_margin))
    err << "damping margin " << damping_margin << " must be >= 0 (below 0.5 the hold adds energy); ";
  if (!std::isfinite(coupling_stiffness_n_mm)) err << "coupling stiffness must be finite; ";
  if (!std::isfinite(blend_s) || blend_s > 1.0) err << "blend time must be <= 1 s; ";
  return err.str();
}

double HapticCouplingSettings::stiffness_n_mm() const {
  if (coupling_stiffness_n_mm > 0) return coupling_stiffness_n_mm;
  return device_damping_n_s_mm / ((0.5 + damping_margin) * period_s());
}

void LocalForceRenderer::init(const HapticCouplingSettings& settings) {
  settings_ = settings;
  k_c_ = settings.stiffness_n_mm();
  blend_ = settings.blend_s > 0 ? settings.blend_s : 0.02;
  reset();
}

void LocalForceRenderer::reset() {
  solver_.clear();
  has_last_ = false;
  offset0_.setZero();
  offset_start_ = 0.0;
  models_ = 0;
  energy_ = 0.0;
  velocity_.setZero();
  guard_ticks_ = 0;
  guard_energy_ = 0.0;
  guard_last_.setZero();
  out_ = Output{};
}

void LocalForceRenderer::update_model(const LocalContactModel& model, double now_s, double physics_period_s) {
  if (settings_.blend_s > 0)
    blend_ = settings_.blend_s;
  else if (physics_period_s > 0)
    blend_ = std::clamp(physics_period_s, settings_.period_s(), 0.05);
  // what the hand feels now without the damping: the old model's force and what is left of
  // the last offset; the new model starts from the same force
  const double fade = blend_ > 0 ? std::max(0.0, 1.0 - (now_s - offset_start_) / blend_) : 0.0;
  const Eigen::Vector3d before = out_.contact_n + fade * offset0_;
  (void)solver_.set(model, 1.0 / k_c_);
  ++models_;
  if (!has_last_) {
    offset0_.setZero();
    offset_start_ = now_s;
    return;
  }
  const Eigen::Vector3d after = solver_.solve(last_device_).force_n;
  offset0_ = before - after;
  offset_start_ = now_s;
  out_.contact_n = after;
}

const LocalForceRenderer::Output& LocalForceRenderer::tick(const Eigen::Vector3d& device_mm, double now_s) {
  Output& o = out_;
  // the observer: the last tick's force, held while the device moved here
  double dt = 0.0;
  if (has_last_) {
    energy_ -= o.force_n.dot(device_mm - last_device_);
    dt = now_s - last_time_;
    velocity_ = dt > 0 ? Eigen::Vector3d((device_mm - last_device_) / dt) : Eigen::Vector3d::Zero();
  }
  const LocalContactSolver::Result& r = solver_.solve(device_mm);
  o.contact_n = r.force_n;
  o.proxy_mm = r.proxy_mm;
  o.stiffness_n_mm = r.stiffness_n_mm;
  o.contacts = r.active;
  o.converged = r.converged;
  // damping from the device rate: -beta T K v (v: the device's velocity over the last tick)
  o.damping_n.setZero();
  if (has_last_ && r.active > 0)
    o.damping_n = -(settings_.damping_margin * settings_.period_s()) * (r.stiffness_n_mm * velocity_);
  const double fade = blend_ > 0 ? std::max(0.0, 1.0 - (now_s - offset_start_) / blend_) : 0.0;
  o.offset_n = fade * offset0_;
  o.force_n = o.contact_n + o.damping_n + o.offset_n;
  // the controller: over the coming tick (the device keeping its velocity, with a 20 % margin)
  // the force may give the hand at most 1/n of the energy it has put in (n: the taper's ticks),
  // so that as the energy runs out the force along the motion fades geometrically, by 1/n per
  // tick, instead of being cut in one tick; a correction is released by 1/n per tick too
  o.guard_n.setZero();
  if (settings_.energy_guard && has_last_) {
    const double n = std::max(1.0, kGuardTaper_s / settings_.period_s());
    Eigen::Vector3d g = (1.0 - 1.0 / n) * guard_last_;
    const double v2 = velocity_.squaredNorm();
    if (v2 > 0) {
      const double h = 1.2 * (dt > 0 ? dt : settings_.period_s());
      const double out = (o.force_n + g).dot(velocity_) * h;  // energy to the hand over the coming tick
      const double allowed = std::max(0.0, energy_) / n;
      if (out > allowed) {
        g -= ((out - allowed) / (v2 * h)) * velocity_;
        ++guard_ticks_;
        guard_energy_ += out - allowed;
      }
    }
    if (g.squaredNorm() > 1e-30) {
      o.guard_n = g;
      o.force_n += g;
    }
  }
  guard_last_ = o.guard_n;
  o.energy_mj = energy_;
  has_last_ = true;
  last_device_ = device_mm;
  last_time_ = now_s;
  return o;
}

}  // namespace vx
