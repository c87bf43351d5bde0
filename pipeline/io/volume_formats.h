#pragma once
/// @file volume_formats.h
/// Private to pipeline/io: the reader and writer of each volume file format, one file each,
/// which volume_io.cpp picks by extension, and what they share.
///
/// - vti_io.cpp: .vti through vtkXMLImageData{Reader,Writer} (VTK 9.1 keeps the direction).
/// - metaimage_io.cpp: .mha/.mhd; the header is parsed here (vtkMetaImageReader drops
///   TransformMatrix), voxels in one file (raw or zlib) are read here with every size checked
///   (metaio turns damaged compressed data into zeros without an error), data split over several
///   files goes through vtkMetaImageReader; written here (vtkMetaImageWriter drops the direction).
/// - nifti_io.cpp: .nii/.nii.gz through vtkNIFTIImage{Reader,Writer}; RAS <-> LPS and the
///   reader's slice reversal (qfac = -1) are undone so voxel order matches the file.
/// - nrrd_io.cpp: .nrrd/.nhdr, read and written here (vtkNrrdReader 9.1 takes a first axis of 9
///   or fewer samples for vector components, ignores orientation and reads only the first
///   slice of gzip data).
/// - raw_io.cpp: raw voxel bytes of any scalar type to float HU (NRRD, MetaImage);
///   compression.h: zlib.
/// - volume_formats.cpp: the helpers below.
///
/// Readers return geometry in LPS mm and the voxels in the file's order (x fastest);
/// read_volume() checks what they produced. Writers write the temporary file `tmp` that
/// write_volume() renames onto the target; the volume was checked before.

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <initializer_list>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <vtkDataArray.h>
#include <vtkSmartPointer.h>

#include <functional>

#include "io/volume.h"
#include "util/vtk_messages.h"

class vtkAlgorithm;

