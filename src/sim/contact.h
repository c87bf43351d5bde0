#pragma once
/// @file contact.h
/// Collision of the elastic object's nodes with rigid probes and the workspace walls
/// (docs/model.md section 8, paper 4.1 and 4.3).
///
/// Each listed node (simulation.h: every free node) that is inside a probe (or outside the
/// workspace box) is put back on the probe's surface (the wall), and its velocity relative to
/// the probe is reflected along the surface normal: v_rel_n -> -e v_rel_n (e = restitution,
/// 1 = the paper's elastic collision), with optional Coulomb friction on the tangential part
/// (impulse-form cone, position-level stick: see ContactSettings::friction). The force of the tissue on a probe is
/// minus the momentum change of those nodes per step:  F = -sum_i m_i (v_i' - v_i) / dt  (N).
///
/// Broad phase (a Verlet list): when rebuilt, each probe and the walls keep the list of
/// nodes within `skin_mm` of them. The lists stay valid while the largest node displacement
/// since the rebuild plus the probe's own displacement is below the skin; only the listed
/// nodes are tested. A node that is not listed cannot have reached the probe, so the result is
/// identical (bit for bit) to testing every node, which `broad_phase = false` does.
///
/// The implicit integrator takes the contact into its solve instead (integrators.h): collect()
/// hands it the same nodes, from the same broad phase, as unilateral constraints linearised at
/// its iterates; the forces are then its multipliers, the contact is perfectly inelastic
/// (restitution does not apply) and frictionless (see docs/scenes.md).
///
/// Units: positions mm, velocities mm/s, masses N*s^2/mm (material.h), forces N.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "sim/contact_constraint.h"
#include "sim/probe.h"

namespace vx {

/// A box of walls the object stays in (LPS mm). Disabled by default (no walls).
struct Workspace {
  bool enabled{false};
  Eigen::Vector3d min_mm{Eigen::Vector3d::Zero()};
  Eigen::Vector3d max_mm{Eigen::Vector3d::Zero()};
};

/// How collisions respond.
struct ContactSettings {
  double restitution{1.0};  ///< normal restitution e in [0,1]; 1 = elastic collision (the paper)
  /// Coulomb coefficient >= 0; 0 = frictionless (the paper). A node sticks when stopping its
  /// tangential velocity relative to the surface takes no more than mu times its normal
  /// impulse; its slip since it last touched the surface is then undone. Else it slides and
  /// that fraction of velocity and slip is removed.
  double friction{0.0};
  double skin_mm{0.0};     ///< broad-phase margin, mm; <= 0 picks 2 x the mean surface node spacing
  bool broad_phase{true};  ///< false tests every listed node every step (the reference)

  /// Empty when valid, else what is wrong.
  [[nodiscard]] std::string validate() const;
};

/// Work counters (cumulative since init()).
struct ContactCounters {
  std::int64_t narrow_tests{0};          ///< node-probe and node-wall tests done
  std::int64_t narrow_tests_skipped{0};  ///< tests the broad phase made unnecessary
  std::int64_t rebuilds{0};              ///< broad-phase list rebuilds
  std::int64_t broad_tests{0};           ///< node distance tests done by the rebuilds
  std::int64_t contacts{0};              ///< node-probe contacts resolved
  std::int64_t wall_contacts{0};         ///< node-wall contacts resolved
};

/// Resolves contacts between nodes and probes/walls. Allocates in init() and on the
/// (rare) rebuilds only while a list grows; resolve() itself does not allocate otherwise.
class ContactSolver {
 public:
  /// `nodes`: the node ids that may collide (simulation.h: the free nodes), `probes` the
  /// number of probes, `spacing_mm` the typical surface node spacing (for the automatic skin).
  void init(std::vector<std::int32_t> nodes, int probes, const Workspace& workspace, const ContactSettings& settings,
            double spacing_mm);

  /// Moves the listed nodes that entered a probe or left the workspace back onto the surface
  /// and reflects their velocities. `node_mass` in N*s^2/mm. Writes the force of the tissue on
  /// each probe (N, one per probe) and on the walls. With `records`, also appends each probe
  /// contact of the step (node, probe, surface point, outward normal, and as force_n the normal
  /// momentum change per step of the node, N): the local contact model's per-node forces.
  void resolve(Eigen::Matrix3Xd& positions, Eigen::Matrix3Xd& velocities, const std::vector<double>& node_mass,
               const std::vector<ProbeGeometry>& geometry, const std::vector<ProbeState>& probes, double dt_s,
               std::vector<Eigen::Vector3d>& probe_force_n, Eigen::Vector3d& wall_force_n,
               std::vector<int>* probe_contacts = nullptr, std::vector<ContactConstraint>* records = nullptr);

