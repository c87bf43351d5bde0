#pragma once
/// @file dicom_series_parts.h
/// Private to the DICOM series reader (dicom_series.cpp): what its passes hand each other.
/// - dicom_header.cpp: the header pass, one file at a time (everything but the pixels);
/// - dicom_series.cpp: the files of the inputs, grouped into series, one chosen (and the entry
///   point, read_dicom_series);
/// - dicom_slice_layout.cpp: the chosen series' frames sorted along the slice normal, checked
///   (duplicates, gaps, spacing) and laid out on a grid (gantry tilt sheared back);
/// - dicom_pixels.cpp: the pixel pass, frame by frame straight into the float HU volume.
/// Geometry in LPS mm. Never included by public headers (it names DCMTK types).

#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dctypes.h>

#include <Eigen/Core>
#include <cstddef>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "io/read_options.h"
#include "io/volume.h"

namespace vx::dicom {

/// Values longer than this stay on disk during the header pass (pixel data, big private blobs).
inline constexpr Uint32 kHeaderReadLimit = 4096;
/// Progress is shown from this many files / frames on.
inline constexpr std::size_t kProgressFrom = 64;

/// One frame (a 2D image) of a file: a classic file has one, an enhanced one many.
struct FrameInfo {
  std::size_t file{0};  ///< index into the file list
  int frame{0};         ///< 0-based frame number in the file
  bool has_position{false}, has_orientation{false}, has_spacing{false};
  Eigen::Vector3d position{0, 0, 0};  ///< ImagePositionPatient: centre of the first pixel, LPS mm
  Eigen::Vector3d row{1, 0, 0};       ///< direction of increasing column index (along a row)
  Eigen::Vector3d col{0, 1, 0};       ///< direction of increasing row index (down a column)
  double row_spacing{1.0};            ///< PixelSpacing[0]: between rows, mm
  double col_spacing{1.0};            ///< PixelSpacing[1]: between columns, mm
  double thickness{0.0};              ///< SliceThickness or SpacingBetweenSlices, mm (fallback only)
  double slice_thickness{0.0};        ///< SliceThickness, mm (0: absent): a single slice's depth
  double slope{1.0}, intercept{0.0};  ///< rescale to HU
  bool has_rescale{false};
  long instance{0};             ///< InstanceNumber / frame number, for ordering without geometry
  double normal_position{0.0};  ///< position projected on the slice normal, mm
};

enum class FileKind { image, not_dicom, non_image, broken };

/// What the header pass learnt about one file.
struct FileInfo {
  std::filesystem::path path;
  bool explicit_input{false};  ///< named on the command line (not found in a folder)
  FileKind kind{FileKind::not_dicom};
  std::string problem;  ///< why it is broken / not DICOM
  std::string series_uid, sop_class, sop_instance, modality, description;
  std::string xfer_uid, xfer_name;
  bool xfer_decodable{true};
  int rows{0}, cols{0}, bits_allocated{0}, bits_stored{0}, high_bit{0}, pixel_rep{0}, samples{1};
  std::string photometric;
  bool has_padding{false}, has_padding_limit{false};
  long padding{0}, padding_limit{0};  ///< raw stored values (sign applied)
  bool localizer{false};
  bool is_ct{false};
  /// Modality LUT Sequence (0028,3000), when present: stored value v -> lut[clamp(v - lut_first)]
  std::vector<double> lut;
  long lut_first{0};
  std::vector<FrameInfo> frames;
};

/// A series found in the inputs.
struct SeriesInfo {
  std::string uid;
  std::vector<std::size_t> files;  ///< image files (localizers excluded)
  std::size_t frames{0};
  std::size_t localizers{0};
  std::string modality, description;
  bool is_ct{false};
  [[nodiscard]] std::string label() const;
};

/// Where the sorted frames sit: the grid and, per slice, the in-plane shift a gantry tilt causes.
struct SliceLayout {
  GridGeometry geometry;               ///< output grid (orthogonal)
  std::vector<Eigen::Vector2d> shift;  ///< per slice: input pixel (i',j') = output (i,j) + offset - shift
  Eigen::Vector2i offset{0, 0};
  bool tilted{false};
};

// the header pass (dicom_header.cpp)

/// `s` fit for a terminal: control characters (escape sequences from a hostile file) become '?'.
[[nodiscard]] std::string printable(std::string s);

/// Everything about a file except its pixel values; `file_index` goes into each frame's `file`.
[[nodiscard]] FileInfo read_header(const std::filesystem::path& path, bool explicit_input, std::size_t file_index);

/// The header pass: everything about each listed file (path, named itself) but its pixels.
[[nodiscard]] std::vector<FileInfo> read_headers(const std::vector<std::pair<std::filesystem::path, bool>>& listed);

// the slice layout (dicom_slice_layout.cpp)

/// Sorts `frames` along the slice normal (by InstanceNumber when a non-CT series has no
/// geometry, given options.any_modality), drops repeated copies of one image and checks the
/// pixel formats, orientations, pixel spacings, duplicates, gaps and tilt.
/// Throws vx::Error naming the frames at fault.
[[nodiscard]] SliceLayout lay_out_slices(std::vector<FileInfo>& files, std::vector<FrameInfo>& frames,
                                         const SeriesInfo& series, const ReadOptions& options);

// the pixel pass (dicom_pixels.cpp)

/// The volume of the slice layout, filled with air. Throws vx::Error, before allocating, when
/// it would take more than `max_bytes` (0: half the machine's physical memory).
[[nodiscard]] Volume allocate_volume(const SliceLayout& layout, const SeriesInfo& series, std::uint64_t max_bytes);

/// File by file (frames of a file in frame order), each frame of `frames` (slice k = index k)
/// straight into its slice of `volume`.
void read_pixels(const std::vector<FileInfo>& files, const std::vector<FrameInfo>& frames, const SliceLayout& layout,
                 Volume& volume);

}  // namespace vx::dicom
