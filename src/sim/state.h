#pragma once
/// @file state.h
/// The mutable simulation state (MuJoCo's mjData to the PhysicsModel's mjModel): positions,
/// velocities, per-element warm-start rotations, scene inputs (gravity, fixed nodes, external
/// forces), health flags and the step's scratch. Many states can share one PhysicsModel.
/// Everything a step needs is allocated by make_state(); stepping allocates nothing.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <atomic>
#include <cstdint>
#include <future>
#include <memory>
#include <string>
#include <vector>

#include "physics/elements.h"
#include "physics/physics_model.h"

namespace vx {

/// Health of a state after a step.
enum class StepStatus : std::uint8_t {
  ok,          ///< all values finite and within the runaway limits
  non_finite,  ///< a NaN or Inf appeared: the step was not applied, the state stops
  runaway,     ///< a speed or displacement exceeded its limit (unstable time step or input)
};
[[nodiscard]] const char* to_string(StepStatus s);

/// Energies, N*mm (= mJ).
struct Energies {
  double kinetic{0.0};        ///< sum 1/2 m |v|^2
  double elastic{0.0};        ///< sum of element energies (shape + volume term)
  double gravitational{0.0};  ///< -sum m g . (x - x_rest): zero at the rest positions
  [[nodiscard]] double total() const { return kinetic + elastic + gravitational; }
};

/// One face of an axis-aligned box.
enum class BoxFace : std::uint8_t { x_min, x_max, y_min, y_max, z_min, z_max };

/// Nodes whose rest position lies on `face` of the model's rest bounding box (within tol_mm).
[[nodiscard]] std::vector<int> nodes_on_face(const Model& model, BoxFace face, double tol_mm = 1e-6);
/// Nodes whose rest position lies inside the box [lo, hi] (mm, inclusive).
[[nodiscard]] std::vector<int> nodes_in_box(const Model& model, const Eigen::Vector3d& lo_mm,
                                            const Eigen::Vector3d& hi_mm);

/// Scratch of a step: buffers sized once by make_state().
struct StepScratch {
  Eigen::Matrix3Xd entry_forces;       ///< 3 x vertex entries, N (node-major, see PhysicsModel::entry_slot)
  Eigen::Matrix3Xd next_positions;     ///< 3 x nodes: the step writes here, then swaps
  Eigen::Matrix3Xd next_velocities;    ///< 3 x nodes
  std::vector<double> element_energy;  ///< elements, N*mm (when energies are tracked)
  ElementPassScratch element_pass;
  std::vector<std::uint8_t> node_chunk_flags;  ///< per node chunk: bit 0 non-finite, bit 1 runaway
  std::vector<double> node_chunk_sums;  ///< per node chunk: partial kinetic and gravitational energies, the implicit
                                        ///< step's largest squared speed
};

class ProjectiveSolver;

/// What an integrator keeps per state between steps: the implicit integrator's factorisation
/// (projective_solver.h) and the key of its contact warm start. Owned by the state, so no
/// integrator finds a state's cache by its address (a state rebuilt at a freed address cannot
/// meet a stale factor); a copy of a state starts without one (its first implicit step factors).
/// The solver sits above the state (it steps one): the state holds it with the deleter its maker
/// gives (integrators.cpp), so the state never includes the solver's header.
struct IntegratorCache {
  using SolverPtr = std::unique_ptr<ProjectiveSolver, void (*)(ProjectiveSolver*)>;
  SolverPtr solver{nullptr, nullptr};  ///< null until the first implicit step
  std::uint64_t fixed_version{0};      ///< SimState::fixed_version the solver was built for
  std::uint64_t contact_epoch{0};      ///< the contact provider the warm start belongs to (0: none)
  std::int64_t next_step{-1};          ///< the warm start holds for the step that starts at this count
  double next_time_s{0.0};             ///< ... and at this time
  /// A solver being built on a thread of its own while the tissue rests
  /// (IntegratorSettings::factor_in_background); valid() until a step takes it. Destroying a
  /// cache that holds one asks it to stop (`pending_stop`) and waits for the stage it is in to
  /// end (METIS and the numeric factorisation cannot be cut short; abandon_pending() does not wait).
  std::future<SolverPtr> pending;
  /// The pending build's own stop, asked by the destructor and abandon_pending() (null: none).
  std::shared_ptr<std::atomic<bool>> pending_stop;
  std::uint64_t pending_fixed_version{0};  ///< SimState::fixed_version the pending solver is built for
  double pending_since_s{0.0};             ///< steady-clock seconds when it was started (pending_age_s())

