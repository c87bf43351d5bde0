#include "physics/element_gradient.h"

#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <utility>
#include <vector>

#include "base/parallel.h"

namespace vx {

namespace {

/// Outward area vector (mm^2) of a voxel face normal to index axis `axis` on side `sign` (+1/-1).
Eigen::Vector3d voxel_face_area(const GridGeometry& g, int axis, int sign) {
  return double(sign) * (g.voxel_volume_mm3() / g.spacing_mm(axis)) * g.direction.col(axis);
}

/// The vertices of one element, looked up by lattice point.
class ElementVertices {
 public:
  ElementVertices(const Model& m, int e) {
    const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
    keys_.reserve(std::size_t(n));
    for (int j = b; j < b + n; ++j) keys_.emplace_back(key(m.node_lattice.col(m.element_vertices[j])), j);
    std::sort(keys_.begin(), keys_.end());
  }
  [[nodiscard]] const std::vector<std::pair<std::uint64_t, std::int32_t>>& entries() const { return keys_; }
  /// The vertex entry at lattice point p, or -1.
  [[nodiscard]] int find(const Eigen::Vector3i& p) const {
    const std::uint64_t k = key(p);
    const auto it = std::lower_bound(keys_.begin(), keys_.end(), std::make_pair(k, std::int32_t(-1)));
    return it != keys_.end() && it->first == k ? it->second : -1;
  }

 private:
  static std::uint64_t key(const Eigen::Vector3i& p) {
    return (std::uint64_t(std::uint32_t(p.x())) << 42) | (std::uint64_t(std::uint32_t(p.y())) << 21) |
           std::uint64_t(std::uint32_t(p.z()));
  }
  std::vector<std::pair<std::uint64_t, std::int32_t>> keys_;
};

/// Shares the boundary faces of one element among its vertices (a_i, mm^2, into `area`).
/// Returns false when some voxel face found no enclosing square of vertices.
class FaceSharer {
 public:
  FaceSharer(const Model& m, int e, Eigen::Matrix3Xd& area) : m_(m), verts_(m, e), area_(area) {}

  /// The boundary face of the cell at lattice corner `cell` (width w) on side `sign` of `axis`;
  /// `group` is the lattice corner of the element's 2x2x2 group.
  bool share_cell_face(const Eigen::Vector3i& group, const Eigen::Vector3i& cell, int w, int axis, int sign) {
    axis_ = axis;
    a_ = (axis + 1) % 3;
    b_ = (axis + 2) % 3;
    plane_ = cell(axis) + (sign > 0 ? w : 0);
    face_area_ = voxel_face_area(m_.grid, axis, sign);
    ok_ = true;
    max_side_ = 2 * w;
    // the element's whole face (2w wide) is the largest square considered
    Square top{group(a_), group(b_), 2 * w, {-1, -1, -1, -1}};
    const Square* valid = corners(top) ? &top : nullptr;
    descend(cell(a_), cell(b_), w, valid);
    return ok_;
  }

 private:
  struct Square {
    int qa, qb, size;
    std::array<int, 4> entry;  ///< vertex entries at (0,0), (s,0), (0,s), (s,s)
  };

  /// True (and fills s.entry) when the four corners of s are vertices of the element.
  bool corners(Square& s) const {
    for (int c = 0; c < 4; ++c) {
      Eigen::Vector3i p;
      p(axis_) = plane_;
      p(a_) = s.qa + ((c & 1) ? s.size : 0);
      p(b_) = s.qb + ((c & 2) ? s.size : 0);
      s.entry[std::size_t(c)] = verts_.find(p);
      if (s.entry[std::size_t(c)] < 0) return false;
    }
    return true;
  }

