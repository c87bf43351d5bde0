#pragma once
/// @file element_batches.h
/// The element pass vectorised across elements (ElementKernel::batched, elements.h): the
/// elements are grouped into batches of kBatchLanes, one element per SIMD lane, and each
/// batch's vertex entries are stored as rows of kBatchLanes entries (row r holds entry r of
/// every lane's element), so that every step of the element kernel (the sums of A and F, the
/// rigid velocity fit, the rotation check, the forces) runs on kBatchLanes elements at once.
///
/// Batches never leave a window of kElementGrain consecutive elements (the parallel chunk of
/// the other kernels, spatially compact), and inside a window the elements are sorted by their
/// number of vertex entries before they are grouped, so that the lanes of a batch have nearly
/// the same count: the padding rows (weight 0, zero constants) add 0.4 % to the 128^3 sphere's
/// 270k entries. A lane's rows beyond its element's count and the lanes of a short last batch
/// repeat valid data and are never written back.
///
/// Each lane's sums run over its entries in entry order, as in the scalar kernels; the result
/// equals theirs up to rounding (the compiled clone may contract multiply-adds). Elements with
/// more than kBatchMaxRows entries are left to the packed kernel (none in the phantoms: at most
/// 29 entries).
///
/// The batches' data (ElementBatches, held by the PhysicsModel) is in element_batch_layout.h;
/// this header builds it and runs the kernel on it.

#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

#include "physics/element_batch_layout.h"

namespace vx {

struct PhysicsModel;
struct RotationFitSettings;
struct ElementPassStats;

/// Builds the batches of `physics` (its entry constants, element constants and slots must be
/// set). `window` is the element window (kElementGrain); elements with more than `max_rows`
/// entries (at most kBatchMaxRows) are left unbatched.
void build_element_batches(const PhysicsModel& physics, std::int64_t window, ElementBatches& out,
                           int max_rows = kBatchMaxRows);

/// The batched kernel over batches [b0, b1): writes the forces of every batched element of
/// those batches into `ef` (3 x vertex entries, node-major slots), with damping when
/// `damping` (then `vs` must be set). No energy, no volume term (the caller picks the packed
/// kernel for those). `level` picks the compiled copy; one this CPU cannot run falls back to
/// best_simd_level().
void element_batches_range(const PhysicsModel& physics, const double* xs, const double* vs,
                           Eigen::Quaterniond* rotations, double* ef, std::int64_t b0, std::int64_t b1,
                           const RotationFitSettings& fit, bool damping, ElementPassStats& stats,
                           SimdLevel level = SimdLevel::automatic);

}  // namespace vx
