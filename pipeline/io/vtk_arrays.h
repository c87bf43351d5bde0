#pragma once
/// @file vtk_arrays.h
/// Small VTK helpers shared by the model, surface and time-series writers (pipeline only).

#include <vtkCellType.h>
#include <vtkFieldData.h>
#include <vtkNew.h>
#include <vtkSmartPointer.h>
#include <vtkStringArray.h>
#include <vtkUnstructuredGrid.h>

#include <string>
#include <vector>

#include "io/element_faces.h"
#include "model/model.h"

namespace vx {

/// A named data array of `tuples` x `components`, allocated.
template <class ArrayT>
vtkSmartPointer<ArrayT> make_array(const char* name, int components, vtkIdType tuples) {
  auto a = vtkSmartPointer<ArrayT>::New();
  a->SetName(name);
  a->SetNumberOfComponents(components);
  a->SetNumberOfTuples(tuples);
  return a;
}

/// Adds a one-value string array to field data.
inline void add_string(vtkFieldData* fd, const char* name, const std::string& value) {
  vtkNew<vtkStringArray> a;
  a->SetName(name);
  a->InsertNextValue(value);
  fd->AddArray(a);
}

/// Marks a mesh's coordinates as LPS the way 3D Slicer reads it (a field-data string `SPACE`,
/// following NRRD's naming): Slicer then shows it in place instead of mirroring x and y.
inline void mark_lps(vtkFieldData* fd) {
  fd->RemoveArray("SPACE");
  add_string(fd, "SPACE", "LPS");
}

/// Inserts one VTK_POLYHEDRON cell per element into `ug` (whose points are the model's nodes):
/// the cell's point list is the element's vertex list in order, plus its face stream. A 2D
/// (slice) model gets one VTK_POLYGON per element instead: its vertex list goes round the
/// element counter-clockwise (seen from the slice normal; gradational_builder_2d.cpp).
inline void insert_element_polyhedra(const Model& m, vtkUnstructuredGrid* ug) {
  const int ne = m.num_elements();
  if (m.is_2d()) {
    ug->AllocateEstimate(ne, 16);
    std::vector<vtkIdType> ring;
    for (int e = 0; e < ne; ++e) {
      const int b = m.element_offsets[std::size_t(e)], n = m.num_vertices(e);
      ring.assign(m.element_vertices.begin() + b, m.element_vertices.begin() + b + n);
      ug->InsertNextCell(VTK_POLYGON, n, ring.data());
    }
    return;
  }
  ug->AllocateEstimate(ne, 64);
  FacePolygons faces;
  std::vector<vtkIdType> ids, stream;
  for (int e = 0; e < ne; ++e) {
    const int b = m.element_offsets[std::size_t(e)], n = m.num_vertices(e);
    ids.assign(m.element_vertices.begin() + b, m.element_vertices.begin() + b + n);
    faces.clear();
    append_element_faces(m, e, faces);
    stream.clear();
    for (int f = 0; f < faces.size(); ++f) {
      stream.push_back(faces.offsets[std::size_t(f) + 1] - faces.offsets[std::size_t(f)]);
      for (int k = faces.offsets[std::size_t(f)]; k < faces.offsets[std::size_t(f) + 1]; ++k)
        stream.push_back(faces.nodes[std::size_t(k)]);
    }
    ug->InsertNextCell(VTK_POLYHEDRON, n, ids.data(), faces.size(), stream.data());
  }
}

}  // namespace vx
