#include "surface/surface.h"

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <exception>
#include <limits>
#include <numeric>
#include <set>
#include <sstream>
#include <unordered_map>

#include "base/error.h"
#include "base/parallel.h"

namespace vx {

const char* to_string(SurfaceMethod m) {
  switch (m) {
    case SurfaceMethod::staircase: return "staircase";
    case SurfaceMethod::paper: return "paper";
    case SurfaceMethod::iso: return "iso";
    case SurfaceMethod::slice: return "slice";
  }
  return "?";
}

SurfaceMethod parse_surface_method(const std::string& s) {
  if (s == "staircase") return SurfaceMethod::staircase;
  if (s == "paper") return SurfaceMethod::paper;
  if (s == "iso") return SurfaceMethod::iso;
  throw Error("unknown surface method '" + s + "': use paper, iso or staircase");
}

// ---------------------------------------------------------------------------------------------
// EmbeddedSurface

void EmbeddedSurface::finalize() {
  const int nv = num_vertices(), nt = num_triangles();
  // vertex -> triangles, by counting
  vertex_face_offsets.assign(std::size_t(nv) + 1, 0);
  for (int t = 0; t < nt; ++t)
    for (int c = 0; c < 3; ++c) ++vertex_face_offsets[std::size_t(triangles(c, t)) + 1];
  for (int v = 0; v < nv; ++v) vertex_face_offsets[std::size_t(v) + 1] += vertex_face_offsets[std::size_t(v)];
  vertex_faces.assign(std::size_t(3) * std::size_t(nt), 0);
  std::vector<std::int32_t> fill(vertex_face_offsets.begin(), vertex_face_offsets.end() - 1);
  for (int t = 0; t < nt; ++t)
    for (int c = 0; c < 3; ++c) vertex_faces[std::size_t(fill[std::size_t(triangles(c, t))]++)] = t;
  compute_vertex_normals(*this, rest_vertices, rest_normals);
}

std::string EmbeddedSurface::validate() const {
  std::ostringstream err;
  const int nv = num_vertices(), nt = num_triangles();
  if (nt > 0 && (triangles.minCoeff() < 0 || triangles.maxCoeff() >= nv))
    err << "triangles refer to vertices outside 0.." << nv - 1 << "; ";
  if (int(embed_offsets.size()) != nv + 1 || embed_offsets.front() != 0 ||
      embed_offsets.back() != std::int32_t(embed_nodes.size()) || embed_nodes.size() != embed_weights.size()) {
    err << "embedding arrays do not match " << nv << " vertices; ";
    return err.str();
  }
  for (int v = 0; v < nv; ++v) {
    const int b = embed_offsets[std::size_t(v)], e = embed_offsets[std::size_t(v) + 1];
    if (e <= b) { err << "vertex " << v << " has no embedding entry; "; break; }
    double sum = 0;
    bool bad_node = false;
    for (int k = b; k < e; ++k) {
      sum += embed_weights[std::size_t(k)];
      bad_node = bad_node || embed_nodes[std::size_t(k)] < 0 || embed_nodes[std::size_t(k)] >= model_nodes;
    }
    if (bad_node) { err << "vertex " << v << " refers to a node outside 0.." << model_nodes - 1 << "; "; break; }
    if (!(std::abs(sum - 1.0) < 1e-9)) { err << "weights of vertex " << v << " sum to " << sum << ", not 1; "; break; }
  }
  return err.str();
}

// ---------------------------------------------------------------------------------------------
// mesh checks

MeshTopology mesh_topology(const Eigen::Matrix3Xi& triangles, int num_vertices) {
  MeshTopology topo;
  const int nt = int(triangles.cols());
  // directed edges as (undirected key, direction)
  std::vector<std::pair<std::uint64_t, int>> edges;
  edges.reserve(std::size_t(3) * std::size_t(nt));
  std::vector<std::uint8_t> used(std::size_t(std::max(num_vertices, 0)), 0);
  for (int t = 0; t < nt; ++t) {
    const int a = triangles(0, t), b = triangles(1, t), c = triangles(2, t);
    if (a == b || b == c || c == a) {
      ++topo.degenerate_triangles;
      continue;
    }
    const int v[3] = {a, b, c};
    for (int i = 0; i < 3; ++i) {
      const std::uint32_t p = std::uint32_t(v[i]), q = std::uint32_t(v[(i + 1) % 3]);
      used[p] = 1;
      edges.emplace_back(std::uint64_t(std::min(p, q)) << 32 | std::max(p, q), p < q ? 1 : -1);
    }
  }
  std::sort(edges.begin(), edges.end());
  for (std::size_t i = 0; i < edges.size();) {
    std::size_t j = i;
    int forward = 0, backward = 0;
    for (; j < edges.size() && edges[j].first == edges[i].first; ++j) (edges[j].second > 0 ? forward : backward)++;
    ++topo.edges;
    const int n = forward + backward;
    if (n == 1) ++topo.open_edges;
    if (n > 2) ++topo.non_manifold_edges;
    if (n >= 2 && forward != backward) ++topo.misoriented_edges;
    i = j;
  }
  const std::int64_t nv_used = std::count(used.begin(), used.end(), std::uint8_t(1));
  topo.euler_characteristic = nv_used - topo.edges + (nt - topo.degenerate_triangles);
  return topo;
}

double enclosed_volume_mm3(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles) {
  if (vertices.cols() == 0) return 0.0;
  // relative to a reference point: exact for a closed mesh, and free of large-origin cancellation
  const Eigen::Vector3d ref = vertices.col(0);
  double six_v = 0;
  for (Eigen::Index t = 0; t < triangles.cols(); ++t) {
    const Eigen::Vector3d a = vertices.col(triangles(0, t)) - ref, b = vertices.col(triangles(1, t)) - ref,
                          c = vertices.col(triangles(2, t)) - ref;
    six_v += a.dot(b.cross(c));
  }
  return six_v / 6.0;
}

// ---------------------------------------------------------------------------------------------
// deformation

void deform_vertices(const EmbeddedSurface& s, const Eigen::Matrix3Xd& node_positions, Eigen::Matrix3Xd& out) {
  const int nv = s.num_vertices();
  assert(node_positions.cols() == s.model_nodes && "node positions of another model");
  if (out.cols() != nv) out.resize(3, nv);
  const std::int32_t* off = s.embed_offsets.data();
  const std::int32_t* nodes = s.embed_nodes.data();
  const double* w = s.embed_weights.data();
  const double* x = node_positions.data();
  double* o = out.data();
  // each vertex: its weighted sum of node positions (independent, so any thread count gives
  // the same result)
#pragma omp parallel for schedule(static) if (nv > 4096)
  for (int v = 0; v < nv; ++v) {
    double px = 0, py = 0, pz = 0;
    for (int k = off[v]; k < off[v + 1]; ++k) {
      const double* p = x + 3 * std::size_t(nodes[k]);
      px += w[k] * p[0];
      py += w[k] * p[1];
      pz += w[k] * p[2];
    }
    o[3 * std::size_t(v)] = px;
    o[3 * std::size_t(v) + 1] = py;
    o[3 * std::size_t(v) + 2] = pz;
  }
}

namespace {

/// Unit normal of triangle t (zero when its area is zero).
inline Eigen::Vector3d face_normal(const EmbeddedSurface& s, const Eigen::Matrix3Xd& x, int t) {
  const Eigen::Vector3d a = x.col(s.triangles(0, t));
  const Eigen::Vector3d n = (x.col(s.triangles(1, t)) - a).cross(x.col(s.triangles(2, t)) - a);
  const double len = n.norm();
  return len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
}

}  // namespace

void compute_vertex_normals(const EmbeddedSurface& s, const Eigen::Matrix3Xd& vertices, Eigen::Matrix3Xd& out,
                            Eigen::Matrix3Xd* face_normals) {
  const int nv = s.num_vertices(), nt = s.num_triangles();
  if (out.cols() != nv) out.resize(3, nv);
  if (int(s.vertex_face_offsets.size()) != nv + 1) {
    out.setZero();  // not finalized: no adjacency
    return;
  }
  if (face_normals) {
    // each triangle's unit normal once
    if (face_normals->cols() != nt) face_normals->resize(3, nt);
    Eigen::Matrix3Xd& fn = *face_normals;
#pragma omp parallel for schedule(static) if (nt > 8192)
    for (int t = 0; t < nt; ++t) fn.col(t) = face_normal(s, vertices, t);
  }
  // each vertex: the mean of the unit normals of its triangles (paper 3.3), normalized
#pragma omp parallel for schedule(static) if (nv > 4096)
  for (int v = 0; v < nv; ++v) {
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    for (int k = s.vertex_face_offsets[std::size_t(v)]; k < s.vertex_face_offsets[std::size_t(v) + 1]; ++k) {
      const int t = s.vertex_faces[std::size_t(k)];
      n += face_normals ? Eigen::Vector3d(face_normals->col(t)) : face_normal(s, vertices, t);
    }
    const double len = n.norm();
    out.col(v) = len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
  }
}

void deform(const EmbeddedSurface& s, const Eigen::Matrix3Xd& node_positions, Eigen::Matrix3Xd& out_vertices,
            Eigen::Matrix3Xd& out_normals) {
  deform_vertices(s, node_positions, out_vertices);
  compute_vertex_normals(s, out_vertices, out_normals);
}

void deform(const EmbeddedSurface& s, const Eigen::Matrix3Xd& node_positions, SurfaceFrame& frame) {
  deform_vertices(s, node_positions, frame.vertices);
  compute_vertex_normals(s, frame.vertices, frame.normals, &frame.face_normals);
}

// ---------------------------------------------------------------------------------------------
// lookups into the model shared by the surface builders

namespace {

/// Lattice point (voxel corner) a as one integer; lattice points per axis are dims + 1.
struct LatticeKey {
  Eigen::Vector3i points;  ///< lattice points per axis
  explicit LatticeKey(const Eigen::Vector3i& voxel_dims) : points(voxel_dims.array() + 1) {}
  [[nodiscard]] std::int64_t operator()(const Eigen::Vector3i& a) const {
    return a.x() + std::int64_t(points.x()) * (a.y() + std::int64_t(points.y()) * a.z());
  }
};

/// Node ids by lattice point (sorted, binary search), for all nodes or the surface nodes only.
class NodeFinder {
 public:
  NodeFinder(const Model& m, bool surface_only) : key_(m.grid.dims) {
    for (int n = 0; n < m.num_nodes(); ++n)
      if (!surface_only || m.node_surface[std::size_t(n)]) nodes_.emplace_back(key_(m.node_lattice.col(n)), n);
    std::sort(nodes_.begin(), nodes_.end());
  }
  /// Node at lattice point a, or -1.
  [[nodiscard]] int find(const Eigen::Vector3i& a) const { return find_key(key_(a)); }
  [[nodiscard]] int find_key(std::int64_t k) const {
    auto it = std::lower_bound(nodes_.begin(), nodes_.end(), std::make_pair(k, std::int32_t(-1)));
    return it != nodes_.end() && it->first == k ? it->second : -1;
  }

