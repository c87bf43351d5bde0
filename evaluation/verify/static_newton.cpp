#include "verify/static_newton.h"

#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>

#include "base/error.h"
#include "physics/elements.h"
#include "verify/case_helpers.h"

namespace vx::cases {

HeldCoordinates held_nodes(int num_nodes, const std::vector<int>& nodes) {
  HeldCoordinates held(std::size_t(3 * num_nodes), 0);
  for (int i : nodes)
    for (int a = 0; a < 3; ++a) held[std::size_t(3 * i + a)] = 1;
  return held;
}

Eigen::Matrix3Xd newton_static_positions(const PhysicsModel& p, const Eigen::Matrix3Xd& start,
                                         const HeldCoordinates& held, const Eigen::Vector3d& gravity_mm_s2,
                                         double* residual_n) {
  const Model& m = *p.model;
  const int nn = m.num_nodes();
  std::vector<int> dof(std::size_t(3 * nn), -1);
  if (start.cols() != nn || int(held.size()) != 3 * nn)
    throw Error("static Newton solve: the start or the held coordinates have the wrong size");
  int free = 0;
  for (int k = 0; k < 3 * nn; ++k)
    if (!held[std::size_t(k)]) dof[std::size_t(k)] = free++;
  ElementPassOptions o;
  o.damping = false;
  o.rotation = RotationFitSettings{50, 1e-15};
  ElementPassScratch scratch;
  Eigen::Matrix3Xd entry, nf;
  auto forces = [&](const Eigen::Matrix3Xd& x, std::vector<Eigen::Quaterniond>& rot) {
    compute_element_forces(p, x, nullptr, rot, entry, nullptr, o, kThreads, scratch);
    gather_node_forces(p, entry, nf, kThreads);
    for (int i = 0; i < nn; ++i)
      nf.col(i) += p.node_mass[std::size_t(i)] * p.node_gravity_ratio[std::size_t(i)] * gravity_mm_s2;
    return nf;
  };
  // nodes coloured so that no two of a colour share an element: one colour's nodes are moved at
  // once, and each element's entry forces change by its one moved node (27 colours on voxels)
  std::vector<std::vector<int>> node_elements(static_cast<std::size_t>(nn));
  for (int e = 0; e < m.num_elements(); ++e)
    for (int j = m.element_offsets[std::size_t(e)]; j < m.element_offsets[std::size_t(e) + 1]; ++j)
      node_elements[std::size_t(m.element_vertices[std::size_t(j)])].push_back(e);
  std::vector<int> colour(std::size_t(nn), -1);
  int colours = 0;
  for (int i = 0; i < nn; ++i) {
    std::vector<char> taken(std::size_t(colours) + 1, 0);
    for (int e : node_elements[std::size_t(i)])
      for (int j = m.element_offsets[std::size_t(e)]; j < m.element_offsets[std::size_t(e) + 1]; ++j)
        if (const int c = colour[std::size_t(m.element_vertices[std::size_t(j)])]; c >= 0) taken[std::size_t(c)] = 1;
    int c = 0;
    while (taken[std::size_t(c)]) ++c;
    colour[std::size_t(i)] = c;
    colours = std::max(colours, c + 1);
  }
  // the tangent -df/dx at x0 by central differences of the entry forces, rotations warm-started from `at`
  auto tangent = [&](const Eigen::Matrix3Xd& x0, const std::vector<Eigen::Quaterniond>& at) {
    std::vector<Eigen::Triplet<double>> t;
    const double step = 1e-6;
    Eigen::Matrix3Xd plus;
    for (int c = 0; c < colours; ++c)
      for (int a = 0; a < 3; ++a) {
        Eigen::Matrix3Xd x = x0;
        std::vector<Eigen::Quaterniond> rot = at;
        for (int i = 0; i < nn; ++i)
          if (colour[std::size_t(i)] == c) x(a, i) += step;
        compute_element_forces(p, x, nullptr, rot, entry, nullptr, o, kThreads, scratch);
        plus = entry;
        for (int i = 0; i < nn; ++i)
          if (colour[std::size_t(i)] == c) x(a, i) -= 2 * step;
        rot = at;
        compute_element_forces(p, x, nullptr, rot, entry, nullptr, o, kThreads, scratch);
        for (int e = 0; e < m.num_elements(); ++e) {
          const int lo = m.element_offsets[std::size_t(e)], hi = m.element_offsets[std::size_t(e) + 1];
          int moved = -1;
          for (int j = lo; j < hi; ++j)
            if (colour[std::size_t(m.element_vertices[std::size_t(j)])] == c)
              moved = m.element_vertices[std::size_t(j)];
          const int col = moved < 0 ? -1 : dof[std::size_t(3 * moved + a)];
          if (col < 0) continue;
          for (int j = lo; j < hi; ++j) {
            const int i = m.element_vertices[std::size_t(j)], slot = p.entry_slot[std::size_t(j)];
            for (int b = 0; b < 3; ++b)
              if (const int row = dof[std::size_t(3 * i + b)]; row >= 0)
                t.emplace_back(row, col, -(plus(b, slot) - entry(b, slot)) / (2 * step));
          }
        }
      }
    Eigen::SparseMatrix<double> k(free, free);
    k.setFromTriplets(t.begin(), t.end());  // (duplicates summed: an entry from every shared element)
    return Eigen::SparseMatrix<double>(0.5 * (k + Eigen::SparseMatrix<double>(k.transpose())));
  };
  Eigen::Matrix3Xd x = start;
  std::vector<Eigen::Quaterniond> rot(std::size_t(p.num_elements()), Eigen::Quaterniond::Identity());
  Eigen::VectorXd r(free);
  double largest = 0;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver;
  for (int it = 0;; ++it) {
    const Eigen::Matrix3Xd f = forces(x, rot);
    largest = 0;
    for (int i = 0; i < nn; ++i)
      for (int a = 0; a < 3; ++a)
        if (const int row = dof[std::size_t(3 * i + a)]; row >= 0) {
          r(row) = f(a, i);
          largest = std::max(largest, std::abs(f(a, i)));
        }
    if (it < 2) {  // the tangent at the start, then at the first step's (nearly the solution): quadratic from there
      solver.compute(tangent(x, rot));
      if (solver.info() != Eigen::Success)
        throw Error("static Newton solve: the tangent could not be factored (a part held nowhere?)");
    }
    const Eigen::VectorXd dx = solver.solve(r);
    for (int i = 0; i < nn; ++i)
      for (int a = 0; a < 3; ++a)
        if (const int row = dof[std::size_t(3 * i + a)]; row >= 0) x(a, i) += dx(row);
    if (dx.lpNorm<Eigen::Infinity>() < 1e-8) break;  // (the rotation fit's rounding leaves about 3e-10 mm)
    if (it == 30) throw Error("static Newton solve: no convergence in 30 iterations");
  }
  if (residual_n) *residual_n = largest;
  return x;
}

}  // namespace vx::cases