  /// Wall time since the pending solver was started, s (0 without one).
  [[nodiscard]] double pending_age_s() const;
  /// Asks the pending build to stop and hands it over (an empty future without one): its holder
  /// decides whether to wait for it. It stops at its next stage and keeps nothing (Cancelled).
  [[nodiscard]] std::future<SolverPtr> abandon_pending();

  IntegratorCache();
  ~IntegratorCache();
  IntegratorCache(const IntegratorCache&);             ///< an empty cache
  IntegratorCache& operator=(const IntegratorCache&);  ///< empties this cache
  IntegratorCache(IntegratorCache&&) noexcept;
  IntegratorCache& operator=(IntegratorCache&&) noexcept;
};

/// A simulation state. Create with make_state(); change fixed nodes with the methods below
/// (they bump fixed_version so implicit integrators refactor).
struct SimState {
  std::shared_ptr<const PhysicsModel> physics;

  // dynamic state
  Eigen::Matrix3Xd positions;                 ///< 3 x nodes, mm
  Eigen::Matrix3Xd velocities;                ///< 3 x nodes, mm/s (fixed nodes: their prescribed velocity)
  std::vector<Eigen::Quaterniond> rotations;  ///< elements: last fitted rotation (warm start)
  double time_s{0.0};
  std::int64_t steps{0};

  // scene inputs
  Eigen::Vector3d gravity_mm_s2{0.0, 0.0, 0.0};  ///< e.g. (0, 0, -kStandardGravityMmS2)
  Eigen::Matrix3Xd external_forces;              ///< 3 x nodes, N, added every step until changed (contacts)
  std::vector<std::uint8_t> node_fixed;          ///< nodes: 1 = kinematic (moves with its velocity only)
  std::uint64_t fixed_version{0};                ///< bumped whenever node_fixed changes
  /// Bumped whenever the positions are set other than by a step (a reset, a restore, a static
  /// solve, the tissue put at rest): the regional solves' promise to the contact
  /// (ProjectiveSolver::solve, ContactProvider::watch_moving) does not outlive it.
  std::uint64_t positions_version{0};

  // results of the last step
  Energies energies;               ///< at the start of the last step (when tracked)
  ElementPassStats element_stats;  ///< counters of the last force pass
  StepStatus status{StepStatus::ok};
  std::string message;  ///< what went wrong (empty when ok)

  StepScratch scratch;
  IntegratorCache integrator_cache;  ///< the implicit integrator's factorisation (integrators.h)

  [[nodiscard]] int num_nodes() const { return int(positions.cols()); }
  [[nodiscard]] int num_fixed() const;
  [[nodiscard]] bool failed() const { return status != StepStatus::ok; }

  /// Makes `nodes` kinematic (fixed at their position, moving only with their velocity,
  /// which is set to zero). Throws vx::Error for an index out of range.
  void fix_nodes(const std::vector<int>& nodes);
  /// Frees `nodes` again.
  void free_nodes(const std::vector<int>& nodes);
  /// Frees every node.
  void free_all_nodes();
  /// Back to rest: rest positions, zero velocity, identity rotations, time 0, status ok
  /// (fixed nodes, gravity and external forces are kept).
  void reset();
  /// Clears a failure so stepping continues (after the caller repaired the state).
  void clear_failure();
};

/// A state at rest for `physics` (positions = rest positions, velocities 0, nothing fixed).
[[nodiscard]] SimState make_state(std::shared_ptr<const PhysicsModel> physics);

/// Energies of the state as it is now (elastic energy with the rotation fits converged from the
/// state's warm starts, which are left untouched). Parallel and deterministic.
[[nodiscard]] Energies compute_energies(const SimState& state, int threads = 0);

/// Net elastic force (N) on the given nodes at the state's positions (e.g. the reaction on a
/// fixed face). Allocates; not for the hot loop.
[[nodiscard]] Eigen::Vector3d elastic_force_on(const SimState& state, const std::vector<int>& nodes, int threads = 0);

}  // namespace vx