 private:
  LatticeKey key_;
  std::vector<std::pair<std::int64_t, std::int32_t>> nodes_;
};

/// The element covering a voxel, found level by level from the elements' aligned groups
/// (no voxel-sized array, so it works for any grid size).
class ElementFinder {
 public:
  explicit ElementFinder(const Model& m) : m_(m), key_(m.grid.dims), levels_(m.num_levels()) {
    by_group_.reserve(std::size_t(m.num_elements()));
    for (int e = 0; e < m.num_elements(); ++e)
      by_group_.emplace(group_key(m.element_anchor.col(e), m.element_level[std::size_t(e)]), e);
  }
  /// Element whose covered cells hold voxel v, or -1 (not tissue, or outside the grid).
  [[nodiscard]] int owner(const Eigen::Vector3i& v) const {
    if ((v.array() < 0).any() || (v.array() >= m_.grid.dims.array()).any()) return -1;
    // voxel-level models: one element per voxel, anchored at the voxel
    if (m_.layout == Layout::voxel) {
      auto it = by_group_.find(group_key(v, 0));
      return it == by_group_.end() ? -1 : it->second;
    }
    // a tissue voxel not covered below level L lies in a 1-cell at level L, so the first group
    // found that holds it decides: covered there, or the voxel is not tissue
    for (int level = 0; level < levels_; ++level) {
      const int w = 1 << level, g = 2 * w;
      const Eigen::Vector3i anchor = (v.array() / g * g).matrix();
      auto it = by_group_.find(group_key(anchor, level));
      if (it == by_group_.end()) continue;
      const int e = it->second;
      const Eigen::Vector3i c = (v - anchor) / w;
      return (m_.element_cells[std::size_t(e)] >> (c.x() + 2 * c.y() + 4 * c.z()) & 1) ? e : -1;
    }
    return -1;
  }

