#pragma once
/// @file element_batch_layout.h
/// The data of the batched element pass (element_batches.h): the elements grouped into batches
/// of kBatchLanes, one element per SIMD lane, each batch's vertex entries stored as rows of
/// kBatchLanes entries. The PhysicsModel holds it (physics_model.h); element_batches.h builds
/// it and runs the kernel on it. The instruction sets it runs on (SimdLevel) are here too: the
/// element pass's options name them (elements.h).
///
/// Units: mm, N, s.

#include <cstdint>
#include <vector>

#include "base/simd.h"
#include "physics/element_modes.h"

namespace vx {

/// Elements per batch (SIMD lanes of 4 doubles: AVX2).
inline constexpr int kBatchLanes = 4;
/// Largest entry count of a batched element (the kernel keeps a batch's positions on the stack).
inline constexpr int kBatchMaxRows = 64;

/// Row r of a batch: vertex entry r of each lane's element (structure of arrays).
struct alignas(64) BatchRow {
  double rest_weighted[3][kBatchLanes];  ///< w_i R0_i per component, mm (0 in padding)
  double gradient[3][kBatchLanes];       ///< g_i per component, 1/mm (0 in padding)
  double weight[kBatchLanes];            ///< w_i (0 in padding)
  std::int32_t vertex[kBatchLanes];      ///< the entry's node (padding: the lane's first node)
  std::int32_t slot[kBatchLanes];        ///< its column of the node-major entry buffers
};
static_assert(sizeof(BatchRow) == 256);

/// Row r of a batch's bending-mode weights (hourglass element, element_modes.h), parallel to
/// its BatchRow: h_pr per mode p and lane (0 in padding).
struct alignas(64) ModeRow {
  double mode[kBendingModes][kBatchLanes];  ///< sqrt(N/mm)
};
static_assert(sizeof(ModeRow) == 128);

/// The per-element constants of one batch, per lane.
struct alignas(64) ElementBatch {
  double stiffness[kBatchLanes];         ///< k_e, N/mm
  double affine_stiffness[kBatchLanes];  ///< 2 mu V_e, N*mm
  double damping[kBatchLanes];           ///< c_e, N*s/mm
  double spread[9][kBatchLanes];         ///< C0, row-major, mm^2
  std::int32_t element[kBatchLanes];     ///< the lane's element (-1: an empty lane)
  std::int32_t count[kBatchLanes];       ///< its vertex entries (0: an empty lane)
  std::int32_t first_row{0};             ///< its rows in ElementBatches::rows
  std::int32_t rows{0};                  ///< the largest count of its lanes
};

/// The batched layout of a PhysicsModel (derived data, built by make_physics_model).
struct ElementBatches {
  std::vector<ElementBatch> batches;
  std::vector<BatchRow> rows;
  /// the bending-mode weights of every row (parallel to rows); empty for the paper's element
  std::vector<ModeRow> mode_rows;
  /// Batches of window w (elements [w kElementGrain, (w+1) kElementGrain)):
  /// [window_offsets[w], window_offsets[w+1]).
  std::vector<std::int32_t> window_offsets;
  /// Elements too large for a batch (more than kBatchMaxRows entries), left to the packed kernel.
  std::vector<std::int32_t> unbatched;
  [[nodiscard]] bool empty() const { return window_offsets.empty(); }
};

}  // namespace vx
