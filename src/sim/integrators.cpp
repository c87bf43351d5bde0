#include "sim/integrators.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <future>
#include <optional>
#include <sstream>
#include <thread>
#include <utility>

#include "base/error.h"
#include "base/parallel.h"
#include "sim/projective_solver.h"

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
  return 10.0 * std::max(p.rest_diagonal_mm, 1.0);
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
      if (s.element_stats.non_finite > 0)
        msg << " (" << s.element_stats.non_finite << " elements with non-finite input)";
    } else if (node >= 0) {
      msg << "runaway at node " << node << ": speed " << s.scratch.next_velocities.col(node).norm() << " mm/s (limit "
          << max_v << "), displacement " << (s.scratch.next_positions.col(node) - rest.col(node)).norm()
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

/// The report of a step a stopped state refuses (blocked(): its status, nothing done); empty
/// when the state may be stepped.
std::optional<StepReport> refused_step(const SimState& s, const IntegratorSettings& set) {
  if (!blocked(s, set)) return std::nullopt;
  StepReport rep;
  rep.status = s.status;
  return rep;
}

/// What every integrator's step does first, written once: a stopped state refused with its
/// status (refused_step), else the integrator's own step (step_state).
class SteppingIntegrator : public Integrator {
 public:
  using Integrator::Integrator;
  StepReport step(SimState& s) final {
    if (const std::optional<StepReport> refused = refused_step(s, settings_)) return *refused;
    return step_state(s);
  }

 protected:
  /// One step of a state that may be stepped.
  virtual StepReport step_state(SimState& s) = 0;
};

// ---------------------------------------------------------------------------------------------
// explicit and symplectic Euler

/// The per-node part of an explicit step (what it reads and writes; raw pointers, so that the
/// compiler need not reload them through the state's members).
struct NodePass {
  double dt{0}, max_v2{0}, max_d2{0}, gx{0}, gy{0}, gz{0};
  const double *ef{}, *xs{}, *vs{}, *fext{}, *rest{}, *mass{}, *inv_mass{}, *gravity_ratio{};
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
      grav -= n.mass[i] * n.gravity_ratio[i] * (n.gx * (x[0] - r[0]) + n.gy * (x[1] - r[1]) + n.gz * (x[2] - r[2]));
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
    const double im = n.inv_mass[i], gr = n.gravity_ratio[i];  // gravity: the physical weight
    const double a0 = free ? f0 * im + gr * n.gx : 0.0, a1 = free ? f1 * im + gr * n.gy : 0.0,
                 a2 = free ? f2 * im + gr * n.gz : 0.0;
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

class ExplicitIntegrator final : public SteppingIntegrator {
 public:
  using SteppingIntegrator::SteppingIntegrator;

  StepReport step_state(SimState& s) override {
    StepReport rep;
    const PhysicsModel& p = *s.physics;
    const int threads = settings_.threads;
    const double dt = settings_.time_step_s;
    const double max_d = max_displacement(p, settings_.limits);
    // forces of the elements at (x, v)
    ElementPassOptions opt;
    opt.damping = p.damped;
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
    np.max_d2 = max_d * max_d;
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
    np.gravity_ratio = p.node_gravity_ratio.data();
    np.chunk_flags = s.scratch.node_chunk_flags.data();
    np.chunk_sums = s.scratch.node_chunk_sums.data();
    const auto run = symplectic ? (track ? &explicit_nodes<true, true> : &explicit_nodes<true, false>)
                                : (track ? &explicit_nodes<false, true> : &explicit_nodes<false, false>);
    parallel_for_chunks(p.num_nodes(), kNodeGrain, threads,
                        [&](std::int64_t c, std::int64_t b, std::int64_t e) { run(np, c, b, e); });
    finish_node_pass(s, p, settings_, track, s.element_stats.elastic_energy, rep);
    return rep;
  }
};

// ---------------------------------------------------------------------------------------------
// implicit (backward Euler by projective dynamics)

class ImplicitIntegrator final : public SteppingIntegrator {
 public:
  explicit ImplicitIntegrator(const IntegratorSettings& settings) : SteppingIntegrator(settings) {}

  [[nodiscard]] bool solves_contact() const override { return true; }
  void set_contact_provider(ContactProvider* provider) override {
    contact_ = provider;
    contact_epoch_ = provider ? next_contact_epoch() : 0;  // the warm starts of the old provider do not apply
    contacts_.clear();
  }
  [[nodiscard]] const std::vector<ContactConstraint>& contacts() const override { return contacts_; }
  bool contact_compliance(SimState& s, const std::vector<std::int32_t>& nodes, Eigen::MatrixXd& g) override {
    if (!s.integrator_cache.solver) return false;
    return s.integrator_cache.solver->contact_compliance(nodes, g);
  }

  StepReport step_state(SimState& s) override {
    StepReport rep;
    const PhysicsModel& p = *s.physics;
    const int threads = settings_.threads;
    const double dt = settings_.time_step_s;
    const bool regional = settings_.region_radius_mm > 0 && contact_;
    rep.threads = resolve_threads(threads);
    ProjectiveSolver* built = solver_for(s, rep, regional);
    // at rest while its solver is built on a thread of its own (factor_in_background)
    if (!built) return sleep_step(s, rep);
    ScopedThreads wake;
    ProjectiveSolver& solver = *built;
    solver.set_region_diagnostics(settings_.region_solve_far_field, settings_.region_refresh_on_move,
                                  settings_.region_visit_still_far_field);
    solver.set_carry_far_field(settings_.region_far_field_degree);
    rep.factor_nonzeros = solver.factor_nonzeros();
    if (regional) {
      // (a solver taken from the background finds the tissue as it was built for: still asleep)
      if (asleep_ && still_at_rest(s, rep.refactored && !rep.factored_in_background)) return sleep_step(s, rep);
      if (asleep_) {
        // the wake: on wake_threads (the loops asked for 0 follow this thread's setting)
        rep.woke = true;
        if (threads == 0) {
          wake.set(settings_.wake_threads);
          rep.threads = resolve_threads(0);
        }
      }
      asleep_ = false;
      update_region(s, solver, rep.refactored);
      // while the tissue may move and no tool touches, a full solve now and then lets the far
      // field that slept relax
      if (!contacts_.empty()) {
        settling_ = true;
        idle_steps_ = 0;
      } else if (settling_ && solver.has_region() && settings_.region_idle_refresh_steps > 0 &&
                 double(idle_steps_ + 1) * dt <= settings_.region_idle_refresh_window_s &&
                 ++idle_steps_ % settings_.region_idle_refresh_steps == 0) {
        solver.refresh_all_next();
      }
    }
    if (settings_.track_energy) {
      ElementPassOptions opt;
      opt.damping = false;
      opt.energy = true;
      opt.rotation = settings_.rotation;
      s.energies.elastic = compute_element_forces(p, s.positions, nullptr, s.rotations, s.scratch.entry_forces,
                                                  &s.scratch.element_energy, opt, threads, s.scratch.element_pass)
                               .elastic_energy;
    }
    // start of step: x_n (the state's positions), the iterations' start x_n + dt v_n (the
    // kinematic nodes' targets), the inertial right-hand side M y / dt^2
    const Eigen::Matrix3Xd& xs = s.positions;
    Eigen::Matrix3Xd& x = s.scratch.next_positions;
    const Eigen::Vector3d g = s.gravity_mm_s2;
    const std::vector<int>& free = solver.free_nodes();
    Eigen::MatrixX3d& rc = solver.constant_rhs();
    const double inv_dt2 = 1.0 / (dt * dt);
    // (once the regional solves hold the far field still, its nodes are where this would put
    // them already: ProjectiveSolver::still_far_field_nodes)
    const std::vector<int>* near = solver.still_far_field_nodes(s, false);
    const std::int64_t n_near = near ? std::int64_t(near->size()) : p.num_nodes();
    parallel_for(n_near, kNodeGrain, threads, [&](std::int64_t b, std::int64_t e) {
      for (std::int64_t k = b; k < e; ++k) {
        const std::int64_t i = near ? (*near)[std::size_t(k)] : k;
        x.col(i) = xs.col(i) + dt * s.velocities.col(i);
      }
    });
    // (and whether a free node has an external force: the solver's closure-only passes)
    std::vector<std::uint8_t>& pushed = s.scratch.node_chunk_flags;  // written again after the solve
    const std::int64_t free_chunks = chunk_count(std::int64_t(free.size()), kNodeGrain);
    parallel_for_chunks(
        std::int64_t(free.size()), kNodeGrain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
          bool any = false;
          for (std::int64_t f = b; f < e; ++f) {
            const int i = free[std::size_t(f)];
            const double mass = p.node_mass[std::size_t(i)];
            // y = x_n + dt v_n + dt^2 (g + f_ext / m); rhs = M y / dt^2
            // (the iterations start from x_n + dt v_n, not from y: at large dt the dt^2 g of a
            // held body puts y far from the solution)
            const Eigen::Vector3d fe = s.external_forces.col(i);
            any = any || !fe.isZero(0.0);
            const Eigen::Vector3d y = x.col(i) + dt * dt * (p.node_gravity_ratio[std::size_t(i)] * g + fe / mass);
            rc.row(f) = (mass * inv_dt2) * y.transpose();
          }
          pushed[std::size_t(c)] = any ? 1 : 0;
        });
    ProjectiveIterations its;
    its.max_iterations = settings_.max_iterations;
    its.tolerance_mm = settings_.tolerance_mm;
    its.residual_tolerance_n = settings_.residual_tolerance_n;
    its.free_max_iterations = settings_.free_iterations;
    its.free_tolerance_mm = settings_.free_tolerance_mm;
    its.rotation = settings_.rotation;
    its.threads = threads;
    its.inputs_given = true;
    its.gravity_mm_s2 = g;
    its.external_forces =
        std::any_of(pushed.begin(), pushed.begin() + free_chunks, [](std::uint8_t f) { return f != 0; });
    solver.solve(s, x, its, contact_, rep);
    rep.region_elements = solver.region_elements();
    rep.region_nodes = solver.region_nodes();
    if (contact_) contacts_ = solver.active_contacts();

    // velocities, checks, energies
    const double max_v2 = settings_.limits.max_speed_mm_s * settings_.limits.max_speed_mm_s;
    const double max_d = max_displacement(p, settings_.limits), max_d2 = max_d * max_d;
    const Eigen::Matrix3Xd& rest = p.model->rest_positions;
    const bool track = settings_.track_energy;
    // (the far field held still in this solve and the two before: its velocities are 0 in both
    // buffers and its checks passed when they were written; not with the energies, which sum
    // every node)
    const std::vector<int>* still = track ? nullptr : solver.still_far_field_nodes(s, true);
    const std::int64_t n_pass = still ? std::int64_t(still->size()) : p.num_nodes();
    const std::int64_t pass_chunks = chunk_count(n_pass, kNodeGrain);
    for (auto c = std::size_t(pass_chunks); c < std::size_t(chunk_count(p.num_nodes(), kNodeGrain)); ++c) {
      s.scratch.node_chunk_flags[c] = 0;
      for (int k = 0; k < 3; ++k) s.scratch.node_chunk_sums[3 * c + std::size_t(k)] = 0.0;
    }
    parallel_for_chunks(n_pass, kNodeGrain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
      std::uint8_t flags = 0;
      double kin = 0, grav = 0, v2 = 0;
      for (std::int64_t k = b; k < e; ++k) {
        const std::int64_t i = still ? (*still)[std::size_t(k)] : k;
        const double mass = p.node_mass[std::size_t(i)];
        if (track) {
          kin += 0.5 * mass * s.velocities.col(i).squaredNorm();
          grav -= mass * p.node_gravity_ratio[std::size_t(i)] * g.dot(xs.col(i) - rest.col(i));
        }
        if (s.node_fixed[std::size_t(i)])
          s.scratch.next_velocities.col(i) = s.velocities.col(i);
        else
          s.scratch.next_velocities.col(i) = (x.col(i) - xs.col(i)) / dt;
        v2 = std::max(v2, s.scratch.next_velocities.col(i).squaredNorm());
        flags |= check_node(x.col(i), s.scratch.next_velocities.col(i), rest.col(i), max_v2, max_d2);
      }
      s.scratch.node_chunk_flags[std::size_t(c)] = flags;
      s.scratch.node_chunk_sums[3 * std::size_t(c)] = kin;
      s.scratch.node_chunk_sums[3 * std::size_t(c) + 1] = grav;
      s.scratch.node_chunk_sums[3 * std::size_t(c) + 2] = v2;
    });
    finish_node_pass(s, p, settings_, track, s.energies.elastic, rep);
    if (regional && !s.failed()) settle(s, solver, rep);
    // the contact warm start holds for the step that follows this one
    s.integrator_cache.next_step = s.steps;
    s.integrator_cache.next_time_s = s.time_s;
    s.integrator_cache.contact_epoch = contact_epoch_;
    return rep;
  }

 private:
  /// A number no other provider binding of any integrator has (0 is "none").
  static std::uint64_t next_contact_epoch() {
    static std::atomic<std::uint64_t> counter{0};
    return ++counter;
  }

  /// The state's solver, (re)built when it has none or when its fixed nodes, the time step or
  /// the damping changed; the contact warm start is dropped unless this step follows the last
  /// one with the same provider. Null: the tissue rests while its solver is built on a thread of
  /// its own (factor_in_background); this step is a step at rest.
  ProjectiveSolver* solver_for(SimState& s, StepReport& rep, bool regional) {
    IntegratorCache& cache = s.integrator_cache;
    ProjectiveSetup setup;
    setup.time_step_s = settings_.time_step_s;
    setup.inertia = true;
    setup.damping = s.physics->damped;
    setup.single_precision_sweeps = settings_.single_precision_sweeps;
    if (cache.pending.valid() && !take_pending(s, rep)) return nullptr;
    if (!cache.solver || cache.solver->setup() != setup || cache.fixed_version != s.fixed_version ||
        &cache.solver->physics() != s.physics.get()) {
      cache.solver.reset();
      if (regional && settings_.factor_in_background && settings_.region_rest_speed_mm_s > 0 && exactly_at_rest(s)) {
        // the tissue's one equilibrium is where it is: it sleeps while the solver is built
        auto physics = s.physics;
        auto fixed = s.node_fixed;  // a copy: the state's may change while the thread reads it
        auto factor_cache = settings_.factor_cache;
        const int threads = settings_.threads;
        const double delay_s = settings_.factor_in_background_delay_s;
        // stopped by its own flag (a cache dropped) or by the caller's (a session that quits)
        auto own = std::make_shared<std::atomic<bool>>(false);
        std::shared_ptr<const std::atomic<bool>> callers = settings_.stop_background;
        auto stop = [own, callers] { return own->load() || (callers && callers->load()); };
        auto on_start = settings_.background_thread_start;
        cache.pending =
            std::async(std::launch::async, [physics, fixed, setup, factor_cache, threads, delay_s, stop, on_start] {
              if (on_start) on_start();
              if (delay_s > 0) std::this_thread::sleep_for(std::chrono::duration<double>(delay_s));
              return new_solver(physics, fixed, setup, factor_cache.get(), threads, stop);
            });
        cache.pending_stop = std::move(own);
        cache.pending_fixed_version = s.fixed_version;
        cache.pending_since_s =
            std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
        fall_asleep(s, rep, SleepCause::near_rest, 0.0, false);
        rep.factor_pending = true;
        return nullptr;
      }
      cache.solver = new_solver(s.physics, s.node_fixed, setup, settings_.factor_cache.get(), settings_.threads);
      cache.fixed_version = s.fixed_version;
      took_solver(*cache.solver, rep);
    }
    if (cache.next_step != s.steps || cache.next_time_s != s.time_s || cache.contact_epoch != contact_epoch_)
      cache.solver->forget_contacts();
    return cache.solver.get();
  }

  /// The solver being built in the background: taken when it is ready, or once the tissue is
  /// not at rest any more (then this step waits for it); false: neither, the tissue rests on.
  /// A solver built for other fixed nodes is taken too, and solver_for() replaces it. Rethrows
  /// what the building threw.
  bool take_pending(SimState& s, StepReport& rep) {
    IntegratorCache& cache = s.integrator_cache;
    const bool ready = cache.pending.wait_for(std::chrono::seconds(0)) == std::future_status::ready;
    if (!ready && cache.pending_fixed_version == s.fixed_version) {
      // asleep as before, or put back at rest (a reset): it rests on
      const bool resting = asleep_ && still_at_rest(s, false);
      if (resting || exactly_at_rest(s)) {
        if (!resting) rest_from_here(s);
        rep.factor_pending = true;
        return false;
      }
    }
    const auto t0 = std::chrono::steady_clock::now();
    // (a caller that stops the build, a session that quits, is not kept waiting by this step)
    if (const auto& callers = settings_.stop_background; !ready && callers)
      while (cache.pending.wait_for(std::chrono::milliseconds(20)) != std::future_status::ready)
        if (callers->load())
          throw Cancelled("the step waiting for the solver being built in the background was stopped");
    cache.solver = cache.pending.get();  // (the future is empty from here, whatever it threw)
    cache.pending_stop.reset();
    if (!ready) rep.factor_wait_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    cache.fixed_version = cache.pending_fixed_version;
    took_solver(*cache.solver, rep);
    rep.factored_in_background = true;
    return true;
  }

  static IntegratorCache::SolverPtr new_solver(std::shared_ptr<const PhysicsModel> physics,
                                               const std::vector<std::uint8_t>& fixed, const ProjectiveSetup& setup,
                                               FactorCache* factor_cache, int threads,
                                               const std::function<bool()>& stop = {}) {
    return {new ProjectiveSolver(std::move(physics), fixed, setup, factor_cache, threads, stop),
            [](ProjectiveSolver* p) { delete p; }};
  }

  /// A new solver for the state: its contact cache reserved (reserve_contact_cache), the step's
  /// report told.
  void took_solver(ProjectiveSolver& solver, StepReport& rep) const {
    if (settings_.reserve_contact_cache) solver.reserve_contact_cache();
    rep.refactored = true;
    rep.factor_from_cache = solver.factor().from_cache();
    rep.order_from_cache = solver.factor().order_given();
    rep.factor_s = solver.factor().factor_seconds();
  }

  /// The tissue sleeps from this step on: what still_at_rest() watches is recorded (no report;
  /// fall_asleep() reports).
  void rest_from_here(const SimState& s) {
    asleep_ = true;
    settling_ = false;
    asleep_gravity_ = s.gravity_mm_s2;
    asleep_fixed_version_ = s.fixed_version;
    asleep_step_ = s.steps;
    asleep_time_s_ = s.time_s;
  }

  /// Whether the tissue is exactly at its rest shape and at rest, with its rest shape its one
  /// equilibrium and no node within the contact margin of a tool or a wall: its step is itself.
  bool exactly_at_rest(const SimState& s) {
    return rest_shape_known(s) && s.velocities.isZero(0.0) && s.positions == s.physics->model->rest_positions &&
           nothing_near(s);
  }

  /// The largest node speed of the step just finished, mm/s (the velocity pass keeps each
  /// chunk's largest squared speed).
  static double max_speed_mm_s(const SimState& s) {
    double m = 0.0;
    const std::size_t chunks = std::size_t(chunk_count(s.num_nodes(), kNodeGrain));
    for (std::size_t c = 0; c < chunks; ++c) m = std::max(m, s.scratch.node_chunk_sums[3 * c + 2]);
    return std::sqrt(m);
  }

  /// Whether the tissue's one equilibrium is its rest shape: no gravity, no external force and
  /// every fixed node at its rest position (no tool touches: the caller knows).
  static bool rest_shape_known(const SimState& s) {
    if (!s.gravity_mm_s2.isZero(0.0) || !s.external_forces.isZero(0.0)) return false;
    const Eigen::Matrix3Xd& rest = s.physics->model->rest_positions;
    for (int i = 0; i < s.num_nodes(); ++i)
      if (s.node_fixed[std::size_t(i)] && (s.positions.col(i) - rest.col(i)).squaredNorm() > 1e-18) return false;
    return true;
  }

  /// The largest node displacement from the rest shape, mm.
  double offset_from_rest_mm(const SimState& s, int threads) {
    const Eigen::Matrix3Xd& rest = s.physics->model->rest_positions;
    std::vector<double>& largest = chunk_largest_;
    largest.assign(std::size_t(chunk_count(s.num_nodes(), kNodeGrain)), 0.0);
    parallel_for_chunks(s.num_nodes(), kNodeGrain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
      double m = 0.0;
      for (std::int64_t i = b; i < e; ++i) m = std::max(m, (s.positions.col(i) - rest.col(i)).squaredNorm());
      largest[std::size_t(c)] = m;
    });
    return std::sqrt(*std::max_element(largest.begin(), largest.end()));
  }

  /// After a regional step: the release (the displacement the tissue returns from), and whether
  /// the tissue, untouched, is at rest now: a full solve found no node faster than the rest speed
  /// and, when its rest shape is known, every node within the rest fraction of it (then it is
  /// put there); or, rest shape known, the idle refresh window is over (no full solve comes to
  /// tell: it is put at its rest shape, the static solution).
  void settle(SimState& s, ProjectiveSolver& solver, StepReport& rep) {
    const double dt = settings_.time_step_s;
    if (!contacts_.empty()) {
      touching_ = true;
      return;
    }
    if (touching_) {
      touching_ = false;
      release_time_s_ = s.time_s;
      release_offset_mm_ = rest_shape_known(s) ? offset_from_rest_mm(s, settings_.threads) : 0.0;
    }
    if (!settling_ || settings_.region_rest_speed_mm_s <= 0) return;
    const bool full = solver.last_solve_full();
    const bool window_over = settings_.region_idle_refresh_steps > 0 && solver.has_region() &&
                             double(idle_steps_ + 1) * dt > settings_.region_idle_refresh_window_s;
    if (!full && !window_over) return;
    const bool known = rest_shape_known(s);
    const bool slow = full && max_speed_mm_s(s) < settings_.region_rest_speed_mm_s;
    if (!known || settings_.region_rest_fraction <= 0) {
      // by speed alone (the offset reported when it is known, the tissue left where it is)
      if (slow) fall_asleep(s, rep, SleepCause::slow, known ? offset_from_rest_mm(s, settings_.threads) : -1.0, false);
      return;
    }
    const double offset = offset_from_rest_mm(s, settings_.threads);
    const double near = std::max(kRestFloorMm, settings_.region_rest_fraction * release_offset_mm_);
    // put at its rest shape unless it is within the floor of it already (then left where it is,
    // as the regional solves' far field and forward solution have it)
    const bool move = offset > kRestFloorMm;
    if (slow && offset <= near)
      fall_asleep(s, rep, SleepCause::near_rest, offset, move);
    else if (window_over)
      fall_asleep(s, rep, SleepCause::window_end, offset, move);
    // moved to its rest: the first solve after the sleep brings every node and element up to
    // date (the regional solves' far field and forward solution are the state's before)
    if (asleep_ && move) solver.refresh_all_next();
  }

  /// The tissue is at rest: from now on its steps only advance the time, until still_at_rest()
  /// says otherwise. What it watches is recorded here. With `to_rest` it is put at its rest
  /// shape: positions at rest, rotations the identity (as Simulation::reset).
  void fall_asleep(SimState& s, StepReport& rep, SleepCause cause, double offset_mm, bool to_rest) {
    s.velocities.setZero();
    if (to_rest) {
      s.positions = s.physics->model->rest_positions;
      ++s.positions_version;
      std::fill(s.rotations.begin(), s.rotations.end(), Eigen::Quaterniond::Identity());
    }
    rep.fell_asleep = cause;
    rep.sleep_offset_mm = offset_mm;
    rep.since_release_s = s.time_s - release_time_s_;
    rep.release_offset_mm = release_offset_mm_;
    rest_from_here(s);
  }

  /// Whether a sleeping tissue may go on sleeping this step: the same state continued (no reset,
  /// no restore), the same gravity, fixed nodes and matrix, no external force, and no node within
  /// the contact margin of a tool or a wall.
  bool still_at_rest(const SimState& s, bool refactored) {
    if (refactored || s.steps != asleep_step_ || s.time_s != asleep_time_s_ || s.gravity_mm_s2 != asleep_gravity_ ||
        s.fixed_version != asleep_fixed_version_ || !s.external_forces.isZero(0.0))
      return false;
    return nothing_near(s);
  }

  /// No node within the contact margin of a tool or a wall.
  bool nothing_near(const SimState& s) {
    near_.clear();
    contact_->collect(s.positions, true, near_);
    return near_.empty();
  }

  /// A step of a tissue at rest: the time advances, nothing moves.
  StepReport& sleep_step(SimState& s, StepReport& rep) {
    s.time_s += settings_.time_step_s;
    ++s.steps;
    asleep_step_ = s.steps;
    asleep_time_s_ = s.time_s;
    rep.asleep = true;
    rep.region_elements = 0;
    rep.region_nodes = 0;
    s.integrator_cache.next_step = s.steps;
    s.integrator_cache.next_time_s = s.time_s;
    s.integrator_cache.contact_epoch = contact_epoch_;
    return rep;
  }

  /// Regional solves: the free nodes within region_radius_mm of a tool, recomputed when a tool
  /// has moved a quarter of the radius since (or after a refactorisation).
  void update_region(SimState& s, ProjectiveSolver& solver, bool refactored) {
    contact_->focus_points(focus_);
    if (focus_.empty()) {
      solver.clear_region();
      return;
    }
    const double r = settings_.region_radius_mm;
    bool moved = refactored || !solver.has_region() || focus_.size() != centres_.size();
    for (std::size_t k = 0; k < focus_.size() && !moved; ++k) moved = (focus_[k] - centres_[k]).norm() > 0.25 * r;
    if (!moved) return;
    centres_ = focus_;
    awake_.clear();
    for (int i = 0; i < s.num_nodes(); ++i) {
      if (s.node_fixed[std::size_t(i)]) continue;
      for (const auto& c : centres_)
        if ((s.positions.col(i) - c).squaredNorm() <= r * r) {
          awake_.push_back(i);
          break;
        }
    }
    solver.set_region(awake_);
  }

  ContactProvider* contact_{nullptr};
  std::uint64_t contact_epoch_{0};
  std::vector<Eigen::Vector3d> focus_, centres_;
  std::vector<int> awake_;
  /// a displacement from the rest shape this small is at rest whatever the release, mm
  static constexpr double kRestFloorMm = 1e-3;
  bool settling_{true};            ///< the tissue may be moving (from the start, and after a contact)
  std::int64_t idle_steps_{0};     ///< steps since the last contact
  bool touching_{false};           ///< a tool touched in the last step
  double release_time_s_{0.0};     ///< when the last contact ended (0: the start), s
  double release_offset_mm_{0.0};  ///< the largest displacement from the rest shape then (0: unknown or none), mm
  bool asleep_{false};             ///< at rest: steps only advance the time (fall_asleep)
  Eigen::Vector3d asleep_gravity_{Eigen::Vector3d::Zero()};
  std::uint64_t asleep_fixed_version_{0};
  std::int64_t asleep_step_{0};
  double asleep_time_s_{0.0};
  std::vector<ContactConstraint> near_;      ///< still_at_rest(): candidates near a tool or wall
  std::vector<double> chunk_largest_;        ///< offset_from_rest_mm(): per node chunk
  std::vector<ContactConstraint> contacts_;  ///< active at the end of the last step
};