 private:
  [[nodiscard]] std::int64_t group_key(const Eigen::Vector3i& anchor, int level) const {
    return key_(anchor) * 32 + level;
  }
  const Model& m_;
  LatticeKey key_;
  int levels_;
  std::unordered_map<std::int64_t, std::int32_t> by_group_;
};

// ---------------------------------------------------------------------------------------------
// voxel surface (staircase and the paper's surface)

/// Corner c of a voxel is (c & 1, c >> 1 & 1, c >> 2 & 1). Face f of a voxel: axis f / 2,
/// side f % 2 (0: the low side, 1: the high side).
Eigen::Vector3i corner_offset(int c) { return {c & 1, c >> 1 & 1, c >> 2 & 1}; }

/// Corners (8-bit set) on face f.
std::uint8_t face_corners(int f) {
  const int axis = f / 2, side = f % 2;
  std::uint8_t m = 0;
  for (int c = 0; c < 8; ++c)
    if ((c >> axis & 1) == side) m |= std::uint8_t(1u << c);
  return m;
}

/// Triangles (local corner ids, outward) of the faces of the convex hull of the corner set
/// `corners` that lie inside the voxel (not on its boundary faces). Computed once per set.
const std::vector<std::array<int, 3>>& hull_inner_faces(std::uint8_t corners) {
  static const auto table = [] {
    std::array<std::vector<std::array<int, 3>>, 256> t;
    for (int set = 0; set < 256; ++set) {
      std::vector<int> pts;
      for (int c = 0; c < 8; ++c)
        if (set >> c & 1) pts.push_back(c);
      std::set<std::array<int, 4>> planes;
      for (std::size_t a = 0; a < pts.size(); ++a)
        for (std::size_t b = a + 1; b < pts.size(); ++b)
          for (std::size_t c = b + 1; c < pts.size(); ++c) {
            const Eigen::Vector3i pa = corner_offset(pts[a]), pb = corner_offset(pts[b]), pc = corner_offset(pts[c]);
            Eigen::Vector3i n = (pb - pa).cross(pc - pa);
            if (n.isZero()) continue;
            // faces on the voxel's own faces are handled with the neighbours
            if ((n.array() == 0).count() == 2) continue;
            int d = n.dot(pa), pos = 0, neg = 0;
            for (int q : pts) {
              const int s = n.dot(corner_offset(q)) - d;
              pos += s > 0;
              neg += s < 0;
            }
            if (pos && neg) continue;  // not a supporting plane
            if (pos) n = -n, d = -d;   // make n point out of the hull
            const int g = std::gcd(std::gcd(std::abs(n.x()), std::abs(n.y())), std::gcd(std::abs(n.z()), std::abs(d)));
            if (!planes.insert({n.x() / g, n.y() / g, n.z() / g, d / g}).second) continue;
            // the face polygon: all hull points on the plane, ordered around their centre
            std::vector<int> poly;
            for (int q : pts)
              if (n.dot(corner_offset(q)) == d) poly.push_back(q);
            Eigen::Vector3d centre = Eigen::Vector3d::Zero();
            for (int q : poly) centre += corner_offset(q).cast<double>();
            centre /= double(poly.size());
            const Eigen::Vector3d nd = n.cast<double>().normalized();
            const Eigen::Vector3d u = (corner_offset(poly[0]).cast<double>() - centre).normalized();
            const Eigen::Vector3d v = nd.cross(u);
            std::sort(poly.begin(), poly.end(), [&](int x, int y) {
              const Eigen::Vector3d px = corner_offset(x).cast<double>() - centre, py = corner_offset(y).cast<double>() - centre;
              return std::atan2(px.dot(v), px.dot(u)) < std::atan2(py.dot(v), py.dot(u));
            });
            // counter-clockwise about n, so a fan is outward
            for (std::size_t i = 1; i + 1 < poly.size(); ++i) t[std::size_t(set)].push_back({poly[0], poly[i], poly[i + 1]});
          }
    }
    return t;
  }();
  return table[corners];
}

/// Accumulates triangles on lattice points and numbers the points in order of first use.
class LatticeMesh {
 public:
  explicit LatticeMesh(const Eigen::Vector3i& dims) : key_(dims) {}
  /// Adds triangle (a, b, c), turned so its normal points along `outward`.
  void add(const Eigen::Vector3i& a, Eigen::Vector3i b, Eigen::Vector3i c, const Eigen::Vector3i& outward) {
    if ((b - a).cross(c - a).dot(outward) < 0) std::swap(b, c);
    tris_.push_back({id(a), id(b), id(c)});
  }
  /// Adds triangle (a, b, c) as given.
  void add(const Eigen::Vector3i& a, const Eigen::Vector3i& b, const Eigen::Vector3i& c) {
    tris_.push_back({id(a), id(b), id(c)});
  }
  [[nodiscard]] const std::vector<Eigen::Vector3i>& points() const { return points_; }
  [[nodiscard]] const std::vector<std::array<int, 3>>& triangles() const { return tris_; }

