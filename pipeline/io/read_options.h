#pragma once
/// @file read_options.h
/// Options for reading volumes (volume_io.h); the DICOM-specific ones are used by the DICOM
/// series reader (dicom_series.h) only.

#include <cstdint>
#include <string>

namespace vx {

/// Options for reading volumes (DICOM-specific ones are used for DICOM input only).
struct ReadOptions {
  std::string series_uid;    ///< DICOM: series to read; empty = the largest CT series
  bool any_modality{false};  ///< DICOM: accept non-CT images (MR, secondary capture) with a warning
  /// DICOM: the largest volume to allocate, bytes (0: half the machine's physical memory, as
  /// reading and converting need more than the volume). A series whose image size, frame count
  /// or slice positions ask for more is refused before anything is allocated (compressed pixel
  /// data can declare any image size in a few bytes).
  std::uint64_t max_volume_bytes{0};
};

}  // namespace vx
