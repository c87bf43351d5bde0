#pragma once
/// @file lattice_origin.h
/// Choosing where the builder's lattice starts (docs/model.md section 3.5): the same tissue,
/// padded on its low side by a few air voxels per axis, is grouped differently into 2x2x2 cells
/// at every level, and some alignments give fewer elements and vertex entries (the cost of a
/// step) than others. Patient positions do not change: only the grid's first voxel moves.

#include <cstdint>

#include <Eigen/Core>

#include "model/gradational_builder.h"
#include "model/voxel_grid.h"

namespace vx {

/// What choose_lattice_shift tried and found.
struct LatticeShiftReport {
  Eigen::Vector3i shift{0, 0, 0};     ///< air voxels added before the first voxel, per axis
  std::int64_t entries_unshifted{0};  ///< vertex entries of the model of the grid as given
  std::int64_t entries_chosen{0};     ///< vertex entries at the chosen shift
  std::int64_t elements_unshifted{0};
  std::int64_t elements_chosen{0};
  int builds{0};                      ///< models built to decide
  double seconds{0.0};                ///< wall time spent deciding
};

/// The grid padded by `shift` (>= 0 per axis) air voxels on the low side of each axis: the same
/// voxels at the same patient positions, the first voxel `shift` voxels earlier.
[[nodiscard]] VoxelGrid pad_low(const VoxelGrid& grid, const Eigen::Vector3i& shift);

/// The shift (0 .. period-1 per axis, period a power of two >= 1) that gives the fewest vertex
/// entries of the model `settings` builds, found axis by axis (x, then y, then z, each with the
/// others fixed at their best so far; ties keep the smaller shift, so an unshifted grid that is
/// already best stays as it is). A voxel-layout model does not depend on the shift (shift 0,
/// one build). A 2D model (settings.dimensions == 2) never shifts its third axis. Costs
/// 1 + (period - 1) x axes builds.
[[nodiscard]] Eigen::Vector3i choose_lattice_shift(const VoxelGrid& grid, const BuildSettings& settings,
                                                   int period = 4, LatticeShiftReport* report = nullptr);

}  // namespace vx
