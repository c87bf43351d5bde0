#pragma once
/// @file threshold.h
/// From a volume in HU to a binary voxel grid.

#include <limits>
#include <string>

#include "io/volume.h"
#include "model/voxel_grid.h"

namespace vx {

/// An HU window: voxels with lo <= value <= hi are tissue.
struct HuRange {
  double lo{-200.0};
  double hi{std::numeric_limits<double>::infinity()};
};

/// Parses "LO", "LO:HI" or a preset name (soft-tissue, bone, ...); throws vx::Error otherwise.
[[nodiscard]] HuRange parse_threshold(const std::string& text);

/// Tissue = voxels within the range.
[[nodiscard]] VoxelGrid threshold(const Volume& volume, const HuRange& range);

}  // namespace vx
