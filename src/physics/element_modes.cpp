#include "physics/element_modes.h"

#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <cmath>

namespace vx {

ModeWeights bending_patterns(const Eigen::Matrix3Xd& local, const Eigen::VectorXd& w, int dimensions) {
  const int n = int(local.cols());
  ModeWeights p = ModeWeights::Zero(kBendingModes, n);
  if (n < (dimensions == 2 ? 4 : 8)) return p;
  // box coordinates in [-1, 1]
  const Eigen::Vector3d lo = local.rowwise().minCoeff(), hi = local.rowwise().maxCoeff();
  const Eigen::Vector3d centre = 0.5 * (lo + hi), half = 0.5 * (hi - lo);
  const double big = half.maxCoeff();
  if (!(big > 0)) return p;
  Eigen::Matrix3Xd xi = Eigen::Matrix3Xd::Zero(3, n);
  for (int d = 0; d < 3; ++d)
    if (half(d) > 1e-9 * big) xi.row(d) = (local.row(d).array() - centre(d)) / half(d);
  // the patterns yz, zx, xy, xyz
  p.row(0) = xi.row(1).cwiseProduct(xi.row(2));
  p.row(1) = xi.row(2).cwiseProduct(xi.row(0));
  p.row(2) = xi.row(0).cwiseProduct(xi.row(1));
  p.row(3) = p.row(0).cwiseProduct(xi.row(0));
  // w-orthogonal to the affine functions 1, x, y, z (least squares, any rank)
  Eigen::Matrix<double, 4, Eigen::Dynamic> b(4, n);
  b.row(0).setOnes();
  b.bottomRows<3>() = xi;
  const Eigen::Matrix4d bwb = b * w.asDiagonal() * b.transpose();
  const Eigen::Matrix4d pwb = p * w.asDiagonal() * b.transpose();
  const Eigen::CompleteOrthogonalDecomposition<Eigen::Matrix4d> cod(bwb);
  const Eigen::Matrix4d coef = cod.solve(pwb.transpose()).transpose();
  p -= coef * b;
  // w-orthonormal among themselves: G^{-1/2} p (symmetric: each stays closest to its pattern);
  // directions the vertices cannot show (tiny eigenvalues) are dropped
  const Eigen::Matrix4d g = p * w.asDiagonal() * p.transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix4d> eig(g);
  const double floor = 1e-8 * w.sum();
  Eigen::Vector4d inv_sqrt;
  for (int k = 0; k < 4; ++k) inv_sqrt(k) = eig.eigenvalues()(k) > floor ? 1.0 / std::sqrt(eig.eigenvalues()(k)) : 0.0;
  const Eigen::Matrix4d g_inv_sqrt = eig.eigenvectors() * inv_sqrt.asDiagonal() * eig.eigenvectors().transpose();
  return g_inv_sqrt * p;
}

double calibrated_bending_relief(const Eigen::Matrix3Xd& local, const Eigen::VectorXd& w, const Eigen::Matrix3Xd& g,
                                 const ModeWeights& patterns, double k, double mu, double volume, double xyz_relief,
                                 int dimensions, double poisson_ratio) {
  const int axes = dimensions == 2 ? 2 : 3;
  const int n = int(local.cols());
  const Eigen::Vector3d lo = local.rowwise().minCoeff(), hi = local.rowwise().maxCoeff();
  const Eigen::Vector3d centre = 0.5 * (lo + hi), half = 0.5 * (hi - lo);
  const Eigen::MatrixXd wp = patterns * w.asDiagonal();  // sum_i w_i gamma_pi x_i: the modes' amplitudes
  double have = 0, want = 0, relievable = 0;
  for (int a = 0; a < axes; ++a)
    for (int c = 0; c < axes; ++c) {
      if (a == c) continue;
      // pure bending in the a-c plane about the box centre (unit curvature)
      Eigen::Matrix3Xd u = Eigen::Matrix3Xd::Zero(3, n);
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d x = local.col(i) - centre;
        u(a, i) = -x(a) * x(c);
        u(c, i) = 0.5 * x(a) * x(a);
      }
      // the element's energy of it, linearised: mu V |sym F|^2 + k/2 sum w |d|^2 - the xyz relief
      const Eigen::Matrix3d f = u * g.transpose();
      const Eigen::Matrix3d eps = 0.5 * (f + f.transpose());
      const Eigen::Vector3d ubar = u * w / w.sum();
      double penalty = 0;
      for (int i = 0; i < n; ++i) penalty += w(i) * (u.col(i) - ubar - f * local.col(i)).squaredNorm();
      const Eigen::MatrixXd q = u * wp.transpose();  // 3 x modes
      have += mu * volume * eps.squaredNorm() + 0.5 * k * penalty - 0.5 * xyz_relief * k * q.col(3).squaredNorm();
      relievable += 0.5 * k * q.leftCols<3>().squaredNorm();
      // linear elasticity: strain eps_aa = -x_c, energy (E/2) int x_c^2 dV, E = 2 mu (1 + nu)
      // (at Poisson 0 the shear part mu int x_c^2 dV)
      want += (1.0 + poisson_ratio) * mu * volume * half(c) * half(c) / 3.0;
    }
  return relievable > 0 ? (have - want) / relievable : 0.0;
}

}  // namespace vx
