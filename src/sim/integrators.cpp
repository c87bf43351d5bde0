#include "sim/integrators.h"

#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <sstream>

#include "base/error.h"
#include "base/parallel.h"

namespace vx {

StepReport Integrator::advance(SimState& state, int steps) {
  StepReport r;
  for (int i = 0; i < steps; ++i) {
    r = step(state);
    if (state.status == StepStatus::non_finite ||
        (state.status == StepStatus::runaway && settings_.limits.stop_on_runaway))
      break;
  }
  return r;
}

const std::vector<ContactConstraint>& Integrator::contacts() const {
  static const std::vector<ContactConstraint> none;
  return none;
}

namespace {

// ---------------------------------------------------------------------------------------------
// shared: checking and applying a step

constexpr std::uint8_t kFlagNonFinite = 1;
constexpr std::uint8_t kFlagRunaway = 2;

double max_displacement(const PhysicsModel& p, const StabilityLimits& l) {
  if (l.max_displacement_mm > 0) return l.max_displacement_mm;
  const Eigen::Matrix3Xd& r = p.model->rest_positions;
  const double diag = (r.rowwise().maxCoeff() - r.rowwise().minCoeff()).norm();
  return 10.0 * std::max(diag, 1.0);
}

/// Checks one node's new position and velocity.
inline std::uint8_t check_node(const Eigen::Vector3d& xn, const Eigen::Vector3d& vn, const Eigen::Vector3d& rest,
                               double max_v2, double max_d2) {
  if (!xn.allFinite() || !vn.allFinite()) return kFlagNonFinite;
  if (vn.squaredNorm() > max_v2 || (xn - rest).squaredNorm() > max_d2) return kFlagRunaway;
  return 0;
}

/// Applies (or refuses) the step in state.scratch.next_*: on success swaps it in and advances
/// time; on failure sets the state's status and a message saying what and where.
void finish_step(SimState& s, const IntegratorSettings& set, std::uint8_t flags, StepReport& rep) {
  const double dt = set.time_step_s;
  if (flags) {
    const PhysicsModel& p = *s.physics;
    const double max_v = set.limits.max_speed_mm_s, max_d = max_displacement(p, set.limits);
    // find the first offending node (failure path only: may allocate)
    int node = -1;
    const Eigen::Matrix3Xd& rest = p.model->rest_positions;
    for (int i = 0; i < s.num_nodes() && node < 0; ++i)
      if (check_node(s.scratch.next_positions.col(i), s.scratch.next_velocities.col(i), rest.col(i), max_v * max_v,
                     max_d * max_d) != 0)
        node = i;
    const double limit = stable_time_step(p, set.kind);
    std::ostringstream msg;
    msg << to_string(set.kind) << " step " << s.steps << " (t = " << s.time_s << " s, dt = " << dt << " s): ";
    if (flags & kFlagNonFinite) {
      msg << "NaN/Inf";
      if (node >= 0) msg << " at node " << node;
      if (s.element_stats.non_finite > 0) msg << " (" << s.element_stats.non_finite << " elements with non-finite input)";
    } else if (node >= 0) {
      msg << "runaway at node " << node << ": speed " << s.scratch.next_velocities.col(node).norm()
          << " mm/s (limit " << max_v << "), displacement " << (s.scratch.next_positions.col(node) - rest.col(node)).norm()
          << " mm (limit " << max_d << ")";
    } else {
      msg << "runaway";
    }
    msg << "; the stable time step of " << to_string(set.kind) << " is estimated at " << limit << " s";
    if (set.kind == IntegratorKind::explicit_euler && limit == 0.0)
      msg << " (explicit Euler needs damping: set a damping ratio > 0)";
    if (flags & kFlagNonFinite || set.limits.stop_on_runaway) msg << "; the step was not applied, the state is stopped";
    s.status = (flags & kFlagNonFinite) ? StepStatus::non_finite : StepStatus::runaway;
    s.message = msg.str();
    rep.status = s.status;
    if ((flags & kFlagNonFinite) || set.limits.stop_on_runaway) return;
  }
  s.positions.swap(s.scratch.next_positions);
  s.velocities.swap(s.scratch.next_velocities);
  s.time_s += dt;
  ++s.steps;
}

/// Ends a step after the per-chunk node pass: merges the chunks' flags and kinetic and
/// gravitational energies in chunk order (the same for any thread count), stores the energies
/// when tracked (with the given elastic energy) and finishes the step.
void finish_node_pass(SimState& s, const PhysicsModel& p, const IntegratorSettings& set, bool track,
                      double elastic_energy, StepReport& rep) {
  std::uint8_t flags = s.element_stats.non_finite > 0 ? kFlagNonFinite : 0;
  Energies en;
  const std::size_t chunks = std::size_t(chunk_count(p.num_nodes(), kNodeGrain));
  for (std::size_t c = 0; c < chunks; ++c) {
    flags |= s.scratch.node_chunk_flags[c];
    en.kinetic += s.scratch.node_chunk_sums[3 * c];
    en.gravitational += s.scratch.node_chunk_sums[3 * c + 1];
  }
  if (track) {
    en.elastic = elastic_energy;
    s.energies = en;
  }
  finish_step(s, set, flags, rep);
}

/// True when the state may not be stepped: a NaN/Inf, or a runaway under stop_on_runaway.
bool blocked(const SimState& s, const IntegratorSettings& set) {
  return s.status == StepStatus::non_finite || (s.status == StepStatus::runaway && set.limits.stop_on_runaway);
}

bool any_damping(const PhysicsModel& p) {
  for (double c : p.element_damping)
    if (c > 0) return true;
  return false;
}

// ---------------------------------------------------------------------------------------------
// explicit and symplectic Euler

/// The per-node part of an explicit step (what it reads and writes; raw pointers, so that the
/// compiler need not reload them through the state's members).
struct NodePass {
  double dt{0}, max_v2{0}, max_d2{0}, gx{0}, gy{0}, gz{0};
  const double *ef{}, *xs{}, *vs{}, *fext{}, *rest{}, *mass{}, *inv_mass{};
  double *xo{}, *vo{}, *chunk_sums{};
  const std::uint8_t* fixed{};
  const std::int32_t* noff{};
  std::uint8_t* chunk_flags{};
};

/// Nodes [b, e) (chunk c) of an explicit step: gather the entry forces in entry order, add
/// external forces and gravity, integrate (symplectic: position with the new velocity; else
/// the paper's eq. 1-2, position with the old velocity; fixed nodes move kinematically), check
/// (finite, speed, distance from rest) and sum the energies when tracked.
template <bool kSymplectic, bool kTrack>
void explicit_nodes(const NodePass& n, std::int64_t c, std::int64_t b, std::int64_t e) {
  std::uint8_t flags = 0;
  double kin = 0, grav = 0;
  const double dt = n.dt;
  for (std::int64_t i = b; i < e; ++i) {
    const double* x = n.xs + 3 * i;
    const double* v = n.vs + 3 * i;
    const double* r = n.rest + 3 * i;
    if constexpr (kTrack) {
      kin += 0.5 * n.mass[i] * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      grav -= n.mass[i] * (n.gx * (x[0] - r[0]) + n.gy * (x[1] - r[1]) + n.gz * (x[2] - r[2]));
    }
    double f0 = n.fext[3 * i], f1 = n.fext[3 * i + 1], f2 = n.fext[3 * i + 2];
    for (std::int32_t j = n.noff[i]; j < n.noff[i + 1]; ++j) {  // contiguous slots
      const double* fj = n.ef + 3 * std::int64_t(j);
      f0 += fj[0];
      f1 += fj[1];
      f2 += fj[2];
    }
    // a fixed node is kinematic: no acceleration (its forces do not act)
    const bool free = !n.fixed[i];
    const double im = n.inv_mass[i];
    const double a0 = free ? f0 * im + n.gx : 0.0, a1 = free ? f1 * im + n.gy : 0.0, a2 = free ? f2 * im + n.gz : 0.0;
    double nx0, nx1, nx2, nv0, nv1, nv2;
    nv0 = v[0] + dt * a0, nv1 = v[1] + dt * a1, nv2 = v[2] + dt * a2;
    if constexpr (kSymplectic) {
      nx0 = x[0] + dt * nv0, nx1 = x[1] + dt * nv1, nx2 = x[2] + dt * nv2;
    } else {
      nx0 = x[0] + dt * v[0], nx1 = x[1] + dt * v[1], nx2 = x[2] + dt * v[2];
    }
    const double v2 = nv0 * nv0 + nv1 * nv1 + nv2 * nv2;
    const double dx = nx0 - r[0], dy = nx1 - r[1], dz = nx2 - r[2];
    const double d2 = dx * dx + dy * dy + dz * dz;
    if (!std::isfinite(v2 + d2 + nx0 + nx1 + nx2))
      flags |= kFlagNonFinite;
    else if (v2 > n.max_v2 || d2 > n.max_d2)
      flags |= kFlagRunaway;
    double* xo = n.xo + 3 * i;
    double* vo = n.vo + 3 * i;
    xo[0] = nx0, xo[1] = nx1, xo[2] = nx2;
    vo[0] = nv0, vo[1] = nv1, vo[2] = nv2;
  }
  n.chunk_flags[c] = flags;
  n.chunk_sums[3 * c] = kin;
  n.chunk_sums[3 * c + 1] = grav;
}

class ExplicitIntegrator final : public Integrator {
 public:
  using Integrator::Integrator;

