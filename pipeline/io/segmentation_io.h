#pragma once
/// @file segmentation_io.h
/// 3D Slicer segmentations (.seg.nrrd): a NRRD labelmap whose header names its segments in
/// `Segment<k>_` key/value pairs (`Segment0_Name:=liver`, `Segment0_LabelValue:=1`,
/// `Segment0_Layer:=0`, ...). Two forms are read: a 3D labelmap (one layer, each segment a
/// label value), and the layered 4D form whose first axis is the layer ("kinds: list domain
/// domain domain"; segments may overlap, each in its layer). Files of Slicer 4.10 and older
/// lack LabelValue and Layer: a 3D file's segment k is label k+1 of layer 0, a 4D file's is
/// label 1 of layer k, as Slicer reads them. Geometry in LPS mm, voxels x fastest.

#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "io/volume.h"
#include "model/voxel_grid.h"

namespace vx {

/// One segment: where its voxels are (a label value in a layer) and what it is called.
struct Segment {
  std::string id;                                       ///< Segment<k>_ID (Slicer's internal name)
  std::string name;                                     ///< Segment<k>_Name (what the user sees)
  int label_value{1};                                   ///< Segment<k>_LabelValue: its voxels' value in its layer
  int layer{0};                                         ///< Segment<k>_Layer: 0 .. layers-1
  Eigen::Vector3d color{0.501961, 0.682353, 0.501961};  ///< Segment<k>_Color: red, green, blue in [0, 1]
};

/// A segmentation as read: the voxels of every layer and the segments they hold.
struct Segmentation {
  GridGeometry geometry;                   ///< LPS mm
  std::vector<std::vector<float>> layers;  ///< per layer: geometry.voxel_count() label values, x fastest
  std::vector<Segment> segments;           ///< in the file's order (Segment0 first)

  /// The segments' names, in order.
  [[nodiscard]] std::vector<std::string> names() const;
  /// The voxels of `segment` as a volume of the same geometry: 1 where its layer holds its
  /// label value, 0 elsewhere.
  [[nodiscard]] Volume mask(const Segment& segment) const;
  /// Voxels of `segment`.
  [[nodiscard]] std::int64_t count(const Segment& segment) const;
};

/// True when the file name ends in ".seg.nrrd" (any case): 3D Slicer's segmentation file.
[[nodiscard]] bool is_segmentation_path(const std::filesystem::path& path);

/// Reads a .seg.nrrd (or any NRRD with Segment<k>_ fields). Throws vx::Error with what is
/// wrong: not a NRRD, no Segment0_ fields (a plain labelmap: use its label numbers), a segment
/// whose layer or label value is not in the file, a damaged header or data.
[[nodiscard]] Segmentation read_segmentation(const std::filesystem::path& path);

/// Writes one segment as a 3D Slicer segmentation (.seg.nrrd: unsigned char, LPS, gzip): the
/// voxels where `mask` is non-zero get `segment.label_value` (1..255), the others 0; its
/// Segment0_ fields (ID, Name, Color, LabelValue, Layer 0, Extent: the voxels' bounding box in
/// index space, "0 -1 0 -1 0 -1" when empty) and the Segmentation_ fields Slicer reads.
/// Atomic (temporary file, then rename). Throws vx::Error for a mask of the wrong size, a
/// label value outside 1..255 or a path that cannot be written.
void write_segmentation(const GridGeometry& geometry, const std::vector<std::uint8_t>& mask, const Segment& segment,
                        const std::filesystem::path& path);

}  // namespace vx
