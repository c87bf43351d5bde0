#pragma once
/// @file case_helpers.h
/// Private to evaluation/verify: what the verify cases share (the theme files *_cases.cpp): the
/// objects they build, settings on one physics thread (cases run in parallel instead), fits,
/// energies, and the ball pressed into a block that the Hertz, lesion and layout cases use.
/// Units: mm, s, N, kPa, kg/m^3.

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include "convert/phantom.h"
#include "model/model.h"
#include "physics/material.h"
#include "physics/physics_model.h"
#include "sim/integrators.h"
#include "sim/state.h"
#include "sim/static_solver.h"

namespace vx::cases {

inline constexpr int kThreads = 1;  ///< physics threads per case (cases run in parallel)
inline constexpr double kPi = std::numbers::pi;

/// A solid block of dims voxels of edge h mm, its corner at the origin, in layout `r`.
[[nodiscard]] std::shared_ptr<const Model> block_model(Layout r, const Eigen::Vector3i& dims, double h);
/// Tissue of modulus `e_kpa`: 1000 kg/m^3, damping ratio `damping`, Poisson 0.
[[nodiscard]] Material tissue(double e_kpa, double damping = 0.1);
/// Static solves to 1e-9 mm (3000 iterations at most) on kThreads.
[[nodiscard]] StaticSolveSettings static_settings();
/// `kind` at step `dt_s` on kThreads.
[[nodiscard]] IntegratorSettings integrator(IntegratorKind kind, double dt_s);
/// The stable step a case scales its time steps from: the integrator's own, and for the
/// implicit integrator (stable at any step) that of symplectic Euler.
[[nodiscard]] double reference_step_s(const PhysicsModel& p, IntegratorKind kind);

/// Lowest and highest rest coordinate of the model's nodes along `axis`, mm.
[[nodiscard]] double rest_min(const Model& m, int axis);
[[nodiscard]] double rest_max(const Model& m, int axis);
/// Mean displacement along `axis` of `nodes`, mm.
[[nodiscard]] double mean_displacement(const SimState& s, const std::vector<int>& nodes, int axis);
/// Least-squares slope through the origin of y against x (NaN without data).
[[nodiscard]] double slope_through_origin(const std::vector<double>& x, const std::vector<double>& y);
/// Least-squares slope of y against x, with intercept (NaN for fewer than 2 points).
[[nodiscard]] double fitted_slope(const std::vector<double>& x, const std::vector<double>& y);
/// Kinetic + elastic + gravitational energy, N*mm.
[[nodiscard]] double energy(const SimState& s);
[[nodiscard]] std::string layout_name(Layout r);
/// The tissue of phantom `name` at `size` voxels of 1 mm, thresholded half-way between tissue
/// and air; `shape` (optional) receives its analytic shape.
[[nodiscard]] VoxelGrid phantom_grid(const std::string& name, int size, PhantomShape* shape = nullptr);

/// A ball pressed into the top of a block fixed at its base: the force and depth, averaged over
/// bins of 32 steps.
struct Indentation {
  std::vector<double> depth_mm, force_n;
  Eigen::Matrix3Xd final_positions;  ///< 3 x nodes at the end, mm
  std::string failure;               ///< "" when the run finished
};
/// A ball of radius `radius_mm` pressed `depth_mm` at `speed_mm_s` into the top of the model
/// (fixed at z_min), centred over (x_mm, y_mm); symplectic Euler at half its stable step.
[[nodiscard]] Indentation indent(const std::shared_ptr<const PhysicsModel>& p, double radius_mm, double depth_mm,
                                 double x_mm, double y_mm, double speed_mm_s = 10.0);

/// Whether `steps` steps of dt from random small velocities stay bounded (not stopped by the
/// runaway guard, finite, energy below 1e4 times the start).
[[nodiscard]] bool runs_stably(const std::shared_ptr<const PhysicsModel>& p, IntegratorKind kind, double dt,
                               int steps);

}  // namespace vx::cases
