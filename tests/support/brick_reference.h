#pragma once
/// @file brick_reference.h
/// An independent reference for the Poisson press of poisson_locking_slow_test (issue 27,
/// docs/model.md section 5, "Against a B-bar brick on the same mesh"): plain small-strain
/// linear finite elements on the voxel layout's mesh, none of the model's code but the sparse
/// factor.
///
/// The element is the trilinear hexahedron (8-node brick) on a cube of edge h, integrated
/// selectively: its deviatoric part at the 2 x 2 x 2 Gauss points, its volumetric part at the
/// centre (the mean dilatation: Hughes' B-bar brick, free of volumetric locking), or everything
/// at 2 x 2 x 2 (`full`, which locks as nu -> 1/2: the contrast). The block is W x W x H mm of
/// such cubes, bonded at its base (z = 0); the ball of radius R sits on the axis through the
/// centre of the top face and is pushed d into it. Contact is frictionless and linearised: the
/// top nodes under the ball may only move down to its surface, z_top - w_i <= the ball's
/// surface height over the node's rest position (the ball's normal taken vertical, lateral
/// motion free, the gap measured at the rest position: small-strain geometry, which at d = R / 2
/// is an approximation the finite-layer solution shares), solved by an active set on the
/// candidates' compliance matrix (prescribe w_i on the active nodes, release those pulled up,
/// add those that would penetrate). With `quarter` the two symmetry planes through the ball's
/// axis cut the block to a quarter (normal displacement 0 on them), and the force is 4 times
/// the quarter's. Units: mm, N, kPa.
#include <Eigen/Core>
#include <Eigen/Dense>
#include <Eigen/SparseCore>

#include <array>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "physics/material.h"
#include "sim/sparse_factor.h"

