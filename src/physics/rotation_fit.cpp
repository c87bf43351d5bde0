#include "physics/rotation_fit.h"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>

namespace vx {

namespace {

/// q rotated by the small rotation vector theta (applied after q), first order and normalised:
/// exact direction, angle 2 atan(|theta|/2); no trigonometry.
Eigen::Quaterniond rotate_by(const Eigen::Quaterniond& q, const Eigen::Vector3d& theta) {
  const Eigen::Quaterniond dq(0.0, 0.5 * theta.x(), 0.5 * theta.y(), 0.5 * theta.z());
  Eigen::Quaterniond r = dq * q;
  r.coeffs() += q.coeffs();
  r.normalize();
  return r;
}

/// The closest point x to `s0` on the surface x_1 ... x_N = 1 (N = 2, 3; the singular values
/// of the volume term's closest matrix, in units where det = 1), by Newton on the KKT system
/// x_i - s0_i = lambda prod_{j != i} x_j, prod x = 1, started from the scaled (or
/// sign-repaired) values, which already satisfy the constraint. Returns a point on the positive
/// branch that is a constrained minimum, else that start.
template <int N>
Eigen::Matrix<double, N, 1> closest_on_unit_product(const Eigen::Matrix<double, N, 1>& s0) {
  using Vec = Eigen::Matrix<double, N, 1>;
  const auto root = [](double v) { return N == 3 ? std::cbrt(v) : std::sqrt(v); };
  const double top = std::max(s0.cwiseAbs().maxCoeff(), 1e-3);
  Vec start = s0.cwiseMax(0.1 * top);
  start /= root(start.prod());
  Vec x = start;
  double lambda = 0;
  bool ok = false;
  for (int it = 0; it < 30; ++it) {
    Vec pr;  // prod_{j != i} x_j
    if constexpr (N == 3)
      pr << x(1) * x(2), x(0) * x(2), x(0) * x(1);
    else
      pr << x(1), x(0);
    Eigen::Matrix<double, N + 1, 1> r;
    r.template head<N>() = x - s0 - lambda * pr;
    r(N) = x.prod() - 1.0;
    if (r.cwiseAbs().maxCoeff() < 1e-14) {
      ok = true;
      break;
    }
    Eigen::Matrix<double, N + 1, N + 1> jac = Eigen::Matrix<double, N + 1, N + 1>::Zero();
    for (int i = 0; i < N; ++i)
      for (int j = 0; j < N; ++j)  // 1 on the diagonal, -lambda prod_{k != i, j} x_k off it
        jac(i, j) = i == j ? 1.0 : -lambda * (N == 3 ? x(3 - i - j) : 1.0);
    jac.template block<N, 1>(0, N) = -pr;
    jac.template block<1, N>(N, 0) = pr.transpose();
    const Eigen::Matrix<double, N + 1, 1> step = jac.fullPivLu().solve(-r);
    if (!step.allFinite()) break;
    x += step.template head<N>();
    lambda += step(N);
  }
  if (!ok || (x.array() <= 0).any() || (x - s0).squaredNorm() > (start - s0).squaredNorm()) x = start;
  return x;
}

}  // namespace

int fit_rotation(const Eigen::Matrix3d& a, Eigen::Quaterniond& q, const RotationFitSettings& settings, bool* converged,
                 Eigen::Matrix3d* rotation) {
  // scale out the size: thresholds are relative
  const double scale2 = a.squaredNorm();
  const auto finish = [&](bool ok, int it) {
    if (converged) *converged = ok;
    if (rotation) *rotation = q.toRotationMatrix();
    return it;
  };
  if (!std::isfinite(scale2)) return finish(false, 0);
  if (scale2 < 1e-300) return finish(true, 0);  // collapsed to a point: every rotation fits; keep the warm start
  const Eigen::Matrix3d an = a * (1.0 / std::sqrt(scale2));
  const double tol2 = settings.tolerance * settings.tolerance;
  // from here on r is always q's rotation matrix: the exits hand it out instead of recomputing it
  Eigen::Matrix3d r = q.toRotationMatrix();
  const auto done = [&](int it) {
    if (converged) *converged = true;
    if (rotation) *rotation = r;
    return it;
  };
  Eigen::Matrix3d p = an * r.transpose();
  double f = p.trace();
  int it = 0;
  for (; it < settings.max_iterations; ++it) {
    // gradient of tr(Q^T A) over rotations applied after Q: the moment imbalance
    const Eigen::Vector3d g(p(2, 1) - p(1, 2), p(0, 2) - p(2, 0), p(1, 0) - p(0, 1));
    // Hessian (negated): h = tr(P) 1 - sym(P); its cofactors give the Sylvester test and the
    // Newton step at once
    const double h00 = f - p(0, 0), h11 = f - p(1, 1), h22 = f - p(2, 2);
    const double h01 = -0.5 * (p(0, 1) + p(1, 0)), h02 = -0.5 * (p(0, 2) + p(2, 0)), h12 = -0.5 * (p(1, 2) + p(2, 1));
    const double c00 = h11 * h22 - h12 * h12, c01 = h02 * h12 - h01 * h22, c02 = h01 * h12 - h02 * h11;
    const double det = h00 * c00 + h01 * c01 + h02 * c02;
    const bool pd = h00 > 1e-6 && h00 * h11 - h01 * h01 > 1e-12 && det > 1e-18;
    if (g.squaredNorm() <= tol2) {
      if (pd) return done(it);  // a strict maximum
      Eigen::Matrix3d h;
      h << h00, h01, h02, h01, h11, h12, h02, h12, h22;
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
      eig.computeDirect(h);
      if (eig.eigenvalues()(0) >= -1e-9) return done(it);  // flat direction of a degenerate A: a maximum too
      // a saddle or minimum of the trace: half a revolution about the worst axis gains
      // 2 |u^T h u| exactly
      const Eigen::Vector3d u = eig.eigenvectors().col(0).normalized();
      q = Eigen::Quaterniond(0.0, u.x(), u.y(), u.z()) * q;
      q.normalize();
      r = q.toRotationMatrix();
      p = an * r.transpose();
      f = p.trace();
      continue;
    }
    // Newton where the Hessian is positive definite (quadratic convergence near the optimum)
    if (pd) {
      const double c11 = h00 * h22 - h02 * h02, c12 = h01 * h02 - h00 * h12, c22 = h00 * h11 - h01 * h01;
      Eigen::Vector3d theta(c00 * g.x() + c01 * g.y() + c02 * g.z(), c01 * g.x() + c11 * g.y() + c12 * g.z(),
                            c02 * g.x() + c12 * g.y() + c22 * g.z());
      theta *= 1.0 / det;
      const double len2 = theta.squaredNorm();
      if (len2 > 1.0) theta *= 1.0 / std::sqrt(len2);  // at most about one radian per iteration
      const Eigen::Quaterniond qn = rotate_by(q, theta);
      const Eigen::Matrix3d rn = qn.toRotationMatrix();
      // a small Newton step leaves an error of order |theta|^2: done without re-evaluating
      if (len2 <= settings.tolerance) {
        q = qn;
        if (rotation) *rotation = rn;
        if (converged) *converged = true;
        return it + 1;
      }
      const Eigen::Matrix3d pn = an * rn.transpose();
      const double fn = pn.trace();
      if (fn >= f - 1e-13) {  // an increase, up to rounding of the trace
        q = qn;
        r = rn;
        p = pn;
        f = fn;
        continue;
      }
    }
    // else the exact maximum along the gradient axis u: the trace is
    // tr P + alpha sin(phi) - beta (1 - cos(phi)), alpha = |g|, beta = u^T h u,
    // maximal at phi = atan2(alpha, beta) (a half turn or more where the curvature is negative)
    const double alpha = g.norm();
    const Eigen::Vector3d u = g / alpha;
    const double beta = h00 * u.x() * u.x() + h11 * u.y() * u.y() + h22 * u.z() * u.z() +
                        2.0 * (h01 * u.x() * u.y() + h02 * u.x() * u.z() + h12 * u.y() * u.z());
    const double half = 0.5 * std::atan2(alpha, beta);
    const double sh = std::sin(half);
    q = Eigen::Quaterniond(std::cos(half), sh * u.x(), sh * u.y(), sh * u.z()) * q;
    q.normalize();
    r = q.toRotationMatrix();
    p = an * r.transpose();
    f = p.trace();
  }
  if (converged) *converged = false;
  if (rotation) *rotation = r;
  return it;
}

Eigen::Matrix3d optimal_rotation_svd(const Eigen::Matrix3d& a) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(a, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d u = svd.matrixU();
  const Eigen::Matrix3d v = svd.matrixV();
  if ((u * v.transpose()).determinant() < 0) u.col(2) *= -1.0;
  return u * v.transpose();
}

Eigen::Matrix3d closest_with_determinant(const Eigen::Matrix3d& b, double det, Eigen::Quaterniond& q,
                                         const RotationFitSettings& settings) {
  // signed SVD b = U diag(s) V^T with U, V proper: polar rotation + symmetric eigen
  fit_rotation(b, q, settings);
  const Eigen::Matrix3d rot = q.toRotationMatrix();
  Eigen::Matrix3d s = rot.transpose() * b;
  s = 0.5 * (s + s.transpose());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(s);
  const Eigen::Vector3d sig = eig.eigenvalues();
  // the closest point to the singular values (in units where det = 1) on x1 x2 x3 = 1
  const double unit = std::cbrt(det);
  const Eigen::Vector3d s0 = sig / unit;
  const Eigen::Vector3d x = closest_on_unit_product<3>(s0);
  const Eigen::Vector3d d = x - s0;
  const Eigen::Vector3d sp = (s0 + d) * unit;
  return rot * eig.eigenvectors() * sp.asDiagonal() * eig.eigenvectors().transpose();
}

int fit_plane_rotation(const Eigen::Matrix3d& a, const Eigen::Matrix3d& frame, Eigen::Quaterniond& q, bool* converged,
                       Eigen::Matrix3d* rotation) {
  const auto e = frame.leftCols<2>();
  const Eigen::Matrix2d a2 = e.transpose() * a * e;
  const double c = a2(0, 0) + a2(1, 1), s = a2(1, 0) - a2(0, 1);
  double theta = 0;
  if (c * c + s * s > 1e-28 * (a2.squaredNorm() + 1e-300) && std::isfinite(c) && std::isfinite(s)) {
    theta = std::atan2(s, c);
    q = Eigen::Quaterniond(Eigen::AngleAxisd(theta, frame.col(2)));
  } else {
    // no rotational part (collapsed): keep the warm start's angle about the normal
    const Eigen::Vector3d rotated = q * frame.col(0);
    theta = std::atan2(rotated.dot(frame.col(1)), rotated.dot(frame.col(0)));
  }
  if (rotation) {
    Eigen::Matrix2d q2;
    q2 << std::cos(theta), -std::sin(theta), std::sin(theta), std::cos(theta);
    *rotation = e * q2 * e.transpose();
  }
  if (converged) *converged = true;
  return 1;
}

Eigen::Matrix3d closest_with_determinant_in_plane(const Eigen::Matrix3d& b, double det, const Eigen::Matrix3d& frame) {
  // b2 = R S (R the closed-form best rotation, S = R^T b2 symmetric), S = V diag(sig) V^T;
  // the closest x on x1 x2 = det (closest_on_unit_product, as in 3D)
  const auto e = frame.leftCols<2>();
  const Eigen::Matrix2d b2 = e.transpose() * b * e;
  const double c = b2(0, 0) + b2(1, 1), sn = b2(1, 0) - b2(0, 1);
  const double theta = (c * c + sn * sn > 0) ? std::atan2(sn, c) : 0.0;
  Eigen::Matrix2d rot;
  rot << std::cos(theta), -std::sin(theta), std::sin(theta), std::cos(theta);
  Eigen::Matrix2d sym = rot.transpose() * b2;
  sym = 0.5 * (sym + sym.transpose());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(sym);
  const double unit = std::sqrt(det);
  const Eigen::Vector2d s0 = eig.eigenvalues() / unit;
  const Eigen::Vector2d x = closest_on_unit_product<2>(s0);
  const Eigen::Matrix2d x2 = rot * eig.eigenvectors() * (x * unit).asDiagonal() * eig.eigenvectors().transpose();
  return e * x2 * e.transpose();
}

int fit_element_rotation(const PhysicsModel& phys, const Eigen::Matrix3d& a, Eigen::Quaterniond& q,
                         const RotationFitSettings& settings, bool* converged, Eigen::Matrix3d* rotation) {
  if (phys.is_2d()) return fit_plane_rotation(a, phys.plane_frame, q, converged, rotation);
  return fit_rotation(a, q, settings, converged, rotation);
}

Eigen::Matrix3d element_closest_with_determinant(const PhysicsModel& phys, const Eigen::Matrix3d& b, double det,
                                                 Eigen::Quaterniond& q, const RotationFitSettings& settings) {
  if (phys.is_2d()) return closest_with_determinant_in_plane(b, det, phys.plane_frame);
  return closest_with_determinant(b, det, q, settings);
}

double element_determinant(const PhysicsModel& phys, const Eigen::Matrix3d& f) {
  if (!phys.is_2d()) return f.determinant();
  const auto e = phys.plane_frame.leftCols<2>();
  return (e.transpose() * f * e).determinant();
}

}  // namespace vx