  StepReport step(SimState& s) override {
    StepReport rep;
    if (blocked(s, settings_)) {
      rep.status = s.status;
      return rep;
    }
    const PhysicsModel& p = *s.physics;
    const int threads = settings_.threads;
    const double dt = settings_.time_step_s;
    if (cached_physics_ != &p) {  // per-model constants (no allocation)
      cached_physics_ = &p;
      damped_ = any_damping(p);
      max_d_ = max_displacement(p, settings_.limits);
    }
    // forces of the elements at (x, v)
    ElementPassOptions opt;
    opt.damping = damped_;
    opt.energy = settings_.track_energy;
    opt.rotation = settings_.rotation;
    s.element_stats = compute_element_forces(p, s.positions, &s.velocities, s.rotations, s.scratch.entry_forces,
                                             &s.scratch.element_energy, opt, threads, s.scratch.element_pass);
    rep.iterations = 1;
    rep.inverted_elements = s.element_stats.inverted;
    rep.unconverged_rotations = s.element_stats.unconverged;

    // per node: gather, add gravity and external forces, integrate, check
    const bool symplectic = settings_.kind == IntegratorKind::symplectic_euler;
    const bool track = settings_.track_energy;
    NodePass np;
    np.dt = dt;
    np.max_v2 = settings_.limits.max_speed_mm_s * settings_.limits.max_speed_mm_s;
    np.max_d2 = max_d_ * max_d_;
    np.gx = s.gravity_mm_s2.x(), np.gy = s.gravity_mm_s2.y(), np.gz = s.gravity_mm_s2.z();
    np.ef = s.scratch.entry_forces.data();
    np.xs = s.positions.data();
    np.vs = s.velocities.data();
    np.fext = s.external_forces.data();
    np.rest = p.model->rest_positions.data();
    np.xo = s.scratch.next_positions.data();
    np.vo = s.scratch.next_velocities.data();
    np.fixed = s.node_fixed.data();
    np.noff = p.node_entry_offsets.data();
    np.mass = p.node_mass.data();
    np.inv_mass = p.node_inv_mass.data();
    np.chunk_flags = s.scratch.node_chunk_flags.data();
    np.chunk_sums = s.scratch.node_chunk_sums.data();
    const auto run = symplectic ? (track ? &explicit_nodes<true, true> : &explicit_nodes<true, false>)
                                : (track ? &explicit_nodes<false, true> : &explicit_nodes<false, false>);
    parallel_for_chunks(p.num_nodes(), kNodeGrain, threads,
                        [&](std::int64_t c, std::int64_t b, std::int64_t e) { run(np, c, b, e); });
    finish_node_pass(s, p, settings_, track, s.element_stats.elastic_energy, rep);
    return rep;
  }

 private:
  const PhysicsModel* cached_physics_{nullptr};
  bool damped_{false};
  double max_d_{0.0};
};

// ---------------------------------------------------------------------------------------------
// projective dynamics: prefactored global matrix + local rotation fits

using SpMat = Eigen::SparseMatrix<double>;

class ProjectiveSolver {
 public:
  /// True when the factorisation fits this state, time step and mode.
  [[nodiscard]] bool ready_for(const SimState& s, double dt, bool inertia, bool damping) const {
    return physics_ == s.physics.get() && state_ == &s && fixed_version_ == s.fixed_version && dt_ == dt &&
           inertia_ == inertia && damping_ == damping;
  }