  /// Walks the aligned squares inside (qa, qb, size) down to voxel faces, keeping the smallest
  /// square with four vertex corners that contains each voxel face.
  void descend(int qa, int qb, int size, const Square* valid) {
    Square here{qa, qb, size, {-1, -1, -1, -1}};
    if (corners(here)) valid = &here;
    if (size > 1) {
      const int h = size / 2;
      for (int c = 0; c < 4; ++c) descend(qa + ((c & 1) ? h : 0), qb + ((c & 2) ? h : 0), h, valid);
      return;
    }
    Rect rect;
    if (valid) {
      rect = {valid->qa, valid->qb, valid->size, valid->size, valid->entry};
    } else if (!smallest_rectangle(qa, qb, rect)) {
      ok_ = spread_over_plane(qa, qb) && ok_;
      ++irregular_faces_;
      return;
    }
    // bilinear shares of the voxel face [qa, qa+1] x [qb, qb+1] in the rectangle: the mean of
    // each corner's hat function over the face
    const double u = (qa - rect.qa + 0.5) / rect.sa, v = (qb - rect.qb + 0.5) / rect.sb;
    const double share[4] = {(1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v};
    for (int c = 0; c < 4; ++c) area_.col(rect.entry[std::size_t(c)]) += share[c] * face_area_;
  }

  /// Where the nodes on the face form no rectangle around the voxel face (a non-conforming
  /// patch between partly filled elements): the least-norm weights over the element's vertices
  /// in the face's plane that still integrate linear fields exactly (sum 1, centroid the voxel
  /// face's centre). The element stays exact for affine motion; its shares at these nodes may
  /// differ a little from its neighbour's.
  bool spread_over_plane(int qa, int qb) {
    std::vector<int> entries;
    std::vector<Eigen::Vector2d> pts;
    for (const auto& [key, j] : verts_.entries()) {
      const Eigen::Vector3i p = m_.node_lattice.col(m_.element_vertices[j]);
      if (p(axis_) != plane_) continue;
      entries.push_back(j);
      pts.emplace_back(p(a_) - (qa + 0.5), p(b_) - (qb + 0.5));
    }
    const int n = int(entries.size());
    if (n < 3) return false;
    Eigen::MatrixXd c(3, n);
    for (int i = 0; i < n; ++i) c.col(i) << 1.0, pts[std::size_t(i)].x(), pts[std::size_t(i)].y();
    const Eigen::Matrix3d cct = c * c.transpose();
    const Eigen::Vector3d rhs(1.0, 0.0, 0.0);
    Eigen::FullPivLU<Eigen::Matrix3d> lu(cct);
    if (lu.rank() < 3) return false;  // collinear nodes
    const Eigen::VectorXd alpha = c.transpose() * lu.solve(rhs);
    for (int i = 0; i < n; ++i) area_.col(entries[std::size_t(i)]) += alpha(i) * face_area_;
    return true;
  }

 public:
  [[nodiscard]] std::int64_t irregular_faces() const { return irregular_faces_; }

 private:
  struct Rect {
    int qa{0}, qb{0}, sa{1}, sb{1};
    std::array<int, 4> entry{-1, -1, -1, -1};
  };

  /// Where no square fits (a face of a partly filled element, two cells by one): the first
  /// aligned rectangle with four vertex corners containing the voxel face at (qa, qb), by
  /// longer side (1, 2, 4, ...), then the wider shorter side first (the square), then side a.
  bool smallest_rectangle(int qa, int qb, Rect& out) const {
    for (int s = 1; s <= max_side_; s *= 2)
      for (int t = s; t >= 1; t /= 2)
        for (int flip = 0; flip < (t == s ? 1 : 2); ++flip) {
          Rect r;
          r.sa = flip ? t : s;
          r.sb = flip ? s : t;
          r.qa = qa - qa % r.sa;
          r.qb = qb - qb % r.sb;
          bool ok = true;
          for (int c = 0; c < 4 && ok; ++c) {
            Eigen::Vector3i p;
            p(axis_) = plane_;
            p(a_) = r.qa + ((c & 1) ? r.sa : 0);
            p(b_) = r.qb + ((c & 2) ? r.sb : 0);
            r.entry[std::size_t(c)] = verts_.find(p);
            ok = r.entry[std::size_t(c)] >= 0;
          }
          if (ok) {
            out = r;
            return true;
          }
        }
    return false;
  }

  const Model& m_;
  ElementVertices verts_;
  Eigen::Matrix3Xd& area_;
  int axis_{0}, a_{1}, b_{2}, plane_{0}, max_side_{1};
  Eigen::Vector3d face_area_{Eigen::Vector3d::Zero()};
  bool ok_{true};
  std::int64_t irregular_faces_{0};
};

/// The 2D analogue (a slice model, docs/model.md section 12.2) for element e: each boundary
/// pixel edge of the element's cells is shared linearly between the nearest vertices of the
/// element on its line at or before its start and at or after its end (the ends of the
/// straight boundary run it lies on are corners of the element, hence vertices; a neighbour
/// across the edge holds the same nodes there, so the two sides' shares are equal and
/// opposite). The area vector of a pixel edge is its length times the slice thickness, along
/// the in-plane normal. Returns false when some edge found no bracketing vertices.
bool share_element_edges_2d(const Model& m, int e, Eigen::Matrix3Xd& area) {
  const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
  const int w = m.element_cell_voxels[std::size_t(e)];
  const Eigen::Vector3i group = m.element_anchor.col(e);
  const std::uint8_t mask = m.element_cells[std::size_t(e)];
  const int cells = m.layout == Layout::voxel ? 1 : 2;
  const auto filled = [&](int cx, int cy) {
    return cx >= 0 && cy >= 0 && cx < cells && cy < cells && (cells == 1 || ((mask >> (cx + 2 * cy)) & 1));
  };
  bool ok = true;
  for (int cy = 0; cy < cells; ++cy)
    for (int cx = 0; cx < cells; ++cx) {
      if (!filled(cx, cy)) continue;
      const Eigen::Vector2i lo(group.x() + w * cx, group.y() + w * cy);
      for (int axis = 0; axis < 2; ++axis)
        for (int sign : {-1, 1}) {
          const int nbx = cx + (axis == 0 ? sign : 0), nby = cy + (axis == 1 ? sign : 0);
          if (cells == 2 && filled(nbx, nby)) continue;  // inside the element
          const int along = 1 - axis;
          const int line = lo(axis) + (sign > 0 ? w : 0);
          const Eigen::Vector3d face = voxel_face_area(m.grid, axis, sign);
          for (int q = lo(along); q < lo(along) + w; ++q) {
            // the nearest vertices on the line at or before q and at or after q + 1
            int below = -1, above = -1, qb = 0, qa = 0;
            for (int j = b; j < b + n; ++j) {
              const Eigen::Vector3i p = m.node_lattice.col(m.element_vertices[j]);
              if (p(axis) != line) continue;
              const int t = p(along);
              if (t <= q && (below < 0 || t > qb)) below = j, qb = t;
              if (t >= q + 1 && (above < 0 || t < qa)) above = j, qa = t;
            }
            if (below < 0 || above < 0) {
              ok = false;
              continue;
            }
            const double u = (q + 0.5 - qb) / double(qa - qb);
            area.col(below) += (1.0 - u) * face;
            area.col(above) += u * face;
          }
        }
    }
  return ok;
}

}  // namespace

ElementGradients compute_element_gradients(const Model& m, int threads) {
  const int ne = m.num_elements();
  ElementGradients out;
  if (m.is_2d()) {
    out.entry_gradient = Eigen::Matrix3Xd::Zero(3, m.num_vertex_entries());
    out.element_fallback.assign(std::size_t(ne), 0);
    out.element_irregular_faces.assign(std::size_t(ne), 0);
    parallel_for(ne, 64, threads, [&](std::int64_t e0, std::int64_t e1) {
      for (int e = int(e0); e < int(e1); ++e) {
        const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
        if (!share_element_edges_2d(m, e, out.entry_gradient)) {
          out.element_fallback[std::size_t(e)] = 1;
          out.entry_gradient.middleCols(b, n).setZero();
          continue;
        }
        out.entry_gradient.middleCols(b, n) /= m.element_volume_mm3[std::size_t(e)];
      }
    });
    for (auto f : out.element_fallback) out.fallback_elements += f;
    return out;
  }
  out.entry_gradient = Eigen::Matrix3Xd::Zero(3, m.num_vertex_entries());
  out.element_fallback.assign(std::size_t(ne), 0);
  out.element_irregular_faces.assign(std::size_t(ne), 0);
  parallel_for(ne, 16, threads, [&](std::int64_t e0, std::int64_t e1) {
    for (int e = int(e0); e < int(e1); ++e) {
      FaceSharer sharer(m, e, out.entry_gradient);
      const int w = m.element_cell_voxels[std::size_t(e)];
      const Eigen::Vector3i group = m.element_anchor.col(e);
      const std::uint8_t mask = m.element_cells[std::size_t(e)];
      const auto filled = [&](int cx, int cy, int cz) {
        return cx >= 0 && cy >= 0 && cz >= 0 && cx < 2 && cy < 2 && cz < 2 && ((mask >> (cx + 2 * cy + 4 * cz)) & 1);
      };
      // voxel-level elements are one cell; their group is the cell itself
      const int cells = m.layout == Layout::voxel ? 1 : 2;
      bool ok = true;
      for (int cz = 0; cz < cells; ++cz)
        for (int cy = 0; cy < cells; ++cy)
          for (int cx = 0; cx < cells; ++cx) {
            if (!filled(cx, cy, cz)) continue;
            const Eigen::Vector3i c(cx, cy, cz);
            for (int axis = 0; axis < 3; ++axis)
              for (int sign : {-1, 1}) {
                Eigen::Vector3i nb = c;
                nb(axis) += sign;
                if (cells == 2 && filled(nb.x(), nb.y(), nb.z())) continue;  // inside the element
                ok = sharer.share_cell_face(group, group + w * c, w, axis, sign) && ok;
              }
          }
      const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
      out.element_irregular_faces[std::size_t(e)] = std::int32_t(sharer.irregular_faces());
      if (!ok) {
        out.element_fallback[std::size_t(e)] = 1;
        out.entry_gradient.middleCols(b, n).setZero();
        continue;
      }
      out.entry_gradient.middleCols(b, n) /= m.element_volume_mm3[std::size_t(e)];
    }
  });
  for (auto f : out.element_fallback) out.fallback_elements += f;
  for (auto f : out.element_irregular_faces) out.irregular_faces += f;
  return out;
}

Eigen::Matrix3Xd boundary_area_vectors(const Model& m) {
  // lattice point -> node
  std::vector<std::pair<std::uint64_t, int>> keys;
  keys.reserve(std::size_t(m.num_nodes()));
  const std::uint64_t lx = std::uint64_t(m.grid.dims.x()) + 1, ly = std::uint64_t(m.grid.dims.y()) + 1;
  const auto key = [&](const Eigen::Vector3i& p) { return std::uint64_t(p.x()) + lx * (std::uint64_t(p.y()) + ly * std::uint64_t(p.z())); };
  for (int i = 0; i < m.num_nodes(); ++i) keys.emplace_back(key(m.node_lattice.col(i)), i);
  std::sort(keys.begin(), keys.end());
  const auto node = [&](const Eigen::Vector3i& p) {
    const auto it = std::lower_bound(keys.begin(), keys.end(), std::make_pair(key(p), -1));
    return it != keys.end() && it->first == key(p) ? it->second : -1;
  };
  // tissue voxels: every cell of every element
  std::vector<std::uint64_t> voxels;
  for (int e = 0; e < m.num_elements(); ++e) {
    const int w = m.element_cell_voxels[std::size_t(e)];
    for (int c = 0; c < 8; ++c) {
      if (!((m.element_cells[std::size_t(e)] >> c) & 1)) continue;
      const Eigen::Vector3i lo = m.element_anchor.col(e) + w * Eigen::Vector3i(c & 1, (c >> 1) & 1, (c >> 2) & 1);
      for (int z = 0; z < w; ++z)
        for (int y = 0; y < w; ++y)
          for (int x = 0; x < w; ++x) voxels.push_back(key(lo + Eigen::Vector3i(x, y, z)));
    }
  }
  std::sort(voxels.begin(), voxels.end());
  const auto tissue = [&](const Eigen::Vector3i& v) {
    if ((v.array() < 0).any()) return false;
    return std::binary_search(voxels.begin(), voxels.end(), key(v));
  };
  Eigen::Matrix3Xd out = Eigen::Matrix3Xd::Zero(3, m.num_nodes());
  for (std::uint64_t k : voxels) {
    const Eigen::Vector3i v(int(k % lx), int((k / lx) % ly), int(k / (lx * ly)));
    for (int axis = 0; axis < 3; ++axis)
      for (int sign : {-1, 1}) {
        Eigen::Vector3i nb = v;
        nb(axis) += sign;
        if (tissue(nb)) continue;
        const Eigen::Vector3d area = voxel_face_area(m.grid, axis, sign);
        const int a = (axis + 1) % 3, b = (axis + 2) % 3;
        for (int c = 0; c < 4; ++c) {
          Eigen::Vector3i p = v;
          if (sign > 0) p(axis) += 1;
          p(a) += c & 1;
          p(b) += (c >> 1) & 1;
          const int i = node(p);
          if (i >= 0) out.col(i) += 0.25 * area;
        }
      }
  }
  return out;
}

}  // namespace vx
