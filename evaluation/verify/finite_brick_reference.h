#pragma once
/// @file finite_brick_reference.h
/// A finite-strain reference for the Poisson press (issue 27, docs/model.md section 5, "A
/// finite-strain reference"): the B-bar brick of tests/support/brick_reference.h made geometrically and
/// materially non-linear, pressed by a rigid frictionless sphere whose contact pushes each node
/// along the sphere's normal at its deformed position, as the model's contact does. None of the
/// model's code but the sparse factor.
///
/// The element is the trilinear hexahedron on a cube of edge h with the mean-dilatation (Q1/P0)
/// split of a compressible neo-Hookean solid (Simo, Taylor and Pister 1985): its energy is
///     sum over the 2 x 2 x 2 Gauss points g of (h^3 / 8) mu/2 (J_g^(-2/3) tr(F_g^T F_g) - 3)
///     + V U(v / V),   U(J) = kappa/4 (J^2 - 1 - 2 ln J),   kappa = lambda + 2 mu / 3,
/// with v = sum_g (h^3 / 8) J_g the element's current volume (exact for the trilinear field) and
/// V = h^3. Linearised at rest it is brick_stiffness(h, mu, lambda, bbar) exactly (the isochoric
/// part at the points gives the deviatoric matrix, U''(1) = kappa on the mean dilatation), so
/// small presses reproduce the linear reference; at finite strain it keeps its volume without
/// locking as the B-bar brick does.
///
/// The press: brick_reference.h's block (quarter by symmetry, bonded base), the ball's centre at
/// (0, 0, H + R - d). Every top node gets the penalty energy kp/2 max(0, R - |x_i - c|)^2 with
/// kp = `penalty_n_mm` (N/mm): its push kp g_i n_i along the sphere's normal n_i = (x_i - c) /
/// |x_i - c| at the node's current position, frictionless; the depth grows in `steps` equal
/// steps (each started from the last step's change again), each solved by Newton's method on the
/// total energy to a residual below `residual_n`: the penalty on an active set of nodes (its
/// quadratic continued past the surface, so the energy is smooth), a node that goes inside
/// joining at once and the set taken anew from the solution until it does not change; the exact
/// Hessian (its contact part's indefinite term capped), solved by conjugate gradients
/// preconditioned with a factor of an earlier Hessian of the step (factored anew when they stall;
/// a diagonal shift when a Hessian is not positive definite); a backtracking line search on the
/// energy. The force is the vertical part of the pushes (x 4 with the quarter), recorded at every
/// step's depth. The law: `FiniteMaterial` (the element above, or corotational_brick_energy).
/// Units: mm, N, kPa.
#include <Eigen/Core>
#include <Eigen/Dense>
#include <Eigen/SparseCore>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <stdexcept>
#include <vector>

#include "physics/material.h"
#include "sim/sparse_factor.h"

