#include "surface/surface.h"

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <limits>
#include <numeric>
#include <set>
#include <sstream>
#include <unordered_map>

#include "base/error.h"
#include "surface/lattice_lookup.h"

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
    if (e <= b) {
      err << "vertex " << v << " has no embedding entry; ";
      break;
    }
    double sum = 0;
    bool bad_node = false;
    for (int k = b; k < e; ++k) {
      sum += embed_weights[std::size_t(k)];
      bad_node = bad_node || embed_nodes[std::size_t(k)] < 0 || embed_nodes[std::size_t(k)] >= model_nodes;
    }
    if (bad_node) {
      err << "vertex " << v << " refers to a node outside 0.." << model_nodes - 1 << "; ";
      break;
    }
    if (!(std::abs(sum - 1.0) < 1e-9)) {
      err << "weights of vertex " << v << " sum to " << sum << ", not 1; ";
      break;
    }
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

namespace {

using detail::corner_offset;
using detail::ElementFinder;
using detail::LatticeKey;
using detail::NodeFinder;

// ---------------------------------------------------------------------------------------------
// voxel surface (staircase and the paper's surface)

/// Face f of a voxel: axis f / 2, side f % 2 (0: the low side, 1: the high side).

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
              const Eigen::Vector3d px = corner_offset(x).cast<double>() - centre,
                                    py = corner_offset(y).cast<double>() - centre;
              return std::atan2(px.dot(v), px.dot(u)) < std::atan2(py.dot(v), py.dot(u));
            });
            // counter-clockwise about n, so a fan is outward
            for (std::size_t i = 1; i + 1 < poly.size(); ++i)
              t[std::size_t(set)].push_back({poly[0], poly[i], poly[i + 1]});
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
  [[nodiscard]] std::size_t index(const Eigen::Vector3i& v) const {
    return std::size_t(grid.index(v.x(), v.y(), v.z()));
  }
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
  const int my = __builtin_ctz(~y & 0xF);       // y is a half square missing corner my
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
    throw Error("the voxel grid does not match the model: " + std::to_string(grid.count()) +
                " tissue voxels, model covers " + std::to_string(model.covered_voxels()));
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
  EmbeddedSurface s =
      embed_on_surface_nodes(model, mesh, hide_concave_steps ? SurfaceMethod::paper : SurfaceMethod::staircase);
  if (report_out) *report_out = report;
  return s;
}

}  // namespace vx
