// NIfTI (.nii, .nii.gz) through vtkNIFTIImage{Reader,Writer}: RAS on disk, LPS here. The
// reader reverses the slices of a left-handed grid (qfac = -1); that is undone here, so the
// voxel order matches the file, and a left-handed grid is written with qfac = -1 likewise.
#include <fmt/format.h>
#include <vtkDataArray.h>
#include <vtkErrorCode.h>
#include <vtkImageData.h>
#include <vtkMatrix4x4.h>
#include <vtkNIFTIImageHeader.h>
#include <vtkNIFTIImageReader.h>
#include <vtkNIFTIImageWriter.h>
#include <vtkNew.h>
#include <vtkPointData.h>

#include <zlib.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <cstdio>

#include "base/error.h"
#include "io/volume_formats.h"
#include "util/log.h"
#include "util/text.h"

namespace vx::volume_formats {
namespace {
namespace fs = std::filesystem;

/// What the header says about the voxels, read here before vtkNIFTIImageReader reads them:
/// VTK 9.1 trusts the header (a zero dimension crashes it inside gzread, an unknown data type
/// makes it allocate gigabytes).
struct NiftiHeader {
  int version{1};              ///< 1 or 2
  std::array<std::int64_t, 8> dim{};
  int datatype{0};
  double vox_offset{0};
};

template <typename T>
T field(const unsigned char* h, std::size_t at, bool swap) {
  unsigned char b[sizeof(T)];
  std::memcpy(b, h + at, sizeof(T));
  if (swap) std::reverse(b, b + sizeof(T));
  T v;
  std::memcpy(&v, b, sizeof(T));
  return v;
}

/// Bytes per voxel of a NIfTI scalar data type; 0 for types that are not one number per voxel.
int nifti_scalar_bytes(int datatype) {
  switch (datatype) {
    case 2: case 256: return 1;                 // uint8, int8
    case 4: case 512: return 2;                 // int16, uint16
    case 8: case 768: case 16: return 4;        // int32, uint32, float32
    case 64: case 1024: case 1280: return 8;    // float64, int64, uint64
    default: return 0;
  }
}

const char* nifti_type_name(int datatype) {
  switch (datatype) {
    case 32: return "complex64";
    case 128: return "RGB24";
    case 1536: return "float128";
    case 1792: return "complex128";
    case 2048: return "complex256";
    case 2304: return "RGBA32";
    case 1: return "binary (1 bit)";
    default: return nullptr;
  }
}

/// Reads and checks the header (plain or gzip: zlib reads both); throws vx::Error.
NiftiHeader check_nifti_header(const fs::path& path) {
  unsigned char h[540] = {};
  int got = 0;
  if (gzFile f = gzopen(path.c_str(), "rb")) {
    got = gzread(f, h, sizeof h);
    gzclose(f);
  }
  if (got < 348)
    throw Error(fmt::format("{} is not a NIfTI file: it holds {} bytes of header, a NIfTI header has 348 (the file "
                            "is cut short or damaged; export it again)",
                            quoted(path), std::max(got, 0)));
  NiftiHeader n;
  const std::int32_t size = field<std::int32_t>(h, 0, false);
  bool swap = false;
  if (size == 348 || size == 540) {
    swap = false;
  } else if (field<std::int32_t>(h, 0, true) == 348 || field<std::int32_t>(h, 0, true) == 540) {
    swap = true;
  } else {
    throw Error(quoted(path) + " is not a NIfTI file: its first four bytes are not the header size 348 (NIfTI-1) or "
                               "540 (NIfTI-2)");
  }
  n.version = field<std::int32_t>(h, 0, swap) == 540 ? 2 : 1;
  if (n.version == 2 && got < 540)
    throw Error(quoted(path) + " is cut short inside its NIfTI-2 header (540 bytes)");
  if (n.version == 1) {
    for (int i = 0; i < 8; ++i) n.dim[std::size_t(i)] = field<std::int16_t>(h, 40 + 2 * std::size_t(i), swap);
    n.datatype = field<std::int16_t>(h, 70, swap);
    n.vox_offset = field<float>(h, 108, swap);
  } else {
    for (int i = 0; i < 8; ++i) n.dim[std::size_t(i)] = field<std::int64_t>(h, 16 + 8 * std::size_t(i), swap);
    n.datatype = field<std::int16_t>(h, 12, swap);
    n.vox_offset = double(field<std::int64_t>(h, 168, swap));
  }
  const std::int64_t rank = n.dim[0];
  if (rank < 1 || rank > 7)
    throw Error(fmt::format("{}: NIfTI dim[0] = {} (the number of dimensions) must be 1 to 7; the header is damaged",
                            quoted(path), rank));
  for (int i = 1; i <= rank; ++i)
    if (n.dim[std::size_t(i)] < 1)
      throw Error(fmt::format("{}: NIfTI dim[{}] = {}: every dimension must hold at least one voxel; the header is "
                              "damaged (export the volume again)",
                              quoted(path), i, n.dim[std::size_t(i)]));
  for (int i = int(rank) + 1; i <= 3; ++i) n.dim[std::size_t(i)] = 1;
  if (rank >= 4 && n.dim[4] > 1)
    throw Error(fmt::format("{} is a 4D NIfTI with {} volumes; voxelastic reads one 3D volume: extract one (e.g. "
                            "'fslroi in out 0 1') first",
                            quoted(path), n.dim[4]));
  for (int i = 5; i <= rank; ++i)
    if (n.dim[std::size_t(i)] > 1)
      throw Error(fmt::format("{}: NIfTI dim[{}] = {}: a vector or higher-dimensional image; voxelastic needs one "
                              "value (HU) per voxel",
                              quoted(path), i, n.dim[std::size_t(i)]));
  const int bytes = nifti_scalar_bytes(n.datatype);
  if (bytes == 0) {
    const char* name = nifti_type_name(n.datatype);
    throw Error(name ? fmt::format("{}: NIfTI datatype {} ({}) is not one number per voxel; voxelastic needs one "
                                   "value (HU) per voxel",
                                   quoted(path), n.datatype, name)
                     : fmt::format("{}: NIfTI datatype {} is not a known data type (the header is damaged; export the "
                                   "volume again)",
                                   quoted(path), n.datatype));
  }
  if (!std::isfinite(n.vox_offset) || n.vox_offset < 0)
    throw Error(fmt::format("{}: NIfTI vox_offset {} is not a byte position; the header is damaged", quoted(path),
                            n.vox_offset));
  for (int i = 1; i <= 3; ++i)
    if (n.dim[std::size_t(i)] > 1000000)
      throw Error(fmt::format("{}: NIfTI dim[{}] = {} voxels; the header is damaged", quoted(path), i,
                              n.dim[std::size_t(i)]));
  (void)checked_voxel_count(Eigen::Vector3i(int(n.dim[1]), int(n.dim[2]), int(n.dim[3])), path);
  // the voxels must be in the file: all of them after vox_offset, or for gzip at most what
  // deflate can pack into the file (about 1032:1)
  const double needed = double(n.dim[1]) * double(n.dim[2]) * double(n.dim[3]) * bytes;
  const double start = std::max(n.vox_offset, n.version == 1 ? 352.0 : 544.0);
  const double file_bytes = double(file_size_or_zero(path));
  const bool gz = [&] {
    unsigned char magic[2] = {};
    if (FILE* f = std::fopen(path.c_str(), "rb")) {
      const std::size_t r = std::fread(magic, 1, 2, f);
      std::fclose(f);
      return r == 2 && magic[0] == 0x1f && magic[1] == 0x8b;
    }
    return false;
  }();
  if (!gz && start + needed > file_bytes)
    throw Error(fmt::format("{} is truncated: its header promises {:.0f} bytes of voxels from byte {:.0f}, the file "
                            "holds {:.0f} bytes (copy or export it again)",
                            quoted(path), needed, start, file_bytes));
  if (gz && start + needed > 1100.0 * file_bytes + 4096.0)
    throw Error(fmt::format("{}: {:.0f} bytes of gzip data cannot hold the {:.0f} bytes of voxels its header promises "
                            "(damaged header or cut-short file; copy or export it again)",
                            quoted(path), file_bytes, needed));
  return n;
}

}  // namespace

NiftiAffine choose_nifti_affine(int qform_code, const std::pair<Eigen::Matrix3d, Eigen::Vector3d>& qform,
                                int sform_code, const std::pair<Eigen::Matrix3d, Eigen::Vector3d>& sform,
                                const Eigen::Vector3i& dims) {
  NiftiAffine out;
  const auto use = [&](const std::pair<Eigen::Matrix3d, Eigen::Vector3d>& a, const char* name) {
    out.A = a.first;
    out.t = a.second;
    out.source = name;
  };
  // no orientation at all: NIfTI "method 1", the voxel sizes only (A carries pixdim already)
  if (qform_code <= 0 && sform_code <= 0) {
    use(qform, "pixdim");
    return out;
  }
  if (sform_code <= 0) return use(qform, "qform"), out;
  if (qform_code <= 0) return use(sform, "sform"), out;
  // both: where they put the grid's corners
  double gap_mm = 0;
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector3d ijk((c & 1) ? dims.x() - 1 : 0, (c & 2) ? dims.y() - 1 : 0, (c & 4) ? dims.z() - 1 : 0);
    gap_mm = std::max(gap_mm, ((qform.first * ijk + qform.second) - (sform.first * ijk + sform.second)).norm());
  }
  const double spacing = std::max({qform.first.col(0).norm(), qform.first.col(1).norm(), qform.first.col(2).norm()});
  const bool disagree = !(gap_mm <= std::max(0.01, 1e-3 * spacing));
  // the sform only when it is scanner-anatomical (code 1), as ITK and so 3D Slicer read it;
  // an sform with shear cannot be an orthogonal grid: then the qform
  Eigen::Matrix3d n = sform.first;
  for (int c = 0; c < 3; ++c) n.col(c).normalize();
  const bool sheared = !((n.transpose() * n - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() <= 1e-3);
  const bool sform_wins = sform_code == 1 && !sheared;
  if (sform_wins) use(sform, "sform");
  else use(qform, "qform");
  if (disagree)
    out.warning = fmt::format(
        "the qform (code {}) and sform (code {}) disagree, by up to {:.3g} mm at the grid's corners; following the {} "
        "as 3D Slicer and ITK do (the sform only when it is scanner-anatomical, code 1, and has no shear)",
        qform_code, sform_code, gap_mm, out.source);
  return out;
}

Volume read_nifti(const std::filesystem::path& path) {
  (void)check_nifti_header(path);
  VtkMessages messages;
  vtkNew<vtkNIFTIImageReader> reader;
  if (!reader->CanReadFile(path.c_str()))
    throw Error(quoted(path) + " is not a NIfTI file: its 348-byte header is missing or damaged (export it "
                               "again; if it is gzip-compressed it must end in .nii.gz)");
  reader->SetFileName(path.c_str());
  read_header_then_data(*reader, [&] { return extent_dims(reader->GetDataExtent()); }, messages, path, "NIfTI");
  if (reader->GetTimeDimension() > 1)
    throw Error(fmt::format("{} is a 4D NIfTI with {} volumes; voxelastic reads one 3D volume: extract one "
                            "(e.g. 'fslroi in out 0 1') first",
                            quoted(path), reader->GetTimeDimension()));
  vtkImageData* image = reader->GetOutput();
  int extent[6];
  image->GetExtent(extent);
  const Eigen::Vector3i dims = extent_dims(extent);
  vtkDataArray* array = image->GetPointData()->GetScalars();
  if ((dims.array() <= 0).any() || !array)
    throw Error(quoted(path) + " holds no voxels (empty NIfTI image)");
  if (array->GetNumberOfComponents() != 1)
    throw Error(fmt::format("{}: {} values per voxel (vector, complex or RGB NIfTI); voxelastic needs one value "
                            "(HU) per voxel",
                            quoted(path), array->GetNumberOfComponents()));
  const std::size_t n = std::size_t(dims.prod());
  if (std::size_t(array->GetNumberOfTuples()) != n) throw Error(quoted(path) + ": voxel data incomplete");

  // the affine from VTK's (possibly slice-reversed) index to RAS, in mm
  double unit_mm = 1.0;  // spatial units: mm unless the header says metres or microns
  switch (reader->GetNIFTIHeader()->GetXYZTUnits() & 0x07) {
    case 1: unit_mm = 1000.0; break;  // NIFTI_UNITS_METER
    case 3: unit_mm = 0.001; break;   // NIFTI_UNITS_MICRON
    default: break;                   // NIFTI_UNITS_MM or unknown
  }
  const double* sp = image->GetSpacing();
  const auto affine_of = [&](vtkMatrix4x4* m) {
    std::pair<Eigen::Matrix3d, Eigen::Vector3d> at{Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()};
    if (m)
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) at.first(r, c) = m->GetElement(r, c);
        at.second[r] = m->GetElement(r, 3);
      }
    at.first = at.first * Eigen::Vector3d(sp[0], sp[1], sp[2]).asDiagonal() * unit_mm;
    at.second *= unit_mm;
    return at;
  };
  const auto choice = choose_nifti_affine(reader->GetNIFTIHeader()->GetQFormCode(), affine_of(reader->GetQFormMatrix()),
                                          reader->GetNIFTIHeader()->GetSFormCode(), affine_of(reader->GetSFormMatrix()),
                                          dims);
  if (!choice.warning.empty()) log::warn("{}: {}", path.string(), choice.warning);
  Eigen::Matrix3d A = choice.A;
  Eigen::Vector3d t = choice.t;

  Volume v;
  const double slope = reader->GetRescaleSlope(), intercept = reader->GetRescaleIntercept();
  const bool scaled = slope != 0.0 && std::isfinite(slope) && std::isfinite(intercept);
  v.hu = vtk_array_to_float(array, n, scaled ? slope : 1.0, scaled ? intercept : 0.0);
  if (reader->GetQFac() < 0) {
    // the reader reversed the slices (qfac = -1 or a left-handed sform); restore the file's order
    reverse_slices(v.hu, dims);
    t += A.col(2) * double(dims.z() - 1);
    A.col(2) = -A.col(2);
  }
  v.geometry = geometry_from_affine(dims, kRasToLps * A, kRasToLps * t);
  messages.print_warnings(path);
  return v;
}

