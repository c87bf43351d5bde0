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
///   4. device force (device_force.h): the raw force averaged and played as half sines, only
///      when the simulation has a device;
///   5. a frame for a display thread, only when one was requested; the embedded surface is
///      deformed only when someone asks for it.
/// With local contact models (settings.local_contact), each step also feeds the per-node contact
/// forces into the anchor's means, and publish_local_contact() (called by whoever runs the
/// physics, at the end of each physics update) hands the device thread one LocalContactModel
/// per probe (local_contact.h) through a lock-free triple buffer.
///
/// Work a scene does not need is skipped and counted (SimulationCounters); with
/// `skip_unneeded = false` every optional piece of work is done every step, which changes no
/// result (tests/core/simulation_test.cpp checks this bit for bit).
///
/// Threads. The physics thread owns the Simulation and calls step() / advance_to(). Other
/// threads may call only the methods marked "any thread": set_live() (input thread),
/// probe_snapshot() (device thread: read the raw force and the half-sine pulse to play),
/// take_local_contact() (one device thread), request_frame() / take_frame() (display thread).
///
/// Units: mm, s, N; gravity mm/s^2 here (the scene file takes m/s^2).

#include <Eigen/Core>
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "base/triple_buffer.h"
#include "physics/physics_model.h"
#include "sim/contact.h"
#include "sim/device_force.h"
#include "sim/integrators.h"
#include "sim/local_compliance.h"
#include "sim/local_contact.h"
#include "sim/probe.h"
#include "sim/state.h"
#include "surface/surface.h"

namespace vx {

/// How a simulation builds the local contact models it publishes (local_contact.h).
struct LocalContactSettings {
  /// Candidates besides the nodes in contact: the nodes within this gap of the tool, mm; <= 0:
  /// the broad-phase skin (twice the mean voxel size). It covers the tool's travel between
  /// two physics updates (20 mm/s for 50 ms: 1 mm).
  double margin_mm{0.0};
  int max_nodes{LocalContactSolver::kMaxNodes};  ///< at most this many candidates (nearest kept)
  /// The anchor (tool position, per-node forces) is an exponential mean over this time, s;
  /// < 0: automatic: 0 for the implicit integrator (its contact forces are smooth: the last
  /// step), 2 ms for the explicit ones (their node impulses jitter from step to step).
  double average_s{-1.0};
  /// The time between two physics updates (the probe app sets its physics period), s.
  double update_period_s{0.02};
  /// The compliance: the implicit integrator's own factor when it has one and one step spans
  /// at least half an update (its step's exact linearisation, as SOFA does) and the material
  /// has Poisson 0; else, or when false, A_T on a patch (local_compliance.h) at the horizon.
  bool integrator_compliance{true};
  /// The patch's T, s: long enough for the quasi-static response of a tissue the tool moves
  /// smoothly (a short T adds the inertia of a sudden jump: on a 16 mm block the contact
  /// stiffness at T = 2 ms is 1.35x that at 20 ms, and at 1 kHz updates the model then overshoots
  /// the force's change: 0.21 % RMS error against 0.07 % at 0.1 s).
  double horizon_s{0.1};
  /// W is scaled by this. 1: the projective matrix as it is, the exact linearisation of an
  /// implicit step of one local/global iteration. Converged (or explicit) dynamics respond
  /// along the true tangent, which the projective matrix overestimates (it leaves out the
  /// rotations' derivatives): 1.22x under a ball pressed into a block
  /// (tests/core/sim/local_contact_test.cpp), 1.0 under a flat plate. 1.2 halves the demo's
  /// error at 60 Hz (1.05 % -> 0.56 % RMS), but a model softer than the tissue, anchored one
  /// update late, returns more energy than it took: the closed-loop test goes active (docs/probe.md).
  /// A stiffer model errs on the dissipative side, hence 1.
  double compliance_scale{1.0};
  double patch_radius_mm{0.0};  ///< patch: radius; <= 0: max(6 x tool radius, 12 x voxel size)

