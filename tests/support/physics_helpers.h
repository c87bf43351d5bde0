#pragma once
// Hand-made models and small utilities for the physics tests (elements, integrators,
// calibration): one 8-vertex cube, a block of cubes, one element with arbitrary vertices,
// and voxel blocks for build_model (balls: model/voxel_shapes.h).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <memory>
#include <random>
#include <vector>

#include "model/model.h"
#include "model/voxel_grid.h"
#include "physics/physics_model.h"
#include "sim/state.h"

namespace vx::testing {

/// A block of nx x ny x nz voxel-level elements (8-vertex cubes of edge h mm), built by hand
/// (not by build_model): nodes on the lattice, x fastest.
inline Model hand_block(int nx, int ny, int nz, double h = 1.0) {
  Model m;
  m.layout = Layout::voxel;
  m.grid.dims = {nx, ny, nz};
  m.grid.spacing_mm = Eigen::Vector3d::Constant(h);
  m.grid.origin_mm = Eigen::Vector3d::Constant(0.5 * h);  // voxel (0,0,0) centre: corner 0 at the origin
  const int lx = nx + 1, ly = ny + 1, lz = nz + 1;
  const auto node = [&](int i, int j, int k) { return i + lx * (j + ly * k); };
  m.rest_positions.resize(3, lx * ly * lz);
  m.node_lattice.resize(3, lx * ly * lz);
  m.node_surface.assign(std::size_t(lx * ly * lz), 0);
  for (int k = 0; k < lz; ++k)
    for (int j = 0; j < ly; ++j)
      for (int i = 0; i < lx; ++i) {
        const int n = node(i, j, k);
        m.rest_positions.col(n) = Eigen::Vector3d(i, j, k) * h;
        m.node_lattice.col(n) = Eigen::Vector3i(i, j, k);
        m.node_surface[std::size_t(n)] = (i == 0 || j == 0 || k == 0 || i == nx || j == ny || k == nz) ? 1 : 0;
      }
  m.element_offsets.push_back(0);
  m.element_anchor.resize(3, nx * ny * nz);
  int e = 0;
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i, ++e) {
        for (int c = 0; c < 8; ++c) m.element_vertices.push_back(node(i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1)));
        m.element_offsets.push_back(int(m.element_vertices.size()));
        m.element_level.push_back(0);
        m.element_cell_voxels.push_back(1);
        m.element_cells.push_back(1);
        m.element_anchor.col(e) = Eigen::Vector3i(i, j, k);
      }
  m.finalize();
  return m;
}

/// One 8-vertex cube element of edge h mm.
inline Model hand_cube(double h = 1.0) { return hand_block(1, 1, 1, h); }

/// One element whose vertices are the given points (mm); volume = one voxel of edge h.
inline Model hand_element(const Eigen::Matrix3Xd& points, double h = 1.0) {
  Model m;
  m.layout = Layout::voxel;
  m.grid.dims = {1, 1, 1};
  m.grid.spacing_mm = Eigen::Vector3d::Constant(h);
  const int n = int(points.cols());
  m.rest_positions = points;
  m.node_lattice = Eigen::Matrix3Xi::Zero(3, n);
  m.node_surface.assign(std::size_t(n), 1);
  m.element_offsets = {0, n};
  for (int i = 0; i < n; ++i) m.element_vertices.push_back(i);
  m.element_level = {0};
  m.element_cell_voxels = {1};
  m.element_cells = {1};
  m.element_anchor = Eigen::Matrix3Xi::Zero(3, 1);
  m.finalize();
  return m;
}

/// A grid of nx x ny x nz voxels (edge h mm) with tissue in the box [lo, hi) of voxels.
inline VoxelGrid box_grid(const Eigen::Vector3i& dims, const Eigen::Vector3i& lo, const Eigen::Vector3i& hi,
                          double h = 1.0) {
  GridGeometry g;
  g.dims = dims;
  g.spacing_mm = Eigen::Vector3d::Constant(h);
  VoxelGrid grid(g);
  for (int k = lo.z(); k < hi.z(); ++k)
    for (int j = lo.y(); j < hi.y(); ++j)
      for (int i = lo.x(); i < hi.x(); ++i) grid.set(i, j, k, 1);
  return grid;
}

/// A random proper rotation.
inline Eigen::Matrix3d random_rotation(std::mt19937& rng) {
  std::normal_distribution<double> n01(0.0, 1.0);
  Eigen::Quaterniond q(n01(rng), n01(rng), n01(rng), n01(rng));
  q.normalize();
  return q.toRotationMatrix();
}

/// A random 3x3 matrix with entries in [-1, 1].
inline Eigen::Matrix3d random_matrix(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::Matrix3d m;
  for (int i = 0; i < 9; ++i) m(i) = u(rng);
  return m;
}

/// Net elastic (+damping) node forces of the state's current positions/velocities, fits converged.
inline Eigen::Matrix3Xd node_forces(const SimState& s, bool damping = false, double* energy = nullptr) {
  const PhysicsModel& p = *s.physics;
  std::vector<Eigen::Quaterniond> rot = s.rotations;
  Eigen::Matrix3Xd ef(3, p.num_vertex_entries()), nf;
  std::vector<double> en;
  ElementPassScratch scratch;
  ElementPassOptions opt;
  opt.damping = damping;
  opt.energy = energy != nullptr;
  opt.rotation.max_iterations = 200;
  opt.rotation.tolerance = 1e-14;
  const auto st = compute_element_forces(p, s.positions, damping ? &s.velocities : nullptr, rot, ef, &en, opt, 1, scratch);
  if (energy) *energy = st.elastic_energy;
  gather_node_forces(p, ef, nf, 1);
  return nf;
}

}  // namespace vx::testing
