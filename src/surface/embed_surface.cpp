#include "surface/surface.h"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <exception>
#include <limits>
#include <unordered_map>
#include <vector>

#include "base/error.h"
#include "base/parallel.h"
#include "surface/lattice_lookup.h"

// The embedding of any mesh in a model's elements (surface.h, embed_surface): each vertex
// trilinear over its voxel cell's lattice points, each lattice point a node or an element's fit.

namespace vx {

using detail::corner_offset;
using detail::ElementFinder;
using detail::LatticeKey;
using detail::NodeFinder;

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
    for (std::size_t i = 0; i < f.nodes.size(); ++i)
      out.emplace_back(f.nodes[i], 1.0 / n + f.offsets.col(Eigen::Index(i)).dot(g));
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