  /// Builds and factors the system matrix (allocates). Throws vx::Error on failure.
  void setup(const SimState& s, double dt, bool inertia, bool damping) {
    const PhysicsModel& p = *s.physics;
    const Model& m = *p.model;
    const int nn = p.num_nodes(), ne = p.num_elements();
    physics_ = s.physics.get();
    state_ = &s;
    fixed_version_ = s.fixed_version;
    dt_ = dt;
    inertia_ = inertia;
    damping_ = damping;
    // free numbering
    free_index_.assign(std::size_t(nn), -1);
    fixed_index_.assign(std::size_t(nn), -1);
    free_nodes_.clear();
    fixed_nodes_.clear();
    for (int i = 0; i < nn; ++i) {
      if (s.node_fixed[std::size_t(i)]) {
        fixed_index_[std::size_t(i)] = int(fixed_nodes_.size());
        fixed_nodes_.push_back(i);
      } else {
        free_index_[std::size_t(i)] = int(free_nodes_.size());
        free_nodes_.push_back(i);
      }
    }
    const int nf = int(free_nodes_.size()), nc = int(fixed_nodes_.size());
    if (!inertia) check_held(s);
    // weights kappa_e = k_v,e (+ c_e / dt) of diag(w) - w w^T / W (volume and damping terms)
    kappa_.resize(std::size_t(ne));
    for (int e = 0; e < ne; ++e)
      kappa_[std::size_t(e)] = (p.has_volume_term() ? p.element_volume_stiffness[std::size_t(e)] : 0.0) +
                               (damping ? p.element_damping[std::size_t(e)] / dt : 0.0);
    // assemble M/dt^2 + sum_e (K_e + kappa_e (diag(w) - w w^T / W)), split into free-free and
    // free-fixed (K_e: the elastic matrix, elements.h)
    std::vector<Eigen::Triplet<double>> tff, tfc;
    std::size_t guess = 0;
    for (int e = 0; e < ne; ++e) guess += std::size_t(m.num_vertices(e)) * std::size_t(m.num_vertices(e));
    tff.reserve(guess + std::size_t(nf));
    Eigen::MatrixXd ke;
    for (int e = 0; e < ne; ++e) {
      const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
      const double kap = kappa_[std::size_t(e)];
      const double* w = p.entry_weight.data() + b;
      double wsum = 0;
      for (int i = 0; i < n; ++i) wsum += w[i];
      element_elastic_matrix(p, e, ke);
      for (int i = 0; i < n; ++i) {
        const int fi = free_index_[std::size_t(m.element_vertices[b + i])];
        if (fi < 0) continue;
        for (int j = 0; j < n; ++j) {
          const int nj = m.element_vertices[b + j];
          const double v = ke(i, j) + kap * ((i == j ? w[i] : 0.0) - w[i] * w[j] / wsum);
          if (free_index_[std::size_t(nj)] >= 0)
            tff.emplace_back(fi, free_index_[std::size_t(nj)], v);
          else
            tfc.emplace_back(fi, fixed_index_[std::size_t(nj)], v);
        }
      }
    }
    if (inertia)
      for (int f = 0; f < nf; ++f) tff.emplace_back(f, f, p.node_mass[std::size_t(free_nodes_[std::size_t(f)])] / (dt * dt));
    SpMat a(nf, nf);
    a.setFromTriplets(tff.begin(), tff.end());
    tff.clear();
    tff.shrink_to_fit();
    a_fc_.resize(nf, nc);
    a_fc_.setFromTriplets(tfc.begin(), tfc.end());
    ldlt_.compute(a);
    if (ldlt_.info() != Eigen::Success)
      throw Error("implicit integrator: the system matrix could not be factored (" + std::to_string(nf) +
                  " free nodes); is a part of the model held by nothing?");
    nnz_factor_ = ldlt_.matrixL().nestedExpression().nonZeros();
    // buffers
    const std::int64_t entries = p.num_vertex_entries();
    targets_.resize(3, entries);
    rest_now_.resize(3, entries);
    damp_rot_.assign(std::size_t(ne), Eigen::Quaterniond::Identity());
    rhs_const_.resize(nf, 3);
    rhs_.resize(nf, 3);
    rhs_prev_.resize(nf, 3);
    sol_.resize(nf, 3);
    work_.assign(3 * std::size_t(nf), 0.0);
    xc_.resize(nc, 3);
    x_start_.resize(3, nn);
    const std::size_t ec = std::size_t(chunk_count(ne, kElementGrain));
    elem_chunks_.assign(ec, ElementPassStats{});
    const std::size_t fc = std::size_t(chunk_count(nf, kNodeGrain));
    free_chunk_sums_.assign(2 * fc, 0.0);
    // contact: the cached columns A_s^-1 e_i belong to the old factorisation
    xu_.resize(nf, 3);
    x_trial_.resize(3, nn);
    col_work_.assign(std::size_t(nf), 0.0);
    col_slot_.assign(std::size_t(nf), -1);
    slot_free_.clear();
    slot_stamp_.clear();
    used_slots_ = 0;
    if (cols_.rows() != nf) cols_.resize(nf, 0);
  }

  /// Contact constraints for the following iterate() calls (null: none).
  void set_contact(ContactProvider* provider) { contact_ = provider; }
  [[nodiscard]] bool has_contact() const { return contact_ != nullptr; }
  /// The constraints active after the last global solve, sorted by (owner, node), with their
  /// multipliers (N); the next solve starts from them (warm start).
  [[nodiscard]] const std::vector<ContactConstraint>& active_contacts() const { return active_; }
  /// Forgets the warm start (the state was reset or replaced).
  void forget_contacts() { active_.clear(); }

  [[nodiscard]] int num_free() const { return int(free_nodes_.size()); }
  [[nodiscard]] std::int64_t factor_nonzeros() const { return nnz_factor_; }

  /// Runs the local/global iterations on `x` (3 x nodes; fixed nodes already at their targets).
  /// `rhs_const_` must be set by the caller (per free node: inertia and external terms minus
  /// the fixed nodes' coupling, see set_fixed_coupling()).
  void iterate(SimState& s, Eigen::Matrix3Xd& x, int max_iterations, double tolerance_mm,
               const RotationFitSettings& fit, int threads, StepReport& rep) {
    const PhysicsModel& p = *s.physics;
    const int nf = num_free();
    double max_update = std::numeric_limits<double>::infinity();
    ElementPassStats last;
    int it = 0;
    for (; it < max_iterations; ++it) {
      last = local_step(s, x, fit, threads);
      // global right-hand side: per free node, in entry order
      parallel_for(nf, kNodeGrain, threads, [&](std::int64_t b, std::int64_t e) {
        for (std::int64_t f = b; f < e; ++f) {
          const Eigen::Vector3d t = gather_node_force(p, targets_, free_nodes_[std::size_t(f)]);
          rhs_.row(f) = rhs_const_.row(f) + t.transpose();
        }
      });
      if (it > 0) rep.residual_n = rms_difference(rhs_, rhs_prev_, threads);
      if (tolerance_mm > 0 && it > 0 && max_update <= tolerance_mm) break;
      solve();
      if (contact_) solve_contacts(x, threads, rep);
      max_update = scatter(x, threads);
      rhs_prev_.swap(rhs_);
    }
    if (contact_) rep.contacts = int(active_.size());
    rep.iterations = it;
    rep.max_update_mm = it > 0 ? max_update : 0.0;
    rep.inverted_elements = last.inverted;
    rep.unconverged_rotations = last.unconverged;
    s.element_stats = last;
  }

  /// rhs_const_ -= A_fc * x_c for the fixed nodes' positions in x.
  void subtract_fixed_coupling(const Eigen::Matrix3Xd& x) {
    if (fixed_nodes_.empty()) return;
    for (std::size_t c = 0; c < fixed_nodes_.size(); ++c) xc_.row(Eigen::Index(c)) = x.col(fixed_nodes_[c]).transpose();
    rhs_const_.noalias() -= a_fc_ * xc_;
  }

