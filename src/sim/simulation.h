#pragma once
/// @file simulation.h
/// One simulation of an elastic object pressed, tapped and grasped by rigid probes (docs/model.md
/// sections 7-9). One step:
///
///   1. move the probes to the step's end time (path, scripted joystick or live input);
///   2. elastic forces, gravity and time integration of the nodes (integrators.h);
///   3. collide the nodes near a probe or a wall (contact.h, collidable_nodes()): put them back on the
///      surface, reflect their velocity relative to the probe; the reaction on each probe is
///      the momentum change of its nodes per step (the raw force, N);
///      With the implicit integrator, steps 2 and 3 are one: the probes and walls are
///      unilateral constraints of its solve (integrators.h), found by the same broad phase;
///      the reaction on each probe is minus the sum of its constraints' multipliers (N), right
///      at long steps where the momentum change falls far short of the elastic reaction. That
///      contact is perfectly inelastic (restitution does not apply) and frictionless;
///   4. the step listener, when one is attached: the device side (haptics/device_side.h: the
///      device force, the local contact models) takes the step's forces and contacts;
///   5. the embedded surface is deformed only when someone asks for it (surface_vertices,
///      copy_frame).
///
/// Work a scene does not need is skipped and counted (SimulationCounters); with
/// `skip_unneeded = false` every optional piece of work is done every step, which changes no
/// result (tests/core/simulation_test.cpp checks this bit for bit).
///
/// Threads. A Simulation belongs to one thread: every method is called from the thread that
/// steps it (OpenMP inside a step aside). An app that feeds it from other threads hands data over
/// itself (the probe app: apps/probe/sim_exchange.h).
///
/// Units: mm, s, N; gravity mm/s^2 here (the scene file takes m/s^2).

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "physics/physics_model.h"
#include "sim/contact.h"
#include "sim/integrators.h"
#include "sim/probe.h"
#include "sim/state.h"
#include "surface/surface.h"

