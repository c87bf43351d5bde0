#pragma once
/// @file voxel_grid.h
/// A binary voxel grid (1 = tissue, 0 = outside) with its place in patient space.

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace vx {

/// Where a grid of voxels sits in patient space (LPS, mm), the DICOM/VTK convention:
/// the centre of voxel (i,j,k) is at origin + direction * diag(spacing) * (i,j,k).
/// Voxel corners (lattice points, 0..dims per axis) are at half-integer voxel indices.
struct GridGeometry {
  Eigen::Vector3i dims{0, 0, 0};                          ///< voxels per axis
  Eigen::Vector3d spacing_mm{1.0, 1.0, 1.0};              ///< voxel size per axis, mm
  Eigen::Vector3d origin_mm{0.0, 0.0, 0.0};               ///< centre of voxel (0,0,0), LPS mm
  Eigen::Matrix3d direction{Eigen::Matrix3d::Identity()}; ///< columns: index axes in LPS

  /// Patient position (LPS mm) of a point given in continuous voxel-index coordinates.
  [[nodiscard]] Eigen::Vector3d index_to_lps(const Eigen::Vector3d& ijk) const;
  /// Continuous voxel-index coordinates of a patient position (LPS mm).
  [[nodiscard]] Eigen::Vector3d lps_to_index(const Eigen::Vector3d& lps_mm) const;
  /// Patient position of lattice point (voxel corner) a, 0 <= a <= dims.
  [[nodiscard]] Eigen::Vector3d lattice_to_lps(const Eigen::Vector3i& a) const;
  /// Number of voxels.
  [[nodiscard]] std::int64_t voxel_count() const {
    return std::int64_t(dims.x()) * dims.y() * dims.z();
  }
  /// Volume of one voxel, mm^3.
  [[nodiscard]] double voxel_volume_mm3() const { return spacing_mm.prod(); }
  /// True when direction is orthonormal with determinant +1 or -1 (within 1e-6).
  [[nodiscard]] bool direction_is_orthonormal() const;
  bool operator==(const GridGeometry&) const = default;
};

/// A binary voxel grid: one byte per voxel, x fastest (index = i + nx*(j + ny*k)).
class VoxelGrid {
 public:
  VoxelGrid() = default;
  explicit VoxelGrid(const GridGeometry& geometry);

  [[nodiscard]] const GridGeometry& geometry() const { return geometry_; }
  [[nodiscard]] const Eigen::Vector3i& dims() const { return geometry_.dims; }
  [[nodiscard]] std::int64_t index(int i, int j, int k) const {
    return i + std::int64_t(geometry_.dims.x()) * (j + std::int64_t(geometry_.dims.y()) * k);
  }
  [[nodiscard]] bool inside(int i, int j, int k) const {
    return i >= 0 && j >= 0 && k >= 0 && i < geometry_.dims.x() && j < geometry_.dims.y() &&
           k < geometry_.dims.z();
  }
  /// Value at (i,j,k); 0 outside the grid (the border counts as outside).
  [[nodiscard]] std::uint8_t at(int i, int j, int k) const {
    return inside(i, j, k) ? data_[std::size_t(index(i, j, k))] : 0;
  }
  void set(int i, int j, int k, std::uint8_t v) { data_[std::size_t(index(i, j, k))] = v ? 1 : 0; }
  /// Number of tissue voxels.
  [[nodiscard]] std::int64_t count() const;
  /// Smallest box holding all tissue voxels: lo inclusive, hi exclusive; empty grid gives lo=hi=0.
  void tissue_bounds(Eigen::Vector3i& lo, Eigen::Vector3i& hi) const;

  [[nodiscard]] std::vector<std::uint8_t>& data() { return data_; }
  [[nodiscard]] const std::vector<std::uint8_t>& data() const { return data_; }

 private:
  GridGeometry geometry_;
  std::vector<std::uint8_t> data_;
};

}  // namespace vx