namespace vx::reference {

using FiniteBrickVector = Eigen::Matrix<double, 24, 1>;
using FiniteBrickMatrix = Eigen::Matrix<double, 24, 24>;

/// The gradients of the trilinear shape functions at the 8 Gauss points of a cube of edge h,
/// brick_stiffness's corner numbering (corner a at (s_x, s_y, s_z) h / 2, s_c = 2 bit_c(a) - 1).
inline std::array<Eigen::Matrix<double, 3, 8>, 8> finite_brick_gradients(double h) {
  std::array<Eigen::Matrix<double, 3, 8>, 8> out;
  const double g = 1.0 / std::sqrt(3.0);
  for (int p = 0; p < 8; ++p) {
    const double xi = p & 1 ? g : -g, eta = p & 2 ? g : -g, zeta = p & 4 ? g : -g;
    for (int a = 0; a < 8; ++a) {
      const double sx = 2.0 * (a & 1) - 1, sy = 2.0 * ((a >> 1) & 1) - 1, sz = 2.0 * ((a >> 2) & 1) - 1;
      out[std::size_t(p)](0, a) = sx * (1 + sy * eta) * (1 + sz * zeta) / 4 / h;
      out[std::size_t(p)](1, a) = sy * (1 + sx * xi) * (1 + sz * zeta) / 4 / h;
      out[std::size_t(p)](2, a) = sz * (1 + sx * xi) * (1 + sy * eta) / 4 / h;
    }
  }
  return out;
}

namespace detail {

using Vec9 = Eigen::Matrix<double, 9, 1>;
using Mat9 = Eigen::Matrix<double, 9, 9>;

/// finite_brick_gradients(h), kept for the last h of this thread.
inline const std::array<Eigen::Matrix<double, 3, 8>, 8>& cached_brick_gradients(double h) {
  static thread_local double cached_h = -1;
  static thread_local std::array<Eigen::Matrix<double, 3, 8>, 8> dn;
  if (h != cached_h) dn = finite_brick_gradients(h), cached_h = h;
  return dn;
}

/// m as a 9-vector, index 3 i + l of m(i, l).
inline Vec9 vec9(const Eigen::Matrix3d& m) {
  Vec9 v;
  for (int i = 0; i < 3; ++i)
    for (int l = 0; l < 3; ++l) v(3 * i + l) = m(i, l);
  return v;
}

/// The deformation gradient F = 1 + sum_a u_a d_a^T at a point with shape gradients d.
inline Eigen::Matrix3d deformation_gradient(const FiniteBrickVector& u, const Eigen::Matrix<double, 3, 8>& d) {
  Eigen::Matrix3d f = Eigen::Matrix3d::Identity();
  for (int a = 0; a < 8; ++a) f += u.segment<3>(3 * a) * d.col(a).transpose();
  return f;
}

/// dF = B du: F(i, l) takes u(3 c + i) d(l, c).
inline Eigen::Matrix<double, 9, 24> gradient_operator(const Eigen::Matrix<double, 3, 8>& d) {
  Eigen::Matrix<double, 9, 24> b = Eigen::Matrix<double, 9, 24>::Zero();
  for (int c = 0; c < 8; ++c)
    for (int i = 0; i < 3; ++i)
      for (int l = 0; l < 3; ++l) b(3 * i + l, 3 * c + i) = d(l, c);
  return b;
}

/// The energy (N mm) of a B-bar brick at the corner displacements u (mm, 3 per corner), with
/// `grad` / `hess` its gradient (N) and Hessian (N/mm): the 8 Gauss points' law on their own F
/// plus a law U of the mean dilatation v / V on the element's volume (the one structure both
/// FiniteMaterial laws share). `point(f, j, fit, p, c)` returns a point's energy density (N/mm^2)
/// at F = f (J = j > 0, F^-T = fit) and, where asked (p, c not null), its stress P = dW/dF and
/// dP/dF (column 3 j + l for dF = e_j e_l^T); `mean(jbar)` returns {U, U', U''}. +infinity when a
/// point or the element turns inside out.
template <class PointLaw, class MeanLaw>
double bbar_brick_energy(const FiniteBrickVector& u, double h, const PointLaw& point, const MeanLaw& mean,
                         FiniteBrickVector* grad, FiniteBrickMatrix* hess) {
  const auto& dn = cached_brick_gradients(h);
  const double w = h * h * h / 8, volume = h * h * h;
  double energy = 0, v = 0;
  FiniteBrickVector gv = FiniteBrickVector::Zero();
  FiniteBrickMatrix hv = FiniteBrickMatrix::Zero();
  if (grad) grad->setZero();
  if (hess) hess->setZero();
  for (int p = 0; p < 8; ++p) {
    const auto& d = dn[std::size_t(p)];
    const Eigen::Matrix3d f = deformation_gradient(u, d);
    const double j = f.determinant();
    if (!(j > 0)) return std::numeric_limits<double>::infinity();
    const Eigen::Matrix3d fit = f.inverse().transpose();
    Eigen::Matrix3d stress;
    Mat9 dstress;
    energy += w * point(f, j, fit, grad || hess ? &stress : nullptr, hess ? &dstress : nullptr);
    v += w * j;
    if (!grad && !hess) continue;
    const Eigen::Matrix<double, 9, 24> b = gradient_operator(d);
    if (grad) *grad += w * b.transpose() * vec9(stress);
    gv += w * b.transpose() * vec9(j * fit);
    if (!hess) continue;
    Mat9 cj;  // d(J F^-T) / dF, column 3 j + l for dF = e_j e_l^T
    for (int jj = 0; jj < 3; ++jj)
      for (int l = 0; l < 3; ++l) {
        Eigen::Matrix3d df = Eigen::Matrix3d::Zero();
        df(jj, l) = 1;
        const double tr_fit = (fit.array() * df.array()).sum();
        cj.col(3 * jj + l) = vec9(j * tr_fit * fit - j * (fit * df.transpose() * fit));
      }
    *hess += w * b.transpose() * dstress * b;
    hv += w * b.transpose() * cj * b;
  }
  const double jbar = v / volume;
  if (!(jbar > 0)) return std::numeric_limits<double>::infinity();
  const std::array<double, 3> um = mean(jbar);  // U, U', U''
  energy += volume * um[0];
  if (grad) *grad += um[1] * gv;
  if (hess) *hess += um[2] / volume * gv * gv.transpose() + um[1] * hv;
  return energy;
}

}  // namespace detail

/// The material law of the finite-strain brick (see the file comment).
enum class FiniteMaterial {
  neo_hookean,   ///< mu/2 (J^(-2/3) I1 - 3) at the points, kappa/4 (J^2 - 1 - 2 ln J) on the mean
  corotational,  ///< mu |F - R|^2 at the points (R: F's rotation), lambda/2 (J - 1)^2 on the mean
};

/// The corotational law's energy (N mm) at the corner displacements u, with `grad` / `hess`:
/// mu |F_g - R_g|^2 at the 8 points (linear elasticity in the rotated frame, the model's shape
/// term at Poisson 0) and lambda/2 V (v / V - 1)^2 on the element's volume (the model's volume
/// term to second order). dR / dF from F = R S: R^T dR = [w]x, w = (tr S 1 - S)^-1 axial(R^T dF -
/// dF^T R). +infinity when a point turns inside out.
inline double corotational_brick_energy(const FiniteBrickVector& u, double h, double mu, double lambda,
                                        FiniteBrickVector* grad = nullptr, FiniteBrickMatrix* hess = nullptr) {
  using detail::Mat9, detail::vec9;
  auto cross = [](const Eigen::Vector3d& a) {
    Eigen::Matrix3d m;
    m << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
    return m;
  };
  const auto point = [&](const Eigen::Matrix3d& f, double, const Eigen::Matrix3d&, Eigen::Matrix3d* p, Mat9* c) {
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(f, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const Eigen::Matrix3d rot = svd.matrixU() * svd.matrixV().transpose();  // det F > 0: proper
    if (p) *p = 2 * mu * (f - rot);
    if (c) {
      const Eigen::Matrix3d stretch = rot.transpose() * f;
      const Eigen::Matrix3d spin = (stretch.trace() * Eigen::Matrix3d::Identity() - stretch).inverse();
      for (int jj = 0; jj < 3; ++jj)
        for (int l = 0; l < 3; ++l) {
          Eigen::Matrix3d df = Eigen::Matrix3d::Zero();
          df(jj, l) = 1;
          const Eigen::Matrix3d skew = rot.transpose() * df - df.transpose() * rot;
          const Eigen::Vector3d ax(skew(2, 1), skew(0, 2), skew(1, 0));
          c->col(3 * jj + l) = vec9(2 * mu * (df - rot * cross(spin * ax)));
        }
    }
    return mu * (f - rot).squaredNorm();
  };
  const auto mean = [&](double jbar) {
    return std::array<double, 3>{lambda / 2 * (jbar - 1) * (jbar - 1), lambda * (jbar - 1), lambda};
  };
  return detail::bbar_brick_energy(u, h, point, mean, grad, hess);
}

/// The element's energy (N mm) at the corner displacements u (mm, 3 per corner), and with
/// `grad` / `hess` its gradient (N) and Hessian (N/mm). mu, lambda in N/mm^2. +infinity when a
/// Gauss point or the element turns inside out (J <= 0).
inline double finite_brick_energy(const FiniteBrickVector& u, double h, double mu, double lambda,
                                  FiniteBrickVector* grad = nullptr, FiniteBrickMatrix* hess = nullptr) {
  using detail::Mat9, detail::vec9;
  const double kappa = lambda + 2.0 * mu / 3.0;
  const auto point = [&](const Eigen::Matrix3d& f, double j, const Eigen::Matrix3d& fit, Eigen::Matrix3d* p, Mat9* c) {
    const double i1 = (f.array() * f.array()).sum(), a13 = std::pow(j, -2.0 / 3.0);
    if (p) *p = mu * a13 * (f - i1 / 3 * fit);
    if (c)
      for (int jj = 0; jj < 3; ++jj)
        for (int l = 0; l < 3; ++l) {
          Eigen::Matrix3d df = Eigen::Matrix3d::Zero();
          df(jj, l) = 1;
          const double tr_fit = (fit.array() * df.array()).sum(), tr_f = (f.array() * df.array()).sum();
          const Eigen::Matrix3d turn = fit * df.transpose() * fit;
          c->col(3 * jj + l) =
              vec9(mu * a13 * (-2.0 / 3.0 * tr_fit * (f - i1 / 3 * fit) + df - 2.0 / 3.0 * tr_f * fit + i1 / 3 * turn));
        }
    return 0.5 * mu * (a13 * i1 - 3);
  };
  const auto mean = [&](double jbar) {
    return std::array<double, 3>{kappa / 4 * (jbar * jbar - 1 - 2 * std::log(jbar)), kappa / 2 * (jbar - 1 / jbar),
                                 kappa / 2 * (1 + 1 / (jbar * jbar))};
  };
  return detail::bbar_brick_energy(u, h, point, mean, grad, hess);
}

struct FinitePress {
  double width_mm{32}, height_mm{16}, voxel_mm{1}, radius_mm{4}, depth_mm{2}, youngs_kpa{10};
  int steps{8};              ///< equal depth steps to depth_mm (the force is recorded at each)
  double penalty_n_mm{100};  ///< kp: a node's push per mm inside the sphere
  double residual_n{1e-9};   ///< Newton stops below this largest residual force (or 100 x it at
                             ///< the energy's rounding)
  int max_newton{60};        ///< per step; more throws
  FiniteMaterial material{FiniteMaterial::neo_hookean};
};

struct FinitePressResult {
  std::vector<double> depth_mm, force_n;  ///< at each step's depth
  std::vector<int> contact_nodes;         ///< inside the sphere at each step (of the quarter)
  std::vector<int> newton_iterations;     ///< per step
  double max_penetration_mm{0};           ///< at the last step
  int dofs{0};
  double total_s{0};
};

/// The finite-strain press at Poisson's ratio nu (see the file comment), on the quarter block.
/// Throws std::runtime_error when the voxel does not divide the block or Newton does not converge.
inline FinitePressResult finite_brick_press(const FinitePress& s, double nu) {
  const auto t0 = std::chrono::steady_clock::now();
  const double h = s.voxel_mm;
  const int nw = int(std::lround(s.width_mm / h)), nz = int(std::lround(s.height_mm / h));
  if (nw % 2 != 0 || std::abs(nw * h - s.width_mm) > 1e-9 || std::abs(nz * h - s.height_mm) > 1e-9)
    throw std::runtime_error("finite_brick_press: the voxel must divide the block (an even count across)");
  const int nx = nw / 2, ny = nx;
  const double e = s.youngs_kpa * kKpaToNPerMm2, mu = e / (2 * (1 + nu)), lambda = e * nu / ((1 + nu) * (1 - 2 * nu));
  auto node = [&](int i, int j, int k) { return (k * (ny + 1) + j) * (nx + 1) + i; };
  const int nodes = (nx + 1) * (ny + 1) * (nz + 1);
  std::vector<int> dof(std::size_t(3 * nodes), -1);
  int n = 0;
  for (int k = 0; k <= nz; ++k)
    for (int j = 0; j <= ny; ++j)
      for (int i = 0; i <= nx; ++i)
        for (int c = 0; c < 3; ++c)
          if (!(k == 0 || (c == 0 && i == 0) || (c == 1 && j == 0))) dof[std::size_t(3 * node(i, j, k) + c)] = n++;
  std::vector<std::array<int, 8>> elements;
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        std::array<int, 8> c{};
        for (int a = 0; a < 8; ++a) c[std::size_t(a)] = node(i + (a & 1), j + ((a >> 1) & 1), k + ((a >> 2) & 1));
        elements.push_back(c);
      }
  std::vector<int> top;
  std::vector<Eigen::Vector3d> top_rest;
  for (int j = 0; j <= ny; ++j)
    for (int i = 0; i <= nx; ++i) top.push_back(node(i, j, nz)), top_rest.emplace_back(i * h, j * h, s.height_mm);
  auto displacement = [&](const Eigen::VectorXd& x, int nd) {
    Eigen::Vector3d u;
    for (int c = 0; c < 3; ++c) {
      const int r = dof[std::size_t(3 * nd + c)];
      u(c) = r >= 0 ? x(r) : 0.0;
    }
    return u;
  };
  // the total energy at x with the ball's centre c; with `g` / `t` its gradient and Hessian
  // (lower triangle, as triplets); `force` the ball's vertical force (the quarter's)
  // `active`: the top nodes whose penalty is on (its quadratic continued past the surface, a pull);
  // null: those inside the sphere (the penalty itself)
  auto total = [&](const Eigen::VectorXd& x, const Eigen::Vector3d& centre, const std::vector<char>* active,
                   Eigen::VectorXd* g, std::vector<Eigen::Triplet<double>>* t, double* force = nullptr,
                   int* touching = nullptr, double* deepest = nullptr) {
    double energy = 0;
    if (g) g->setZero(n);
    if (t) t->clear();
    FiniteBrickVector ue, ge;
    FiniteBrickMatrix he;
    for (const auto& el : elements) {
      for (int a = 0; a < 8; ++a) ue.segment<3>(3 * a) = displacement(x, el[std::size_t(a)]);
      const double ee = s.material == FiniteMaterial::neo_hookean
                            ? finite_brick_energy(ue, h, mu, lambda, g ? &ge : nullptr, t ? &he : nullptr)
                            : corotational_brick_energy(ue, h, mu, lambda, g ? &ge : nullptr, t ? &he : nullptr);
      if (!std::isfinite(ee)) return ee;
      energy += ee;
      for (int a = 0; a < 24; ++a) {
        const int r = dof[std::size_t(3 * el[std::size_t(a / 3)] + a % 3)];
        if (r < 0) continue;
        if (g) (*g)(r) += ge(a);
        if (t)
          for (int b = 0; b < 24; ++b) {
            const int c = dof[std::size_t(3 * el[std::size_t(b / 3)] + b % 3)];
            if (c >= 0 && c <= r) t->emplace_back(r, c, he(a, b));
          }
      }
    }
    if (force) *force = 0;
    if (touching) *touching = 0;
    if (deepest) *deepest = 0;
    for (std::size_t q = 0; q < top.size(); ++q) {
      const Eigen::Vector3d rel = top_rest[q] + displacement(x, top[q]) - Eigen::Vector3d(0, 0, centre.z());
      const double dist = rel.norm(), gap = s.radius_mm - dist;
      if (active ? !(*active)[q] : gap <= 0) continue;
      const Eigen::Vector3d nrm = rel / dist;
      energy += 0.5 * s.penalty_n_mm * gap * gap;
      if (force) *force -= s.penalty_n_mm * gap * nrm.z();
      if (touching) ++*touching;
      if (deepest) *deepest = std::max(*deepest, gap);
      // gradient -kp g n; Hessian kp n n^T - kp g / |d| (1 - n n^T), its second (indefinite)
      // part with |g| capped at 1e-3 h: exact near the solution, where g is a push over kp, and
      // no collapse of the first iteration after the ball moves
      const double g_cap = std::clamp(gap, -1e-3 * h, 1e-3 * h);
      const Eigen::Matrix3d hc = s.penalty_n_mm * (nrm * nrm.transpose()) -
                                 s.penalty_n_mm * g_cap / dist * (Eigen::Matrix3d::Identity() - nrm * nrm.transpose());
      for (int a = 0; a < 3; ++a) {
        const int r = dof[std::size_t(3 * top[q] + a)];
        if (r < 0) continue;
        if (g) (*g)(r) -= s.penalty_n_mm * gap * nrm(a);
        if (t)
          for (int b = 0; b < 3; ++b) {
            const int c = dof[std::size_t(3 * top[q] + b)];
            if (c >= 0 && c <= r) t->emplace_back(r, c, hc(a, b));
          }
      }
    }
    return energy;
  };
  FinitePressResult out;
  out.dofs = n;
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n), g(n), trial(n), dx(n), r(n), z(n), p(n), ap(n);
  std::vector<Eigen::Triplet<double>> t;
  SparseFactor::Matrix a(n, n);
  SparseFactor factor;
  Eigen::MatrixX3d rhs = Eigen::MatrixX3d::Zero(n, 3), sol(n, 3);
  auto precondition = [&](const Eigen::VectorXd& in, Eigen::VectorXd& o) {
    rhs.col(0) = in;
    factor.solve3(rhs, sol);
    o = sol.col(0);
  };
  // H dx = -g by conjugate gradients preconditioned with the last factor (of an earlier Hessian
  // of this step); false when they stall or meet negative curvature (then: factor anew)
  auto pcg = [&](int limit) {
    dx.setZero();
    r = -g;
    precondition(r, z);
    p = z;
    double rz = r.dot(z);
    const double goal = 1e-8 * g.norm();
    for (int k = 0; k < limit; ++k) {
      ap = a.selfadjointView<Eigen::Lower>() * p;
      const double curv = p.dot(ap);
      if (!(curv > 0)) return false;
      const double alpha = rz / curv;
      dx += alpha * p;
      r -= alpha * ap;
      if (r.norm() < goal) return true;
      precondition(r, z);
      const double rz_new = r.dot(z);
      p = z + (rz_new / rz) * p;
      rz = rz_new;
    }
    return false;
  };
  auto refactor = [&]() {
    double shift = 0;
    while (!factor.compute(a)) {  // not positive definite: a diagonal shift (a damped step)
      shift = shift == 0 ? 1e-4 * e * h : 10 * shift;
      if (shift > 1e6) throw std::runtime_error("finite_brick_press: no positive definite Hessian");
      for (int q = 0; q < n; ++q) t.emplace_back(q, q, shift);
      a.setFromTriplets(t.begin(), t.end());
    }
    return shift;
  };
  const bool log = std::getenv("VX_NEWTON_LOG") != nullptr;
  Eigen::VectorXd last = x;
  std::vector<char> active(top.size());
  for (int step = 1; step <= s.steps; ++step) {
    const double depth = s.depth_mm * step / s.steps;
    const Eigen::Vector3d centre(0, 0, s.height_mm + s.radius_mm - depth);
    const Eigen::VectorXd start = x;
    if (step > 1) x += x - last;  // the start: the last step's change again (equal steps)
    last = start;
    auto inside = [&](std::size_t q) {
      return (top_rest[q] + displacement(x, top[q]) - Eigen::Vector3d(0, 0, centre.z())).norm() < s.radius_mm;
    };
    for (std::size_t q = 0; q < top.size(); ++q) active[q] = inside(q) ? 1 : 0;
    bool factored = false;
    int it = 0;
    // an active set: Newton with the penalty on the active nodes (smooth), then the set from
    // the solution (the nodes inside the sphere), until it does not change
    for (int round = 0;; ++round) {
      if (round > 40) throw std::runtime_error("finite_brick_press: the contact set does not settle");
      for (;; ++it) {
        const double energy = total(x, centre, &active, &g, &t);
        if (g.cwiseAbs().maxCoeff() < s.residual_n) break;
        if (it >= s.max_newton) throw std::runtime_error("finite_brick_press: Newton did not converge");
        a.setFromTriplets(t.begin(), t.end());
        double shift = 0;
        if (!factored || !pcg(40)) {
          shift = refactor();
          factored = true;
          if (!pcg(40)) precondition(-g, dx);  // the shifted factor's step
        }
        const double slope = g.dot(dx);
        double step_length = 1;
        bool floor = false;
        for (;;) {
          trial = x + step_length * dx;
          const double et = total(trial, centre, &active, nullptr, nullptr);
          if (std::isfinite(et) && et <= energy + 1e-4 * step_length * slope) break;
          step_length *= 0.5;
          if (step_length < 1e-6) {  // the energy's rounding: no decrease to be seen
            floor = true;
            break;
          }
        }
        if (floor && g.cwiseAbs().maxCoeff() < 100 * s.residual_n) break;  // converged to rounding
        if (floor) trial = x + dx;
        x = trial;
        // a node that went inside the sphere joins at once (it would sink freely until the set's
        // next update); nodes leave only when a set has converged
        for (std::size_t q = 0; q < top.size(); ++q)
          if (!active[q] && inside(q)) active[q] = 1;
        if (log)
          std::fprintf(stderr, "step %d round %d it %d residual %.3e shift %.1e length %.3g at %.2f s\n", step, round,
                       it, g.cwiseAbs().maxCoeff(), shift, step_length,
                       std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      }
      bool changed = false;
      for (std::size_t q = 0; q < top.size(); ++q)
        if ((inside(q) ? 1 : 0) != active[q]) active[q] = inside(q) ? 1 : 0, changed = true;
      if (!changed) break;
    }
    double force = 0, deepest = 0;
    int touching = 0;
    total(x, centre, nullptr, nullptr, nullptr, &force, &touching, &deepest);
    out.depth_mm.push_back(depth);
    out.force_n.push_back(4 * force);
    out.contact_nodes.push_back(touching);
    out.newton_iterations.push_back(it);
    out.max_penetration_mm = deepest;
  }
  out.total_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

}  // namespace vx::reference