  /// Relative offsets of the vertices at the start of the step (for the damping term).
  void record_start_shape(const PhysicsModel& p, const Eigen::Matrix3Xd& x, int threads) {
    const Model& m = *p.model;
    parallel_for(p.num_elements(), kElementGrain, threads, [&](std::int64_t b, std::int64_t e) {
      for (std::int64_t el = b; el < e; ++el) {
        const int o = m.element_offsets[el], n = m.element_offsets[el + 1] - o;
        Eigen::Vector3d c = Eigen::Vector3d::Zero();
        double sw = 0;
        for (int j = o; j < o + n; ++j) {
          c += p.entry_weight[std::size_t(j)] * x.col(m.element_vertices[j]);
          sw += p.entry_weight[std::size_t(j)];
        }
        c /= sw;
        for (int j = o; j < o + n; ++j) rest_now_.col(j) = x.col(m.element_vertices[j]) - c;
        damp_rot_[std::size_t(el)] = Eigen::Quaterniond::Identity();
      }
    });
  }

  Eigen::MatrixX3d& rhs_const() { return rhs_const_; }
  const std::vector<int>& free_nodes() const { return free_nodes_; }
  Eigen::Matrix3Xd& x_start() { return x_start_; }
  std::vector<double>& free_chunk_sums() { return free_chunk_sums_; }

 private:
  /// Every connected part of the model must hold a fixed node (static solve).
  void check_held(const SimState& s) const {
    const PhysicsModel& p = *s.physics;
    const Model& m = *p.model;
    std::vector<int> parent(std::size_t(p.num_nodes()));
    std::iota(parent.begin(), parent.end(), 0);
    const auto find = [&](int a) {
      while (parent[std::size_t(a)] != a) a = parent[std::size_t(a)] = parent[std::size_t(parent[std::size_t(a)])];
      return a;
    };
    for (int e = 0; e < p.num_elements(); ++e)
      for (int j = m.element_offsets[e] + 1; j < m.element_offsets[e + 1]; ++j)
        parent[std::size_t(find(m.element_vertices[j]))] = find(m.element_vertices[m.element_offsets[e]]);
    std::vector<std::uint8_t> held(std::size_t(p.num_nodes()), 0);
    for (int i : fixed_nodes_) held[std::size_t(find(i))] = 1;
    for (int i = 0; i < p.num_nodes(); ++i)
      if (!held[std::size_t(find(i))])
        throw Error("static solve: node " + std::to_string(i) +
                    " belongs to a part of the model that no fixed node holds; fix nodes in every part "
                    "(e.g. nodes_on_face) before solving");
  }

  /// Local step: per element the rotation fits and the per-entry targets
  /// t_i = 2 mu V Q g_i + w_i (k_v T R0_i + (c/dt) R_d r_i^n)  (w_i: vertex weight, g_i: gradient weight).
  ElementPassStats local_step(SimState& s, const Eigen::Matrix3Xd& x, const RotationFitSettings& fit, int threads) {
    const PhysicsModel& p = *s.physics;
    const Model& m = *p.model;
    const bool volume = p.has_volume_term();
    const double inv_dt = 1.0 / dt_;
    parallel_for_chunks(p.num_elements(), kElementGrain, threads, [&](std::int64_t chunk, std::int64_t b, std::int64_t e) {
      ElementPassStats st;
      for (std::int64_t el = b; el < e; ++el) {
        const int o = m.element_offsets[el], n = m.element_offsets[el + 1] - o;
        // (sum w R0 = sum w r^n = 0: no centring needed)
        const Eigen::Vector3d x0 = x.col(m.element_vertices[o]);
        Eigen::Matrix3d a = Eigen::Matrix3d::Zero(), fg = Eigen::Matrix3d::Zero(), ad = Eigen::Matrix3d::Zero();
        for (int j = o; j < o + n; ++j) {
          const Eigen::Vector3d y = x.col(m.element_vertices[j]) - x0;
          fg.noalias() += y * p.entry_gradient.col(j).transpose();
          if (volume) a.noalias() += y * p.entry_rest_weighted.col(j).transpose();
          if (damping_) ad.noalias() += (p.entry_weight[std::size_t(j)] * y) * rest_now_.col(j).transpose();
        }
        const std::int32_t* slot = p.entry_slot.data();
        if (!fg.allFinite() || !a.allFinite()) {
          ++st.non_finite;
          for (int j = o; j < o + n; ++j) targets_.col(slot[j]).setZero();
          continue;
        }
        bool conv = true;
        Eigen::Matrix3d rq;
        st.rotation_iterations += fit_rotation(fg, s.rotations[std::size_t(el)], fit, &conv, &rq);
        st.unconverged += conv ? 0 : 1;
        if (fg.determinant() <= 0) ++st.inverted;
        const Eigen::Matrix3d mg = p.element_affine_stiffness[std::size_t(el)] * rq;
        Eigen::Matrix3d mq = Eigen::Matrix3d::Zero();
        if (volume) {
          const Eigen::Matrix3d& ninv = p.element_spread_inv_sqrt[std::size_t(el)];
          Eigen::Quaterniond qv = s.rotations[std::size_t(el)];
          mq = p.element_volume_stiffness[std::size_t(el)] *
               closest_with_determinant(a * ninv, p.element_spread_sqrt_det[std::size_t(el)], qv, fit) * ninv;
        }
        if (damping_) {
          Eigen::Matrix3d rd;
          fit_rotation(ad, damp_rot_[std::size_t(el)], fit, nullptr, &rd);
          const Eigen::Matrix3d md = p.element_damping[std::size_t(el)] * inv_dt * rd;
          for (int j = o; j < o + n; ++j)
            targets_.col(slot[j]).noalias() = mg * p.entry_gradient.col(j) + mq * p.entry_rest_weighted.col(j) +
                                              p.entry_weight[std::size_t(j)] * (md * rest_now_.col(j));
        } else {
          for (int j = o; j < o + n; ++j)
            targets_.col(slot[j]).noalias() = mg * p.entry_gradient.col(j) + mq * p.entry_rest_weighted.col(j);
        }
      }
      elem_chunks_[std::size_t(chunk)] = st;
    });
    ElementPassStats total;
    for (const auto& c : elem_chunks_) total.add(c);
    return total;
  }

  /// Global step: P^T L D L^T P x = b for the three coordinates at once, in one pass over the
  /// factor per triangle (each entry of L serves three right-hand sides; serial, so no
  /// thread waits at a barrier; deterministic). L is Eigen's strictly lower unit factor.
  void solve() {
    const int nf = num_free();
    const auto& perm = ldlt_.permutationP().indices();
    double* w = work_.data();  // nf x 3, row-major
    for (int i = 0; i < nf; ++i)
      for (int c = 0; c < 3; ++c) w[3 * perm(i) + c] = rhs_(i, c);
    factor_solve_in_place<3>(w, 0);
    for (int i = 0; i < nf; ++i)
      for (int c = 0; c < 3; ++c) sol_(i, c) = w[3 * perm(i) + c];
  }

