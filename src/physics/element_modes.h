#pragma once
/// @file element_modes.h
/// The bending (hourglass) modes of an element and their calibrated relief: what the
/// `hourglass` element (ElementKind, physics_model.h; elements.h) takes off the paper's
/// non-affine penalty so that large elements bend like linear elasticity (docs/model.md
/// section 5, "Bending: the hourglass element"; measured: docs/verify.md, docs/bench.md).
///
/// Why. The paper's element holds every non-affine motion of its vertices with the penalty
/// k/2 sum_i w_i |r_i - F R0_i|^2. An 8-vertex cube of edge h has 12 non-affine modes: the
/// patterns yz, zx, xy and xyz of the vertex signs, each in 3 components. Pure bending
/// (u_x = -kappa x z, u_z = kappa x^2 / 2, Poisson 0) moves the corners in the xz pattern only
/// (its u_z is a translation at the corners), with amplitude a = kappa h^2 / 4. Linear
/// elasticity gives it E kappa^2 h^5 / 24 = (2/3) E h a^2; the penalty gives k/2 8 a^2 =
/// 2 E h a^2 (k = E h / 2): three times too much, so a body whose stress reaches large elements
/// reads too stiff (a fully integrated trilinear hexahedron gives 1.5 times). The twist of the
/// cube (u_x = -theta y z, u_y = theta x z) gets 7.1 times Saint-Venant's energy.
///
/// The relief. Per element, the four patterns are sampled at its vertices in its own box
/// coordinates (the grid's axes; an element with extra face vertices samples them there too),
/// made w-orthogonal to the affine functions (1, x, y, z) and w-orthonormal among themselves:
/// gamma_pi. The element's energy gets
///   E_relief = -1/2 sum_p |sum_i h_pi x_i|^2,   h_pi = sqrt(beta_p k) w_i gamma_pi,
/// which takes the fraction beta_p of the penalty off mode p and leaves every other
/// non-affine mode (an element's extra face vertices moving against its corners) at k.
/// Because gamma_p is orthogonal to the affine functions, sum_i h_pi x_i vanishes under every
/// affine motion: no energy and no force under rigid motion, the patch test and the affine
/// response (E = 2k/h) unchanged, and E_relief is rotation invariant (|R q| = |q|). With
/// beta_p < 1 the element stays positive definite on its non-affine modes (Bessel: the relief
/// is at most beta_p times the penalty of the same motion). E_relief is a constant quadratic
/// form, so the projective-dynamics matrix just loses sum_p h_p h_p^T (elements.h,
/// element_elastic_matrix) and the local step is unchanged.
///
/// Calibration. beta of the three bilinear patterns is set per element so that the six pure
/// bending fields of its box (u_a = -kappa x_a x_c, u_c = kappa x_a^2 / 2, a != c) get, summed,
/// exactly linear elasticity's energy mu kappa^2 V h_c^2 / 12 (the model's shear part; the
/// volume term is separate): 2/3 on an 8-vertex cube, 0.70-0.75 on elements with extra face
/// vertices (whose x^2 part of the bending field shows at the face vertices and keeps the full
/// penalty), clamped to [0, 0.95]. beta of the xyz pattern is 7/9: the energy of the trilinear
/// field x y z of a cube (8/9 mu h a^2 against the penalty's 4 mu h a^2). On a cube every
/// single mode then has the energy of the incompatible-modes hexahedron (Wilson-Taylor); only
/// the coupling of the three twist-type components (u_x in yz, u_y in zx, u_z in xy), which
/// needs the element's rotation, is left out: the cube's twist gets 2.4 times Saint-Venant's
/// energy (7.1 before), its warp u = grad(xyz) half its energy.

#include <Eigen/Core>

namespace vx {

/// Modes per element: the bilinear patterns yz, zx, xy and the trilinear xyz.
inline constexpr int kBendingModes = 4;

/// kBendingModes x vertices.
using ModeWeights = Eigen::Matrix<double, kBendingModes, Eigen::Dynamic>;

/// The w-orthonormal bending patterns gamma_pi of one element: `local` are its vertices' rest
/// offsets in the element's axes (3 x n, mm; any origin), `w` their weights. Rows of patterns the
/// vertex set cannot show (fewer than 8 vertices, a flat element) are zero. dimensions = 2: a
/// slice element (z = const in `local`, at least 4 vertices): only the xy pattern is non-zero.
[[nodiscard]] ModeWeights bending_patterns(const Eigen::Matrix3Xd& local, const Eigen::VectorXd& w,
                                           int dimensions = 3);

/// The fraction of the penalty to take off the bilinear patterns so that the six pure-bending
/// fields of the element's box get linear elasticity's energy (see above): `local` rest offsets
/// about the weighted centroid in the element's axes, `gradient` the consistent gradient
/// weights in the same axes (element_gradient.h), `patterns` from bending_patterns, k the
/// penalty (N/mm), mu the shear modulus (N/mm^2), volume in mm^3, xyz_relief the fraction
/// taken off the xyz pattern. Not clamped (the caller clamps). dimensions = 2: the two in-plane
/// bending fields of a slice element (plane stress, the same shear energy mu kappa^2 V h_c^2 / 12).
/// poisson_ratio > 0: the target is the bending energy of uniaxial stress, (1 + nu) times the
/// shear part (E = 2 mu (1 + nu)): the volume term acts on the element's mean dilatation only
/// and does not see a bending field's (zero-mean) dilatation, which the material's lateral
/// contraction would cancel (docs/model.md section 5, "Locking").
[[nodiscard]] double calibrated_bending_relief(const Eigen::Matrix3Xd& local, const Eigen::VectorXd& w,
                                               const Eigen::Matrix3Xd& gradient, const ModeWeights& patterns,
                                               double k, double mu, double volume, double xyz_relief,
                                               int dimensions = 3, double poisson_ratio = 0.0);

}  // namespace vx
