#include "model/voxel_grid.h"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>

namespace vx {

Eigen::Vector3d GridGeometry::index_to_lps(const Eigen::Vector3d& ijk) const {
  return origin_mm + direction * spacing_mm.cwiseProduct(ijk);
}

Eigen::Vector3d GridGeometry::lps_to_index(const Eigen::Vector3d& lps_mm) const {
  return (direction.inverse() * (lps_mm - origin_mm)).cwiseQuotient(spacing_mm);
}

Eigen::Vector3d GridGeometry::lattice_to_lps(const Eigen::Vector3i& a) const {
  return index_to_lps(a.cast<double>() - Eigen::Vector3d::Constant(0.5));
}

bool GridGeometry::direction_is_orthonormal() const {
  const double err = (direction.transpose() * direction - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  return err < 1e-6 && std::abs(std::abs(direction.determinant()) - 1.0) < 1e-6;
}

VoxelGrid::VoxelGrid(const GridGeometry& geometry)
    : geometry_(geometry), data_(std::size_t(std::max<std::int64_t>(geometry.voxel_count(), 0)), 0) {}

std::int64_t VoxelGrid::count() const {
  return std::count_if(data_.begin(), data_.end(), [](std::uint8_t v) { return v != 0; });
}

void VoxelGrid::tissue_bounds(Eigen::Vector3i& lo, Eigen::Vector3i& hi) const {
  const Eigen::Vector3i& d = geometry_.dims;
  lo = d;
  hi = Eigen::Vector3i::Zero();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j) {
      const std::uint8_t* row = data_.data() + index(0, j, k);
      for (int i = 0; i < d.x(); ++i)
        if (row[i]) {
          lo = lo.cwiseMin(Eigen::Vector3i(i, j, k));
          hi = hi.cwiseMax(Eigen::Vector3i(i + 1, j + 1, k + 1));
        }
    }
  if ((hi.array() <= lo.array()).any()) lo = hi = Eigen::Vector3i::Zero();
}

}  // namespace vx
