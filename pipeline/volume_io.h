#pragma once
/// @file volume_io.h
/// Reading and writing volumes. Formats are picked from the path: a folder or a .dcm file
/// is a DICOM series (dicom_series.h); `.vti`, `.mha`/`.mhd`, `.nii`/`.nii.gz`, `.nrrd`/`.nhdr`
/// are read through VTK. Geometry is always returned in LPS mm (NIfTI's RAS is converted).

#include <filesystem>
#include <string>

#include "volume.h"

namespace vx {

/// Options for reading volumes (DICOM-specific ones are used for DICOM input only).
struct ReadOptions {
  std::string series_uid;      ///< DICOM: series to read; empty = the largest CT series
  bool any_modality{false};    ///< DICOM: accept non-CT images (MR, secondary capture) with a warning
};

/// Reads a volume; throws vx::Error with a clear message (what, where, how to fix) on failure.
[[nodiscard]] Volume read_volume(const std::filesystem::path& path, const ReadOptions& options = {});

/// Writes a volume; the extension picks the format (`.vti`, `.mha`, `.nii.gz`/`.nii`; a path
/// ending in '/' or an existing folder writes a DICOM series). Atomic: no partial output.
void write_volume(const Volume& volume, const std::filesystem::path& path);

/// The format name a path maps to ("vti", "mha", "nifti", "nrrd", "dicom"), or "" when unknown.
[[nodiscard]] std::string volume_format(const std::filesystem::path& path);

}  // namespace vx
