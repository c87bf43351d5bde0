#pragma once
/// @file contact_constraint.h
/// Contact as constraints of an implicit step (docs/model.md section 8): what the simulation's
/// probes and walls hand the projective-dynamics solver (projective_solver.h), which solves them
/// with its active set (contact_active_set.h).

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <vector>

namespace vx {

/// One unilateral contact constraint of an implicit step: node `node` must stay on the free side
/// of the plane through `point_mm` with unit normal `normal`,  normal . x_node >= normal . point_mm
/// (the probe's or wall's surface linearised at the node: its closest surface point and outward
/// normal, see probe_signed_distance() in contact.h).
struct ContactConstraint {
  std::int32_t node{0};
  std::int32_t owner{0};  ///< who pushes (the provider's numbering: a probe, a wall face)
  Eigen::Vector3d point_mm{Eigen::Vector3d::Zero()};
  Eigen::Vector3d normal{Eigen::Vector3d::UnitZ()};
  /// solver output: the multiplier, the force of the surface on the node along `normal`
  /// (N, >= 0; the force of the node on the probe is -force_n * normal)
  double force_n{0.0};
};

/// Supplies the contact constraints of an implicit step (the simulation's probes and walls;
/// contact.h finds them). The solver calls it with its iterates during the step.
class ContactProvider {
 public:
  virtual ~ContactProvider() = default;
  /// Appends a constraint (linearised at x) for every collidable node that `x` (3 x nodes, mm)
  /// puts inside a probe or beyond a wall, and with `near` also for the nodes within the
  /// provider's margin outside them (candidates that may touch within the step). Each
  /// (owner, node) pair at most once. Must not allocate in steady state.
  virtual void collect(const Eigen::Matrix3Xd& x, bool near, std::vector<ContactConstraint>& out) = 0;
  /// Where the tools are (mm): the centres of the implicit integrator's regional solves
  /// (IntegratorSettings::region_radius_mm). None by default.
  virtual void focus_points(std::vector<Eigen::Vector3d>& out) { out.clear(); }
  /// The owners below this are tools (probes), the others walls: a solve goes on iterating
  /// only while no tool touches (ProjectiveIterations::free_max_iterations). Every owner by default.
  [[nodiscard]] virtual int tool_owners() const { return std::numeric_limits<int>::max(); }
  /// A promise for the collects that follow, until the next call: the nodes outside `moving`
  /// (node ids, ascending) have the same position in every x given to collect(), so the provider
  /// may look for the broad phase's largest move among `moving` only. `period` names the stretch
  /// the promise covers: a call with the last call's period (and the same `moving`) continues it,
  /// the positions outside `moving` still those of its earlier collects; any other value starts a
  /// new one. `period` 0: no promise (every node may move); `moving` null with the period: a
  /// pause (every node may move until the same period resumes the promise). The regional
  /// solves' (projective_solver.h): the rows outside the closure keep their positions. Ignored
  /// by default.
  virtual void watch_moving(const std::vector<int>* moving, std::uint64_t period) {
    (void)moving;
    (void)period;
  }
};

}  // namespace vx
