// The 2D (quadtree) gradational builder (docs/model.md section 12.1): the paper's procedure
// (its 3.1 names 2 x 2 groups for the 2D model) on one slice. It is gradational_builder.cpp
// with squares for cubes: 2x2 groups of cells, edges for faces, rings for shells, polygons for
// polyhedra; the same rules decide which group gets an element, where vertices go and how
// levels share their nodes.

#include <algorithm>
#include <limits>
#include <string>

#include "base/error.h"
#include "model/gradational_builder_2d.h"

namespace vx {
namespace {

/// A square grid of 0/1 cells at one level, x fastest; cells outside read as 0.
struct CellGrid2 {
  int nx{0}, ny{0};
  std::vector<std::uint8_t> cells;

  [[nodiscard]] std::int64_t index(int i, int j) const { return i + std::int64_t(nx) * j; }
  [[nodiscard]] std::uint8_t at(int i, int j) const {
    if (i < 0 || j < 0 || i >= nx || j >= ny) return 0;
    return cells[std::size_t(index(i, j))];
  }
  [[nodiscard]] bool empty() const {
    for (auto c : cells)
      if (c) return false;
    return true;
  }
};

/// An element while building: a 2x2 group of cells of width w voxels.
struct Seed2 {
  int ax, ay;          ///< lowest lattice corner (voxel units)
  int level;
  int width;           ///< cell width, voxels
  std::uint8_t cells;  ///< bit cx + 2cy set when that cell is covered
};

/// True when local point (px, py), 0..2 each, is a corner of the union of the covered cells:
/// the 2x2 pattern of covered cells around it is the same along neither axis (a straight edge,
/// the inside or nothing at all is the same along one).
bool is_corner_2d(std::uint8_t cells, int px, int py) {
  int o[2][2] = {};
  bool any = false;
  for (int dy = 0; dy < 2; ++dy)
    for (int dx = 0; dx < 2; ++dx) {
      const int cx = px - 1 + dx, cy = py - 1 + dy;
      o[dx][dy] = cx >= 0 && cx < 2 && cy >= 0 && cy < 2 && (cells >> (cx + 2 * cy) & 1);
      any = any || o[dx][dy];
    }
  if (!any) return false;
  const bool same_x = o[0][0] == o[1][0] && o[0][1] == o[1][1];
  const bool same_y = o[0][0] == o[0][1] && o[1][0] == o[1][1];
  return !(same_x || same_y);
}

/// The group's local points (bit px + 3 py) that are vertices by the element's own rules:
/// corners of the union of its cells, and both ends of every surface-boundary edge (an edge
/// between a covered cell and a 0-cell of the current level grid; the border counts as 0).
std::uint32_t own_vertex_points_2d(const CellGrid2& grid, int gx, int gy, std::uint8_t cells) {
  std::uint32_t points = 0;
  for (int py = 0; py < 3; ++py)
    for (int px = 0; px < 3; ++px)
      if (is_corner_2d(cells, px, py)) points |= 1u << (px + 3 * py);
  static constexpr int edge_dir[4][2] = {{-1, 0}, {1, 0}, {0, -1}, {0, 1}};
  for (int cy = 0; cy < 2; ++cy)
    for (int cx = 0; cx < 2; ++cx) {
      if (!(cells >> (cx + 2 * cy) & 1)) continue;
      const int i = 2 * gx + cx, j = 2 * gy + cy;
      for (const auto& d : edge_dir) {
        if (grid.at(i + d[0], j + d[1])) continue;
        // the edge's two ends: along its normal the coordinate is fixed
        for (int a = 0; a < 2; ++a) {
          const int px = d[0] ? cx + (d[0] > 0 ? 1 : 0) : cx + a;
          const int py = d[1] ? cy + (d[1] > 0 ? 1 : 0) : cy + a;
          points |= 1u << (px + 3 * py);
        }
      }
    }
  return points;
}

/// Halves a cell grid: a new cell is 1 when all 4 cells under it are 1 (outside counts as 0).
CellGrid2 halve_2d(const CellGrid2& fine) {
  CellGrid2 coarse;
  coarse.nx = (fine.nx + 1) / 2;
  coarse.ny = (fine.ny + 1) / 2;
  coarse.cells.assign(std::size_t(coarse.nx) * std::size_t(coarse.ny), 0);
  for (int j = 0; j < coarse.ny; ++j)
    for (int i = 0; i < coarse.nx; ++i)
      coarse.cells[std::size_t(coarse.index(i, j))] =
          fine.at(2 * i, 2 * j) && fine.at(2 * i + 1, 2 * j) && fine.at(2 * i, 2 * j + 1) && fine.at(2 * i + 1, 2 * j + 1);
  return coarse;
}

/// Node ids on the pixel lattice ((nx + 1) x (ny + 1) points): -1 = no node.
struct NodeLattice2 {
  int lx, ly;
  std::vector<std::int32_t> id;