  /// Implicit path: appends a constraint for every listed node that `positions` put inside a
  /// probe or beyond a wall, and with `near` also within near_margin_mm() outside, linearised at
  /// the node (closest surface point, outward normal). Owner: the probe index, or
  /// probes + 2 * axis + side for the walls (side 0: the min wall). Rebuilds the broad-phase
  /// lists when they may miss such a node (the same rule as resolve(), with the margin).
  void collect(const Eigen::Matrix3Xd& positions, const std::vector<ProbeGeometry>& geometry,
               const std::vector<ProbeState>& probes, bool near, std::vector<ContactConstraint>& out);
  /// The margin of collect(near = true), mm: a quarter of the skin.
  [[nodiscard]] double near_margin_mm() const { return 0.25 * skin_mm_; }
  /// Implicit path: counts the contacts a step resolved (its active constraints).
  void count_contacts(std::int64_t probe_contacts, std::int64_t wall_contacts) {
    counters_.contacts += probe_contacts;
    counters_.wall_contacts += wall_contacts;
  }

  [[nodiscard]] const ContactCounters& counters() const { return counters_; }
  [[nodiscard]] double skin_mm() const { return skin_mm_; }
  [[nodiscard]] const std::vector<std::int32_t>& nodes() const { return nodes_; }
  /// Threads of the broad phase's check of every listed node's move (0: OpenMP's default; the
  /// step's threads: the check runs between the step's parallel passes). The same result on any
  /// number (a largest value).
  void set_threads(int threads) { threads_ = threads; }
  /// Forces a broad-phase rebuild at the next resolve() and forgets the friction anchors
  /// (after positions were set from outside, e.g. a reset). Ends a promise (watch_moving).
  void invalidate();
  /// The regional solves' promise (ContactProvider::watch_moving): while it holds, the broad
  /// phase's check of the nodes' move since the rebuild looks at the nodes of `moving` only,
  /// after one check of every node in the period, which keeps the largest move of the others.
  /// The same largest move to the bit as a check of every node (the same values). `moving` null
  /// pauses the promise: the checks look at every node again (and keep the others' largest
  /// move), and a later call with the same period resumes it. Period 0, resolve() (it moves
  /// nodes), init() and invalidate() end it. Allocates only when `moving` outgrows the nodes.
  void watch_moving(const std::vector<int>* moving, std::uint64_t period);
  /// Checks of the nodes' move that looked at the watched nodes only (a diagnostic for tests).
  [[nodiscard]] std::int64_t watched_checks() const { return watched_checks_; }

 private:
  void rebuild(const Eigen::Matrix3Xd& positions, const std::vector<ProbeGeometry>& geometry,
               const std::vector<ProbeState>& probes);
  [[nodiscard]] double node_move(const Eigen::Matrix3Xd& positions);
  /// Rebuilds the lists unless list q (a probe, or probes_ for the walls) still holds every
  /// node within `margin` of its surface: `moved` (the largest node move since the rebuild;
  /// reset by one) plus the probe's own move plus the margin below the skin.
  void keep_lists_valid(const Eigen::Matrix3Xd& positions, const std::vector<ProbeGeometry>& geometry,
                        const std::vector<ProbeState>& probes, int q, double margin, double& moved);

  std::vector<std::int32_t> nodes_;
  Workspace workspace_;
  ContactSettings settings_;
  double skin_mm_{1.0};
  int probes_{0};
  bool valid_{false};
  // broad phase: per probe (and the walls, last) the listed nodes, sorted by node id
  std::vector<std::vector<std::int32_t>> lists_;
  Eigen::Matrix3Xd node_at_rebuild_;  ///< 3 x nodes_.size()
  int threads_{1};
  std::vector<double> chunk_move_;  ///< node_move()'s largest squared move per chunk
  // the promise (watch_moving)
  std::uint64_t watch_period_{0};         ///< 0: none
  bool watch_active_{false};              ///< not paused
  bool watch_ready_{false};               ///< still_move2_ known for this period
  double still_move2_{0.0};               ///< the largest squared move of the nodes outside the watch
  std::vector<std::int64_t> watched_;     ///< positions in nodes_ of the watched nodes, ascending
  std::vector<std::uint8_t> is_watched_;  ///< per position in nodes_
  std::vector<double> chunk_still_;       ///< a full check's largest squared move outside the watch, per chunk
  std::int64_t watched_checks_{0};
  void end_watch();
  std::vector<Eigen::Vector3d> probe_at_rebuild_;
  /// rebuild(): a ball round each probe and its squared reach (the ball's radius plus the skin)
  struct ProbeReach {
    Eigen::Vector3d centre{Eigen::Vector3d::Zero()};
    double reach2{0.0};
  };
  std::vector<ProbeReach> reach_;
  ContactCounters counters_;
  // friction: where each node last touched a surface, in that surface's frame (per node id)
  static constexpr std::int64_t kAnchorSteps = 8;
  std::vector<Eigen::Vector3d> anchor_;
  std::vector<int> anchor_owner_;  ///< probe index, probes_ for the walls, -1 none
  std::vector<std::int64_t> anchor_step_;
  std::int64_t step_{0};
};

}  // namespace vx