void write_nifti(const Volume& v, const std::filesystem::path& tmp) {
  const GridGeometry& g = v.geometry;
  if (!g.direction_is_orthonormal())
    throw Error("NIfTI stores orientation as a rotation: the volume's direction matrix is not orthonormal");
  // NIfTI wants a rotation (det +1) in RAS; a left-handed grid is stored with qfac = -1: hand
  // VTK the slices reversed, and it reverses them back while writing.
  Eigen::Matrix3d R = kRasToLps * g.direction;  // LPS->RAS is the same flip
  Eigen::Vector3d t = kRasToLps * g.origin_mm;
  const bool left_handed = R.determinant() < 0;
  std::vector<float> values = v.hu;
  if (left_handed) {
    reverse_slices(values, g.dims);
    t += R.col(2) * g.spacing_mm.z() * double(g.dims.z() - 1);
    R.col(2) = -R.col(2);
  }
  vtkNew<vtkImageData> image;
  image->SetDimensions(g.dims.x(), g.dims.y(), g.dims.z());
  image->SetSpacing(g.spacing_mm.x(), g.spacing_mm.y(), g.spacing_mm.z());
  image->SetOrigin(0, 0, 0);
  image->GetPointData()->SetScalars(hu_array(values));

  vtkNew<vtkMatrix4x4> m;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m->SetElement(r, c, R(r, c));
    m->SetElement(r, 3, t[r]);
  }
  vtkNew<vtkNIFTIImageHeader> header;
  header->SetXYZTUnits(2);  // NIFTI_UNITS_MM
  header->SetDescrip("voxelastic (HU)");
  VtkMessages messages;
  vtkNew<vtkNIFTIImageWriter> writer;
  writer->SetNIFTIVersion(1);
  writer->SetNIFTIHeader(header);
  writer->SetRescaleSlope(1.0);
  writer->SetRescaleIntercept(0.0);
  writer->SetQFac(left_handed ? -1.0 : 1.0);
  writer->SetQFormMatrix(m);
  writer->SetSFormMatrix(m);
  writer->SetInputData(image);
  writer->SetFileName(tmp.c_str());
  writer->Write();
  if (messages.failed() || writer->GetErrorCode() != vtkErrorCode::NoError)
    throw Error("NIfTI writer failed: " + messages.reason(writer->GetErrorCode()));
}

}  // namespace vx::volume_formats
