#include "model/gradational_builder.h"

#include <array>
#include <chrono>
#include <limits>
#include <string>

#include "base/error.h"
#include "model/gradational_builder_2d.h"

namespace vx {
namespace {

/// A cube-shaped grid of 0/1 cells at one level, x fastest; cells outside read as 0.
struct CellGrid {
  Eigen::Vector3i dims{0, 0, 0};
  std::vector<std::uint8_t> cells;

  [[nodiscard]] std::int64_t index(int i, int j, int k) const {
    return i + std::int64_t(dims.x()) * (j + std::int64_t(dims.y()) * k);
  }
  [[nodiscard]] std::uint8_t at(int i, int j, int k) const {
    if (i < 0 || j < 0 || k < 0 || i >= dims.x() || j >= dims.y() || k >= dims.z()) return 0;
    return cells[std::size_t(index(i, j, k))];
  }
  [[nodiscard]] bool empty() const {
    for (auto c : cells)
      if (c) return false;
    return true;
  }
};

/// An element while building: a 2x2x2 group of cells of width w voxels.
struct ElementSeed {
  Eigen::Vector3i anchor;  ///< lowest lattice corner (voxel units)
  int level;
  int width;               ///< cell width, voxels
  std::uint8_t cells;      ///< bit cx + 2cy + 4cz set when that cell is covered
};

constexpr int cell_bit(int cx, int cy, int cz) { return cx + 2 * cy + 4 * cz; }

/// Local points of a group are (px,py,pz) in 0..2 per axis (cell corners); bit px+3py+9pz.
constexpr int point_bit(int px, int py, int pz) { return px + 3 * py + 9 * pz; }

/// Bits of the cells (within a group) whose closed extent contains local coordinate p along one
/// axis: p = 0 -> cell 0, p = 1 -> cells 0 and 1, p = 2 -> cell 1. Returned as a 2-bit set.
constexpr int cells_at(int p) { return p == 0 ? 1 : (p == 1 ? 3 : 2); }


/// True when local point p is a corner of the union of the covered cells: the 2x2x2 pattern of
/// covered cells around p is not the same along any axis (a flat face, a straight edge, the
/// inside, or nothing at all is the same along some axis).
bool is_corner(std::uint8_t cells, int px, int py, int pz) {
  // occupancy o[dx][dy][dz] of the 8 cells around p (dx = 0: the cell below p along x)
  int o[2][2][2] = {};
  bool any = false;
  for (int dz = 0; dz < 2; ++dz)
    for (int dy = 0; dy < 2; ++dy)
      for (int dx = 0; dx < 2; ++dx) {
        const int cx = px - 1 + dx, cy = py - 1 + dy, cz = pz - 1 + dz;
        const bool in = cx >= 0 && cx < 2 && cy >= 0 && cy < 2 && cz >= 0 && cz < 2;
        o[dx][dy][dz] = in && (cells >> cell_bit(cx, cy, cz) & 1);
        any = any || o[dx][dy][dz];
      }
  if (!any) return false;
  bool same_x = true, same_y = true, same_z = true;
  for (int a = 0; a < 2; ++a)
    for (int b = 0; b < 2; ++b) {
      same_x = same_x && o[0][a][b] == o[1][a][b];
      same_y = same_y && o[a][0][b] == o[a][1][b];
      same_z = same_z && o[a][b][0] == o[a][b][1];
    }
  return !(same_x || same_y || same_z);
}

/// The group's local points that are vertices by the element's own rules: corners of the union
/// of its cells, and every cell corner on a surface-boundary face (a face between a covered cell
/// and a 0-cell of the current level grid; the grid border counts as 0). Returns a 27-bit set.
std::uint32_t own_vertex_points(const CellGrid& grid, int gx, int gy, int gz, std::uint8_t cells) {
  std::uint32_t points = 0;
  for (int pz = 0; pz < 3; ++pz)
    for (int py = 0; py < 3; ++py)
      for (int px = 0; px < 3; ++px)
        if (is_corner(cells, px, py, pz)) points |= 1u << point_bit(px, py, pz);
  static constexpr int face_dir[6][3] = {{-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}};
  for (int cz = 0; cz < 2; ++cz)
    for (int cy = 0; cy < 2; ++cy)
      for (int cx = 0; cx < 2; ++cx) {
        if (!(cells >> cell_bit(cx, cy, cz) & 1)) continue;
        const int i = 2 * gx + cx, j = 2 * gy + cy, k = 2 * gz + cz;
        for (const auto& d : face_dir) {
          if (grid.at(i + d[0], j + d[1], k + d[2])) continue;
          // the face's 4 corners: along the face normal the corner coordinate is fixed
          for (int b = 0; b < 2; ++b)
            for (int a = 0; a < 2; ++a) {
              int p[3];
              const int axis = d[0] ? 0 : (d[1] ? 1 : 2);
              const int u = (axis + 1) % 3, v = (axis + 2) % 3;
              const int c[3] = {cx, cy, cz};
              p[axis] = c[axis] + (d[axis] > 0 ? 1 : 0);
              p[u] = c[u] + a;
              p[v] = c[v] + b;
              points |= 1u << point_bit(p[0], p[1], p[2]);
            }
        }
      }
  return points;
}

/// Halves a cell grid: a new cell is 1 when all 8 cells under it are 1 (outside counts as 0).
CellGrid halve(const CellGrid& fine) {
  CellGrid coarse;
  coarse.dims = (fine.dims.array() + 1) / 2;
  coarse.cells.assign(std::size_t(coarse.dims.prod()), 0);
  for (int k = 0; k < coarse.dims.z(); ++k)
    for (int j = 0; j < coarse.dims.y(); ++j)
      for (int i = 0; i < coarse.dims.x(); ++i) {
        bool all = true;
        for (int c = 0; c < 8 && all; ++c) all = fine.at(2 * i + (c & 1), 2 * j + (c >> 1 & 1), 2 * k + (c >> 2 & 1));
        coarse.cells[std::size_t(coarse.index(i, j, k))] = all;
      }
  return coarse;
}

/// Node ids on the voxel lattice (dims + 1 per axis): -1 = no node.
struct NodeLattice {
  Eigen::Vector3i dims;  ///< lattice points per axis
  std::vector<std::int32_t> id;

