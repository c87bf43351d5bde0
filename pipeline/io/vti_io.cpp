// .vti (VTK XML image data) through vtkXMLImageData{Reader,Writer}: VTK 9.1 keeps the
// direction matrix; a negative spacing is a flipped axis, a non-zero extent start an offset.
#include <fmt/format.h>
#include <vtkCellData.h>
#include <vtkDataArray.h>
#include <vtkErrorCode.h>
#include <vtkImageData.h>
#include <vtkInformation.h>
#include <vtkMatrix3x3.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkStreamingDemandDrivenPipeline.h>
#include <vtkXMLImageDataReader.h>
#include <vtkXMLImageDataWriter.h>

#include "base/error.h"
#include "io/volume_formats.h"
#include "util/text.h"

namespace vx::volume_formats {

Volume read_vti(const std::filesystem::path& path) {
  VtkMessages messages;
  vtkNew<vtkXMLImageDataReader> reader;
  if (!reader->CanReadFile(path.c_str()))
    throw Error(quoted(path) + " is not a VTK XML image file (.vti): its header is missing or damaged; "
                               "export it again");
  reader->SetFileName(path.c_str());
  const auto header_dims = [&] {
    int e[6] = {0, -1, 0, -1, 0, -1};
    reader->GetOutputInformation(0)->Get(vtkStreamingDemandDrivenPipeline::WHOLE_EXTENT(), e);
    return extent_dims(e);
  };
  read_header_then_data(*reader, header_dims, messages, path, "a VTK image (.vti)");
  vtkImageData* image = reader->GetOutput();
  int extent[6];
  image->GetExtent(extent);
  const Eigen::Vector3i dims = extent_dims(extent);
  if ((dims.array() <= 0).any())
    throw Error(quoted(path) + " holds no voxels (empty extent); export the volume again");
  vtkPointData* pd = image->GetPointData();
  vtkDataArray* array = pd->GetScalars();
  if (!array && pd->GetNumberOfArrays() > 0) array = pd->GetArray(0);
  if (!array) {
    const bool cells = image->GetCellData() && image->GetCellData()->GetNumberOfArrays() > 0;
    throw Error(quoted(path) + " has no point-data array (voxel values)" +
                (cells ? std::string(" (it has cell data only: convert it with ParaView's 'Cell Data to Point "
                                     "Data', or save the image with point scalars)")
                       : std::string("; save the image with its scalars")));
  }
  if (array->GetNumberOfComponents() != 1)
    throw Error(fmt::format("{}: array '{}' has {} components per voxel; voxelastic needs one value (HU) per "
                            "voxel: extract one component (e.g. ParaView 'Extract Component') first",
                            quoted(path), array->GetName() ? array->GetName() : "", array->GetNumberOfComponents()));
  const std::size_t n = std::size_t(dims.x()) * std::size_t(dims.y()) * std::size_t(dims.z());
  if (std::size_t(array->GetNumberOfTuples()) != n)
    throw Error(fmt::format("{}: array has {} values for {} voxels (damaged file; export it again)", quoted(path),
                            array->GetNumberOfTuples(), n));
  Volume v;
  const double* sp = image->GetSpacing();
  const double* o = image->GetOrigin();
  Eigen::Matrix3d D;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) D(r, c) = image->GetDirectionMatrix()->GetElement(r, c);
  const Eigen::Vector3d spacing(sp[0], sp[1], sp[2]);
  // a negative spacing is a flipped axis
  Eigen::Matrix3d A = D * spacing.asDiagonal();
  const Eigen::Vector3d first(extent[0], extent[2], extent[4]);
  const Eigen::Vector3d t = Eigen::Vector3d(o[0], o[1], o[2]) + A * first;
  v.geometry = geometry_from_affine(dims, A, t);
  v.hu = vtk_array_to_float(array, n, 1.0, 0.0);
  messages.print_warnings(path);
  return v;
}

void write_vti(const Volume& v, const std::filesystem::path& tmp) {
  const GridGeometry& g = v.geometry;
  vtkNew<vtkImageData> image;
  image->SetDimensions(g.dims.x(), g.dims.y(), g.dims.z());
  image->SetSpacing(g.spacing_mm.x(), g.spacing_mm.y(), g.spacing_mm.z());
  image->SetOrigin(g.origin_mm.x(), g.origin_mm.y(), g.origin_mm.z());
  double d[9];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) d[3 * r + c] = g.direction(r, c);
  image->SetDirectionMatrix(d);
  image->GetPointData()->SetScalars(hu_array(v.hu));

  VtkMessages messages;
  vtkNew<vtkXMLImageDataWriter> writer;
  writer->SetInputData(image);
  writer->SetFileName(tmp.c_str());
  writer->SetCompressorTypeToZLib();
  writer->SetDataModeToAppended();
  writer->EncodeAppendedDataOff();
  writer->SetHeaderTypeToUInt64();
  const int ok = writer->Write();
  if (!ok || messages.failed() || writer->GetErrorCode() != vtkErrorCode::NoError)
    throw Error("VTK image writer failed: " + messages.reason(writer->GetErrorCode()));
}

}  // namespace vx::volume_formats