 private:
  int id(const Eigen::Vector3i& a) {
    auto [it, fresh] = ids_.try_emplace(key_(a), int(points_.size()));
    if (fresh) points_.push_back(a);
    return it->second;
  }
  LatticeKey key_;
  std::unordered_map<std::int64_t, int> ids_;
  std::vector<Eigen::Vector3i> points_;
  std::vector<std::array<int, 3>> tris_;
};


/// The voxel grid seen as tissue or not, by lattice coordinates.
struct VoxelAccess {
  const VoxelGrid& grid;
  [[nodiscard]] std::size_t index(const Eigen::Vector3i& v) const { return std::size_t(grid.index(v.x(), v.y(), v.z())); }
  [[nodiscard]] bool inside(const Eigen::Vector3i& v) const { return grid.inside(v.x(), v.y(), v.z()); }
  [[nodiscard]] bool tissue(const Eigen::Vector3i& v) const { return grid.at(v.x(), v.y(), v.z()) != 0; }
};

Eigen::Vector3i axis_step(int axis) { return Eigen::Vector3i::Unit(axis); }

/// Fills of the concave steps (the paper's 3.3): for each empty voxel of the box [box_lo, box_hi]
/// touching tissue across two perpendicular faces, the set of its corners on its tissue faces
/// (the fill is their convex hull); 0 = no fill. One value per grid voxel.
std::vector<std::uint8_t> concave_step_fills(const VoxelAccess& g, const Eigen::Vector3i& box_lo,
                                             const Eigen::Vector3i& box_hi, VoxelSurfaceReport& report) {
  std::vector<std::uint8_t> fill(std::size_t(g.grid.geometry().voxel_count()), 0);
  for (int k = box_lo.z(); k <= box_hi.z(); ++k)
    for (int j = box_lo.y(); j <= box_hi.y(); ++j)
      for (int i = box_lo.x(); i <= box_hi.x(); ++i) {
        const Eigen::Vector3i v(i, j, k);
        if (g.tissue(v)) continue;
        int faces = 0;
        for (int f = 0; f < 6; ++f)
          if (g.tissue(v + (f % 2 ? 1 : -1) * axis_step(f / 2))) faces |= 1 << f;
        std::uint8_t corners = 0;
        for (int f = 0; f < 6; ++f)
          for (int h = f + 1; h < 6; ++h)
            if ((faces >> f & 1) && (faces >> h & 1) && f / 2 != h / 2) corners |= face_corners(f) | face_corners(h);
        fill[g.index(v)] = corners;
      }
  // two face-adjacent fills whose traces on the shared face are triangles on crossing
  // diagonals would leave a point off the lattice: leave both out (keep the staircase there)
  std::vector<std::size_t> drop;
  for (int k = box_lo.z(); k <= box_hi.z(); ++k)
    for (int j = box_lo.y(); j <= box_hi.y(); ++j)
      for (int i = box_lo.x(); i <= box_hi.x(); ++i) {
        const Eigen::Vector3i v(i, j, k);
        const std::uint8_t cv = fill[g.index(v)];
        if (!cv) continue;
        for (int axis = 0; axis < 3; ++axis) {
          const Eigen::Vector3i n = v + axis_step(axis);
          if (!g.inside(n) || !fill[g.index(n)]) continue;
          const std::uint8_t cn = fill[g.index(n)];
          // missing corner of each trace, as the lattice offset within the shared face
          const std::uint8_t tv = cv & face_corners(2 * axis + 1), tn = cn & face_corners(2 * axis);
          if (__builtin_popcount(tv) != 3 || __builtin_popcount(tn) != 3) continue;
          const Eigen::Vector3i mv = corner_offset(__builtin_ctz(face_corners(2 * axis + 1) & ~tv));
          const Eigen::Vector3i mn = corner_offset(__builtin_ctz(face_corners(2 * axis) & ~tn));
          const int differ = (mv - mn).cwiseAbs().sum() - 1;  // along the face: 0 same, 1 adjacent, 2 opposite
          if (differ == 1) {
            drop.push_back(g.index(v));
            drop.push_back(g.index(n));
          }
        }
      }
  std::sort(drop.begin(), drop.end());
  drop.erase(std::unique(drop.begin(), drop.end()), drop.end());
  for (std::size_t x : drop) fill[x] = 0;
  report.dropped_fills = std::int64_t(drop.size());
  return fill;
}

/// What one side of a voxel face holds and the other does not (4-bit traces over the face's
/// points pu + 2 pw): nothing, the square, or a half square (for two half squares on one
/// diagonal, each side keeps its own half).
int region_only(int x, int y) {
  if (x == 0 || x == y || y == 0xF) return 0;
  if (y == 0) return x;
  const int my = __builtin_ctz(~y & 0xF);  // y is a half square missing corner my
  if (x == 0xF) return 0xF & ~(1 << (3 - my));  // the other half: my and its two neighbours
  const int mx = __builtin_ctz(~x & 0xF);
  if (mx + my == 3) return x;  // halves of the same diagonal: x is wholly outside y
  throw Error("internal: crossing half-square traces on a voxel face");
}

/// On each voxel face of the box, compares the solid traces of the two voxels (tissue: the whole
/// face; a fill: the hull of its corners on the face; else nothing) and adds what is solid on one
/// side only, facing the other side. `fill` is empty without fills (the staircase).
void add_boundary_faces(const VoxelAccess& g, const std::vector<std::uint8_t>& fill, const Eigen::Vector3i& box_lo,
                        const Eigen::Vector3i& box_hi, LatticeMesh& mesh, VoxelSurfaceReport& report) {
  const auto fill_of = [&](const Eigen::Vector3i& v) -> std::uint8_t {
    return !fill.empty() && g.inside(v) ? fill[g.index(v)] : 0;
  };
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, w = (axis + 2) % 3;
    const Eigen::Vector3i e = axis_step(axis);
    Eigen::Vector3i start = box_lo, stop = box_hi;
    stop[axis] += 1;  // faces from the low side of box_lo to the high side of box_hi
    // trace of voxel v on its face at side s of this axis: 4-bit set over face points (pu + 2 pw)
    const auto trace = [&](const Eigen::Vector3i& v, int side) -> int {
      if (!g.inside(v)) return 0;
      if (g.tissue(v)) return 0xF;
      const std::uint8_t c = fill_of(v);
      int t = 0;
      for (int q = 0; q < 4; ++q) {
        Eigen::Vector3i o = Eigen::Vector3i::Zero();
        o[axis] = side;
        o[u] = q & 1;
        o[w] = q >> 1;
        if (c >> (o.x() + 2 * o.y() + 4 * o.z()) & 1) t |= 1 << q;
      }
      return __builtin_popcount(t) >= 3 ? t : 0;
    };
    for (int k = start.z(); k <= stop.z(); ++k)
      for (int j = start.y(); j <= stop.y(); ++j)
        for (int i = start.x(); i <= stop.x(); ++i) {
          const Eigen::Vector3i p(i, j, k);  // the voxel on the high side; the face's lowest corner
          const Eigen::Vector3i a = p - e;   // the voxel on the low side
          const bool ta = g.inside(a) && g.tissue(a), tb = g.inside(p) && g.tissue(p);
          report.boundary_faces += ta != tb;
          const int sa = trace(a, 1), sb = trace(p, 0);
          if (sa == sb) continue;
          const auto point = [&](int q) {
            Eigen::Vector3i x = p;
            x[u] += q & 1;
            x[w] += q >> 1;
            return x;
          };
          // emits the region (4 bits: the square, 3 bits: a half square) facing `out`
          const auto emit = [&](int region, const Eigen::Vector3i& out) {
            if (region == 0xF) {
              mesh.add(point(0), point(1), point(3), out);
              mesh.add(point(0), point(3), point(2), out);
            } else {
              int q[3], n = 0;
              for (int b = 0; b < 4; ++b)
                if (region >> b & 1) q[n++] = b;
              mesh.add(point(q[0]), point(q[1]), point(q[2]), out);
            }
          };
          const int a_only = region_only(sa, sb), b_only = region_only(sb, sa);
          if (a_only) emit(a_only, e);
          if (b_only) emit(b_only, -e);
        }
  }
}

/// Adds the hull faces inside each fill.
void add_fill_faces(const VoxelAccess& g, const std::vector<std::uint8_t>& fill, const Eigen::Vector3i& box_lo,
                    const Eigen::Vector3i& box_hi, LatticeMesh& mesh, VoxelSurfaceReport& report) {
  for (int k = box_lo.z(); k <= box_hi.z(); ++k)
    for (int j = box_lo.y(); j <= box_hi.y(); ++j)
      for (int i = box_lo.x(); i <= box_hi.x(); ++i) {
        const Eigen::Vector3i v(i, j, k);
        const std::uint8_t c = fill[g.index(v)];
        if (!c) continue;
        const int n = __builtin_popcount(c);
        (n == 8 ? report.filled_voxels : n == 7 ? report.filled_corners : report.filled_steps)++;
        for (const auto& t : hull_inner_faces(c))
          mesh.add(v + corner_offset(t[0]), v + corner_offset(t[1]), v + corner_offset(t[2]));
      }
}

/// The lattice mesh as a surface whose vertices are the model's surface nodes.
EmbeddedSurface embed_on_surface_nodes(const Model& model, const LatticeMesh& mesh, SurfaceMethod method) {
  const NodeFinder nodes(model, true);
  EmbeddedSurface s;
  s.method = method;
  s.model_nodes = model.num_nodes();
  const int nv = int(mesh.points().size()), nt = int(mesh.triangles().size());
  s.rest_vertices.resize(3, nv);
  s.embed_offsets.resize(std::size_t(nv) + 1);
  s.embed_nodes.resize(std::size_t(nv));
  s.embed_weights.assign(std::size_t(nv), 1.0);
  for (int v = 0; v < nv; ++v) {
    const Eigen::Vector3i& a = mesh.points()[std::size_t(v)];
    const int n = nodes.find(a);
    if (n < 0)
      throw Error("internal: surface point (" + std::to_string(a.x()) + "," + std::to_string(a.y()) + "," +
                  std::to_string(a.z()) + ") is not a model surface node; is the grid the model's grid?");
    s.embed_offsets[std::size_t(v)] = v;
    s.embed_nodes[std::size_t(v)] = n;
    s.rest_vertices.col(v) = model.rest_positions.col(n);
  }
  s.embed_offsets[std::size_t(nv)] = nv;
  // a mirroring direction matrix turns lattice-space orientation inside out
  const bool mirrored = model.grid.direction.determinant() < 0;
  s.triangles.resize(3, nt);
  for (int t = 0; t < nt; ++t) {
    const auto& tri = mesh.triangles()[std::size_t(t)];
    s.triangles.col(t) = mirrored ? Eigen::Vector3i(tri[0], tri[2], tri[1]) : Eigen::Vector3i(tri[0], tri[1], tri[2]);
  }
  s.finalize();
  return s;
}

}  // namespace

