#pragma once
/// @file dicom_series.h
/// DICOM CT series in and out (DCMTK). Geometry in LPS mm; values in HU (float).

#include <filesystem>
#include <string>
#include <vector>

#include "io/read_options.h"
#include "io/volume.h"

namespace vx {

/// Reads one series from a folder (searched recursively) or a list of files.
/// Picks options.series_uid, or the largest CT series (listing the others on stderr).
/// Throws vx::Error with a clear message for every kind of bad input.
[[nodiscard]] Volume read_dicom_series(const std::vector<std::filesystem::path>& inputs,
                                       const ReadOptions& options = {});

/// Settings for writing a synthetic CT series.
struct DicomWriteSettings {
  std::string patient_name{"VOXELASTIC^PHANTOM"};
  std::string series_description{"voxelastic phantom"};
  std::string transfer_syntax{"explicit-little"};  ///< explicit-little, implicit-little, rle, jpeg-lossless, jpeg-ls-lossless, jpeg2000-lossless, jpeg2000 (lossy 8:1)
};

/// Writes `volume` as a CT Image Storage series into `folder` (one file per slice), all or
/// nothing: written into a temporary folder, then renamed.
void write_dicom_series(const Volume& volume, const std::filesystem::path& folder,
                        const DicomWriteSettings& settings = {});

}  // namespace vx
