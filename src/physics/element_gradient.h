#pragma once
/// @file element_gradient.h
/// The consistent (boundary-integral) deformation gradient of each element (docs/model.md
/// section 4): the operator
/// F = sum_i x_i g_i^T that is exact for every affine motion and makes the elastic forces of
/// neighbouring elements cancel at their shared nodes under a uniform strain (the patch test).
///
/// Why it is needed. The paper's element fits its rotation to A = sum_i w_i r_i R0_i^T, i.e. it
/// measures the deformation by the least-squares affine fit F_LS = A C0^{-1}. Under a uniform
/// strain eps each element then pushes its vertex i with k w_i eps R0_i. For an 8-vertex cube
/// this equals the traction of the stress 2 mu eps on the vertex's share of the cube's faces,
/// so shared nodes balance exactly. An element of the gradational layout, however, also carries
/// its smaller neighbours' nodes on its faces; its pushes k w_i eps R0_i, which point from its
/// centroid, no longer match its neighbours' (a corner of a level-L element pushes about four
/// times harder than the corner of the level-(L-1) element it replaces). The uniform state is
/// then no equilibrium, the model relaxes into a softer one, and a 32^3 cube under plate
/// compression reads 11 % soft (6.7 % at 16^3, growing with the number of levels).
///
/// The remedy is the divergence theorem: for any region V with boundary dV,
///   integral_V grad(u) dV = integral_dV u n^T dA,
/// so with u interpolated on each boundary face from the element's vertices,
///   F = (1/V) sum_i x_i a_i^T,   g_i = a_i / V,
/// where a_i (mm^2) is vertex i's share of the element's outward boundary area vector. Each
/// boundary voxel face of the element is shared bilinearly among the corners of the smallest
/// aligned lattice square that contains it and whose four corners are all mesh nodes. That
/// square depends only on the nodes present on the face, and two elements sharing a face hold
/// the same nodes there (every node on an element's closed region is its vertex), so the two
/// sides give opposite shares at every shared node: the interior balance is exact. For an
/// 8-vertex cube g_i = C0^{-1} w_i R0_i, i.e. F equals the paper's fit there.
///
/// A 2D (slice) model shares each boundary pixel edge linearly between the element's nearest
/// vertices on its line (g_i lies in the slice plane; docs/model.md section 12.2).
///
/// Checks (tests/core/element_gradient_test.cpp): sum_i a_i = 0 and sum_i X_i a_i^T = V I per
/// element; summed over elements the shares vanish at interior nodes and equal the tissue's
/// boundary area vector at surface nodes.

#include <Eigen/Core>
#include <cstdint>

#include "model/model.h"

namespace vx {

/// Per vertex entry, the gradient weights g_i (1/mm) of the element's consistent deformation
/// gradient, F = sum_i x_i g_i^T.
struct ElementGradients {
  Eigen::Matrix3Xd entry_gradient;  ///< 3 x vertex entries, 1/mm
  /// Elements where some boundary voxel face found no enclosing square of mesh nodes (a model
  /// edited by hand); those elements keep the least-squares fit (their g is left zero and the
  /// caller fills it in).
  std::int64_t fallback_elements{0};
  std::vector<std::uint8_t> element_fallback;  ///< elements: 1 where the fallback applies
  /// Voxel faces whose nodes form no rectangle around them (non-conforming patches between
  /// partly filled elements, on curved surfaces): shared by least-norm linear-exact weights
  /// over the element's vertices in the plane; exact per element, not always equal and
  /// opposite to the neighbour's shares (see the test for how much).
  std::vector<std::int32_t> element_irregular_faces;  ///< elements: such voxel faces
  std::int64_t irregular_faces{0};                    ///< in all
};

/// Computes the consistent gradient weights of every element of a finalized model.
[[nodiscard]] ElementGradients compute_element_gradients(const Model& model, int threads = 0);

/// Boundary area vector (mm^2, outward) of the tissue at every node: the sum over the tissue's
/// boundary voxel faces of a quarter of each face's area vector at each of its corners (for the
/// checks). Nodes not on the boundary get zero.
[[nodiscard]] Eigen::Matrix3Xd boundary_area_vectors(const Model& model);

}  // namespace vx
