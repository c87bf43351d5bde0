#include "convert/stats.h"

#include <fmt/format.h>

#include <nlohmann/json.hpp>

namespace vx {

ModelStats model_stats(const Model& m) {
  ModelStats s;
  s.layout = to_string(m.layout);
  s.dimensions = m.dimensions;
  s.grid = m.grid.dims;
  s.spacing_mm = m.grid.spacing_mm;
  s.voxels = m.covered_voxels();
  s.volume_mm3 = double(s.voxels) * m.grid.voxel_volume_mm3();
  s.elements = m.num_elements();
  s.elements_per_level = m.elements_per_level();
  s.element_edge_mm.assign(s.elements_per_level.size(), 0.0);
  for (int e = 0; e < m.num_elements() && std::size_t(e) < m.element_size_mm.size(); ++e)
    s.element_edge_mm[std::size_t(m.element_level[std::size_t(e)])] = m.element_size_mm[std::size_t(e)];
  s.nodes = m.num_nodes();
  s.surface_nodes = m.num_surface_nodes();
  s.vertex_entries = m.num_vertex_entries();
  s.voxel_model_vertex_entries = (m.is_2d() ? 4 : 8) * s.voxels;
  s.reduction = s.vertex_entries > 0 ? double(s.voxel_model_vertex_entries) / double(s.vertex_entries) : 0.0;
  if (m.num_nodes() > 0) {
    s.bounds_min_mm = m.rest_positions.rowwise().minCoeff();
    s.bounds_max_mm = m.rest_positions.rowwise().maxCoeff();
  }
  return s;
}

void to_json(nlohmann::json& j, const ModelStats& s) {
  const auto vec = [](const auto& v) { return nlohmann::json::array({v.x(), v.y(), v.z()}); };
  j = nlohmann::json{{"resolution", s.layout},
                     {"dimensions", s.dimensions},
                     {"grid", vec(s.grid)},
                     {"spacing_mm", vec(s.spacing_mm)},
                     {"voxels", s.voxels},
                     {"volume_mm3", s.volume_mm3},
                     {"elements", s.elements},
                     {"elements_per_level", s.elements_per_level},
                     {"element_edge_mm", s.element_edge_mm},
                     {"nodes", s.nodes},
                     {"surface_nodes", s.surface_nodes},
                     {"vertex_entries", s.vertex_entries},
                     {"voxel_model_vertex_entries", s.voxel_model_vertex_entries},
                     {"reduction", s.reduction},
                     {"bounds_mm", {{"min", vec(s.bounds_min_mm)}, {"max", vec(s.bounds_max_mm)}}}};
}

std::string summary(const ModelStats& s) {
  std::string levels;
  for (std::size_t l = 0; l < s.elements_per_level.size(); ++l)
    levels += fmt::format("{}level {}: {} ({:.3g} mm)", l ? ", " : "", l, s.elements_per_level[l], s.element_edge_mm[l]);
  std::string out;
  if (s.dimensions == 2) {
    // the pixel size is the input's (or the resampled one), printed with it
    out += fmt::format("model:          2D (slice, plane stress) {} resolution, {} x {} pixels\n", s.layout, s.grid.x(),
                       s.grid.y());
    out += fmt::format("tissue:         {} pixels, {:.1f} mm^2 ({:.1f} mm^3 of slice)\n", s.voxels,
                       s.volume_mm3 / s.spacing_mm.z(), s.volume_mm3);
  } else {
    out += fmt::format("model:          {} resolution, grid {} x {} x {} voxels\n", s.layout, s.grid.x(), s.grid.y(),
                       s.grid.z());
    out += fmt::format("tissue:         {} voxels, {:.1f} mm^3 ({:.2f} ml)\n", s.voxels, s.volume_mm3, s.volume_mm3 * 1e-3);
  }
  out += fmt::format("elements:       {} ({})\n", s.elements, levels);
  out += fmt::format("nodes:          {} ({} on the surface)\n", s.nodes, s.surface_nodes);
  out += fmt::format("vertex entries: {} ({}-level model: {}, {} per {}; reduction {:.1f}x)\n", s.vertex_entries,
                     s.dimensions == 2 ? "pixel" : "voxel", s.voxel_model_vertex_entries, s.dimensions == 2 ? 4 : 8,
                     s.dimensions == 2 ? "pixel" : "voxel", s.reduction);
  const Eigen::Vector3d size = s.bounds_max_mm - s.bounds_min_mm;
  out += fmt::format("extent:         {:.1f} x {:.1f} x {:.1f} mm (LPS box [{:.1f}, {:.1f}] x [{:.1f}, {:.1f}] x [{:.1f}, {:.1f}])",
                     size.x(), size.y(), size.z(), s.bounds_min_mm.x(), s.bounds_max_mm.x(), s.bounds_min_mm.y(),
                     s.bounds_max_mm.y(), s.bounds_min_mm.z(), s.bounds_max_mm.z());
  return out;
}

}  // namespace vx
