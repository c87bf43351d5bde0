// Reading and writing volumes in the formats medical imaging tools exchange: the format by the
// path's extension, then its reader or writer (volume_formats.h: one file per format; DICOM
// series: dicom_series.cpp), and the checks every reader's result and every written volume get.
//
// Every reader returns geometry in LPS mm with the voxel order of the file (x fastest);
// every writer is atomic.

#include "io/volume_io.h"

#include <fmt/format.h>

#include <Eigen/Dense>
#include <cmath>
#include <cstdint>

#include "base/error.h"
#include "io/dicom_common.h"
#include "io/dicom_series.h"
#include "io/volume_formats.h"
#include "util/atomic_file.h"
#include "util/text.h"

namespace vx {
namespace {
namespace fs = std::filesystem;

constexpr const char* kSupported =
    ".vti, .mha, .mhd, .nii, .nii.gz, .nrrd, .nhdr, or a DICOM series (a folder, a path "
    "ending in '/', or one .dcm file of the series)";
constexpr const char* kWritable = ".vti, .mha, .nii.gz, .nii, .nrrd, or a folder path ending in '/' (DICOM)";

void check_volume_for_writing(const Volume& v, const fs::path& path) {
  const GridGeometry& g = v.geometry;
  if ((g.dims.array() <= 0).any())
    throw Error(fmt::format("cannot write {}: the volume is empty ({}x{}x{} voxels)", quoted(path), g.dims.x(),
                            g.dims.y(), g.dims.z()));
  if (std::int64_t(v.hu.size()) != g.voxel_count())
    throw Error(fmt::format("cannot write {}: the volume holds {} values for {}x{}x{} = {} voxels", quoted(path),
                            v.hu.size(), g.dims.x(), g.dims.y(), g.dims.z(), g.voxel_count()));
  if (!g.spacing_mm.allFinite() || (g.spacing_mm.array() <= 0).any())
    throw Error(fmt::format("cannot write {}: voxel spacing ({}, {}, {}) mm must be positive and finite",
                            quoted(path), g.spacing_mm.x(), g.spacing_mm.y(), g.spacing_mm.z()));
  if (!g.origin_mm.allFinite() || !g.direction.allFinite())
    throw Error("cannot write " + quoted(path) + ": the origin or direction is not finite");
  if (std::abs(g.direction.determinant()) < 1e-9)
    throw Error("cannot write " + quoted(path) + ": the direction matrix is singular");
}

/// "dir/" -> "dir"
fs::path without_trailing_slash(const fs::path& path) {
  std::string s = path.string();
  while (s.size() > 1 && s.back() == '/') s.pop_back();
  return s;
}


}  // namespace

std::string volume_format(const fs::path& path) {
  const std::string s = path.string();
  if (s.empty()) return "";
  if (s.back() == '/') return "dicom";
  std::error_code ec;
  if (fs::is_directory(path, ec)) return "dicom";
  const std::string name = lower(path.filename().string());
  if (name.ends_with(".vti")) return "vti";
  if (name.ends_with(".mha") || name.ends_with(".mhd")) return "mha";
  if (name.ends_with(".nii") || name.ends_with(".nii.gz")) return "nifti";
  if (name.ends_with(".nrrd") || name.ends_with(".nhdr")) return "nrrd";
  if (name.ends_with(".dcm")) return "dicom";
  return "";
}

Volume read_volume(const fs::path& path, const ReadOptions& options) {
  const std::string format = volume_format(path);
  std::error_code ec;
  if (format == "dicom") {
    if (!fs::exists(without_trailing_slash(path), ec))
      throw Error("cannot read " + quoted(path) + ": no such folder or file (check the path)");
    return read_dicom_series({path}, options);
  }
  if (!fs::exists(path, ec))
    throw Error("cannot read " + quoted(path) + ": no such file (check the path and the current folder)");
  if (!fs::is_regular_file(path, ec))
    throw Error("cannot read " + quoted(path) + ": not a regular file");
  if (format.empty()) {
    // DICOM files often have no extension: recognise them by their magic
    if (dicom::has_dicm_magic(path)) return read_dicom_series({path}, options);
    throw Error(fmt::format("cannot read {}: unknown volume format '{}' (supported: {})", quoted(path),
                            path.extension().string(), kSupported));
  }
  if (volume_formats::file_size_or_zero(path) == 0) throw Error("cannot read " + quoted(path) + ": the file is empty");
  Volume v;
  if (format == "vti") v = volume_formats::read_vti(path);
  else if (format == "mha") v = volume_formats::read_mha(path);
  else if (format == "nifti") v = volume_formats::read_nifti(path);
  else v = volume_formats::read_nrrd(path);
  volume_formats::finish_volume(v, path);
  return v;
}

void write_volume(const Volume& volume, const fs::path& path) {
  const std::string format = volume_format(path);
  if (format == "dicom") {
    if (lower(path.filename().string()).ends_with(".dcm"))
      throw Error("cannot write " + quoted(path) + ": a DICOM series is a folder of files: give a folder path "
                                                   "ending in '/' (e.g. out/series/)");
    check_volume_for_writing(volume, path);
    write_dicom_series(volume, without_trailing_slash(path));
    return;
  }
  if (format.empty())
    throw Error(fmt::format("cannot write {}: unknown volume format '{}' (writable: {})", quoted(path),
                            path.extension().string(), kWritable));
  const std::string name = lower(path.filename().string());
  if (name.ends_with(".mhd"))
    throw Error("cannot write " + quoted(path) + ": .mhd needs a separate data file; write a single-file .mha "
                                                 "instead");
  if (name.ends_with(".nhdr"))
    throw Error("cannot write " + quoted(path) + ": .nhdr needs a separate data file; write a single-file .nrrd "
                                                 "instead");
  check_volume_for_writing(volume, path);
  write_atomically(path, [&](const fs::path& tmp) {
    if (format == "vti") volume_formats::write_vti(volume, tmp);
    else if (format == "mha") volume_formats::write_mha(volume, tmp);
    else if (format == "nifti") volume_formats::write_nifti(volume, tmp);
    else volume_formats::write_nrrd(volume, tmp);
  });
}

}  // namespace vx
