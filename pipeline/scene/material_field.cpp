// The material of a scene per element: Young's modulus (and density) from a Hounsfield table and
// spherical inclusions, averaged over each element's voxels; and the voxels a model covers.
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "base/error.h"
#include "scene/scene.h"

namespace vx {

double modulus_from_hu(const std::vector<HuModulus>& t, double hu) {
  if (t.empty()) return 0.0;
  if (hu <= t.front().hu) return t.front().youngs_modulus_kpa;
  if (hu >= t.back().hu) return t.back().youngs_modulus_kpa;
  const auto it = std::upper_bound(t.begin(), t.end(), hu, [](double h, const HuModulus& r) { return h < r.hu; });
  const HuModulus& b = *it;
  const HuModulus& a = *(it - 1);
  const double u = (hu - a.hu) / (b.hu - a.hu);
  return (1 - u) * a.youngs_modulus_kpa + u * b.youngs_modulus_kpa;
}

namespace {

/// Calls fn(i, j, k) for every voxel covered by element e of the model.
template <class Fn>
void for_each_voxel(const Model& m, int e, Fn&& fn) {
  const int w = m.element_cell_voxels[std::size_t(e)];
  const Eigen::Vector3i a = m.element_anchor.col(e);
  const std::uint8_t cells = m.element_cells[std::size_t(e)];
  for (int c = 0; c < 8; ++c) {
    if (!(cells & (1u << c))) continue;
    const Eigen::Vector3i lo = a + w * Eigen::Vector3i(c & 1, (c >> 1) & 1, (c >> 2) & 1);
    for (int k = lo.z(); k < lo.z() + w; ++k)
      for (int j = lo.y(); j < lo.y() + w; ++j)
        for (int i = lo.x(); i < lo.x() + w; ++i) fn(i, j, k);
  }
}

float sample_hu(const Volume& v, const Eigen::Vector3d& p) {
  const Eigen::Vector3d ijk = v.geometry.lps_to_index(p);
  const Eigen::Vector3i& d = v.geometry.dims;
  const int i = std::clamp(int(std::lround(ijk.x())), 0, d.x() - 1);
  const int j = std::clamp(int(std::lround(ijk.y())), 0, d.y() - 1);
  const int k = std::clamp(int(std::lround(ijk.z())), 0, d.z() - 1);
  return v.at(i, j, k);
}

}  // namespace

MaterialField material_field(const Model& m, const SceneMaterial& mat, const Volume* hu) {
  MaterialField field;
  if (mat.hounsfield.empty() && mat.inclusions.empty()) return field;
  if (!mat.hounsfield.empty() && !hu) throw Error("material: the Hounsfield table needs the object's volume");
  const int ne = m.num_elements();
  const bool any_density = std::any_of(mat.inclusions.begin(), mat.inclusions.end(),
                                       [](const Inclusion& i) { return i.density_kg_m3 > 0; });
  field.youngs_modulus_kpa.assign(std::size_t(ne), mat.base.youngs_modulus_kpa);
  if (any_density) field.density_kg_m3.assign(std::size_t(ne), mat.base.density_kg_m3);
#pragma omp parallel for schedule(dynamic, 64)
  for (int e = 0; e < ne; ++e) {
    // Voigt average over the element's voxels (voxel centres)
    double sum_e = 0, sum_rho = 0;
    std::int64_t n = 0;
    for_each_voxel(m, e, [&](int i, int j, int k) {
      const Eigen::Vector3d p = m.grid.index_to_lps(Eigen::Vector3d(i, j, k));
      double e_kpa = hu && !mat.hounsfield.empty() ? modulus_from_hu(mat.hounsfield, sample_hu(*hu, p))
                                                   : mat.base.youngs_modulus_kpa;
      double rho = mat.base.density_kg_m3;
      for (const Inclusion& inc : mat.inclusions)  // the last inclusion holding the voxel wins
        if ((p - inc.center_mm).squaredNorm() < inc.radius_mm * inc.radius_mm) {
          e_kpa = inc.youngs_modulus_kpa;
          if (inc.density_kg_m3 > 0) rho = inc.density_kg_m3;
        }
      sum_e += e_kpa;
      sum_rho += rho;
      ++n;
    });
    if (n > 0) {
      field.youngs_modulus_kpa[std::size_t(e)] = sum_e / double(n);
      if (any_density) field.density_kg_m3[std::size_t(e)] = sum_rho / double(n);
    }
  }
  return field;
}

std::vector<double> element_mean_values(const Model& m, const Volume& volume) {
  const int ne = m.num_elements();
  std::vector<double> mean(std::size_t(ne), 0.0);
#pragma omp parallel for schedule(dynamic, 64)
  for (int e = 0; e < ne; ++e) {
    double sum = 0;
    std::int64_t n = 0;
    for_each_voxel(m, e, [&](int i, int j, int k) {
      sum += sample_hu(volume, m.grid.index_to_lps(Eigen::Vector3d(i, j, k)));
      ++n;
    });
    mean[std::size_t(e)] = n > 0 ? sum / double(n) : 0.0;
  }
  return mean;
}

VoxelGrid grid_from_model(const Model& m) {
  VoxelGrid grid(m.grid);
  for (int e = 0; e < m.num_elements(); ++e)
    for_each_voxel(m, e, [&](int i, int j, int k) {
      if (grid.inside(i, j, k)) grid.set(i, j, k, 1);
    });
  return grid;
}

}  // namespace vx
