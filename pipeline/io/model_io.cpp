#include "io/model_io.h"

#include <fmt/format.h>
#include <vtkCellArray.h>
#include <vtkCellData.h>
#include <vtkDataArray.h>
#include <vtkDoubleArray.h>
#include <vtkFieldData.h>
#include <vtkIdTypeArray.h>
#include <vtkIntArray.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkSmartPointer.h>
#include <vtkStringArray.h>
#include <vtkUnsignedCharArray.h>
#include <vtkUnstructuredGrid.h>
#include <vtkXMLUnstructuredGridReader.h>
#include <vtkXMLUnstructuredGridWriter.h>

#include <cmath>
#include <string>
#include <system_error>
#include <vector>

#include "base/error.h"
#include "io/element_faces.h"
#include "io/vtk_arrays.h"
#include "util/atomic_file.h"
#include "util/vtk_messages.h"

namespace vx {
namespace fs = std::filesystem;

namespace {

constexpr const char* kMagic = "voxelastic-model";  ///< field data `voxelastic` holds this
constexpr int kFormatVersion = 1;

/// The model as an unstructured grid of VTK_POLYHEDRON cells with all its arrays.
vtkSmartPointer<vtkUnstructuredGrid> to_vtk(const Model& m) {
  const int nn = m.num_nodes(), ne = m.num_elements();
  auto ug = vtkSmartPointer<vtkUnstructuredGrid>::New();

  // nodes, LPS mm, double precision so a round trip is exact
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(nn);
  for (int i = 0; i < nn; ++i) points->SetPoint(i, m.rest_positions.col(i).data());
  ug->SetPoints(points);

  // one polyhedron per element: point list = vertex list in order, plus its face stream
  insert_element_polyhedra(m, ug);

  // per element
  auto level = make_array<vtkIntArray>("level", 1, ne);
  auto cell_voxels = make_array<vtkIntArray>("cell_voxels", 1, ne);
  auto cells_mask = make_array<vtkUnsignedCharArray>("cells_mask", 1, ne);
  auto anchor = make_array<vtkIntArray>("anchor", 3, ne);
  auto volume = make_array<vtkDoubleArray>("volume_mm3", 1, ne);
  auto vertex_count = make_array<vtkIntArray>("vertex_count", 1, ne);
  for (int e = 0; e < ne; ++e) {
    const auto se = std::size_t(e);
    level->SetValue(e, m.element_level[se]);
    cell_voxels->SetValue(e, m.element_cell_voxels[se]);
    cells_mask->SetValue(e, m.element_cells[se]);
    for (int c = 0; c < 3; ++c) anchor->SetTypedComponent(e, c, m.element_anchor(c, e));
    volume->SetValue(e, se < m.element_volume_mm3.size() ? m.element_volume_mm3[se] : 0.0);
    vertex_count->SetValue(e, m.num_vertices(e));
  }
  for (vtkDataArray* a : {static_cast<vtkDataArray*>(level), static_cast<vtkDataArray*>(cell_voxels),
                          static_cast<vtkDataArray*>(cells_mask), static_cast<vtkDataArray*>(anchor),
                          static_cast<vtkDataArray*>(volume), static_cast<vtkDataArray*>(vertex_count)})
    ug->GetCellData()->AddArray(a);
  ug->GetCellData()->SetActiveScalars("level");

  // per node
  auto lattice = make_array<vtkIntArray>("lattice", 3, nn);
  auto surface = make_array<vtkUnsignedCharArray>("surface", 1, nn);
  for (int i = 0; i < nn; ++i) {
    for (int c = 0; c < 3; ++c) lattice->SetTypedComponent(i, c, m.node_lattice(c, i));
    surface->SetValue(i, m.node_surface[std::size_t(i)]);
  }
  ug->GetPointData()->AddArray(lattice);
  ug->GetPointData()->AddArray(surface);

  // the whole model: what it is, and the grid it was built from
  vtkFieldData* fd = ug->GetFieldData();
  add_string(fd, "voxelastic", kMagic);
  mark_lps(fd);
  auto version = make_array<vtkIntArray>("format_version", 1, 1);
  version->SetValue(0, kFormatVersion);
  fd->AddArray(version);
  add_string(fd, "resolution", to_string(m.layout));
  auto dimensions = make_array<vtkIntArray>("dimensions", 1, 1);  // 3: volume model; 2: slice (format 1 files without it: 3)
  dimensions->SetValue(0, m.dimensions);
  fd->AddArray(dimensions);
  auto dims = make_array<vtkIntArray>("grid_dims", 3, 1);
  auto spacing = make_array<vtkDoubleArray>("grid_spacing_mm", 3, 1);
  auto origin = make_array<vtkDoubleArray>("grid_origin_mm", 3, 1);
  auto direction = make_array<vtkDoubleArray>("grid_direction", 9, 1);  // row-major 3x3
  for (int c = 0; c < 3; ++c) {
    dims->SetTypedComponent(0, c, m.grid.dims[c]);
    spacing->SetTypedComponent(0, c, m.grid.spacing_mm[c]);
    origin->SetTypedComponent(0, c, m.grid.origin_mm[c]);
    for (int r = 0; r < 3; ++r) direction->SetTypedComponent(0, 3 * r + c, m.grid.direction(r, c));
  }
  for (vtkDataArray* a : {static_cast<vtkDataArray*>(dims), static_cast<vtkDataArray*>(spacing),
                          static_cast<vtkDataArray*>(origin), static_cast<vtkDataArray*>(direction)})
    fd->AddArray(a);
  return ug;
}

/// An array of a model file, checked for presence, component count and length.
vtkDataArray* require(vtkFieldData* data, const char* kind, const char* name, int components, vtkIdType tuples,
                      const std::string& where) {
  vtkDataArray* a = data ? data->GetArray(name) : nullptr;
  if (!a)
    throw Error("'" + where + "' is not a complete voxelastic model: the " + kind + " array '" + name +
                "' is missing (write the model with `voxelastic convert`)");
  if (a->GetNumberOfComponents() != components || a->GetNumberOfTuples() != tuples)
    throw Error("'" + where + "' is corrupt: the " + kind + " array '" + name + "' has " +
                std::to_string(a->GetNumberOfTuples()) + " x " + std::to_string(a->GetNumberOfComponents()) +
                " values, expected " + std::to_string(tuples) + " x " + std::to_string(components));
  return a;
}

/// An integer read from a double, or an error naming the array when it is not one.
int as_int(double x, const char* name, const std::string& where) {
  if (!std::isfinite(x) || x != std::floor(x) || std::fabs(x) > 2147483647.0)
    throw Error("'" + where + "' is corrupt: array '" + name + "' holds " + std::to_string(x) + ", not an integer");
  return int(x);
}

}  // namespace

void save_model(const Model& model, const fs::path& path, const ElementArrays& element_arrays) {
  if (path.extension() != ".vtu")
    throw Error("cannot save the model as '" + path.string() + "': use a .vtu file name (VTK XML unstructured grid)");
  if (const std::string problem = model.validate(); !problem.empty())
    throw Error("cannot save the model to '" + path.string() + "': it is inconsistent: " + problem);
  const vtkSmartPointer<vtkUnstructuredGrid> ug = to_vtk(model);
  for (const auto& [name, values] : element_arrays) {
    if (std::int64_t(values.size()) != model.num_elements())
      throw Error(fmt::format("cannot save the model to '{}': the element array '{}' has {} values for {} elements",
                              path.string(), name, values.size(), model.num_elements()));
    auto a = make_array<vtkDoubleArray>(name.c_str(), 1, model.num_elements());
    for (int e = 0; e < model.num_elements(); ++e) a->SetValue(e, values[std::size_t(e)]);
    ug->GetCellData()->AddArray(a);
  }
  write_atomically(path, [&](const fs::path& tmp) {
    const VtkMessageCapture vtk_messages;
    vtkNew<vtkXMLUnstructuredGridWriter> writer;
    writer->SetInputData(ug);
    writer->SetFileName(tmp.c_str());
    writer->SetDataModeToAppended();
    writer->EncodeAppendedDataOff();  // raw binary
    writer->SetCompressorTypeToZLib();
    writer->SetHeaderTypeToUInt64();  // blocks over 4 GiB
    writer->SetIdTypeToInt64();
    const int ok = writer->Write();
    if (!ok || !vtk_messages.errors().empty())
      throw Error("VTK could not write the file: " + vtk_messages.first_error("disk full or no permission?"));
  });
}

Model load_model(const fs::path& path) {
  const std::string where = path.string();
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("cannot load model '" + where + "': no such file");
  if (fs::is_directory(path, ec)) throw Error("cannot load model '" + where + "': it is a folder, give a .vtu file");
  if (!fs::is_regular_file(path, ec)) throw Error("cannot load model '" + where + "': not a regular file");

  const VtkMessageCapture vtk_messages;
  vtkNew<vtkXMLUnstructuredGridReader> reader;
  if (!reader->CanReadFile(path.c_str()))
    throw Error("cannot load model '" + where +
                "': it is not a VTK XML unstructured grid (.vtu); voxelastic models are written by `voxelastic convert`");
  reader->SetFileName(path.c_str());
  reader->Update();
  vtkUnstructuredGrid* ug = reader->GetOutput();
  if (!vtk_messages.errors().empty() || reader->GetErrorCode() != 0 || !ug)
    throw Error("cannot load model '" + where + "': the file is corrupt or truncated (VTK: " +
                vtk_messages.first_error("the reader failed") + "); write it again with `voxelastic convert`");

  // is this a voxelastic model?
  vtkFieldData* fd = ug->GetFieldData();
  auto* magic = fd ? vtkStringArray::SafeDownCast(fd->GetAbstractArray("voxelastic")) : nullptr;
  if (!magic || magic->GetNumberOfValues() != 1 || magic->GetValue(0) != kMagic)
    throw Error("'" + where +
                "' is a .vtu file but not a voxelastic model (its field data lacks 'voxelastic' = '" + kMagic +
                "'); make a model with `voxelastic convert INPUT -o MODEL.vtu`");
  vtkDataArray* version = require(fd, "field", "format_version", 1, 1, where);
  if (int(version->GetComponent(0, 0)) > kFormatVersion)
    throw Error("'" + where + "' is a voxelastic model of format version " +
                std::to_string(int(version->GetComponent(0, 0))) + ", newer than this program reads (" +
                std::to_string(kFormatVersion) + "): update voxelastic");

  Model m;
  auto* layout = vtkStringArray::SafeDownCast(fd->GetAbstractArray("resolution"));
  if (!layout || layout->GetNumberOfValues() != 1)
    throw Error("'" + where + "' is not a complete voxelastic model: the field array 'resolution' is missing");
  try {
    m.layout = parse_layout(layout->GetValue(0));
  } catch (const Error& e) {
    throw Error("'" + where + "' is corrupt: " + e.what());
  }
  if (vtkDataArray* d = fd->GetArray("dimensions")) {
    if (d->GetNumberOfTuples() != 1 || d->GetNumberOfComponents() != 1)
      throw Error("'" + where + "' is corrupt: the field array 'dimensions' must hold one value");
    m.dimensions = as_int(d->GetComponent(0, 0), "dimensions", where);
    if (m.dimensions != 2 && m.dimensions != 3)
      throw Error("'" + where + "' is corrupt: field array 'dimensions' is " + std::to_string(m.dimensions) +
                  " (2: a slice model, 3: a volume model)");
  }
  const int cell_type = m.dimensions == 2 ? VTK_POLYGON : VTK_POLYHEDRON;
  vtkDataArray* dims = require(fd, "field", "grid_dims", 3, 1, where);
  vtkDataArray* spacing = require(fd, "field", "grid_spacing_mm", 3, 1, where);
  vtkDataArray* origin = require(fd, "field", "grid_origin_mm", 3, 1, where);
  vtkDataArray* direction = require(fd, "field", "grid_direction", 9, 1, where);
  for (int c = 0; c < 3; ++c) {
    m.grid.dims[c] = as_int(dims->GetComponent(0, c), "grid_dims", where);
    m.grid.spacing_mm[c] = spacing->GetComponent(0, c);
    m.grid.origin_mm[c] = origin->GetComponent(0, c);
    for (int r = 0; r < 3; ++r) m.grid.direction(r, c) = direction->GetComponent(0, 3 * r + c);
  }
  if ((m.grid.dims.array() <= 0).any() || !(m.grid.spacing_mm.array() > 0).all() || !m.grid.origin_mm.allFinite() ||
      !m.grid.direction.allFinite())
    throw Error("'" + where + "' is corrupt: the grid geometry (field data grid_*) is not valid");

  // nodes
  const vtkIdType nn = ug->GetNumberOfPoints(), ne = ug->GetNumberOfCells();
  vtkDataArray* lattice = require(ug->GetPointData(), "point", "lattice", 3, nn, where);
  vtkDataArray* surface = require(ug->GetPointData(), "point", "surface", 1, nn, where);
  vtkCellData* cd = ug->GetCellData();
  vtkDataArray* level = require(cd, "cell", "level", 1, ne, where);
  vtkDataArray* cell_voxels = require(cd, "cell", "cell_voxels", 1, ne, where);
  vtkDataArray* cells_mask = require(cd, "cell", "cells_mask", 1, ne, where);
  vtkDataArray* anchor = require(cd, "cell", "anchor", 3, ne, where);
  require(cd, "cell", "volume_mm3", 1, ne, where);
  vtkDataArray* vertex_count = require(cd, "cell", "vertex_count", 1, ne, where);
  if (nn > 2147483647 || ne > 2147483647) throw Error("'" + where + "' is too large (over 2^31 nodes or elements)");

  m.rest_positions.resize(3, nn);
  m.node_lattice.resize(3, nn);
  m.node_surface.resize(std::size_t(nn));
  for (vtkIdType i = 0; i < nn; ++i) {
    double p[3];
    ug->GetPoint(i, p);
    for (int c = 0; c < 3; ++c) {
      m.rest_positions(c, i) = p[c];
      m.node_lattice(c, i) = as_int(lattice->GetComponent(i, c), "lattice", where);
    }
    const int s = as_int(surface->GetComponent(i, 0), "surface", where);
    if (s != 0 && s != 1) throw Error("'" + where + "' is corrupt: point array 'surface' holds " + std::to_string(s));
    m.node_surface[std::size_t(i)] = std::uint8_t(s);
  }
  if (!m.rest_positions.allFinite()) throw Error("'" + where + "' is corrupt: a node position is not finite");

  // elements: the polyhedron's (2D: the polygon's) point list is the vertex list, in order
  m.element_offsets.assign(1, 0);
  m.element_vertices.reserve(std::size_t(ug->GetCells()->GetNumberOfConnectivityIds()));
  m.element_level.resize(std::size_t(ne));
  m.element_cell_voxels.resize(std::size_t(ne));
  m.element_cells.resize(std::size_t(ne));
  m.element_anchor.resize(3, ne);
  vtkNew<vtkIdList> pts;
  for (vtkIdType e = 0; e < ne; ++e) {
    if (ug->GetCellType(e) != cell_type)
      throw Error("'" + where + "' is corrupt: cell " + std::to_string(e) + " is VTK cell type " +
                  std::to_string(ug->GetCellType(e)) + ", expected " +
                  (cell_type == VTK_POLYGON ? "a polygon (7) in a 2D model" : "a polyhedron (42)"));
    ug->GetCellPoints(e, pts);
    const int n = int(pts->GetNumberOfIds());
    if (n != as_int(vertex_count->GetComponent(e, 0), "vertex_count", where))
      throw Error("'" + where + "' is corrupt: element " + std::to_string(e) + " has " + std::to_string(n) +
                  " points but vertex_count says " + std::to_string(int(vertex_count->GetComponent(e, 0))));
    for (int i = 0; i < n; ++i) {
      const vtkIdType id = pts->GetId(i);
      if (id < 0 || id >= nn)
        throw Error("'" + where + "' is corrupt: element " + std::to_string(e) + " refers to point " +
                    std::to_string(id) + " of " + std::to_string(nn));
      m.element_vertices.push_back(std::int32_t(id));
    }
    m.element_offsets.push_back(std::int32_t(m.element_vertices.size()));
    const int l = as_int(level->GetComponent(e, 0), "level", where);
    const int w = as_int(cell_voxels->GetComponent(e, 0), "cell_voxels", where);
    const int mask = as_int(cells_mask->GetComponent(e, 0), "cells_mask", where);
    if (l < 0 || l > 30 || w < 1 || mask < 1 || mask > 255)
      throw Error("'" + where + "' is corrupt: element " + std::to_string(e) + " has level " + std::to_string(l) +
                  ", cell width " + std::to_string(w) + " voxels, cell mask " + std::to_string(mask));
    m.element_level[std::size_t(e)] = std::int8_t(l);
    m.element_cell_voxels[std::size_t(e)] = w;
    m.element_cells[std::size_t(e)] = std::uint8_t(mask);
    for (int c = 0; c < 3; ++c) m.element_anchor(c, e) = as_int(anchor->GetComponent(e, c), "anchor", where);
  }
  if (const std::string problem = m.validate(); !problem.empty())
    throw Error("'" + where + "' is corrupt: " + problem);
  m.finalize();
  return m;
}

}  // namespace vx
