#include "physics/vertex_weights.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace vx {

double spread_anisotropy(const Eigen::Matrix3d& c, int dimensions) {
  if (dimensions == 2) {
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(c.topLeftCorner<2, 2>());
    const Eigen::Vector2d ev = eig.eigenvalues();
    const double mean = ev.sum() / 2.0;
    return mean > 0 ? (ev.maxCoeff() - ev.minCoeff()) / mean : 0.0;
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(c);
  const Eigen::Vector3d ev = eig.eigenvalues();
  const double mean = ev.sum() / 3.0;
  return mean > 0 ? (ev.maxCoeff() - ev.minCoeff()) / mean : 0.0;
}

Eigen::VectorXd isotropic_weights(const Eigen::Matrix3Xd& points, double min_weight, double max_weight,
                                  double* anisotropy, int dimensions) {
  const int n = int(points.cols());
  const bool flat = dimensions == 2;
  // constraints: sum w = n and the spread's off-diagonals and diagonal differences (3D: xy, xz,
  // yz, xx - yy, yy - zz; 2D: xy, xx - yy, the other rows zero: their multipliers stay 0)
  Eigen::VectorXd w = Eigen::VectorXd::Ones(n);
  // centred and scaled for conditioning
  Eigen::Matrix3Xd x = points.colwise() - points.rowwise().mean();
  const double scale = std::sqrt(x.colwise().squaredNorm().mean());
  if (scale > 0) x /= scale;
  std::vector<std::uint8_t> at_bound(std::size_t(n), 0);
  Eigen::Matrix3d central = Eigen::Matrix3d::Identity();
  const auto moments = [&](Eigen::Vector3d& c) {
    const double s0 = w.sum();
    c = x * w / s0;
    Eigen::Matrix3d m = Eigen::Matrix3d::Zero();
    for (int i = 0; i < n; ++i) m += w(i) * (x.col(i) - c) * (x.col(i) - c).transpose();
    return m;
  };
  for (int outer = 0; outer < n; ++outer) {
    for (int it = 0; it < 30; ++it) {
      // constraints: sum w = n, off-diagonals of the central spread 0, its diagonal equal
      Eigen::Vector3d c;
      central = moments(c);
      Eigen::Matrix<double, 6, 1> g;
      if (flat)
        g << w.sum() - n, central(0, 1), 0.0, 0.0, central(0, 0) - central(1, 1), 0.0;
      else
        g << w.sum() - n, central(0, 1), central(0, 2), central(1, 2), central(0, 0) - central(1, 1),
            central(1, 1) - central(2, 2);
      if (g.cwiseAbs().maxCoeff() < 1e-13) break;
      // Jacobian: d(central)/dw_i = (x_i - c)(x_i - c)^T; entries at the bound do not move
      Eigen::Matrix<double, 6, Eigen::Dynamic> jac(6, n);
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d d = x.col(i) - c;
        if (flat)
          jac.col(i) << 1.0, d.x() * d.y(), 0.0, 0.0, d.x() * d.x() - d.y() * d.y(), 0.0;
        else
          jac.col(i) << 1.0, d.x() * d.y(), d.x() * d.z(), d.y() * d.z(), d.x() * d.x() - d.y() * d.y(),
              d.y() * d.y() - d.z() * d.z();
        if (at_bound[std::size_t(i)]) jac.col(i).setZero();
      }
      // least change of w towards 1 that zeroes the linearised constraints
      Eigen::VectorXd u = w - Eigen::VectorXd::Ones(n);
      for (int i = 0; i < n; ++i)
        if (at_bound[std::size_t(i)]) u(i) = 0;
      Eigen::Matrix<double, 6, 6> jj = jac * jac.transpose();
      jj.diagonal().array() += 1e-12 * (jj.trace() + 1.0);
      const Eigen::Matrix<double, 6, 1> lambda = jj.ldlt().solve(jac * u - g);
      Eigen::VectorXd delta = -u + jac.transpose() * lambda;
      for (int i = 0; i < n; ++i)
        if (at_bound[std::size_t(i)]) delta(i) = 0;
      if (!delta.allFinite()) break;
      w += delta;
      if (delta.cwiseAbs().maxCoeff() < 1e-12) break;  // stalled: the bounded compromise
    }
    // weights outside the bounds: hold them at the bound and solve again
    bool changed = false;
    for (int i = 0; i < n; ++i)
      if (w(i) < min_weight || w(i) > max_weight) {
        w(i) = std::clamp(w(i), min_weight, max_weight);
        at_bound[std::size_t(i)] = 1;
        changed = true;
      }
    if (!changed) break;
  }
  // keep the result only where it is valid and more isotropic than equal weights
  Eigen::Vector3d c;
  double aniso = std::numeric_limits<double>::infinity();
  if (w.allFinite() && (w.array() >= min_weight - 1e-9).all() && (w.array() <= max_weight + 1e-9).all()) {
    w *= n / w.sum();
    aniso = spread_anisotropy(moments(c), dimensions);
  }
  const Eigen::VectorXd weighted = w;
  w.setOnes();
  const double plain = spread_anisotropy(moments(c), dimensions);
  if (aniso < plain) {
    w = weighted;
  } else {
    aniso = plain;
  }
  if (anisotropy) *anisotropy = aniso;
  return w;
}

}  // namespace vx