namespace vx::testing {

enum class BrickIntegration {
  bbar,  ///< deviatoric part at 2 x 2 x 2 points, volumetric at 1 (selective reduced: B-bar)
  full,  ///< everything at 2 x 2 x 2 (locks in volume)
};

using BrickMatrix = Eigen::Matrix<double, 24, 24>;

/// The stiffness of a cube of edge h: corner a at (s_x, s_y, s_z) h / 2 with s_c = 2 bit_c(a) - 1
/// (bit 0 x, bit 1 y, bit 2 z), degree of freedom 3 a + c; mu, lambda in N/mm^2, N/mm.
inline BrickMatrix brick_stiffness(double h, double mu, double lambda, BrickIntegration integration) {
  auto gradients = [h](double xi, double eta, double zeta) {
    Eigen::Matrix<double, 3, 8> d;
    for (int a = 0; a < 8; ++a) {
      const double sx = 2.0 * (a & 1) - 1, sy = 2.0 * ((a >> 1) & 1) - 1, sz = 2.0 * ((a >> 2) & 1) - 1;
      d(0, a) = sx * (1 + sy * eta) * (1 + sz * zeta) / 8 * 2 / h;
      d(1, a) = sy * (1 + sx * xi) * (1 + sz * zeta) / 8 * 2 / h;
      d(2, a) = sz * (1 + sx * xi) * (1 + sy * eta) / 8 * 2 / h;
    }
    return d;
  };
  // engineering strain (xx, yy, zz, 2xy, 2yz, 2xz) = B u
  auto strain = [](const Eigen::Matrix<double, 3, 8>& d) {
    Eigen::Matrix<double, 6, 24> b = Eigen::Matrix<double, 6, 24>::Zero();
    for (int a = 0; a < 8; ++a) {
      b(0, 3 * a) = d(0, a);
      b(1, 3 * a + 1) = d(1, a);
      b(2, 3 * a + 2) = d(2, a);
      b(3, 3 * a) = d(1, a);
      b(3, 3 * a + 1) = d(0, a);
      b(4, 3 * a + 1) = d(2, a);
      b(4, 3 * a + 2) = d(1, a);
      b(5, 3 * a) = d(2, a);
      b(5, 3 * a + 2) = d(0, a);
    }
    return b;
  };
  const double kappa = lambda + 2.0 * mu / 3.0;
  Eigen::Matrix<double, 6, 6> dev = Eigen::Matrix<double, 6, 6>::Zero(), all;
  dev.topLeftCorner<3, 3>() = 2.0 * mu * (Eigen::Matrix3d::Identity() - Eigen::Matrix3d::Constant(1.0 / 3.0));
  dev.bottomRightCorner<3, 3>() = mu * Eigen::Matrix3d::Identity();
  all = dev;
  all.topLeftCorner<3, 3>().array() += kappa;
  const Eigen::Matrix<double, 6, 6>& at_points = integration == BrickIntegration::bbar ? dev : all;
  BrickMatrix k = BrickMatrix::Zero();
  const double g = 1.0 / std::sqrt(3.0), weight = h * h * h / 8.0;
  for (int p = 0; p < 8; ++p) {
    const auto b = strain(gradients(p & 1 ? g : -g, p & 2 ? g : -g, p & 4 ? g : -g));
    k += weight * b.transpose() * at_points * b;
  }
  if (integration == BrickIntegration::bbar) {
    const auto b = strain(gradients(0, 0, 0));
    const Eigen::Matrix<double, 1, 24> div = b.row(0) + b.row(1) + b.row(2);
    k += kappa * h * h * h * div.transpose() * div;
  }
  return k;
}

struct BrickPress {
  double width_mm{32}, height_mm{16}, voxel_mm{1}, radius_mm{4}, depth_mm{2}, youngs_kpa{10};
  BrickIntegration integration{BrickIntegration::bbar};
  bool quarter{true};      ///< the symmetry planes through the ball's axis (force x 4)
  bool paraboloid{false};  ///< Hertz's paraboloid z = r^2 / 2R under the ball instead of its sphere
  /// the sphere's own normals instead of the vertical: node i may only move along n_i (from the
  /// ball's centre through its rest position) to the sphere, n_i . u_i >= R - |X_i - c|, and the
  /// ball pushes it along n_i (outwards as well as down), as the model's contact does; the force
  /// is the vertical part of the pushes (still linearised: n_i at rest)
  bool radial_normals{false};
};

struct BrickPressResult {
  double force_n{0};
  int contact_nodes{0};      ///< active at the end (of the quarter with `quarter`)
  int active_set_rounds{0};  ///< solves of the contact set
  int dofs{0};               ///< free degrees of freedom
  double factor_s{0}, total_s{0};
  long long factor_nonzeros{0};
};

/// The ball's force on a linear body of stiffness `stiffness` (free degrees of freedom, symmetric; the
/// lower triangle is read): candidate c may move along normal[c] (its free degrees of freedom
/// rows[c], -1 where held) by at least need[c] and is pushed along normal[c]; the active set
/// finds the pushes (see the file comment). The force is `scale` times the pushes' downward part.
inline BrickPressResult press_with_matrix(const SparseFactor::Matrix& stiffness,
                                          const std::vector<std::array<int, 3>>& rows,
                                          const std::vector<Eigen::Vector3d>& normal, const std::vector<double>& need,
                                          double scale) {
  SparseFactor factor;
  const auto tf = std::chrono::steady_clock::now();
  if (!factor.compute(stiffness)) throw std::runtime_error("brick_press: the stiffness is not positive definite");
  BrickPressResult out;
  out.factor_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - tf).count();
  out.factor_nonzeros = factor.nonzeros();
  out.dofs = int(stiffness.rows());
  const int m = int(rows.size());
  // forward vectors of every free degree of freedom a push moves (3 per candidate; held ones -1)
  std::vector<SparseFactor::UnitForward> z(static_cast<std::size_t>(3 * m));
  for (int c = 0; c < m; ++c)
    for (int a = 0; a < 3; ++a)
      if (rows[std::size_t(c)][std::size_t(a)] >= 0 && normal[std::size_t(c)](a) != 0.0)
        factor.forward_unit(rows[std::size_t(c)][std::size_t(a)], z[std::size_t(3 * c + a)]);
  // mm / N: the motion of i along n_i under a unit push at j along n_j
  Eigen::MatrixXd compliance = Eigen::MatrixXd::Zero(m, m);
  for (int i = 0; i < m; ++i)
    for (int j = 0; j <= i; ++j) {
      double g = 0;
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) {
          const double w = normal[std::size_t(i)](a) * normal[std::size_t(j)](b);
          if (w == 0.0 || rows[std::size_t(i)][std::size_t(a)] < 0 || rows[std::size_t(j)][std::size_t(b)] < 0)
            continue;
          g += w * SparseFactor::dot(z[std::size_t(3 * i + a)], z[std::size_t(3 * j + b)]);
        }
      compliance(i, j) = compliance(j, i) = g;
    }
  const Eigen::Map<const Eigen::VectorXd> d(need.data(), m);
  std::vector<bool> active(static_cast<std::size_t>(m));
  for (int c = 0; c < m; ++c) active[std::size_t(c)] = need[std::size_t(c)] > 0;
  Eigen::VectorXd p = Eigen::VectorXd::Zero(m);
  for (int round = 0; round < 200; ++round) {
    ++out.active_set_rounds;
    std::vector<int> on;
    for (int c = 0; c < m; ++c)
      if (active[std::size_t(c)]) on.push_back(c);
    Eigen::MatrixXd caa(on.size(), on.size());
    Eigen::VectorXd da(on.size());
    for (std::size_t i = 0; i < on.size(); ++i) {
      da(Eigen::Index(i)) = d(on[i]);
      for (std::size_t j = 0; j < on.size(); ++j) caa(Eigen::Index(i), Eigen::Index(j)) = compliance(on[i], on[j]);
    }
    const Eigen::VectorXd pa = caa.ldlt().solve(da);
    p.setZero();
    for (std::size_t i = 0; i < on.size(); ++i) p(on[i]) = pa(Eigen::Index(i));
    bool changed = false;
    for (int c : on)
      if (p(c) < 0) active[std::size_t(c)] = false, changed = true;  // pulled up: released
    if (!changed) {
      const Eigen::VectorXd w = compliance * p;
      for (int c = 0; c < m; ++c)
        if (!active[std::size_t(c)] && w(c) < d(c) - 1e-12) active[std::size_t(c)] = true, changed = true;
    }
    if (!changed) break;
  }
  for (int c = 0; c < m; ++c) out.contact_nodes += active[std::size_t(c)] ? 1 : 0;
  double down = 0;
  for (int c = 0; c < m; ++c) down -= p(c) * normal[std::size_t(c)].z();
  out.force_n = scale * down;
  return out;
}

