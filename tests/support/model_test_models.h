#pragma once
// Small models made by hand (not by the builder) for the model_io and render tests.

#include <Eigen/Geometry>
#include <map>
#include <vector>

#include "model/model.h"

namespace vx::testing {

/// One element to place by hand: a 2x2x2 group of cells `width` voxels wide at lattice `anchor`.
struct HandElement {
  Eigen::Vector3i anchor;
  int width;
  std::uint8_t cells;  ///< bit cx + 2cy + 4cz
  int level;
};

/// A model from hand-placed elements. Nodes: every corner of every covered cell (denser than
/// the builder's rule, still a valid model); each element's vertices are all nodes on its
/// closed region, in lattice order (as the builder orders them).
inline Model make_hand_model(const std::vector<HandElement>& elements, const GridGeometry& grid,
                             Layout layout = Layout::gradational) {
  Model m;
  m.layout = layout;
  m.grid = grid;
  const Eigen::Vector3i L = grid.dims.array() + 1;
  const auto key = [&](const Eigen::Vector3i& a) { return a.z() * std::int64_t(L.y() * L.x()) + a.y() * std::int64_t(L.x()) + a.x(); };
  const auto cell_lo = [](const HandElement& h, int c) {
    return Eigen::Vector3i(h.anchor + Eigen::Vector3i(c & 1, c >> 1 & 1, c >> 2 & 1) * h.width);
  };
  // voxel coverage, for the surface flags
  std::vector<std::uint8_t> covered(std::size_t(grid.voxel_count()), 0);
  std::map<std::int64_t, Eigen::Vector3i> nodes;  // lattice order
  for (const auto& h : elements)
    for (int c = 0; c < 8; ++c) {
      if (!(h.cells >> c & 1)) continue;
      const Eigen::Vector3i lo = cell_lo(h, c);
      for (int k = 0; k < 8; ++k) {
        const Eigen::Vector3i a = lo + Eigen::Vector3i(k & 1, k >> 1 & 1, k >> 2 & 1) * h.width;
        nodes[key(a)] = a;
      }
      for (int z = lo.z(); z < lo.z() + h.width; ++z)
        for (int y = lo.y(); y < lo.y() + h.width; ++y)
          for (int x = lo.x(); x < lo.x() + h.width; ++x)
            covered[std::size_t(x + grid.dims.x() * (y + grid.dims.y() * z))] = 1;
    }
  const auto voxel = [&](int x, int y, int z) {
    if (x < 0 || y < 0 || z < 0 || x >= grid.dims.x() || y >= grid.dims.y() || z >= grid.dims.z()) return false;
    return covered[std::size_t(x + grid.dims.x() * (y + grid.dims.y() * z))] != 0;
  };
  std::map<std::int64_t, int> id;
  m.rest_positions.resize(3, std::int64_t(nodes.size()));
  m.node_lattice.resize(3, std::int64_t(nodes.size()));
  for (const auto& [k, a] : nodes) {
    const int n = int(id.size());
    id[k] = n;
    m.node_lattice.col(n) = a;
    m.rest_positions.col(n) = grid.lattice_to_lps(a);
    bool all = true;
    for (int c = 0; c < 8; ++c) all = all && voxel(a.x() - 1 + (c & 1), a.y() - 1 + (c >> 1 & 1), a.z() - 1 + (c >> 2 & 1));
    m.node_surface.push_back(all ? 0 : 1);
  }
  m.element_offsets.assign(1, 0);
  m.element_anchor.resize(3, std::int64_t(elements.size()));
  for (std::size_t e = 0; e < elements.size(); ++e) {
    const auto& h = elements[e];
    for (const auto& [k, a] : nodes) {
      bool on = false;
      for (int c = 0; c < 8 && !on; ++c) {
        if (!(h.cells >> c & 1)) continue;
        const Eigen::Vector3i lo = cell_lo(h, c);
        on = (a.array() >= lo.array()).all() && (a.array() <= lo.array() + h.width).all();
      }
      if (on) m.element_vertices.push_back(id[k]);
    }
    m.element_offsets.push_back(std::int32_t(m.element_vertices.size()));
    m.element_level.push_back(std::int8_t(h.level));
    m.element_cell_voxels.push_back(h.width);
    m.element_cells.push_back(h.cells);
    m.element_anchor.col(std::int64_t(e)) = h.anchor;
  }
  m.finalize();
  return m;
}

/// An oblique, anisotropic grid geometry (rotation about a skew axis, det +1).
inline GridGeometry oblique_grid(const Eigen::Vector3i& dims) {
  GridGeometry g;
  g.dims = dims;
  g.spacing_mm = {0.5, 0.8, 1.25};
  g.origin_mm = {-120.25, 33.5, 1002.0};
  g.direction = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  return g;
}

}  // namespace vx::testing
