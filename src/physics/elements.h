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
#include <vector>

#include "base/parallel.h"
#include "physics/element_batch_layout.h"
#include "physics/physics_model.h"

namespace vx {

/// How hard the rotation fit works per element and step.
struct RotationFitSettings {
  int max_iterations{8};    ///< per element and call; the warm start carries work to the next step
  double tolerance{1e-9};   ///< on |g| / |A|_F (about the remaining angle, rad); a Newton step
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
[[nodiscard]] Eigen::Matrix3d closest_with_determinant(const Eigen::Matrix3d& b, double det,
                                                       Eigen::Quaterniond& q,
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

/// Which implementation of the element pass runs; both compute the same forces.
enum class ElementKernel {
  batched,    ///< the fastest: packed's arithmetic on kBatchLanes elements at once (element_batches.h);
              ///< without energy and volume term, and with simd automatic only on a CPU with AVX2
              ///< (else packed runs)
  packed,     ///< packed per-entry constants (PackedEntry), each force written once
  reference,  ///< the plain kernel, one loop per term over separate arrays (for tests and benchmarks)
};

/// "batched", "packed" or "reference".
[[nodiscard]] const char* to_string(ElementKernel k);

/// What an element pass should compute.
struct ElementPassOptions {
  bool damping{true};    ///< add damping (needs velocities)
  bool energy{false};    ///< write per-element elastic energy
  RotationFitSettings rotation;
  ElementKernel kernel{ElementKernel::batched};
  SimdLevel simd{SimdLevel::automatic};  ///< the batched kernel's instruction set (element_batches.h)
};

/// Counters of one element pass (summed over elements).
struct ElementPassStats {
  std::int64_t inverted{0};             ///< elements with det(A) <= 0 (inverted or flat)
  std::int64_t unconverged{0};          ///< elements whose rotation fit did not reach the tolerance
  std::int64_t rotation_iterations{0};  ///< total fit iterations
  std::int64_t non_finite{0};           ///< elements with a NaN/Inf input or fit
  double elastic_energy{0.0};           ///< N*mm (only with options.energy)
  void add(const ElementPassStats& o);
};

/// Scratch of an element pass, allocated once (per-chunk partial counters).
struct ElementPassScratch {
  std::vector<ElementPassStats> chunks;  ///< element_pass_slots(elements) of them
};

/// Element grain of the parallel passes (elements per chunk).
inline constexpr std::int64_t kElementGrain = 256;
/// Node grain of the parallel passes (nodes per chunk).
inline constexpr std::int64_t kNodeGrain = 1024;

/// Partial counters of an element pass over `elements`: one per element window (chunk of
/// kElementGrain), and one for the elements the batched kernel leaves to the packed one.
[[nodiscard]] inline std::int64_t element_pass_slots(std::int64_t elements) {
  return chunk_count(elements, kElementGrain) + 1;
}

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
