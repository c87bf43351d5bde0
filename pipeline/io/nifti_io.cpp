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

#include <Eigen/Dense>
#include <cmath>

#include "base/error.h"
#include "io/volume_formats.h"
#include "util/text.h"

namespace vx::volume_formats {

Volume read_nifti(const std::filesystem::path& path) {
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

  // the affine from VTK's (possibly slice-reversed) index to RAS: sform if present, else qform
  // (nibabel's order), else scaling only (NIfTI "method 1")
  vtkMatrix4x4* m = reader->GetSFormMatrix() ? reader->GetSFormMatrix() : reader->GetQFormMatrix();
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  if (m)
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) R(r, c) = m->GetElement(r, c);
      t[r] = m->GetElement(r, 3);
    }
  const double* sp = image->GetSpacing();
  Eigen::Matrix3d A = R * Eigen::Vector3d(sp[0], sp[1], sp[2]).asDiagonal();
  // spatial units: mm unless the header says metres or microns
  double unit_mm = 1.0;
  switch (reader->GetNIFTIHeader()->GetXYZTUnits() & 0x07) {
    case 1: unit_mm = 1000.0; break;  // NIFTI_UNITS_METER
    case 3: unit_mm = 0.001; break;   // NIFTI_UNITS_MICRON
    default: break;                   // NIFTI_UNITS_MM or unknown
  }
  A *= unit_mm;
  t *= unit_mm;

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
