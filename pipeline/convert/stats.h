#pragma once
/// @file stats.h
/// The numbers that describe a built model, for the console summary and the stats file
/// (`voxelastic convert --stats STATS.json`).

#include <Eigen/Core>
#include <cstdint>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "model/model.h"

namespace vx {

/// Counts, sizes and cost of a model, derived from the model alone.
struct ModelStats {
  std::string layout;                        ///< gradational, uniform or voxel
  int dimensions{3};                         ///< 3: a volume model; 2: a slice model (docs/model.md section 12)
  Eigen::Vector3i grid{0, 0, 0};                 ///< voxels per axis of the grid the model was built from
  Eigen::Vector3d spacing_mm{0, 0, 0};           ///< voxel size per axis, mm
  std::int64_t voxels{0};                        ///< tissue voxels covered by the elements
  double volume_mm3{0};                          ///< tissue volume, mm^3
  std::int64_t elements{0};
  std::vector<std::int64_t> elements_per_level;  ///< level 0 first
  std::vector<double> element_edge_mm;           ///< per level: edge of the element cube, mm
  std::int64_t nodes{0};
  std::int64_t surface_nodes{0};
  std::int64_t vertex_entries{0};                ///< sum of the elements' vertex counts (work per step)
  std::int64_t voxel_model_vertex_entries{0};    ///< 8 per tissue voxel: one 8-vertex element per voxel (2D: 4 per pixel)
  double reduction{0};                           ///< voxel_model_vertex_entries / vertex_entries
  Eigen::Vector3d bounds_min_mm{0, 0, 0};        ///< tissue bounding box, LPS mm
  Eigen::Vector3d bounds_max_mm{0, 0, 0};
};

/// Computes the statistics of `model` (an empty model gives zeros).
[[nodiscard]] ModelStats model_stats(const Model& model);

/// The statistics as JSON with keys: resolution, dimensions (2 or 3), grid [nx,ny,nz], spacing_mm [3], voxels,
/// volume_mm3, elements, elements_per_level, element_edge_mm, nodes, surface_nodes,
/// vertex_entries, voxel_model_vertex_entries, reduction, bounds_mm {"min":[3],"max":[3]}.
void to_json(nlohmann::json& j, const ModelStats& s);

/// Human-readable lines for the console (no trailing newline).
[[nodiscard]] std::string summary(const ModelStats& s);

}  // namespace vx