namespace vx {

/// Everything a simulation needs besides the physics model (plain settings; the scene file
/// fills them, see pipeline/scene/scene.h).
struct SimulationSettings {
  IntegratorSettings integrator;  ///< kind, time step, threads
  Eigen::Vector3d gravity_mm_s2{Eigen::Vector3d::Zero()};
  std::vector<int> fixed_nodes;  ///< nodes held at their rest position
  Workspace workspace;           ///< walls (disabled: none)
  ContactSettings contact;
  std::vector<ProbeSettings> probes;
  std::shared_ptr<const EmbeddedSurface> surface;  ///< optional surface that follows the nodes
  bool skip_unneeded{true};                        ///< false: do all optional work every step
};

/// A probe after a step.
struct ProbeOutput {
  ProbeState pose;                                       ///< position mm, velocity mm/s
  Eigen::Vector3d raw_force_n{Eigen::Vector3d::Zero()};  ///< force of the tissue on the probe this step
  int contacts{0};                                       ///< nodes in contact this step
  double time_s{0.0};                                    ///< time of this output
};

/// Work done and skipped, cumulative.
struct SimulationCounters {
  std::int64_t steps{0};
  std::int64_t contact_passes{0};           ///< steps with a collision pass
  std::int64_t contact_passes_skipped{0};   ///< steps without probes or walls (no pass needed)
  ContactCounters contact;                  ///< narrow-phase tests done / skipped by the broad phase
  std::int64_t surface_updates{0};          ///< surface deformations
  std::int64_t surface_updates_skipped{0};  ///< steps that ended without one (nobody looked)
  /// implicit with regional solves (IntegratorSettings::region_radius_mm): element rotation
  /// fits and node solves left out because they sleep, summed over steps
  std::int64_t sleeping_element_updates{0};
  std::int64_t sleeping_node_solves{0};
  /// implicit with regional solves: steps of a tissue at rest that computed nothing
  /// (IntegratorSettings::region_rest_speed_mm_s)
  std::int64_t steps_at_rest{0};
  /// ... times it fell asleep, and the last time: when (simulated, s; < 0: never), how long
  /// after a tool last let go of it (or after the start), s, its largest node displacement from
  /// its rest shape then, mm (< 0: not known), and why (it was put at rest unless `slow`)
  std::int64_t sleeps{0};
  double last_sleep_s{-1.0};
  double last_sleep_since_release_s{0.0};
  double last_sleep_offset_mm{-1.0};
  double last_release_offset_mm{0.0};  ///< its largest displacement from its rest shape when let go, mm (0: unknown)
  SleepCause last_sleep_cause{SleepCause::none};
  /// ... steps that woke it (a tool's first touch after a rest), and the threads the last of them
  /// ran on (IntegratorSettings::wake_threads)
  std::int64_t wakes{0};
  int last_wake_threads{0};
  /// implicit: system matrices factored (or loaded from the factor cache), and their wall time, s
  std::int64_t factorisations{0};
  std::int64_t factors_from_cache{0};
  std::int64_t orders_from_cache{0};  ///< factored in METIS's order kept by the pattern
  double factor_s{0.0};
  /// ... of them built on a thread of their own while the tissue rested
  /// (IntegratorSettings::factor_in_background), and the wall time steps waited for them, s
  std::int64_t factors_in_background{0};
  double factor_wait_s{0.0};
  /// implicit: local/global iterations (global solves) summed over the steps
  std::int64_t iterations{0};
};

/// The state at one step as a display draws it (Simulation::copy_frame).
struct SimulationFrame {
  double time_s{0.0};
  std::int64_t step{0};
  Eigen::Matrix3Xd positions;         ///< 3 x nodes, mm (3 x 0 when not asked for: copy_frame)
  Eigen::Matrix3Xd surface_vertices;  ///< 3 x V (empty without a surface), mm
  Eigen::Matrix3Xd surface_normals;   ///< 3 x V
  /// The surface those vertices deform (its triangles; null without one): a display that holds
  /// another (Simulation::set_surface swapped it) takes this one's triangles
  std::shared_ptr<const EmbeddedSurface> surface;
  std::vector<ProbeOutput> probes;
};

/// The tissue's dynamic state at one step (Simulation::save_tissue / restore_tissue): what a
/// failed step is rolled back to. Positions and velocities 3 x nodes (mm, mm/s), the elements'
/// rotation fits (their warm starts), the time and step count it was taken at.
struct TissueSnapshot {
  Eigen::Matrix3Xd positions;
  Eigen::Matrix3Xd velocities;
  std::vector<Eigen::Quaterniond> rotations;
  double time_s{0.0};
  std::int64_t step{-1};  ///< -1: never taken
  [[nodiscard]] bool empty() const { return step < 0; }
};

/// What runs beside the physics at every step (haptics/device_side.h: the device force and the
/// local contact models), on the physics thread.
class StepListener {
 public:
  virtual ~StepListener() = default;
  /// After each step: the probes' outputs (Simulation::probe) and step_contacts() are this step's.
  virtual void after_step() = 0;
  /// After Simulation::reset().
  virtual void after_reset() = 0;
};

/// A running simulation. Create it, then step it; see the file comment for threads.
class Simulation {
 public:
  /// Checks the settings against the model (node ids, probes) and prepares
  /// every buffer. Throws vx::Error with what is wrong.
  Simulation(std::shared_ptr<const PhysicsModel> physics, SimulationSettings settings);
  ~Simulation();
  Simulation(const Simulation&) = delete;
  Simulation& operator=(const Simulation&) = delete;