EmbeddedSurface make_voxel_surface(const Model& model, const VoxelGrid& grid, bool hide_concave_steps,
                                   VoxelSurfaceReport* report_out) {
  const Eigen::Vector3i d = grid.dims();
  if (d != model.grid.dims || std::int64_t(grid.data().size()) != grid.geometry().voxel_count())
    throw Error("the voxel grid does not match the model's grid (dims differ)");
  if (grid.count() != model.covered_voxels())
    throw Error("the voxel grid does not match the model: " + std::to_string(grid.count()) + " tissue voxels, model covers " +
                std::to_string(model.covered_voxels()));
  VoxelSurfaceReport report;
  const VoxelAccess g{grid};
  // voxels that can hold surface: the tissue box plus one voxel, within the grid (inclusive)
  Eigen::Vector3i lo, hi;
  grid.tissue_bounds(lo, hi);
  const Eigen::Vector3i box_lo = (lo.array() - 1).max(0).matrix(), box_hi = hi.array().min(d.array() - 1).matrix();
  // the paper's fills of the concave steps, the faces between solid and empty, the fills' faces
  const std::vector<std::uint8_t> fill =
      hide_concave_steps ? concave_step_fills(g, box_lo, box_hi, report) : std::vector<std::uint8_t>{};
  LatticeMesh mesh(d);
  add_boundary_faces(g, fill, box_lo, box_hi, mesh, report);
  if (hide_concave_steps) add_fill_faces(g, fill, box_lo, box_hi, mesh, report);
  EmbeddedSurface s = embed_on_surface_nodes(model, mesh, hide_concave_steps ? SurfaceMethod::paper : SurfaceMethod::staircase);
  if (report_out) *report_out = report;
  return s;
}

// ---------------------------------------------------------------------------------------------
// embedding of any mesh