namespace vx::volume_formats {

// ---------------------------------------------------------------------------------------
// the formats

[[nodiscard]] Volume read_vti(const std::filesystem::path& path);
void write_vti(const Volume& volume, const std::filesystem::path& tmp);
[[nodiscard]] Volume read_mha(const std::filesystem::path& path);  ///< .mha and .mhd
void write_mha(const Volume& volume, const std::filesystem::path& tmp);
[[nodiscard]] Volume read_nifti(const std::filesystem::path& path);  ///< .nii and .nii.gz
void write_nifti(const Volume& volume, const std::filesystem::path& tmp);
/// The NIfTI orientation voxelastic follows, as 3D Slicer and ITK do: the qform, unless the
/// sform is scanner-anatomical (sform_code 1) and has no shear; the one present when only one
/// is (code > 0); the voxel sizes alone when neither is. `qform`, `sform`: the affine (A: one
/// voxel step per index axis, t: voxel 0) each gives, RAS mm. `warning` is set when both are
/// present and put the grid's corners more than 0.01 mm (or 1e-3 voxel) apart.
struct NiftiAffine {
  Eigen::Matrix3d A{Eigen::Matrix3d::Identity()};
  Eigen::Vector3d t{Eigen::Vector3d::Zero()};
  const char* source{"pixdim"};  ///< "qform", "sform" or "pixdim"
  std::string warning;
};
[[nodiscard]] NiftiAffine choose_nifti_affine(int qform_code, const std::pair<Eigen::Matrix3d, Eigen::Vector3d>& qform,
                                              int sform_code, const std::pair<Eigen::Matrix3d, Eigen::Vector3d>& sform,
                                              const Eigen::Vector3i& dims);
[[nodiscard]] Volume read_nrrd(const std::filesystem::path& path);  ///< .nrrd and .nhdr
void write_nrrd(const Volume& volume, const std::filesystem::path& tmp);
/// A NRRD file whose first axis may be a list of layers (3D Slicer's layered segmentation,
/// "kinds: list domain domain domain"), with its `key:=value` pairs.
struct NrrdLayers {
  GridGeometry geometry;                   ///< the spatial axes, LPS mm
  std::vector<std::vector<float>> layers;  ///< per layer: voxel_count() values, x fastest (one layer for a 3D file)
  std::map<std::string, std::string>
      key_values;  ///< 'key:=value' pairs of the header, keys as written, values unescaped
};
inline constexpr long long kMaxNrrdLayers = 1000;  ///< more values per voxel are not a segmentation's layers
[[nodiscard]] NrrdLayers read_nrrd_layers(const std::filesystem::path& path);
/// Writes a 3D unsigned-char labelmap (LPS, gzip) with `key_values` as 'key:=value' lines.
void write_nrrd_labels(const GridGeometry& geometry, const std::vector<std::uint8_t>& labels,
                       const std::vector<std::pair<std::string, std::string>>& key_values,
                       const std::filesystem::path& tmp);

// ---------------------------------------------------------------------------------------
// raw voxel data (raw_io.cpp)

/// Scalar types of raw voxel data (NRRD, MetaImage).
enum class ScalarType { i8, u8, i16, u16, i32, u32, i64, u64, f32, f64 };
/// Bytes per value of `t`.
[[nodiscard]] int scalar_bytes(ScalarType t);
/// `n` values of type `t` at `bytes` (byte-swapped when `swap`) as float.
[[nodiscard]] std::vector<float> raw_to_float(const char* bytes, std::size_t n, ScalarType t, bool swap);

// ---------------------------------------------------------------------------------------
// header text (volume_formats.cpp)

/// The `field: value` (NRRD) or `Key = Value` (MetaImage) lines of a header.
struct HeaderFields {
  std::map<std::string, std::string> values;  ///< field -> value
  /// The value of the first of `keys` present; nullopt when none is.
  [[nodiscard]] std::optional<std::string> get(std::initializer_list<const char*> keys) const;
};

/// The white-space separated words of `s`.
[[nodiscard]] std::vector<std::string> split_ws(const std::string& s);
/// Parses a whole string as a finite-or-not double; nullopt when it is not a number.
[[nodiscard]] std::optional<double> to_double(const std::string& text);
/// Whitespace-separated numbers; nullopt unless all of them parse.
[[nodiscard]] std::optional<std::vector<double>> to_doubles(const std::string& s);
/// The numbers as a header writes them, separated by `sep` ("-0" written as "0").
[[nodiscard]] std::string format_numbers(std::initializer_list<double> values, const char* sep = " ");

// ---------------------------------------------------------------------------------------
// files (volume_formats.cpp)

/// The size of a file in bytes, 0 when it cannot be read.
[[nodiscard]] std::uintmax_t file_size_or_zero(const std::filesystem::path& path);
/// Voxel count of `dims`, refusing sizes no machine here holds (a damaged header, usually).
[[nodiscard]] std::size_t checked_voxel_count(const Eigen::Vector3i& dims, const std::filesystem::path& path);
/// The first `max_bytes` of a file (fewer when it is shorter).
[[nodiscard]] std::string read_file_prefix(const std::filesystem::path& path, std::size_t max_bytes);
/// `count` bytes from byte `offset`; throws vx::Error when the file is shorter.
[[nodiscard]] std::vector<char> read_file_bytes(const std::filesystem::path& path, std::uintmax_t offset,
                                                std::uintmax_t count);
/// Writes a text header and then the (compressed) voxels to `tmp`; throws vx::Error on failure.
void write_header_and_data(const std::filesystem::path& tmp, const std::string& header,
                           const std::vector<unsigned char>& data);

// ---------------------------------------------------------------------------------------
// voxels and geometry (volume_formats.cpp)

/// RAS (NIfTI, NRRD 'right-anterior-superior') to LPS: flip x and y.
inline const Eigen::Matrix3d kRasToLps = Eigen::Vector3d(-1, -1, 1).asDiagonal();

/// True when every value is an integer that int16 holds (then files store int16).
[[nodiscard]] bool fits_int16(const std::vector<float>& hu);
/// The voxels as int16 (`as_short`: every value integral and in range) or float32, deflated
/// (zlib stream, or gzip when `gzip`).
[[nodiscard]] std::vector<unsigned char> deflate_voxels(const Volume& v, bool as_short, bool gzip);
/// Voxels per axis of a VTK extent {i0, i1, j0, j1, k0, k1}.
[[nodiscard]] inline Eigen::Vector3i extent_dims(const int extent[6]) {
  return {extent[1] - extent[0] + 1, extent[3] - extent[2] + 1, extent[5] - extent[4] + 1};
}
/// A geometry from a 3x3 affine A (columns: one voxel step along each index axis, LPS mm)
/// and the position of voxel 0.
[[nodiscard]] GridGeometry geometry_from_affine(const Eigen::Vector3i& dims, const Eigen::Matrix3d& A,
                                                const Eigen::Vector3d& t);
/// The first `n` values of a one-component VTK array as float HU: value * slope + intercept.
[[nodiscard]] std::vector<float> vtk_array_to_float(vtkDataArray* array, std::size_t n, double slope,
                                                    double intercept);
/// The values as the VTK array "HU" a writer stores: int16 when fits_int16(), else float32.
[[nodiscard]] vtkSmartPointer<vtkDataArray> hu_array(const std::vector<float>& hu);
/// Reverses the slice (k) order of `hu` in place.
void reverse_slices(std::vector<float>& hu, const Eigen::Vector3i& dims);

/// The checks every reader's result gets (read_volume, read_segmentation): voxels for the whole
/// grid, positive finite spacing, finite origin, no NaN; a direction that is orthonormal up to
/// the file's float precision made exactly so, a sheared one refused. Throws vx::Error naming `path`.
void finish_volume(Volume& v, const std::filesystem::path& path);

/// VTK's messages while one file is read or written: collected by vtk_messages.h (nothing
/// reaches the console), reported as the file's errors and warnings.
class VtkMessages {
 public:
  [[nodiscard]] bool failed() const { return !capture_.errors().empty(); }
  /// The first few error messages (first lines), joined; the pipeline's generic "Algorithm X
  /// returned failure" only when nothing more specific was said.
  [[nodiscard]] std::string errors() const;
  /// Why a VTK reader or writer failed: errors(), or when VTK said nothing, the text of its
  /// error code (vtkErrorCode).
  [[nodiscard]] std::string reason(unsigned long error_code) const;
  /// Prints the warnings (deduplicated) to stderr, naming the file.
  void print_warnings(const std::filesystem::path& path) const;

 private:
  VtkMessageCapture capture_;
};

/// Runs a VTK reader whose file name is set: its header first, whose voxel count (from
/// `header_dims`, asked after the header was read) must pass checked_voxel_count so that a
/// damaged header cannot make VTK allocate terabytes, then its data. Throws vx::Error "cannot
/// read PATH as `what`: reason (the file is damaged or cut short; export it again)".
/// `before_data`, when given, runs between the two and throws for what the reader must not read.
void read_header_then_data(vtkAlgorithm& reader, const std::function<Eigen::Vector3i()>& header_dims,
                           const VtkMessages& messages, const std::filesystem::path& path, const char* what,
                           const std::function<void()>& before_data = {});

}  // namespace vx::volume_formats
