#pragma once
/// @file surface.h
/// The smoothed surface that follows the deformation (docs/model.md section 10, paper 3.3).
///
/// A surface is a closed triangle mesh whose every vertex is a fixed weighted sum of model
/// nodes (its embedding). Deforming it for a frame is one gather per vertex plus the vertex
/// normals, with no allocation. Three surfaces are made:
///
/// - `staircase`: the raw voxel boundary (faces between tissue and non-tissue voxels), the
///   baseline the others are measured against.
/// - `paper`: the paper's surface. The staircase with its concave steps hidden: every empty
///   voxel that touches tissue across two perpendicular faces (a concave step or corner of the
///   staircase) is filled with the convex hull of its corners that lie on those tissue faces,
///   so the step is spanned by one flat face (see make_voxel_surface). Vertices are model
///   surface nodes (voxel corners), each embedded with weight 1: deforming is an exact gather.
/// - `iso`: an iso-surface of the volume, smoothed (pipeline/convert/iso_surface.h), each vertex
///   embedded by trilinear interpolation in its voxel cell over the cell's 8 lattice points,
///   where a lattice point that is not a node is interpolated in (or extrapolated from) the
///   element that holds it or is nearest (see embed_surface). Exact for affine motion of the
///   nodes, and continuous across cells and elements.
///
/// Vertex normals are the mean of the unit normals of the triangles around the vertex
/// (the paper's Gouraud shading), recomputed from the deformed positions every frame.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "model/model.h"
#include "model/voxel_grid.h"

namespace vx {

/// How a surface was made.
enum class SurfaceMethod : std::uint8_t {
  staircase,  ///< raw voxel boundary
  paper,      ///< voxel boundary with the concave steps hidden (paper 3.3)
  iso,        ///< smoothed iso-surface embedded in the elements
  slice,      ///< a 2D model's slice: the flat sheet of its elements (make_slice_surface)
};
[[nodiscard]] const char* to_string(SurfaceMethod m);
/// Parses "staircase", "paper" or "iso"; throws vx::Error otherwise.
[[nodiscard]] SurfaceMethod parse_surface_method(const std::string& s);

/// A closed, outward-oriented triangle mesh embedded in a model's nodes.
///
/// Vertex v at any time is sum_k embed_weights[k] * x(embed_nodes[k]) over
/// k in [embed_offsets[v], embed_offsets[v+1]); at rest this gives rest_vertices.
struct EmbeddedSurface {
  SurfaceMethod method{SurfaceMethod::paper};
  int model_nodes{0};                    ///< node count of the model it is embedded in

  Eigen::Matrix3Xd rest_vertices;        ///< 3 x V, LPS mm
  Eigen::Matrix3Xi triangles;            ///< 3 x T, vertex ids, counter-clockwise seen from outside

  // embedding (CSR over vertices)
  std::vector<std::int32_t> embed_offsets;  ///< V + 1
  std::vector<std::int32_t> embed_nodes;    ///< entries: model node id
  std::vector<double> embed_weights;        ///< entries: weight (a vertex's weights sum to 1)

  // derived by finalize()
  std::vector<std::int32_t> vertex_face_offsets;  ///< V + 1: triangles around each vertex (CSR)
  std::vector<std::int32_t> vertex_faces;         ///< 3 T entries: triangle ids
  Eigen::Matrix3Xd rest_normals;                  ///< 3 x V, unit vertex normals at rest

  [[nodiscard]] int num_vertices() const { return int(rest_vertices.cols()); }
  [[nodiscard]] int num_triangles() const { return int(triangles.cols()); }
  [[nodiscard]] std::int64_t num_embed_entries() const { return std::int64_t(embed_nodes.size()); }

  /// Derives the vertex-to-triangle lists and the rest normals. Call after building or loading.
  void finalize();