  /// Solves L D L^T w = w in place on the factor (permuted order; K right-hand sides
  /// interleaved, row-major nf x K). Entries before `first` must be zero in every lane: the
  /// forward pass starts there (a unit vector's solve skips the rows above it).
  template <int K>
  void factor_solve_in_place(double* w, int first) const {
    const int nf = num_free();
    const auto& l = ldlt_.matrixL().nestedExpression();
    const auto& d = ldlt_.vectorD();
    const auto* outer = l.outerIndexPtr();
    const auto* nnz = l.innerNonZeroPtr();
    const auto* inner = l.innerIndexPtr();
    const double* val = l.valuePtr();
    // forward: L z = w
    for (int j = first; j < nf; ++j) {
      double wj[K];
      bool zero = true;
      for (int c = 0; c < K; ++c) {
        wj[c] = w[K * j + c];
        zero = zero && wj[c] == 0.0;
      }
      if (zero) continue;  // nothing to carry (sparse right-hand sides)
      const auto end = nnz ? outer[j] + nnz[j] : outer[j + 1];
      for (auto p = outer[j]; p < end; ++p) {
        double* wi = w + K * std::int64_t(inner[p]);
        for (int c = 0; c < K; ++c) wi[c] -= val[p] * wj[c];
      }
    }
    // diagonal
    for (int j = 0; j < nf; ++j) {
      const double inv = 1.0 / d(j);
      for (int c = 0; c < K; ++c) w[K * j + c] *= inv;
    }
    // backward: L^T x = z
    for (int j = nf - 1; j >= 0; --j) {
      double wj[K];
      for (int c = 0; c < K; ++c) wj[c] = w[K * j + c];
      const auto end = nnz ? outer[j] + nnz[j] : outer[j + 1];
      for (auto p = outer[j]; p < end; ++p) {
        const double* wi = w + K * std::int64_t(inner[p]);
        for (int c = 0; c < K; ++c) wj[c] -= val[p] * wi[c];
      }
      for (int c = 0; c < K; ++c) w[K * j + c] = wj[c];
    }
  }

  /// Writes the solution into x; returns the largest node move.
  double scatter(Eigen::Matrix3Xd& x, int threads) {
    const int nf = num_free();
    const std::int64_t chunks = chunk_count(nf, kNodeGrain);
    parallel_for_chunks(nf, kNodeGrain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
      double mx = 0;
      for (std::int64_t f = b; f < e; ++f) {
        const int i = free_nodes_[std::size_t(f)];
        const Eigen::Vector3d nx = sol_.row(f).transpose();
        mx = std::max(mx, (nx - x.col(i)).squaredNorm());
        x.col(i) = nx;
      }
      free_chunk_sums_[std::size_t(c)] = mx;
    });
    double mx = 0;
    for (std::int64_t c = 0; c < chunks; ++c) mx = std::max(mx, free_chunk_sums_[std::size_t(c)]);
    return std::sqrt(mx);
  }

  // -------------------------------------------------------------------------------------------
  // contact inside the global step
  //
  // Why here: after the integrator's step the post-step projection (contact.h) only sees the
  // momentum change m (v' - v) / dt of the nodes it moves, which at long implicit steps is a
  // small part of the elastic reaction (roughly (m/dt^2) / (K + m/dt^2) of it): the nodes
  // relaxed to the free equilibrium inside the step. So the probes and walls take part in the
  // minimisation itself: every global step solves
  //   A x = b + sum_i lambda_i n_i e_i^T,  n_i . x_i >= n_i . p_i,  lambda_i >= 0,
  //   lambda_i (n_i . x_i - n_i . p_i) = 0,
  // with each constraint linearised at the current iterate (the closest surface point p_i and
  // the outward normal n_i; re-linearised every local/global iteration, so a curved probe is
  // followed). A acts on each coordinate alike, so with G = A_s^-1 (the scalar matrix),
  //   x = x_u + sum_j lambda_j n_j G e_j,    x_u = A^-1 b (the unconstrained solve),
  // and the constraints on the working set W give the Schur complement system
  //   S lambda = d,  S_ij = (n_i . n_j) G_ij,  d_i = n_i . (p_i - x_u,i),
  // exact on the existing factorisation. The columns G e_j are solved once per node and cached
  // until the matrix is refactored (memory nf doubles each, within kColumnBudgetBytes; the
  // least recently used are reused beyond it). An active-set iteration keeps lambda >= 0: it
  // drops the constraints that pull and adds the candidates the solution violates, starting
  // from the last solve's active set (a warm start that usually converges in 1-2 rounds).
  // The multipliers are the contact forces (N, A x = b is a force balance). Serial and in a
  // fixed order: the same result for any thread count.

  static constexpr int kMaxContactRounds = 100;   ///< active-set rounds per global solve
  static constexpr int kMaxContactPasses = 4;     ///< re-checks for nodes pushed into a probe
  static constexpr double kGapToleranceMm = 1e-9; ///< a violation smaller than this is none
  static constexpr double kColumnBudgetBytes = 256.0 * 1024 * 1024;

  static bool key_less(const ContactConstraint& a, const ContactConstraint& b) {
    return a.owner != b.owner ? a.owner < b.owner : a.node < b.node;
  }

  /// G e_f (one scalar solve on the factor), into `out` (nf values in free order).
  void solve_unit(int f, double* out) {
    const int nf = num_free();
    const auto& perm = ldlt_.permutationP().indices();
    double* w = col_work_.data();
    std::fill(col_work_.begin(), col_work_.end(), 0.0);
    w[perm(f)] = 1.0;
    factor_solve_in_place<1>(w, perm(f));
    for (int i = 0; i < nf; ++i) out[i] = w[perm(i)];
  }

  /// The column slot of free node f, solving its column when it has none (allocates when the
  /// cache grows).
  int ensure_column(int f, StepReport& rep) {
    int slot = col_slot_[std::size_t(f)];
    if (slot < 0) {
      const int nf = num_free();
      if (used_slots_ < cols_.cols()) {
        slot = used_slots_++;
      } else if (double(cols_.cols()) * nf * sizeof(double) < kColumnBudgetBytes) {
        const Eigen::Index grow = std::max<Eigen::Index>(16, cols_.cols());
        cols_.conservativeResize(nf, cols_.cols() + grow);
        slot = used_slots_++;
      } else {
        // full: reuse the least recently used slot (never one of this solve)
        std::int64_t oldest = stamp_;
        for (int k = 0; k < used_slots_; ++k)
          if (slot_stamp_[std::size_t(k)] < oldest) oldest = slot_stamp_[std::size_t(k)], slot = k;
        if (slot < 0) {  // all in use now: grow beyond the budget
          cols_.conservativeResize(nf, cols_.cols() + 16);
          slot = used_slots_++;
        } else {
          col_slot_[std::size_t(slot_free_[std::size_t(slot)])] = -1;
        }
      }
      if (std::size_t(slot) >= slot_free_.size()) {
        slot_free_.resize(std::size_t(cols_.cols()), -1);
        slot_stamp_.resize(std::size_t(cols_.cols()), 0);
      }
      solve_unit(f, cols_.col(slot).data());
      col_slot_[std::size_t(f)] = slot;
      slot_free_[std::size_t(slot)] = f;
      ++rep.contact_columns;
    }
    slot_stamp_[std::size_t(slot)] = stamp_;
    return slot;
  }