namespace {

using WeightList = std::vector<std::pair<std::int32_t, double>>;

/// An element's least-squares affine fit (LatticeEmbedding::affine_weights).
struct Fit {
  std::vector<std::int32_t> nodes;
  Eigen::Matrix3Xd offsets;  ///< rest positions minus centroid
  Eigen::Vector3d centroid;
  Eigen::Matrix3d inverse_moment;
};

/// Node weights that express a lattice point: the node itself, or an element's affine fit. The
/// finders are built once and only read, so threads share one; each thread keeps its own
/// Scratch (the fits it made, the voxels' elements it looked up).
class LatticeEmbedding {
 public:
  struct Scratch {
    std::unordered_map<int, Fit> fits;
    /// owner() of recent voxels, direct-mapped by voxel key: neighbouring lattice points
    /// search the same voxels
    std::vector<std::pair<std::int64_t, std::int32_t>> owners =
        std::vector<std::pair<std::int64_t, std::int32_t>>(4096, {-1, -1});
  };

  explicit LatticeEmbedding(const Model& m) : m_(m), key_(m.grid.dims.array() + 2), nodes_(m, false), elements_(m) {}

  /// Appends the weights of lattice point a to `out`. Throws vx::Error for a point more than
  /// 8 voxels from any tissue.
  void weights(const Eigen::Vector3i& a, Scratch& scratch, WeightList& out) const {
    const int n = nodes_.find(a);
    if (n >= 0) {
      out.emplace_back(n, 1.0);
      return;
    }
    affine_weights(nearest_element(a, scratch), a, scratch, out);
  }

 private:
  /// elements_.owner(v), through the scratch's cache.
  int owner(const Eigen::Vector3i& v, Scratch& scratch) const {
    // a voxel outside the grid has none: clamped to one outside, every such voxel is one key
    const std::int64_t k = key_(v.cwiseMax(-1).cwiseMin(m_.grid.dims) + Eigen::Vector3i::Ones());
    auto& slot = scratch.owners[std::size_t(k) % scratch.owners.size()];
    if (slot.first != k) slot = {k, elements_.owner(v)};
    return slot.second;
  }

  /// Element of the tissue voxel nearest to lattice point a (the voxels around it first);
  /// ties go to the first in scan order.
  int nearest_element(const Eigen::Vector3i& a, Scratch& scratch) const {
    constexpr int max_radius = 8;
    int best = -1;
    double best_d2 = 0;
    for (int r = 1; r <= max_radius; ++r) {
      for (int z = -r; z < r; ++z)
        for (int y = -r; y < r; ++y)
          for (int x = -r; x < r; ++x) {
            // only the shell at Chebyshev radius r
            if (std::max({x < 0 ? -x : x + 1, y < 0 ? -y : y + 1, z < 0 ? -z : z + 1}) != r) continue;
            const int e = owner(a + Eigen::Vector3i(x, y, z), scratch);
            if (e < 0) continue;
            const double d2 = (x + 0.5) * (x + 0.5) + (y + 0.5) * (y + 0.5) + (z + 0.5) * (z + 0.5);
            if (best < 0 || d2 < best_d2) best = e, best_d2 = d2;
          }
      // voxels of the next shell are at least r + 0.5 away
      if (best >= 0 && best_d2 <= (r + 0.5) * (r + 0.5)) return best;
    }
    if (best >= 0) return best;
    throw Error("a surface vertex lies more than " + std::to_string(max_radius) +
                " voxels from any tissue: the surface does not belong to this model");
  }

  /// Weights of lattice point a from element e, exact for affine motion. A box element (all
  /// cells covered) interpolates trilinearly between its 8 corners. Any other element uses the
  /// least-squares affine fit of the corners of its region (the vertices where the union of
  /// its covered cells has a corner), evaluated at a's position p:
  /// w_i = 1/n + R_i^T M^-1 (p - C), R_i = X_i - C, M = sum_j R_j R_j^T. The corners span the
  /// element in 3D, so the fit is exact for affine motion, with about 8 weights instead of up to 27.
  void affine_weights(int e, const Eigen::Vector3i& a, Scratch& scratch, WeightList& out) const {
    // a box element (all 8 cells covered): trilinear over its 8 corners, fewer weights for
    // points on its edges and faces
    if (m_.element_cells[std::size_t(e)] == 0xFF) {
      const int w2 = 2 * m_.element_cell_voxels[std::size_t(e)];
      const Eigen::Vector3i anchor = m_.element_anchor.col(e);
      const Eigen::Vector3d t = (a - anchor).cast<double>() / double(w2);
      int corner_nodes[8];
      bool all = true;
      for (int c = 0; c < 8 && all; ++c) {
        corner_nodes[c] = nodes_.find(anchor + w2 * corner_offset(c));
        all = corner_nodes[c] >= 0;
      }
      if (all) {
        for (int c = 0; c < 8; ++c) {
          const Eigen::Vector3i o = corner_offset(c);
          const double wc = (o.x() ? t.x() : 1 - t.x()) * (o.y() ? t.y() : 1 - t.y()) * (o.z() ? t.z() : 1 - t.z());
          if (wc != 0) out.emplace_back(corner_nodes[c], wc);
        }
        return;
      }
    }
    const Eigen::Vector3d p = m_.grid.lattice_to_lps(a);
    auto it = scratch.fits.find(e);
    if (it == scratch.fits.end()) it = scratch.fits.emplace(e, fit_of(e)).first;
    const Fit& f = it->second;
    const Eigen::Vector3d g = f.inverse_moment * (p - f.centroid);
    const double n = double(f.nodes.size());
    for (std::size_t i = 0; i < f.nodes.size(); ++i) out.emplace_back(f.nodes[i], 1.0 / n + f.offsets.col(Eigen::Index(i)).dot(g));
  }