  /// One step (see the file comment). Returns the state's status; a failed state stays put.
  StepStatus step();
  /// Steps until time_s() >= target_time_s - dt/2 or `max_steps` were taken (a real-time loop
  /// calls this with the wall-clock time since its start and a step budget). Returns steps taken.
  int advance_to(double target_time_s, int max_steps);
  /// Back to t = 0 at rest (probes at their start, counters kept; the listener told).
  void reset();
  /// Copies the tissue's state now into `out` (its buffers reused: no allocation once sized).
  void save_tissue(TissueSnapshot& out) const;
  /// The tissue back to `snap` (positions, velocities, rotation fits) and a failure cleared;
  /// time, step count, probes and device shaping go on from where they are (a rollback of the
  /// tissue, not of the session). `drop_solver`: the implicit integrator refactors at the next
  /// step (after an exception thrown inside a step its factor cannot be trusted). Throws
  /// vx::Error for a snapshot of another size.
  void restore_tissue(const TissueSnapshot& snap, bool drop_solver = false);

  [[nodiscard]] double time_s() const { return state_.time_s; }
  [[nodiscard]] std::int64_t steps() const { return state_.steps; }
  [[nodiscard]] double dt_s() const { return settings_.integrator.time_step_s; }
  [[nodiscard]] bool failed() const { return state_.failed(); }
  [[nodiscard]] const SimState& state() const { return state_; }
  [[nodiscard]] const PhysicsModel& physics() const { return *physics_; }
  [[nodiscard]] const SimulationSettings& settings() const { return settings_; }
  [[nodiscard]] const SimulationCounters& counters() const { return counters_; }
  /// The implicit solver is being built on a thread of its own while the tissue rests
  /// (IntegratorSettings::factor_in_background); for how long so far, s (0: not being built).
  [[nodiscard]] bool solver_pending() const { return state_.integrator_cache.pending.valid(); }
  [[nodiscard]] double solver_pending_s() const { return state_.integrator_cache.pending_age_s(); }
  /// Stops the solver being built in the background and hands it over, for a caller that ends the
  /// run and will not wait for it (IntegratorCache::abandon_pending; an empty future without one).
  /// Not while a step runs.
  [[nodiscard]] std::future<IntegratorCache::SolverPtr> abandon_pending_solver() {
    return state_.integrator_cache.abandon_pending();
  }
  [[nodiscard]] const std::shared_ptr<const PhysicsModel>& shared_physics() const { return physics_; }

  [[nodiscard]] int num_probes() const { return int(drivers_.size()); }
  /// Probe `i` after the last step.
  [[nodiscard]] const ProbeOutput& probe(int i) const { return outputs_[std::size_t(i)]; }
  /// Force of the tissue on the walls this step, N.
  [[nodiscard]] const Eigen::Vector3d& wall_force_n() const { return wall_force_; }
  /// Probe `i`'s shape.
  [[nodiscard]] const ProbeGeometry& probe_geometry(int i) const { return geometry_[std::size_t(i)]; }
  /// Index of the probe named `name`, or -1.
  [[nodiscard]] int probe_index(const std::string& name) const;

  /// Deformed surface vertices (3 x V, mm) at the current step, deforming it now if the
  /// surface is stale. Throws vx::Error when the simulation has no surface.
  const Eigen::Matrix3Xd& surface_vertices();
  [[nodiscard]] bool has_surface() const { return bool(settings_.surface); }
  /// Deforms `surface` from now on instead of the one it had (a display surface refined while
  /// the simulation runs: the probe app's first start of an organ); the next surface_vertices()
  /// or frame deforms it. Null: no surface from now on. Throws vx::Error when it is embedded in
  /// a model of another node count (the simulation keeps its surface then).
  void set_surface(std::shared_ptr<const EmbeddedSurface> surface);

  /// Live input for probe `i` (a `live` probe); applied from the next step on.
  /// Throws vx::Error for a bad index or a probe that is not live.
  void set_live(int i, const LiveCommand& command);
  /// The state now as a frame (positions, the deformed surface and its normals, the probes),
  /// into `out` (its buffers reused); deforms the surface when it is stale. Without
  /// `with_positions` the node positions are left out (3 x 0): a display that draws the surface
  /// only does not need them (5 MB on a 327,000-node organ).
  void copy_frame(SimulationFrame& out, bool with_positions = true);