  /// Empty when valid, else what is wrong.
  [[nodiscard]] std::string validate() const;
};

/// Everything a simulation needs besides the physics model (plain settings; the scene file
/// fills them, see pipeline/scene/scene.h).
struct SimulationSettings {
  IntegratorSettings integrator;                      ///< kind, time step, threads
  Eigen::Vector3d gravity_mm_s2{Eigen::Vector3d::Zero()};
  std::vector<int> fixed_nodes;                       ///< nodes held at their rest position
  Workspace workspace;                                ///< walls (disabled: none)
  ContactSettings contact;
  std::vector<ProbeSettings> probes;
  std::optional<DeviceForceSettings> device;          ///< absent: no device, no force shaping
  std::optional<LocalContactSettings> local_contact;  ///< absent: no local contact models
  std::shared_ptr<const EmbeddedSurface> surface;     ///< optional surface that follows the nodes
  bool skip_unneeded{true};                           ///< false: do all optional work every step
};

/// A probe after a step.
struct ProbeOutput {
  ProbeState pose;                                     ///< position mm, velocity mm/s
  Eigen::Vector3d raw_force_n{Eigen::Vector3d::Zero()};    ///< force of the tissue on the probe this step
  Eigen::Vector3d shaped_force_n{Eigen::Vector3d::Zero()}; ///< device force now (zero without a device)
  HalfSinePulse pulse;                                 ///< the half sine being played (device only)
  int contacts{0};                                     ///< nodes in contact this step
  double time_s{0.0};                                  ///< time of this output
};

/// Work done and skipped, cumulative.
struct SimulationCounters {
  std::int64_t steps{0};
  std::int64_t contact_passes{0};           ///< steps with a collision pass
  std::int64_t contact_passes_skipped{0};   ///< steps without probes or walls (no pass needed)
  ContactCounters contact;                  ///< narrow-phase tests done / skipped by the broad phase
  std::int64_t device_shaping_steps{0};     ///< probe-steps whose device force was shaped
  std::int64_t device_shaping_skipped{0};   ///< probe-steps not shaped (no device)
  std::int64_t surface_updates{0};          ///< surface deformations
  std::int64_t surface_updates_skipped{0};  ///< steps that ended without one (nobody looked)
  std::int64_t frames_published{0};         ///< frames copied for a display thread
  std::int64_t frames_skipped{0};           ///< steps without a requested frame
  /// implicit with regional solves (IntegratorSettings::region_radius_mm): element rotation
  /// fits and node solves left out because they sleep, summed over steps
  std::int64_t sleeping_element_updates{0};
  std::int64_t sleeping_node_solves{0};
  /// implicit: system matrices factored (or loaded from the factor cache), and their wall time, s
  std::int64_t factorisations{0};
  std::int64_t factors_from_cache{0};
  double factor_s{0.0};
};

/// A frame for a display thread.
struct SimulationFrame {
  double time_s{0.0};
  std::int64_t step{0};
  Eigen::Matrix3Xd positions;        ///< 3 x nodes, mm
  Eigen::Matrix3Xd surface_vertices; ///< 3 x V (empty without a surface), mm
  Eigen::Matrix3Xd surface_normals;  ///< 3 x V
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

/// A running simulation. Create it, then step it; see the file comment for threads.
class Simulation {
 public:
  /// Checks the settings against the model (node ids, probes, device interval) and prepares
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
  /// Back to t = 0 at rest (probes at their start, device forces cleared, counters kept).
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
  /// A device with the paper's half sines (a `local` device is the probe app's: it shapes the
  /// force from the local contact models, and the simulation plays no half sines for it).
  [[nodiscard]] bool has_device() const {
    return settings_.device.has_value() && settings_.device->shaping == ForceShaping::paper;
  }

  [[nodiscard]] int num_probes() const { return int(drivers_.size()); }
  /// Probe `i` after the last step (physics thread).
  [[nodiscard]] const ProbeOutput& probe(int i) const { return outputs_[std::size_t(i)]; }
  /// Force of the tissue on the walls this step, N (physics thread).
  [[nodiscard]] const Eigen::Vector3d& wall_force_n() const { return wall_force_; }
  /// Index of the probe named `name`, or -1.
  [[nodiscard]] int probe_index(const std::string& name) const;

  /// Deformed surface vertices (3 x V, mm) at the current step, deforming it now if the
  /// surface is stale. Throws vx::Error when the simulation has no surface. Physics thread.
  const Eigen::Matrix3Xd& surface_vertices();
  [[nodiscard]] bool has_surface() const { return bool(settings_.surface); }

  // --- any thread ---------------------------------------------------------------------------
  /// Live input for probe `i` (a `live` probe); applied from the next step on.
  /// Throws vx::Error for a bad index or a probe that is not live.
  void set_live(int i, const LiveCommand& command);
  /// Probe `i` after the last completed step: pose, raw force, shaped force and the pulse
  /// (a device thread can evaluate pulse.at(its own time) between physics steps).
  [[nodiscard]] ProbeOutput probe_snapshot(int i) const;
  /// Device thread (one consumer): the newest local contact model of probe `i` if one was
  /// published since the last call, else null. The model stays valid until the next call for
  /// the same probe. Null without settings.local_contact.
  [[nodiscard]] const LocalContactModel* take_local_contact(int i);

