#include "model/model.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "base/error.h"

namespace vx {

const char* to_string(Layout r) {
  switch (r) {
    case Layout::gradational: return "gradational";
    case Layout::uniform: return "uniform";
    case Layout::voxel: return "voxel";
  }
  return "?";
}

Layout parse_layout(const std::string& s) {
  if (s == "gradational") return Layout::gradational;
  if (s == "uniform") return Layout::uniform;
  if (s == "voxel") return Layout::voxel;
  throw Error("unknown resolution '" + s + "': use gradational, uniform or voxel");
}

int Model::num_surface_nodes() const {
  return int(std::count(node_surface.begin(), node_surface.end(), std::uint8_t(1)));
}

int Model::num_levels() const {
  int top = -1;
  for (auto l : element_level) top = std::max(top, int(l));
  return top + 1;
}

std::vector<std::int64_t> Model::elements_per_level() const {
  std::vector<std::int64_t> counts(std::size_t(num_levels()), 0);
  for (auto l : element_level) ++counts[std::size_t(l)];
  return counts;
}

std::int64_t Model::covered_voxels() const {
  std::int64_t n = 0;
  for (int e = 0; e < num_elements(); ++e) {
    const std::int64_t w = element_cell_voxels[e];
    n += std::int64_t(__builtin_popcount(element_cells[e])) * w * w * cell_depth_voxels(int(w));
  }
  return n;
}

double Model::total_volume_mm3() const {
  double v = 0;
  for (double x : element_volume_mm3) v += x;
  return v;
}

void Model::finalize() {
  const int ne = num_elements();
  rest_offsets.resize(3, num_vertex_entries());
  rest_centroids.resize(3, ne);
  element_volume_mm3.assign(std::size_t(ne), 0.0);
  element_size_mm.assign(std::size_t(ne), 0.0);
  const double voxel_mm3 = grid.voxel_volume_mm3();
  // the element's edge: in-plane for a 2D model (the slice thickness is its depth, not its size)
  const double voxel_edge_mm =
      is_2d() ? std::sqrt(grid.spacing_mm.x() * grid.spacing_mm.y()) : std::cbrt(voxel_mm3);
  for (int e = 0; e < ne; ++e) {
    const int b = element_offsets[e], n = element_offsets[e + 1] - b;
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    for (int i = 0; i < n; ++i) c += rest_positions.col(element_vertices[b + i]);
    c /= double(n);
    rest_centroids.col(e) = c;
    for (int i = 0; i < n; ++i) rest_offsets.col(b + i) = rest_positions.col(element_vertices[b + i]) - c;
    const double w = element_cell_voxels[e];
    element_volume_mm3[e] = __builtin_popcount(element_cells[e]) * w * w * cell_depth_voxels(int(w)) * voxel_mm3;
    element_size_mm[e] = element_edge_voxels(e) * voxel_edge_mm;
  }
}

namespace {

/// Edge-connected parts of a 2x2 cell mask (bit cx + 2 cy), each as a mask.
std::vector<std::uint8_t> cell_parts(std::uint8_t mask) {
  std::vector<std::uint8_t> parts;
  std::uint8_t left = mask & 0x0F;
  while (left) {
    std::uint8_t part = std::uint8_t(left & -left);  // lowest cell
    for (bool grew = true; grew;) {
      grew = false;
      for (int c = 0; c < 4; ++c) {
        if (!((left >> c) & 1) || ((part >> c) & 1)) continue;
        // edge neighbours of cell c: flip x (c ^ 1) or flip y (c ^ 2)
        if (((part >> (c ^ 1)) & 1) || ((part >> (c ^ 2)) & 1)) {
          part = std::uint8_t(part | (1u << c));
          grew = true;
        }
      }
    }
    parts.push_back(part);
    left = std::uint8_t(left & ~part);
  }
  return parts;
}

/// The boundary of the part as corner points (cell units) in counter-clockwise order.
std::vector<Eigen::Vector2i> part_loop(std::uint8_t part) {
  // directed edges of every cell, counter-clockwise; an edge shared by two cells of the part
  // appears once each way and cancels
  std::vector<std::pair<Eigen::Vector2i, Eigen::Vector2i>> edges;
  for (int c = 0; c < 4; ++c) {
    if (!((part >> c) & 1)) continue;
    const Eigen::Vector2i o(c & 1, (c >> 1) & 1);
    const std::array<Eigen::Vector2i, 4> k = {o, o + Eigen::Vector2i(1, 0), o + Eigen::Vector2i(1, 1),
                                              o + Eigen::Vector2i(0, 1)};
    for (int i = 0; i < 4; ++i) {
      const auto a = k[std::size_t(i)], b = k[std::size_t((i + 1) % 4)];
      const auto twin = std::find_if(edges.begin(), edges.end(), [&](const auto& e) { return e.first == b && e.second == a; });
      if (twin != edges.end())
        edges.erase(twin);
      else
        edges.emplace_back(a, b);
    }
  }
  std::vector<Eigen::Vector2i> loop;
  if (edges.empty()) return loop;
  Eigen::Vector2i at = edges.front().first;
  const Eigen::Vector2i start = at;
  do {
    loop.push_back(at);
    const auto next = std::find_if(edges.begin(), edges.end(), [&](const auto& e) { return e.first == at; });
    if (next == edges.end()) break;
    at = next->second;
    edges.erase(next);
  } while (at != start && loop.size() < 16);
  return loop;
}

}  // namespace

std::vector<SlicePart> slice_element_parts(const Model& m, int e) {
  std::vector<SlicePart> parts;
  const int b = m.element_offsets[std::size_t(e)], n = m.element_offsets[std::size_t(e) + 1] - b;
  const int w = m.element_cell_voxels[std::size_t(e)];
  const Eigen::Vector2i anchor = m.element_anchor.col(e).head<2>();
  const std::uint8_t mask = m.layout == Layout::voxel ? std::uint8_t(1) : m.element_cells[std::size_t(e)];
  for (const std::uint8_t cells : cell_parts(mask)) {
    SlicePart part{cells, {}};
    const std::vector<Eigen::Vector2i> loop = part_loop(cells);
    for (std::size_t k = 0; k < loop.size(); ++k) {
      const Eigen::Vector2i a = anchor + w * loop[k], c = anchor + w * loop[(k + 1) % loop.size()];
      const Eigen::Vector2i dir = (c - a) / w;  // unit step along the side
      std::vector<std::pair<int, int>> on_side;  // (distance from a, node)
      for (int j = b; j < b + n; ++j) {
        const Eigen::Vector2i p = m.node_lattice.col(m.element_vertices[std::size_t(j)]).head<2>();
        const Eigen::Vector2i d = p - a;
        const int t = d.dot(dir);
        if (t >= 0 && t < w && d == t * dir) on_side.emplace_back(t, m.element_vertices[std::size_t(j)]);
      }
      std::sort(on_side.begin(), on_side.end());
      for (const auto& [t, node] : on_side) part.ring.push_back(node);
    }
    parts.push_back(std::move(part));
  }
  return parts;
}

Eigen::Vector3d node_position(const GridGeometry& grid, const Eigen::Vector3i& a, int dimensions) {
  if (dimensions != 2) return grid.lattice_to_lps(a);
  return grid.index_to_lps(Eigen::Vector3d(a.x() - 0.5, a.y() - 0.5, 0.0));
}

std::string Model::validate() const {
  std::ostringstream err;
  const int nn = num_nodes(), ne = num_elements();
  if (dimensions != 2 && dimensions != 3) err << "dimensions is " << dimensions << " (2 or 3); ";
  if (dimensions == 2 && grid.dims.z() != 1) err << "a 2D model's grid must be one voxel thick (dims z " << grid.dims.z() << "); ";
  if (node_lattice.cols() != nn) err << "node_lattice has " << node_lattice.cols() << " columns, expected " << nn << "; ";
  if (int(node_surface.size()) != nn) err << "node_surface size " << node_surface.size() << " != nodes " << nn << "; ";
  if (int(element_level.size()) != ne || int(element_cell_voxels.size()) != ne ||
      int(element_cells.size()) != ne || element_anchor.cols() != ne)
    err << "per-element arrays do not all have " << ne << " entries; ";
  if (!element_offsets.empty() && (element_offsets.front() != 0 || element_offsets.back() != int(element_vertices.size())))
    err << "element_offsets do not span element_vertices; ";
  for (int e = 0; e < ne && err.tellp() == 0; ++e) {
    const int b = element_offsets[e], n = element_offsets[e + 1] - b;
    if (n < (dimensions == 2 ? 3 : 4)) { err << "element " << e << " has " << n << " vertices (< " << (dimensions == 2 ? 3 : 4) << "); "; break; }
    std::vector<int> v(element_vertices.begin() + b, element_vertices.begin() + b + n);
    for (int x : v)
      if (x < 0 || x >= nn) { err << "element " << e << " refers to node " << x << " outside 0.." << nn - 1 << "; "; break; }
    std::sort(v.begin(), v.end());
    if (std::adjacent_find(v.begin(), v.end()) != v.end()) err << "element " << e << " repeats a vertex; ";
    if (element_cells[e] == 0) err << "element " << e << " covers no cell; ";
    if (dimensions == 2 && (element_cells[e] > 0x0F || element_anchor(2, e) != 0))
      err << "element " << e << " of a 2D model has cells or an anchor off the slice; ";
  }
  return err.str();
}

bool same_model(const Model& a, const Model& b, double tol_mm) {
  if (a.layout != b.layout || a.dimensions != b.dimensions || a.num_nodes() != b.num_nodes() || a.num_elements() != b.num_elements())
    return false;
  if (a.grid.dims != b.grid.dims || !a.grid.spacing_mm.isApprox(b.grid.spacing_mm, 1e-12) ||
      (a.grid.origin_mm - b.grid.origin_mm).cwiseAbs().maxCoeff() > tol_mm ||
      (a.grid.direction - b.grid.direction).cwiseAbs().maxCoeff() > 1e-12)
    return false;
  if (a.element_offsets != b.element_offsets || a.element_vertices != b.element_vertices ||
      a.element_level != b.element_level || a.element_cell_voxels != b.element_cell_voxels ||
      a.element_cells != b.element_cells || a.element_anchor != b.element_anchor ||
      a.node_lattice != b.node_lattice || a.node_surface != b.node_surface)
    return false;
  if (a.num_nodes() > 0 && (a.rest_positions - b.rest_positions).cwiseAbs().maxCoeff() > tol_mm) return false;
  if (a.num_vertex_entries() > 0 && (a.rest_offsets - b.rest_offsets).cwiseAbs().maxCoeff() > tol_mm) return false;
  return true;
}

}  // namespace vx