/// The press at Poisson's ratio nu (see the file comment); with `element`, that 24 x 24 stiffness
/// (brick_stiffness's numbering, for a cube of edge s.voxel_mm) instead of the brick's: another
/// element's linearisation on the same mesh, with the same contact. Throws std::runtime_error
/// when the voxel does not divide the block or the factor fails.
inline BrickPressResult brick_press(const BrickPress& s, double nu, const BrickMatrix* element = nullptr) {
  const auto t0 = std::chrono::steady_clock::now();
  const double h = s.voxel_mm;
  const int nw = int(std::lround(s.width_mm / h)), nz = int(std::lround(s.height_mm / h));
  if (nw % 2 != 0 || std::abs(nw * h - s.width_mm) > 1e-9 || std::abs(nz * h - s.height_mm) > 1e-9)
    throw std::runtime_error("brick_press: the voxel must divide the block (an even count across)");
  const int nx = s.quarter ? nw / 2 : nw, ny = nx;        // elements along x, y
  const double x0 = s.quarter ? 0.0 : -0.5 * s.width_mm;  // the ball's axis at x = y = 0
  const double e = s.youngs_kpa * kKpaToNPerMm2, mu = e / (2 * (1 + nu)), lambda = e * nu / ((1 + nu) * (1 - 2 * nu));
  const BrickMatrix ke = element ? *element : brick_stiffness(h, mu, lambda, s.integration);
  auto node = [&](int i, int j, int k) { return (k * (ny + 1) + j) * (nx + 1) + i; };
  const int nodes = (nx + 1) * (ny + 1) * (nz + 1);
  std::vector<int> dof(std::size_t(3 * nodes), -1);
  int n = 0;
  for (int k = 0; k <= nz; ++k)
    for (int j = 0; j <= ny; ++j)
      for (int i = 0; i <= nx; ++i)
        for (int c = 0; c < 3; ++c) {
          const bool held = k == 0 || (s.quarter && ((c == 0 && i == 0) || (c == 1 && j == 0)));
          if (!held) dof[std::size_t(3 * node(i, j, k) + c)] = n++;
        }
  std::vector<Eigen::Triplet<double>> t;
  t.reserve(std::size_t(nx) * ny * nz * 300);
  int corner[8];
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        for (int a = 0; a < 8; ++a) corner[a] = node(i + (a & 1), j + ((a >> 1) & 1), k + ((a >> 2) & 1));
        for (int a = 0; a < 24; ++a) {
          const int r = dof[std::size_t(3 * corner[a / 3] + a % 3)];
          if (r < 0) continue;
          for (int b = 0; b < 24; ++b) {
            const int c = dof[std::size_t(3 * corner[b / 3] + b % 3)];
            if (c >= 0 && c <= r) t.emplace_back(r, c, ke(a, b));
          }
        }
      }
  SparseFactor::Matrix a(n, n);
  a.setFromTriplets(t.begin(), t.end());
  t = {};
  // candidates: the top nodes under the ball; need_i = the motion along n_i (vertical: downward)
  // that puts node i on the ball's surface
  std::vector<std::array<int, 3>> rows;
  std::vector<Eigen::Vector3d> normal;
  std::vector<double> need;
  const double r2 = s.radius_mm * s.radius_mm;
  const Eigen::Vector3d centre(0, 0, s.height_mm + s.radius_mm - s.depth_mm);
  for (int j = 0; j <= ny; ++j)
    for (int i = 0; i <= nx; ++i) {
      const double x = x0 + i * h, y = x0 + j * h, rr = x * x + y * y;
      if (rr >= r2) continue;
      std::array<int, 3> r{};
      for (int c = 0; c < 3; ++c) r[std::size_t(c)] = dof[std::size_t(3 * node(i, j, nz) + c)];
      rows.push_back(r);
      if (s.radial_normals) {
        const Eigen::Vector3d rel = Eigen::Vector3d(x, y, s.height_mm) - centre;
        normal.push_back(rel.normalized());
        need.push_back(s.radius_mm - rel.norm());
      } else {
        const double lift = s.paraboloid ? rr / (2 * s.radius_mm) : s.radius_mm - std::sqrt(r2 - rr);
        normal.emplace_back(0, 0, -1);
        need.push_back(s.depth_mm - lift);
      }
    }
  BrickPressResult out = press_with_matrix(a, rows, normal, need, s.quarter ? 4.0 : 1.0);
  out.total_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

}  // namespace vx::testing