  /// True when lattice point a is a corner of the union of element e's covered cells.
  bool is_region_corner(int e, const Eigen::Vector3i& a) const {
    const int w = m_.element_cell_voxels[std::size_t(e)];
    const Eigen::Vector3i q = a - m_.element_anchor.col(e);
    if (q.x() % w || q.y() % w || q.z() % w) return false;
    const Eigen::Vector3i c = q / w;  // 0..2 per axis
    // occupancy of the 8 cells around the point; a corner is where it is not the same along any axis
    int o[2][2][2] = {};
    bool any = false;
    for (int dz = 0; dz < 2; ++dz)
      for (int dy = 0; dy < 2; ++dy)
        for (int dx = 0; dx < 2; ++dx) {
          const Eigen::Vector3i cell = c + Eigen::Vector3i(dx - 1, dy - 1, dz - 1);
          const bool in = (cell.array() >= 0).all() && (cell.array() < 2).all();
          o[dx][dy][dz] = in && (m_.element_cells[std::size_t(e)] >> (cell.x() + 2 * cell.y() + 4 * cell.z()) & 1);
          any = any || o[dx][dy][dz];
        }
    if (!any) return false;
    bool same_x = true, same_y = true, same_z = true;
    for (int i = 0; i < 2; ++i)
      for (int j = 0; j < 2; ++j) {
        same_x = same_x && o[0][i][j] == o[1][i][j];
        same_y = same_y && o[i][0][j] == o[i][1][j];
        same_z = same_z && o[i][j][0] == o[i][j][1];
      }
    return !(same_x || same_y || same_z);
  }

  Fit fit_of(int e) const {
    const int b = m_.element_offsets[std::size_t(e)], n = m_.element_offsets[std::size_t(e) + 1] - b;
    Fit f;
    for (int i = 0; i < n; ++i) {
      const int node = m_.element_vertices[std::size_t(b + i)];
      if (is_region_corner(e, m_.node_lattice.col(node))) f.nodes.push_back(node);
    }
    const auto solve = [&]() {
      const Eigen::Index k = Eigen::Index(f.nodes.size());
      f.offsets.resize(3, k);
      f.centroid.setZero();
      for (Eigen::Index i = 0; i < k; ++i) f.centroid += m_.rest_positions.col(f.nodes[std::size_t(i)]);
      f.centroid /= double(k);
      Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
      for (Eigen::Index i = 0; i < k; ++i) {
        f.offsets.col(i) = m_.rest_positions.col(f.nodes[std::size_t(i)]) - f.centroid;
        M += f.offsets.col(i) * f.offsets.col(i).transpose();
      }
      f.inverse_moment = M.inverse();
      // well conditioned for any set of cell corners spanning 3D; else report failure
      return k >= 4 && f.inverse_moment.allFinite() && M.determinant() > 1e-9 * std::pow(M.trace() / 3, 3);
    };
    if (solve()) return f;
    // defensive: all the element's vertices (always span 3D: they include a cell's 8 corners)
    f.nodes.assign(m_.element_vertices.begin() + b, m_.element_vertices.begin() + b + n);
    if (!solve()) throw Error("internal: element " + std::to_string(e) + " has degenerate vertices");
    return f;
  }

  const Model& m_;
  LatticeKey key_;  ///< of voxels clamped to one outside the grid, shifted by one (owner)
  NodeFinder nodes_;
  ElementFinder elements_;
};

/// Trilinear weight of corner c (corner_offset) of a cell at fractions t.
double corner_weight(const Eigen::Vector3d& t, int c) {
  const Eigen::Vector3i o = corner_offset(c);
  return (o.x() ? t.x() : 1 - t.x()) * (o.y() ? t.y() : 1 - t.y()) * (o.z() ? t.z() : 1 - t.z());
}

/// The lattice points a set of cells uses, as a bitmap over their box: each point's rank
/// among them (its row in a table of their weights) in constant time.
class UsedLatticePoints {
 public:
  UsedLatticePoints(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi)
      : lo_(lo),
        dims_((hi - lo).array() + 1),
        bits_(std::size_t((std::int64_t(dims_.x()) * dims_.y() * dims_.z() + 63) / 64), 0) {}
  void mark(const Eigen::Vector3i& a) {
    const std::int64_t i = index(a);
    bits_[std::size_t(i >> 6)] |= std::uint64_t(1) << (i & 63);
  }
  /// Ends the marking: the ranks, and the points in rank order.
  std::vector<Eigen::Vector3i> finish() {
    ranks_.assign(bits_.size() + 1, 0);
    std::vector<Eigen::Vector3i> points;
    for (std::size_t w = 0; w < bits_.size(); ++w) {
      ranks_[w + 1] = ranks_[w] + __builtin_popcountll(bits_[w]);
      for (std::uint64_t b = bits_[w]; b; b &= b - 1) {
        std::int64_t i = std::int64_t(w) * 64 + __builtin_ctzll(b);
        const int x = int(i % dims_.x());
        i /= dims_.x();
        points.push_back(lo_ + Eigen::Vector3i(x, int(i % dims_.y()), int(i / dims_.y())));
      }
    }
    return points;
  }
  /// Rank of marked point a (after finish).
  [[nodiscard]] std::int64_t rank(const Eigen::Vector3i& a) const {
    const std::int64_t i = index(a);
    const std::uint64_t below = (std::uint64_t(1) << (i & 63)) - 1;
    return ranks_[std::size_t(i >> 6)] + __builtin_popcountll(bits_[std::size_t(i >> 6)] & below);
  }

 private:
  [[nodiscard]] std::int64_t index(const Eigen::Vector3i& a) const {
    const Eigen::Vector3i q = a - lo_;
    return q.x() + std::int64_t(dims_.x()) * (q.y() + std::int64_t(dims_.y()) * q.z());
  }
  Eigen::Vector3i lo_, dims_;
  std::vector<std::uint64_t> bits_;
  std::vector<std::int64_t> ranks_;
};

/// Runs fn(chunk, begin, end) over [0, n) in parallel (parallel_for_chunks), then rethrows the
/// first chunk's exception, if any (a chunk stops at its first).
template <class Fn>
void parallel_chunks_rethrowing(std::int64_t n, std::int64_t grain, Fn&& fn) {
  std::vector<std::exception_ptr> failed(std::size_t(chunk_count(n, grain)));
  parallel_for_chunks(n, grain, 0, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
    try {
      fn(c, b, e);
    } catch (...) {
      failed[std::size_t(c)] = std::current_exception();
    }
  });
  for (const std::exception_ptr& f : failed)
    if (f) std::rethrow_exception(f);
}

}  // namespace

