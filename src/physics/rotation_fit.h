#pragma once
/// @file rotation_fit.h
/// The element's rotation fit and the volume term's closest matrix (elements.h: the element
/// they serve; docs/model.md sections 2 and 5): Q = argmax_{Q in SO(3)} tr(Q^T F) (the paper's
/// moment balance, eq. 3), T = argmin_{det T = 1} |F - T|^2, and their 2D forms in a slice's
/// plane. Used by every kernel of the element pass (elements.cpp, element_batches.cpp).
///
/// Rotation fit: warm-started Newton iteration on the rotation (the gradient
/// g = sum_c Q_c x A_c is the paper's moment balance; Hessian tr(P) 1 - sym(P), P = A Q^T),
/// falling back to the scaled-gradient step of Mueller et al. 2016 ("A robust method to
/// extract the rotational part of deformations") where the Hessian is not positive definite,
/// with a monotone line search. The result is a unit quaternion, hence always a proper
/// rotation; for inverted elements it converges to U diag(1, 1, det(U V^T)) V^T, for flat
/// ones to the unique best rotation, for a collapsed element (A = 0) it keeps the warm start,
/// so its force k Q R0_i pushes it back to a proper shape.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>

#include "physics/physics_model.h"

namespace vx {

/// How hard the rotation fit works per element and step.
struct RotationFitSettings {
  int max_iterations{8};   ///< per element and call; the warm start carries work to the next step
  double tolerance{1e-9};  ///< on |g| / |A|_F (about the remaining angle, rad); a Newton step
                           ///< shorter than sqrt(tolerance) ends the fit (quadratic convergence)
};

/// Fits the rotation maximising tr(Q^T a), starting from (and writing back) `q`.
/// Returns the iterations done; sets *converged when the tolerance was reached and
/// *rotation to the rotation matrix of the result.
int fit_rotation(const Eigen::Matrix3d& a, Eigen::Quaterniond& q, const RotationFitSettings& settings,
                 bool* converged = nullptr, Eigen::Matrix3d* rotation = nullptr);

/// Reference: the same rotation from a 3x3 SVD with the determinant fixed (slow; for tests).
[[nodiscard]] Eigen::Matrix3d optimal_rotation_svd(const Eigen::Matrix3d& a);

/// The closest matrix to `b` (Frobenius) with determinant `det` > 0, starting the polar
/// rotation fit from `q` (written back). Used by the volume term.
[[nodiscard]] Eigen::Matrix3d closest_with_determinant(const Eigen::Matrix3d& b, double det, Eigen::Quaterniond& q,
                                                       const RotationFitSettings& settings);

/// 2D (a slice model, docs/model.md section 12.2): the rotation about the normal of `frame`
/// (columns: two in-plane axes, the normal; orthonormal, right-handed) maximising tr(Q^T a)
/// over the in-plane block a2 = E^T a E (E: the first two columns), in closed form:
/// theta = atan2(a2_10 - a2_01, a2_00 + a2_11), so a proper rotation even for an inverted a2.
/// q gets the rotation about the normal by theta (kept when a2 has no rotational part: a
/// collapsed element). *rotation gets E Q2 E^T, the in-plane rotation with a zero normal block
/// (a slice element has no extent along the normal, so |F - Q|^2 stays the in-plane distance).
/// Returns 1 (one evaluation); *converged is set to true.
int fit_plane_rotation(const Eigen::Matrix3d& a, const Eigen::Matrix3d& frame, Eigen::Quaterniond& q,
                       bool* converged = nullptr, Eigen::Matrix3d* rotation = nullptr);

/// 2D: the closest matrix to `b` in the plane of `frame` (its in-plane block) with in-plane
/// determinant `det` > 0, as E X2 E^T (zero normal block).
[[nodiscard]] Eigen::Matrix3d closest_with_determinant_in_plane(const Eigen::Matrix3d& b, double det,
                                                                const Eigen::Matrix3d& frame);

/// The element's rotation fit for `physics`: fit_rotation for a volume model, fit_plane_rotation
/// in the slice plane for a 2D model.
int fit_element_rotation(const PhysicsModel& physics, const Eigen::Matrix3d& a, Eigen::Quaterniond& q,
                         const RotationFitSettings& settings, bool* converged = nullptr,
                         Eigen::Matrix3d* rotation = nullptr);

/// The volume term's closest matrix for `physics`: closest_with_determinant for a volume
/// model, closest_with_determinant_in_plane (the area kept) for a 2D model.
[[nodiscard]] Eigen::Matrix3d element_closest_with_determinant(const PhysicsModel& physics, const Eigen::Matrix3d& b,
                                                               double det, Eigen::Quaterniond& q,
                                                               const RotationFitSettings& settings);

/// Calls fn(s, F_s, T_s) for each volume point s of element e (PhysicsModel::volume_point_offsets):
/// F_s = fg + sum_t y_t delta_t^T (fg: the element's consistent F, y: positions in `xs`, 3 x
/// nodes, relative to the element's first vertex) and T_s its closest matrix with det 1 (the
/// projection warm-started from `q`, not written back).
template <typename Fn>
void for_each_volume_point(const PhysicsModel& phys, const double* xs, int e, const Eigen::Matrix3d& fg,
                           const Eigen::Quaterniond& q, const RotationFitSettings& fit, Fn&& fn) {
  const Model& m = *phys.model;
  const double* x0 = xs + 3 * std::int64_t(m.element_vertices[std::size_t(m.element_offsets[std::size_t(e)])]);
  for (int s = phys.volume_point_offsets[std::size_t(e)]; s < phys.volume_point_offsets[std::size_t(e) + 1]; ++s) {
    Eigen::Matrix3d fs = fg;
    for (int t = phys.volume_point_term_offsets[std::size_t(s)]; t < phys.volume_point_term_offsets[std::size_t(s) + 1];
         ++t) {
      const double* xp = xs + 3 * std::int64_t(m.element_vertices[std::size_t(phys.volume_term_entry[std::size_t(t)])]);
      fs.noalias() +=
          Eigen::Vector3d(xp[0] - x0[0], xp[1] - x0[1], xp[2] - x0[2]) * phys.volume_term_delta.col(t).transpose();
    }
    Eigen::Quaterniond qs = q;
    const Eigen::Matrix3d ts = closest_with_determinant(fs, 1.0, qs, fit);
    fn(s, fs, ts);
  }
}

/// det F of an element's deformation gradient (2D: of its in-plane block); <= 0: inverted or flat.
[[nodiscard]] double element_determinant(const PhysicsModel& physics, const Eigen::Matrix3d& f);

}  // namespace vx
