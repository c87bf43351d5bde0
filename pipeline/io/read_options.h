#pragma once
/// @file read_options.h
/// Options for reading volumes (volume_io.h); the DICOM-specific ones are used by the DICOM
/// series reader (dicom_series.h) only.

#include <string>

namespace vx {

/// Options for reading volumes (DICOM-specific ones are used for DICOM input only).
struct ReadOptions {
  std::string series_uid;      ///< DICOM: series to read; empty = the largest CT series
  bool any_modality{false};    ///< DICOM: accept non-CT images (MR, secondary capture) with a warning
};

}  // namespace vx
