#pragma once
/// @file model.h
/// The immutable elastic model built from a voxel grid (docs/model.md section 3; the layouts: section 1).
/// Many simulation states can share one model; nothing here changes during a simulation.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "model/voxel_grid.h"

namespace vx {

/// Which layout of elements a model uses.
enum class Layout : std::uint8_t {
  gradational,  ///< the paper's layout: level-0 shell at the surface, larger elements inside
  uniform,      ///< every element at level 0 (2x2x2 voxels), same vertex rules
  voxel,        ///< one 8-vertex element per tissue voxel (the fine reference)
};
[[nodiscard]] const char* to_string(Layout r);
/// Parses "gradational", "uniform" or "voxel"; throws vx::Error otherwise.
[[nodiscard]] Layout parse_layout(const std::string& s);

/// The elastic model. Nodes sit on voxel corners (lattice points); an element is a set of
/// nodes (its vertices) covering the tissue cells of one 2x2x2 group of cells at its level.
///
/// Element e covers cells of width `element_cell_voxels[e]` voxels: the 2x2x2 group whose
/// lowest lattice corner is `element_anchor.col(e)`; bit (cx + 2*cy + 4*cz) of
/// `element_cells[e]` says whether cell (cx,cy,cz) of the group is tissue (is covered).
/// Voxel-level elements have cell width 1 and only cell (0,0,0).
///
/// A 2D model (`dimensions == 2`, docs/model.md section 12) is built from a one-voxel-thick
/// grid (dims z = 1: one slice): its elements are 2x2 groups of square cells (quadtree), bits
/// cx + 2*cy of `element_cells`, anchors and node lattice points with z = 0. Its nodes lie on
/// the slice's centre plane (the plane of the voxel centres, spanned by the grid's first two
/// direction axes; `node_position`), so positions stay 3 x nodes in LPS mm; a cell of width w
/// is w x w x 1 voxels, and element volumes are areas times the slice thickness
/// (grid.spacing_mm.z(), the depth of the plane-stress slab).
struct Model {
  Layout layout{Layout::gradational};
  GridGeometry grid;                      ///< geometry of the voxel grid the model was built from
  int dimensions{3};                      ///< 3: a volume model; 2: a slice model (quadtree, planar nodes)

  // nodes
  Eigen::Matrix3Xd rest_positions;        ///< 3 x nodes, LPS mm
  Eigen::Matrix3Xi node_lattice;          ///< 3 x nodes, lattice coordinates (voxel corners)
  std::vector<std::uint8_t> node_surface; ///< nodes: 1 if on the tissue/outside boundary

  // elements (CSR): vertices of e are element_vertices[element_offsets[e] .. element_offsets[e+1])
  std::vector<std::int32_t> element_offsets;   ///< elements + 1
  std::vector<std::int32_t> element_vertices;  ///< vertex entries: node index per entry
  std::vector<std::int8_t> element_level;      ///< elements: level L (cell width 2^L voxels)
  std::vector<std::int32_t> element_cell_voxels; ///< elements: cell width in voxels
  Eigen::Matrix3Xi element_anchor;             ///< 3 x elements, lowest lattice corner of the group
  std::vector<std::uint8_t> element_cells;     ///< elements: mask of covered cells (8 bits)

  // rest shape (derived from the above by finalize())
  Eigen::Matrix3Xd rest_offsets;          ///< 3 x vertex entries: rest vertex minus element centroid, mm
  Eigen::Matrix3Xd rest_centroids;        ///< 3 x elements, mean of the element's rest vertices, mm
  std::vector<double> element_volume_mm3; ///< elements: volume of the covered tissue, mm^3
  std::vector<double> element_size_mm;    ///< elements: edge of the element's cube (element_edge_voxels), mm (geometric mean over axes)

  [[nodiscard]] bool is_2d() const { return dimensions == 2; }
  /// Voxels a cell of width w spans along the grid's third axis: w (3D) or 1 (2D).
  [[nodiscard]] int cell_depth_voxels(int w) const { return dimensions == 2 ? 1 : w; }
  /// Cells of a group: 8 (2x2x2) or 4 (2x2).
  [[nodiscard]] int group_cells() const { return dimensions == 2 ? 4 : 8; }
  /// Unit normal of a 2D model's plane (the grid's third direction axis), LPS.
  [[nodiscard]] Eigen::Vector3d plane_normal() const { return grid.direction.col(2).normalized(); }

  [[nodiscard]] int num_nodes() const { return int(rest_positions.cols()); }
  [[nodiscard]] int num_elements() const {
    return element_offsets.empty() ? 0 : int(element_offsets.size()) - 1;
  }
  [[nodiscard]] std::int64_t num_vertex_entries() const { return std::int64_t(element_vertices.size()); }
  [[nodiscard]] int num_vertices(int e) const { return element_offsets[e + 1] - element_offsets[e]; }
  /// Edge of element e's cube in voxels: 2 cells of element_cell_voxels[e], or the one voxel
  /// of a voxel-layout element.
  [[nodiscard]] int element_edge_voxels(int e) const {
    return (layout == Layout::voxel ? 1 : 2) * element_cell_voxels[std::size_t(e)];
  }
  /// Number of surface nodes.
  [[nodiscard]] int num_surface_nodes() const;
  /// Highest element level + 1 (0 for an empty model).
  [[nodiscard]] int num_levels() const;
  /// Elements per level, level 0 first.
  [[nodiscard]] std::vector<std::int64_t> elements_per_level() const;
  /// Number of tissue voxels covered (sum of cell volumes in voxels).
  [[nodiscard]] std::int64_t covered_voxels() const;
  /// Total tissue volume, mm^3.
  [[nodiscard]] double total_volume_mm3() const;

  /// Recomputes the derived rest-shape data (offsets, centroids, volumes, sizes) from
  /// the nodes, the vertex lists and the element cells. Call after building or loading.
  void finalize();

  /// Checks internal consistency (sizes, index ranges, no repeated vertex in an element);
  /// returns an empty string when consistent, else what is wrong.
  [[nodiscard]] std::string validate() const;
};

/// One edge-connected part of a 2D element's cells (docs/model.md section 12): its cells (bits
/// cx + 2 cy of the 2x2 group) and the element's vertices (node ids) around it, counter-clockwise
/// in the lattice's (x, y), i.e. seen from the slice normal e1 x e2, starting at a corner.
struct SlicePart {
  std::uint8_t cells{0};
  std::vector<int> ring;
};

/// The parts of element e of a 2D model: one for a square, domino, L or full group; two for the
/// rare group whose two cells touch at a corner only (they share that vertex).
[[nodiscard]] std::vector<SlicePart> slice_element_parts(const Model& model, int e);

/// Rest position (LPS mm) of lattice point a of a model of `dimensions` built on `grid`: the
/// voxel corner (3D), or for a 2D model the corner projected onto the slice's centre plane.
[[nodiscard]] Eigen::Vector3d node_position(const GridGeometry& grid, const Eigen::Vector3i& a, int dimensions);

/// True when two models hold the same nodes, elements and rest data (positions within tol_mm).
[[nodiscard]] bool same_model(const Model& a, const Model& b, double tol_mm = 1e-9);

}  // namespace vx
