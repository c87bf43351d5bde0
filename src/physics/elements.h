#pragma once
/// @file elements.h
/// The local shape-keeping element (docs/model.md sections 2, 4 and 5, paper 2.3-2.4): rotation fit,
/// elastic forces, energy and damping relative to the element's rigid motion.
///
/// For element e with vertices i of weight w_i (material.h: weights that make the rest
/// spread isotropic; 1 for an 8-vertex cube), rest offsets R0_i from the weighted rest
/// centroid, current offsets r_i = x_i - c from the current weighted centroid c:
///   A   = sum_i w_i r_i R0_i^T                   (3x3, mm^2)
///   F   = sum_i x_i g_i^T                         consistent deformation gradient (element_gradient.h)
///   Q   = argmax_{Q in SO(3)} tr(Q^T F)          (rotational part of the polar decomposition;
///                                                 the paper's moment balance, eq. 3)
///   E   = mu V |F - Q|^2 + k/2 sum_i w_i |r_i - F R0_i|^2     elastic energy, N*mm
///   f_i = k w_i (F R0_i - r_i) + G g_i,  G = 2 mu V (Q - F) + k (A - F C0)
///                                                 elastic force, N; f_i = -dE/dx_i exactly
///                                                 because Q is optimal (envelope theorem)
/// For an 8-vertex cube F = A C0^{-1} and 2 mu V = k S / 3, and this is exactly the paper's
/// shape-keeping element: E = k/2 sum_i w_i |r_i - Q R0_i|^2, f_i = k w_i (Q R0_i - r_i).
/// The hourglass element (ElementKind::hourglass, the default; element_modes.h) adds
///   E  -= 1/2 sum_p |qm_p|^2,  qm_p = sum_i h_pi x_i,   f_i += sum_p qm_p h_pi
/// with the relief weights h_pi = sqrt(beta_p k) w_i gamma_pi of its bending (hourglass)
/// patterns gamma_p, orthogonal to the affine motions: its affine response (and everything
/// above under affine motion) is the paper's, its bending modes get linear elasticity's energy.
/// The split (affine part on the consistent F, the rest on the vertex fit) only differs where
/// an element carries its smaller neighbours' nodes, and there it makes a uniform strain an
/// equilibrium of the whole model (material.h, element_gradient.h).
/// Volume term (Poisson ratio > 0, see material.h):
///   T   = argmin_{det T = 1} |F - T|^2 (on the consistent F),  G += k_v (T - F),
///   E  += k_v/2 |F - T|^2   (k_v = 3 lambda V; one volume constraint per element, on its
///   affine part only: no non-affine motion is stiffened, hence no locking of the bending
///   modes; docs/model.md section 5, "Locking"). T from the signed singular values of F (proper
///   polar decomposition + symmetric eigen), moved to det = 1 (closest_with_determinant).
/// Damping: the element's rigid velocity at vertex i is v_c + omega x r_i with v_c the weighted
/// mean vertex velocity and omega = I^{-1} sum_i w_i r_i x (v_i - v_c),
/// I = sum_i w_i (|r_i|^2 1 - r_i r_i^T) (the weighted least-squares rigid fit of the vertex
/// velocities); f_i += c w_i (v_c + omega x r_i - v_i). It removes only deformation energy:
/// sum f_i = 0 and sum r_i x f_i = 0.
///
/// Layout: the rotation fit is in rotation_fit.h, the pass's options and counters in
/// element_pass.h, the batched (SIMD) kernel in element_batches.h; this header runs the pass.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

#include "physics/element_pass.h"
#include "physics/physics_model.h"
#include "physics/rotation_fit.h"

namespace vx {

/// Elastic (and damping) forces of every element into `entry_forces` (3 x vertex entries, N,
/// node-major: vertex entry j in column physics.entry_slot[j]), parallel over elements; rotations (one per element) are warm starts and are updated.
/// velocities may be null when options.damping is false. Per-element energies go to
/// `element_energy` (elements) when options.energy. Deterministic for any thread count.
ElementPassStats compute_element_forces(const PhysicsModel& physics, const Eigen::Matrix3Xd& positions,
                                        const Eigen::Matrix3Xd* velocities,
                                        std::vector<Eigen::Quaterniond>& rotations,
                                        Eigen::Matrix3Xd& entry_forces, std::vector<double>* element_energy,
                                        const ElementPassOptions& options, int threads,
                                        ElementPassScratch& scratch);

/// The force on one node: the sum of its vertex entries' forces (its contiguous slots of the
/// node-major entry buffer), in entry order.
[[nodiscard]] inline Eigen::Vector3d gather_node_force(const PhysicsModel& physics,
                                                       const Eigen::Matrix3Xd& entry_forces, int node) {
  Eigen::Vector3d f = Eigen::Vector3d::Zero();
  for (int j = physics.node_entry_offsets[std::size_t(node)]; j < physics.node_entry_offsets[std::size_t(node) + 1]; ++j)
    f += entry_forces.col(j);
  return f;
}

/// Sums entry forces into node forces (3 x nodes, N); parallel over nodes, deterministic.
void gather_node_forces(const PhysicsModel& physics, const Eigen::Matrix3Xd& entry_forces,
                        Eigen::Matrix3Xd& node_forces, int threads);

/// The constant quadratic part of one element's elastic energy, as an n x n matrix acting on
/// each coordinate alike (n = the element's vertices):
///   K_ij = (2 mu V + k_v) g_i . g_j + k sum_l w_l P_li P_lj,  P_lj = delta_lj - w_j / W - R0_l . g_j
/// (the affine part mu V |F|^2, the volume term's k_v/2 |F|^2 and the non-affine part
/// k/2 sum_l w_l |r_l - F R0_l|^2). It is
/// the projective-dynamics system matrix of the element and the Hessian at rest less the
/// rotation's curvature; rows sum to zero (translations cost nothing). The hourglass element
/// (element_modes.h) subtracts its relief sum_p h_p h_p^T, unless `relieved` is false (the
/// paper's matrix of the same element: an upper bound of it, for the stable-step estimates).
/// `volume` false leaves the volume term out (the local contact model's compliance,
/// local_compliance.h, replaces it by a factor in nu).
void element_elastic_matrix(const PhysicsModel& physics, int element, Eigen::MatrixXd& k, bool relieved = true,
                            bool volume = true);

/// Elastic energy of one element at `positions` with rotation warm start `q` (updated), N*mm.
/// Includes the volume term. For tests and diagnostics (not the hot path).
[[nodiscard]] double element_energy(const PhysicsModel& physics, int element, const Eigen::Matrix3Xd& positions,
                                    Eigen::Quaterniond& q, const RotationFitSettings& settings);

}  // namespace vx
