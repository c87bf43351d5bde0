#pragma once
/// @file vertex_weights.h
/// Vertex weights that make an element's weighted rest spread isotropic (docs/model.md
/// section 5): the calibration's first step (physics_model.h).

#include <Eigen/Core>

namespace vx {

/// Vertex weights (mean 1, in [min_weight, max_weight], closest to 1) making the weighted
/// spread of the points (3 x n, mm) isotropic about their weighted centroid, by Gauss-Newton
/// with the bounds enforced by an active set. Where isotropy is out of reach (thin partly
/// filled elements, extra vertices on opposite faces only) the result is the bounded compromise,
/// or equal weights when those are more isotropic. *anisotropy gets the remaining
/// (max - min) / mean eigenvalue of the weighted spread.
/// dimensions = 2: the points lie in the plane z = const of their frame (a 2D element in its
/// plane's coordinates) and the spread is made isotropic in x and y only.
[[nodiscard]] Eigen::VectorXd isotropic_weights(const Eigen::Matrix3Xd& points, double min_weight,
                                                double max_weight = 4.0, double* anisotropy = nullptr,
                                                int dimensions = 3);

/// (max - min) / mean eigenvalue of a symmetric 3x3 matrix (0: isotropic); dimensions = 2: of
/// its upper-left 2x2 block.
[[nodiscard]] double spread_anisotropy(const Eigen::Matrix3d& spread, int dimensions = 3);

}  // namespace vx