  NodeLattice2(int nx, int ny) : lx(nx + 1), ly(ny + 1), id(std::size_t(lx) * std::size_t(ly), -1) {}
  [[nodiscard]] std::int64_t index(int i, int j) const { return i + std::int64_t(lx) * j; }
  void mark(int i, int j) { id[std::size_t(index(i, j))] = 0; }
};

/// Numbers the marked lattice points in lattice order and fills the node arrays.
void number_nodes_2d(NodeLattice2& lattice, const VoxelGrid& grid, Model& model) {
  builder::number_marked(lattice.id, model, "resample the image to larger pixels (--voxel MM)");
  for (int j = 0; j < lattice.ly; ++j)
    for (int i = 0; i < lattice.lx; ++i) {
      const std::int32_t n = lattice.id[std::size_t(lattice.index(i, j))];
      if (n < 0) continue;
      const Eigen::Vector3i a(i, j, 0);
      model.node_lattice.col(n) = a;
      model.rest_positions.col(n) = node_position(grid.geometry(), a, 2);
      // a node is on the outline when the 4 pixels around it are not all tissue
      const bool all = grid.at(i - 1, j - 1, 0) && grid.at(i, j - 1, 0) && grid.at(i - 1, j, 0) && grid.at(i, j, 0);
      model.node_surface[std::size_t(n)] = all ? 0 : 1;
    }
}

/// Appends the element: its vertices are all nodes on the closed region of its covered cells,
/// in lattice order.
void append_element_2d(const Seed2& s, const NodeLattice2& lattice, Model& model) {
  const int w = s.width, n = 2 * w;
  // per axis: which of the two cells' closures contain local fine coordinate q (0..2w)
  const auto axis_cells = [w](int q) { return q < w ? 1 : (q == w ? 3 : 2); };
  for (int qy = 0; qy <= n; ++qy) {
    const int sy = axis_cells(qy);
    const bool line_y = qy % w == 0;
    const std::int64_t row = lattice.index(s.ax, s.ay + qy);
    for (int qx = 0; qx <= n; ++qx) {
      // nodes lie on cell edges: skip points strictly inside a cell
      if (!line_y && qx % w != 0) {
        qx = (qx / w + 1) * w - 1;
        continue;
      }
      const int sx = axis_cells(qx);
      bool on_cell = false;
      for (int c = 0; c < 4 && !on_cell; ++c)
        on_cell = (s.cells >> c & 1) && (sx >> (c & 1) & 1) && (sy >> (c >> 1 & 1) & 1);
      if (!on_cell) continue;
      const std::int32_t id = lattice.id[std::size_t(row + qx)];
      if (id >= 0) model.element_vertices.push_back(id);
    }
  }
  builder::close_element(s, model);
}

/// The paper's procedure in 2D: rings of elements, level by level.
std::vector<Seed2> gradational_seeds_2d(const VoxelGrid& grid, int max_level, NodeLattice2& lattice,
                                        BuildReport& report, const std::function<void(double)>& progress) {
  std::vector<Seed2> seeds;
  CellGrid2 fine;
  fine.nx = grid.dims().x();
  fine.ny = grid.dims().y();
  fine.cells = grid.data();
  builder::level_by_level(
      std::move(fine), grid.count(), max_level, report, progress,
      [&](CellGrid2& cells, int level, bool take_all, std::int64_t& covered) {
        const int w = 1 << level;
        const int gnx = (cells.nx + 1) / 2, gny = (cells.ny + 1) / 2;
        std::int64_t on_level = 0;
        std::vector<std::int64_t> taken;
        // (1) scan 2x2 groups; a group with a 1-cell gets an element when one of its cells is a
        // 0-cell or a 1-cell has an edge against a 0-cell (outside counts as 0)
        for (int gy = 0; gy < gny; ++gy)
          for (int gx = 0; gx < gnx; ++gx) {
            std::uint8_t mask = 0;
            for (int c = 0; c < 4; ++c)
              if (cells.at(2 * gx + (c & 1), 2 * gy + (c >> 1))) mask |= std::uint8_t(1u << c);
            if (mask == 0) continue;
            bool boundary = take_all || mask != 0x0F;
            for (int c = 0; c < 4 && !boundary; ++c) {
              const int i = 2 * gx + (c & 1), j = 2 * gy + (c >> 1);
              // the group is full: only edges leaving it can meet a 0-cell
              const int di = (c & 1) ? 1 : -1, dj = (c >> 1) ? 1 : -1;
              boundary = !cells.at(i + di, j) || !cells.at(i, j + dj);
            }
            if (!boundary) continue;
            const std::uint32_t points = own_vertex_points_2d(cells, gx, gy, mask);
            const int ax = gx * 2 * w, ay = gy * 2 * w;
            for (int p = 0; p < 9; ++p)
              if (points >> p & 1) lattice.mark(ax + (p % 3) * w, ay + (p / 3) * w);
            seeds.push_back({ax, ay, level, w, mask});
            taken.push_back(gx + std::int64_t(gnx) * gy);
            covered += std::int64_t(__builtin_popcount(mask)) * w * w;
            ++on_level;
          }
        // (2) cells that received an element become 0
        for (std::int64_t g : taken) {
          const int gx = int(g % gnx), gy = int(g / gnx);
          for (int c = 0; c < 4; ++c) {
            const int i = 2 * gx + (c & 1), j = 2 * gy + (c >> 1);
            if (i < cells.nx && j < cells.ny) cells.cells[std::size_t(cells.index(i, j))] = 0;
          }
        }
        return on_level;
      },
      halve_2d);
  return seeds;
}

/// One 4-vertex element per tissue pixel.
std::vector<Seed2> pixel_seeds(const VoxelGrid& grid, NodeLattice2& lattice, BuildReport& report) {
  std::vector<Seed2> seeds;
  for (int j = 0; j < grid.dims().y(); ++j)
    for (int i = 0; i < grid.dims().x(); ++i) {
      if (!grid.at(i, j, 0)) continue;
      for (int c = 0; c < 4; ++c) lattice.mark(i + (c & 1), j + (c >> 1));
      seeds.push_back({i, j, 0, 1, 1});
    }
  report.elements_per_level.assign(1, std::int64_t(seeds.size()));
  return seeds;
}

}  // namespace

Model build_model_2d(const VoxelGrid& grid, const BuildSettings& settings, BuildReport& report) {
  const Eigen::Vector3i& d = grid.dims();
  Model model;
  model.layout = settings.layout;
  model.grid = grid.geometry();
  model.dimensions = 2;
  NodeLattice2 lattice(d.x(), d.y());
  const std::vector<Seed2> seeds = builder::layout_seeds(
      settings,
      [&](int max_level) { return gradational_seeds_2d(grid, max_level, lattice, report, settings.progress); },
      [&] { return pixel_seeds(grid, lattice, report); });
  number_nodes_2d(lattice, grid, model);
  builder::store_seeds(
      seeds, model, settings.progress, "resample the image to larger pixels (--voxel MM)",
      [](const Seed2& s) { return Eigen::Vector3i(s.ax, s.ay, 0); },
      [&](const Seed2& s) { append_element_2d(s, lattice, model); });
  // each element's vertices around its boundary, counter-clockwise (slice_element_parts), so
  // that a polygon through the vertex list in order is the element (the model file's cells)
  for (int e = 0; e < model.num_elements(); ++e) {
    const int b = model.element_offsets[std::size_t(e)], n = model.element_offsets[std::size_t(e) + 1] - b;
    std::vector<std::int32_t> order;
    order.reserve(std::size_t(n));
    for (const SlicePart& part : slice_element_parts(model, e))
      for (const int node : part.ring)
        if (std::find(order.begin(), order.end(), node) == order.end()) order.push_back(node);
    for (int j = b; j < b + n; ++j)  // (every vertex lies on the boundary; kept whatever happens)
      if (std::find(order.begin(), order.end(), model.element_vertices[std::size_t(j)]) == order.end())
        order.push_back(model.element_vertices[std::size_t(j)]);
    // start at the group's centre when it is a vertex (the inner corner of an L, the point where
    // two diagonal cells touch): an L is star-shaped from there, so the fan of triangles from the
    // first point that VTK draws a polygon with covers it exactly
    const int w = model.element_cell_voxels[std::size_t(e)];
    const Eigen::Vector3i centre = model.element_anchor.col(e) + Eigen::Vector3i(w, w, 0);
    for (std::size_t k = 0; k < order.size(); ++k)
      if (model.node_lattice.col(order[k]) == centre) {
        std::rotate(order.begin(), order.begin() + std::ptrdiff_t(k), order.end());
        break;
      }
    std::copy(order.begin(), order.end(), model.element_vertices.begin() + b);
  }
  model.finalize();
  return model;
}

}  // namespace vx