  /// Solves S lambda = d in place (S: n x n row-major, symmetric positive definite; lower
  /// triangle used) by Cholesky. S is the Hadamard product of the normals' Gram matrix and G,
  /// positive definite unless one node has two parallel constraints; a pivot below 1e-12 of its
  /// diagonal (that case) is raised to it, which splits the force between them.
  static void dense_solve(double* a, int n, double* b) {
    for (int j = 0; j < n; ++j) {
      double piv = a[j * n + j];
      for (int k = 0; k < j; ++k) piv -= a[j * n + k] * a[j * n + k];
      const double floor = 1e-12 * std::abs(a[j * n + j]);
      piv = std::sqrt(std::max(piv, floor > 0 ? floor : 1e-300));
      a[j * n + j] = piv;
      for (int i = j + 1; i < n; ++i) {
        double v = a[i * n + j];
        for (int k = 0; k < j; ++k) v -= a[i * n + k] * a[j * n + k];
        a[i * n + j] = v / piv;
      }
    }
    for (int i = 0; i < n; ++i) {
      double v = b[i];
      for (int k = 0; k < i; ++k) v -= a[i * n + k] * b[k];
      b[i] = v / a[i * n + i];
    }
    for (int i = n - 1; i >= 0; --i) {
      double v = b[i];
      for (int k = i + 1; k < n; ++k) v -= a[k * n + i] * b[k];
      b[i] = v / a[i * n + i];
    }
  }

  /// Position of candidate c's node for the current multipliers of the working set.
  Eigen::Vector3d constrained_position(int c) const {
    const int f = cand_free_[std::size_t(c)];
    Eigen::Vector3d xi = xu_.row(f).transpose();
    for (std::size_t b = 0; b < w_.size(); ++b)
      xi += cols_(f, w_slot_[b]) * Eigen::Vector3d(wl_[3 * b], wl_[3 * b + 1], wl_[3 * b + 2]);
    return xi;
  }

  /// Active-set iteration on the candidates with x_u = xu_; leaves the multipliers in
  /// cand_[c].force_n (0 off the working set) and wl_/w_slot_ for the working set. Returns the
  /// rounds taken.
  int active_set(StepReport& rep) {
    const int nc = int(cand_.size());
    int round = 1;
    for (;; ++round) {
      w_.clear();
      for (int c = 0; c < nc; ++c) {
        cand_[std::size_t(c)].force_n = 0.0;
        if (in_w_[std::size_t(c)]) w_.push_back(c);
      }
      const int nw = int(w_.size());
      w_slot_.resize(std::size_t(nw));
      wl_.resize(3 * std::size_t(nw));
      s_.resize(std::size_t(nw) * std::size_t(nw));
      d_.resize(std::size_t(nw));
      for (int a = 0; a < nw; ++a) w_slot_[std::size_t(a)] = ensure_column(cand_free_[std::size_t(w_[std::size_t(a)])], rep);
      for (int a = 0; a < nw; ++a) {
        const ContactConstraint& ca = cand_[std::size_t(w_[std::size_t(a)])];
        const int fa = cand_free_[std::size_t(w_[std::size_t(a)])];
        for (int b = 0; b <= a; ++b) {
          const ContactConstraint& cb = cand_[std::size_t(w_[std::size_t(b)])];
          s_[std::size_t(a * nw + b)] = ca.normal.dot(cb.normal) * cols_(fa, w_slot_[std::size_t(b)]);
        }
        d_[std::size_t(a)] = ca.normal.dot(ca.point_mm - xu_.row(fa).transpose());
      }
      if (nw > 0) dense_solve(s_.data(), nw, d_.data());
      bool pulled = false;
      for (int a = 0; a < nw; ++a) {
        const int c = w_[std::size_t(a)];
        const double lambda = d_[std::size_t(a)];
        cand_[std::size_t(c)].force_n = lambda;
        const Eigen::Vector3d ln = lambda * cand_[std::size_t(c)].normal;
        for (int k = 0; k < 3; ++k) wl_[3 * std::size_t(a) + std::size_t(k)] = ln[k];
        if (!(lambda >= 0.0)) {  // pulls (or NaN): leave the working set
          in_w_[std::size_t(c)] = 0;
          pulled = true;
        }
      }
      if (round >= kMaxContactRounds) break;
      if (pulled) continue;
      // candidates off the working set that the solution pushes through their surface
      bool added = false;
      for (int c = 0; c < nc; ++c) {
        if (in_w_[std::size_t(c)]) continue;
        const ContactConstraint& cc = cand_[std::size_t(c)];
        if (cc.normal.dot(constrained_position(c) - cc.point_mm) < -kGapToleranceMm) {
          in_w_[std::size_t(c)] = 1;
          added = true;
        }
      }
      if (!added) break;
    }
    // (not converged within the rounds: keep the multipliers that push; the rest are zero)
    for (std::size_t a = 0; a < w_.size(); ++a)
      if (!(cand_[std::size_t(w_[a])].force_n >= 0.0)) {
        cand_[std::size_t(w_[a])].force_n = 0.0;
        for (int k = 0; k < 3; ++k) wl_[3 * a + std::size_t(k)] = 0.0;
      }
    return round;
  }

  /// sol_ = xu_ + sum over the working set of lambda_j n_j G e_j (per free node, parallel).
  void apply_contact_forces(int threads) {
    const int nf = num_free();
    const std::size_t nw = w_.size();
    if (nw == 0) {
      sol_ = xu_;
      return;
    }
    // column by column within a chunk of nodes (contiguous reads; each node sums its terms in
    // working-set order whatever the chunking)
    parallel_for(nf, kNodeGrain, threads, [&](std::int64_t lo, std::int64_t hi) {
      double* s0 = sol_.col(0).data();
      double* s1 = sol_.col(1).data();
      double* s2 = sol_.col(2).data();
      for (std::int64_t f = lo; f < hi; ++f) {
        s0[f] = xu_(f, 0);
        s1[f] = xu_(f, 1);
        s2[f] = xu_(f, 2);
      }
      for (std::size_t b = 0; b < nw; ++b) {
        const double* g = cols_.col(w_slot_[b]).data();
        const double l0 = wl_[3 * b], l1 = wl_[3 * b + 1], l2 = wl_[3 * b + 2];
        for (std::int64_t f = lo; f < hi; ++f) {
          s0[f] += g[f] * l0;
          s1[f] += g[f] * l1;
          s2[f] += g[f] * l2;
        }
      }
    });
  }