  // --- what the device side (haptics/device_side.h) reads ------------------------------------
  /// Attaches `listener` (null: none), told after every step and reset. `record_contacts`: the
  /// explicit integrators keep each step's probe contacts for step_contacts().
  void set_step_listener(StepListener* listener, bool record_contacts);
  /// This step's contacts with their forces: the implicit integrator's constraints, or the
  /// explicit path's recorded probe contacts (empty unless a listener asked for them).
  [[nodiscard]] const std::vector<ContactConstraint>& step_contacts() const;
  [[nodiscard]] const ContactSolver& contact_solver() const { return contact_; }
  /// The integrator solves the contact (implicit) and so can give its compliance.
  [[nodiscard]] bool solves_contact() const;
  /// The integrator's compliance between `nodes` (integrators.h contact_compliance); false when it has none.
  bool contact_compliance(const std::vector<std::int32_t>& nodes, Eigen::MatrixXd& g);

 private:
  /// Hands the probes and walls to an implicit integrator (contact inside its solve).
  class ImplicitContact final : public ContactProvider {
   public:
    explicit ImplicitContact(Simulation& sim) : sim_(sim) {}
    void collect(const Eigen::Matrix3Xd& x, bool near, std::vector<ContactConstraint>& out) override;
    void focus_points(std::vector<Eigen::Vector3d>& out) override;
    void watch_moving(const std::vector<int>* moving, std::uint64_t period) override;
    [[nodiscard]] int tool_owners() const override { return sim_.num_probes(); }  // then the walls

   private:
    Simulation& sim_;
  };

  /// Probe and wall forces from the implicit integrator's contact multipliers.
  void take_implicit_contact_forces();
  /// 2D (a slice model): the probes' centres on the slice plane (a sphere becomes the circle
  /// of its radius in the plane)
  void project_probes_to_plane();
  /// 2D: every node back on the slice plane, with no velocity along its normal (plane stress:
  /// the slice does not move out of its plane; the elastic forces never push it out, this
  /// removes the round-off and what contact constraints along a tilted normal leave)
  void hold_plane();
  std::shared_ptr<const PhysicsModel> physics_;
  SimulationSettings settings_;
  SimState state_;
  std::unique_ptr<Integrator> integrator_;
  ContactSolver contact_;
  std::unique_ptr<ImplicitContact> implicit_contact_;  ///< set: the integrator solves the contact
  std::vector<ProbeDriver> drivers_;
  std::vector<ProbeGeometry> geometry_;
  std::vector<ProbeState> poses_;
  std::vector<ProbeOutput> outputs_;
  std::vector<Eigen::Vector3d> raw_;
  std::vector<int> contacts_;
  Eigen::Vector3d wall_force_{Eigen::Vector3d::Zero()};
  bool collide_{false};
  SimulationCounters counters_;

  // the device side
  StepListener* listener_{nullptr};
  bool record_contacts_{false};
  std::vector<ContactConstraint> contact_records_;  ///< explicit: this step's probe contacts

  // surface
  SurfaceFrame surface_frame_;     ///< the deformed surface and its normals (each triangle's normal once)
  std::int64_t surface_step_{-1};  ///< step the surface was deformed at (-1: never)
};

/// What collides: every node that is not fixed. The surface nodes meet a probe first; the
/// nodes below the surface only meet it when the surface layer has folded around a frictionless
/// tool pressed deeper than a surface element (only nodes collide, not the faces between
/// them), and they then hold the tool up instead of letting it sink through (with the surface
/// nodes alone the palpation demo's 5 mm slide read 0 N from mid-slide on; scene_test). The
/// broad phase keeps the cost to the nodes near a probe.
[[nodiscard]] std::vector<std::int32_t> collidable_nodes(const Model& model, const std::vector<std::uint8_t>& fixed);

/// Mean spacing of neighbouring surface nodes, mm (the grid's mean voxel size).
[[nodiscard]] double surface_node_spacing_mm(const Model& model);

}  // namespace vx
