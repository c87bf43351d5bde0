#pragma once
/// @file dicom_common.h
/// Private to the pipeline: DCMTK set-up and value formatting shared by the DICOM series
/// reader (dicom_series.cpp) and writer (dicom_writer.cpp). Never included by public headers.

#include <string>

namespace vx::dicom {

/// Checks that the DICOM data dictionary is loaded, quiets DCMTK's per-file log output and
/// registers the RLE, JPEG (incl. lossless) and JPEG-LS decoders and encoders, once.
/// Throws vx::Error when the dictionary is missing (every load would fail otherwise).
void init_dcmtk();

/// A decimal string (DICOM VR DS, at most 16 characters) with as many significant digits as fit.
[[nodiscard]] std::string format_ds(double value);

/// Hounsfield value given to padding pixels and to samples outside the acquired data.
inline constexpr float kAirHu = -1000.0f;

}  // namespace vx::dicom