  /// Keeps the constraints of free nodes and records their free indices.
  void index_candidates(std::size_t from) {
    std::size_t k = from;
    for (std::size_t c = from; c < cand_.size(); ++c)
      if (cand_[c].node >= 0 && std::size_t(cand_[c].node) < free_index_.size() &&
          free_index_[std::size_t(cand_[c].node)] >= 0)
        cand_[k++] = cand_[c];
    cand_.resize(k);
    cand_free_.resize(k);
    in_w_.resize(k, 0);
    for (std::size_t c = from; c < k; ++c) cand_free_[c] = free_index_[std::size_t(cand_[c].node)];
  }

  /// Turns the unconstrained solution in sol_ into the constrained one (see above); `x` is the
  /// iterate before this solve (where the constraints are linearised).
  void solve_contacts(const Eigen::Matrix3Xd& x, int threads, StepReport& rep) {
    ++stamp_;
    xu_ = sol_;
    // candidates near the surfaces at the current iterate, sorted by (owner, node)
    cand_.clear();
    contact_->collect(x, true, cand_);
    index_candidates(0);
    std::sort(cand_.begin(), cand_.end(), key_less);
    for (std::size_t c = 0; c < cand_.size(); ++c) cand_free_[c] = free_index_[std::size_t(cand_[c].node)];
    // warm start: the last solve's active set (both sorted by key)
    std::fill(in_w_.begin(), in_w_.end(), std::uint8_t(0));
    for (std::size_t c = 0, a = 0; c < cand_.size() && a < active_.size();) {
      if (key_less(cand_[c], active_[a])) {
        ++c;
      } else if (key_less(active_[a], cand_[c])) {
        ++a;
      } else {
        in_w_[c] = 1;
        ++c;
        ++a;
      }
    }
    const std::size_t sorted = cand_.size();
    for (int pass = 0;; ++pass) {
      rep.contact_rounds += active_set(rep);
      apply_contact_forces(threads);
      if (pass + 1 >= kMaxContactPasses) break;
      // nodes that were not candidates but that the constrained solution puts inside a probe
      // (they moved farther than the provider's margin in this solve): add them and redo
      x_trial_ = x;
      for (int f = 0; f < num_free(); ++f) x_trial_.col(free_nodes_[std::size_t(f)]) = sol_.row(f).transpose();
      extra_.clear();
      contact_->collect(x_trial_, false, extra_);
      const std::size_t before = cand_.size();
      for (const ContactConstraint& e : extra_) {
        const auto it = std::lower_bound(cand_.begin(), cand_.begin() + std::ptrdiff_t(sorted), e, key_less);
        bool known = it != cand_.begin() + std::ptrdiff_t(sorted) && !key_less(e, *it);
        for (std::size_t c = sorted; c < cand_.size() && !known; ++c)
          known = cand_[c].owner == e.owner && cand_[c].node == e.node;
        if (!known) cand_.push_back(e);
      }
      index_candidates(before);
      if (cand_.size() == before) break;
    }
    // the active set, sorted by key, with the multipliers
    active_.clear();
    for (const int c : w_)
      if (cand_[std::size_t(c)].force_n > 0.0) active_.push_back(cand_[std::size_t(c)]);
    std::sort(active_.begin(), active_.end(), key_less);
  }

  double rms_difference(const Eigen::MatrixX3d& a, const Eigen::MatrixX3d& b, int threads) {
    const int nf = num_free();
    if (nf == 0) return 0.0;
    const std::int64_t chunks = chunk_count(nf, kNodeGrain);
    parallel_for_chunks(nf, kNodeGrain, threads, [&](std::int64_t c, std::int64_t lo, std::int64_t hi) {
      double s = 0;
      for (std::int64_t f = lo; f < hi; ++f) s += (a.row(f) - b.row(f)).squaredNorm();
      free_chunk_sums_[std::size_t(c)] = s;
    });
    double s = 0;
    for (std::int64_t c = 0; c < chunks; ++c) s += free_chunk_sums_[std::size_t(c)];
    return std::sqrt(s / nf);
  }

  const PhysicsModel* physics_{nullptr};
  const SimState* state_{nullptr};
  std::uint64_t fixed_version_{0};
  double dt_{0.0};
  bool inertia_{true};
  bool damping_{false};

  std::vector<int> free_index_, fixed_index_, free_nodes_, fixed_nodes_;
  std::vector<double> kappa_;
  SpMat a_fc_;
  Eigen::SimplicialLDLT<SpMat> ldlt_;
  std::int64_t nnz_factor_{0};

  Eigen::Matrix3Xd targets_, rest_now_, x_start_;
  std::vector<Eigen::Quaterniond> damp_rot_;
  Eigen::MatrixX3d rhs_const_, rhs_, rhs_prev_, sol_, xc_;
  std::vector<double> work_;
  std::vector<ElementPassStats> elem_chunks_;
  std::vector<double> free_chunk_sums_;

  // contact (see solve_contacts())
  ContactProvider* contact_{nullptr};
  std::vector<ContactConstraint> cand_, extra_, active_;
  std::vector<int> cand_free_;            ///< free index of each candidate's node
  std::vector<std::uint8_t> in_w_;        ///< candidate in the working (active) set
  std::vector<int> w_;                    ///< candidates of the working set
  std::vector<double> s_, d_;             ///< Schur complement (row-major) and right-hand side
  std::vector<double> wl_;                ///< per working-set member: lambda n (3) and its column slot
  std::vector<int> w_slot_;
  Eigen::MatrixX3d xu_;                   ///< unconstrained solution of the global step
  Eigen::Matrix3Xd x_trial_;              ///< constrained iterate (all nodes) for the last check
  Eigen::MatrixXd cols_;                  ///< cached columns A_s^-1 e_f (nf x capacity)
  std::vector<int> col_slot_;             ///< free index -> column slot, -1 none
  std::vector<int> slot_free_;            ///< slot -> free index
  std::vector<std::int64_t> slot_stamp_;  ///< slot -> last global solve that used it
  int used_slots_{0};
  std::int64_t stamp_{0};
  std::vector<double> col_work_;
};

// ---------------------------------------------------------------------------------------------
// implicit (backward Euler by projective dynamics)

class ImplicitIntegrator final : public Integrator {
 public:
  using Integrator::Integrator;

  [[nodiscard]] bool solves_contact() const override { return true; }
  void set_contact_provider(ContactProvider* provider) override {
    solver_.set_contact(provider);
    solver_.forget_contacts();
  }
  [[nodiscard]] const std::vector<ContactConstraint>& contacts() const override { return solver_.active_contacts(); }