  explicit NodeLattice(const Eigen::Vector3i& voxel_dims)
      : dims(voxel_dims.array() + 1), id(std::size_t(std::int64_t(dims.x()) * dims.y() * dims.z()), -1) {}
  [[nodiscard]] std::int64_t index(int i, int j, int k) const {
    return i + std::int64_t(dims.x()) * (j + std::int64_t(dims.y()) * k);
  }
  void mark(const Eigen::Vector3i& a) { id[std::size_t(index(a.x(), a.y(), a.z()))] = 0; }
};

/// Numbers the marked lattice points in lattice order and fills the node arrays.
void number_nodes(NodeLattice& lattice, const VoxelGrid& grid, Model& model) {
  builder::number_marked(lattice.id, model, "resample the volume to larger voxels (--voxel MM)");
  const Eigen::Vector3i& d = lattice.dims;
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const std::int32_t n = lattice.id[std::size_t(lattice.index(i, j, k))];
        if (n < 0) continue;
        const Eigen::Vector3i a(i, j, k);
        model.node_lattice.col(n) = a;
        model.rest_positions.col(n) = grid.geometry().lattice_to_lps(a);
        // a node is on the surface when the 8 voxels around it are not all tissue
        bool all = true;
        for (int c = 0; c < 8 && all; ++c) all = grid.at(i - 1 + (c & 1), j - 1 + (c >> 1 & 1), k - 1 + (c >> 2 & 1));
        model.node_surface[std::size_t(n)] = all ? 0 : 1;
      }
}

/// Appends the element: its vertices are all nodes on the closed region of its covered cells,
/// in lattice order (nodes are numbered in lattice order, and the box is walked in that order).
void append_element(const ElementSeed& s, const NodeLattice& lattice, Model& model) {
  const int w = s.width, n = 2 * w;
  // per-axis: which of the two cells' closures contain local fine coordinate q (0..2w)
  auto axis_cells = [w](int q) { return q < w ? 1 : (q == w ? 3 : 2); };
  for (int qz = 0; qz <= n; ++qz) {
    const int sz = axis_cells(qz);
    const bool plane_z = qz % w == 0;
    for (int qy = 0; qy <= n; ++qy) {
      const int sy = axis_cells(qy);
      const bool plane_y = qy % w == 0;
      const std::int64_t row = lattice.index(s.anchor.x(), s.anchor.y() + qy, s.anchor.z() + qz);
      for (int qx = 0; qx <= n; ++qx) {
        // nodes lie on cell faces: skip points strictly inside a cell (on no plane)
        if (!(plane_z || plane_y || qx % w == 0)) {
          qx = (qx / w + 1) * w - 1;  // jump to the next plane along x
          continue;
        }
        const int sx = axis_cells(qx);
        bool on_cell = false;
        for (int c = 0; c < 8 && !on_cell; ++c)
          on_cell = (s.cells >> c & 1) && (sx >> (c & 1) & 1) && (sy >> (c >> 1 & 1) & 1) && (sz >> (c >> 2 & 1) & 1);
        if (!on_cell) continue;
        const std::int32_t id = lattice.id[std::size_t(row + qx)];
        if (id >= 0) model.element_vertices.push_back(id);
      }
    }
  }
  builder::close_element(s, model);
}

/// The paper's procedure (docs/model.md section 3): shells of elements, level by level.
std::vector<ElementSeed> gradational_seeds(const VoxelGrid& grid, int max_level, NodeLattice& lattice,
                                           BuildReport& report, const std::function<void(double)>& progress) {
  std::vector<ElementSeed> seeds;
  CellGrid fine;
  fine.dims = grid.dims();
  fine.cells = grid.data();
  builder::level_by_level(
      std::move(fine), grid.count(), max_level, report, progress,
      [&](CellGrid& cells, int level, bool take_all, std::int64_t& covered) {
        const int w = 1 << level;
        const Eigen::Vector3i groups = (cells.dims.array() + 1) / 2;
        std::int64_t on_level = 0;
        std::vector<std::int64_t> taken;  // indices of groups that got an element
        // (1) scan 2x2x2 groups; a group with a 1-cell gets an element when one of its cells is a
        // 0-cell or a 1-cell touches the boundary (a face against a 0-cell; outside counts as 0)
        for (int gz = 0; gz < groups.z(); ++gz)
          for (int gy = 0; gy < groups.y(); ++gy)
            for (int gx = 0; gx < groups.x(); ++gx) {
              std::uint8_t mask = 0;
              for (int c = 0; c < 8; ++c)
                if (cells.at(2 * gx + (c & 1), 2 * gy + (c >> 1 & 1), 2 * gz + (c >> 2 & 1))) mask |= std::uint8_t(1u << c);
              if (mask == 0) continue;
              bool boundary = take_all || mask != 0xFF;
              for (int c = 0; c < 8 && !boundary; ++c) {
                const int i = 2 * gx + (c & 1), j = 2 * gy + (c >> 1 & 1), k = 2 * gz + (c >> 2 & 1);
                // only faces leaving the group can meet a 0-cell here (the group is full)
                const int di = (c & 1) ? 1 : -1, dj = (c >> 1 & 1) ? 1 : -1, dk = (c >> 2 & 1) ? 1 : -1;
                boundary = !cells.at(i + di, j, k) || !cells.at(i, j + dj, k) || !cells.at(i, j, k + dk);
              }
              if (!boundary) continue;
              const std::uint32_t points = own_vertex_points(cells, gx, gy, gz, mask);
              const Eigen::Vector3i anchor = Eigen::Vector3i(gx, gy, gz) * (2 * w);
              for (int p = 0; p < 27; ++p)
                if (points >> p & 1) lattice.mark(anchor + Eigen::Vector3i(p % 3, p / 3 % 3, p / 9) * w);
              seeds.push_back({anchor, level, w, mask});
              taken.push_back(gx + std::int64_t(groups.x()) * (gy + std::int64_t(groups.y()) * gz));
              covered += std::int64_t(__builtin_popcount(mask)) * w * w * w;
              ++on_level;
            }
        // (2) cells that received an element become 0
        for (std::int64_t g : taken) {
          const int gx = int(g % groups.x()), gy = int(g / groups.x() % groups.y()), gz = int(g / groups.x() / groups.y());
          for (int c = 0; c < 8; ++c) {
            const int i = 2 * gx + (c & 1), j = 2 * gy + (c >> 1 & 1), k = 2 * gz + (c >> 2 & 1);
            if (i < cells.dims.x() && j < cells.dims.y() && k < cells.dims.z()) cells.cells[std::size_t(cells.index(i, j, k))] = 0;
          }
        }
        return on_level;
      },
      halve);
  return seeds;
}

/// One 8-vertex element per tissue voxel.
std::vector<ElementSeed> voxel_seeds(const VoxelGrid& grid, NodeLattice& lattice, BuildReport& report) {
  std::vector<ElementSeed> seeds;
  const Eigen::Vector3i& d = grid.dims();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        if (!grid.at(i, j, k)) continue;
        const Eigen::Vector3i a(i, j, k);
        for (int c = 0; c < 8; ++c) lattice.mark(a + Eigen::Vector3i(c & 1, c >> 1 & 1, c >> 2 & 1));
        seeds.push_back({a, 0, 1, 1});
      }
  report.elements_per_level.assign(1, std::int64_t(seeds.size()));
  return seeds;
}

}  // namespace