EmbeddedSurface embed_surface(const Model& model, const Eigen::Matrix3Xd& rest_vertices_mm,
                              const Eigen::Matrix3Xi& triangles, SurfaceMethod method) {
  if (model.num_nodes() == 0) throw Error("cannot embed a surface in an empty model");
  EmbeddedSurface s;
  s.method = method;
  s.model_nodes = model.num_nodes();
  s.rest_vertices = rest_vertices_mm;
  s.triangles = triangles;
  const int nv = int(rest_vertices_mm.cols());
  const Eigen::Vector3i d = model.grid.dims;
  // each vertex's voxel cell in lattice coordinates (lattice point a sits at index a - 0.5) and
  // its place in the cell
  std::vector<Eigen::Vector3i> cells;
  cells.resize(std::size_t(nv));
  Eigen::Matrix3Xd fractions(3, nv);
  Eigen::Vector3i lo = Eigen::Vector3i::Constant(std::numeric_limits<int>::max()), hi = -lo;
  for (int v = 0; v < nv; ++v) {
    const Eigen::Vector3d a = model.grid.lps_to_index(rest_vertices_mm.col(v)).array() + 0.5;
    if (!a.allFinite()) throw Error("surface vertex " + std::to_string(v) + " is not finite");
    Eigen::Vector3i& cell = cells[std::size_t(v)];
    for (int i = 0; i < 3; ++i) cell[i] = std::clamp(int(std::floor(a[i])), 0, std::max(d[i] - 1, 0));
    fractions.col(v) = a - cell.cast<double>();
    lo = lo.cwiseMin(cell);
    hi = hi.cwiseMax(cell);
  }
  if (nv == 0) {
    s.embed_offsets.assign(1, 0);
    s.finalize();
    return s;
  }
  // the lattice points with a weight (trilinear over each cell's 8), each expressed by nodes
  // once, in parallel: most are shared by several vertices, and one off the tissue searches
  // for its nearest element
  UsedLatticePoints used(lo, hi.array() + 1);
  for (int v = 0; v < nv; ++v)
    for (int c = 0; c < 8; ++c)
      if (corner_weight(fractions.col(v), c) != 0) used.mark(cells[std::size_t(v)] + corner_offset(c));
  const std::vector<Eigen::Vector3i> points = used.finish();
  const LatticeEmbedding lattice(model);
  constexpr std::int64_t grain = 4096;
  const std::int64_t np = std::int64_t(points.size());
  std::vector<WeightList> point_weights(std::size_t(chunk_count(np, grain)));
  std::vector<std::vector<std::int32_t>> point_ends(point_weights.size());  // per chunk: each point's end
  parallel_chunks_rethrowing(np, grain, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
    LatticeEmbedding::Scratch scratch;
    WeightList& out = point_weights[std::size_t(c)];
    for (std::int64_t i = b; i < e; ++i) {
      lattice.weights(points[std::size_t(i)], scratch, out);
      point_ends[std::size_t(c)].push_back(std::int32_t(out.size()));
    }
  });
  // each vertex: trilinear over its cell's lattice points, one entry per node (vertex chunks
  // of fixed bounds, joined in order: the same embedding on any number of threads)
  std::vector<std::vector<std::int32_t>> chunk_nodes(std::size_t(chunk_count(nv, grain)));
  std::vector<std::vector<double>> chunk_weights(chunk_nodes.size());
  std::vector<std::vector<std::int32_t>> chunk_counts(chunk_nodes.size());
  parallel_chunks_rethrowing(nv, grain, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
    WeightList w;
    for (std::int64_t v = b; v < e; ++v) {
      w.clear();
      for (int k = 0; k < 8; ++k) {
        const double tk = corner_weight(fractions.col(v), k);
        if (tk == 0) continue;
        const std::int64_t r = used.rank(cells[std::size_t(v)] + corner_offset(k));
        const std::size_t pc = std::size_t(r / grain), pi = std::size_t(r % grain);
        const WeightList& list = point_weights[pc];
        for (std::int32_t j = pi == 0 ? 0 : point_ends[pc][pi - 1]; j < point_ends[pc][pi]; ++j)
          w.emplace_back(list[std::size_t(j)].first, tk * list[std::size_t(j)].second);
      }
      std::sort(w.begin(), w.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
      std::size_t out = 0;
      for (std::size_t i = 0; i < w.size(); ++i) {
        if (out > 0 && w[out - 1].first == w[i].first)
          w[out - 1].second += w[i].second;
        else
          w[out++] = w[i];
      }
      std::int32_t kept = 0;
      for (std::size_t i = 0; i < out; ++i)
        if (w[i].second != 0) {
          chunk_nodes[std::size_t(c)].push_back(w[i].first);
          chunk_weights[std::size_t(c)].push_back(w[i].second);
          ++kept;
        }
      chunk_counts[std::size_t(c)].push_back(kept);
    }
  });
  std::int64_t entries = 0;
  for (const auto& n : chunk_nodes) entries += std::int64_t(n.size());
  if (entries > std::numeric_limits<std::int32_t>::max())
    throw Error("the surface embedding would exceed 2^31 entries: use a coarser surface");
  s.embed_offsets.reserve(std::size_t(nv) + 1);
  s.embed_offsets.assign(1, 0);
  s.embed_nodes.reserve(std::size_t(entries));
  s.embed_weights.reserve(std::size_t(entries));
  for (std::size_t c = 0; c < chunk_nodes.size(); ++c) {
    for (const std::int32_t k : chunk_counts[c]) s.embed_offsets.push_back(s.embed_offsets.back() + k);
    s.embed_nodes.insert(s.embed_nodes.end(), chunk_nodes[c].begin(), chunk_nodes[c].end());
    s.embed_weights.insert(s.embed_weights.end(), chunk_weights[c].begin(), chunk_weights[c].end());
    // each chunk freed once copied: the embedding is not held twice
    std::vector<std::int32_t>().swap(chunk_nodes[c]);
    std::vector<double>().swap(chunk_weights[c]);
  }
  s.finalize();
  return s;
}

}  // namespace vx