  StepReport step(SimState& s) override {
    StepReport rep;
    if (blocked(s, settings_)) {
      rep.status = s.status;
      return rep;
    }
    // the warm start of the contact solve holds only for the step that follows the last one
    if (&s != last_state_ || s.steps != last_steps_ || s.time_s != last_time_s_) solver_.forget_contacts();
    const PhysicsModel& p = *s.physics;
    const int threads = settings_.threads;
    const double dt = settings_.time_step_s;
    const bool damping = any_damping(p);
    if (!solver_.ready_for(s, dt, true, damping)) {
      solver_.setup(s, dt, true, damping);
      max_d_ = max_displacement(p, settings_.limits);
      rep.refactored = true;
    }
    rep.factor_nonzeros = solver_.factor_nonzeros();
    if (settings_.track_energy) {
      ElementPassOptions opt;
      opt.damping = false;
      opt.energy = true;
      opt.rotation = settings_.rotation;
      s.energies.elastic = compute_element_forces(p, s.positions, nullptr, s.rotations, s.scratch.entry_forces,
                                                  &s.scratch.element_energy, opt, threads, s.scratch.element_pass)
                               .elastic_energy;
    }
    // start of step: x_n, the inertial prediction y, the kinematic nodes' targets
    Eigen::Matrix3Xd& xs = solver_.x_start();
    xs = s.positions;
    if (damping) solver_.record_start_shape(p, xs, threads);
    Eigen::Matrix3Xd& x = s.scratch.next_positions;
    const Eigen::Vector3d g = s.gravity_mm_s2;
    const std::vector<int>& free = solver_.free_nodes();
    Eigen::MatrixX3d& rc = solver_.rhs_const();
    const double inv_dt2 = 1.0 / (dt * dt);
    parallel_for(p.num_nodes(), kNodeGrain, threads, [&](std::int64_t b, std::int64_t e) {
      for (std::int64_t i = b; i < e; ++i) x.col(i) = xs.col(i) + dt * s.velocities.col(i);
    });
    parallel_for(std::int64_t(free.size()), kNodeGrain, threads, [&](std::int64_t b, std::int64_t e) {
      for (std::int64_t f = b; f < e; ++f) {
        const int i = free[std::size_t(f)];
        const double mass = p.node_mass[std::size_t(i)];
        // y = x_n + dt v_n + dt^2 (g + f_ext / m); rhs = M y / dt^2
        // (the iterations start from x_n + dt v_n, not from y: at large dt the dt^2 g of a
        // held body puts y far from the solution)
        const Eigen::Vector3d y = x.col(i) + dt * dt * (g + s.external_forces.col(i) / mass);
        rc.row(f) = (mass * inv_dt2) * y.transpose();
      }
    });
    solver_.subtract_fixed_coupling(x);
    solver_.iterate(s, x, settings_.max_iterations, settings_.tolerance_mm, settings_.rotation, threads, rep);

    // velocities, checks, energies
    const double max_v2 = settings_.limits.max_speed_mm_s * settings_.limits.max_speed_mm_s;
    const double max_d2 = max_d_ * max_d_;
    const Eigen::Matrix3Xd& rest = p.model->rest_positions;
    const bool track = settings_.track_energy;
    parallel_for_chunks(p.num_nodes(), kNodeGrain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
      std::uint8_t flags = 0;
      double kin = 0, grav = 0;
      for (std::int64_t i = b; i < e; ++i) {
        const double mass = p.node_mass[std::size_t(i)];
        if (track) {
          kin += 0.5 * mass * s.velocities.col(i).squaredNorm();
          grav -= mass * g.dot(xs.col(i) - rest.col(i));
        }
        if (s.node_fixed[std::size_t(i)])
          s.scratch.next_velocities.col(i) = s.velocities.col(i);
        else
          s.scratch.next_velocities.col(i) = (x.col(i) - xs.col(i)) / dt;
        flags |= check_node(x.col(i), s.scratch.next_velocities.col(i), rest.col(i), max_v2, max_d2);
      }
      s.scratch.node_chunk_flags[std::size_t(c)] = flags;
      s.scratch.node_chunk_sums[3 * std::size_t(c)] = kin;
      s.scratch.node_chunk_sums[3 * std::size_t(c) + 1] = grav;
    });
    finish_node_pass(s, p, settings_, track, s.energies.elastic, rep);
    last_state_ = &s;  // where the next step should start
    last_steps_ = s.steps;
    last_time_s_ = s.time_s;
    return rep;
  }

 private:
  ProjectiveSolver solver_;
  double max_d_{0.0};
  const SimState* last_state_{nullptr};
  std::int64_t last_steps_{-1};
  double last_time_s_{0.0};
};

void check_settings(const IntegratorSettings& s) {
  std::ostringstream err;
  if (!(s.time_step_s > 0) || !std::isfinite(s.time_step_s)) err << "time step " << s.time_step_s << " s must be > 0; ";
  if (s.threads < 0) err << "threads " << s.threads << " must be >= 0 (0: all); ";
  if (s.max_iterations < 1) err << "max_iterations " << s.max_iterations << " must be >= 1; ";
  if (!(s.tolerance_mm >= 0)) err << "tolerance " << s.tolerance_mm << " mm must be >= 0; ";
  if (s.rotation.max_iterations < 1) err << "rotation max_iterations must be >= 1; ";
  if (!(s.limits.max_speed_mm_s > 0)) err << "max speed must be > 0; ";
  if (!err.str().empty()) throw Error("integrator settings: " + err.str());
}

}  // namespace

std::unique_ptr<Integrator> make_integrator(const IntegratorSettings& settings) {
  check_settings(settings);
  switch (settings.kind) {
    case IntegratorKind::explicit_euler:
    case IntegratorKind::symplectic_euler: return std::make_unique<ExplicitIntegrator>(settings);
    case IntegratorKind::implicit: return std::make_unique<ImplicitIntegrator>(settings);
  }
  throw Error("unknown integrator kind");
}

StepReport solve_static(SimState& s, const StaticSolveSettings& settings) {
  if (settings.max_iterations < 1) throw Error("static solve: max_iterations must be >= 1");
  const PhysicsModel& p = *s.physics;
  ProjectiveSolver solver;
  solver.setup(s, 1.0, false, false);
  StepReport rep;
  rep.refactored = true;
  rep.factor_nonzeros = solver.factor_nonzeros();
  // rhs = gravity + external forces - A_fc x_c
  const std::vector<int>& free = solver.free_nodes();
  Eigen::MatrixX3d& rc = solver.rhs_const();
  for (std::size_t f = 0; f < free.size(); ++f) {
    const int i = free[f];
    rc.row(Eigen::Index(f)) = (p.node_mass[std::size_t(i)] * s.gravity_mm_s2 + s.external_forces.col(i)).transpose();
  }
  Eigen::Matrix3Xd x = s.positions;
  solver.subtract_fixed_coupling(x);
  solver.iterate(s, x, settings.max_iterations, settings.tolerance_mm, settings.rotation, settings.threads, rep);
  if (!x.allFinite()) {
    s.status = StepStatus::non_finite;
    s.message = "static solve: NaN/Inf in the solution; the state was not changed";
    rep.status = s.status;
    return rep;
  }
  s.positions = x;
  for (int i = 0; i < s.num_nodes(); ++i)
    if (!s.node_fixed[std::size_t(i)]) s.velocities.col(i).setZero();
  return rep;
}

}  // namespace vx