void check_settings(const IntegratorSettings& s) {
  std::ostringstream err;
  if (!(s.time_step_s > 0) || !std::isfinite(s.time_step_s)) err << "time step " << s.time_step_s << " s must be > 0; ";
  if (s.threads < 0) err << "threads " << s.threads << " must be >= 0 (0: all); ";
  if (s.max_iterations < 1) err << "max_iterations " << s.max_iterations << " must be >= 1; ";
  if (!(s.tolerance_mm >= 0)) err << "tolerance " << s.tolerance_mm << " mm must be >= 0; ";
  if (!(s.region_radius_mm >= 0)) err << "region radius " << s.region_radius_mm << " mm must be >= 0; ";
  if (s.free_iterations < 0) err << "free_iterations " << s.free_iterations << " must be >= 0; ";
  if (!(s.free_tolerance_mm >= 0)) err << "free tolerance " << s.free_tolerance_mm << " mm must be >= 0; ";
  if (!(s.residual_tolerance_n >= 0)) err << "residual tolerance " << s.residual_tolerance_n << " N must be >= 0; ";
  if (!(s.region_rest_fraction >= 0) || !std::isfinite(s.region_rest_fraction))
    err << "region rest fraction " << s.region_rest_fraction << " must be >= 0; ";
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

}  // namespace vx