  /// Checks sizes and index ranges (triangles, embedding, node ids < model_nodes, weights
  /// summing to 1); returns an empty string when consistent, else what is wrong.
  [[nodiscard]] std::string validate() const;
};

/// Topology of a triangle mesh, for checks and reports.
struct MeshTopology {
  std::int64_t edges{0};                  ///< distinct undirected edges
  std::int64_t open_edges{0};             ///< edges with one triangle (0 for a closed mesh)
  std::int64_t non_manifold_edges{0};     ///< edges with more than two triangles
  std::int64_t misoriented_edges{0};      ///< edges used twice in the same direction
  std::int64_t degenerate_triangles{0};   ///< triangles repeating a vertex
  std::int64_t euler_characteristic{0};   ///< V - E + T over the vertices used
  [[nodiscard]] bool closed_and_oriented() const {
    return open_edges == 0 && misoriented_edges == 0 && degenerate_triangles == 0;
  }
};
[[nodiscard]] MeshTopology mesh_topology(const Eigen::Matrix3Xi& triangles, int num_vertices);

/// Enclosed volume of a closed outward mesh (divergence theorem), mm^3.
[[nodiscard]] double enclosed_volume_mm3(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles);

/// What make_voxel_surface did.
struct VoxelSurfaceReport {
  std::int64_t boundary_faces{0};     ///< voxel faces between tissue and non-tissue
  std::int64_t filled_steps{0};       ///< empty voxels filled with a flat face across a step (prism)
  std::int64_t filled_corners{0};     ///< empty voxels filled across a concave corner (cube minus a corner)
  std::int64_t filled_voxels{0};      ///< empty voxels filled completely (1-voxel grooves and pits)
  std::int64_t dropped_fills{0};      ///< fills left out because two neighbours' fills disagreed
};

/// The voxel boundary surface of `grid` (which must be the grid `model` was built from),
/// with vertices on model surface nodes (voxel corners), each embedded with weight 1.
///
/// `hide_concave_steps = false` gives the raw staircase: each boundary voxel face is two
/// triangles facing out of the tissue.
///
/// `hide_concave_steps = true` gives the paper's surface (paper 3.3, fig. 7). A concave step
/// of the staircase is an edge where an empty voxel E touches tissue across two
/// perpendicular faces. Each such E (inside the grid) is filled with the convex hull of its
/// corners that lie on its tissue faces; depending on its tissue faces this is
///  - a half-voxel prism (two perpendicular tissue faces): the L-shaped step becomes one flat
///    1 x sqrt(2) voxel face across E's diagonal;
///  - the voxel minus one corner tetrahedron (three mutually perpendicular tissue faces, a
///    concave corner): the corner becomes one triangle across the three corners' neighbours;
///  - the whole voxel (tissue on two opposite faces and a third: a 1-voxel groove or pit).
/// The surface is the boundary of tissue plus fills: on each voxel face the solid traces of
/// the two voxels are compared, and the hull faces inside each E are added. It is therefore
/// closed and consistently oriented, and every vertex is a voxel corner on a tissue face, so
/// a model node. Where two face-adjacent fills would cut their shared face along crossing
/// diagonals (rare: walls on opposite sides of one empty column), both are left out and the
/// staircase stays there (counted in the report). Convex edges and corners stay as they are.
///
/// Throws vx::Error when the grid does not match the model or a vertex is not a node.
[[nodiscard]] EmbeddedSurface make_voxel_surface(const Model& model, const VoxelGrid& grid, bool hide_concave_steps,
                                                 VoxelSurfaceReport* report = nullptr);

/// The surface of a 2D (slice) model (docs/model.md section 12): the slice itself as a flat
/// sheet of triangles facing the slice normal, so that everything that shows or writes a
/// surface shows the deforming slice. Every model node is a vertex (weight 1); each element adds
/// one vertex inside each edge-connected part of its cells (the centre of the part's kernel: the
/// part is a square, two squares, an L or four squares, each star-shaped from there), embedded
/// by the least-squares affine fit over the element's vertices (exact for affine motion), and is
/// split into the fan of triangles from it to its boundary vertices in counter-clockwise order
/// seen from the normal. Throws vx::Error for a volume model.
[[nodiscard]] EmbeddedSurface make_slice_surface(const Model& model);

/// Embeds a triangle mesh given at rest (LPS mm) in the model's nodes.
///
/// Weights: the vertex's voxel cell (the unit cube of lattice points around it; clamped to
/// the grid) gives trilinear weights over its 8 lattice points. A lattice point that is a
/// node is itself. One that is not is expressed by one element: the element holding the
/// point (the element of a tissue voxel touching it), or, for a point off the tissue
/// (smoothing moves vertices out by up to a voxel or so), the element of the nearest tissue
/// voxel, extrapolated. A box element (all 8 cells covered) interpolates trilinearly between
/// its 8 corners; any other element uses the least-squares affine fit of its region's corners
/// X_i: w_i = 1/n + R_i^T M^-1 (p - C), R_i = X_i - C, C their centroid, M = sum_j R_j R_j^T.
/// Every lattice point has one fixed expression, so the surface is continuous across cells
/// and elements (a per-element fit of each vertex would crease it at element boundaries);
/// trilinear interpolation and affine fits both reproduce affine motion, so rigid motion and
/// uniform stretch are exact. Weights per vertex are about 15 (8 lattice points, most of them
/// surface nodes). The weights sum to 1 and are fixed at rest.
///
/// Throws vx::Error when a vertex is more than 8 voxels from any tissue.
[[nodiscard]] EmbeddedSurface embed_surface(const Model& model, const Eigen::Matrix3Xd& rest_vertices_mm,
                                            const Eigen::Matrix3Xi& triangles, SurfaceMethod method);

/// Deformed vertex positions: out_vertices (3 x V) = embedding applied to node_positions
/// (3 x nodes, mm). Parallel over vertices; allocates only when out_vertices has the wrong size.
void deform_vertices(const EmbeddedSurface& surface, const Eigen::Matrix3Xd& node_positions,
                     Eigen::Matrix3Xd& out_vertices);

/// Unit vertex normals (3 x V): the mean of the unit normals of the triangles around each
/// vertex (zero for a vertex whose triangles all have zero area). With `face_normals` (3 x T
/// scratch, sized on first use) each triangle's normal is found once, else once per corner
/// (about 2.5 times the work); the results are identical. Parallel; allocates only when an
/// output has the wrong size.
void compute_vertex_normals(const EmbeddedSurface& surface, const Eigen::Matrix3Xd& vertices,
                            Eigen::Matrix3Xd& out_normals, Eigen::Matrix3Xd* face_normals = nullptr);

/// One frame: deform_vertices then compute_vertex_normals (without scratch).
void deform(const EmbeddedSurface& surface, const Eigen::Matrix3Xd& node_positions, Eigen::Matrix3Xd& out_vertices,
            Eigen::Matrix3Xd& out_normals);

/// The mutable side of a deforming surface (the surface itself is const and shared): one
/// frame's output plus scratch, sized on the first deform and reused after.
struct SurfaceFrame {
  Eigen::Matrix3Xd vertices;      ///< 3 x V, mm
  Eigen::Matrix3Xd normals;       ///< 3 x V, unit vertex normals
  Eigen::Matrix3Xd face_normals;  ///< 3 x T, unit triangle normals (scratch)
};

/// One frame, the fast way: positions, triangle normals once each, vertex normals.
void deform(const EmbeddedSurface& surface, const Eigen::Matrix3Xd& node_positions, SurfaceFrame& frame);

}  // namespace vx