Model build_model(const VoxelGrid& grid, const BuildSettings& settings, BuildReport* report_out) {
  if (settings.dimensions != 2 && settings.dimensions != 3)
    throw Error("build settings: dimensions " + std::to_string(settings.dimensions) + " must be 2 or 3");
  const bool flat = settings.dimensions == 2;
  const auto start = std::chrono::steady_clock::now();
  const Eigen::Vector3i& d = grid.dims();
  if ((d.array() <= 0).any() || std::int64_t(grid.data().size()) != grid.geometry().voxel_count())
    throw Error("the voxel grid is empty or inconsistent (dims " + std::to_string(d.x()) + "x" +
                std::to_string(d.y()) + "x" + std::to_string(d.z()) + ")");
  if (flat && d.z() != 1)
    throw Error("a 2D model needs a grid one voxel thick (one slice); this grid has " + std::to_string(d.z()) +
                " slices");
  if ((grid.geometry().spacing_mm.array() <= 0).any() || !grid.geometry().spacing_mm.allFinite())
    throw Error(flat ? "the voxel spacing (and the slice thickness) must be positive and finite"
                     : "the voxel spacing must be positive and finite");
  BuildReport report;
  report.tissue_voxels = grid.count();
  if (report.tissue_voxels == 0)
    throw Error(std::string(flat ? "the slice" : "the voxel grid") +
                " holds no tissue: nothing to build (check the HU threshold)");
  const auto finish = [&](Model model) {
    if (settings.progress) settings.progress(1.0);
    report.build_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (report_out) *report_out = report;
    return model;
  };
  if (flat) return finish(build_model_2d(grid, settings, report));

  Model model;
  model.layout = settings.layout;
  model.grid = grid.geometry();
  NodeLattice lattice(d);
  const std::vector<ElementSeed> seeds = builder::layout_seeds(
      settings, [&](int max_level) { return gradational_seeds(grid, max_level, lattice, report, settings.progress); },
      [&] { return voxel_seeds(grid, lattice, report); });
  number_nodes(lattice, grid, model);
  builder::store_seeds(
      seeds, model, settings.progress, "resample the volume to larger voxels (--voxel MM)",
      [](const ElementSeed& s) { return s.anchor; }, [&](const ElementSeed& s) { append_element(s, lattice, model); });
  model.finalize();
  return finish(std::move(model));
}

}  // namespace vx
