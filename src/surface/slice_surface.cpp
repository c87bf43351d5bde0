// The surface of a 2D (slice) model: the slice as a flat sheet of triangles (surface.h,
// make_slice_surface; docs/model.md section 12).
#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <utility>
#include <vector>

#include "base/error.h"
#include "surface/surface.h"

namespace vx {

namespace {

/// The point (in cell units, 0..2) from which the part is star-shaped with no boundary vertex
/// collinear: a cell's or the union's centre; for an L the centre of its corner cell.
Eigen::Vector2d part_apex(std::uint8_t part) {
  const int n = __builtin_popcount(part);
  Eigen::Vector2d sum = Eigen::Vector2d::Zero();
  for (int c = 0; c < 4; ++c)
    if ((part >> c) & 1) sum += Eigen::Vector2d((c & 1) + 0.5, ((c >> 1) & 1) + 0.5);
  if (n != 3) return sum / n;
  for (int c = 0; c < 4; ++c)  // the corner cell: both its edge neighbours are in the part
    if (((part >> c) & 1) && ((part >> (c ^ 1)) & 1) && ((part >> (c ^ 2)) & 1))
      return Eigen::Vector2d((c & 1) + 0.5, ((c >> 1) & 1) + 0.5);
  return sum / n;
}

}  // namespace

EmbeddedSurface make_slice_surface(const Model& m) {
  if (!m.is_2d()) throw Error("make_slice_surface: the model is not a 2D (slice) model");
  const int nn = m.num_nodes();
  const Eigen::Vector3d e1 = m.grid.direction.col(0).normalized();
  const Eigen::Vector3d e2 = (m.grid.direction.col(1) - e1.dot(m.grid.direction.col(1)) * e1).normalized();
  EmbeddedSurface s;
  s.method = SurfaceMethod::slice;
  s.model_nodes = nn;
  std::vector<Eigen::Vector3d> vertices;
  vertices.reserve(std::size_t(nn) + std::size_t(m.num_elements()));
  s.embed_offsets.push_back(0);
  for (int i = 0; i < nn; ++i) {
    vertices.push_back(m.rest_positions.col(i));
    s.embed_nodes.push_back(i);
    s.embed_weights.push_back(1.0);
    s.embed_offsets.push_back(std::int32_t(s.embed_nodes.size()));
  }
  std::vector<Eigen::Vector3i> tris;
  for (int e = 0; e < m.num_elements(); ++e) {
    const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
    const int w = m.element_cell_voxels[std::size_t(e)];
    const Eigen::Vector2i anchor = m.element_anchor.col(e).head<2>();
    // the element's least-squares affine fit over its vertices, in the plane
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (int j = b; j < b + n; ++j) centroid += m.rest_positions.col(m.element_vertices[j]);
    centroid /= n;
    Eigen::Matrix2d moment = Eigen::Matrix2d::Zero();
    std::vector<Eigen::Vector2d> offsets;
    for (int j = b; j < b + n; ++j) {
      const Eigen::Vector3d r = m.rest_positions.col(m.element_vertices[j]) - centroid;
      offsets.emplace_back(e1.dot(r), e2.dot(r));
      moment += offsets.back() * offsets.back().transpose();
    }
    const Eigen::Matrix2d inv = moment.inverse();
    for (const SlicePart& part : slice_element_parts(m, e)) {
      // the apex vertex, embedded by the affine fit
      const Eigen::Vector2d apex_cells = part_apex(part.cells);
      const Eigen::Vector3d apex = m.grid.index_to_lps(
          Eigen::Vector3d(anchor.x() + w * apex_cells.x() - 0.5, anchor.y() + w * apex_cells.y() - 0.5, 0.0));
      const Eigen::Vector2d q(e1.dot(apex - centroid), e2.dot(apex - centroid));
      const int apex_id = int(vertices.size());
      vertices.push_back(apex);
      for (int j = 0; j < n; ++j) {
        s.embed_nodes.push_back(m.element_vertices[b + j]);
        s.embed_weights.push_back(1.0 / n + offsets[std::size_t(j)].dot(inv * q));
      }
      s.embed_offsets.push_back(std::int32_t(s.embed_nodes.size()));
      const std::vector<int>& ring = part.ring;
      for (std::size_t k = 0; k < ring.size(); ++k)
        tris.emplace_back(apex_id, ring[k], ring[(k + 1) % ring.size()]);
    }
  }
  s.rest_vertices.resize(3, Eigen::Index(vertices.size()));
  for (std::size_t v = 0; v < vertices.size(); ++v) s.rest_vertices.col(Eigen::Index(v)) = vertices[v];
  s.triangles.resize(3, Eigen::Index(tris.size()));
  for (std::size_t t = 0; t < tris.size(); ++t) s.triangles.col(Eigen::Index(t)) = tris[t];
  // counter-clockwise in the lattice's (x, y) is counter-clockwise seen from e1 x e2
  s.finalize();
  if (const std::string bad = s.validate(); !bad.empty()) throw Error("make_slice_surface: " + bad);
  return s;
}

}  // namespace vx