  // --- physics thread -------------------------------------------------------------------------
  /// Builds one local contact model per probe from the state now and the anchor means, and
  /// publishes them (settings.local_contact; else does nothing). Call it at the end of each
  /// physics update (after a chunk of steps). Allocates when the candidates grow.
  void publish_local_contact();
  /// Builds probe `i`'s local contact model into `out` without publishing it (tests, tools).
  void build_local_contact(int i, LocalContactModel& out);
  [[nodiscard]] bool has_local_contact() const { return settings_.local_contact.has_value(); }
  /// Local contact models published so far.
  [[nodiscard]] std::int64_t local_contact_updates() const { return local_updates_; }
  /// The patch compliance (explicit integrators), for reports.
  [[nodiscard]] const PatchCompliance& patch_compliance() const { return patch_; }

  /// Asks the physics thread to copy a frame at the end of its next step.
  void request_frame() { frame_requested_.store(true, std::memory_order_release); }
  /// Swaps the latest frame into `out` if a new one is ready; returns whether it was.
  bool take_frame(SimulationFrame& out);

 private:
  /// Hands the probes and walls to an implicit integrator (contact inside its solve).
  class ImplicitContact final : public ContactProvider {
   public:
    explicit ImplicitContact(Simulation& sim) : sim_(sim) {}
    void collect(const Eigen::Matrix3Xd& x, bool near, std::vector<ContactConstraint>& out) override;
    void focus_points(std::vector<Eigen::Vector3d>& out) override;

   private:
    Simulation& sim_;
  };

  void publish();
  /// Probe and wall forces from the implicit integrator's contact multipliers.
  void take_implicit_contact_forces();
  /// 2D (a slice model): the probes' centres on the slice plane (a sphere becomes the circle
  /// of its radius in the plane)
  void project_probes_to_plane();
  /// 2D: every node back on the slice plane, with no velocity along its normal (plane stress:
  /// the slice does not move out of its plane; the elastic forces never push it out, this
  /// removes the round-off and what contact constraints along a tilted normal leave)
  void hold_plane();
  /// Feeds this step's per-node contact forces into the anchor means.
  void accumulate_local_contact();
  /// The local contact models take their compliance from the integrator's factor.
  [[nodiscard]] bool use_integrator_compliance() const;
  /// The scale of the local contact models' compliance (LocalContactSettings::compliance_scale).
  [[nodiscard]] double local_compliance_scale() const;

  /// The anchor of one probe's local contact model: exponential means over average_s.
  struct LocalAnchor {
    bool started{false};
    Eigen::Vector3d pose{Eigen::Vector3d::Zero()};
    std::vector<Eigen::Vector3d> node_force;  ///< per node: mean force of the tool on it, N (lambda n)
    std::vector<std::int32_t> nodes;          ///< nodes with a nonzero mean force
    std::vector<std::uint8_t> listed;         ///< per node: in `nodes`
  };

  std::shared_ptr<const PhysicsModel> physics_;
  SimulationSettings settings_;
  SimState state_;
  std::unique_ptr<Integrator> integrator_;
  ContactSolver contact_;
  std::unique_ptr<ImplicitContact> implicit_contact_;  ///< set: the integrator solves the contact
  std::vector<ProbeDriver> drivers_;
  std::vector<ProbeGeometry> geometry_;
  std::vector<ProbeState> poses_;
  std::vector<DeviceForceShaper> shapers_;
  std::vector<ProbeOutput> outputs_;
  std::vector<Eigen::Vector3d> raw_;
  std::vector<int> contacts_;
  Eigen::Vector3d wall_force_{Eigen::Vector3d::Zero()};
  bool collide_{false};
  bool shape_{false};
  SimulationCounters counters_;

  // local contact models
  double local_average_s_{0.0};
  std::vector<LocalAnchor> local_anchor_;
  std::vector<ContactConstraint> contact_records_;  ///< explicit: this step's probe contacts
  std::vector<std::unique_ptr<TripleBuffer<LocalContactModel>>> local_out_;
  PatchCompliance patch_;
  std::int64_t local_updates_{0};
  struct LocalCandidate {
    std::int32_t node;
    double force_n, gap_mm;
    Eigen::Vector3d normal;
  };
  std::vector<LocalCandidate> local_candidates_;
  Eigen::MatrixXd local_g_;

  // surface
  SurfaceFrame surface_frame_;  ///< the deformed surface and its normals (each triangle's normal once)
  std::int64_t surface_step_{-1};  ///< step the surface was deformed at (-1: never)

  // shared with other threads
  mutable std::mutex mutex_;
  std::vector<LiveCommand> live_;        ///< guarded
  std::vector<bool> live_dirty_;         ///< guarded
  std::atomic<bool> live_pending_{false};
  std::vector<ProbeOutput> published_;   ///< guarded
  std::atomic<bool> frame_requested_{false};
  SimulationFrame frame_;                ///< guarded
  bool frame_ready_{false};              ///< guarded
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
