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
