#pragma once
/// @file lattice_lookup.h
/// Lookups into a model's lattice shared by the surface builders (surface.cpp) and the embedding
/// of any mesh (embed_surface.cpp): lattice points as keys, nodes and elements by lattice point
/// and voxel, the corners of a voxel. Internal to src/surface/.

#include <Eigen/Core>
#include <algorithm>
#include <cstdint>
#include <unordered_map>
#include <utility>
#include <vector>

#include "model/model.h"

namespace vx::detail {

/// Corner c of a voxel is (c & 1, c >> 1 & 1, c >> 2 & 1).
inline Eigen::Vector3i corner_offset(int c) { return {c & 1, c >> 1 & 1, c >> 2 & 1}; }

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

}  // namespace vx::detail
