#pragma once
// Independent checks of a built model, computed from the model's own arrays only
// (not from the builder's code paths): coverage, node sharing, neighbour levels.

#include <gtest/gtest.h>

#include <functional>
#include <string>
#include <unordered_map>
#include <vector>

#include "model/model.h"
#include "model/voxel_grid.h"

namespace vx::testing {

/// A grid of the given size with tissue where `inside(i,j,k)` is true.
inline VoxelGrid make_grid(const Eigen::Vector3i& dims, const std::function<bool(int, int, int)>& inside,
                           double spacing_mm = 1.0) {
  GridGeometry g;
  g.dims = dims;
  g.spacing_mm = Eigen::Vector3d::Constant(spacing_mm);
  VoxelGrid grid(g);
  for (int k = 0; k < dims.z(); ++k)
    for (int j = 0; j < dims.y(); ++j)
      for (int i = 0; i < dims.x(); ++i) grid.set(i, j, k, inside(i, j, k) ? 1 : 0);
  return grid;
}

/// For every voxel, the element covering it (-1 none); fails the test on double coverage.
/// A 2D model's cells are w x w x 1 voxels (its cells have no z bit).
inline std::vector<int> voxel_owner(const Model& m) {
  const Eigen::Vector3i d = m.grid.dims;
  std::vector<int> owner(std::size_t(d.prod()), -1);
  for (int e = 0; e < m.num_elements(); ++e) {
    const int w = m.element_cell_voxels[std::size_t(e)];
    const int depth = m.cell_depth_voxels(w);
    for (int c = 0; c < 8; ++c) {
      if (!(m.element_cells[std::size_t(e)] >> c & 1)) continue;
      if (m.is_2d() && c >= 4) ADD_FAILURE() << "element " << e << " of a 2D model has a cell off the slice";
      const Eigen::Vector3i lo = m.element_anchor.col(e) + Eigen::Vector3i(c & 1, c >> 1 & 1, c >> 2 & 1) * w;
      for (int k = lo.z(); k < lo.z() + depth; ++k)
        for (int j = lo.y(); j < lo.y() + w; ++j)
          for (int i = lo.x(); i < lo.x() + w; ++i) {
            if (i >= d.x() || j >= d.y() || k >= d.z()) {
              ADD_FAILURE() << "element " << e << " covers voxel (" << i << "," << j << "," << k << ") outside the grid";
              continue;
            }
            int& o = owner[std::size_t(i + d.x() * (j + d.y() * k))];
            if (o >= 0) ADD_FAILURE() << "voxel (" << i << "," << j << "," << k << ") covered by elements " << o << " and " << e;
            o = e;
          }
    }
  }
  return owner;
}

/// Every tissue voxel covered by exactly one element, no other voxel covered.
inline void expect_exact_cover(const Model& m, const VoxelGrid& grid) {
  const auto owner = voxel_owner(m);
  std::int64_t wrong = 0;
  for (std::size_t v = 0; v < owner.size(); ++v) wrong += (owner[v] >= 0) != (grid.data()[v] != 0);
  EXPECT_EQ(wrong, 0) << "voxels covered wrongly";
}

/// Every node lying on the closed region of an element is a vertex of it, and every vertex of an
/// element lies on that region (no hanging node missing, no stray vertex).
inline void expect_nodes_shared(const Model& m) {
  const Eigen::Vector3i L = m.grid.dims.array() + 1;
  std::unordered_map<std::int64_t, int> node_at;
  for (int n = 0; n < m.num_nodes(); ++n) {
    const Eigen::Vector3i a = m.node_lattice.col(n);
    node_at[a.x() + std::int64_t(L.x()) * (a.y() + std::int64_t(L.y()) * a.z())] = n;
  }
  std::int64_t missing = 0, stray = 0;
  for (int e = 0; e < m.num_elements(); ++e) {
    const int w = m.element_cell_voxels[std::size_t(e)];
    const Eigen::Vector3i A = m.element_anchor.col(e);
    // a 2D model's lattice is one plane (z = 0): its cells' closures are flat
    const Eigen::Vector3i extent(w, w, m.is_2d() ? 0 : w);
    const auto on_region = [&](const Eigen::Vector3i& a) {
      for (int c = 0; c < 8; ++c) {
        if (!(m.element_cells[std::size_t(e)] >> c & 1)) continue;
        const Eigen::Vector3i lo = A + Eigen::Vector3i(c & 1, c >> 1 & 1, c >> 2 & 1) * w;
        if ((a.array() >= lo.array()).all() && (a.array() <= (lo + extent).array()).all()) return true;
      }
      return false;
    };
    std::vector<int> expected;
    for (int z = 0; z <= 2 * extent.z(); ++z)
      for (int y = 0; y <= 2 * w; ++y)
        for (int x = 0; x <= 2 * w; ++x) {
          const Eigen::Vector3i a = A + Eigen::Vector3i(x, y, z);
          if ((a.array() >= L.array()).any()) continue;
          auto it = node_at.find(a.x() + std::int64_t(L.x()) * (a.y() + std::int64_t(L.y()) * a.z()));
          if (it != node_at.end() && on_region(a)) expected.push_back(it->second);
        }
    std::vector<int> have(m.element_vertices.begin() + m.element_offsets[std::size_t(e)],
                          m.element_vertices.begin() + m.element_offsets[std::size_t(e) + 1]);
    std::sort(expected.begin(), expected.end());
    std::sort(have.begin(), have.end());
    std::vector<int> diff;
    std::set_difference(expected.begin(), expected.end(), have.begin(), have.end(), std::back_inserter(diff));
    missing += std::int64_t(diff.size());
    diff.clear();
    std::set_difference(have.begin(), have.end(), expected.begin(), expected.end(), std::back_inserter(diff));
    stray += std::int64_t(diff.size());
  }
  EXPECT_EQ(missing, 0) << "nodes on an element's region missing from its vertex list";
  EXPECT_EQ(stray, 0) << "vertices off their element's region";
}

/// Face-adjacent tissue voxels belong to elements whose levels differ by at most one.
inline int max_neighbour_level_jump(const Model& m) {
  const auto owner = voxel_owner(m);
  const Eigen::Vector3i d = m.grid.dims;
  int jump = 0;
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const int a = owner[std::size_t(i + d.x() * (j + d.y() * k))];
        if (a < 0) continue;
        const int nb[3] = {i + 1 < d.x() ? owner[std::size_t(i + 1 + d.x() * (j + d.y() * k))] : -1,
                           j + 1 < d.y() ? owner[std::size_t(i + d.x() * (j + 1 + d.y() * k))] : -1,
                           k + 1 < d.z() ? owner[std::size_t(i + d.x() * (j + d.y() * (k + 1)))] : -1};
        for (int b : nb)
          if (b >= 0) jump = std::max(jump, std::abs(m.element_level[std::size_t(a)] - m.element_level[std::size_t(b)]));
      }
  return jump;
}

}  // namespace vx::testing
