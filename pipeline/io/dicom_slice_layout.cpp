// The slice layout of the DICOM series reader: the chosen series' frames sorted along the slice
// normal and checked (one pixel format, parallel slices, one pixel spacing, no two slices at one
// place, no gaps), then laid out on an orthogonal grid, a gantry tilt sheared back.

#include <fmt/format.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>

#include "base/error.h"
#include "io/dicom_series_parts.h"
#include "util/log.h"
#include "util/text.h"

namespace vx::dicom {
namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::string frame_name(const std::vector<FileInfo>& files, const FrameInfo& fr) {
  const FileInfo& f = files[fr.file];
  return f.frames.size() > 1 ? fmt::format("frame {} of {}", fr.frame + 1, quoted(f.path)) : quoted(f.path);
}

/// The slice axes every frame shares: row and column directions, the slice normal, pixel spacing.
struct SliceAxes {
  Eigen::Vector3d row, col, normal;
  double row_spacing{1.0}, col_spacing{1.0};  ///< mm
};

/// Every frame must share the image size and a pixel layout the reader decodes (greyscale,
/// 8, 16 or 32 bits); `first` is the frame the others are compared with.
void check_pixel_formats(const std::vector<FileInfo>& files, const std::vector<FrameInfo>& frames,
                         const SeriesInfo& series, const FrameInfo& first) {
  const FileInfo& ff = files[first.file];
  for (const FrameInfo& fr : frames) {
    const FileInfo& f = files[fr.file];
    if (f.rows != ff.rows || f.cols != ff.cols)
      throw Error(fmt::format("DICOM: series {} mixes image sizes: {} is {} x {} (columns x rows) but {} is {} x {}; "
                              "the slices of a volume must all have the same size (remove the odd files or choose "
                              "another series with --series)",
                              series.uid, frame_name(files, first), ff.cols, ff.rows, frame_name(files, fr), f.cols, f.rows));
    if (f.samples != 1)
      throw Error(fmt::format("DICOM: {} is a colour image (SamplesPerPixel {}, {}); only greyscale CT-like images "
                              "can become a volume", frame_name(files, fr), f.samples, f.photometric));
    if (f.photometric != "MONOCHROME1" && f.photometric != "MONOCHROME2" && !f.photometric.empty())
      throw Error(fmt::format("DICOM: {} has photometric interpretation {}; only MONOCHROME1/2 images can become a volume",
                              frame_name(files, fr), f.photometric));
    if (f.bits_allocated != 8 && f.bits_allocated != 16 && f.bits_allocated != 32)
      throw Error(fmt::format("DICOM: {} has {} bits allocated per pixel; only 8, 16 and 32 are supported",
                              frame_name(files, fr), f.bits_allocated));
    if (f.bits_stored < 1 || f.bits_stored > f.bits_allocated || f.high_bit >= f.bits_allocated)
      throw Error(fmt::format("DICOM: {} has inconsistent BitsStored {} / HighBit {} for BitsAllocated {}",
                              frame_name(files, fr), f.bits_stored, f.high_bit, f.bits_allocated));
  }
}

/// Frames without patient position and orientation: refused, unless a non-CT series is read
/// with options.any_modality; then ordered by InstanceNumber on an axis-aligned grid, spaced by
/// `first`'s thickness (else 1 mm).
void place_without_geometry(const std::vector<FileInfo>& files, std::vector<FrameInfo>& frames,
                            const SeriesInfo& series, const ReadOptions& options, const FrameInfo& first) {
  const bool have_geometry = std::all_of(frames.begin(), frames.end(), [](const FrameInfo& fr) {
    return fr.has_position && fr.has_orientation;
  });
  if (have_geometry) return;
  const auto missing = std::find_if(frames.begin(), frames.end(), [](const FrameInfo& fr) {
    return !fr.has_position || !fr.has_orientation;
  });
  if (!options.any_modality || series.is_ct)
    throw Error(fmt::format("DICOM: {} has no usable ImagePositionPatient / ImageOrientationPatient, so the slices "
                            "cannot be placed in patient space (the series is incomplete; re-export it)",
                            frame_name(files, *missing)));
  log::warn("DICOM: {} has no patient position/orientation; slices are ordered by InstanceNumber and placed on an "
            "axis-aligned grid",
            frame_name(files, *missing));
  std::sort(frames.begin(), frames.end(), [&](const FrameInfo& a, const FrameInfo& b) {
    return a.instance != b.instance ? a.instance < b.instance : files[a.file].path < files[b.file].path;
  });
  const double dz = first.thickness > 0 ? first.thickness : 1.0;
  for (std::size_t k = 0; k < frames.size(); ++k) {
    frames[k].position = Eigen::Vector3d(0, 0, dz * double(k));
    frames[k].row = Eigen::Vector3d::UnitX();
    frames[k].col = Eigen::Vector3d::UnitY();
  }
}

/// The axes of the first frame, which every frame must share (orientation and pixel spacing).
SliceAxes shared_axes(const std::vector<FileInfo>& files, const std::vector<FrameInfo>& frames,
                      const SeriesInfo& series) {
  const Eigen::Vector3d row = frames.front().row, col = frames.front().col;
  const double row_spacing = frames.front().row_spacing, col_spacing = frames.front().col_spacing;
  for (const FrameInfo& fr : frames) {
    if ((fr.row - row).norm() > 1e-4 || (fr.col - col).norm() > 1e-4)
      throw Error(fmt::format("DICOM: series {} mixes slice orientations ({} differs from {}); a volume needs parallel "
                              "slices (choose another series with --series, or split the series)",
                              series.uid, frame_name(files, fr), frame_name(files, frames.front())));
    if (std::abs(fr.row_spacing - row_spacing) > 1e-4 * row_spacing ||
        std::abs(fr.col_spacing - col_spacing) > 1e-4 * col_spacing)
      throw Error(fmt::format("DICOM: series {} mixes pixel spacings: {} has {} x {} mm but {} has {} x {} mm",
                              series.uid, frame_name(files, frames.front()), row_spacing, col_spacing,
                              frame_name(files, fr), fr.row_spacing, fr.col_spacing));
  }
  if (!frames.front().has_spacing)
    log::warn("DICOM: no PixelSpacing in {}; assuming 1 mm pixels", frame_name(files, frames.front()));
  if (frames.size() == 1)
    log::info("DICOM: series {} has a single slice ({}): a one-slice volume, which convert makes a 2D model",
              series.uid, frame_name(files, frames.front()));
  return SliceAxes{row, col, row.cross(col).normalized(), row_spacing, col_spacing};
}

/// Sorts the frames by position along the normal (not InstanceNumber); the same image twice is
/// dropped, two images at one place are refused.
void sort_along_normal(const std::vector<FileInfo>& files, std::vector<FrameInfo>& frames, const SeriesInfo& series,
                       const Eigen::Vector3d& normal) {
  for (FrameInfo& fr : frames) fr.normal_position = fr.position.dot(normal);
  std::stable_sort(frames.begin(), frames.end(), [](const FrameInfo& a, const FrameInfo& b) {
    return a.normal_position < b.normal_position;
  });

  // duplicates: the same image twice is dropped, two images at one place are refused
  constexpr double kSamePlaceMm = 1e-3;
  std::vector<FrameInfo> unique;
  std::size_t dropped = 0;
  for (const FrameInfo& fr : frames) {
    if (!unique.empty() && fr.normal_position - unique.back().normal_position < kSamePlaceMm) {
      const FileInfo& a = files[unique.back().file];
      const FileInfo& b = files[fr.file];
      if (!a.sop_instance.empty() && a.sop_instance == b.sop_instance && unique.back().frame == fr.frame) {
        ++dropped;
        continue;
      }
      throw Error(fmt::format("DICOM: series {} has two different slices at the same position ({:.3f} mm along the "
                              "slice normal): {} and {}. The series may hold several phases or echoes; remove the "
                              "extra files or choose one series with --series",
                              series.uid, fr.normal_position, frame_name(files, unique.back()), frame_name(files, fr)));
    }
    unique.push_back(fr);
  }
  if (dropped)
    log::info("DICOM: ignored {} duplicate cop{} of images already read", dropped, dropped == 1 ? "y" : "ies");
  frames = std::move(unique);
}

/// The slice spacing, mm: the median gap, every gap checked against it (a whole multiple is a
/// missing slice). One slice: its depth is the slice thickness (SliceThickness, else
/// SpacingBetweenSlices, else 1 mm), the thickness of the 2D model's plane-stress slab
/// (docs/model.md section 12).
double slice_spacing(const std::vector<FileInfo>& files, const std::vector<FrameInfo>& frames,
                     const SeriesInfo& series) {
  std::vector<double> gaps;
  for (std::size_t k = 1; k < frames.size(); ++k) gaps.push_back(frames[k].normal_position - frames[k - 1].normal_position);
  double dz = 0;
  if (frames.size() == 1) {
    const FrameInfo& only = frames.front();
    dz = only.slice_thickness > 0 ? only.slice_thickness : only.thickness;
    if (!(dz > 0)) {
      dz = 1.0;
      log::warn("DICOM: {} gives no SliceThickness (0018,0050) or SpacingBetweenSlices (0018,0088); assuming a 1 mm "
                "thick slice (the 2D model's forces scale with it)",
                frame_name(files, only));
    }
  } else {
    dz = median(gaps);
  }
  const double tolerance = std::max(0.01, 0.05 * dz);
  for (std::size_t k = 1; k < frames.size(); ++k) {
    const double gap = gaps[k - 1];
    if (std::abs(gap - dz) <= tolerance) continue;
    const double ratio = gap / dz;
    const long whole = std::lround(ratio);
    if (whole >= 2 && std::abs(gap - double(whole) * dz) <= tolerance)
      throw Error(fmt::format("DICOM: series {} misses {} slice{} between {} and {} (gap {:.3f} mm, slice spacing "
                              "{:.3f} mm); the series is incomplete, re-export it",
                              series.uid, whole - 1, whole - 1 == 1 ? "" : "s", frame_name(files, frames[k - 1]),
                              frame_name(files, frames[k]), gap, dz));
    throw Error(fmt::format("DICOM: series {} has non-uniform slice spacing: {:.3f} mm between {} and {}, but "
                            "{:.3f} mm typically; a volume needs evenly spaced slices (resample the series first)",
                            series.uid, gap, frame_name(files, frames[k - 1]), frame_name(files, frames[k]), dz));
  }
  return dz;
}

/// Gantry tilt: slice origins drift within the slice plane; each slice is sheared back. Sets the
/// layout's shifts, offset and tilt; returns the grid's size (`cols` x `rows` x slices, grown to
/// cover every sheared slice).
Eigen::Vector3i shear_for_tilt(const std::vector<FrameInfo>& frames, const SliceAxes& axes, int cols, int rows,
                               const SeriesInfo& series, SliceLayout& layout) {
  const Eigen::Vector3d &row = axes.row, &col = axes.col, &normal = axes.normal;
  const double row_spacing = axes.row_spacing, col_spacing = axes.col_spacing;
  layout.shift.resize(frames.size(), Eigen::Vector2d::Zero());
  double max_drift = 0.0;
  Eigen::Vector2d lo(0, 0), hi(0, 0);
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const Eigen::Vector3d d = frames[k].position - frames.front().position;
    const Eigen::Vector3d in_plane = d - d.dot(normal) * normal;
    max_drift = std::max(max_drift, in_plane.norm());
    layout.shift[k] = Eigen::Vector2d(in_plane.dot(row) / col_spacing, in_plane.dot(col) / row_spacing);
    lo = lo.cwiseMin(layout.shift[k]);
    hi = hi.cwiseMax(layout.shift[k]);
  }
  // drifts under 5% of a pixel are rounding in the positions, not a tilt worth resampling
  layout.tilted = max_drift > 0.05 * std::min(row_spacing, col_spacing);
  Eigen::Vector3i dims(cols, rows, int(frames.size()));
  if (layout.tilted) {
    // the output grid covers every sheared slice
    layout.offset = Eigen::Vector2i(int(std::floor(lo.x() + 1e-6)), int(std::floor(lo.y() + 1e-6)));
    const Eigen::Vector2i top(int(std::ceil(hi.x() - 1e-6)), int(std::ceil(hi.y() - 1e-6)));
    dims.x() = cols + top.x() - layout.offset.x();
    dims.y() = rows + top.y() - layout.offset.y();
    const double span = frames.back().normal_position - frames.front().normal_position;
    const double angle = std::atan2(
        (frames.back().position - frames.front().position - span * normal).norm(), span) * 180.0 / std::numbers::pi;
    log::warn("DICOM: series {} is tilted by {:.2f} degrees (gantry tilt); resampling it onto an orthogonal grid of "
              "{} x {} x {} voxels (samples outside the scan become air)",
              series.uid, angle, dims.x(), dims.y(), dims.z());
  } else {
    for (auto& s : layout.shift) s.setZero();
  }
  return dims;
}

}  // namespace

SliceLayout lay_out_slices(std::vector<FileInfo>& files, std::vector<FrameInfo>& frames, const SeriesInfo& series,
                           const ReadOptions& options) {
  const FrameInfo first = frames.front();  // a copy: frames get sorted below
  check_pixel_formats(files, frames, series, first);
  place_without_geometry(files, frames, series, options, first);
  const SliceAxes axes = shared_axes(files, frames, series);
  sort_along_normal(files, frames, series, axes.normal);
  const double dz = slice_spacing(files, frames, series);
  SliceLayout layout;
  const FileInfo& ff = files[first.file];
  const Eigen::Vector3i dims = shear_for_tilt(frames, axes, ff.cols, ff.rows, series, layout);
  GridGeometry& g = layout.geometry;
  g.dims = dims;
  g.spacing_mm = Eigen::Vector3d(axes.col_spacing, axes.row_spacing, dz);
  g.direction.col(0) = axes.row;
  g.direction.col(1) = axes.col;
  g.direction.col(2) = axes.normal;
  g.origin_mm = frames.front().position + axes.row * (layout.offset.x() * axes.col_spacing) +
                axes.col * (layout.offset.y() * axes.row_spacing);
  return layout;
}

}  // namespace vx::dicom
