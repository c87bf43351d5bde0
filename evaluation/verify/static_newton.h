#pragma once
/// @file static_newton.h
/// Private to evaluation/verify: the model's static equilibrium by Newton's method on its own
/// element forces, with single coordinates of nodes held (a node held along z only slides in x
/// and y: the frictionless ends of the bulge case). The static solver (sim/static_solver.h) holds
/// whole nodes only (its projective solver shares one factor between x, y and z), and its
/// local/global iteration is slow on bending as the Poisson ratio nears 0.5. Units: mm, N.

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "physics/physics_model.h"

namespace vx::cases {

/// held[3 i + a] = 1: coordinate a of node i is held where the start puts it.
using HeldCoordinates = std::vector<std::uint8_t>;

/// The coordinates of `nodes` held in all three axes (the rest free), for `num_nodes` nodes.
[[nodiscard]] HeldCoordinates held_nodes(int num_nodes, const std::vector<int>& nodes);

/// The model's static equilibrium under gravity from `start` (3 x nodes, mm) with the `held`
/// coordinates kept, by Newton's method: the tangent K = -df/dx of the element pass (no damping)
/// by central differences (the nodes of one colour moved at once, no two of them in one
/// element), at the start and after the first step (then kept); x += K^-1 r(x) with r the
/// elastic forces plus the weight on the free coordinates, until none moves more than 1e-8 mm.
/// Returns the positions; `residual_n` (optional) the largest free force left, N. Throws
/// vx::Error when the tangent cannot be factored (a part held nowhere) or after 30 iterations.
[[nodiscard]] Eigen::Matrix3Xd newton_static_positions(const PhysicsModel& p, const Eigen::Matrix3Xd& start,
                                                       const HeldCoordinates& held,
                                                       const Eigen::Vector3d& gravity_mm_s2,
                                                       double* residual_n = nullptr);

}  // namespace vx::cases
