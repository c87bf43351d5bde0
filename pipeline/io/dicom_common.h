#pragma once
/// @file dicom_common.h
/// Private to the pipeline: DCMTK set-up, value formatting and the DICOM file test shared by
/// the DICOM series reader (dicom_series.cpp), its writer (dicom_writer.cpp) and the volume
/// reader's dispatch (volume_io.cpp). Never included by public headers.

#include <filesystem>
#include <string>

namespace vx::dicom {

/// Checks that the DICOM data dictionary is loaded, quiets DCMTK's per-file log output and
/// registers the RLE, JPEG (incl. lossless) and JPEG-LS decoders and encoders, once.
/// Throws vx::Error when the dictionary is missing (every load would fail otherwise).
void init_dcmtk();

/// A decimal string (DICOM VR DS, at most 16 characters) with as many significant digits as fit.
[[nodiscard]] std::string format_ds(double value);

/// True when `path` starts like a DICOM Part 10 file: a 128-byte preamble, then "DICM". A
/// file shorter than 132 bytes is not one. Throws vx::Error when the file cannot be opened for
/// reading ("cannot open 'F' for reading (check its permissions)"), so an unreadable file is
/// reported as such rather than as a file of another format.
[[nodiscard]] bool has_dicm_magic(const std::filesystem::path& path);

/// Hounsfield value given to padding pixels and to samples outside the acquired data.
inline constexpr float kAirHu = -1000.0f;

}  // namespace vx::dicom
