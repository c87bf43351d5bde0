#include "io/surface_io.h"

#include <vtkCellArray.h>
#include <vtkDataArray.h>
#include <vtkDoubleArray.h>
#include <vtkFieldData.h>
#include <vtkIdTypeArray.h>
#include <vtkIntArray.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkSmartPointer.h>
#include <vtkStringArray.h>
#include <vtkTypeInt64Array.h>
#include <vtkXMLPolyDataReader.h>
#include <vtkXMLPolyDataWriter.h>

#include <cmath>
#include <string>
#include <system_error>

#include "base/error.h"
#include "io/vtk_arrays.h"
#include "util/atomic_file.h"
#include "util/vtk_messages.h"

namespace vx {
namespace fs = std::filesystem;

namespace {

constexpr const char* kMagic = "voxelastic-surface";  ///< field data `voxelastic` holds this
constexpr int kFormatVersion = 1;

vtkSmartPointer<vtkPolyData> to_vtk(const EmbeddedSurface& s) {
  const int nv = s.num_vertices(), nt = s.num_triangles();
  auto pd = vtkSmartPointer<vtkPolyData>::New();
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();  // exact round trip
  points->SetNumberOfPoints(nv);
  for (int v = 0; v < nv; ++v) points->SetPoint(v, s.rest_vertices.col(v).data());
  pd->SetPoints(points);

  auto offsets = make_array<vtkTypeInt64Array>("offsets", 1, nt + 1);
  auto connectivity = make_array<vtkTypeInt64Array>("connectivity", 1, 3 * vtkIdType(nt));
  for (int t = 0; t <= nt; ++t) offsets->SetValue(t, 3 * vtkTypeInt64(t));
  for (int t = 0; t < nt; ++t)
    for (int c = 0; c < 3; ++c) connectivity->SetValue(3 * vtkIdType(t) + c, s.triangles(c, t));
  vtkNew<vtkCellArray> polys;
  polys->SetData(offsets, connectivity);
  pd->SetPolys(polys);

  // per vertex: rest normals and the embedding's entry count
  auto normals = make_array<vtkDoubleArray>("Normals", 3, nv);
  auto count = make_array<vtkIntArray>("embed_count", 1, nv);
  for (int v = 0; v < nv; ++v) {
    for (int c = 0; c < 3; ++c) normals->SetTypedComponent(v, c, s.rest_normals.cols() == nv ? s.rest_normals(c, v) : 0.0);
    count->SetValue(v, s.embed_offsets[std::size_t(v) + 1] - s.embed_offsets[std::size_t(v)]);
  }
  pd->GetPointData()->SetNormals(normals);
  pd->GetPointData()->AddArray(count);

  // the whole surface: what it is, which model, and the embedding (CSR)
  vtkFieldData* fd = pd->GetFieldData();
  add_string(fd, "voxelastic", kMagic);
  mark_lps(fd);
  auto version = make_array<vtkIntArray>("format_version", 1, 1);
  version->SetValue(0, kFormatVersion);
  fd->AddArray(version);
  add_string(fd, "surface_method", to_string(s.method));
  auto model_nodes = make_array<vtkTypeInt64Array>("model_nodes", 1, 1);
  model_nodes->SetValue(0, s.model_nodes);
  fd->AddArray(model_nodes);
  const vtkIdType ne = vtkIdType(s.embed_nodes.size());
  auto embed_offsets = make_array<vtkTypeInt64Array>("embed_offsets", 1, nv + 1);
  auto embed_nodes = make_array<vtkIntArray>("embed_nodes", 1, ne);
  auto embed_weights = make_array<vtkDoubleArray>("embed_weights", 1, ne);
  for (int v = 0; v <= nv; ++v) embed_offsets->SetValue(v, s.embed_offsets[std::size_t(v)]);
  for (vtkIdType k = 0; k < ne; ++k) {
    embed_nodes->SetValue(k, s.embed_nodes[std::size_t(k)]);
    embed_weights->SetValue(k, s.embed_weights[std::size_t(k)]);
  }
  fd->AddArray(embed_offsets);
  fd->AddArray(embed_nodes);
  fd->AddArray(embed_weights);
  return pd;
}

/// A field or point array of a surface file, checked for presence, components and length.
vtkDataArray* require(vtkFieldData* data, const char* kind, const char* name, int components, vtkIdType tuples,
                      const std::string& where) {
  vtkDataArray* a = data ? data->GetArray(name) : nullptr;
  if (!a)
    throw Error("'" + where + "' is not a complete voxelastic surface: the " + kind + " array '" + name +
                "' is missing (write the surface with `voxelastic convert --surface`)");
  if (a->GetNumberOfComponents() != components || (tuples >= 0 && a->GetNumberOfTuples() != tuples))
    throw Error("'" + where + "' is corrupt: the " + kind + " array '" + name + "' has " +
                std::to_string(a->GetNumberOfTuples()) + " x " + std::to_string(a->GetNumberOfComponents()) +
                " values, expected " + (tuples >= 0 ? std::to_string(tuples) : std::string("n")) + " x " +
                std::to_string(components));
  return a;
}

}  // namespace

void save_surface(const EmbeddedSurface& surface, const fs::path& path) {
  if (path.extension() != ".vtp")
    throw Error("cannot save the surface as '" + path.string() + "': use a .vtp file name (VTK XML polydata)");
  if (const std::string problem = surface.validate(); !problem.empty())
    throw Error("cannot save the surface to '" + path.string() + "': it is inconsistent: " + problem);
  save_polydata(*to_vtk(surface), path);
}

void save_polydata(vtkPolyData& polydata, const fs::path& path) {
  write_atomically(path, [&](const fs::path& tmp) {
    const VtkMessageCapture vtk_messages;
    vtkNew<vtkXMLPolyDataWriter> writer;
    writer->SetInputData(&polydata);
    writer->SetFileName(tmp.c_str());
    writer->SetDataModeToAppended();
    writer->EncodeAppendedDataOff();
    writer->SetCompressorTypeToZLib();
    writer->SetHeaderTypeToUInt64();
    writer->SetIdTypeToInt64();
    const int ok = writer->Write();
    if (!ok || !vtk_messages.errors().empty())
      throw Error("VTK could not write the file: " + vtk_messages.first_error("disk full or no permission?"));
  });
}

EmbeddedSurface load_surface(const fs::path& path, const Model* model) {
  const std::string where = path.string();
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("cannot load surface '" + where + "': no such file");
  if (!fs::is_regular_file(path, ec)) throw Error("cannot load surface '" + where + "': not a regular file");

  const VtkMessageCapture vtk_messages;
  vtkNew<vtkXMLPolyDataReader> reader;
  if (!reader->CanReadFile(path.c_str()))
    throw Error("cannot load surface '" + where +
                "': it is not a VTK XML polydata file (.vtp); surfaces are written by `voxelastic convert --surface`");
  reader->SetFileName(path.c_str());
  reader->Update();
  vtkPolyData* pd = reader->GetOutput();
  if (!vtk_messages.errors().empty() || reader->GetErrorCode() != 0 || !pd)
    throw Error("cannot load surface '" + where + "': the file is corrupt or truncated (VTK: " +
                vtk_messages.first_error("the reader failed") + ")");

  vtkFieldData* fd = pd->GetFieldData();
  auto* magic = fd ? vtkStringArray::SafeDownCast(fd->GetAbstractArray("voxelastic")) : nullptr;
  if (!magic || magic->GetNumberOfValues() != 1 || magic->GetValue(0) != kMagic)
    throw Error("'" + where + "' is a .vtp file but not a voxelastic surface (its field data lacks 'voxelastic' = '" +
                kMagic + "'); write one with `voxelastic convert ... --surface SURFACE.vtp`");
  vtkDataArray* version = require(fd, "field", "format_version", 1, 1, where);
  if (int(version->GetComponent(0, 0)) > kFormatVersion)
    throw Error("'" + where + "' is a voxelastic surface of format version " +
                std::to_string(int(version->GetComponent(0, 0))) + ", newer than this program reads (" +
                std::to_string(kFormatVersion) + "): update voxelastic");

  EmbeddedSurface s;
  auto* method = vtkStringArray::SafeDownCast(fd->GetAbstractArray("surface_method"));
  if (!method || method->GetNumberOfValues() != 1)
    throw Error("'" + where + "' is not a complete voxelastic surface: the field array 'surface_method' is missing");
  try {
    // "slice": a 2D model's surface (surface.h, make_slice_surface), made, never asked for
    s.method = method->GetValue(0) == "slice" ? SurfaceMethod::slice : parse_surface_method(method->GetValue(0));
  } catch (const Error& e) {
    throw Error("'" + where + "' is corrupt: " + e.what());
  }
  const double model_nodes = require(fd, "field", "model_nodes", 1, 1, where)->GetComponent(0, 0);
  if (!(model_nodes >= 1 && model_nodes <= 2147483647.0 && model_nodes == std::floor(model_nodes)))
    throw Error("'" + where + "' is corrupt: model_nodes is " + std::to_string(model_nodes));
  s.model_nodes = int(model_nodes);

  // vertices and triangles
  const vtkIdType nv = pd->GetNumberOfPoints();
  if (nv > 2147483647) throw Error("'" + where + "' is too large (over 2^31 vertices)");
  s.rest_vertices.resize(3, nv);
  for (vtkIdType v = 0; v < nv; ++v) {
    double p[3];
    pd->GetPoint(v, p);
    s.rest_vertices.col(v) = Eigen::Vector3d(p[0], p[1], p[2]);
  }
  if (!s.rest_vertices.allFinite()) throw Error("'" + where + "' is corrupt: a vertex is not finite");
  vtkCellArray* polys = pd->GetPolys();
  const vtkIdType nt = polys ? polys->GetNumberOfCells() : 0;
  if (pd->GetNumberOfCells() != nt)
    throw Error("'" + where + "' is corrupt: it holds cells other than triangles (lines, strips or vertices)");
  s.triangles.resize(3, nt);
  polys->InitTraversal();
  vtkIdType npts = 0;
  const vtkIdType* pts = nullptr;
  for (vtkIdType t = 0; polys->GetNextCell(npts, pts); ++t) {
    if (npts != 3) throw Error("'" + where + "' is corrupt: polygon " + std::to_string(t) + " is not a triangle");
    for (int c = 0; c < 3; ++c) {
      if (pts[c] < 0 || pts[c] >= nv) throw Error("'" + where + "' is corrupt: triangle " + std::to_string(t) + " refers to a missing vertex");
      s.triangles(c, t) = int(pts[c]);
    }
  }

  // embedding
  vtkDataArray* offsets = require(fd, "field", "embed_offsets", 1, nv + 1, where);
  vtkDataArray* nodes = require(fd, "field", "embed_nodes", 1, -1, where);
  vtkDataArray* weights = require(fd, "field", "embed_weights", 1, nodes->GetNumberOfTuples(), where);
  const vtkIdType ne = nodes->GetNumberOfTuples();
  if (ne > 2147483647) throw Error("'" + where + "' is too large (over 2^31 embedding entries)");
  s.embed_offsets.resize(std::size_t(nv) + 1);
  for (vtkIdType v = 0; v <= nv; ++v) {
    const double o = offsets->GetComponent(v, 0);
    if (!(o >= 0 && o <= double(ne) && o == std::floor(o)) || (v > 0 && o < s.embed_offsets[std::size_t(v) - 1]))
      throw Error("'" + where + "' is corrupt: embed_offsets is not an increasing list within 0.." + std::to_string(ne));
    s.embed_offsets[std::size_t(v)] = std::int32_t(o);
  }
  s.embed_nodes.resize(std::size_t(ne));
  s.embed_weights.resize(std::size_t(ne));
  for (vtkIdType k = 0; k < ne; ++k) {
    const double n = nodes->GetComponent(k, 0);
    if (!(n >= 0 && n < model_nodes && n == std::floor(n)))
      throw Error("'" + where + "' is corrupt: embed_nodes holds " + std::to_string(n) + ", not a node id below " +
                  std::to_string(s.model_nodes));
    s.embed_nodes[std::size_t(k)] = std::int32_t(n);
    s.embed_weights[std::size_t(k)] = weights->GetComponent(k, 0);
  }
  if (const std::string problem = s.validate(); !problem.empty())
    throw Error("'" + where + "' is corrupt: " + problem);

  if (model) {
    if (model->num_nodes() != s.model_nodes)
      throw Error("the surface '" + where + "' belongs to a model of " + std::to_string(s.model_nodes) +
                  " nodes, not to this model of " + std::to_string(model->num_nodes()) +
                  " nodes: write the surface again with the model (`voxelastic convert ... --surface`)");
    Eigen::Matrix3Xd at_rest;
    deform_vertices(s, model->rest_positions, at_rest);
    const double err = nv > 0 ? (at_rest - s.rest_vertices).cwiseAbs().maxCoeff() : 0.0;
    if (!(err <= 1e-6))
      throw Error("the surface '" + where + "' does not belong to this model: its embedding puts vertices up to " +
                  std::to_string(err) + " mm from their rest positions; write the surface again with the model");
  }
  s.finalize();
  return s;
}

}  // namespace vx
