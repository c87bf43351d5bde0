#pragma once
// The 2D (quadtree) builder behind build_model (private to src/model: call build_model with
// settings.dimensions = 2).

#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "base/error.h"
#include "model/gradational_builder.h"

namespace vx {

/// The 2D (quadtree) analogue of the builder for a grid one voxel thick (dims z = 1),
/// gradational_builder_2d.cpp: 2x2 groups of square cells, the same shell rules (edges for
/// faces, rings for shells), dense vertices at the cell corners of surface-boundary edges,
/// shared nodes between levels. Nodes on the slice's centre plane (model.h). `grid` has been
/// checked by build_model (consistent, one slice, tissue in it); fills report's
/// elements_per_level.
[[nodiscard]] Model build_model_2d(const VoxelGrid& grid, const BuildSettings& settings, BuildReport& report);

// What the 3D and the 2D builder share, over their own seed types (an element while building:
// `level`, `width` in voxels, `cells` its covered cells as bits).
namespace builder {

/// The seeds of the layout settings.layout names: `gradational(max_level)` (gradational: up to
/// settings.max_level; uniform: 0, every element one group of level 0), or `per_voxel()`.
template <class Gradational, class PerVoxel>
[[nodiscard]] auto layout_seeds(const BuildSettings& settings, const Gradational& gradational,
                                const PerVoxel& per_voxel) -> decltype(per_voxel()) {
  decltype(per_voxel()) seeds;
  switch (settings.layout) {
    case Layout::gradational: seeds = gradational(settings.max_level); break;
    case Layout::uniform: seeds = gradational(0); break;
    case Layout::voxel: seeds = per_voxel(); break;
  }
  return seeds;
}

/// The paper's level loop (docs/model.md section 3) from `cells`, the 0/1 cells of width one
/// voxel, `total` of them 1: at each level (cells 2^level voxels wide; every group with a 1-cell
/// taken from max_level on when it is >= 0) `level_pass(cells, level, take_all, covered)` gives
/// elements to the groups that get one, zeroes their cells, adds the voxels they cover to
/// `covered` and returns how many it gave; then the grid is halved (`halve`). Until no 1-cell is
/// left. Progress runs from 0 to 0.6.
template <class Cells, class LevelPass, class Halve>
void level_by_level(Cells cells, std::int64_t total, int max_level, BuildReport& report,
                    const std::function<void(double)>& progress, const LevelPass& level_pass, const Halve& halve) {
  std::int64_t covered = 0;
  for (int level = 0; !cells.empty(); ++level) {
    if (level > 30) throw Error("internal: more than 30 levels");
    const bool take_all = max_level >= 0 && level >= max_level;
    report.elements_per_level.push_back(level_pass(cells, level, take_all, covered));
    if (progress) progress(0.6 * double(covered) / double(total));
    // (3) halve the grid, (4) double the element size
    cells = halve(cells);
  }
}

/// Numbers the marked points of a node lattice (`id`: >= 0 marked, -1 not) in lattice order
/// and sizes the model's node arrays for them; returns the count. Throws vx::Error past 2^31
/// nodes, naming `too_fine` (what to resample, and how).
inline std::int64_t number_marked(std::vector<std::int32_t>& id, Model& model, const char* too_fine) {
  std::int64_t count = 0;
  for (auto& v : id)
    if (v >= 0) {
      if (count >= std::numeric_limits<std::int32_t>::max())
        throw Error(std::string("the model would have more than 2^31 nodes: ") + too_fine);
      v = std::int32_t(count++);
    }
  model.rest_positions.resize(3, count);
  model.node_lattice.resize(3, count);
  model.node_surface.assign(std::size_t(count), 0);
  return count;
}

/// Closes the element whose vertices were just appended: its offset, level, cell width, cells.
template <class Seed>
void close_element(const Seed& s, Model& model) {
  model.element_offsets.push_back(std::int32_t(model.element_vertices.size()));
  model.element_level.push_back(std::int8_t(s.level));
  model.element_cell_voxels.push_back(s.width);
  model.element_cells.push_back(s.cells);
}

/// Stores the seeds as the model's elements in order: `append(seed)` appends a seed's vertices
/// and closes it, `anchor(seed)` is its lowest lattice corner. Progress runs from 0.6 to 1.
/// Throws vx::Error past 2^31 vertex entries, naming `too_fine` (what to resample, and how).
template <class Seed, class Anchor, class Append>
void store_seeds(const std::vector<Seed>& seeds, Model& model, const std::function<void(double)>& progress,
                 const char* too_fine, const Anchor& anchor, const Append& append) {
  model.element_offsets.assign(1, 0);
  model.element_anchor.resize(3, std::int64_t(seeds.size()));
  for (std::size_t e = 0; e < seeds.size(); ++e) {
    model.element_anchor.col(std::int64_t(e)) = anchor(seeds[e]);
    append(seeds[e]);
    if (model.element_vertices.size() > std::size_t(std::numeric_limits<std::int32_t>::max()))
      throw Error(std::string("the model would have more than 2^31 vertex entries: ") + too_fine);
    if (progress && (e & 4095) == 0) progress(0.6 + 0.4 * double(e) / double(seeds.size()));
  }
}

}  // namespace builder

}  // namespace vx
