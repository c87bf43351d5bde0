#include "physics/calibration_key.h"
// The calibration cache's key (calibration_key.h): what a calibration depends on,
// hashed.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <type_traits>
#include <vector>

#include "base/content_hash.h"
#include "model/gradational_builder.h"
#include "physics/calibrated_fields.h"
#include "physics/calibration.h"

namespace vx {

namespace {

/// Raised by hand when the calibration's output changes in a way the reference model below would
/// not show (an element shape it lacks): the keys of older files then no longer match.
/// 2: the isotropic weights solved once per element shape (calibrate_elements), which moves some
/// congruent elements' weights off their own solve's where the reference ball shows no change.
constexpr std::uint64_t kCalibrationVersion = 2;

void add_material(ContentHash& h, const Material& material, const MaterialField& field, const CalibrationOptions& o) {
  h.add_value(material.youngs_modulus_kpa);
  h.add_value(material.density_kg_m3);
  h.add_value(material.damping_ratio);
  h.add_value(material.poisson_ratio);
  h.add_vector(field.youngs_modulus_kpa);
  h.add_vector(field.density_kg_m3);
  h.add_value(std::uint8_t(o.element));
  h.add_value(o.bending_relief);
  h.add_value(o.xyz_relief);
  h.add_value(std::uint8_t(o.isotropic_weights ? 1 : 0));
  h.add_value(o.min_weight);
  h.add_value(o.max_weight);
  h.add_value(o.mass_scaling.factor);
  h.add_value(o.mass_scaling.time_step_s);
  h.add_value(o.volume_mean_fraction);
  h.add_value(o.volume_point_position);
  h.add_value(o.volume_variation_cap);
}

/// The calibrated part of a PhysicsModel (calibrated_fields.h), bit for bit.
void add_calibration(ContentHash& h, const PhysicsModel& p) {
  for_each_calibrated_field(
      [&h](const char*, CalibratedCount, const auto& v) {
        using V = std::decay_t<decltype(v)>;
        if constexpr (std::is_arithmetic_v<V>)
          h.add_value(v);
        else if constexpr (std::is_same_v<V, std::vector<Eigen::Matrix3d>>)
          for (const Eigen::Matrix3d& c : v) h.add_matrix(c);
        else if constexpr (std::is_base_of_v<Eigen::EigenBase<V>, V>)
          h.add_matrix(v);
        else
          h.add_vector(v);
      },
      p);
  h.add_vector(p.node_mass);  // the derived masses too (mass scaling)
}

/// The calibration of a small reference object built like `model` (its layout, dimensions, voxel
/// spacing and directions: a ball of radius 5.5 voxels, whose surface has partly filled elements
/// and extra face vertices, the inside larger elements) with the same material and options,
/// hashed: this build's calibration code, as far as the reference shows it.
std::uint64_t reference_calibration(const Model& model, const Material& material, const CalibrationOptions& options) {
  GridGeometry g;
  const bool flat = model.is_2d();
  g.dims = flat ? Eigen::Vector3i(14, 14, 1) : Eigen::Vector3i(14, 14, 14);
  g.spacing_mm = model.grid.spacing_mm;
  g.direction = model.grid.direction;
  VoxelGrid grid(g);
  const Eigen::Vector3d c = 0.5 * (g.dims.cast<double>() - Eigen::Vector3d::Ones());
  for (int k = 0; k < g.dims.z(); ++k)
    for (int j = 0; j < g.dims.y(); ++j)
      for (int i = 0; i < g.dims.x(); ++i) {
        const Eigen::Vector3d d = Eigen::Vector3d(i, j, k) - c;
        const double r2 = flat ? d.head<2>().squaredNorm() : d.squaredNorm();
        grid.set(i, j, k, r2 <= 5.5 * 5.5 ? 1 : 0);
      }
  BuildSettings build;
  build.layout = model.layout;
  build.dimensions = model.dimensions;
  const auto physics = make_physics_model(build_model(grid, build), material, {}, options);
  ContentHash h;
  add_calibration(h, *physics);
  return h.value();
}

}  // namespace

// the values one by one: no padding is hashed
void add_model_content(ContentHash& h, const Model& m) {
  h.add_value(std::uint8_t(m.layout));
  h.add_value(std::int32_t(m.dimensions));
  h.add_matrix(m.grid.dims);
  h.add_matrix(m.grid.spacing_mm);
  h.add_matrix(m.grid.origin_mm);
  h.add_matrix(m.grid.direction);
  h.add_matrix(m.rest_positions);
  h.add_matrix(m.node_lattice);
  h.add_vector(m.node_surface);
  h.add_vector(m.element_offsets);
  h.add_vector(m.element_vertices);
  h.add_vector(m.element_level);
  h.add_vector(m.element_cell_voxels);
  h.add_matrix(m.element_anchor);
  h.add_vector(m.element_cells);
  h.add_matrix(m.rest_offsets);
  h.add_matrix(m.rest_centroids);
  h.add_vector(m.element_volume_mm3);
  h.add_vector(m.element_size_mm);
}

std::string CalibrationKey::name() const {
  char hex[17];
  static constexpr char kDigits[] = "0123456789abcdef";
  for (int i = 0; i < 16; ++i) hex[i] = kDigits[(hash >> (60 - 4 * i)) & 0xF];
  hex[16] = 0;
  return "calibration-" + std::to_string(elements) + "e-" + std::to_string(entries) + "v-" + hex;
}

CalibrationKey calibration_key(const Model& model, const Material& material, const MaterialField& field,
                               const CalibrationOptions& options) {
  ContentHash h;
  h.add_value(kCalibrationVersion);
  add_model_content(h, model);
  add_material(h, material, field, options);
  h.add_value(reference_calibration(model, material, options));
  CalibrationKey key;
  key.hash = h.value();
  key.elements = model.num_elements();
  key.entries = model.num_vertex_entries();
  return key;
}

}  // namespace vx
