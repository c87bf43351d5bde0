#pragma once
/// @file volume_io.h
/// Reading and writing volumes. Formats are picked from the path: a folder or a .dcm file
/// is a DICOM series (dicom_series.h); `.vti`, `.mha`/`.mhd`, `.nii`/`.nii.gz`, `.nrrd`/`.nhdr`
/// are files (a file with another extension that starts like DICOM is read as DICOM too).
/// Geometry is always returned in LPS mm (NIfTI's RAS and NRRD's RAS/LAS spaces are
/// converted), voxels in the file's order, values as float HU (NIfTI scl_slope/scl_inter
/// applied). Not thread-safe: VTK's message output is redirected while a file is read.

#include <filesystem>
#include <string>

#include "io/read_options.h"
#include "io/volume.h"

namespace vx {

/// Reads a volume; throws vx::Error with a clear message (what, where, how to fix) on failure.
[[nodiscard]] Volume read_volume(const std::filesystem::path& path, const ReadOptions& options = {});

/// Writes a volume; the extension picks the format (`.vti`, `.mha`, `.nii.gz`/`.nii`, `.nrrd`;
/// a path ending in '/' or an existing folder writes a DICOM series). Values are stored as
/// int16 when all are whole numbers in its range, else float32; `.vti`, `.mha` and `.nrrd` are
/// zlib/gzip compressed. Orientation is kept by every format (NIfTI: qform and sform, in RAS).
/// Atomic: no partial output. Throws vx::Error for an unknown extension, `.mhd`/`.nhdr`
/// (two-file formats: use `.mha`/`.nrrd`), an empty volume or a bad geometry.
void write_volume(const Volume& volume, const std::filesystem::path& path);

/// The format name a path maps to ("vti", "mha", "nifti", "nrrd", "dicom"), or "" when unknown.
[[nodiscard]] std::string volume_format(const std::filesystem::path& path);

}  // namespace vx
